//! The window's state below both the app and the panels: what has been loaded and computed
//! ([`Loaded`]), the window's own bits ([`Shell`]: toasts, recent datasets, help), the detection
//! on screen ([`DetectionView`]: stage 1's boxes and an MLOD case's refinements) and the
//! [`Action`]s a panel asks the app to carry out. Panels draw from these and edit the session;
//! only the app starts jobs and recomputes.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;

use eframe::egui;
use egui::{Color32, RichText};

use crate::analysis::inspect::{PointsInside, PredictionDetails};
use crate::dataset::{Dataset, DatasetFormat, Frame, LidarChannel, SampleSummary};
use crate::detect::{Case, Detection};
use crate::eval::{match_drawn, GtOutcome, MatchRule, PredOutcome};
use crate::geometry::{iou_3d, IouKind};
use crate::pipeline::FusedCloud;
use crate::refine::Refined;
use crate::render::{Camera, Projection, View};
use crate::session::{BoxLayer, CameraPose, DetectionSettings, FailureScope};

/// Ground-truth box colour (paper: green).
pub const GT_COLOR: [u8; 4] = [70, 230, 110, 255];
/// Stage-1 proposal colour (paper: blue); a true positive.
pub const PROPOSAL_COLOR: [u8; 4] = [70, 150, 255, 255];
/// A proposal that matches no ground truth (false positive): a greyed blue.
pub const FALSE_POSITIVE_COLOR: [u8; 4] = [150, 160, 200, 255];
/// An MLOD refined box (paper: red); a true positive.
pub const REFINED_COLOR: [u8; 4] = [235, 60, 60, 255];
/// A refined box that matches no ground truth: a greyed red.
pub const REFINED_FALSE_POSITIVE_COLOR: [u8; 4] = [200, 150, 150, 255];
/// The selected box, drawn over its layer's colour: amber, a colour no layer uses.
pub const SELECTED_COLOR: [u8; 4] = [255, 200, 40, 255];
/// The halo under the selected box's amber lines: a darker amber.
pub const SELECTED_HALO_COLOR: [u8; 4] = [170, 115, 10, 255];
/// The thin line from a proposal's centre to its refinement's: a dimmer red.
pub const LINK_COLOR: [u8; 4] = [150, 55, 55, 255];
/// The active points (§V-C) of the hovered or selected refined box: white, a colour no
/// colouring uses.
pub const ACTIVE_POINT_COLOR: [u8; 4] = [255, 255, 255, 255];

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
    /// Online calibration (ICP) of the sample on screen, in the background.
    Calibrate,
    /// Drop the calibration in flight.
    CancelCalibration,
    /// The match IoU or the min score changed: match the detection on screen again.
    Rematch,
    /// A layer was switched on or off: rebuild the box lines.
    RebuildLines,
    /// Clear the selected box (Escape).
    ClearSelection,
    /// Point the camera at the selected box (F).
    FocusSelection,
    /// Compare mode was switched on or off, or its case changed.
    CompareChanged,
    /// Start "play α" (to the given α), or stop it.
    TogglePlay(f64),
    /// Write "play α" of the current view as an animated GIF (in the background).
    ExportClip(PathBuf),
    /// Read a sweep folder and show its AP-against-α plot.
    OpenSweep(PathBuf),
    /// Run the detectors from another models folder (its manifest.json is checked first).
    OpenModels(PathBuf),
    /// The ground gate was switched on or off (the session holds which).
    GateChanged,
    /// Open (or close) the failure browser.
    ToggleFailures,
    /// Scan the session's case over the browser's scope at the session's perturbation.
    ScanFailures,
    /// Stop the scan in flight.
    CancelScan,
    /// Load a failure's sample and select and focus its box.
    GoToFailure(crate::analysis::failures::BoxFailure),
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
    /// "Play α" in progress.
    pub play: Option<Play>,
    /// The open sweep folder (the sweep window).
    pub sweep: Option<SweepView>,
    /// The failure browser, while open.
    pub failures: Option<FailureBrowser>,
    /// First sight: the window opened without a session shows the source-LiDAR colours at α = 0
    /// and switches to tr(Ξ) the first time α leaves 0, unless the user chose a colouring first.
    pub auto_color: bool,
    /// A desktop file dialog can open (else every file action asks with a path field).
    pub native_dialogs: bool,
    /// The path field standing in for a file dialog, while open.
    pub prompt: Option<PathPrompt>,
    /// The session file last saved or loaded (the window's title names it).
    pub session_file: Option<PathBuf>,
    /// The window title as last sent.
    pub title: String,
    /// Tab: the side panels hidden.
    pub hide_panels: bool,
    /// Where the controls panel was drawn last frame (none while hidden).
    pub controls_rect: Option<egui::Rect>,
    /// How many points the controls' open sections run past the panel's height (≤ 0: none).
    pub controls_overflow: f32,
}

