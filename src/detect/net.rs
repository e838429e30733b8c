//! The stage-1 network (SECOND v1.5-style, paper §IV-A), written with candle for the CPU.
//!
//! Stages, in OpenPCDet's order: voxeliser + FLN ([`super::voxel`]) → middle layers → RPN → heads.
//! - Middle layers: SECOND's sparse 3D convolutions squeeze z into channels; candle has no sparse
//!   convolution, so here the z voxels are already channels of a height-compressed BEV map and the
//!   middle layers are two dense 2D conv + BatchNorm + ReLU layers (the first with stride 2, 0.4 m →
//!   0.8 m cells). This is the documented deviation from SECOND.
//! - Feature Fusion (§IV-A-2) gives each LiDAR its own middle layers; their BEV maps, all in the
//!   base frame, are fused by the element-wise maximum before one RPN.
//! - RPN: SECOND's two downsample blocks (stride 1 and 2, 3×3 conv + BN + ReLU) and the neck that
//!   brings both back to 0.8 m (1×1 conv and a stride-2 transposed conv) and concatenates them.
//! - Heads (1×1 convs): class logits (sigmoid), SECOND's 7 box residuals and 2 direction logits per
//!   anchor. Sized for a 2-core CPU (see `shared/notes/candle-cpu.md`: the "tiny" configuration).
//!
//! Inference does not run this candle graph: [`super::infer::FastNet`] folds a trained network
//! into plain gemm layers (about 3× faster on this CPU); this module is the training graph and the
//! reference the folded network is tested against.
//!
//! Weights are named like the module tree (`middle.conv1.weight`, `rpn.block2.0.bn.running_mean`,
//! `rpn.cls.bias`) so the safetensors file reads like the network. Initial values are drawn from a
//! seeded ChaCha8 stream ([`Stage1Net::init_weights`]), because candle's CPU initialiser is not
//! seedable.

use candle_core::{DType, Device, Tensor, D};
use candle_nn::{
    batch_norm, conv2d_no_bias, conv_transpose2d_no_bias, BatchNorm, BatchNormConfig, Conv2d, Conv2dConfig,
    ConvTranspose2d, ConvTranspose2dConfig, VarBuilder, VarMap,
};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use super::voxel::GridConfig;

/// Widths of the network; the defaults are the CPU-sized "tiny" configuration.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NetConfig {
    /// Channels out of the middle layers (and of RPN block 1).
    pub mid_channels: usize,
    /// Channels of RPN block 2 (and of each upsampled neck branch).
    pub rpn_channels: usize,
    /// 3×3 layers after the first conv of each RPN block.
    pub rpn_layers: usize,
    /// Anchors per head cell (one class × two orientations).
    pub anchors_per_cell: usize,
}

impl Default for NetConfig {
    fn default() -> Self {
        Self {
            mid_channels: 24,
            rpn_channels: 48,
            rpn_layers: 2,
            anchors_per_cell: 2,
        }
    }
}

/// Conv (no bias) + BatchNorm + ReLU.
#[derive(Debug, Clone)]
struct ConvBn {
    conv: Conv2d,
    bn: BatchNorm,
}

impl ConvBn {
    fn new(cin: usize, cout: usize, k: usize, stride: usize, vb: VarBuilder) -> candle_core::Result<Self> {
        let cfg = Conv2dConfig {
            padding: k / 2,
            stride,
            ..Default::default()
        };
        Ok(Self {
            conv: conv2d_no_bias(cin, cout, k, cfg, vb.pp("conv"))?,
            bn: batch_norm(cout, BatchNormConfig::default(), vb.pp("bn"))?,
        })
    }

    fn forward_t(&self, x: &Tensor, train: bool) -> candle_core::Result<Tensor> {
        x.apply(&self.conv)?.apply_t(&self.bn, train)?.relu()
    }
}

/// Transposed conv (no bias) + BatchNorm + ReLU.
#[derive(Debug, Clone)]
struct DeconvBn {
    deconv: ConvTranspose2d,
    bn: BatchNorm,
}

impl DeconvBn {
    fn new(cin: usize, cout: usize, stride: usize, vb: VarBuilder) -> candle_core::Result<Self> {
        let cfg = ConvTranspose2dConfig {
            stride,
            ..Default::default()
        };
        Ok(Self {
            deconv: conv_transpose2d_no_bias(cin, cout, stride, cfg, vb.pp("deconv"))?,
            bn: batch_norm(cout, BatchNormConfig::default(), vb.pp("bn"))?,
        })
    }

