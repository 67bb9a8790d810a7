"""Reads a COLMAP model with pycolmap, dumps it as JSON on stdout, and writes it
back in pycolmap's binary and text forms.

Used by crates/colmap/tests/pycolmap.rs as an independent implementation of
COLMAP's model formats. Usage: colmap_roundtrip.py IN_DIR OUT_BIN_DIR OUT_TXT_DIR
"""

import json
import os
import sys

import pycolmap


def dump(rec):
    cameras = {}
    for camera_id, cam in rec.cameras.items():
        cameras[str(camera_id)] = {
            "model": cam.model.name,
            "width": cam.width,
            "height": cam.height,
            "params": [float(p) for p in cam.params],
        }
    images = {}
    for image_id, image in rec.images.items():
        pose = image.cam_from_world()
        x, y, z, w = (float(v) for v in pose.rotation.quat)
        images[str(image_id)] = {
            "name": image.name,
            "camera_id": image.camera_id,
            "qvec": [w, x, y, z],
            "tvec": [float(v) for v in pose.translation],
            "points2D": [
                [float(p.xy[0]), float(p.xy[1]), p.point3D_id if p.has_point3D() else -1]
                for p in image.points2D
            ],
        }
    points = {}
    for point_id, point in rec.points3D.items():
        points[str(point_id)] = {
            "xyz": [float(v) for v in point.xyz],
            "rgb": [int(v) for v in point.color],
            "error": float(point.error),
            "track": [[e.image_id, e.point2D_idx] for e in point.track.elements],
        }
    return {"version": pycolmap.__version__, "cameras": cameras, "images": images, "points3D": points}


def main():
    in_dir, out_bin, out_txt = sys.argv[1:4]
    rec = pycolmap.Reconstruction(in_dir)
    os.makedirs(out_bin, exist_ok=True)
    os.makedirs(out_txt, exist_ok=True)
    rec.write_binary(out_bin)
    rec.write_text(out_txt)
    json.dump(dump(rec), sys.stdout)


if __name__ == "__main__":
    main()