/// What a file dialog is for: its title, file type and suggested name, and the action it ends in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FilePurpose {
    OpenDataset,
    OpenSweep,
    OpenModels,
    SaveSession,
    LoadSession,
    ExportPng,
    ExportCloud,
    ExportClip,
}

impl FilePurpose {
    pub fn title(self) -> &'static str {
        match self {
            FilePurpose::OpenDataset => "Open dataset (a folder)",
            FilePurpose::OpenSweep => "Open sweep results (a folder)",
            FilePurpose::OpenModels => "Open models folder (with manifest.json)",
            FilePurpose::SaveSession => "Save session",
            FilePurpose::LoadSession => "Load session",
            FilePurpose::ExportPng => "Export viewport PNG",
            FilePurpose::ExportCloud => "Export fused cloud (.ply or .pcd)",
            FilePurpose::ExportClip => "Export clip (GIF)",
        }
    }

    /// The file name offered (empty for folders).
    pub fn default_name(self) -> &'static str {
        match self {
            FilePurpose::OpenDataset | FilePurpose::OpenSweep | FilePurpose::OpenModels => "",
            FilePurpose::SaveSession | FilePurpose::LoadSession => "session.json",
            FilePurpose::ExportPng => "viewport.png",
            FilePurpose::ExportCloud => "fused.ply",
            FilePurpose::ExportClip => "clip.gif",
        }
    }

    /// Whether it writes a file (a save dialog), picks a folder, or reads a file.
    pub fn saves(self) -> bool {
        matches!(
            self,
            FilePurpose::SaveSession
                | FilePurpose::ExportPng
                | FilePurpose::ExportCloud
                | FilePurpose::ExportClip
        )
    }

    pub fn folder(self) -> bool {
        matches!(
            self,
            FilePurpose::OpenDataset | FilePurpose::OpenSweep | FilePurpose::OpenModels
        )
    }

    /// The extensions its filter offers.
    pub fn extensions(self) -> &'static [&'static str] {
        match self {
            FilePurpose::OpenDataset | FilePurpose::OpenSweep | FilePurpose::OpenModels => &[],
            FilePurpose::SaveSession | FilePurpose::LoadSession => &["json"],
            FilePurpose::ExportPng => &["png"],
            FilePurpose::ExportCloud => &["ply", "pcd"],
            FilePurpose::ExportClip => &["gif"],
        }
    }

    /// The action a chosen path ends in.
    pub fn action(self, path: PathBuf) -> Action {
        match self {
            FilePurpose::OpenDataset => Action::OpenDataset(path),
            FilePurpose::OpenSweep => Action::OpenSweep(path),
            FilePurpose::OpenModels => Action::OpenModels(path),
            FilePurpose::SaveSession => Action::SaveSession(path),
            FilePurpose::LoadSession => Action::LoadSession(path),
            FilePurpose::ExportPng => Action::ExportPng(path),
            FilePurpose::ExportCloud => Action::ExportCloud(path),
            FilePurpose::ExportClip => Action::ExportClip(path),
        }
    }
}

/// The path field shown where no desktop file dialog could open.
#[derive(Debug, Clone, PartialEq)]
pub struct PathPrompt {
    pub purpose: FilePurpose,
    pub text: String,
    /// Why it is shown (no dialog service, or the dialog did not open).
    pub why: String,
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

/// How the failure browser sorts its boxes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FailureSort {
    /// Samples worst first (misses + false positives, then the worst IoU drop).
    Sample,
    /// The largest IoU drop first.
    Drop,
    /// Misses, then false positives, then drops.
    Kind,
}

