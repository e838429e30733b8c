"""Self-tests of the devkit reference scripts (no mlod binary needed).

    /work/devkit-venv/bin/python -m pytest -q tests/devkit

compare_dataset.py is exercised on the real fixture tables, staged with a placeholder map PNG and
small synthetic .bin files at the host-a101 filenames, against a fake `mlod` that prints the
`mlod inspect --json` schema built from tests/fixtures/devkit_expected/real_boxes.json.
"""

import copy
import json
import math
import shutil
import stat
import sys
from pathlib import Path

import numpy as np
import pytest

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import compare_dataset  # noqa: E402
import devkit_common as dc  # noqa: E402
import map_eval  # noqa: E402
import real_boxes  # noqa: E402

EXPECTED = HERE.parents[1] / "tests" / "fixtures" / "devkit_expected" / "real_boxes.json"
IDENTITY = {"translation": [0.0, 0.0, 0.0], "rotation_wxyz": [1.0, 0.0, 0.0, 0.0]}
COUNTS = {"LIDAR_TOP": 7, "LIDAR_FRONT_LEFT": 3, "LIDAR_FRONT_RIGHT": 4}

needs_fixture = pytest.mark.skipif(not (dc.REAL_TABLES / "v1.01-train").is_dir(), reason="no real fixture")


@pytest.fixture(scope="module")
def expected():
    with open(EXPECTED) as f:
        return json.load(f)


@pytest.fixture()
def dataset(expected):
    """Real tables + placeholder map + synthetic .bin files (LIDAR_TOP gets one NaN row)."""
    d = dc.staged_real_fixture()
    rng = np.random.default_rng(0)
    for ch, info in expected["lidar_files"].items():
        pts = rng.normal(size=(COUNTS[ch], 5)).astype(np.float32)
        if ch == "LIDAR_TOP":
            pts[2, 1] = np.nan
        (d / info["filename"]).parent.mkdir(parents=True, exist_ok=True)
        pts.tofile(d / info["filename"])
    yield d
    shutil.rmtree(d, ignore_errors=True)


def mock_doc(expected, yaw_key="yaw_zyx"):
    """What a correct `mlod inspect --json` would print for the real sample."""
    lidars = []
    for ch in dc.LIDAR_CHANNELS:
        ext = IDENTITY if ch == "LIDAR_TOP" else expected["extrinsics"][ch]
        lidars.append(
            {
                "channel": ch,
                "num_points": COUNTS[ch] - (1 if ch == "LIDAR_TOP" else 0),
                "dropped_points": 1 if ch == "LIDAR_TOP" else 0,
                "file": expected["lidar_files"][ch]["filename"],
                "extrinsic": {"translation": ext["translation"], "rotation_wxyz": ext["rotation_wxyz"]},
            }
        )
    boxes = [
        {
            "category": b["category"],
            "center": b["center"],
            "size_lwh": [b["wlh"][1], b["wlh"][0], b["wlh"][2]],
            "yaw": b[yaw_key],
        }
        for b in expected["boxes"]
    ]
    return {"sample_token": expected["sample_token"], "lidars": lidars, "boxes": boxes}


def run_compare(dataset, doc, *extra):
    return compare_dataset.main([str(dataset), "unused-mlod", *extra], mlod_runner=lambda tok: copy.deepcopy(doc))


# --------------------------------------------------------------------------- real_boxes.json


@needs_fixture
def test_real_boxes_reproducible():
    assert real_boxes.main(["--check", "--out", str(EXPECTED)]) == 0


def test_real_extrinsics_match_notice(expected):
    # NOTICE.md of the fixture: FRONT_LEFT (-2.234, -0.970, -1.336), FRONT_RIGHT (-2.283, 0.920, -1.333)
    fl = expected["extrinsics"]["LIDAR_FRONT_LEFT"]["translation"]
    fr = expected["extrinsics"]["LIDAR_FRONT_RIGHT"]["translation"]
    assert np.allclose(fl, [-2.234, -0.970, -1.336], atol=6e-4)
    assert np.allclose(fr, [-2.283, 0.920, -1.333], atol=6e-4)


def test_real_box_values_consistent(expected):
    from pyquaternion import Quaternion

    assert len(expected["boxes"]) == 4
    for b in expected["boxes"]:
        q = Quaternion(b["orientation_wxyz"])
        assert math.isclose(q.yaw_pitch_roll[0], b["yaw"], abs_tol=1e-15)
        R = np.array(b["rotation_matrix"])
        assert np.allclose(dc.quat_to_matrix(b["orientation_wxyz"]), R, atol=1e-14)
        assert math.isclose(dc.yaw_zyx(R), b["yaw_zyx"], abs_tol=1e-15)
    # the two yaw conventions differ by more than the 1e-4 rad tolerance on this tilted frame
    assert max(abs(b["yaw"] - b["yaw_zyx"]) for b in expected["boxes"]) > 1e-4


