//! Training of the refiner (paper §V-A-6).
//!
//! How it works:
//! - Data: the [`crate::train::proposals`] database of the training scenes (the validation scenes are
//!   never in it). Epoch e visits its entries in a shuffle from ChaCha8(seed, stream e).
//! - One step = one entry: the sample fused under the entry's perturbation and indexed once; every
//!   proposal labelled by [`crate::train::refiner_loss::assign`]; up to `positives` positives and the rest of
//!   `batch` from the negatives drawn with ChaCha8(seed, stream 2³² + step) (steps without a
//!   labelled proposal are skipped and counted).
//! - Augmentation, per proposal, in its own frame (where the points are normalised, so a global
//!   rotation or translation would change nothing): with probability 0.5 a mirror about its
//!   heading axis (points and ground truth), a scale s ∈ [0.95, 1.05] of the points and the ground
//!   truth about its centre, then the proposal itself moved by up to ±0.1 m per axis and turned by
//!   up to ±3° about z; the label and the residuals are computed on the augmented boxes. Then
//!   `points` rows are drawn (re-sampled every step).
//! - Loss eq. 17 ([`crate::train::refiner_loss`]), AdamW (lr warm-up then cosine decay, weight decay 0.01,
//!   gradient-norm clip 10), BatchNorm in training mode. The step runs on the native trainer
//!   ([`crate::train::refiner_native`]: forward, backward and AdamW over flat buffers) unless `slow_autograd`
//!   asks for candle's autograd graph; both compute the same step to float rounding.
//! - Checkpoints (weights, moments, step, elapsed, loss rows) are written atomically every few
//!   minutes and at the end; `resume` continues from one exactly as if uninterrupted.
//! - At the end: the weights (with the configuration in their metadata) and the `refiner` entry of
//!   the folder's manifest (command, seed, steps, wall time).

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use candle_core::{Device, Tensor};
use candle_nn::VarMap;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::dataset::Dataset;
use crate::detect::weights::varmap_tensors;
use crate::detect::weights::{
    encode_safetensors, file_name_of, folder_of, read_weights, sha256_hex, Manifest, ModelEntry,
};
use crate::geometry::{iou_3d, Box3d};
use crate::pipeline::{fuse, FusedCloud};
use crate::refine::net::{proposal_features, RefinerConfig, RefinerNet, PROPOSAL_FEATURES};
use crate::refine::points::{push_row, sample, CloudIndex, ProposalPoints};
use crate::refine::RefineError;
use crate::train::checkpoint::{loss_rows_before, restore_varmap, write_loss_csv};
use crate::train::optim::AdamW;
use crate::train::proposals::{load, ProposalEntry};
use crate::train::refiner_loss::{loss, Target, NEGATIVE_IOU, POSITIVE_IOU};
use crate::train::refiner_native::{NativeRefiner, RefinerTerms};

/// Training settings.
#[derive(Debug, Clone)]
pub struct RefineTrainConfig {
    pub dataset: PathBuf,
    pub proposals: PathBuf,
    pub out: PathBuf,
    pub checkpoint: PathBuf,
    pub loss_csv: PathBuf,
    pub steps: u64,
    pub seed: u64,
    pub lr: f64,
    pub warmup: u64,
    pub weight_decay: f64,
    /// Proposals per step, of which at most `positives` positive.
    pub batch: usize,
    pub positives: usize,
    pub checkpoint_every_s: f64,
    pub resume: bool,
    pub model: RefinerConfig,
    pub command: String,
    /// Stop after this many steps with a checkpoint and no final weights, as a kill would (tests).
    pub stop_after: Option<u64>,
    /// Train on candle's autograd graph instead of the native trainer ([`crate::train::refiner_native`]).
    pub slow_autograd: bool,
}

