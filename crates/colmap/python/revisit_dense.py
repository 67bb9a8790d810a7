"""Revisit's dense surfaces: each visit's own surface from its images at the model's poses.

Run by revisit-colmap's dense driver from the project's virtual environment (embedded in
the Rust binary and written next to the output). For every registered image of a visit, up to
PARTNERS images of the same visit that best see the same ground (viewing axes within 25
degrees, baseline 8-80% of the image's depth, nearest 30% first) are each rectified with it
(both cameras turned to look square to their baseline, distortion undone through the camera
model) and matched by OpenCV's semi-global block matching, at --scale of the resolution
(smoothed first). A pixel's depth is kept where at least two of these depth maps agree within
--agreement of the depth (two independent pairs put a point on a surface there) and where the
image shows texture (--min-texture: semi-global matching fills a textureless area from its
surroundings, and two pairs may make the same guess); the agreeing depths are averaged, sampled
every --step pixels, and the visit's points from all its images averaged in voxels of --voxel
of the altitude. On a survey flown in lines, an image's two nearest partners are usually the
one ahead and the one behind, each seeing a different half of it: the third and fourth (the
next ones along the line, or the neighbouring line's) give the rest of the image a second
pair. Sparse SfM points sample texture (sand grains); these sample every surface that shows
some, so a smooth coral table that a storm removed is in the earlier visit's surface, and sand
in the later.

Writes OUTPUT/<visit>.ply (binary little-endian: double x, y, z in the model's frame, uchar
red, green, blue) and prints one JSON line: per visit, its images, the images with at least two
partners, points and seconds. Logs go to stderr.
"""

import argparse
import itertools
import json
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pycolmap

# Partners: viewing axes within this cosine, baselines within these fractions of the depth.
MIN_AXIS_COSINE = 0.9
BASELINE_RANGE = (0.08, 0.8)
BASELINE_BEST = 0.3
# Partners an image is matched with: a pixel needs two of them to agree.
PARTNERS = 4
# Disparities searched, as fractions of the nominal one (depth 1/1.8 to 1/0.6 of the image's).
DISPARITY_RANGE = (0.6, 1.8)
BLOCK = 5


def visit_of_name(name: str) -> str:
    return name.split("/", 1)[0] if "/" in name else ""


def median_depths(rec) -> dict:
    """Each image's median depth of its triangulated points, by image id."""
    depths = {}
    for image_id, image in rec.images.items():
        xyz = [rec.points3D[p.point3D_id].xyz for p in image.points2D if p.has_point3D()]
        if xyz:
            z = (image.cam_from_world() * np.array(xyz))[:, 2]
            z = z[z > 0]
            if len(z):
                depths[image_id] = float(np.median(z))
    return depths


def partners(rec, image_id, images, depth) -> list:
    image = rec.images[image_id]
    axis = image.cam_from_world().rotation.matrix()[2]
    centre = image.projection_center()
    scored = []
    for other_id in images:
        if other_id == image_id:
            continue
        other = rec.images[other_id]
        if other.cam_from_world().rotation.matrix()[2] @ axis < MIN_AXIS_COSINE:
            continue
        ratio = np.linalg.norm(other.projection_center() - centre) / depth
        if BASELINE_RANGE[0] <= ratio <= BASELINE_RANGE[1]:
            scored.append((abs(ratio - BASELINE_BEST), other_id))
    return [other_id for _, other_id in sorted(scored)[:PARTNERS]]


