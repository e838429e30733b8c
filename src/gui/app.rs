//! The debugger window: state, layout and the glue between the panels, the library pipeline and
//! the viewport. All numbers come from the library (`pipeline::fuse`, `color`, `box_stats`); this
//! file only holds state, lays out widgets and hands data to the renderer.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use eframe::egui;
use egui::{Color32, RichText};

use super::jobs::{DetectRequest, JobResult, Jobs};
use super::panels;
use super::viewport::{self, box_lines, grid_lines, Camera, Projection, SceneHandle, View, Viewport};
use crate::color::{auto_range, colorize, histogram, scalars, ColorMode, Scale};
use crate::detect::weights::default_models_dir;
use crate::detect::{Case, Detection, Detector};
use crate::eval::{match_sample, GtOutcome, MatchRule, PredOutcome};
use crate::geometry::IouKind;
use crate::lyft::{Dataset, Frame, LidarChannel, SampleSummary};
use crate::pipeline::{box_stats, fuse, BoxStats, FusedCloud};
use crate::session::{CameraPose, Session};
use crate::uncertainty::UNCERTAIN_TRACE;

/// How the app starts.
#[derive(Debug, Clone)]
pub struct AppOptions {
    pub dataset: PathBuf,
    pub session: Option<Session>,
    /// Run loading jobs inline and leave wall-clock timings out of the UI (tests, snapshots and
    /// headless screenshots need deterministic pixels).
    pub synchronous: bool,
    /// Measure the window: repaint continuously for this many frames, print the frame times to
    /// stderr and close (`mlod gui --measure-frames N`).
    pub measure_frames: Option<usize>,
    /// Folder of the stage-1 weights and their manifest (default: `$MLOD_MODELS`, else the
    /// crate's `assets/models`).
    pub models: Option<PathBuf>,
}

/// A message shown at the bottom right for a few seconds.
pub struct Toast {
    pub text: String,
    pub error: bool,
    pub until: f64,
}

/// Ground-truth box colour (paper: green).
pub const GT_COLOR: [u8; 4] = [70, 230, 110, 255];
/// Stage-1 proposal colour (paper: blue); a true positive.
pub const PROPOSAL_COLOR: [u8; 4] = [70, 150, 255, 255];
/// A proposal that matches no ground truth (false positive): a greyed blue.
pub const FALSE_POSITIVE_COLOR: [u8; 4] = [150, 160, 200, 255];

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
const HISTOGRAM_BINS: usize = 64;
const RECENT_KEY: &str = "mlod_recent_datasets";

/// The application.
pub struct MlodApp {
    pub(crate) session: Session,
    pub(crate) view: Viewport,
    pub(crate) scene: SceneHandle,
    jobs: Jobs,
    pub(crate) dataset: Option<Arc<Dataset>>,
    pub(crate) samples: Vec<SampleSummary>,
    pub(crate) frame: Option<Arc<Frame>>,
    pub(crate) fused: Option<FusedCloud>,
    /// Fused-cloud index of each point handed to the scene (hidden LiDARs are left out).
    scene_index: Vec<u32>,
    pub(crate) histogram: Vec<u32>,
    pub(crate) uncertain_fraction: f64,
    pub(crate) fuse_ms: f64,
    pub(crate) frame_ms: f64,
    wanted_token: Option<String>,
    loading_dataset: Option<PathBuf>,
    /// Heading of the ego car's +x in the base frame (LIDAR_TOP is mounted turned ~180°).
    ego_heading: f32,
    camera_from_session: bool,
    pub(crate) toasts: Vec<Toast>,
    pub(crate) recent: Vec<PathBuf>,
    pub(crate) show_help: bool,
    needs_fuse: bool,
    needs_color: bool,
    pub(crate) hovered_box: Option<(usize, BoxStats)>,
    pub(crate) show_timings: bool,
    measure: Option<(usize, Vec<Instant>)>,
    viewport_rect: egui::Rect,
    /// Bumped on every re-fuse: a detection made at an older generation is stale.
    fuse_generation: u64,
    detectors: BTreeMap<Case, Arc<dyn Detector>>,
    pub(crate) detection: Option<DetectionView>,
    detect_in_flight: bool,
    detect_again: bool,
    pub(crate) hovered_detection: Option<usize>,
    models_dir: PathBuf,
}