    fn forward_t(&self, x: &Tensor, train: bool) -> candle_core::Result<Tensor> {
        x.apply(&self.deconv)?.apply_t(&self.bn, train)?.relu()
    }
}

/// The middle layers of one LiDAR branch: BEV input → 0.8 m feature map.
#[derive(Debug, Clone)]
pub struct MiddleLayers {
    conv1: ConvBn,
    conv2: ConvBn,
}

impl MiddleLayers {
    pub fn new(cin: usize, cfg: &NetConfig, vb: VarBuilder) -> candle_core::Result<Self> {
        Ok(Self {
            conv1: ConvBn::new(cin, cfg.mid_channels, 3, 2, vb.pp("conv1"))?,
            conv2: ConvBn::new(cfg.mid_channels, cfg.mid_channels, 3, 1, vb.pp("conv2"))?,
        })
    }

    /// `[1, C_in, n, n]` → `[1, mid, n/2, n/2]`.
    pub fn forward_t(&self, x: &Tensor, train: bool) -> candle_core::Result<Tensor> {
        self.conv2.forward_t(&self.conv1.forward_t(x, train)?, train)
    }
}

/// The raw head outputs, one row per anchor (anchor order: head row, column, orientation).
#[derive(Debug, Clone)]
pub struct HeadOutput {
    /// `[N]` class logits.
    pub cls: Tensor,
    /// `[N, 7]` box residuals.
    pub reg: Tensor,
    /// `[N, 2]` direction logits.
    pub dir: Tensor,
}

/// SECOND's region proposal network with its heads.
#[derive(Debug, Clone)]
pub struct Rpn {
    block1: Vec<ConvBn>,
    block2: Vec<ConvBn>,
    up1: ConvBn,
    up2: DeconvBn,
    cls: Conv2d,
    reg: Conv2d,
    dir: Conv2d,
    anchors_per_cell: usize,
}

impl Rpn {
    pub fn new(cfg: &NetConfig, vb: VarBuilder) -> candle_core::Result<Self> {
        let (m, r, a) = (cfg.mid_channels, cfg.rpn_channels, cfg.anchors_per_cell);
        let block1 = (0..cfg.rpn_layers)
            .map(|i| ConvBn::new(m, m, 3, 1, vb.pp(format!("block1.{i}"))))
            .collect::<candle_core::Result<Vec<_>>>()?;
        let mut block2 = vec![ConvBn::new(m, r, 3, 2, vb.pp("block2.0"))?];
        for i in 0..cfg.rpn_layers {
            block2.push(ConvBn::new(r, r, 3, 1, vb.pp(format!("block2.{}", i + 1)))?);
        }
        let head = |n: usize, name: &str, bias: f64| -> candle_core::Result<Conv2d> {
            let vb = vb.pp(name);
            let w = vb.get_with_hints((n, 2 * r, 1, 1), "weight", candle_nn::Init::Const(0.0))?;
            let b = vb.get_with_hints(n, "bias", candle_nn::Init::Const(bias))?;
            Ok(Conv2d::new(w, Some(b), Conv2dConfig::default()))
        };
        // Prior probability 0.01 for the class logits (focal-loss initialisation).
        let prior_bias = -((1.0f64 - 0.01) / 0.01).ln();
        Ok(Self {
            block1,
            block2,
            up1: ConvBn::new(m, r, 1, 1, vb.pp("up1"))?,
            up2: DeconvBn::new(r, r, 2, vb.pp("up2"))?,
            cls: head(a, "cls", prior_bias)?,
            reg: head(a * 7, "reg", 0.0)?,
            dir: head(a * 2, "dir", 0.0)?,
            anchors_per_cell: a,
        })
    }

