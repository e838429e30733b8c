//! Per-point covariance Ξ = H Θ Hᵀ (paper eq. 5–8) and its trace tr(Ξ).
//!
//! A point p of LiDAR i goes to the base frame as y = R p + t with R = exp(φ^)R̄, t = t̄ + ρ,
//! p = p̄ + ζ (eq. 1–4). To first order y ≈ h + H θ with θ = [ρ, φ, ζ]. Two linearisations:
//!
//! * [`Linearization::Separate`]: H = [I, −(R̄p)^, R̄], eq. 6 as written. This is the exact
//!   Jacobian of the way we inject noise (rotation perturbed on the left of R̄, translation added
//!   separately), so it is the default; `tests/core/monte_carlo.rs` confirms it within 3 %.
//! * [`Linearization::Se3Left`]: H = [I, −(R̄p + t̄)^, R̄], the whole transform perturbed on the
//!   left, T = exp(ξ^)T̄. Only this one reproduces the worked example matrix of §III-B.
//!
//! Since Θ is block-diagonal, Ξ = P + q^ Φ q^ᵀ + R̄ Z R̄ᵀ with q the lever arm above, and
//! tr(Ξ) = tr P + tr Z + |q|² tr Φ − qᵀ Φ q: no 3×9 matrix per point. [`trace_cloud`] and
//! [`covariance_cloud`] apply that closed form to structure-of-arrays clouds, in parallel.

use std::fmt;
use std::str::FromStr;

use nalgebra::{Matrix3, SMatrix, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::prior::Prior;
use crate::geometry::hat;

/// Which first-order model of y = R p + t the covariance uses (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Linearization {
    /// H = [I, −(R̄p)^, R̄]: matches t = t̄ + ρ, R = exp(φ^)R̄ (how we inject noise).
    #[default]
    Separate,
    /// H = [I, −(R̄p + t̄)^, R̄]: matches T = exp(ξ^)T̄; reproduces the paper's worked example.
    Se3Left,
}

impl Linearization {
    pub const ALL: [Linearization; 2] = [Linearization::Separate, Linearization::Se3Left];

    pub fn name(self) -> &'static str {
        match self {
            Linearization::Separate => "separate",
            Linearization::Se3Left => "se3-left",
        }
    }
}

impl fmt::Display for Linearization {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Linearization {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "separate" => Ok(Self::Separate),
            "se3-left" | "se3_left" => Ok(Self::Se3Left),
            other => Err(format!(
                "unknown linearization '{other}' (expected separate or se3-left)"
            )),
        }
    }
}

/// The lever arm q of the rotation block: H = [I, −q^, R̄].
#[inline]
fn lever(r: &Matrix3<f64>, t: &Vector3<f64>, p: &Vector3<f64>, lin: Linearization) -> Vector3<f64> {
    match lin {
        Linearization::Separate => r * p,
        Linearization::Se3Left => r * p + t,
    }
}

/// The 3×9 Jacobian H of eq. 6 for one point (reference form; the cloud paths never build it).
pub fn jacobian(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    p: &Vector3<f64>,
    lin: Linearization,
) -> SMatrix<f64, 3, 9> {
    let q = lever(r, t, p, lin);
    let mut h = SMatrix::<f64, 3, 9>::zeros();
    h.fixed_view_mut::<3, 3>(0, 0).copy_from(&Matrix3::identity());
    h.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-hat(&q)));
    h.fixed_view_mut::<3, 3>(0, 6).copy_from(r);
    h
}

/// Ξ = H Θ Hᵀ (eq. 8) for one point p (sensor frame) through the nominal extrinsic (R̄, t̄).
/// `prior` is Θ already scaled by α.
pub fn covariance(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    p: &Vector3<f64>,
    prior: &Prior,
    lin: Linearization,
) -> Matrix3<f64> {
    let q = lever(r, t, p, lin);
    let qh = hat(&q);
    prior.p + qh * prior.phi * qh.transpose() + r * prior.z * r.transpose()
}