impl MlodApp {
    /// Creates the app, installs the viewport's GPU resources and starts loading the dataset.
    pub fn new(cc: &eframe::CreationContext<'_>, options: AppOptions) -> Self {
        if let Some(rs) = cc.wgpu_render_state.as_ref() {
            viewport::install(rs);
        }
        let recent = cc
            .storage
            .and_then(|s| eframe::get_value::<Vec<PathBuf>>(s, RECENT_KEY))
            .unwrap_or_default();
        let mut app = Self::headless(options, Some(cc.egui_ctx.clone()));
        app.recent = recent;
        app
    }

    /// The app without a window (state and data only); the screenshot command uses this.
    pub fn headless(options: AppOptions, ctx: Option<egui::Context>) -> Self {
        let session = options
            .session
            .unwrap_or_else(|| Session::new(options.dataset.clone()));
        let camera_from_session = session.camera.is_some();
        let mut view = Viewport::default();
        view.settings.point_size = session.point_size;
        if let Some(c) = session.camera {
            view.camera = camera_from_pose(&c);
        }
        let mut app = Self {
            view,
            scene: SceneHandle::new(),
            jobs: Jobs::new(ctx, options.synchronous),
            dataset: None,
            samples: Vec::new(),
            frame: None,
            fused: None,
            scene_index: Vec::new(),
            histogram: Vec::new(),
            uncertain_fraction: 0.0,
            fuse_ms: 0.0,
            frame_ms: 0.0,
            wanted_token: session.sample_token.clone(),
            loading_dataset: None,
            ego_heading: 0.0,
            camera_from_session,
            toasts: Vec::new(),
            recent: Vec::new(),
            show_help: false,
            needs_fuse: false,
            needs_color: false,
            hovered_box: None,
            show_timings: !options.synchronous,
            viewport_rect: egui::Rect::NOTHING,
            measure: options.measure_frames.map(|n| (n, Vec::with_capacity(n + 1))),
            fuse_generation: 0,
            detectors: BTreeMap::new(),
            detection: None,
            detect_in_flight: false,
            detect_again: false,
            hovered_detection: None,
            models_dir: options
                .models
                .clone()
                .or_else(|| std::env::var_os("MLOD_MODELS").map(PathBuf::from))
                .unwrap_or_else(default_models_dir),
            session,
        };
        let path = app.session.dataset.clone();
        app.open_dataset(path);
        app.process_jobs(0.0);
        app
    }

    /// Starts opening a dataset; the current one stays until the new one has loaded.
    pub fn open_dataset(&mut self, path: PathBuf) {
        self.loading_dataset = Some(path.clone());
        self.jobs.open_dataset(path);
    }

    /// Asks for a sample; the current frame stays until it has loaded.
    pub fn select_sample(&mut self, token: &str) {
        let Some(ds) = self.dataset.clone() else { return };
        self.wanted_token = Some(token.to_string());
        self.jobs.load_frame(ds, token.to_string());
    }

    /// Steps through the samples in scene order.
    pub fn step_sample(&mut self, delta: i64) {
        let Some(current) = self.frame.as_ref().map(|f| f.sample_token.clone()) else {
            return;
        };
        let Some(i) = self.samples.iter().position(|s| s.sample_token == current) else {
            return;
        };
        let j = (i as i64 + delta).clamp(0, self.samples.len() as i64 - 1) as usize;
        if j != i {
            let token = self.samples[j].sample_token.clone();
            self.select_sample(&token);
        }
    }

    pub(crate) fn toast(&mut self, now: f64, text: impl Into<String>, error: bool) {
        let text = text.into();
        self.toasts.push(Toast {
            text,
            error,
            until: now + if error { 8.0 } else { 3.0 },
        });
    }

    /// Applies finished jobs. Errors keep the last good state and become toasts.
    pub fn process_jobs(&mut self, now: f64) {
        // A finished job may start another (dataset -> its first frame): drain until quiet.
        // (In synchronous mode a re-fuse may itself finish a job: a detector run.)
        loop {
            let results = self.jobs.poll();
            if !results.is_empty() {
                self.apply_results(results, now);
                continue;
            }
            if self.needs_fuse {
                self.refuse(now);
                continue;
            }
            break;
        }
        if self.needs_color {
            self.recolor();
        }
        if !self.camera_from_session && self.fused.is_some() {
            self.set_preset(View::Overview);
            self.camera_from_session = true;
        }
    }

