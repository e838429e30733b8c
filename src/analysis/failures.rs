//! Failure cases: a case run over samples at one perturbation and again at α = 0 (same seed), its
//! drawn boxes (score ≥ a minimum) matched against the ground truth as the window matches them,
//! and every sample's worst outcomes listed — ground truth missed, false positives, and the
//! ground-truth boxes whose 3D IoU dropped most between α = 0 and the perturbation. The window's
//! failure browser and `mlod failures` both call [`scan`].
//!
//! How it works: samples run in parallel (rayon), each one fused twice (α = 0 and the given
//! perturbation) and detected twice; a `cancel` flag is polled between samples. The lists are
//! sorted deterministically, so any thread count gives the same output.

use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use rayon::prelude::*;
use serde::Serialize;

use crate::dataset::Dataset;
use crate::detect::{Case, DetectError, Detection, Detector};
use crate::eval::{match_drawn, GtOutcome, MatchRule, PredOutcome};
use crate::geometry::IouKind;
use crate::pipeline::FuseParams;

/// What a failure scan runs.
#[derive(Debug, Clone, PartialEq)]
pub struct ScanConfig {
    pub case: Case,
    /// The perturbation (and calibration-free fuse settings) of the "now" run; the reference run
    /// is the same with α = 0.
    pub params: FuseParams,
    pub tokens: Vec<String>,
    /// 3D IoU a box needs to match its ground truth.
    pub match_iou: f64,
    /// Boxes from this score up take part (as drawn in the window).
    pub min_score: f32,
    /// Every point's intensity replaced by this before the detector runs (`--set-intensity`).
    pub set_intensity: Option<f32>,
}

/// What went wrong with one box.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FailureKind {
    /// A ground-truth box no drawn box matched.
    Missed,
    /// A drawn box that matched no ground truth.
    FalsePositive,
    /// A ground-truth box matched at α = 0 whose IoU fell (it may still be matched).
    IouDrop,
}

/// One failing box.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BoxFailure {
    pub sample_token: String,
    pub kind: FailureKind,
    pub category: String,
    /// The ground-truth object (missed and IoU drops; a false positive has none).
    pub annotation: Option<String>,
    /// Centre of the box (the ground truth's, or the false positive's), base frame.
    pub center: [f64; 3],
    /// A false positive's score.
    pub score: Option<f32>,
    /// Matched IoU of the object at α = 0 and now (0: not matched).
    pub iou_at_zero: Option<f64>,
    pub iou_now: Option<f64>,
    /// Points of the perturbed cloud inside the box (the ground truth's, or the false positive's).
    pub points: usize,
}

impl BoxFailure {
    /// Distance of the box's centre from the base frame's origin on the ground (m).
    pub fn range(&self) -> f64 {
        self.center[0].hypot(self.center[1])
    }

    /// A miss that the perturbation alone caused: the object was detected at α = 0.
    pub fn lost_by_perturbation(&self) -> bool {
        self.kind == FailureKind::Missed && self.iou_at_zero.is_some_and(|v| v > 0.0)
    }

    /// IoU at α = 0 minus IoU now (0 when not defined).
    pub fn iou_drop(&self) -> f64 {
        match (self.iou_at_zero, self.iou_now) {
            (Some(a), Some(b)) => a - b,
            _ => 0.0,
        }
    }
}

/// One sample's outcomes.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SampleFailures {
    pub sample_token: String,
    /// Position in the scan's token list.
    pub index: usize,
    pub ground_truth: usize,
    pub missed: usize,
    pub false_positives: usize,
    /// Misses and false positives at α = 0, for comparison.
    pub missed_at_zero: usize,
    pub false_positives_at_zero: usize,
    /// The largest IoU drop of a ground-truth object (0 if none).
    pub worst_drop: f64,
    /// Its failing boxes: misses, false positives, IoU drops (largest first within each).
    pub boxes: Vec<BoxFailure>,
}

impl SampleFailures {
    /// How bad the sample is, for sorting: misses and false positives, then the worst drop.
    pub fn badness(&self) -> (usize, f64) {
        (self.missed + self.false_positives, self.worst_drop)
    }
}

/// Errors of a scan.
#[derive(Debug, thiserror::Error)]
pub enum ScanError {
    #[error("bad parameter: {0}")]
    BadParameter(String),
    #[error("sample {token}: {source}")]
    Sample { token: String, source: DetectError },
    #[error("cancelled")]
    Cancelled,
}

/// (matched IoU per ground truth or None, false positives) of `dets` on `gts` under the rule.
fn outcomes(
    dets: &[Detection],
    gts: &[Detection],
    rule: &MatchRule,
    min_score: f32,
    region: Option<&crate::dataset::EvalRegion>,
) -> (Vec<Option<f64>>, Vec<usize>) {
    let m = match_drawn(dets, gts, rule, min_score, region, |_| true);
    let ious = m
        .gts
        .iter()
        .map(|g| match g {
            GtOutcome::Matched { iou, .. } => Some(*iou),
            _ => None,
        })
        .collect();
    let fps = m
        .preds
        .iter()
        .enumerate()
        .filter(|(_, o)| matches!(o, PredOutcome::FalsePositive { .. }))
        .map(|(i, _)| i)
        .collect();
    (ious, fps)
}

