//! The native training path of the stage-1 networks (issue 28): the training counterpart of the
//! folded inference network ([`crate::detect::infer::FastNet`]). Forward and backward of every layer are
//! written out over flat buffers that live as long as the trainer — convolutions as im2col +
//! gemm, the neck's transposed convolution as gemm + scatter, BatchNorm (batch statistics) fused
//! with its ReLU, the heads, SECOND's loss ([`loss`]) and AdamW with global-norm clipping — with
//! no graph, no allocation per op (but Feature Fusion's routing of the maximum's gradient) and
//! no zero-filling beyond what a layer needs.
//!
//! It computes the function and the update of the candle graph ([`crate::detect::net::Stage1Net`] +
//! [`crate::train::stage1::compute_loss_with`] + [`crate::train::optim::AdamW`]) to float rounding: the tests
//! compare every gradient and whole training runs against candle's autograd. The trainer reads
//! its tensors from, and writes them back to, the candle model's variables and the AdamW moments
//! ([`NativeTrainer::store`]), so checkpoints and weight files are the same on either path.
//!
//! Work is parallel over rayon's threads (gemm's blocks, one channel per task elsewhere) and
//! every reduction runs in a fixed order, so a step is deterministic for a given thread count.

pub mod loss;
pub(crate) mod state;
#[cfg(test)]
mod tests;
#[cfg(test)]
pub(crate) mod testutil;

use self::loss::{loss_and_grad, LossTerms};
use self::state::{gradient_of, params_of, stats_of, store_stats, value_of, FlatAdamW, TensorIndex};
use crate::detect::model::Stage1Model;
use crate::detect::net::branch_prefix;
use crate::detect::DetectError;
use crate::nn::gemm::Geom;
use crate::nn::layers::{ConvBn, DeconvBn, Heads, Param};
use crate::train::optim::AdamW;
use crate::train::stage1::PreparedSample;

/// One LiDAR branch's middle layers.
#[derive(Debug)]
struct Branch {
    conv1: ConvBn,
    conv2: ConvBn,
}

/// The outcome of one training step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NativeStep {
    pub loss: LossTerms,
    /// The global gradient norm before clipping.
    pub grad_norm: f64,
}

/// A stage-1 network's tensors and buffers for training (see the module doc).
#[derive(Debug)]
pub struct NativeTrainer {
    /// Trainable tensors in AdamW's order (name order).
    params: Vec<Param>,
    /// BatchNorm's running statistics.
    stats: Vec<Param>,
    adam: FlatAdamW,
    branches: Vec<Branch>,
    /// Running maxima over the present branches (Feature Fusion), and ∂L/∂(fused map).
    fused: Vec<Vec<f32>>,
    dfused: Vec<f32>,
    block1: Vec<ConvBn>,
    block2: Vec<ConvBn>,
    up1: ConvBn,
    up2: DeconvBn,
    heads: Heads,
    anchors_per_cell: usize,
}

/// The conv + BN layer `prefix` on an input of `h × w`, with padding k/2.
fn conv(names: &TensorIndex, prefix: &str, h: usize, w: usize, stride: usize) -> Result<ConvBn, DetectError> {
    let name = format!("{prefix}.conv.weight");
    let s = names.shape(&name)?;
    let &[cout, cin, k, k2] = s else {
        return Err(DetectError::BadParameter(format!("{name}: shape {s:?}")));
    };
    if k != k2 {
        return Err(DetectError::BadParameter(format!("{name}: shape {s:?}")));
    }
    let geom = Geom::new(cin, h, w, k, stride, k / 2)?;
    Ok(ConvBn::new(geom, cout, names.param(&name)?, names.bn(prefix)?))
}

