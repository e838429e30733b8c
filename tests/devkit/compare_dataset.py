#!/usr/bin/env python3
"""Check that the official Lyft devkit and `mlod inspect` agree on a dataset.

Usage:
    /work/devkit-venv/bin/python tests/devkit/compare_dataset.py DATASET_DIR MLOD_BIN [options]

DATASET_DIR is opened with `LyftDataset(data_path=DATASET_DIR, json_path=<table folder>)` (the table
folder is DATASET_DIR itself if it holds sample.json, else DATASET_DIR/v1.01-train, else its only
sub-folder with sample.json). Nothing is added to the dataset: if the devkit cannot open it (e.g. the
map PNG named by map.json is missing), that is reported as a failure (exit 2).

MLOD_BIN is split like a shell word list, so `"cargo run -q --release --"` works as well as a path.
For every sample that has a LIDAR_TOP key frame it runs
    MLOD_BIN inspect --dataset DATASET_DIR --sample TOKEN --json
expecting {"sample_token", "lidars": [{"channel","num_points","dropped_points","file",
"extrinsic": {"translation","rotation_wxyz"}}], "boxes": [{"category","center","size_lwh","yaw"}]}
and checks, against the devkit:
  * boxes: `get_sample_data(LIDAR_TOP token)` (boxes in the LIDAR_TOP frame). Matched by order when that
    matches (same count, same categories, centres within tolerance), otherwise by nearest centre
    (optimal assignment, same category only). |d centre| <= --tol-center (1e-4 m, Euclidean),
    |d yaw| <= --tol-yaw (1e-4 rad, wrapped to (-pi, pi]), size_lwh == [wlh[1], wlh[0], wlh[2]] within
    --tol-size (1e-4 m), same category, same count.
    Yaw convention (--yaw): "zyx" (default) = atan2(R10, R00), heading of the box x-axis, R = Rz Ry Rx;
    "pyquaternion" = devkit `orientation.yaw_pitch_roll[0]` (R = Rx Ry Rz). In a tilted LIDAR_TOP
    frame they differ by up to ~6e-4 rad on the real data, i.e. more than the tolerance; see NOTES.md.
    Both deltas are printed for the worst box.
  * LiDARs: same set of key-frame LiDAR channels; extrinsic T^b_{l_i} vs numpy through the global
    frame (|d t| <= --tol-center, rotation angle <= --tol-yaw); "file" resolves to the devkit's
    sample_data path; point counts vs `LidarPointCloud.from_file` (float32 reshaped to (-1, 5)):
    devkit count == num_points + dropped_points, and num_points == number of rows whose 5 values
    (or, accepted too, x/y/z) are finite.
Exit status: 0 all agree, 1 any mismatch (summary printed), 2 devkit could not open the dataset.
"""

import argparse
import json
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import devkit_common as dc  # noqa: E402


# --------------------------------------------------------------------------- devkit side


def devkit_sample(lyftd, sample, yaw_convention):
    """Devkit view of one sample: boxes in the LIDAR_TOP frame, lidar files, counts, extrinsics."""
    top_token = sample["data"]["LIDAR_TOP"]
    _path, boxes, _ = lyftd.get_sample_data(top_token)
    out_boxes = []
    for b in boxes:
        R = b.rotation_matrix
        yz = dc.yaw_zyx(R)
        yp = float(b.orientation.yaw_pitch_roll[0])
        out_boxes.append(
            {
                "token": b.token,
                "category": b.name,
                "center": np.array(b.center, dtype=np.float64),
                "wlh": np.array(b.wlh, dtype=np.float64),
                "yaw_zyx": yz,
                "yaw_pyquaternion": yp,
                "yaw": yz if yaw_convention == "zyx" else yp,
            }
        )
    ext = dc.lidar_extrinsics_via_global(lyftd, sample, "LIDAR_TOP")
    lidars = {}
    for ch, e in ext.items():
        sd_token = sample["data"][ch]
        path = lyftd.get_sample_data_path(sd_token)
        lidars[ch] = {"path": Path(path), "extrinsic": e, "counts": point_counts(Path(path))}
    return out_boxes, lidars


