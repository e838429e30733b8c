//! The window's state below both the app and the panels: what has been loaded and computed
//! ([`Loaded`]), the window's own bits ([`Shell`]: toasts, recent datasets, help), the stage-1
//! detection on screen ([`DetectionView`]) and the [`Action`]s a panel asks the app to carry
//! out. Panels draw from these and edit the session; only the app starts jobs and recomputes.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;

use eframe::egui;
use egui::{Color32, RichText};

use super::viewport::{Camera, Projection, View};
use crate::detect::{Case, Detection};
use crate::eval::{match_sample, GtOutcome, MatchRule, PredOutcome};
use crate::geometry::IouKind;
use crate::lyft::{Dataset, Frame, LidarChannel, SampleSummary};
use crate::pipeline::FusedCloud;
use crate::session::{CameraPose, DetectionSettings};

/// Ground-truth box colour (paper: green).
pub const GT_COLOR: [u8; 4] = [70, 230, 110, 255];
/// Stage-1 proposal colour (paper: blue); a true positive.
pub const PROPOSAL_COLOR: [u8; 4] = [70, 150, 255, 255];
/// A proposal that matches no ground truth (false positive): a greyed blue.
pub const FALSE_POSITIVE_COLOR: [u8; 4] = [150, 160, 200, 255];

/// What a panel asks the app to do (the panels cannot start jobs or recompute themselves).
#[derive(Debug, Clone, PartialEq)]
pub enum Action {
    OpenDataset(PathBuf),
    SelectSample(String),
    SaveSession(PathBuf),
    LoadSession(PathBuf),
    ExportPng(PathBuf),
    ExportCloud(PathBuf),
    SetPreset(View),
    /// Step through the samples in scene order (−1: previous, +1: next).
    StepSample(i64),
    /// The perturbation or the visible LiDARs changed: re-fuse and recolour.
    Refuse,
    /// The colouring changed: recolour without moving points.
    Recolor,
    RunDetector,
    /// The match IoU or the min score changed: match the detection on screen again.
    Rematch,
    /// A layer was switched on or off: rebuild the box lines.
    RebuildLines,
}

/// A message shown at the bottom right for a few seconds.
pub struct Toast {
    pub text: String,
    pub error: bool,
    pub until: f64,
}

/// The window's own state, apart from the session and the data.
#[derive(Default)]
pub struct Shell {
    pub toasts: Vec<Toast>,
    /// Most recent first, at most 8.
    pub recent: Vec<PathBuf>,
    pub show_help: bool,
    /// Wall-clock timings in the UI (off for deterministic snapshots).
    pub show_timings: bool,
}

impl Shell {
    /// Shows a message: errors for 8 s, others for 3 s.
    pub fn toast(&mut self, now: f64, text: impl Into<String>, error: bool) {
        self.toasts.push(Toast {
            text: text.into(),
            error,
            until: now + if error { 8.0 } else { 3.0 },
        });
    }

    /// Puts a dataset first in the recent list.
    pub fn remember(&mut self, path: &PathBuf) {
        self.recent.retain(|p| p != path);
        self.recent.insert(0, path.clone());
        self.recent.truncate(8);
    }
}

/// What the app has loaded and computed for the sample on screen.
#[derive(Default)]
pub struct Loaded {
    pub dataset: Option<Arc<Dataset>>,
    pub samples: Vec<SampleSummary>,
    pub frame: Option<Arc<Frame>>,
    pub fused: Option<FusedCloud>,
    pub histogram: Vec<u32>,
    pub uncertain_fraction: f64,
    pub fuse_ms: f64,
    pub frame_ms: f64,
    /// Bumped on every re-fuse: a detection made at an older generation is stale.
    pub fuse_generation: u64,
    pub detection: Option<DetectionView>,
    /// A detector run is in flight.
    pub detecting: bool,
}

impl Loaded {
    /// Whether the detection on screen was made before the last change of perturbation or with
    /// another case than `case`.
    pub fn detection_is_stale(&self, case: Case) -> bool {
        self.detection
            .as_ref()
            .is_some_and(|d| d.generation != self.fuse_generation || d.case != case)
    }

    /// The detection on screen and its counts (drawn proposals: score ≥ `min_score`).
    pub fn detection(&self, min_score: f32) -> Option<(&DetectionView, DetectionCounts)> {
        let d = self.detection.as_ref()?;
        Some((d, d.counts(min_score)))
    }
}

/// The last stage-1 detection run on the sample on screen, matched against its ground truth.
#[derive(Debug, Clone)]
pub struct DetectionView {
    pub case: Case,
    pub token: String,
    /// The fuse generation it was computed at; older than the app's: stale (α changed since).
    pub generation: u64,
    /// Highest score first.
    pub detections: Vec<Detection>,
    /// Per detection: TP (with its GT and IoU), FP or ignored, at the session's match IoU.
    pub outcomes: Vec<PredOutcome>,
    /// Per ground-truth box of the frame: matched or missed; ignored when the detector does not
    /// output its category.
    pub gt_outcomes: Vec<GtOutcome>,
    /// The categories the detector outputs.
    pub categories: Vec<String>,
    pub millis: f64,
}