impl RefineTrainConfig {
    pub fn new(dataset: PathBuf, proposals: PathBuf, out: PathBuf) -> Self {
        Self {
            checkpoint: out.with_extension("ckpt.safetensors"),
            loss_csv: out.with_extension("loss.csv"),
            dataset,
            proposals,
            out,
            steps: 3000,
            seed: 0,
            lr: 1e-3,
            warmup: 100,
            weight_decay: 0.01,
            batch: 32,
            positives: 16,
            checkpoint_every_s: 120.0,
            resume: false,
            model: RefinerConfig::default(),
            command: String::new(),
            stop_after: None,
            slow_autograd: false,
        }
    }

    /// Linear warm-up, then cosine decay to 5 % of `lr`.
    pub fn lr_at(&self, step: u64) -> f64 {
        if step < self.warmup {
            return self.lr * (step + 1) as f64 / self.warmup.max(1) as f64;
        }
        let span = self.steps.saturating_sub(self.warmup).max(1) as f64;
        let p = ((step - self.warmup) as f64 / span).min(1.0);
        self.lr * (0.05 + 0.95 * 0.5 * (1.0 + (std::f64::consts::PI * p).cos()))
    }
}

fn stream(seed: u64, s: u64) -> ChaCha8Rng {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    r.set_stream(s);
    r
}

/// One proposal's augmentation (drawn per step).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoiAugmentation {
    pub flip: bool,
    pub scale: f64,
    /// The proposal's move in its own frame, m, and turn, rad.
    pub shift: [f64; 3],
    pub turn: f64,
}

impl RoiAugmentation {
    pub const NONE: Self = Self {
        flip: false,
        scale: 1.0,
        shift: [0.0; 3],
        turn: 0.0,
    };

    pub fn draw(rng: &mut ChaCha8Rng) -> Self {
        Self {
            flip: rng.random::<bool>(),
            scale: rng.random_range(0.95..1.05),
            shift: [
                rng.random_range(-0.1..0.1),
                rng.random_range(-0.1..0.1),
                rng.random_range(-0.1..0.1),
            ],
            turn: rng.random_range(-3f64.to_radians()..3f64.to_radians()),
        }
    }
}

/// A training example: the augmented proposal's points (normalised, gathered as at inference),
/// its features and its target.
pub struct Example {
    pub points: ProposalPoints,
    pub features: [f32; PROPOSAL_FEATURES],
    pub target: Target,
}

/// The points and target of `proposal` under `aug`, all in the proposal's frame: ground truth and
/// points mirrored and scaled, then seen from the moved proposal.
pub fn example(
    cloud: &FusedCloud,
    index: &CloudIndex,
    proposal: &Box3d,
    score: f32,
    truth: &[Box3d],
    aug: &RoiAugmentation,
    cfg: &RefinerConfig,
) -> Example {
    let [l, w, h] = proposal.size_lwh;
    let m = cfg.gather.margin.max(0.0);
    let f = cfg.gather.features;
    // In the proposal's frame: (x, y, z) → mirrored y → scaled.
    let to_aug = |q: [f64; 3]| -> [f64; 3] {
        let y = if aug.flip { -q[1] } else { q[1] };
        [q[0] * aug.scale, y * aug.scale, q[2] * aug.scale]
    };
    let moved = Box3d::new(aug.shift, [l, w, h], aug.turn);
    let truth_aug: Vec<Box3d> = truth
        .iter()
        .map(|g| {
            let c = to_aug(proposal.to_local(g.center));
            let dyaw = g.yaw - proposal.yaw;
            Box3d::new(
                c,
                [
                    g.size_lwh[0] * aug.scale,
                    g.size_lwh[1] * aug.scale,
                    g.size_lwh[2] * aug.scale,
                ],
                if aug.flip { -dyaw } else { dyaw },
            )
        })
        .collect();
    let target = crate::train::refiner_loss::assign(&moved, &truth_aug);
    // Points: every candidate within the moved, enlarged box.
    let half = [l / 2.0 + m, w / 2.0 + m, h / 2.0 + m];
    let reach = (half[0] * half[0] + half[1] * half[1]).sqrt() + 0.5;
    let mut pts = ProposalPoints {
        channels: f.channels(),
        ..Default::default()
    };
    let (st, ct) = aug.turn.sin_cos();
    for i in index.candidates([proposal.center[0], proposal.center[1]], reach * 1.06) {
        let k = i as usize;
        let q = to_aug(proposal.to_local([cloud.x[k] as f64, cloud.y[k] as f64, cloud.z[k] as f64]));
        let (dx, dy, dz) = (q[0] - aug.shift[0], q[1] - aug.shift[1], q[2] - aug.shift[2]);
        let lx = ct * dx + st * dy;
        let ly = -st * dx + ct * dy;
        if lx.abs() > half[0] || ly.abs() > half[1] || dz.abs() > half[2] {
            continue;
        }
        push_row(&mut pts, cloud, k, [lx / l, ly / w, dz / h], &f);
    }
    // The moved proposal in the world, for its features.
    let (s, c) = proposal.yaw.sin_cos();
    let world = Box3d::new(
        [
            proposal.center[0] + c * aug.shift[0] - s * aug.shift[1],
            proposal.center[1] + s * aug.shift[0] + c * aug.shift[1],
            proposal.center[2] + aug.shift[2],
        ],
        [l, w, h],
        proposal.yaw + aug.turn,
    );
    Example {
        points: pts,
        features: proposal_features(&world, score),
        target,
    }
}

