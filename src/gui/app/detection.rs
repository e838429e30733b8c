//! The app's detection half: running the session's case in the background (stage 1, or MLOD:
//! stage 1 and the refiner), matching what comes back, drawing the layers (ground truth in green,
//! stage 1's boxes in blue, refined boxes in red with a line to their proposal) and highlighting the
//! active points of the hovered or selected refined box. The boxes, the matching and the active
//! points all come from the library; this file only hands them to the scene.

use std::sync::Arc;

use super::MlodApp;
use crate::dataset::Frame;
use crate::detect::Case;
use crate::eval::PredOutcome;
use crate::geometry::Box3d;
use crate::gui::jobs::{DetectOutput, DetectRequest};
use crate::gui::state::{
    DetectionCounts, DetectionView, RawDetection, ACTIVE_POINT_COLOR, FALSE_POSITIVE_COLOR, GT_COLOR,
    LINK_COLOR, PROPOSAL_COLOR, REFINED_COLOR, REFINED_FALSE_POSITIVE_COLOR, SELECTED_COLOR,
    SELECTED_HALO_COLOR,
};
use crate::render::{box_lines, ego_lines, grid_lines, LineVertex};

impl MlodApp {
    /// Runs the session's case on the sample on screen, in the background. A request while one
    /// is running is remembered and run once that one is back (latest state wins).
    pub fn run_detector(&mut self) {
        let Some(frame) = self.loaded.frame.clone() else {
            return;
        };
        if self.loaded.detecting {
            self.detect_again = true;
            return;
        }
        let case = self.session.detection.case;
        if !self.may_run(case) {
            return;
        }
        // The cloud on screen is the one the case sees: an (OC) case the corrected cloud (after
        // calibrating, if there is no calibration yet), any other case the drifted one.
        if case.is_oc() {
            if !self.calibration_is_current() {
                if !self.is_calibrating() {
                    self.calibrate();
                }
                self.detect_after_calibration = true;
                return;
            }
            if !self.session.oc.show_corrected {
                self.session.oc.show_corrected = true;
                self.refuse_now(0.0, false);
            }
        } else if self.session.oc.show_corrected {
            self.session.oc.show_corrected = false;
            self.refuse_now(0.0, false);
        }
        self.loaded.detecting = true;
        self.jobs.detect(self.detect_request(frame, case, false));
        self.run_compare();
    }

    /// A run of `case` on `frame` with the perturbation (and calibration) on screen, with the
    /// already-loaded detector of that case if any.
    pub(super) fn detect_request(&self, frame: Arc<Frame>, case: Case, compare: bool) -> DetectRequest {
        DetectRequest {
            frame,
            params: self.session.fuse_params(),
            generation: self.loaded.fuse_generation,
            case,
            cached: self.detectors.get(&case).cloned(),
            models: self.models_dir.clone(),
            gate: self.gate_choice(),
            compare,
        }
    }

    /// A finished run's boxes matched against the ground truth, if its sample is still on screen;
    /// the loaded detector is kept for the next run either way.
    pub(super) fn matched_on_screen(
        &mut self,
        token: String,
        generation: u64,
        case: Case,
        out: DetectOutput,
        millis: f64,
    ) -> Option<DetectionView> {
        if out.models != self.models_dir || out.gate != self.gate_choice() {
            // Loaded from the folder (or with the ground gate) the window had before File > Open
            // models folder… or the gate's checkbox: neither shown nor kept (the switch ran the
            // case again).
            return None;
        }
        let frame = self.loaded.frame.as_deref().filter(|f| f.sample_token == token);
        let view = frame.map(|frame| {
            let raw = RawDetection {
                case,
                token,
                generation,
                detections: out.detections,
                refined: out.refined,
                categories: out.detector.categories(),
                millis,
            };
            DetectionView::matched(raw, Some(frame), &self.session.detection)
        });
        self.detectors.insert(case, out.detector);
        view
    }

