//! Training of the stage-1 networks (paper §V-A-5, following SECOND) and the temperature
//! calibration of Result Fusion's generators.
//!
//! How it works:
//! - Split: the dataset's scenes in scene order; every 10th scene (index % 10 == 9) is the
//!   validation split (temperature fitting), the rest is trained on. Test scenes live in a
//!   different dataset generated with another seed, never seen here.
//! - One step = one sample (batch 1, fastest on a CPU): fuse with the nominal extrinsics, with
//!   `gt_sample` > 0 paste ground-truth-sampled objects ([`crate::train::gt_sampling`]), with
//!   probability 0.3 augment points and boxes together (flip y → −y with probability 0.5, rotate
//!   by U(−5°, 5°) about z, translate by U(±0.5, ±0.5, ±0.3) m), voxelise each branch, assign
//!   targets, then loss = focal(cls) + 2·smooth-L1(box, sin-difference angle) + 0.2·CE(direction),
//!   each normalised by the number of positives (SECOND's code weights: the three log-size terms
//!   times `size_weight`, 1 by default), and one AdamW update (linear warm-up, cosine
//!   decay, gradient-norm clip 10).
//! - The step runs on the native trainer ([`crate::train::stage1::native`]: forward, backward and AdamW written
//!   out over flat buffers) unless `slow_autograd` asks for candle's autograd graph; both compute
//!   the same function and write the same checkpoints.
//! - Determinism: the sample order of epoch e is a shuffle from ChaCha8(seed, stream e); step s
//!   draws its augmentation from ChaCha8(seed, stream 2³² + s), its sampled objects from
//!   ChaCha8(seed, stream 2³³ + s), its transfer augmentation from stream 2³⁴ + s and, for the
//!   cases trained under drift (issue 32), its perturbation from stream 2³⁵ + s; weights start
//!   from ChaCha8(seed).
//!   Nothing else is random, so a run resumed from a checkpoint continues exactly as if it had not
//!   stopped (given the same thread count).
//! - Checkpoints (weights, AdamW moments, step, elapsed time, the loss-curve rows) are written
//!   atomically every few minutes and at the end; `resume` restarts from one.

pub mod native;

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use candle_core::{DType, Device, Tensor};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::dataset::region::EvalRegion;
pub use crate::dataset::train_validation_split as split;
use crate::dataset::{Dataset, Frame};
use crate::detect::anchors::{assign, raw_box, Anchors, RawBox, Targets};
use crate::detect::model::{branch_points, ModelConfig, Stage1Model};
use crate::detect::net::{cross_entropy_rows, sigmoid_focal_loss, smooth_l1};
use crate::detect::voxel::{voxelize, Bev, PointsRef};
use crate::detect::weights::{
    file_name_of, folder_of, read_weights, sha256_hex, InitRecord, Manifest, ModelEntry,
};
use crate::detect::{Case, DetectError};
use crate::pipeline::{fuse, FuseParams, FusedCloud};
use crate::train::checkpoint::{loss_rows_before, restore_varmap, write_loss_csv};
use crate::train::gt_sampling::{paste, GtDatabase, GtObject, Inside};
pub use crate::train::optim::AdamW;
use crate::train::stage1::native::loss::LossTerms;
use crate::train::stage1::native::NativeTrainer;
pub use crate::train::temperature::{calibrate_temperatures, fit_temperature, label_detections};
use crate::train::transfer_aug::TransferAug;
pub use crate::train::warm_start::warm_start;

/// The §V-A-5 augmentation of one sample.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Augmentation {
    pub flip_y: bool,
    /// Rotation about z (rad).
    pub yaw: f32,
    pub translation: [f32; 3],
}

impl Augmentation {
    /// Draws the augmentation of one step: 30% of the samples are augmented.
    pub fn draw(rng: &mut ChaCha8Rng) -> Option<Self> {
        if rng.random::<f64>() >= 0.3 {
            return None;
        }
        Some(Self {
            flip_y: rng.random::<bool>(),
            yaw: rng.random_range(-5f32..=5.0).to_radians(),
            translation: [
                rng.random_range(-0.5f32..=0.5),
                rng.random_range(-0.5f32..=0.5),
                rng.random_range(-0.3f32..=0.3),
            ],
        })
    }

