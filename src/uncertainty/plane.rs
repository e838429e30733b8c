//! Plane fitting with and without the uncertainty prior (paper §III-C, Fig. 2).
//!
//! A plane n·p = d (d ≠ 0) is written x = n/d, so every point on it satisfies pᵀx = 1: stacking the
//! points as the rows of A gives A x = 1 (b = the all-ones vector). The unweighted fit is the
//! ordinary least-squares solution; the weighted fit solves x* = (AᵀWA)⁻¹AᵀW1 with
//! W_jj = 1 / tr(Ξ_j) — points of a LiDAR whose extrinsic is uncertain count less.
//!
//! The experiment of Fig. 2: 10 000 points on a plane with 0.02 m Gaussian noise are split at
//! random into two halves, the primary LiDAR's (base frame, exact) and an auxiliary LiDAR's,
//! whose points are expressed in its own frame through the §III-B extrinsic (rpy 10°, t = 1 m)
//! and brought back with an extrinsic perturbed by α (bounded at ±σ, as in §V-A-3). For each α
//! in 0, 0.01, …, 0.1 and 100 trials we record the mean ‖x_gt − x_est‖ of both fits.

use nalgebra::{Matrix3, Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rayon::prelude::*;
use serde::Serialize;

use super::perturb::{draw, ExtrinsicNoise};
use super::prior::{check_alpha, Prior};
use super::propagate::{trace, worked_example, Linearization};
use super::UncertaintyError;
use crate::geometry::{pose_from_rt, Pose};

/// Solves A x = 1 in the (weighted) least-squares sense. `weights`, if given, must have one
/// finite positive entry per point. Errors if the normal matrix is singular (collinear points or
/// a plane through the origin).
pub fn fit_plane(points: &[Vector3<f64>], weights: Option<&[f64]>) -> Result<Vector3<f64>, UncertaintyError> {
    if let Some(w) = weights {
        if w.len() != points.len() {
            return Err(UncertaintyError::BadInput(format!(
                "{} weights for {} points",
                w.len(),
                points.len()
            )));
        }
        if let Some(i) = w.iter().position(|v| !v.is_finite() || *v <= 0.0) {
            return Err(UncertaintyError::BadInput(format!(
                "weight {i} is {} (must be finite and > 0)",
                w[i]
            )));
        }
    }
    if let Some(i) = points.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
        return Err(UncertaintyError::BadInput(format!("point {i} is not finite")));
    }
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    for (j, p) in points.iter().enumerate() {
        let w = weights.map_or(1.0, |w| w[j]);
        ata += p * p.transpose() * w;
        atb += p * w;
    }
    let chol = ata.cholesky().ok_or_else(|| {
        UncertaintyError::Degenerate(format!("AᵀWA is singular for {} points", points.len()))
    })?;
    Ok(chol.solve(&atb))
}

/// One planar surface of the experiment: n·p = d, sampled over a rectangle on the plane.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct PlaneCase {
    pub name: &'static str,
    /// Unit normal.
    pub normal: [f64; 3],
    /// Offset d of n·p = d (m).
    pub offset: f64,
    /// Centre of the sampled patch (a point on the plane).
    pub center: [f64; 3],
    /// Half-extents of the patch along the two in-plane axes (m).
    pub half_extent: [f64; 2],
}

impl PlaneCase {
    /// The two planar cases we plot (the paper does not give its cases): a gently sloped road
    /// surface below the sensors and a building facade to the side.
    pub fn paper_cases() -> [PlaneCase; 2] {
        let ground = Vector3::new(0.03, -0.02, 1.0).normalize();
        let wall = Vector3::new(0.2, 1.0, 0.0).normalize();
        let g_center = Vector3::new(12.0, 0.0, -1.8);
        let w_center = Vector3::new(10.0, 12.0, 1.0);
        [
            PlaneCase {
                name: "ground",
                normal: ground.into(),
                offset: ground.dot(&g_center),
                center: g_center.into(),
                half_extent: [15.0, 10.0],
            },
            PlaneCase {
                name: "wall",
                normal: wall.into(),
                offset: wall.dot(&w_center),
                center: w_center.into(),
                half_extent: [12.0, 3.0],
            },
        ]
    }

    /// x_gt = n / d.
    pub fn ground_truth(&self) -> Vector3<f64> {
        Vector3::from(self.normal) / self.offset
    }

    /// Two in-plane unit axes (u horizontal where possible, v = n × u).
    fn axes(&self) -> (Vector3<f64>, Vector3<f64>) {
        let n = Vector3::from(self.normal);
        let helper = if n.z.abs() < 0.9 {
            Vector3::z()
        } else {
            Vector3::x()
        };
        let u = helper.cross(&n).normalize();
        (u, n.cross(&u))
    }
}

/// Configuration of the Fig. 2 experiment.
#[derive(Debug, Clone, Serialize)]
pub struct PlaneFitConfig {
    pub trials: usize,
    pub seed: u64,
    pub points: usize,
    pub noise_std: f64,
    pub alphas: Vec<f64>,
    pub linearization: Linearization,
}

impl Default for PlaneFitConfig {
    fn default() -> Self {
        Self {
            trials: 100,
            seed: 0,
            points: 10_000,
            noise_std: 0.02,
            alphas: (0..=10).map(|i| i as f64 * 0.01).collect(),
            linearization: Linearization::Separate,
        }
    }
}

/// One row of the result: mean errors over the trials for one (case, α).
#[derive(Debug, Clone, Serialize)]
pub struct PlaneFitRow {
    pub case: String,
    pub alpha: f64,
    pub weighted_error: f64,
    pub unweighted_error: f64,
}

