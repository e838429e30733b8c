//! The panels around the viewport: menu, sample browser, perturbation / colour / view controls
//! (with the tr(Ξ) legend and histogram), status bar, help overlay and toasts. They draw from a
//! [`Panels`] view of the state, edit the session and ask for the rest as [`Action`]s; they
//! compute nothing and know nothing of the app.

use std::path::PathBuf;

use eframe::egui;
use egui::{Color32, RichText, Sense, Stroke};

mod banner;
mod calibration;
mod detection;
mod failures;
mod selection;
mod sweep;

pub use banner::banner;
use banner::NO_AUXILIARY;
pub use failures::failure_window;
pub use sweep::sweep_window;

use super::state::{channel_counts, color32, lidar_label, Action, Loaded, Shell, GT_COLOR};
use super::viewport::{Projection, View, Viewport, CONTROLS_HELP};
use crate::color::{normalize, ticks, turbo, ColorMode, Scale, HIGHLIGHT};
use crate::dataset::LidarChannel;
use crate::session::Session;
use crate::uncertainty::{ExtrinsicNoise, Linearization, UNCERTAIN_TRACE};

/// The paper's perturbation levels (Table II).
const ALPHA_MARKS: [f64; 4] = [0.0, 0.02, 0.04, 0.1];

/// What the panels see and may edit, and the actions they ask for.
pub struct Panels<'a> {
    pub session: &'a mut Session,
    pub view: &'a mut Viewport,
    pub shell: &'a mut Shell,
    pub loaded: &'a Loaded,
    pub actions: Vec<Action>,
}

impl Panels<'_> {
    fn act(&mut self, a: Action) {
        self.actions.push(a);
    }
}

/// A file dialog's answer: a path to save to (with `name` as the suggested file name), or none.
fn save_dialog(title: &str, filter: (&str, &[&str]), name: &str) -> Option<PathBuf> {
    rfd::FileDialog::new()
        .set_title(title)
        .add_filter(filter.0, filter.1)
        .set_file_name(name)
        .save_file()
}

/// The keyboard shortcuts (when no text field has the focus): D runs the detector, ←/→ step
/// through the samples, B toggles bird's eye, F points the camera at the selected box, F1 or ?
/// the help, Esc closes it (or cancels a calibration, or clears the selection).
pub fn keys(p: &mut Panels<'_>, ctx: &egui::Context) {
    if ctx.egui_wants_keyboard_input() {
        return;
    }
    let (detect, left, right, help, esc, bev, focus) = ctx.input(|i| {
        (
            i.key_pressed(egui::Key::D),
            i.key_pressed(egui::Key::ArrowLeft),
            i.key_pressed(egui::Key::ArrowRight),
            i.key_pressed(egui::Key::F1)
                || i.events
                    .iter()
                    .any(|e| matches!(e, egui::Event::Text(t) if t == "?")),
            i.key_pressed(egui::Key::Escape),
            i.key_pressed(egui::Key::B),
            i.key_pressed(egui::Key::F),
        )
    });
    if focus {
        p.act(Action::FocusSelection);
    }
    if detect {
        p.act(Action::RunDetector);
    }
    if left {
        p.act(Action::StepSample(-1));
    }
    if right {
        p.act(Action::StepSample(1));
    }
    if help {
        p.shell.show_help = !p.shell.show_help;
    }
    if esc {
        // Escape undoes the most recent thing first: the help, a calibration in flight, then the
        // selection.
        if p.shell.show_help {
            p.shell.show_help = false;
        } else if p.loaded.calibrating.is_some() {
            p.act(Action::CancelCalibration);
        } else if p.loaded.selected.is_some() || p.session.selection.is_some() {
            p.act(Action::ClearSelection);
        }
    }
    if bev {
        let v = if p.view.camera.projection == Projection::BirdsEye {
            View::Overview
        } else {
            View::Bev
        };
        p.act(Action::SetPreset(v));
    }
}