    fn point(&self, x: f32, y: f32, z: f32) -> [f32; 3] {
        let y = if self.flip_y { -y } else { y };
        let (s, c) = self.yaw.sin_cos();
        [
            c * x - s * y + self.translation[0],
            s * x + c * y + self.translation[1],
            z + self.translation[2],
        ]
    }

    /// Where a point of the augmented frame was before [`Augmentation::apply`].
    pub fn undo(&self, p: [f32; 3]) -> [f32; 3] {
        let (x, y) = (p[0] - self.translation[0], p[1] - self.translation[1]);
        let (s, c) = self.yaw.sin_cos();
        let (x, y) = (c * x + s * y, -s * x + c * y);
        [x, if self.flip_y { -y } else { y }, p[2] - self.translation[2]]
    }

    /// Moves points and boxes together.
    pub fn apply(&self, cloud: &mut FusedCloud, boxes: &mut [RawBox]) {
        for i in 0..cloud.x.len().min(cloud.y.len()).min(cloud.z.len()) {
            let p = self.point(cloud.x[i], cloud.y[i], cloud.z[i]);
            cloud.x[i] = p[0];
            cloud.y[i] = p[1];
            cloud.z[i] = p[2];
        }
        for b in boxes {
            let p = self.point(b[0], b[1], b[2]);
            let yaw = if self.flip_y { -b[6] } else { b[6] };
            *b = [p[0], p[1], p[2], b[3], b[4], b[5], yaw + self.yaw];
        }
    }
}

/// A sample ready for the network: the BEV of each branch and the targets.
#[derive(Debug, Clone)]
pub struct PreparedSample {
    pub bevs: Vec<Option<Bev>>,
    pub targets: Targets,
    /// Boxes of the class learned as positives / as don't-care.
    pub num_gt: usize,
    pub num_dont_care: usize,
}

