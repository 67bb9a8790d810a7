"""Revisit's mapping entry point: one joint COLMAP run over a Revisit store.

Run by revisit-colmap's mapper driver from the project's virtual environment
(it is embedded in the Rust binary and written next to the output, with the
module it imports, revisit_change_aware.py). Reads the store (a COLMAP
database), maps with pycolmap (change-aware when asked), writes every model it produced to
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

from revisit_change_aware import adjustment, map_jointly, umeyama, visit_of_name


# The smallest standard deviation a de-biased navigation prior is given, metres.
MIN_DRIFT_SIGMA_M = 0.01
# COLMAP adjusts the whole model again each time it has grown by this factor (in images and in
# points; its default 1.1), and once more at the end. On the 110 subvo frames (one thread) 1.25
# maps in 96 s instead of 134 s with every image registered, the same mean reprojection error
# (0.418 px) and camera centres within 0.04% of the track's radius of the default's; at 1.4
# (82 s) they move by 0.5%. The number of global adjustments grows with the log of the
# survey's size, so the saving holds at any size.
GLOBAL_BA_GROWTH = 1.25


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


def read_priors(database: Path) -> dict:
    """Each image's pose prior (navigation) with a position, by image id."""
    import pycolmap

    db = pycolmap.Database.open(str(database))
    try:
        return {p.corr_data_id.id: p for p in db.read_all_pose_priors() if p.has_position()}
    finally:
        db.close()


def visit_of(image):
    return visit_of_name(image.name)


def with_priors(model, priors):
    """(image ids, camera centres, prior positions) of the registered images with a prior."""
    import numpy as np

    ids = sorted(i for i, image in model.images.items() if image.has_pose and i in priors)
    centres = np.array([model.images[i].projection_center() for i in ids]).reshape(-1, 3)
    positions = np.array([priors[i].position for i in ids]).reshape(-1, 3)
    return ids, centres, positions


def covariance(prior):
    """A prior's position covariance, None when unknown."""
    import numpy as np

    c = np.asarray(prior.position_covariance)
    return c if np.all(np.isfinite(c)) else None


def place_on_navigation(model, priors, constant, seed, threads, refine=True):
    """Places `model` on the navigation: a similarity onto the prior positions, then (`refine`)
    bundle adjustment with each camera's prior, per visit de-biased.

    A visit's navigation carries one error common to all its images (its position fix, e.g.
    USBL) and one that grows along the track (dead-reckoning drift). The images tie visits to
    each other far more tightly than a fix does, so each visit's common offset is estimated from
    the images (its mean gap to the model after the similarity) and taken out of its priors, and
    each prior is weighted by the part of its covariance beyond the visit's smallest (the drift):
    the navigation then fixes the model's frame, metric scale and every visit's shape and scale,
    and the images the visits' placement relative to each other. Returns, per visit, the offset
    taken out (metres) and its size in standard deviations of the visit's common error (None
    when unknown); None when fewer than 3 registered images have a prior."""
    import numpy as np
    import pycolmap

    ids, centres, positions = with_priors(model, priors)
    if len(ids) < 3:
        return None
    scale, rotation, translation = umeyama(centres, positions)
    model.transform(pycolmap.Sim3d(scale, pycolmap.Rotation3d(rotation), translation))
    visits = {}
    for i in ids:
        visits.setdefault(visit_of(model.images[i]), []).append(i)
    common = {}
    for visit, members in visits.items():
        known = [covariance(priors[i]) for i in members]
        common[visit] = None if any(c is None for c in known) else np.min([np.diag(c) for c in known], axis=0)
    rounds = 3 if refine else 1
    for _ in range(rounds):
        ids, centres, positions = with_priors(model, priors)
        row = {i: k for k, i in enumerate(ids)}
        offsets = {v: np.mean([positions[row[i]] - centres[row[i]] for i in m], axis=0) for v, m in visits.items()}
        if not refine:
            break
        adjusted = []
        for i in ids:
            prior, visit = priors[i], visit_of(model.images[i])
            full = covariance(prior)
            drift = None if full is None or common[visit] is None else np.diag(
                np.maximum(np.diag(full) - common[visit], MIN_DRIFT_SIGMA_M ** 2))
            debiased = pycolmap.PosePrior(position=positions[row[i]] - offsets[visit],
                                          coordinate_system=prior.coordinate_system)
            if drift is not None:
                debiased.position_covariance = drift
            debiased.corr_data_id = prior.corr_data_id
            adjusted.append(debiased)
        options, config = adjustment(model, constant, threads)
        prior_options = pycolmap.PosePriorBundleAdjustmentOptions()
        prior_options.ceres.prior_position_loss_function_type = pycolmap.LossFunctionType.CAUCHY
        prior_options.alignment_ransac.random_seed = seed
        pycolmap.create_pose_prior_bundle_adjuster(options, prior_options, config, adjusted, model).solve()
    placed = {}
    for visit, offset in offsets.items():
        sigmas = None
        if common[visit] is not None:
            sigmas = float(np.sqrt(np.sum(offset ** 2 / np.maximum(common[visit], 1e-12))))
        placed[visit] = {"offset_m": float(np.linalg.norm(offset)), "offset_sigmas": sigmas}
    return placed


