#!/usr/bin/env python3
"""PyTorch eager reference for one training step of mlod's networks on the CPU (issue 28).

The same architectures, losses, AdamW (weight decay 0.01) and gradient-norm clipping (10) as
src/detect/net.rs + src/train/stage1.rs (stage 1, LiDAR-Top: 33 x 256 x 256 input, mid 24,
RPN 48 x 2 layers, 32 768 anchors) and src/refine/net.rs + loss (PointNet 4 -> 32/64/128, max,
proposal MLP 9 -> 32, head 160 -> 128 -> 64, cls 1 + reg 8; 32 proposals x 1024 points).
Inputs and targets are seeded random data of the right shape (dense convolutions cost the same
on any input). Prints the median and minimum milliseconds per step.

    python3 scripts/torch_train_step.py --threads 2 --steps 20
"""
import argparse
import statistics
import time

import torch
import torch.nn as nn
import torch.nn.functional as F


def conv_bn(cin, cout, k, stride):
    return nn.Sequential(nn.Conv2d(cin, cout, k, stride, k // 2, bias=False), nn.BatchNorm2d(cout), nn.ReLU())


class Stage1(nn.Module):
    def __init__(self, cin=33, mid=24, rpn=48, layers=2, anchors=2):
        super().__init__()
        self.middle = nn.Sequential(conv_bn(cin, mid, 3, 2), conv_bn(mid, mid, 3, 1))
        self.block1 = nn.Sequential(*[conv_bn(mid, mid, 3, 1) for _ in range(layers)])
        self.block2 = nn.Sequential(conv_bn(mid, rpn, 3, 2), *[conv_bn(rpn, rpn, 3, 1) for _ in range(layers)])
        self.up1 = conv_bn(mid, rpn, 1, 1)
        self.up2 = nn.Sequential(nn.ConvTranspose2d(rpn, rpn, 2, 2, bias=False), nn.BatchNorm2d(rpn), nn.ReLU())
        self.cls = nn.Conv2d(2 * rpn, anchors, 1)
        self.reg = nn.Conv2d(2 * rpn, anchors * 7, 1)
        self.dir = nn.Conv2d(2 * rpn, anchors * 2, 1)
        self.a = anchors

    def forward(self, x):
        a = self.block1(self.middle(x))
        b = self.block2(a)
        f = torch.cat([self.up1(a), self.up2(b)], 1)

        def per_anchor(t, k):
            _, _, h, w = t.shape
            return t.reshape(self.a, k, h, w).permute(2, 3, 0, 1).reshape(h * w * self.a, k)

        return per_anchor(self.cls(f), 1).squeeze(1), per_anchor(self.reg(f), 7), per_anchor(self.dir(f), 2)


def focal(x, t, alpha=0.25):
    ce = F.relu(x) - x * t + torch.log1p(torch.exp(-x.abs()))
    p = torch.sigmoid(x)
    pt = p * t + (1 - p) * (1 - t)
    return (alpha * t + (1 - alpha) * (1 - t)) * (1 - pt).clamp(0, 1) ** 2 * ce


def smooth_l1(d, beta=1.0 / 9.0):
    a = d.abs()
    return torch.where(a < beta, 0.5 * a * a / beta, a - 0.5 * beta)


def stage1_step_fn(threads):
    g = torch.Generator().manual_seed(0)
    net = Stage1()
    opt = torch.optim.AdamW(net.parameters(), lr=1e-4, weight_decay=0.01)
    x = (torch.rand(1, 33, 256, 256, generator=g) < 0.03).float() * torch.rand(1, 33, 256, 256, generator=g)
    n = 128 * 128 * 2
    labels = torch.zeros(n)
    pos = torch.randperm(n, generator=g)[:40]
    labels[pos] = 1.0
    weights = torch.ones(n)
    reg_t = torch.randn(40, 7, generator=g) * 0.1
    dir_t = torch.randint(0, 2, (40,), generator=g)

    def step():
        cls, reg, dr = net(x)
        norm = 40.0
        lc = (focal(cls, labels) * weights).sum() / norm
        p = reg[pos]
        p6, t6 = p[:, 6:7], reg_t[:, 6:7]
        pred = torch.cat([p[:, :6], torch.sin(p6) * torch.cos(t6)], 1)
        tgt = torch.cat([reg_t[:, :6], torch.cos(p6) * torch.sin(t6)], 1)
        lr_ = smooth_l1(pred - tgt).sum() * 2.0 / norm
        ld = F.cross_entropy(dr[pos], dir_t, reduction="sum") * 0.2 / norm
        loss = lc + lr_ + ld
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), 10.0)
        opt.step()

    return step


class Refiner(nn.Module):
    def __init__(self, cin=4, mlp=(32, 64, 128), prop=32, head=(128, 64)):
        super().__init__()
        layers, c = [], cin
        for w in mlp:
            layers += [nn.Linear(c, w), nn.BatchNorm1d(w), nn.ReLU()]
            c = w
        self.point = nn.Sequential(*layers)
        self.prop = nn.Linear(9, prop)
        hs, c = [], mlp[-1] + prop
        for w in head:
            hs += [nn.Linear(c, w), nn.ReLU()]
            c = w
        self.head = nn.Sequential(*hs)
        self.cls = nn.Linear(c, 1)
        self.reg = nn.Linear(c, 8)
        self.width = mlp[-1]

    def forward(self, pts, b, n, props):
        g = self.point(pts).reshape(b, n, self.width).max(1).values
        h = self.head(torch.cat([g, F.relu(self.prop(props))], -1))
        return self.cls(h).squeeze(-1), self.reg(h)


def refiner_step_fn(threads, b=32, n=1024):
    g = torch.Generator().manual_seed(1)
    net = Refiner()
    opt = torch.optim.AdamW(net.parameters(), lr=1e-4, weight_decay=0.01)
    pts = torch.rand(b * n, 4, generator=g) * 2 - 1
    props = torch.rand(b, 9, generator=g) * 2 - 1
    cls_t = torch.zeros(b)
    cls_t[::4] = 1.0
    reg_t = torch.randn(b, 8, generator=g) * 0.1

    def step():
        cls, reg = net(pts, b, n, props)
        npos = float(cls_t.sum())
        lc = focal(cls, cls_t).sum() / npos
        lr_ = (smooth_l1(reg - reg_t) * cls_t[:, None]).sum() / npos
        loss = lc + lr_
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), 10.0)
        opt.step()

    return step


def measure(step, steps, warmup):
    for _ in range(warmup):
        step()
    times = []
    for _ in range(steps):
        t = time.perf_counter()
        step()
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times), min(times)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--warmup", type=int, default=3)
    a = ap.parse_args()
    torch.manual_seed(0)
    torch.set_num_threads(a.threads)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, {a.steps} steps after {a.warmup} warm-up")
    for name, fn in [("stage1 (LiDAR-Top)", stage1_step_fn), ("refiner (32 x 1024 points)", refiner_step_fn)]:
        med, lo = measure(fn(a.threads), a.steps, a.warmup)
        print(f"{name}: median {med:.1f} ms/step, min {lo:.1f} ms")


if __name__ == "__main__":
    main()