pub fn menu_bar(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    egui::Panel::top("menu").show(ui, |ui| {
        egui::MenuBar::new().ui(ui, |ui| {
            ui.menu_button("File", |ui| {
                if ui.button("Open dataset…").clicked() {
                    if let Some(dir) = rfd::FileDialog::new()
                        .set_title("Open a Lyft-format dataset")
                        .pick_folder()
                    {
                        p.act(Action::OpenDataset(dir));
                    }
                }
                ui.menu_button("Recent datasets", |ui| {
                    let recent: Vec<PathBuf> = p.shell.recent.clone();
                    if recent.is_empty() {
                        ui.label("none yet");
                    }
                    for path in recent {
                        if ui.button(path.display().to_string()).clicked() {
                            p.act(Action::OpenDataset(path));
                        }
                    }
                });
                ui.separator();
                if ui
                    .button("Open sweep results…")
                    .on_hover_text("A folder written by `mlod sweep --out`: its AP-against-α plot")
                    .clicked()
                {
                    ui.close();
                    if let Some(dir) = rfd::FileDialog::new()
                        .set_title("Open a sweep folder")
                        .pick_folder()
                    {
                        p.act(Action::OpenSweep(dir));
                    }
                }
                if ui.button("Save session…").clicked() {
                    if let Some(path) = save_dialog("Save session", ("session", &["json"]), "session.json") {
                        p.act(Action::SaveSession(path));
                    }
                }
                if ui.button("Load session…").clicked() {
                    if let Some(path) = rfd::FileDialog::new()
                        .add_filter("session", &["json"])
                        .pick_file()
                    {
                        p.act(Action::LoadSession(path));
                    }
                }
                ui.separator();
                if ui.button("Export viewport PNG…").clicked() {
                    if let Some(path) = save_dialog("Export viewport", ("PNG", &["png"]), "viewport.png") {
                        p.act(Action::ExportPng(path));
                    }
                }
                let can_export = p.loaded.fused.is_some();
                if ui
                    .add_enabled(can_export, egui::Button::new("Export fused cloud…"))
                    .on_hover_text(
                        "The fused, perturbed cloud with per-point LiDAR and tr(Ξ): PLY (CloudCompare, \
                         Open3D) or PCD (PCL), chosen by the extension",
                    )
                    .clicked()
                {
                    if let Some(path) = rfd::FileDialog::new()
                        .set_title("Export fused cloud")
                        .add_filter("PLY", &["ply"])
                        .add_filter("PCD", &["pcd"])
                        .set_file_name("fused.ply")
                        .save_file()
                    {
                        p.act(Action::ExportCloud(path));
                    }
                }
                ui.separator();
                if ui.button("Quit").clicked() {
                    ui.ctx().send_viewport_cmd(egui::ViewportCommand::Close);
                }
            });
            ui.menu_button("View", |ui| {
                for v in View::ALL {
                    if ui.button(v.name()).clicked() {
                        p.act(Action::SetPreset(v));
                    }
                }
            });
            ui.menu_button("Help", |ui| {
                if ui.button("Keyboard and mouse (F1)").clicked() {
                    p.shell.show_help = true;
                }
            });
            ui.separator();
            ui.label(RichText::new("MLOD debugger").strong());
            let name = p
                .session
                .dataset
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            ui.label(RichText::new(name).weak())
                .on_hover_text(p.session.dataset.display().to_string());
        });
    });
}

pub fn status_bar(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    egui::Panel::bottom("status").show(ui, |ui| {
        ui.horizontal(|ui| {
            match (&p.loaded.frame, &p.loaded.fused) {
                (Some(f), Some(c)) => {
                    ui.label(format!("{} points", c.len()));
                    for (ch, n) in channel_counts(c) {
                        ui.label(lidar_label(ch));
                        ui.label(format!("{n}"));
                    }
                    ui.separator();
                    ui.label(format!("{} boxes", f.boxes.len()));
                    ui.separator();
                    if p.shell.show_timings {
                        ui.label(format!(
                            "load {:.0} ms · fuse + tr(Ξ) + colour {:.1} ms",
                            p.loaded.frame_ms, p.loaded.fuse_ms
                        ));
                    }
                }
                _ => {
                    ui.label("no sample");
                }
            }
            ui.with_layout(egui::Layout::right_to_left(egui::Align::Center), |ui| {
                ui.label(RichText::new("F1: help").weak());
            });
        });
    });
}

