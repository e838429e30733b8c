//! Targets and loss of the refiner (paper eq. 15–17, §V-A-6).
//!
//! Targets (OpenPCDet's proposal target layer, apart from the network): a proposal whose largest
//! 3D IoU with a ground-truth box of its category exceeds 0.6 is positive, with the residuals of
//! eq. 14 toward that box; below 0.45 it is negative; in between it gets no classification loss
//! and no regression loss.
//!
//! Loss: L = L_reg + η·L_cls + λ·L_uct with η = 2, λ = 0.005 —
//! - L_reg: smooth-L1 (β = 1/9) of the eight residuals, summed, over the positives;
//! - L_cls: sigmoid focal loss (α = 0.25, γ = 2) of the objectness over the labelled proposals;
//! - L_uct (eq. 16): Σ_i exp(1 − f(max_j tr Ξ_j))·‖u′_i‖₂ over the positives, u′_i the *predicted*
//!   residuals without the cosine term, f clamping to [1e-3, 0.5]: large refinements cost more where
//!   the points are certain.
//!
//! Each term is divided by the number of positives (at least 1), as SECOND normalises.
//!
//! Beyond the paper (`mlod train refiner --iou-score`, [`crate::refine::net::RefinerConfig::iou_score`]):
//! L_cls becomes the binary cross-entropy toward each proposal's IoU quality, clamp((IoU − 0.25) /
//! 0.5, 0, 1), on every proposal of the batch; the native trainer computes it
//! ([`crate::train::refiner_native::iou_quality`]), this candle graph does not.

use candle_core::{Device, Tensor, D};

use crate::detect::net::{sigmoid_focal_loss, smooth_l1};
use crate::geometry::{iou_3d, Box3d};
use crate::refine::coding::{encode, RESIDUALS};
use crate::refine::net::RefinerOutput;

pub const POSITIVE_IOU: f64 = 0.6;
pub const NEGATIVE_IOU: f64 = 0.45;
pub const ETA: f64 = 2.0;
pub const LAMBDA: f64 = 0.005;

/// What a proposal should become.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Target {
    Positive {
        residuals: [f64; RESIDUALS],
        iou: f64,
    },
    Negative {
        iou: f64,
    },
    /// Between the thresholds: no loss.
    Ignored {
        iou: f64,
    },
}

impl Target {
    pub fn iou(&self) -> f64 {
        match *self {
            Target::Positive { iou, .. } | Target::Negative { iou } | Target::Ignored { iou } => iou,
        }
    }
}

/// The target of `proposal` among `truth` (boxes of its category).
pub fn assign(proposal: &Box3d, truth: &[Box3d]) -> Target {
    let best = truth
        .iter()
        .map(|g| (iou_3d(proposal, g), g))
        .filter(|(v, _)| v.is_finite())
        .max_by(|a, b| a.0.total_cmp(&b.0));
    match best {
        Some((iou, g)) if iou > POSITIVE_IOU => Target::Positive {
            residuals: encode(proposal, g),
            iou,
        },
        Some((iou, _)) if iou >= NEGATIVE_IOU => Target::Ignored { iou },
        Some((iou, _)) => Target::Negative { iou },
        None => Target::Negative { iou: 0.0 },
    }
}

/// L_uct's weight of a proposal: exp(1 − f(max_j tr Ξ_j)), f clamping to [1e-3, 0.5].
pub fn uct_weight(max_trace: f32) -> f32 {
    let f = if max_trace.is_finite() {
        max_trace.clamp(1e-3, 0.5)
    } else {
        0.5
    };
    (1.0 - f).exp()
}

/// The loss terms of one batch.
#[derive(Debug)]
pub struct Losses {
    pub total: Tensor,
    pub reg: f32,
    pub cls: f32,
    pub uct: f32,
    pub positives: usize,
}