    /// A finished detector run: matched and drawn if its sample is still on screen; an error
    /// (missing weights or refiner) becomes a toast and keeps what is on screen.
    pub(super) fn apply_detection(
        &mut self,
        token: String,
        generation: u64,
        case: Case,
        result: Result<DetectOutput, String>,
        millis: f64,
        now: f64,
    ) {
        self.loaded.detecting = false;
        match result {
            Ok(out) => {
                if let Some(view) = self.matched_on_screen(token, generation, case, out, millis) {
                    self.loaded.detection = Some(view);
                    // A new run: indices of the old one mean nothing; the selection is found
                    // again by its object (this also redraws the lines and the highlight).
                    self.hovered_refined = None;
                    self.resolve_selection();
                }
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

    /// Whether a detector run is in flight.
    pub fn is_detecting(&self) -> bool {
        self.loaded.detecting
    }

    /// Whether the detection on screen was made before the last change of perturbation.
    pub fn detection_is_stale(&self) -> bool {
        self.loaded.detection_is_stale(self.session.detection.case)
    }

    /// Re-matches the detection on screen (after the match IoU or the min score changed).
    pub fn rematch(&mut self) {
        if let Some(d) = self.loaded.detection.take() {
            let frame = self.loaded.frame.as_deref();
            self.loaded.detection = Some(d.rematched(frame, &self.session.detection));
        }
        if let Some(d) = self.loaded.detection_b.take() {
            let frame = self.loaded.frame.as_deref();
            self.loaded.detection_b = Some(d.rematched(frame, &self.session.detection));
        }
        self.resolve_selection();
    }

    /// The detection on screen and its counts (drawn boxes: score ≥ the session's min score; the
    /// refined ones for an MLOD case).
    pub fn detection(&self) -> Option<(&DetectionView, DetectionCounts)> {
        self.loaded.detection(self.session.detection.min_score)
    }

    /// The proposal and the refined box under the pointer last frame (indices into the detection
    /// on screen), and the selected refined box.
    pub fn hovered_detection(&self) -> (Option<usize>, Option<usize>, Option<usize>) {
        (
            self.hovered_detection,
            self.hovered_refined,
            self.loaded.selected_refined(),
        )
    }

    /// The refined box whose active points are highlighted now, if any.
    pub fn highlighted_refined(&self) -> Option<usize> {
        self.highlighted
    }

    /// The refined box whose active points should be highlighted: with "show active points" on,
    /// the hovered one, else the selected one.
    fn wanted_highlight(&self) -> Option<usize> {
        let d = self.loaded.detection.as_ref()?;
        let r = d.refinement.as_ref()?;
        let s = &self.session.detection;
        if !(s.show_active && s.show_refined) {
            return None;
        }
        self.hovered_refined
            .or(self.loaded.selected_refined())
            .filter(|&k| k < r.refined.len())
    }

    /// Recolours when the highlighted refined box changed; true if it did.
    pub(super) fn update_highlight(&mut self) -> bool {
        let wanted = self.wanted_highlight();
        if wanted == self.highlighted {
            return false;
        }
        self.highlighted = wanted;
        let colors = self.colors();
        if self.scene.set_colors(colors).is_err() {
            self.rebuild_scene();
        }
        true
    }

    /// Paints the active points of the highlighted refined box over `colors` (one per scene
    /// point).
    pub(super) fn paint_active(&self, colors: &mut [[u8; 4]]) {
        let Some(k) = self.highlighted else { return };
        let Some(r) = self.loaded.detection.as_ref().and_then(|d| d.refinement.as_ref()) else {
            return;
        };
        let Some(refined) = r.refined.get(k) else { return };
        // The scene's points are the visible LiDARs' fused points in ascending order.
        for i in &refined.active {
            if let Ok(s) = self.scene_index.binary_search(i) {
                if let Some(c) = colors.get_mut(s) {
                    *c = ACTIVE_POINT_COLOR;
                }
            }
        }
    }

    /// The line segments: the grid and the ego vehicle in depth with the points, then, over the
    /// points, the ground truth (green), stage 1's boxes (blue, false positives greyed) and the
    /// refined boxes (red) with a line from each proposal's centre to its refinement's, in that
    /// order (a later layer wins where lines overlap); with a box selected, the others dimmed and
    /// the selected one last, thick and amber.
    pub(crate) fn rebuild_lines(&mut self) {
        let selected = self.loaded.selected.and_then(|p| self.box_of(p));
        let (lines, from) = self.lines_for(self.loaded.detection.as_ref(), selected);
        self.scene.set_lines_with_overlay(lines, from);
        if self.session.compare.is_some() {
            let (lines, from) = self.lines_for(self.loaded.detection_b.as_ref(), None);
            self.scene_b.set_lines_with_overlay(lines, from);
        }
    }

    /// The grid and the ego vehicle, then (from the returned index on, drawn over the points) the
    /// ground truth and a detection's layers as the session's settings draw them, and `selected`.
    pub(super) fn lines_for(
        &self,
        d: Option<&DetectionView>,
        selected: Option<Box3d>,
    ) -> (Vec<LineVertex>, usize) {
        let mut lines = grid_lines(80.0, 10.0, GROUND_Z);
        lines.extend(ego_lines(self.ego_heading, GROUND_Z, EGO_ARROW).0);
        let from = lines.len();
        let bg = self.view.settings.background;
        let dim = |c: [u8; 4]| match selected {
            Some(_) => dimmed(c, bg),
            None => c,
        };
        if self.session.show_ground_truth {
            if let Some(f) = &self.loaded.frame {
                for b in &f.boxes {
                    lines.extend(box_lines(b.box3d.corners(), dim(GT_COLOR), true));
                }
            }
        }
        let settings = self.session.detection;
        if let Some(d) = d {
            let color = |o: &PredOutcome, tp: [u8; 4], fp: [u8; 4]| match o {
                PredOutcome::FalsePositive { .. } => dim(fp),
                _ => dim(tp),
            };
            if settings.show {
                for (det, o) in d.detections.iter().zip(&d.outcomes) {
                    if det.score >= settings.min_score {
                        let c = color(o, PROPOSAL_COLOR, FALSE_POSITIVE_COLOR);
                        lines.extend(box_lines(det.box3d.corners(), c, true));
                    }
                }
            }
            if let Some(r) = d.refinement.as_ref().filter(|_| settings.show_refined) {
                let centre = |c: [f64; 3]| [c[0] as f32, c[1] as f32, c[2] as f32];
                for (x, o) in r.refined.iter().zip(&r.outcomes) {
                    if x.detection.score < settings.min_score {
                        continue;
                    }
                    if let Some(p) = d.detections.get(x.proposal) {
                        let link = dim(LINK_COLOR);
                        lines.push(LineVertex::new(centre(p.box3d.center), link).with_width(0.5));
                        lines.push(LineVertex::new(centre(x.detection.box3d.center), link).with_width(0.5));
                    }
                    let c = color(o, REFINED_COLOR, REFINED_FALSE_POSITIVE_COLOR);
                    lines.extend(box_lines(x.detection.box3d.corners(), c, true));
                }
            }
        }
        if let Some(b) = selected {
            // A wide dark-amber halo under a bright amber core.
            let halo = box_lines(b.corners(), SELECTED_HALO_COLOR, true);
            lines.extend(halo.into_iter().map(|v| v.with_width(SELECTED_HALO_WIDTH)));
            let core = box_lines(b.corners(), SELECTED_COLOR, true);
            lines.extend(core.into_iter().map(|v| v.with_width(SELECTED_WIDTH)));
        }
        (lines, from)
    }
}

/// The ground plane of the grid and the ego outline (base frame, m).
pub(crate) const GROUND_Z: f32 = -1.8;
/// Length of the ego vehicle's forward arrow beyond its front (m).
pub(crate) const EGO_ARROW: f32 = 6.0;
/// The selected box's core and halo widths, as multiples of the box line width.
const SELECTED_WIDTH: f32 = 2.0;
const SELECTED_HALO_WIDTH: f32 = 6.4;

/// A box colour halfway to the background: the boxes around a selection.
fn dimmed(c: [u8; 4], bg: [u8; 3]) -> [u8; 4] {
    let mix = |a: u8, b: u8| ((u16::from(a) * 2 + u16::from(b) * 3) / 5) as u8;
    [mix(c[0], bg[0]), mix(c[1], bg[1]), mix(c[2], bg[2]), c[3]]
}