impl NativeTrainer {
    /// The trainer of `model` (trainable) with the state of `opt` (its moments and step).
    pub fn new(model: &Stage1Model, opt: &AdamW) -> Result<Self, DetectError> {
        let varmap = model
            .varmap
            .as_ref()
            .ok_or_else(|| DetectError::BadParameter("model is not trainable".into()))?;
        let params = params_of(opt)?;
        let stats = stats_of(varmap)?;
        let adam = FlatAdamW::of(opt)?;
        let names = TensorIndex::new(&params, &stats);
        let cfg = &model.config;
        let n = cfg.grid.n;
        let branch_names: Vec<&str> = model.net.branches.iter().map(|(b, _)| b.as_str()).collect();
        let mut branches = Vec::new();
        for b in &branch_names {
            let prefix = branch_prefix(&branch_names, b);
            let conv1 = conv(&names, &format!("{prefix}.conv1"), n, n, 2)?;
            let (h1, w1) = (conv1.geom_out().0, conv1.geom_out().1);
            let conv2 = conv(&names, &format!("{prefix}.conv2"), h1, w1, 1)?;
            branches.push(Branch { conv1, conv2 });
        }
        let (h1, w1) = branches
            .first()
            .map(|b| b.conv2.geom_out())
            .ok_or_else(|| DetectError::BadParameter("a network without branches".into()))?;
        let layers = cfg.net.rpn_layers;
        if layers == 0 {
            return Err(DetectError::BadParameter(
                "the native trainer needs rpn_layers >= 1 (train with --slow-autograd)".into(),
            ));
        }
        let block1 = (0..layers)
            .map(|i| conv(&names, &format!("rpn.block1.{i}"), h1, w1, 1))
            .collect::<Result<Vec<_>, _>>()?;
        let mut block2 = vec![conv(&names, "rpn.block2.0", h1, w1, 2)?];
        let (h2, w2) = block2[0].geom_out();
        for i in 1..=layers {
            block2.push(conv(&names, &format!("rpn.block2.{i}"), h2, w2, 1)?);
        }
        let up1 = conv(&names, "rpn.up1", h1, w1, 1)?;
        let dname = "rpn.up2.deconv.weight";
        let ds = names.shape(dname)?;
        let &[dcin, dcout, s, s2] = ds else {
            return Err(DetectError::BadParameter(format!("{dname}: shape {ds:?}")));
        };
        if s != s2 || h2 * s != h1 || w2 * s != w1 || dcout != up1.cout() {
            return Err(DetectError::BadParameter(format!(
                "{dname}: shape {ds:?} does not bring {h2}×{w2} to {h1}×{w1}"
            )));
        }
        let up2 = DeconvBn::new(dcin, dcout, s, h2, w2, names.param(dname)?, names.bn("rpn.up2")?);
        let na = cfg.net.anchors_per_cell;
        let head = |name: &str, rows: usize| -> Result<(usize, usize, usize), DetectError> {
            let w = names.param(&format!("rpn.{name}.weight"))?;
            let shape = &params[w].shape;
            if shape.len() != 4 || shape[0] != rows || shape[1] != 2 * dcout {
                return Err(DetectError::BadParameter(format!(
                    "rpn.{name}.weight: shape {shape:?}, expected [{rows}, {}, 1, 1]",
                    2 * dcout
                )));
            }
            Ok((w, names.param(&format!("rpn.{name}.bias"))?, rows))
        };
        let parts = [head("cls", na)?, head("reg", 7 * na)?, head("dir", 2 * na)?];
        let heads = Heads::new(parts, dcout, h1 * w1);
        let mid = branches[0].conv2.cout() * h1 * w1;
        let fused = (1..branches.len()).map(|_| vec![0.0; mid]).collect();
        Ok(Self {
            params,
            stats,
            adam,
            branches,
            fused,
            dfused: vec![0.0; mid],
            block1,
            block2,
            up1,
            up2,
            heads,
            anchors_per_cell: na,
        })
    }

    /// Forward, loss and backward on a prepared sample: the gradients of this step.
    pub fn forward_backward(
        &mut self,
        s: &PreparedSample,
        size_weight: f32,
    ) -> Result<LossTerms, DetectError> {
        let terms = self.forward(s, size_weight)?;
        self.backward(s, terms.num_pos > 0)?;
        Ok(terms)
    }

