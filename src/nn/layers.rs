//! The layers of the native training network ([`crate::train::stage1::native::NativeTrainer`]): convolution and
//! transposed convolution as gemm (forward, weight gradient, input gradient), BatchNorm in
//! training mode fused with its ReLU, and the 1×1 heads. Every buffer is allocated once, when the
//! trainer is built, and reused at every step.

use candle_core::Result;
use rayon::prelude::*;

use crate::nn::gemm::{deconv_permute, Geom, Mat};
use crate::nn::kernel::gemm as gemm_into;
use crate::nn::{dgrad, implicit};

/// candle_nn's BatchNorm defaults, which the candle graph trains with.
const BN_EPS: f32 = 1e-5;
const BN_MOMENTUM: f32 = 0.1;

/// A tensor of the network: its value and, for trainable ones, the gradient of the last step.
#[derive(Debug, Clone)]
pub(crate) struct Param {
    pub name: String,
    pub shape: Vec<usize>,
    pub value: Vec<f32>,
    pub grad: Vec<f32>,
    /// Whether the last step reached this tensor (AdamW leaves the others alone, as it does
    /// with candle's gradient store: an absent LiDAR's branch, the box heads without positives).
    pub has_grad: bool,
}

/// Σ v, accumulated in f64 over eight lanes (vectorised; the same order at every call).
/// BatchNorm's sums need the wider accumulator: over a sparse BEV channel (most cells one constant
/// value) f32 lanes lose enough of the mean that the gradients of the layers below drift by 1e-3.
pub(crate) fn sum8(v: &[f32]) -> f32 {
    sum8_by(v, |x| x as f64) as f32
}

/// (Σ v, Σ v²) in f64 over eight lanes, one pass.
fn moments8(v: &[f32]) -> (f64, f64) {
    let (mut s, mut q) = ([0f64; 8], [0f64; 8]);
    let chunks = v.chunks_exact(8);
    let (mut rs, mut rq) = (0f64, 0f64);
    for &x in chunks.remainder() {
        rs += x as f64;
        rq += (x as f64) * (x as f64);
    }
    for c in chunks {
        for ((a, b), &x) in s.iter_mut().zip(q.iter_mut()).zip(c) {
            let x = x as f64;
            *a += x;
            *b += x * x;
        }
    }
    (s.iter().sum::<f64>() + rs, q.iter().sum::<f64>() + rq)
}

fn sum8_by(v: &[f32], f: impl Fn(f32) -> f64) -> f64 {
    let mut acc = [0f64; 8];
    let chunks = v.chunks_exact(8);
    let rest: f64 = chunks.remainder().iter().map(|&x| f(x)).sum();
    for c in chunks {
        for (a, &x) in acc.iter_mut().zip(c) {
            *a += f(x);
        }
    }
    acc.iter().sum::<f64>() + rest
}

/// BatchNorm (batch statistics) + ReLU over `c` channels of `p` pixels, and its buffers.
#[derive(Debug)]
pub(crate) struct BnRelu {
    gamma: usize,
    beta: usize,
    running_mean: usize,
    running_var: usize,
    c: usize,
    p: usize,
    /// The layer's pre-BN output; after the forward pass, x̂ (normalised, before γ, β).
    pub y: Vec<f32>,
    invstd: Vec<f32>,
    mean: Vec<f32>,
    var: Vec<f32>,
    /// The layer's output, ReLU(γ x̂ + β).
    pub out: Vec<f32>,
    /// ∂L/∂out, filled by the layers above; the backward pass turns it into ∂L/∂y in place.
    pub dout: Vec<f32>,
}

impl BnRelu {
    /// `idx`: γ, β (trainable) and running mean, var (statistics).
    pub fn new(idx: [usize; 4], c: usize, p: usize) -> Self {
        Self {
            gamma: idx[0],
            beta: idx[1],
            running_mean: idx[2],
            running_var: idx[3],
            c,
            p,
            y: vec![0.0; c * p],
            invstd: vec![0.0; c],
            mean: vec![0.0; c],
            var: vec![0.0; c],
            out: vec![0.0; c * p],
            dout: vec![0.0; c * p],
        }
    }

