//! Robustness sweeps (the paper's Table II): car AP_3D@0.7 easy/moderate/hard of many cases at
//! several α over perturbation trials, resumable, shardable and identical whatever the thread
//! count.
//!
//! How it works: the work is cut into units (case, α, trial), grouped by (α, trial). Trial k at α
//! injects the perturbation of `mlod eval --alpha α --seed S+k` into every sample (one drift, as
//! on one car: what makes the spread across trials) or, with [`Draw::PerSample`], a new draw per
//! sample. Within a group every sample is loaded and fused once, calibrated once when an (OC) case
//! is asked for, stage 1 runs once per fusion scheme and cloud and its proposals are refined for
//! the MLOD variant; samples run in parallel (rayon) and are evaluated together, in sample order.
//! LiDAR-Top sees no perturbation, and at α = 0 every draw is zero: one trial each. Each finished unit is written at once,
//! atomically, as `units/<case>_a<α>_t<trial>.json`: a killed sweep resumes where it stopped; a
//! folder holding another configuration is refused, naming the setting that differs. `--shard
//! i/n` runs every n-th group; [`merge`] unites shard folders into one.

#![deny(clippy::indexing_slicing)]

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::calib::{IcpConfig, OcPrior};
use crate::dataset::Dataset;
use crate::detect::model::Voting;
use crate::detect::{Case, DetectError, Detection, Detector};
use crate::eval::{evaluate_detections, EvalOptions};
use crate::io::write_atomic;
use crate::pipeline::{calibrate, fuse, FuseParams};
use crate::refine::Refiner;
use crate::uncertainty::Perturbation;

mod shard;
pub use shard::{Shard, ShardSpec};

/// How perturbations are drawn across the samples of a trial.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Draw {
    /// One draw per trial for all samples (seed S + k), as on one car whose LiDARs drifted.
    #[default]
    OneCar,
    /// A new draw for every sample of every trial.
    PerSample,
}

/// Everything that decides a sweep's numbers (a resumed or merged sweep must match it exactly).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepConfig {
    pub cases: Vec<Case>,
    pub alphas: Vec<f64>,
    pub trials: usize,
    pub seed: u64,
    pub draw: Draw,
    pub oc_prior: OcPrior,
    /// The evaluated samples, in dataset order.
    pub samples: Vec<String>,
    /// A mis-specified prior: Ξ (and so the refiner's tr(Ξ)) computed with this α whatever α
    /// perturbed the points (the paper's supplementary "fixed α" analysis). `None`: the true α.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub assumed_alpha: Option<f64>,
    /// `input-drop`'s threshold on tr(Ξ) (m²), when that case is swept.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drop_trace: Option<f32>,
    /// The command line of each external detector swept (`ext:NAME`, `mlod-ext:NAME`), by name:
    /// a resumed or merged sweep must have run the same programs.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub detectors: BTreeMap<String, String>,
}

/// One unit of work.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Unit {
    pub case: Case,
    pub alpha: f64,
    pub trial: usize,
}

impl Unit {
    /// The unit's result file, inside the sweep folder's `units/`.
    pub fn file(&self) -> String {
        format!("{}_a{}_t{}.json", self.case.as_str(), self.alpha, self.trial)
    }
}

/// A finished unit: car AP_3D@0.7 (%) by difficulty (`None`: no car of that difficulty).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UnitResult {
    pub case: Case,
    pub alpha: f64,
    pub trial: usize,
    pub easy: Option<f64>,
    pub moderate: Option<f64>,
    pub hard: Option<f64>,
}

