//! Per-sample matching of predictions to ground truth, the KITTI way as the paper uses it
//! (§V-A-2): predictions are visited by descending score and each takes the unclaimed ground-truth
//! box of the same category with the highest IoU, if that IoU is ≥ the threshold.
//!
//! The distance rule of a difficulty (range < R metres from the base-frame origin in BEV):
//! - ground truth at range ≥ R is *ignored*: neither a positive to find nor a miss;
//! - a prediction at range ≥ R is ignored, not a false positive;
//! - a prediction inside R that does not match any in-range box but overlaps an ignored box by
//!   ≥ the threshold is ignored too (it found a real object just beyond the border, KITTI's
//!   "don't care" rule).
//!
//! The outcome of every box is returned, so the GUI and the reports can say per box why it is a
//! true positive, a false positive or a miss; AP is computed from the same outcomes.

use serde::Serialize;

use crate::dataset::EvalRegion;
use crate::geometry::iou::{iou_matrix, IouKind};
use crate::geometry::nms::score_order;
use crate::geometry::Detection;

/// What one prediction turned out to be.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "outcome", rename_all = "snake_case")]
pub enum PredOutcome {
    TruePositive {
        gt: usize,
        iou: f64,
    },
    /// `best_iou`: its highest IoU with any ground truth of its category (0 if none).
    FalsePositive {
        best_iou: f64,
    },
    Ignored,
}

/// What one ground-truth box turned out to be.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "outcome", rename_all = "snake_case")]
pub enum GtOutcome {
    Matched { pred: usize, iou: f64 },
    Missed,
    Ignored,
}

/// The rule of one matching: IoU threshold, kind, and the difficulty's range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchRule {
    pub iou_threshold: f64,
    pub kind: IouKind,
    /// Boxes at BEV range ≥ this are ignored (`f64::INFINITY` for none).
    pub max_range: f64,
}

impl Default for MatchRule {
    fn default() -> Self {
        Self {
            iou_threshold: 0.7,
            kind: IouKind::ThreeD,
            max_range: f64::INFINITY,
        }
    }
}

/// Outcomes of one sample, indexed like its inputs.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SampleMatch {
    pub preds: Vec<PredOutcome>,
    pub gts: Vec<GtOutcome>,
}

impl SampleMatch {
    pub fn true_positives(&self) -> usize {
        self.preds
            .iter()
            .filter(|o| matches!(o, PredOutcome::TruePositive { .. }))
            .count()
    }
    pub fn false_positives(&self) -> usize {
        self.preds
            .iter()
            .filter(|o| matches!(o, PredOutcome::FalsePositive { .. }))
            .count()
    }
    pub fn misses(&self) -> usize {
        self.gts.iter().filter(|o| matches!(o, GtOutcome::Missed)).count()
    }
}

/// Match one class of one sample given its IoU matrix (`ious[i * gts + j]`, predictions × GT).
/// This is the core that AP and the per-box outcomes share.
pub fn match_with_ious(
    scores: &[f32],
    pred_ranges: &[f64],
    gt_ranges: &[f64],
    ious: &[f64],
    iou_threshold: f64,
    max_range: f64,
) -> SampleMatch {
    let ng = gt_ranges.len();
    let beyond = |r: f64| r >= max_range || r.is_nan();
    let gt_ignored: Vec<bool> = gt_ranges.iter().map(|&r| beyond(r)).collect();
    let mut gts: Vec<GtOutcome> = gt_ignored
        .iter()
        .map(|&ig| if ig { GtOutcome::Ignored } else { GtOutcome::Missed })
        .collect();
    let mut preds = vec![PredOutcome::Ignored; scores.len()];
    for i in score_order(scores) {
        if beyond(pred_ranges[i]) {
            continue;
        }
        let row = &ious[i * ng..(i + 1) * ng];
        let mut best: Option<(usize, f64)> = None;
        let mut best_any = 0.0f64;
        let mut dont_care = false;
        for (j, &iou) in row.iter().enumerate() {
            best_any = best_any.max(iou);
            if iou < iou_threshold {
                continue;
            }
            if gt_ignored[j] {
                dont_care = true;
            } else if matches!(gts[j], GtOutcome::Missed) && best.is_none_or(|(_, b)| iou > b) {
                best = Some((j, iou));
            }
        }
        preds[i] = match best {
            Some((j, iou)) => {
                gts[j] = GtOutcome::Matched { pred: i, iou };
                PredOutcome::TruePositive { gt: j, iou }
            }
            None if dont_care => PredOutcome::Ignored,
            None => PredOutcome::FalsePositive { best_iou: best_any },
        };
    }
    SampleMatch { preds, gts }
}

