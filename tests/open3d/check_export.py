#!/usr/bin/env python3
"""Opens files written by `mlod export` with Open3D and checks what it sees.

For each file: the point count through the legacy reader (o3d.io.read_point_cloud) and the
tensor reader (o3d.t.io.read_point_cloud), and the tensor reader's attributes with dtype, shape
and range. Exits 1 when a count differs from --expected, when a field `mlod export` always writes
(positions, intensity, lidar, trace) is missing, when `lidar` holds a value other than 0, 1, 2, or
when the six xi_* are there but their diagonal does not sum to trace (1e-5 relative).

Usage: check_export.py --expected N FILE [FILE ...]   (see README.md beside it; not part of CI)
"""

import argparse
import sys

import numpy as np
import open3d as o3d

ALWAYS = ["positions", "intensity", "lidar", "trace"]
XI = ["xi_xx", "xi_xy", "xi_xz", "xi_yy", "xi_yz", "xi_zz"]


def check(path: str, expected: int) -> list[str]:
    """Prints what Open3D reads from `path`; returns the problems found."""
    problems = []
    legacy = o3d.io.read_point_cloud(path)
    tensor = o3d.t.io.read_point_cloud(path)
    names = sorted(tensor.point)
    n_tensor = tensor.point["positions"].shape[0] if "positions" in names else 0
    print(f"{path}: legacy {len(legacy.points)} points, tensor {n_tensor} points")
    for name in names:
        a = tensor.point[name].numpy()
        lo, hi = (a.min(), a.max()) if a.size else (float("nan"), float("nan"))
        print(f"  {name:<10} {str(tensor.point[name].dtype):<8} {str(a.shape):<14} {lo:.6g} .. {hi:.6g}")
    for what, n in [("legacy", len(legacy.points)), ("tensor", n_tensor)]:
        if n != expected:
            problems.append(f"{path}: {what} reader sees {n} points, expected {expected}")
    missing = [f for f in ALWAYS if f not in names]
    if missing:
        problems.append(f"{path}: missing field(s) {', '.join(missing)}")
    if "lidar" in names:
        ids = set(np.unique(tensor.point["lidar"].numpy()).tolist())
        if not ids <= {0, 1, 2}:
            problems.append(f"{path}: lidar values {sorted(ids)} outside 0, 1, 2")
    if all(x in names for x in XI) and "trace" in names:
        diag = sum(tensor.point[x].numpy().astype(np.float64) for x in ["xi_xx", "xi_yy", "xi_zz"])
        tr = tensor.point["trace"].numpy().astype(np.float64)
        worst = float(np.max(np.abs(diag - tr) / np.maximum(np.abs(tr), 1e-12))) if tr.size else 0.0
        print(f"  xi_xx + xi_yy + xi_zz vs trace: worst relative difference {worst:.2e}")
        if worst > 1e-5:
            problems.append(f"{path}: the diagonal of Xi differs from trace by {worst:.2e} (relative)")
    return problems


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--expected", type=int, required=True, help="the point count `mlod export` printed")
    parser.add_argument("files", nargs="+", help=".ply or .pcd files written by `mlod export`")
    args = parser.parse_args()
    print(f"open3d {o3d.__version__}, python {sys.version.split()[0]}")
    problems = [p for f in args.files for p in check(f, args.expected)]
    for p in problems:
        print(f"FAIL {p}")
    print("OK" if not problems else f"{len(problems)} problem(s)")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
