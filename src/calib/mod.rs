//! Online calibration (the paper's "(OC)" cases, §V-A-4): point-to-plane ICP re-estimates each
//! auxiliary LiDAR's extrinsic against the top LiDAR's cloud, starting from the drifted
//! (perturbed) extrinsic, and says what it leaves uncertain.
//!
//! How it works ([`icp`]): both clouds are voxel-downsampled; the target (LIDAR_TOP, the base
//! frame) gets a kd-tree (kiddo) and a normal per point from its k nearest neighbours; each
//! iteration pairs every source point with its nearest target point within a distance that shrinks
//! over the iterations, weights the point-to-plane residuals with a Huber kernel and takes one
//! Gauss-Newton step on se(3) in the perturbation's own convention (t = t̄ + ρ, R = exp(φ^)R̄, so
//! the estimate's covariance is in the same (ρ, φ) as the prior Θ). Directions the scene does not
//! constrain (a flat ground, a corridor of parallel walls) show up as small eigenvalues of the 6×6
//! normal matrix; the step is projected off them, so they stay at their start value instead of
//! drifting on noise (Zhang et al., "On degeneracy of optimization-based state estimation
//! problems", ICRA 2016, solution remapping), and they are reported by name.
//!
//! Beyond the paper: the estimate's covariance, σ² (JᵀWJ)⁻¹ on the constrained directions (σ² the
//! weighted residual variance) and the prior's variance on the degenerate ones. With
//! [`OcPrior::Icp`] the points of a calibrated LiDAR get their Ξ from this covariance instead of
//! the prior Θ(α) (`pipeline::fuse`).

pub mod icp;
pub mod report;

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::dataset::LidarChannel;
use crate::geometry::{log, Pose};

pub use icp::{align, voxel_downsample, IcpOutcome, Target};

/// Which uncertainty the points of a calibrated LiDAR carry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OcPrior {
    /// The covariance ICP estimated (what is left after calibration).
    #[default]
    Icp,
    /// The prior Θ(α), as if ICP had not run (the points move, their tr(Ξ) does not).
    Alpha,
}

impl OcPrior {
    pub fn name(self) -> &'static str {
        match self {
            OcPrior::Icp => "icp",
            OcPrior::Alpha => "alpha",
        }
    }
}

impl fmt::Display for OcPrior {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for OcPrior {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "icp" => Ok(Self::Icp),
            "alpha" => Ok(Self::Alpha),
            other => Err(format!("unknown OC prior '{other}' (expected icp or alpha)")),
        }
    }
}

/// The settings of the ICP (defaults chosen on the validation scenes, `docs/calibration.md`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct IcpConfig {
    /// Voxel side of the source (auxiliary) cloud (m).
    pub source_voxel: f32,
    /// Voxel side of the target (top) cloud (m).
    pub target_voxel: f32,
    /// Points farther than this from their sensor are left out (m).
    pub max_range: f32,
    /// Neighbours of a target point that define its normal.
    pub normal_k: usize,
    /// A target point whose neighbourhood's surface variation λ₀/(λ₀+λ₁+λ₂) is above this has no
    /// normal (an edge or clutter, not a plane) and takes no correspondence.
    pub max_curvature: f32,
    /// … and one whose neighbourhood is a line rather than a plane, λ₁ < `min_spread`·λ₂ (0: no
    /// such check).
    pub min_spread: f32,
    /// Correspondence distance of the first iteration (m) …
    pub max_distance: f64,
    /// … multiplied by `shrink` every iteration down to `min_distance` (m).
    pub min_distance: f64,
    pub shrink: f64,
    /// Huber threshold on the point-to-plane residual (m).
    pub huber: f64,
    pub max_iterations: usize,
    /// Converged when a step at the final distance moves less than these (m, rad).
    pub tolerance_translation: f64,
    pub tolerance_rotation: f64,
    /// A direction whose eigenvalue of the normal matrix (rotations scaled by the RMS lever arm,
    /// so both are in m) per unit of correspondence weight is below this is degenerate.
    pub degeneracy: f64,
    /// Fewer correspondences than this and ICP stops where it is (not converged).
    pub min_correspondences: usize,
    /// Multiplies σ²(JᵀWJ)⁻¹: neighbouring residuals are not independent (both clouds sample
    /// the same surfaces, the voxel centroids share points), so the textbook covariance is too
    /// small. Fitted on the validation scenes so that the true errors' median squared Mahalanobis
    /// distance is χ²₆'s median, 5.35 (`docs/calibration.md`).
    pub covariance_scale: f64,
}

