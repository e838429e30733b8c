//! The panels around the viewport: menu, sample browser, perturbation / colour / view controls
//! (with the tr(Ξ) legend and histogram), status bar, help overlay and toasts. They edit the
//! app's session and mark what must be recomputed; they compute nothing themselves.

use std::path::PathBuf;

use eframe::egui;
use egui::{Color32, RichText, Sense, Stroke};

use super::app::{channel_counts, lidar_label, MlodApp, FALSE_POSITIVE_COLOR, GT_COLOR, PROPOSAL_COLOR};
use super::viewport::{View, CONTROLS_HELP};
use crate::color::{normalize, ticks, turbo, ColorMode, Scale, HIGHLIGHT};
use crate::detect::Case;
use crate::lyft::LidarChannel;
use crate::session::Session;
use crate::uncertainty::{ExtrinsicNoise, Linearization, UNCERTAIN_TRACE};

/// The paper's perturbation levels (Table II).
const ALPHA_MARKS: [f64; 4] = [0.0, 0.02, 0.04, 0.1];

fn color32(c: [u8; 4]) -> Color32 {
    Color32::from_rgba_unmultiplied(c[0], c[1], c[2], c[3])
}

pub fn menu_bar(app: &mut MlodApp, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
    egui::Panel::top("menu").show(ui, |ui| {
        egui::MenuBar::new().ui(ui, |ui| {
            ui.menu_button("File", |ui| {
                if ui.button("Open dataset…").clicked() {
                    if let Some(dir) = rfd::FileDialog::new()
                        .set_title("Open a Lyft-format dataset")
                        .pick_folder()
                    {
                        app.open_dataset(dir);
                    }
                }
                ui.menu_button("Recent datasets", |ui| {
                    let recent: Vec<PathBuf> = app.recent.clone();
                    if recent.is_empty() {
                        ui.label("none yet");
                    }
                    for p in recent {
                        if ui.button(p.display().to_string()).clicked() {
                            app.open_dataset(p);
                        }
                    }
                });
                ui.separator();
                if ui.button("Save session…").clicked() {
                    save_session(app, ui.ctx());
                }
                if ui.button("Load session…").clicked() {
                    load_session(app, ui.ctx());
                }
                ui.separator();
                if ui.button("Export viewport PNG…").clicked() {
                    export_png(app, ui.ctx(), frame);
                }
                ui.separator();
                if ui.button("Quit").clicked() {
                    ui.ctx().send_viewport_cmd(egui::ViewportCommand::Close);
                }
            });
            ui.menu_button("View", |ui| {
                for v in View::ALL {
                    if ui.button(v.name()).clicked() {
                        app.set_preset(v);
                    }
                }
            });
            ui.menu_button("Help", |ui| {
                if ui.button("Keyboard and mouse (F1)").clicked() {
                    app.show_help = true;
                }
            });
            ui.separator();
            ui.label(RichText::new("MLOD debugger").strong());
            let name = app
                .session
                .dataset
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            ui.label(RichText::new(name).weak())
                .on_hover_text(app.session.dataset.display().to_string());
        });
    });
}

fn save_session(app: &mut MlodApp, ctx: &egui::Context) {
    let now = ctx.input(|i| i.time);
    let Some(path) = rfd::FileDialog::new()
        .add_filter("session", &["json"])
        .set_file_name("session.json")
        .save_file()
    else {
        return;
    };
    match app.current_session().save(&path) {
        Ok(()) => app.toast(now, format!("saved {}", path.display()), false),
        Err(e) => app.toast(now, e.to_string(), true),
    }
}

fn load_session(app: &mut MlodApp, ctx: &egui::Context) {
    let now = ctx.input(|i| i.time);
    let Some(path) = rfd::FileDialog::new()
        .add_filter("session", &["json"])
        .pick_file()
    else {
        return;
    };
    match Session::load(&path) {
        Ok(s) => app.apply_session(s),
        Err(e) => app.toast(now, e.to_string(), true),
    }
}

