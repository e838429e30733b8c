//! The proposal database the refiner trains on (paper §V-A-6): the shipped stage-1 fusion detectors
//! run once over the training scenes under injected perturbations, their boxes kept on disk, so
//! that training steps never run stage 1.
//!
//! Each training sample gets `draws` perturbations. Draw d of sample s takes α = 0 with probability
//! `zero_share` (0.4: α = 0 to α > 0 about 1 : 1.5) and otherwise one of 0.02, 0.04, 0.06, 0.08,
//! 0.1, and a perturbation seed, all from ChaCha8(seed, stream s·draws + d); every case in `cases`
//! runs on that same perturbation. One [`ProposalEntry`] per (sample, case, α, seed), keyed by
//! them. Samples are processed in shards of [`SHARD`] written atomically
//! (`shard-00000.json`, …); a killed build resumes at the first missing shard.

use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::cases::load_detector;
use crate::dataset::{train_validation_split, Dataset};
use crate::detect::model::Voting;
use crate::detect::{Case, Detection};
use crate::geometry::Box3d;
use crate::pipeline::FuseParams;
use crate::refine::RefineError;
use crate::uncertainty::Perturbation;

/// Samples per shard file.
pub const SHARD: usize = 32;

/// The non-zero perturbation levels a draw picks from.
pub const ALPHAS: [f64; 5] = crate::uncertainty::TRAINING_ALPHAS;

/// Stage 1's boxes of one sample under one perturbation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProposalEntry {
    pub sample: String,
    pub case: Case,
    pub alpha: f64,
    pub seed: u64,
    /// Per proposal: x, y, z, l, w, h, yaw, score (base frame, highest score first).
    pub boxes: Vec<[f32; 8]>,
    /// Their category (one per entry: the detectors' only class).
    pub category: String,
}

impl ProposalEntry {
    /// The proposals as detections.
    pub fn detections(&self) -> Vec<Detection> {
        self.boxes
            .iter()
            .map(|b| Detection {
                box3d: Box3d::new(
                    [b[0] as f64, b[1] as f64, b[2] as f64],
                    [b[3] as f64, b[4] as f64, b[5] as f64],
                    b[6] as f64,
                ),
                score: b[7],
                category: self.category.clone(),
            })
            .collect()
    }

    /// The fuse parameters of its perturbation.
    pub fn fuse_params(&self) -> Result<FuseParams, RefineError> {
        Ok(FuseParams {
            perturbation: Perturbation::new(self.alpha, self.seed)
                .map_err(|e| RefineError::BadParameter(e.to_string()))?,
            ..Default::default()
        })
    }
}

/// How the database is built.
#[derive(Debug, Clone)]
pub struct DatabaseConfig {
    pub dataset: PathBuf,
    pub models: PathBuf,
    pub out: PathBuf,
    pub cases: Vec<Case>,
    pub draws: usize,
    pub seed: u64,
    pub zero_share: f64,
    /// At most this many training samples (0: all).
    pub max_samples: usize,
}

/// α and the perturbation seed of draw `d` of the `s`-th training sample.
pub fn draw(seed: u64, s: usize, draws: usize, d: usize, zero_share: f64) -> (f64, u64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream((s * draws.max(1) + d) as u64);
    let alpha = if rng.random::<f64>() < zero_share {
        0.0
    } else {
        ALPHAS[rng.random_range(0..ALPHAS.len())]
    };
    (alpha, rng.random::<u32>() as u64)
}

fn shard_path(dir: &Path, k: usize) -> PathBuf {
    dir.join(format!("shard-{k:05}.json"))
}

