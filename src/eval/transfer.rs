//! The transfer check: how a detector trained elsewhere (our simulator) does on real frames, in
//! the measures of issue 29 that do not punish a box for the target's car sizes. For one
//! category (cars) within a range (50 m) of the base origin:
//!
//! - **found**: the share of ground-truth boxes matched by a prediction scoring ≥ `min_score`
//!   whose BEV centre lies within `centre_dist` (2 m) of theirs (greedy by descending score, each
//!   prediction and box used once, the nearest unmatched box first);
//! - **AP (centre)**: KITTI R40 AP in percent over the same centre-distance matches, every score;
//! - **confident false positives per frame**: predictions scoring ≥ `min_score` within the range
//!   with no ground-truth box of *any* category (also beyond the range) within `centre_dist`;
//! - **found at IoU**: the share of the boxes matched by a prediction scoring ≥ `min_score` at 3D
//!   IoU ≥ `iou` (0.5), with the usual greedy matching.
//!
//! Predictions outside a frame's evaluated region (KITTI: camera 2's view, DontCare regions) have
//! been removed before, as for AP.

use serde::Serialize;

use super::ap::{interpolated_ap, pr_curve, Interpolation};
use super::kitti::SampleBoxes;
use super::matching::{match_with_ious, GtOutcome, PredOutcome};
use crate::geometry::{iou_matrix, Detection, IouKind};

/// The thresholds of the transfer check.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TransferRule {
    pub category: String,
    /// BEV range from the base origin (m): boxes and predictions at or beyond it are ignored.
    pub max_range: f64,
    pub min_score: f32,
    /// BEV centre distance of a match (m).
    pub centre_dist: f64,
    /// 3D IoU of the IoU matches.
    pub iou: f64,
}

impl Default for TransferRule {
    fn default() -> Self {
        Self {
            category: "car".into(),
            max_range: 50.0,
            min_score: 0.3,
            centre_dist: 2.0,
            iou: 0.5,
        }
    }
}

/// What the per-car table shows of a ground-truth box beyond the box itself.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct GtInfo {
    /// Points inside the box (every LiDAR, unperturbed); `None` when not counted.
    pub points: Option<usize>,
    /// The label's occlusion and truncation, where the format has them (KITTI).
    pub occlusion: Option<u8>,
    pub truncation: Option<f32>,
}

/// A frame's token and, per ground-truth box (in `SampleBoxes::gts` order), its [`GtInfo`].
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TransferFrame {
    pub token: String,
    pub gts: Vec<GtInfo>,
}

/// One car of the check: where it is, what the labels say, and what the detector gave it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CarRow {
    pub frame: String,
    /// BEV range from the base origin (m).
    pub range_m: f64,
    #[serde(flatten)]
    pub info: GtInfo,
    /// The best score of a prediction of the category with its BEV centre within `centre_dist`.
    pub best_score: Option<f32>,
    /// 3D IoU of that best-scoring prediction with the car.
    pub best_iou: Option<f64>,
    /// Found by centre distance at `min_score`; found at 3D IoU ≥ `iou`.
    pub found: bool,
    pub found_iou: bool,
}

/// A bootstrap interval.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Interval {
    pub lo: f64,
    pub hi: f64,
}

/// 90 % bootstrap intervals of the check's figures: the shares resample cars, AP and false
/// positives per frame resample frames (their false positives belong to no car).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TransferIntervals {
    pub resamples: usize,
    pub found_pct: Option<Interval>,
    pub found_iou_pct: Option<Interval>,
    pub ap_centre: Option<Interval>,
    pub confident_false_positives_per_frame: Option<Interval>,
}

/// The transfer check's figures (shares and AP in percent).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TransferReport {
    pub rule: TransferRule,
    pub frames: usize,
    /// Ground-truth boxes of the category within the range.
    pub boxes: usize,
    /// Of them, found by centre distance at `min_score`.
    pub found: usize,
    pub found_pct: Option<f64>,
    /// R40 AP over centre-distance matches (percent).
    pub ap_centre: Option<f64>,
    pub confident_false_positives: usize,
    pub confident_false_positives_per_frame: Option<f64>,
    /// Of the boxes, matched at 3D IoU ≥ `iou` by a prediction scoring ≥ `min_score`.
    pub found_iou: usize,
    pub found_iou_pct: Option<f64>,
    /// 90 % bootstrap intervals of the figures above.
    pub intervals: TransferIntervals,
    /// One row per car within the range.
    pub cars: Vec<CarRow>,
}

