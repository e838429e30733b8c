//! The sweep window: a sweep folder's car moderate AP_3D@0.7 against α, one curve per case with
//! ±std error bars over its finished trials (a running sweep shows what it has so far); hovering a
//! point gives its numbers. Drawn with egui's painter; the numbers are `sweep::progress`'s, the
//! same as the folder's `ap_vs_alpha.png` once the sweep is complete.

use eframe::egui;
use egui::{Color32, Pos2, Rect, RichText, Sense, Stroke};

use super::Panels;
use crate::analysis::plot::{series_styles, SERIES_COLOURS};
use crate::gui::state::SweepView;

/// Each curve's colour and whether it is dashed, as the folder's `ap_vs_alpha.png` draws it.
fn curve_styles(prog: &crate::analysis::sweep::SweepProgress) -> Vec<(Color32, bool)> {
    series_styles(prog.curves.iter().map(|(name, _)| name.as_str()))
        .into_iter()
        .map(|(k, dashed)| {
            let [r, g, b] = SERIES_COLOURS[k % SERIES_COLOURS.len()];
            (Color32::from_rgb(r, g, b), dashed)
        })
        .collect()
}

/// The sweep window, while a sweep is open.
pub fn sweep_window(p: &mut Panels<'_>, ctx: &egui::Context) {
    let Some(view) = p.shell.sweep.as_ref() else {
        return;
    };
    let mut open = true;
    let title = format!("Sweep: {}", view.dir.display());
    egui::Window::new(title)
        .id(egui::Id::unique("mlod_sweep_window"))
        .open(&mut open)
        .default_size([640.0, 400.0 + legend_height(view.progress.curves.len())])
        .resizable(true)
        .show(ctx, |ui| plot(ui, view));
    if !open {
        p.shell.sweep = None;
        p.session.sweep = None;
    }
}

/// Height the legend below the plot needs for `n` curves (about three names a row), so that a
/// sweep with many cases (Table II with those beyond the paper) shows every name.
fn legend_height(n: usize) -> f32 {
    18.0 * (n.max(1) as f32 / 3.0).ceil() + 10.0
}

fn plot(ui: &mut egui::Ui, view: &SweepView) {
    let prog = &view.progress;
    ui.label(
        RichText::new(format!(
            "car moderate AP_3D@0.7 (%), mean ± std over trials; {} of {} units finished",
            prog.rows.len(),
            prog.total
        ))
        .weak(),
    );
    let pts = prog.curves.iter().flat_map(|c| c.1.iter());
    let (mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY);
    for &(_, m, s) in pts {
        y0 = y0.min(m - s);
        y1 = y1.max(m + s);
    }
    if !y0.is_finite() {
        ui.label("no finished unit yet");
        return;
    }
    let step = if y1 - y0 > 30.0 { 10.0 } else { 5.0 };
    let (y0, y1) = (
        (y0 / step).floor() * step,
        ((y1 / step).ceil() * step).max(y0 + step),
    );
    let alphas = &prog.config.alphas;
    let x0 = alphas.iter().copied().fold(f64::INFINITY, f64::min);
    let x1 = alphas
        .iter()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max)
        .max(x0 + 1e-6);
    let size = egui::vec2(
        ui.available_width().max(200.0),
        (ui.available_height() - legend_height(prog.curves.len())).max(160.0),
    );
    let (rect, resp) = ui.allocate_exact_size(size, Sense::hover());
    let painter = ui.painter_at(rect);
    let area = Rect::from_min_max(
        rect.min + egui::vec2(44.0, 8.0),
        rect.max - egui::vec2(36.0, 22.0),
    );
    let sx = |x: f64| area.left() + ((x - x0) / (x1 - x0)) as f32 * area.width();
    let sy = |y: f64| area.bottom() - ((y - y0) / (y1 - y0)) as f32 * area.height();
    let axis = ui.visuals().weak_text_color();
    let font = egui::FontId::proportional(12.0);
    painter.rect_filled(area, 2.0, ui.visuals().extreme_bg_color);
    let mut y = y0;
    while y <= y1 + 1e-9 {
        painter.line_segment(
            [Pos2::new(area.left(), sy(y)), Pos2::new(area.right(), sy(y))],
            Stroke::new(0.5, axis),
        );
        painter.text(
            Pos2::new(area.left() - 6.0, sy(y)),
            egui::Align2::RIGHT_CENTER,
            format!("{y:.0}"),
            font.clone(),
            axis,
        );
        y += step;
    }
    for &a in alphas {
        painter.text(
            Pos2::new(sx(a), area.bottom() + 4.0),
            egui::Align2::CENTER_TOP,
            format!("α = {a}"),
            font.clone(),
            axis,
        );
    }
    // Curves, error bars with caps, points; the nearest point to the pointer for the tooltip.
    let pointer = resp.hover_pos();
    let mut nearest: Option<(f32, usize, (f64, f64, f64))> = None;
    let styles = curve_styles(prog);
    for (i, ((_, points), &(c, oc))) in prog.curves.iter().zip(&styles).enumerate() {
        let screen: Vec<Pos2> = points.iter().map(|&(a, m, _)| Pos2::new(sx(a), sy(m))).collect();
        if screen.len() > 1 {
            if oc {
                painter.extend(egui::Shape::dashed_line(&screen, Stroke::new(1.8, c), 6.0, 4.0));
            } else {
                painter.add(egui::Shape::line(screen.clone(), Stroke::new(1.8, c)));
            }
        }
        for (&(a, m, s), &pt) in points.iter().zip(&screen) {
            let (top, bot) = (sy(m + s), sy(m - s));
            painter.line_segment([Pos2::new(pt.x, top), Pos2::new(pt.x, bot)], Stroke::new(1.2, c));
            for yy in [top, bot] {
                painter.line_segment(
                    [Pos2::new(pt.x - 3.0, yy), Pos2::new(pt.x + 3.0, yy)],
                    Stroke::new(1.2, c),
                );
            }
            painter.circle_filled(pt, 3.0, c);
            if let Some(ptr) = pointer {
                let d = ptr.distance(pt);
                if d < 14.0 && nearest.is_none_or(|n| d < n.0) {
                    nearest = Some((d, i, (a, m, s)));
                }
            }
        }
    }
    if let Some((_, i, (a, m, s))) = nearest {
        let (name, _) = &prog.curves[i];
        let case = prog.config.cases.get(i).copied();
        let n = case.map_or(0, |c| prog.trials(c, a));
        resp.on_hover_text_at_pointer(format!("{name} at α = {a}: {m:.2} ± {s:.2} ({n} trials)"));
    }
    ui.horizontal_wrapped(|ui| {
        for ((name, _), &(c, oc)) in prog.curves.iter().zip(&styles) {
            let mark = if oc { "- -" } else { "—" };
            ui.label(RichText::new(format!("{mark} {name}")).color(c));
        }
    });
}
