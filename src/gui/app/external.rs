//! The app's side of external detectors: whether a case may run now (asking first for a
//! session's detector, `gui::consent`), the question's window, and the consents kept in the
//! window's storage.

use eframe::egui;

use super::MlodApp;
use crate::detect::Case;
use crate::gui::consent::Gate;

impl MlodApp {
    /// Whether `case` may run now. A session's external detector not agreed to yet becomes the
    /// pending question (nothing is started); an undefined one a notice.
    pub(super) fn may_run(&mut self, case: Case) -> bool {
        match self.consent.gate(case, &self.session) {
            Gate::Run => true,
            Gate::Ask => false,
            Gate::Undefined(why) => {
                self.consent_notice = Some(why);
                false
            }
        }
    }

    /// Draws the pending question and applies its answer (a yes runs the case); turns a notice
    /// into a toast.
    pub(super) fn consent_window(&mut self, ctx: &egui::Context, now: f64) {
        if let Some(why) = self.consent_notice.take() {
            self.toast(now, why, true);
        }
        let Some(answer) = self.consent.dialog(ctx, &self.session) else {
            return;
        };
        match self.consent.answer(answer, &self.session) {
            Ok(Some(case)) => {
                if self.session.detection.case == case {
                    self.run_detector();
                } else {
                    self.run_compare();
                }
            }
            Ok(None) => self.toast(now, "the external detector was not run", false),
            Err(e) => self.toast(now, e, true),
        }
    }

    /// Whether a question about an external detector is open (tests).
    pub fn consent_pending(&self) -> Option<String> {
        self.consent.pending.as_ref().map(|(s, _)| s.command_line())
    }

    /// The consents given, as the window stores them.
    pub(super) fn consents(&self) -> Vec<String> {
        self.consent.granted.iter().cloned().collect()
    }
}
