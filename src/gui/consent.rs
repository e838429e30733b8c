//! Asking before an external detector runs: a session is data that people share, and the command
//! of an `ext:NAME` case in it is code. The window runs such a command only after showing it and
//! being told yes; the answer is remembered per command and session file (in the window's
//! storage), so the same session asks once.
//!
//! How it works: a case's definition is the session's (`Session::external`) or, failing that, the
//! one the command line gave (`mlod window --detector`, already defined in the process). A
//! definition that is the process's own runs at once; a session's that the user has not agreed to
//! becomes the pending question, drawn as a modal window with the command, its folder and
//! environment; "Run it" defines it in the process ([`external::define`]) and runs the case.

use std::collections::BTreeSet;

use eframe::egui;

use crate::detect::Case;
use crate::external::{self, ExternalSpec};
use crate::session::Session;

/// The window's storage key of the consents given.
pub const CONSENT_KEY: &str = "mlod_external_consent";

/// What the window may do with a case.
#[derive(Debug, Clone, PartialEq)]
pub enum Gate {
    /// Built in, or an external detector the process may run.
    Run,
    /// An external detector from the session, not agreed to yet (now the pending question).
    Ask,
    /// An external case nobody defined.
    Undefined(String),
}

/// The answer the user gave in the dialog.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Answer {
    Allow,
    Refuse,
}

/// The consents given and the question pending.
#[derive(Debug, Default)]
pub struct Consent {
    /// (session file, command, folder, environment) keys the user agreed to.
    pub granted: BTreeSet<String>,
    /// The definition waiting for an answer, and the case to run after a yes.
    pub pending: Option<(ExternalSpec, Case)>,
}

fn key(session: &Session, spec: &ExternalSpec) -> String {
    let file = session
        .source
        .0
        .as_ref()
        .map(|p| p.display().to_string())
        .unwrap_or_else(|| "(unsaved session)".into());
    let env: Vec<String> = spec.env.iter().map(|(k, v)| format!("{k}={v}")).collect();
    let dir = spec.dir.as_ref().map(|d| d.display().to_string());
    format!(
        "{file}\n{}\n{}\n{}",
        spec.command_line(),
        dir.unwrap_or_default(),
        env.join(" ")
    )
}

impl Consent {
    /// Whether `case` may run now; an external case from the session that was agreed to before
    /// is defined on the way, one not agreed to becomes the pending question.
    pub fn gate(&mut self, case: Case, session: &Session) -> Gate {
        let Some(name) = case.external_name() else {
            return Gate::Run;
        };
        let ours = external::definition(name);
        let Some(spec) = session.external.iter().find(|s| s.name == name).cloned() else {
            return match ours {
                Some(_) => Gate::Run,
                None => Gate::Undefined(format!(
                    "{case}: no external detector '{name}' is defined (start the window with --detector {name}=COMMAND)"
                )),
            };
        };
        if ours.as_ref() == Some(&spec) {
            return Gate::Run;
        }
        if self.granted.contains(&key(session, &spec)) && external::define(spec.clone()).is_ok() {
            return Gate::Run;
        }
        self.pending = Some((spec, case));
        Gate::Ask
    }

    /// Applies the user's answer to the pending question: the case to run after a yes.
    pub fn answer(&mut self, answer: Answer, session: &Session) -> Result<Option<Case>, String> {
        let Some((spec, case)) = self.pending.take() else {
            return Ok(None);
        };
        match answer {
            Answer::Refuse => Ok(None),
            Answer::Allow => {
                external::define(spec.clone()).map_err(|e| e.to_string())?;
                self.granted.insert(key(session, &spec));
                Ok(Some(case))
            }
        }
    }

    /// The pending question as a modal window; the button pressed, if any.
    pub fn dialog(&self, ctx: &egui::Context, session: &Session) -> Option<Answer> {
        let (spec, case) = self.pending.as_ref()?;
        let mut answer = None;
        let file = session
            .source
            .0
            .as_ref()
            .map(|p| p.display().to_string())
            .unwrap_or_else(|| "this session".into());
        egui::Modal::new(egui::Id::unique("mlod_external_consent")).show(ctx, |ui| {
            ui.heading("Run an external detector?");
            ui.label(format!(
                "{file} runs the case {case} with a program of its own. It will run on this computer with your permissions:"
            ));
            ui.add(egui::Label::new(egui::RichText::new(spec.command_line()).monospace()).wrap());
            if let Some(d) = &spec.dir {
                ui.label(format!("in the folder {}", d.display()));
            }
            if !spec.env.is_empty() {
                let env: Vec<String> = spec.env.iter().map(|(k, v)| format!("{k}={v}")).collect();
                ui.label(format!("with {}", env.join(" ")));
            }
            ui.label("Run it only if you trust where the session came from. The answer is remembered for this command and file.");
            ui.horizontal(|ui| {
                if ui.button("Run it").clicked() {
                    answer = Some(Answer::Allow);
                }
                if ui.button("Don't run").clicked() {
                    answer = Some(Answer::Refuse);
                }
            });
        });
        answer
    }
}

/// The external cases the case list offers: `ext:NAME` and `mlod-ext:NAME` of every detector the
/// session or the command line defines, by name.
pub fn external_cases(session: &Session) -> Vec<Case> {
    let mut names: BTreeSet<String> = session.external.iter().map(|s| s.name.clone()).collect();
    names.extend(external::definitions().into_iter().map(|s| s.name));
    names
        .iter()
        .flat_map(|n| [external::ext_case(n), external::mlod_ext_case(n)])
        .collect()
}

/// Adds to `session` the definition (from the command line) of each external case it uses and does
/// not define itself, so that the saved session says what it ran.
pub fn store_definitions(session: &mut Session) {
    let cases = [Some(session.detection.case), session.compare];
    for name in cases.into_iter().flatten().filter_map(|c| c.external_name()) {
        if session.external.iter().all(|s| s.name != name) {
            if let Some(spec) = external::definition(name) {
                session.external.push(spec);
            }
        }
    }
}
