//! Adaptation to a user's sensor (`mlod train adapt`, issue 53): fine-tunes the stage-1 cases of a
//! models folder on a few labelled real frames and writes a complete models folder beside it.
//!
//! How it works:
//! - The cases adapted are those the data can feed ([`adaptable_cases`]): LiDAR-Top always;
//!   Input and Feature Fusion when the frames have an auxiliary LiDAR. The refiner and Result
//!   Fusion's temperatures stay the base folder's.
//! - Each case starts from the base folder's weights ([`TrainConfig::init`]) with the base
//!   model's input (intensity or not) and trains on every labelled sample
//!   ([`TrainConfig::all_samples`]) with the transfer augmentation, SECOND's augmentation and
//!   ground-truth sampling from the real frames' own cars, so that a few frames go far.
//! - Only annotated regions teach: where a format labels part of the sweep (KITTI: camera 2's
//!   view), negative anchors outside it are ignored ([`crate::train::stage1`]).
//! - The output folder starts as a copy of the base folder (every file its manifest names, and
//!   their loss curves); the adapted weights replace the base's, and the manifest records the
//!   base folder's manifest hash, the dataset, the command ([`AdaptRecord`]). Files are written
//!   atomically. A run killed part-way resumes from each case's checkpoint when run again.

use std::path::{Path, PathBuf};

use crate::dataset::Dataset;
use crate::detect::weights::{read_weights, sha256_hex, AdaptRecord, Manifest};
use crate::detect::{Case, DetectError};
use crate::train::stage1::{train_stage1, StepRecord, TrainConfig, TrainSummary};

/// What `mlod train adapt` is asked to do.
#[derive(Debug, Clone, PartialEq)]
pub struct AdaptConfig {
    /// The labelled real data (any format the reader opens).
    pub dataset: PathBuf,
    /// The models folder to start from.
    pub base: PathBuf,
    /// The adapted models folder (created; may not be `base`).
    pub out: PathBuf,
    /// The cases to adapt (empty: [`adaptable_cases`]).
    pub cases: Vec<Case>,
    /// Steps per case.
    pub steps: u64,
    pub seed: u64,
    /// Peak learning rate (a quarter of training's from scratch by default).
    pub lr: f64,
    /// Ground-truth sampling: boxes per frame pasted from the frames' own cars (0: off).
    pub gt_sample: usize,
    /// The command line, and the base folder and dataset as the manifest names them (the
    /// paths as given by default; the command line makes them relative to where it ran).
    pub command: String,
    pub base_name: String,
    pub dataset_name: String,
}

impl AdaptConfig {
    pub fn new(dataset: PathBuf, base: PathBuf, out: PathBuf) -> Self {
        Self {
            base_name: base.display().to_string(),
            dataset_name: dataset.display().to_string(),
            dataset,
            base,
            out,
            cases: Vec::new(),
            steps: 1500,
            seed: 0,
            lr: 5e-4,
            gt_sample: 15,
            command: String::new(),
        }
    }
}

/// The stage-1 cases a dataset can teach: LiDAR-Top, and the fusion cases when a sample has an
/// auxiliary LiDAR. Only cases the base folder has weights for.
pub fn adaptable_cases(dataset: &Dataset, base: &Manifest) -> Vec<Case> {
    let rig = dataset
        .samples()
        .first()
        .and_then(|s| dataset.frame_info(&s.sample_token).ok())
        .is_some_and(|f| !f.auxiliaries.is_empty());
    let wanted: &[Case] = if rig {
        &[Case::Top, Case::Input, Case::Feature]
    } else {
        &[Case::Top]
    };
    wanted
        .iter()
        .copied()
        .filter(|c| base.models.contains_key(c))
        .collect()
}

fn bad(what: String) -> DetectError {
    DetectError::BadParameter(what)
}

/// Copies every file the base manifest names (and its loss curve) into `out`, unless already
/// there (a resumed run keeps what it adapted), then the manifest when `out` has none.
fn copy_base(base: &Path, manifest: &Manifest, out: &Path) -> Result<(), DetectError> {
    std::fs::create_dir_all(out).map_err(|e| crate::io::IoError::new("cannot create", out, e))?;
    let entries = manifest
        .models
        .values()
        .chain(manifest.refiner.as_ref())
        .chain(manifest.refiner_notrace.as_ref());
    for e in entries {
        let src = e.path_in(base)?;
        let loss = src.with_extension("loss.csv");
        for src in std::iter::once(src).chain(loss.is_file().then_some(loss)) {
            let name = src.file_name().map(PathBuf::from).unwrap_or_default();
            let dst = out.join(name);
            if dst.exists() {
                continue;
            }
            let bytes = std::fs::read(&src).map_err(|e| crate::io::IoError::new("cannot read", &src, e))?;
            crate::io::write_atomic(&dst, &bytes)?;
        }
    }
    if !out.join(Manifest::FILE).is_file() {
        manifest.save(out)?;
    }
    Ok(())
}