/// The failure browser: a scan of the session's case at the session's perturbation.
#[derive(Debug, Clone)]
pub struct FailureBrowser {
    pub scope: FailureScope,
    pub sort: FailureSort,
    /// The scan in flight: its id, samples done (shared with the worker), its total, and the
    /// flag that cancels it.
    pub running: Option<(
        u64,
        Arc<std::sync::atomic::AtomicUsize>,
        usize,
        Arc<std::sync::atomic::AtomicBool>,
    )>,
    /// The last finished scan: its case, α and seed, and the samples worst first.
    pub result: Option<(Case, f64, u64, Vec<crate::analysis::failures::SampleFailures>)>,
    /// Wall time of the last scan (ms).
    pub millis: f64,
    /// The case, α and seed of the scan in flight.
    pub scanning: Option<(Case, f64, u64)>,
    /// Show only the objects the perturbation lost (detected at α = 0, missed now).
    pub lost_only: bool,
}

impl Default for FailureBrowser {
    fn default() -> Self {
        Self {
            scope: FailureScope::Scene,
            sort: FailureSort::Sample,
            running: None,
            result: None,
            millis: 0.0,
            scanning: None,
            lost_only: false,
        }
    }
}

/// A sweep folder read for the sweep window.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepView {
    pub dir: PathBuf,
    pub progress: crate::analysis::sweep::SweepProgress,
}

/// "Play α": α steps from 0 to `alpha_to` in `frames` equal steps (the seed, hence the drift's
/// direction, fixed), one step each time the previous one is fused (and detected, with auto-run).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Play {
    pub alpha_to: f64,
    pub frames: usize,
    /// The next frame's index.
    pub next: usize,
}

impl Play {
    /// α of frame `k`.
    pub fn alpha(&self, k: usize) -> f64 {
        crate::gui::clip::step_alpha(self.alpha_to, self.frames, k)
    }
}

/// What the app has loaded and computed for the sample on screen.
#[derive(Default)]
pub struct Loaded {
    pub dataset: Option<Arc<Dataset>>,
    /// What differs between the dataset and the models' training data
    /// (`dataset::out_of_depth_notes`, over a few samples), shown under the menu.
    pub depth_notes: Vec<String>,
    pub samples: Vec<SampleSummary>,
    pub frame: Option<Arc<Frame>>,
    pub fused: Option<FusedCloud>,
    pub histogram: Vec<u32>,
    /// The histogram's range and scale (its x axis), and whether it shows tr(Ξ).
    pub histogram_axis: Option<((f32, f32), crate::color::Scale, bool)>,
    pub uncertain_fraction: f64,
    pub fuse_ms: f64,
    pub frame_ms: f64,
    /// Bumped on every re-fuse: a detection made at an older generation is stale.
    pub fuse_generation: u64,
    pub detection: Option<DetectionView>,
    /// A detector run is in flight.
    pub detecting: bool,
    /// Compare mode: the second case's last detection (the right half) and its run in flight.
    pub detection_b: Option<DetectionView>,
    pub detecting_b: bool,
    /// The selected box on screen (its layer and index: into the frame's boxes, the detection's
    /// proposals or its refinement), resolved from the session's selection.
    pub selected: Option<(BoxLayer, usize)>,
    /// What the details panel shows of it.
    pub selection_details: Option<SelectionDetails>,
    /// The id of the calibration in flight.
    pub calibrating: Option<u64>,
    /// Wall time of the last calibration (ms).
    pub calibrate_ms: f64,
    /// The models folder's ground gate (m; `mlod train tune-gate`), which its stage-1 cases
    /// run behind.
    pub ground_gate_m: Option<f32>,
    /// The models folder the detectors run from (named in the Detection panel).
    pub models: PathBuf,
    /// What its manifest says of an adaptation to real data (`mlod train adapt`), if any.
    pub models_adapted: Option<String>,
}

/// The details panel's content for the selected box.
#[derive(Debug, Clone, PartialEq)]
pub enum SelectionDetails {
    /// A proposal or a refined box.
    Prediction {
        layer: BoxLayer,
        index: usize,
        details: Box<PredictionDetails>,
    },
    /// A ground-truth box: its points and the box that detected it (IoU), if any.
    Truth {
        index: usize,
        annotation: String,
        category: String,
        inside: PointsInside,
        detected_iou: Option<f64>,
    },
}

