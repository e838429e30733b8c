//! The Detection panel: pick a case (the paper's, their (OC) variants and ablations, and the cases
//! beyond the paper), run it on the sample on screen, switch its layers on and off and read its
//! boxes matched against the ground truth (for an MLOD case the refined boxes, with the
//! proposals' counts beside them).

use eframe::egui;
use egui::{Color32, RichText};

use super::Panels;
use crate::detect::Case;
use crate::gui::state::{
    color32, Action, DetectionCounts, FALSE_POSITIVE_COLOR, GT_COLOR, PROPOSAL_COLOR, REFINED_COLOR,
    REFINED_FALSE_POSITIVE_COLOR,
};

pub(super) fn detection(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    let mut run = false;
    let mut rematch = false;
    let mut redraw = false;
    let external = crate::gui::consent::external_cases(p.session);
    ui.horizontal(|ui| {
        let d = &mut p.session.detection;
        egui::ComboBox::new("mlod_detector_case", "case")
            .selected_text(d.case.paper_name())
            .show_ui(ui, |ui| {
                for c in Case::LISTED.into_iter().chain(external) {
                    if c == Case::BEYOND[0] {
                        ui.separator();
                        ui.weak("beyond the paper");
                    }
                    ui.selectable_value(&mut d.case, c, c.paper_name())
                        .on_hover_text(c.description());
                }
            });
        let label = if p.loaded.detecting {
            "Running…"
        } else {
            "Run (D)"
        };
        run |= ui
            .add_enabled(p.loaded.frame.is_some(), egui::Button::new(label))
            .on_hover_text("Run the detector on this sample with the current perturbation")
            .clicked();
    });
    if let Some(note) = p
        .loaded
        .frame
        .as_ref()
        .and_then(|f| p.session.detection.case.missing_lidars_note(f))
    {
        ui.label(RichText::new(note).color(Color32::from_rgb(230, 180, 90)));
    }
    compare_row(p, ui);
    ui.horizontal_wrapped(|ui| {
        if ui
            .button("failure cases…")
            .on_hover_text(
                "Scan this case over the scene or the dataset and list its worst samples and boxes",
            )
            .clicked()
        {
            p.act(Action::ToggleFailures);
        }
        models_label(p, ui);
    });
    ui.horizontal_wrapped(|ui| {
        let d = &mut p.session.detection;
        ui.checkbox(&mut d.auto_run, "run again on every change")
            .on_hover_text("Re-run after each change of sample, α or offsets (latest change wins)");
        gate_checkbox(p, ui);
    });
    let d = &mut p.session.detection;
    let mlod = d.case.is_mlod();
    rematch |= ui
        .add(egui::Slider::new(&mut d.min_score, 0.05..=0.95).text("min score"))
        .changed();
    ui.horizontal(|ui| {
        ui.label("true positive at 3D IoU ≥");
        rematch |= ui.radio_value(&mut d.match_iou, 0.5, "0.5").changed();
        rematch |= ui.radio_value(&mut d.match_iou, 0.7, "0.7").changed();
    });
    ui.horizontal_wrapped(|ui| {
        let proposals = if mlod { "proposals" } else { "proposal boxes" };
        redraw |= ui
            .checkbox(
                &mut d.show,
                RichText::new(proposals).color(color32(PROPOSAL_COLOR)),
            )
            .changed();
        if mlod {
            redraw |= ui
                .checkbox(
                    &mut d.show_refined,
                    RichText::new("refinements").color(color32(REFINED_COLOR)),
                )
                .on_hover_text("The refined boxes and a line from each proposal's centre to its refinement's")
                .changed();
        }
        redraw |= ui
            .checkbox(
                &mut p.session.show_ground_truth,
                RichText::new("ground-truth boxes").color(color32(GT_COLOR)),
            )
            .changed();
    });
    if mlod {
        ui.checkbox(&mut d.show_active, "show active points")
            .on_hover_text(
                "Highlight the points that won the refiner's max-pool (§V-C) for the hovered refined \
                 box, or the one clicked (click empty space to clear)",
            );
    }
    let stale = p.loaded.detection_is_stale(p.session.detection.case);
    let min_score = p.session.detection.min_score;
    match p.loaded.detection(min_score) {
        Some((v, c)) => {
            let refined = v.refinement.is_some();
            let (tp, fp) = if refined {
                (REFINED_COLOR, REFINED_FALSE_POSITIVE_COLOR)
            } else {
                (PROPOSAL_COLOR, FALSE_POSITIVE_COLOR)
            };
            let what = if refined { "refined boxes" } else { "proposals" };
            ui.horizontal_wrapped(|ui| {
                ui.label(format!("{}:", v.case.paper_name()));
                ui.label(format!("{} {what}", c.shown));
                ui.label(RichText::new(format!("{} TP", c.true_positives)).color(color32(tp)));
                ui.label(RichText::new(format!("{} FP", c.false_positives)).color(color32(fp)));
                ui.label(
                    RichText::new(format!(
                        "{} of {} {} missed",
                        c.missed,
                        c.ground_truth,
                        v.categories.join("/")
                    ))
                    .color(color32(GT_COLOR)),
                );
                if c.unscored() > 0 {
                    ui.label(RichText::new(format!("{} not scored", c.unscored())).weak())
                        .on_hover_text(
                            "outside the evaluated region: this dataset labels only what its camera sees \
                             (KITTI: camera 2's view without its DontCare regions), so boxes elsewhere \
                             are neither true nor false positives",
                        );
                }
            });
            compare_lines(p, ui, c);
            if refined {
                proposal_line(ui, &v.proposal_counts(min_score));
            }
            if p.shell.show_timings {
                let steps = if refined {
                    "weights, fuse, stage 1, gather, refiner"
                } else {
                    "weights, fuse, voxelise, network, NMS"
                };
                ui.label(RichText::new(format!("{:.0} ms ({steps})", v.millis)).weak());
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
        p.act(Action::RunDetector);
    }
    if rematch {
        p.act(Action::Rematch);
    } else if redraw {
        p.act(Action::RebuildLines);
    }
}

/// The proposals' counts under the refined ones, weaker, so that the refiner's gain shows.
fn proposal_line(ui: &mut egui::Ui, c: &DetectionCounts) {
    ui.label(
        RichText::new(format!(
            "proposals: {} TP, {} FP, {} missed",
            c.true_positives, c.false_positives, c.missed
        ))
        .weak(),
    );
}

/// The cases compare mode offers against `a`: any other case but the (OC) ones.
fn comparable(a: Case) -> impl Iterator<Item = Case> {
    Case::LISTED.into_iter().filter(move |c| *c != a && !c.is_oc())
}

/// "compare with [case]": a split viewport with a second case on the same perturbed frame.
fn compare_row(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    let a = p.session.detection.case;
    let mut changed = false;
    ui.horizontal(|ui| {
        let mut on = p.session.compare.is_some();
        let toggle = ui
            .add_enabled(!a.is_oc(), egui::Checkbox::new(&mut on, "compare with"))
            .on_hover_text("Split the viewport: a second case on the same perturbed frame, same camera")
            .on_disabled_hover_text("The (OC) cases see the calibrated cloud: they cannot share a viewport");
        if toggle.changed() {
            // Stage 1 against its MLOD, or MLOD against its stage 1, by default.
            let default = a
                .refined()
                .or_else(|| a.is_mlod().then(|| a.stage1()))
                .unwrap_or(Case::Input);
            p.session.compare = on
                .then_some(default)
                .filter(|b| *b != a)
                .or(on.then_some(Case::Top));
            changed = true;
        }
        if let Some(b) = &mut p.session.compare {
            egui::ComboBox::new("mlod_compare_case", "case B")
                .selected_text(b.paper_name())
                .show_ui(ui, |ui| {
                    for c in comparable(a) {
                        changed |= ui.selectable_value(b, c, c.paper_name()).changed();
                    }
                });
        }
    });
    if changed {
        p.act(Action::CompareChanged);
    }
}

/// In compare mode: the second case's counts and the difference, spelled out.
fn compare_lines(p: &Panels<'_>, ui: &mut egui::Ui, a: DetectionCounts) {
    let Some(b_case) = p.session.compare else { return };
    let a_case = p.session.detection.case;
    if b_case == a_case || b_case.is_oc() || a_case.is_oc() {
        return;
    }
    let Some(v) = p.loaded.detection_b.as_ref() else {
        ui.label(RichText::new(format!("{}: not run yet", b_case.paper_name())).weak());
        return;
    };
    let b = v.counts(p.session.detection.min_score);
    ui.label(format!(
        "{}: {} TP, {} FP, {} of {} missed",
        b_case.paper_name(),
        b.true_positives,
        b.false_positives,
        b.missed,
        b.ground_truth
    ));
    // From the main case's side: what it gains (or loses) over the compare case.
    let d = |x: usize, y: usize| x as i64 - y as i64;
    ui.label(
        RichText::new(format!(
            "{} vs {}: {:+} TP, {:+} FP, {:+} missed",
            a_case.paper_name(),
            b_case.paper_name(),
            d(a.true_positives, b.true_positives),
            d(a.false_positives, b.false_positives),
            d(a.missed, b.missed)
        ))
        .strong(),
    );
}

/// The models folder the detectors run from (beside the failure-cases button).
fn models_label(p: &Panels<'_>, ui: &mut egui::Ui) {
    let dir = &p.loaded.models;
    let shown = dir.strip_prefix(env!("CARGO_MANIFEST_DIR")).unwrap_or(dir);
    let adapted = p.loaded.models_adapted.as_deref();
    let name = match adapted {
        Some(_) => format!("models: {} (adapted)", shown.display()),
        None => format!("models: {}", shown.display()),
    };
    ui.label(RichText::new(name).weak()).on_hover_text(format!(
        "{}{}\nFile > Open models folder… runs the detectors from another folder",
        dir.display(),
        adapted.map_or(String::new(), |a| format!("\n{a}"))
    ));
}

/// The models folder's ground gate, switchable (beside "run again on every change").
fn gate_checkbox(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    if let (Some(m), false) = (p.loaded.ground_gate_m, p.session.detection.case.is_mlod()) {
        let gate = &mut p.session.detection.ground_gate;
        if ui
            .checkbox(gate, format!("ground gate {m} m"))
            .on_hover_text(
                "The models folder's gate (mlod train tune-gate chose it): drop stage-1 boxes \
                 whose bottom lies more than this above the ground around them; off shows what \
                 it drops (--ground-gate off in the CLI)",
            )
            .changed()
        {
            p.act(Action::GateChanged);
        }
    }
}
