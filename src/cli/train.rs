//! `mlod train`: the stage-1 detectors (paper §IV-A, §V-A-5), Result Fusion's temperatures and
//! the box-voting IoU.

use std::path::PathBuf;

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};

use mlod::cases::ground_gate::GateChoice;
use mlod::detect::model::Voting;
use mlod::detect::weights::default_models_dir;
use mlod::detect::Case;
use mlod::train::stage1::{calibrate_temperatures, train_stage1, TrainConfig};

use super::args::command_line;
use super::detect::DetectorRun;

#[derive(clap::Subcommand)]
pub enum TrainCommand {
    /// Train a stage-1 detector (top|left|right|input|feature); resumable, deterministic per seed.
    Stage1(Stage1Args),
    /// Fit Result Fusion's per-generator temperatures on the validation split (scenes % 10 == 9).
    CalibrateTemperature(CalibrateArgs),
    /// Choose the box-voting IoU of every detector on the validation split (plain NMS or each
    /// candidate, by the mean car moderate AP_3D@0.7 over the cases) and record it, with every
    /// candidate's figures, in the models' manifest.json.
    TuneVote(TuneVoteArgs),
    /// Choose the ground gate of the stage-1 cases on the validation split (no gate or each
    /// candidate; the smallest gate that costs no mean car moderate AP_3D@0.7 wins) and record it,
    /// with every candidate's figures, in the models' manifest.json.
    TuneGate(TuneGateArgs),
    /// Build the refiner's proposal database: the stage-1 fusion detectors run once over the
    /// training scenes under injected perturbations (resumable, shard by shard).
    Proposals(super::refine::ProposalsArgs),
    /// Train the stage-2 refiner (MLOD) on a proposal database; resumable, deterministic per seed.
    Refiner(super::refine::RefinerArgs),
    /// Choose how the refiner's output is decoded (score rule, NMS after refinement) on the
    /// validation split and record it in the models' manifest.json.
    TuneRefiner(super::refine::TuneRefinerArgs),
    /// Fine-tune a models folder on your sensor's labelled frames (LiDAR-Top; the fusion cases
    /// too on a rig) into a new, complete models folder; resumable; open it with `--models` or
    /// the window's File > Open models folder.
    Adapt(super::adapt::AdaptArgs),
    /// The whole chain of a models folder in one resumable command: the five stage-1 cases,
    /// temperatures, voting, the gate, proposals, both refiners, their decoding and the training
    /// data's statistics (rerun the same command after a kill).
    Chain(super::chain::ChainArgs),
}

#[derive(clap::Args)]
pub struct TuneVoteArgs {
    /// The training dataset (its validation scenes are used).
    #[arg(long)]
    dataset: PathBuf,
    /// Models folder with manifest.json (default: assets/models); its manifest records the choice.
    #[arg(long)]
    models: Option<PathBuf>,
    /// Candidate vote IoUs in (0, 1] besides plain NMS (comma separated).
    #[arg(long, value_delimiter = ',', default_value = "0.3,0.5,0.7")]
    candidates: Vec<f64>,
    /// The cases scored (comma separated; default: all six).
    #[arg(long, value_delimiter = ',')]
    cases: Vec<Case>,
    /// At most this many validation samples.
    #[arg(long)]
    samples: Option<usize>,
}

#[derive(clap::Args)]
pub struct TuneGateArgs {
    /// The training dataset (its validation scenes are used).
    #[arg(long)]
    dataset: PathBuf,
    /// Models folder with manifest.json (default: assets/models); its manifest records the choice.
    #[arg(long)]
    models: Option<PathBuf>,
    /// Candidate gates in metres, in (0, 5] (comma separated). They start at 0.5 m: on real
    /// frames true cars' bottoms lie up to 0.3 m above the ground estimate (docs/realism.md).
    #[arg(long, value_delimiter = ',', default_value = "0.5,0.75,1.0")]
    candidates: Vec<f64>,
    /// The stage-1 cases scored (comma separated; default: those the manifest has weights for).
    #[arg(long, value_delimiter = ',')]
    cases: Vec<Case>,
    /// At most this many validation samples.
    #[arg(long)]
    samples: Option<usize>,
}