impl Loaded {
    /// The selected refined box (index into the refinement on screen), if a refined box is
    /// selected.
    pub fn selected_refined(&self) -> Option<usize> {
        match self.selected {
            Some((BoxLayer::Refined, k)) => Some(k),
            _ => None,
        }
    }

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

/// The last detection run on the sample on screen, matched against its ground truth: stage 1's
/// boxes and, for an MLOD case, their refinements.
#[derive(Debug, Clone)]
pub struct DetectionView {
    pub case: Case,
    pub token: String,
    /// The fuse generation it was computed at; older than the app's: stale (α changed since).
    pub generation: u64,
    /// Stage 1's boxes (an MLOD case's proposals), highest score first.
    pub detections: Vec<Detection>,
    /// Per detection: TP (with its GT and IoU), FP or ignored, at the session's match IoU.
    pub outcomes: Vec<PredOutcome>,
    /// Per ground-truth box of the frame: matched or missed by stage 1; ignored when the detector
    /// does not output its category.
    pub gt_outcomes: Vec<GtOutcome>,
    /// An MLOD case's refined boxes, matched on their own.
    pub refinement: Option<Refinement>,
    /// The categories the detector outputs.
    pub categories: Vec<String>,
    pub millis: f64,
}

/// The refined boxes of an MLOD run, matched against the ground truth like stage 1's.
#[derive(Debug, Clone)]
pub struct Refinement {
    /// Highest score first; each links to its proposal in [`DetectionView::detections`].
    pub refined: Vec<Refined>,
    pub outcomes: Vec<PredOutcome>,
    pub gt_outcomes: Vec<GtOutcome>,
    /// Per refined box: the best 3D IoU of its proposal with a ground-truth box of its category
    /// (before refinement) and of the refined box (after).
    pub iou_before: Vec<f64>,
    pub iou_after: Vec<f64>,
}

/// Counts shown in the Detection panel (drawn boxes only, i.e. score ≥ min score).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DetectionCounts {
    pub shown: usize,
    pub true_positives: usize,
    pub false_positives: usize,
    /// Ground-truth boxes of the detector's categories, and how many of them no drawn box
    /// matched.
    pub ground_truth: usize,
    pub missed: usize,
}

impl DetectionCounts {
    /// Drawn boxes neither true nor false positives: outside the frame's evaluation region
    /// (KITTI: camera 2's view, DontCare regions).
    pub fn unscored(&self) -> usize {
        self.shown
            .saturating_sub(self.true_positives + self.false_positives)
    }
}

/// A detector's output before it is matched: what a run returns.
pub struct RawDetection {
    pub case: Case,
    pub token: String,
    pub generation: u64,
    pub detections: Vec<Detection>,
    /// An MLOD case's refinements of `detections`.
    pub refined: Option<Vec<Refined>>,
    pub categories: Vec<String>,
    pub millis: f64,
}

impl DetectionView {
    /// Matches a run's boxes (stage 1's, and the refined ones on their own) against the frame's
    /// ground truth at the settings' operating point: only the drawn boxes (score ≥ min score)
    /// take part; ground truth of classes the detector does not output is matched by nothing and
    /// ignored.
    pub fn matched(raw: RawDetection, frame: Option<&Frame>, settings: &DetectionSettings) -> Self {
        let gts: Vec<Detection> = frame
            .map(|f| f.boxes.iter().map(|b| b.as_detection()).collect())
            .unwrap_or_default();
        let region = frame.and_then(|f| f.eval_region.as_ref());
        let (outcomes, gt_outcomes) = match_layer(&raw.detections, &gts, &raw.categories, settings, region);
        let refinement = raw.refined.map(|refined| {
            let dets: Vec<Detection> = refined.iter().map(|r| r.detection.clone()).collect();
            let (outcomes, gt_outcomes) = match_layer(&dets, &gts, &raw.categories, settings, region);
            let best = |d: &Detection| {
                gts.iter()
                    .filter(|g| g.category == d.category)
                    .map(|g| iou_3d(&d.box3d, &g.box3d))
                    .fold(0.0, f64::max)
            };
            Refinement {
                iou_before: refined
                    .iter()
                    .map(|r| raw.detections.get(r.proposal).map_or(0.0, best))
                    .collect(),
                iou_after: dets.iter().map(best).collect(),
                refined,
                outcomes,
                gt_outcomes,
            }
        });
        Self {
            case: raw.case,
            token: raw.token,
            generation: raw.generation,
            detections: raw.detections,
            outcomes,
            gt_outcomes,
            refinement,
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
            refined: self.refinement.map(|r| r.refined),
            categories: self.categories,
            millis: self.millis,
        };
        Self::matched(raw, frame, settings)
    }

