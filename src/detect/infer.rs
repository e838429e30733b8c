//! The inference path of the stage-1 network: the same layers as [`super::net`], evaluated
//! without candle for speed.
//!
//! Why: candle's CPU conv2d gathers its im2col matrix element by element and runs BatchNorm as
//! four broadcast passes, so one network took ~130 ms on two cores and Result Fusion (three
//! networks) ~350 ms. Here a trained network is folded once, at load, into plain layers:
//! - feature maps are row-major `[h, w, c]` (HWC), so a 3×3 patch row is one contiguous
//!   `3·c` copy and im2col is a handful of `memcpy`s per output pixel;
//! - BatchNorm (eval mode, `(x − mean)/√(var + ε)·γ + β`) is folded into the conv weights and a
//!   bias; ReLU is applied in the same pass as the bias;
//! - every conv is one `gemm` (the `gemm` crate candle itself uses) per band of output rows, the
//!   bands run in parallel with rayon; the band layout is fixed, so results do not depend on the
//!   number of threads;
//! - the neck writes both upsampled branches straight into the concatenated map, and the three
//!   heads are one 1×1 conv.
//!
//! Training keeps candle (it needs the gradients). Results agree with candle's forward to float
//! rounding (the summation order differs); `tests` checks it on the shipped weights.

use candle_core::Tensor;
use rayon::prelude::*;

use super::config::ModelConfig;
use super::net::{branch_prefix, HeadOutput};
use super::voxel::Bev;
use super::DetectError;
use crate::nn::gemm::gemm_rm;

/// BatchNorm's ε in candle-nn's default configuration, which [`super::net`] uses.
const BN_EPS: f32 = 1e-5;

/// Output pixels per gemm band (rows of the im2col matrix).
const BAND_PIXELS: usize = 512;

/// A feature map, row-major `[h, w, c]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Map {
    pub h: usize,
    pub w: usize,
    pub c: usize,
    pub data: Vec<f32>,
}

impl Map {
    fn zeros(h: usize, w: usize, c: usize) -> Self {
        Self {
            h,
            w,
            c,
            data: vec![0.0; h * w * c],
        }
    }

    /// A channel-major BEV `[C, n, n]` as an HWC map.
    pub fn from_bev(bev: &Bev) -> Self {
        let (n, c) = (bev.n, bev.channels);
        let plane = n * n;
        let mut m = Self::zeros(n, n, c);
        if bev.data.len() < c * plane {
            return m;
        }
        m.data.par_chunks_mut(n * c).enumerate().for_each(|(y, row)| {
            for ch in 0..c {
                let src = &bev.data[ch * plane + y * n..ch * plane + (y + 1) * n];
                for (x, v) in src.iter().enumerate() {
                    row[x * c + ch] = *v;
                }
            }
        });
        m
    }
}

/// The raw head outputs in anchor order (head row, column, orientation): `cls[i]`,
/// `reg[7i..7i + 7]`, `dir[2i..2i + 2]` for anchor `i`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RawHeads {
    pub cls: Vec<f32>,
    pub reg: Vec<f32>,
    pub dir: Vec<f32>,
}

impl RawHeads {
    /// The candle head tensors as plain vectors.
    pub fn from_candle(h: &HeadOutput) -> candle_core::Result<Self> {
        Ok(Self {
            cls: h.cls.to_vec1()?,
            reg: h.reg.flatten_all()?.to_vec1()?,
            dir: h.dir.flatten_all()?.to_vec1()?,
        })
    }
}

fn internal(what: String) -> DetectError {
    DetectError::BadParameter(format!("fast inference: {what}"))
}

/// Whether every band's gemm had operands of its shape ([`crate::nn::gemm::gemm_rm`] returned true).
fn gemms_fit(ok: bool) -> Result<(), DetectError> {
    if ok {
        Ok(())
    } else {
        Err(internal("a gemm operand is shorter than its shape".into()))
    }
}