/// tr(Ξ) for one point in f64, by the closed form tr P + tr Z + |q|² tr Φ − qᵀΦq.
pub fn trace(r: &Matrix3<f64>, t: &Vector3<f64>, p: &Vector3<f64>, prior: &Prior, lin: Linearization) -> f64 {
    let q = lever(r, t, p, lin);
    prior.p.trace() + prior.z.trace() + q.norm_squared() * prior.phi.trace() - q.dot(&(prior.phi * q))
}

/// The extrinsic part of Ξ alone (P and Φ terms), e.g. to report Ξ per unit α.
pub fn extrinsic_covariance(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    p: &Vector3<f64>,
    prior: &Prior,
    lin: Linearization,
) -> Matrix3<f64> {
    let q = lever(r, t, p, lin);
    let qh = hat(&q);
    prior.p + qh * prior.phi * qh.transpose()
}

/// Per-LiDAR constants of the closed form, computed once per cloud.
#[derive(Debug, Clone, Copy)]
pub struct TraceKernel {
    r: [[f32; 3]; 3],
    /// Added to the lever arm: t̄ for `Se3Left`, 0 for `Separate`.
    offset: [f32; 3],
    /// tr P + tr Z.
    base: f32,
    tr_phi: f32,
    /// Φ (symmetric): xx, yy, zz, xy, xz, yz.
    phi: [f32; 6],
    /// P + R̄ Z R̄ᵀ (symmetric, same order): the point-independent part of Ξ.
    c0: [f32; 6],
    /// C = Cov(ρ, φ) by rows (zero for the block-diagonal Θ of the paper), and its trace
    /// contribution tr(−(C q^ᵀ + q^ Cᵀ)) = −2 w·q with w = (C₂₁−C₁₂, C₀₂−C₂₀, C₁₀−C₀₁).
    cross: Option<([[f32; 3]; 3], [f32; 3])>,
}