def navigation_rms_m(model, priors):
    """RMS distance between the registered cameras' centres and their prior positions, in the
    model's units (metres when it is placed on the priors); None without priors."""
    import numpy as np

    ids, centres, positions = with_priors(model, priors)
    return float(np.sqrt(np.mean(np.sum((centres - positions) ** 2, axis=1)))) if ids else None


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
                        help="place the models on the database's pose priors (navigation) after mapping")
    parser.add_argument("--change-aware", action="store_true",
                        help="map each visit alone, place the visits by their cross-visit matches' consensus "
                             "and solve jointly on the matches that hold (incremental engine, fresh mappings)")
    args = parser.parse_args()

    try:
        import pycolmap
    except ImportError as err:
        print(f"pycolmap is not importable from {sys.executable}: {err}", file=sys.stderr)
        return 3

    constant = {int(c) for c in args.constant_cameras.split(",") if c}
    priors = read_priors(args.database) if args.pose_priors else {}
    change_aware = None
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
        options.ba_global_frames_ratio = GLOBAL_BA_GROWTH
        options.ba_global_points_ratio = GLOBAL_BA_GROWTH
        options.constant_cameras = constant
        options.mapper.constant_cameras = constant
        if constant and constant >= all_cameras(args.database):
            # pycolmap 4.2.1's incremental pipeline does not hold every constant camera in
            # every bundle adjustment: a calibrated camera's focal length was seen refined from
            # 512 to 163 px (a visit bent by 10 degrees). With every camera calibrated, turn
            # intrinsics refinement off altogether.
            options.ba_refine_focal_length = False
            options.ba_refine_principal_point = False
            options.ba_refine_extra_params = False
        raw = args.output / "raw"
        raw.mkdir()
        jointly = None
        if args.change_aware and not args.input_path:
            jointly = map_jointly(args.database, args.image_path, raw / "change-aware", options, priors,
                                  args.seed, args.threads, constant)
        if jointly:
            models, change_aware = jointly
        else:
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
    # Mapped from the images alone, then placed on the navigation: the largest model refined
    # with its priors, the others (visits not linked to it) only moved onto theirs.
    placements = [place_on_navigation(model, priors, constant, args.seed, args.threads, refine=(k == 0))
                  if priors else None
                  for k, model in enumerate(ordered)]
    on_priors = bool(ordered) and placements[0] is not None
    summary = []
    for k, (model, placed) in enumerate(zip(ordered, placements)):
        path = args.output / str(k)
        path.mkdir()
        model.write_binary(str(path))
        summary.append({
            "path": str(path),
            "registered_images": sorted(img.name for img in model.images.values() if img.has_pose),
            "points": model.num_points3D(),
            "mean_reprojection_error_px": model.compute_mean_reprojection_error(),
            "navigation_rms_m": navigation_rms_m(model, priors) if placed else None,
            "navigation_offsets": placed or {},
        })
    print(json.dumps({"seconds": time.monotonic() - started, "models": summary, "on_priors": on_priors,
                      "change_aware": change_aware, "peak_rss_mib": peak_rss_mib()}))
    return 0


if __name__ == "__main__":
    exit_with_parent()
    sys.exit(main())
