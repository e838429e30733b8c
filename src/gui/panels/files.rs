//! File dialogs that never fail silently. Where a desktop file dialog can open (rfd, through the
//! XDG desktop portal on Linux) it is used; where none can — no session bus, as under Xvfb, or
//! the dialog came back at once without a user in the loop — a small window asks for the path
//! in a text field instead. Either way the chosen path becomes the purpose's [`Action`].

use std::path::PathBuf;
use std::time::{Duration, Instant};

use eframe::egui;
use egui::RichText;

use super::Panels;
use crate::gui::state::{FilePurpose, PathPrompt};

/// A dialog that returns nothing faster than this did not open (no person cancels that fast).
const TOO_FAST: Duration = Duration::from_millis(300);

/// Whether a desktop file dialog can open here: a D-Bus session bus (the portal's transport)
/// and not switched off with `MLOD_FILE_DIALOG=off`.
pub fn dialog_service_available() -> bool {
    if std::env::var("MLOD_FILE_DIALOG").is_ok_and(|v| v == "off") {
        return false;
    }
    if cfg!(target_os = "linux") {
        return std::env::var_os("DBUS_SESSION_BUS_ADDRESS").is_some_and(|v| !v.is_empty());
    }
    true
}

/// Asks for a path for `purpose`: the desktop dialog, or the path field where none opens.
pub fn ask(p: &mut Panels<'_>, purpose: FilePurpose) {
    if !p.shell.native_dialogs {
        open_prompt(p, purpose, "no desktop file dialog is available here");
        return;
    }
    let start = Instant::now();
    match native(purpose) {
        Some(path) => p.act(purpose.action(path)),
        None if start.elapsed() < TOO_FAST => {
            // It came back before anyone could have cancelled it: it never opened. Ask the
            // path field from now on.
            p.shell.native_dialogs = false;
            open_prompt(p, purpose, "the desktop file dialog did not open");
        }
        None => {}
    }
}

fn native(purpose: FilePurpose) -> Option<PathBuf> {
    let mut d = rfd::FileDialog::new().set_title(purpose.title());
    if !purpose.extensions().is_empty() {
        d = d.add_filter(purpose.title(), purpose.extensions());
    }
    if purpose.folder() {
        d.pick_folder()
    } else if purpose.saves() {
        d.set_file_name(purpose.default_name()).save_file()
    } else {
        d.pick_file()
    }
}

fn open_prompt(p: &mut Panels<'_>, purpose: FilePurpose, why: &str) {
    let text = if purpose.folder() {
        p.session.dataset.display().to_string()
    } else {
        let dir = std::env::current_dir().unwrap_or_default();
        dir.join(purpose.default_name()).display().to_string()
    };
    p.shell.prompt = Some(PathPrompt {
        purpose,
        text,
        why: why.to_string(),
    });
}

/// The path field, while a file action waits for a path.
pub fn file_prompt(p: &mut Panels<'_>, ctx: &egui::Context) {
    let Some(prompt) = p.shell.prompt.as_mut() else {
        return;
    };
    let mut done = None;
    let mut open = true;
    egui::Window::new(prompt.purpose.title())
        .id(egui::Id::unique("mlod_file_prompt"))
        .open(&mut open)
        .collapsible(false)
        .resizable(false)
        .anchor(egui::Align2::CENTER_CENTER, [0.0, 0.0])
        .show(ctx, |ui| {
            ui.label(RichText::new(format!("{}: type the path.", prompt.why)).weak());
            let what = if prompt.purpose.folder() { "folder" } else { "file" };
            let field = ui.add(
                egui::TextEdit::singleline(&mut prompt.text)
                    .desired_width(460.0)
                    .hint_text(format!("path of the {what}")),
            );
            let enter = field.lost_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter));
            ui.horizontal(|ui| {
                let verb = if prompt.purpose.saves() { "save" } else { "open" };
                let ok = ui.add_enabled(!prompt.text.trim().is_empty(), egui::Button::new(verb));
                if ok.clicked() || (enter && !prompt.text.trim().is_empty()) {
                    done = Some(Some(PathBuf::from(prompt.text.trim())));
                }
                if ui.button("cancel").clicked() {
                    done = Some(None);
                }
            });
        });
    if !open {
        done = Some(None);
    }
    if let Some(answer) = done {
        let purpose = prompt.purpose;
        p.shell.prompt = None;
        if let Some(path) = answer {
            p.act(purpose.action(path));
        }
    }
}