impl TraceKernel {
    pub fn new(r: &Matrix3<f64>, t: &Vector3<f64>, prior: &Prior, lin: Linearization) -> Self {
        let offset = match lin {
            Linearization::Separate => [0.0; 3],
            Linearization::Se3Left => [t.x as f32, t.y as f32, t.z as f32],
        };
        let sym6 = |m: &Matrix3<f64>| {
            [m[(0, 0)], m[(1, 1)], m[(2, 2)], m[(0, 1)], m[(0, 2)], m[(1, 2)]].map(|v| v as f32)
        };
        let c0 = prior.p + r * prior.z * r.transpose();
        let mut rr = [[0.0f32; 3]; 3];
        for (i, row) in rr.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = r[(i, j)] as f32;
            }
        }
        Self {
            r: rr,
            offset,
            base: (prior.p.trace() + prior.z.trace()) as f32,
            tr_phi: prior.phi.trace() as f32,
            phi: sym6(&prior.phi),
            c0: sym6(&c0),
            cross: None,
        }
    }

    /// The kernel for a full 6×6 extrinsic covariance Σ of (ρ, φ) (e.g. what ICP leaves, see
    /// `crate::calib`), cross terms included, plus the measurement covariance `z`:
    /// Ξ = Σ_ρρ + q^ Σ_φφ q^ᵀ − Σ_ρφ q^ᵀ − q^ Σ_φρ + R̄ Z R̄ᵀ.
    pub fn with_covariance(
        r: &Matrix3<f64>,
        t: &Vector3<f64>,
        sigma: &nalgebra::Matrix6<f64>,
        z: &Matrix3<f64>,
        lin: Linearization,
    ) -> Self {
        let sym = sigma.symmetric_part();
        let prior = Prior {
            p: sym.fixed_view::<3, 3>(0, 0).into_owned(),
            phi: sym.fixed_view::<3, 3>(3, 3).into_owned(),
            z: *z,
        };
        let c = sym.fixed_view::<3, 3>(0, 3).into_owned();
        let mut k = Self::new(r, t, &prior, lin);
        let rows: [[f32; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| c[(i, j)] as f32));
        let w = [
            (c[(2, 1)] - c[(1, 2)]) as f32,
            (c[(0, 2)] - c[(2, 0)]) as f32,
            (c[(1, 0)] - c[(0, 1)]) as f32,
        ];
        if c.iter().any(|v| *v != 0.0) {
            k.cross = Some((rows, w));
        }
        k
    }

    #[inline(always)]
    fn q(&self, x: f32, y: f32, z: f32) -> [f32; 3] {
        let r = &self.r;
        [
            r[0][0] * x + r[0][1] * y + r[0][2] * z + self.offset[0],
            r[1][0] * x + r[1][1] * y + r[1][2] * z + self.offset[1],
            r[2][0] * x + r[2][1] * y + r[2][2] * z + self.offset[2],
        ]
    }

    /// tr(Ξ) = tr P + tr Z + |q|² tr Φ − qᵀ Φ q.
    #[inline(always)]
    pub fn trace(&self, x: f32, y: f32, z: f32) -> f32 {
        let [a, b, c] = self.q(x, y, z);
        let f = &self.phi;
        let qphiq =
            f[0] * a * a + f[1] * b * b + f[2] * c * c + 2.0 * (f[3] * a * b + f[4] * a * c + f[5] * b * c);
        let cross = match &self.cross {
            None => 0.0,
            Some((_, w)) => -2.0 * (w[0] * a + w[1] * b + w[2] * c),
        };
        self.base + (a * a + b * b + c * c) * self.tr_phi - qphiq + cross
    }

    /// The six unique entries of Ξ (xx, yy, zz, xy, xz, yz).
    #[inline(always)]
    pub fn covariance6(&self, x: f32, y: f32, z: f32) -> [f32; 6] {
        let [a, b, c] = self.q(x, y, z);
        let f = &self.phi;
        // q^ = [[0,-c,b],[c,0,-a],[-b,a,0]]; M = q^ Φ q^ᵀ, entry by entry.
        // Row vectors of q^: r0 = (0,-c,b), r1 = (c,0,-a), r2 = (-b,a,0); M_ij = r_i Φ r_jᵀ.
        let rows = [[0.0, -c, b], [c, 0.0, -a], [-b, a, 0.0]];
        let phi = [[f[0], f[3], f[4]], [f[3], f[1], f[5]], [f[4], f[5], f[2]]];
        let mut pr = [[0.0f32; 3]; 3]; // r_i Φ
        for i in 0..3 {
            for j in 0..3 {
                pr[i][j] = rows[i][0] * phi[0][j] + rows[i][1] * phi[1][j] + rows[i][2] * phi[2][j];
            }
        }
        let dot = |u: &[f32; 3], v: &[f32; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
        let m = [
            dot(&pr[0], &rows[0]),
            dot(&pr[1], &rows[1]),
            dot(&pr[2], &rows[2]),
            dot(&pr[0], &rows[1]),
            dot(&pr[0], &rows[2]),
            dot(&pr[1], &rows[2]),
        ];
        let mut out = self.c0;
        for k in 0..6 {
            out[k] += m[k];
        }
        if let Some((cr, _)) = &self.cross {
            // −(C q^ᵀ + q^ Cᵀ): entry (i, j) is −(C_i·(q^)_j + C_j·(q^)_i).
            let e = |i: usize, j: usize| -(dot(&cr[i], &rows[j]) + dot(&cr[j], &rows[i]));
            let add = [e(0, 0), e(1, 1), e(2, 2), e(0, 1), e(0, 2), e(1, 2)];
            for k in 0..6 {
                out[k] += add[k];
            }
        }
        out
    }
}

/// Below this many points the cloud paths run on one thread (rayon's overhead dominates).
pub const PARALLEL_THRESHOLD: usize = 16_384;
const CHUNK: usize = 4096;

