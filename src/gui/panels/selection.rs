//! The details of the selected box (click a box; F focuses it, Escape clears): its scores before
//! and after refinement, its 3D IoU with its ground truth and the residuals before and after
//! (`mlod eval --per-box`'s), the points inside per LiDAR with their tr(Ξ) histogram and uncertain
//! share, and the uncertain share of the refiner's active points.

use eframe::egui;
use egui::{Color32, RichText, Sense};

use super::Panels;
use crate::analysis::inspect::{trace_bin_edge, PointsInside, TRACE_BINS};
use crate::color::turbo;
use crate::eval::BoxError;
use crate::gui::state::{
    color32, lidar_label, Action, SelectionDetails, GT_COLOR, PROPOSAL_COLOR, REFINED_COLOR, SELECTED_COLOR,
};
use crate::session::BoxLayer;

pub(super) fn selection(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    let Some(sel) = p.session.selection.as_ref() else {
        return;
    };
    ui.separator();
    ui.horizontal(|ui| {
        ui.heading(RichText::new("Selected box").color(color32(SELECTED_COLOR)));
        if ui.small_button("focus (F)").clicked() {
            p.actions.push(Action::FocusSelection);
        }
        if ui.small_button("clear (Esc)").clicked() {
            p.actions.push(Action::ClearSelection);
        }
    });
    let Some(details) = p.loaded.selection_details.as_ref() else {
        let what = match sel.layer {
            BoxLayer::Truth => "ground-truth box",
            BoxLayer::Proposal => "proposal",
            BoxLayer::Refined => "refined box",
        };
        ui.label(
            RichText::new(format!(
                "no {what} on this object now (missed, below the min score, or not run yet)"
            ))
            .color(Color32::from_rgb(240, 190, 80)),
        );
        return;
    };
    match details {
        SelectionDetails::Truth {
            annotation,
            category,
            inside,
            detected_iou,
            ..
        } => {
            ui.label(RichText::new(format!("ground truth: {category}")).color(color32(GT_COLOR)));
            ui.label(RichText::new(format!("annotation {}", short(annotation))).weak());
            match detected_iou {
                Some(iou) => ui.label(format!("detected: 3D IoU {iou:.3}")),
                None if p.loaded.detection.is_some() => ui.label("missed by the detection on screen"),
                None => ui.label(RichText::new("no detection on this sample yet").weak()),
            };
            points(ui, "points inside", inside, p.format());
        }
        SelectionDetails::Prediction {
            layer, details: d, ..
        } => {
            let case = p.loaded.detection.as_ref().map(|v| v.case);
            let (name, color) = match layer {
                BoxLayer::Refined => ("refined box", REFINED_COLOR),
                _ => ("proposal", PROPOSAL_COLOR),
            };
            let case = case.map(|c| format!(" ({})", c.paper_name())).unwrap_or_default();
            ui.label(RichText::new(format!("{name}{case}: {}", d.category)).color(color32(color)));
            match (d.refined_score, d.head_score) {
                (Some(s), Some(h)) => ui.label(format!(
                    "score {s:.3} after refinement (stage 1 {:.3}, head {h:.3})",
                    d.proposal_score
                )),
                _ => ui.label(format!("score {:.3}", d.proposal_score)),
            };
            match &d.truth {
                Some(t) => {
                    let how = if t.matched {
                        "its match"
                    } else {
                        "best overlap, not a match: a false positive"
                    };
                    ui.label(
                        RichText::new(format!("vs ground truth {} ({how})", short(&t.annotation_token)))
                            .color(color32(GT_COLOR)),
                    );
                    residuals(ui, d.iou_before, d.residual_before, d.iou_after, d.residual_after);
                }
                None => {
                    ui.label(RichText::new("no ground truth overlaps it: a false positive").weak());
                }
            }
            points(ui, "points inside", &d.inside, p.format());
            if let Some(a) = &d.active {
                ui.label(format!(
                    "active points {}: uncertain |P_u|/|P| {:.0} % ({} of them)",
                    a.total,
                    100.0 * a.uncertain_fraction(),
                    a.uncertain
                ))
                .on_hover_text("The points that won the refiner's max-pool (§V-C)");
            }
        }
    }
}

