#!/usr/bin/env python3
"""Official Lyft 3D-detection mAP, per IoU threshold, with the devkit's own functions.

Usage:
    /work/devkit-venv/bin/python tests/devkit/map_eval.py PRED_JSON GT_JSON OUT_JSON [--thresholds ...]

PRED_JSON / GT_JSON are devkit-format lists (lyft_dataset_sdk/eval/detection/mAP_evaluation.py docstring):
    gt   = [{"sample_token", "translation": [3], "size": [w, l, h], "rotation": [w, x, y, z], "name"}]
    pred = [{... same ..., "score"}]
(a {"results": [...]}-style object holding such a list is accepted too).

For each threshold in 0.5, 0.55, ..., 0.95 it calls `get_average_precisions(gt, pred, class_names, t)` with
`class_names = get_class_names(gt)` (sorted GT names, as the devkit's __main__ does), and mAP = mean over
those classes. The headline number of the Lyft Kaggle challenge is the mean of the ten mAPs
("mAP_mean_over_thresholds"). Caveats inherited from the devkit (see NOTES.md): IoU must be strictly
greater than the threshold; prediction classes absent from the GT are ignored; GT classes without any
prediction count AP 0; the BEV footprint uses cos = R[0,0], sin = R[0,1] (i.e. it is rotated by -yaw).

OUT_JSON: {"devkit_version", "class_names", "thresholds", "per_threshold": [{"iou_threshold", "mAP",
"ap_per_class": {name: ap}}], "mAP_mean_over_thresholds", "num_gt", "num_pred",
"ignored_prediction_classes"}.
"""

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import devkit_common as dc  # noqa: E402

THRESHOLDS = [round(0.5 + 0.05 * i, 2) for i in range(10)]  # 0.5 ... 0.95, no float drift


def load_list(path):
    with open(path) as f:
        doc = json.load(f)
    if isinstance(doc, dict):
        for key in ("results", "predictions", "gt", "boxes"):
            if isinstance(doc.get(key), list):
                return doc[key]
        raise ValueError(f"{path}: expected a list of boxes (or an object with a 'results' list)")
    return doc


def evaluate(pred, gt, thresholds=THRESHOLDS):
    from lyft_dataset_sdk.eval.detection.mAP_evaluation import get_average_precisions, get_class_names

    class_names = get_class_names(gt)
    per = []
    for t in thresholds:
        aps = get_average_precisions(gt, pred, class_names, t)
        per.append(
            {
                "iou_threshold": t,
                "mAP": float(np.mean(aps)) if len(aps) else 0.0,
                "ap_per_class": {c: float(a) for c, a in zip(class_names, aps)},
            }
        )
    return {
        "devkit_version": dc.devkit_version(),
        "class_names": class_names,
        "thresholds": list(thresholds),
        "per_threshold": per,
        "mAP_mean_over_thresholds": float(np.mean([p["mAP"] for p in per])) if per else 0.0,
        "num_gt": len(gt),
        "num_pred": len(pred),
        "ignored_prediction_classes": sorted({p["name"] for p in pred} - set(class_names)),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("pred_json", type=Path)
    ap.add_argument("gt_json", type=Path)
    ap.add_argument("out_json", type=Path)
    ap.add_argument("--thresholds", type=float, nargs="+", default=THRESHOLDS)
    args = ap.parse_args(argv)

    pred, gt = load_list(args.pred_json), load_list(args.gt_json)
    if not gt:
        print("FAIL: empty ground truth", file=sys.stderr)
        return 2
    res = evaluate(pred, gt, args.thresholds)
    args.out_json.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out_json, "w") as f:
        json.dump(res, f, indent=2)
        f.write("\n")
    for p in res["per_threshold"]:
        print(f"IoU > {p['iou_threshold']:.2f}: mAP {p['mAP']:.6f}  " +
              "  ".join(f"{c} {a:.4f}" for c, a in p["ap_per_class"].items()))
    print(f"mean over thresholds: {res['mAP_mean_over_thresholds']:.6f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
