//! What one box shows when it is selected (the window's details panel): the points inside it per
//! LiDAR with their tr(Ξ) histogram and uncertain share |P_u|/|P|, and — for a prediction — its
//! scores, its 3D IoU with a ground-truth box before and after refinement and the residuals
//! (prediction − truth in the truth's heading frame, the same [`BoxError`] `mlod eval --per-box`
//! reports), plus the share of its refiner's active points that are uncertain.
//!
//! How it works: one pass over the fused cloud keeps the points inside the box (a square reject
//! around the box, then the exact oriented test), counting them per source LiDAR and per
//! log-spaced tr(Ξ) bin; everything else is arithmetic on boxes the caller already has.

use rayon::prelude::*;
use serde::Serialize;

use crate::dataset::LidarChannel;
use crate::eval::BoxError;
use crate::geometry::{iou_3d, Box3d, Detection};
use crate::pipeline::FusedCloud;
use crate::refine::Refined;
use crate::uncertainty::UNCERTAIN_TRACE;

/// Bins of the tr(Ξ) histogram: four per decade over 1e-3 … 10 m² (values outside are clamped).
pub const TRACE_BINS: usize = 16;
const TRACE_LO: f32 = 1e-3;
const TRACE_DECADES: f32 = 4.0;

/// The histogram bin of a tr(Ξ) value.
pub fn trace_bin(tr: f32) -> usize {
    if !tr.is_finite() || tr <= TRACE_LO {
        return 0;
    }
    let t = (tr / TRACE_LO).log10() / TRACE_DECADES;
    ((t * TRACE_BINS as f32) as usize).min(TRACE_BINS - 1)
}

/// The lower edge of bin `k` (m²).
pub fn trace_bin_edge(k: usize) -> f32 {
    TRACE_LO * 10f32.powf(TRACE_DECADES * k as f32 / TRACE_BINS as f32)
}

/// The fused points inside a box.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct PointsInside {
    pub total: usize,
    /// Per LiDAR of the cloud, in the cloud's order.
    pub per_lidar: Vec<(LidarChannel, usize)>,
    /// Points with tr(Ξ) above the paper's 0.05 m² (P_u).
    pub uncertain: usize,
    pub mean_trace: f32,
    /// Counts per [`trace_bin`].
    pub trace_histogram: Vec<u32>,
}

impl PointsInside {
    /// |P_u| / |P| (0 without points).
    pub fn uncertain_fraction(&self) -> f64 {
        if self.total == 0 {
            0.0
        } else {
            self.uncertain as f64 / self.total as f64
        }
    }
}

/// Counts per LiDAR, uncertain points, mean tr(Ξ) and histogram of the points `idx` yields.
fn tally(cloud: &FusedCloud, idx: impl ParallelIterator<Item = usize>) -> PointsInside {
    let nl = cloud.lidars.len();
    let zero = || (vec![0usize; nl], 0usize, 0f64, vec![0u32; TRACE_BINS]);
    let (per, unc, sum, hist) = idx
        .fold(zero, |mut a, i| {
            let s = cloud.source.get(i).map_or(0, |&s| s as usize);
            if let Some(c) = a.0.get_mut(s) {
                *c += 1;
            }
            let tr = cloud.trace.get(i).copied().unwrap_or(0.0);
            a.1 += usize::from(tr > UNCERTAIN_TRACE);
            a.2 += tr as f64;
            a.3[trace_bin(tr)] += 1;
            a
        })
        .reduce(zero, |mut a, b| {
            a.0.iter_mut().zip(&b.0).for_each(|(x, y)| *x += y);
            a.3.iter_mut().zip(&b.3).for_each(|(x, y)| *x += y);
            (a.0, a.1 + b.1, a.2 + b.2, a.3)
        });
    let total: usize = per.iter().sum();
    PointsInside {
        total,
        per_lidar: cloud.lidars.iter().map(|l| l.channel).zip(per).collect(),
        uncertain: unc,
        mean_trace: if total == 0 {
            0.0
        } else {
            (sum / total as f64) as f32
        },
        trace_histogram: hist,
    }
}

/// The fused points inside `b` (base frame).
pub fn points_inside(cloud: &FusedCloud, b: &Box3d) -> PointsInside {
    let r = 0.5 * b.size_lwh[0].hypot(b.size_lwh[1]) as f32;
    let (cx, cy) = (b.center[0] as f32, b.center[1] as f32);
    let idx = (0..cloud.len())
        .into_par_iter()
        .with_min_len(8192)
        .filter(move |&i| {
            (cloud.x[i] - cx).abs() <= r
                && (cloud.y[i] - cy).abs() <= r
                && b.contains([cloud.x[i] as f64, cloud.y[i] as f64, cloud.z[i] as f64], 0.0)
        });
    tally(cloud, idx)
}

/// A ground-truth box a prediction is compared with.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TruthRef {
    /// Index among the frame's boxes.
    pub index: usize,
    pub annotation_token: String,
    /// Whether the matching made this pair a true positive (else: the truth of the category with
    /// the best 3D IoU, for a false positive).
    pub matched: bool,
}

/// What a selected prediction (a proposal, or a refined box with its proposal) shows.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PredictionDetails {
    pub category: String,
    /// Stage 1's score (of the proposal).
    pub proposal_score: f32,
    /// After refinement: the decoded score and the classification head's probability.
    pub refined_score: Option<f32>,
    pub head_score: Option<f32>,
    pub truth: Option<TruthRef>,
    /// 3D IoU with the truth of the proposal (before) and of the refined box (after).
    pub iou_before: Option<f64>,
    pub iou_after: Option<f64>,
    /// Prediction − truth, in the truth's heading frame.
    pub residual_before: Option<BoxError>,
    pub residual_after: Option<BoxError>,
    /// The points inside the box shown (the refined one for a refined box).
    pub inside: PointsInside,
    /// The refiner's active points (§V-C): how many, and per LiDAR / uncertain.
    pub active: Option<PointsInside>,
}

