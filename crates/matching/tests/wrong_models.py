"""Small ONNX models that break the output contract of Revisit's LightGlue
matchers, for crates/matching/tests/wrong_models.rs.

Usage: wrong_models.py OUT_DIR

Both take LighterGlue's inputs (kpts0/1 [1, M|N, 2], desc0/1 [1, M|N, 64],
size0/1 [1, 2]) and score with descriptor dot products:
- transposed_scores.onnx: `scores` is [1, N+1, M+1] (image b's keypoints
  first), not [1, M+1, N+1]: only a run shows it, when M != N;
- flat_scores.onnx: `scores` is declared (and is) [1, (M+1) * (N+1)].
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


def matcher(path, flat):
    f = TensorProto.FLOAT
    inputs = [
        helper.make_tensor_value_info("kpts0", f, [1, "m", 2]),
        helper.make_tensor_value_info("kpts1", f, [1, "n", 2]),
        helper.make_tensor_value_info("desc0", f, [1, "m", 64]),
        helper.make_tensor_value_info("desc1", f, [1, "n", 64]),
        helper.make_tensor_value_info("size0", f, [1, 2]),
        helper.make_tensor_value_info("size1", f, [1, 2]),
    ]
    initializers = [numpy_helper.from_array(np.array([0, 0, 0, 0, 1, 1], np.int64), "pads")]
    nodes = [
        helper.make_node("Transpose", ["desc0"], ["desc0_t"], perm=[0, 2, 1]),
        helper.make_node("MatMul", ["desc1", "desc0_t"], ["similarity"]),
        helper.make_node("Pad", ["similarity", "pads"], ["padded" if flat else "scores"]),
    ]
    if flat:
        initializers.append(numpy_helper.from_array(np.array([1, -1], np.int64), "flat_shape"))
        nodes.append(helper.make_node("Reshape", ["padded", "flat_shape"], ["scores"]))
        shape = [1, "cells"]
    else:
        shape = [1, "rows", "columns"]
    outputs = [helper.make_tensor_value_info("scores", f, shape)]
    save(helper.make_graph(nodes, path.stem, inputs, outputs, initializer=initializers), path)


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    matcher(out / "transposed_scores.onnx", flat=False)
    matcher(out / "flat_scores.onnx", flat=True)


if __name__ == "__main__":
    main()