#[derive(clap::Args)]
pub struct Stage1Args {
    #[arg(long)]
    case: Case,
    /// Training dataset (root or version folder); every 10th scene is held out for validation.
    #[arg(long)]
    dataset: PathBuf,
    /// Final weights file (safetensors); its folder's manifest.json gets the model's entry.
    #[arg(long)]
    out: PathBuf,
    #[arg(long, default_value_t = 8000)]
    steps: u64,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Continue from the checkpoint (default <out>.ckpt.safetensors) after a kill.
    #[arg(long)]
    resume: bool,
    /// Checkpoint file (default: <out> with extension .ckpt.safetensors).
    #[arg(long)]
    checkpoint: Option<PathBuf>,
    /// Seconds between checkpoints.
    #[arg(long, default_value_t = 300.0)]
    checkpoint_every: f64,
    /// Peak learning rate (AdamW; warm-up then cosine decay).
    #[arg(long, default_value_t = 2e-3)]
    lr: f64,
    /// Train on at most this many samples (0: all).
    #[arg(long, default_value_t = 0)]
    max_samples: usize,
    /// Start from another model's weights (warm start; a single-branch model initialises every
    /// Feature Fusion branch).
    #[arg(long)]
    init: Option<PathBuf>,
    /// Ground-truth sampling (SECOND's dataset sampling, paper §V-A-5): top every training frame
    /// up to N boxes of the learned category with objects from the training split (0: off;
    /// SECOND uses 15 for cars).
    #[arg(long, default_value_t = 0)]
    gt_sample: usize,
    /// SECOND's code weight of the box-size residuals (log l, log w, log h) in the regression loss
    /// (1: all seven residuals weigh the same, as in SECOND's default).
    #[arg(long, default_value_t = 1.0)]
    size_weight: f32,
    /// Augmentation for transfer to other sensors and cars: object scaling, global scaling and
    /// random point density (src/train/transfer_aug.rs).
    #[arg(long)]
    transfer_aug: bool,
    /// With --transfer-aug: each car box, with probability 0.5, keeps its points with one
    /// probability from U(0.2, 0.6) (real cars carry fewer points than simulated ones; LiDAR-Top's
    /// recipe: docs/notes/2026-12-07-lever-object-ray-drop-rule.md).
    #[arg(long, requires = "transfer_aug")]
    car_drop: bool,
    /// Leave intensity out of the input (its BEV channel stays zero): for data whose intensity
    /// is not real (real Lyft files hold 100 everywhere) or differs between sensors.
    #[arg(long)]
    no_intensity: bool,
    /// Print one line every N steps (besides the progress bar).
    #[arg(long, default_value_t = 50)]
    log_every: u64,
    /// Train on candle's autograd graph with its own convolutions (the reference path, ~10x
    /// slower) instead of the native trainer; for comparison.
    #[arg(long)]
    slow_autograd: bool,
}

#[derive(clap::Args)]
pub struct CalibrateArgs {
    /// The training dataset (its validation scenes are used).
    #[arg(long)]
    dataset: PathBuf,
    /// Models folder with manifest.json (default: assets/models).
    #[arg(long)]
    models: Option<PathBuf>,
    /// At most this many validation samples (0: all).
    #[arg(long, default_value_t = 0)]
    samples: usize,
    /// 3D IoU for a detection to count as a true positive.
    #[arg(long, default_value_t = 0.7)]
    iou: f64,
}

