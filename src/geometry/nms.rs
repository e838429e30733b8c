//! Greedy non-maximum suppression on BEV or 3D IoU: boxes are visited by descending score
//! (ties by input order, NaN scores last) and a box is kept unless it overlaps an already kept
//! box by more than the threshold. Used by the detectors' decoding and by Result Fusion.

use super::iou::{iou_with_footprints, Footprint, IouKind};
use super::so3::wrap_angle;
use super::Box3d;

/// The visiting order of NMS and of score-ranked matching: descending score, ties by index,
/// NaN last.
pub fn score_order(scores: &[f32]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..scores.len()).collect();
    let key = |s: f32| if s.is_nan() { f32::NEG_INFINITY } else { s };
    order.sort_by(|&a, &b| key(scores[b]).total_cmp(&key(scores[a])).then(a.cmp(&b)));
    order
}

/// Indices of the kept boxes, highest score first. `boxes` and `scores` must have the same
/// length; extra entries of the longer one are ignored.
pub fn nms(boxes: &[Box3d], scores: &[f32], iou_threshold: f64, kind: IouKind) -> Vec<usize> {
    let n = boxes.len().min(scores.len());
    let order = score_order(&scores[..n]);
    let foot: Vec<Footprint> = boxes[..n].iter().map(Footprint::of_box).collect();
    let mut kept: Vec<usize> = Vec::new();
    for &i in &order {
        let suppressed = kept
            .iter()
            .any(|&k| iou_with_footprints(&boxes[i], &foot[i], &boxes[k], &foot[k], kind) > iou_threshold);
        if !suppressed {
            kept.push(i);
        }
    }
    kept
}

/// `v` if it is a usable vote IoU, in (0, 1]: at 0 or below boxes of other objects would vote,
/// above 1 nothing but the kept box would.
pub fn check_vote_iou(v: f64) -> Result<f64, String> {
    if v.is_finite() && v > 0.0 && v <= 1.0 {
        Ok(v)
    } else {
        Err(format!("a vote IoU must be in (0, 1], got {v}"))
    }
}

/// Box voting ("weighted NMS"): each kept box replaced by the score-weighted mean of every
/// candidate that overlaps it by at least `vote_iou` (itself included). Centre and size are
/// averaged; the heading is the kept box's plus the weighted mean of the others' headings
/// relative to it, each folded into [-π/2, π/2) so a candidate flipped by the direction head
/// votes for the same axis. `kept` comes from [`nms`] on the same boxes; the score of a voted box
/// stays the kept box's. Candidates with a non-finite or non-positive score do not vote.
pub fn vote(boxes: &[Box3d], scores: &[f32], kept: &[usize], vote_iou: f64, kind: IouKind) -> Vec<Box3d> {
    let n = boxes.len().min(scores.len());
    let foot: Vec<Footprint> = boxes[..n].iter().map(Footprint::of_box).collect();
    kept.iter()
        .filter(|&&k| k < n)
        .map(|&k| {
            let base = boxes[k];
            let mut sum_w = 0.0;
            let mut c = [0.0; 3];
            let mut s = [0.0; 3];
            let mut dyaw = 0.0;
            for i in 0..n {
                let w = f64::from(scores[i]);
                if !(w.is_finite() && w > 0.0) {
                    continue;
                }
                if i != k && iou_with_footprints(&boxes[i], &foot[i], &base, &foot[k], kind) < vote_iou {
                    continue;
                }
                let b = &boxes[i];
                for j in 0..3 {
                    c[j] += w * b.center[j];
                    s[j] += w * b.size_lwh[j];
                }
                let half = std::f64::consts::FRAC_PI_2;
                dyaw += w * ((wrap_angle(b.yaw - base.yaw) + half).rem_euclid(std::f64::consts::PI) - half);
                sum_w += w;
            }
            if sum_w <= 0.0 {
                return base;
            }
            Box3d::new(
                c.map(|v| v / sum_w),
                s.map(|v| v / sum_w),
                wrap_angle(base.yaw + dyaw / sum_w),
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bx(x: f64, yaw: f64) -> Box3d {
        Box3d::new([x, 0.0, 0.0], [4.0, 2.0, 1.5], yaw)
    }

    #[test]
    fn keeps_the_best_of_a_cluster() {
        let boxes = [bx(0.0, 0.0), bx(0.3, 0.05), bx(10.0, 0.0), bx(0.1, 0.0)];
        let scores = [0.5, 0.9, 0.4, 0.8];
        assert_eq!(nms(&boxes, &scores, 0.5, IouKind::ThreeD), vec![1, 2]);
        // A threshold of 1 suppresses nothing.
        assert_eq!(nms(&boxes, &scores, 1.0, IouKind::Bev), vec![1, 3, 0, 2]);
    }

    #[test]
    fn ties_keep_input_order_and_nan_goes_last() {
        let boxes = [bx(0.0, 0.0), bx(0.0, 0.0), bx(20.0, 0.0)];
        assert_eq!(nms(&boxes, &[0.7, 0.7, f32::NAN], 0.5, IouKind::Bev), vec![0, 2]);
        assert_eq!(score_order(&[f32::NAN, 0.1, 0.1, 0.3]), vec![3, 1, 2, 0]);
    }

    #[test]
    fn boxes_stacked_in_height_survive_3d_but_not_bev() {
        let a = Box3d::new([0.0, 0.0, 0.0], [4.0, 2.0, 1.0], 0.0);
        let b = Box3d::new([0.0, 0.0, 1.5], [4.0, 2.0, 1.0], 0.0);
        assert_eq!(nms(&[a, b], &[0.9, 0.8], 0.1, IouKind::ThreeD), vec![0, 1]);
        assert_eq!(nms(&[a, b], &[0.9, 0.8], 0.1, IouKind::Bev), vec![0]);
    }

    #[test]
    fn voting_averages_the_overlapping_candidates_by_score() {
        let a = Box3d::new([0.0, 0.0, 0.0], [4.0, 2.0, 1.5], 0.0);
        let b = Box3d::new([0.4, 0.2, 0.1], [4.4, 2.0, 1.5], 0.1);
        // Flipped by the direction head: votes for the same axis, not for a half-turn.
        let c = Box3d::new([0.0, 0.0, 0.0], [4.0, 2.0, 1.5], std::f64::consts::PI);
        let far = Box3d::new([20.0, 0.0, 0.0], [4.0, 2.0, 1.5], 0.0);
        let boxes = [a, b, c, far];
        let scores = [0.6, 0.2, 0.2, 0.9];
        let kept = nms(&boxes, &scores, 0.1, IouKind::Bev);
        assert_eq!(kept, vec![3, 0]);
        let v = vote(&boxes, &scores, &kept, 0.5, IouKind::Bev);
        assert_eq!(v[0], far, "a lone box votes for itself");
        let m = v[1];
        assert!((m.center[0] - 0.08).abs() < 1e-6 && (m.center[1] - 0.04).abs() < 1e-6);
        assert!((m.size_lwh[0] - 4.08).abs() < 1e-6);
        assert!((m.yaw - 0.02).abs() < 1e-6, "yaw {}", m.yaw);
        // A vote threshold above every overlap leaves the kept boxes as they were.
        assert_eq!(vote(&boxes, &scores, &kept, 1.01, IouKind::Bev), vec![far, a]);
    }
}
