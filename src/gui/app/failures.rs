//! The failure browser's app side: a scan of the session's case over the scene on screen or the
//! whole dataset, at the session's perturbation, in the background (progress, cancel); and going
//! to a failure — its sample loaded with the same perturbation, the case run, the box selected
//! (the ground truth of a miss, the final box of a false positive or an IoU drop) and focused.

use std::sync::atomic::{AtomicBool, AtomicUsize};
use std::sync::Arc;

use super::MlodApp;
use crate::analysis::failures::{BoxFailure, FailureKind, SampleFailures, ScanConfig};
use crate::gui::state::FailureBrowser;
use crate::session::{BoxLayer, BoxSelection, FailureScope};

impl MlodApp {
    /// Opens the failure browser, or closes it (cancelling a scan in flight).
    pub fn toggle_failures(&mut self) {
        match self.shell.failures.take() {
            Some(b) => {
                if let Some((_, _, _, cancel)) = b.running {
                    cancel.store(true, std::sync::atomic::Ordering::Relaxed);
                }
            }
            None => self.shell.failures = Some(FailureBrowser::default()),
        }
    }

    /// Opens the browser a session names and scans once the sample is on screen.
    pub(super) fn reopen_failures(&mut self) {
        self.shell.failures = self.session.failures.map(|scope| FailureBrowser {
            scope,
            ..Default::default()
        });
        self.scan_on_load = self.session.failures.is_some();
    }

    /// The failure browser, if open.
    pub fn failure_browser(&self) -> Option<&FailureBrowser> {
        self.shell.failures.as_ref()
    }

    /// Sets the scope of the next scan (opening the browser if needed).
    pub fn set_scan_scope(&mut self, scope: FailureScope) {
        self.shell
            .failures
            .get_or_insert_with(FailureBrowser::default)
            .scope = scope;
    }

    /// The samples a scan of `scope` covers, in dataset order.
    fn scan_tokens(&self, scope: FailureScope) -> Vec<String> {
        let scene = self.loaded.frame.as_ref().and_then(|f| {
            self.loaded
                .samples
                .iter()
                .find(|s| s.sample_token == f.sample_token)
                .map(|s| s.scene_token.clone())
        });
        self.loaded
            .samples
            .iter()
            .filter(|s| scope == FailureScope::Dataset || Some(&s.scene_token) == scene.as_ref())
            .map(|s| s.sample_token.clone())
            .collect()
    }

    /// Starts a scan of the session's case over the browser's scope (a scan in flight is
    /// cancelled first).
    pub fn scan_failures(&mut self, now: f64) {
        let Some(dataset) = self.loaded.dataset.clone() else {
            return;
        };
        let browser = self.shell.failures.get_or_insert_with(FailureBrowser::default);
        if let Some((_, _, _, cancel)) = browser.running.take() {
            cancel.store(true, std::sync::atomic::Ordering::Relaxed);
        }
        let scope = browser.scope;
        let case = self.session.detection.case;
        if case.is_oc() {
            self.toast(
                now,
                format!("{}: scan its case without (OC)", case.paper_name()),
                true,
            );
            return;
        }
        let cfg = ScanConfig {
            case,
            params: self.session.fuse.clone(),
            tokens: self.scan_tokens(scope),
            match_iou: self.session.detection.match_iou,
            min_score: self.session.detection.min_score,
            set_intensity: None,
        };
        self.scan_seq += 1;
        let id = self.scan_seq;
        let done = Arc::new(AtomicUsize::new(0));
        let cancel = Arc::new(AtomicBool::new(false));
        let total = cfg.tokens.len();
        if let Some(b) = self.shell.failures.as_mut() {
            b.running = Some((id, done.clone(), total, cancel.clone()));
            b.scanning = Some((case, cfg.params.perturbation.alpha, cfg.params.perturbation.seed));
        }
        let models = self.models_dir.clone();
        self.jobs
            .scan(id, dataset, (models, self.gate_choice()), cfg, done, cancel);
    }

    /// Stops the scan in flight (its result is dropped).
    pub fn cancel_scan(&mut self) {
        if let Some(b) = self.shell.failures.as_mut() {
            if let Some((_, _, _, cancel)) = b.running.take() {
                cancel.store(true, std::sync::atomic::Ordering::Relaxed);
            }
            b.scanning = None;
        }
    }

    /// A finished scan: kept if it is the one the browser waits for.
    pub(super) fn apply_scan(
        &mut self,
        id: u64,
        result: Result<Vec<SampleFailures>, String>,
        millis: f64,
        now: f64,
    ) {
        let Some(b) = self.shell.failures.as_mut() else {
            return;
        };
        if b.running.as_ref().map(|r| r.0) != Some(id) {
            return;
        }
        b.running = None;
        b.millis = millis;
        let Some(params) = b.scanning.take() else { return };
        match result {
            Ok(rows) => b.result = Some((params.0, params.1, params.2, rows)),
            Err(e) => self.toast(now, format!("failure scan: {e}"), true),
        }
    }

    /// Loads a failure's sample (same perturbation), runs the case and selects and focuses the
    /// box once it is on screen.
    pub fn go_to_failure(&mut self, f: &BoxFailure) {
        // The scan's case and exact perturbation.
        if let Some((case, alpha, seed)) = self
            .shell
            .failures
            .as_ref()
            .and_then(|b| b.result.as_ref())
            .map(|r| (r.0, r.1, r.2))
        {
            let p = &mut self.session.fuse.perturbation;
            if (self.session.detection.case, p.alpha, p.seed) != (case, alpha, seed) {
                self.session.detection.case = case;
                p.alpha = alpha;
                p.seed = seed;
                self.refuse_now(0.0, false);
            }
        }
        let final_layer = if self.session.detection.case.is_mlod() {
            BoxLayer::Refined
        } else {
            BoxLayer::Proposal
        };
        let layer = match f.kind {
            FailureKind::Missed => BoxLayer::Truth,
            FailureKind::FalsePositive | FailureKind::IouDrop => final_layer,
        };
        let selection = BoxSelection {
            layer,
            annotation: f.annotation.clone(),
            center: f.center,
            category: f.category.clone(),
        };
        self.focus_pending = true;
        let on_screen = self
            .loaded
            .frame
            .as_ref()
            .is_some_and(|fr| fr.sample_token == f.sample_token);
        if on_screen {
            self.session.selection = Some(selection);
            self.resolve_selection();
            if self.loaded.detection_is_stale(self.session.detection.case) || self.loaded.detection.is_none()
            {
                self.run_detector();
            }
        } else {
            self.pending_selection = Some(selection);
            self.detect_on_load = true;
            self.select_sample(&f.sample_token);
        }
    }
}