/// Applies `f(x, y, z)` to every point of a structure-of-arrays cloud, writing `out[i]`; serial
/// below [`PARALLEL_THRESHOLD`], rayon chunks above. Works on the common length of the slices.
fn map_points<T: Send>(
    x: &[f32],
    y: &[f32],
    z: &[f32],
    out: &mut [T],
    f: impl Fn(f32, f32, f32) -> T + Sync,
) {
    let n = out.len().min(x.len()).min(y.len()).min(z.len());
    let (x, y, z, out) = (&x[..n], &y[..n], &z[..n], &mut out[..n]);
    let run = |start: usize, o: &mut [T]| {
        let (xs, ys, zs) = (&x[start..], &y[start..], &z[start..]);
        for (i, v) in o.iter_mut().enumerate() {
            *v = f(xs[i], ys[i], zs[i]);
        }
    };
    if n < PARALLEL_THRESHOLD {
        run(0, out);
    } else {
        out.par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(c, o)| run(c * CHUNK, o));
    }
}

/// tr(Ξ) for every point of a structure-of-arrays cloud (sensor-frame x, y, z) through one
/// extrinsic, written into `out`. Works on the common length of the four slices.
pub fn trace_cloud(kernel: &TraceKernel, x: &[f32], y: &[f32], z: &[f32], out: &mut [f32]) {
    map_points(x, y, z, out, |a, b, c| kernel.trace(a, b, c));
}

/// The six unique entries of Ξ for every point (xx, yy, zz, xy, xz, yz), into `out`.
pub fn covariance_cloud(kernel: &TraceKernel, x: &[f32], y: &[f32], z: &[f32], out: &mut [[f32; 6]]) {
    map_points(x, y, z, out, |a, b, c| kernel.covariance6(a, b, c));
}