/// A k×k convolution (stride `stride`, padding k/2) with folded BatchNorm and optional ReLU.
#[derive(Debug, Clone)]
struct Conv {
    k: usize,
    stride: usize,
    cin: usize,
    cout: usize,
    /// `[(ky, kx, ci), co]`, row-major.
    w: Vec<f32>,
    b: Vec<f32>,
    relu: bool,
}

impl Conv {
    /// From candle's `[cout, cin, k, k]` weight, a per-output scale and bias (folded BatchNorm).
    fn new(weight: &[f32], dims: &[usize], scale: &[f32], bias: Vec<f32>, stride: usize, relu: bool) -> Self {
        let (cout, cin, k) = (dims[0], dims[1], dims[2]);
        let mut w = vec![0f32; k * k * cin * cout];
        for co in 0..cout {
            for ci in 0..cin {
                for ky in 0..k {
                    for kx in 0..k {
                        w[((ky * k + kx) * cin + ci) * cout + co] =
                            weight[((co * cin + ci) * k + ky) * k + kx] * scale[co];
                    }
                }
            }
        }
        Self {
            k,
            stride,
            cin,
            cout,
            w,
            b: bias,
            relu,
        }
    }

    fn out_size(&self, n: usize) -> usize {
        (n + 2 * (self.k / 2)).saturating_sub(self.k) / self.stride + 1
    }

    fn forward(&self, x: &Map) -> Result<Map, DetectError> {
        let mut out = Map::zeros(self.out_size(x.h), self.out_size(x.w), self.cout);
        self.forward_into(x, &mut out, 0)?;
        Ok(out)
    }

    /// Writes the output into channels `c0..c0 + cout` of `dst` (whose size must match).
    fn forward_into(&self, x: &Map, dst: &mut Map, c0: usize) -> Result<(), DetectError> {
        let (oh, ow) = (self.out_size(x.h), self.out_size(x.w));
        if x.c != self.cin || dst.h != oh || dst.w != ow || c0 + self.cout > dst.c {
            return Err(internal(format!(
                "conv {}→{} on a {}×{}×{} map into {}×{}×{} at channel {c0}",
                self.cin, self.cout, x.h, x.w, x.c, dst.h, dst.w, dst.c
            )));
        }
        let (k, s, cin, cout, ldc) = (self.k, self.stride, self.cin, self.cout, dst.c);
        let pad = k / 2;
        let kk = k * k * cin;
        let rows_per_band = (BAND_PIXELS / ow.max(1)).max(1);
        let direct = k == 1 && s == 1;
        let ok = dst
            .data
            .par_chunks_mut(rows_per_band * ow * ldc)
            .enumerate()
            .map(|(band, chunk)| {
                let oy0 = band * rows_per_band;
                let rows = chunk.len() / (ow * ldc);
                let m = rows * ow;
                let fine = if direct {
                    gemm_rm(
                        m,
                        cout,
                        cin,
                        &x.data[oy0 * x.w * cin..],
                        cin,
                        &self.w,
                        cout,
                        &mut chunk[c0..],
                        ldc,
                        false,
                    )
                } else {
                    let mut patch = vec![0f32; m * kk];
                    for r in 0..rows {
                        let oy = oy0 + r;
                        for ox in 0..ow {
                            let p = &mut patch[(r * ow + ox) * kk..(r * ow + ox + 1) * kk];
                            for ky in 0..k {
                                let iy = (oy * s + ky) as isize - pad as isize;
                                if iy < 0 || iy >= x.h as isize {
                                    continue;
                                }
                                let row = iy as usize * x.w;
                                let ix0 = (ox * s) as isize - pad as isize;
                                let dst_row = &mut p[ky * k * cin..(ky + 1) * k * cin];
                                if ix0 >= 0 && ix0 as usize + k <= x.w {
                                    let from = (row + ix0 as usize) * cin;
                                    dst_row.copy_from_slice(&x.data[from..from + k * cin]);
                                } else {
                                    for kx in 0..k {
                                        let ix = ix0 + kx as isize;
                                        if ix >= 0 && (ix as usize) < x.w {
                                            let from = (row + ix as usize) * cin;
                                            dst_row[kx * cin..(kx + 1) * cin]
                                                .copy_from_slice(&x.data[from..from + cin]);
                                        }
                                    }
                                }
                            }
                        }
                    }
                    gemm_rm(
                        m,
                        cout,
                        kk,
                        &patch,
                        kk,
                        &self.w,
                        cout,
                        &mut chunk[c0..],
                        ldc,
                        false,
                    )
                };
                for px in chunk.chunks_mut(ldc) {
                    for (v, b) in px[c0..c0 + cout].iter_mut().zip(&self.b) {
                        *v += b;
                        if self.relu && *v < 0.0 {
                            *v = 0.0;
                        }
                    }
                }
                fine
            })
            .reduce(|| true, |a, b| a && b);
        gemms_fit(ok)
    }
}

