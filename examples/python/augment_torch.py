"""Uncertainty-aware augmentation in a PyTorch training loop: every step perturbs the auxiliary
LiDARs anew (α and seed drawn per step, the paper's perturbation model), fuses the sample and
feeds tr(Xi) as an extra point feature to a small per-point network that learns which points
lie on a car. A detector of your own would take the same (points, features) batch.

    pip install ./python torch
    python examples/python/augment_torch.py --dataset sample_data --steps 60

Compare `--no-trace` (the same loop without the tr(Xi) feature).
"""

import argparse

import numpy as np
import torch
from torch import nn

import mlod


def car_mask(points: np.ndarray, boxes) -> np.ndarray:
    """Which points lie inside a ground-truth car box (base frame, yaw about z)."""
    inside = np.zeros(len(points), dtype=bool)
    for b in boxes:
        if b["category"] != "car":
            continue
        c, (l, w, h), yaw = np.array(b["center"]), b["size_lwh"], b["yaw"]
        d = points - c
        cos, sin = np.cos(-yaw), np.sin(-yaw)
        x, y = cos * d[:, 0] - sin * d[:, 1], sin * d[:, 0] + cos * d[:, 1]
        inside |= (np.abs(x) <= l / 2) & (np.abs(y) <= w / 2) & (np.abs(d[:, 2]) <= h / 2)
    return inside


def batch(ds, sample, rng, n, use_trace):
    alpha = float(rng.uniform(0.0, 0.2))  # a new drift every step ...
    seed = int(rng.integers(0, 2**31))  # ... of both auxiliary LiDARs
    cloud = ds.fuse(sample, alpha=alpha, seed=seed)
    truth = ds.fuse(sample)  # where the points are without drift, for the labels
    keep = rng.choice(len(cloud["points"]), size=min(n, len(cloud["points"])), replace=False)
    feats = [cloud["points"][keep] / 50.0, cloud["intensity"][keep, None] / 255.0]
    if use_trace:
        feats.append(np.log1p(cloud["trace"][keep, None]))  # tr(Xi) as a point feature
    x = torch.from_numpy(np.concatenate(feats, axis=1).astype(np.float32))
    y = torch.from_numpy(car_mask(truth["points"][keep], ds.frame(sample)["boxes"]).astype(np.float32))
    return x, y, alpha


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", default="sample_data")
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--points", type=int, default=16384)
    ap.add_argument("--no-trace", action="store_true")
    args = ap.parse_args()

    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    ds = mlod.open(args.dataset)
    train, val = ds.samples[:-2], ds.samples[-2:]
    use_trace = not args.no_trace
    net = nn.Sequential(nn.Linear(5 if use_trace else 4, 64), nn.ReLU(), nn.Linear(64, 64), nn.ReLU(), nn.Linear(64, 1))
    opt = torch.optim.AdamW(net.parameters(), lr=3e-3)
    loss_fn = nn.BCEWithLogitsLoss(pos_weight=torch.tensor(5.0))
    for step in range(1, args.steps + 1):
        x, y, alpha = batch(ds, train[step % len(train)], rng, args.points, use_trace)
        loss = loss_fn(net(x).squeeze(1), y)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if step % 10 == 0:
            print(f"step {step:4d}  alpha {alpha:.3f}  loss {loss.item():.4f}")
    with torch.no_grad():
        hits = total = 0
        for s in val:
            x, y, _ = batch(ds, s, rng, args.points, use_trace)
            pred = net(x).squeeze(1) > 0
            hits += int((pred & (y > 0)).sum())
            total += int((y > 0).sum())
    print(f"validation: {hits} of {total} car points found ({100.0 * hits / max(total, 1):.1f} %), tr(Xi) feature {'on' if use_trace else 'off'}")


if __name__ == "__main__":
    main()