/// Eq. 17 for a batch: `targets[i]` and `max_trace[i]` belong to the batch's i-th proposal.
pub fn loss(out: &RefinerOutput, targets: &[Target], max_trace: &[f32]) -> candle_core::Result<Losses> {
    let b = targets.len();
    let dev = Device::Cpu;
    let mut cls_t = vec![0f32; b];
    let mut cls_w = vec![0f32; b];
    let mut reg_t = vec![0f32; b * RESIDUALS];
    let mut pos_w = vec![0f32; b];
    let mut uct_w = vec![0f32; b];
    let mut positives = 0;
    for (i, t) in targets.iter().enumerate() {
        match t {
            Target::Positive { residuals, .. } => {
                positives += 1;
                cls_t[i] = 1.0;
                cls_w[i] = 1.0;
                pos_w[i] = 1.0;
                uct_w[i] = uct_weight(max_trace.get(i).copied().unwrap_or(0.0));
                for k in 0..RESIDUALS {
                    reg_t[i * RESIDUALS + k] = residuals[k] as f32;
                }
            }
            Target::Negative { .. } => cls_w[i] = 1.0,
            Target::Ignored { .. } => {}
        }
    }
    let norm = 1.0 / positives.max(1) as f64;
    let cls_t = Tensor::from_vec(cls_t, b, &dev)?;
    let cls_w = Tensor::from_vec(cls_w, b, &dev)?;
    let reg_t = Tensor::from_vec(reg_t, (b, RESIDUALS), &dev)?;
    let pos_w = Tensor::from_vec(pos_w, (b, 1), &dev)?;
    let uct_w = Tensor::from_vec(uct_w, b, &dev)?;
    let cls = (sigmoid_focal_loss(&out.cls, &cls_t, 0.25, 2.0)? * &cls_w)?
        .sum_all()?
        .affine(norm, 0.0)?;
    let reg = smooth_l1(&(&out.reg - &reg_t)?, 1.0 / 9.0)?
        .broadcast_mul(&pos_w)?
        .sum_all()?
        .affine(norm, 0.0)?;
    // ‖u′‖₂ of the predicted residuals without the cosine (the last) term; +1e-12 keeps the
    // gradient of the norm finite at zero.
    let u = out.reg.narrow(D::Minus1, 0, RESIDUALS - 1)?;
    let unorm = (u.sqr()?.sum(D::Minus1)? + 1e-12)?.sqrt()?;
    let uct = (unorm * &uct_w)?.sum_all()?.affine(norm, 0.0)?;
    let total = ((&reg + cls.affine(ETA, 0.0)?)? + uct.affine(LAMBDA, 0.0)?)?;
    Ok(Losses {
        reg: reg.to_scalar()?,
        cls: cls.to_scalar()?,
        uct: uct.to_scalar()?,
        total,
        positives,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn targets_follow_the_iou_thresholds() {
        let g = Box3d::new([10.0, 0.0, 0.0], [4.0, 2.0, 1.5], 0.0);
        assert!(matches!(assign(&g, &[g]), Target::Positive { iou, .. } if (iou - 1.0).abs() < 1e-9));
        // Shifted by 1.2 m along its length: IoU 2.8/5.2 = 0.54, between the thresholds.
        let s = Box3d::new([11.2, 0.0, 0.0], [4.0, 2.0, 1.5], 0.0);
        assert!(matches!(assign(&s, &[g]), Target::Ignored { .. }));
        let far = Box3d::new([30.0, 0.0, 0.0], [4.0, 2.0, 1.5], 0.0);
        assert!(matches!(assign(&far, &[g]), Target::Negative { iou } if iou == 0.0));
        assert!(matches!(assign(&g, &[]), Target::Negative { .. }));
    }

    #[test]
    fn l_uct_equals_a_hand_computed_value() {
        // Two positives, one negative. Predicted residuals u1 = (0.3, −0.4, 0, 0, 0, 0, 0, 1),
        // u2 = (0, 0, 0, 0.1, 0, 0, 0.2, 0.98), max tr 0.01 and 2.0:
        // L_uct = (e^{1−0.01}·0.5 + e^{1−0.5}·sqrt(0.01 + 0.04)) / 2.
        let reg = Tensor::from_vec(
            vec![
                0.3f32, -0.4, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.1, 0.0, 0.0, 0.2, 0.98, 1.0,
                1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0,
            ],
            (3, 8),
            &Device::Cpu,
        )
        .unwrap();
        let out = RefinerOutput {
            cls: Tensor::from_vec(vec![2.0f32, 1.0, -3.0], 3, &Device::Cpu).unwrap(),
            reg,
        };
        let z = [0.0; RESIDUALS];
        let targets = [
            Target::Positive {
                residuals: z,
                iou: 0.9,
            },
            Target::Positive {
                residuals: z,
                iou: 0.7,
            },
            Target::Negative { iou: 0.1 },
        ];
        let l = loss(&out, &targets, &[0.01, 2.0, 0.3]).unwrap();
        let want = ((0.99f64).exp() * 0.5 + (0.5f64).exp() * 0.05f64.sqrt()) / 2.0;
        assert!((l.uct as f64 - want).abs() < 1e-5, "{} vs {want}", l.uct);
        assert_eq!(l.positives, 2);
        // The total is L_reg + 2 L_cls + 0.005 L_uct.
        let total: f32 = l.total.to_scalar().unwrap();
        assert!((total - (l.reg + 2.0 * l.cls + 0.005 * l.uct)).abs() < 1e-5);
        // The uncertainty weight is e^{1−f}: largest for certain points.
        assert!((uct_weight(0.0) - 0.999f32.exp()).abs() < 1e-6);
        assert!((uct_weight(7.0) - 0.5f32.exp()).abs() < 1e-6);
        assert!((uct_weight(f32::NAN) - 0.5f32.exp()).abs() < 1e-6);
    }
}
