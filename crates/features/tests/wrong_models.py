"""Small ONNX models that break the output contracts of Revisit's learned
feature extractors, for crates/features/tests/wrong_models.rs.

Usage: wrong_models.py OUT_DIR

- xfeat_32_feats.onnx: an XFeat backbone whose `feats` output is declared
  (and is) [1, 32, H/8, W/8], not [1, 64, H/8, W/8];
- xfeat_dynamic_feats.onnx: one whose `feats` has as many channels as the
  image has 8-pixel columns, declared as a dynamic dimension, so that only a
  run shows the wrong count;
- aliked_64_descriptors.onnx: an ALIKED export of 32x32 whose `descriptors`
  are [1, 4, 64], not [1, 4, 128].
"""

import sys
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper


def save(graph, path):
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))


def xfeat(path, feats_channels):
    """Every output is the image's 8x8 cell means, repeated over the channels.
    `feats_channels` None: as many `feats` channels as cell columns, a count
    that only a run reveals."""
    image = helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 1, "height", "width"])
    channels = {"feats": feats_channels, "keypoints": 65, "heatmap": 1}
    shapes = {n: [1, c if c else "channels", "rows", "columns"] for n, c in channels.items()}
    outputs = [helper.make_tensor_value_info(n, TensorProto.FLOAT, shape) for n, shape in shapes.items()]
    nodes = [helper.make_node("AveragePool", ["image"], ["cells"], kernel_shape=[8, 8], strides=[8, 8])]
    initializers = []
    for name, count in channels.items():
        if count:
            initializers.append(numpy_helper.from_array(np.array([1, count, 1, 1], np.int64), f"{name}_repeats"))
        else:
            initializers.append(numpy_helper.from_array(np.array([1], np.int64), "one"))
            nodes += [
                helper.make_node("Shape", ["cells"], ["columns"], start=3),
                helper.make_node("Concat", ["one", "columns", "one", "one"], [f"{name}_repeats"], axis=0),
            ]
        nodes.append(helper.make_node("Tile", ["cells", f"{name}_repeats"], [name]))
    save(helper.make_graph(nodes, path.stem, [image], outputs, initializer=initializers), path)


def aliked_64_descriptors(path):
    """Fixed 32x32 input; four constant keypoints with 64-float descriptors."""
    image = helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, 32, 32])
    values = {
        "keypoints": np.full((1, 4, 2), 8.0, np.float32),
        "descriptors": np.full((1, 4, 64), 0.125, np.float32),
        "scores": np.ones((1, 4), np.float32),
    }
    outputs = [helper.make_tensor_value_info(n, TensorProto.FLOAT, list(v.shape)) for n, v in values.items()]
    nodes = [helper.make_node("Constant", [], [n], value=numpy_helper.from_array(v, n)) for n, v in values.items()]
    save(helper.make_graph(nodes, path.stem, [image], outputs), path)


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    xfeat(out / "xfeat_32_feats.onnx", 32)
    xfeat(out / "xfeat_dynamic_feats.onnx", None)
    aliked_64_descriptors(out / "aliked_64_descriptors.onnx")


if __name__ == "__main__":
    main()
