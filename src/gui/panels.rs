//! The panels around the viewport: menu, sample browser, perturbation / colour / view controls
//! (with the tr(Ξ) legend and histogram), status bar, help overlay and toasts. They draw from a
//! [`Panels`] view of the state, edit the session and ask for the rest as [`Action`]s; they
//! compute nothing and know nothing of the app.

use std::path::PathBuf;

use eframe::egui;
use egui::{Color32, RichText};

mod banner;
mod calibration;
mod coloring;
mod detection;
mod failures;
mod files;
mod help;
mod selection;
mod sweep;

pub use banner::banner;
use banner::NO_AUXILIARY;
pub use failures::failure_panel;
pub use files::{dialog_service_available, file_prompt};
pub use help::help_overlay;
pub use sweep::sweep_window;

use super::state::{channel_counts, lidar_label, Action, FilePurpose, Loaded, Shell};
use crate::dataset::LidarChannel;
use crate::render::{Projection, View, Viewport};
use crate::session::Session;
use crate::uncertainty::{ExtrinsicNoise, Linearization};

/// The paper's perturbation levels (Table II).
const ALPHA_MARKS: [f64; 4] = [0.0, 0.02, 0.04, 0.1];

const SAVE_SHORTCUT: egui::KeyboardShortcut =
    egui::KeyboardShortcut::new(egui::Modifiers::COMMAND, egui::Key::S);
const OPEN_SHORTCUT: egui::KeyboardShortcut =
    egui::KeyboardShortcut::new(egui::Modifiers::COMMAND, egui::Key::O);

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

    /// The format of the dataset on screen.
    fn format(&self) -> Option<crate::dataset::DatasetFormat> {
        self.loaded.dataset.as_ref().map(|d| d.format())
    }

    /// The LiDAR slots the dataset's format fills (Argoverse 2: two).
    fn lidars(&self) -> &'static [LidarChannel] {
        self.format().map_or(&LidarChannel::ALL, |f| f.lidars())
    }

    /// A LiDAR's name in its colour, as the dataset names it.
    fn label(&self, ch: LidarChannel) -> egui::RichText {
        lidar_label(self.format(), ch)
    }
}