/// The paper's worked example of §III-B: rpy (10°, 10°, 10°), t = (1, 1, 1) m, p = (10, 10, 10) m.
pub fn worked_example() -> (Matrix3<f64>, Vector3<f64>, Vector3<f64>) {
    let d = 10f64.to_radians();
    (
        crate::geometry::rpy_to_matrix(d, d, d),
        Vector3::new(1.0, 1.0, 1.0),
        Vector3::new(10.0, 10.0, 10.0),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn paper_matrix() -> Matrix3<f64> {
        Matrix3::new(2.36, -1.24, -1.20, -1.24, 2.41, -1.18, -1.20, -1.18, 2.49)
    }

    #[test]
    fn se3_left_reproduces_the_worked_example() {
        let (r, t, p) = worked_example();
        let per_alpha = extrinsic_covariance(&r, &t, &p, &Prior::paper(), Linearization::Se3Left);
        let err = (per_alpha - paper_matrix()).abs().max();
        assert!(
            err <= 0.01,
            "se3-left: {per_alpha} differs from the paper by {err}"
        );
    }

    #[test]
    fn separate_gives_the_smaller_matrix() {
        let (r, t, p) = worked_example();
        let per_alpha = extrinsic_covariance(&r, &t, &p, &Prior::paper(), Linearization::Separate);
        assert!((per_alpha[(0, 0)] - 1.95).abs() < 0.01, "{per_alpha}");
        assert!((per_alpha[(0, 1)] - -1.03).abs() < 0.01, "{per_alpha}");
        assert!((per_alpha[(0, 2)] - -0.99).abs() < 0.01, "{per_alpha}");
        assert!((per_alpha - paper_matrix()).abs().max() > 0.2);
    }

    #[test]
    fn full_covariance_kernel_equals_h_sigma_ht() {
        let (r, t, _) = worked_example();
        // A positive-definite 6×6 with cross terms between ρ and φ.
        let a = nalgebra::Matrix6::from_fn(|i, j| {
            ((i * 7 + j * 3) % 5) as f64 * 0.01 + if i == j { 0.05 } else { 0.0 }
        });
        let sigma = a * a.transpose();
        let z = Matrix3::from_diagonal_element(4e-4);
        for lin in Linearization::ALL {
            let k = TraceKernel::with_covariance(&r, &t, &sigma, &z, lin);
            for p in [Vector3::new(10.0, 10.0, 10.0), Vector3::new(-3.0, 25.0, -1.5)] {
                let q = lever(&r, &t, &p, lin);
                let mut h = nalgebra::SMatrix::<f64, 3, 6>::zeros();
                h.fixed_view_mut::<3, 3>(0, 0).copy_from(&Matrix3::identity());
                h.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-hat(&q)));
                let xi = h * sigma * h.transpose() + r * z * r.transpose();
                let c6 = k.covariance6(p.x as f32, p.y as f32, p.z as f32);
                let want = [
                    xi[(0, 0)],
                    xi[(1, 1)],
                    xi[(2, 2)],
                    xi[(0, 1)],
                    xi[(0, 2)],
                    xi[(1, 2)],
                ];
                for (got, want) in c6.iter().zip(want) {
                    assert!(
                        (*got as f64 - want).abs() <= 1e-4 * want.abs().max(1.0),
                        "{lin}: {c6:?} vs {want:?}"
                    );
                }
                let tr = k.trace(p.x as f32, p.y as f32, p.z as f32) as f64;
                assert!(
                    (tr - xi.trace()).abs() <= 1e-4 * xi.trace(),
                    "{lin}: {tr} vs {}",
                    xi.trace()
                );
            }
        }
    }

    #[test]
    fn closed_form_equals_h_theta_ht() {
        let (r, t, _) = worked_example();
        let prior = Prior::from_std([0.03, 0.05, 0.07], [0.1, 0.2, 0.05], [0.02, 0.03, 0.01]).unwrap();
        for lin in Linearization::ALL {
            for p in [
                Vector3::new(10.0, -3.0, 2.0),
                Vector3::new(-40.0, 25.0, -1.5),
                Vector3::zeros(),
            ] {
                let h = jacobian(&r, &t, &p, lin);
                let full = h * prior.theta() * h.transpose();
                let fast = covariance(&r, &t, &p, &prior, lin);
                assert!((full - fast).abs().max() < 1e-12);
                let k = TraceKernel::new(&r, &t, &prior, lin);
                assert!((trace(&r, &t, &p, &prior, lin) - full.trace()).abs() < 1e-12 * full.trace());
                let tr = k.trace(p.x as f32, p.y as f32, p.z as f32) as f64;
                assert!(
                    (tr - full.trace()).abs() < 1e-5 * full.trace().max(1.0),
                    "{tr} vs {}",
                    full.trace()
                );
                let c6 = k.covariance6(p.x as f32, p.y as f32, p.z as f32);
                let idx = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)];
                for (k, (i, j)) in idx.iter().enumerate() {
                    assert!((c6[k] as f64 - full[(*i, *j)]).abs() < 1e-5 * full.abs().max().max(1.0));
                }
            }
        }
    }

    #[test]
    fn cloud_paths_match_single_point_and_split_work() {
        let (r, t, _) = worked_example();
        let k = TraceKernel::new(
            &r,
            &t,
            &Prior::paper().scaled(0.04).unwrap(),
            Linearization::Separate,
        );
        let n = PARALLEL_THRESHOLD * 2 + 17; // exercises the parallel path and a ragged chunk
        let x: Vec<f32> = (0..n).map(|i| (i % 97) as f32 - 48.0).collect();
        let y: Vec<f32> = (0..n).map(|i| (i % 31) as f32 * 0.5).collect();
        let z: Vec<f32> = (0..n).map(|i| (i % 7) as f32 - 3.0).collect();
        let mut tr = vec![0.0; n];
        trace_cloud(&k, &x, &y, &z, &mut tr);
        let mut c6 = vec![[0.0; 6]; n];
        covariance_cloud(&k, &x, &y, &z, &mut c6);
        for i in [0, 1, PARALLEL_THRESHOLD, n - 1] {
            assert_eq!(tr[i], k.trace(x[i], y[i], z[i]));
            let sum = c6[i][0] + c6[i][1] + c6[i][2];
            assert!((sum - tr[i]).abs() < 1e-4 * tr[i]);
        }
    }

    #[test]
    fn linearization_parses() {
        assert_eq!(
            "se3-left".parse::<Linearization>().unwrap(),
            Linearization::Se3Left
        );
        assert_eq!(
            "separate".parse::<Linearization>().unwrap(),
            Linearization::Separate
        );
        assert!("left".parse::<Linearization>().is_err());
    }
}
