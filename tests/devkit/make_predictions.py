#!/usr/bin/env python3
"""Randomly perturbed predictions for a Lyft-format dataset, to check `mlod eval` against the devkit.

Usage:
    python3 tests/devkit/make_predictions.py DATASET_DIR OUT_DIR [--seed 0]

Reads the dataset's tables with plain json (no devkit needed) and writes to OUT_DIR:
  gt.json          every annotation as a devkit ground-truth record (name = category name)
  pred_valid.json  predictions the devkit accepts: for ~90% of the boxes a copy with noisy centre
                   (per-box noise scale, so IoUs spread over 0.5-0.95), size, yaw (10% turned by pi,
                   10% slightly tilted in pitch/roll), 5% relabelled, 8% duplicated; plus ~3 random
                   false positives per sample; scores rounded to 2 decimals, so ties occur
  pred_all.json    pred_valid.json with 6 invalid records spliced in (NaN, unknown sample token,
                   negative size, non-unit quaternion, missing score, wrong length) - `mlod eval`
                   must reject exactly those and agree with the devkit on the rest

The devkit result is then computed with `map_eval.py OUT_DIR/pred_valid.json OUT_DIR/gt.json ...`.
"""

import argparse
import json
import math
import random
from pathlib import Path


def find_version_dir(root: Path) -> Path:
    if (root / "sample.json").exists():
        return root
    for d in sorted(root.iterdir()):
        if d.is_dir() and (d / "sample.json").exists():
            return d
    raise SystemExit(f"{root}: no version folder with sample.json")


def load(vdir: Path, name: str):
    with open(vdir / f"{name}.json") as f:
        return json.load(f)


def quat_mul(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return [
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ]


def axis_quat(axis, angle):
    s = math.sin(angle / 2)
    return [math.cos(angle / 2)] + [s * a for a in axis]


def normalise(q):
    n = math.sqrt(sum(x * x for x in q))
    return [x / n for x in q]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = random.Random(args.seed)

    vdir = find_version_dir(args.dataset)
    cat_name = {c["token"]: c["name"] for c in load(vdir, "category")}
    inst_cat = {i["token"]: cat_name[i["category_token"]] for i in load(vdir, "instance")}
    samples = [s["token"] for s in load(vdir, "sample")]
    names = sorted(set(cat_name.values()))

    gt = []
    for a in load(vdir, "sample_annotation"):
        gt.append(
            {
                "sample_token": a["sample_token"],
                "translation": a["translation"],
                "size": a["size"],
                "rotation": a["rotation"],
                "name": inst_cat[a["instance_token"]],
            }
        )

    preds = []

    def noisy(g):
        scale = rng.uniform(0.0, 0.5)
        t = [g["translation"][0] + rng.gauss(0, scale), g["translation"][1] + rng.gauss(0, scale),
             g["translation"][2] + rng.gauss(0, 0.3 * scale)]
        size = [s * math.exp(rng.gauss(0, 0.3 * scale)) for s in g["size"]]
        q = quat_mul(axis_quat([0, 0, 1], rng.gauss(0, 0.3 * scale)), g["rotation"])
        u = rng.random()
        if u < 0.1:
            q = quat_mul(axis_quat([0, 0, 1], math.pi), q)
        elif u < 0.2:
            q = quat_mul(axis_quat([1, 0, 0], rng.gauss(0, 0.03)), q)
            q = quat_mul(axis_quat([0, 1, 0], rng.gauss(0, 0.03)), q)
        name = g["name"] if rng.random() > 0.05 else rng.choice(names)
        score = round(max(0.01, min(0.99, 0.9 - scale + rng.gauss(0, 0.15))), 2)
        return {"sample_token": g["sample_token"], "translation": t, "size": size,
                "rotation": normalise(q), "name": name, "score": score}

    for g in gt:
        if rng.random() < 0.9:
            preds.append(noisy(g))
            if rng.random() < 0.08:
                preds.append(noisy(g))
    # ~3 false positives per sample, within 15 m of one of its GT boxes (or skipped if none).
    by_sample = {}
    for g in gt:
        by_sample.setdefault(g["sample_token"], []).append(g)
    for s in samples:
        near = by_sample.get(s)
        if not near:
            continue
        for _ in range(3):
            a = rng.choice(near)["translation"]
            r, th = rng.uniform(1, 15), rng.uniform(-math.pi, math.pi)
            preds.append({"sample_token": s,
                          "translation": [a[0] + r * math.cos(th), a[1] + r * math.sin(th), a[2] + rng.uniform(-1, 1)],
                          "size": [rng.uniform(0.5, 2.5), rng.uniform(0.5, 6), rng.uniform(1, 2)],
                          "rotation": axis_quat([0, 0, 1], rng.uniform(-math.pi, math.pi)),
                          "name": rng.choice(names), "score": round(rng.uniform(0.01, 0.6), 2)})
    rng.shuffle(preds)

    bad = []
    base = dict(preds[0])
    bad.append({**base, "translation": [base["translation"][0], float("nan"), base["translation"][2]]})
    bad.append({**base, "sample_token": "not-a-sample"})
    bad.append({**base, "size": [-1.0, base["size"][1], base["size"][2]]})
    bad.append({**base, "rotation": [2.0, 0.0, 0.0, 0.0]})
    bad.append({k: v for k, v in base.items() if k != "score"})
    bad.append({**base, "size": base["size"][:2]})
    all_preds = list(preds)
    for i, b in enumerate(bad):
        all_preds.insert(7 * i + 3, b)

    args.out.mkdir(parents=True, exist_ok=True)
    for name, doc in (("gt.json", gt), ("pred_valid.json", preds), ("pred_all.json", all_preds)):
        with open(args.out / name, "w") as f:
            json.dump(doc, f)
            f.write("\n")
    print(f"{len(gt)} GT, {len(preds)} valid predictions (+{len(bad)} invalid) in {args.out}")


if __name__ == "__main__":
    main()
