//! The debugger window: state, layout and the glue between the panels, the library pipeline and
//! the viewport. All numbers come from the library (`pipeline::fuse`, `color`, `box_stats`); this
//! file only holds state, lays out widgets and hands data to the renderer. Running a detector,
//! drawing its layers and highlighting active points live in [`detection`].

mod actions;
mod calibration;
mod compare;
mod demo;
mod detection;
mod external;
mod failures;
mod measure;
mod models;
mod scene;
mod selection;

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use eframe::egui;

use super::jobs::{JobResult, Jobs, LoadedDetector};
use super::overlay::{self, OverlayInput};
use super::panels::{self, Panels};
use super::state::{camera_from_pose, pose_from_camera};
use super::state::{Loaded, Shell, Toast};
use crate::color::ColorMode;
use crate::dataset::{Frame, LidarChannel};
use crate::detect::weights::{default_models_dir, Manifest};
use crate::detect::Case;
use crate::pipeline::{fuse, BoxStats, FusedCloud};
use crate::render::{Camera, SceneHandle, View, Viewport};
use crate::session::Session;
use measure::Measure;

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
    /// With `measure_frames`: after the idle frames, press Run (the session's case) and then scan
    /// the scene for failure cases, measuring the frames while each is in flight and the time
    /// from Run to the boxes on screen (`mlod gui --measure-frames N --measure-run`).
    pub measure_run: bool,
    /// Folder of the stage-1 weights and their manifest (default: `$MLOD_MODELS`, else the
    /// crate's `assets/models`).
    pub models: Option<PathBuf>,
    /// The file `session` was read from (named in the window's title; Ctrl+S saves to it).
    pub session_file: Option<PathBuf>,
}

const HISTOGRAM_BINS: usize = 64;
/// The controls panel's width (UI points): wide enough for its widest row at 1280×800.
const RIGHT_PANEL_WIDTH: f32 = 350.0;
const RECENT_KEY: &str = "mlod_recent_datasets";

/// The application.
pub struct MlodApp {
    session: Session,
    view: Viewport,
    scene: SceneHandle,
    /// The compare half's scene: the same points, the second case's boxes.
    scene_b: SceneHandle,
    jobs: Jobs,
    loaded: Loaded,
    shell: Shell,
    /// Fused-cloud index of each point handed to the scene (hidden LiDARs are left out).
    scene_index: Vec<u32>,
    wanted_token: Option<String>,
    loading_dataset: Option<PathBuf>,
    /// Heading of the ego car's +x in the base frame (LIDAR_TOP is mounted turned ~180°).
    ego_heading: f32,
    camera_from_session: bool,
    needs_fuse: bool,
    needs_color: bool,
    hovered_box: Option<(usize, BoxStats)>,
    measure: Option<Measure>,
    viewport_rect: egui::Rect,
    detectors: BTreeMap<Case, LoadedDetector>,
    detect_again: bool,
    hovered_detection: Option<usize>,
    hovered_refined: Option<usize>,
    /// The refined box whose active points are painted over the colouring.
    highlighted: Option<usize>,
    models_dir: PathBuf,
    /// Id of the last calibration asked for (a result with another id is dropped).
    calib_seq: u64,
    /// An (OC) case asked to detect before a calibration existed: detect once it is back.
    detect_after_calibration: bool,
    /// The compare case was asked to run again while it was running.
    compare_again: bool,
    /// Id of the last failure scan asked for.
    scan_seq: u64,
    /// A selection to make once the sample being loaded is on screen (the failure browser's).
    pending_selection: Option<crate::session::BoxSelection>,
    /// Run the detector once the sample being loaded is fused.
    detect_on_load: bool,
    /// Focus the selection as soon as it is found.
    focus_pending: bool,
    /// Scan for failure cases once the sample is fused (a session with the browser open).
    scan_on_load: bool,
    /// A dataset opened without a session: its first sample picks the default case (LiDAR-Top
    /// on a LIDAR_TOP-only sample).
    case_from_data: bool,
    /// Consents to run a session's external detectors, and the question pending (`gui::consent`).
    consent: crate::gui::consent::Consent,
    /// Why an external case could not run, shown as a toast at the next frame.
    consent_notice: Option<String>,
}