/// Details of a prediction: `proposal` is stage 1's box, `refined` its refinement if the case has
/// one; `truth` the ground-truth box to compare with (the caller's matching decides which).
pub fn prediction_details(
    cloud: &FusedCloud,
    proposal: &Detection,
    refined: Option<&Refined>,
    truth: Option<(TruthRef, &Box3d)>,
) -> PredictionDetails {
    let shown = refined.map_or(&proposal.box3d, |r| &r.detection.box3d);
    let (truth, gt) = match truth {
        Some((t, b)) => (Some(t), Some(b)),
        None => (None, None),
    };
    let active = refined.map(|r| {
        let n = cloud.len();
        let idx: Vec<usize> = r.active.iter().map(|&k| k as usize).filter(|&k| k < n).collect();
        tally(cloud, idx.into_par_iter())
    });
    PredictionDetails {
        category: proposal.category.clone(),
        proposal_score: proposal.score,
        refined_score: refined.map(|r| r.detection.score),
        head_score: refined.map(|r| r.refined_score),
        iou_before: gt.map(|g| iou_3d(&proposal.box3d, g)),
        iou_after: gt.zip(refined).map(|(g, r)| iou_3d(&r.detection.box3d, g)),
        residual_before: gt.map(|g| BoxError::between(&proposal.box3d, g)),
        residual_after: gt
            .zip(refined)
            .map(|(g, r)| BoxError::between(&r.detection.box3d, g)),
        truth,
        inside: points_inside(cloud, shown),
        active,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::FusedLidar;

    fn cloud() -> FusedCloud {
        // Two LiDARs: three points in a 4 × 2 × 2 box at the origin, one far away.
        let pts = [
            [0.0, 0.0, 0.0],
            [1.0, 0.5, 0.2],
            [-1.4, -0.5, 0.0],
            [20.0, 0.0, 0.0],
        ];
        FusedCloud {
            x: pts.iter().map(|p| p[0]).collect(),
            y: pts.iter().map(|p| p[1]).collect(),
            z: pts.iter().map(|p| p[2]).collect(),
            intensity: vec![0.0; 4],
            source: vec![0, 1, 1, 0],
            trace: vec![1e-3, 0.2, 0.01, 5.0],
            lidars: vec![
                FusedLidar::identity(LidarChannel::Top, 0..1),
                FusedLidar::identity(LidarChannel::FrontLeft, 1..3),
            ],
        }
    }

    fn car(x: f64, l: f64) -> Detection {
        Detection {
            box3d: Box3d {
                center: [x, 0.0, 0.0],
                size_lwh: [l, 2.0, 2.0],
                yaw: 0.0,
            },
            score: 0.8,
            category: "car".into(),
        }
    }

    #[test]
    fn bins_cover_four_decades() {
        assert_eq!(trace_bin(0.0), 0);
        assert_eq!(trace_bin(f32::NAN), 0);
        assert_eq!(trace_bin(1e-3), 0);
        assert_eq!(trace_bin(0.011), 4);
        assert_eq!(trace_bin(1e3), TRACE_BINS - 1);
        assert!((trace_bin_edge(4) - 0.01).abs() < 1e-6);
        for k in 0..TRACE_BINS {
            assert_eq!(trace_bin(trace_bin_edge(k) * 1.01), k);
        }
    }

    #[test]
    fn points_inside_count_per_lidar_and_uncertain() {
        let c = cloud();
        let p = points_inside(&c, &car(0.0, 4.0).box3d);
        assert_eq!(p.total, 3);
        assert_eq!(
            p.per_lidar,
            vec![(LidarChannel::Top, 1), (LidarChannel::FrontLeft, 2)]
        );
        assert_eq!(p.uncertain, 1);
        assert!((p.uncertain_fraction() - 1.0 / 3.0).abs() < 1e-12);
        assert_eq!(p.trace_histogram.iter().sum::<u32>(), 3);
        assert!((p.mean_trace - (1e-3 + 0.2 + 0.01) / 3.0).abs() < 1e-6);
        assert_eq!(
            points_inside(&c, &car(50.0, 4.0).box3d),
            PointsInside {
                per_lidar: vec![(LidarChannel::Top, 0), (LidarChannel::FrontLeft, 0)],
                trace_histogram: vec![0; TRACE_BINS],
                ..Default::default()
            }
        );
    }

    #[test]
    fn a_prediction_against_its_truth() {
        let c = cloud();
        let gt = car(0.0, 4.0);
        let proposal = car(0.5, 4.0);
        let d = prediction_details(
            &c,
            &proposal,
            None,
            Some((
                TruthRef {
                    index: 0,
                    annotation_token: "a".into(),
                    matched: true,
                },
                &gt.box3d,
            )),
        );
        let e = d.residual_before.unwrap();
        assert!((e.along - 0.5).abs() < 1e-12 && e.lateral.abs() < 1e-12);
        assert!((d.iou_before.unwrap() - 3.5 / 4.5).abs() < 1e-9);
        assert!(d.iou_after.is_none() && d.active.is_none() && d.refined_score.is_none());
        assert_eq!(d.inside.total, 3);
        // No truth to compare with: no IoU, no residual.
        let d = prediction_details(&c, &proposal, None, None);
        assert!(d.truth.is_none() && d.iou_before.is_none() && d.residual_before.is_none());
    }
}