def rectify(rec, image, pixels, canvas, rect_from_world, focal):
    """The image resampled as seen by a camera at its centre turned to rect_from_world."""
    width, height = canvas
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    rays = np.stack([(u - width / 2) / focal, (v - height / 2) / focal, np.ones_like(u)], -1).reshape(-1, 3)
    cam_from_rect = image.cam_from_world().rotation.matrix() @ rect_from_world.T
    in_cam = rays @ cam_from_rect.T
    ahead = in_cam[:, 2] > 1e-6
    camera = rec.cameras[image.camera_id]
    xy = np.full((len(rays), 2), -1.0)
    xy[ahead] = camera.img_from_cam(in_cam[ahead], check_cheirality=False) - 0.5
    map_x = xy[:, 0].reshape(height, width).astype(np.float32)
    map_y = xy[:, 1].reshape(height, width).astype(np.float32)
    warped = cv2.remap(pixels, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    inside = (map_x >= 0) & (map_x <= camera.width - 1) & (map_y >= 0) & (map_y <= camera.height - 1)
    return warped, inside


def pair_points(rec, image, other, pixels, depth, scale, min_texture):
    """World points of image's pixels matched in other (semi-global matching on the rectified pair)."""
    centre, other_centre = image.projection_center(), other.projection_center()
    x = other_centre - centre
    baseline = np.linalg.norm(x)
    x /= baseline
    z = image.cam_from_world().rotation.matrix()[2] + other.cam_from_world().rotation.matrix()[2]
    z -= (z @ x) * x
    z /= np.linalg.norm(z)
    rect_from_world = np.stack([x, np.cross(z, x), z])
    camera = rec.cameras[image.camera_id]
    focal = scale * float(np.mean(camera.calibration_matrix()[[0, 1], [0, 1]]))
    side = int(np.ceil(1.5 * scale * max(camera.width, camera.height)))
    canvas = (side, side)
    # Resampled at `scale`: smoothed first so that the coarser grid does not alias.
    smooth = (lambda p: cv2.GaussianBlur(p, (0, 0), 0.5 / scale)) if scale < 1 else (lambda p: p)
    left, left_in = rectify(rec, image, smooth(pixels[image.image_id]), canvas, rect_from_world, focal)
    right, right_in = rectify(rec, other, smooth(pixels[other.image_id]), canvas, rect_from_world, focal)
    nominal = focal * baseline / depth
    low = int(nominal * DISPARITY_RANGE[0]) // 16 * 16
    count = int(np.ceil((nominal * DISPARITY_RANGE[1] - low) / 16)) * 16
    sgbm = cv2.StereoSGBM_create(
        minDisparity=low, numDisparities=max(count, 16), blockSize=BLOCK,
        P1=8 * 3 * BLOCK * BLOCK, P2=32 * 3 * BLOCK * BLOCK, disp12MaxDiff=1, uniquenessRatio=10,
        speckleWindowSize=100, speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    disparity = sgbm.compute(left, right).astype(np.float64) / 16.0
    grey = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY).astype(np.float64)
    mean = cv2.blur(grey, (7, 7))
    texture = np.sqrt(np.maximum(cv2.blur(grey * grey, (7, 7)) - mean * mean, 0))
    textured = texture >= min_texture
    rows, cols = np.nonzero((disparity > low) & left_in & textured)
    d = disparity[rows, cols]
    seen = right_in[rows, np.clip(np.round(cols - d).astype(int), 0, side - 1)]
    rows, cols, d = rows[seen], cols[seen], d[seen]
    z_rect = focal * baseline / d
    in_rect = np.stack([(cols - side / 2) * z_rect / focal, (rows - side / 2) * z_rect / focal, z_rect], 1)
    return centre + in_rect @ rect_from_world


def depth_grid(rec, image, world, step):
    """Nearest depth of world points per step x step block of image's pixels (inf where none)."""
    camera = rec.cameras[image.camera_id]
    in_cam = image.cam_from_world() * world
    ahead = in_cam[:, 2] > 0
    in_cam = in_cam[ahead]
    uv = camera.img_from_cam(in_cam, check_cheirality=False)
    cols, rows = np.floor(uv[:, 0] / step).astype(int), np.floor(uv[:, 1] / step).astype(int)
    width, height = camera.width // step, camera.height // step
    keep = (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
    grid = np.full((height, width), np.inf)
    np.minimum.at(grid, (rows[keep], cols[keep]), in_cam[keep, 2])
    return grid


def fused_points(rec, image, grids, step, agreement):
    """The image's points where at least two pairs' depths agree, in the world frame, with pixels."""
    stack = np.stack(grids)
    finite = np.isfinite(stack)
    agreeing = np.zeros(stack.shape, bool)
    with np.errstate(invalid="ignore"):
        for i, j in itertools.permutations(range(len(grids)), 2):
            close = np.abs(stack[i] - stack[j]) <= agreement * np.minimum(stack[i], stack[j])
            agreeing[i] |= finite[i] & finite[j] & close
    count = agreeing.sum(0)
    rows, cols = np.nonzero(count >= 2)
    z = np.where(agreeing, stack, 0.0).sum(0)[rows, cols] / count[rows, cols]
    camera = rec.cameras[image.camera_id]
    uv = np.stack([(cols + 0.5) * step, (rows + 0.5) * step], 1)
    rays = camera.cam_from_img(uv)
    in_cam = np.concatenate([rays, np.ones((len(rays), 1))], 1) * z[:, None]
    world = image.cam_from_world().inverse() * in_cam
    return world, uv


def voxel_means(points, colours, voxel):
    """Points and colours averaged per voxel (in a fixed order: the same input, the same output)."""
    if len(points) == 0:
        return points, colours
    keys = np.floor(points / voxel).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, inverse, points)
    colour_sums = np.zeros((len(counts), 3))
    np.add.at(colour_sums, inverse, colours.astype(np.float64))
    return sums / counts[:, None], np.round(colour_sums / counts[:, None]).astype(np.uint8)


def write_ply(path: Path, points, colours) -> None:
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment Revisit dense surface of one visit, model frame\n"
        f"element vertex {len(points)}\nproperty double x\nproperty double y\nproperty double z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")
    vertex = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    rows = np.empty(len(points), dtype=vertex)
    for k, name in enumerate(("x", "y", "z")):
        rows[name] = points[:, k]
    for k, name in enumerate(("red", "green", "blue")):
        rows[name] = colours[:, k]
    part = path.with_suffix(".ply.part")
    with open(part, "wb") as out:
        out.write(header.encode("ascii"))
        out.write(rows.tobytes())
    os.replace(part, path)


