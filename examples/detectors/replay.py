#!/usr/bin/env python3
"""Serve recorded boxes over mlod-detector/1: the smallest working adapter.

    mlod detect --dataset sample_data --case top --sample TOKEN --json > top_TOKEN.json   # per sample
    mlod eval --dataset sample_data --case ext:replay \
        --detector "replay=python3 examples/detectors/replay.py top_*.json"

Each FILE is the output of `mlod detect --json` (one sample), a JSON list of such outputs, or a map
{sample_token: [box, ...]}. A sample with no recorded boxes gets none. Useful to evaluate boxes a
detector wrote offline as if it ran live, and as the skeleton of a real adapter.
"""
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from mlod_detector import serve  # noqa: E402


def load(paths):
    boxes = {}
    for path in paths:
        with open(path) as f:
            v = json.load(f)
        items = v if isinstance(v, list) else [v]
        for item in items:
            if "sample_token" in item and "detections" in item:
                boxes[item["sample_token"]] = item["detections"]
            else:
                boxes.update(item)
    return boxes


def main():
    if len(sys.argv) < 2:
        sys.exit("usage: replay.py FILE...  (outputs of `mlod detect --json`, or {token: [box, ...]})")
    boxes = load(sys.argv[1:])
    serve(lambda request, _points: boxes.get(request["sample_token"], []))


if __name__ == "__main__":
    main()
