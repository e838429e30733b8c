//! Point-to-plane ICP with degeneracy-aware Gauss-Newton steps and the estimate's covariance (see
//! the module docs of [`crate::calib`]).
//!
//! Every sum over points runs in fixed chunks whose partial sums are added in chunk order, so the
//! result is bit-identical whatever the number of threads.

use std::num::NonZero;
use std::time::Instant;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix3, Matrix6, SymmetricEigen, Vector3, Vector6};
use rayon::prelude::*;

use super::{CalibError, Degenerate, IcpConfig, DIRECTION_NAMES};
use crate::geometry::{exp, pose_from_rt, Pose};

/// Points per chunk of every parallel sum (fixed, so the summation order is too).
const CHUNK: usize = 1024;
/// Fewer points than this is not a cloud ICP can work with.
const MIN_POINTS: usize = 30;

/// Voxel-grid downsampling: the centroid of the points of each cubic voxel of side `voxel`, in
/// voxel order. Points that are not finite or farther than `max_range` from the origin (the
/// sensor) are left out.
pub fn voxel_downsample(x: &[f32], y: &[f32], z: &[f32], voxel: f32, max_range: f32) -> Vec<[f32; 3]> {
    const OFF: i64 = 1 << 20;
    let n = x.len().min(y.len()).min(z.len());
    let inv = 1.0 / voxel as f64;
    let r2 = (max_range as f64).powi(2);
    let mut keyed: Vec<(u64, u32)> = (0..n)
        .into_par_iter()
        .with_min_len(4096)
        .filter_map(|i| {
            let p = [x[i] as f64, y[i] as f64, z[i] as f64];
            if !p.iter().all(|v| v.is_finite()) || p[0] * p[0] + p[1] * p[1] + p[2] * p[2] > r2 {
                return None;
            }
            let k = p.map(|v| ((v * inv).floor() as i64 + OFF).clamp(0, 2 * OFF - 1) as u64);
            Some(((k[0] << 42) | (k[1] << 21) | k[2], i as u32))
        })
        .collect();
    // Distinct (key, index) pairs: the sorted order, and so the output, is unique.
    keyed.par_sort_unstable();
    let mut out = Vec::new();
    let mut i = 0;
    while i < keyed.len() {
        let key = keyed[i].0;
        let mut sum = [0.0f64; 3];
        let mut count = 0usize;
        while i < keyed.len() && keyed[i].0 == key {
            let j = keyed[i].1 as usize;
            sum[0] += x[j] as f64;
            sum[1] += y[j] as f64;
            sum[2] += z[j] as f64;
            count += 1;
            i += 1;
        }
        out.push(sum.map(|s| (s / count as f64) as f32));
    }
    out
}

/// The cloud ICP aligns to: points, a kd-tree over them and a normal per point (NaN where the
/// neighbourhood is not planar).
pub struct Target {
    pub points: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    tree: ImmutableKdTree<f32, 3>,
}

impl std::fmt::Debug for Target {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Target")
            .field("points", &self.points.len())
            .finish()
    }
}

impl Target {
    /// Builds the kd-tree and estimates the normals (PCA of the `normal_k` nearest neighbours).
    pub fn new(points: Vec<[f32; 3]>, cfg: &IcpConfig) -> Result<Self, CalibError> {
        check_cloud("target", &points)?;
        let tree: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice(&points);
        let k = NonZero::new(cfg.normal_k.min(points.len())).unwrap_or(NonZero::<usize>::MIN);
        let normals = points
            .par_iter()
            .with_min_len(512)
            .map(|p| {
                let nn = tree.nearest_n::<SquaredEuclidean>(p, k);
                let neighbours: Vec<[f32; 3]> = nn.iter().map(|n| points[n.item as usize]).collect();
                plane_normal(&neighbours, cfg.max_curvature, cfg.min_spread).unwrap_or([f32::NAN; 3])
            })
            .collect();
        Ok(Self {
            points,
            normals,
            tree,
        })
    }

    /// The nearest target point to `p`: its index and squared distance.
    pub fn nearest(&self, p: &[f32; 3]) -> (usize, f32) {
        let n = self.tree.nearest_one::<SquaredEuclidean>(p);
        (n.item as usize, n.distance)
    }

    /// Points with a normal.
    pub fn planar_points(&self) -> usize {
        self.normals.iter().filter(|n| n[0].is_finite()).count()
    }
}

