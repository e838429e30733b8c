#!/usr/bin/env python3
"""Independent check of `mlod stats` on a KITTI folder (numpy only, no mlod code).

Points per sweep, distinct rings (a new ring where the azimuth crosses from negative to
non-negative, as the Velodyne driver writes them) and the points inside each labelled box:
label (h w l x y z ry, camera frame) -> centre (x, y - h/2, z) moved by inv(R0_rect . Tr_velo_to_cam),
yaw = -ry - pi/2, then the oriented-box test in the LiDAR frame.

    python3 scripts/check_kitti_stats.py KITTI_DIR     # KITTI_DIR/training/{velodyne,label_2,calib}
Compare with: mlod stats --dataset KITTI_DIR --per-box --json
"""
import math
import pathlib
import sys

import numpy as np


def calib(path):
    rows = {}
    for line in path.read_text().splitlines():
        if ":" in line:
            k, v = line.split(":", 1)
            rows[k.strip()] = np.array([float(x) for x in v.split()])
    r0 = np.eye(4)
    r0[:3, :3] = rows["R0_rect"].reshape(3, 3)
    tr = np.eye(4)
    tr[:3, :4] = rows["Tr_velo_to_cam"].reshape(3, 4)
    return np.linalg.inv(r0 @ tr)


def main(root):
    t = pathlib.Path(root) / "training"
    counts = []
    for bin_path in sorted((t / "velodyne").glob("*.bin")):
        frame = bin_path.stem
        pts = np.fromfile(bin_path, dtype="<f4").reshape(-1, 4).astype(np.float64)
        az = np.arctan2(pts[:, 1], pts[:, 0])
        new_ring = (az[:-1] < 0) & (az[1:] >= 0) & (az[1:] - az[:-1] < 1.0)
        counts.append(len(pts))
        print(f"{frame}: {len(pts)} points, {int(new_ring.sum()) + 1} rings")
        to_velo = calib(t / "calib" / f"{frame}.txt")
        for line in (t / "label_2" / f"{frame}.txt").read_text().splitlines():
            f = line.split()
            if not f or f[0] == "DontCare":
                continue
            h, w, l, x, y, z, ry = (float(v) for v in f[8:15])
            c = to_velo @ np.array([x, y - h / 2, z, 1.0])
            yaw = -ry - math.pi / 2
            d = pts[:, :3] - c[:3]
            along = math.cos(yaw) * d[:, 0] + math.sin(yaw) * d[:, 1]
            across = -math.sin(yaw) * d[:, 0] + math.cos(yaw) * d[:, 1]
            inside = (np.abs(along) <= l / 2) & (np.abs(across) <= w / 2) & (np.abs(d[:, 2]) <= h / 2)
            rng = math.hypot(c[0], c[1])
            print(f"  {f[0]:<10} range {rng:6.2f} m  {int(inside.sum()):5d} points")
    print(f"points per sweep: median {np.median(counts):.0f}, min {min(counts)}, max {max(counts)}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "tests/fixtures/kitti")