/// One sample: detected at α = 0 and at the scan's perturbation, its failures listed.
fn scan_sample(
    dataset: &Dataset,
    detector: &dyn Detector,
    cfg: &ScanConfig,
    index: usize,
    token: &str,
) -> Result<SampleFailures, DetectError> {
    let mut frame = dataset.frame(token)?;
    if let Some(v) = cfg.set_intensity {
        frame.set_intensity(v);
    }
    let categories = detector.categories();
    let gt_boxes: Vec<&crate::dataset::GtBox> = frame
        .boxes
        .iter()
        .filter(|b| categories.contains(&b.category))
        .collect();
    let gts: Vec<Detection> = gt_boxes.iter().map(|b| b.as_detection()).collect();
    let rule = MatchRule {
        iou_threshold: cfg.match_iou,
        kind: IouKind::ThreeD,
        max_range: f64::INFINITY,
    };
    let mut zero = cfg.params.clone();
    zero.perturbation.alpha = 0.0;
    let now_dets = detector.detect(&frame, &cfg.params)?;
    let zero_dets = detector.detect(&frame, &zero)?;
    let region = frame.eval_region.as_ref();
    let (now, fps) = outcomes(&now_dets, &gts, &rule, cfg.min_score, region);
    let (then, fps_zero) = outcomes(&zero_dets, &gts, &rule, cfg.min_score, region);
    let cloud = crate::pipeline::fuse(&frame, &cfg.params)?;
    let points = |b: &crate::geometry::Box3d| crate::pipeline::box_stats(&cloud, b).points;
    let mut missed = Vec::new();
    let mut drops = Vec::new();
    for (j, g) in gt_boxes.iter().enumerate() {
        let f = |kind| BoxFailure {
            sample_token: token.to_string(),
            kind,
            category: g.category.clone(),
            annotation: Some(g.annotation_token.clone()),
            center: g.box3d.center,
            score: None,
            iou_at_zero: Some(then[j].unwrap_or(0.0)),
            iou_now: Some(now[j].unwrap_or(0.0)),
            points: points(&g.box3d),
        };
        if now[j].is_none() {
            missed.push(f(FailureKind::Missed));
        } else if then[j].is_some_and(|t| t > now[j].unwrap_or(0.0) + 1e-9) {
            drops.push(f(FailureKind::IouDrop));
        }
    }
    let by_drop = |a: &BoxFailure, b: &BoxFailure| b.iou_drop().total_cmp(&a.iou_drop());
    missed.sort_by(by_drop);
    drops.sort_by(by_drop);
    let worst_drop = missed
        .iter()
        .chain(&drops)
        .map(|b| b.iou_drop())
        .fold(0.0, f64::max);
    let false_positives: Vec<BoxFailure> = fps
        .iter()
        .map(|&i| BoxFailure {
            sample_token: token.to_string(),
            kind: FailureKind::FalsePositive,
            category: now_dets[i].category.clone(),
            annotation: None,
            center: now_dets[i].box3d.center,
            score: Some(now_dets[i].score),
            iou_at_zero: None,
            iou_now: None,
            points: points(&now_dets[i].box3d),
        })
        .collect();
    Ok(SampleFailures {
        sample_token: token.to_string(),
        index,
        ground_truth: gts.len(),
        missed: missed.len(),
        false_positives: false_positives.len(),
        missed_at_zero: then.iter().filter(|x| x.is_none()).count(),
        false_positives_at_zero: fps_zero.len(),
        worst_drop,
        boxes: missed.into_iter().chain(false_positives).chain(drops).collect(),
    })
}

/// A scan's parameters in range, and a case it can run.
fn check(cfg: &ScanConfig) -> Result<(), ScanError> {
    if !(cfg.match_iou.is_finite() && cfg.match_iou > 0.0 && cfg.match_iou <= 1.0) {
        return Err(ScanError::BadParameter(format!(
            "match IoU {} must be in (0, 1]",
            cfg.match_iou
        )));
    }
    if !(cfg.min_score.is_finite() && (0.0..=1.0).contains(&cfg.min_score)) {
        return Err(ScanError::BadParameter(format!(
            "min score {} must be in [0, 1]",
            cfg.min_score
        )));
    }
    if cfg.case.is_oc() {
        return Err(ScanError::BadParameter(format!(
            "{} calibrates each frame: scan its case without (OC)",
            cfg.case.paper_name()
        )));
    }
    if let Some(v) = cfg.set_intensity {
        if !v.is_finite() {
            return Err(ScanError::BadParameter(format!("intensity {v} must be finite")));
        }
    }
    Ok(())
}

