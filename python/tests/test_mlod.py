"""The Python package against the CLI: each function's output equals what the `mlod` binary of the
same checkout prints or writes for the same inputs; errors raise MlodError naming what is wrong;
calls from two threads at once; no leaks over many calls.

The binary: $MLOD_BIN, else target/debug/mlod, else target/release/mlod of this checkout (the
test fails, never skips, when none is there: build it with `cargo build`)."""

from __future__ import annotations

import gc
import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

import mlod

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "sample_data"
ALPHA, SEED = 0.1, 3


def _cli() -> Path:
    env = os.environ.get("MLOD_BIN")
    candidates = [Path(env)] if env else [ROOT / "target" / "debug" / "mlod", ROOT / "target" / "release" / "mlod"]
    for c in candidates:
        if c.is_file():
            return c
    pytest.fail(f"no mlod binary at {[str(c) for c in candidates]}: run `cargo build` (or set MLOD_BIN)")


def cli(*args: str) -> str:
    out = subprocess.run([str(_cli()), *args], capture_output=True, text=True, check=False)
    assert out.returncode == 0, f"mlod {' '.join(args)} failed: {out.stderr}"
    return out.stdout


def cli_json(*args: str):
    return json.loads(cli(*args, "--json"))


@pytest.fixture(scope="module")
def ds() -> mlod.Dataset:
    return mlod.open(DATA)


@pytest.fixture(scope="module")
def sample(ds: mlod.Dataset) -> str:
    return ds.samples[0]


def read_ply(path: Path) -> np.ndarray:
    """The binary PLY `mlod export` writes, as a structured array."""
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    types = {"float": "<f4", "uchar": "u1", "double": "<f8"}
    fields = []
    for line in raw[:end].decode().splitlines():
        parts = line.split()
        if parts[:1] == ["property"]:
            fields.append((parts[2], types[parts[1]]))
    return np.frombuffer(raw[end:], dtype=np.dtype(fields))


def test_samples_are_inspect_list_order(ds):
    listed = [s["sample_token"] for s in cli_json("inspect", "--dataset", str(DATA), "--list")]
    assert ds.samples == listed and len(listed) == 10


def test_frame_holds_the_files_points_and_boxes(ds, sample):
    f = ds.frame(sample)
    info = cli_json("fuse", "--dataset", str(DATA), "--sample", sample)
    assert [l["channel"] for l in f["lidars"]] == [l["channel"] for l in info["lidars"]]
    for lidar, row in zip(f["lidars"], info["lidars"]):
        assert lidar["points"].dtype == np.float32 and lidar["points"].shape[1] == 5
        assert lidar["points"].shape[0] == row["num_points"]
        assert lidar["extrinsic"].shape == (4, 4)
        np.testing.assert_allclose(lidar["extrinsic"][:3, 3], row["applied_extrinsic"]["translation"], atol=1e-12)
    assert len(f["boxes"]) == len(info["boxes"]) > 0
    assert {b["category"] for b in f["boxes"]} >= {"car"}


def test_fuse_equals_mlod_export(ds, sample, tmp_path):
    ply = tmp_path / "cloud.ply"
    cli("export", "--dataset", str(DATA), "--sample", sample, "--alpha", str(ALPHA), "--seed", str(SEED), "--out", str(ply))
    want = read_ply(ply)
    got = ds.fuse(sample, alpha=ALPHA, seed=SEED)
    assert got["points"].shape == (len(want), 3) and got["points"].dtype == np.float32
    for k, col in enumerate("xyz"):
        assert np.array_equal(got["points"][:, k], want[col])
    assert np.array_equal(got["intensity"], want["intensity"])
    assert np.array_equal(got["lidar"], want["lidar"]) and got["lidar"].dtype == np.uint8
    assert np.array_equal(got["trace"], want["trace"])
    assert got["channels"] == ["LIDAR_TOP", "LIDAR_FRONT_LEFT", "LIDAR_FRONT_RIGHT"]


def test_perturb_is_the_drift_fuse_applies(ds, sample):
    info = cli_json("fuse", "--dataset", str(DATA), "--sample", sample, "--alpha", str(ALPHA), "--seed", str(SEED))
    frame = ds.frame(sample)
    for lidar, row in zip(frame["lidars"][1:], info["lidars"][1:]):
        m = mlod.perturb(lidar["extrinsic"], ALPHA, SEED, lidar["channel"])
        np.testing.assert_allclose(m[:3, 3], row["applied_extrinsic"]["translation"], atol=1e-12)
        w, x, y, z = row["applied_extrinsic"]["rotation_wxyz"]
        r = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )
        np.testing.assert_allclose(m[:3, :3], r, atol=1e-12)
        assert not np.allclose(m, lidar["extrinsic"])  # it did drift
    # α = 0 draws nothing (equal up to the quaternion round trip of the 3 x 3 block).
    np.testing.assert_allclose(mlod.perturb(frame["lidars"][1]["extrinsic"], 0.0, SEED), frame["lidars"][1]["extrinsic"], atol=1e-12)