pub fn sample_browser(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    ui.heading("Samples");
    ui.label(RichText::new("Left / Right arrow keys step through samples").weak());
    ui.separator();
    let current = p.loaded.frame.as_ref().map(|f| f.sample_token.clone());
    let mut clicked = None;
    egui::ScrollArea::vertical().show(ui, |ui| {
        let mut last_scene = String::new();
        for (i, s) in p.loaded.samples.iter().enumerate() {
            if s.scene_name != last_scene {
                ui.add_space(4.0);
                ui.label(RichText::new(format!("scene {}", s.scene_name)).strong().small());
                last_scene = s.scene_name.clone();
            }
            let selected = current.as_deref() == Some(s.sample_token.as_str());
            let tags: String = s
                .lidar_channels
                .iter()
                .map(|c| match c.as_str() {
                    "LIDAR_TOP" => "T",
                    "LIDAR_FRONT_LEFT" => "L",
                    "LIDAR_FRONT_RIGHT" => "R",
                    _ => "?",
                })
                .collect();
            let text = format!(
                "#{i:<3} {}…  {tags}  {} obj",
                &s.sample_token[..s.sample_token.len().min(8)],
                s.num_boxes
            );
            if ui
                .selectable_label(selected, RichText::new(text).monospace())
                .clicked()
            {
                clicked = Some(s.sample_token.clone());
            }
        }
    });
    if let Some(t) = clicked {
        p.act(Action::SelectSample(t));
    }
}

pub fn controls(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    egui::ScrollArea::vertical().show(ui, |ui| {
        perturbation(p, ui);
        ui.separator();
        detection::detection(p, ui);
        selection::selection(p, ui);
        ui.separator();
        coloring(p, ui);
        ui.separator();
        view_controls(p, ui);
    });
}

fn perturbation(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    ui.heading("Extrinsic perturbation");
    // A LIDAR_TOP-only sample has nothing to perturb: the controls stay visible but off.
    let has_aux = p.loaded.frame.as_ref().is_none_or(|f| !f.is_single_lidar());
    // Disabled widgets still take accessibility actions (a screen reader's "set value"): on a
    // LIDAR_TOP-only sample whatever they changed is undone.
    let before = (!has_aux).then(|| p.session.fuse.clone());
    let acted = p.actions.len();
    ui.add_enabled_ui(has_aux, |ui| perturbation_controls(p, ui, has_aux));
    if let Some(before) = before {
        p.session.fuse = before;
        p.actions.truncate(acted);
    }
    if !has_aux {
        ui.label(RichText::new("off: this sample has LIDAR_TOP only").weak())
            .on_hover_text(NO_AUXILIARY);
    }
    ui.add_space(4.0);
    calibration::calibration(p, ui);
}

