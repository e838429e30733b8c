#!/usr/bin/env python3
"""LiDAR-Top in PyTorch: the shipped `top` detector re-implemented and served over mlod-detector/1.

    mlod detect --dataset sample_data --case ext:torch \
        --detector "torch=python3 examples/detectors/torch_top.py [--models DIR] [--threads N]"

Options: --models DIR (default assets/models; give mlod the same --models), --threads N (torch's
CPU threads), --vote-iou manifest|off|IOU (as mlod's --vote-iou), --timing (per-frame times on
stderr). Tested against the built-in case: tests/cli/external.rs, torch_top_equals_the_built_in_top.

It loads the LiDAR-Top weights of a models folder (manifest.json + the safetensors file it names,
sha256-checked) and reproduces `mlod detect --case top` step by step, as the Rust side does it:

- points: the rows of LIDAR_TOP (`lidar` == 0) of the request, in file order (the top case sees
  that LiDAR's slice of the fused cloud; intensity stays on the 0-255 scale the voxeliser
  divides by 255);
- voxeliser (src/detect/voxel.rs): the grid of the file's `mlod.config` metadata, float32, sums
  accumulated point by point in file order (np.add.at) as the Rust loop does;
- network (src/detect/infer.rs): BatchNorm folded into the convolutions at load, as the Rust
  FastNet does (scale = gamma / sqrt(var + 1e-5), w * scale, beta - mean * scale), in float32;
- decoding (src/detect/model.rs, anchors.rs): SECOND's residuals on the anchors, the direction
  head's half-turn, score threshold on the logit, top `pre_nms`, float32 like Rust;
- rotated BEV NMS and box voting (src/geometry/nms.rs, iou.rs) in float64 with the same
  Sutherland-Hodgman clipping, visiting order and tie rules; voting at the manifest's `vote.iou`
  (as `mlod detect --vote-iou manifest`, the default).

The channel counts, layer counts, grid and anchors all come from the file's metadata, so a
retrained file with another configuration loads as it is. Only numpy and torch are needed.
"""
import argparse
import hashlib
import json
import math
import os
import struct
import sys
import time

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from mlod_detector import serve  # noqa: E402

BN_EPS = np.float32(1e-5)  # candle-nn's BatchNorm epsilon, which the Rust network uses
F32_PI = np.float32(math.pi)
DIR_OFFSET = np.float32(math.pi / 4)
ROTATIONS = (np.float32(0.0), np.float32(math.pi / 2))
TOP_LIDAR = 0.0  # the `lidar` field of LIDAR_TOP's points
DTYPES = {"F32": "<f4", "F64": "<f8", "F16": "<f2", "I64": "<i8", "I32": "<i4"}


# ---------------------------------------------------------------- weights


