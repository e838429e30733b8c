//! `mlod train proposals` and `mlod train refiner`: the stage-2 refiner's proposal database and
//! its training (paper §IV-B, §V-A-6).

use std::path::PathBuf;

use anyhow::{Context, Result};

use mlod::detect::weights::default_models_dir;
use mlod::detect::Case;
use mlod::train::proposals::{build, DatabaseConfig};
use mlod::train::refiner::{train_refiner, RefineTrainConfig};

#[derive(clap::Args)]
pub struct ProposalsArgs {
    /// The training dataset (its validation scenes are left out).
    #[arg(long)]
    dataset: PathBuf,
    /// Output folder of the database (shard-*.json); an existing one is completed, not redone.
    #[arg(long)]
    out: PathBuf,
    /// Models folder of the stage-1 detectors (default: assets/models).
    #[arg(long)]
    models: Option<PathBuf>,
    /// The stage-1 cases whose proposals are kept (comma separated).
    #[arg(long, value_delimiter = ',', default_value = "input,feature,result")]
    cases: Vec<Case>,
    /// Perturbation draws per training sample.
    #[arg(long, default_value_t = 2)]
    draws: usize,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Share of draws at α = 0 (the rest: α ∈ {0.02, 0.04, 0.06, 0.08, 0.1}).
    #[arg(long, default_value_t = 0.4)]
    zero_share: f64,
    /// At most this many training samples (0: all).
    #[arg(long, default_value_t = 0)]
    max_samples: usize,
}

#[derive(clap::Args)]
pub struct RefinerArgs {
    /// The training dataset the database was built from.
    #[arg(long)]
    dataset: PathBuf,
    /// The proposal database (`mlod train proposals --out`).
    #[arg(long)]
    proposals: PathBuf,
    /// Final weights file; its folder's manifest.json gets the `refiner` entry.
    #[arg(long)]
    out: PathBuf,
    #[arg(long, default_value_t = 3000)]
    steps: u64,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Peak learning rate (AdamW; warm-up then cosine decay).
    #[arg(long, default_value_t = 1e-3)]
    lr: f64,
    /// Proposals per step.
    #[arg(long, default_value_t = 32)]
    batch: usize,
    /// Points per proposal.
    #[arg(long, default_value_t = 1024)]
    points: usize,
    /// Also feed the points' intensity and source LiDAR (besides x_n, y_n, z_n and tr(Ξ)).
    #[arg(long)]
    extra_features: bool,
    /// Leave tr(Ξ) out of the point features (an ablation: the network then cannot see it).
    #[arg(long)]
    no_trace: bool,
    /// The classification head learns each proposal's localisation quality (3D IoU with its
    /// ground truth, PV-RCNN's target) instead of objectness, so the score ranks boxes by how
    /// well they fit (issue 32).
    #[arg(long)]
    iou_score: bool,
    /// Widths of the shared point MLP, comma-separated (the last is the global feature's).
    #[arg(long, value_delimiter = ',', default_values_t = [32, 64, 128])]
    point_mlp: Vec<usize>,
    /// Widths of the fully connected layers before the two heads, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [128, 64])]
    head: Vec<usize>,
    /// Continue from the checkpoint (<out>.ckpt.safetensors) after a kill.
    #[arg(long)]
    resume: bool,
    /// Seconds between checkpoints.
    #[arg(long, default_value_t = 120.0)]
    checkpoint_every: f64,
    /// Print a loss line every N steps.
    #[arg(long, default_value_t = 50)]
    log_every: u64,
    /// Train on candle's autograd graph (the reference path, ~15x slower) instead of the native
    /// trainer; for comparison.
    #[arg(long)]
    slow_autograd: bool,
}