    /// `[1, mid, h, w]` → per-anchor head outputs.
    pub fn forward_t(&self, x: &Tensor, train: bool) -> candle_core::Result<HeadOutput> {
        let mut a = x.clone();
        for l in &self.block1 {
            a = l.forward_t(&a, train)?;
        }
        let mut b = a.clone();
        for l in &self.block2 {
            b = l.forward_t(&b, train)?;
        }
        let feat = Tensor::cat(
            &[self.up1.forward_t(&a, train)?, self.up2.forward_t(&b, train)?],
            1,
        )?;
        let na = self.anchors_per_cell;
        let per_anchor = |t: Tensor, k: usize| -> candle_core::Result<Tensor> {
            let (_, _, h, w) = t.dims4()?;
            // [1, A·k, h, w] → [h, w, A, k] → [h·w·A, k]
            t.reshape((na, k, h, w))?
                .permute((2, 3, 0, 1))?
                .contiguous()?
                .reshape((h * w * na, k))
        };
        Ok(HeadOutput {
            cls: per_anchor(feat.apply(&self.cls)?, 1)?.squeeze(1)?,
            reg: per_anchor(feat.apply(&self.reg)?, 7)?,
            dir: per_anchor(feat.apply(&self.dir)?, 2)?,
        })
    }
}

/// The name prefix of a branch's middle layers: `middle` in a single-branch network,
/// `middle_<lidar>` in Feature Fusion.
pub fn branch_prefix(branch_names: &[&str], name: &str) -> String {
    if branch_names.len() == 1 {
        "middle".to_string()
    } else {
        format!("middle_{name}")
    }
}

/// The whole stage-1 network: one middle-layer branch per input (one for single-LiDAR and Input
/// Fusion, three for Feature Fusion) and one RPN.
#[derive(Debug, Clone)]
pub struct Stage1Net {
    pub branches: Vec<(String, MiddleLayers)>,
    pub rpn: Rpn,
}

impl Stage1Net {
    /// Builds the network with its variables in `vb` (a fresh `VarMap` or loaded weights).
    pub fn new(
        grid: &GridConfig,
        cfg: &NetConfig,
        branch_names: &[&str],
        vb: VarBuilder,
    ) -> candle_core::Result<Self> {
        let branches = branch_names
            .iter()
            .map(|name| {
                Ok((
                    name.to_string(),
                    MiddleLayers::new(grid.channels(), cfg, vb.pp(branch_prefix(branch_names, name)))?,
                ))
            })
            .collect::<candle_core::Result<Vec<_>>>()?;
        Ok(Self {
            branches,
            rpn: Rpn::new(cfg, vb.pp("rpn"))?,
        })
    }

    /// The fused BEV feature map of the inputs present: `inputs[i]` is branch i's BEV tensor
    /// `[1, C, n, n]`, or `None` when that LiDAR is absent. Element-wise maximum over the present
    /// branches (paper eq. 10); with one branch present it is that branch's map exactly.
    pub fn features(&self, inputs: &[Option<Tensor>], train: bool) -> candle_core::Result<Tensor> {
        let mut fused: Option<Tensor> = None;
        for ((_, branch), x) in self.branches.iter().zip(inputs) {
            let Some(x) = x else { continue };
            let f = branch.forward_t(x, train)?;
            fused = Some(match fused {
                None => f,
                Some(g) => g.maximum(&f)?,
            });
        }
        fused.ok_or_else(|| candle_core::Error::Msg("no input branch present".into()))
    }

    pub fn forward_t(&self, inputs: &[Option<Tensor>], train: bool) -> candle_core::Result<HeadOutput> {
        self.rpn.forward_t(&self.features(inputs, train)?, train)
    }

    /// Draws every conv weight from N(0, 2/fan_in) (He), head weights from N(0, 0.01²), with a
    /// seeded ChaCha8 stream over the variables in name order; BatchNorm and biases keep their
    /// constant initialisation.
    pub fn init_weights(varmap: &VarMap, seed: u64) -> candle_core::Result<()> {
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
            if dims.len() != 4 || !name.ends_with("weight") {
                continue;
            }
            let head =
                name.starts_with("rpn.cls") || name.starts_with("rpn.reg") || name.starts_with("rpn.dir");
            // A stride-k transposed conv with a k×k kernel sees dims[0] inputs per output.
            let fan_in = if name.contains("deconv") {
                dims[0]
            } else {
                dims[1] * dims[2] * dims[3]
            };
            let std = if head {
                0.01
            } else {
                (2.0 / fan_in.max(1) as f64).sqrt()
            };
            let normal = Normal::new(0.0, std).map_err(|e| candle_core::Error::Msg(e.to_string()))?;
            let n: usize = dims.iter().product();
            let v: Vec<f32> = (0..n).map(|_| normal.sample(&mut rng) as f32).collect();
            var.set(&Tensor::from_vec(v, dims, &Device::Cpu)?)?;
        }
        Ok(())
    }
}