/// Points of `pts` inside an upright box (counted on the slices the case's branches see).
fn points_in(b: &RawBox, parts: &[Option<PointsRef<'_>>]) -> usize {
    let inside = Inside::new(b);
    parts
        .iter()
        .flatten()
        .map(|p| {
            (0..p.len())
                .filter(|&i| inside.contains(p.x[i], p.y[i], p.z[i]))
                .count()
        })
        .sum()
}

/// Fuses (nominal extrinsics), pastes the ground-truth-sampled `objects` (see [`gt_sampling`]),
/// augments, voxelises and assigns one frame.
pub fn prepare_sample(
    model: &Stage1Model,
    frame: &Frame,
    aug: Option<&Augmentation>,
    objects: &[&GtObject],
) -> Result<PreparedSample, DetectError> {
    prepare_sample_with(model, frame, aug, objects, None, &FuseParams::default())
}

/// Boxes per frame that [`TransferAug`] may scale (the rest keep their size).
const MAX_SCALED_BOXES: usize = 128;

/// [`prepare_sample`] with the transfer augmentation before SECOND's, fused with `params`.
pub fn prepare_sample_with(
    model: &Stage1Model,
    frame: &Frame,
    aug: Option<&Augmentation>,
    objects: &[&GtObject],
    transfer: Option<&TransferAug>,
    params: &FuseParams,
) -> Result<PreparedSample, DetectError> {
    let cfg = &model.config;
    let mut cloud = fuse(frame, params)?;
    if !objects.is_empty() {
        cloud = paste(&cloud, objects);
    }
    let mut boxes: Vec<RawBox> = Vec::new();
    for b in frame.boxes.iter().filter(|b| b.category == cfg.anchor.category) {
        if b.box3d.is_valid() {
            boxes.push(raw_box(&b.box3d));
        }
    }
    boxes.extend(objects.iter().map(|o| o.raw));
    if let Some(t) = transfer {
        t.apply(&mut cloud, &mut boxes);
    }
    if let Some(a) = aug {
        a.apply(&mut cloud, &mut boxes);
    }
    let parts = branch_points(cfg.case, &cloud);
    let (mut gts, mut dont_care) = (Vec::new(), Vec::new());
    for b in boxes {
        if points_in(&b, &parts) >= cfg.anchor.min_points {
            gts.push(b);
        } else {
            dont_care.push(b);
        }
    }
    let bevs = parts.iter().map(|p| p.map(|p| voxelize(&cfg.grid, p))).collect();
    let mut targets = assign(&model.anchors, &cfg.anchor, &gts, &dont_care);
    if let Some(region) = &frame.eval_region {
        ignore_unlabelled(&mut targets, &model.anchors, region, aug, transfer);
    }
    Ok(PreparedSample {
        bevs,
        targets,
        num_gt: gts.len(),
        num_dont_care: dont_care.len(),
    })
}

/// Only annotated regions teach: a negative anchor whose centre, moved back through the
/// augmentation, lies where the frame's labels say nothing (KITTI: outside camera 2's columns or
/// in a `DontCare` region, [`EvalRegion::labels_point`]) is ignored, so an unlabelled car there
/// does not teach "background". Positives (labelled or pasted cars) keep their weight. The
/// transfer augmentation's tilt (at most 1.5°) is not undone: it moves a centre by centimetres.
pub(crate) fn ignore_unlabelled(
    targets: &mut Targets,
    anchors: &Anchors,
    region: &EvalRegion,
    aug: Option<&Augmentation>,
    transfer: Option<&TransferAug>,
) {
    let scale = transfer.map_or(1.0, |t| t.global_scale);
    let scale = if scale.is_finite() && scale > 0.0 {
        scale
    } else {
        1.0
    };
    let n = targets
        .labels
        .len()
        .min(targets.cls_weights.len())
        .min(anchors.boxes.len());
    let mut seen: Option<([f32; 2], bool)> = None;
    for i in 0..n {
        if targets.labels[i] > 0.0 || targets.cls_weights[i] == 0.0 {
            continue;
        }
        let a = &anchors.boxes[i];
        // The rotations of one cell share a centre: test it once.
        let labelled = match seen {
            Some((c, v)) if c == [a[0], a[1]] => v,
            _ => {
                let p = aug.map_or([a[0], a[1], a[2]], |g| g.undo([a[0], a[1], a[2]]));
                let p = [p[0] / scale, p[1] / scale, p[2] / scale].map(f64::from);
                let v = region.labels_point(p);
                seen = Some(([a[0], a[1]], v));
                v
            }
        };
        if !labelled {
            targets.cls_weights[i] = 0.0;
        }
    }
}

/// The loss terms of one step.
#[derive(Debug, Clone)]
pub struct Losses {
    pub total: Tensor,
    pub cls: f32,
    pub reg: f32,
    pub dir: f32,
    pub num_pos: usize,
}

impl Losses {
    /// The terms as plain numbers.
    pub fn terms(&self) -> LossTerms {
        LossTerms {
            cls: self.cls,
            reg: self.reg,
            dir: self.dir,
            num_pos: self.num_pos,
        }
    }
}

/// Forward pass and SECOND's loss on a prepared sample.
pub fn compute_loss(model: &Stage1Model, s: &PreparedSample) -> Result<Losses, DetectError> {
    compute_loss_with(model, s, 1.0)
}

/// [`compute_loss`] with SECOND's code weights (1, 1, 1, w, w, w, 1): the smooth-L1 terms of the
/// three log-size residuals are multiplied by `size_weight` (1: the plain loss, bit for bit).
pub fn compute_loss_with(
    model: &Stage1Model,
    s: &PreparedSample,
    size_weight: f32,
) -> Result<Losses, DetectError> {
    let dev = Device::Cpu;
    let heads = model.forward(&s.bevs, true)?;
    let t = &s.targets;
    let n = t.labels.len();
    let npos = t.positives.len();
    let norm = npos.max(1) as f64;
    let labels = Tensor::from_slice(&t.labels, n, &dev)?;
    let weights = Tensor::from_slice(&t.cls_weights, n, &dev)?;
    let cls = (sigmoid_focal_loss(&heads.cls, &labels, 0.25, 2.0)? * weights)?
        .sum_all()?
        .affine(1.0 / norm, 0.0)?;
    let (reg, dir) = if npos > 0 {
        let idx = Tensor::from_slice(&t.positives, npos, &dev)?;
        let pred = heads.reg.index_select(&idx, 0)?;
        let tgt = Tensor::from_slice(&t.reg, (npos, 7), &dev)?;
        // SECOND's sin-difference: sin(p − t) = sin p cos t − cos p sin t, split over both sides.
        let (p6, t6) = (pred.narrow(1, 6, 1)?, tgt.narrow(1, 6, 1)?);
        let pred = Tensor::cat(&[pred.narrow(1, 0, 6)?, (p6.sin()? * t6.cos()?)?], 1)?;
        let tgt = Tensor::cat(&[tgt.narrow(1, 0, 6)?, (p6.cos()? * t6.sin()?)?], 1)?;
        let mut reg = smooth_l1(&(pred - tgt)?, 1.0 / 9.0)?;
        if size_weight != 1.0 {
            let w = [1.0, 1.0, 1.0, size_weight, size_weight, size_weight, 1.0];
            reg = reg.broadcast_mul(&Tensor::from_slice(&w, (1, 7), &dev)?)?;
        }
        let reg = reg.sum_all()?.affine(2.0 / norm, 0.0)?;
        let dl = Tensor::from_slice(&t.dir, npos, &dev)?;
        let dir = cross_entropy_rows(&heads.dir.index_select(&idx, 0)?, &dl)?
            .sum_all()?
            .affine(0.2 / norm, 0.0)?;
        (reg, dir)
    } else {
        let z = Tensor::zeros((), DType::F32, &dev)?;
        (z.clone(), z)
    };
    let (c, r, d) = (
        cls.to_scalar::<f32>()?,
        reg.to_scalar::<f32>()?,
        dir.to_scalar::<f32>()?,
    );
    Ok(Losses {
        total: ((cls + reg)? + dir)?,
        cls: c,
        reg: r,
        dir: d,
        num_pos: npos,
    })
}

/// Training settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    pub case: Case,
    pub dataset: PathBuf,
    /// The final weights file.
    pub out: PathBuf,
    pub steps: u64,
    pub seed: u64,
    pub lr: f64,
    pub warmup: u64,
    pub weight_decay: f64,
    /// Checkpoint file (weights + optimiser + step + loss rows).
    pub checkpoint: PathBuf,
    /// Seconds between checkpoints.
    pub checkpoint_every_s: f64,
    /// Loss curve CSV.
    pub loss_csv: PathBuf,
    pub resume: bool,
    /// Use at most this many training samples (0: all).
    pub max_samples: usize,
    /// Start from these weights instead of random ones (a model of the same network shape; a
    /// single-branch model also initialises every Feature Fusion branch). Ignored on resume.
    pub init: Option<PathBuf>,
    /// Ground-truth sampling (SECOND's dataset sampling): top every frame up to this many boxes of
    /// the learned category from a database cut from the training split (0: off).
    pub gt_sample: usize,
    /// SECOND's code weight of the three log-size residuals (1: the plain loss).
    pub size_weight: f32,
    /// The command line, recorded in the manifest.
    pub command: String,
    /// Train on candle's own conv2d / conv_transpose2d and their autograd (the reference path)
    /// instead of the fast gemm convolutions ([`crate::nn::gemm`]). Same weights, same function;
    /// only the float rounding and the speed differ.
    #[serde(default)]
    pub slow_autograd: bool,
    /// [`crate::train::transfer_aug`]: object and global scaling, random point density.
    #[serde(default)]
    pub transfer_aug: bool,
    /// With `transfer_aug`: the car ray drop ([`TransferAug::draw_car_keep`]).
    #[serde(default)]
    pub car_drop: bool,
    /// The model's input leaves intensity out ([`crate::detect::voxel::GridConfig::intensity`]).
    #[serde(default)]
    pub no_intensity: bool,
    /// Train on every sample, the validation scenes included (adaptation to a few labelled
    /// frames, [`crate::train::adapt`]).
    #[serde(default)]
    pub all_samples: bool,
}

