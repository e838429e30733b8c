//! The failure browser, docked under the viewport (resizable; it never covers the boxes it finds):
//! scan the session's case over this scene or the whole dataset at the session's perturbation
//! (progress bar, cancel), then read the worst samples and their failing boxes — misses, false
//! positives, the largest IoU drops against α = 0 — with their class, range and points, sortable
//! and filtered to what the perturbation alone lost if asked; a click on a box loads its sample
//! with the same perturbation and selects and frames it.

use eframe::egui;
use egui::RichText;

use super::Panels;
use crate::analysis::failures::{BoxFailure, FailureKind};
use crate::gui::state::{color32, Action, FailureSort, FALSE_POSITIVE_COLOR, GT_COLOR, SELECTED_COLOR};
use crate::session::FailureScope;

/// Rows shown at most (the worst first).
const MAX_ROWS: usize = 200;

/// The failure browser docked at the bottom of the viewport, while open.
pub fn failure_panel(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    if p.shell.failures.is_none() {
        return;
    }
    egui::Panel::bottom("mlod_failures")
        .resizable(true)
        .default_size(210.0)
        .min_size(90.0)
        .show(ui, |ui| {
            ui.horizontal(|ui| {
                ui.strong("Failure cases");
                ui.with_layout(egui::Layout::right_to_left(egui::Align::Center), |ui| {
                    if ui.small_button("close").clicked() {
                        p.act(Action::ToggleFailures);
                    }
                });
            });
            browser(p, ui);
        });
}

fn kind_label(k: FailureKind) -> RichText {
    match k {
        FailureKind::Missed => RichText::new("missed").color(color32(GT_COLOR)),
        FailureKind::FalsePositive => RichText::new("false positive").color(color32(FALSE_POSITIVE_COLOR)),
        FailureKind::IouDrop => RichText::new("IoU drop").color(color32(SELECTED_COLOR)),
    }
}

fn browser(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    let case = p.session.detection.case;
    let alpha = p.session.fuse.perturbation.alpha;
    let seed = p.session.fuse.perturbation.seed;
    let Some(b) = p.shell.failures.as_mut() else {
        return;
    };
    let mut actions = Vec::new();
    ui.horizontal(|ui| {
        ui.radio_value(&mut b.scope, FailureScope::Scene, "this scene");
        ui.radio_value(&mut b.scope, FailureScope::Dataset, "whole dataset");
        let label = format!("scan {} at α = {alpha} (seed {seed})", case.paper_name());
        if ui
            .add_enabled(b.running.is_none(), egui::Button::new(label))
            .on_hover_text("Run the case here and at α = 0 on every sample of the scope, in the background")
            .clicked()
        {
            actions.push(Action::ScanFailures);
        }
    });
    if let Some((_, done, total, _)) = &b.running {
        let d = done.load(std::sync::atomic::Ordering::Relaxed);
        ui.horizontal(|ui| {
            ui.add(
                egui::ProgressBar::new(d as f32 / (*total).max(1) as f32)
                    .text(format!("{d} / {total} samples")),
            );
            if ui.button("cancel").clicked() {
                actions.push(Action::CancelScan);
            }
        });
    }
    if let Some((c, a, s, rows)) = &b.result {
        ui.label(
            RichText::new(format!(
                "{} at α = {a} (seed {s}): {} samples, {} missed ({} at α = 0), {} false positives",
                c.paper_name(),
                rows.len(),
                rows.iter().map(|r| r.missed).sum::<usize>(),
                rows.iter().map(|r| r.missed_at_zero).sum::<usize>(),
                rows.iter().map(|r| r.false_positives).sum::<usize>(),
            ))
            .weak(),
        );
        if p.shell.show_timings {
            ui.label(RichText::new(format!("scanned in {:.1} s", b.millis / 1e3)).weak());
        }
        ui.horizontal(|ui| {
            ui.label("sort by");
            ui.radio_value(&mut b.sort, FailureSort::Sample, "worst sample");
            ui.radio_value(&mut b.sort, FailureSort::Drop, "IoU drop");
            ui.radio_value(&mut b.sort, FailureSort::Kind, "kind");
            ui.separator();
            ui.checkbox(&mut b.lost_only, "lost by the perturbation only")
                .on_hover_text("Only the objects detected at α = 0 and missed now");
        });
        let lost_only = b.lost_only;
        let mut boxes: Vec<(usize, &BoxFailure)> = rows
            .iter()
            .flat_map(|r| r.boxes.iter().map(move |x| (r.index, x)))
            .filter(|(_, x)| !lost_only || x.lost_by_perturbation())
            .collect();
        match b.sort {
            FailureSort::Sample => {}
            FailureSort::Drop => boxes.sort_by(|x, y| y.1.iou_drop().total_cmp(&x.1.iou_drop())),
            FailureSort::Kind => boxes.sort_by_key(|x| x.1.kind as u8),
        }
        egui::ScrollArea::vertical()
            .auto_shrink([false, false])
            .show(ui, |ui| {
                egui::Grid::new("mlod_failure_rows")
                    .striped(true)
                    .num_columns(8)
                    .show(ui, |ui| {
                        for h in [
                            "sample",
                            "what",
                            "class",
                            "range",
                            "points",
                            "IoU α = 0",
                            "IoU now",
                            "score",
                        ] {
                            ui.strong(h);
                        }
                        ui.end_row();
                        for (index, f) in boxes.iter().take(MAX_ROWS) {
                            let link = ui
                                .link(format!(
                                    "#{index} {}",
                                    &f.sample_token.get(..8).unwrap_or(&f.sample_token)
                                ))
                                .on_hover_text(
                                    "Load this sample with the same perturbation, select and focus the box",
                                );
                            ui.label(kind_label(f.kind));
                            ui.label(&f.category);
                            ui.monospace(format!("{:.1} m", f.range()));
                            ui.monospace(format!("{}", f.points));
                            let iou = |v: Option<f64>| v.map_or("–".to_string(), |x| format!("{x:.2}"));
                            ui.monospace(iou(f.iou_at_zero));
                            ui.monospace(iou(f.iou_now));
                            ui.monospace(f.score.map_or("–".to_string(), |s| format!("{s:.2}")));
                            ui.end_row();
                            if link.clicked() {
                                actions.push(Action::GoToFailure((*f).clone()));
                            }
                        }
                    });
                if boxes.len() > MAX_ROWS {
                    ui.label(RichText::new(format!("… and {} more", boxes.len() - MAX_ROWS)).weak());
                }
            });
    } else if b.running.is_none() {
        ui.label(RichText::new("no scan yet").weak());
    }
    p.actions.extend(actions);
}