fn perturbation_controls(p: &mut Panels<'_>, ui: &mut egui::Ui, has_aux: bool) {
    let fp = &mut p.session.fuse;
    let mut changed = false;
    let why = |r: egui::Response| {
        if has_aux {
            r
        } else {
            r.on_disabled_hover_text(NO_AUXILIARY)
        }
    };
    changed |= why(ui.add(
        egui::Slider::new(&mut fp.perturbation.alpha, 0.0..=0.1)
            .text("α")
            .step_by(0.001)
            .fixed_decimals(3),
    ))
    .changed();
    ui.horizontal(|ui| {
        ui.label(RichText::new("paper levels").weak());
        for a in ALPHA_MARKS {
            if why(ui.selectable_label(fp.perturbation.alpha == a, format!("{a}"))).clicked() {
                fp.perturbation.alpha = a;
                changed = true;
            }
        }
    });
    let alpha_now = fp.perturbation.alpha;
    let mut toggle = None;
    let mut clip = None;
    ui.horizontal(|ui| {
        let to = crate::gui::clip::play_target(alpha_now);
        let play = if p.shell.play.is_some() {
            "stop playing".to_string()
        } else {
            format!("play α 0 to {to}")
        };
        if why(ui.button(play).on_hover_text(
            "Animate α from 0 in 40 steps (same seed: the same drift, scaled), re-fusing, \
                 recolouring and, with \"run again on every change\", re-detecting",
        ))
        .clicked()
        {
            toggle = Some(to);
        }
        if ui
            .button("export clip…")
            .on_hover_text("Write the same animation of this view as an animated GIF (like `mlod clip`)")
            .clicked()
        {
            clip = save_dialog("Export clip", ("GIF", &["gif"]), "clip.gif");
        }
    });
    if let Some(to) = toggle {
        p.act(Action::TogglePlay(to));
    }
    if let Some(path) = clip {
        p.act(Action::ExportClip(path));
    }
    let fp = &mut p.session.fuse;
    ui.horizontal(|ui| {
        let label = ui.label("seed");
        changed |= ui
            .add(egui::DragValue::new(&mut fp.perturbation.seed))
            .labelled_by(label.id)
            .changed();
        if ui
            .button("resample")
            .on_hover_text("draw a new perturbation (next seed)")
            .clicked()
        {
            fp.perturbation.seed = fp.perturbation.seed.wrapping_add(1);
            changed = true;
        }
    });
    let mut decoupled = fp.prior_alpha.is_some();
    if ui
        .checkbox(&mut decoupled, "prior assumes another α")
        .on_hover_text(
            "compute Ξ with a different α than the one that perturbed the points (a mis-specified prior)",
        )
        .changed()
    {
        fp.prior_alpha = decoupled.then_some(fp.perturbation.alpha);
        changed = true;
    }
    if let Some(pa) = &mut fp.prior_alpha {
        changed |= ui
            .add(
                egui::Slider::new(pa, 0.0..=0.1)
                    .text("prior α")
                    .step_by(0.001)
                    .fixed_decimals(3),
            )
            .changed();
    }
    ui.horizontal(|ui| {
        ui.label("linearisation");
        for lin in Linearization::ALL {
            changed |= ui.radio_value(&mut fp.linearization, lin, lin.name()).changed();
        }
    });
    for ch in [LidarChannel::FrontLeft, LidarChannel::FrontRight] {
        let sampled = p.session.sampled.get(&ch).copied();
        egui::CollapsingHeader::new(lidar_label(ch))
            .id_salt(ch.as_str())
            .default_open(false)
            .show(ui, |ui| {
                if let Some(n) = sampled {
                    ui.label(RichText::new("applied perturbation (sampled + manual)").weak());
                    ui.monospace(format!(
                        "ρ = ({:+.1}, {:+.1}, {:+.1}) cm",
                        n.rho[0] * 100.0,
                        n.rho[1] * 100.0,
                        n.rho[2] * 100.0
                    ));
                    ui.monospace(format!(
                        "φ = ({:+.3}, {:+.3}, {:+.3})°",
                        n.phi[0].to_degrees(),
                        n.phi[1].to_degrees(),
                        n.phi[2].to_degrees()
                    ));
                }
                ui.label(RichText::new("manual offset (added)").weak());
                let m = p.session.fuse.manual.entry(ch).or_default();
                let mut deg = m.phi.map(f64::to_degrees);
                let mut cm = m.rho.map(|v| v * 100.0);
                changed |= drag_row(ui, &mut deg, ["roll", "pitch", "yaw"], 0.05, 10.0, "°");
                changed |= drag_row(ui, &mut cm, ["x", "y", "z"], 0.5, 100.0, " cm");
                *m = ExtrinsicNoise {
                    rho: cm.map(|v| v / 100.0),
                    phi: deg.map(f64::to_radians),
                };
                if ui.small_button("reset offset").clicked() {
                    *m = ExtrinsicNoise::ZERO;
                    changed = true;
                }
            });
    }
    p.session.fuse.manual.retain(|_, n| *n != ExtrinsicNoise::ZERO);
    if changed {
        p.act(Action::Refuse);
    }
}

/// Three labelled drag values in a row, each within ±`limit`; true if any changed.
fn drag_row(
    ui: &mut egui::Ui,
    values: &mut [f64; 3],
    names: [&str; 3],
    speed: f64,
    limit: f64,
    suffix: &str,
) -> bool {
    let mut changed = false;
    ui.horizontal(|ui| {
        for (v, name) in values.iter_mut().zip(names) {
            let widget = egui::DragValue::new(v)
                .speed(speed)
                .range(-limit..=limit)
                .suffix(suffix)
                .prefix(format!("{name} "));
            changed |= ui.add(widget).changed();
        }
    });
    changed
}