impl TrainConfig {
    pub fn new(case: Case, dataset: PathBuf, out: PathBuf) -> Self {
        let checkpoint = out.with_extension("ckpt.safetensors");
        let loss_csv = out.with_extension("loss.csv");
        Self {
            case,
            dataset,
            out,
            steps: 8000,
            seed: 0,
            lr: 2e-3,
            warmup: 200,
            weight_decay: 0.01,
            checkpoint,
            checkpoint_every_s: 300.0,
            loss_csv,
            resume: false,
            max_samples: 0,
            init: None,
            gt_sample: 0,
            size_weight: 1.0,
            command: String::new(),
            slow_autograd: false,
            transfer_aug: false,
            car_drop: false,
            no_intensity: false,
            all_samples: false,
        }
    }

    /// Learning rate at a step: linear warm-up, then cosine decay to 5% of `lr`.
    pub fn lr_at(&self, step: u64) -> f64 {
        if step < self.warmup {
            return self.lr * (step + 1) as f64 / self.warmup as f64;
        }
        let span = self.steps.saturating_sub(self.warmup).max(1) as f64;
        let p = ((step - self.warmup) as f64 / span).min(1.0);
        self.lr * (0.05 + 0.95 * 0.5 * (1.0 + (std::f64::consts::PI * p).cos()))
    }
}