def test_quat_roundtrip():
    rng = np.random.default_rng(1)
    for _ in range(200):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q2 = dc.matrix_to_quat(dc.quat_to_matrix(q))
        assert dc.rotation_angle_between(q, q2) < 1e-7
        assert q2[0] >= 0


# --------------------------------------------------------------------------- compare_dataset.py


@needs_fixture
def test_compare_ok(dataset, expected):
    assert run_compare(dataset, mock_doc(expected)) == 0


@needs_fixture
def test_compare_ok_reordered_boxes(dataset, expected):
    doc = mock_doc(expected)
    doc["boxes"].reverse()
    assert run_compare(dataset, doc) == 0


@needs_fixture
def test_compare_yaw_convention_matters(dataset, expected):
    assert run_compare(dataset, mock_doc(expected, "yaw"), "--yaw", "pyquaternion") == 0
    assert run_compare(dataset, mock_doc(expected, "yaw")) == 1  # default zyx
    assert run_compare(dataset, mock_doc(expected), "--yaw", "pyquaternion") == 1


@needs_fixture
def test_compare_yaw_wraps(dataset, expected):
    doc = mock_doc(expected)
    doc["boxes"][0]["yaw"] += 2 * math.pi
    assert run_compare(dataset, doc) == 0


@pytest.mark.parametrize(
    "mutate",
    [
        lambda d: d["boxes"][1]["center"].__setitem__(0, d["boxes"][1]["center"][0] + 2e-4),
        lambda d: d["boxes"][2].__setitem__("yaw", d["boxes"][2]["yaw"] + 2e-4),
        lambda d: d["boxes"][0].__setitem__("size_lwh", [d["boxes"][0]["size_lwh"][i] for i in (1, 0, 2)]),
        lambda d: d["boxes"][0].__setitem__("category", "truck"),
        lambda d: d["boxes"].pop(),
        lambda d: d["lidars"][1].__setitem__("num_points", 99),
        lambda d: d["lidars"][0].__setitem__("dropped_points", 0),
        lambda d: d["lidars"].pop(),
        lambda d: d["lidars"][1]["extrinsic"]["translation"].__setitem__(2, -1.0),
        lambda d: d["lidars"][2]["extrinsic"].__setitem__("rotation_wxyz", [1.0, 0.0, 0.0, 0.0]),
        lambda d: d["lidars"][0].__setitem__("file", "lidar/other.bin"),
        lambda d: d.__setitem__("sample_token", "nope"),
        lambda d: d["boxes"][0].__setitem__("center", [1.0, 2.0]),
    ],
)
@needs_fixture
def test_compare_detects_mismatch(dataset, expected, mutate):
    doc = copy.deepcopy(mock_doc(expected))
    mutate(doc)
    assert run_compare(dataset, doc) == 1


@needs_fixture
def test_compare_quaternion_sign_irrelevant(dataset, expected):
    doc = mock_doc(expected)
    doc["lidars"][1]["extrinsic"]["rotation_wxyz"] = [-v for v in doc["lidars"][1]["extrinsic"]["rotation_wxyz"]]
    assert run_compare(dataset, doc) == 0


@needs_fixture
def test_compare_missing_bin(dataset, expected):
    (dataset / expected["lidar_files"]["LIDAR_FRONT_LEFT"]["filename"]).unlink()
    assert run_compare(dataset, mock_doc(expected)) == 1


@needs_fixture
def test_compare_truncated_bin(dataset, expected):
    p = dataset / expected["lidar_files"]["LIDAR_FRONT_RIGHT"]["filename"]
    p.write_bytes(p.read_bytes()[:-4])
    assert run_compare(dataset, mock_doc(expected)) == 1


@needs_fixture
def test_compare_devkit_refuses_without_map_png(dataset, expected):
    shutil.rmtree(dataset / "maps")
    assert run_compare(dataset, mock_doc(expected)) == 2


@needs_fixture
def test_compare_via_subprocess(dataset, expected, tmp_path, capsys):
    """The real code path: MLOD_BIN is executed with `inspect --dataset D --sample T --json`."""
    docs = tmp_path / "docs.json"
    docs.write_text(json.dumps({expected["sample_token"]: mock_doc(expected)}))
    fake = tmp_path / "fake-mlod"
    fake.write_text(
        f"#!{sys.executable}\n"
        "import json, sys\n"
        "a = sys.argv[1:]\n"
        "assert a[0] == 'inspect' and a[1] == '--dataset' and a[3] == '--sample' and a[5] == '--json', a\n"
        f"d = json.load(open({str(docs)!r}))\n"
        "if a[4] not in d:\n"
        "    sys.exit('unknown sample ' + a[4])\n"
        "print(json.dumps(d[a[4]]))\n"
    )
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    assert compare_dataset.main([str(dataset), str(fake)]) == 0
    assert "RESULT: OK" in capsys.readouterr().out
    # a failing binary is a mismatch, not a crash
    bad = tmp_path / "bad-mlod"
    bad.write_text("#!/bin/sh\necho 'error: lidar/x.bin missing' >&2\nexit 3\n")
    bad.chmod(bad.stat().st_mode | stat.S_IEXEC)
    assert compare_dataset.main([str(dataset), str(bad)]) == 1
    assert "exited 3" in capsys.readouterr().out


