//! How well an auxiliary LiDAR's points lie on the primary LiDAR's surfaces, and whether tr(Ξ)
//! predicts how far a perturbation moves them off those surfaces: the two checks of online
//! calibration on a real rig, where no extrinsic is known to be true (docs/av2.md).
//!
//! How it works: the primary's points (base frame) are voxel-downsampled and get a normal each
//! from their nearest neighbours ([`Target`], the ICP target). An auxiliary point, moved into the
//! base frame by an extrinsic, is matched to its nearest target point with a normal within
//! `max_distance`; its residual is the signed distance to that point's plane, nᵀ(p − q).
//! - [`residual_table`]: residuals per surface kind (ground-like: |n_z| > 0.9, else walls and
//!   objects) and range, at any extrinsic; the same source points at every extrinsic.
//! - [`xi_check`]: for draws of the perturbation at α (unbounded Gaussians, which is what the
//!   analytic Ξ describes), each point's change of residual Δd = d_α − d_0 against its predicted
//!   standard deviation √(nᵀ Ξ_ext n), Ξ_ext the point's Ξ from the extrinsic alone (Θ_z left
//!   out: the same point's measurement noise is in d_α and d_0 alike). If Ξ is right, z = Δd/σ is
//!   standard normal: median z² 0.455 (χ²₁), 68.3 % within 1σ, 95.4 % within 2σ.

use serde::Serialize;

use crate::calib::icp::{voxel_downsample, Target};
use crate::calib::{CalibError, IcpConfig};
use crate::dataset::{Frame, LidarChannel};
use crate::geometry::Pose;
use crate::pipeline::{fuse, fused_covariance, FuseParams, PipelineError};
use crate::uncertainty::{Perturbation, Prior, UncertaintyError};

/// What the checks look at.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct AlignConfig {
    /// Voxel side of the primary's surfaces (m).
    pub target_voxel: f32,
    /// Points farther from their sensor are left out (m).
    pub max_range: f32,
    /// A point farther than this from the nearest surface point is not on that surface (m).
    pub max_distance: f32,
    /// Every n-th auxiliary point is checked (the checks are statistics; 1: all).
    pub stride: usize,
}

impl Default for AlignConfig {
    fn default() -> Self {
        Self {
            target_voxel: 0.1,
            max_range: 60.0,
            max_distance: 0.3,
            stride: 4,
        }
    }
}