def point_counts(path: Path):
    """Devkit count (LidarPointCloud.from_file) plus finite counts from the raw float32 rows."""
    from lyft_dataset_sdk.utils.data_classes import LidarPointCloud

    res = {"error": None}
    if not path.is_file():
        res["error"] = f"file missing: {path}"
        return res
    try:
        pc = LidarPointCloud.from_file(path)
        res["devkit_total"] = int(pc.points.shape[1])
    except Exception as e:  # e.g. reshape error on a size not a multiple of 20 bytes
        res["error"] = f"devkit LidarPointCloud.from_file failed: {type(e).__name__}: {e}"
        return res
    raw = np.fromfile(str(path), dtype=np.float32).reshape((-1, 5))
    res["finite_all5"] = int(np.isfinite(raw).all(axis=1).sum())
    res["finite_xyz"] = int(np.isfinite(raw[:, :3]).all(axis=1).sum())
    return res


# --------------------------------------------------------------------------- mlod side


def run_mlod(mlod_cmd, dataset_dir, token):
    cmd = mlod_cmd + ["inspect", "--dataset", str(dataset_dir), "--sample", token, "--json"]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"`{shlex.join(cmd)}` exited {p.returncode}: {p.stderr.strip()[-2000:]}")
    try:
        return json.loads(p.stdout)
    except json.JSONDecodeError as e:
        raise RuntimeError(f"`{shlex.join(cmd)}` did not print JSON ({e}): {p.stdout[:500]!r}")


def parse_mlod(doc):
    """Validate and normalise the `mlod inspect --json` schema; raises ValueError on schema errors."""

    def vec(x, n, what):
        if not (isinstance(x, list) and len(x) == n and all(isinstance(v, (int, float)) for v in x)):
            raise ValueError(f"{what}: expected {n} numbers, got {x!r}")
        return np.array(x, dtype=np.float64)

    if not isinstance(doc, dict):
        raise ValueError("top level is not an object")
    for key in ("sample_token", "lidars", "boxes"):
        if key not in doc:
            raise ValueError(f"missing key {key!r}")
    lidars = {}
    for i, l in enumerate(doc["lidars"]):
        ch = l["channel"]
        if ch in lidars:
            raise ValueError(f"lidar channel {ch} listed twice")
        lidars[ch] = {
            "num_points": int(l["num_points"]),
            "dropped_points": int(l["dropped_points"]),
            "file": str(l["file"]),
            "translation": vec(l["extrinsic"]["translation"], 3, f"lidars[{i}].extrinsic.translation"),
            "rotation_wxyz": vec(l["extrinsic"]["rotation_wxyz"], 4, f"lidars[{i}].extrinsic.rotation_wxyz"),
        }
    boxes = []
    for i, b in enumerate(doc["boxes"]):
        boxes.append(
            {
                "category": str(b["category"]),
                "center": vec(b["center"], 3, f"boxes[{i}].center"),
                "size_lwh": vec(b["size_lwh"], 3, f"boxes[{i}].size_lwh"),
                "yaw": float(b["yaw"]),
            }
        )
    return {"sample_token": doc["sample_token"], "lidars": lidars, "boxes": boxes}


# --------------------------------------------------------------------------- comparison


def match_boxes(dk, ml, tol_center):
    """List of (i_devkit, j_mlod) pairs: by order if that is consistent, else nearest centre."""
    if len(dk) == len(ml) and all(
        a["category"] == b["category"] and np.linalg.norm(a["center"] - b["center"]) <= tol_center
        for a, b in zip(dk, ml)
    ):
        return [(i, i) for i in range(len(dk))], "order"
    if not dk or not ml:
        return [], "none"
    from scipy.optimize import linear_sum_assignment

    cost = np.array([[np.linalg.norm(a["center"] - b["center"]) for b in ml] for a in dk])
    big = 1e9
    for i, a in enumerate(dk):
        for j, b in enumerate(ml):
            if a["category"] != b["category"]:
                cost[i, j] += big
    rows, cols = linear_sum_assignment(cost)
    return [(int(i), int(j)) for i, j in zip(rows, cols)], "nearest-centre"


