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

/// The command line as a user types it: `mlod` and the arguments (not the binary's path).
pub fn command_line() -> String {
    std::iter::once("mlod".to_string())
        .chain(std::env::args().skip(1))
        .collect::<Vec<_>>()
        .join(" ")
}