fn check_cloud(cloud: &'static str, points: &[[f32; 3]]) -> Result<(), CalibError> {
    if points.len() < MIN_POINTS {
        return Err(CalibError::BadCloud {
            cloud,
            what: format!(
                "{} points after downsampling, ICP needs at least {MIN_POINTS}",
                points.len()
            ),
        });
    }
    if let Some(i) = points.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
        return Err(CalibError::BadCloud {
            cloud,
            what: format!("point {i} is not finite: {:?}", points[i]),
        });
    }
    Ok(())
}

/// The unit normal of the least-squares plane through `pts`, if they are planar enough: the
/// surface variation λ₀/(λ₀+λ₁+λ₂) at most `max_curvature`, and a plane rather than a line,
/// λ₁ ≥ `min_spread`·λ₂ (a single scan ring far away is a line, whose normal is any direction
/// across it).
fn plane_normal(pts: &[[f32; 3]], max_curvature: f32, min_spread: f32) -> Option<[f32; 3]> {
    if pts.len() < 3 {
        return None;
    }
    let n = pts.len() as f64;
    let mut mean = [0.0f64; 3];
    for p in pts {
        for k in 0..3 {
            mean[k] += p[k] as f64;
        }
    }
    let mean = mean.map(|m| m / n);
    let mut c = [[0.0f64; 3]; 3];
    for p in pts {
        let d = [
            p[0] as f64 - mean[0],
            p[1] as f64 - mean[1],
            p[2] as f64 - mean[2],
        ];
        for i in 0..3 {
            for j in i..3 {
                c[i][j] += d[i] * d[j];
            }
        }
    }
    c[1][0] = c[0][1];
    c[2][0] = c[0][2];
    c[2][1] = c[1][2];
    // nalgebra's iterative solver (a closed-form solver was no faster where it matters: the
    // time goes into the neighbour queries).
    let eig = SymmetricEigen::new(Matrix3::from_fn(|i, j| c[i][j]));
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let [l0, l1, l2] = order.map(|i| eig.eigenvalues[i]);
    let total = l0 + l1 + l2;
    if !(total.is_finite() && total > 0.0)
        || l0.max(0.0) / total > max_curvature as f64
        || l1 < min_spread as f64 * l2
    {
        return None;
    }
    let v = eig.eigenvectors.column(order[0]);
    let len = v.norm();
    if !(len.is_finite() && len > 0.0) {
        return None;
    }
    Some([(v[0] / len) as f32, (v[1] / len) as f32, (v[2] / len) as f32])
}

/// Sums of one pass over the correspondences.
#[derive(Debug, Clone, Copy, Default)]
struct Normal {
    /// JᵀWJ, upper triangle row by row.
    ata: [f64; 21],
    /// JᵀWr.
    atb: [f64; 6],
    /// Σ w r², Σ r², Σ w, Σ |R p|².
    wrr: f64,
    rr: f64,
    w: f64,
    lever2: f64,
    count: usize,
}

impl Normal {
    fn add(&mut self, o: &Normal) {
        for (a, b) in self.ata.iter_mut().zip(&o.ata) {
            *a += b;
        }
        for (a, b) in self.atb.iter_mut().zip(&o.atb) {
            *a += b;
        }
        self.wrr += o.wrr;
        self.rr += o.rr;
        self.w += o.w;
        self.lever2 += o.lever2;
        self.count += o.count;
    }

    fn matrix(&self) -> Matrix6<f64> {
        let mut m = Matrix6::zeros();
        let mut k = 0;
        for i in 0..6 {
            for j in i..6 {
                m[(i, j)] = self.ata[k];
                m[(j, i)] = self.ata[k];
                k += 1;
            }
        }
        m
    }
}

