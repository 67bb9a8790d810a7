"""Small ONNX place-recognition models for Revisit's tests.

Usage: place_test_models.py OUT_DIR

Writes four models that follow (or break) the contract of
`revisit reconstruct --vpr-model` (an RGB image [1, 3, H, W] in [0, 1] in,
one descriptor [1, D] out):
- grid_64.onnx: fixed 64x64 input; the mean colour of each cell of a 4x4 grid,
  a 48-float descriptor (Revisit resizes images to the input's size);
- mean_dynamic.onnx: any H and W; the image's mean colour (3 floats);
- grey_input.onnx: takes a [1, 1, H, W] grey image, which breaks the contract;
- two_rows.onnx: gives two descriptors [2, 3], which breaks it after a run.
"""

import sys
from pathlib import Path

import onnx
from onnx import TensorProto, helper


def save(graph, path):
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))


def grid_64(path):
    image = helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, 64, 64])
    descriptor = helper.make_tensor_value_info("descriptor", TensorProto.FLOAT, [1, 48])
    nodes = [
        helper.make_node("AveragePool", ["image"], ["cells"], kernel_shape=[16, 16], strides=[16, 16]),
        helper.make_node("Flatten", ["cells"], ["descriptor"], axis=1),
    ]
    save(helper.make_graph(nodes, "grid_64", [image], [descriptor]), path)


def global_mean(path, input_name, channels):
    """Any H and W; the image's mean per channel (`channels` floats)."""
    image = helper.make_tensor_value_info(input_name, TensorProto.FLOAT, [1, channels, "height", "width"])
    descriptor = helper.make_tensor_value_info("descriptor", TensorProto.FLOAT, [1, channels])
    nodes = [
        helper.make_node("GlobalAveragePool", [input_name], ["mean"]),
        helper.make_node("Flatten", ["mean"], ["descriptor"], axis=1),
    ]
    save(helper.make_graph(nodes, path.stem, [image], [descriptor]), path)


def two_rows(path):
    """The image's mean colour, twice: a [2, 3] output."""
    image = helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, "height", "width"])
    descriptor = helper.make_tensor_value_info("descriptor", TensorProto.FLOAT, [2, 3])
    nodes = [
        helper.make_node("GlobalAveragePool", ["image"], ["mean"]),
        helper.make_node("Flatten", ["mean"], ["row"], axis=1),
        helper.make_node("Concat", ["row", "row"], ["descriptor"], axis=0),
    ]
    save(helper.make_graph(nodes, path.stem, [image], [descriptor]), path)


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    grid_64(out / "grid_64.onnx")
    global_mean(out / "mean_dynamic.onnx", "image", 3)
    global_mean(out / "grey_input.onnx", "grey", 1)
    two_rows(out / "two_rows.onnx")


if __name__ == "__main__":
    main()