/// A stride-s transposed convolution with an s×s kernel, folded BatchNorm and ReLU.
#[derive(Debug, Clone)]
struct Deconv {
    s: usize,
    cin: usize,
    cout: usize,
    /// `[ci, (ky, kx, co)]`, row-major.
    w: Vec<f32>,
    b: Vec<f32>,
}

impl Deconv {
    /// From candle's `[cin, cout, s, s]` weight and a folded BatchNorm.
    fn new(weight: &[f32], dims: &[usize], scale: &[f32], bias: Vec<f32>) -> Self {
        let (cin, cout, s) = (dims[0], dims[1], dims[2]);
        let mut w = vec![0f32; cin * s * s * cout];
        for ci in 0..cin {
            for co in 0..cout {
                for ky in 0..s {
                    for kx in 0..s {
                        w[ci * s * s * cout + (ky * s + kx) * cout + co] =
                            weight[((ci * cout + co) * s + ky) * s + kx] * scale[co];
                    }
                }
            }
        }
        Self {
            s,
            cin,
            cout,
            w,
            b: bias,
        }
    }

    /// Writes the output (`s·h × s·w`) into channels `c0..c0 + cout` of `dst`.
    fn forward_into(&self, x: &Map, dst: &mut Map, c0: usize) -> Result<(), DetectError> {
        let s = self.s;
        if x.c != self.cin || dst.h != s * x.h || dst.w != s * x.w || c0 + self.cout > dst.c {
            return Err(internal(format!(
                "deconv {}→{} on a {}×{}×{} map into {}×{}×{}",
                self.cin, self.cout, x.h, x.w, x.c, dst.h, dst.w, dst.c
            )));
        }
        let (cin, cout, ldc, ow) = (self.cin, self.cout, dst.c, dst.w);
        let n = s * s * cout;
        let rows_per_band = (BAND_PIXELS / x.w.max(1)).max(1);
        let ok = dst
            .data
            .par_chunks_mut(rows_per_band * s * ow * ldc)
            .enumerate()
            .map(|(band, chunk)| {
                let y0 = band * rows_per_band;
                let rows = chunk.len() / (s * ow * ldc);
                let m = rows * x.w;
                let mut tmp = vec![0f32; m * n];
                let fine = gemm_rm(
                    m,
                    n,
                    cin,
                    &x.data[y0 * x.w * cin..],
                    cin,
                    &self.w,
                    n,
                    &mut tmp,
                    n,
                    false,
                );
                for r in 0..rows {
                    for xi in 0..x.w {
                        let t = &tmp[(r * x.w + xi) * n..(r * x.w + xi + 1) * n];
                        for ky in 0..s {
                            for kx in 0..s {
                                let o = ((r * s + ky) * ow + xi * s + kx) * ldc + c0;
                                let src = &t[(ky * s + kx) * cout..(ky * s + kx + 1) * cout];
                                for ((d, v), b) in chunk[o..o + cout].iter_mut().zip(src).zip(&self.b) {
                                    *d = (v + b).max(0.0);
                                }
                            }
                        }
                    }
                }
                fine
            })
            .reduce(|| true, |a, b| a && b);
        gemms_fit(ok)
    }
}