/// Adapts the cases (see the module doc); `on_step` sees each case's steps. Returns each
/// case's training summary; the manifest's `adapted` record is written last, without figures
/// (the caller adds them with [`record_fit`]).
pub fn adapt(
    cfg: &AdaptConfig,
    mut on_step: impl FnMut(Case, &StepRecord),
) -> Result<Vec<(Case, TrainSummary)>, DetectError> {
    if cfg.steps == 0 || cfg.steps > 1_000_000 {
        return Err(bad(format!("--steps must be in 1..=1000000, got {}", cfg.steps)));
    }
    // Checked before anything is written (the trainer checks again).
    if !(cfg.lr.is_finite() && cfg.lr > 0.0 && cfg.lr < 1.0) {
        return Err(bad(format!("--lr must be in (0, 1), got {}", cfg.lr)));
    }
    let same = |a: &Path, b: &Path| match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    };
    if same(&cfg.base, &cfg.out) {
        return Err(bad(format!(
            "--out {} is the base models folder: adapted weights go to a folder of their own",
            cfg.out.display()
        )));
    }
    let manifest_path = cfg.base.join(Manifest::FILE);
    let manifest_bytes = std::fs::read(&manifest_path)
        .map_err(|e| crate::io::IoError::new("cannot read", &manifest_path, e))?;
    let base = Manifest::load(&cfg.base)?;
    let dataset = Dataset::open(&cfg.dataset)?;
    let labelled = dataset
        .samples()
        .iter()
        .filter(|s| {
            dataset
                .frame_info(&s.sample_token)
                .is_ok_and(|f| !f.boxes.is_empty())
        })
        .count();
    if labelled == 0 {
        return Err(bad(format!(
            "{}: no sample has a labelled box; adaptation learns from labels",
            cfg.dataset.display()
        )));
    }
    let cases = match cfg.cases.is_empty() {
        true => adaptable_cases(&dataset, &base),
        false => cfg.cases.clone(),
    };
    if let Some(c) = cases.iter().find(|c| !c.is_trainable()) {
        return Err(bad(format!(
            "{c}: only the stage-1 networks adapt (top, left, right, input, feature)"
        )));
    }
    copy_base(&cfg.base, &base, &cfg.out)?;
    let mut done = Vec::new();
    for &case in &cases {
        let init = base.entry(&cfg.base, case)?.path_in(&cfg.base)?;
        let base_config = read_weights(&init, None)?.model_config()?;
        let out = cfg.out.join(format!("{case}.safetensors"));
        let mut t = TrainConfig::new(case, cfg.dataset.clone(), out);
        t.steps = cfg.steps;
        t.seed = cfg.seed;
        t.lr = cfg.lr;
        t.warmup = (cfg.steps / 10).clamp(1, 200);
        t.init = Some(init);
        t.gt_sample = cfg.gt_sample;
        t.transfer_aug = true;
        t.no_intensity = !base_config.grid.intensity;
        t.all_samples = true;
        t.checkpoint_every_s = 30.0;
        t.resume = t.checkpoint.is_file();
        t.command = cfg.command.clone();
        let summary = train_stage1(&t, |r| on_step(case, r))?;
        done.push((case, summary));
    }
    let mut manifest = Manifest::load(&cfg.out)?;
    manifest.adapted = Some(AdaptRecord {
        base: cfg.base_name.clone(),
        base_manifest_sha256: sha256_hex(&manifest_bytes),
        dataset: cfg.dataset_name.clone(),
        samples: labelled,
        cases,
        steps: cfg.steps,
        command: cfg.command.clone(),
        fit: Default::default(),
    });
    manifest.save(&cfg.out)?;
    Ok(done)
}

/// Adds figures measured on the adaptation frames (`case/model` → name → value) to the adapted
/// folder's manifest.
pub fn record_fit(
    out: &Path,
    fit: std::collections::BTreeMap<String, std::collections::BTreeMap<String, f64>>,
) -> Result<(), DetectError> {
    let mut manifest = Manifest::load(out)?;
    let record = manifest
        .adapted
        .as_mut()
        .ok_or_else(|| bad(format!("{}: not an adapted models folder", out.display())))?;
    record.fit = fit;
    manifest.save(out)
}