impl MlodApp {
    /// Creates the app, installs the viewport's GPU resources and starts loading the dataset.
    pub fn new(cc: &eframe::CreationContext<'_>, options: AppOptions) -> Self {
        if let Some(rs) = cc.wgpu_render_state.as_ref() {
            crate::render::install(rs);
        }
        let recent = cc
            .storage
            .and_then(|s| eframe::get_value::<Vec<PathBuf>>(s, RECENT_KEY))
            .unwrap_or_default();
        let consents = cc
            .storage
            .and_then(|s| eframe::get_value::<Vec<String>>(s, crate::gui::consent::CONSENT_KEY))
            .unwrap_or_default();
        let mut app = Self::headless(options, Some(cc.egui_ctx.clone()));
        app.shell.recent = recent;
        app.consent.granted = consents.into_iter().collect();
        app
    }

    /// The app without a window (state and data only); the screenshot command uses this.
    pub fn headless(options: AppOptions, ctx: Option<egui::Context>) -> Self {
        // First sight (no session): the LiDARs in their paper colours, until α leaves 0.
        let auto_color = options.session.is_none();
        let session = options.session.unwrap_or_else(|| {
            let mut s = Session::new(options.dataset.clone());
            s.color.mode = ColorMode::Source;
            s
        });
        let camera_from_session = session.camera.is_some();
        let mut view = Viewport::default();
        view.settings.point_size = session.point_size;
        view.settings.line_width = session.line_width;
        if let Some(c) = session.camera {
            view.camera = camera_from_pose(&c);
        }
        let mut app = Self {
            view,
            scene: SceneHandle::new(),
            scene_b: SceneHandle::new(),
            jobs: Jobs::new(ctx, options.synchronous),
            scene_index: Vec::new(),
            wanted_token: session.sample_token.clone(),
            loading_dataset: None,
            ego_heading: 0.0,
            camera_from_session,
            needs_fuse: false,
            needs_color: false,
            hovered_box: None,
            loaded: Loaded::default(),
            shell: Shell {
                show_timings: !options.synchronous,
                auto_color,
                // Never a blocking native dialog in tests and headless runs.
                native_dialogs: !options.synchronous && panels::dialog_service_available(),
                session_file: options.session_file.clone(),
                ..Default::default()
            },
            viewport_rect: egui::Rect::NOTHING,
            measure: options
                .measure_frames
                .map(|n| Measure::new(n, options.measure_run)),
            detectors: BTreeMap::new(),
            detect_again: false,
            hovered_detection: None,
            hovered_refined: None,
            highlighted: None,
            models_dir: options
                .models
                .clone()
                .or_else(|| session.models.clone())
                .or_else(|| std::env::var_os("MLOD_MODELS").map(PathBuf::from))
                .unwrap_or_else(default_models_dir),
            calib_seq: 0,
            detect_after_calibration: false,
            compare_again: false,
            scan_seq: 0,
            pending_selection: None,
            detect_on_load: false,
            focus_pending: false,
            scan_on_load: false,
            case_from_data: false,
            consent: Default::default(),
            consent_notice: None,
            session,
        };
        app.loaded.ground_gate_m = crate::cases::ground_gate::manifest_gate(&app.models_dir);
        app.loaded.models = app.models_dir.clone();
        app.loaded.models_adapted = Manifest::load(&app.models_dir)
            .ok()
            .and_then(|m| m.adapted_summary());
        let path = app.session.dataset.clone();
        app.open_dataset(path);
        app.case_from_data = auto_color;
        app.reopen_failures();
        app.process_jobs(0.0);
        app.reopen_sweep(0.0);
        app
    }

    /// Starts opening a dataset; the current one stays until the new one has loaded.
    pub fn open_dataset(&mut self, path: PathBuf) {
        self.case_from_data = true;
        self.loading_dataset = Some(path.clone());
        self.jobs.open_dataset(path);
    }

    /// Asks for a sample; the current frame stays until it has loaded.
    pub fn select_sample(&mut self, token: &str) {
        let Some(ds) = self.loaded.dataset.clone() else {
            return;
        };
        self.wanted_token = Some(token.to_string());
        self.jobs.load_frame(ds, token.to_string());
    }

    /// Steps through the samples in scene order.
    pub fn step_sample(&mut self, delta: i64) {
        let Some(current) = self.loaded.frame.as_ref().map(|f| f.sample_token.clone()) else {
            return;
        };
        let Some(i) = self.loaded.samples.iter().position(|s| s.sample_token == current) else {
            return;
        };
        let j = (i as i64 + delta).clamp(0, self.loaded.samples.len() as i64 - 1) as usize;
        if j != i {
            let token = self.loaded.samples[j].sample_token.clone();
            self.select_sample(&token);
        }
    }