/// The stage-1 network, folded for inference (see the module doc).
#[derive(Debug, Clone)]
pub struct FastNet {
    /// Per branch: conv1 (stride 2), conv2.
    branches: Vec<[Conv; 2]>,
    block1: Vec<Conv>,
    block2: Vec<Conv>,
    up1: Conv,
    up2: Deconv,
    /// cls, reg and dir heads as one 1×1 conv: channels `[cls (A), reg (7A), dir (2A)]`.
    heads: Conv,
    anchors_per_cell: usize,
}

/// Reads a tensor by name as (values, dims).
fn fetch(get: &dyn Fn(&str) -> Option<Tensor>, name: &str) -> Result<(Vec<f32>, Vec<usize>), DetectError> {
    let t = get(name).ok_or_else(|| internal(format!("no tensor {name}")))?;
    let dims = t.dims().to_vec();
    let v = t
        .to_dtype(candle_core::DType::F32)?
        .flatten_all()?
        .to_vec1::<f32>()?;
    Ok((v, dims))
}

/// Folds `prefix.bn.*` into (scale, bias) per channel, checking it has `n` channels.
fn fold_bn(
    get: &dyn Fn(&str) -> Option<Tensor>,
    prefix: &str,
    n: usize,
) -> Result<(Vec<f32>, Vec<f32>), DetectError> {
    let (gamma, _) = fetch(get, &format!("{prefix}.bn.weight"))?;
    let (beta, _) = fetch(get, &format!("{prefix}.bn.bias"))?;
    let (mean, _) = fetch(get, &format!("{prefix}.bn.running_mean"))?;
    let (var, _) = fetch(get, &format!("{prefix}.bn.running_var"))?;
    if [gamma.len(), beta.len(), mean.len(), var.len()]
        .iter()
        .any(|&l| l != n)
    {
        return Err(internal(format!("{prefix}.bn does not have {n} channels")));
    }
    let scale: Vec<f32> = gamma
        .iter()
        .zip(&var)
        .map(|(g, v)| g / (v + BN_EPS).sqrt())
        .collect();
    let bias = beta
        .iter()
        .zip(&mean)
        .zip(&scale)
        .map(|((b, m), s)| b - m * s)
        .collect();
    Ok((scale, bias))
}

fn conv_bn(get: &dyn Fn(&str) -> Option<Tensor>, prefix: &str, stride: usize) -> Result<Conv, DetectError> {
    let (w, dims) = fetch(get, &format!("{prefix}.conv.weight"))?;
    if dims.len() != 4 || dims[2] != dims[3] || dims[2] % 2 == 0 {
        return Err(internal(format!("{prefix}.conv.weight has shape {dims:?}")));
    }
    let (scale, bias) = fold_bn(get, prefix, dims[0])?;
    Ok(Conv::new(&w, &dims, &scale, bias, stride, true))
}

