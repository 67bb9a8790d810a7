"""The Python side of `revisit bench bag`: read every message of an mcap bag with mcap +
mcap-ros2-support, decode it, and turn every image message into pixels (numpy; cv2 for
compressed), the same work Revisit's side does. Prints one JSON line of figures.

usage: bag_read.py MCAP_FILE REPEATS
"""
import json
import statistics
import sys
import time

import cv2
import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

CHANNELS = {"mono8": 1, "mono16": 1, "rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4}


def read(path):
    messages = images = 0
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, _, _, message in reader.iter_decoded_messages(log_time_order=False):
            messages += 1
            if schema.name == "sensor_msgs/msg/Image":
                dtype = np.uint16 if message.encoding.endswith("16") else np.uint8
                rows = np.frombuffer(message.data, dtype=np.uint8).reshape(message.height, message.step)
                width_bytes = message.width * CHANNELS.get(message.encoding, 1) * np.dtype(dtype).itemsize
                pixels = np.ascontiguousarray(rows[:, :width_bytes]).view(dtype)
                images += int(pixels.size > 0)
            elif schema.name == "sensor_msgs/msg/CompressedImage":
                pixels = cv2.imdecode(np.frombuffer(message.data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
                images += int(pixels is not None)
    return messages, images


def main():
    path, repeats = sys.argv[1], int(sys.argv[2])
    cv2.setNumThreads(1)
    seconds = []
    for _ in range(repeats):
        start = time.perf_counter()
        messages, images = read(path)
        seconds.append(time.perf_counter() - start)
    print(json.dumps({"messages": messages, "images": images, "seconds_median": statistics.median(seconds)}))


if __name__ == "__main__":
    main()