fn coloring(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    ui.heading("Colour");
    let c = &mut p.session.color;
    let mut changed = false;
    ui.horizontal_wrapped(|ui| {
        for m in ColorMode::ALL {
            changed |= ui.radio_value(&mut c.mode, m, m.label()).changed();
        }
    });
    if changed {
        // The user's choice outlives the first-sight switch to tr(Ξ).
        p.shell.auto_color = false;
    }
    if c.mode != ColorMode::Source {
        ui.horizontal(|ui| {
            changed |= ui.radio_value(&mut c.scale, Scale::Linear, "linear").changed();
            changed |= ui.radio_value(&mut c.scale, Scale::Log, "log").changed();
            changed |= ui.checkbox(&mut p.session.auto_range, "auto range").changed();
        });
        if !p.session.auto_range {
            ui.horizontal(|ui| {
                let (lo, hi) = &mut c.range;
                changed |= ui
                    .add(egui::DragValue::new(lo).speed(0.001).prefix("min "))
                    .changed();
                changed |= ui
                    .add(egui::DragValue::new(hi).speed(0.001).prefix("max "))
                    .changed();
                if *hi <= *lo {
                    *hi = *lo + 1e-3;
                }
            });
        }
    }
    let mut hl = c.highlight_above.is_some();
    if ui
        .checkbox(
            &mut hl,
            format!("highlight uncertain points (tr Ξ > {UNCERTAIN_TRACE})"),
        )
        .changed()
    {
        c.highlight_above = hl.then_some(UNCERTAIN_TRACE);
        changed = true;
    }
    legend(p, ui);
    histogram(p, ui);
    if changed {
        p.act(Action::Recolor);
    }
}

fn legend(p: &Panels<'_>, ui: &mut egui::Ui) {
    let c = &p.session.color;
    if c.mode == ColorMode::Source {
        ui.horizontal(|ui| {
            for ch in LidarChannel::ALL {
                ui.label(lidar_label(ch));
            }
        });
        return;
    }
    let width = ui.available_width().min(300.0);
    let (rect, _) = ui.allocate_exact_size(egui::vec2(width, 40.0), Sense::hover());
    let bar = egui::Rect::from_min_size(rect.min + egui::vec2(8.0, 2.0), egui::vec2(width - 16.0, 14.0));
    let painter = ui.painter_at(rect);
    let steps = 64;
    for i in 0..steps {
        let t0 = i as f32 / steps as f32;
        let x0 = bar.left() + t0 * bar.width();
        let x1 = bar.left() + (i + 1) as f32 / steps as f32 * bar.width();
        painter.rect_filled(
            egui::Rect::from_x_y_ranges(x0..=x1 + 0.5, bar.y_range()),
            0.0,
            color32(turbo(t0 + 0.5 / steps as f32)),
        );
    }
    let text = ui.visuals().text_color();
    for t in ticks(c.range, c.scale) {
        let x = bar.left() + normalize(t, c.range, c.scale) * bar.width();
        painter.line_segment(
            [egui::pos2(x, bar.bottom()), egui::pos2(x, bar.bottom() + 4.0)],
            Stroke::new(1.0, text),
        );
        painter.text(
            egui::pos2(x, bar.bottom() + 5.0),
            egui::Align2::CENTER_TOP,
            format_tick(t),
            egui::FontId::proportional(11.0),
            text,
        );
    }
    if c.mode == ColorMode::Trace && c.range.0 < UNCERTAIN_TRACE && UNCERTAIN_TRACE < c.range.1 {
        let x = bar.left() + normalize(UNCERTAIN_TRACE, c.range, c.scale) * bar.width();
        painter.line_segment(
            [egui::pos2(x, bar.top() - 2.0), egui::pos2(x, bar.bottom() + 2.0)],
            Stroke::new(2.0, color32(HIGHLIGHT)),
        );
    }
    ui.label(
        RichText::new(format!(
            "{} ({})",
            c.mode.label(),
            if c.mode.unit().is_empty() {
                "-"
            } else {
                c.mode.unit()
            }
        ))
        .weak(),
    );
}

fn format_tick(t: f32) -> String {
    let a = t.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-2..1e4).contains(&a) {
        format!("{t:.0e}")
    } else if a < 1.0 {
        format!("{t:.2}")
    } else {
        format!("{t:.0}")
    }
}