/// One row of the loss curve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefineStep {
    pub step: u64,
    pub loss: f32,
    pub reg: f32,
    pub cls: f32,
    pub uct: f32,
    pub positives: usize,
    pub batch: usize,
    pub lr: f64,
    pub grad_norm: f64,
    pub elapsed_s: f64,
}

impl RefineStep {
    pub const CSV_HEADER: &'static str = "step,loss,reg,cls,uct,positives,batch,lr,grad_norm,elapsed_s";

    pub fn csv(&self) -> String {
        format!(
            "{},{:.6},{:.6},{:.6},{:.6},{},{},{:.6e},{:.4},{:.2}",
            self.step,
            self.loss,
            self.reg,
            self.cls,
            self.uct,
            self.positives,
            self.batch,
            self.lr,
            self.grad_norm,
            self.elapsed_s
        )
    }
}

/// A batch ready for the network.
pub struct Batch {
    pub points: Tensor,
    pub props: Tensor,
    pub targets: Vec<Target>,
    pub max_trace: Vec<f32>,
}

/// The batch of step `step` from `entry` (None: no labelled proposal with points).
pub fn make_batch(
    cfg: &RefineTrainConfig,
    dataset: &Dataset,
    entry: &ProposalEntry,
    step: u64,
) -> Result<Option<Batch>, RefineError> {
    let frame = dataset.frame(&entry.sample)?;
    let cloud = fuse(&frame, &entry.fuse_params()?)?;
    let index = CloudIndex::new(&cloud, 2.0);
    let truth: Vec<Box3d> = frame
        .boxes
        .iter()
        .filter(|b| b.category == cfg.model.category)
        .map(|b| b.box3d)
        .collect();
    let proposals = entry.detections();
    let mut rng = stream(cfg.seed, (1u64 << 32) + step);
    // Label on the proposals as stage 1 gave them; pick positives and negatives.
    let mut pos = Vec::new();
    let mut neg = Vec::new();
    for (i, p) in proposals.iter().enumerate() {
        if !p.box3d.is_valid() {
            continue;
        }
        let iou = truth.iter().map(|g| iou_3d(&p.box3d, g)).fold(0.0f64, f64::max);
        if iou > POSITIVE_IOU {
            pos.push(i);
        } else if iou < NEGATIVE_IOU || cfg.model.iou_score {
            neg.push(i);
        }
    }
    pos.shuffle(&mut rng);
    neg.shuffle(&mut rng);
    pos.truncate(cfg.positives);
    neg.truncate(cfg.batch.saturating_sub(pos.len()));
    let picked: Vec<usize> = pos.into_iter().chain(neg).collect();
    let n = cfg.model.gather.points;
    let ch = cfg.model.gather.features.channels();
    let mut rows = Vec::with_capacity(picked.len() * n * ch);
    let mut props = Vec::with_capacity(picked.len() * PROPOSAL_FEATURES);
    let mut targets = Vec::new();
    let mut max_trace = Vec::new();
    for i in picked {
        let aug = RoiAugmentation::draw(&mut rng);
        let ex = example(
            &cloud,
            &index,
            &proposals[i].box3d,
            proposals[i].score,
            &truth,
            &aug,
            &cfg.model,
        );
        let draw_seed: u64 = rng.random();
        if ex.points.is_empty() {
            continue;
        }
        let s = sample(&ex.points, n, draw_seed);
        rows.extend_from_slice(&s.rows);
        props.extend_from_slice(&ex.features);
        targets.push(ex.target);
        max_trace.push(ex.points.max_trace);
    }
    if targets.is_empty() {
        return Ok(None);
    }
    let b = targets.len();
    Ok(Some(Batch {
        points: Tensor::from_vec(rows, (b * n, ch), &Device::Cpu)?,
        props: Tensor::from_vec(props, (b, PROPOSAL_FEATURES), &Device::Cpu)?,
        targets,
        max_trace,
    }))
}

