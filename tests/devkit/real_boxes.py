#!/usr/bin/env python3
"""Reference box/extrinsic values for the real Lyft fixture, computed with the OFFICIAL devkit.

Output: tests/fixtures/devkit_expected/real_boxes.json (committed; Rust tests compare against it).

It was computed once with lyft-dataset-sdk 0.0.8 (numpy 2.4.6, pyquaternion 0.9.9, Python 3.11.7;
full pin list in tests/devkit/requirements.txt). To rerun:

    python3 -m venv /work/devkit-venv
    /work/devkit-venv/bin/pip install -r tests/devkit/requirements.txt
    /work/devkit-venv/bin/python tests/devkit/real_boxes.py            # rewrites the JSON
    /work/devkit-venv/bin/python tests/devkit/real_boxes.py --check    # compares instead (exit 1 on diff)

What it does:
  * The real tables (/work/shared/lyft-real-tables, override with $MLOD_REAL_TABLES) cannot be opened
    in place: `LyftDataset.__init__` asserts that the map raster named by map.json
    (maps/map_raster_palo_alto.png) exists under data_path (utils/map_mask.py:25). So the 13 tables are
    copied to a temp dir and a 1x1 placeholder PNG is written at that path (the raster is only read
    lazily, never here). Nothing else is added: no .bin file is needed for get_sample_data.
  * For the one sample: LIDAR_TOP sample_data token -> `get_sample_data(token)` -> boxes in the
    LIDAR_TOP sensor frame (ego-pose inverse, then calibrated_sensor inverse), exactly as the devkit.
  * Extrinsics T^b_{l_i} of every LiDAR relative to LIDAR_TOP, in numpy through the global frame:
        T_b<-li = (T_global<-ego_top . T_ego<-top)^-1 . T_global<-ego_i . T_ego<-li

Box fields: "yaw" is the devkit's `orientation.yaw_pitch_roll[0]` (pyquaternion convention,
R = Rx(roll) Ry(pitch) Rz(yaw), yaw = atan2(-R01, R00) after normalisation) as requested; because
the boxes are tilted in the LIDAR_TOP frame (roll ~2.7 deg) it differs from the heading of the box
x-axis, "yaw_zyx" = atan2(R10, R00) (R = Rz Ry Rx), by up to 6e-4 rad. Both are recorded; see NOTES.md.
"""

import argparse
import json
import math
import shutil
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import devkit_common as dc  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
OUT = REPO / "tests" / "fixtures" / "devkit_expected" / "real_boxes.json"


