//! Precision–recall curves and average precision, in the three forms the project needs:
//! KITTI's interpolated AP at 40 recall points (R40, the default since KITTI's 2019 update) or at
//! 11 points (R11, the original PASCAL/KITTI form), and the VOC all-point AP with a precision
//! envelope that the Lyft devkit computes.

use serde::{Deserialize, Serialize};

/// KITTI-style interpolation of the precision–recall curve.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Interpolation {
    /// Recall 1/40, 2/40, …, 1 (recall 0 excluded).
    #[default]
    R40,
    /// Recall 0, 0.1, …, 1.
    R11,
}

/// Cumulative recall and precision along predictions sorted by descending score.
/// `tp[k]` says whether the k-th prediction is a true positive; `num_gt` is the number of
/// ground-truth boxes that can be matched. Precision divides by `max(tp + fp, ε)` as the devkit.
pub fn pr_curve(tp: &[bool], num_gt: usize) -> (Vec<f64>, Vec<f64>) {
    let mut recall = Vec::with_capacity(tp.len());
    let mut precision = Vec::with_capacity(tp.len());
    let (mut ctp, mut cfp) = (0.0f64, 0.0f64);
    for &t in tp {
        if t {
            ctp += 1.0;
        } else {
            cfp += 1.0;
        }
        recall.push(if num_gt > 0 { ctp / num_gt as f64 } else { 0.0 });
        precision.push(ctp / (ctp + cfp).max(f64::EPSILON));
    }
    (recall, precision)
}

/// KITTI interpolated AP in [0, 1]: the mean over the recall points r of the highest precision
/// reached at a recall ≥ r (0 where the curve never reaches r).
pub fn interpolated_ap(recall: &[f64], precision: &[f64], interpolation: Interpolation) -> f64 {
    // Envelope from the right: best precision at this recall or beyond.
    let mut env = precision.to_vec();
    for i in (0..env.len().saturating_sub(1)).rev() {
        env[i] = env[i].max(env[i + 1]);
    }
    let at = |r: f64| -> f64 {
        // First index whose recall reaches r (recall is non-decreasing).
        let k = recall.partition_point(|&x| x < r - 1e-12);
        env.get(k).copied().unwrap_or(0.0)
    };
    match interpolation {
        Interpolation::R40 => (1..=40).map(|i| at(i as f64 / 40.0)).sum::<f64>() / 40.0,
        Interpolation::R11 => (0..=10).map(|i| at(i as f64 / 10.0)).sum::<f64>() / 11.0,
    }
}

/// The Lyft devkit's AP (`get_ap`): sentinels recall [0, …, 1] and precision [0, …, 0], the
/// precision envelope from the right, then Σ (r[i+1] − r[i]) · p[i+1] where recall changes.
pub fn voc_ap(recall: &[f64], precision: &[f64]) -> f64 {
    let mut r = Vec::with_capacity(recall.len() + 2);
    r.push(0.0);
    r.extend_from_slice(recall);
    r.push(1.0);
    let mut p = Vec::with_capacity(precision.len() + 2);
    p.push(0.0);
    p.extend_from_slice(precision);
    p.push(0.0);
    for i in (1..p.len()).rev() {
        p[i - 1] = p[i - 1].max(p[i]);
    }
    (0..r.len() - 1)
        .filter(|&i| r[i + 1] != r[i])
        .map(|i| (r[i + 1] - r[i]) * p[i + 1])
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn perfect_detector_scores_one() {
        let (r, p) = pr_curve(&[true, true, true], 3);
        assert_eq!(interpolated_ap(&r, &p, Interpolation::R40), 1.0);
        assert_eq!(interpolated_ap(&r, &p, Interpolation::R11), 1.0);
        assert_eq!(voc_ap(&r, &p), 1.0);
    }

    #[test]
    fn hand_computed_curve() {
        // TP, FP, TP with 4 GT: recall .25 .25 .5, precision 1 .5 .667.
        let (r, p) = pr_curve(&[true, false, true], 4);
        assert_eq!(r, vec![0.25, 0.25, 0.5]);
        // VOC: envelope [1, 2/3, 2/3]; area = .25·1 + .25·(2/3).
        assert!((voc_ap(&r, &p) - (0.25 + 0.25 * 2.0 / 3.0)).abs() < 1e-15);
        // R40: points 1..10 (r ≤ .25) take 1, 11..20 take 2/3, the rest 0.
        let r40 = (10.0 + 10.0 * 2.0 / 3.0) / 40.0;
        assert!((interpolated_ap(&r, &p, Interpolation::R40) - r40).abs() < 1e-15);
        // R11: r = 0, .1, .2 take 1; .3, .4, .5 take 2/3.
        let r11 = (3.0 + 3.0 * 2.0 / 3.0) / 11.0;
        assert!((interpolated_ap(&r, &p, Interpolation::R11) - r11).abs() < 1e-15);
    }

    #[test]
    fn no_predictions_or_no_hits_score_zero() {
        let (r, p) = pr_curve(&[], 5);
        assert_eq!(voc_ap(&r, &p), 0.0);
        assert_eq!(interpolated_ap(&r, &p, Interpolation::R40), 0.0);
        let (r, p) = pr_curve(&[false, false], 5);
        assert_eq!(voc_ap(&r, &p), 0.0);
        assert_eq!(interpolated_ap(&r, &p, Interpolation::R11), 0.0);
    }
}