/// One row of the loss curve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepRecord {
    pub step: u64,
    pub loss: f32,
    pub cls: f32,
    pub reg: f32,
    pub dir: f32,
    pub num_pos: usize,
    pub lr: f64,
    pub grad_norm: f64,
    pub elapsed_s: f64,
    /// Milliseconds spent on data (load, fuse, augment, voxelise, assign), forward + loss,
    /// backward, and the optimiser update.
    pub timing_ms: [f64; 4],
}

impl StepRecord {
    pub const CSV_HEADER: &'static str = "step,loss,cls,reg,dir,num_pos,lr,grad_norm,elapsed_s";

    pub fn csv(&self) -> String {
        format!(
            "{},{:.6},{:.6},{:.6},{:.6},{},{:.6e},{:.4},{:.2}",
            self.step,
            self.loss,
            self.cls,
            self.reg,
            self.dir,
            self.num_pos,
            self.lr,
            self.grad_norm,
            self.elapsed_s
        )
    }
}

/// The database objects pasted into the frame of a step (from ChaCha8(seed, stream 2³³ + step)).
fn sample_objects(
    database: &GtDatabase,
    frame: &Frame,
    category: &str,
    cfg: &TrainConfig,
    step: u64,
) -> Vec<usize> {
    if cfg.gt_sample == 0 || database.is_empty() {
        return Vec::new();
    }
    let occupied: Vec<RawBox> = frame.boxes.iter().map(|b| raw_box(&b.box3d)).collect();
    let existing = frame.boxes.iter().filter(|b| b.category == category).count();
    let mut rng = stream_rng(cfg.seed, (1u64 << 33) + step);
    database.sample(&mut rng, existing, &occupied, cfg.gt_sample)
}

/// The outcome of a training run.
#[derive(Debug, Clone, PartialEq)]
pub struct TrainSummary {
    pub steps: u64,
    pub wall_time_s: f64,
    pub sha256: String,
    pub out: PathBuf,
}

fn stream_rng(seed: u64, stream: u64) -> ChaCha8Rng {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    r.set_stream(stream);
    r
}

struct Checkpoint {
    step: u64,
    elapsed_s: f64,
    rows: Vec<String>,
}

fn save_checkpoint(
    cfg: &TrainConfig,
    model: &Stage1Model,
    opt: &AdamW,
    ck: &Checkpoint,
) -> Result<(), DetectError> {
    let extra = opt.state_tensors();
    let mut meta = BTreeMap::new();
    meta.insert("train.step".into(), ck.step.to_string());
    meta.insert("train.elapsed_s".into(), format!("{}", ck.elapsed_s));
    meta.insert("train.seed".into(), cfg.seed.to_string());
    meta.insert("train.steps".into(), cfg.steps.to_string());
    let bytes = model.to_safetensors(extra, meta)?;
    crate::io::write_atomic(&cfg.checkpoint, &bytes)?;
    write_loss_csv(&cfg.loss_csv, StepRecord::CSV_HEADER, &ck.rows)?;
    Ok(())
}

fn load_checkpoint(
    cfg: &TrainConfig,
    model: &Stage1Model,
    opt: &mut AdamW,
) -> Result<Checkpoint, DetectError> {
    let path = &cfg.checkpoint;
    let w = read_weights(path, None)?;
    let bad = |what: String| DetectError::Weights {
        path: path.clone(),
        what,
    };
    let ck_cfg = w.model_config()?;
    if ck_cfg != model.config {
        return Err(bad(format!(
            "checkpoint is for another model ({:?})",
            ck_cfg.case
        )));
    }
    let seed: u64 = w
        .metadata
        .get("train.seed")
        .and_then(|s| s.parse().ok())
        .unwrap_or(u64::MAX);
    if seed != cfg.seed {
        return Err(bad(format!(
            "checkpoint seed {seed} differs from --seed {}",
            cfg.seed
        )));
    }
    if let Some(varmap) = &model.varmap {
        restore_varmap(varmap, |n| w.tensors.get(n).cloned()).map_err(bad)?;
    }
    let step: u64 = w
        .metadata
        .get("train.step")
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| bad("no train.step".into()))?;
    opt.restore(|n| w.tensors.get(n).cloned(), step).map_err(bad)?;
    let elapsed_s = w
        .metadata
        .get("train.elapsed_s")
        .and_then(|s| s.parse().ok())
        .unwrap_or(0.0);
    let rows = loss_rows_before(&cfg.loss_csv, step);
    Ok(Checkpoint {
        step,
        elapsed_s,
        rows,
    })
}

