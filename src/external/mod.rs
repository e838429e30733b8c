//! Detectors in other processes: the cases `ext:NAME` and `mlod-ext:NAME`, served over the
//! protocol `mlod-detector/1` (docs/external.md is its specification).
//!
//! How it works: a detector is defined by a command line (with a working folder, environment,
//! classes and a timeout), from `--detector NAME=COMMAND` or a detectors file
//! ([`DetectorsFile`], `detectors.toml`). A definition is data, and its command is code: nothing
//! here runs a command that was not [`define`]d by the caller (the CLI defines only what its own
//! command line names; the window only after the user agreed). [`process::ExternalDetector`]
//! starts the command at its first frame and keeps it for the run: per frame it writes the fused
//! cloud ([`protocol`]) to a file, sends one JSON line on the child's stdin and waits, bounded by
//! the timeout, for one JSON line on its stdout; any failure kills and reaps the child and names
//! the detector and what it did.
//!
//! Case names are interned (one leaked string per distinct name a user defines), so that
//! [`Case`] stays `Copy`.

pub mod process;
pub mod protocol;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::detect::Case;

pub use process::{spawn_count, ExternalDetector};

pub use crate::detect::case::{check_name, ext_case, mlod_ext_case, EXT_PREFIX, MLOD_EXT_PREFIX};

impl From<ExternalError> for crate::detect::DetectError {
    fn from(e: ExternalError) -> Self {
        crate::detect::DetectError::External(e.to_string())
    }
}

/// How long a detector may take to answer one frame unless told otherwise (s).
pub const DEFAULT_TIMEOUT_S: f64 = 60.0;

/// Errors of external detectors: each names the detector (or the definition) and what happened.
#[derive(Debug, thiserror::Error)]
pub enum ExternalError {
    /// The detector process did something the protocol does not allow (or did not start).
    #[error("external detector '{name}' (`{command}`): {what}")]
    Detector {
        name: String,
        command: String,
        what: String,
    },
    /// A case names a detector nobody defined.
    #[error("{case}: no external detector '{name}' is defined: give --detector {name}=COMMAND, or --detectors FILE that defines it")]
    Undefined { case: String, name: String },
    /// A definition that cannot be used.
    #[error("detector definition {what}")]
    Definition { what: String },
    /// A detectors file that cannot be read.
    #[error("detectors file {path}: {what}")]
    File { path: PathBuf, what: String },
}

/// How to run one external detector.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExternalSpec {
    /// Its case is `ext:NAME`.
    pub name: String,
    /// The program and its arguments (a command line split like a shell would).
    pub command: Vec<String>,
    /// Working folder of the process (default: mlod's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dir: Option<PathBuf>,
    /// Variables added to its environment.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub env: BTreeMap<String, String>,
    /// The categories it detects (what evaluation scores it on).
    #[serde(default = "default_classes")]
    pub classes: Vec<String>,
    /// Longest wait for one answer (s); `None`: [`DEFAULT_TIMEOUT_S`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timeout_s: Option<f64>,
}

fn default_classes() -> Vec<String> {
    vec!["car".into()]
}

impl ExternalSpec {
    /// A detector NAME running `command`, with the defaults for the rest.
    pub fn new(name: &str, command: Vec<String>) -> Result<Self, ExternalError> {
        let spec = Self {
            name: name.to_string(),
            command,
            dir: None,
            env: BTreeMap::new(),
            classes: default_classes(),
            timeout_s: None,
        };
        spec.validate()?;
        Ok(spec)
    }

    /// `NAME=COMMAND` (`--detector`), the command split like a shell line.
    pub fn parse_arg(arg: &str) -> Result<Self, ExternalError> {
        let bad = |what: &str| ExternalError::Definition {
            what: format!("'{arg}': {what}"),
        };
        let (name, command) = arg
            .split_once('=')
            .ok_or_else(|| bad("expected NAME=COMMAND, e.g. pp='python3 serve.py'"))?;
        let words = shlex::split(command).ok_or_else(|| bad("unbalanced quotes in the command"))?;
        Self::new(name.trim(), words)
    }