/// Why a check could not run.
#[derive(Debug, thiserror::Error)]
pub enum AlignError {
    #[error(transparent)]
    Calib(#[from] CalibError),
    #[error(transparent)]
    Pipeline(#[from] PipelineError),
    #[error(transparent)]
    Uncertainty(#[from] UncertaintyError),
    #[error("the frame has no {0} LiDAR")]
    NoLidar(LidarChannel),
}

/// The primary LiDAR's surfaces in the base frame.
pub struct Surfaces {
    target: Target,
    cfg: AlignConfig,
}

impl Surfaces {
    pub fn new(frame: &Frame, cfg: AlignConfig) -> Result<Self, AlignError> {
        let p = &frame.primary.points;
        let points = voxel_downsample(&p.x, &p.y, &p.z, cfg.target_voxel, cfg.max_range);
        let icp = IcpConfig::default();
        Ok(Self {
            target: Target::new(points, &icp)?,
            cfg,
        })
    }

    /// The signed distance of `p` (base frame) to the nearest surface point's plane and that
    /// plane's normal; `None` off every surface (too far, or no normal there).
    pub fn residual(&self, p: [f32; 3]) -> Option<(f32, [f32; 3])> {
        let (i, d2) = self.target.nearest(&p);
        if d2 > self.cfg.max_distance * self.cfg.max_distance {
            return None;
        }
        let n = *self.target.normals.get(i)?;
        let q = self.target.points.get(i)?;
        if !n[0].is_finite() {
            return None;
        }
        Some((
            n[0] * (p[0] - q[0]) + n[1] * (p[1] - q[1]) + n[2] * (p[2] - q[2]),
            n,
        ))
    }
}

/// The range bins of the tables (m, upper bounds; the last is open).
pub const RANGE_BINS: [f32; 4] = [10.0, 20.0, 40.0, f32::INFINITY];

/// One cell of a residual table.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ResidualRow {
    /// `ground` (|n_z| > 0.9) or `walls & objects`.
    pub surface: &'static str,
    /// The range bin's bounds (m).
    pub range: [f32; 2],
    pub points: usize,
    /// Median |d| (cm).
    pub median_abs_cm: f64,
    /// Mean signed d (cm): a shift along the normals.
    pub mean_cm: f64,
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Residuals of `channel`'s points moved into the base frame by `extrinsic`, per surface and range.
pub fn residual_table(
    frame: &Frame,
    surfaces: &Surfaces,
    channel: LidarChannel,
    extrinsic: &Pose,
) -> Result<Vec<ResidualRow>, AlignError> {
    let scan = frame.lidar(channel).ok_or(AlignError::NoLidar(channel))?;
    let pts = &scan.points;
    let cfg = surfaces.cfg;
    // (surface, bin) → residuals in cm
    let mut cells: Vec<Vec<f64>> = vec![Vec::new(); 2 * RANGE_BINS.len()];
    for i in (0..pts.len()).step_by(cfg.stride.max(1)) {
        let (x, y, z) = (pts.x[i], pts.y[i], pts.z[i]);
        let range = (x * x + y * y + z * z).sqrt();
        if range > cfg.max_range {
            continue;
        }
        let p = extrinsic * nalgebra::Point3::new(f64::from(x), f64::from(y), f64::from(z));
        let Some((d, n)) = surfaces.residual([p.x as f32, p.y as f32, p.z as f32]) else {
            continue;
        };
        let kind = usize::from(n[2].abs() <= 0.9);
        let bin = RANGE_BINS
            .iter()
            .position(|b| range < *b)
            .unwrap_or(RANGE_BINS.len() - 1);
        if let Some(c) = cells.get_mut(kind * RANGE_BINS.len() + bin) {
            c.push(f64::from(d) * 100.0);
        }
    }
    Ok(cells
        .into_iter()
        .enumerate()
        .map(|(k, mut v)| {
            let (kind, bin) = (k / RANGE_BINS.len(), k % RANGE_BINS.len());
            let lo = if bin == 0 { 0.0 } else { RANGE_BINS[bin - 1] };
            let mean_cm = v.iter().sum::<f64>() / v.len().max(1) as f64;
            let mut abs: Vec<f64> = v.iter().map(|d| d.abs()).collect();
            v.clear();
            ResidualRow {
                surface: if kind == 0 { "ground" } else { "walls & objects" },
                range: [lo, RANGE_BINS[bin]],
                points: abs.len(),
                median_abs_cm: median(&mut abs),
                mean_cm,
            }
        })
        .collect())
}

/// The χ² check of Ξ at one α.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct XiCheck {
    pub alpha: f64,
    pub draws: usize,
    /// (point, draw) pairs on a surface at α = 0 and at the draw.
    pub pairs: usize,
    /// Median z² (χ²₁: 0.455).
    pub median_z2: f64,
    /// Share within 1σ (0.683) and 2σ (0.954).
    pub within_1sigma: f64,
    pub within_2sigma: f64,
    /// Median predicted σ along the normal (cm) and median |Δd| (cm).
    pub median_sigma_cm: f64,
    pub median_abs_dd_cm: f64,
}

/// For `draws` unbounded draws at `alpha` (seeds `seed`…), how each `channel` point's residual
/// changes against what Ξ predicts along the surface normal.
pub fn xi_check(
    frame: &Frame,
    surfaces: &Surfaces,
    channel: LidarChannel,
    alpha: f64,
    draws: usize,
    seed: u64,
) -> Result<XiCheck, AlignError> {
    let cfg = surfaces.cfg;
    let base = fuse(frame, &FuseParams::default())?;
    let lidar = base
        .lidars
        .iter()
        .find(|l| l.channel == channel)
        .ok_or(AlignError::NoLidar(channel))?;
    let range = lidar.range.clone();
    let scan = frame.lidar(channel).ok_or(AlignError::NoLidar(channel))?;
    // Residuals at the dataset's extrinsic, for the points checked.
    let idx: Vec<usize> = range
        .clone()
        .step_by(cfg.stride.max(1))
        .filter(|&i| {
            let k = i - range.start;
            let (x, y, z) = (scan.points.x[k], scan.points.y[k], scan.points.z[k]);
            (x * x + y * y + z * z).sqrt() <= cfg.max_range
        })
        .collect();
    let d0: Vec<Option<f32>> = idx
        .iter()
        .map(|&i| surfaces.residual([base.x[i], base.y[i], base.z[i]]).map(|r| r.0))
        .collect();
    let default = Prior::default();
    let no_noise = Prior::new(default.p, default.phi, nalgebra::Matrix3::zeros())?;
    let (mut z2, mut sig, mut dd) = (Vec::new(), Vec::new(), Vec::new());
    for k in 0..draws {
        let mut perturbation = Perturbation::new(alpha, seed + k as u64)?;
        perturbation.bounded = false;
        let params = FuseParams {
            perturbation,
            prior: no_noise,
            ..Default::default()
        };
        let cloud = fuse(frame, &params)?;
        let cov = fused_covariance(frame, &params)?;
        for (&i, d0) in idx.iter().zip(&d0) {
            let Some(d0) = d0 else { continue };
            let Some((d, n)) = surfaces.residual([cloud.x[i], cloud.y[i], cloud.z[i]]) else {
                continue;
            };
            let Some(c) = cov.get(i) else { continue };
            // Ξ entries (xx, yy, zz, xy, xz, yz).
            let var = n[0] * n[0] * c[0]
                + n[1] * n[1] * c[1]
                + n[2] * n[2] * c[2]
                + 2.0 * (n[0] * n[1] * c[3] + n[0] * n[2] * c[4] + n[1] * n[2] * c[5]);
            if var <= 0.0 {
                continue;
            }
            let delta = f64::from(d - d0);
            z2.push(delta * delta / f64::from(var));
            sig.push(f64::from(var).sqrt() * 100.0);
            dd.push(delta.abs() * 100.0);
        }
    }
    let pairs = z2.len();
    let share = |k: f64| z2.iter().filter(|v| **v <= k * k).count() as f64 / pairs.max(1) as f64;
    let (w1, w2) = (share(1.0), share(2.0));
    Ok(XiCheck {
        alpha,
        draws,
        pairs,
        median_z2: median(&mut z2),
        within_1sigma: w1,
        within_2sigma: w2,
        median_sigma_cm: median(&mut sig),
        median_abs_dd_cm: median(&mut dd),
    })
}