    fn apply_results(&mut self, results: Vec<JobResult>, now: f64) {
        for result in results {
            match result {
                JobResult::Dataset { path, result } => {
                    if self.loading_dataset.as_ref() != Some(&path) {
                        continue;
                    }
                    self.loading_dataset = None;
                    match result {
                        Ok((ds, samples)) => {
                            let keep = self
                                .wanted_token
                                .clone()
                                .filter(|t| samples.iter().any(|s| &s.sample_token == t));
                            let first = keep.or_else(|| samples.first().map(|s| s.sample_token.clone()));
                            self.dataset = Some(ds);
                            self.samples = samples;
                            self.session.dataset = path.clone();
                            self.recent.retain(|p| p != &path);
                            self.recent.insert(0, path.clone());
                            self.recent.truncate(8);
                            match first {
                                Some(token) => self.select_sample(&token),
                                None => self.toast(now, format!("{} has no samples", path.display()), true),
                            }
                        }
                        Err(e) => self.toast(now, format!("cannot open dataset: {e}"), true),
                    }
                }
                JobResult::Frame {
                    token,
                    result,
                    millis,
                } => {
                    if self.wanted_token.as_deref() != Some(token.as_str()) {
                        continue;
                    }
                    match result {
                        Ok(frame) => {
                            for w in &frame.warnings {
                                self.toasts.push(Toast {
                                    text: w.clone(),
                                    error: false,
                                    until: now + 5.0,
                                });
                            }
                            self.ego_heading = ego_heading(&frame);
                            if self.detection.as_ref().is_some_and(|d| d.token != token) {
                                self.detection = None;
                            }
                            self.session.sample_token = Some(token);
                            self.frame = Some(frame);
                            self.frame_ms = millis;
                            self.needs_fuse = true;
                        }
                        Err(e) => self.toast(now, format!("cannot load sample {token}: {e}"), true),
                    }
                }
                JobResult::Detect {
                    token,
                    generation,
                    case,
                    result,
                    millis,
                } => {
                    self.detect_in_flight = false;
                    match result {
                        Ok(out) => {
                            let on_screen = self.frame.as_ref().is_some_and(|f| f.sample_token == token);
                            if on_screen {
                                let categories = out.detector.categories();
                                self.detection = Some(self.match_detections(
                                    case,
                                    token,
                                    generation,
                                    out.detections,
                                    categories,
                                    millis,
                                ));
                                self.rebuild_lines();
                            }
                            self.detectors.insert(case, out.detector);
                        }
                        Err(e) => {
                            self.detect_again = false;
                            self.toast(now, format!("cannot run {}: {e}", case.paper_name()), true);
                        }
                    }
                    if std::mem::take(&mut self.detect_again) {
                        self.run_detector();
                    }
                }
            }
        }
    }

    /// Runs the session's stage-1 detector on the sample on screen, in the background. A request
    /// while one is running is remembered and run once that one is back (latest state wins).
    pub fn run_detector(&mut self) {
        let Some(frame) = self.frame.clone() else { return };
        if self.detect_in_flight {
            self.detect_again = true;
            return;
        }
        let case = self.session.detection.case;
        self.detect_in_flight = true;
        self.jobs.detect(DetectRequest {
            frame,
            params: self.session.fuse.clone(),
            generation: self.fuse_generation,
            case,
            cached: self.detectors.get(&case).cloned(),
            models: self.models_dir.clone(),
        });
    }

    /// Whether a detector run is in flight.
    pub fn is_detecting(&self) -> bool {
        self.detect_in_flight
    }

    /// Whether the detection on screen was made before the last change of perturbation.
    pub fn detection_is_stale(&self) -> bool {
        self.detection
            .as_ref()
            .is_some_and(|d| d.generation != self.fuse_generation || d.case != self.session.detection.case)
    }

