#!/usr/bin/env python3
"""How far each confident box of a LiDAR-Top sits above the ground estimate of `--ground-gate`
(the 10th percentile of the lowest points of the 1 m cells within 6 m of its centre) on the six
KITTI frames, and whether a labelled car lies within 2 m of it (docs/realism.md, "Walls at the
curb"). Plain Python, no numpy: a few seconds per frame.

Usage: MLOD=target/release/mlod scripts/kitti_ground_lift.py MODELS [KITTI_DIR]
"""
import json
import math
import os
import struct
import subprocess
import sys

MLOD = os.environ.get("MLOD", "mlod")


def run(*args):
    out = subprocess.run([MLOD, *args], capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def main():
    models = sys.argv[1]
    kitti = sys.argv[2] if len(sys.argv) > 2 else "../shared/real-lidar/kitti"
    for tok in ["000000", "000001", "000002", "000003", "000004", "000005"]:
        raw = open(f"{kitti}/training/velodyne/{tok}.bin", "rb").read()
        pts = [struct.unpack_from("<4f", raw, i * 16) for i in range(len(raw) // 16)]
        labels = run("inspect", "--dataset", kitti, "--sample", tok, "--json")
        cars = [b["center"] for b in labels["boxes"] if b["category"] == "car"]
        dets = run("detect", "--dataset", kitti, "--sample", tok, "--case", "top",
                   "--models", models, "--ground-gate", "off", "--json")
        for d in dets["detections"]:
            x, y, z = d["center"]
            if d["score"] < 0.3 or math.hypot(x, y) > 50 or x <= 0:
                continue
            cells = {}
            for p in pts:
                if (p[0] - x) ** 2 + (p[1] - y) ** 2 < 64:
                    key = (math.floor(p[0]), math.floor(p[1]))
                    if math.hypot(key[0] + 0.5 - x, key[1] + 0.5 - y) <= 6:
                        cells[key] = min(cells.get(key, math.inf), p[2])
            lows = sorted(cells.values())
            if len(lows) < 5:
                continue
            ground = lows[round((len(lows) - 1) * 0.1)]
            lift = z - d["size_lwh"][2] / 2 - ground
            car = any(math.hypot(x - c[0], y - c[1]) < 2 for c in cars)
            print(f"{tok} {'car' if car else 'fp '} range {math.hypot(x, y):4.1f} m "
                  f"score {d['score']:.2f} lift {lift:+.2f} m")


if __name__ == "__main__":
    main()