    /// The counts of the Detection panel: of the refined boxes for an MLOD case, else of stage 1's.
    pub fn counts(&self, min_score: f32) -> DetectionCounts {
        match &self.refinement {
            Some(r) => {
                let scores = r.refined.iter().map(|x| x.detection.score);
                count_layer(scores, &r.outcomes, &r.gt_outcomes, min_score)
            }
            None => self.proposal_counts(min_score),
        }
    }

    /// The counts of stage 1's boxes (an MLOD case's proposals).
    pub fn proposal_counts(&self, min_score: f32) -> DetectionCounts {
        let scores = self.detections.iter().map(|x| x.score);
        count_layer(scores, &self.outcomes, &self.gt_outcomes, min_score)
    }

    /// Per ground-truth box: matched or missed by the final boxes (the refined ones for MLOD).
    pub fn final_gt_outcomes(&self) -> &[GtOutcome] {
        match &self.refinement {
            Some(r) => &r.gt_outcomes,
            None => &self.gt_outcomes,
        }
    }
}

/// Matches the drawn boxes of one layer (score ≥ min score) against the ground truth of the
/// detector's categories; outcomes indexed by `detections` and by `gts`.
fn match_layer(
    detections: &[Detection],
    gts: &[Detection],
    categories: &[String],
    settings: &DetectionSettings,
    region: Option<&crate::dataset::EvalRegion>,
) -> (Vec<PredOutcome>, Vec<GtOutcome>) {
    let rule = MatchRule {
        iou_threshold: settings.match_iou,
        kind: IouKind::ThreeD,
        max_range: f64::INFINITY,
    };
    let m = match_drawn(detections, gts, &rule, settings.min_score, region, |g| {
        categories.contains(&g.category)
    });
    (m.preds, m.gts)
}

fn count_layer(
    scores: impl Iterator<Item = f32>,
    outcomes: &[PredOutcome],
    gt_outcomes: &[GtOutcome],
    min_score: f32,
) -> DetectionCounts {
    let mut c = DetectionCounts {
        shown: scores.filter(|&s| s >= min_score).count(),
        ..Default::default()
    };
    for o in outcomes {
        match o {
            PredOutcome::TruePositive { .. } => c.true_positives += 1,
            PredOutcome::FalsePositive { .. } => c.false_positives += 1,
            PredOutcome::Ignored => {}
        }
    }
    c.missed = gt_outcomes
        .iter()
        .filter(|g| matches!(g, GtOutcome::Missed))
        .count();
    c.ground_truth = gt_outcomes
        .iter()
        .filter(|g| !matches!(g, GtOutcome::Ignored))
        .count();
    c
}

/// Points per LiDAR of a fused cloud.
pub fn channel_counts(cloud: &FusedCloud) -> BTreeMap<LidarChannel, usize> {
    cloud.lidars.iter().map(|l| (l.channel, l.range.len())).collect()
}

/// A LiDAR's name: the rig's own for a format that names its LiDARs (Argoverse 2's `up_lidar`,
/// `down_lidar`), else the paper's (LiDAR-Top, …).
pub fn lidar_name(format: Option<DatasetFormat>, ch: LidarChannel) -> &'static str {
    match format {
        Some(f) if f.rig().is_some() => f.lidar_name(ch),
        _ => ch.paper_name(),
    }
}

/// A LiDAR's name in its paper colour.
pub fn lidar_label(format: Option<DatasetFormat>, ch: LidarChannel) -> RichText {
    let [r, g, b, _] = crate::color::LIDAR_COLORS[ch as usize];
    RichText::new(lidar_name(format, ch)).color(Color32::from_rgb(r, g, b))
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