    fn match_detections(
        &self,
        case: Case,
        token: String,
        generation: u64,
        detections: Vec<Detection>,
        categories: Vec<String>,
        millis: f64,
    ) -> DetectionView {
        let gts: Vec<Detection> = self
            .frame
            .as_ref()
            .map(|f| f.boxes.iter().map(|b| b.as_detection()).collect())
            .unwrap_or_default();
        let rule = MatchRule {
            iou_threshold: self.session.detection.match_iou,
            kind: IouKind::ThreeD,
            max_range: f64::INFINITY,
        };
        // Match the operating point on screen: only the drawn proposals (score ≥ min score).
        let min = self.session.detection.min_score;
        let kept: Vec<usize> = (0..detections.len())
            .filter(|&i| detections[i].score >= min)
            .collect();
        let shown: Vec<Detection> = kept.iter().map(|&i| detections[i].clone()).collect();
        // Ground truth of classes the detector does not output is matched by nothing and ignored.
        let known: Vec<usize> = (0..gts.len())
            .filter(|&j| categories.contains(&gts[j].category))
            .collect();
        let known_gts: Vec<Detection> = known.iter().map(|&j| gts[j].clone()).collect();
        let m = match_sample(&shown, &known_gts, &rule);
        let mut outcomes = vec![PredOutcome::Ignored; detections.len()];
        for (k, o) in kept.iter().zip(m.preds) {
            outcomes[*k] = o;
        }
        let gt_outcomes = m
            .gts
            .into_iter()
            .map(|g| match g {
                GtOutcome::Matched { pred, iou } => GtOutcome::Matched {
                    pred: kept[pred],
                    iou,
                },
                other => other,
            })
            .collect();
        DetectionView {
            case,
            token,
            generation,
            detections,
            outcomes,
            gt_outcomes,
            categories,
            millis,
        }
    }

    /// Re-matches the detection on screen (after the match IoU or the min score changed).
    pub fn rematch(&mut self) {
        if let Some(d) = self.detection.take() {
            self.detection = Some(self.match_detections(
                d.case,
                d.token,
                d.generation,
                d.detections,
                d.categories,
                d.millis,
            ));
        }
        self.rebuild_lines();
    }

    /// The detection on screen and its counts (drawn proposals: score ≥ the session's min score).
    pub fn detection(&self) -> Option<(&DetectionView, DetectionCounts)> {
        let d = self.detection.as_ref()?;
        let min = self.session.detection.min_score;
        let mut c = DetectionCounts {
            shown: d.detections.iter().filter(|x| x.score >= min).count(),
            ..Default::default()
        };
        for o in &d.outcomes {
            match o {
                PredOutcome::TruePositive { .. } => c.true_positives += 1,
                PredOutcome::FalsePositive { .. } => c.false_positives += 1,
                PredOutcome::Ignored => {}
            }
        }
        c.missed = d
            .gt_outcomes
            .iter()
            .filter(|g| matches!(g, GtOutcome::Missed))
            .count();
        c.ground_truth = d
            .gt_outcomes
            .iter()
            .filter(|g| !matches!(g, GtOutcome::Ignored))
            .count();
        Some((d, c))
    }

    /// A preset view, turned so that the ego car's front is "forward" in it.
    pub fn set_preset(&mut self, v: View) {
        let radius = self.scene.radius().clamp(30.0, 80.0);
        let mut cam = Camera::preset(v, radius);
        // Presets are defined for a car facing +x; turn them (target included) to the ego heading.
        let (sn, cs) = self.ego_heading.sin_cos();
        let [x, y, z] = cam.target;
        cam.target = [cs * x - sn * y, sn * x + cs * y, z];
        cam.yaw += self.ego_heading;
        self.view.camera = cam;
    }

    /// Looks at `target` from `distance` metres (keeps the direction of view).
    pub fn focus_camera(&mut self, target: [f32; 3], distance: f32) {
        self.view.camera.focus_on(target);
        if distance.is_finite() && distance > 0.0 {
            self.view.camera.distance = distance;
        }
    }

    /// Re-fuse (and re-colour) on the next frame: call after editing the session's perturbation.
    pub fn mark_fuse(&mut self) {
        self.needs_fuse = true;
    }

    pub(crate) fn mark_color(&mut self) {
        self.needs_color = true;
    }

    /// Re-fuses the frame with the current perturbation and recolours (the α-slider path).
    fn refuse(&mut self, now: f64) {
        self.needs_fuse = false;
        let Some(frame) = self.frame.clone() else { return };
        let start = Instant::now();
        match fuse(&frame, &self.session.fuse) {
            Ok(cloud) => {
                self.session.sampled = cloud
                    .lidars
                    .iter()
                    .filter(|l| l.channel != LidarChannel::Top)
                    .map(|l| (l.channel, l.noise))
                    .collect();
                self.fused = Some(cloud);
                self.fuse_generation += 1;
                self.rebuild_scene();
                if self.session.detection.auto_run {
                    self.run_detector();
                }
                self.fuse_ms = start.elapsed().as_secs_f64() * 1e3;
            }
            Err(e) => self.toast(now, format!("cannot fuse: {e}"), true),
        }
    }