    pub fn forward(&mut self, params: &[Param], stats: &mut [Param]) {
        let p = self.p;
        let (gamma, beta) = (&params[self.gamma].value, &params[self.beta].value);
        self.y
            .par_chunks_mut(p)
            .zip(self.out.par_chunks_mut(p))
            .zip(self.mean.par_iter_mut().zip(self.var.par_iter_mut()))
            .zip(self.invstd.par_iter_mut())
            .enumerate()
            .for_each(|(ch, (((y, out), (mean, var)), invstd))| {
                let (sum, sq) = moments8(y);
                let mu = sum / p as f64;
                let (m, v) = (mu as f32, (sq / p as f64 - mu * mu).max(0.0) as f32);
                let inv = 1.0 / (v + BN_EPS).sqrt();
                let (g, b) = (gamma[ch], beta[ch]);
                for (yv, o) in y.iter_mut().zip(out.iter_mut()) {
                    let xh = (*yv - m) * inv;
                    *yv = xh;
                    *o = (g * xh + b).max(0.0);
                }
                (*mean, *var, *invstd) = (m, v, inv);
            });
        // Running statistics as candle_nn updates them (unbiased variance).
        let unbias = (BN_MOMENTUM as f64 * p as f64 / (p as f64 - 1.0).max(1.0)) as f32;
        for (r, m) in stats[self.running_mean].value.iter_mut().zip(&self.mean) {
            *r = *r * (1.0 - BN_MOMENTUM) + m * BN_MOMENTUM;
        }
        for (r, v) in stats[self.running_var].value.iter_mut().zip(&self.var) {
            *r = *r * (1.0 - BN_MOMENTUM) + v * unbias;
        }
    }

    /// ∂L/∂out → ∂L/∂y in `dout`; γ's and β's gradients.
    pub fn backward(&mut self, params: &mut [Param]) {
        let (p, c) = (self.p, self.c);
        let mut dg = vec![0f32; c];
        let mut db = vec![0f32; c];
        {
            let (gamma, beta) = (&params[self.gamma].value, &params[self.beta].value);
            self.dout
                .par_chunks_mut(p)
                .zip(self.y.par_chunks(p))
                .zip(dg.par_iter_mut().zip(db.par_iter_mut()))
                .zip(self.invstd.par_iter())
                .enumerate()
                .for_each(|(ch, (((d, xh), (dgv, dbv)), &inv))| {
                    let (g, b) = (gamma[ch], beta[ch]);
                    // candle's ReLU passes the gradient where its input is ≥ 0.
                    let (mut sb, mut sg) = ([0f64; 8], [0f64; 8]);
                    for (dc, xc) in d.chunks_mut(8).zip(xh.chunks(8)) {
                        for (k, (dv, &x)) in dc.iter_mut().zip(xc).enumerate() {
                            let dz = if g * x + b >= 0.0 { *dv } else { 0.0 };
                            *dv = dz;
                            sb[k] += dz as f64;
                            sg[k] += (dz * x) as f64;
                        }
                    }
                    let (sb, sg): (f32, f32) = (sb.iter().sum::<f64>() as f32, sg.iter().sum::<f64>() as f32);
                    let n = p as f32;
                    let k = g * inv / n;
                    for (dv, &x) in d.iter_mut().zip(xh) {
                        *dv = k * (n * *dv - sb - x * sg);
                    }
                    (*dgv, *dbv) = (sg, sb);
                });
        }
        for (i, g) in [(self.gamma, dg), (self.beta, db)] {
            params[i].grad = g;
            params[i].has_grad = true;
        }
    }
}

/// Where a layer's input gradient goes: written over, or added to, the buffer.
pub(crate) type InputGrad<'a> = Option<(&'a mut [f32], bool)>;

/// Convolution (no bias) + BatchNorm + ReLU.
#[derive(Debug)]
pub(crate) struct ConvBn {
    geom: Geom,
    cout: usize,
    weight: usize,
    /// 1×1 stride 1: the input is the gemm's `b` itself.
    direct: bool,
    /// Stride-1 same conv on AVX-512 ([`implicit::applies`]): forward, weight and input gradient
    /// read the input's (or ∂L/∂y's) shifted rows; no `col`.
    implicit: bool,
    /// im2col of the input (`K × P`), then the input's column gradient (strided convs, or
    /// without AVX-512); empty for 1×1 and implicit convs.
    col: Vec<f32>,
    pub bn: BnRelu,
}

impl ConvBn {
    pub fn new(geom: Geom, cout: usize, weight: usize, bn: [usize; 4]) -> Self {
        let direct = geom.k == 1 && geom.stride == 1 && geom.pad == 0;
        let implicit = implicit::applies(&geom);
        Self {
            geom,
            cout,
            weight,
            direct,
            implicit,
            col: if direct || implicit {
                Vec::new()
            } else {
                vec![0.0; geom.kk() * geom.p()]
            },
            bn: BnRelu::new(bn, cout, geom.p()),
        }
    }

    /// Output height and width.
    pub fn geom_out(&self) -> (usize, usize) {
        (self.geom.ho, self.geom.wo)
    }

    pub fn cout(&self) -> usize {
        self.cout
    }

