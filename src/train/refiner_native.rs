//! The native training path of the refiner (issue 28), as [`crate::train::stage1::native`] is stage 1's:
//! forward, backward and AdamW of [`crate::refine::net::RefinerNet`] + [`crate::train::refiner_loss::loss`] written out
//! over flat buffers that live as long as the trainer, no graph and no allocation per op (buffers
//! are resized only when a batch has another number of proposals).
//!
//! Layout: channels first. The point MLP works on `C × P` matrices (P = b·n points,
//! proposal-major), so every Linear is one gemm `Y = W·X` and every BatchNorm row is contiguous
//! ([`BnRelu`], stage 1's fused BatchNorm + ReLU with f64 batch statistics); the input points
//! (`(P, C)` row-major, as the batch has them) are read through a transposed view. The max over
//! each proposal's n points makes the `width × b` global feature; the proposal MLP, the head and
//! the two outputs are `C × b` gemms.
//!
//! It computes the function and the update of the candle graph to float rounding: the tests
//! compare every gradient with candle's graph run in f64, and a few steps with candle's path.
//! The candle graph's quirks are kept: the max's gradient goes to every point that ties for it,
//! ReLU passes the gradient where its input is ≥ 0, every tensor gets a gradient at every step
//! (the regression head too when a batch has no positives: zero, which AdamW still applies, as
//! candle's gradient store holds it). Work is parallel over rayon's threads (gemm's blocks, one
//! channel per task elsewhere) with every reduction in a fixed order: a step is deterministic
//! for a given thread count.

#[cfg(test)]
mod tests;

use candle_nn::VarMap;
use rayon::prelude::*;

use crate::nn::gemm::Mat;
use crate::nn::kernel::gemm as gemm_into;
use crate::nn::layers::{sum8, BnRelu, Param};
use crate::refine::coding::RESIDUALS;
use crate::refine::net::{RefinerConfig, PROPOSAL_FEATURES};
use crate::refine::RefineError;
use crate::train::optim::AdamW;
use crate::train::refiner_loss::{uct_weight, Target, ETA, LAMBDA};
use crate::train::stage1::native::loss::{focal, smooth_l1};
use crate::train::stage1::native::state::{
    gradient_of, params_of, stats_of, store_stats, value_of, FlatAdamW, TensorIndex,
};

/// The loss terms of one step, as the trainer logs them (eq. 17).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefinerTerms {
    pub total: f32,
    pub reg: f32,
    pub cls: f32,
    pub uct: f32,
    pub positives: usize,
}

/// The outcome of one training step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NativeRefinerStep {
    pub loss: RefinerTerms,
    /// The global gradient norm before clipping.
    pub grad_norm: f64,
}

/// One point-MLP layer: Linear (with bias) + BatchNorm + ReLU over `cout × P`.
#[derive(Debug)]
struct PointLayer {
    weight: usize,
    bias: usize,
    bn_idx: [usize; 4],
    cin: usize,
    cout: usize,
    bn: BnRelu,
}

/// A Linear (with bias) on `cin × b` columns, optionally followed by ReLU.
#[derive(Debug)]
struct Dense {
    weight: usize,
    bias: usize,
    cin: usize,
    cout: usize,
    relu: bool,
    /// Pre-activation `cout × b`.
    z: Vec<f32>,
    out: Vec<f32>,
    /// ∂L/∂out, turned into ∂L/∂z in place by the backward pass.
    dout: Vec<f32>,
}

impl Dense {
    fn resize(&mut self, b: usize) {
        for v in [&mut self.z, &mut self.out, &mut self.dout] {
            v.resize(self.cout * b, 0.0);
        }
    }

    /// `x` viewed as `cin × b` through `xm`.
    fn forward(&mut self, x: &[f32], xm: Mat, b: usize, params: &[Param]) -> candle_core::Result<()> {
        gemm_into(
            &mut self.z,
            Mat::rm(self.cout, b),
            &params[self.weight].value,
            Mat::rm(self.cout, self.cin),
            x,
            xm,
            false,
        )?;
        let bias = &params[self.bias].value;
        for ((zr, or), &bv) in self.z.chunks_mut(b).zip(self.out.chunks_mut(b)).zip(bias) {
            for (z, o) in zr.iter_mut().zip(or.iter_mut()) {
                *z += bv;
                *o = if self.relu { z.max(0.0) } else { *z };
            }
        }
        Ok(())
    }