    fn visible(&self, ch: LidarChannel) -> bool {
        self.session.visible.get(&ch).copied().unwrap_or(true)
    }

    /// Hands positions, colours and lines of the visible LiDARs to the renderer.
    fn rebuild_scene(&mut self) {
        self.needs_color = false;
        let Some(cloud) = &self.fused else { return };
        let mut index = Vec::with_capacity(cloud.len());
        for l in &cloud.lidars {
            if self.visible(l.channel) {
                index.extend(l.range.start as u32..l.range.end as u32);
            }
        }
        let positions: Vec<[f32; 3]> = index
            .iter()
            .map(|&i| {
                let i = i as usize;
                [cloud.x[i], cloud.y[i], cloud.z[i]]
            })
            .collect();
        self.scene_index = index;
        let colors = self.colors();
        if let Err(e) = self.scene.set_points(positions, colors) {
            eprintln!("mlod: {e}");
        }
        self.rebuild_lines();
        self.update_histogram();
    }

    /// Recolours without moving points (colour mode, range, highlight).
    fn recolor(&mut self) {
        self.needs_color = false;
        let colors = self.colors();
        if self.scene.set_colors(colors).is_err() {
            self.rebuild_scene();
        }
        self.update_histogram();
    }

    fn colors(&mut self) -> Vec<[u8; 4]> {
        let Some(cloud) = &self.fused else {
            return Vec::new();
        };
        if self.session.auto_range && self.session.color.mode != ColorMode::Source {
            self.session.color.range =
                auto_range(scalars(cloud, self.session.color.mode), self.session.color.scale);
        }
        let all = colorize(cloud, &self.session.color);
        self.scene_index.iter().map(|&i| all[i as usize]).collect()
    }

    fn update_histogram(&mut self) {
        let Some(cloud) = &self.fused else { return };
        let c = &self.session.color;
        // In source-LiDAR mode the histogram still shows tr(Ξ), on its own log range.
        self.histogram = if c.mode == ColorMode::Source {
            histogram(
                &cloud.trace,
                auto_range(&cloud.trace, Scale::Log),
                Scale::Log,
                HISTOGRAM_BINS,
            )
        } else {
            histogram(scalars(cloud, c.mode), c.range, c.scale, HISTOGRAM_BINS)
        };
        self.uncertain_fraction = cloud.uncertain_fraction(UNCERTAIN_TRACE);
    }

    pub(crate) fn rebuild_lines(&mut self) {
        let mut lines = grid_lines(80.0, 10.0, -1.8);
        if self.session.show_ground_truth {
            if let Some(f) = &self.frame {
                for b in &f.boxes {
                    lines.extend(box_lines(b.box3d.corners(), GT_COLOR, true));
                }
            }
        }
        let settings = self.session.detection;
        if let Some(d) = self.detection.as_ref().filter(|_| settings.show) {
            for (det, o) in d.detections.iter().zip(&d.outcomes) {
                if det.score < settings.min_score {
                    continue;
                }
                let color = match o {
                    PredOutcome::FalsePositive { .. } => FALSE_POSITIVE_COLOR,
                    _ => PROPOSAL_COLOR,
                };
                lines.extend(box_lines(det.box3d.corners(), color, true));
            }
        }
        self.scene.set_lines(lines);
    }

    /// The session as it stands now (camera included), for saving.
    pub fn current_session(&self) -> Session {
        let mut s = self.session.clone();
        s.camera = Some(pose_from_camera(&self.view.camera));
        s.point_size = self.view.settings.point_size;
        s
    }

    /// Replaces the whole state by a session (loading its dataset if it differs).
    pub fn apply_session(&mut self, s: Session) {
        self.view.camera = s.camera.map(|c| camera_from_pose(&c)).unwrap_or_default();
        self.camera_from_session = s.camera.is_some();
        self.view.settings.point_size = s.point_size;
        let same_dataset = self.dataset.is_some() && s.dataset == self.session.dataset;
        self.wanted_token = s.sample_token.clone();
        self.session = s;
        if same_dataset {
            match self.wanted_token.clone() {
                Some(t) if self.frame.as_ref().map(|f| f.sample_token != t).unwrap_or(true) => {
                    self.select_sample(&t)
                }
                _ => self.needs_fuse = true,
            }
        } else {
            let path = self.session.dataset.clone();
            self.open_dataset(path);
        }
    }

