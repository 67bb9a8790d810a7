"""Revisit's mapping entry point: one joint COLMAP run over a Revisit store.

Run by revisit-colmap's mapper driver from the project's virtual environment
(it is embedded in the Rust binary and written next to the output). Reads the
store (a COLMAP database), maps with pycolmap, writes every model it produced to
OUTPUT/<k> (k = 0, 1, ... by decreasing number of registered images), and
prints one JSON line with a summary of each model on stdout. Logs go to stderr.
"""

import argparse
import json
import os
import shutil
import sqlite3
import sys
import threading
import time
from pathlib import Path


def exit_with_parent() -> None:
    """Ends this process when the one that started it dies (a mapper node killed with SIGKILL
    must not leave COLMAP writing into the folder its restart maps again)."""
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.2)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def all_cameras(database: Path) -> set:
    with sqlite3.connect(f"file:{database}?mode=ro", uri=True) as db:
        return {row[0] for row in db.execute("SELECT camera_id FROM cameras")}


def prior_positions(database: Path) -> dict:
    """Each image's prior position (navigation), by image id."""
    import pycolmap
    import numpy as np

    db = pycolmap.Database.open(str(database))
    try:
        return {p.corr_data_id.id: np.asarray(p.position) for p in db.read_all_pose_priors() if p.has_position()}
    finally:
        db.close()


def navigation_rms_m(model, priors: dict):
    """RMS distance between the registered cameras' centres and their prior positions, in the
    model's units (metres when it is placed on the priors); None without priors."""
    import numpy as np

    gaps = [np.linalg.norm(img.projection_center() - priors[img.image_id])
            for img in model.images.values() if img.has_pose and img.image_id in priors]
    return float(np.sqrt(np.mean(np.square(gaps)))) if gaps else None


def peak_rss_mib():
    """This process's peak resident memory, MiB (Linux's VmHWM: unlike ru_maxrss, it does not
    count the parent's memory at the fork that started this process)."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--database", required=True, type=Path)
    parser.add_argument("--image-path", required=True, type=Path)
    parser.add_argument("--output", required=True, type=Path)
    parser.add_argument("--engine", choices=["incremental", "global"], default="incremental")
    parser.add_argument("--input-path", type=Path, default=None,
                        help="existing model to extend (incremental only)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=-1)
    parser.add_argument("--min-model-size", type=int, default=10)
    parser.add_argument("--min-pose-inliers", type=int, default=30,
                        help="fewest 2D-3D inliers with which an image joins a model")
    parser.add_argument("--constant-cameras", default="",
                        help="comma-separated ids of calibrated cameras, whose intrinsics are held fixed")
    parser.add_argument("--pose-priors", action="store_true",
                        help="place the model on the database's pose priors (navigation)")
    args = parser.parse_args()

    try:
        import pycolmap
    except ImportError as err:
        print(f"pycolmap is not importable from {sys.executable}: {err}", file=sys.stderr)
        return 3

    constant = {int(c) for c in args.constant_cameras.split(",") if c}
    if args.output.exists():
        shutil.rmtree(args.output)
    args.output.mkdir(parents=True)
    started = time.monotonic()
    if args.engine == "incremental":
        options = pycolmap.IncrementalPipelineOptions()
        options.random_seed = args.seed
        options.num_threads = args.threads
        options.min_model_size = args.min_model_size
        options.mapper.random_seed = args.seed
        options.mapper.num_threads = args.threads
        options.mapper.abs_pose_min_num_inliers = args.min_pose_inliers
        options.constant_cameras = constant
        options.mapper.constant_cameras = constant
        if args.pose_priors:
            # Bundle adjustment with each camera's prior position, weighted by its covariance,
            # Cauchy-robust (a navigation glitch pulls little); the model ends in the priors' frame.
            options.use_prior_position = True
            options.use_robust_loss_on_prior_position = True
        raw = args.output / "raw"
        raw.mkdir()
        models = pycolmap.incremental_mapping(
            args.database, args.image_path, raw, options,
            input_path=str(args.input_path) if args.input_path else "",
        )
    else:
        options = pycolmap.GlobalPipelineOptions()
        if hasattr(options, "random_seed"):
            options.random_seed = args.seed
        if hasattr(options, "num_threads"):
            options.num_threads = args.threads
        # GLOMAP holds all cameras fixed or none.
        if constant and constant >= all_cameras(args.database):
            ba = options.mapper.bundle_adjustment
            ba.refine_focal_length = False
            ba.refine_principal_point = False
            ba.refine_extra_params = False
        raw = args.output / "raw"
        raw.mkdir()
        models = pycolmap.global_mapping(args.database, args.image_path, raw, options)
    shutil.rmtree(raw, ignore_errors=True)

    ordered = sorted(models.values(), key=lambda r: (-r.num_reg_images(), -r.num_points3D()))
    # GLOMAP in pycolmap 4.2 has no pose-prior adjustment: its models stay in their own frame.
    on_priors = args.pose_priors and args.engine == "incremental"
    priors = prior_positions(args.database) if on_priors else {}
    summary = []
    for k, model in enumerate(ordered):
        path = args.output / str(k)
        path.mkdir()
        model.write_binary(str(path))
        summary.append({
            "path": str(path),
            "registered_images": sorted(img.name for img in model.images.values() if img.has_pose),
            "points": model.num_points3D(),
            "mean_reprojection_error_px": model.compute_mean_reprojection_error(),
            "navigation_rms_m": navigation_rms_m(model, priors),
        })
    print(json.dumps({"seconds": time.monotonic() - started, "models": summary, "on_priors": on_priors,
                      "peak_rss_mib": peak_rss_mib()}))
    return 0


if __name__ == "__main__":
    exit_with_parent()
    sys.exit(main())