    /// The whole command line, quoted where needed (what the window shows before running it).
    pub fn command_line(&self) -> String {
        shlex::try_join(self.command.iter().map(String::as_str)).unwrap_or_else(|_| self.command.join(" "))
    }

    /// The wait for one answer.
    pub fn timeout(&self) -> Duration {
        Duration::from_secs_f64(self.timeout_s.unwrap_or(DEFAULT_TIMEOUT_S))
    }

    /// Checks the name, command, classes and timeout.
    pub fn validate(&self) -> Result<(), ExternalError> {
        let bad = |what: String| ExternalError::Definition {
            what: format!("'{}': {what}", self.name),
        };
        check_name(&self.name).map_err(bad)?;
        if self.command.first().is_none_or(|p| p.is_empty()) {
            return Err(bad("the command is empty".into()));
        }
        if self.classes.is_empty() || self.classes.iter().any(|c| c.is_empty()) {
            return Err(bad("classes must name at least one category".into()));
        }
        if let Some(t) = self.timeout_s {
            if !(t.is_finite() && t > 0.0 && t <= 86_400.0) {
                return Err(bad(format!("timeout {t} s is not in (0, 86400]")));
            }
        }
        Ok(())
    }
}

fn registry() -> std::sync::MutexGuard<'static, BTreeMap<String, ExternalSpec>> {
    static DEFINED: Mutex<BTreeMap<String, ExternalSpec>> = Mutex::new(BTreeMap::new());
    match DEFINED.lock() {
        Ok(g) => g,
        Err(p) => p.into_inner(),
    }
}

/// Makes `spec` the definition of its name in this process (replacing an earlier one): from here
/// on, loading `ext:NAME` may run its command. Call it only for definitions the user gave (on the
/// command line, in a file named there, or agreed to in the window).
pub fn define(spec: ExternalSpec) -> Result<(), ExternalError> {
    spec.validate()?;
    registry().insert(spec.name.clone(), spec);
    Ok(())
}

/// The definition of NAME, if one was given.
pub fn definition(name: &str) -> Option<ExternalSpec> {
    registry().get(name).cloned()
}

/// Every definition given, by name.
pub fn definitions() -> Vec<ExternalSpec> {
    registry().values().cloned().collect()
}

/// The detector of an `ext:NAME` case (not started yet: its process starts at the first frame).
pub fn load(case: Case) -> Result<ExternalDetector, ExternalError> {
    let name = case.external_name().ok_or_else(|| ExternalError::Definition {
        what: format!("{case} is not an external case"),
    })?;
    let spec = definition(name).ok_or_else(|| ExternalError::Undefined {
        case: case.to_string(),
        name: name.to_string(),
    })?;
    Ok(ExternalDetector::new(spec))
}