    /// The fused cloud on screen.
    pub fn fused(&self) -> Option<&FusedCloud> {
        self.fused.as_ref()
    }

    /// The frame on screen.
    pub fn frame(&self) -> Option<&Frame> {
        self.frame.as_deref()
    }

    /// The session state (without the camera; see [`Self::current_session`]).
    pub fn session(&self) -> &Session {
        &self.session
    }

    /// The session state, to edit (then [`Self::mark_fuse`] or [`Self::rematch`]).
    pub fn session_mut(&mut self) -> &mut Session {
        &mut self.session
    }

    /// |P_u|/|P| of the fused cloud and the histogram the colour panel shows.
    pub fn uncertainty_summary(&self) -> (f64, &[u32]) {
        (self.uncertain_fraction, &self.histogram)
    }

    /// The viewport (camera and draw settings) and the scene handed to the renderer.
    pub fn viewport(&self) -> (&Viewport, &SceneHandle) {
        (&self.view, &self.scene)
    }

    /// Where the viewport was drawn last frame, and the ground-truth box under the pointer with
    /// its statistics (what the tooltip shows).
    pub fn hover_state(&self) -> (egui::Rect, Option<(usize, BoxStats)>) {
        (self.viewport_rect, self.hovered_box)
    }

    /// Whether a load is still running (tests wait on this).
    pub fn is_busy(&self) -> bool {
        self.jobs.running() > 0 || self.needs_fuse || self.detect_in_flight
    }

    fn handle_keys(&mut self, ctx: &egui::Context) {
        if ctx.egui_wants_keyboard_input() {
            return;
        }
        if ctx.input(|i| i.key_pressed(egui::Key::D)) {
            self.run_detector();
        }
        let (left, right, help, esc, bev) = ctx.input(|i| {
            (
                i.key_pressed(egui::Key::ArrowLeft),
                i.key_pressed(egui::Key::ArrowRight),
                i.key_pressed(egui::Key::F1)
                    || i.events
                        .iter()
                        .any(|e| matches!(e, egui::Event::Text(t) if t == "?")),
                i.key_pressed(egui::Key::Escape),
                i.key_pressed(egui::Key::B),
            )
        });
        if left {
            self.step_sample(-1);
        }
        if right {
            self.step_sample(1);
        }
        if help {
            self.show_help = !self.show_help;
        }
        if esc {
            self.show_help = false;
        }
        if bev {
            let v = if self.view.camera.projection == Projection::BirdsEye {
                View::Overview
            } else {
                View::Bev
            };
            self.set_preset(v);
        }
    }

    fn handle_dropped_files(&mut self, ctx: &egui::Context) {
        let dropped: Vec<PathBuf> = ctx.input(|i| {
            i.raw
                .dropped_files
                .iter()
                .map(|f| f.path().to_path_buf())
                .filter(|p| !p.as_os_str().is_empty())
                .collect()
        });
        if let Some(path) = dropped.into_iter().next() {
            let path = if path.is_file() {
                match path.file_name().and_then(|n| n.to_str()) {
                    Some(n) if n.ends_with(".json") && path.parent().is_some() => {
                        if let Ok(s) = Session::load(&path) {
                            self.apply_session(s);
                            return;
                        }
                        path.parent().map(PathBuf::from).unwrap_or(path)
                    }
                    _ => path,
                }
            } else {
                path
            };
            self.open_dataset(path);
        }
    }