/// One pass: every source point through (R, t), its nearest target point within `max_dist`, the
/// Huber-weighted point-to-plane residual and its Jacobian [nᵀ, (R p × n)ᵀ] in (ρ, φ).
fn normal_equations(
    source: &[[f32; 3]],
    target: &Target,
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    max_dist: f64,
    huber: f64,
) -> Normal {
    let m: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| r[(i, j)]));
    let d2 = max_dist * max_dist;
    let partial: Vec<Normal> = source
        .par_chunks(CHUNK)
        .map(|chunk| {
            let mut acc = Normal::default();
            for p in chunk {
                let (px, py, pz) = (p[0] as f64, p[1] as f64, p[2] as f64);
                let a = [
                    m[0][0] * px + m[0][1] * py + m[0][2] * pz,
                    m[1][0] * px + m[1][1] * py + m[1][2] * pz,
                    m[2][0] * px + m[2][1] * py + m[2][2] * pz,
                ];
                let y = [a[0] + t.x, a[1] + t.y, a[2] + t.z];
                let nn =
                    target
                        .tree
                        .nearest_one::<SquaredEuclidean>(&[y[0] as f32, y[1] as f32, y[2] as f32]);
                let idx = nn.item as usize;
                let q = target.points[idx];
                let dq = [y[0] - q[0] as f64, y[1] - q[1] as f64, y[2] - q[2] as f64];
                if dq[0] * dq[0] + dq[1] * dq[1] + dq[2] * dq[2] > d2 {
                    continue;
                }
                let nv = target.normals[idx];
                if !nv[0].is_finite() {
                    continue;
                }
                let n = [nv[0] as f64, nv[1] as f64, nv[2] as f64];
                let res = n[0] * dq[0] + n[1] * dq[1] + n[2] * dq[2];
                let w = if res.abs() <= huber {
                    1.0
                } else {
                    huber / res.abs()
                };
                let j = [
                    n[0],
                    n[1],
                    n[2],
                    a[1] * n[2] - a[2] * n[1],
                    a[2] * n[0] - a[0] * n[2],
                    a[0] * n[1] - a[1] * n[0],
                ];
                let mut k = 0;
                for i in 0..6 {
                    let wj = w * j[i];
                    for jj in &j[i..] {
                        acc.ata[k] += wj * jj;
                        k += 1;
                    }
                    acc.atb[i] += wj * res;
                }
                acc.wrr += w * res * res;
                acc.rr += res * res;
                acc.w += w;
                acc.lever2 += a[0] * a[0] + a[1] * a[1] + a[2] * a[2];
                acc.count += 1;
            }
            acc
        })
        .collect();
    let mut total = Normal::default();
    for p in &partial {
        total.add(p);
    }
    total
}

/// The scaled normal matrix's eigen-decomposition: rotations multiplied by the RMS lever arm L so
/// both blocks are in metres and their eigenvalues comparable.
struct Spectrum {
    /// diag(1, 1, 1, 1/L, 1/L, 1/L): x = S x̃.
    s: Vector6<f64>,
    values: Vector6<f64>,
    vectors: Matrix6<f64>,
    /// Which eigenvalues are degenerate.
    degenerate: [bool; 6],
    /// Eigenvalues per unit weight.
    per_weight: Vector6<f64>,
}

fn spectrum(eq: &Normal, cfg: &IcpConfig) -> Spectrum {
    let lever = (eq.lever2 / eq.count.max(1) as f64).sqrt().max(1.0);
    let s = Vector6::new(1.0, 1.0, 1.0, 1.0 / lever, 1.0 / lever, 1.0 / lever);
    let a = eq.matrix();
    let scaled = Matrix6::from_fn(|i, j| a[(i, j)] * s[i] * s[j]);
    let eig = SymmetricEigen::new(scaled);
    let per_weight = eig.eigenvalues / eq.w.max(f64::MIN_POSITIVE);
    let degenerate = std::array::from_fn(|i| per_weight[i].is_nan() || per_weight[i] < cfg.degeneracy);
    Spectrum {
        s,
        values: eig.eigenvalues,
        vectors: eig.eigenvectors,
        degenerate,
        per_weight,
    }
}

/// The Gauss-Newton step −A⁺b restricted to the constrained eigen-directions.
fn step(eq: &Normal, sp: &Spectrum) -> Vector6<f64> {
    let b = Vector6::from_fn(|i, _| eq.atb[i] * sp.s[i]);
    let mut dx = Vector6::zeros();
    for i in 0..6 {
        if sp.degenerate[i] {
            continue;
        }
        let v = sp.vectors.column(i);
        dx -= v * (v.dot(&b) / sp.values[i]);
    }
    dx.component_mul(&sp.s)
}

/// What one alignment gives.
#[derive(Debug, Clone, PartialEq)]
pub struct IcpOutcome {
    pub extrinsic: Pose,
    /// (ρ, φ) covariance of `extrinsic`, see [`super::LidarCalibration::covariance`].
    pub covariance: Matrix6<f64>,
    pub converged: bool,
    pub iterations: usize,
    pub fitness: f64,
    pub rmse: f64,
    pub correspondences: usize,
    pub eigenvalues: [f64; 6],
    pub degenerate: Vec<Degenerate>,
    pub ms: f64,
}