fn bev_dist(a: &Detection, b: &Detection) -> f64 {
    let (pa, pb) = (a.box3d.center, b.box3d.center);
    (pa[0] - pb[0]).hypot(pa[1] - pb[1])
}

/// Centre distance as a similarity (−distance, predictions × boxes), for [`match_with_ious`]
/// with the threshold −`centre_dist`.
fn centre_similarity(preds: &[&Detection], gts: &[&Detection]) -> Vec<f64> {
    preds
        .iter()
        .flat_map(|p| gts.iter().map(move |g| -bev_dist(p, g)))
        .collect()
}

fn pct(k: usize, n: usize) -> Option<f64> {
    (n > 0).then(|| 100.0 * k as f64 / n as f64)
}

/// One frame's matching of `preds` to `gts` (one category) under a similarity matrix, with
/// boxes beyond the range ignored.
fn matched(
    preds: &[&Detection],
    gts: &[&Detection],
    sim: &[f64],
    threshold: f64,
    range: f64,
) -> (Vec<PredOutcome>, Vec<GtOutcome>) {
    let scores: Vec<f32> = preds.iter().map(|d| d.score).collect();
    let pr: Vec<f64> = preds.iter().map(|d| d.box3d.bev_range()).collect();
    let gr: Vec<f64> = gts.iter().map(|d| d.box3d.bev_range()).collect();
    let m = match_with_ious(&scores, &pr, &gr, sim, threshold, range);
    (m.preds, m.gts)
}

/// One frame's part of the check.
#[derive(Default, Clone)]
struct FrameTally {
    boxes: usize,
    /// (score, true positive) of every prediction the centre-distance AP counts.
    ranked: Vec<(f32, bool)>,
    fps: usize,
}

fn ap_of(frames: &[&FrameTally]) -> Option<f64> {
    let boxes: usize = frames.iter().map(|f| f.boxes).sum();
    let mut ranked: Vec<(f32, bool)> = frames.iter().flat_map(|f| f.ranked.iter().copied()).collect();
    ranked.sort_by(|a, b| b.0.total_cmp(&a.0));
    let tp: Vec<bool> = ranked.iter().map(|r| r.1).collect();
    (boxes > 0).then(|| {
        let (r, p) = pr_curve(&tp, boxes);
        100.0 * interpolated_ap(&r, &p, Interpolation::R40)
    })
}

/// The transfer check over evaluated samples (predictions already restricted to the region),
/// without per-car information beyond the boxes.
pub fn transfer_check(samples: &[SampleBoxes], rule: &TransferRule) -> TransferReport {
    transfer_check_with(samples, &[], rule)
}