/// Trains a stage-1 model (see the module doc). `on_step` sees every step's record.
pub fn train_stage1(
    cfg: &TrainConfig,
    mut on_step: impl FnMut(&StepRecord),
) -> Result<TrainSummary, DetectError> {
    if !cfg.case.is_trainable() {
        return Err(DetectError::BadParameter(
            "Result Fusion is not trained: train top, left and right, then calibrate-temperature".into(),
        ));
    }
    if cfg.steps == 0 {
        return Err(DetectError::BadParameter("steps must be at least 1".into()));
    }
    if !(cfg.lr.is_finite() && cfg.lr > 0.0 && cfg.lr < 1.0) {
        return Err(DetectError::BadParameter(format!(
            "the learning rate must be in (0, 1), got {}",
            cfg.lr
        )));
    }
    if !(cfg.weight_decay.is_finite() && cfg.weight_decay >= 0.0) {
        return Err(DetectError::BadParameter(format!(
            "the weight decay must be finite and >= 0, got {}",
            cfg.weight_decay
        )));
    }
    let dataset = Dataset::open(&cfg.dataset)?;
    let mut train = match cfg.all_samples {
        true => dataset.samples().into_iter().map(|s| s.sample_token).collect(),
        false => split(&dataset).0,
    };
    if cfg.max_samples > 0 {
        train.truncate(cfg.max_samples);
    }
    if train.is_empty() {
        return Err(DetectError::BadParameter(format!(
            "{}: no training samples",
            cfg.dataset.display()
        )));
    }
    let mut config = ModelConfig::new(cfg.case);
    config.grid.intensity = !cfg.no_intensity;
    let model = Stage1Model::new_trainable(config, cfg.seed)?;
    let database = if cfg.gt_sample > 0 {
        let a = &model.config.anchor;
        GtDatabase::build(&dataset, &train, cfg.case, &a.category, a.min_points)?
    } else {
        GtDatabase::default()
    };
    let mut opt = AdamW::new(&model, cfg.weight_decay)?;
    let mut ck = if cfg.resume && cfg.checkpoint.exists() {
        load_checkpoint(cfg, &model, &mut opt)?
    } else {
        if let Some(init) = &cfg.init {
            warm_start(&model, init)?;
        }
        Checkpoint {
            step: 0,
            elapsed_s: 0.0,
            rows: Vec::new(),
        }
    };
    // The native path (the default) or candle's autograd graph (`--slow-autograd`).
    let mut native = match cfg.slow_autograd {
        false => Some(NativeTrainer::new(&model, &opt)?),
        true => None,
    };
    let start = Instant::now();
    let base_elapsed = ck.elapsed_s;
    let mut last_ckpt = Instant::now();
    let n = train.len() as u64;
    // Samples are prepared one step ahead on a thread of their own (deterministic per step:
    // the order of epoch e and the draws of step s come from their own ChaCha8 streams).
    let prepare = |step: u64, order: &mut (u64, Vec<usize>)| -> Result<(PreparedSample, f64), DetectError> {
        let epoch = step / n;
        if epoch != order.0 {
            order.1 = (0..train.len()).collect();
            order.1.shuffle(&mut stream_rng(cfg.seed, epoch));
            order.0 = epoch;
        }
        let token = &train[order.1[(step % n) as usize]];
        let mut rng = stream_rng(cfg.seed, (1u64 << 32) + step);
        let aug = Augmentation::draw(&mut rng);
        let t0 = Instant::now();
        let frame = dataset.frame(token)?;
        let picked = sample_objects(&database, &frame, &model.config.anchor.category, cfg, step);
        let objects: Vec<&GtObject> = picked.iter().filter_map(|&i| database.objects.get(i)).collect();
        let transfer = cfg.transfer_aug.then(|| {
            let mut t = TransferAug::draw(&mut stream_rng(cfg.seed, (1u64 << 34) + step), MAX_SCALED_BOXES);
            if cfg.car_drop {
                t.car_keep = TransferAug::draw_car_keep(
                    &mut stream_rng(cfg.seed, (1u64 << 35) + step),
                    MAX_SCALED_BOXES,
                );
            }
            t
        });
        let params = FuseParams::default();
        let sample = prepare_sample_with(&model, &frame, aug.as_ref(), &objects, transfer.as_ref(), &params)?;
        Ok((sample, t0.elapsed().as_secs_f64() * 1e3))
    };
    std::thread::scope(|scope| -> Result<(), DetectError> {
        // Inside the scope: when a step fails, `rx` is dropped before the scope joins the
        // loader, whose blocked send then returns.
        let (tx, rx) = std::sync::mpsc::sync_channel(1);
        let first = ck.step;
        scope.spawn(move || {
            let mut order = (u64::MAX, Vec::new());
            for step in first..cfg.steps {
                let r = prepare(step, &mut order);
                let failed = r.is_err();
                if tx.send(r).is_err() || failed {
                    break;
                }
            }
        });
        while ck.step < cfg.steps {
            let step = ck.step;
            let (sample, data_ms) = rx
                .recv()
                .map_err(|_| DetectError::BadParameter("the sample loader stopped".into()))??;
            let t1 = Instant::now();
            let lr = cfg.lr_at(step);
            let (terms, grad_norm, t2, t3) = match native.as_mut() {
                Some(n) => {
                    let terms = n.forward(&sample, cfg.size_weight)?;
                    let t2 = Instant::now();
                    n.backward(&sample, terms.num_pos > 0)?;
                    let t3 = Instant::now();
                    (terms, n.update(lr, 10.0)?, t2, t3)
                }
                None => {
                    let losses = compute_loss_with(&model, &sample, cfg.size_weight)?;
                    let t2 = Instant::now();
                    let grads = losses.total.backward()?;
                    let t3 = Instant::now();
                    (losses.terms(), opt.update(&grads, lr, 10.0)?, t2, t3)
                }
            };
            let timing_ms = [
                data_ms,
                (t2 - t1).as_secs_f64() * 1e3,
                (t3 - t2).as_secs_f64() * 1e3,
                t3.elapsed().as_secs_f64() * 1e3,
            ];
            ck.step += 1;
            ck.elapsed_s = base_elapsed + start.elapsed().as_secs_f64();
            let rec = StepRecord {
                step,
                loss: terms.cls + terms.reg + terms.dir,
                cls: terms.cls,
                reg: terms.reg,
                dir: terms.dir,
                num_pos: terms.num_pos,
                lr,
                grad_norm,
                elapsed_s: ck.elapsed_s,
                timing_ms,
            };
            ck.rows.push(rec.csv());
            on_step(&rec);
            if last_ckpt.elapsed().as_secs_f64() >= cfg.checkpoint_every_s {
                if let Some(n) = &native {
                    n.store(&model, &mut opt)?;
                }
                save_checkpoint(cfg, &model, &opt, &ck)?;
                last_ckpt = Instant::now();
            }
        }
        Ok(())
    })?;
    if let Some(n) = &native {
        n.store(&model, &mut opt)?;
    }
    save_checkpoint(cfg, &model, &opt, &ck)?;
    let mut meta = BTreeMap::new();
    meta.insert("train.steps".into(), ck.step.to_string());
    meta.insert("train.seed".into(), cfg.seed.to_string());
    let bytes = model.to_safetensors(BTreeMap::new(), meta)?;
    crate::io::write_atomic(&cfg.out, &bytes)?;
    let sha256 = sha256_hex(&bytes);
    // Record the model in the manifest beside it.
    if let Some(dir) = folder_of(&cfg.out) {
        let mut manifest = Manifest::load(dir).unwrap_or_default();
        let file = file_name_of(&cfg.out);
        let init = cfg.init.as_deref().map(InitRecord::of_file);
        manifest.models.insert(
            cfg.case,
            ModelEntry {
                file,
                sha256: sha256.clone(),
                command: cfg.command.clone(),
                seed: cfg.seed,
                steps: ck.step,
                wall_time_s: ck.elapsed_s,
                test_ap: BTreeMap::new(),
                init,
            },
        );
        manifest.save(dir)?;
    }
    Ok(TrainSummary {
        steps: ck.step,
        wall_time_s: ck.elapsed_s,
        sha256,
        out: cfg.out.clone(),
    })
}

#[cfg(test)]
mod tests;