impl FastNet {
    /// Folds the network of `config` from its named tensors (`middle.conv1.conv.weight`, ...).
    pub fn build(config: &ModelConfig, get: &dyn Fn(&str) -> Option<Tensor>) -> Result<Self, DetectError> {
        let names = config.branch_names();
        let branches = names
            .iter()
            .map(|name| {
                let p = branch_prefix(&names, name);
                Ok([
                    conv_bn(get, &format!("{p}.conv1"), 2)?,
                    conv_bn(get, &format!("{p}.conv2"), 1)?,
                ])
            })
            .collect::<Result<Vec<_>, DetectError>>()?;
        let net = &config.net;
        let block1 = (0..net.rpn_layers)
            .map(|i| conv_bn(get, &format!("rpn.block1.{i}"), 1))
            .collect::<Result<Vec<_>, _>>()?;
        let block2 = (0..=net.rpn_layers)
            .map(|i| conv_bn(get, &format!("rpn.block2.{i}"), if i == 0 { 2 } else { 1 }))
            .collect::<Result<Vec<_>, _>>()?;
        let up1 = conv_bn(get, "rpn.up1", 1)?;
        let (w, dims) = fetch(get, "rpn.up2.deconv.weight")?;
        if dims.len() != 4 || dims[2] != dims[3] {
            return Err(internal(format!("rpn.up2.deconv.weight has shape {dims:?}")));
        }
        let (scale, bias) = fold_bn(get, "rpn.up2", dims[1])?;
        let up2 = Deconv::new(&w, &dims, &scale, bias);
        // The three heads side by side as one [10A, 2r, 1, 1] conv.
        let (mut hw, mut hb, mut cin) = (Vec::new(), Vec::new(), None);
        for head in ["cls", "reg", "dir"] {
            let (w, dims) = fetch(get, &format!("rpn.{head}.weight"))?;
            let (b, _) = fetch(get, &format!("rpn.{head}.bias"))?;
            if dims.len() != 4 || b.len() != dims[0] || cin.is_some_and(|c| c != dims[1]) {
                return Err(internal(format!("rpn.{head}.weight has shape {dims:?}")));
            }
            cin = Some(dims[1]);
            hw.extend(w);
            hb.extend(b);
        }
        let cin = cin.unwrap_or(0);
        let cout = hb.len();
        let heads = Conv::new(&hw, &[cout, cin, 1, 1], &vec![1.0; cout], hb, 1, false);
        let a = net.anchors_per_cell;
        if cout != 10 * a {
            return Err(internal(format!(
                "heads have {cout} channels, expected {}",
                10 * a
            )));
        }
        Ok(Self {
            branches,
            block1,
            block2,
            up1,
            up2,
            heads,
            anchors_per_cell: a,
        })
    }

    /// The head outputs on BEV inputs (one per branch, `None` where the LiDAR is absent);
    /// branch features are fused by the element-wise maximum (paper eq. 10).
    pub fn forward(&self, bevs: &[Option<Bev>]) -> Result<RawHeads, DetectError> {
        let mut fused: Option<Map> = None;
        for (branch, bev) in self.branches.iter().zip(bevs) {
            let Some(bev) = bev else { continue };
            let f = branch[1].forward(&branch[0].forward(&Map::from_bev(bev))?)?;
            fused = Some(match fused {
                None => f,
                Some(mut g) => {
                    if g.data.len() != f.data.len() {
                        return Err(internal("branch feature maps differ in size".into()));
                    }
                    g.data
                        .par_chunks_mut(4096)
                        .zip(f.data.par_chunks(4096))
                        .for_each(|(a, b)| a.iter_mut().zip(b).for_each(|(x, y)| *x = x.max(*y)));
                    g
                }
            });
        }
        let mut a = fused.ok_or_else(|| internal("no input branch present".into()))?;
        for l in &self.block1 {
            a = l.forward(&a)?;
        }
        let mut b = self.block2[0].forward(&a)?;
        for l in &self.block2[1..] {
            b = l.forward(&b)?;
        }
        let r = self.up1.cout;
        let mut feat = Map::zeros(a.h, a.w, r + self.up2.cout);
        self.up1.forward_into(&a, &mut feat, 0)?;
        self.up2.forward_into(&b, &mut feat, r)?;
        let out = self.heads.forward(&feat)?;
        let na = self.anchors_per_cell;
        let pixels = out.h * out.w;
        let mut heads = RawHeads {
            cls: Vec::with_capacity(pixels * na),
            reg: Vec::with_capacity(pixels * na * 7),
            dir: Vec::with_capacity(pixels * na * 2),
        };
        for px in out.data.chunks_exact(10 * na) {
            heads.cls.extend_from_slice(&px[..na]);
            heads.reg.extend_from_slice(&px[na..8 * na]);
            heads.dir.extend_from_slice(&px[8 * na..]);
        }
        Ok(heads)
    }
}