    /// The viewport and the box tooltip.
    fn central(&mut self, ui: &mut egui::Ui) {
        let out = viewport::show(ui, &mut self.view, &self.scene);
        self.viewport_rect = out.response.rect;
        if self.frame.is_none() {
            let msg = if self.jobs.running() > 0 {
                "loading…"
            } else {
                "no sample loaded — File > Open dataset…"
            };
            ui.painter().text(
                out.response.rect.center(),
                egui::Align2::CENTER_CENTER,
                msg,
                egui::FontId::proportional(18.0),
                Color32::from_gray(170),
            );
        }
        if let Some(i) = out.picked {
            if let (Some(cloud), Some(&k)) = (&self.fused, self.scene_index.get(i)) {
                let k = k as usize;
                let ch = cloud
                    .lidars
                    .iter()
                    .find(|l| l.range.contains(&k))
                    .map(|l| l.channel.paper_name())
                    .unwrap_or("?");
                let now = ui.input(|i| i.time);
                self.toast(
                    now,
                    format!("focused a {ch} point, tr(Ξ) = {:.4} m²", cloud.trace[k]),
                    false,
                );
            }
        }
        self.hovered_box = None;
        self.hovered_detection = None;
        let Some(pointer) = out.response.hover_pos() else {
            return;
        };
        let (Some(frame), Some(cloud)) = (&self.frame, &self.fused) else {
            return;
        };
        let rect = out.response.rect;
        let camera = &self.view.camera;
        // The box under the pointer with the smallest screen rectangle; GT and proposals compete.
        let screen_rect = |corners: [[f64; 3]; 8]| -> Option<egui::Rect> {
            let pts: Vec<egui::Pos2> = corners
                .iter()
                .filter_map(|c| camera.project([c[0] as f32, c[1] as f32, c[2] as f32], rect))
                .collect();
            (pts.len() == 8).then(|| egui::Rect::from_points(&pts))
        };
        let mut best: Option<(Hovered, f32)> = None;
        let mut consider = |h: Hovered, r: Option<egui::Rect>| {
            if let Some(r) = r {
                if r.contains(pointer) && best.is_none_or(|(_, a)| r.area() < a) {
                    best = Some((h, r.area()));
                }
            }
        };
        if self.session.show_ground_truth {
            for (bi, b) in frame.boxes.iter().enumerate() {
                consider(Hovered::Truth(bi), screen_rect(b.box3d.corners()));
            }
        }
        let settings = self.session.detection;
        if let Some(d) = self.detection.as_ref().filter(|_| settings.show) {
            for (i, det) in d.detections.iter().enumerate() {
                if det.score >= settings.min_score {
                    consider(Hovered::Proposal(i), screen_rect(det.box3d.corners()));
                }
            }
        }
        match best {
            Some((Hovered::Truth(bi), _)) => {
                let b = &frame.boxes[bi];
                let stats = box_stats(cloud, &b.box3d);
                self.hovered_box = Some((bi, stats));
                let [l, w, h] = b.box3d.size_lwh;
                let matched = self
                    .detection
                    .as_ref()
                    .and_then(|d| d.gt_outcomes.get(bi).copied());
                out.response.on_hover_ui_at_pointer(|ui| {
                    ui.strong(format!("ground truth: {}", b.category));
                    ui.label(format!("size l×w×h  {l:.2} × {w:.2} × {h:.2} m"));
                    ui.label(format!("distance  {:.1} m", b.box3d.bev_range()));
                    ui.label(format!("points inside  {}", stats.points));
                    ui.label(format!("mean tr(Ξ) inside  {:.4} m²", stats.mean_trace));
                    ui.label(format!(
                        "uncertain (tr Ξ > 0.05)  {:.0} %",
                        100.0 * stats.uncertain_fraction
                    ));
                    match matched {
                        Some(GtOutcome::Matched { iou, .. }) => {
                            ui.label(format!("detected: 3D IoU {iou:.2}"));
                        }
                        Some(GtOutcome::Missed) => {
                            ui.label("missed by the detector");
                        }
                        _ => {}
                    }
                });
            }
            Some((Hovered::Proposal(i), _)) => {
                self.hovered_detection = Some(i);
                let Some(d) = self.detection.as_ref() else { return };
                let det = &d.detections[i];
                let stats = box_stats(cloud, &det.box3d);
                let [l, w, h] = det.box3d.size_lwh;
                let outcome = d.outcomes[i];
                let case = d.case;
                out.response.on_hover_ui_at_pointer(|ui| {
                    ui.strong(format!("proposal ({}): {}", case.paper_name(), det.category));
                    ui.label(format!("score  {:.3}", det.score));
                    ui.label(format!("size l×w×h  {l:.2} × {w:.2} × {h:.2} m"));
                    ui.label(format!("distance  {:.1} m", det.box3d.bev_range()));
                    ui.label(format!("points inside  {}", stats.points));
                    ui.label(format!("mean tr(Ξ) inside  {:.4} m²", stats.mean_trace));
                    match outcome {
                        PredOutcome::TruePositive { iou, .. } => {
                            ui.label(format!("true positive: 3D IoU {iou:.2}"));
                        }
                        PredOutcome::FalsePositive { best_iou } => {
                            ui.label(format!("false positive: best 3D IoU {best_iou:.2}"));
                        }
                        PredOutcome::Ignored => {}
                    }
                });
            }
            None => {}
        }
    }
}

