"""pycolmap's own pipeline on a set of images, for `revisit bench colmap`.

SIFT extraction (one camera per folder, i.e. per session), exhaustive or
sequential matching with COLMAP's geometric verification, and incremental
mapping, each stage timed. Prints one JSON line: seconds per stage, images
registered in the largest model, number of models, and the process's peak
resident memory. Everything runs on the CPU with `--threads` threads.
"""

import argparse
import json
import sys
import time
from pathlib import Path


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
    parser.add_argument("--image-path", required=True, type=Path, help="root the image names are relative to")
    parser.add_argument("--image-list", required=True, type=Path, help="one image name per line")
    parser.add_argument("--work", required=True, type=Path, help="empty folder for the database and models")
    parser.add_argument("--matching", choices=["exhaustive", "sequential"], default="exhaustive")
    parser.add_argument("--max-features", type=int, default=4096)
    parser.add_argument("--threads", type=int, default=-1)
    parser.add_argument("--camera-model", default="SIMPLE_RADIAL")
    parser.add_argument("--camera-params", default="", help="COLMAP's parameter order; empty: estimated")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    import pycolmap

    pycolmap.logging.minloglevel = 1  # warnings and errors only: the stages' times are the output

    names = [line.strip() for line in args.image_list.read_text().splitlines() if line.strip()]
    args.work.mkdir(parents=True, exist_ok=True)
    database = args.work / "database.db"
    if database.exists():
        database.unlink()
    seconds = {}

    started = time.monotonic()
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = args.threads
    extraction.use_gpu = False
    extraction.sift.max_num_features = args.max_features
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = args.camera_model
    reader.camera_params = args.camera_params
    pycolmap.extract_features(
        database, args.image_path, image_names=names, camera_mode=pycolmap.CameraMode.PER_FOLDER,
        reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu,
    )
    seconds["features"] = time.monotonic() - started

    started = time.monotonic()
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = args.threads
    matching.use_gpu = False
    if args.matching == "exhaustive":
        pycolmap.match_exhaustive(database, matching_options=matching, device=pycolmap.Device.cpu)
    else:
        pycolmap.match_sequential(database, matching_options=matching, device=pycolmap.Device.cpu)
    seconds["matching"] = time.monotonic() - started

    started = time.monotonic()
    options = pycolmap.IncrementalPipelineOptions()
    options.random_seed = args.seed
    options.num_threads = args.threads
    options.mapper.random_seed = args.seed
    options.mapper.num_threads = args.threads
    models = pycolmap.incremental_mapping(database, args.image_path, args.work / "sparse", options)
    seconds["mapping"] = time.monotonic() - started

    registered = max((m.num_reg_images() for m in models.values()), default=0)
    print(json.dumps({
        "seconds": seconds,
        "images": len(names),
        "registered": registered,
        "models": len(models),
        "peak_rss_mib": peak_rss_mib(),
    }))
    return 0


if __name__ == "__main__":
    sys.exit(main())