    pub fn input_len(&self) -> usize {
        self.geom.cin * self.geom.h * self.geom.w
    }

    pub fn forward(&mut self, x: &[f32], params: &[Param], stats: &mut [Param]) -> Result<()> {
        let (kk, p, co) = (self.geom.kk(), self.geom.p(), self.cout);
        let w = &params[self.weight].value;
        if self.implicit {
            implicit::forward(&self.geom, co, w, x, &mut self.bn.y)?;
            self.bn.forward(params, stats);
            return Ok(());
        }
        if !self.direct {
            self.geom.im2col(x, &mut self.col);
        }
        let col: &[f32] = if self.direct { x } else { &self.col };
        gemm_into(
            &mut self.bn.y,
            Mat::rm(co, p),
            w,
            Mat::rm(co, kk),
            col,
            Mat::rm(kk, p),
            false,
        )?;
        self.bn.forward(params, stats);
        Ok(())
    }

    /// Backward from `bn.dout`; `x` is the forward pass's input.
    pub fn backward(&mut self, x: &[f32], params: &mut [Param], dx: InputGrad<'_>) -> Result<()> {
        self.bn.backward(params);
        let (kk, p, co) = (self.geom.kk(), self.geom.p(), self.cout);
        let direct = self.direct;
        {
            let pw = &mut params[self.weight];
            if self.implicit {
                implicit::weight_grad(&self.geom, co, &self.bn.dout, x, &mut pw.grad)?;
            } else {
                let col: &[f32] = if direct { x } else { &self.col };
                gemm_into(
                    &mut pw.grad,
                    Mat::rm(co, kk),
                    &self.bn.dout,
                    Mat::rm(co, p),
                    col,
                    Mat::tr(kk, p),
                    false,
                )?;
            }
            pw.has_grad = true;
        }
        let Some((dx, accumulate)) = dx else {
            return Ok(());
        };
        let w = &params[self.weight].value;
        if self.implicit {
            // Stride-1 3×3: straight from ∂L/∂y, no column gradient, no col2im.
            dgrad::input_grad(&self.geom, co, w, &self.bn.dout, dx, accumulate)?;
        } else if direct {
            gemm_into(
                dx,
                Mat::rm(kk, p),
                w,
                Mat::tr(co, kk),
                &self.bn.dout,
                Mat::rm(co, p),
                accumulate,
            )?;
        } else {
            gemm_into(
                &mut self.col,
                Mat::rm(kk, p),
                w,
                Mat::tr(co, kk),
                &self.bn.dout,
                Mat::rm(co, p),
                false,
            )?;
            self.geom.col2im_into(&self.col, dx, accumulate);
        }
        Ok(())
    }
}

/// Transposed convolution with kernel = stride (no bias) + BatchNorm + ReLU; weight
/// `[C_in, C_out, s, s]`.
#[derive(Debug)]
pub(crate) struct DeconvBn {
    cin: usize,
    cout: usize,
    s: usize,
    h: usize,
    w: usize,
    weight: usize,
    /// `[C_out·s·s, H·W]`: the gemm's output, then the output gradient gathered back.
    z: Vec<f32>,
    pub bn: BnRelu,
}

impl DeconvBn {
    pub fn new(cin: usize, cout: usize, s: usize, h: usize, w: usize, weight: usize, bn: [usize; 4]) -> Self {
        Self {
            cin,
            cout,
            s,
            h,
            w,
            weight,
            z: vec![0.0; cout * s * s * h * w],
            bn: BnRelu::new(bn, cout, s * s * h * w),
        }
    }

    pub fn forward(&mut self, x: &[f32], params: &[Param], stats: &mut [Param]) -> Result<()> {
        let (p, j) = (self.h * self.w, self.cout * self.s * self.s);
        let w = &params[self.weight].value;
        gemm_into(
            &mut self.z,
            Mat::rm(j, p),
            w,
            Mat::tr(self.cin, j),
            x,
            Mat::rm(self.cin, p),
            false,
        )?;
        deconv_permute(&mut self.z, &mut self.bn.y, self.s, self.h, self.w, false);
        self.bn.forward(params, stats);
        Ok(())
    }

    pub fn backward(&mut self, x: &[f32], params: &mut [Param], dx: InputGrad<'_>) -> Result<()> {
        self.bn.backward(params);
        let (p, j, ci) = (self.h * self.w, self.cout * self.s * self.s, self.cin);
        deconv_permute(&mut self.z, &mut self.bn.dout, self.s, self.h, self.w, true);
        {
            let pw = &mut params[self.weight];
            gemm_into(
                &mut pw.grad,
                Mat::rm(ci, j),
                x,
                Mat::rm(ci, p),
                &self.z,
                Mat::tr(j, p),
                false,
            )?;
            pw.has_grad = true;
        }
        if let Some((dx, accumulate)) = dx {
            let w = &params[self.weight].value;
            gemm_into(
                dx,
                Mat::rm(ci, p),
                w,
                Mat::rm(ci, j),
                &self.z,
                Mat::rm(j, p),
                accumulate,
            )?;
        }
        Ok(())
    }
}