def dense_visit(rec, visit, image_root: Path, output: Path, options) -> dict:
    started = time.monotonic()
    images = sorted(i for i, image in rec.images.items() if visit_of_name(image.name) == visit)
    depths = median_depths(rec)
    known = [depths[i] for i in images if i in depths]
    if not known:
        raise SystemExit(f"visit {visit}: no triangulated point in its images to tell the altitude")
    altitude = float(np.median(known))
    pixels = {}

    def load(image_id):
        if image_id not in pixels:
            path = image_root / rec.images[image_id].name
            read = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if read is None:
                raise SystemExit(f"{path}: cannot read the image (--images)")
            pixels[image_id] = read
        return pixels[image_id]

    all_points, all_colours, fused = [], [], 0
    for n, image_id in enumerate(images):
        image = rec.images[image_id]
        depth = depths.get(image_id, altitude)
        pair = partners(rec, image_id, images, depth)
        if len(pair) < 2:
            continue
        for other_id in [image_id, *pair]:
            load(other_id)
        grids = [depth_grid(rec, image, pair_points(rec, image, rec.images[o], pixels, depth, options.scale, options.min_texture),
                            options.step)
                 for o in pair]
        world, uv = fused_points(rec, image, grids, options.step, options.agreement)
        columns = np.clip(uv[:, 0].astype(int), 0, pixels[image_id].shape[1] - 1)
        rows = np.clip(uv[:, 1].astype(int), 0, pixels[image_id].shape[0] - 1)
        all_points.append(world)
        all_colours.append(pixels[image_id][rows, columns][:, ::-1])
        fused += 1
        print(f"dense {visit}: {n + 1}/{len(images)} {image.name}: {len(world)} points", file=sys.stderr, flush=True)
        # Keep the images a later image may pair with (its neighbours); drop the rest.
        for stale in [k for k in pixels if k not in pair and k != image_id]:
            del pixels[stale]
    points = np.concatenate(all_points) if all_points else np.zeros((0, 3))
    colours = np.concatenate(all_colours) if all_colours else np.zeros((0, 3), np.uint8)
    points, colours = voxel_means(points, colours, options.voxel * altitude)
    write_ply(output / f"{visit}.ply", points, colours)
    return {"visit": visit, "images": len(images), "fused": fused, "points": int(len(points)),
            "altitude": altitude, "seconds": time.monotonic() - started}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--model", type=Path, required=True)
    parser.add_argument("--image-path", type=Path, required=True)
    parser.add_argument("--output", type=Path, required=True)
    parser.add_argument("--visit", action="append", required=True)
    parser.add_argument("--step", type=int, default=4)
    parser.add_argument("--agreement", type=float, default=0.01)
    parser.add_argument("--min-texture", type=float, default=3.0)
    parser.add_argument("--voxel", type=float, default=0.01)
    parser.add_argument("--scale", type=float, default=0.5)
    parser.add_argument("--threads", type=int, default=0)
    options = parser.parse_args()
    cv2.setNumThreads(options.threads)
    rec = pycolmap.Reconstruction(str(options.model))
    options.output.mkdir(parents=True, exist_ok=True)
    visits = [dense_visit(rec, visit, options.image_path, options.output, options) for visit in options.visit]
    print(json.dumps({"visits": visits}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
