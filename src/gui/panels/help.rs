//! The F1 help: every key and mouse gesture in a two-column table.

use eframe::egui;
use egui::RichText;

use super::Panels;

/// (key or gesture, what it does), in the order the help lists them.
pub const HELP_ROWS: &[(&str, &str)] = &[
    ("Drag", "rotate (bird's eye: pan)"),
    (
        "Right-drag, Shift+drag, middle-drag",
        "pan (bird's eye: right-drag rotates)",
    ),
    ("Scroll or pinch", "zoom"),
    ("Double-click a point", "focus on it"),
    ("Click a box", "select it (details in the right panel)"),
    ("F", "focus the selected box"),
    ("Esc", "close / cancel / clear the selection"),
    ("Left / Right", "previous / next sample"),
    ("B", "bird's eye / overview"),
    ("D", "run the detector (Detection panel)"),
    ("Tab", "hide / show the side panels"),
    ("Ctrl+S", "save the session (to its file, once it has one)"),
    ("Ctrl+O", "open a dataset"),
    ("F1 or ?", "this help"),
];

pub fn help_overlay(p: &mut Panels<'_>, ctx: &egui::Context) {
    if !p.shell.show_help {
        return;
    }
    let mut open = true;
    egui::Window::new("Keyboard and mouse")
        .open(&mut open)
        .collapsible(false)
        .resizable(false)
        .anchor(egui::Align2::CENTER_CENTER, [0.0, 0.0])
        .show(ctx, |ui| {
            egui::Grid::new("mlod_help")
                .striped(true)
                .num_columns(2)
                .spacing([18.0, 4.0])
                .show(ui, |ui| {
                    for (key, what) in HELP_ROWS {
                        ui.label(RichText::new(*key).monospace().strong());
                        ui.label(*what);
                        ui.end_row();
                    }
                });
            ui.separator();
            ui.label("Drop a dataset folder or a session .json on the window to open it.");
        });
    if !open {
        p.shell.show_help = false;
    }
}
