//! Value parsers and helpers shared by the subcommands.

use anyhow::{Context, Result};

pub fn parse_f64(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("'{s}' is not a number"))?;
    if !v.is_finite() {
        return Err(format!("'{s}' is not a finite number"));
    }
    Ok(v)
}

pub fn parse_vec3(s: &str) -> Result<[f64; 3], String> {
    let parts: Vec<&str> = s.split(',').collect();
    if parts.len() != 3 {
        return Err(format!("expected three comma-separated numbers, got '{s}'"));
    }
    Ok([parse_f64(parts[0])?, parse_f64(parts[1])?, parse_f64(parts[2])?])
}

pub fn parse_unit(s: &str) -> Result<f64, String> {
    let v = parse_f64(s)?;
    if !(0.0..=1.0).contains(&v) {
        return Err(format!("must be in [0, 1], got {v}"));
    }
    Ok(v)
}

/// A tr(Ξ) threshold (m²): finite and positive.
pub fn parse_trace_threshold(s: &str) -> Result<f32, String> {
    let v = parse_f64(s)?;
    if v <= 0.0 || v > f64::from(f32::MAX) {
        return Err(format!(
            "a tr(Ξ) threshold must be a positive number of m², got {v}"
        ));
    }
    Ok(v as f32)
}

pub fn parse_alpha(s: &str) -> Result<f64, String> {
    let a = parse_f64(s)?;
    if !(0.0..=1.0).contains(&a) {
        return Err(format!(
            "alpha must be in [0, 1] (the paper studies 0 to 0.1), got {a}"
        ));
    }
    Ok(a)
}

/// The sample asked for, or the dataset's first sample in scene order.
pub fn sample_token(dataset: &mlod::dataset::Dataset, sample: Option<&str>) -> Result<String> {
    match sample {
        Some(t) => Ok(t.to_string()),
        None => Ok(dataset
            .first_sample_token()
            .context("the dataset has no samples")?
            .to_string()),
    }
}

/// The command line as a user types it: `mlod` and the arguments (not the binary's path), with
/// absolute paths made relative to the current folder (provenance must not hold one machine's
/// folders).
pub fn command_line() -> String {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let cwd = std::env::current_dir().unwrap_or_default();
    portable_command(&args, &cwd)
}

/// `mlod` and `args`, each absolute path (also in `--flag=/path`) relative to `cwd`.
pub fn portable_command(args: &[String], cwd: &std::path::Path) -> String {
    let rel = |a: &str| -> String {
        let p = std::path::Path::new(a);
        if !p.is_absolute() || !cwd.is_absolute() {
            return a.to_string();
        }
        relative_to(p, cwd).to_string_lossy().into_owned()
    };
    std::iter::once("mlod".to_string())
        .chain(args.iter().map(|a| match a.split_once('=') {
            Some((flag, value)) if flag.starts_with("--") => format!("{flag}={}", rel(value)),
            _ => rel(a),
        }))
        .collect::<Vec<_>>()
        .join(" ")
}

/// A path as provenance names it: relative to `cwd` when absolute (see [`portable_command`]).
pub fn portable_path(path: &std::path::Path, cwd: &std::path::Path) -> String {
    if path.is_absolute() && cwd.is_absolute() {
        relative_to(path, cwd).to_string_lossy().into_owned()
    } else {
        path.display().to_string()
    }
}

/// `path` relative to `base` (both absolute), with `..` where it leaves `base`.
fn relative_to(path: &std::path::Path, base: &std::path::Path) -> std::path::PathBuf {
    let p: Vec<_> = path.components().collect();
    let b: Vec<_> = base.components().collect();
    let common = p.iter().zip(&b).take_while(|(x, y)| x == y).count();
    let mut out = std::path::PathBuf::new();
    for _ in common..b.len() {
        out.push("..");
    }
    for c in p.iter().skip(common) {
        out.push(c.as_os_str());
    }
    if out.as_os_str().is_empty() {
        out.push(".");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recorded_commands_hold_relative_paths() {
        let args: Vec<String> = [
            "train",
            "tune-vote",
            "--dataset",
            "/work/data/train",
            "--models=/work/main/assets/models",
            "--steps",
            "10",
            "rel/x",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        assert_eq!(
            portable_command(&args, std::path::Path::new("/work/main")),
            "mlod train tune-vote --dataset ../data/train --models=assets/models --steps 10 rel/x"
        );
        assert_eq!(
            portable_command(
                &["--out".into(), "/work/main".into()],
                std::path::Path::new("/work/main")
            ),
            "mlod --out ."
        );
    }
}