# --------------------------------------------------------------------------- map_eval.py


def box(tok, x, y, yaw, size=(2.0, 4.0, 1.5), name="car", score=None):
    d = {
        "sample_token": tok,
        "translation": [x, y, 0.0],
        "size": list(size),
        "rotation": [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)],
        "name": name,
    }
    if score is not None:
        d["score"] = score
    return d


def test_map_perfect():
    gt = [box("s1", 0, 0, 0.3), box("s1", 10, 5, -1.0), box("s2", 3, 3, 2.0, name="pedestrian", size=(0.7, 0.7, 1.8))]
    pred = [dict(b, score=0.9) for b in gt]
    res = map_eval.evaluate(pred, gt)
    assert res["thresholds"] == [0.5, 0.55, 0.6, 0.65, 0.7, 0.75, 0.8, 0.85, 0.9, 0.95]
    assert all(p["mAP"] == 1.0 for p in res["per_threshold"])
    assert res["class_names"] == ["car", "pedestrian"]


def test_map_strict_threshold():
    # w=2, l=3, h=1 boxes shifted 1 m along x: intersection 2*2*1 = 4, union 6+6-4 = 8, IoU exactly 0.5
    gt = [box("s", 0, 0, 0.0, size=(2.0, 3.0, 1.0))]
    pred = [box("s", 1, 0, 0.0, size=(2.0, 3.0, 1.0), score=1.0)]
    res = map_eval.evaluate(pred, gt, [0.49, 0.5])
    assert [p["mAP"] for p in res["per_threshold"]] == [1.0, 0.0]  # IoU must be > threshold


def test_map_footprint_quirk():
    """The footprint is built with cos=R[0,0], sin=R[0,1] = -sin(yaw): rotated by -yaw. A box shifted
    1 m along its own 45 deg heading truly has IoU (4-1)/(4+1) = 0.6, the devkit sees 1/3."""
    from lyft_dataset_sdk.eval.detection.mAP_evaluation import Box3D

    yaw = math.pi / 4
    g = Box3D(**box("s", 0, 0, yaw))
    p = Box3D(**box("s", math.cos(yaw), math.sin(yaw), yaw))
    assert math.isclose(g.get_iou(p), 1.0 / 3.0, rel_tol=1e-9)
    # the same shift along -45 deg (perpendicular to the true heading) looks like a shift along length
    p2 = Box3D(**box("s", math.cos(-yaw), math.sin(-yaw), yaw))
    assert math.isclose(g.get_iou(p2), 0.6, rel_tol=1e-9)
    # no effect for yaw 0 / pi
    g0, p0 = Box3D(**box("s", 0, 0, 0.0)), Box3D(**box("s", 1, 0, 0.0))
    assert math.isclose(g0.get_iou(p0), 0.6, rel_tol=1e-9)


def test_map_matching_rules():
    gt = [box("s", 0, 0, 0.0), box("s", 20, 0, 0.0)]
    pred = [
        box("s", 0, 0, 0.0, score=0.9),  # TP
        box("s", 0.1, 0, 0.0, score=0.8),  # duplicate of a matched GT -> FP
        box("s", 20, 0, 0.0, score=0.7),  # TP
        box("s", 20, 0, 0.0, name="bus", score=0.99),  # class not in GT -> ignored
        box("other", 0, 0, 0.0, score=0.95),  # sample without GT -> FP
    ]
    res = map_eval.evaluate(pred, gt, [0.5])
    # sorted by score: other(FP) 0.95, TP 0.9, FP 0.8, TP 0.7 -> P = 0, .5, .33, .5 at R = 0, .5, .5, 1
    # envelope: .5, .5, .5, .5 -> AP = .5*.5 + .5*.5 = 0.5
    assert math.isclose(res["per_threshold"][0]["mAP"], 0.5, rel_tol=1e-12)
    assert res["ignored_prediction_classes"] == ["bus"]


def test_map_cli(tmp_path):
    gt = [box("s", 0, 0, 0.0)]
    pred = [box("s", 0, 0, 0.0, score=0.5)]
    (tmp_path / "gt.json").write_text(json.dumps(gt))
    (tmp_path / "pred.json").write_text(json.dumps(pred))
    out = tmp_path / "out" / "map.json"
    assert map_eval.main([str(tmp_path / "pred.json"), str(tmp_path / "gt.json"), str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["mAP_mean_over_thresholds"] == 1.0 and len(res["per_threshold"]) == 10