    fn toast(&mut self, now: f64, text: impl Into<String>, error: bool) {
        self.shell.toast(now, text, error);
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
        if !self.camera_from_session && self.loaded.fused.is_some() {
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
                            for note in ds.notes() {
                                self.shell.toasts.push(Toast {
                                    text: note,
                                    error: false,
                                    until: now + 10.0,
                                });
                            }
                            self.loaded.depth_notes.clear();
                            self.jobs
                                .depth_notes(path.clone(), ds.clone(), self.models_dir.clone());
                            self.loaded.dataset = Some(ds);
                            self.loaded.samples = samples;
                            self.session.dataset = path.clone();
                            self.shell.remember(&path);
                            match first {
                                Some(token) => self.select_sample(&token),
                                None => self.toast(now, format!("{} has no samples", path.display()), true),
                            }
                        }
                        Err(e) => self.toast(now, format!("cannot open dataset: {e}"), true),
                    }
                }
                JobResult::DepthNotes { path, notes } => {
                    if self.session.dataset == path {
                        self.loaded.depth_notes = notes;
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
                                self.shell.toasts.push(Toast {
                                    text: w.clone(),
                                    error: false,
                                    until: now + 5.0,
                                });
                            }
                            self.ego_heading = ego_heading(&frame);
                            if std::mem::take(&mut self.case_from_data) && frame.is_single_lidar() {
                                let case = &mut self.session.detection.case;
                                if !case.missing_lidars(&frame).is_empty() {
                                    *case = crate::detect::Case::Top;
                                    self.shell.toasts.push(Toast {
                                        text: "This sample has LIDAR_TOP only: the case is LiDAR-Top".into(),
                                        error: false,
                                        until: now + 5.0,
                                    });
                                }
                            }
                            if self.loaded.detection.as_ref().is_some_and(|d| d.token != token) {
                                self.loaded.detection = None;
                            }
                            if self.loaded.detection_b.as_ref().is_some_and(|d| d.token != token) {
                                self.loaded.detection_b = None;
                            }
                            if self.session.sample_token.as_deref() != Some(token.as_str()) {
                                // Another sample: other objects.
                                self.session.selection = None;
                            }
                            if let Some(p) = self.pending_selection.take() {
                                self.session.selection = Some(p);
                            }
                            self.session.sample_token = Some(token);
                            self.loaded.frame = Some(frame);
                            self.loaded.frame_ms = millis;
                            self.needs_fuse = true;
                        }
                        Err(e) => self.toast(now, format!("cannot load sample {token}: {e}"), true),
                    }
                }
                JobResult::Detect {
                    token,
                    generation,
                    case,
                    compare: false,
                    result,
                    millis,
                } => self.apply_detection(token, generation, case, result, millis, now),
                JobResult::Detect {
                    token,
                    generation,
                    case,
                    compare: true,
                    result,
                    millis,
                } => self.apply_compare(token, generation, case, result, millis, now),
                JobResult::Scan { id, result, millis } => self.apply_scan(id, result, millis, now),
                JobResult::Clip { path, result, millis } => match result {
                    Ok((n, bytes)) => self.toast(
                        now,
                        format!(
                            "wrote {} ({n} frames, {:.0} kB, {:.1} s)",
                            path.display(),
                            bytes as f64 / 1e3,
                            millis / 1e3
                        ),
                        false,
                    ),
                    Err(e) => self.toast(now, format!("cannot export the clip: {e}"), true),
                },
                JobResult::Calibrate {
                    id,
                    token,
                    result,
                    millis,
                } => self.apply_calibration(id, token, result, millis, now),
            }
        }
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

    /// Re-fuses the frame with the current perturbation and recolours (the α-slider path).
    fn refuse(&mut self, now: f64) {
        self.refuse_now(now, self.session.detection.auto_run);
    }

    /// [`Self::refuse`], re-running the detector after it only if `auto_run`. A calibration that
    /// no longer fits the sample or the drift is dropped first.
    fn refuse_now(&mut self, now: f64, auto_run: bool) {
        self.needs_fuse = false;
        let Some(frame) = self.loaded.frame.clone() else {
            return;
        };
        let start = Instant::now();
        let mut result = fuse(&frame, &self.session.fuse_params());
        if let Err(e) = &result {
            if self.drop_stale_calibration(e) {
                result = fuse(&frame, &self.session.fuse_params());
            }
        } else if self.session.oc.calibration.is_some() && !self.calibration_is_current() {
            // Not shown, but kept: drop it too once the drift or the sample changed.
            self.session.oc.calibration = None;
            self.session.oc.show_corrected = false;
        }
        match result {
            Ok(cloud) => {
                self.session.sampled = cloud
                    .lidars
                    .iter()
                    .filter(|l| l.channel != LidarChannel::Top)
                    .map(|l| (l.channel, l.noise))
                    .collect();
                self.loaded.fused = Some(cloud);
                self.loaded.fuse_generation += 1;
                if self.shell.auto_color && self.session.fuse.perturbation.alpha > 0.0 {
                    // First sight: the drift is what there is to see now.
                    self.shell.auto_color = false;
                    if self.session.color.mode == ColorMode::Source {
                        self.session.color.mode = ColorMode::Trace;
                    }
                }
                self.rebuild_scene();
                self.resolve_selection();
                if auto_run || std::mem::take(&mut self.detect_on_load) {
                    self.run_detector();
                }
                if std::mem::take(&mut self.scan_on_load) {
                    self.scan_failures(now);
                }
                self.loaded.fuse_ms = start.elapsed().as_secs_f64() * 1e3;
            }
            Err(e) => self.toast(now, format!("cannot fuse: {e}"), true),
        }
    }

    /// The session as it stands now (camera included), for saving.
    pub fn current_session(&self) -> Session {
        let mut s = self.session.clone();
        s.failures = self.shell.failures.as_ref().map(|b| b.scope);
        s.camera = Some(pose_from_camera(&self.view.camera));
        s.point_size = self.view.settings.point_size;
        s.line_width = self.view.settings.line_width;
        crate::gui::consent::store_definitions(&mut s);
        s
    }

    /// Replaces the whole state by a session (loading its dataset if it differs).
    pub fn apply_session(&mut self, s: Session) {
        self.view.camera = s.camera.map(|c| camera_from_pose(&c)).unwrap_or_default();
        self.camera_from_session = s.camera.is_some();
        self.view.settings.point_size = s.point_size;
        self.view.settings.line_width = s.line_width;
        let same_dataset = self.loaded.dataset.is_some() && s.dataset == self.session.dataset;
        self.wanted_token = s.sample_token.clone();
        let models = s.models.clone();
        self.session = s;
        if let Some(dir) = models.filter(|d| *d != self.models_dir) {
            self.open_models(dir, 0.0);
        }
        self.shell.auto_color = false;
        self.loaded.detection_b = None;
        self.reopen_sweep(0.0);
        self.reopen_failures();
        if same_dataset {
            match self.wanted_token.clone() {
                Some(t)
                    if self
                        .loaded
                        .frame
                        .as_ref()
                        .map(|f| f.sample_token != t)
                        .unwrap_or(true) =>
                {
                    self.select_sample(&t)
                }
                _ => self.needs_fuse = true,
            }
        } else {
            let path = self.session.dataset.clone();
            self.open_dataset(path);
            // The session says which case.
            self.case_from_data = false;
        }
    }

    /// The fused cloud on screen.
    pub fn fused(&self) -> Option<&FusedCloud> {
        self.loaded.fused.as_ref()
    }

    /// The frame on screen.
    pub fn frame(&self) -> Option<&Frame> {
        self.loaded.frame.as_deref()
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
        (self.loaded.uncertain_fraction, &self.loaded.histogram)
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

    /// The viewport (split in two in compare mode), the box under the pointer and its tooltip.
    fn central(&mut self, ui: &mut egui::Ui) {
        if self.compare_case().is_some() {
            self.central_split(ui);
        } else {
            self.central_main(ui);
        }
    }

    /// The main view: the session's case, with hover, tooltips and selection.
    fn central_main(&mut self, ui: &mut egui::Ui) {
        let labels = self.scene_labels(true);
        let input = OverlayInput {
            loaded: &self.loaded,
            session: &self.session,
            scene_index: &self.scene_index,
            loading: self.jobs.running() > 0,
            labels: &labels,
            playing_alpha: self.shell.play.map(|_| self.session.fuse.perturbation.alpha),
        };
        let out = overlay::show(ui, &mut self.view, &self.scene, &input);
        self.viewport_rect = out.rect;
        self.hovered_box = out.hovered_box;
        self.hovered_detection = out.hovered_detection;
        self.hovered_refined = out.hovered_refined;
        if let Some(pick) = out.clicked {
            // A click selects the box under the pointer; elsewhere it clears.
            self.select_box(pick);
        }
        if self.update_highlight() {
            ui.ctx().request_repaint();
        }
        if let Some(text) = out.message {
            let now = ui.input(|i| i.time);
            self.toast(now, text, false);
        }
    }

    /// What the panels see of the app.
    fn panels(&mut self) -> Panels<'_> {
        Panels {
            session: &mut self.session,
            view: &mut self.view,
            shell: &mut self.shell,
            loaded: &self.loaded,
            actions: Vec::new(),
        }
    }

    /// The first error toast on screen, if any (a headless screenshot fails with it).
    pub fn first_error(&self) -> Option<&str> {
        self.shell
            .toasts
            .iter()
            .find(|t| t.error)
            .map(|t| t.text.as_str())
    }

    /// Whether a load is still running (tests wait on this).
    pub fn is_busy(&self) -> bool {
        self.jobs.running() > 0 || self.needs_fuse || self.loaded.detecting || self.loaded.detecting_b
    }
}

