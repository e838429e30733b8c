//! The uncertainty prior Θ = diag(P, Φ, Z) of the paper (§III-A, eq. 9), with α scaling only the
//! six extrinsic entries (P for translation, Φ for rotation); Z, the measurement noise, stays put.

use nalgebra::{Matrix3, SMatrix};
use serde::{Deserialize, Serialize};

use super::UncertaintyError;

/// The prior Θ = diag(P, Φ, Z) at α = 1. Use [`Prior::scaled`] for the α of an experiment.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Prior {
    /// Translation covariance P (m²).
    pub p: Matrix3<f64>,
    /// Rotation covariance Φ (rad²), in the tangent space of R = exp(φ^)R̄.
    pub phi: Matrix3<f64>,
    /// Measurement covariance Z (m²); not scaled by α.
    pub z: Matrix3<f64>,
}

impl Default for Prior {
    fn default() -> Self {
        Self::paper()
    }
}

impl Prior {
    /// Eq. 9: Θ = diag²{1/20 ×3, 1/10 ×3, 1/50 ×3}.
    pub fn paper() -> Self {
        Self {
            p: Matrix3::from_diagonal_element((1.0f64 / 20.0).powi(2)),
            phi: Matrix3::from_diagonal_element((1.0f64 / 10.0).powi(2)),
            z: Matrix3::from_diagonal_element((1.0f64 / 50.0).powi(2)),
        }
    }

    /// A user-given prior; each block must be finite, symmetric and positive semi-definite
    /// (P and Φ may be zero, as they are at α = 0).
    pub fn new(p: Matrix3<f64>, phi: Matrix3<f64>, z: Matrix3<f64>) -> Result<Self, UncertaintyError> {
        for (name, m) in [("P", &p), ("Phi", &phi), ("Z", &z)] {
            check_psd(name, m)?;
        }
        Ok(Self { p, phi, z })
    }

    /// A prior with diagonal blocks given as standard deviations (m, rad, m).
    pub fn from_std(p_std: [f64; 3], phi_std: [f64; 3], z_std: [f64; 3]) -> Result<Self, UncertaintyError> {
        let d = |s: [f64; 3]| {
            Matrix3::from_diagonal(&nalgebra::Vector3::new(s[0] * s[0], s[1] * s[1], s[2] * s[2]))
        };
        for (name, s) in [("P", p_std), ("Phi", phi_std), ("Z", z_std)] {
            if s.iter().any(|v| !v.is_finite() || *v < 0.0) {
                return Err(UncertaintyError::BadPrior {
                    block: name,
                    reason: format!("standard deviations must be finite and ≥ 0, got {s:?}"),
                });
            }
        }
        Self::new(d(p_std), d(phi_std), d(z_std))
    }

    /// Θ(α): P and Φ multiplied by α, Z unchanged. α must be finite and ≥ 0.
    pub fn scaled(&self, alpha: f64) -> Result<Self, UncertaintyError> {
        check_alpha(alpha)?;
        Ok(Self {
            p: self.p * alpha,
            phi: self.phi * alpha,
            z: self.z,
        })
    }

    /// The full 9×9 Θ = diag(P, Φ, Z).
    pub fn theta(&self) -> SMatrix<f64, 9, 9> {
        let mut t = SMatrix::<f64, 9, 9>::zeros();
        t.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.p);
        t.fixed_view_mut::<3, 3>(3, 3).copy_from(&self.phi);
        t.fixed_view_mut::<3, 3>(6, 6).copy_from(&self.z);
        t
    }
}

/// α must be a finite number ≥ 0.
pub fn check_alpha(alpha: f64) -> Result<(), UncertaintyError> {
    if !alpha.is_finite() || alpha < 0.0 {
        return Err(UncertaintyError::BadAlpha(alpha));
    }
    Ok(())
}

fn check_psd(name: &'static str, m: &Matrix3<f64>) -> Result<(), UncertaintyError> {
    if m.iter().any(|v| !v.is_finite()) {
        return Err(UncertaintyError::BadPrior {
            block: name,
            reason: "has a non-finite entry".into(),
        });
    }
    let asym = (m - m.transpose()).abs().max();
    let scale = m.abs().max().max(1e-300);
    if asym > 1e-9 * scale {
        return Err(UncertaintyError::BadPrior {
            block: name,
            reason: format!("is not symmetric (largest asymmetry {asym:e})"),
        });
    }
    let eig = m.symmetric_eigenvalues();
    let min = eig.min();
    if min < -1e-12 * scale {
        return Err(UncertaintyError::BadPrior {
            block: name,
            reason: format!("is not positive semi-definite (smallest eigenvalue {min:e})"),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_prior_values_and_alpha_scaling() {
        let t = Prior::paper().scaled(0.02).unwrap().theta();
        assert!((t[(0, 0)] - 0.02 * 0.0025).abs() < 1e-15);
        assert!((t[(4, 4)] - 0.02 * 0.01).abs() < 1e-15);
        assert!((t[(8, 8)] - 0.0004).abs() < 1e-15, "Z is not scaled by α");
        assert_eq!(t[(0, 1)], 0.0);
    }

    #[test]
    fn bad_alpha_and_bad_prior_are_errors() {
        assert!(Prior::paper().scaled(-0.1).is_err());
        assert!(Prior::paper().scaled(f64::NAN).is_err());
        assert!(Prior::paper().scaled(f64::INFINITY).is_err());
        let bad = Matrix3::new(1.0, 2.0, 0.0, 2.0, 1.0, 0.0, 0.0, 0.0, 1.0); // eigenvalue −1
        let e = Prior::new(bad, Matrix3::identity(), Matrix3::identity()).unwrap_err();
        assert!(e.to_string().contains("positive semi-definite"), "{e}");
        let asym = Matrix3::new(1.0, 0.5, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0);
        assert!(Prior::new(Matrix3::identity(), asym, Matrix3::identity()).is_err());
        assert!(Prior::from_std([0.1, -0.1, 0.1], [0.1; 3], [0.1; 3]).is_err());
        assert!(Prior::from_std([0.05; 3], [0.1; 3], [0.02; 3]).unwrap() == Prior::paper());
    }
}
