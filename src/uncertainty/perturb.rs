//! Extrinsic perturbation injection (paper eq. 1–2 and §V-A-3): ρ ~ N(0, αP), φ ~ N(0, αΦ),
//! each component bounded within ±σ ("to remove the effects from outliers"), then
//! t = t̄ + ρ and R = exp(φ^)R̄. Every draw comes from a seeded ChaCha8 stream, so a session can
//! store (α, seed) — or the sampled (ρ, φ) themselves — and replay the exact same extrinsics.

use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use super::prior::{check_alpha, Prior};
use super::UncertaintyError;
use crate::geometry::{exp, Pose};

/// A sampled extrinsic perturbation θ_ext = [ρ, φ] of one LiDAR.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ExtrinsicNoise {
    /// Translation offset ρ (m), added: t = t̄ + ρ.
    pub rho: [f64; 3],
    /// Rotation offset φ (rad), on the left: R = exp(φ^) R̄.
    pub phi: [f64; 3],
}

impl ExtrinsicNoise {
    pub const ZERO: ExtrinsicNoise = ExtrinsicNoise {
        rho: [0.0; 3],
        phi: [0.0; 3],
    };

    /// The perturbed extrinsic: t = t̄ + ρ, R = exp(φ^) R̄ (eq. 1–2).
    pub fn apply(&self, nominal: &Pose) -> Pose {
        let r = exp(&Vector3::from(self.phi)) * nominal.rotation.to_rotation_matrix().into_inner();
        let t = nominal.translation.vector + Vector3::from(self.rho);
        Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_matrix(&r))
    }

    /// Component-wise sum (e.g. a sampled perturbation plus a manual offset).
    pub fn plus(&self, other: &ExtrinsicNoise) -> ExtrinsicNoise {
        ExtrinsicNoise {
            rho: std::array::from_fn(|i| self.rho[i] + other.rho[i]),
            phi: std::array::from_fn(|i| self.phi[i] + other.phi[i]),
        }
    }

    pub fn is_finite(&self) -> bool {
        self.rho.iter().chain(self.phi.iter()).all(|v| v.is_finite())
    }
}

/// How to draw perturbations: α scales the prior's extrinsic blocks; `seed` picks the stream.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Perturbation {
    pub alpha: f64,
    pub seed: u64,
    /// Bound each component within ±σ (the paper's injection). `false` draws plain Gaussians,
    /// which is what the analytic Ξ describes (used by the Monte Carlo checks).
    pub bounded: bool,
}

impl Default for Perturbation {
    fn default() -> Self {
        Self {
            alpha: 0.0,
            seed: 0,
            bounded: true,
        }
    }
}

/// Rejection sampling of the ±σ box gives up after this many tries and clamps (never seen:
/// the acceptance rate of three independent components is 0.683³ ≈ 0.32).
const MAX_TRIES: usize = 10_000;

impl Perturbation {
    pub fn new(alpha: f64, seed: u64) -> Result<Self, UncertaintyError> {
        check_alpha(alpha)?;
        Ok(Self {
            alpha,
            seed,
            bounded: true,
        })
    }

    /// The random stream of LiDAR `lidar_index` (1, 2, … for the auxiliaries): independent
    /// streams, so adding or removing one LiDAR never changes another's draw.
    pub fn rng(&self, lidar_index: u64) -> ChaCha8Rng {
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        rng.set_stream(lidar_index);
        rng
    }

    /// Draws (ρ, φ) for one LiDAR from Θ(α) of `prior` (the α = 1 prior).
    pub fn sample(&self, prior: &Prior, lidar_index: u64) -> Result<ExtrinsicNoise, UncertaintyError> {
        let scaled = prior.scaled(self.alpha)?;
        let mut rng = self.rng(lidar_index);
        Ok(ExtrinsicNoise {
            rho: draw(&mut rng, &scaled.p, self.bounded),
            phi: draw(&mut rng, &scaled.phi, self.bounded),
        })
    }
}

/// One draw from N(0, Σ) (optionally inside the ±σ box), using rng.
pub fn draw<R: Rng>(rng: &mut R, cov: &Matrix3<f64>, bounded: bool) -> [f64; 3] {
    let l = sqrt_psd(cov);
    let sigma = Vector3::new(cov[(0, 0)], cov[(1, 1)], cov[(2, 2)]).map(|v| v.max(0.0).sqrt());
    let mut x = Vector3::zeros();
    for _ in 0..MAX_TRIES {
        let z = Vector3::new(
            rng.sample::<f64, _>(StandardNormal),
            rng.sample::<f64, _>(StandardNormal),
            rng.sample::<f64, _>(StandardNormal),
        );
        x = l * z;
        if !bounded || (0..3).all(|i| x[i].abs() <= sigma[i]) {
            return [x.x, x.y, x.z];
        }
    }
    std::array::from_fn(|i| x[i].clamp(-sigma[i], sigma[i]))
}