fn export_png(app: &mut MlodApp, ctx: &egui::Context, frame: &eframe::Frame) {
    let now = ctx.input(|i| i.time);
    let Some(rs) = frame.wgpu_render_state() else {
        app.toast(now, "no GPU device to render with", true);
        return;
    };
    let Some(path) = rfd::FileDialog::new()
        .add_filter("PNG", &["png"])
        .set_file_name("viewport.png")
        .save_file()
    else {
        return;
    };
    let result = super::viewport::render_offscreen(&rs.device, &rs.queue, &app.scene, &app.view, (1280, 800))
        .map_err(|e| e.to_string())
        .and_then(|img| super::write_png(&path, &img).map_err(|e| e.to_string()));
    match result {
        Ok(()) => app.toast(now, format!("wrote {}", path.display()), false),
        Err(e) => app.toast(now, e, true),
    }
}

pub fn status_bar(app: &mut MlodApp, ui: &mut egui::Ui) {
    egui::Panel::bottom("status").show(ui, |ui| {
        ui.horizontal(|ui| {
            match (&app.frame, &app.fused) {
                (Some(f), Some(c)) => {
                    ui.label(format!("{} points", c.len()));
                    for (ch, n) in channel_counts(c) {
                        ui.label(lidar_label(ch));
                        ui.label(format!("{n}"));
                    }
                    ui.separator();
                    ui.label(format!("{} boxes", f.boxes.len()));
                    ui.separator();
                    if app.show_timings {
                        ui.label(format!(
                            "load {:.0} ms · fuse + tr(Ξ) + colour {:.1} ms",
                            app.frame_ms, app.fuse_ms
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

pub fn sample_browser(app: &mut MlodApp, ui: &mut egui::Ui) {
    ui.heading("Samples");
    ui.label(RichText::new("Left / Right arrow keys step through samples").weak());
    ui.separator();
    let current = app.frame.as_ref().map(|f| f.sample_token.clone());
    let mut clicked = None;
    egui::ScrollArea::vertical().show(ui, |ui| {
        let mut last_scene = String::new();
        for (i, s) in app.samples.iter().enumerate() {
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
        app.select_sample(&t);
    }
}

pub fn controls(app: &mut MlodApp, ui: &mut egui::Ui) {
    egui::ScrollArea::vertical().show(ui, |ui| {
        perturbation(app, ui);
        ui.separator();
        detection(app, ui);
        ui.separator();
        coloring(app, ui);
        ui.separator();
        view_controls(app, ui);
    });
}

fn perturbation(app: &mut MlodApp, ui: &mut egui::Ui) {
    ui.heading("Extrinsic perturbation");
    let p = &mut app.session.fuse;
    let mut changed = false;
    changed |= ui
        .add(
            egui::Slider::new(&mut p.perturbation.alpha, 0.0..=0.1)
                .text("α")
                .step_by(0.001)
                .fixed_decimals(3),
        )
        .changed();
    ui.horizontal(|ui| {
        ui.label(RichText::new("paper levels").weak());
        for a in ALPHA_MARKS {
            if ui
                .selectable_label(p.perturbation.alpha == a, format!("{a}"))
                .clicked()
            {
                p.perturbation.alpha = a;
                changed = true;
            }
        }
    });
    ui.horizontal(|ui| {
        let label = ui.label("seed");
        changed |= ui
            .add(egui::DragValue::new(&mut p.perturbation.seed))
            .labelled_by(label.id)
            .changed();
        if ui
            .button("resample")
            .on_hover_text("draw a new perturbation (next seed)")
            .clicked()
        {
            p.perturbation.seed = p.perturbation.seed.wrapping_add(1);
            changed = true;
        }
    });
    let mut decoupled = p.prior_alpha.is_some();
    if ui
        .checkbox(&mut decoupled, "prior assumes another α")
        .on_hover_text(
            "compute Ξ with a different α than the one that perturbed the points (a mis-specified prior)",
        )
        .changed()
    {
        p.prior_alpha = decoupled.then_some(p.perturbation.alpha);
        changed = true;
    }
    if let Some(pa) = &mut p.prior_alpha {
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
            changed |= ui.radio_value(&mut p.linearization, lin, lin.name()).changed();
        }
    });
    for ch in [LidarChannel::FrontLeft, LidarChannel::FrontRight] {
        let sampled = app.session.sampled.get(&ch).copied();
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
                let m = app.session.fuse.manual.entry(ch).or_default();
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
    app.session.fuse.manual.retain(|_, n| *n != ExtrinsicNoise::ZERO);
    if changed {
        app.mark_fuse();
    }
}

/// Three labelled drag values in a row, each within ±`limit`; true if any changed.
/// Stage-1 detection: pick a case, run it on the sample on screen, see its proposals matched
/// against the ground truth.
fn detection(app: &mut MlodApp, ui: &mut egui::Ui) {
    ui.heading("Detection (stage 1)");
    let mut run = false;
    let mut rematch = false;
    let mut redraw = false;
    ui.horizontal(|ui| {
        let d = &mut app.session.detection;
        egui::ComboBox::new("mlod_detector_case", "case")
            .selected_text(d.case.paper_name())
            .show_ui(ui, |ui| {
                for c in Case::ALL {
                    ui.selectable_value(&mut d.case, c, c.paper_name());
                }
            });
        let label = if app.is_detecting() {
            "Running…"
        } else {
            "Run (D)"
        };
        run |= ui
            .add_enabled(app.frame.is_some(), egui::Button::new(label))
            .on_hover_text("Run the detector on this sample with the current perturbation")
            .clicked();
    });
    let d = &mut app.session.detection;
    ui.checkbox(&mut d.auto_run, "run again on every change")
        .on_hover_text("Re-run after each change of sample, α or offsets (latest change wins)");
    rematch |= ui
        .add(egui::Slider::new(&mut d.min_score, 0.05..=0.95).text("min score"))
        .changed();
    ui.horizontal(|ui| {
        ui.label("true positive at 3D IoU ≥");
        rematch |= ui.radio_value(&mut d.match_iou, 0.5, "0.5").changed();
        rematch |= ui.radio_value(&mut d.match_iou, 0.7, "0.7").changed();
    });
    redraw |= ui
        .checkbox(
            &mut d.show,
            RichText::new("proposal boxes").color(color32(PROPOSAL_COLOR)),
        )
        .changed();
    let stale = app.detection_is_stale();
    match app.detection() {
        Some((v, c)) => {
            ui.horizontal_wrapped(|ui| {
                ui.label(format!("{}:", v.case.paper_name()));
                ui.label(format!("{} proposals", c.shown));
                ui.label(RichText::new(format!("{} TP", c.true_positives)).color(color32(PROPOSAL_COLOR)));
                ui.label(
                    RichText::new(format!("{} FP", c.false_positives)).color(color32(FALSE_POSITIVE_COLOR)),
                );
                ui.label(
                    RichText::new(format!(
                        "{} of {} {} missed",
                        c.missed,
                        c.ground_truth,
                        v.categories.join("/")
                    ))
                    .color(color32(GT_COLOR)),
                );
            });
            if app.show_timings {
                ui.label(
                    RichText::new(format!(
                        "{:.0} ms (weights, fuse, voxelise, network, NMS)",
                        v.millis
                    ))
                    .weak(),
                );
            }
            if stale {
                ui.label(
                    RichText::new("stale: the perturbation or the case changed since this run. Run again")
                        .color(Color32::from_rgb(240, 190, 80)),
                );
            }
        }
        None => {
            ui.label(RichText::new("no detection on this sample yet").weak());
        }
    }
    if run {
        app.run_detector();
    }
    if rematch {
        app.rematch();
    } else if redraw {
        app.rebuild_lines();
    }
}

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

fn coloring(app: &mut MlodApp, ui: &mut egui::Ui) {
    ui.heading("Colour");
    let c = &mut app.session.color;
    let mut changed = false;
    ui.horizontal_wrapped(|ui| {
        for m in ColorMode::ALL {
            changed |= ui.radio_value(&mut c.mode, m, m.label()).changed();
        }
    });
    if c.mode != ColorMode::Source {
        ui.horizontal(|ui| {
            changed |= ui.radio_value(&mut c.scale, Scale::Linear, "linear").changed();
            changed |= ui.radio_value(&mut c.scale, Scale::Log, "log").changed();
            changed |= ui.checkbox(&mut app.session.auto_range, "auto range").changed();
        });
        if !app.session.auto_range {
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
    legend(app, ui);
    histogram(app, ui);
    if changed {
        app.mark_color();
    }
}

fn legend(app: &MlodApp, ui: &mut egui::Ui) {
    let c = &app.session.color;
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

fn histogram(app: &MlodApp, ui: &mut egui::Ui) {
    let Some(cloud) = &app.fused else { return };
    if app.histogram.is_empty() {
        return;
    }
    let traced = app.session.color.mode == ColorMode::Source;
    let title = if traced {
        "tr(Ξ) histogram (log)".to_string()
    } else {
        format!("{} histogram", app.session.color.mode.label())
    };
    ui.label(RichText::new(title).weak());
    let width = ui.available_width().min(300.0);
    let (rect, _) = ui.allocate_exact_size(egui::vec2(width, 70.0), Sense::hover());
    let painter = ui.painter_at(rect);
    painter.rect_filled(rect, 2.0, ui.visuals().extreme_bg_color);
    let max = app.histogram.iter().copied().max().unwrap_or(1).max(1) as f32;
    let n = app.histogram.len() as f32;
    for (i, &count) in app.histogram.iter().enumerate() {
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
        100.0 * app.uncertain_fraction,
        (app.uncertain_fraction * cloud.len() as f64).round(),
        cloud.len()
    ));
    if let Some((lo, hi)) = cloud.trace_range() {
        ui.label(RichText::new(format!("tr(Ξ) from {lo:.4} to {hi:.4} m²")).weak());
    }
}

fn view_controls(app: &mut MlodApp, ui: &mut egui::Ui) {
    ui.heading("View");
    ui.horizontal_wrapped(|ui| {
        for v in View::ALL {
            if ui.button(v.name()).clicked() {
                app.set_preset(v);
            }
        }
    });
    ui.add(egui::Slider::new(&mut app.view.settings.point_size, 1.0..=8.0).text("point size"));
    let mut changed = false;
    ui.horizontal(|ui| {
        for ch in LidarChannel::ALL {
            let mut v = app.session.visible.get(&ch).copied().unwrap_or(true);
            if ui.checkbox(&mut v, lidar_label(ch)).changed() {
                app.session.visible.insert(ch, v);
                changed = true;
            }
        }
    });
    let mut gt = app.session.show_ground_truth;
    if ui
        .checkbox(
            &mut gt,
            RichText::new("ground-truth boxes").color(color32(GT_COLOR)),
        )
        .changed()
    {
        app.session.show_ground_truth = gt;
        app.rebuild_lines();
    }
    if changed {
        app.mark_fuse();
    }
}

pub fn help_overlay(app: &mut MlodApp, ctx: &egui::Context) {
    if !app.show_help {
        return;
    }
    let mut open = true;
    egui::Window::new("Keyboard and mouse").open(&mut open).collapsible(false).resizable(false).anchor(egui::Align2::CENTER_CENTER, [0.0, 0.0]).show(ctx, |ui| {
        ui.monospace(CONTROLS_HELP);
        ui.separator();
        ui.monospace("Left/Right  previous / next sample\nB           bird's eye / overview\nD           run the stage-1 detector\nF1 or ?     this help\nEsc         close");
        ui.separator();
        ui.label("Drop a dataset folder or a session .json on the window to open it.");
    });
    if !open {
        app.show_help = false;
    }
}

pub fn toasts(app: &mut MlodApp, ctx: &egui::Context, now: f64) {
    app.toasts.retain(|t| t.until > now);
    if app.toasts.is_empty() {
        return;
    }
    egui::Area::new(egui::Id::unique("mlod_toasts"))
        .anchor(egui::Align2::RIGHT_BOTTOM, [-12.0, -36.0])
        .show(ctx, |ui| {
            for t in &app.toasts {
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