/// Match the predictions of one sample to its ground truth, category by category.
pub fn match_sample(preds: &[Detection], gts: &[Detection], rule: &MatchRule) -> SampleMatch {
    let mut out = SampleMatch {
        preds: vec![PredOutcome::Ignored; preds.len()],
        gts: vec![GtOutcome::Missed; gts.len()],
    };
    let mut categories: Vec<&str> = preds.iter().chain(gts).map(|d| d.category.as_str()).collect();
    categories.sort_unstable();
    categories.dedup();
    for cat in categories {
        let pi: Vec<usize> = (0..preds.len()).filter(|&i| preds[i].category == cat).collect();
        let gi: Vec<usize> = (0..gts.len()).filter(|&j| gts[j].category == cat).collect();
        let pb: Vec<_> = pi.iter().map(|&i| preds[i].box3d).collect();
        let gb: Vec<_> = gi.iter().map(|&j| gts[j].box3d).collect();
        let ious = iou_matrix(&pb, &gb, rule.kind);
        let scores: Vec<f32> = pi.iter().map(|&i| preds[i].score).collect();
        let pr: Vec<f64> = pb.iter().map(|b| b.bev_range()).collect();
        let gr: Vec<f64> = gb.iter().map(|b| b.bev_range()).collect();
        let m = match_with_ious(&scores, &pr, &gr, &ious, rule.iou_threshold, rule.max_range);
        for (k, o) in m.preds.into_iter().enumerate() {
            out.preds[pi[k]] = match o {
                PredOutcome::TruePositive { gt, iou } => PredOutcome::TruePositive { gt: gi[gt], iou },
                other => other,
            };
        }
        for (k, o) in m.gts.into_iter().enumerate() {
            out.gts[gi[k]] = match o {
                GtOutcome::Matched { pred, iou } => GtOutcome::Matched { pred: pi[pred], iou },
                other => other,
            };
        }
    }
    out
}