fn histogram(p: &Panels<'_>, ui: &mut egui::Ui) {
    let Some(cloud) = &p.loaded.fused else { return };
    if p.loaded.histogram.is_empty() {
        return;
    }
    let traced = p.session.color.mode == ColorMode::Source;
    let title = if traced {
        "tr(Ξ) histogram (log)".to_string()
    } else {
        format!("{} histogram", p.session.color.mode.label())
    };
    ui.label(RichText::new(title).weak());
    let width = ui.available_width().min(300.0);
    let (rect, _) = ui.allocate_exact_size(egui::vec2(width, 70.0), Sense::hover());
    let painter = ui.painter_at(rect);
    painter.rect_filled(rect, 2.0, ui.visuals().extreme_bg_color);
    let max = p.loaded.histogram.iter().copied().max().unwrap_or(1).max(1) as f32;
    let n = p.loaded.histogram.len() as f32;
    for (i, &count) in p.loaded.histogram.iter().enumerate() {
        if count == 0 {
            continue;
        }
        // Square-root height so that small bins stay visible next to the dominant one.
        let h = (count as f32 / max).sqrt() * (rect.height() - 4.0);
        let x0 = rect.left() + i as f32 / n * rect.width();
        let x1 = rect.left() + (i + 1) as f32 / n * rect.width();
        let col = if traced {
            Color32::from_gray(170)
        } else {
            color32(turbo((i as f32 + 0.5) / n))
        };
        painter.rect_filled(
            egui::Rect::from_min_max(
                egui::pos2(x0, rect.bottom() - h),
                egui::pos2(x1 - 0.5, rect.bottom()),
            ),
            0.0,
            col,
        );
    }
    ui.label(format!(
        "uncertain points |P_u|/|P| = {:.1} %  (tr Ξ > {UNCERTAIN_TRACE}, {} of {})",
        100.0 * p.loaded.uncertain_fraction,
        (p.loaded.uncertain_fraction * cloud.len() as f64).round(),
        cloud.len()
    ));
    if let Some((lo, hi)) = cloud.trace_range() {
        ui.label(RichText::new(format!("tr(Ξ) from {lo:.4} to {hi:.4} m²")).weak());
    }
}

fn view_controls(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    ui.heading("View");
    ui.horizontal_wrapped(|ui| {
        for v in View::ALL {
            if ui.button(v.name()).clicked() {
                p.act(Action::SetPreset(v));
            }
        }
    });
    ui.add(egui::Slider::new(&mut p.view.settings.point_size, 1.0..=8.0).text("point size"));
    let mut changed = false;
    ui.horizontal(|ui| {
        for ch in LidarChannel::ALL {
            let mut v = p.session.visible.get(&ch).copied().unwrap_or(true);
            if ui.checkbox(&mut v, lidar_label(ch)).changed() {
                p.session.visible.insert(ch, v);
                changed = true;
            }
        }
    });
    let mut gt = p.session.show_ground_truth;
    if ui
        .checkbox(
            &mut gt,
            RichText::new("ground-truth boxes").color(color32(GT_COLOR)),
        )
        .changed()
    {
        p.session.show_ground_truth = gt;
        p.act(Action::RebuildLines);
    }
    if changed {
        p.act(Action::Refuse);
    }
}

pub fn help_overlay(p: &mut Panels<'_>, ctx: &egui::Context) {
    if !p.shell.show_help {
        return;
    }
    let mut open = true;
    egui::Window::new("Keyboard and mouse").open(&mut open).collapsible(false).resizable(false).anchor(egui::Align2::CENTER_CENTER, [0.0, 0.0]).show(ctx, |ui| {
        ui.monospace(CONTROLS_HELP);
        ui.separator();
        ui.monospace("Left/Right  previous / next sample\nB           bird's eye / overview\nD           run the detector (Detection panel)\nF           focus the selected box\nF1 or ?     this help\nEsc         close / cancel / clear the selection");
        ui.separator();
        ui.label("Drop a dataset folder or a session .json on the window to open it.");
    });
    if !open {
        p.shell.show_help = false;
    }
}

pub fn toasts(p: &mut Panels<'_>, ctx: &egui::Context, now: f64) {
    p.shell.toasts.retain(|t| t.until > now);
    if p.shell.toasts.is_empty() {
        return;
    }
    egui::Area::new(egui::Id::unique("mlod_toasts"))
        .anchor(egui::Align2::RIGHT_BOTTOM, [-12.0, -36.0])
        .show(ctx, |ui| {
            for t in &p.shell.toasts {
                let fill = if t.error {
                    Color32::from_rgb(110, 30, 30)
                } else {
                    Color32::from_rgb(35, 55, 80)
                };
                egui::Frame::popup(ui.style()).fill(fill).show(ui, |ui| {
                    ui.set_max_width(420.0);
                    ui.label(RichText::new(&t.text).color(Color32::WHITE));
                });
            }
        });
    ctx.request_repaint_after(std::time::Duration::from_millis(250));
}
