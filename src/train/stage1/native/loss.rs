//! SECOND's loss on the heads' outputs, with its gradient written straight into ∂L/∂h: the same
//! terms as [`crate::train::stage1::compute_loss_with`] (focal class loss over every anchor,
//! smooth-L1 with the sine-difference angle and 0.2 × direction cross-entropy over the positives,
//! all over max(1, positives)).

use crate::detect::anchors::Targets;
use crate::detect::DetectError;

const ALPHA: f32 = 0.25;
const BETA: f32 = 1.0 / 9.0;
const REG_WEIGHT: f64 = 2.0;
const DIR_WEIGHT: f64 = 0.2;

/// The loss terms of one step, as the trainer logs them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LossTerms {
    pub cls: f32,
    pub reg: f32,
    pub dir: f32,
    pub num_pos: usize,
}

/// Focal loss (α = 0.25, γ = 2) of one logit and its derivative, as the candle graph computes it:
/// ce = relu(x) − x·t + ln(1 + e^{−|x|}), p_t = p t + (1 − p)(1 − t), loss = α_t (1 − p_t)² ce.
pub(crate) fn focal(x: f32, t: f32) -> (f32, f32) {
    let ce = x.max(0.0) - x * t + (1.0 + (-x.abs()).exp()).ln();
    let p = 1.0 / (1.0 + (-x).exp());
    let p_t = p * t + (1.0 - p) * (1.0 - t);
    let base = (1.0 - p_t).clamp(0.0, 1.0);
    let alpha_t = t * (2.0 * ALPHA - 1.0) + (1.0 - ALPHA);
    let loss = alpha_t * base * base * ce;
    // d base/dx = p (1 − p)(1 − 2t), d ce/dx = p − t.
    let grad = alpha_t * (2.0 * base * p * (1.0 - p) * (1.0 - 2.0 * t) * ce + base * base * (p - t));
    (loss, grad)
}

/// Smooth-L1 of `d` and its derivative.
pub(crate) fn smooth_l1(d: f32) -> (f32, f32) {
    let a = d.abs();
    let sign = if d >= 0.0 { 1.0 } else { -1.0 };
    if a < BETA {
        (0.5 * a * a / BETA, d / BETA)
    } else {
        (a - 0.5 * BETA, sign)
    }
}

/// Loss of head outputs `h` (`[rows, P]`, rows = 10·A: A class rows, 7A box rows, 2A direction
/// rows; anchor `i = pixel·A + a`) against `t`; writes ∂L/∂h into `dh`.
pub fn loss_and_grad(
    h: &[f32],
    dh: &mut [f32],
    p: usize,
    na: usize,
    t: &Targets,
    size_weight: f32,
) -> Result<LossTerms, DetectError> {
    let n = p * na;
    if h.len() != 10 * na * p || dh.len() != h.len() {
        return Err(DetectError::BadParameter(format!(
            "head outputs of {} values do not fit {na} anchors per cell over {p} cells",
            h.len()
        )));
    }
    if t.labels.len() != n || t.cls_weights.len() != n {
        return Err(DetectError::BadParameter(format!(
            "targets for {} anchors, the network has {n}",
            t.labels.len()
        )));
    }
    let npos = t.positives.len();
    if t.reg.len() != 7 * npos || t.dir.len() != npos {
        return Err(DetectError::BadParameter(format!(
            "{npos} positives with {} box targets and {} direction labels",
            t.reg.len() / 7,
            t.dir.len()
        )));
    }
    let norm = npos.max(1) as f64;
    let inv = (1.0 / norm) as f32;
    let mut cls = 0f64;
    for a in 0..na {
        let (row, drow) = (&h[a * p..(a + 1) * p], &mut dh[a * p..(a + 1) * p]);
        for (pix, (&x, d)) in row.iter().zip(drow.iter_mut()).enumerate() {
            let i = pix * na + a;
            let (l, g) = focal(x, t.labels[i]);
            let w = t.cls_weights[i];
            cls += (l * w) as f64;
            *d = g * w * inv;
        }
    }
    dh[na * p..].fill(0.0);
    let (mut reg, mut dir) = (0f64, 0f64);
    let sizes = [1.0, 1.0, 1.0, size_weight, size_weight, size_weight, 1.0];
    let reg_scale = (REG_WEIGHT / norm) as f32;
    let dir_scale = (DIR_WEIGHT / norm) as f32;
    for (j, &anchor) in t.positives.iter().enumerate() {
        let i = anchor as usize;
        if i >= n {
            return Err(DetectError::BadParameter(format!("positive anchor {i} of {n}")));
        }
        let (pix, a) = (i / na, i % na);
        let at = |row: usize| row * p + pix;
        let tgt = &t.reg[j * 7..j * 7 + 7];
        for (k, (&tk, &wk)) in tgt.iter().zip(&sizes).enumerate() {
            let idx = at(na + a * 7 + k);
            let x = h[idx];
            // The angle as SECOND compares it: sin(p − t) = sin p cos t − cos p sin t.
            let (d, dd) = if k == 6 {
                let (sp, cp) = x.sin_cos();
                let (st, ct) = tk.sin_cos();
                (sp * ct - cp * st, cp * ct + sp * st)
            } else {
                (x - tk, 1.0)
            };
            let (l, g) = smooth_l1(d);
            reg += (l * wk) as f64;
            dh[idx] += g * dd * wk * reg_scale;
        }
        let label = t.dir[j] as usize;
        if label > 1 {
            return Err(DetectError::BadParameter(format!(
                "direction label {label} of positive {j}"
            )));
        }
        let (i0, i1) = (at(8 * na + 2 * a), at(8 * na + 2 * a + 1));
        let (l0, l1) = (h[i0], h[i1]);
        let m = l0.max(l1);
        let lse = m + ((l0 - m).exp() + (l1 - m).exp()).ln();
        let (p0, p1) = ((l0 - lse).exp(), (l1 - lse).exp());
        dir += (lse - if label == 0 { l0 } else { l1 }) as f64;
        dh[i0] += (p0 - if label == 0 { 1.0 } else { 0.0 }) * dir_scale;
        dh[i1] += (p1 - if label == 1 { 1.0 } else { 0.0 }) * dir_scale;
    }
    Ok(LossTerms {
        cls: (cls / norm) as f32,
        reg: (reg * REG_WEIGHT / norm) as f32,
        dir: (dir * DIR_WEIGHT / norm) as f32,
        num_pos: npos,
    })
}