/// A square root S with S Sᵀ = Σ for a symmetric PSD Σ (zero allowed, unlike Cholesky).
fn sqrt_psd(cov: &Matrix3<f64>) -> Matrix3<f64> {
    let off_diagonal = [
        cov[(0, 1)],
        cov[(0, 2)],
        cov[(1, 2)],
        cov[(1, 0)],
        cov[(2, 0)],
        cov[(2, 1)],
    ];
    if off_diagonal.iter().all(|v| *v == 0.0) {
        return Matrix3::from_diagonal(&cov.diagonal().map(|v| v.max(0.0).sqrt()));
    }
    let eig = cov.symmetric_eigen();
    eig.eigenvectors * Matrix3::from_diagonal(&eig.eigenvalues.map(|v| v.max(0.0).sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::rpy_to_matrix;

    fn stats(alpha: f64, n: u64) -> ([f64; 6], [f64; 6]) {
        let prior = Prior::paper();
        let mut max = [0.0f64; 6];
        let mut var = [0.0f64; 6];
        for seed in 0..n {
            let s = Perturbation::new(alpha, seed).unwrap().sample(&prior, 1).unwrap();
            for (k, v) in s.rho.iter().chain(s.phi.iter()).enumerate() {
                max[k] = max[k].max(v.abs());
                var[k] += v * v / n as f64;
            }
        }
        (max, var)
    }

    #[test]
    fn bounded_within_sigma_and_variance_scales_with_alpha() {
        let (max_a, var_a) = stats(0.02, 4000);
        let (max_b, var_b) = stats(0.1, 4000);
        let sig = |alpha: f64, k: usize| {
            if k < 3 {
                (alpha * 0.0025f64).sqrt()
            } else {
                (alpha * 0.01f64).sqrt()
            }
        };
        for k in 0..6 {
            assert!(
                max_a[k] <= sig(0.02, k) + 1e-15,
                "component {k} exceeds σ at α=0.02"
            );
            assert!(
                max_b[k] <= sig(0.1, k) + 1e-15,
                "component {k} exceeds σ at α=0.1"
            );
            // A N(0, σ²) truncated to ±σ has variance 0.2911 σ².
            let expect = 0.2911 * sig(0.1, k).powi(2);
            assert!(
                (var_b[k] / expect - 1.0).abs() < 0.08,
                "var {k}: {} vs {expect}",
                var_b[k]
            );
            let ratio = var_b[k] / var_a[k];
            assert!(
                (ratio / 5.0 - 1.0).abs() < 0.12,
                "variance ratio {ratio} for α 0.1/0.02"
            );
        }
    }

    #[test]
    fn same_seed_same_draw_and_streams_differ() {
        let prior = Prior::paper();
        let p = Perturbation::new(0.04, 7).unwrap();
        assert_eq!(p.sample(&prior, 1).unwrap(), p.sample(&prior, 1).unwrap());
        assert_ne!(p.sample(&prior, 1).unwrap(), p.sample(&prior, 2).unwrap());
        let zero = Perturbation::new(0.0, 7).unwrap().sample(&prior, 1).unwrap();
        assert_eq!(zero, ExtrinsicNoise::ZERO);
    }

    #[test]
    fn apply_perturbs_translation_and_rotation_on_the_left() {
        let nominal =
            crate::geometry::pose_from_rt(&rpy_to_matrix(0.1, 0.2, 0.3), &Vector3::new(1.0, 2.0, 3.0));
        let n = ExtrinsicNoise {
            rho: [0.01, -0.02, 0.03],
            phi: [0.0, 0.0, 0.05],
        };
        let p = n.apply(&nominal);
        assert!((p.translation.vector - Vector3::new(1.01, 1.98, 3.03)).norm() < 1e-12);
        let expect = exp(&Vector3::new(0.0, 0.0, 0.05)) * rpy_to_matrix(0.1, 0.2, 0.3);
        assert!(
            (p.rotation.to_rotation_matrix().into_inner() - expect)
                .abs()
                .max()
                < 1e-12
        );
    }
}