impl MlodApp {
    /// The window's title: the tool, and the session file once there is one.
    fn update_title(&mut self, ctx: &egui::Context) {
        let title = match self.shell.session_file.as_ref().and_then(|p| p.file_name()) {
            Some(name) => format!("{} — {}", super::TITLE, name.to_string_lossy()),
            None => super::TITLE.to_string(),
        };
        if self.shell.title != title {
            ctx.send_viewport_cmd(egui::ViewportCommand::Title(title.clone()));
            self.shell.title = title;
        }
    }

    /// The messages on screen (toasts), oldest first.
    pub fn toast_texts(&self) -> Vec<&str> {
        self.shell.toasts.iter().map(|t| t.text.as_str()).collect()
    }

    /// The window title as last set.
    pub fn title(&self) -> &str {
        &self.shell.title
    }

    /// The controls panel's rectangle last frame (none while hidden), and how far its open
    /// sections ran past its height (≤ 0: all in sight; else its scroll bar shows).
    pub fn controls_layout(&self) -> Option<(egui::Rect, f32)> {
        self.shell
            .controls_rect
            .map(|r| (r, self.shell.controls_overflow))
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

impl eframe::App for MlodApp {
    fn ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        let ctx = ui.ctx().clone();
        let now = ctx.input(|i| i.time);
        self.process_jobs(now);
        if self.advance_play() {
            ctx.request_repaint();
        }
        self.handle_dropped_files(&ctx);
        let mut p = self.panels();
        panels::keys(&mut p, &ctx);
        panels::menu_bar(&mut p, ui);
        panels::banner(&mut p, ui);
        panels::status_bar(&mut p, ui);
        // Tab hides the side panels (the viewport, or both compare halves, take the width).
        if !p.shell.hide_panels {
            egui::Panel::left("samples")
                .resizable(true)
                .default_size(230.0)
                .show(ui, |ui| panels::sample_browser(&mut p, ui));
            let right = egui::Panel::right("controls")
                .resizable(true)
                .default_size(RIGHT_PANEL_WIDTH)
                .min_size(RIGHT_PANEL_WIDTH)
                .show(ui, |ui| panels::controls(&mut p, ui));
            p.shell.controls_rect = Some(right.response.rect);
        } else {
            p.shell.controls_rect = None;
        }
        // The failure browser docked under the viewport: it never covers what it finds.
        panels::failure_panel(&mut p, ui);
        let actions = std::mem::take(&mut p.actions);
        self.apply_actions(actions, now, Some(frame));
        self.consent_window(&ctx, now);
        if self.needs_fuse {
            self.refuse(now);
        } else if self.needs_color {
            self.recolor();
        }
        egui::CentralPanel::default()
            .frame(egui::Frame::NONE)
            .show(ui, |ui| self.central(ui));
        self.update_title(&ctx);
        let mut p = self.panels();
        panels::help_overlay(&mut p, &ctx);
        panels::sweep_window(&mut p, &ctx);
        panels::file_prompt(&mut p, &ctx);
        panels::toasts(&mut p, &ctx, now);
        let actions = std::mem::take(&mut p.actions);
        self.apply_actions(actions, now, Some(frame));
        if self.jobs.running() > 0 {
            ctx.request_repaint_after(std::time::Duration::from_millis(50));
        }
        self.measure_frame(&ctx);
    }

    fn save(&mut self, storage: &mut dyn eframe::Storage) {
        eframe::set_value(storage, RECENT_KEY, &self.shell.recent);
        eframe::set_value(storage, crate::gui::consent::CONSENT_KEY, &self.consents());
    }
}