/// What training returns.
#[derive(Debug, Clone)]
pub struct RefineSummary {
    pub steps: u64,
    pub skipped: u64,
    pub final_loss: f32,
    pub wall_time_s: f64,
    pub sha256: String,
    pub out: PathBuf,
}

fn save_tensors(
    varmap: &VarMap,
    extra: BTreeMap<String, Tensor>,
    meta: BTreeMap<String, String>,
) -> Result<Vec<u8>, RefineError> {
    let mut tensors = varmap_tensors(varmap)?;
    tensors.extend(extra);
    Ok(encode_safetensors(&tensors, &meta)?)
}

struct Checkpoint {
    step: u64,
    skipped: u64,
    elapsed_s: f64,
    rows: Vec<String>,
}

fn meta_of(cfg: &RefineTrainConfig) -> Result<BTreeMap<String, String>, RefineError> {
    let mut meta = BTreeMap::new();
    meta.insert(
        "mlod.refiner".into(),
        serde_json::to_string(&cfg.model).map_err(|e| RefineError::BadParameter(e.to_string()))?,
    );
    Ok(meta)
}

fn save_checkpoint(
    cfg: &RefineTrainConfig,
    varmap: &VarMap,
    opt: &AdamW,
    ck: &Checkpoint,
) -> Result<(), RefineError> {
    let extra = opt.state_tensors();
    let mut meta = meta_of(cfg)?;
    meta.insert("train.step".into(), ck.step.to_string());
    meta.insert("train.skipped".into(), ck.skipped.to_string());
    meta.insert("train.elapsed_s".into(), format!("{}", ck.elapsed_s));
    meta.insert("train.seed".into(), cfg.seed.to_string());
    crate::io::write_atomic(&cfg.checkpoint, &save_tensors(varmap, extra, meta)?)?;
    write_loss_csv(&cfg.loss_csv, RefineStep::CSV_HEADER, &ck.rows)?;
    Ok(())
}

