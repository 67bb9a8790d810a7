"""OpenCV's SIFT on a list of images, for `revisit bench sift`.

Usage: opencv_sift.py --max-features N --threads T --out FILE LIST

LIST is a text file with one image path per line. Only `detectAndCompute` is
timed, per image. Keypoints are converted to COLMAP's conventions (pixel-corner
coordinates: + 0.5; scale = sigma = size / 2; orientation in radians in the
y-down image frame) and descriptors to RootSIFT bytes the way COLMAP stores them
(L1-normalise, square root, min(255, round(512 v))).

Note: OpenCV's doubled first octave is centre-aligned but reported as if it were
corner-aligned, so its positions carry a constant +0.25 px offset; it is left
as is (a constant offset in both images does not change verification).

Output (little-endian): b"RVSIFT01", u32 image count, then per image: u32
keypoint count n, f64 seconds, n x 4 f32 (x, y, scale, orientation), n x 128 u8.
"""

import argparse
import struct
import sys
import time

import cv2
import numpy as np


def root_sift_bytes(descriptors: np.ndarray) -> np.ndarray:
    d = descriptors.astype(np.float64)
    d /= np.maximum(d.sum(axis=1, keepdims=True), 1e-12)
    d = np.sqrt(d)
    return np.minimum(255.0, np.round(512.0 * d)).astype(np.uint8)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("list", help="text file with one image path per line")
    parser.add_argument("--max-features", type=int, default=2048)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()

    cv2.setNumThreads(args.threads)
    with open(args.list, encoding="utf-8") as f:
        paths = [line.strip() for line in f if line.strip()]
    sift = cv2.SIFT_create(nfeatures=args.max_features)
    with open(args.out, "wb") as out:
        out.write(b"RVSIFT01")
        out.write(struct.pack("<I", len(paths)))
        for path in paths:
            image = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
            if image is None:
                print(f"error: cannot read image {path}", file=sys.stderr)
                return 1
            start = time.perf_counter()
            keypoints, descriptors = sift.detectAndCompute(image, None)
            seconds = time.perf_counter() - start
            n = len(keypoints)
            frames = np.array(
                [(k.pt[0] + 0.5, k.pt[1] + 0.5, k.size / 2.0, np.deg2rad(k.angle)) for k in keypoints],
                dtype="<f4",
            ).reshape(n, 4)
            if descriptors is None:
                descriptors = np.zeros((0, 128), dtype=np.float32)
            out.write(struct.pack("<Id", n, seconds))
            out.write(frames.tobytes())
            out.write(root_sift_bytes(descriptors).tobytes())
    return 0


if __name__ == "__main__":
    sys.exit(main())