/// The transfer check with the frames' tokens and their boxes' [`GtInfo`] for the per-car table
/// (`frames` in `samples` order; missing entries leave the table's columns empty).
pub fn transfer_check_with(
    samples: &[SampleBoxes],
    frames: &[TransferFrame],
    rule: &TransferRule,
) -> TransferReport {
    let mut tallies = Vec::with_capacity(samples.len());
    let mut cars = Vec::new();
    for (k, s) in samples.iter().enumerate() {
        let meta = frames.get(k);
        let mut t = FrameTally::default();
        let preds: Vec<&Detection> = s.preds.iter().filter(|d| d.category == rule.category).collect();
        let (gts, infos): (Vec<&Detection>, Vec<GtInfo>) = s
            .gts
            .iter()
            .enumerate()
            .filter(|(_, d)| d.category == rule.category)
            .map(|(i, d)| (d, meta.and_then(|m| m.gts.get(i).copied()).unwrap_or_default()))
            .unzip();
        let in_range = |d: &Detection| d.box3d.bev_range() < rule.max_range;
        t.boxes = gts.iter().filter(|g| in_range(g)).count();
        let sim = centre_similarity(&preds, &gts);
        let (po, _) = matched(&preds, &gts, &sim, -rule.centre_dist, rule.max_range);
        for (p, o) in preds.iter().zip(&po) {
            match o {
                PredOutcome::TruePositive { .. } => t.ranked.push((p.score, true)),
                PredOutcome::FalsePositive { .. } => t.ranked.push((p.score, false)),
                PredOutcome::Ignored => {}
            }
        }
        let confident: Vec<&Detection> = preds
            .iter()
            .copied()
            .filter(|p| p.score >= rule.min_score)
            .collect();
        let sim = centre_similarity(&confident, &gts);
        let (_, found) = matched(&confident, &gts, &sim, -rule.centre_dist, rule.max_range);
        t.fps = confident
            .iter()
            .filter(|p| in_range(p) && !s.gts.iter().any(|g| bev_dist(p, g) <= rule.centre_dist))
            .count();
        let cb: Vec<_> = confident.iter().map(|d| d.box3d).collect();
        let gb: Vec<_> = gts.iter().map(|d| d.box3d).collect();
        let ious = iou_matrix(&cb, &gb, IouKind::ThreeD);
        let (_, found_iou) = matched(&confident, &gts, &ious, rule.iou, rule.max_range);
        for (j, g) in gts.iter().enumerate() {
            if !in_range(g) {
                continue;
            }
            let best = preds
                .iter()
                .filter(|p| bev_dist(p, g) <= rule.centre_dist)
                .max_by(|a, b| a.score.total_cmp(&b.score));
            let is = |o: Option<&GtOutcome>| matches!(o, Some(GtOutcome::Matched { .. }));
            cars.push(CarRow {
                frame: meta.map_or_else(|| k.to_string(), |m| m.token.clone()),
                range_m: g.box3d.bev_range(),
                info: infos.get(j).copied().unwrap_or_default(),
                best_score: best.map(|p| p.score),
                best_iou: best.map(|p| iou_matrix(&[p.box3d], &[g.box3d], IouKind::ThreeD)[0]),
                found: is(found.get(j)),
                found_iou: is(found_iou.get(j)),
            });
        }
        tallies.push(t);
    }
    let boxes = cars.len();
    let found = cars.iter().filter(|c| c.found).count();
    let found_iou = cars.iter().filter(|c| c.found_iou).count();
    let fps: usize = tallies.iter().map(|t| t.fps).sum();
    let all: Vec<&FrameTally> = tallies.iter().collect();
    let n_frames = samples.len();
    TransferReport {
        rule: rule.clone(),
        frames: n_frames,
        boxes,
        found,
        found_pct: pct(found, boxes),
        ap_centre: ap_of(&all),
        confident_false_positives: fps,
        confident_false_positives_per_frame: (n_frames > 0).then(|| fps as f64 / n_frames as f64),
        found_iou,
        found_iou_pct: pct(found_iou, boxes),
        intervals: intervals(&cars, &tallies),
        cars,
    }
}

/// Resamples of the bootstrap (fixed seed: the same figures give the same interval).
pub const BOOTSTRAP_RESAMPLES: usize = 2000;