    /// The indices of the branches whose LiDAR is present in `s`.
    fn present(&self, s: &PreparedSample) -> Result<Vec<usize>, DetectError> {
        if s.bevs.len() != self.branches.len() {
            return Err(DetectError::BadParameter(format!(
                "{} inputs for {} branches",
                s.bevs.len(),
                self.branches.len()
            )));
        }
        let present: Vec<usize> = (0..s.bevs.len()).filter(|&i| s.bevs[i].is_some()).collect();
        if present.is_empty() {
            return Err(DetectError::BadParameter(
                "none of the case's LiDARs is present".into(),
            ));
        }
        Ok(present)
    }

    /// Forward pass and loss; leaves ∂L/∂(head outputs) for [`Self::backward`].
    pub fn forward(&mut self, s: &PreparedSample, size_weight: f32) -> Result<LossTerms, DetectError> {
        let present = self.present(s)?;
        for p in &mut self.params {
            p.has_grad = false;
        }
        let na = self.anchors_per_cell;
        let Self {
            params,
            stats,
            branches,
            fused,
            block1,
            block2,
            up1,
            up2,
            heads,
            ..
        } = &mut *self;
        for &i in &present {
            let Some(bev) = &s.bevs[i] else { continue };
            let b = &mut branches[i];
            if bev.data.len() != b.conv1.input_len() {
                return Err(DetectError::BadParameter(format!(
                    "a BEV input of {} values, the network takes {}",
                    bev.data.len(),
                    b.conv1.input_len()
                )));
            }
            b.conv1.forward(&bev.data, params, stats)?;
            b.conv2.forward(&b.conv1.bn.out, params, stats)?;
        }
        for k in 1..present.len() {
            let (done, rest) = fused.split_at_mut(k - 1);
            let prev: &[f32] = match done.last() {
                Some(f) => f,
                None => &branches[present[0]].conv2.bn.out,
            };
            let cur = &branches[present[k]].conv2.bn.out;
            for ((o, a), b) in rest[0].iter_mut().zip(prev).zip(cur) {
                *o = a.max(*b);
            }
        }
        let feat: &[f32] = if present.len() == 1 {
            &branches[present[0]].conv2.bn.out
        } else {
            &fused[present.len() - 2]
        };
        stack_forward(block1, feat, params, stats)?;
        let a = last_out(block1);
        stack_forward(block2, a, params, stats)?;
        up1.forward(a, params, stats)?;
        up2.forward(last_out(block2), params, stats)?;
        heads.forward(&up1.bn.out, &up2.bn.out, params)?;
        let p = up1.bn.out.len() / up1.cout();
        loss_and_grad(&heads.h, &mut heads.dh, p, na, &s.targets, size_weight)
    }

    /// Backward pass of the last [`Self::forward`] on the same sample: every gradient. The box
    /// and direction heads are reached only when the sample had positives (`box_heads`).
    pub fn backward(&mut self, s: &PreparedSample, box_heads: bool) -> Result<(), DetectError> {
        let present = self.present(s)?;
        let Self {
            params,
            branches,
            fused,
            dfused,
            block1,
            block2,
            up1,
            up2,
            heads,
            ..
        } = &mut *self;
        let feat: &[f32] = if present.len() == 1 {
            &branches[present[0]].conv2.bn.out
        } else {
            &fused[present.len() - 2]
        };
        heads.backward(
            &up1.bn.out,
            &up2.bn.out,
            params,
            [true, box_heads, box_heads],
            &mut up1.bn.dout,
            &mut up2.bn.dout,
        )?;
        {
            let last = block2.last_mut().ok_or_else(no_layer)?;
            up2.backward(&last.bn.out, params, Some((&mut last.bn.dout, false)))?;
        }
        {
            let last1 = block1.last_mut().ok_or_else(no_layer)?;
            stack_backward(block2, &last1.bn.out, params, Some((&mut last1.bn.dout, false)))?;
            up1.backward(&last1.bn.out, params, Some((&mut last1.bn.dout, true)))?;
        }
        stack_backward(block1, feat, params, Some((dfused, false)))?;
        // The fused map's gradient back to the branches (candle's maximum: ties share it).
        if present.len() == 1 {
            std::mem::swap(dfused, &mut branches[present[0]].conv2.bn.dout);
        } else {
            let mut g = std::mem::take(dfused);
            for k in (1..present.len()).rev() {
                let node = &fused[k - 1];
                let prev: &[f32] = if k == 1 {
                    &branches[present[0]].conv2.bn.out
                } else {
                    &fused[k - 2]
                };
                let cur = &branches[present[k]].conv2.bn.out;
                let mut g_prev = vec![0f32; g.len()];
                let mut g_cur = vec![0f32; g.len()];
                for i in 0..g.len() {
                    let (ml, mr) = (
                        (prev[i] == node[i]) as u8 as f32,
                        (cur[i] == node[i]) as u8 as f32,
                    );
                    g_prev[i] = ml * g[i] / (mr + 1.0);
                    g_cur[i] = mr * g[i] / (ml + 1.0);
                }
                branches[present[k]].conv2.bn.dout = g_cur;
                g = g_prev;
            }
            let first = &mut branches[present[0]].conv2.bn.dout;
            *dfused = std::mem::replace(first, g);
        }
        for &i in &present {
            let Some(bev) = &s.bevs[i] else { continue };
            let b = &mut branches[i];
            b.conv2
                .backward(&b.conv1.bn.out, params, Some((&mut b.conv1.bn.dout, false)))?;
            b.conv1.backward(&bev.data, params, None)?;
        }
        Ok(())
    }

