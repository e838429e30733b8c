//! The desktop debugger (eframe + egui on wgpu). This first window is a placeholder that already
//! runs through the library: it shows the paper's worked example of §III-B and lets the user drag
//! α and switch the linearisation. The 3D viewport, sample browser and perturbation panel come
//! with the GUI issue; the GUI never computes geometry itself, it calls `crate::uncertainty`.

use std::path::{Path, PathBuf};

use eframe::egui;
use nalgebra::Matrix3;

use crate::uncertainty::propagate::{covariance, worked_example};
use crate::uncertainty::{Linearization, Prior};

/// The window title (screenshots find the window by it).
pub const TITLE: &str = "MLOD debugger";

/// The embedded sample dataset next to the crate.
pub fn default_dataset() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("sample_data")
}

/// The placeholder application state.
pub struct MlodApp {
    dataset: PathBuf,
    alpha: f64,
    linearization: Linearization,
}

impl MlodApp {
    pub fn new(dataset: PathBuf) -> Self {
        Self {
            dataset,
            alpha: 0.02,
            linearization: Linearization::Separate,
        }
    }

    fn worked_example_xi(&self) -> Option<Matrix3<f64>> {
        let (r, t, p) = worked_example();
        let prior = Prior::paper().scaled(self.alpha).ok()?;
        Some(covariance(&r, &t, &p, &prior, self.linearization))
    }
}

impl eframe::App for MlodApp {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        egui::Panel::top("top_bar").show(ui, |ui| {
            ui.horizontal(|ui| {
                ui.heading(TITLE);
                ui.separator();
                ui.label(format!("dataset: {}", self.dataset.display()));
            });
        });
        egui::CentralPanel::default().show(ui, |ui| {
            ui.add_space(8.0);
            ui.label(
                "Multi-LiDAR 3D object detection under extrinsic perturbation (MLOD). \
                 Coming next: the 3D viewport of a Lyft sample with points coloured by tr(Ξ), \
                 the perturbation panel, detectors, the refiner and ground-truth boxes.",
            );
            ui.add_space(12.0);
            ui.group(|ui| {
                ui.strong("Uncertainty propagation — paper §III-B worked example");
                ui.label("extrinsic rpy (10°, 10°, 10°), t = (1, 1, 1) m, point p = (10, 10, 10) m");
                ui.add(
                    egui::Slider::new(&mut self.alpha, 0.0..=0.1)
                        .text("α")
                        .step_by(0.001),
                );
                ui.horizontal(|ui| {
                    for lin in Linearization::ALL {
                        ui.radio_value(&mut self.linearization, lin, lin.name());
                    }
                });
                if let Some(xi) = self.worked_example_xi() {
                    egui::Grid::new("xi").striped(true).show(ui, |ui| {
                        for i in 0..3 {
                            for j in 0..3 {
                                ui.monospace(format!("{:>8.4}", xi[(i, j)]));
                            }
                            ui.end_row();
                        }
                    });
                    let std: Vec<String> = (0..3).map(|i| format!("{:.3}", xi[(i, i)].sqrt())).collect();
                    ui.label(format!(
                        "tr(Ξ) = {:.4} m²   std = [{}] m",
                        xi.trace(),
                        std.join(", ")
                    ));
                }
            });
        });
    }
}

/// Opens the window. Errors (no GPU adapter, no display) come back instead of panicking.
pub fn run(dataset: PathBuf) -> Result<(), eframe::Error> {
    let options = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default()
            .with_title(TITLE)
            .with_inner_size([1280.0, 800.0]),
        ..Default::default()
    };
    let result = eframe::run_native(
        TITLE,
        options,
        Box::new(move |_cc| Ok(Box::new(MlodApp::new(dataset)))),
    );
    if let Err(e) = &result {
        eprintln!(
            "mlod: could not open the window ({e}).\n  On Linux without a GPU install software Vulkan: \
             `apt-get install mesa-vulkan-drivers libvulkan1`, or try WGPU_BACKEND=gl; \
             without a display use Xvfb (`xvfb-run -a mlod`)."
        );
    }
    result
}