fn intervals(cars: &[CarRow], frames: &[FrameTally]) -> TransferIntervals {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(90);
    let b = BOOTSTRAP_RESAMPLES;
    let pct90 = |mut v: Vec<f64>| -> Option<Interval> {
        v.retain(|x| x.is_finite());
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        let at = |q: f64| v[((q * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)];
        Some(Interval {
            lo: at(0.05),
            hi: at(0.95),
        })
    };
    let (mut found, mut found_iou) = (Vec::with_capacity(b), Vec::with_capacity(b));
    if !cars.is_empty() {
        for _ in 0..b {
            let (mut f, mut fi) = (0usize, 0usize);
            for _ in 0..cars.len() {
                let c = &cars[rng.random_range(0..cars.len())];
                f += usize::from(c.found);
                fi += usize::from(c.found_iou);
            }
            found.push(100.0 * f as f64 / cars.len() as f64);
            found_iou.push(100.0 * fi as f64 / cars.len() as f64);
        }
    }
    let (mut ap, mut fpf) = (Vec::with_capacity(b), Vec::with_capacity(b));
    if !frames.is_empty() {
        for _ in 0..b {
            let pick: Vec<&FrameTally> = (0..frames.len())
                .map(|_| &frames[rng.random_range(0..frames.len())])
                .collect();
            ap.push(ap_of(&pick).unwrap_or(f64::NAN));
            fpf.push(pick.iter().map(|t| t.fps).sum::<usize>() as f64 / pick.len() as f64);
        }
    }
    TransferIntervals {
        resamples: b,
        found_pct: pct90(found),
        found_iou_pct: pct90(found_iou),
        ap_centre: pct90(ap),
        confident_false_positives_per_frame: pct90(fpf),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Box3d;

    fn det(x: f64, y: f64, l: f64, score: f32, cat: &str) -> Detection {
        Detection {
            box3d: Box3d::new([x, y, 0.0], [l, 1.8, 1.6], 0.0),
            score,
            category: cat.into(),
        }
    }

    #[test]
    fn counts_found_false_positives_and_iou_matches() {
        // Three cars within 50 m and one beyond; a short prediction on the first (centre 0.5 m
        // off: found, IoU < 0.5), an exact one on the second, a weak one on the third (score
        // 0.1: not found), a confident one on empty road (a false positive), a confident one
        // 1 m from a pedestrian (not a false positive) and one beyond the range (ignored).
        let gts = vec![
            det(10.0, 0.0, 4.7, 1.0, "car"),
            det(20.0, 5.0, 4.7, 1.0, "car"),
            det(30.0, -5.0, 4.7, 1.0, "car"),
            det(60.0, 0.0, 4.7, 1.0, "car"),
            det(15.0, 10.0, 0.8, 1.0, "pedestrian"),
        ];
        let preds = vec![
            det(10.5, 0.0, 2.0, 0.9, "car"),
            det(20.0, 5.0, 4.7, 0.8, "car"),
            det(30.0, -5.0, 4.7, 0.1, "car"),
            det(0.0, 30.0, 4.7, 0.7, "car"),
            det(15.0, 11.0, 4.7, 0.6, "car"),
            det(60.0, 0.0, 4.7, 0.95, "car"),
        ];
        let r = transfer_check(&[SampleBoxes { preds, gts }], &TransferRule::default());
        assert_eq!((r.boxes, r.found, r.found_iou), (3, 2, 1));
        assert_eq!(r.confident_false_positives, 1);
        assert_eq!(r.confident_false_positives_per_frame, Some(1.0));
        // Ranked: 0.9 TP, 0.8 TP, 0.7 FP, 0.6 FP, 0.1 TP → recall 1/3, 2/3 at precision 1,
        // recall 1 at precision 3/5: R40 = (26·1 + 14·0.6) / 40.
        let ap = r.ap_centre.unwrap_or(f64::NAN);
        assert!((ap - 100.0 * (26.0 + 14.0 * 0.6) / 40.0).abs() < 1e-9, "{ap}");
        // The per-car table: the three cars within range, in label order.
        let rows: Vec<(Option<f32>, bool, bool)> = r
            .cars
            .iter()
            .map(|c| (c.best_score, c.found, c.found_iou))
            .collect();
        assert_eq!(
            rows,
            [
                (Some(0.9), true, false),
                (Some(0.8), true, true),
                (Some(0.1), false, false)
            ]
        );
        assert!((r.cars[1].best_iou.unwrap_or(0.0) - 1.0).abs() < 1e-9);
        // Bootstrap over 3 cars: the interval holds the estimate and is not a point.
        let i = r.intervals.found_pct.unwrap_or(Interval { lo: 0.0, hi: 0.0 });
        assert!(i.lo <= 66.7 && 66.6 <= i.hi && i.lo < i.hi, "{i:?}");
    }

    #[test]
    fn intervals_narrow_as_cars_grow_and_repeat() {
        // n frames with one car each, found in every other frame.
        let frames = |n: usize| -> Vec<SampleBoxes> {
            (0..n)
                .map(|k| SampleBoxes {
                    preds: if k % 2 == 0 {
                        vec![det(10.0, 0.0, 4.7, 0.9, "car")]
                    } else {
                        vec![]
                    },
                    gts: vec![det(10.0, 0.0, 4.7, 1.0, "car")],
                })
                .collect()
        };
        let small = transfer_check(&frames(10), &TransferRule::default()).intervals;
        let large = transfer_check(&frames(200), &TransferRule::default()).intervals;
        let w = |i: Option<Interval>| i.map_or(f64::NAN, |i| i.hi - i.lo);
        assert!(
            w(large.found_pct) < 0.5 * w(small.found_pct),
            "{small:?} {large:?}"
        );
        assert_eq!(
            small,
            transfer_check(&frames(10), &TransferRule::default()).intervals
        );
    }

    #[test]
    fn no_boxes_gives_no_shares() {
        let r = transfer_check(
            &[SampleBoxes {
                preds: vec![],
                gts: vec![],
            }],
            &TransferRule::default(),
        );
        assert_eq!(r.found_pct, None);
        assert_eq!(r.ap_centre, None);
        assert_eq!(r.confident_false_positives_per_frame, Some(0.0));
    }
}