    /// One training step: forward, loss, backward and AdamW with learning rate `lr`, the
    /// gradients scaled to a global norm of at most `clip`.
    pub fn step(
        &mut self,
        s: &PreparedSample,
        size_weight: f32,
        lr: f64,
        clip: f64,
    ) -> Result<NativeStep, DetectError> {
        let loss = self.forward_backward(s, size_weight)?;
        let grad_norm = self.update(lr, clip)?;
        Ok(NativeStep { loss, grad_norm })
    }

    /// AdamW over the tensors the last step reached, as [`AdamW::update`] computes it; the
    /// gradient norm before clipping.
    pub fn update(&mut self, lr: f64, clip: f64) -> Result<f64, DetectError> {
        self.adam.update(&mut self.params, lr, clip)
    }

    /// Writes the weights and running statistics into `model`'s variables and the moments and
    /// step count into `opt` (before a checkpoint or the final weights are written).
    pub fn store(&self, model: &Stage1Model, opt: &mut AdamW) -> Result<(), DetectError> {
        self.adam.store(&self.params, opt)?;
        let varmap = model
            .varmap
            .as_ref()
            .ok_or_else(|| DetectError::BadParameter("model is not trainable".into()))?;
        store_stats(varmap, &self.stats)
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

fn no_layer() -> DetectError {
    DetectError::BadParameter("an RPN block without layers".into())
}

fn last_out(v: &[ConvBn]) -> &[f32] {
    v.last().map(|l| l.bn.out.as_slice()).unwrap_or(&[])
}

/// Runs a stack of layers on `input`.
fn stack_forward(
    layers: &mut [ConvBn],
    input: &[f32],
    params: &[Param],
    stats: &mut [Param],
) -> candle_core::Result<()> {
    for i in 0..layers.len() {
        let (done, rest) = layers.split_at_mut(i);
        let x = done.last().map(|l| l.bn.out.as_slice()).unwrap_or(input);
        rest[0].forward(x, params, stats)?;
    }
    Ok(())
}

/// Backward through a stack whose last layer's `bn.dout` is set; the first layer's input
/// gradient goes to `dinput`.
fn stack_backward(
    layers: &mut [ConvBn],
    input: &[f32],
    params: &mut [Param],
    mut dinput: crate::nn::layers::InputGrad<'_>,
) -> candle_core::Result<()> {
    for i in (0..layers.len()).rev() {
        let (done, rest) = layers.split_at_mut(i);
        let cur = &mut rest[0];
        match done.last_mut() {
            Some(prev) => cur.backward(&prev.bn.out, params, Some((&mut prev.bn.dout, false)))?,
            None => cur.backward(input, params, dinput.take())?,
        }
    }
    Ok(())
}
