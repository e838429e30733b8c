//! Uncertainty of multi-LiDAR points under extrinsic perturbation (paper §III):
//! the prior Θ and α ([`prior`]), seeded perturbation injection ([`perturb`]), per-point
//! covariance propagation Ξ = HΘHᵀ and tr(Ξ) ([`propagate`]), and the weighted plane fit of
//! §III-C with its Fig. 2 experiment ([`plane`]).

pub mod perturb;
pub mod plane;
pub mod prior;
pub mod propagate;

pub use perturb::{ExtrinsicNoise, Perturbation};
pub use prior::Prior;
pub use propagate::{covariance, trace_cloud, Linearization, TraceKernel};

/// The paper's threshold for an "uncertain" point: tr(Ξ) > 0.05 m² (§V-C footnote).
pub const UNCERTAIN_TRACE: f32 = 0.05;

/// The non-zero α a training draw picks from (the refiner's proposal database, and stage 1
/// trained under drift).
pub const TRAINING_ALPHAS: [f64; 5] = [0.02, 0.04, 0.06, 0.08, 0.1];

/// The share of training draws at α = 0 (α = 0 to α > 0 about 1 : 1.5).
pub const TRAINING_ZERO_SHARE: f64 = 0.4;

/// Errors of the uncertainty core; each names the value at fault.
#[derive(Debug, thiserror::Error)]
pub enum UncertaintyError {
    #[error("alpha must be a finite number >= 0, got {0}")]
    BadAlpha(f64),
    #[error("prior block {block} {reason}")]
    BadPrior { block: &'static str, reason: String },
    #[error("plane fit is degenerate: {0}")]
    Degenerate(String),
    #[error("{0}")]
    BadInput(String),
}