/// The keyboard shortcuts (when no text field has the focus): D runs the detector, ←/→ step
/// through the samples, B toggles bird's eye, F points the camera at the selected box, Tab hides
/// the side panels, Ctrl+S saves the session (to its file, once it has one), Ctrl+O opens a
/// dataset, F1 or ? the help, Esc closes it (or cancels a calibration, or clears the selection).
pub fn keys(p: &mut Panels<'_>, ctx: &egui::Context) {
    if ctx.egui_wants_keyboard_input() || p.shell.prompt.is_some() {
        return;
    }
    let (save, open, tab) = ctx.input_mut(|i| {
        (
            i.consume_shortcut(&SAVE_SHORTCUT),
            i.consume_shortcut(&OPEN_SHORTCUT),
            i.consume_key(egui::Modifiers::NONE, egui::Key::Tab),
        )
    });
    if save {
        match p.shell.session_file.clone() {
            Some(path) => p.act(Action::SaveSession(path)),
            None => files::ask(p, FilePurpose::SaveSession),
        }
    }
    if open {
        files::ask(p, FilePurpose::OpenDataset);
    }
    if tab {
        p.shell.hide_panels = !p.shell.hide_panels;
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
                let shortcut = |ui: &egui::Ui, s: &egui::KeyboardShortcut| ui.ctx().format_shortcut(s);
                let open = egui::Button::new("Open dataset…").shortcut_text(shortcut(ui, &OPEN_SHORTCUT));
                if ui.add(open).clicked() {
                    ui.close();
                    files::ask(p, FilePurpose::OpenDataset);
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
                    files::ask(p, FilePurpose::OpenSweep);
                }
                if ui
                    .button("Open models folder…")
                    .on_hover_text(
                        "Run the detectors from another folder of weights with its manifest.json \
                         (your own `mlod train` output, or an earlier set from git history)",
                    )
                    .clicked()
                {
                    ui.close();
                    files::ask(p, FilePurpose::OpenModels);
                }
                let save = egui::Button::new("Save session…").shortcut_text(shortcut(ui, &SAVE_SHORTCUT));
                if ui.add(save).clicked() {
                    ui.close();
                    files::ask(p, FilePurpose::SaveSession);
                }
                if ui.button("Load session…").clicked() {
                    ui.close();
                    files::ask(p, FilePurpose::LoadSession);
                }
                ui.separator();
                if ui.button("Export viewport PNG…").clicked() {
                    ui.close();
                    files::ask(p, FilePurpose::ExportPng);
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
                    ui.close();
                    files::ask(p, FilePurpose::ExportCloud);
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
                ui.separator();
                let label = if p.shell.hide_panels {
                    "Show side panels"
                } else {
                    "Hide side panels"
                };
                if ui.add(egui::Button::new(label).shortcut_text("Tab")).clicked() {
                    p.shell.hide_panels = !p.shell.hide_panels;
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
                        ui.label(lidar_label(p.format(), ch));
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
                ui.label(RichText::new("F1: help · Tab: hide panels").weak());
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

/// The controls: each section under a header that folds, so that what is open fits 1280×800;
/// the scroll bar always shows when the rest does not fit.
pub fn controls(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    let out = egui::ScrollArea::vertical()
        .scroll_bar_visibility(egui::scroll_area::ScrollBarVisibility::AlwaysVisible)
        .show(ui, |ui| {
            section(ui, "Extrinsic perturbation", true, |ui| perturbation(p, ui));
            section(ui, "Detection", true, |ui| {
                detection::detection(p, ui);
                selection::selection(p, ui);
            });
            section(ui, "Colour", true, |ui| coloring::coloring(p, ui));
            section(ui, "View", false, |ui| view_controls(p, ui));
        });
    // How far the open sections run past the visible height (≤ 0: everything is in sight).
    p.shell.controls_overflow = out.content_size.y - out.inner_rect.height();
}

/// A folding section of the controls.
fn section(ui: &mut egui::Ui, title: &str, open: bool, body: impl FnOnce(&mut egui::Ui)) {
    egui::CollapsingHeader::new(RichText::new(title).heading())
        .id_salt(title)
        .default_open(open)
        .show(ui, body);
}

fn perturbation(p: &mut Panels<'_>, ui: &mut egui::Ui) {
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
    let mut clip = false;
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
            clip = true;
        }
    });
    if let Some(to) = toggle {
        p.act(Action::TogglePlay(to));
    }
    if clip {
        files::ask(p, FilePurpose::ExportClip);
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
        if !p.lidars().contains(&ch) {
            continue;
        }
        let sampled = p.session.sampled.get(&ch).copied();
        egui::CollapsingHeader::new(p.label(ch))
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
        p.session.oc.show_factory = false;
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

fn view_controls(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    ui.horizontal_wrapped(|ui| {
        for v in View::ALL {
            if ui.button(v.name()).clicked() {
                p.act(Action::SetPreset(v));
            }
        }
    });
    ui.add(egui::Slider::new(&mut p.view.settings.point_size, 1.0..=8.0).text("point size"));
    ui.add(egui::Slider::new(&mut p.view.settings.line_width, 1.0..=6.0).text("box line width"));
    coloring::palette(p, ui);
    let mut changed = false;
    ui.horizontal(|ui| {
        for &ch in p.lidars() {
            let mut v = p.session.visible.get(&ch).copied().unwrap_or(true);
            if ui.checkbox(&mut v, p.label(ch)).changed() {
                p.session.visible.insert(ch, v);
                changed = true;
            }
        }
    });
    if changed {
        p.act(Action::Refuse);
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