/// Aligns `source` (points in the auxiliary LiDAR's own frame) to `target` (base frame), starting
/// from the extrinsic `start`. `prior` is the (ρ, φ) covariance of the start (Θ(α)): degenerate
/// directions keep it in the returned covariance, since they keep the start's value.
pub fn align(
    source: &[[f32; 3]],
    start: &Pose,
    target: &Target,
    prior: &Matrix6<f64>,
    cfg: &IcpConfig,
) -> Result<IcpOutcome, CalibError> {
    cfg.validate()?;
    check_cloud("source", source)?;
    if !prior.iter().all(|v| v.is_finite()) {
        return Err(CalibError::BadParameter(
            "the prior covariance is not finite".into(),
        ));
    }
    let clock = Instant::now();
    let mut r = start.rotation.to_rotation_matrix().into_inner();
    let mut t = start.translation.vector;
    let mut dist = cfg.max_distance;
    let mut converged = false;
    let mut iterations = 0;
    while iterations < cfg.max_iterations {
        let eq = normal_equations(source, target, &r, &t, dist, cfg.huber);
        if eq.count < cfg.min_correspondences {
            break;
        }
        iterations += 1;
        let sp = spectrum(&eq, cfg);
        let dx = step(&eq, &sp);
        if !dx.iter().all(|v| v.is_finite()) {
            break;
        }
        let (dr, dphi) = (
            Vector3::new(dx[0], dx[1], dx[2]),
            Vector3::new(dx[3], dx[4], dx[5]),
        );
        r = exp(&dphi) * r;
        t += dr;
        let at_final = dist <= cfg.min_distance;
        if at_final && dr.norm() < cfg.tolerance_translation && dphi.norm() < cfg.tolerance_rotation {
            converged = true;
            break;
        }
        dist = (dist * cfg.shrink).max(cfg.min_distance);
    }
    // The final pass: fitness, residuals, the spectrum and the covariance at the estimate.
    let eq = normal_equations(source, target, &r, &t, cfg.min_distance, cfg.huber);
    let extrinsic = pose_from_rt(&r, &t);
    if eq.count < cfg.min_correspondences.max(7) {
        return Ok(IcpOutcome {
            extrinsic,
            covariance: *prior,
            converged: false,
            iterations,
            fitness: eq.count as f64 / source.len() as f64,
            rmse: if eq.count > 0 {
                (eq.rr / eq.count as f64).sqrt()
            } else {
                f64::NAN
            },
            correspondences: eq.count,
            eigenvalues: [0.0; 6],
            degenerate: Vec::new(),
            ms: clock.elapsed().as_secs_f64() * 1e3,
        });
    }
    let sp = spectrum(&eq, cfg);
    let sigma2 = cfg.covariance_scale * eq.wrr / (eq.w - 6.0).max(1.0);
    // Scaled prior S⁻¹ Θ S⁻¹ for the degenerate directions.
    let prior_scaled = Matrix6::from_fn(|i, j| prior[(i, j)] / (sp.s[i] * sp.s[j]));
    // Constrained directions: σ²/λ along each eigenvector. Degenerate ones keep their start value,
    // so the prior restricted to their subspace (basis-free: P_d Θ̃ P_d).
    let mut cov_scaled = Matrix6::zeros();
    let mut proj = Matrix6::zeros();
    let mut degenerate = Vec::new();
    for i in 0..6 {
        let v = sp.vectors.column(i).into_owned();
        if sp.degenerate[i] {
            let axis = v.iamax();
            degenerate.push(Degenerate {
                axis: DIRECTION_NAMES[axis].to_string(),
                eigenvalue: sp.per_weight[i],
                vector: std::array::from_fn(|k| v[k]),
            });
            proj += v * v.transpose();
        } else {
            cov_scaled += v * v.transpose() * (sigma2 / sp.values[i]);
        }
    }
    cov_scaled += proj * prior_scaled * proj;
    let covariance = Matrix6::from_fn(|i, j| cov_scaled[(i, j)] * sp.s[i] * sp.s[j]);
    let mut eigenvalues: [f64; 6] = std::array::from_fn(|i| sp.per_weight[i]);
    eigenvalues.sort_by(f64::total_cmp);
    degenerate.sort_by(|a, b| a.eigenvalue.total_cmp(&b.eigenvalue));
    Ok(IcpOutcome {
        extrinsic,
        covariance,
        converged,
        iterations,
        fitness: eq.count as f64 / source.len() as f64,
        rmse: (eq.rr / eq.count as f64).sqrt(),
        correspondences: eq.count,
        eigenvalues,
        degenerate,
        ms: clock.elapsed().as_secs_f64() * 1e3,
    })
}

#[cfg(test)]
mod tests;