/// Errors of a sweep.
#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    #[error("{dir}: it holds a sweep with another {setting}: use another --out, or the same settings")]
    OtherConfig { dir: PathBuf, setting: String },
    #[error("bad sweep setting: {0}")]
    BadParameter(String),
    #[error("{path}: {what}")]
    File { path: PathBuf, what: String },
    #[error("merge: {0}")]
    Merge(String),
    /// A group of units failed; they are not written, so resuming retries them.
    #[error("α {alpha}, trial {trial} (units {units}) failed and will be retried when the sweep is resumed: {source}")]
    Group {
        alpha: f64,
        trial: usize,
        units: String,
        source: Box<SweepError>,
    },
    #[error(transparent)]
    Detect(#[from] DetectError),
    #[error(transparent)]
    Eval(#[from] crate::eval::EvalError),
    #[error(transparent)]
    Io(#[from] crate::io::IoError),
    #[error(transparent)]
    Plot(#[from] crate::analysis::plot::PlotError),
}

/// `n` samples spread evenly over `all` (all of them if `n` is `None` or larger).
pub fn spread_samples(all: &[String], n: Option<usize>) -> Vec<String> {
    match n {
        Some(n) if n < all.len() => (0..n)
            .filter_map(|i| all.get(i * all.len() / n).cloned())
            .collect(),
        _ => all.to_vec(),
    }
}

/// The first element that an earlier one equals.
fn first_repeat<T: PartialEq>(v: &[T]) -> Option<&T> {
    v.iter()
        .enumerate()
        .find(|(i, x)| v.iter().take(*i).any(|y| y == *x))
        .map(|(_, x)| x)
}

impl SweepConfig {
    /// Most perturbation trials a sweep may ask for (the paper runs 10).
    pub const MAX_TRIALS: usize = 10_000;
    /// Most α values a sweep may list (the paper lists 4).
    pub const MAX_ALPHAS: usize = 1_000;

    pub fn validate(&self) -> Result<(), SweepError> {
        let bad = |m: String| Err(SweepError::BadParameter(m));
        if self.cases.is_empty() || self.alphas.is_empty() || self.samples.is_empty() || self.trials == 0 {
            return bad("a sweep needs at least one case, α, sample and trial".into());
        }
        if let Some(a) = self
            .alphas
            .iter()
            .chain(&self.assumed_alpha)
            .find(|a| !(a.is_finite() && (0.0..=1.0).contains(*a)))
        {
            return bad(format!(
                "α must be in [0, 1] (the paper studies 0 to 0.1), got {a}"
            ));
        }
        if self.trials > Self::MAX_TRIALS || self.alphas.len() > Self::MAX_ALPHAS {
            return bad(format!(
                "{} trials at {} α: at most {} trials and {} α (a folder's configuration decides \
                 how many unit files are looked for)",
                self.trials,
                self.alphas.len(),
                Self::MAX_TRIALS,
                Self::MAX_ALPHAS
            ));
        }
        if let Some(d) = self.drop_trace.filter(|d| !(d.is_finite() && *d > 0.0)) {
            return bad(format!(
                "the drop threshold must be a positive tr(Ξ) in m², got {d}"
            ));
        }
        if let Some(a) = first_repeat(&self.alphas) {
            return bad(format!("α {a} is listed twice"));
        }
        if let Some(c) = first_repeat(&self.cases) {
            return bad(format!("case {c} is listed twice"));
        }
        Ok(())
    }

    /// Every unit, case by case in the order given, then α, then trial.
    pub fn units(&self) -> Vec<Unit> {
        let mut out = Vec::new();
        for &case in &self.cases {
            for &alpha in &self.alphas {
                let trials = self.trials_at(case, alpha);
                for trial in 0..trials {
                    out.push(Unit { case, alpha, trial });
                }
            }
        }
        out
    }

    /// Trials of a case at α: one for LiDAR-Top (it does not see the perturbation) and at α = 0
    /// (every draw is zero), `trials` otherwise.
    pub fn trials_at(&self, case: Case, alpha: f64) -> usize {
        if case == Case::Top || alpha == 0.0 {
            1
        } else {
            self.trials
        }
    }

    /// The groups (α, trial) in a fixed order: what `--shard` divides.
    fn groups(&self) -> Vec<(f64, usize)> {
        let mut g = Vec::new();
        for &alpha in &self.alphas {
            let trials = if alpha == 0.0 { 1 } else { self.trials };
            for trial in 0..trials {
                g.push((alpha, trial));
            }
        }
        g
    }

    /// The fuse parameters of sample `j` in trial `trial` at `alpha`.
    pub fn fuse_params(&self, alpha: f64, trial: usize, j: usize) -> Result<FuseParams, SweepError> {
        Ok(FuseParams {
            perturbation: self.perturbation(alpha, trial, j)?,
            prior_alpha: self.assumed_alpha,
            ..Default::default()
        })
    }

    /// The perturbation of sample `j` in trial `k` at `alpha`.
    pub fn perturbation(&self, alpha: f64, trial: usize, j: usize) -> Result<Perturbation, SweepError> {
        let seed = match self.draw {
            Draw::OneCar => self.seed.wrapping_add(trial as u64),
            Draw::PerSample => self
                .seed
                .wrapping_add(trial as u64)
                .wrapping_mul(1_000_003)
                .wrapping_add(j as u64),
        };
        Perturbation::new(alpha, seed).map_err(|e| SweepError::BadParameter(e.to_string()))
    }
}

const CONFIG_FILE: &str = "config.json";
const UNITS_DIR: &str = "units";

/// Writes `cfg` into `dir`, or checks that the one there is the same (naming what differs).
fn claim(dir: &Path, cfg: &SweepConfig) -> Result<(), SweepError> {
    let path = dir.join(CONFIG_FILE);
    match std::fs::read(&path) {
        Ok(bytes) => {
            let theirs: SweepConfig = serde_json::from_slice(&bytes).map_err(|e| SweepError::File {
                path: path.clone(),
                what: format!("not a sweep configuration: {e}"),
            })?;
            if theirs != *cfg {
                // Both through the same serialisation, so floats compare like for like.
                let (a, b) = (serde_json::to_value(&theirs), serde_json::to_value(cfg));
                let setting = match (a, b) {
                    (Ok(a), Ok(serde_json::Value::Object(b))) => b
                        .iter()
                        .find(|(k, v)| a.get(k.as_str()) != Some(v))
                        .map(|(k, _)| k.clone())
                        .or_else(|| {
                            a.as_object()
                                .and_then(|a| a.keys().find(|k| !b.contains_key(*k)).cloned())
                        }),
                    _ => None,
                }
                .unwrap_or_else(|| "configuration".into());
                return Err(SweepError::OtherConfig {
                    dir: dir.to_path_buf(),
                    setting,
                });
            }
            Ok(())
        }
        Err(_) => {
            std::fs::create_dir_all(dir.join(UNITS_DIR)).map_err(|e| SweepError::File {
                path: dir.to_path_buf(),
                what: e.to_string(),
            })?;
            let text =
                serde_json::to_string_pretty(cfg).map_err(|e| SweepError::BadParameter(e.to_string()))?;
            Ok(write_atomic(&path, format!("{text}\n").as_bytes())?)
        }
    }
}

fn read_unit(dir: &Path, u: &Unit) -> Option<UnitResult> {
    let bytes = std::fs::read(dir.join(UNITS_DIR).join(u.file())).ok()?;
    serde_json::from_slice(&bytes).ok()
}

/// The rows of a finished sweep's `results.json` (none when the file is absent).
fn read_merged_rows(dir: &Path) -> Result<Vec<UnitResult>, SweepError> {
    #[derive(Deserialize)]
    struct Merged {
        rows: Vec<UnitResult>,
    }
    let path = dir.join("results.json");
    let Ok(bytes) = std::fs::read(&path) else {
        return Ok(Vec::new());
    };
    serde_json::from_slice::<Merged>(&bytes)
        .map(|m| m.rows)
        .map_err(|e| SweepError::File {
            path,
            what: format!("not a sweep's results: {e}"),
        })
}

/// The stage-1 networks a case runs (Input Fusion for `input-drop`, Result Fusion for
/// `result-drop`; each stage 1 of a proposal union).
fn base_cases(c: Case) -> Vec<Case> {
    c.without_oc()
        .proposal_cases()
        .into_iter()
        .map(|b| b.dropped().unwrap_or(b))
        .collect()
}

/// The shipped detectors a sweep needs, loaded once.
struct Detectors {
    stage1: HashMap<Case, Box<dyn Detector>>,
    /// The refiner of each kind an MLOD case needs, keyed by whether it sees tr(Ξ) and whether
    /// it refines a proposal union (NMS after it).
    refiners: HashMap<(bool, bool), Arc<Refiner>>,
}

impl Detectors {
    fn load(models: &Path, cases: &[Case]) -> Result<Self, SweepError> {
        let mut stage1 = HashMap::new();
        for base in cases.iter().flat_map(|c| base_cases(*c)) {
            if let std::collections::hash_map::Entry::Vacant(e) = stage1.entry(base) {
                e.insert(crate::cases::load_detector(models, base, Voting::Manifest)?);
            }
        }
        let mut refiners = HashMap::new();
        for c in cases.iter().filter(|c| c.is_mlod()) {
            let key = (c.refiner_sees_trace(), c.is_union());
            if let std::collections::hash_map::Entry::Vacant(e) = refiners.entry(key) {
                e.insert(Arc::new(crate::cases::load_refiner(models, *c)?));
            }
        }
        Ok(Self { stage1, refiners })
    }
}

/// One sample of one group: every pending case's detections, sharing fuses, the calibration and
/// stage-1 runs.
fn detect_sample(
    dataset: &Dataset,
    token: &str,
    params: &FuseParams,
    cases: &[Case],
    det: &Detectors,
    cfg: &SweepConfig,
) -> Result<HashMap<Case, Vec<Detection>>, SweepError> {
    let oc_prior = cfg.oc_prior;
    let frame = dataset.frame(token).map_err(DetectError::from)?;
    let drifted = fuse(&frame, params).map_err(DetectError::from)?;
    let corrected = if cases.iter().any(|c| c.is_oc()) {
        let mut p = params.clone();
        p.calibration =
            Some(calibrate(&frame, params, &IcpConfig::default(), oc_prior).map_err(DetectError::from)?);
        Some(fuse(&frame, &p).map_err(DetectError::from)?)
    } else {
        None
    };
    let mut proposals: HashMap<(Case, bool), Vec<Detection>> = HashMap::new();
    let mut out = HashMap::new();
    // The certain points' cloud, made once for every "drop" stage 1 that a case needs.
    let drops: Vec<Case> = crate::detect::case::TABLE
        .iter()
        .map(|r| r.case)
        .filter(|d| d.dropped().is_some())
        .filter(|d| cases.iter().any(|c| c.without_oc().proposal_cases().contains(d)))
        .collect();
    if !drops.is_empty() {
        let t = cfg.drop_trace.unwrap_or(crate::cases::drop::DROP_TRACE);
        let kept = crate::cases::drop::drop_uncertain(&drifted, t);
        for drop in drops {
            let base = drop.dropped().unwrap_or(drop);
            let d = det
                .stage1
                .get(&base)
                .ok_or_else(|| SweepError::BadParameter(format!("no detector for {base}")))?;
            proposals.insert((drop, false), d.detect_fused(&frame, &kept)?);
        }
    }
    for &case in cases {
        let oc = case.is_oc();
        let cloud = if oc {
            corrected.as_ref().unwrap_or(&drifted)
        } else {
            &drifted
        };
        for base in case.without_oc().proposal_cases() {
            if let std::collections::hash_map::Entry::Vacant(e) = proposals.entry((base, oc)) {
                let d = det
                    .stage1
                    .get(&base)
                    .ok_or_else(|| SweepError::BadParameter(format!("no detector for {base}")))?;
                e.insert(d.detect_fused(&frame, cloud)?);
            }
        }
        let lists: Vec<&[Detection]> = case
            .without_oc()
            .proposal_cases()
            .iter()
            .filter_map(|b| proposals.get(&(*b, oc)).map(|v| v.as_slice()))
            .collect();
        // One stage 1's proposals are borrowed from the cache; a union is built.
        let props: std::borrow::Cow<'_, [Detection]> = match lists.as_slice() {
            [one] => std::borrow::Cow::Borrowed(*one),
            many => std::borrow::Cow::Owned(crate::cases::union::union_of(many)),
        };
        let dets = if case.is_mlod() {
            let r = det
                .refiners
                .get(&(case.refiner_sees_trace(), case.is_union()))
                .ok_or_else(|| SweepError::BadParameter(format!("no refiner for {case}")))?;
            r.refine(cloud, &props)
                .map_err(|e| DetectError::Refiner(e.to_string()))?
                .into_iter()
                .map(|r| r.detection)
                .collect()
        } else {
            props.into_owned()
        };
        out.insert(case, dets);
    }
    Ok(out)
}

/// Runs (or resumes) a sweep's shard in `dir`; `stop_after` stops after that many units (to
/// test resuming). Returns the units computed now. `progress` is told of every finished sample.
pub fn run(
    dataset: &Dataset,
    models: &Path,
    cfg: &SweepConfig,
    dir: &Path,
    shard: Shard,
    stop_after: Option<usize>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<usize, SweepError> {
    cfg.validate()?;
    claim(dir, cfg)?;
    let units = cfg.units();
    let groups: Vec<(usize, (f64, usize))> = cfg
        .groups()
        .into_iter()
        .enumerate()
        .filter(|(g, _)| g % shard.count == shard.index)
        .collect();
    let pending_of = |alpha: f64, trial: usize| -> Vec<Unit> {
        units
            .iter()
            .filter(|u| u.alpha == alpha && u.trial == trial && read_unit(dir, u).is_none())
            .copied()
            .collect()
    };
    let total_samples: usize = groups
        .iter()
        .filter(|(_, (a, t))| !pending_of(*a, *t).is_empty())
        .count()
        * cfg.samples.len();
    let done_samples = std::sync::atomic::AtomicUsize::new(0);
    let mut detectors: Option<Detectors> = None;
    let mut written = 0;
    let opts = EvalOptions {
        only: Some(cfg.samples.clone()),
        ..Default::default()
    };
    for (_, (alpha, trial)) in groups {
        let pending = pending_of(alpha, trial);
        if pending.is_empty() {
            continue;
        }
        if detectors.is_none() {
            detectors = Some(Detectors::load(models, &cfg.cases)?);
        }
        let det = detectors
            .as_ref()
            .ok_or_else(|| SweepError::BadParameter("no detectors".into()))?;
        let cases: Vec<Case> = pending.iter().map(|u| u.case).collect();
        let per_sample: Vec<(String, HashMap<Case, Vec<Detection>>)> = cfg
            .samples
            .par_iter()
            .enumerate()
            .map(|(j, token)| {
                let params = cfg.fuse_params(alpha, trial, j)?;
                let d = detect_sample(dataset, token, &params, &cases, det, cfg)?;
                let n = done_samples.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                progress(n, total_samples);
                Ok((token.clone(), d))
            })
            .collect::<Result<_, SweepError>>()
            .map_err(|e| SweepError::Group {
                alpha,
                trial,
                units: pending
                    .iter()
                    .map(|u| u.case.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
                source: Box::new(e),
            })?;
        for u in &pending {
            let dets: HashMap<String, Vec<Detection>> = per_sample
                .iter()
                .map(|(t, d)| (t.clone(), d.get(&u.case).cloned().unwrap_or_default()))
                .collect();
            let report = evaluate_detections(dataset, &dets, &opts)?;
            let cell = |d: &str| crate::eval::kitti::ap_cell(&report.kitti, "car", "iou_0.7", d);
            let r = UnitResult {
                case: u.case,
                alpha: u.alpha,
                trial: u.trial,
                easy: cell("easy"),
                moderate: cell("moderate"),
                hard: cell("hard"),
            };
            let text =
                serde_json::to_string_pretty(&r).map_err(|e| SweepError::BadParameter(e.to_string()))?;
            write_atomic(
                &dir.join(UNITS_DIR).join(u.file()),
                format!("{text}\n").as_bytes(),
            )?;
            written += 1;
            if stop_after.is_some_and(|s| written >= s) {
                return Ok(written);
            }
        }
    }
    Ok(written)
}

/// The finished units of `dir` in unit order, or the ones missing.
pub fn collect(dir: &Path, cfg: &SweepConfig) -> Result<Vec<UnitResult>, Vec<Unit>> {
    let mut rows = Vec::new();
    let mut missing = Vec::new();
    for u in cfg.units() {
        match read_unit(dir, &u) {
            Some(r) => rows.push(r),
            None => missing.push(u),
        }
    }
    if missing.is_empty() {
        Ok(rows)
    } else {
        Err(missing)
    }
}

/// Reads a sweep folder's configuration.
pub fn read_config(dir: &Path) -> Result<SweepConfig, SweepError> {
    let path = dir.join(CONFIG_FILE);
    let bytes = std::fs::read(&path).map_err(|e| SweepError::File {
        path: path.clone(),
        what: e.to_string(),
    })?;
    serde_json::from_slice(&bytes).map_err(|e| SweepError::File {
        path,
        what: format!("not a sweep configuration: {e}"),
    })
}

/// Mean and sample standard deviation (0 for one value); `None` without values.
fn mean_std(v: &[f64]) -> Option<(f64, f64)> {
    if v.is_empty() {
        return None;
    }
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let s = if v.len() > 1 {
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    Some((m, s))
}

/// Per (case, α): mean ± std of easy, moderate, hard over the trials.
pub type Summary = BTreeMap<(usize, usize), [Option<(f64, f64)>; 3]>;

fn summarize(cfg: &SweepConfig, rows: &[UnitResult]) -> Summary {
    let mut out = Summary::new();
    for (ci, case) in cfg.cases.iter().enumerate() {
        for (ai, alpha) in cfg.alphas.iter().enumerate() {
            let rs: Vec<&UnitResult> = rows
                .iter()
                .filter(|r| r.case == *case && r.alpha == *alpha)
                .collect();
            let pick = |f: fn(&UnitResult) -> Option<f64>| {
                mean_std(&rs.iter().filter_map(|r| f(r)).collect::<Vec<_>>())
            };
            out.insert(
                (ci, ai),
                [pick(|r| r.easy), pick(|r| r.moderate), pick(|r| r.hard)],
            );
        }
    }
    out
}

/// Per case (paper name): (α, mean, std) of the moderate AP where it has finished trials.
fn curves_of(cfg: &SweepConfig, summary: &Summary) -> Vec<crate::analysis::plot::Curve> {
    cfg.cases
        .iter()
        .enumerate()
        .map(|(ci, case)| {
            let pts = cfg
                .alphas
                .iter()
                .enumerate()
                .filter_map(|(ai, a)| summary.get(&(ci, ai)).and_then(|c| c[1]).map(|(m, s)| (*a, m, s)))
                .collect();
            (case.paper_name().to_string(), pts)
        })
        .collect()
}

/// What a sweep folder holds so far (a finished, running or partial sweep): its configuration,
/// the finished units and the AP-against-α curves over them.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepProgress {
    pub config: SweepConfig,
    /// The finished units, in unit order.
    pub rows: Vec<UnitResult>,
    /// Units of the whole sweep.
    pub total: usize,
    /// Per case: (α, mean, std) of car moderate AP_3D@0.7 over its finished trials.
    pub curves: Vec<crate::analysis::plot::Curve>,
}

impl SweepProgress {
    /// How many trials a (case, α) point averages.
    pub fn trials(&self, case: Case, alpha: f64) -> usize {
        self.rows
            .iter()
            .filter(|r| r.case == case && r.alpha == alpha && r.moderate.is_some())
            .count()
    }
}

/// Reads a sweep folder (what `mlod sweep --out` writes) as far as it has come.
pub fn progress(dir: &Path) -> Result<SweepProgress, SweepError> {
    let config = read_config(dir)?;
    config.validate()?;
    let units = config.units();
    let mut rows: Vec<UnitResult> = units.iter().filter_map(|u| read_unit(dir, u)).collect();
    if rows.is_empty() {
        // A committed sweep keeps its merged results.json, not the per-unit files.
        rows = read_merged_rows(dir)?;
    }
    let curves = curves_of(&config, &summarize(&config, &rows));
    Ok(SweepProgress {
        total: units.len(),
        rows,
        curves,
        config,
    })
}

/// Writes `table.md`, `results.json`, `results.csv` and `ap_vs_alpha.png` of a complete sweep.
pub fn write_outputs(dir: &Path, cfg: &SweepConfig, rows: &[UnitResult]) -> Result<(), SweepError> {
    let summary = summarize(cfg, rows);
    let fmt = |c: &Option<(f64, f64)>| c.map_or("–".to_string(), |(m, s)| format!("{m:.1} ± {s:.1}"));
    let mut md =
        String::from("Car AP_3D@0.7 (%), easy / moderate / hard, mean ± std over the trials.\n\n| Method |");
    for a in &cfg.alphas {
        md.push_str(&format!(" α = {a} easy | moderate | hard |"));
    }
    md.push_str("\n|---|");
    md.push_str(&"---:|".repeat(3 * cfg.alphas.len()));
    md.push('\n');
    for (ci, case) in cfg.cases.iter().enumerate() {
        md.push_str(&format!("| {} |", case.paper_name()));
        for ai in 0..cfg.alphas.len() {
            for cell in summary.get(&(ci, ai)).into_iter().flatten() {
                md.push_str(&format!(" {} |", fmt(cell)));
            }
        }
        md.push('\n');
    }
    write_atomic(&dir.join("table.md"), md.as_bytes())?;
    let json = serde_json::json!({ "config": cfg, "rows": rows });
    let text = serde_json::to_string_pretty(&json).map_err(|e| SweepError::BadParameter(e.to_string()))?;
    write_atomic(&dir.join("results.json"), format!("{text}\n").as_bytes())?;
    let mut csv = String::from("case,alpha,trial,easy,moderate,hard\n");
    let f = |v: Option<f64>| v.map_or(String::new(), |x| format!("{x}"));
    for r in rows {
        csv.push_str(&format!(
            "{},{},{},{},{},{}\n",
            r.case.as_str(),
            r.alpha,
            r.trial,
            f(r.easy),
            f(r.moderate),
            f(r.hard)
        ));
    }
    write_atomic(&dir.join("results.csv"), csv.as_bytes())?;
    let curves = curves_of(cfg, &summary);
    crate::analysis::plot::curves_with_error_bars_png(
        &curves,
        "Car moderate AP_3D@0.7 under extrinsic perturbation",
        "α",
        "AP_3D (%)",
        &dir.join("ap_vs_alpha.png"),
    )?;
    Ok(())
}

/// Unites shard folders of one sweep into `out` (the same files as one run): refuses shards of
/// another configuration and a union with missing units.
pub fn merge(out: &Path, shards: &[PathBuf]) -> Result<SweepConfig, SweepError> {
    let first = shards
        .first()
        .ok_or_else(|| SweepError::Merge("no shard folders given".into()))?;
    let cfg = read_config(first)?;
    for s in shards.iter().skip(1) {
        let c = read_config(s)?;
        if c != cfg {
            return Err(SweepError::Merge(format!(
                "{} holds another sweep than {}",
                s.display(),
                first.display()
            )));
        }
    }
    claim(out, &cfg)?;
    for u in cfg.units() {
        if read_unit(out, &u).is_some() {
            continue;
        }
        if let Some(r) = shards.iter().find_map(|s| read_unit(s, &u)) {
            let text =
                serde_json::to_string_pretty(&r).map_err(|e| SweepError::BadParameter(e.to_string()))?;
            write_atomic(
                &out.join(UNITS_DIR).join(u.file()),
                format!("{text}\n").as_bytes(),
            )?;
        }
    }
    match collect(out, &cfg) {
        Ok(rows) => {
            write_outputs(out, &cfg, &rows)?;
            Ok(cfg)
        }
        Err(missing) => Err(SweepError::Merge(match missing.first() {
            Some(u) => format!(
                "{} units missing from the shards, e.g. {} at α {} trial {}",
                missing.len(),
                u.case,
                u.alpha,
                u.trial
            ),
            None => "units missing from the shards".into(),
        })),
    }
}

#[cfg(test)]
mod tests;
