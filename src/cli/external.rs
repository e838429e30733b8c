//! The options that define external detectors (`ext:NAME`, `mlod-ext:NAME`): `--detector
//! NAME=COMMAND`, `--detectors FILE` and `--detector-timeout`, shared by every command that takes
//! a case. Only what is named here is ever run (docs/external.md).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};

use mlod::external::{self, DetectorsFile, ExternalSpec};

#[derive(clap::Args, Clone, Default)]
pub struct ExternalArgs {
    /// An external detector for the cases ext:NAME and mlod-ext:NAME: NAME=COMMAND, the command
    /// split like a shell line, speaking mlod-detector/1 (docs/external.md). Repeatable.
    #[arg(long = "detector", value_name = "NAME=COMMAND")]
    pub detector: Vec<String>,
    /// A detectors file (detectors.toml: command, dir, env, classes, timeout per detector).
    /// Repeatable.
    #[arg(long = "detectors", value_name = "FILE")]
    pub detectors: Vec<PathBuf>,
    /// Longest wait for one answer of an external detector, in seconds (default 60; overrides
    /// the files' timeouts).
    #[arg(long, value_name = "SECONDS", value_parser = parse_timeout)]
    pub detector_timeout: Option<f64>,
}

fn parse_timeout(s: &str) -> Result<f64, String> {
    let t: f64 = s
        .parse()
        .map_err(|_| format!("'{s}' is not a number of seconds"))?;
    if t.is_finite() && t > 0.0 && t <= 86_400.0 {
        Ok(t)
    } else {
        Err(format!("{t}: a timeout is in (0, 86400] s"))
    }
}

impl ExternalArgs {
    /// The definitions given, files first, then `--detector` (a name given twice is refused).
    pub fn specs(&self) -> Result<Vec<ExternalSpec>> {
        let mut out: Vec<ExternalSpec> = Vec::new();
        for path in &self.detectors {
            out.extend(DetectorsFile::load(path)?.detectors);
        }
        for arg in &self.detector {
            out.push(ExternalSpec::parse_arg(arg).context("--detector")?);
        }
        for (i, s) in out.iter().enumerate() {
            if out.iter().take(i).any(|o| o.name == s.name) {
                bail!("external detector '{}' is defined twice", s.name);
            }
        }
        if let Some(t) = self.detector_timeout {
            out.iter_mut().for_each(|s| s.timeout_s = Some(t));
        }
        Ok(out)
    }

    /// Defines the detectors given for this process (their commands may run from here on).
    pub fn define(&self) -> Result<Vec<ExternalSpec>> {
        let specs = self.specs()?;
        for s in &specs {
            external::define(s.clone())?;
        }
        Ok(specs)
    }

    /// Defines the detectors given and checks that every external case among `cases` has one.
    pub fn define_for(&self, cases: &[mlod::detect::Case]) -> Result<Vec<ExternalSpec>> {
        let specs = self.define()?;
        for c in cases {
            if let Some(name) = c.external_name() {
                if !specs.iter().any(|s| s.name == name) {
                    return Err(external::ExternalError::Undefined {
                        case: c.to_string(),
                        name: name.to_string(),
                    }
                    .into());
                }
            }
        }
        Ok(specs)
    }
}
