//! The app's online-calibration half: "calibrate (ICP)" runs `pipeline::calibrate` on a worker
//! thread (Escape cancels: the result is dropped when it arrives), the result is kept in the
//! session so a saved session reopens with the same corrected extrinsics, and the view fuses with
//! them while "show corrected cloud" is on. A calibration belongs to one sample and one drift:
//! when either changes it is dropped (the fuse refuses a stale one). An (OC) case that finds no
//! calibration calibrates first and then detects.

use super::MlodApp;
use crate::calib::Calibration;
use crate::pipeline::PipelineError;

impl MlodApp {
    /// Starts calibrating the sample on screen (drifted as the session says).
    pub fn calibrate(&mut self) {
        let Some(frame) = self.loaded.frame.clone() else {
            return;
        };
        self.calib_seq += 1;
        self.loaded.calibrating = Some(self.calib_seq);
        let mut params = self.session.fuse.clone();
        params.calibration = None;
        self.jobs
            .calibrate(self.calib_seq, frame, params, self.session.oc.prior);
    }

    /// Cancels the calibration in flight (its result will be dropped).
    pub fn cancel_calibration(&mut self, now: f64) {
        if self.loaded.calibrating.take().is_some() {
            self.detect_after_calibration = false;
            self.toast(now, "calibration cancelled", false);
        }
    }

    /// Whether a calibration is in flight.
    pub fn is_calibrating(&self) -> bool {
        self.loaded.calibrating.is_some()
    }

    /// A finished calibration: shown (corrected cloud on) if it is the one asked for and its
    /// sample is still on screen.
    pub(super) fn apply_calibration(
        &mut self,
        id: u64,
        token: String,
        result: Result<Calibration, String>,
        millis: f64,
        now: f64,
    ) {
        if self.loaded.calibrating != Some(id) {
            return;
        }
        self.loaded.calibrating = None;
        let on_screen = self
            .loaded
            .frame
            .as_ref()
            .is_some_and(|f| f.sample_token == token);
        match result {
            Ok(cal) if on_screen => {
                self.loaded.calibrate_ms = millis;
                self.session.oc.calibration = Some(cal);
                self.session.oc.show_corrected = true;
                self.session.oc.show_factory = false;
                self.refuse_now(now, false);
                if std::mem::take(&mut self.detect_after_calibration) {
                    self.run_detector();
                }
            }
            Ok(_) => self.detect_after_calibration = false,
            Err(e) => {
                self.detect_after_calibration = false;
                self.toast(now, format!("cannot calibrate: {e}"), true);
            }
        }
    }

    /// Whether the session's calibration is for the sample on screen and its current drift.
    pub(super) fn calibration_is_current(&self) -> bool {
        let (Some(frame), Some(cal)) = (self.loaded.frame.as_deref(), &self.session.oc.calibration) else {
            return false;
        };
        // The fuse's own check (`LidarCalibration::started_from`), without fusing.
        cal.sample_token == frame.sample_token
            && frame
                .auxiliaries
                .iter()
                .all(|scan| match cal.lidar(scan.info.channel) {
                    Some(l) => self
                        .session
                        .fuse
                        .noise_for(scan.info.channel)
                        .is_ok_and(|n| l.started_from(&n.apply(&scan.info.extrinsic))),
                    None => false,
                })
    }

    /// A fuse error that says the calibration no longer fits: drop it and fuse without.
    pub(super) fn drop_stale_calibration(&mut self, e: &PipelineError) -> bool {
        if matches!(e, PipelineError::StaleCalibration(_)) {
            self.session.oc.calibration = None;
            self.session.oc.show_corrected = false;
            true
        } else {
            false
        }
    }
}