    /// Backward from `dout`; `xtm` views `x` as `b × cin`. The input gradient goes to `dx`
    /// (written over, or added to).
    fn backward(
        &mut self,
        x: &[f32],
        xtm: Mat,
        b: usize,
        params: &mut [Param],
        dx: Option<(&mut [f32], bool)>,
    ) -> candle_core::Result<()> {
        if self.relu {
            for (d, &z) in self.dout.iter_mut().zip(&self.z) {
                if z < 0.0 {
                    *d = 0.0;
                }
            }
        }
        {
            let pw = &mut params[self.weight];
            gemm_into(
                &mut pw.grad,
                Mat::rm(self.cout, self.cin),
                &self.dout,
                Mat::rm(self.cout, b),
                x,
                xtm,
                false,
            )?;
            pw.has_grad = true;
        }
        let db: Vec<f32> = self.dout.chunks(b).map(sum8).collect();
        params[self.bias].grad = db;
        params[self.bias].has_grad = true;
        if let Some((dx, accumulate)) = dx {
            gemm_into(
                dx,
                Mat::rm(self.cin, b),
                &params[self.weight].value,
                Mat::tr(self.cout, self.cin),
                &self.dout,
                Mat::rm(self.cout, b),
                accumulate,
            )?;
        }
        Ok(())
    }
}

/// A refiner's tensors and buffers for training (see the module doc).
#[derive(Debug)]
pub struct NativeRefiner {
    /// Trainable tensors in AdamW's order (name order).
    params: Vec<Param>,
    /// BatchNorm's running statistics.
    stats: Vec<Param>,
    adam: FlatAdamW,
    point: Vec<PointLayer>,
    /// Points per proposal, input channels, the global feature's width.
    n: usize,
    ch: usize,
    width: usize,
    /// Proposals in the current buffers.
    b: usize,
    /// The concatenation [global; proposal code] (`(width + pw) × b`) and its gradient.
    h0: Vec<f32>,
    dh0: Vec<f32>,
    prop: Dense,
    head: Vec<Dense>,
    cls: Dense,
    reg: Dense,
    /// The classification target is the IoU quality ([`RefinerConfig::iou_score`]).
    iou_score: bool,
}

/// The IoU-quality target of a proposal with 3D IoU `iou` (PV-RCNN's): 0 up to 0.25, 1 from 0.75.
pub fn iou_quality(iou: f64) -> f32 {
    ((iou - 0.25) / 0.5).clamp(0.0, 1.0) as f32
}

/// Binary cross-entropy of the logit `x` toward the soft label `y`, and its derivative in `x`
/// (σ(x) − y); computed as max(x, 0) − x·y + ln(1 + e^(−|x|)), stable for any `x`.
fn bce(x: f32, y: f32) -> (f32, f32) {
    let l = x.max(0.0) - x * y + (-x.abs()).exp().ln_1p();
    let s = 1.0 / (1.0 + (-x).exp());
    (l, s - y)
}

fn bad(what: String) -> RefineError {
    RefineError::BadParameter(format!("native refiner trainer: {what}"))
}

/// (weight, bias) of the Linear `prefix`, checked to be `cout × cin`.
fn linear(names: &TensorIndex, prefix: &str, cin: usize, cout: usize) -> Result<(usize, usize), RefineError> {
    let weight = format!("{prefix}.weight");
    let bias = format!("{prefix}.bias");
    let (ws, bs) = (names.shape(&weight)?, names.shape(&bias)?);
    if ws != [cout, cin] || bs != [cout] {
        return Err(bad(format!(
            "{prefix}: shapes {ws:?}, {bs:?}, expected [{cout}, {cin}], [{cout}]"
        )));
    }
    Ok((names.param(&weight)?, names.param(&bias)?))
}

fn dense(
    names: &TensorIndex,
    prefix: &str,
    cin: usize,
    cout: usize,
    relu: bool,
) -> Result<Dense, RefineError> {
    let (weight, bias) = linear(names, prefix, cin, cout)?;
    Ok(Dense {
        weight,
        bias,
        cin,
        cout,
        relu,
        z: Vec::new(),
        out: Vec::new(),
        dout: Vec::new(),
    })
}