/// Builds (or completes) the database; `on_shard(done, total)` after each shard. Returns the
/// number of entries in the whole database.
pub fn build(cfg: &DatabaseConfig, mut on_shard: impl FnMut(usize, usize)) -> Result<usize, RefineError> {
    if cfg.cases.iter().any(|c| c.is_mlod()) {
        return Err(RefineError::BadParameter(
            "the database holds stage-1 proposals: give stage-1 cases".into(),
        ));
    }
    if cfg.draws == 0 || cfg.cases.is_empty() {
        return Err(RefineError::BadParameter(
            "the database needs at least one draw and one case".into(),
        ));
    }
    if !(0.0..=1.0).contains(&cfg.zero_share) {
        return Err(RefineError::BadParameter(format!(
            "zero share {} is not in [0, 1]",
            cfg.zero_share
        )));
    }
    let dataset = Dataset::open(&cfg.dataset)?;
    let (mut train, _) = train_validation_split(&dataset);
    if cfg.max_samples > 0 {
        train.truncate(cfg.max_samples);
    }
    std::fs::create_dir_all(&cfg.out)
        .map_err(|e| crate::io::IoError::new("cannot create folder", &cfg.out, e))?;
    let detectors = cfg
        .cases
        .iter()
        .map(|&c| Ok((c, load_detector(&cfg.models, c, Voting::Manifest)?)))
        .collect::<Result<Vec<_>, RefineError>>()?;
    let shards = train.len().div_ceil(SHARD);
    for k in 0..shards {
        let path = shard_path(&cfg.out, k);
        if path.exists() {
            on_shard(k + 1, shards);
            continue;
        }
        let lo = k * SHARD;
        let hi = (lo + SHARD).min(train.len());
        let jobs: Vec<(usize, usize)> = (lo..hi)
            .flat_map(|s| (0..cfg.draws).map(move |d| (s, d)))
            .collect();
        let entries: Vec<Vec<ProposalEntry>> = jobs
            .par_iter()
            .map(|&(s, d)| -> Result<Vec<ProposalEntry>, RefineError> {
                let token = &train[s];
                let frame = dataset.frame(token)?;
                let (alpha, seed) = draw(cfg.seed, s, cfg.draws, d, cfg.zero_share);
                let params = FuseParams {
                    perturbation: Perturbation::new(alpha, seed)
                        .map_err(|e| RefineError::BadParameter(e.to_string()))?,
                    ..Default::default()
                };
                let mut out = Vec::new();
                for (case, det) in &detectors {
                    let dets = det.detect(&frame, &params)?;
                    let category = det
                        .categories()
                        .into_iter()
                        .next()
                        .unwrap_or_else(|| "car".into());
                    out.push(ProposalEntry {
                        sample: token.clone(),
                        case: *case,
                        alpha,
                        seed,
                        boxes: dets
                            .iter()
                            .filter(|x| x.category == category)
                            .map(|x| {
                                let b = &x.box3d;
                                [
                                    b.center[0] as f32,
                                    b.center[1] as f32,
                                    b.center[2] as f32,
                                    b.size_lwh[0] as f32,
                                    b.size_lwh[1] as f32,
                                    b.size_lwh[2] as f32,
                                    b.yaw as f32,
                                    x.score,
                                ]
                            })
                            .collect(),
                        category,
                    });
                }
                Ok(out)
            })
            .collect::<Result<_, _>>()?;
        let flat: Vec<ProposalEntry> = entries.into_iter().flatten().collect();
        let json = serde_json::to_vec(&flat).map_err(|e| RefineError::Database {
            path: path.clone(),
            what: e.to_string(),
        })?;
        crate::io::write_atomic(&path, &json)?;
        on_shard(k + 1, shards);
    }
    Ok(load(&cfg.out)?.len())
}

/// Every entry of a database folder, shard by shard.
pub fn load(dir: &Path) -> Result<Vec<ProposalEntry>, RefineError> {
    let mut out = Vec::new();
    for k in 0.. {
        let path = shard_path(dir, k);
        if !path.exists() {
            if k == 0 {
                return Err(RefineError::Database {
                    path: dir.to_path_buf(),
                    what: "no shard-00000.json: build it with `mlod train proposals`".into(),
                });
            }
            break;
        }
        let bytes = std::fs::read(&path).map_err(|e| crate::io::IoError::new("cannot read", &path, e))?;
        let entries: Vec<ProposalEntry> =
            serde_json::from_slice(&bytes).map_err(|e| RefineError::Database {
                path: path.clone(),
                what: e.to_string(),
            })?;
        for e in &entries {
            if e.boxes.iter().any(|b| b.iter().any(|v| !v.is_finite())) || !(0.0..=1.0).contains(&e.alpha) {
                return Err(RefineError::Database {
                    path: path.clone(),
                    what: format!(
                        "sample {} case {}: a non-finite box or an α outside [0, 1]",
                        e.sample, e.case
                    ),
                });
            }
        }
        out.extend(entries);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_are_seeded_and_about_forty_percent_zero() {
        let n = 5000;
        let zeros = (0..n).filter(|&s| draw(7, s, 2, 1, 0.4).0 == 0.0).count();
        assert!((zeros as f64 / n as f64 - 0.4).abs() < 0.03, "{zeros}");
        assert_eq!(draw(7, 3, 2, 1, 0.4), draw(7, 3, 2, 1, 0.4));
        assert_ne!(draw(7, 3, 2, 1, 0.4).1, draw(7, 3, 2, 0, 0.4).1);
        for s in 0..100 {
            let (a, _) = draw(1, s, 1, 0, 0.4);
            assert!(a == 0.0 || ALPHAS.contains(&a));
        }
    }
}