/// What a viewer matches: only the predictions scoring at least `min_score` (the boxes drawn)
/// and inside the frame's evaluation region (KITTI: camera 2's view), against only the ground
/// truth `keep` accepts (e.g. the detector's categories). Outcomes are indexed like `preds` and
/// `gts`; the others are `Ignored`.
pub fn match_drawn(
    preds: &[Detection],
    gts: &[Detection],
    rule: &MatchRule,
    min_score: f32,
    region: Option<&EvalRegion>,
    keep: impl Fn(&Detection) -> bool,
) -> SampleMatch {
    let kept: Vec<usize> = (0..preds.len())
        .filter(|&i| preds[i].score >= min_score && region.is_none_or(|r| r.contains(&preds[i].box3d)))
        .collect();
    let drawn: Vec<Detection> = kept.iter().map(|&i| preds[i].clone()).collect();
    let known: Vec<usize> = (0..gts.len()).filter(|&j| keep(&gts[j])).collect();
    let known_gts: Vec<Detection> = known.iter().map(|&j| gts[j].clone()).collect();
    let m = match_sample(&drawn, &known_gts, rule);
    let mut out = SampleMatch {
        preds: vec![PredOutcome::Ignored; preds.len()],
        gts: vec![GtOutcome::Ignored; gts.len()],
    };
    for (&i, o) in kept.iter().zip(m.preds) {
        out.preds[i] = match o {
            PredOutcome::TruePositive { gt, iou } => PredOutcome::TruePositive { gt: known[gt], iou },
            other => other,
        };
    }
    for (&j, g) in known.iter().zip(m.gts) {
        out.gts[j] = match g {
            GtOutcome::Matched { pred, iou } => GtOutcome::Matched {
                pred: kept[pred],
                iou,
            },
            other => other,
        };
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Box3d;

    fn det(x: f64, y: f64, score: f32, cat: &str) -> Detection {
        Detection {
            box3d: Box3d::new([x, y, 0.0], [4.0, 2.0, 1.5], 0.0),
            score,
            category: cat.into(),
        }
    }

    #[test]
    fn match_drawn_ignores_undrawn_boxes_and_kept_out_truth_and_keeps_indices() {
        let gts = [det(0.0, 15.0, 1.0, "truck"), det(10.0, 0.0, 1.0, "car")];
        let preds = [
            det(30.0, 0.0, 0.9, "car"),  // drawn, nothing there
            det(10.0, 0.0, 0.1, "car"),  // below min score: not drawn
            det(10.0, 0.05, 0.8, "car"), // drawn, on gt 1
        ];
        let m = match_drawn(&preds, &gts, &MatchRule::default(), 0.3, None, |g| {
            g.category == "car"
        });
        assert!(matches!(m.preds[0], PredOutcome::FalsePositive { .. }));
        assert_eq!(m.preds[1], PredOutcome::Ignored);
        assert!(matches!(m.preds[2], PredOutcome::TruePositive { gt: 1, .. }));
        assert_eq!(m.gts[0], GtOutcome::Ignored);
        assert!(matches!(m.gts[1], GtOutcome::Matched { pred: 2, .. }));
    }

    #[test]
    fn greedy_by_score_duplicates_are_false_positives() {
        let gts = [det(10.0, 0.0, 1.0, "car"), det(0.0, 15.0, 1.0, "car")];
        let preds = [
            det(10.1, 0.0, 0.6, "car"),  // duplicate of the next, lower score
            det(10.0, 0.05, 0.9, "car"), // TP on gt 0
            det(0.0, 15.0, 0.5, "pedestrian"),
            det(30.0, 30.0, 0.4, "car"), // nothing there
        ];
        let m = match_sample(&preds, &gts, &MatchRule::default());
        assert!(matches!(m.preds[1], PredOutcome::TruePositive { gt: 0, .. }));
        assert!(matches!(m.preds[0], PredOutcome::FalsePositive { best_iou } if best_iou > 0.7));
        // Wrong category never matches.
        assert!(matches!(m.preds[2], PredOutcome::FalsePositive { best_iou } if best_iou == 0.0));
        assert!(matches!(m.preds[3], PredOutcome::FalsePositive { .. }));
        assert!(matches!(m.gts[0], GtOutcome::Matched { pred: 1, .. }));
        assert_eq!(m.gts[1], GtOutcome::Missed);
        assert_eq!((m.true_positives(), m.false_positives(), m.misses()), (1, 3, 1));
    }

    #[test]
    fn range_rule_ignores_far_boxes_and_dont_care_matches() {
        let gts = [det(19.0, 0.0, 1.0, "car"), det(21.0, 0.0, 1.0, "car")];
        let preds = [
            det(19.0, 0.0, 0.9, "car"), // TP
            det(21.0, 0.0, 0.8, "car"), // beyond 20 m: ignored
            det(19.5, 0.0, 0.7, "car"), // inside 20 m; GT 0 is taken, far GT 1 overlaps 5/11
            det(40.0, 0.0, 0.6, "car"), // far FP: ignored
        ];
        let rule = MatchRule {
            iou_threshold: 0.5,
            max_range: 20.0,
            ..Default::default()
        };
        let m = match_sample(&preds, &gts, &rule);
        assert!(matches!(m.preds[0], PredOutcome::TruePositive { gt: 0, .. }));
        assert_eq!(m.preds[1], PredOutcome::Ignored);
        // Its IoU with the far GT is 5/11 = 0.45 < 0.5: a false positive.
        assert!(matches!(m.preds[2], PredOutcome::FalsePositive { .. }));
        assert_eq!(m.preds[3], PredOutcome::Ignored);
        assert_eq!(m.gts[1], GtOutcome::Ignored);
        // At IoU 0.4 it overlaps the ignored far box enough: don't care.
        let m = match_sample(
            &preds,
            &gts,
            &MatchRule {
                iou_threshold: 0.4,
                ..rule
            },
        );
        assert_eq!(m.preds[2], PredOutcome::Ignored);
    }
}