impl NativeRefiner {
    /// The trainer of the refiner `cfg` whose variables are `varmap`, with the state of `opt`
    /// (its moments and step count).
    pub fn new(cfg: &RefinerConfig, varmap: &VarMap, opt: &AdamW) -> Result<Self, RefineError> {
        let params = params_of(opt)?;
        let stats = stats_of(varmap)?;
        let adam = FlatAdamW::of(opt)?;
        let names = TensorIndex::new(&params, &stats);
        if cfg.point_mlp.is_empty() {
            return Err(bad(
                "a point MLP without layers (train with --slow-autograd)".into()
            ));
        }
        let ch = cfg.gather.features.channels();
        let mut cin = ch;
        let mut point = Vec::new();
        for (k, &cout) in cfg.point_mlp.iter().enumerate() {
            let p = format!("point.{k}");
            let (weight, bias) = linear(&names, &format!("{p}.lin"), cin, cout)?;
            let bn_idx = names.bn(&p)?;
            point.push(PointLayer {
                weight,
                bias,
                bn_idx,
                cin,
                cout,
                bn: BnRelu::new(bn_idx, cout, 0),
            });
            cin = cout;
        }
        let width = cin;
        let pw = cfg.proposal_width;
        let prop = dense(&names, "prop", PROPOSAL_FEATURES, pw, true)?;
        let mut c = width + pw;
        let mut head = Vec::new();
        for (k, &w) in cfg.head.iter().enumerate() {
            head.push(dense(&names, &format!("head.{k}"), c, w, true)?);
            c = w;
        }
        let cls = dense(&names, "cls", c, 1, false)?;
        let reg = dense(&names, "reg", c, RESIDUALS, false)?;
        Ok(Self {
            params,
            stats,
            adam,
            point,
            n: cfg.gather.points,
            ch,
            width,
            b: 0,
            h0: Vec::new(),
            dh0: Vec::new(),
            prop,
            head,
            cls,
            reg,
            iou_score: cfg.iou_score,
        })
    }

    /// Buffers for `b` proposals.
    fn resize(&mut self, b: usize) {
        if b == self.b {
            return;
        }
        self.b = b;
        let p = b * self.n;
        for l in &mut self.point {
            l.bn = BnRelu::new(l.bn_idx, l.cout, p);
        }
        let rows = self.width + self.prop.cout;
        self.h0.resize(rows * b, 0.0);
        self.dh0.resize(rows * b, 0.0);
        self.prop.resize(b);
        for d in &mut self.head {
            d.resize(b);
        }
        self.cls.resize(b);
        self.reg.resize(b);
    }

    /// Forward, loss and backward on a batch: `points` `(b·n, C)` row-major, `props` `(b, 9)`,
    /// `targets` and `max_trace` per proposal (as [`crate::train::refiner_loss::loss`] takes them). Leaves
    /// every gradient of this step.
    pub fn forward_backward(
        &mut self,
        points: &[f32],
        props: &[f32],
        targets: &[Target],
        max_trace: &[f32],
    ) -> Result<RefinerTerms, RefineError> {
        let b = targets.len();
        if b == 0 {
            return Err(bad("an empty batch".into()));
        }
        if points.len() != b * self.n * self.ch || props.len() != b * PROPOSAL_FEATURES {
            return Err(RefineError::Shape(format!(
                "{} point values and {} proposal values for {b} proposals of {} points × {} channels",
                points.len(),
                props.len(),
                self.n,
                self.ch
            )));
        }
        self.resize(b);
        for p in &mut self.params {
            p.has_grad = false;
        }
        self.forward(points, props)?;
        let terms = self.loss(targets, max_trace);
        self.backward(points, props)?;
        Ok(terms)
    }