/// The three 1×1 heads (class, box, direction; with bias) over the concatenation of the two
/// neck branches, as one stacked `rows × 2r` matrix.
#[derive(Debug)]
pub(crate) struct Heads {
    /// (weight, bias, rows) of cls, reg, dir.
    parts: [(usize, usize, usize); 3],
    r: usize,
    p: usize,
    rows: usize,
    w: Vec<f32>,
    dw: Vec<f32>,
    /// Head outputs `[rows, P]`: cls rows, then reg, then dir (candle's channel order).
    pub h: Vec<f32>,
    /// ∂L/∂h, written by the loss.
    pub dh: Vec<f32>,
}

impl Heads {
    pub fn new(parts: [(usize, usize, usize); 3], r: usize, p: usize) -> Self {
        let rows = parts.iter().map(|q| q.2).sum();
        Self {
            parts,
            r,
            p,
            rows,
            w: vec![0.0; rows * 2 * r],
            dw: vec![0.0; rows * 2 * r],
            h: vec![0.0; rows * p],
            dh: vec![0.0; rows * p],
        }
    }

    /// `h = W[:, :r]·u1 + W[:, r:]·u2 + b`.
    pub fn forward(&mut self, u1: &[f32], u2: &[f32], params: &[Param]) -> Result<()> {
        let (r, p, rows) = (self.r, self.p, self.rows);
        let mut row0 = 0;
        for &(wi, _, n) in &self.parts {
            self.w[row0 * 2 * r..(row0 + n) * 2 * r].copy_from_slice(&params[wi].value);
            row0 += n;
        }
        let half = Mat::strided(rows, r, 2 * r, 1);
        gemm_into(
            &mut self.h,
            Mat::rm(rows, p),
            &self.w,
            half,
            u1,
            Mat::rm(r, p),
            false,
        )?;
        gemm_into(
            &mut self.h,
            Mat::rm(rows, p),
            &self.w[r..],
            half,
            u2,
            Mat::rm(r, p),
            true,
        )?;
        let mut row0 = 0;
        for &(_, bi, n) in &self.parts {
            let b = &params[bi].value;
            self.h[row0 * p..(row0 + n) * p]
                .par_chunks_mut(p)
                .zip(b.par_iter())
                .for_each(|(row, &bv)| row.iter_mut().for_each(|v| *v += bv));
            row0 += n;
        }
        Ok(())
    }

    /// Backward from `dh`: the heads' gradients (those in `reached`: cls, reg, dir), and ∂L/∂u1,
    /// ∂L/∂u2 written into `du1`, `du2`.
    pub fn backward(
        &mut self,
        u1: &[f32],
        u2: &[f32],
        params: &mut [Param],
        reached: [bool; 3],
        du1: &mut [f32],
        du2: &mut [f32],
    ) -> Result<()> {
        let (r, p, rows) = (self.r, self.p, self.rows);
        let half = Mat::strided(rows, r, 2 * r, 1);
        gemm_into(
            &mut self.dw,
            half,
            &self.dh,
            Mat::rm(rows, p),
            u1,
            Mat::tr(r, p),
            false,
        )?;
        gemm_into(
            &mut self.dw[r..],
            half,
            &self.dh,
            Mat::rm(rows, p),
            u2,
            Mat::tr(r, p),
            false,
        )?;
        let half_t = Mat::strided(r, rows, 1, 2 * r);
        gemm_into(
            du1,
            Mat::rm(r, p),
            &self.w,
            half_t,
            &self.dh,
            Mat::rm(rows, p),
            false,
        )?;
        gemm_into(
            du2,
            Mat::rm(r, p),
            &self.w[r..],
            half_t,
            &self.dh,
            Mat::rm(rows, p),
            false,
        )?;
        let mut row0 = 0;
        for (&(wi, bi, n), reached) in self.parts.iter().zip(reached) {
            let db: Vec<f32> = self.dh[row0 * p..(row0 + n) * p]
                .par_chunks(p)
                .map(sum8)
                .collect();
            params[wi]
                .grad
                .copy_from_slice(&self.dw[row0 * 2 * r..(row0 + n) * 2 * r]);
            params[bi].grad = db;
            params[wi].has_grad = reached;
            params[bi].has_grad = reached;
            row0 += n;
        }
        Ok(())
    }
}