/// Runs the scan: the samples worst first (most misses + false positives, then the largest IoU
/// drop, then token order). `progress(done, total)` after each sample; `cancel` stops it.
pub fn scan(
    dataset: &Dataset,
    models: &Path,
    gate: crate::cases::ground_gate::GateChoice,
    cfg: &ScanConfig,
    cancel: &AtomicBool,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Vec<SampleFailures>, ScanError> {
    check(cfg)?;
    // The models folder's decoding: box voting and, for stage-1 cases, `gate` (its ground gate
    // with `GateChoice::Manifest`).
    let detector = crate::cases::load_gated(models, cfg.case, gate).map_err(|source| ScanError::Sample {
        token: "(loading the detector)".into(),
        source,
    })?;
    scan_with(dataset, detector.as_ref(), cfg, cancel, progress)
}

/// [`scan`] with a detector the caller loaded (`mlod failures` loads it as `mlod detect` does:
/// its `--vote-iou`, `--ground-gate` and `--drop-trace`); `cfg.case` must be its case.
pub fn scan_with(
    dataset: &Dataset,
    detector: &dyn Detector,
    cfg: &ScanConfig,
    cancel: &AtomicBool,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Vec<SampleFailures>, ScanError> {
    if detector.case() != cfg.case {
        return Err(ScanError::BadParameter(format!(
            "the detector runs {}, the scan asks for {}",
            detector.case().paper_name(),
            cfg.case.paper_name()
        )));
    }
    check(cfg)?;
    let done = AtomicUsize::new(0);
    let total = cfg.tokens.len();
    let mut out: Vec<SampleFailures> = cfg
        .tokens
        .par_iter()
        .enumerate()
        .map(|(i, token)| {
            if cancel.load(Ordering::Relaxed) {
                return Err(ScanError::Cancelled);
            }
            let r = scan_sample(dataset, detector, cfg, i, token).map_err(|source| ScanError::Sample {
                token: token.clone(),
                source,
            });
            progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
            r
        })
        .collect::<Result<_, _>>()?;
    out.sort_by(|a, b| {
        let (ba, bb) = (a.badness(), b.badness());
        bb.0.cmp(&ba.0)
            .then(bb.1.total_cmp(&ba.1))
            .then(a.index.cmp(&b.index))
    });
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cases::ground_gate::GateChoice;
    use crate::detect::weights::default_models_dir;
    use crate::uncertainty::Perturbation;

    fn dataset() -> Dataset {
        Dataset::open(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data")).unwrap()
    }

    /// A scan with the shipped models and their decoding.
    fn shipped(
        ds: &Dataset,
        cfg: &ScanConfig,
        cancel: &AtomicBool,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<Vec<SampleFailures>, ScanError> {
        scan(
            ds,
            &default_models_dir(),
            GateChoice::Manifest,
            cfg,
            cancel,
            progress,
        )
    }

    fn config(ds: &Dataset, alpha: f64) -> ScanConfig {
        ScanConfig {
            case: Case::Input,
            params: FuseParams {
                perturbation: Perturbation::new(alpha, 0).unwrap(),
                ..Default::default()
            },
            tokens: ds.sample_tokens().iter().take(3).map(|t| t.to_string()).collect(),
            match_iou: 0.7,
            min_score: 0.3,
            set_intensity: None,
        }
    }

    #[test]
    fn at_alpha_zero_nothing_drops_and_the_counts_are_the_matching() {
        let ds = dataset();
        let cancel = AtomicBool::new(false);
        let r = shipped(&ds, &config(&ds, 0.0), &cancel, &|_, _| {}).unwrap();
        assert_eq!(r.len(), 3);
        for s in &r {
            assert_eq!(
                (s.missed, s.false_positives),
                (s.missed_at_zero, s.false_positives_at_zero)
            );
            assert_eq!(s.worst_drop, 0.0);
            assert!(s.boxes.iter().all(|b| b.kind != FailureKind::IouDrop));
            let kinds = |k| s.boxes.iter().filter(|b| b.kind == k).count();
            assert_eq!(
                (kinds(FailureKind::Missed), kinds(FailureKind::FalsePositive)),
                (s.missed, s.false_positives)
            );
        }
        // Worst first.
        assert!(r.windows(2).all(|w| w[0].badness().0 >= w[1].badness().0));
    }

    #[test]
    fn a_drift_makes_failures_the_same_on_any_thread_count_and_cancel_stops() {
        let ds = dataset();
        let cfg = config(&ds, 0.1);
        let cancel = AtomicBool::new(false);
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| shipped(&ds, &cfg, &cancel, &|_, _| {}).unwrap())
        };
        let one = run(1);
        assert_eq!(one, run(2));
        let missed: usize = one.iter().map(|s| s.missed).sum();
        let at_zero: usize = one.iter().map(|s| s.missed_at_zero).sum();
        assert!(missed > at_zero, "α = 0.1 misses more: {missed} vs {at_zero}");
        assert!(one.iter().any(|s| s.worst_drop > 0.0));
        cancel.store(true, Ordering::Relaxed);
        assert!(matches!(
            shipped(&ds, &cfg, &cancel, &|_, _| {}),
            Err(ScanError::Cancelled)
        ));
        let mut bad = cfg.clone();
        bad.match_iou = f64::NAN;
        assert!(shipped(&ds, &bad, &AtomicBool::new(false), &|_, _| {})
            .unwrap_err()
            .to_string()
            .contains("match IoU"));
    }
}