def compare_sample(lyftd, sample, dataset_dir, mlod_doc, args):
    """Returns (list of error strings, stats dict)."""
    errors = []
    stats = {"boxes": 0, "max_dcenter": 0.0, "max_dyaw": 0.0, "max_dyaw_other": 0.0, "max_dsize": 0.0,
             "max_dext_t": 0.0, "max_dext_r": 0.0, "lidars": 0, "match": None}
    tok = sample["token"]
    try:
        ml = parse_mlod(mlod_doc)
    except (ValueError, KeyError, TypeError) as e:
        return [f"{tok}: bad mlod JSON: {e}"], stats
    if ml["sample_token"] != tok:
        errors.append(f"{tok}: mlod reports sample_token {ml['sample_token']}")

    dk_boxes, dk_lidars = devkit_sample(lyftd, sample, args.yaw)

    # ---- boxes
    if len(dk_boxes) != len(ml["boxes"]):
        errors.append(f"{tok}: box count devkit {len(dk_boxes)} != mlod {len(ml['boxes'])}")
    pairs, how = match_boxes(dk_boxes, ml["boxes"], args.tol_center)
    stats["match"] = how
    other = "yaw_pyquaternion" if args.yaw == "zyx" else "yaw_zyx"
    for i, j in pairs:
        a, b = dk_boxes[i], ml["boxes"][j]
        label = f"{tok}: box devkit#{i} ({a['token'][:12]}…) / mlod#{j}"
        if a["category"] != b["category"]:
            errors.append(f"{label}: category {a['category']!r} != {b['category']!r}")
        dcen = float(np.linalg.norm(a["center"] - b["center"]))
        dyaw = abs(dc.wrap_angle(a["yaw"] - b["yaw"]))
        dyaw_other = abs(dc.wrap_angle(a[other] - b["yaw"]))
        lwh = np.array([a["wlh"][1], a["wlh"][0], a["wlh"][2]])
        dsize = float(np.max(np.abs(lwh - b["size_lwh"])))
        stats["boxes"] += 1
        stats["max_dcenter"] = max(stats["max_dcenter"], dcen)
        stats["max_dyaw"] = max(stats["max_dyaw"], dyaw)
        stats["max_dyaw_other"] = max(stats["max_dyaw_other"], dyaw_other)
        stats["max_dsize"] = max(stats["max_dsize"], dsize)
        if not dcen <= args.tol_center:
            errors.append(f"{label}: |d centre| {dcen:.3e} m > {args.tol_center:g} "
                          f"(devkit {a['center'].tolist()}, mlod {b['center'].tolist()})")
        if not dyaw <= args.tol_yaw:
            errors.append(f"{label}: |d yaw| ({args.yaw}) {dyaw:.3e} rad > {args.tol_yaw:g} "
                          f"(devkit {a['yaw']!r}, mlod {b['yaw']!r}; {other} delta {dyaw_other:.3e})")
        if not dsize <= args.tol_size:
            errors.append(f"{label}: size_lwh {b['size_lwh'].tolist()} vs devkit wlh {a['wlh'].tolist()} "
                          f"(max d {dsize:.3e})")

    # ---- lidars
    if set(dk_lidars) != set(ml["lidars"]):
        errors.append(f"{tok}: lidar channels devkit {sorted(dk_lidars)} != mlod {sorted(ml['lidars'])}")
    for ch in sorted(set(dk_lidars) & set(ml["lidars"])):
        d, m = dk_lidars[ch], ml["lidars"][ch]
        stats["lidars"] += 1
        e = d["extrinsic"]
        dt = float(np.linalg.norm(np.array(e["translation"]) - m["translation"]))
        dr = dc.rotation_angle_between(e["rotation_wxyz"], m["rotation_wxyz"])
        stats["max_dext_t"] = max(stats["max_dext_t"], dt)
        stats["max_dext_r"] = max(stats["max_dext_r"], dr)
        if not dt <= args.tol_center:
            errors.append(f"{tok}: {ch} extrinsic translation d {dt:.3e} m (devkit {e['translation']}, "
                          f"mlod {m['translation'].tolist()})")
        if not dr <= args.tol_yaw:
            errors.append(f"{tok}: {ch} extrinsic rotation d {dr:.3e} rad (devkit {e['rotation_wxyz']}, "
                          f"mlod {m['rotation_wxyz'].tolist()})")
        if not same_file(m["file"], d["path"], dataset_dir):
            errors.append(f"{tok}: {ch} file {m['file']!r} is not the devkit's {str(d['path'])!r}")
        c = d["counts"]
        if c["error"]:
            errors.append(f"{tok}: {ch}: {c['error']}")
            continue
        if c["devkit_total"] != m["num_points"] + m["dropped_points"]:
            errors.append(f"{tok}: {ch} devkit reads {c['devkit_total']} points, mlod num_points "
                          f"{m['num_points']} + dropped {m['dropped_points']}")
        if m["num_points"] not in (c["finite_all5"], c["finite_xyz"]):
            errors.append(f"{tok}: {ch} mlod num_points {m['num_points']} != finite rows "
                          f"(all 5 values {c['finite_all5']}, xyz {c['finite_xyz']})")
    return errors, stats


