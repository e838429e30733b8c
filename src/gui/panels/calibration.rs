//! The "Online calibration (ICP)" group of the perturbation panel: the calibrate button (Escape
//! cancels), per auxiliary LiDAR the error against the true extrinsic before → after, the
//! iterations and the degenerate directions, the corrected/drifted toggle and the prior the
//! corrected points' tr(Ξ) follows.

use eframe::egui;
use egui::{Color32, RichText};

use super::Panels;
use crate::calib::{OcPrior, PoseError};
use crate::gui::state::Action;

pub(super) fn calibration(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    ui.label(RichText::new("Online calibration (ICP)").strong());
    let busy = p.loaded.calibrating.is_some();
    let has_aux = p.loaded.frame.as_ref().is_none_or(|f| !f.is_single_lidar());
    ui.horizontal(|ui| {
        let label = if busy {
            "calibrating… (Esc)"
        } else {
            "calibrate (ICP)"
        };
        if ui
            .add_enabled(
                p.loaded.frame.is_some() && !busy && has_aux,
                egui::Button::new(label),
            )
            .on_hover_text(
                "Re-estimate the drifted auxiliary extrinsics by point-to-plane ICP against LiDAR-Top",
            )
            .on_disabled_hover_text(if has_aux {
                "A calibration is running or no sample is loaded"
            } else {
                super::NO_AUXILIARY
            })
            .clicked()
        {
            p.act(Action::Calibrate);
        }
        if busy && ui.small_button("cancel").clicked() {
            p.act(Action::CancelCalibration);
        }
    });
    // Three views only differ once something moved the auxiliary LiDARs (or ICP ran); at first
    // sight the row would be noise (and push the panel past 800 px).
    let moved = p.session.fuse.perturbation.alpha > 0.0
        || !p.session.fuse.manual.is_empty()
        || p.session.oc.calibration.is_some()
        || p.session.oc.show_factory;
    if has_aux && moved {
        view_selector(p, ui);
    }
    let Some(cal) = p.session.oc.calibration.clone() else {
        let text = if has_aux {
            "not calibrated: the cloud uses the drifted extrinsics"
        } else {
            "no auxiliary LiDAR to calibrate"
        };
        ui.label(RichText::new(text).weak());
        return;
    };
    let frame = p.loaded.frame.clone();
    let timings = p.shell.show_timings;
    for l in &cal.lidars {
        // Wrapped rows: nothing runs off the panel's right edge at 1280×800.
        ui.horizontal_wrapped(|ui| {
            ui.label(p.label(l.channel));
            let truth = frame
                .as_ref()
                .and_then(|f| f.lidar(l.channel))
                .map(|s| s.info.extrinsic);
            let fmt = |e: PoseError| format!("{:.3}° {:.1} cm", e.rot_deg, e.trans_m * 100.0);
            match truth {
                Some(t) => ui.monospace(format!("{} -> {}", fmt(l.error_before(&t)), fmt(l.error(&t)))),
                None => ui.label("—"),
            };
        });
        ui.horizontal_wrapped(|ui| {
            ui.add_space(12.0);
            let status = if !l.converged {
                RichText::new(format!("not converged ({} it)", l.iterations))
                    .color(Color32::from_rgb(230, 120, 60))
            } else if !l.degenerate.is_empty() {
                RichText::new(format!("degenerate: {}", l.degenerate_axes().join(", ")))
                    .color(Color32::from_rgb(230, 180, 60))
            } else {
                let ms = if timings {
                    format!(", {:.0} ms", l.ms)
                } else {
                    String::new()
                };
                RichText::new(format!(
                    "converged in {} it, fitness {:.2}{ms}",
                    l.iterations, l.fitness
                ))
                .weak()
            };
            ui.label(status).on_hover_text(format!(
                "RMSE {:.2} cm over {} correspondences; σ: t ({:.2}, {:.2}, {:.2}) cm, \
                 rot ({:.3}, {:.3}, {:.3})°",
                l.rmse * 100.0,
                l.correspondences,
                l.std()[0] * 100.0,
                l.std()[1] * 100.0,
                l.std()[2] * 100.0,
                l.std()[3].to_degrees(),
                l.std()[4].to_degrees(),
                l.std()[5].to_degrees()
            ));
        });
    }
    let against = if p.format().is_some_and(|f| f.rig().is_some()) {
        "error against the factory calibration (on real data not the truth): drifted -> calibrated"
    } else {
        "error against the true extrinsic: drifted -> calibrated"
    };
    ui.label(RichText::new(against).weak());
    let mut changed = false;
    ui.horizontal_wrapped(|ui| {
        ui.label("tr(Ξ) after calibration");
        changed |= ui
            .radio_value(&mut p.session.oc.prior, OcPrior::Icp, "ICP covariance")
            .on_hover_text("What ICP leaves uncertain (the (OC) cases' default)")
            .changed();
        changed |= ui
            .radio_value(&mut p.session.oc.prior, OcPrior::Alpha, "prior Θ(α)")
            .on_hover_text("The prior, as if ICP had not run")
            .changed();
    });
    if changed {
        p.act(Action::Refuse);
    }
}

/// Which extrinsics the cloud on screen uses, one click each: the dataset's own (the factory
/// calibration on real data), the perturbed ones (α and the offsets), or ICP's (calibrating first
/// when there is no current calibration).
fn view_selector(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    #[derive(PartialEq, Clone, Copy)]
    enum View {
        Factory,
        Perturbed,
        Icp,
    }
    let oc = &p.session.oc;
    let current = if oc.show_factory {
        View::Factory
    } else if oc.show_corrected && oc.calibration.is_some() {
        View::Icp
    } else {
        View::Perturbed
    };
    let mut view = current;
    ui.horizontal(|ui| {
        ui.label("view");
        ui.radio_value(&mut view, View::Factory, "factory").on_hover_text(
            "The dataset's own extrinsics (on real data, the factory calibration): no perturbation",
        );
        ui.radio_value(&mut view, View::Perturbed, "perturbed")
            .on_hover_text("The extrinsics perturbed by α and the manual offsets");
        ui.radio_value(&mut view, View::Icp, "ICP")
            .on_hover_text("ICP's estimate from the perturbed start (calibrates first if needed)");
    });
    if view == current {
        return;
    }
    p.session.oc.show_factory = view == View::Factory;
    p.session.oc.show_corrected = view == View::Icp;
    if view == View::Icp && p.session.oc.calibration.is_none() {
        if p.loaded.calibrating.is_none() {
            p.act(Action::Calibrate);
        }
        return;
    }
    p.act(Action::Refuse);
}
