//! File > Open models folder…: the detectors run from another folder of weights (a user's own
//! training run, or an earlier set from git history). The
//! folder's manifest.json is read first; one that does not load leaves the window on the folder
//! it had, with the reason in a toast.

use std::path::PathBuf;

use super::MlodApp;
use crate::cases::ground_gate::GateChoice;
use crate::detect::weights::Manifest;

impl MlodApp {
    /// Switches the detectors to the models folder `dir`: the loaded detectors are dropped, the
    /// folder's ground gate and the dataset's notes against its training data are read again, and
    /// a detection on screen (or in flight) runs again from the new folder.
    pub fn open_models(&mut self, dir: PathBuf, now: f64) {
        let manifest = match Manifest::load(&dir) {
            Ok(m) => m,
            Err(e) => {
                self.toast(now, format!("cannot open the models folder: {e}"), true);
                return;
            }
        };
        self.models_dir = dir.clone();
        self.session.models = Some(dir.clone());
        self.loaded.models = dir.clone();
        self.loaded.ground_gate_m = manifest.ground_gate_m();
        self.loaded.models_adapted = manifest.adapted_summary();
        if let Some(ds) = self.loaded.dataset.clone() {
            self.loaded.depth_notes.clear();
            self.jobs
                .depth_notes(self.session.dataset.clone(), ds, dir.clone());
        }
        let adapted = self
            .loaded
            .models_adapted
            .as_deref()
            .map_or(String::new(), |a| format!(", {a}"));
        self.toast(now, format!("detectors from {}{adapted}", dir.display()), false);
        self.reload_detectors();
    }

    /// The ground gate the stage-1 cases run behind: the models folder's, unless the Detection
    /// panel switched it off.
    pub(super) fn gate_choice(&self) -> GateChoice {
        if self.session.detection.ground_gate {
            GateChoice::Manifest
        } else {
            GateChoice::Off
        }
    }

    /// The models folder or the ground gate changed: the detectors load again, and a detection on
    /// screen (or in flight) runs again.
    pub fn reload_detectors(&mut self) {
        self.detectors.clear();
        let shown = self.loaded.detection.is_some() || self.loaded.detection_b.is_some();
        if shown || self.loaded.detecting {
            self.run_detector();
        }
    }

    /// The models folder the detectors run from.
    pub fn models_dir(&self) -> &std::path::Path {
        &self.models_dir
    }
}
