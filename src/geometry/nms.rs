//! Greedy non-maximum suppression on BEV or 3D IoU: boxes are visited by descending score
//! (ties by input order, NaN scores last) and a box is kept unless it overlaps an already kept
//! box by more than the threshold. Used by the detectors' decoding and by Result Fusion.

use super::iou::{iou_with_footprints, Footprint, IouKind};
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
}
