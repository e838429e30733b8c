//! The demo half of the app: "play α" (α stepped from 0 in equal steps, re-fusing and, with
//! auto-run, re-detecting at each), exporting it as a GIF in the background, and the sweep window's
//! folder.

use std::path::PathBuf;

use super::{AppOptions, MlodApp};
use crate::gui::clip::{play_target, PLAY_FRAMES};

impl MlodApp {
    /// Opens the session's sweep folder, if any (an error is a toast and closes it).
    pub(super) fn reopen_sweep(&mut self, now: f64) {
        self.shell.sweep = None;
        if let Some(dir) = self.session.sweep.clone() {
            if let Err(e) = self.open_sweep(&dir) {
                self.session.sweep = None;
                self.toast(now, format!("cannot open the sweep: {e}"), true);
            }
        }
    }

    /// Reads a sweep folder (finished or not) and opens the sweep window on it; an error keeps
    /// the window as it was.
    pub fn open_sweep(&mut self, dir: &std::path::Path) -> Result<(), crate::analysis::sweep::SweepError> {
        let progress = crate::analysis::sweep::progress(dir)?;
        self.session.sweep = Some(dir.to_path_buf());
        self.shell.sweep = Some(crate::gui::state::SweepView {
            dir: dir.to_path_buf(),
            progress,
        });
        Ok(())
    }

    /// The sweep the sweep window shows.
    pub fn open_sweep_view(&self) -> Option<&crate::gui::state::SweepView> {
        self.shell.sweep.as_ref()
    }

    /// Starts "play α": α from 0 to `alpha_to` in `frames` steps.
    pub fn start_play(&mut self, alpha_to: f64, frames: usize) {
        if alpha_to.is_finite() && alpha_to > 0.0 && frames >= 2 {
            self.shell.play = Some(crate::gui::state::Play {
                alpha_to,
                frames,
                next: 0,
            });
        }
    }

    /// "Play α" asked from the panel: an ICP calibration fits one drift only, so it cannot follow
    /// α; the toast says so rather than dropping it silently (calibrate again where α stops).
    pub(super) fn play_from_panel(&mut self, alpha_to: f64, now: f64) {
        if self.session.oc.calibration.is_some() {
            let alpha = self.session.fuse.perturbation.alpha;
            self.toast(
                now,
                format!(
                    "play α: the ICP calibration was estimated at α = {alpha} and fits that drift \
                     only, so the animation shows the drifted cloud; calibrate again where α stops"
                ),
                false,
            );
        }
        self.start_play(alpha_to, PLAY_FRAMES);
    }

    /// Whether "play α" is running.
    pub fn is_playing(&self) -> bool {
        self.shell.play.is_some()
    }

    /// One step of "play α" once the previous one is on screen; true if it stepped.
    pub(super) fn advance_play(&mut self) -> bool {
        let Some(mut play) = self.shell.play else {
            return false;
        };
        if self.is_busy() || self.is_calibrating() {
            return false;
        }
        self.session.fuse.perturbation.alpha = play.alpha(play.next);
        self.mark_fuse();
        play.next += 1;
        self.shell.play = (play.next < play.frames).then_some(play);
        true
    }

    /// Renders "play α" of the current view to a GIF in the background.
    pub(super) fn export_clip(&mut self, path: PathBuf, now: f64) {
        let alpha = self.session.fuse.perturbation.alpha;
        let clip = crate::gui::clip::ClipOptions {
            alpha_to: play_target(alpha),
            frames: PLAY_FRAMES,
            ..Default::default()
        };
        let options = AppOptions {
            dataset: self.session.dataset.clone(),
            session: Some(self.current_session()),
            synchronous: true,
            measure_frames: None,
            measure_run: false,
            models: Some(self.models_dir.clone()),
            session_file: None,
        };
        self.toast(
            now,
            format!("rendering {} frames to {}…", clip.frames, path.display()),
            false,
        );
        self.jobs.clip(options, clip, path);
    }
}
