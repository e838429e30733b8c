//! The banners under the menu: what differs from the models' training data, and what the
//! sample on screen lacks (and what that turns off).

use eframe::egui;
use egui::{Color32, RichText};

use super::Panels;
use crate::dataset::LidarChannel;

/// Why the perturbation controls are off on a LIDAR_TOP-only sample (their tooltip).
pub(super) const NO_AUXILIARY: &str = "This sample has LIDAR_TOP only: α, play α, the manual offsets and \
    calibrate (ICP) act on the auxiliary LiDARs (LIDAR_FRONT_LEFT, LIDAR_FRONT_RIGHT), and there are none";

/// The banner under the menu: what the sample on screen lacks, and what that turns off.
pub fn banner(p: &mut Panels<'_>, ui: &mut egui::Ui) {
    if !p.loaded.depth_notes.is_empty() {
        let text = format!(
            "The models were trained on other data (`mlod stats` compares): {}.",
            p.loaded.depth_notes.join(" · ")
        );
        egui::Panel::top("depth_banner")
            .frame(
                egui::Frame::new()
                    .fill(Color32::from_rgb(70, 48, 78))
                    .inner_margin(egui::Margin::symmetric(8, 4)),
            )
            .show(ui, |ui| {
                ui.label(RichText::new(text).color(Color32::from_rgb(235, 210, 250)))
                    .on_hover_text(
                        "The loaded models' training statistics (manifest.json's training_stats) \
                         against a few samples of this dataset: detections here are outside what \
                         the models have seen",
                    );
            });
    }
    let rig = p.loaded.dataset.as_ref().and_then(|d| d.format().rig());
    if let Some(rig) = rig {
        egui::Panel::top("rig_banner")
            .frame(
                egui::Frame::new()
                    .fill(Color32::from_rgb(28, 58, 84))
                    .inner_margin(egui::Margin::symmetric(8, 4)),
            )
            .show(ui, |ui| {
                ui.label(RichText::new(format!(
                    "{rig}. α perturbs down_lidar; calibrate (ICP) aligns it to up_lidar; fusion cases fuse both."
                ))
                .color(Color32::from_rgb(200, 225, 250)));
            });
    }
    let Some(frame) = p.loaded.frame.clone() else {
        return;
    };
    let slots = p
        .loaded
        .dataset
        .as_ref()
        .map_or(&LidarChannel::ALL[..], |d| d.format().lidars());
    let mut missing = frame.missing_auxiliaries();
    missing.retain(|c| slots.contains(c));
    if missing.is_empty() {
        return;
    }
    let names = missing
        .iter()
        .map(|c| c.as_str())
        .collect::<Vec<_>>()
        .join(" and ");
    let text = if frame.is_single_lidar() {
        format!(
            "LIDAR_TOP only: this sample has no {names} (as most real Lyft scenes, and every KITTI and \
             nuScenes sample). α, play α, the offsets and calibrate (ICP) are off; fusion cases run on \
             LIDAR_TOP alone."
        )
    } else {
        format!("This sample has no {names}: α perturbs the auxiliary LiDAR that is there; fusion cases run without it.")
    };
    egui::Panel::top("lidar_banner")
        .frame(
            egui::Frame::new()
                .fill(Color32::from_rgb(92, 72, 20))
                .inner_margin(egui::Margin::symmetric(8, 4)),
        )
        .show(ui, |ui| {
            ui.label(RichText::new(text).color(Color32::from_rgb(255, 230, 160)));
        });
}
