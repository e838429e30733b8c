//! `mlod sweep`: the paper's Table II on a dataset — cases × α × perturbation trials, resumable
//! and shardable (`mlod::analysis::sweep`); `mlod sweep merge` unites shard folders.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};

use mlod::analysis::sweep::{self, Draw, ShardSpec, SweepConfig};
use mlod::calib::OcPrior;
use mlod::detect::weights::default_models_dir;
use mlod::detect::Case;

#[derive(clap::Args)]
#[command(args_conflicts_with_subcommands = true)]
pub struct SweepArgs {
    #[command(subcommand)]
    pub merge: Option<SweepCommand>,
    /// Dataset root or its version folder (the held-out test split for Table II).
    #[arg(long)]
    pub dataset: Option<PathBuf>,
    /// Cases, comma-separated (e.g. top,input,mlod-i,input-oc,mlod-i-oc; ext:NAME and mlod-ext:NAME
    /// with --detector, docs/external.md).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "top,input,mlod-i,input-oc,mlod-i-oc"
    )]
    pub cases: Vec<Case>,
    /// α levels, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "0,0.02,0.04,0.1")]
    pub alphas: Vec<f64>,
    /// N samples spread evenly over the dataset (default: all).
    #[arg(long)]
    pub samples: Option<usize>,
    /// Perturbation trials per α (trial k: seed S + k).
    #[arg(long, default_value_t = 10)]
    pub trials: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// one-car: one draw per trial for all samples (as `mlod eval --seed S+k`); per-sample: a new
    /// draw for every sample.
    #[arg(long, value_enum, default_value = "one-car")]
    pub draw: Draw,
    /// (OC) cases: the uncertainty of the calibrated points (as `mlod eval --oc-prior`).
    #[arg(long, default_value = "icp")]
    pub oc_prior: OcPrior,
    /// A mis-specified prior: compute Ξ with this α whatever α perturbed the points (e.g. the
    /// true 0.1 assumed 0.02).
    #[arg(long)]
    pub assumed_alpha: Option<f64>,
    /// `input-drop`: the tr(Ξ) threshold (m²) above which points are removed (default: the one
    /// chosen on the validation scenes).
    #[arg(long, value_parser = super::args::parse_trace_threshold)]
    pub drop_trace: Option<f32>,
    /// Models folder with manifest.json (default: assets/models).
    #[arg(long)]
    pub models: Option<PathBuf>,
    /// Output folder: one file per finished unit, then table.md, results.json, results.csv and
    /// ap_vs_alpha.png. Rerun the same command to resume.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Run only the i-th of n shards (0-based), e.g. 0/4; unite them with `mlod sweep merge`.
    /// `auto`: the index and count of a Slurm job array; `auto/N`: the index of a Kubernetes
    /// Indexed Job with N completions (docs/cluster.md).
    #[arg(long, default_value = "0/1")]
    pub shard: ShardSpec,
    #[command(flatten)]
    pub external: super::external::ExternalArgs,
}

#[derive(clap::Subcommand)]
pub enum SweepCommand {
    /// Unite shard folders of one sweep into one folder (the same files as one run).
    Merge {
        #[arg(long)]
        out: PathBuf,
        /// The shard folders.
        #[arg(required = true)]
        shards: Vec<PathBuf>,
    },
}

pub fn run(args: SweepArgs) -> Result<()> {
    if let Some(SweepCommand::Merge { out, shards }) = args.merge {
        let cfg = sweep::merge(&out, &shards)?;
        print_table(&out, &cfg)?;
        return Ok(());
    }
    let (Some(dataset_dir), Some(out)) = (args.dataset.as_ref(), args.out.as_ref()) else {
        bail!("give --dataset DIR and --out DIR (or `mlod sweep merge --out DIR SHARD...`)");
    };
    let dataset = super::open_dataset(dataset_dir)?;
    let all: Vec<String> = dataset.sample_tokens().iter().map(|s| s.to_string()).collect();
    if args.samples == Some(0) {
        bail!("--samples must be at least 1");
    }
    let (shard, shard_from) = args
        .shard
        .resolve(&|k| std::env::var(k).ok())
        .map_err(anyhow::Error::msg)?;
    if shard.count > 1 {
        eprintln!("{shard_from}");
    }
    let specs = args.external.define_for(&args.cases)?;
    let detectors = specs
        .iter()
        .filter(|s| {
            args.cases
                .iter()
                .any(|c| c.external_name() == Some(s.name.as_str()))
        })
        .map(|s| (s.name.clone(), s.command_line()))
        .collect();
    let cfg = SweepConfig {
        cases: args.cases.clone(),
        alphas: args.alphas.clone(),
        trials: args.trials,
        seed: args.seed,
        draw: args.draw,
        oc_prior: args.oc_prior,
        samples: sweep::spread_samples(&all, args.samples),
        assumed_alpha: args.assumed_alpha,
        drop_trace: if args
            .cases
            .iter()
            .any(|c| c.proposal_cases().iter().any(|p| p.dropped().is_some()))
        {
            Some(args.drop_trace.unwrap_or(mlod::cases::drop::DROP_TRACE))
        } else {
            None
        },
        detectors,
    };
    cfg.validate()?;
    let models = args.models.clone().unwrap_or_else(default_models_dir);
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:40} {pos}/{len} samples × groups  {elapsed} elapsed, ETA {eta}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let n = sweep::run(&dataset, &models, &cfg, out, shard, None, &|done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })
    .with_context(|| format!("sweep into {}", out.display()))?;
    bar.finish_and_clear();
    eprintln!("{n} units computed in {}", out.display());
    match sweep::collect(out, &cfg) {
        Ok(rows) => {
            sweep::write_outputs(out, &cfg, &rows)?;
            print_table(out, &cfg)
        }
        Err(missing) => {
            eprintln!(
                "{} of {} units are in other shards (or not run yet): `mlod sweep merge` unites the shard folders",
                missing.len(),
                cfg.units().len()
            );
            Ok(())
        }
    }
}

fn print_table(out: &std::path::Path, cfg: &SweepConfig) -> Result<()> {
    let table = std::fs::read_to_string(out.join("table.md")).context("reading table.md")?;
    println!("{table}");
    eprintln!(
        "{} cases × {} α × {} trials on {} samples: {}/table.md, results.json, results.csv, ap_vs_alpha.png",
        cfg.cases.len(),
        cfg.alphas.len(),
        cfg.trials,
        cfg.samples.len(),
        out.display()
    );
    Ok(())
}