fn load_checkpoint(
    cfg: &RefineTrainConfig,
    varmap: &VarMap,
    opt: &mut AdamW,
) -> Result<Checkpoint, RefineError> {
    let path = &cfg.checkpoint;
    let w = read_weights(path, None)?;
    let bad = |what: String| RefineError::File {
        path: path.clone(),
        what,
    };
    let meta = |k: &str| w.metadata.get(k).cloned().ok_or_else(|| bad(format!("no {k}")));
    let ck_cfg: RefinerConfig =
        serde_json::from_str(&meta("mlod.refiner")?).map_err(|e| bad(e.to_string()))?;
    if ck_cfg != cfg.model {
        return Err(bad("checkpoint is of another refiner configuration".into()));
    }
    if meta("train.seed")? != cfg.seed.to_string() {
        return Err(bad(format!("checkpoint seed differs from --seed {}", cfg.seed)));
    }
    restore_varmap(varmap, |n| w.tensors.get(n).cloned()).map_err(bad)?;
    let num = |k: &str| -> Result<f64, RefineError> {
        meta(k)?.parse::<f64>().map_err(|e| bad(format!("{k}: {e}")))
    };
    let step = num("train.step")? as u64;
    opt.restore(|n| w.tensors.get(n).cloned(), step).map_err(bad)?;
    let rows = loss_rows_before(&cfg.loss_csv, step);
    Ok(Checkpoint {
        step,
        skipped: num("train.skipped")? as u64,
        elapsed_s: num("train.elapsed_s")?,
        rows,
    })
}