def read_safetensors(path):
    """(tensors by name as float32 torch tensors, metadata dict) of a safetensors file."""
    with open(path, "rb") as f:
        data = f.read()
    (n,) = struct.unpack("<Q", data[:8])
    header = json.loads(data[8:8 + n])
    meta = header.pop("__metadata__", {}) or {}
    base = 8 + n
    tensors = {}
    for name, info in header.items():
        dtype = DTYPES.get(info["dtype"])
        if dtype is None:
            raise ValueError("%s: tensor %s has dtype %s" % (path, name, info["dtype"]))
        a, b = info["data_offsets"]
        arr = np.frombuffer(data, dtype=dtype, count=(b - a) // np.dtype(dtype).itemsize, offset=base + a)
        tensors[name] = torch.from_numpy(arr.astype(np.float32).reshape(info["shape"]))
    return tensors, meta


def load_model(models_dir):
    """(config dict, tensors, vote IoU or None) of the models folder's LiDAR-Top."""
    with open(os.path.join(models_dir, "manifest.json")) as f:
        manifest = json.load(f)
    entry = manifest["models"]["top"]
    path = os.path.join(models_dir, entry["file"])
    with open(path, "rb") as f:
        sha = hashlib.sha256(f.read()).hexdigest()
    if entry.get("sha256") and sha != entry["sha256"]:
        raise ValueError("%s: sha256 %s does not match the manifest's %s" % (path, sha, entry["sha256"]))
    tensors, meta = read_safetensors(path)
    config = json.loads(meta["mlod.config"])
    if config["case"] != "top":
        raise ValueError("%s is a model of case %s, not top" % (path, config["case"]))
    config["grid"].setdefault("xy_means", False)  # files older than the in-voxel x/y means
    vote = (manifest.get("vote") or {}).get("iou")
    if vote is None:
        vote = config.get("vote_iou")
    return config, tensors, vote


def fold(tensors, prefix, cout):
    """BatchNorm `prefix.bn.*` as a per-channel (scale, bias), as infer.rs folds it."""
    g, b = tensors[prefix + ".bn.weight"], tensors[prefix + ".bn.bias"]
    m, v = tensors[prefix + ".bn.running_mean"], tensors[prefix + ".bn.running_var"]
    if not all(t.numel() == cout for t in (g, b, m, v)):
        raise ValueError("%s.bn does not have %d channels" % (prefix, cout))
    scale = g / torch.sqrt(v + torch.tensor(BN_EPS))
    return scale, b - m * scale


class FoldedNet:
    """The stage-1 network of one branch (LiDAR-Top), BatchNorm folded into every layer."""

    def __init__(self, config, tensors):
        net = config["net"]

        def conv(prefix, stride):
            w = tensors[prefix + ".conv.weight"]
            scale, bias = fold(tensors, prefix, w.shape[0])
            return (w * scale[:, None, None, None]).contiguous(), bias.contiguous(), stride, w.shape[2] // 2

        self.middle = [conv("middle.conv1", 2), conv("middle.conv2", 1)]
        self.block1 = [conv("rpn.block1.%d" % i, 1) for i in range(net["rpn_layers"])]
        self.block2 = [conv("rpn.block2.%d" % i, 2 if i == 0 else 1) for i in range(net["rpn_layers"] + 1)]
        self.up1 = conv("rpn.up1", 1)
        w = tensors["rpn.up2.deconv.weight"]  # [cin, cout, s, s]
        scale, bias = fold(tensors, "rpn.up2", w.shape[1])
        self.up2 = ((w * scale[None, :, None, None]).contiguous(), bias.contiguous(), w.shape[2])
        self.heads = [(tensors["rpn.%s.weight" % h], tensors["rpn.%s.bias" % h]) for h in ("cls", "reg", "dir")]
        self.a = net["anchors_per_cell"]
        if self.heads[0][0].shape[0] != self.a:
            raise ValueError("the cls head has %d channels, expected %d" % (self.heads[0][0].shape[0], self.a))

    @staticmethod
    def _conv(x, layer):
        w, b, stride, pad = layer
        return F.relu(F.conv2d(x, w, b, stride=stride, padding=pad))

    @torch.no_grad()
    def forward(self, bev):
        """Raw heads of a [C, n, n] BEV in anchor order (row, column, orientation): cls (N,),
        reg (N, 7), dir (N, 2), as numpy float32."""
        x = torch.from_numpy(bev)[None]
        for layer in self.middle:
            x = self._conv(x, layer)
        a = x
        for layer in self.block1:
            a = self._conv(a, layer)
        b = a
        for layer in self.block2:
            b = self._conv(b, layer)
        w, bias, s = self.up2
        feat = torch.cat([self._conv(a, self.up1), F.relu(F.conv_transpose2d(b, w, bias, stride=s))], dim=1)
        out = []
        for (w, bias), k in zip(self.heads, (1, 7, 2)):
            h = F.conv2d(feat, w, bias)[0]  # [k*A, H, W]
            out.append(h.permute(1, 2, 0).reshape(-1, k).numpy())
        return out[0].reshape(-1), out[1], out[2]


# ---------------------------------------------------------------- voxels and anchors


def voxelize(grid, x, y, z, intensity):
    """The [C, n, n] float32 BEV of voxel.rs: density (nz), mean z (nz), column intensity (1),
    then with xy_means mean x (nz) and mean y (nz)."""
    f32 = np.float32
    n, nz = int(grid["n"]), int(grid["nz"])
    xy_min, cell = f32(grid["xy_min"]), f32(grid["cell"])
    z_min = f32(grid["z_min"])
    dz = (f32(grid["z_max"]) - z_min) / f32(nz)
    cols = n * n
    with np.errstate(invalid="ignore"):
        fz = (z - z_min) / dz
        fx = (x - xy_min) / cell
        fy = (y - xy_min) / cell
        ok = (fz >= 0) & (fz < f32(nz)) & (fx >= 0) & (fy >= 0)  # NaN compares false
        ok &= (fx < f32(n + 1)) & (fy < f32(n + 1))  # keep the casts below in range
        ix = np.where(ok, fx, 0).astype(np.int64)
        iy = np.where(ok, fy, 0).astype(np.int64)
    ok &= (ix < n) & (iy < n)
    fx, fy, fz, ix, iy, inten = fx[ok], fy[ok], fz[ok], ix[ok], iy[ok], intensity[ok]
    iz = fz.astype(np.int64)
    c = iy * n + ix
    v = iz * cols + c
    count = np.bincount(v, minlength=nz * cols)
    col_count = np.bincount(c, minlength=cols)

    def seq_sum(idx, vals, size):  # float32, in point order, as the Rust loop adds
        s = np.zeros(size, np.float32)
        np.add.at(s, idx, vals.astype(np.float32))
        return s

    xy = bool(grid["xy_means"])
    bev = np.zeros(((4 if xy else 2) * nz + 1, n, n), np.float32)
    flat = bev.reshape(-1)
    occ = count > 0
    cnt = count[occ].astype(np.float32)
    flat[:nz * cols][occ] = np.log1p(cnt)
    flat[nz * cols:2 * nz * cols][occ] = seq_sum(v, fz - iz.astype(np.float32), nz * cols)[occ] / cnt
    # Models trained with --no-intensity keep the channel at zero (voxel.rs: `intensity: false`).
    if not grid.get("intensity", True):
        inten = np.zeros_like(inten)
    isum = seq_sum(c, inten, cols)
    cocc = col_count > 0
    flat[2 * nz * cols:2 * nz * cols + cols][cocc] = isum[cocc] / (f32(255.0) * col_count[cocc].astype(np.float32))
    if xy:
        o = (2 * nz + 1) * cols
        flat[o:o + nz * cols][occ] = seq_sum(v, fx - np.floor(fx), nz * cols)[occ] / cnt
        flat[o + nz * cols:o + 2 * nz * cols][occ] = seq_sum(v, fy - np.floor(fy), nz * cols)[occ] / cnt
    return bev


def anchors(grid, anchor):
    """(N, 7) float32 anchors in (row, column, orientation) order, as anchors.rs builds them."""
    f32 = np.float32
    stride = max(int(anchor["stride"]), 1)
    n = int(grid["n"]) // stride
    cell = f32(grid["cell"]) * f32(stride)
    centres = f32(grid["xy_min"]) + (np.arange(n, dtype=np.float32) + f32(0.5)) * cell
    iy, ix, r = np.meshgrid(np.arange(n), np.arange(n), np.arange(len(ROTATIONS)), indexing="ij")
    out = np.empty(iy.shape + (7,), np.float32)
    out[..., 0] = centres[ix]
    out[..., 1] = centres[iy]
    out[..., 2] = f32(anchor["z_center"])
    out[..., 3:6] = np.asarray(anchor["size_lwh"], np.float32)
    out[..., 6] = np.asarray(ROTATIONS, np.float32)[r]
    return out.reshape(-1, 7)


def rem_euclid(a, b):
    """Rust's rem_euclid (fmod, then + |b| when negative), in the dtype of a."""
    r = np.fmod(a, b)
    return np.where(r < 0, r + abs(b), r)


def decode(r, a, dirs):
    """anchors.rs `decode` then `apply_direction`, float32, on (M, 7) residuals and anchors."""
    d = np.sqrt(a[:, 3] * a[:, 3] + a[:, 4] * a[:, 4])
    b = np.empty_like(a)
    b[:, 0] = a[:, 0] + r[:, 0] * d
    b[:, 1] = a[:, 1] + r[:, 1] * d
    b[:, 2] = a[:, 2] + r[:, 2] * a[:, 5]
    b[:, 3:6] = a[:, 3:6] * np.exp(r[:, 3:6])
    yaw = a[:, 6] + r[:, 6]
    base = rem_euclid(yaw - DIR_OFFSET, F32_PI) + DIR_OFFSET + np.where(dirs, F32_PI, np.float32(0))
    w = rem_euclid(base.astype(np.float32), np.float32(2) * F32_PI)
    b[:, 6] = np.where(w > F32_PI, w - np.float32(2) * F32_PI, w)
    return b


# ---------------------------------------------------------------- rotated BEV IoU, NMS, voting


def wrap_angle(a):
    """so3.rs wrap_angle: into (-pi, pi]."""
    x = math.fmod(a + math.pi, 2 * math.pi)
    if x < 0:
        x += 2 * math.pi
    x -= math.pi
    return x + 2 * math.pi if x <= -math.pi else x


def footprint(b):
    """iou.rs Footprint::of_box: (counter-clockwise corners, centre, radius, area), float64."""
    cx, cy, _, l, w, _, yaw = b
    s, c = math.sin(yaw), math.cos(yaw)
    u = (0.5 * l * c, 0.5 * l * s)
    v = (-0.5 * w * s, 0.5 * w * c)
    corners = [
        (cx + u[0] + v[0], cy + u[1] + v[1]),
        (cx - u[0] + v[0], cy - u[1] + v[1]),
        (cx - u[0] - v[0], cy - u[1] - v[1]),
        (cx + u[0] - v[0], cy + u[1] - v[1]),
    ]
    cr = u[0] * v[1] - u[1] * v[0]
    if cr < 0:
        corners.reverse()
    radius = max(math.hypot(u[0] + v[0], u[1] + v[1]), math.hypot(u[0] - v[0], u[1] - v[1]))
    return corners, (cx, cy), radius, 4.0 * abs(cr)


def clipped_area(subject, clip):
    """Area of the intersection of two convex CCW quadrilaterals (Sutherland-Hodgman, a vertex
    on an edge counts as inside), as iou.rs computes it."""
    cur = subject
    for e in range(4):
        px, py = clip[e]
        qx, qy = clip[(e + 1) % 4]
        ex, ey = qx - px, qy - py
        nxt = []
        m = len(cur)
        for i in range(m):
            s, t = cur[i], cur[(i + 1) % m]
            ds = ex * (s[1] - py) - ey * (s[0] - px)
            dt = ex * (t[1] - py) - ey * (t[0] - px)
            if ds >= 0.0:
                nxt.append(s)
            if (ds >= 0.0) != (dt >= 0.0):
                k = ds / (ds - dt)
                nxt.append((s[0] + k * (t[0] - s[0]), s[1] + k * (t[1] - s[1])))
        if len(nxt) < 3:
            return 0.0
        cur = nxt[:12]
    twice = 0.0
    for i in range(len(cur)):
        a, b = cur[i], cur[(i + 1) % len(cur)]
        twice += a[0] * b[1] - a[1] * b[0]
    return 0.5 * abs(twice)


def bev_iou(fa, fb):
    """BEV IoU of footprints fa (clipped) and fb (clipping), as iou_with_footprints."""
    dx, dy = fa[1][0] - fb[1][0], fa[1][1] - fb[1][1]
    reach = fa[2] + fb[2]
    inter = 0.0 if dx * dx + dy * dy > reach * reach else clipped_area(fa[0], fb[0])
    union = fa[3] + fb[3] - inter
    return min(max(inter / union, 0.0), 1.0) if union > 0.0 and math.isfinite(inter) else 0.0


def near(centres, radii, i, idx):
    """Those of `idx` whose footprint may touch footprint i (the quick rejection, vectorised)."""
    if len(idx) == 0:
        return idx
    d = centres[idx] - centres[i]
    reach = radii[idx] + radii[i]
    return idx[d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] <= reach * reach]


