//! Compare mode: a second case (the session's `compare`) runs on the same perturbed frame and is
//! drawn in the right half of a split viewport that shares the camera, so Input Fusion and MLOD-I
//! (the paper's Fig. 6) or any two cases can be read side by side; each half carries its case and
//! counts, and the Detection panel spells out the difference in TP, FP and misses.
//!
//! The (OC) cases are left out of compare mode: they see the calibrated cloud, the other half the
//! drifted one, and one viewport shows one cloud.

use eframe::egui;

use super::MlodApp;
use crate::detect::Case;
use crate::gui::jobs::DetectOutput;
use crate::gui::state::{DetectionCounts, DetectionView};

/// Gap between the two halves, UI points.
const GAP: f32 = 3.0;

impl MlodApp {
    /// The case of the compare half, when compare mode can run: a second, different case, and
    /// neither an (OC) one.
    pub fn compare_case(&self) -> Option<Case> {
        let a = self.session.detection.case;
        self.session
            .compare
            .filter(|b| *b != a && !b.is_oc() && !a.is_oc())
    }

    /// The compare half's scene, in compare mode.
    pub fn compare_scene(&self) -> Option<&crate::render::SceneHandle> {
        self.compare_case().map(|_| &self.scene_b)
    }

    /// Switches compare mode on with `case`, or off.
    pub fn set_compare(&mut self, case: Option<Case>) {
        self.session.compare = case;
        self.compare_changed();
    }

    /// The compare half's detection and its counts (drawn boxes: score ≥ the min score).
    pub fn compare_detection(&self) -> Option<(&DetectionView, DetectionCounts)> {
        let d = self.loaded.detection_b.as_ref()?;
        Some((d, d.counts(self.session.detection.min_score)))
    }

    pub(super) fn compare_changed(&mut self) {
        self.loaded.detection_b = None;
        // The second scene gets the points (and the lines) the next time the scene is built.
        self.rebuild_scene();
        if self.loaded.detection.is_some() {
            self.run_compare();
        }
    }

    /// Runs the compare case on the sample on screen with the perturbation on screen.
    pub(super) fn run_compare(&mut self) {
        let (Some(case), Some(frame)) = (self.compare_case(), self.loaded.frame.clone()) else {
            return;
        };
        if self.loaded.detecting_b {
            self.compare_again = true;
            return;
        }
        if !self.may_run(case) {
            return;
        }
        self.loaded.detecting_b = true;
        let request = self.detect_request(frame, case, true);
        self.jobs.detect(request);
    }

    /// A finished run of the compare half.
    pub(super) fn apply_compare(
        &mut self,
        token: String,
        generation: u64,
        case: Case,
        result: Result<DetectOutput, String>,
        millis: f64,
        now: f64,
    ) {
        self.loaded.detecting_b = false;
        match result {
            Ok(out) => {
                let view = self.matched_on_screen(token, generation, case, out, millis);
                if let Some(view) = view.filter(|_| self.compare_case() == Some(case)) {
                    self.loaded.detection_b = Some(view);
                    self.rebuild_lines();
                }
            }
            Err(e) => {
                self.compare_again = false;
                self.toast(
                    now,
                    format!("cannot run {} (compare): {e}", case.paper_name()),
                    true,
                );
            }
        }
        if std::mem::take(&mut self.compare_again) {
            self.run_compare();
        }
    }

    /// The central panel split in two: the main view (with hover, selection and tooltips) on the
    /// left, the compare case on the right, one camera; each half labelled with its case and counts.
    pub(super) fn central_split(&mut self, ui: &mut egui::Ui) {
        let full = ui.available_rect_before_wrap();
        let half = ((full.width() - GAP) / 2.0).max(1.0);
        let left = egui::Rect::from_min_size(full.min, egui::vec2(half, full.height()));
        let right = egui::Rect::from_min_max(egui::pos2(full.max.x - half, full.min.y), full.max);
        let mut a = ui.new_child(egui::UiBuilder::new().max_rect(left).id_salt("mlod_view_a"));
        self.central_main(&mut a);
        let mut b = ui.new_child(egui::UiBuilder::new().max_rect(right).id_salt("mlod_view_b"));
        crate::render::show(&mut b, &mut self.view, &self.scene_b);
        let labels = self.scene_labels(false);
        let alpha = self.shell.play.map(|_| self.session.fuse.perturbation.alpha);
        crate::gui::overlay::annotate(b.painter(), right, &self.view.camera, &labels, alpha);
        ui.allocate_rect(full, egui::Sense::hover());
        let min_score = self.session.detection.min_score;
        let label = |case: Case, d: Option<&DetectionView>| match d {
            Some(d) => {
                let c = d.counts(min_score);
                format!(
                    "{}: {} TP · {} FP · {} of {} missed",
                    case.paper_name(),
                    c.true_positives,
                    c.false_positives,
                    c.missed,
                    c.ground_truth
                )
            }
            None => format!("{}: not run yet (Run / D)", case.paper_name()),
        };
        let painter = ui.painter();
        let a_text = label(self.session.detection.case, self.loaded.detection.as_ref());
        header(painter, left, a_text);
        if let Some(b) = self.compare_case() {
            header(painter, right, label(b, self.loaded.detection_b.as_ref()));
        }
        painter.rect_filled(
            egui::Rect::from_min_max(
                egui::pos2(left.max.x, full.min.y),
                egui::pos2(right.min.x, full.max.y),
            ),
            0.0,
            egui::Color32::from_gray(90),
        );
    }
}

/// A case's label at the top left of its half, on a dark plate.
fn header(painter: &egui::Painter, rect: egui::Rect, text: String) {
    let color = egui::Color32::from_gray(235);
    let galley = painter.layout_no_wrap(text, egui::FontId::proportional(15.0), color);
    let plate = egui::Rect::from_min_size(
        rect.min + egui::vec2(8.0, 8.0),
        galley.size() + egui::vec2(14.0, 8.0),
    );
    painter.rect_filled(plate, 4.0, egui::Color32::from_black_alpha(190));
    painter.galley(plate.min + egui::vec2(7.0, 4.0), galley, color);
}