pub fn train(cmd: TrainCommand) -> Result<()> {
    match cmd {
        TrainCommand::Proposals(a) => super::refine::proposals(a),
        TrainCommand::Refiner(a) => super::refine::refiner(a, command_line()),
        TrainCommand::TuneRefiner(a) => super::refine::tune_refiner(a, command_line()),
        TrainCommand::Adapt(a) => super::adapt::adapt_cmd(a),
        TrainCommand::Chain(a) => super::chain::chain(a),
        TrainCommand::Stage1(a) => {
            let mut cfg = TrainConfig::new(a.case, a.dataset, a.out);
            cfg.steps = a.steps;
            cfg.seed = a.seed;
            cfg.resume = a.resume;
            cfg.lr = a.lr;
            cfg.max_samples = a.max_samples;
            cfg.checkpoint_every_s = a.checkpoint_every;
            cfg.init = a.init;
            cfg.gt_sample = a.gt_sample;
            if !(a.size_weight.is_finite() && a.size_weight > 0.0 && a.size_weight <= 100.0) {
                anyhow::bail!("--size-weight must be in (0, 100], got {}", a.size_weight);
            }
            cfg.size_weight = a.size_weight;
            cfg.slow_autograd = a.slow_autograd;
            cfg.transfer_aug = a.transfer_aug;
            cfg.car_drop = a.car_drop;
            cfg.no_intensity = a.no_intensity;
            // candle runs its element-wise ops on a spinning thread pool of its own beside rayon's
            // (which gemm uses); on 2 busy cores the two pools fight and the spinning took ~40% of
            // a step (docs/stage1.md, "A training step's profile"). One candle thread unless the
            // user chose; set before the first candle op, while the process has one thread.
            if !a.slow_autograd && std::env::var_os("CANDLE_NUM_THREADS").is_none() {
                std::env::set_var("CANDLE_NUM_THREADS", "1");
            }
            if let Some(c) = a.checkpoint {
                cfg.checkpoint = c;
            }
            cfg.command = command_line();
            let bar = ProgressBar::new(cfg.steps);
            bar.set_style(
                ProgressStyle::with_template("{bar:40} {pos}/{len} [{elapsed_precise}<{eta_precise}] {msg}")
                    .unwrap_or_else(|_| ProgressStyle::default_bar()),
            );
            let mut ema: Option<f32> = None;
            let log_every = a.log_every.max(1);
            let summary = train_stage1(&cfg, |r| {
                let e = ema.map_or(r.loss, |e| 0.98 * e + 0.02 * r.loss);
                ema = Some(e);
                bar.set_position(r.step + 1);
                bar.set_message(format!("loss {e:.4}"));
                if (r.step + 1) % log_every == 0 {
                    bar.suspend(|| {
                        eprintln!(
                            "step {} loss {:.4} (ema {e:.4}) cls {:.4} reg {:.4} dir {:.4} pos {} lr {:.2e} |g| {:.2} {:.0} s [data {:.0} fwd {:.0} bwd {:.0} opt {:.0} ms]",
                            r.step + 1,
                            r.loss,
                            r.cls,
                            r.reg,
                            r.dir,
                            r.num_pos,
                            r.lr,
                            r.grad_norm,
                            r.elapsed_s,
                            r.timing_ms[0],
                            r.timing_ms[1],
                            r.timing_ms[2],
                            r.timing_ms[3]
                        )
                    });
                }
            })?;
            bar.finish();
            println!(
                "trained {} steps in {:.0} s -> {} (sha256 {})",
                summary.steps,
                summary.wall_time_s,
                summary.out.display(),
                summary.sha256
            );
            Ok(())
        }
        TrainCommand::TuneVote(a) => tune_vote(a),
        TrainCommand::TuneGate(a) => tune_gate(a),
        TrainCommand::CalibrateTemperature(a) => {
            let models = a.models.unwrap_or_else(default_models_dir);
            let temps = calibrate_temperatures(
                &a.dataset,
                &models,
                a.samples,
                a.iou,
                &command_line(),
                |c, k, n| {
                    if k % 20 == 0 || k == n {
                        eprintln!("{c}: {k}/{n}");
                    }
                },
            )?;
            for (c, t) in temps {
                println!("{c}: T = {t:.4}");
            }
            Ok(())
        }
    }
}

/// `mlod train tune-vote`: every candidate on every case over the validation scenes; the best
/// mean car moderate AP_3D@0.7 wins (plain NMS on a tie) and goes into the manifest atomically.
fn tune_vote(a: TuneVoteArgs) -> Result<()> {
    use mlod::detect::weights::{Manifest, VoteTuning};
    use std::collections::BTreeMap;
    let (models, mut manifest, dataset, opts, tokens) =
        validation_setup(a.models.as_deref(), &a.dataset, a.samples)?;
    let cases = if a.cases.is_empty() {
        Case::ALL.to_vec()
    } else {
        a.cases.clone()
    };
    let mut candidates = vec![Voting::Off];
    for &c in &a.candidates {
        candidates.push(Voting::iou(c).map_err(anyhow::Error::msg)?);
    }
    let mut validation = BTreeMap::new();
    let mut best: Option<(Voting, f64)> = None;
    for voting in candidates {
        let label = format!("vote {voting}");
        let per_case = validation_ap(
            &dataset,
            &tokens,
            &opts,
            &models,
            &cases,
            voting,
            GateChoice::Off,
            &label,
        )?;
        let mean = per_case["mean"];
        validation.insert(voting.to_string(), per_case);
        if best.is_none_or(|(_, b)| mean > b) {
            best = Some((voting, mean));
        }
    }
    let iou = match best {
        Some((Voting::Iou(v), _)) => Some(v),
        _ => None,
    };
    manifest.vote = Some(VoteTuning {
        iou,
        command: command_line(),
        validation,
    });
    manifest.save(&models)?;
    match iou {
        Some(v) => println!("chose vote IoU {v} -> {}", models.join(Manifest::FILE).display()),
        None => println!(
            "plain NMS stays best -> {}",
            models.join(Manifest::FILE).display()
        ),
    }
    Ok(())
}