pub fn proposals(a: ProposalsArgs) -> Result<()> {
    let cfg = DatabaseConfig {
        dataset: a.dataset,
        models: a.models.unwrap_or_else(default_models_dir),
        out: a.out.clone(),
        cases: a.cases,
        draws: a.draws.max(1),
        seed: a.seed,
        zero_share: a.zero_share,
        max_samples: a.max_samples,
    };
    let start = std::time::Instant::now();
    let n = build(&cfg, |done, total| {
        eprintln!("shard {done}/{total}  {:.0} s", start.elapsed().as_secs_f64());
    })
    .with_context(|| format!("building the proposal database in {}", a.out.display()))?;
    eprintln!(
        "{n} entries in {} ({:.0} s)",
        a.out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

pub fn refiner(a: RefinerArgs, command: String) -> Result<()> {
    let mut cfg = RefineTrainConfig::new(a.dataset, a.proposals, a.out);
    cfg.steps = a.steps;
    cfg.seed = a.seed;
    cfg.lr = a.lr;
    cfg.batch = a.batch;
    cfg.positives = a.batch.div_ceil(2);
    cfg.resume = a.resume;
    cfg.checkpoint_every_s = a.checkpoint_every;
    cfg.model.gather.points = a.points;
    cfg.model.gather.features.trace = !a.no_trace;
    cfg.model.iou_score = a.iou_score;
    if a.point_mlp.is_empty() || a.point_mlp.iter().chain(&a.head).any(|&w| w == 0 || w > 4096) {
        anyhow::bail!(
            "--point-mlp and --head take widths of 1 to 4096 (--point-mlp at least one), got {:?} and {:?}",
            a.point_mlp,
            a.head
        );
    }
    cfg.model.point_mlp = a.point_mlp;
    cfg.model.head = a.head;
    cfg.model.gather.features.intensity = a.extra_features;
    cfg.model.gather.features.lidar = a.extra_features;
    cfg.command = command;
    cfg.slow_autograd = a.slow_autograd;
    // One candle thread beside rayon's unless the user chose (as `mlod train stage1` does): the
    // native step runs no candle op, and candle's spinning pool would fight rayon's on 2 cores.
    if !a.slow_autograd && std::env::var_os("CANDLE_NUM_THREADS").is_none() {
        std::env::set_var("CANDLE_NUM_THREADS", "1");
    }
    let every = a.log_every.max(1);
    let s = train_refiner(&cfg, |r| {
        if r.step % every == 0 {
            eprintln!(
                "step {:>6}  loss {:.4}  reg {:.4}  cls {:.4}  uct {:.3}  pos {:>2}/{:>2}  lr {:.2e}  {:.0} s",
                r.step, r.loss, r.reg, r.cls, r.uct, r.positives, r.batch, r.lr, r.elapsed_s
            );
        }
    })?;
    eprintln!(
        "wrote {} after {} steps ({} skipped), final loss {:.4}, {:.0} s, sha256 {}",
        s.out.display(),
        s.steps,
        s.skipped,
        s.final_loss,
        s.wall_time_s,
        s.sha256
    );
    Ok(())
}

#[derive(clap::Args)]
pub struct TuneRefinerArgs {
    /// The training dataset (its validation scenes are used).
    #[arg(long)]
    dataset: PathBuf,
    /// Models folder with the refiner (default: assets/models); its manifest records the choice.
    #[arg(long)]
    models: Option<PathBuf>,
    /// The perturbation levels scored (one draw each, seed --seed).
    #[arg(long, value_delimiter = ',', default_value = "0,0.04,0.1")]
    alphas: Vec<f64>,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// NMS IoUs tried after refinement besides none (comma separated).
    #[arg(long, value_delimiter = ',', default_value = "0.1,0.3")]
    nms: Vec<f64>,
    /// At most this many validation samples.
    #[arg(long)]
    samples: Option<usize>,
    /// The union cases' NMS IoUs tried after refinement (`mlod-u`, with the chosen score rule;
    /// comma separated). Needs LiDAR-Top and Input Fusion in the models folder.
    #[arg(long, value_delimiter = ',', default_value = "0.3,0.5,0.7")]
    union_nms: Vec<f64>,
    /// The union cases' box-voting IoUs tried after their NMS besides none (comma separated;
    /// empty: none tried).
    #[arg(long, value_delimiter = ',')]
    union_vote: Vec<f64>,
    /// The union cases the union decoding is scored on (their mean over --alphas).
    #[arg(long, value_delimiter = ',', default_value = "mlod-u")]
    union_cases: Vec<Case>,
    /// Keep the manifest's MLOD-I/F/R decoding (score rule and NMS); choose the union cases'
    /// decoding only.
    #[arg(long)]
    union_only: bool,
}

/// `mlod train tune-refiner`: MLOD-I/F/R over the validation scenes at each α, every decoding
/// (score rule × NMS) scored on the same runs; the best mean car moderate AP_3D@0.7 wins (the
/// refined score without NMS on a tie) and goes into the manifest atomically.
pub fn tune_refiner(a: TuneRefinerArgs, command: String) -> Result<()> {
    use mlod::cases::load_mlod;
    use mlod::detect::model::Voting;
    use mlod::detect::weights::{Manifest, RefineTuning};
    use mlod::refine::{redecode, Decoding, ScoreRule};
    use rayon::prelude::*;
    use std::collections::{BTreeMap, HashMap};
    let models = a.models.clone().unwrap_or_else(default_models_dir);
    let dataset = super::open_dataset(&a.dataset)?;
    let opts = mlod::eval::EvalOptions {
        samples: a.samples,
        validation_only: true,
        ..Default::default()
    };
    let tokens = super::eval::evaluated_tokens(&dataset, &a.dataset, &opts)?;
    let mut candidates = Vec::new();
    for score in ScoreRule::ALL {
        candidates.push(Decoding {
            score,
            nms_iou: None,
            ..Decoding::default()
        });
        for &v in &a.nms {
            if !(v > 0.0 && v <= 1.0) {
                anyhow::bail!("--nms {v} is not an IoU in (0, 1]");
            }
            candidates.push(Decoding {
                score,
                nms_iou: Some(v),
                ..Decoding::default()
            });
        }
    }
    let name = |d: &Decoding| match d.nms_iou {
        Some(v) => format!("{}+nms{v}", d.score.as_str()),
        None => d.score.as_str().to_string(),
    };
    // An MLOD case's runs over the validation samples at α (one draw, seed --seed).
    let runs_at = |m: &mlod::cases::Mlod, alpha: f64| -> Result<Vec<(String, mlod::refine::MlodRun)>> {
        let params = mlod::pipeline::FuseParams {
            perturbation: mlod::uncertainty::Perturbation::new(alpha, a.seed)?,
            ..Default::default()
        };
        tokens
            .par_iter()
            .map(|t| -> Result<_> { Ok((t.clone(), m.run(&dataset.frame(t)?, &params)?)) })
            .collect()
    };
    let manifest = Manifest::load(&models)?;
    let mut validation: BTreeMap<String, BTreeMap<String, f64>> = BTreeMap::new();
    if a.union_only {
        let kept = manifest
            .refine
            .as_ref()
            .context("--union-only needs a manifest whose refine decoding is chosen")?;
        validation = kept.validation.clone();
        validation.retain(|k, _| !k.starts_with("union+"));
        candidates = vec![Decoding::of(Some(kept)).map_err(anyhow::Error::msg)?];
    }
    let cases: &[Case] = if a.union_only { &[] } else { &Case::MLOD };
    for &case in cases {
        let mut mlod_det = load_mlod(&models, case, Voting::Manifest)?;
        // Runs keep every refined box: each candidate's NMS is applied by `redecode`.
        let all = Decoding {
            nms_iou: None,
            vote_iou: None,
            ..mlod_det.refiner().decoding
        };
        anyhow::ensure!(mlod_det.set_decoding(all), "the refiner is shared");
        for &alpha in &a.alphas {
            let runs = runs_at(&mlod_det, alpha)?;
            for d in &candidates {
                let dets: HashMap<String, Vec<mlod::detect::Detection>> =
                    runs.iter().map(|(t, r)| (t.clone(), redecode(r, *d))).collect();
                let report = mlod::eval::evaluate_detections(&dataset, &dets, &opts)?;
                let ap = mlod::eval::kitti::car_moderate_07(&report.kitti).unwrap_or(0.0);
                eprintln!("{} α {alpha} {}: {ap:.2}", case.paper_name(), name(d));
                validation
                    .entry(name(d))
                    .or_default()
                    .insert(format!("{case}@{alpha}"), ap);
            }
        }
    }
    let mut best: Option<(Decoding, f64)> = None;
    for d in &candidates {
        let per = validation.entry(name(d)).or_default();
        per.remove("mean");
        let mean = per.values().sum::<f64>() / per.len().max(1) as f64;
        per.insert("mean".into(), mean);
        println!("{:<16} mean car moderate AP_3D@0.7 {mean:.2}", name(d));
        if best.is_none_or(|(_, b)| mean > b) {
            best = Some((*d, mean));
        }
    }
    let (d, mean) = best.context("no candidate")?;
    // The union cases' NMS and box voting, with the chosen score rule (issue 32).
    let mut union_best: Option<((f64, Option<f64>), f64)> = None;
    let union_name = |v: f64, vote: Option<f64>| match vote {
        Some(w) => format!("union+nms{v}+vote{w}"),
        None => format!("union+nms{v}"),
    };
    for v in a.union_nms.iter().chain(&a.union_vote) {
        if !(*v > 0.0 && *v <= 1.0) {
            anyhow::bail!("--union-nms / --union-vote {v} is not an IoU in (0, 1]");
        }
    }
    let votes: Vec<Option<f64>> = std::iter::once(None)
        .chain(a.union_vote.iter().map(|w| Some(*w)))
        .collect();
    let runnable = |c: &Case| {
        c.is_union()
            && c.proposal_cases().iter().all(|p| {
                let base = p.dropped().unwrap_or(*p);
                let nets = if base == Case::Result {
                    vec![Case::Top, Case::Left, Case::Right]
                } else {
                    vec![base]
                };
                nets.iter().all(|n| manifest.models.contains_key(n))
            })
    };
    if !a.union_cases.is_empty() && a.union_cases.iter().all(runnable) {
        let mut per_iou: BTreeMap<String, BTreeMap<String, f64>> = BTreeMap::new();
        for &case in &a.union_cases {
            let mut union = load_mlod(&models, case, Voting::Manifest)?;
            let all = Decoding {
                nms_iou: None,
                vote_iou: None,
                ..union.refiner().decoding
            };
            anyhow::ensure!(union.set_decoding(all), "the refiner is shared");
            for &alpha in &a.alphas {
                let runs = runs_at(&union, alpha)?;
                for &v in &a.union_nms {
                    for &vote in &votes {
                        let dd = Decoding {
                            nms_iou: Some(v),
                            vote_iou: vote,
                            ..d
                        };
                        let dets: HashMap<String, Vec<mlod::detect::Detection>> =
                            runs.iter().map(|(t, r)| (t.clone(), redecode(r, dd))).collect();
                        let report = mlod::eval::evaluate_detections(&dataset, &dets, &opts)?;
                        let ap = mlod::eval::kitti::car_moderate_07(&report.kitti).unwrap_or(0.0);
                        eprintln!("{} α {alpha} {}: {ap:.2}", case.paper_name(), union_name(v, vote));
                        per_iou
                            .entry(union_name(v, vote))
                            .or_default()
                            .insert(format!("{case}@{alpha}"), ap);
                    }
                }
            }
        }
        for &v in &a.union_nms {
            for &vote in &votes {
                let per = per_iou.entry(union_name(v, vote)).or_default();
                let m = per.values().sum::<f64>() / per.len().max(1) as f64;
                per.insert("mean".into(), m);
                println!("{:<26} mean car moderate AP_3D@0.7 {m:.2}", union_name(v, vote));
                if union_best.is_none_or(|(_, b)| m > b) {
                    union_best = Some(((v, vote), m));
                }
            }
        }
        validation.extend(per_iou);
    }
    if a.union_only && union_best.is_none() {
        anyhow::bail!(
            "--union-only: the union cases {:?} need their stage-1 weights in {}",
            a.union_cases.iter().map(|c| c.as_str()).collect::<Vec<_>>(),
            models.display()
        );
    }
    let mut manifest = manifest;
    manifest.refine = Some(RefineTuning {
        score: d.score.as_str().to_string(),
        nms_iou: d.nms_iou,
        union_nms_iou: union_best.map(|((v, _), _)| v),
        union_vote_iou: union_best.and_then(|((_, w), _)| w),
        // A union-only run keeps the score rule another command chose: both are on record.
        command: match (&manifest.refine, a.union_only) {
            (Some(old), true) => format!(
                "{} && {command}",
                old.command.split(" && ").next().unwrap_or_default()
            ),
            _ => command,
        },
        validation,
    });
    manifest.save(&models)?;
    println!(
        "chose {} ({mean:.2}){} -> {}",
        name(&d),
        union_best.map_or(String::new(), |((v, w), m)| format!(
            ", union cases {} ({m:.2})",
            union_name(v, w)
        )),
        models.join(Manifest::FILE).display()
    );
    Ok(())
}