/// What the pointer is over.
#[derive(Debug, Clone, Copy)]
enum Hovered {
    Truth(usize),
    Proposal(usize),
}

impl MlodApp {
    /// Frame-time measurement (see [`AppOptions::measure_frames`]): starts once a sample is drawn.
    fn measure_frame(&mut self, ctx: &egui::Context) {
        let Some((n, stamps)) = &mut self.measure else {
            return;
        };
        if self.fused.is_none() {
            ctx.request_repaint();
            return;
        }
        stamps.push(Instant::now());
        if stamps.len() > *n {
            let mut dt: Vec<f64> = stamps
                .windows(2)
                .map(|w| (w[1] - w[0]).as_secs_f64() * 1e3)
                .collect();
            dt.sort_by(f64::total_cmp);
            let mean = dt.iter().sum::<f64>() / dt.len() as f64;
            let pct = |q: f64| dt[((dt.len() - 1) as f64 * q).round() as usize];
            eprintln!(
                "frames: {}  points: {}  mean {:.1} ms  p50 {:.1} ms  p95 {:.1} ms",
                dt.len(),
                self.fused.as_ref().map_or(0, |c| c.len()),
                mean,
                pct(0.5),
                pct(0.95)
            );
            self.measure = None;
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        } else {
            ctx.request_repaint();
        }
    }
}

/// The ego car's forward direction in the base frame (LIDAR_TOP's frame), as a yaw.
fn ego_heading(frame: &Frame) -> f32 {
    let r = frame
        .primary
        .info
        .sensor_to_ego
        .rotation
        .to_rotation_matrix()
        .into_inner();
    // Ego +x expressed in the sensor (base) frame: Rᵀ e_x.
    (r[(0, 1)]).atan2(r[(0, 0)]) as f32
}

pub(crate) fn camera_from_pose(c: &CameraPose) -> Camera {
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

pub(crate) fn pose_from_camera(c: &Camera) -> CameraPose {
    CameraPose {
        target: c.target,
        yaw: c.yaw,
        pitch: c.pitch,
        distance: c.distance,
        fov_y: c.fov_y,
        bev: c.projection == Projection::BirdsEye,
    }
}

impl eframe::App for MlodApp {
    fn ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        let ctx = ui.ctx().clone();
        let now = ctx.input(|i| i.time);
        self.process_jobs(now);
        self.handle_keys(&ctx);
        self.handle_dropped_files(&ctx);
        panels::menu_bar(self, ui, frame);
        panels::status_bar(self, ui);
        egui::Panel::left("samples")
            .resizable(true)
            .default_size(270.0)
            .show(ui, |ui| panels::sample_browser(self, ui));
        egui::Panel::right("controls")
            .resizable(true)
            .default_size(330.0)
            .show(ui, |ui| panels::controls(self, ui));
        if self.needs_fuse {
            self.refuse(now);
        } else if self.needs_color {
            self.recolor();
        }
        egui::CentralPanel::default()
            .frame(egui::Frame::NONE)
            .show(ui, |ui| self.central(ui));
        panels::help_overlay(self, &ctx);
        panels::toasts(self, &ctx, now);
        if self.jobs.running() > 0 {
            ctx.request_repaint_after(std::time::Duration::from_millis(50));
        }
        self.measure_frame(&ctx);
    }

    fn save(&mut self, storage: &mut dyn eframe::Storage) {
        eframe::set_value(storage, RECENT_KEY, &self.recent);
    }
}

/// Per-LiDAR "label (points)" for the sample browser.
pub(crate) fn channel_counts(cloud: &FusedCloud) -> BTreeMap<LidarChannel, usize> {
    cloud.lidars.iter().map(|l| (l.channel, l.range.len())).collect()
}

/// A coloured label for a LiDAR.
pub(crate) fn lidar_label(ch: LidarChannel) -> RichText {
    let [r, g, b, _] = crate::color::LIDAR_COLORS[ch as usize];
    RichText::new(ch.paper_name()).color(Color32::from_rgb(r, g, b))
}
