//! `mlod failures`: a case's worst samples and boxes at a perturbation (misses, false positives,
//! IoU drops against α = 0), what the window's failure browser lists.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

use anyhow::{bail, Result};

use super::args::parse_unit;
use super::detect::DetectorRun;
use mlod::analysis::failures::{scan_with, ScanConfig};
use mlod::detect::Case;

#[derive(clap::Args)]
pub struct FailuresArgs {
    /// A Lyft-format dataset (root or version folder).
    #[arg(long)]
    dataset: PathBuf,
    /// The case to scan (any but the (OC) ones).
    #[arg(long)]
    case: Case,
    #[command(flatten)]
    run: DetectorRun,
    /// Only this scene (its name or token); default: every sample.
    #[arg(long)]
    scene: Option<String>,
    /// At most this many samples, spread evenly over the selection.
    #[arg(long)]
    samples: Option<usize>,
    /// 3D IoU a box needs to match its ground truth.
    #[arg(long, default_value_t = 0.7, value_parser = parse_unit)]
    match_iou: f64,
    /// Boxes from this score up take part (the window's min score).
    #[arg(long, default_value_t = 0.3, value_parser = parse_unit)]
    min_score: f64,
    /// Print this many worst samples (all with --json).
    #[arg(long, default_value_t = 10)]
    top: usize,
    /// Print JSON: every sample worst first, with its failing boxes.
    #[arg(long)]
    json: bool,
    /// Also write the JSON to this file (atomically).
    #[arg(long)]
    out: Option<PathBuf>,
}

pub fn run(a: FailuresArgs) -> Result<()> {
    let dataset = super::open_dataset(&a.dataset)?;
    let all = dataset.samples();
    let chosen: Vec<String> = match &a.scene {
        Some(scene) => {
            let v: Vec<String> = all
                .iter()
                .filter(|s| &s.scene_name == scene || &s.scene_token == scene)
                .map(|s| s.sample_token.clone())
                .collect();
            if v.is_empty() {
                bail!("{}: no scene named or with token '{scene}'", a.dataset.display());
            }
            v
        }
        None => all.iter().map(|s| s.sample_token.clone()).collect(),
    };
    let tokens = mlod::analysis::sweep::spread_samples(&chosen, a.samples);
    if tokens.is_empty() {
        bail!(
            "{}: no samples to scan (its sample table is empty)",
            a.dataset.display()
        );
    }
    let cfg = ScanConfig {
        case: a.case,
        params: a.run.fuse_params()?,
        tokens,
        match_iou: a.match_iou,
        min_score: a.min_score as f32,
        set_intensity: a.run.set_intensity,
    };
    // Loaded as `mlod detect` loads it: --vote-iou, --ground-gate, --drop-trace, --oc-prior.
    let detector = a.run.load(a.case)?;
    let bar = indicatif::ProgressBar::new(cfg.tokens.len() as u64);
    let rows = scan_with(
        &dataset,
        detector.as_ref(),
        &cfg,
        &AtomicBool::new(false),
        &|d, _| bar.set_position(d as u64),
    )?;
    bar.finish_and_clear();
    let json = serde_json::json!({
        "case": cfg.case,
        "alpha": cfg.params.perturbation.alpha,
        "seed": cfg.params.perturbation.seed,
        "match_iou": cfg.match_iou,
        "min_score": cfg.min_score,
        "samples": rows,
    });
    let text = serde_json::to_string_pretty(&json)?;
    if let Some(out) = &a.out {
        mlod::io::write_atomic(out, format!("{text}\n").as_bytes())?;
    }
    if a.json {
        println!("{text}");
        return Ok(());
    }
    println!(
        "{} at α = {} (seed {}), {} samples, worst first (matched at 3D IoU ≥ {}, score ≥ {}):",
        cfg.case.paper_name(),
        cfg.params.perturbation.alpha,
        cfg.params.perturbation.seed,
        rows.len(),
        cfg.match_iou,
        cfg.min_score
    );
    println!(
        "{:>4}  {:<34} {:>7} {:>9} {:>4} {:>10}",
        "#", "sample", "missed", "(α = 0)", "FP", "worst drop"
    );
    for s in rows.iter().take(a.top) {
        println!(
            "{:>4}  {:<34} {:>7} {:>9} {:>4} {:>10.3}",
            s.index, s.sample_token, s.missed, s.missed_at_zero, s.false_positives, s.worst_drop
        );
    }
    Ok(())
}