def nms(boxes, scores, foot, threshold, max_keep):
    """nms.rs: by descending score (ties by index, NaN last), kept unless its IoU with a kept box
    exceeds the threshold; the first `max_keep` kept."""
    key = np.where(np.isnan(scores), -np.inf, scores)
    order = sorted(range(len(boxes)), key=lambda i: (-key[i], i))
    centres = np.array([f[1] for f in foot]).reshape(-1, 2)
    radii = np.array([f[2] for f in foot])
    kept = []
    for i in order:
        if len(kept) >= max_keep:
            break
        cand = near(centres, radii, i, np.asarray(kept, dtype=np.int64))
        if not any(bev_iou(foot[i], foot[k]) > threshold for k in cand):
            kept.append(i)
    return kept


def vote(boxes, scores, foot, kept, vote_iou):
    """nms.rs `vote`: each kept box the score-weighted mean of the candidates overlapping it by
    at least vote_iou (itself included); headings relative to it, folded into [-pi/2, pi/2)."""
    centres = np.array([f[1] for f in foot]).reshape(-1, 2)
    radii = np.array([f[2] for f in foot])
    out = []
    half = math.pi / 2
    for k in kept:
        base = boxes[k]
        maybe = set(near(centres, radii, k, np.arange(len(boxes))).tolist())
        sw, c, s, dyaw = 0.0, [0.0] * 3, [0.0] * 3, 0.0
        for i in range(len(boxes)):
            w = float(scores[i])
            if not (math.isfinite(w) and w > 0.0):
                continue
            if i != k and (i not in maybe or bev_iou(foot[i], foot[k]) < vote_iou):
                continue
            b = boxes[i]
            for j in range(3):
                c[j] += w * b[j]
                s[j] += w * b[3 + j]
            t = wrap_angle(b[6] - base[6]) + half
            t = math.fmod(t, math.pi)
            if t < 0:
                t += math.pi
            dyaw += w * (t - half)
            sw += w
        if sw <= 0.0:
            out.append(list(base))
        else:
            out.append([v / sw for v in c] + [v / sw for v in s] + [wrap_angle(base[6] + dyaw / sw)])
    return out