impl Default for IcpConfig {
    fn default() -> Self {
        Self {
            source_voxel: 0.3,
            target_voxel: 0.3,
            max_range: 60.0,
            normal_k: 10,
            max_curvature: 0.05,
            min_spread: 0.0,
            max_distance: 1.5,
            min_distance: 0.25,
            shrink: 0.7,
            huber: 0.05,
            max_iterations: 60,
            tolerance_translation: 1e-4,
            tolerance_rotation: 1e-5,
            degeneracy: 1e-3,
            min_correspondences: 100,
            covariance_scale: 3.7,
        }
    }
}

impl IcpConfig {
    /// The defaults with `key=value` overrides (the field names above), e.g. from `--icp
    /// source_voxel=0.4`; unknown keys and bad values are errors naming them.
    pub fn with_overrides(overrides: &[String]) -> Result<Self, CalibError> {
        let mut v =
            serde_json::to_value(Self::default()).map_err(|e| CalibError::BadParameter(e.to_string()))?;
        for o in overrides {
            let (key, value) = o
                .split_once('=')
                .ok_or_else(|| CalibError::BadParameter(format!("'{o}': expected key=value")))?;
            let slot = v
                .get_mut(key.trim())
                .ok_or_else(|| CalibError::BadParameter(format!("unknown ICP setting '{}'", key.trim())))?;
            *slot = serde_json::from_str(value.trim()).map_err(|_| {
                CalibError::BadParameter(format!("'{o}': '{}' is not a number", value.trim()))
            })?;
        }
        let cfg: Self =
            serde_json::from_value(v).map_err(|e| CalibError::BadParameter(format!("{overrides:?}: {e}")))?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Refuses settings that cannot work (non-finite, non-positive, a shrink outside (0, 1]).
    pub fn validate(&self) -> Result<(), CalibError> {
        let positive = [
            ("source_voxel", self.source_voxel as f64),
            ("target_voxel", self.target_voxel as f64),
            ("max_range", self.max_range as f64),
            ("max_curvature", self.max_curvature as f64),
            ("max_distance", self.max_distance),
            ("min_distance", self.min_distance),
            ("huber", self.huber),
            ("tolerance_translation", self.tolerance_translation),
            ("tolerance_rotation", self.tolerance_rotation),
            ("degeneracy", self.degeneracy),
            ("covariance_scale", self.covariance_scale),
        ];
        for (name, v) in positive {
            if !v.is_finite() || v <= 0.0 {
                return Err(CalibError::BadParameter(format!(
                    "{name} must be a finite number > 0, got {v}"
                )));
            }
        }
        if !(self.min_spread >= 0.0 && self.min_spread <= 1.0) {
            return Err(CalibError::BadParameter(format!(
                "min_spread must be in [0, 1], got {}",
                self.min_spread
            )));
        }
        if !(self.shrink > 0.0 && self.shrink <= 1.0) {
            return Err(CalibError::BadParameter(format!(
                "shrink must be in (0, 1], got {}",
                self.shrink
            )));
        }
        if self.min_distance > self.max_distance {
            return Err(CalibError::BadParameter(format!(
                "min_distance {} is above max_distance {}",
                self.min_distance, self.max_distance
            )));
        }
        if self.normal_k < 3 || self.max_iterations == 0 || self.min_correspondences < 6 {
            return Err(CalibError::BadParameter(
                "normal_k must be ≥ 3, max_iterations ≥ 1 and min_correspondences ≥ 6".into(),
            ));
        }
        Ok(())
    }
}

/// The six directions of the (ρ, φ) tangent space, by the axis that dominates them.
pub const DIRECTION_NAMES: [&str; 6] = ["tx", "ty", "tz", "roll", "pitch", "yaw"];

/// A direction ICP could not observe: an eigenvector of the (scaled) normal matrix.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Degenerate {
    /// The dominant axis: tx, ty, tz (base-frame translations) or roll, pitch, yaw (rotations
    /// about the base frame's x, y, z).
    pub axis: String,
    /// Its eigenvalue per unit of correspondence weight (dimensionless, see
    /// [`IcpConfig::degeneracy`]).
    pub eigenvalue: f64,
    /// The unit eigenvector in (ρ, φ·L) coordinates, L the RMS lever arm.
    pub vector: [f64; 6],
}

