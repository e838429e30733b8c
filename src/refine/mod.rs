//! Stage 2 (paper §IV-B, eq. 12–17): the MLOD refiner. Each stage-1 proposal's points, with their
//! tr(Ξ), go through a PointNet that learns to trust the certain ones; it outputs an objectness
//! score and the residuals that turn the proposal into a refined box. MLOD-I/F/R are Input,
//! Feature and Result Fusion followed by it.
//!
//! How it is cut (OpenPCDet's ROI-head contract: proposals in, refined boxes out):
//! - [`points`]: the points of a proposal — one spatial index of the cloud per frame, the enlarged
//!   box, eq. 12–13's canonical frame, the seeded draw of a fixed number of points.
//! - [`coding`]: eq. 14 and its inverse.
//! - [`net`]: the network in candle (training); [`native`]: its training step written out over
//!   flat buffers (the default of `mlod train refiner`); [`infer`]: the same folded for inference, with the
//!   max-pool's arg-max (the active points of §V-C).
//! - [`loss`]: proposal targets (IoU > 0.6 / < 0.45) and eq. 15–17.
//! - [`proposals`]: the proposal database training reads (stage 1 run once per sample, case, α and
//!   perturbation seed).
//! - [`train`]: the training loop (§V-A-6 augmentation, AdamW, resumable checkpoints, loss CSV).
//! - [`model`]: a trained refiner, its decoding, and the [`model::Mlod`] detectors.

pub mod coding;
pub mod infer;
pub mod model;
pub mod net;
pub mod points;

pub use model::{redecode, Decoding, MlodRun, Refined, Refiner, ScoreRule, UNION_NMS_IOU};

/// Errors of the refiner.
#[derive(Debug, thiserror::Error)]
pub enum RefineError {
    #[error("refiner weights {path}: {what}")]
    File { path: std::path::PathBuf, what: String },
    #[error("refiner weights: {0}")]
    Weights(String),
    #[error("refiner input: {0}")]
    Shape(String),
    #[error("proposal database {path}: {what}")]
    Database { path: std::path::PathBuf, what: String },
    #[error("bad parameter: {0}")]
    BadParameter(String),
    #[error("network: {0}")]
    Candle(#[from] candle_core::Error),
    #[error(transparent)]
    Detect(#[from] crate::detect::DetectError),
    #[error(transparent)]
    Pipeline(#[from] crate::pipeline::PipelineError),
    #[error(transparent)]
    Lyft(#[from] crate::dataset::DatasetError),
    #[error(transparent)]
    Io(#[from] crate::io::IoError),
}
