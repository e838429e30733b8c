//! The Colour section: what the points show, the palette (both keep off the box colours), the
//! scale and range (automatic by default: the 1st–99th percentiles), the colour bar with its
//! ticks and the histogram with the same axis. Where tr(Ξ) is on the axis, the paper's
//! uncertainty threshold (0.05 m²) is always marked — at its place, or at the edge with an arrow
//! when the range leaves it out.

use eframe::egui;
use egui::{Color32, RichText, Sense, Stroke};

use super::Panels;
use crate::color::{normalize, ticks, ColorMode, Palette, Scale, HIGHLIGHT};
use crate::gui::state::{color32, Action};
use crate::uncertainty::UNCERTAIN_TRACE;

/// Space left of and right of the bar and the histogram, so that no tick label is cut.
const MARGIN: f32 = 16.0;

pub(super) fn coloring(p: &mut Panels<'_>, ui: &mut egui::Ui) {
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
            changed |= ui
                .checkbox(&mut p.session.auto_range, "auto range")
                .on_hover_text("The 1st to 99th percentile of the values on screen")
                .changed();
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
    let c = &mut p.session.color;
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

/// The x of value `v` on an axis drawn over `x0..x1`.
fn axis_x(v: f32, range: (f32, f32), scale: Scale, x0: f32, x1: f32) -> f32 {
    x0 + normalize(v, range, scale) * (x1 - x0)
}

/// Tick marks and labels under `y` for the axis `x0..x1`; labels kept inside `bounds`.
fn draw_ticks(
    painter: &egui::Painter,
    range: (f32, f32),
    scale: Scale,
    (x0, x1, y): (f32, f32, f32),
    bounds: egui::Rect,
    color: Color32,
) {
    let mut last_right = f32::NEG_INFINITY;
    for t in ticks(range, scale) {
        let x = axis_x(t, range, scale, x0, x1);
        painter.line_segment(
            [egui::pos2(x, y), egui::pos2(x, y + 4.0)],
            Stroke::new(1.0, color),
        );
        let galley = painter.layout_no_wrap(format_tick(t), egui::FontId::proportional(11.0), color);
        let w = galley.size().x;
        let left = (x - w / 2.0).clamp(bounds.left(), bounds.right() - w);
        if left < last_right + 4.0 {
            continue; // labels never overlap
        }
        last_right = left + w;
        painter.galley(egui::pos2(left, y + 5.0), galley, color);
    }
}

/// The paper's 0.05 m² on an axis of tr(Ξ): a cyan bar where it is, or an arrow at the edge it
/// lies beyond, labelled either way.
fn mark_threshold(
    painter: &egui::Painter,
    range: (f32, f32),
    scale: Scale,
    x0: f32,
    x1: f32,
    ys: (f32, f32),
) {
    let color = color32(HIGHLIGHT);
    let (top, bottom) = ys;
    let font = egui::FontId::proportional(10.0);
    if UNCERTAIN_TRACE < range.0 || UNCERTAIN_TRACE > range.1 {
        let (x, text, align) = if UNCERTAIN_TRACE < range.0 {
            (x0, "< 0.05", egui::Align2::LEFT_BOTTOM)
        } else {
            (x1, "0.05 >", egui::Align2::RIGHT_BOTTOM)
        };
        painter.line_segment(
            [egui::pos2(x, top - 2.0), egui::pos2(x, bottom + 2.0)],
            Stroke::new(2.0, color),
        );
        painter.text(egui::pos2(x, top - 1.0), align, text, font, color);
        return;
    }
    let x = axis_x(UNCERTAIN_TRACE, range, scale, x0, x1);
    painter.line_segment(
        [egui::pos2(x, top - 2.0), egui::pos2(x, bottom + 2.0)],
        Stroke::new(2.0, color),
    );
    painter.text(
        egui::pos2(x, top - 1.0),
        egui::Align2::CENTER_BOTTOM,
        "0.05",
        font,
        color,
    );
}

fn legend(p: &Panels<'_>, ui: &mut egui::Ui) {
    let c = &p.session.color;
    if c.mode == ColorMode::Source {
        ui.horizontal(|ui| {
            for &ch in p.lidars() {
                let [r, g, b, _] = c.palette.lidar(ch as usize);
                let name = p.label(ch).color(Color32::from_rgb(r, g, b));
                ui.label(name);
            }
        });
        return;
    }
    let width = ui.available_width().min(320.0);
    let (rect, _) = ui.allocate_exact_size(egui::vec2(width, 40.0), Sense::hover());
    let bar = egui::Rect::from_min_size(
        rect.min + egui::vec2(MARGIN, 12.0),
        egui::vec2(width - 2.0 * MARGIN, 14.0),
    );
    let painter = ui.painter_at(rect);
    let steps = 64;
    for i in 0..steps {
        let x0 = bar.left() + i as f32 / steps as f32 * bar.width();
        let x1 = bar.left() + (i + 1) as f32 / steps as f32 * bar.width();
        painter.rect_filled(
            egui::Rect::from_x_y_ranges(x0..=x1 + 0.5, bar.y_range()),
            0.0,
            color32(c.palette.ramp((i as f32 + 0.5) / steps as f32)),
        );
    }
    let text = ui.visuals().text_color();
    draw_ticks(
        &painter,
        c.range,
        c.scale,
        (bar.left(), bar.right(), bar.bottom()),
        rect,
        text,
    );
    if c.mode == ColorMode::Trace {
        mark_threshold(
            &painter,
            c.range,
            c.scale,
            bar.left(),
            bar.right(),
            (bar.top(), bar.bottom()),
        );
    }
    let unit = if c.mode.unit().is_empty() {
        "-"
    } else {
        c.mode.unit()
    };
    ui.label(RichText::new(format!("{} ({unit})", c.mode.label())).weak());
}

/// A tick's label: plain decimals where they are short, else "1e-3" style.
pub(super) fn format_tick(t: f32) -> String {
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
    let Some((range, scale, trace)) = p.loaded.histogram_axis else {
        return;
    };
    if p.loaded.histogram.is_empty() {
        return;
    }
    let source = p.session.color.mode == ColorMode::Source;
    let title = if source {
        "tr(Ξ) histogram (log)".to_string()
    } else {
        format!("{} histogram", p.session.color.mode.label())
    };
    ui.label(RichText::new(title).weak());
    let width = ui.available_width().min(320.0);
    let (rect, _) = ui.allocate_exact_size(egui::vec2(width, 70.0), Sense::hover());
    let plot = egui::Rect::from_min_max(
        rect.min + egui::vec2(MARGIN, 12.0),
        egui::pos2(rect.right() - MARGIN, rect.bottom() - 20.0),
    );
    let painter = ui.painter_at(rect);
    painter.rect_filled(plot, 2.0, ui.visuals().extreme_bg_color);
    let max = p.loaded.histogram.iter().copied().max().unwrap_or(1).max(1) as f32;
    let n = p.loaded.histogram.len() as f32;
    for (i, &count) in p.loaded.histogram.iter().enumerate() {
        if count == 0 {
            continue;
        }
        // Square-root height so that small bins stay visible next to the dominant one.
        let h = (count as f32 / max).sqrt() * (plot.height() - 4.0);
        let x0 = plot.left() + i as f32 / n * plot.width();
        let x1 = plot.left() + (i + 1) as f32 / n * plot.width();
        let col = if source {
            Color32::from_gray(170)
        } else {
            color32(p.session.color.palette.ramp((i as f32 + 0.5) / n))
        };
        painter.rect_filled(
            egui::Rect::from_min_max(
                egui::pos2(x0, plot.bottom() - h),
                egui::pos2(x1 - 0.5, plot.bottom()),
            ),
            0.0,
            col,
        );
    }
    let text = ui.visuals().text_color();
    draw_ticks(
        &painter,
        range,
        scale,
        (plot.left(), plot.right(), plot.bottom()),
        rect,
        text,
    );
    if trace {
        mark_threshold(
            &painter,
            range,
            scale,
            plot.left(),
            plot.right(),
            (plot.top(), plot.bottom()),
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

/// The palette picker (in the View section): both palettes keep off the box colours.
pub(super) fn palette(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    let c = &mut p.session.color;
    let mut changed = false;
    ui.horizontal(|ui| {
        ui.label("point palette");
        egui::ComboBox::from_id_salt("mlod_palette")
            .selected_text(c.palette.label())
            .show_ui(ui, |ui| {
                for pal in Palette::ALL {
                    changed |= ui.selectable_value(&mut c.palette, pal, pal.label()).changed();
                }
            })
            .response
            .on_hover_text("Both palettes keep off the box colours (blue, red, green, amber)");
    });
    if changed {
        p.act(Action::Recolor);
    }
}