/// ICP's result for one auxiliary LiDAR.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LidarCalibration {
    pub channel: LidarChannel,
    /// The extrinsic ICP started from (the drifted one the system believed).
    pub start: Pose,
    /// The re-estimated extrinsic.
    pub extrinsic: Pose,
    /// Covariance of the estimate in (ρ, φ) (m, rad), row-major 6×6: the error model
    /// t = t̂ + ρ, R = exp(φ^) R̂.
    pub covariance: [[f64; 6]; 6],
    pub converged: bool,
    pub iterations: usize,
    /// Share of the source points with a correspondence at the final distance.
    pub fitness: f64,
    /// RMS point-to-plane residual of those correspondences (m).
    pub rmse: f64,
    pub correspondences: usize,
    pub source_points: usize,
    pub target_points: usize,
    /// Eigenvalues of the normal matrix per unit of weight, ascending.
    pub eigenvalues: [f64; 6],
    pub degenerate: Vec<Degenerate>,
    /// Wall time of the alignment (ms; the target's kd-tree and normals not included).
    pub ms: f64,
}

impl LidarCalibration {
    /// (rotation error in degrees, translation error in m) of the estimate against `truth`.
    pub fn error(&self, truth: &Pose) -> PoseError {
        PoseError::between(&self.extrinsic, truth)
    }

    /// The same for the start.
    pub fn error_before(&self, truth: &Pose) -> PoseError {
        PoseError::between(&self.start, truth)
    }

    /// Whether this calibration was computed from the drifted extrinsic `drifted` (else it is
    /// stale: the perturbation changed since).
    pub fn started_from(&self, drifted: &Pose) -> bool {
        let moved = PoseError::between(&self.start, drifted);
        moved.rot_deg <= 1e-9 && moved.trans_m <= 1e-9
    }

    /// Whether the run is flagged (not converged, or some direction degenerate): a flagged run may
    /// end farther from the truth than it started.
    pub fn flagged(&self) -> bool {
        !self.converged || !self.degenerate.is_empty()
    }

    /// The degenerate directions' names.
    pub fn degenerate_axes(&self) -> Vec<String> {
        self.degenerate.iter().map(|d| d.axis.clone()).collect()
    }

    /// Standard deviations of the estimate (ρ in m, φ in rad), from the covariance's diagonal.
    pub fn std(&self) -> [f64; 6] {
        std::array::from_fn(|i| self.covariance[i][i].max(0.0).sqrt())
    }
}

/// The distance between two extrinsics.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct PoseError {
    /// The angle of R_a R_bᵀ (degrees).
    pub rot_deg: f64,
    /// |t_a − t_b| (m).
    pub trans_m: f64,
}

impl PoseError {
    pub fn between(a: &Pose, b: &Pose) -> Self {
        let ra = a.rotation.to_rotation_matrix().into_inner();
        let rb = b.rotation.to_rotation_matrix().into_inner();
        Self {
            rot_deg: log(&(ra * rb.transpose())).norm().to_degrees(),
            trans_m: (a.translation.vector - b.translation.vector).norm(),
        }
    }
}

/// The online calibration of one frame: what `pipeline::fuse` needs to fuse with the corrected
/// extrinsics, and what the user is shown. It is valid only for the sample and the drifted
/// extrinsics it was computed from; `fuse` refuses it otherwise.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Calibration {
    pub sample_token: String,
    /// The uncertainty the calibrated LiDARs' points carry.
    pub prior: OcPrior,
    pub config: IcpConfig,
    pub lidars: Vec<LidarCalibration>,
    /// Wall time of the target's downsampling, kd-tree and normals (ms), built once per frame.
    pub target_ms: f64,
}

impl Calibration {
    pub fn lidar(&self, channel: LidarChannel) -> Option<&LidarCalibration> {
        self.lidars.iter().find(|l| l.channel == channel)
    }
}

/// Errors of the online calibration.
#[derive(Debug, thiserror::Error)]
pub enum CalibError {
    #[error("{cloud} cloud: {what}")]
    BadCloud { cloud: &'static str, what: String },
    #[error("bad ICP setting: {0}")]
    BadParameter(String),
}