def test_propagate_is_fuses_trace(ds, sample):
    cloud = ds.fuse(sample, alpha=ALPHA, seed=SEED)
    frame = ds.frame(sample)
    for index, lidar in enumerate(frame["lidars"][1:], start=1):
        pts = lidar["points"][:, :3]
        xi, trace = mlod.propagate(pts, cloud["extrinsics"][lidar["channel"]], ALPHA)
        assert xi.shape == (len(pts), 3, 3) and trace.shape == (len(pts),)
        assert np.array_equal(trace, cloud["trace"][cloud["lidar"] == index])
        np.testing.assert_allclose(np.trace(xi, axis1=1, axis2=2), trace, rtol=1e-4)
        np.testing.assert_array_equal(xi, np.transpose(xi, (0, 2, 1)))
        assert (np.linalg.eigvalsh(xi.astype(np.float64)) > -1e-6).all()


def numpy_propagation(points: np.ndarray, extrinsic: np.ndarray, alpha: float):
    """Eq. 5-8 written with numpy (the paper's separate linearisation): q = R p,
    Xi = P + [q]x Phi [q]x^T + R Z R^T, vectorised over the points."""
    p_cov, phi, z = mlod.prior(alpha)
    r = extrinsic[:3, :3]
    q = points.astype(np.float64) @ r.T
    hat = np.zeros((len(q), 3, 3))
    hat[:, 0, 1], hat[:, 0, 2] = -q[:, 2], q[:, 1]
    hat[:, 1, 0], hat[:, 1, 2] = q[:, 2], -q[:, 0]
    hat[:, 2, 0], hat[:, 2, 1] = -q[:, 1], q[:, 0]
    xi = p_cov + hat @ phi @ hat.transpose(0, 2, 1) + r @ z @ r.T
    return xi, np.trace(xi, axis1=1, axis2=2)


def test_propagate_is_the_papers_formula(ds, sample):
    cloud = ds.fuse(sample, alpha=ALPHA, seed=SEED)
    lidar = ds.frame(sample)["lidars"][1]
    ext = cloud["extrinsics"][lidar["channel"]]
    xi, trace = mlod.propagate(lidar["points"][:, :3], ext, ALPHA)
    want_xi, want_trace = numpy_propagation(lidar["points"][:, :3], ext, ALPHA)
    np.testing.assert_allclose(trace, want_trace, rtol=1e-4)
    np.testing.assert_allclose(xi, want_xi, rtol=1e-3, atol=1e-6)
    p0, phi0, z0 = mlod.prior(1.0)
    p1, phi1, z1 = mlod.prior(0.1)
    np.testing.assert_allclose(p1, 0.1 * p0) and np.testing.assert_allclose(phi1, 0.1 * phi0)
    assert np.array_equal(z1, z0) and (np.diag(p0) > 0).all()


def test_detect_equals_mlod_detect(ds, sample):
    for case in ["top", "mlod-i"]:
        want = cli_json("detect", "--dataset", str(DATA), "--sample", sample, "--case", case, "--alpha", str(ALPHA), "--seed", str(SEED))
        got = ds.detect(sample, case, alpha=ALPHA, seed=SEED)
        assert got == want["detections"] and len(got) > 0


def test_evaluate_equals_mlod_eval(ds):
    want = cli_json("eval", "--dataset", str(DATA), "--case", "top", "--samples", "2", "--alpha", str(ALPHA), "--seed", str(SEED))
    got = ds.evaluate("top", alpha=ALPHA, seed=SEED, samples=2)
    assert got == want
    assert got["samples"] == 2


def test_calibrate_equals_mlod_calibrate(ds, sample):
    want = cli_json("calibrate", "--dataset", str(DATA), "--sample", sample, "--alpha", str(ALPHA), "--seed", str(SEED))["runs"]
    got = ds.calibrate(sample, alpha=ALPHA, seed=SEED)
    assert [r["channel"] for r in got] == ["LIDAR_FRONT_LEFT", "LIDAR_FRONT_RIGHT"]
    for g, w in zip(got, want):
        assert g.pop("ms") >= 0 and w.pop("ms") >= 0  # wall time: the one field that differs
        assert g == w
        assert np.array(g["covariance"]).shape == (6, 6)


