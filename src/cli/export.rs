//! `mlod export`: the fused cloud of one sample under a perturbation, written as binary PLY or PCD
//! with x, y, z, intensity, lidar and tr(Ξ) per point (and Ξ with `--covariance`) — the same
//! points and tr(Ξ) that `mlod fuse` reports for that sample, α and seed.

use std::path::PathBuf;

use anyhow::{Context, Result};

use mlod::export::{self, ExportOptions, Format};
use mlod::pipeline::{fuse, fused_covariance, FuseParams};
use mlod::uncertainty::Perturbation;

use super::args::{parse_alpha, sample_token};

#[derive(clap::Args)]
pub struct ExportArgs {
    /// Dataset root or its version folder.
    #[arg(long)]
    pub dataset: PathBuf,
    /// Sample token (default: the first sample in scene order).
    #[arg(long)]
    pub sample: Option<String>,
    /// α of the injected perturbation (as `mlod fuse --alpha`).
    #[arg(long, default_value_t = 0.0, value_parser = parse_alpha, allow_hyphen_values = true)]
    pub alpha: f64,
    /// Seed of the perturbation draw (as `mlod fuse --seed`).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// ply or pcd (default: from the --out extension).
    #[arg(long)]
    pub format: Option<Format>,
    /// The file to write (replaced atomically).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write the six entries of Ξ per point (m², base frame).
    #[arg(long)]
    pub covariance: bool,
}

/// Fuses the sample as `mlod fuse` does, writes it and prints one line: path, points, format and
/// the tr(Ξ) range.
pub fn run(args: ExportArgs) -> Result<()> {
    let format = match args.format {
        Some(f) => f,
        None => Format::from_path(&args.out).with_context(|| {
            format!(
                "cannot tell the format of {}: name it .ply or .pcd, or give --format ply|pcd",
                args.out.display()
            )
        })?,
    };
    let dataset = super::open_dataset(&args.dataset)?;
    let token = sample_token(&dataset, args.sample.as_deref())
        .with_context(|| format!("{}", args.dataset.display()))?;
    let frame = dataset.frame(&token)?;
    // The same parameters as `mlod fuse --alpha A --seed S` with its defaults (prior α = α,
    // eq. 9 prior, separate linearisation).
    let params = FuseParams {
        perturbation: Perturbation::new(args.alpha, args.seed)?,
        ..Default::default()
    };
    let cloud = fuse(&frame, &params).with_context(|| format!("fusing sample {token}"))?;
    let covariance = if args.covariance {
        Some(fused_covariance(&frame, &params).with_context(|| format!("Xi of sample {token}"))?)
    } else {
        None
    };
    let comment = export::source_comment(&args.dataset, &token, &params);
    let opts = ExportOptions {
        format,
        covariance: covariance.as_deref(),
        comment: &comment,
    };
    export::write(&args.out, &cloud, &opts)
        .with_context(|| format!("exporting sample {token} to {}", args.out.display()))?;
    let (lo, hi) = cloud.trace_range().unwrap_or((0.0, 0.0));
    println!(
        "{}  {} points  {}{}  tr(Xi) {:.4}..{:.4} m^2",
        args.out.display(),
        cloud.len(),
        format,
        if args.covariance { " with Xi" } else { "" },
        lo,
        hi
    );
    Ok(())
}