def compute(real_tables: Path) -> dict:
    import pyquaternion

    staged = dc.staged_real_fixture(real_tables)
    try:
        lyftd = dc.open_dataset(staged, staged / dc.VERSION_DIR)
        assert len(lyftd.sample) == 1, "the real fixture has exactly one sample"
        sample = lyftd.sample[0]
        top_token = sample["data"]["LIDAR_TOP"]
        _path, boxes, _ = lyftd.get_sample_data(top_token)

        out_boxes = []
        for b in boxes:
            R = b.rotation_matrix
            pitch_zyx, roll_zyx = dc.pitch_roll_zyx(R)
            ypr = b.orientation.yaw_pitch_roll
            out_boxes.append(
                {
                    "annotation_token": b.token,
                    "category": b.name,
                    "center": [float(v) for v in b.center],
                    "wlh": [float(v) for v in b.wlh],
                    "yaw": float(ypr[0]),
                    "orientation_wxyz": [float(v) for v in b.orientation.elements],
                    # extras (not requested, for convenience of the Rust side)
                    "yaw_pitch_roll_pyquaternion": [float(v) for v in ypr],
                    "yaw_zyx": float(dc.yaw_zyx(R)),
                    "pitch_zyx": float(pitch_zyx),
                    "roll_zyx": float(roll_zyx),
                    "rotation_matrix": [[float(v) for v in row] for row in R],
                }
            )

        ext = dc.lidar_extrinsics_via_global(lyftd, sample, "LIDAR_TOP")
        extrinsics = {
            ch: {"translation": e["translation"], "rotation_wxyz": e["rotation_wxyz"]}
            for ch, e in ext.items()
            if ch != "LIDAR_TOP"
        }
        # Sanity: LIDAR_TOP relative to itself is the identity.
        assert np.allclose(ext["LIDAR_TOP"]["matrix"], np.eye(4), atol=1e-12)
        # Cross-check the numpy quaternion maths against pyquaternion.
        for ch, e in ext.items():
            R_pq = pyquaternion.Quaternion(e["rotation_wxyz"]).rotation_matrix
            assert np.allclose(R_pq, e["matrix"][:3, :3], atol=1e-12), ch

        lidar_files = {}
        for ch in dc.LIDAR_CHANNELS:
            if ch in sample["data"]:
                sd = lyftd.get("sample_data", sample["data"][ch])
                lidar_files[ch] = {
                    "sample_data_token": sd["token"],
                    "filename": sd["filename"],
                    "present_in_fixture": (real_tables / sd["filename"]).is_file(),
                }

        return {
            "_comment": (
                "Computed once with the official Lyft devkit (tests/devkit/real_boxes.py); "
                "boxes in the LIDAR_TOP sensor frame from LyftDataset.get_sample_data; "
                "extrinsics T^b_{l_i} relative to LIDAR_TOP via the global frame. "
                "wlh = [w, l, h]; quaternions [w, x, y, z]; 'yaw' = pyquaternion yaw_pitch_roll[0], "
                "'yaw_zyx' = atan2(R10, R00)."
            ),
            "devkit": {
                "lyft-dataset-sdk": dc.devkit_version(),
                "numpy": np.__version__,
                "pyquaternion": _version("pyquaternion"),
                "python": "%d.%d.%d" % sys.version_info[:3],
            },
            "source_tables": "lyft-real-tables/v1.01-train (see its NOTICE.md)",
            "sample_token": sample["token"],
            "lidar_top_sample_data_token": top_token,
            "boxes": out_boxes,
            "extrinsics": extrinsics,
            "lidar_files": lidar_files,
        }
    finally:
        shutil.rmtree(staged, ignore_errors=True)


def _version(pkg):
    from importlib.metadata import version

    return version(pkg)


def _close(a, b, tol=1e-12, path="$"):
    """Numeric comparison of two JSON trees (ignores the "devkit" version block)."""
    diffs = []
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k == "devkit":
                continue
            if k not in a or k not in b:
                diffs.append(f"{path}.{k}: missing on one side")
            else:
                diffs += _close(a[k], b[k], tol, f"{path}.{k}")
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            diffs.append(f"{path}: length {len(a)} != {len(b)}")
        for i, (x, y) in enumerate(zip(a, b)):
            diffs += _close(x, y, tol, f"{path}[{i}]")
    elif isinstance(a, float) or isinstance(b, float):
        if not math.isclose(a, b, rel_tol=tol, abs_tol=tol):
            diffs.append(f"{path}: {a!r} != {b!r}")
    elif a != b:
        diffs.append(f"{path}: {a!r} != {b!r}")
    return diffs


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tables", type=Path, default=dc.REAL_TABLES, help="real fixture root (default %(default)s)")
    ap.add_argument("--out", type=Path, default=OUT, help="output JSON (default %(default)s)")
    ap.add_argument("--check", action="store_true", help="compare with --out instead of writing it")
    args = ap.parse_args(argv)

    result = compute(args.tables)
    if args.check:
        with open(args.out) as f:
            committed = json.load(f)
        diffs = _close(result, committed)
        for d in diffs:
            print("DIFF", d)
        print("real_boxes.json:", "OK" if not diffs else f"{len(diffs)} differences")
        return 1 if diffs else 0

    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(result, f, indent=2)
        f.write("\n")
    print(f"wrote {args.out} ({len(result['boxes'])} boxes, extrinsics for {sorted(result['extrinsics'])})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
