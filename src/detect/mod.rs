//! Stage-1 detectors (paper §IV-A): LiDAR-Top/Left/Right, Input, Feature and Result Fusion, behind
//! one [`Detector`] trait, with their training and their shipped weights.
//!
//! How it is cut (OpenPCDet's stage order):
//! - [`voxel`]: points in the base frame → height-compressed BEV (SECOND v1.5 mean-point FLN:
//!   in-voxel mean x, y, z and density per voxel).
//! - [`net`]: 2D middle layers (one branch per LiDAR in Feature Fusion, max-fused, eq. 10), SECOND's
//!   RPN and heads, focal / smooth-L1 / direction losses.
//! - [`infer`]: the same network folded for inference (BatchNorm in the weights, HWC maps, one
//!   gemm per band of rows, in parallel): what every loaded model runs; candle's forward is kept
//!   for training.
//! - [`anchors`]: anchors, target assignment, SECOND's box coding.
//! - [`model`]: a trained network + its configuration → [`Detection`]s (decoding, NMS), the
//!   [`Detector`] implementations of every [`Case`], Result Fusion (eq. 11) with temperature
//!   scaling.
//! - [`weights`]: safetensors files with their configuration, sha256-checked through
//!   `assets/models/manifest.json`.
//! - [`gt_sampling`]: SECOND's ground-truth (dataset) sampling for training.
//! - [`train`]: the training loop (§V-A-5 augmentation, AdamW, resumable checkpoints, loss CSV) and
//!   the temperature calibration of Result Fusion.

pub mod anchors;
pub mod case;
pub mod config;
pub mod infer;
pub mod model;
pub mod net;
pub mod voxel;
pub mod weights;

use crate::dataset::{Frame, LidarChannel};
use crate::pipeline::{FuseParams, FusedCloud};

/// A detector's output: a base-frame box, its confidence in [0, 1] (calibrated by temperature
/// scaling in Result Fusion) and its Lyft category.
pub use crate::geometry::Detection;
pub use case::{Build, Case, CaseRow, Group};
pub use model::{ModelConfig, ResultFusion, Stage1Model};
pub use weights::{Manifest, ModelEntry};

/// Errors of the detectors.
#[derive(Debug, thiserror::Error)]
pub enum DetectError {
    #[error("weights file {path}: {what}")]
    Weights { path: std::path::PathBuf, what: String },
    #[error("weights file {path}: sha256 {actual} does not match the manifest's {expected} (corrupt or replaced file)")]
    Checksum {
        path: std::path::PathBuf,
        expected: String,
        actual: String,
    },
    #[error("weights file {path} is for case {found}, expected {expected}")]
    WrongCase {
        path: std::path::PathBuf,
        expected: Case,
        found: String,
    },
    #[error("manifest {path}: {what}")]
    Manifest { path: std::path::PathBuf, what: String },
    #[error("sample {sample}: LiDAR {channel} is not present")]
    MissingLidar { sample: String, channel: LidarChannel },
    #[error("bad parameter: {0}")]
    BadParameter(String),
    /// The stage-2 refiner of an MLOD case could not be loaded or run (its message names the file).
    #[error("{0}")]
    Refiner(String),
    #[error("network: {0}")]
    Candle(#[from] candle_core::Error),
    #[error(transparent)]
    Pipeline(#[from] crate::pipeline::PipelineError),
    #[error(transparent)]
    Lyft(#[from] crate::dataset::DatasetError),
    #[error(transparent)]
    Io(#[from] crate::io::IoError),
    /// An external detector failed (`crate::external`; the message names it).
    #[error("{0}")]
    External(String),
    /// A case failed on one sample of a run over many (`crate::cases::run`).
    #[error("{case} on sample {sample}: {source}")]
    Sample {
        case: String,
        sample: String,
        source: Box<DetectError>,
    },
}

/// One entry point for every stage-1 case.
pub trait Detector: Send + Sync {
    /// The case this detector implements.
    fn case(&self) -> Case;

    /// The Lyft categories it can output (`car`, ...); ground truth of other classes is not its
    /// business.
    fn categories(&self) -> Vec<String>;

    /// Detects objects on `cloud`, the frame fused by the caller (`pipeline::fuse`); boxes are in
    /// the base frame, highest score first. A caller that needs the cloud too (the MLOD refiner)
    /// fuses once.
    fn detect_fused(&self, frame: &Frame, cloud: &FusedCloud) -> Result<Vec<Detection>, DetectError>;

    /// The parameters [`Detector::detect`] fuses `frame` with: `params` itself, or for an (OC)
    /// case `params` with the online calibration in them. A detector wrapping another passes
    /// this on, so that a wrapped (OC) case still detects on its calibrated cloud.
    fn fuse_params(&self, frame: &Frame, params: &FuseParams) -> Result<FuseParams, DetectError> {
        let _ = frame;
        Ok(params.clone())
    }

    /// Fuses the frame with [`Detector::fuse_params`] (so perturbations reach the auxiliary
    /// LiDARs) and detects.
    fn detect(&self, frame: &Frame, params: &FuseParams) -> Result<Vec<Detection>, DetectError> {
        let cloud = crate::pipeline::fuse(frame, &self.fuse_params(frame, params)?)?;
        self.detect_fused(frame, &cloud)
    }
}