/// `mlod train tune-gate`: no gate and every candidate (smallest first) on the stage-1 cases
/// over the validation scenes; the smallest gate whose mean car moderate AP_3D@0.7 is at least
/// that without a gate wins, and goes into the manifest atomically.
fn tune_gate(a: TuneGateArgs) -> Result<()> {
    use mlod::detect::weights::{GateTuning, Manifest};
    use std::collections::BTreeMap;
    let (models, mut manifest, dataset, opts, tokens) =
        validation_setup(a.models.as_deref(), &a.dataset, a.samples)?;
    let cases: Vec<Case> = if a.cases.is_empty() {
        manifest.models.keys().copied().collect()
    } else {
        a.cases.clone()
    };
    if let Some(c) = cases.iter().find(|c| c.is_mlod()) {
        anyhow::bail!("{c}: the ground gate is chosen on stage-1 cases");
    }
    let mut candidates = a.candidates.clone();
    candidates.sort_by(f64::total_cmp);
    candidates.dedup();
    let mut choices = vec![(GateChoice::Off, None)];
    for &c in &candidates {
        let gate = mlod::cases::ground_gate::check_gate(c as f32).map_err(anyhow::Error::msg)?;
        choices.push((GateChoice::Metres(gate), Some(c)));
    }
    let mut validation = BTreeMap::new();
    let mut without = f64::NAN;
    let mut chosen = None;
    for (choice, metres) in choices {
        let label = format!("gate {choice}");
        let per_case = validation_ap(
            &dataset,
            &tokens,
            &opts,
            &models,
            &cases,
            Voting::Manifest,
            choice,
            &label,
        )?;
        let mean = per_case["mean"];
        validation.insert(choice.to_string(), per_case);
        match metres {
            Some(v) if chosen.is_none() && mean >= without => chosen = Some(v),
            None => without = mean,
            _ => {}
        }
    }
    manifest.ground_gate = Some(GateTuning {
        max_lift_m: chosen,
        command: command_line(),
        validation,
    });
    manifest.save(&models)?;
    let file = models.join(Manifest::FILE);
    match chosen {
        Some(v) => println!("chose ground gate {v} m -> {}", file.display()),
        None => println!("every gate costs validation AP: none -> {}", file.display()),
    }
    Ok(())
}

/// Car moderate AP_3D@0.7 of each case over the validation `tokens` with `vote_iou` and
/// `ground_gate`, and their mean (`mean`); `label` names the setting in the log.
#[allow(clippy::too_many_arguments)]
fn validation_ap(
    dataset: &mlod::dataset::Dataset,
    tokens: &[String],
    opts: &mlod::eval::EvalOptions,
    models: &std::path::Path,
    cases: &[Case],
    vote_iou: Voting,
    ground_gate: GateChoice,
    label: &str,
) -> Result<std::collections::BTreeMap<String, f64>> {
    let run = DetectorRun::of_models(models.to_path_buf(), vote_iou, ground_gate);
    let mut per_case = std::collections::BTreeMap::new();
    for &case in cases {
        let dets = super::eval::detect_case(dataset, tokens, &run, case)?;
        let report = mlod::eval::evaluate_detections(dataset, &dets, opts)?;
        let ap = mlod::eval::kitti::car_moderate_07(&report.kitti)
            .with_context(|| format!("{case}: no car of moderate difficulty in the validation scenes"))?;
        eprintln!("{label}: {} {ap:.2}", case.paper_name());
        per_case.insert(case.to_string(), ap);
    }
    let mean = per_case.values().sum::<f64>() / per_case.len().max(1) as f64;
    per_case.insert("mean".to_string(), mean);
    println!(
        "{label}: mean car moderate AP_3D@0.7 {mean:.2} over {} samples",
        tokens.len()
    );
    Ok(per_case)
}

/// What `tune-vote` and `tune-gate` start from: the models folder (default: the shipped one)
/// and its manifest, the dataset, evaluation options for its validation scenes and their tokens.
fn validation_setup(
    models: Option<&std::path::Path>,
    dataset_path: &std::path::Path,
    samples: Option<usize>,
) -> Result<(
    PathBuf,
    mlod::detect::weights::Manifest,
    mlod::dataset::Dataset,
    mlod::eval::EvalOptions,
    Vec<String>,
)> {
    let models = models.map_or_else(default_models_dir, std::path::Path::to_path_buf);
    let manifest = mlod::detect::weights::Manifest::load(&models)?;
    let dataset = super::open_dataset(dataset_path)?;
    let opts = mlod::eval::EvalOptions {
        samples,
        validation_only: true,
        ..Default::default()
    };
    let tokens = super::eval::evaluated_tokens(&dataset, dataset_path, &opts)?;
    Ok((models, manifest, dataset, opts, tokens))
}
