//! `mlod gui --measure-frames N [--measure-run]`: frame times of the real window, idle, then
//! (with `--measure-run`) while the session's case runs and while a scene is scanned for failure
//! cases, and the time from Run to the boxes on screen.

use std::time::Instant;

use eframe::egui;

use super::MlodApp;

impl MlodApp {
    /// Frame-time measurement (see [`AppOptions::measure_frames`]): starts once a sample is drawn.
    pub(super) fn measure_frame(&mut self, ctx: &egui::Context) {
        if self.measure.is_none() {
            return;
        }
        if self.loaded.fused.is_none() {
            ctx.request_repaint();
            return;
        }
        let busy = self.loaded.detecting || self.shell.failures.as_ref().is_some_and(|b| b.running.is_some());
        let has_boxes = self.loaded.detection.is_some();
        let points = self.loaded.fused.as_ref().map_or(0, |c| c.len());
        let Some(m) = self.measure.as_mut() else { return };
        m.stamps.push(Instant::now());
        let next = match m.phase {
            MeasurePhase::Idle if m.stamps.len() > m.frames => {
                m.report.push(frame_stats("idle", &m.stamps, points));
                m.run.then_some(MeasurePhase::Detect)
            }
            MeasurePhase::Detect if !busy && has_boxes => {
                m.report.push(format!(
                    "run to boxes on screen: {:.0} ms",
                    m.started.elapsed().as_secs_f64() * 1e3
                ));
                m.report.push(frame_stats("while detecting", &m.stamps, points));
                Some(MeasurePhase::Scan)
            }
            MeasurePhase::Scan if !busy => {
                m.report.push(format!(
                    "scene scan: {:.0} ms",
                    m.started.elapsed().as_secs_f64() * 1e3
                ));
                m.report.push(frame_stats("while scanning", &m.stamps, points));
                None
            }
            _ => {
                ctx.request_repaint();
                return;
            }
        };
        match next {
            Some(phase) => {
                m.phase = phase;
                m.stamps.clear();
                m.started = Instant::now();
                ctx.request_repaint();
                match phase {
                    MeasurePhase::Detect => {
                        self.loaded.detection = None;
                        self.run_detector();
                    }
                    MeasurePhase::Scan => {
                        self.shell.failures.get_or_insert_with(Default::default);
                        self.scan_failures(0.0);
                    }
                    MeasurePhase::Idle => {}
                }
            }
            None => {
                for line in &m.report {
                    eprintln!("{line}");
                }
                self.measure = None;
                ctx.send_viewport_cmd(egui::ViewportCommand::Close);
            }
        }
    }
}

/// Mean, p50 and p95 of the frame times between `stamps`.
fn frame_stats(what: &str, stamps: &[Instant], points: usize) -> String {
    let mut dt: Vec<f64> = stamps
        .windows(2)
        .map(|w| (w[1] - w[0]).as_secs_f64() * 1e3)
        .collect();
    if dt.is_empty() {
        return format!("{what}: no frame");
    }
    dt.sort_by(f64::total_cmp);
    let mean = dt.iter().sum::<f64>() / dt.len() as f64;
    let pct = |q: f64| dt[((dt.len() - 1) as f64 * q).round() as usize];
    format!(
        "{what}: frames: {}  points: {points}  mean {mean:.1} ms  p50 {:.1} ms  p95 {:.1} ms",
        dt.len(),
        pct(0.5),
        pct(0.95)
    )
}

/// The phases of `--measure-frames` (with `--measure-run`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum MeasurePhase {
    Idle,
    Detect,
    Scan,
}

/// A frame-time measurement in progress.
pub(super) struct Measure {
    frames: usize,
    run: bool,
    phase: MeasurePhase,
    stamps: Vec<Instant>,
    report: Vec<String>,
    started: Instant,
}

impl Measure {
    /// `frames` idle frames, then (with `run`) a detection and a scene scan.
    pub(super) fn new(frames: usize, run: bool) -> Self {
        Self {
            frames,
            run,
            phase: MeasurePhase::Idle,
            stamps: Vec::with_capacity(frames + 1),
            report: Vec::new(),
            started: Instant::now(),
        }
    }
}