/// Counts shown in the Detection panel (drawn proposals only, i.e. score ≥ min score).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DetectionCounts {
    pub shown: usize,
    pub true_positives: usize,
    pub false_positives: usize,
    /// Ground-truth boxes of the detector's categories, and how many of them no drawn proposal
    /// matched.
    pub ground_truth: usize,
    pub missed: usize,
}

/// A detector's output before it is matched: what a run returns.
pub struct RawDetection {
    pub case: Case,
    pub token: String,
    pub generation: u64,
    pub detections: Vec<Detection>,
    pub categories: Vec<String>,
    pub millis: f64,
}

impl DetectionView {
    /// Matches a run's detections against the frame's ground truth at the settings' operating
    /// point: only the drawn proposals (score ≥ min score) take part; ground truth of classes
    /// the detector does not output is matched by nothing and ignored.
    pub fn matched(raw: RawDetection, frame: Option<&Frame>, settings: &DetectionSettings) -> Self {
        let gts: Vec<Detection> = frame
            .map(|f| f.boxes.iter().map(|b| b.as_detection()).collect())
            .unwrap_or_default();
        let rule = MatchRule {
            iou_threshold: settings.match_iou,
            kind: IouKind::ThreeD,
            max_range: f64::INFINITY,
        };
        let detections = raw.detections;
        let kept: Vec<usize> = (0..detections.len())
            .filter(|&i| detections[i].score >= settings.min_score)
            .collect();
        let shown: Vec<Detection> = kept.iter().map(|&i| detections[i].clone()).collect();
        let known: Vec<usize> = (0..gts.len())
            .filter(|&j| raw.categories.contains(&gts[j].category))
            .collect();
        let known_gts: Vec<Detection> = known.iter().map(|&j| gts[j].clone()).collect();
        let m = match_sample(&shown, &known_gts, &rule);
        let mut outcomes = vec![PredOutcome::Ignored; detections.len()];
        for (k, o) in kept.iter().zip(m.preds) {
            outcomes[*k] = o;
        }
        // Back to the frame's ground-truth indices and the run's detection indices.
        let mut gt_outcomes = vec![GtOutcome::Ignored; gts.len()];
        for (&j, g) in known.iter().zip(m.gts) {
            gt_outcomes[j] = match g {
                GtOutcome::Matched { pred, iou } => GtOutcome::Matched {
                    pred: kept[pred],
                    iou,
                },
                other => other,
            };
        }
        Self {
            case: raw.case,
            token: raw.token,
            generation: raw.generation,
            detections,
            outcomes,
            gt_outcomes,
            categories: raw.categories,
            millis: raw.millis,
        }
    }

    /// The same run matched again under other settings.
    pub fn rematched(self, frame: Option<&Frame>, settings: &DetectionSettings) -> Self {
        let raw = RawDetection {
            case: self.case,
            token: self.token,
            generation: self.generation,
            detections: self.detections,
            categories: self.categories,
            millis: self.millis,
        };
        Self::matched(raw, frame, settings)
    }

    /// The counts of the Detection panel.
    pub fn counts(&self, min_score: f32) -> DetectionCounts {
        let mut c = DetectionCounts {
            shown: self.detections.iter().filter(|x| x.score >= min_score).count(),
            ..Default::default()
        };
        for o in &self.outcomes {
            match o {
                PredOutcome::TruePositive { .. } => c.true_positives += 1,
                PredOutcome::FalsePositive { .. } => c.false_positives += 1,
                PredOutcome::Ignored => {}
            }
        }
        c.missed = self
            .gt_outcomes
            .iter()
            .filter(|g| matches!(g, GtOutcome::Missed))
            .count();
        c.ground_truth = self
            .gt_outcomes
            .iter()
            .filter(|g| !matches!(g, GtOutcome::Ignored))
            .count();
        c
    }
}

/// Points per LiDAR of a fused cloud.
pub fn channel_counts(cloud: &FusedCloud) -> BTreeMap<LidarChannel, usize> {
    cloud.lidars.iter().map(|l| (l.channel, l.range.len())).collect()
}

/// A LiDAR's name in its paper colour.
pub fn lidar_label(ch: LidarChannel) -> RichText {
    let [r, g, b, _] = crate::color::LIDAR_COLORS[ch as usize];
    RichText::new(ch.paper_name()).color(Color32::from_rgb(r, g, b))
}

/// An sRGB(A) colour of the palette as egui's.
pub fn color32(c: [u8; 4]) -> Color32 {
    Color32::from_rgba_unmultiplied(c[0], c[1], c[2], c[3])
}

/// The camera a session stored.
pub fn camera_from_pose(c: &CameraPose) -> Camera {
    Camera {
        target: c.target,
        yaw: c.yaw,
        pitch: c.pitch,
        distance: c.distance,
        fov_y: c.fov_y,
        projection: if c.bev {
            Projection::BirdsEye
        } else {
            Projection::Perspective
        },
    }
}

/// The camera as a session stores it.
pub fn pose_from_camera(c: &Camera) -> CameraPose {
    CameraPose {
        target: c.target,
        yaw: c.yaw,
        pitch: c.pitch,
        distance: c.distance,
        fov_y: c.fov_y,
        bev: c.projection == Projection::BirdsEye,
    }
}