    fn forward(&mut self, points: &[f32], props: &[f32]) -> candle_core::Result<()> {
        let (b, n) = (self.b, self.n);
        let p = b * n;
        let Self {
            params,
            stats,
            point,
            h0,
            prop,
            head,
            cls,
            reg,
            width,
            ..
        } = &mut *self;
        for k in 0..point.len() {
            let (done, rest) = point.split_at_mut(k);
            let l = &mut rest[0];
            let (x, xm) = match done.last() {
                Some(prev) => (prev.bn.out.as_slice(), Mat::rm(l.cin, p)),
                None => (points, Mat::tr(p, l.cin)),
            };
            gemm_into(
                &mut l.bn.y,
                Mat::rm(l.cout, p),
                &params[l.weight].value,
                Mat::rm(l.cout, l.cin),
                x,
                xm,
                false,
            )?;
            let bias = &params[l.bias].value;
            l.bn.y
                .par_chunks_mut(p)
                .zip(bias.par_iter())
                .for_each(|(row, &bv)| row.iter_mut().for_each(|v| *v += bv));
            l.bn.forward(params, stats);
        }
        // The global feature: each channel's max over each proposal's points.
        let last = point.last().map(|l| l.bn.out.as_slice()).unwrap_or(&[]);
        h0[..*width * b]
            .par_chunks_mut(b)
            .zip(last.par_chunks(p))
            .for_each(|(g, row)| {
                for (gv, pts) in g.iter_mut().zip(row.chunks(n)) {
                    *gv = pts.iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v));
                }
            });
        prop.forward(props, Mat::tr(b, PROPOSAL_FEATURES), b, params)?;
        h0[*width * b..].copy_from_slice(&prop.out);
        for k in 0..head.len() {
            let (done, rest) = head.split_at_mut(k);
            let l = &mut rest[0];
            let x = done.last().map(|d| d.out.as_slice()).unwrap_or(h0.as_slice());
            l.forward(x, Mat::rm(l.cin, b), b, params)?;
        }
        let hidden = head.last().map(|d| d.out.as_slice()).unwrap_or(h0.as_slice());
        cls.forward(hidden, Mat::rm(cls.cin, b), b, params)?;
        reg.forward(hidden, Mat::rm(reg.cin, b), b, params)?;
        Ok(())
    }

    /// Eq. 17 on the outputs, as [`crate::train::refiner_loss::loss`] computes it; ∂L/∂(outputs) into the
    /// output layers' `dout`.
    fn loss(&mut self, targets: &[Target], max_trace: &[f32]) -> RefinerTerms {
        let b = self.b;
        let positives = targets
            .iter()
            .filter(|t| matches!(t, Target::Positive { .. }))
            .count();
        let norm = 1.0 / positives.max(1) as f64;
        let (cls_scale, reg_scale) = ((ETA * norm) as f32, norm as f32);
        let uct_scale = (LAMBDA * norm) as f32;
        let (x, r) = (&self.cls.out, &self.reg.out);
        let (dx, dr) = (&mut self.cls.dout, &mut self.reg.dout);
        dr.fill(0.0);
        let (mut cls, mut reg, mut uct) = (0f64, 0f64, 0f64);
        for (i, t) in targets.iter().enumerate() {
            let ((l, g), weight) = match t {
                _ if self.iou_score => (bce(x[i], iou_quality(t.iou())), 1.0),
                Target::Positive { .. } => (focal(x[i], 1.0), 1.0),
                Target::Negative { .. } => (focal(x[i], 0.0), 1.0),
                Target::Ignored { .. } => (focal(x[i], 0.0), 0.0),
            };
            cls += (l * weight) as f64;
            dx[i] = g * weight * cls_scale;
            let Target::Positive { residuals, .. } = t else {
                continue;
            };
            for (k, &tk) in residuals.iter().enumerate() {
                let (l, g) = smooth_l1(r[k * b + i] - tk as f32);
                reg += l as f64;
                dr[k * b + i] = g * reg_scale;
            }
            // ‖u′‖₂ over the residuals without the cosine term (+1e-12, as candle's graph).
            let w = uct_weight(max_trace.get(i).copied().unwrap_or(0.0));
            let sq: f32 = (0..RESIDUALS - 1).map(|k| r[k * b + i] * r[k * b + i]).sum();
            let un = (sq + 1e-12).sqrt();
            uct += (w * un) as f64;
            for k in 0..RESIDUALS - 1 {
                dr[k * b + i] += uct_scale * w * r[k * b + i] / un;
            }
        }
        let (cls, reg, uct) = (cls * norm, reg * norm, uct * norm);
        RefinerTerms {
            total: (reg + ETA * cls + LAMBDA * uct) as f32,
            reg: reg as f32,
            cls: cls as f32,
            uct: uct as f32,
            positives,
        }
    }

    fn backward(&mut self, points: &[f32], props: &[f32]) -> candle_core::Result<()> {
        let (b, n) = (self.b, self.n);
        let p = b * n;
        let Self {
            params,
            point,
            h0,
            dh0,
            prop,
            head,
            cls,
            reg,
            width,
            ..
        } = &mut *self;
        // The outputs, then the head, down to ∂L/∂h0.
        {
            let (hidden, dhidden): (&[f32], &mut [f32]) = match head.last_mut() {
                Some(d) => (&d.out, &mut d.dout),
                None => (h0.as_slice(), dh0.as_mut_slice()),
            };
            let xt = Mat::tr(cls.cin, b);
            cls.backward(hidden, xt, b, params, Some((&mut *dhidden, false)))?;
            reg.backward(hidden, xt, b, params, Some((dhidden, true)))?;
        }
        for k in (0..head.len()).rev() {
            let (done, rest) = head.split_at_mut(k);
            let l = &mut rest[0];
            let xt = Mat::tr(l.cin, b);
            match done.last_mut() {
                Some(prev) => l.backward(&prev.out, xt, b, params, Some((&mut prev.dout, false)))?,
                None => l.backward(h0, xt, b, params, Some((&mut *dh0, false)))?,
            }
        }
        prop.dout.copy_from_slice(&dh0[*width * b..]);
        prop.backward(props, Mat::rm(b, PROPOSAL_FEATURES), b, params, None)?;
        // The max's gradient to every point that reaches it (candle's max: ties all get it).
        if let Some(last) = point.last_mut() {
            let (out, dout) = (&last.bn.out, &mut last.bn.dout);
            dout.par_chunks_mut(p)
                .zip(out.par_chunks(p))
                .zip(
                    h0[..*width * b]
                        .par_chunks(b)
                        .zip(dh0[..*width * b].par_chunks(b)),
                )
                .for_each(|((d, o), (g, dg))| {
                    for (j, (dc, oc)) in d.chunks_mut(n).zip(o.chunks(n)).enumerate() {
                        for (dv, &ov) in dc.iter_mut().zip(oc) {
                            *dv = if ov == g[j] { dg[j] } else { 0.0 };
                        }
                    }
                });
        }
        for k in (0..point.len()).rev() {
            let (done, rest) = point.split_at_mut(k);
            let l = &mut rest[0];
            l.bn.backward(params);
            let (x, xt) = match done.last() {
                Some(prev) => (prev.bn.out.as_slice(), Mat::tr(l.cin, p)),
                None => (points, Mat::rm(p, l.cin)),
            };
            {
                let pw = &mut params[l.weight];
                gemm_into(
                    &mut pw.grad,
                    Mat::rm(l.cout, l.cin),
                    &l.bn.dout,
                    Mat::rm(l.cout, p),
                    x,
                    xt,
                    false,
                )?;
                pw.has_grad = true;
            }
            let db: Vec<f32> = l.bn.dout.par_chunks(p).map(sum8).collect();
            params[l.bias].grad = db;
            params[l.bias].has_grad = true;
            if let Some(prev) = done.last_mut() {
                gemm_into(
                    &mut prev.bn.dout,
                    Mat::rm(l.cin, p),
                    &params[l.weight].value,
                    Mat::tr(l.cout, l.cin),
                    &l.bn.dout,
                    Mat::rm(l.cout, p),
                    false,
                )?;
            }
        }
        Ok(())
    }

    /// One training step: forward, loss, backward and AdamW with learning rate `lr`, the
    /// gradients scaled to a global norm of at most `clip`.
    pub fn step(
        &mut self,
        points: &[f32],
        props: &[f32],
        targets: &[Target],
        max_trace: &[f32],
        lr: f64,
        clip: f64,
    ) -> Result<NativeRefinerStep, RefineError> {
        let loss = self.forward_backward(points, props, targets, max_trace)?;
        let grad_norm = self.adam.update(&mut self.params, lr, clip)?;
        Ok(NativeRefinerStep { loss, grad_norm })
    }

    /// Writes the weights and running statistics into `varmap`'s variables and the moments and
    /// step count into `opt` (before a checkpoint or the final weights are written).
    pub fn store(&self, varmap: &VarMap, opt: &mut AdamW) -> Result<(), RefineError> {
        self.adam.store(&self.params, opt)?;
        store_stats(varmap, &self.stats)?;
        Ok(())
    }

    /// The gradient of tensor `name` from the last step, if the step reached it.
    pub fn gradient(&self, name: &str) -> Option<&[f32]> {
        gradient_of(&self.params, name)
    }

    /// A tensor's current value (trainable or running statistic).
    pub fn value(&self, name: &str) -> Option<&[f32]> {
        value_of(&self.params, &self.stats, name)
    }
}
