//! KITTI-style AP_3D as the paper reports it (§V-A-2): 360° around the vehicle, three cumulative
//! difficulties by the BEV distance of a box from the base-frame origin (easy < 20 m,
//! moderate < 30 m, hard < 50 m), IoU thresholds 0.7 and 0.5 on 3D IoU, per class, interpolated
//! AP at 40 recall points (11 as an option), in percent as in the paper's tables.
//!
//! Matching and the distance rule are those of [`super::matching`]: greedy by score, boxes beyond
//! the difficulty's range ignored (not false positives). A class with no ground truth inside a
//! difficulty's range has no AP there (`null`).

use serde::ser::SerializeMap;
use serde::{Serialize, Serializer};

use super::ap::{interpolated_ap, pr_curve, Interpolation};
use super::matching::{match_with_ious, GtOutcome, PredOutcome};
use crate::geometry::iou::{iou_matrix, IouKind};
use crate::geometry::nms::score_order;
use crate::geometry::Detection;
use rayon::prelude::*;

/// A map that serialises in insertion order (JSON objects with a meaningful key order).
#[derive(Debug, Clone, PartialEq)]
pub struct Ordered<V>(pub Vec<(String, V)>);

impl<V> Ordered<V> {
    pub fn get(&self, key: &str) -> Option<&V> {
        self.0.iter().find(|(k, _)| k == key).map(|(_, v)| v)
    }
}

impl<V: Serialize> Serialize for Ordered<V> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(Some(self.0.len()))?;
        for (k, v) in &self.0 {
            m.serialize_entry(k, v)?;
        }
        m.end()
    }
}

/// The predictions and ground truth of one sample, in the base frame.
#[derive(Debug, Clone, Default)]
pub struct SampleBoxes {
    pub preds: Vec<Detection>,
    pub gts: Vec<Detection>,
}

/// What to compute.
#[derive(Debug, Clone, PartialEq)]
pub struct KittiConfig {
    pub iou_thresholds: Vec<f64>,
    /// (name, range in metres), cumulative.
    pub difficulties: Vec<(String, f64)>,
    pub interpolation: Interpolation,
    pub kind: IouKind,
}

impl Default for KittiConfig {
    fn default() -> Self {
        Self {
            iou_thresholds: vec![0.7, 0.5],
            difficulties: vec![
                ("easy".into(), 20.0),
                ("moderate".into(), 30.0),
                ("hard".into(), 50.0),
            ],
            interpolation: Interpolation::R40,
            kind: IouKind::ThreeD,
        }
    }
}

/// AP in percent per class → "iou_<t>" → difficulty (`None`: no ground truth in range).
pub type KittiReport = Ordered<Ordered<Ordered<Option<f64>>>>;

/// One cell of a [`KittiReport`]: AP (%) of `class` at threshold key `iou` (`"iou_0.7"`) and
/// `difficulty`; `None` when the report has no such cell or it has no ground truth.
pub fn ap_cell(report: &KittiReport, class: &str, iou: &str, difficulty: &str) -> Option<f64> {
    report.get(class)?.get(iou)?.get(difficulty).copied().flatten()
}

/// Car moderate AP_3D@0.7 (%): the figure the paper's claims compare.
pub fn car_moderate_07(report: &KittiReport) -> Option<f64> {
    ap_cell(report, "car", "iou_0.7", "moderate")
}

/// The classes of the ground truth, `car` first, then alphabetical.
pub fn classes(samples: &[SampleBoxes]) -> Vec<String> {
    let mut c: Vec<String> = samples
        .iter()
        .flat_map(|s| s.gts.iter().map(|g| g.category.clone()))
        .collect();
    c.sort_unstable_by(|a, b| (a != "car", a).cmp(&(b != "car", b)));
    c.dedup();
    c
}

/// One class of one sample: scores, ranges and the IoU matrix, computed once.
struct ClassSample {
    scores: Vec<f32>,
    pred_ranges: Vec<f64>,
    gt_ranges: Vec<f64>,
    ious: Vec<f64>,
}

fn ap_for(cases: &[ClassSample], threshold: f64, range: f64, interpolation: Interpolation) -> Option<f64> {
    let mut scores = Vec::new();
    let mut tp = Vec::new();
    let mut num_gt = 0;
    for c in cases {
        let m = match_with_ious(&c.scores, &c.pred_ranges, &c.gt_ranges, &c.ious, threshold, range);
        num_gt += m.gts.iter().filter(|g| !matches!(g, GtOutcome::Ignored)).count();
        for (o, &s) in m.preds.iter().zip(&c.scores) {
            match o {
                PredOutcome::TruePositive { .. } => {
                    scores.push(s);
                    tp.push(true);
                }
                PredOutcome::FalsePositive { .. } => {
                    scores.push(s);
                    tp.push(false);
                }
                PredOutcome::Ignored => {}
            }
        }
    }
    if num_gt == 0 {
        return None;
    }
    let order = score_order(&scores);
    let sorted: Vec<bool> = order.iter().map(|&i| tp[i]).collect();
    let (recall, precision) = pr_curve(&sorted, num_gt);
    Some(100.0 * interpolated_ap(&recall, &precision, interpolation))
}

