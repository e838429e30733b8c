//! What the panels ask for, carried out: files (sessions, exports, datasets dropped on the
//! window), presets, sample steps and the rest of [`Action`]. Every save and export ends in a
//! toast that names the file.

use std::path::PathBuf;

use eframe::egui;

use super::MlodApp;
use crate::gui::state::Action;
use crate::session::Session;

impl MlodApp {
    /// Carries out what the panels asked for, in order. `frame` gives the GPU device for the PNG
    /// export (none headlessly).
    pub fn apply_actions(&mut self, actions: Vec<Action>, now: f64, frame: Option<&eframe::Frame>) {
        for a in actions {
            match a {
                Action::OpenDataset(path) => self.open_dataset(path),
                Action::SelectSample(token) => self.select_sample(&token),
                Action::SaveSession(path) => match self.current_session().save(&path) {
                    Ok(()) => {
                        self.toast(now, format!("saved the session to {}", path.display()), false);
                        self.shell.session_file = Some(path);
                    }
                    Err(e) => self.toast(now, e.to_string(), true),
                },
                Action::LoadSession(path) => match Session::load(&path) {
                    Ok(s) => {
                        self.apply_session(s);
                        self.shell.session_file = Some(path);
                    }
                    Err(e) => self.toast(now, e.to_string(), true),
                },
                Action::ExportPng(path) => {
                    let result = match frame.and_then(|f| f.wgpu_render_state()) {
                        Some(rs) => crate::render::render_offscreen(
                            &rs.device,
                            &rs.queue,
                            &self.scene,
                            &self.view,
                            (1280, 800),
                        )
                        .map_err(|e| e.to_string())
                        .and_then(|img| crate::gui::write_png(&path, &img).map_err(|e| e.to_string())),
                        None => Err("no GPU device to render with".to_string()),
                    };
                    match result {
                        Ok(()) => self.toast(now, format!("wrote {}", path.display()), false),
                        Err(e) => self.toast(now, e, true),
                    }
                }
                Action::ExportCloud(path) => match self.export_cloud(&path) {
                    Ok(n) => self.toast(now, format!("wrote {} ({n} points)", path.display()), false),
                    Err(e) => self.toast(now, e, true),
                },
                Action::SetPreset(v) => self.set_preset(v),
                Action::StepSample(d) => self.step_sample(d),
                Action::Refuse => self.mark_fuse(),
                Action::ClearSelection => self.select_box(None),
                Action::CompareChanged => self.compare_changed(),
                Action::TogglePlay(alpha_to) => {
                    if self.shell.play.is_some() {
                        self.shell.play = None;
                    } else {
                        self.play_from_panel(alpha_to, now);
                    }
                }
                Action::ExportClip(path) => self.export_clip(path, now),
                Action::ToggleFailures => self.toggle_failures(),
                Action::ScanFailures => self.scan_failures(now),
                Action::CancelScan => self.cancel_scan(),
                Action::GoToFailure(f) => self.go_to_failure(&f),
                Action::OpenSweep(dir) => {
                    if let Err(e) = self.open_sweep(&dir) {
                        self.toast(now, format!("cannot open the sweep: {e}"), true);
                    }
                }
                Action::OpenModels(dir) => self.open_models(dir, now),
                Action::GateChanged => self.reload_detectors(),
                Action::FocusSelection => self.focus_selection(),
                Action::Recolor => self.needs_color = true,
                Action::RunDetector => self.run_detector(),
                Action::Calibrate => self.calibrate(),
                Action::CancelCalibration => self.cancel_calibration(now),
                Action::Rematch => self.rematch(),
                Action::RebuildLines => self.rebuild_lines(),
            }
        }
    }

    /// Writes the fused cloud on screen (all LiDARs, whatever is hidden) as PLY or PCD, by the
    /// extension: what `mlod export` writes for the same sample and perturbation.
    pub fn export_cloud(&self, path: &std::path::Path) -> Result<usize, String> {
        let (Some(frame), Some(cloud)) = (self.loaded.frame.as_deref(), self.loaded.fused.as_ref()) else {
            return Err("no sample on screen to export".into());
        };
        let format = crate::export::Format::from_path(path)
            .ok_or_else(|| format!("{}: give the file a .ply or .pcd extension", path.display()))?;
        let mut comment = crate::export::source_comment(
            &self.session.dataset,
            &frame.sample_token,
            &self.session.fuse_params(),
        );
        if !self.session.fuse.manual.is_empty() {
            comment.push_str(" (plus the window's manual offsets)");
        }
        let opts = crate::export::ExportOptions {
            format,
            covariance: None,
            comment: &comment,
        };
        crate::export::write(path, cloud, &opts).map_err(|e| e.to_string())?;
        Ok(cloud.len())
    }

    pub(super) fn handle_dropped_files(&mut self, ctx: &egui::Context) {
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
}
