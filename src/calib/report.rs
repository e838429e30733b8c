//! What one calibration run of one LiDAR reports: the records of `mlod calibrate --json`'s `runs`
//! (and the Python package's `Dataset.calibrate`), built in one place.

use nalgebra::{Matrix6, Vector6};
use serde::Serialize;

use super::{LidarCalibration, PoseError};
use crate::geometry::{log, Pose};

/// An extrinsic as `mlod calibrate --json` prints it.
#[derive(Serialize, Clone, Copy)]
pub struct Estimate {
    /// [w, x, y, z]
    pub rotation: [f64; 4],
    /// [x, y, z] (m)
    pub translation: [f64; 3],
}

impl From<&Pose> for Estimate {
    fn from(p: &Pose) -> Self {
        let q = p.rotation;
        let t = p.translation.vector;
        Self {
            rotation: [q.w, q.i, q.j, q.k],
            translation: [t.x, t.y, t.z],
        }
    }
}

#[derive(Serialize)]
pub struct CalibrationRun {
    pub sample_token: String,
    pub channel: String,
    /// The perturbation's seed of this run.
    pub seed: u64,
    /// The estimated extrinsic of this LiDAR in the base frame.
    pub estimate: Estimate,
    /// With `--draws`: the distance of the estimate to ICP's fixed point (the run started from
    /// the dataset's calibration).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub to_fixed_point: Option<PoseError>,
    pub error_before: PoseError,
    pub error_after: PoseError,
    pub converged: bool,
    pub degenerate: Vec<String>,
    pub fitness: f64,
    pub rmse: f64,
    pub iterations: usize,
    pub correspondences: usize,
    /// Eigenvalues of the normal matrix per unit weight, ascending (degenerate below the
    /// threshold `IcpConfig::degeneracy`).
    pub eigenvalues: [f64; 6],
    /// Estimated (ρ, φ) covariance, m and rad, 6×6.
    pub covariance: [[f64; 6]; 6],
    /// Standard deviations from it: tx, ty, tz (m), roll, pitch, yaw (deg).
    pub std: [f64; 6],
    /// The true error's squared Mahalanobis distance under `covariance` (≈ 6 on average for an
    /// honest covariance).
    pub mahalanobis2: f64,
    pub ms: f64,
}

impl CalibrationRun {
    /// The record of `l`, calibrated on sample `token` from the drift of `seed`, against the
    /// dataset's extrinsic `truth`; `fixed_point`: the run from the dataset's calibration, when
    /// there is one (`--draws`).
    pub fn new(
        token: &str,
        seed: u64,
        l: &LidarCalibration,
        truth: &Pose,
        fixed_point: Option<&Pose>,
    ) -> Self {
        let s = l.std();
        Self {
            sample_token: token.to_string(),
            channel: l.channel.as_str().to_string(),
            seed,
            estimate: Estimate::from(&l.extrinsic),
            to_fixed_point: fixed_point.map(|f| PoseError::between(&l.extrinsic, f)),
            error_before: l.error_before(truth),
            error_after: l.error(truth),
            converged: l.converged,
            degenerate: l.degenerate_axes(),
            fitness: l.fitness,
            rmse: l.rmse,
            iterations: l.iterations,
            correspondences: l.correspondences,
            eigenvalues: l.eigenvalues,
            covariance: l.covariance,
            std: [
                s[0],
                s[1],
                s[2],
                s[3].to_degrees(),
                s[4].to_degrees(),
                s[5].to_degrees(),
            ],
            mahalanobis2: mahalanobis2(l, truth),
            ms: l.ms,
        }
    }
}

/// The true error (ρ, φ) = (t − t̂, log(R R̂ᵀ)) against the estimate's covariance.
pub fn mahalanobis2(l: &LidarCalibration, truth: &Pose) -> f64 {
    let rho = truth.translation.vector - l.extrinsic.translation.vector;
    let rt = truth.rotation.to_rotation_matrix().into_inner();
    let re = l.extrinsic.rotation.to_rotation_matrix().into_inner();
    let phi = log(&(rt * re.transpose()));
    let e = Vector6::new(rho.x, rho.y, rho.z, phi.x, phi.y, phi.z);
    let cov = Matrix6::from_fn(|i, j| l.covariance[i][j]);
    match cov.pseudo_inverse(1e-18) {
        Ok(inv) => e.dot(&(inv * e)),
        Err(_) => f64::NAN,
    }
}