/// A detectors file (`detectors.toml`): one table per detector,
///
/// ```toml
/// [detectors.pp]
/// command = "python3 serve.py --cfg pointpillars.yaml"   # or ["python3", "serve.py", …]
/// dir = "../openpcdet"          # relative to the file's folder
/// env = { CUDA_VISIBLE_DEVICES = "0" }
/// classes = ["car"]
/// timeout = 30                  # seconds per answer
/// ```
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DetectorsFile {
    pub detectors: Vec<ExternalSpec>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileEntry {
    command: Command,
    #[serde(default)]
    dir: Option<PathBuf>,
    #[serde(default)]
    env: BTreeMap<String, String>,
    #[serde(default = "default_classes")]
    classes: Vec<String>,
    #[serde(default)]
    timeout: Option<f64>,
}

#[derive(Deserialize)]
#[serde(untagged)]
enum Command {
    Line(String),
    Words(Vec<String>),
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileShape {
    #[serde(default)]
    detectors: BTreeMap<String, FileEntry>,
}

impl DetectorsFile {
    /// Reads `path`; relative `dir`s are taken from the file's folder.
    pub fn load(path: &Path) -> Result<Self, ExternalError> {
        let bad = |what: String| ExternalError::File {
            path: path.to_path_buf(),
            what,
        };
        let text = std::fs::read_to_string(path).map_err(|e| bad(e.to_string()))?;
        let base = path.parent().unwrap_or(Path::new("."));
        Self::parse(&text, base).map_err(bad)
    }

    /// Parses the text of a detectors file whose folder is `base`.
    pub fn parse(text: &str, base: &Path) -> Result<Self, String> {
        let shape: FileShape = toml::from_str(text).map_err(|e| e.to_string())?;
        let mut detectors = Vec::new();
        for (name, e) in shape.detectors {
            let command = match e.command {
                Command::Words(w) => w,
                Command::Line(l) => shlex::split(&l)
                    .ok_or_else(|| format!("detector '{name}': unbalanced quotes in the command"))?,
            };
            let spec = ExternalSpec {
                name,
                command,
                dir: e.dir.map(|d| if d.is_absolute() { d } else { base.join(d) }),
                env: e.env,
                classes: e.classes,
                timeout_s: e.timeout,
            };
            spec.validate().map_err(|e| e.to_string())?;
            detectors.push(spec);
        }
        Ok(Self { detectors })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_and_print_back() {
        let c: Case = "ext:pp-1.v2".parse().unwrap();
        assert_eq!(c.as_str(), "ext:pp-1.v2");
        assert_eq!(c.external_name(), Some("pp-1.v2"));
        let m: Case = "mlod-ext:pp-1.v2".parse().unwrap();
        assert!(m.is_mlod() && !c.is_mlod());
        assert_eq!(m.stage1(), c);
        assert_eq!(c.refined(), Some(m));
        assert_eq!(serde_json::to_string(&m).unwrap(), "\"mlod-ext:pp-1.v2\"");
        assert_eq!(serde_json::from_str::<Case>("\"ext:pp-1.v2\"").unwrap(), c);
        assert_eq!(
            serde_json::from_str::<Case>("\"mlod-i-notrace\"").unwrap(),
            Case::MlodINoTrace
        );
        for bad in ["ext:", "ext:a b", "ext:-x", "ext:a/b", "nope"] {
            assert!(bad.parse::<Case>().is_err(), "{bad}");
        }
    }

    #[test]
    fn detector_args_split_like_a_shell() {
        let s = ExternalSpec::parse_arg("pp=python3 'my serve.py' --x \"a b\"").unwrap();
        assert_eq!(s.name, "pp");
        assert_eq!(s.command, ["python3", "my serve.py", "--x", "a b"]);
        assert_eq!(s.command_line(), "python3 'my serve.py' --x 'a b'");
        assert!(ExternalSpec::parse_arg("pp").is_err());
        assert!(ExternalSpec::parse_arg("pp=").is_err());
        assert!(ExternalSpec::parse_arg("pp='open").is_err());
    }

    #[test]
    fn detectors_files_resolve_their_folders() {
        let f = DetectorsFile::parse(
            "[detectors.a]\ncommand = \"python3 a.py\"\ndir = \"sub\"\nenv = { K = \"v\" }\ntimeout = 5\n\
             [detectors.b]\ncommand = [\"./b\", \"x y\"]\nclasses = [\"car\", \"pedestrian\"]\n",
            Path::new("/base"),
        )
        .unwrap();
        let a = &f.detectors[0];
        assert_eq!(a.dir.as_deref(), Some(Path::new("/base/sub")));
        assert_eq!(a.env["K"], "v");
        assert_eq!(a.timeout(), Duration::from_secs(5));
        assert_eq!(f.detectors[1].command, ["./b", "x y"]);
        assert!(DetectorsFile::parse("[detectors.a]\ncommand = \"\"\n", Path::new(".")).is_err());
        assert!(DetectorsFile::parse("[detectors.a]\ncmd = \"x\"\n", Path::new(".")).is_err());
        assert!(
            DetectorsFile::parse("[detectors.a]\ncommand = \"x\"\ntimeout = -1\n", Path::new(".")).is_err()
        );
    }
}
