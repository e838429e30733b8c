"""The Python package's speed (issue 54): `Dataset.fuse` (load + fuse + tr(Xi)) of the largest
sample of sample_data/ against the same Rust call (criterion: `cargo bench --bench pipeline --
sample_data_frame_and_fuse`), and `mlod.propagate` against the paper's propagation written in
numpy (vectorised). Prints one JSON object.

    pip install ./python && python python/bench/fuse_bench.py
"""

import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

import mlod

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "python" / "tests"))
from test_mlod import numpy_propagation  # noqa: E402  (the reference the tests check against)


def times_ms(f, runs):
    """Wall times of `runs` calls of `f` after one warm-up call, in ms."""
    f()  # warm up
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        f()
        times.append((time.perf_counter() - t) * 1e3)
    return times


def main():
    ds = mlod.open(ROOT / "sample_data")
    sizes = {s: sum(len(l["points"]) for l in ds.frame(s)["lidars"]) for s in ds.samples}
    sample = max(sizes, key=sizes.get)
    fuse_times = times_ms(lambda: ds.fuse(sample, alpha=0.1, seed=7), 200)
    cloud = ds.fuse(sample, alpha=0.1, seed=7)
    aux = ds.frame(sample)["lidars"][1:]
    pts = [l["points"][:, :3].copy() for l in aux]
    exts = [cloud["extrinsics"][l["channel"]] for l in aux]
    n_aux = sum(len(p) for p in pts)
    mlod_ms = statistics.median(times_ms(lambda: [mlod.propagate(p, e, 0.1) for p, e in zip(pts, exts)], 20))
    numpy_ms = statistics.median(times_ms(lambda: [numpy_propagation(p, e, 0.1) for p, e in zip(pts, exts)], 5))
    print(
        json.dumps(
            {
                "sample": sample,
                "points": sizes[sample],
                "python_fuse_ms": round(statistics.median(fuse_times), 2),
                "python_fuse_mean_ms": round(statistics.mean(fuse_times), 2),
                "auxiliary_points": n_aux,
                "mlod_propagate_ms": round(mlod_ms, 2),
                "numpy_propagate_ms": round(numpy_ms, 2),
                "speedup_over_numpy": round(numpy_ms / mlod_ms, 1),
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
