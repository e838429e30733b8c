#!/usr/bin/env python3
"""Solves the ICP problems `mlod calibrate --dump DIR` wrote with Open3D's point-to-plane ICP.

For each sample and auxiliary LiDAR in DIR: the same downsampled clouds (`*.target.xyz` in the
base frame, `*.source.xyz` in the LiDAR's frame) and the same start extrinsic as `mlod calibrate`;
normals of the target from its `normal_k` nearest neighbours (Open3D's own estimate), a Huber
kernel with mlod's threshold, and a correspondence distance that shrinks like mlod's (one Open3D
ICP call per distance, each at most a few iterations, then iterations at the final distance).
Prints, per run, both final errors against the true extrinsic and both times, and the medians.
Both times include the target's normals and kd-tree (mlod builds them once per sample for both
LiDARs; `ours_ms` counts that build in full for each LiDAR, as Open3D does).

Usage: icp_reference.py DIR   (not part of CI; see README.md beside it)
"""

import argparse
import glob
import json
import os
import statistics
import sys
import time

import numpy as np
import open3d as o3d


def pose_error(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(rotation error in degrees, translation error in m) between two 4x4 extrinsics."""
    r = a[:3, :3] @ b[:3, :3].T
    cos = max(-1.0, min(1.0, (np.trace(r) - 1.0) / 2.0))
    return float(np.degrees(np.arccos(cos))), float(np.linalg.norm(a[:3, 3] - b[:3, 3]))


def load_xyz(path: str) -> o3d.geometry.PointCloud:
    pts = np.loadtxt(path, dtype=np.float64).reshape(-1, 3)
    pc = o3d.geometry.PointCloud()
    pc.points = o3d.utility.Vector3dVector(pts)
    return pc


def solve(source, target_pts, start, cfg) -> tuple[np.ndarray, float]:
    """Open3D point-to-plane ICP on mlod's problem; returns the extrinsic and the wall time (ms),
    normals and kd-tree included."""
    t0 = time.perf_counter()
    target = o3d.geometry.PointCloud(target_pts)
    target.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=cfg["normal_k"]))
    kernel = o3d.pipelines.registration.HuberLoss(k=cfg["huber"])
    method = o3d.pipelines.registration.TransformationEstimationPointToPlane(kernel)
    pose = start.copy()
    dist = cfg["max_distance"]
    while True:
        final = dist <= cfg["min_distance"]
        crit = o3d.pipelines.registration.ICPConvergenceCriteria(
            relative_fitness=1e-9, relative_rmse=1e-9, max_iteration=60 if final else 1
        )
        result = o3d.pipelines.registration.registration_icp(source, target, dist, pose, method, crit)
        pose = result.transformation
        if final:
            break
        dist = max(dist * cfg["shrink"], cfg["min_distance"])
    return pose, (time.perf_counter() - t0) * 1e3


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dir")
    args = ap.parse_args()
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    rows = []
    for meta_path in sorted(glob.glob(os.path.join(args.dir, "*.json"))):
        meta = json.load(open(meta_path))
        target = load_xyz(os.path.join(args.dir, meta["target"]))
        for lidar in meta["lidars"]:
            source = load_xyz(os.path.join(args.dir, lidar["source"]))
            start, truth, ours = (np.array(lidar[k]) for k in ("start", "truth", "ours"))
            o3d_pose, o3d_ms = solve(source, target, start, meta["config"])
            row = {
                "sample": meta["sample_token"][:8],
                "lidar": lidar["channel"],
                "before": pose_error(start, truth),
                "mlod": pose_error(ours, truth),
                "open3d": pose_error(o3d_pose, truth),
                "mlod_vs_open3d": pose_error(ours, o3d_pose),
                "mlod_ms": lidar["ours_ms"],
                "open3d_ms": o3d_ms,
            }
            rows.append(row)
            print(
                f"{row['sample']} {row['lidar']:<18} before {row['before'][0]:.3f} deg {row['before'][1]*100:.2f} cm"
                f" | mlod {row['mlod'][0]:.4f} deg {row['mlod'][1]*100:.3f} cm {row['mlod_ms']:.1f} ms"
                f" | open3d {row['open3d'][0]:.4f} deg {row['open3d'][1]*100:.3f} cm {row['open3d_ms']:.1f} ms"
                f" | mlod vs open3d {row['mlod_vs_open3d'][0]:.4f} deg {row['mlod_vs_open3d'][1]*100:.3f} cm"
            )
    if not rows:
        print(f"no *.json in {args.dir}: run `mlod calibrate ... --dump {args.dir}` first", file=sys.stderr)
        return 1
    med = lambda key, i: statistics.median(r[key][i] for r in rows)

    def q(key: str, i: int, p: float) -> float:
        v = sorted(r[key][i] for r in rows)
        return v[min(len(v) - 1, round(p * (len(v) - 1)))]

    for key in ("before", "mlod", "open3d", "mlod_vs_open3d"):
        print(
            f"{key:<7} rotation median {q(key, 0, 0.5):.4f} p90 {q(key, 0, 0.9):.4f} worst {q(key, 0, 1.0):.4f} deg;"
            f" translation median {q(key, 1, 0.5)*100:.3f} p90 {q(key, 1, 0.9)*100:.3f} worst {q(key, 1, 1.0)*100:.3f} cm"
        )
    print(
        f"\n{len(rows)} runs, medians: before {med('before', 0):.3f} deg {med('before', 1)*100:.2f} cm"
        f" | mlod {med('mlod', 0):.4f} deg {med('mlod', 1)*100:.3f} cm {statistics.median(r['mlod_ms'] for r in rows):.1f} ms"
        f" | open3d {med('open3d', 0):.4f} deg {med('open3d', 1)*100:.3f} cm {statistics.median(r['open3d_ms'] for r in rows):.1f} ms"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