/// Numerically stable sigmoid focal loss (Lin et al.; α = 0.25, γ = 2), per element:
/// ce = relu(x) − x·t + ln(1 + e^{−|x|}), p_t = p·t + (1 − p)(1 − t),
/// loss = (α t + (1 − α)(1 − t)) (1 − p_t)^γ ce. Finite for any finite logit.
pub fn sigmoid_focal_loss(
    logits: &Tensor,
    targets: &Tensor,
    alpha: f64,
    gamma: f64,
) -> candle_core::Result<Tensor> {
    let ce =
        ((logits.relu()? - (logits * targets)?)? + logits.abs()?.neg()?.exp()?.affine(1.0, 1.0)?.log()?)?;
    let p = candle_nn::ops::sigmoid(logits)?;
    let one_minus_t = targets.affine(-1.0, 1.0)?;
    let p_t = ((&p * targets)? + (p.affine(-1.0, 1.0)? * &one_minus_t)?)?;
    let base = p_t.affine(-1.0, 1.0)?.clamp(0.0, 1.0)?;
    let modulator = if gamma == 2.0 {
        base.sqr()?
    } else {
        base.powf(gamma)?
    };
    let alpha_t = targets.affine(2.0 * alpha - 1.0, 1.0 - alpha)?;
    alpha_t * modulator * ce
}

/// Smooth-L1 (Huber with transition `beta`), per element.
pub fn smooth_l1(diff: &Tensor, beta: f64) -> candle_core::Result<Tensor> {
    let a = diff.abs()?;
    let quad = (a.sqr()? * (0.5 / beta))?;
    let lin = a.affine(1.0, -0.5 * beta)?;
    let mask = a.lt(beta)?;
    mask.where_cond(&quad, &lin)
}

/// Softmax cross-entropy of `[N, 2]` logits against class indices, per row.
pub fn cross_entropy_rows(logits: &Tensor, labels: &Tensor) -> candle_core::Result<Tensor> {
    let logp = candle_nn::ops::log_softmax(logits, D::Minus1)?;
    logp.gather(&labels.unsqueeze(1)?, 1)?.squeeze(1)?.neg()
}

/// A tensor of f32 values on the CPU.
pub fn tensor_f32(v: Vec<f32>, shape: &[usize]) -> candle_core::Result<Tensor> {
    Tensor::from_vec(v, shape, &Device::Cpu)
}

/// The dtype of every tensor of the network.
pub const DTYPE: DType = DType::F32;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn focal_loss_is_finite_and_right_for_large_logits() {
        let x = tensor_f32(vec![-1e4, -30.0, 0.0, 30.0, 1e4, 1e4, -1e4], &[7]).unwrap();
        let t = tensor_f32(vec![0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 1.0], &[7]).unwrap();
        let l: Vec<f32> = sigmoid_focal_loss(&x, &t, 0.25, 2.0).unwrap().to_vec1().unwrap();
        assert!(l.iter().all(|v| v.is_finite()), "{l:?}");
        assert!(
            l[0] < 1e-12 && l[1] < 1e-12 && l[3] < 1e-12 && l[4] < 1e-12,
            "{l:?}"
        );
        // x = 0, t = 1: 0.25 · 0.5² · ln 2.
        assert!((l[2] - 0.25 * 0.25 * 2f32.ln()).abs() < 1e-6);
        // Confidently wrong: α_t · 1 · |x|.
        assert!(
            (l[5] - 0.75 * 1e4).abs() < 1.0 && (l[6] - 0.25 * 1e4).abs() < 1.0,
            "{l:?}"
        );
        // Gradients stay finite too.
        let v = candle_core::Var::from_tensor(&x).unwrap();
        let loss = sigmoid_focal_loss(v.as_tensor(), &t, 0.25, 2.0)
            .unwrap()
            .sum_all()
            .unwrap();
        let g = loss.backward().unwrap();
        let gx: Vec<f32> = g.get(v.as_tensor()).unwrap().to_vec1().unwrap();
        assert!(gx.iter().all(|v| v.is_finite()), "{gx:?}");
    }

    #[test]
    fn smooth_l1_values() {
        let d = tensor_f32(vec![0.0, 0.05, -2.0], &[3]).unwrap();
        let l: Vec<f32> = smooth_l1(&d, 0.1).unwrap().to_vec1().unwrap();
        assert!((l[0]).abs() < 1e-9 && (l[1] - 0.0125).abs() < 1e-7 && (l[2] - 1.95).abs() < 1e-6);
    }
}