/// Threshold key as the JSON shows it: "iou_0.7".
pub fn threshold_key(t: f64) -> String {
    format!("iou_{t}")
}

/// AP_3D per class, threshold and difficulty over a set of samples.
pub fn kitti_ap(samples: &[SampleBoxes], cfg: &KittiConfig) -> KittiReport {
    let mut out = Vec::new();
    for class in classes(samples) {
        let cases: Vec<ClassSample> = samples
            .par_iter()
            .map(|s| {
                let p: Vec<&Detection> = s.preds.iter().filter(|d| d.category == class).collect();
                let g: Vec<&Detection> = s.gts.iter().filter(|d| d.category == class).collect();
                let pb: Vec<_> = p.iter().map(|d| d.box3d).collect();
                let gb: Vec<_> = g.iter().map(|d| d.box3d).collect();
                ClassSample {
                    scores: p.iter().map(|d| d.score).collect(),
                    pred_ranges: pb.iter().map(|b| b.bev_range()).collect(),
                    gt_ranges: gb.iter().map(|b| b.bev_range()).collect(),
                    ious: iou_matrix(&pb, &gb, cfg.kind),
                }
            })
            .collect();
        let per_t = cfg
            .iou_thresholds
            .iter()
            .map(|&t| {
                let per_d = cfg
                    .difficulties
                    .iter()
                    .map(|(name, r)| (name.clone(), ap_for(&cases, t, *r, cfg.interpolation)))
                    .collect();
                (threshold_key(t), Ordered(per_d))
            })
            .collect();
        out.push((class, Ordered(per_t)));
    }
    Ordered(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Box3d;

    fn det(x: f64, y: f64, score: f32) -> Detection {
        Detection {
            box3d: Box3d::new([x, y, 0.0], [4.0, 2.0, 1.5], 0.3),
            score,
            category: "car".into(),
        }
    }

    #[test]
    fn hand_computed_ap_with_difficulties() {
        // Sample 1: GT at 10 m and 25 m; sample 2: GT at 40 m.
        // Predictions: exact hit at 10 m (0.9), FP at 15 m (0.8), exact hit at 25 m (0.6),
        // exact hit at 40 m (0.5).
        let s1 = SampleBoxes {
            preds: vec![det(10.0, 0.0, 0.9), det(0.0, 15.0, 0.8), det(0.0, -25.0, 0.6)],
            gts: vec![det(10.0, 0.0, 1.0), det(0.0, -25.0, 1.0)],
        };
        let s2 = SampleBoxes {
            preds: vec![det(40.0, 0.0, 0.5)],
            gts: vec![det(40.0, 0.0, 1.0)],
        };
        let r = kitti_ap(&[s1, s2], &KittiConfig::default());
        let car = r.get("car").and_then(|c| c.get("iou_0.7")).expect("car at 0.7");
        // easy (< 20 m): 1 GT; TP then FP → recall 1 at precision 1: AP 100.
        assert_eq!(car.get("easy"), Some(&Some(100.0)));
        // moderate: 2 GT; TP (r .5, p 1), FP (r .5, p .5), TP (r 1, p 2/3):
        // R40 points 1..20 → 1, 21..40 → 2/3.
        let m = (20.0 + 20.0 * 2.0 / 3.0) / 40.0 * 100.0;
        assert!((car.get("moderate").copied().flatten().unwrap_or(-1.0) - m).abs() < 1e-9);
        // hard: 3 GT; TP FP TP TP → p 1, .5, .667, .75 at r 1/3, 1/3, 2/3, 1.
        let h = (13.0 + 27.0 * 0.75) / 40.0 * 100.0;
        assert!((car.get("hard").copied().flatten().unwrap_or(-1.0) - h).abs() < 1e-9);
    }

    #[test]
    fn classes_put_car_first_and_missing_gt_is_null() {
        let mut ped = det(5.0, 0.0, 1.0);
        ped.category = "bicycle".into();
        let s = SampleBoxes {
            preds: vec![],
            gts: vec![ped, det(60.0, 0.0, 1.0)],
        };
        assert_eq!(
            classes(std::slice::from_ref(&s)),
            vec!["car".to_string(), "bicycle".to_string()]
        );
        let r = kitti_ap(&[s], &KittiConfig::default());
        // The only car is at 60 m: no difficulty has ground truth.
        let car = r.get("car").and_then(|c| c.get("iou_0.5")).expect("car");
        assert_eq!(car.get("hard"), Some(&None));
        // A bicycle with no predictions: AP 0.
        let b = r.get("bicycle").and_then(|c| c.get("iou_0.5")).expect("bicycle");
        assert_eq!(b.get("easy"), Some(&Some(0.0)));
    }
}