@pytest.mark.parametrize(
    "call, words",
    [
        (lambda ds, s: mlod.open("/nonexistent/dataset"), ["/nonexistent/dataset"]),
        (lambda ds, s: ds.detect(s, "no-such-case"), ["no-such-case"]),
        (lambda ds, s: ds.fuse("no-such-sample"), ["no-such-sample"]),
        (lambda ds, s: ds.fuse(s, alpha=float("nan")), ["alpha"]),
        (lambda ds, s: ds.fuse(s, alpha=-1.0), ["alpha"]),
        (lambda ds, s: ds.fuse(s, seed=-1), ["seed"]),
        (lambda ds, s: ds.evaluate("top", samples=0), ["samples"]),
        (lambda ds, s: mlod.open(DATA, models="/nonexistent/models").detect(s, "top"), ["/nonexistent/models"]),
        (lambda ds, s: mlod.propagate(np.full((4, 3), np.nan, np.float32), np.eye(4), 0.1), ["points", "row 0"]),
        (lambda ds, s: mlod.propagate(np.zeros((4, 2), np.float32), np.eye(4), 0.1), ["points", "N x 3"]),
        (lambda ds, s: mlod.propagate(np.zeros((4, 3)), np.eye(3), 0.1), ["extrinsic", "4 x 4"]),
        (lambda ds, s: mlod.propagate(np.zeros((4, 3)), 2 * np.eye(4), 0.1), ["extrinsic", "rotation"]),
        (lambda ds, s: mlod.propagate([["a", "b", "c"]], np.eye(4), 0.1), ["points"]),
        (lambda ds, s: mlod.perturb(np.full((4, 4), np.inf), 0.1), ["extrinsic", "not finite"]),
        (lambda ds, s: mlod.perturb(np.eye(4), 0.1, 0, "LIDAR_TOP"), ["LIDAR_TOP"]),
        (lambda ds, s: mlod.perturb(np.eye(4), 0.1, 0, "LIDAR_REAR"), ["LIDAR_REAR"]),
        (lambda ds, s: ds.detect(s, "ext:nobody"), ["nobody"]),
    ],
)
def test_bad_input_raises_mlod_error_naming_it(ds, sample, call, words):
    with pytest.raises(mlod.MlodError) as e:
        call(ds, sample)
    for w in words:
        assert w in str(e.value), f"{w!r} not in {e.value}"
    assert issubclass(mlod.MlodError, Exception)


def test_a_corrupt_file_raises_naming_it(tmp_path):
    import shutil

    copy = tmp_path / "data"
    shutil.copytree(DATA, copy)
    tables = next(copy.rglob("sample_data.json"))
    tables.write_text("{ not json")
    with pytest.raises(mlod.MlodError) as e:
        mlod.open(copy)
    assert "sample_data.json" in str(e.value)


def test_two_threads_at_once_give_the_sequential_results(ds):
    a, b = ds.samples[:2]
    want = {s: ds.fuse(s, alpha=ALPHA, seed=SEED)["trace"] for s in (a, b)}
    want_boxes = ds.detect(a, "top")
    got, errors = {}, []
    barrier = threading.Barrier(2)

    def work(s):
        try:
            barrier.wait()
            for _ in range(3):
                got[s] = ds.fuse(s, alpha=ALPHA, seed=SEED)["trace"]
            got[s + "boxes"] = ds.detect(s, "top")
        except Exception as e:  # pragma: no cover - reported below
            errors.append(e)

    threads = [threading.Thread(target=work, args=(s,)) for s in (a, b)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    assert np.array_equal(got[a], want[a]) and np.array_equal(got[b], want[b])
    assert got[a + "boxes"] == want_boxes


def _rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def test_arrays_do_not_leak_over_1000_calls():
    pts = np.random.default_rng(0).normal(scale=20.0, size=(2000, 3)).astype(np.float32)
    ext = np.eye(4)
    xi, trace = mlod.propagate(pts, ext, 0.1)
    # The caller holds the only references (plus getrefcount's own argument).
    assert sys.getrefcount(xi) == 2 and sys.getrefcount(trace) == 2
    for _ in range(100):
        mlod.propagate(pts, ext, 0.1)
    gc.collect()
    objects, rss = len(gc.get_objects()), _rss_bytes()
    for _ in range(1000):
        xi, trace = mlod.propagate(pts, ext, 0.1)
    del xi, trace
    gc.collect()
    # One call returns 2000 x 10 floats (80 kB): a leak of each would be 80 MB over 1000 calls.
    assert len(gc.get_objects()) - objects < 100
    assert _rss_bytes() - rss < 8 * 2**20, f"RSS grew by {(_rss_bytes() - rss) / 2**20:.1f} MiB"