def same_file(mlod_file: str, devkit_path: Path, dataset_dir: Path) -> bool:
    p = Path(mlod_file)
    candidates = [p] if p.is_absolute() else [dataset_dir / p, Path.cwd() / p]
    dk = Path(devkit_path).absolute()
    for c in candidates:
        try:
            if c.absolute() == dk or (c.exists() and dk.exists() and c.resolve() == dk.resolve()):
                return True
        except OSError:
            pass
    # mlod may print the table's relative filename
    return dk.as_posix().endswith("/" + p.as_posix().lstrip("./"))


# --------------------------------------------------------------------------- main


def main(argv=None, mlod_runner=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset_dir", type=Path)
    ap.add_argument("mlod_bin", help="mlod executable (or a command prefix such as 'cargo run -q --')")
    ap.add_argument("--tol-center", type=float, default=1e-4, help="metres (default 1e-4)")
    ap.add_argument("--tol-yaw", type=float, default=1e-4, help="radians (default 1e-4)")
    ap.add_argument("--tol-size", type=float, default=1e-4, help="metres (default 1e-4)")
    ap.add_argument("--yaw", choices=("zyx", "pyquaternion"), default="zyx",
                    help="devkit yaw convention compared with mlod's yaw (default zyx = atan2(R10,R00))")
    ap.add_argument("--max-samples", type=int, default=0, help="check only the first N samples (0 = all)")
    ap.add_argument("--report", type=Path, help="also write a JSON report here")
    ap.add_argument("--verbose", action="store_true")
    args = ap.parse_args(argv)

    dataset_dir = args.dataset_dir.absolute()
    try:
        lyftd = dc.open_dataset(dataset_dir, verbose=args.verbose)
    except Exception as e:
        print(f"FAIL: the devkit (lyft-dataset-sdk {dc.devkit_version()}) cannot open {dataset_dir}: "
              f"{type(e).__name__}: {e}")
        return 2

    mlod_cmd = shlex.split(args.mlod_bin)
    runner = mlod_runner or (lambda token: run_mlod(mlod_cmd, dataset_dir, token))

    samples = lyftd.sample[: args.max_samples] if args.max_samples else lyftd.sample
    all_errors, per_sample, skipped = [], [], []
    for s in samples:
        if "LIDAR_TOP" not in s["data"]:
            skipped.append(s["token"])
            continue
        try:
            doc = runner(s["token"])
        except Exception as e:
            all_errors.append(f"{s['token']}: {e}")
            per_sample.append({"sample_token": s["token"], "errors": 1})
            continue
        errs, stats = compare_sample(lyftd, s, dataset_dir, doc, args)
        all_errors += errs
        per_sample.append({"sample_token": s["token"], "errors": len(errs), **stats})
        if args.verbose:
            print(f"{s['token']}: {len(errs)} errors, {stats}")

    agg = lambda k: max([p.get(k, 0.0) or 0.0 for p in per_sample] or [0.0])  # noqa: E731
    other = "pyquaternion" if args.yaw == "zyx" else "zyx"
    print(f"devkit lyft-dataset-sdk {dc.devkit_version()} vs {args.mlod_bin} on {dataset_dir}")
    print(f"  samples checked: {len(per_sample)}  skipped (no LIDAR_TOP): {len(skipped)}")
    print(f"  boxes compared: {sum(p.get('boxes', 0) for p in per_sample)}  "
          f"lidars compared: {sum(p.get('lidars', 0) for p in per_sample)}")
    print(f"  max |d centre| {agg('max_dcenter'):.3e} m   max |d yaw| ({args.yaw}) {agg('max_dyaw'):.3e} rad "
          f"[{other}: {agg('max_dyaw_other'):.3e}]   max |d size| {agg('max_dsize'):.3e} m")
    print(f"  max extrinsic d: translation {agg('max_dext_t'):.3e} m, rotation {agg('max_dext_r'):.3e} rad")
    for e in all_errors[:50]:
        print("  MISMATCH", e)
    if len(all_errors) > 50:
        print(f"  ... and {len(all_errors) - 50} more")
    print("RESULT:", "OK" if not all_errors else f"FAIL ({len(all_errors)} mismatches)")
    if args.report:
        with open(args.report, "w") as f:
            json.dump({"devkit": dc.devkit_version(), "dataset": str(dataset_dir), "yaw_convention": args.yaw,
                       "errors": all_errors, "samples": per_sample, "skipped": skipped}, f, indent=2)
    return 1 if all_errors else 0


if __name__ == "__main__":
    sys.exit(main())
