//! `mlod train adapt`: a models folder fine-tuned on the user's labelled real frames
//! ([`mlod::train::adapt`]), with a progress bar, and the transfer check on those frames before
//! and after, recorded in the new folder's manifest.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::Result;
use indicatif::{ProgressBar, ProgressStyle};

use mlod::cases::ground_gate::GateChoice;
use mlod::detect::model::Voting;
use mlod::detect::weights::default_models_dir;
use mlod::detect::Case;
use mlod::train::adapt::{adapt, record_fit, AdaptConfig};

use super::args::{command_line, portable_path};
use super::detect::DetectorRun;

#[derive(clap::Args)]
pub struct AdaptArgs {
    /// Labelled real frames of your sensor (any format `mlod inspect` opens; KITTI teaches only
    /// inside camera 2's view, where it is labelled).
    #[arg(long)]
    dataset: PathBuf,
    /// The adapted models folder (created; the base folder's files are copied into it).
    #[arg(long)]
    out: PathBuf,
    /// The models folder to start from (default: assets/models).
    #[arg(long)]
    models: Option<PathBuf>,
    /// The cases to adapt (comma separated; default: top, and input and feature on a rig).
    #[arg(long, value_delimiter = ',')]
    cases: Vec<Case>,
    /// Steps per case (one frame per step).
    #[arg(long, default_value_t = 1500)]
    steps: u64,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Peak learning rate (warm-up over a tenth of the steps, then cosine decay).
    #[arg(long, default_value_t = 5e-4)]
    lr: f64,
    /// Cars pasted into each frame from the frames' own labelled cars (0: off).
    #[arg(long, default_value_t = 15)]
    gt_sample: usize,
    /// Skip the before/after check on the adaptation frames.
    #[arg(long)]
    no_fit_check: bool,
}

pub fn adapt_cmd(a: AdaptArgs) -> Result<()> {
    let base = a.models.clone().unwrap_or_else(default_models_dir);
    let mut cfg = AdaptConfig::new(a.dataset.clone(), base.clone(), a.out.clone());
    cfg.cases = a.cases.clone();
    cfg.steps = a.steps;
    cfg.seed = a.seed;
    cfg.lr = a.lr;
    cfg.gt_sample = a.gt_sample;
    cfg.command = command_line();
    let cwd = std::env::current_dir().unwrap_or_default();
    cfg.base_name = portable_path(&base, &cwd);
    cfg.dataset_name = portable_path(&a.dataset, &cwd);
    if std::env::var_os("CANDLE_NUM_THREADS").is_none() {
        // One candle thread beside rayon's pool (see `mlod train stage1`).
        std::env::set_var("CANDLE_NUM_THREADS", "1");
    }
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template(
            "{prefix:>8} {bar:40} {pos}/{len} [{elapsed_precise}<{eta_precise}] {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut current: Option<Case> = None;
    let mut ema = 0f32;
    let t0 = std::time::Instant::now();
    let done = adapt(&cfg, |case, r| {
        if current != Some(case) {
            current = Some(case);
            bar.reset();
            bar.set_length(cfg.steps);
            bar.set_prefix(case.to_string());
            ema = r.loss;
        }
        ema = 0.98 * ema + 0.02 * r.loss;
        bar.set_position(r.step + 1);
        bar.set_message(format!("loss {ema:.4}"));
    })?;
    bar.finish_and_clear();
    for (case, s) in &done {
        println!(
            "{case}: {} steps in {:.0} s -> {} (sha256 {})",
            s.steps,
            s.wall_time_s,
            s.out.display(),
            s.sha256
        );
    }
    println!(
        "adapted in {:.0} s -> {}",
        t0.elapsed().as_secs_f64(),
        a.out.display()
    );
    if a.no_fit_check {
        return Ok(());
    }
    let dataset = super::open_dataset(&a.dataset)?;
    let opts = mlod::eval::EvalOptions {
        transfer: Some(mlod::eval::TransferRule::default()),
        ..Default::default()
    };
    let tokens = super::eval::evaluated_tokens(&dataset, &a.dataset, &opts)?;
    let mut fit = BTreeMap::new();
    for (case, _) in &done {
        for (name, models) in [("base", &base), ("adapted", &a.out)] {
            let run = DetectorRun::of_models(models.clone(), Voting::Manifest, GateChoice::Manifest);
            let report = super::eval::run_case(&dataset, &tokens, &run, *case, &opts)?;
            let f = transfer_figures(report.transfer);
            println!(
                "{case} {name:>7} on the adaptation frames: {} ({:.0} found of {:.0}), AP {}, {} confident FP/frame",
                pct(f.get("found_pct")),
                f.get("found").copied().unwrap_or(0.0),
                f.get("boxes").copied().unwrap_or(0.0),
                pct(f.get("ap_centre")),
                f.get("confident_false_positives_per_frame")
                    .map_or("-".into(), |v| format!("{v:.2}")),
            );
            fit.insert(format!("{case}/{name}"), f);
        }
    }
    record_fit(&a.out, fit)?;
    println!(
        "(figures on the frames it learned from: they show it learned, not how it does on other frames)"
    );
    Ok(())
}

fn pct(v: Option<&f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.1} %"))
}

/// The transfer check's figures by name (those it could compute).
fn transfer_figures(t: Option<mlod::eval::transfer::TransferReport>) -> BTreeMap<String, f64> {
    let mut f = BTreeMap::new();
    if let Some(t) = t {
        f.insert("frames".into(), t.frames as f64);
        f.insert("boxes".into(), t.boxes as f64);
        f.insert("found".into(), t.found as f64);
        let opt = [
            ("found_pct", t.found_pct),
            ("found_iou_pct", t.found_iou_pct),
            ("ap_centre", t.ap_centre),
            (
                "confident_false_positives_per_frame",
                t.confident_false_positives_per_frame,
            ),
        ];
        for (k, v) in opt {
            if let Some(v) = v {
                f.insert(k.into(), v);
            }
        }
    }
    f
}