/// The first characters of a token.
fn short(token: &str) -> &str {
    token.get(..10).unwrap_or(token)
}

/// IoU and residuals before and after refinement (one column without a refinement).
fn residuals(
    ui: &mut egui::Ui,
    iou_before: Option<f64>,
    before: Option<BoxError>,
    iou_after: Option<f64>,
    after: Option<BoxError>,
) {
    let rows = |e: Option<BoxError>| -> Vec<String> {
        e.map(|e| {
            vec![
                format!("{:+.3}", e.along),
                format!("{:+.3}", e.lateral),
                format!("{:+.3}", e.dz),
                format!("{:+.3}", e.dl),
                format!("{:+.3}", e.dw),
                format!("{:+.3}", e.dh),
                format!("{:+.2}", e.dyaw.to_degrees()),
            ]
        })
        .unwrap_or_default()
    };
    let names = [
        "along (m)",
        "lateral (m)",
        "z (m)",
        "l (m)",
        "w (m)",
        "h (m)",
        "yaw (°)",
    ];
    let (b, a) = (rows(before), rows(after));
    egui::Grid::new("mlod_selection_residuals")
        .striped(true)
        .num_columns(3)
        .show(ui, |ui| {
            ui.label("");
            ui.label(RichText::new("before").color(color32(PROPOSAL_COLOR)));
            if after.is_some() {
                ui.label(RichText::new("after").color(color32(REFINED_COLOR)));
            }
            ui.end_row();
            ui.label("3D IoU");
            ui.monospace(iou_before.map_or("–".into(), |v| format!("{v:.3}")));
            if let Some(v) = iou_after {
                ui.monospace(format!("{v:.3}"));
            }
            ui.end_row();
            for (k, name) in names.iter().enumerate() {
                ui.label(*name);
                ui.monospace(b.get(k).cloned().unwrap_or_default());
                if let Some(x) = a.get(k) {
                    ui.monospace(x);
                }
                ui.end_row();
            }
        });
}

/// Points per LiDAR, the uncertain share and the tr(Ξ) histogram of a box's points.
fn points(ui: &mut egui::Ui, title: &str, p: &PointsInside, format: Option<crate::dataset::DatasetFormat>) {
    ui.horizontal_wrapped(|ui| {
        ui.label(format!("{title} {}:", p.total));
        for (ch, n) in &p.per_lidar {
            ui.label(lidar_label(format, *ch));
            ui.label(n.to_string());
        }
    });
    ui.label(format!(
        "uncertain |P_u|/|P| {:.0} % ({} of {}), mean tr(Ξ) {:.4} m²",
        100.0 * p.uncertain_fraction(),
        p.uncertain,
        p.total,
        p.mean_trace
    ));
    if p.total == 0 {
        return;
    }
    let width = ui.available_width().min(300.0);
    let (rect, resp) = ui.allocate_exact_size(egui::vec2(width, 40.0), Sense::hover());
    let painter = ui.painter_at(rect);
    painter.rect_filled(rect, 2.0, ui.visuals().extreme_bg_color);
    let max = p.trace_histogram.iter().copied().max().unwrap_or(1).max(1) as f32;
    let n = TRACE_BINS as f32;
    for (i, &count) in p.trace_histogram.iter().enumerate() {
        if count == 0 {
            continue;
        }
        let h = (count as f32 / max).sqrt() * (rect.height() - 4.0);
        let x0 = rect.left() + i as f32 / n * rect.width();
        let x1 = rect.left() + (i + 1) as f32 / n * rect.width();
        painter.rect_filled(
            egui::Rect::from_min_max(
                egui::pos2(x0, rect.bottom() - h),
                egui::pos2(x1 - 1.0, rect.bottom()),
            ),
            0.0,
            color32(turbo((i as f32 + 0.5) / n)),
        );
    }
    resp.on_hover_text(format!(
        "tr(Ξ) of the points inside, {} to {} m² in {TRACE_BINS} log bins",
        trace_bin_edge(0),
        trace_bin_edge(TRACE_BINS)
    ));
}
