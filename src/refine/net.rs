//! The stage-2 network (paper §IV-B) in candle, for training: a PointNet over each proposal's
//! points, its stage-1 score and parameters encoded by a small MLP, two heads.
//!
//! Layers (names as in the safetensors file):
//! - `point.{k}`: the shared MLP, Linear + BatchNorm + ReLU per layer, applied to every point's
//!   row (x_n, y_n, z_n, features) — PointNet's 1×1 convolutions written as one matmul over all the
//!   points of the batch; then the max over each proposal's points: the global feature. The point
//!   that wins a channel's max is an *active point* (§V-C).
//! - `prop`: Linear + ReLU on the proposal's [`proposal_features`].
//! - `head.{k}`: Linear + ReLU on the concatenation; `cls` (objectness logit) and `reg` (the
//!   eight residuals of eq. 14).
//!
//! The batch is a set of B proposals of one frame, each with N sampled points: `points` is
//! `(B·N, C)` row-major, proposal-major.

use candle_core::{DType, Device, Module, ModuleT, Tensor, D};
use candle_nn::{batch_norm, linear, BatchNorm, BatchNormConfig, Linear, VarBuilder, VarMap};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use super::coding::RESIDUALS;
use super::points::GatherConfig;
use crate::geometry::Box3d;

/// Inputs of the proposal encoder.
pub const PROPOSAL_FEATURES: usize = 9;

/// The stage-1 score and box of a proposal as the network sees them: score, x/50, y/50, z/3,
/// ln l, ln w, ln h, sin γ, cos γ.
pub fn proposal_features(b: &Box3d, score: f32) -> [f32; PROPOSAL_FEATURES] {
    let ln = |v: f64| v.max(1e-3).ln() as f32;
    [
        score,
        (b.center[0] / 50.0) as f32,
        (b.center[1] / 50.0) as f32,
        (b.center[2] / 3.0) as f32,
        ln(b.size_lwh[0]),
        ln(b.size_lwh[1]),
        ln(b.size_lwh[2]),
        b.yaw.sin() as f32,
        b.yaw.cos() as f32,
    ]
}

/// Everything that defines a refiner besides its weights.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RefinerConfig {
    pub gather: GatherConfig,
    /// Widths of the shared point MLP (the last one is the global feature's).
    pub point_mlp: Vec<usize>,
    /// Width of the proposal encoder.
    pub proposal_width: usize,
    /// Widths of the fully connected layers before the heads.
    pub head: Vec<usize>,
    /// The category it refines (its proposals' and ground truth's).
    pub category: String,
    /// What the classification head learns: `false`, objectness (positive above 3D IoU 0.6,
    /// negative below 0.45, the paper's focal loss); `true`, the proposal's localisation quality
    /// (binary cross-entropy toward clamp((IoU − 0.25) / 0.5, 0, 1) on every proposal, as
    /// PV-RCNN's IoU-guided scoring), so that a box that will not reach IoU 0.7 ranks lower.
    #[serde(default)]
    pub iou_score: bool,
}

impl Default for RefinerConfig {
    fn default() -> Self {
        Self {
            gather: GatherConfig::default(),
            point_mlp: vec![32, 64, 128],
            proposal_width: 32,
            head: vec![128, 64],
            category: "car".into(),
            iou_score: false,
        }
    }
}

/// One point-MLP layer.
#[derive(Debug)]
struct PointLayer {
    lin: Linear,
    bn: BatchNorm,
}

/// The network's output for a batch of B proposals.
#[derive(Debug)]
pub struct RefinerOutput {
    /// `(B)` objectness logits.
    pub cls: Tensor,
    /// `(B, 8)` residuals of eq. 14.
    pub reg: Tensor,
}

/// The trainable refiner network.
#[derive(Debug)]
pub struct RefinerNet {
    point: Vec<PointLayer>,
    prop: Linear,
    head: Vec<Linear>,
    cls: Linear,
    reg: Linear,
    width: usize,
}

impl RefinerNet {
    pub fn new(cfg: &RefinerConfig, vb: VarBuilder) -> candle_core::Result<Self> {
        let mut cin = cfg.gather.features.channels();
        let mut point = Vec::new();
        for (k, &w) in cfg.point_mlp.iter().enumerate() {
            let p = vb.pp(format!("point.{k}"));
            point.push(PointLayer {
                lin: linear(cin, w, p.pp("lin"))?,
                bn: batch_norm(w, BatchNormConfig::default(), p.pp("bn"))?,
            });
            cin = w;
        }
        let width = cin;
        let prop = linear(PROPOSAL_FEATURES, cfg.proposal_width, vb.pp("prop"))?;
        let mut c = width + cfg.proposal_width;
        let mut head = Vec::new();
        for (k, &w) in cfg.head.iter().enumerate() {
            head.push(linear(c, w, vb.pp(format!("head.{k}")))?);
            c = w;
        }
        Ok(Self {
            point,
            prop,
            head,
            cls: linear(c, 1, vb.pp("cls"))?,
            reg: linear(c, RESIDUALS, vb.pp("reg"))?,
            width,
        })
    }

    /// `points`: `(b·n, C)`; `props`: `(b, 9)`.
    pub fn forward_t(
        &self,
        points: &Tensor,
        b: usize,
        n: usize,
        props: &Tensor,
        train: bool,
    ) -> candle_core::Result<RefinerOutput> {
        let mut x = points.clone();
        for l in &self.point {
            x = l.bn.forward_t(&l.lin.forward(&x)?, train)?.relu()?;
        }
        let global = x.reshape((b, n, self.width))?.max(1)?;
        let p = self.prop.forward(props)?.relu()?;
        let mut h = Tensor::cat(&[&global, &p], D::Minus1)?;
        for l in &self.head {
            h = l.forward(&h)?.relu()?;
        }
        Ok(RefinerOutput {
            cls: self.cls.forward(&h)?.squeeze(D::Minus1)?,
            reg: self.reg.forward(&h)?,
        })
    }

    /// A fresh trainable network: He-normal weights (N(0, 0.01²) for the heads) from a seeded
    /// ChaCha8 stream over the variables in name order, zero biases.
    pub fn trainable(cfg: &RefinerConfig, seed: u64) -> candle_core::Result<(Self, VarMap)> {
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
        let net = Self::new(cfg, vb)?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let data = varmap
            .data()
            .lock()
            .map_err(|_| candle_core::Error::Msg("variable map lock poisoned".into()))?;
        let mut names: Vec<&String> = data.keys().collect();
        names.sort();
        for name in names {
            let Some(var) = data.get(name) else { continue };
            let dims = var.dims().to_vec();
            if name.ends_with("bias") && !name.contains(".bn") {
                var.set(&Tensor::zeros(dims.as_slice(), DType::F32, &Device::Cpu)?)?;
                continue;
            }
            if dims.len() != 2 || !name.ends_with("weight") {
                continue;
            }
            let head = name.starts_with("cls") || name.starts_with("reg");
            let std = if head {
                0.01
            } else {
                (2.0 / dims[1].max(1) as f64).sqrt()
            };
            let normal = Normal::new(0.0, std).map_err(|e| candle_core::Error::Msg(e.to_string()))?;
            let v: Vec<f32> = (0..dims[0] * dims[1])
                .map(|_| normal.sample(&mut rng) as f32)
                .collect();
            var.set(&Tensor::from_vec(v, dims, &Device::Cpu)?)?;
        }
        drop(data);
        Ok((net, varmap))
    }
}
