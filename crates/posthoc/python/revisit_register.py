"""Post-hoc registration of one visit's sparse point cloud onto another's, with Open3D.

Embedded in the `revisit` binary (crates/posthoc) and run with the project's Python. Reads two
PLY point clouds, estimates the similarity (scale, rotation, translation) taking MOVING onto
FIXED, and prints one JSON line:
  {"ok": true, "fixed_from_moving": 4x4 rows, "fitness": f, "inlier_rmse": f, "scale_start": f}
or {"ok": false, "reason": "..."} when the registration finds nothing.

Separately built models differ in scale, so every estimate here estimates it:
- icp: point-to-point ICP from a coarse start (the clouds' medians placed on each other, the
  scale from their spreads), coarse to fine correspondence distances, rigid then with scaling.
- fpfh: FPFH features on voxel-downsampled clouds at the coarse scale, rigid RANSAC global
  registration on feature matches, then the same ICP from its result.
"""

import argparse
import json
import sys

import numpy as np
import open3d as o3d

reg = o3d.pipelines.registration

# ICP's correspondence distances, as fractions of the fixed cloud's spread (coarse to fine), and
# whether the step estimates scale: rigid steps first, since point-to-point ICP with scale far
# from convergence shrinks the moving cloud onto a few fixed points.
ICP_STEPS = ((0.3, False), (0.1, False), (0.03, True), (0.03, True))
# A scale this far from the coarse start (either way) is a collapse, not an alignment.
MAX_SCALE_CHANGE = 3.0
# FPFH works on clouds downsampled to this fraction of the spread.
VOXEL_OF_SPREAD = 1.0 / 40.0
# A registration whose fitness (share of moving points with a fixed point within the finest
# distance) is below this has found nothing.
MIN_FITNESS = 0.05


def median_and_spread(points):
    centre = np.median(points, axis=0)
    return centre, float(np.median(np.linalg.norm(points - centre, axis=1)))


def coarse_start(fixed, moving):
    """The centroids on each other and the spreads matched: what a user without navigation has."""
    cf, sf = median_and_spread(np.asarray(fixed.points))
    cm, sm = median_and_spread(np.asarray(moving.points))
    scale = sf / max(sm, 1e-12)
    start = np.eye(4)
    start[:3, :3] *= scale
    start[:3, 3] = cf - scale * cm
    return start, sf, scale


def icp(fixed, moving, start, spread):
    transform, result = start, None
    for fraction, with_scaling in ICP_STEPS:
        result = reg.registration_icp(
            moving,
            fixed,
            fraction * spread,
            transform,
            reg.TransformationEstimationPointToPoint(with_scaling=with_scaling),
            reg.ICPConvergenceCriteria(max_iteration=200),
        )
        transform = result.transformation
    return result


def fpfh_features(cloud, voxel):
    down = cloud.voxel_down_sample(voxel)
    down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2.0 * voxel, max_nn=30))
    features = reg.compute_fpfh_feature(down, o3d.geometry.KDTreeSearchParamHybrid(radius=5.0 * voxel, max_nn=100))
    return down, features


def fpfh(fixed, moving, start, spread):
    """Global registration: rigid RANSAC on FPFH matches after the coarse scale (FPFH's radii
    are metric, so both clouds must be at about one scale first), then ICP with scaling."""
    scale = start[0, 0]
    prescaled = o3d.geometry.PointCloud(moving)
    prescaled.scale(scale, center=np.zeros(3))
    voxel = VOXEL_OF_SPREAD * spread
    fixed_down, fixed_features = fpfh_features(fixed, voxel)
    moving_down, moving_features = fpfh_features(prescaled, voxel)
    distance = 1.5 * voxel
    result = reg.registration_ransac_based_on_feature_matching(
        moving_down,
        fixed_down,
        moving_features,
        fixed_features,
        True,
        distance,
        reg.TransformationEstimationPointToPoint(with_scaling=False),
        3,
        [
            reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
            reg.CorrespondenceCheckerBasedOnDistance(distance),
        ],
        reg.RANSACConvergenceCriteria(100000, 0.999),
    )
    if len(result.correspondence_set) < 3:
        return None
    prescale = np.eye(4)
    prescale[:3, :3] *= scale
    return icp(fixed, moving, result.transformation @ prescale, spread)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fixed", required=True)
    parser.add_argument("--moving", required=True)
    parser.add_argument("--method", choices=["icp", "fpfh"], required=True)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    o3d.utility.random.seed(args.seed)
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)

    fixed = o3d.io.read_point_cloud(args.fixed)
    moving = o3d.io.read_point_cloud(args.moving)
    for name, cloud in (("fixed", fixed), ("moving", moving)):
        if len(cloud.points) < 10:
            print(json.dumps({"ok": False, "reason": f"the {name} cloud has {len(cloud.points)} points"}))
            return
    start, spread, scale_start = coarse_start(fixed, moving)
    result = icp(fixed, moving, start, spread) if args.method == "icp" else fpfh(fixed, moving, start, spread)
    if result is None:
        print(json.dumps({"ok": False, "reason": "global registration found no consistent feature matches"}))
        return
    transform = np.asarray(result.transformation)
    scale = np.cbrt(np.linalg.det(transform[:3, :3]))
    if not np.all(np.isfinite(transform)) or not 1 / MAX_SCALE_CHANGE < scale / scale_start < MAX_SCALE_CHANGE:
        print(json.dumps({"ok": False, "reason": f"the scale collapsed to {scale:.3g} (coarse start {scale_start:.3g})"}))
        return
    if result.fitness < MIN_FITNESS:
        reason = f"fitness {result.fitness:.3f} < {MIN_FITNESS}: the clouds were not brought together"
        print(json.dumps({"ok": False, "reason": reason}))
        return
    print(
        json.dumps(
            {
                "ok": True,
                "fixed_from_moving": transform.tolist(),
                "fitness": result.fitness,
                "inlier_rmse": result.inlier_rmse,
                "scale_start": scale_start,
            }
        )
    )


if __name__ == "__main__":
    sys.exit(main())