# ---------------------------------------------------------------- the detector


class TorchTop:
    def __init__(self, models_dir, vote_iou="manifest"):
        self.config, tensors, manifest_vote = load_model(models_dir)
        self.net = FoldedNet(self.config, tensors)
        self.anchors = anchors(self.config["grid"], self.config["anchor"])
        if vote_iou == "manifest":
            self.vote_iou = manifest_vote
        elif vote_iou == "off":
            self.vote_iou = None
        else:
            self.vote_iou = float(vote_iou)

    def detect_points(self, pts):
        """Boxes (dicts of the protocol) on an (N, 6) float32 request cloud."""
        t0 = time.perf_counter()
        top = pts[pts[:, 4] == TOP_LIDAR]
        if len(pts) > 0 and len(top) == 0:
            raise ValueError("the request has no LIDAR_TOP points (lidar 0): LiDAR-Top has nothing to see")
        c = self.config
        bev = voxelize(c["grid"], top[:, 0], top[:, 1], top[:, 2], top[:, 3])
        t1 = time.perf_counter()
        cls, reg, dirs = self.net.forward(bev)
        t2 = time.perf_counter()
        n = min(len(cls), len(self.anchors))
        cls = cls[:n]
        p = np.float32(min(max(c["score_threshold"], 1e-6), 1.0 - 1e-6))
        logit_min = np.log(p / (np.float32(1) - p)) * np.float32(1.0)
        cand = np.nonzero((cls >= logit_min) & np.isfinite(cls))[0]
        cand = cand[np.lexsort((cand, -cls[cand]))][: int(c["pre_nms"])]
        if len(cand) == 0:
            return []
        raw = decode(reg[cand], self.anchors[cand], dirs[cand, 1] > dirs[cand, 0])
        z = cls[cand] / np.float32(1.0)
        score = np.float32(1) / (np.float32(1) + np.exp(-z))
        boxes = raw.astype(np.float64)
        valid = np.isfinite(boxes).all(axis=1) & (boxes[:, 3:6] > 0).all(axis=1)
        boxes, score = boxes[valid].tolist(), score[valid]
        foot = [footprint(b) for b in boxes]
        kept = nms(boxes, score, foot, float(c["nms_iou"]), int(c["max_detections"]))
        final = vote(boxes, score, foot, kept, self.vote_iou) if self.vote_iou else [boxes[k] for k in kept]
        cat = c["anchor"]["category"]
        self.times = (t1 - t0, t2 - t1, time.perf_counter() - t2)
        return [
            dict(category=cat, score=float(score[k]), center=b[:3], size_lwh=b[3:6], yaw=b[6])
            for k, b in zip(kept, final)
        ]


def default_models():
    """assets/models of the working folder, else of the repository this script is in."""
    if os.path.isdir(os.path.join("assets", "models")):
        return os.path.join("assets", "models")
    here = os.path.dirname(os.path.abspath(__file__))
    return os.path.join(here, "..", "..", "assets", "models")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", default=None, help="models folder with manifest.json (default: assets/models)")
    ap.add_argument("--threads", type=int, default=0, help="torch CPU threads (default: torch's choice)")
    ap.add_argument("--vote-iou", default="manifest", help="manifest (default), off, or an IoU in (0, 1]")
    ap.add_argument("--timing", action="store_true", help="print each frame's times (ms) to stderr")
    args = ap.parse_args()
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    det = TorchTop(args.models or default_models(), args.vote_iou)

    def detect(request, points):
        boxes = det.detect_points(np.asarray(points, np.float32).reshape(-1, 6))
        if args.timing:
            v, n, d = (1e3 * t for t in det.times)
            print("%s: voxels %.1f ms, network %.1f ms, decoding+NMS %.1f ms" % (request["sample_token"], v, n, d),
                  file=sys.stderr, flush=True)
        return boxes

    serve(detect)


if __name__ == "__main__":
    main()