/// Trains (or resumes) a refiner; `on_step` sees every step's record.
pub fn train_refiner(
    cfg: &RefineTrainConfig,
    mut on_step: impl FnMut(&RefineStep),
) -> Result<RefineSummary, RefineError> {
    if cfg.batch == 0 || cfg.model.gather.points == 0 || cfg.steps == 0 {
        return Err(RefineError::BadParameter(
            "batch, points and steps must be at least 1".into(),
        ));
    }
    if !(cfg.lr.is_finite() && cfg.lr > 0.0) {
        return Err(RefineError::BadParameter(format!(
            "learning rate {} must be positive",
            cfg.lr
        )));
    }
    if cfg.slow_autograd && cfg.model.iou_score {
        return Err(RefineError::BadParameter(
            "the IoU-quality score is trained by the native trainer only: leave out --slow-autograd".into(),
        ));
    }
    let dataset = Dataset::open(&cfg.dataset)?;
    let entries = load(&cfg.proposals)?;
    if entries.is_empty() {
        return Err(RefineError::Database {
            path: cfg.proposals.clone(),
            what: "no entries".into(),
        });
    }
    let (net, varmap) = RefinerNet::trainable(&cfg.model, cfg.seed)?;
    let mut opt = AdamW::for_varmap(&varmap, cfg.weight_decay)?;
    let mut ck = if cfg.resume && cfg.checkpoint.exists() {
        load_checkpoint(cfg, &varmap, &mut opt)?
    } else {
        Checkpoint {
            step: 0,
            skipped: 0,
            elapsed_s: 0.0,
            rows: Vec::new(),
        }
    };
    let start = Instant::now();
    let base_elapsed = ck.elapsed_s;
    let mut last_ckpt = Instant::now();
    let n = cfg.model.gather.points;
    let epoch_order = |e: u64| -> Vec<usize> {
        let mut o: Vec<usize> = (0..entries.len()).collect();
        o.shuffle(&mut stream(cfg.seed, e));
        o
    };
    let mut epoch = u64::MAX;
    let mut order = Vec::new();
    let mut final_loss = f32::NAN;
    // The native path (the default) or candle's autograd graph (`--slow-autograd`); the native
    // trainer writes its state back into `varmap` and `opt` before every checkpoint.
    let mut native = match cfg.slow_autograd {
        true => None,
        false => Some(NativeRefiner::new(&cfg.model, &varmap, &opt)?),
    };
    while ck.step < cfg.steps {
        let step = ck.step;
        let e = step / entries.len() as u64;
        if e != epoch {
            epoch = e;
            order = epoch_order(e);
        }
        let entry = &entries[order[(step % entries.len() as u64) as usize]];
        let Some(batch) = make_batch(cfg, &dataset, entry, step)? else {
            ck.skipped += 1;
            ck.step += 1;
            continue;
        };
        let b = batch.targets.len();
        let lr = cfg.lr_at(step);
        let (l, grad_norm) = match native.as_mut() {
            Some(nt) => {
                let points = batch.points.flatten_all()?.to_vec1::<f32>()?;
                let props = batch.props.flatten_all()?.to_vec1::<f32>()?;
                let s = nt.step(&points, &props, &batch.targets, &batch.max_trace, lr, 10.0)?;
                (s.loss, s.grad_norm)
            }
            None => {
                let out = net.forward_t(&batch.points, b, n, &batch.props, true)?;
                let l = loss(&out, &batch.targets, &batch.max_trace)?;
                let grad_norm = opt.update(&l.total.backward()?, lr, 10.0)?;
                let terms = RefinerTerms {
                    total: l.total.to_scalar()?,
                    reg: l.reg,
                    cls: l.cls,
                    uct: l.uct,
                    positives: l.positives,
                };
                (terms, grad_norm)
            }
        };
        let rec = RefineStep {
            step,
            loss: l.total,
            reg: l.reg,
            cls: l.cls,
            uct: l.uct,
            positives: l.positives,
            batch: b,
            lr,
            grad_norm,
            elapsed_s: base_elapsed + start.elapsed().as_secs_f64(),
        };
        final_loss = rec.loss;
        ck.rows.push(rec.csv());
        ck.step += 1;
        on_step(&rec);
        if cfg.stop_after.is_some_and(|k| ck.step >= k) {
            if let Some(nt) = &native {
                nt.store(&varmap, &mut opt)?;
            }
            ck.elapsed_s = base_elapsed + start.elapsed().as_secs_f64();
            save_checkpoint(cfg, &varmap, &opt, &ck)?;
            return Err(RefineError::BadParameter(format!(
                "stopped after step {} (stop_after)",
                ck.step
            )));
        }
        if last_ckpt.elapsed().as_secs_f64() >= cfg.checkpoint_every_s {
            if let Some(nt) = &native {
                nt.store(&varmap, &mut opt)?;
            }
            ck.elapsed_s = base_elapsed + start.elapsed().as_secs_f64();
            save_checkpoint(cfg, &varmap, &opt, &ck)?;
            last_ckpt = Instant::now();
        }
    }
    if let Some(nt) = &native {
        nt.store(&varmap, &mut opt)?;
    }
    ck.elapsed_s = base_elapsed + start.elapsed().as_secs_f64();
    save_checkpoint(cfg, &varmap, &opt, &ck)?;
    let bytes = save_tensors(&varmap, BTreeMap::new(), meta_of(cfg)?)?;
    crate::io::write_atomic(&cfg.out, &bytes)?;
    let sha256 = sha256_hex(&bytes);
    // The refiner entry of the folder's manifest (created if the folder has none).
    if let Some(dir) = folder_of(&cfg.out) {
        let mut manifest = if dir.join(Manifest::FILE).exists() {
            Manifest::load(dir)?
        } else {
            Manifest::default()
        };
        // A refiner without the tr(Ξ) feature is the ablation's (`mlod-i-notrace`).
        let slot = if cfg.model.gather.features.trace {
            &mut manifest.refiner
        } else {
            &mut manifest.refiner_notrace
        };
        *slot = Some(ModelEntry {
            file: file_name_of(&cfg.out),
            sha256: sha256.clone(),
            command: cfg.command.clone(),
            seed: cfg.seed,
            steps: cfg.steps,
            wall_time_s: ck.elapsed_s,
            test_ap: BTreeMap::new(),
            init: None,
        });
        manifest.save(dir)?;
    }
    Ok(RefineSummary {
        steps: ck.step,
        skipped: ck.skipped,
        final_loss,
        wall_time_s: ck.elapsed_s,
        sha256,
        out: cfg.out.clone(),
    })
}

#[cfg(test)]
mod tests;