/// Runs the experiment on the given cases; rows are ordered by case, then α.
pub fn plane_fit_experiment(
    cfg: &PlaneFitConfig,
    cases: &[PlaneCase],
) -> Result<Vec<PlaneFitRow>, UncertaintyError> {
    if cfg.trials == 0 || cfg.points < 6 {
        return Err(UncertaintyError::BadInput(format!(
            "need at least 1 trial and 6 points, got {} trials and {} points",
            cfg.trials, cfg.points
        )));
    }
    if !cfg.noise_std.is_finite() || cfg.noise_std <= 0.0 {
        return Err(UncertaintyError::BadInput(format!(
            "noise std must be > 0, got {}",
            cfg.noise_std
        )));
    }
    for &a in &cfg.alphas {
        check_alpha(a)?;
    }
    let (r, t, _) = worked_example();
    let extrinsic = pose_from_rt(&r, &t);
    let mut rows = Vec::new();
    for (ci, case) in cases.iter().enumerate() {
        for (ai, &alpha) in cfg.alphas.iter().enumerate() {
            let errors: Vec<(f64, f64)> = (0..cfg.trials)
                .into_par_iter()
                .map(|trial| {
                    let stream = ((ci as u64) << 48) | ((ai as u64) << 32) | trial as u64;
                    run_trial(cfg, case, &extrinsic, alpha, stream)
                })
                .collect::<Result<_, _>>()?;
            let n = errors.len() as f64;
            rows.push(PlaneFitRow {
                case: case.name.to_string(),
                alpha,
                weighted_error: errors.iter().map(|e| e.0).sum::<f64>() / n,
                unweighted_error: errors.iter().map(|e| e.1).sum::<f64>() / n,
            });
        }
    }
    Ok(rows)
}

/// One trial: returns (weighted error, unweighted error).
fn run_trial(
    cfg: &PlaneFitConfig,
    case: &PlaneCase,
    extrinsic: &Pose,
    alpha: f64,
    stream: u64,
) -> Result<(f64, f64), UncertaintyError> {
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    rng.set_stream(stream);
    let prior = Prior::paper();
    let scaled = prior.scaled(alpha)?;
    // The auxiliary LiDAR's perturbation for this trial (bounded at ±σ, §V-A-3).
    let noise = ExtrinsicNoise {
        rho: draw(&mut rng, &scaled.p, true),
        phi: draw(&mut rng, &scaled.phi, true),
    };
    let perturbed = noise.apply(extrinsic);
    let to_sensor = extrinsic.inverse();
    let (u, v) = case.axes();
    let center = Vector3::from(case.center);
    let r = extrinsic.rotation.to_rotation_matrix().into_inner();
    let t = extrinsic.translation.vector;
    // The primary LiDAR defines the base frame: its extrinsic is exact, so Ξ = Z and tr(Ξ) = tr Z.
    let primary_weight = 1.0 / scaled.z.trace();

    let mut pts = Vec::with_capacity(cfg.points);
    let mut weights = Vec::with_capacity(cfg.points);
    for _ in 0..cfg.points {
        let a = rng.random_range(-1.0..1.0) * case.half_extent[0];
        let b = rng.random_range(-1.0..1.0) * case.half_extent[1];
        let e = Vector3::new(
            rng.sample::<f64, _>(StandardNormal),
            rng.sample::<f64, _>(StandardNormal),
            rng.sample::<f64, _>(StandardNormal),
        ) * cfg.noise_std;
        let p = center + u * a + v * b + e;
        if rng.random_bool(0.5) {
            // Primary LiDAR: defines the base frame, only measurement noise.
            pts.push(p);
            weights.push(primary_weight);
        } else {
            // Auxiliary LiDAR: observed in its own frame, fused with the perturbed extrinsic.
            let q = to_sensor.transform_point(&Point3::from(p));
            pts.push(perturbed.transform_point(&q).coords);
            weights.push(1.0 / trace(&r, &t, &q.coords, &scaled, cfg.linearization));
        }
    }
    let gt = case.ground_truth();
    let xw = fit_plane(&pts, Some(&weights))?;
    let xu = fit_plane(&pts, None)?;
    Ok(((gt - xw).norm(), (gt - xu).norm()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_points_give_exact_plane_and_degenerate_input_errors() {
        let case = PlaneCase::paper_cases()[1];
        let (u, v) = case.axes();
        let c = Vector3::from(case.center);
        let pts: Vec<_> = (0..50)
            .map(|i| c + u * (i as f64 * 0.3 - 7.0) + v * ((i * 7 % 11) as f64 * 0.2 - 1.0))
            .collect();
        let x = fit_plane(&pts, None).unwrap();
        assert!((x - case.ground_truth()).norm() < 1e-9);
        let w: Vec<f64> = (0..50).map(|i| 1.0 + i as f64).collect();
        assert!((fit_plane(&pts, Some(&w)).unwrap() - case.ground_truth()).norm() < 1e-9);
        // Collinear points: singular.
        let line: Vec<_> = (0..10).map(|i| Vector3::new(i as f64, 1.0, 2.0)).collect();
        assert!(fit_plane(&line, None).is_err());
        assert!(fit_plane(&pts, Some(&w[..3])).is_err());
        let mut bad_w = w.clone();
        bad_w[4] = f64::NAN;
        assert!(fit_plane(&pts, Some(&bad_w)).is_err());
    }
}
