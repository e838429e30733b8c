//! The one path the GUI and the CLI share: `Frame` + perturbation settings → [`FusedCloud`]
//! (every point in the base frame through the possibly perturbed extrinsics, with its source
//! LiDAR and tr(Ξ), paper eq. 8) — and later → detections.
//!
//! How it works: for each auxiliary LiDAR the perturbation (ρ, φ) is drawn from its own seeded
//! stream (plus any manual offset) and applied as t = t̄ + ρ, R = exp(φ^)R̄ (eq. 1–2). The primary
//! LiDAR defines the base frame, so it is never perturbed and its points carry only the
//! measurement covariance (tr Ξ = tr Z). Ξ of an auxiliary point is linearised at the extrinsic
//! the system uses (the applied one), with the prior Θ at `prior_alpha` — which may differ from
//! the α that perturbed the points (a mis-specified prior). One pass per LiDAR transforms the
//! points and evaluates the closed-form trace, over SoA slices, in parallel above 16k points.

use std::collections::BTreeMap;
use std::ops::Range;

use nalgebra::Matrix3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::calib::{self, CalibError, Calibration, IcpConfig, LidarCalibration, OcPrior};
use crate::dataset::{Frame, LidarChannel, LidarScan};
use crate::geometry::Pose;
use crate::uncertainty::propagate::{covariance_cloud, PARALLEL_THRESHOLD};
use crate::uncertainty::{ExtrinsicNoise, Linearization, Perturbation, Prior, TraceKernel, UncertaintyError};

/// Everything that decides how a frame is fused; serialisable so a session can replay it.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FuseParams {
    /// α and seed of the injected perturbation (bounded at ±σ as in §V-A-3).
    pub perturbation: Perturbation,
    /// The α the prior assumes when computing Ξ; `None`: the same as the perturbation's α.
    pub prior_alpha: Option<f64>,
    /// Θ at α = 1 (eq. 9 by default).
    pub prior: Prior,
    pub linearization: Linearization,
    /// Manual offsets per auxiliary LiDAR, added to the sampled perturbation.
    pub manual: BTreeMap<LidarChannel, ExtrinsicNoise>,
    /// Online calibration (the (OC) cases): the auxiliary LiDARs are fused with ICP's extrinsics
    /// instead of the drifted ones, and their points' Ξ follows the calibration's prior. Valid
    /// only for the sample and the drift it was computed from ([`calibrate`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<Calibration>,
}

impl FuseParams {
    /// The α assumed by the prior.
    pub fn effective_prior_alpha(&self) -> f64 {
        self.prior_alpha.unwrap_or(self.perturbation.alpha)
    }

    /// The perturbation applied to one auxiliary LiDAR: the seeded draw plus the manual offset.
    /// The stream index is fixed per channel, so a missing LiDAR never changes another's draw.
    pub fn noise_for(&self, channel: LidarChannel) -> Result<ExtrinsicNoise, PipelineError> {
        if channel == LidarChannel::Top {
            return Ok(ExtrinsicNoise::ZERO);
        }
        let sampled = self.perturbation.sample(&self.prior, channel as u64)?;
        let manual = self.manual.get(&channel).copied().unwrap_or_default();
        if !manual.is_finite() {
            return Err(PipelineError::BadParameter(format!(
                "manual offset of {channel} is not finite"
            )));
        }
        Ok(sampled.plus(&manual))
    }
}

/// One LiDAR's part of a fused cloud.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FusedLidar {
    pub channel: LidarChannel,
    /// Its points in the fused arrays.
    pub range: Range<usize>,
    /// The nominal extrinsic T^b_{l_i} from the dataset.
    pub nominal: Pose,
    /// The perturbation (ρ, φ) applied to it (zero for the primary).
    pub noise: ExtrinsicNoise,
    /// The extrinsic the points were fused with (ICP's when `calibrated`).
    pub applied: Pose,
    /// Whether `applied` comes from online calibration.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub calibrated: bool,
}

/// A fused point cloud in the base frame, structure-of-arrays.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct FusedCloud {
    pub x: Vec<f32>,
    pub y: Vec<f32>,
    pub z: Vec<f32>,
    pub intensity: Vec<f32>,
    /// Index into `lidars` of each point's source LiDAR.
    pub source: Vec<u8>,
    /// tr(Ξ) of each point (m²).
    pub trace: Vec<f32>,
    pub lidars: Vec<FusedLidar>,
}

impl FusedLidar {
    /// A LiDAR at the identity extrinsic, unperturbed, holding `range` of a cloud (tests build
    /// small clouds with it).
    #[cfg(test)]
    pub(crate) fn identity(channel: LidarChannel, range: Range<usize>) -> Self {
        Self {
            channel,
            range,
            nominal: Pose::identity(),
            noise: ExtrinsicNoise::ZERO,
            applied: Pose::identity(),
            calibrated: false,
        }
    }
}

impl FusedCloud {
    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// |P_u| / |P|: the share of points with tr(Ξ) above `threshold` (the paper uses 0.05).
    pub fn uncertain_fraction(&self, threshold: f32) -> f64 {
        if self.trace.is_empty() {
            return 0.0;
        }
        let n = self.trace.par_iter().filter(|t| **t > threshold).count();
        n as f64 / self.trace.len() as f64
    }

    /// The `[min, max]` of tr(Ξ), if there are points.
    pub fn trace_range(&self) -> Option<(f32, f32)> {
        let first = *self.trace.first()?;
        Some(
            self.trace
                .iter()
                .fold((first, first), |(lo, hi), &t| (lo.min(t), hi.max(t))),
        )
    }
}

/// Errors of the pipeline.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error(transparent)]
    Uncertainty(#[from] UncertaintyError),
    #[error("bad parameter: {0}")]
    BadParameter(String),
    #[error("LiDAR {channel}: {what}")]
    BadLidar { channel: LidarChannel, what: String },
    #[error("online calibration: {0}")]
    Calib(#[from] CalibError),
    #[error("online calibration: {0}")]
    StaleCalibration(String),
}

/// One LiDAR of a frame as `fuse` sees it: its points' place in the fused arrays, its nominal,
/// sampled and applied extrinsic, and the kernel of its points' Ξ.
struct LidarSetup<'a> {
    index: usize,
    scan: &'a LidarScan,
    range: Range<usize>,
    nominal: Pose,
    noise: ExtrinsicNoise,
    applied: Pose,
    calibrated: bool,
    r: Matrix3<f64>,
    t: nalgebra::Vector3<f64>,
    kernel: TraceKernel,
}

/// The per-LiDAR setup shared by [`fuse`] and [`fused_covariance`]: the perturbation, applied
/// extrinsic, prior (the primary LiDAR's extrinsic is exact, it is the base frame: only Z
/// remains; the others get Θ at the prior's α) and linearisation of every LiDAR, in frame order.
fn lidar_setups<'a>(frame: &'a Frame, params: &FuseParams) -> Result<Vec<LidarSetup<'a>>, PipelineError> {
    let scaled = params.prior.scaled(params.effective_prior_alpha())?;
    let primary_prior = Prior {
        p: Matrix3::zeros(),
        phi: Matrix3::zeros(),
        z: scaled.z,
    };
    if let Some(cal) = &params.calibration {
        if cal.sample_token != frame.sample_token {
            return Err(PipelineError::StaleCalibration(format!(
                "it was computed for sample {}, not {}: calibrate again",
                cal.sample_token, frame.sample_token
            )));
        }
    }
    let mut start = 0;
    let mut out = Vec::new();
    for (index, scan) in frame.lidars().enumerate() {
        let channel = scan.info.channel;
        if !scan.points.is_consistent() {
            return Err(PipelineError::BadLidar {
                channel,
                what: "point arrays have different lengths".into(),
            });
        }
        let noise = params.noise_for(channel)?;
        let nominal = scan.info.extrinsic;
        let drifted = noise.apply(&nominal);
        let cal = match (&params.calibration, index) {
            (Some(c), 1..) => c.lidar(channel),
            _ => None,
        };
        let applied = match cal {
            Some(l) => {
                if !l.started_from(&drifted) {
                    return Err(PipelineError::StaleCalibration(format!(
                        "{channel} was calibrated from another drifted extrinsic (the perturbation changed): calibrate again"
                    )));
                }
                l.extrinsic
            }
            None => drifted,
        };
        let r = applied.rotation.to_rotation_matrix().into_inner();
        let t = applied.translation.vector;
        let kernel = match (cal, &params.calibration) {
            (Some(l), Some(c)) if c.prior == OcPrior::Icp => {
                let sigma = nalgebra::Matrix6::from_fn(|i, j| l.covariance[i][j]);
                if !sigma.iter().all(|v| v.is_finite()) {
                    return Err(PipelineError::BadLidar {
                        channel,
                        what: "its calibration's covariance is not finite".into(),
                    });
                }
                TraceKernel::with_covariance(&r, &t, &sigma, &scaled.z, params.linearization)
            }
            _ => {
                let prior = if index == 0 { &primary_prior } else { &scaled };
                TraceKernel::new(&r, &t, prior, params.linearization)
            }
        };
        let range = start..start + scan.points.len();
        start = range.end;
        out.push(LidarSetup {
            index,
            scan,
            range,
            nominal,
            noise,
            applied,
            calibrated: cal.is_some(),
            r,
            t,
            kernel,
        });
    }
    Ok(out)
}

/// Fuses a frame: all points in the base frame via the (perturbed) extrinsics, with tr(Ξ).
pub fn fuse(frame: &Frame, params: &FuseParams) -> Result<FusedCloud, PipelineError> {
    let setups = lidar_setups(frame, params)?;
    let total = setups.last().map_or(0, |s| s.range.end);
    let mut out = FusedCloud {
        x: vec![0.0; total],
        y: vec![0.0; total],
        z: vec![0.0; total],
        intensity: Vec::with_capacity(total),
        source: Vec::with_capacity(total),
        trace: vec![0.0; total],
        lidars: Vec::new(),
    };
    for s in setups {
        let pts = &s.scan.points;
        let range = s.range.clone();
        transform_and_trace(
            &s.r,
            &s.t,
            &s.kernel,
            (&pts.x, &pts.y, &pts.z),
            (
                &mut out.x[range.clone()],
                &mut out.y[range.clone()],
                &mut out.z[range.clone()],
                &mut out.trace[range.clone()],
            ),
        );
        out.intensity.extend_from_slice(&pts.intensity);
        out.source.extend(std::iter::repeat_n(s.index as u8, pts.len()));
        out.lidars.push(FusedLidar {
            channel: s.scan.info.channel,
            range,
            nominal: s.nominal,
            noise: s.noise,
            applied: s.applied,
            calibrated: s.calibrated,
        });
    }
    Ok(out)
}

/// Ξ of every fused point (paper eq. 8; six entries xx, yy, zz, xy, xz, yz in the base frame,
/// m²), in the order of [`fuse`]'s arrays: the same per-LiDAR setup as `fuse`, so the trace of
/// each matrix is `fuse(frame, params).trace`.
pub fn fused_covariance(frame: &Frame, params: &FuseParams) -> Result<Vec<[f32; 6]>, PipelineError> {
    let setups = lidar_setups(frame, params)?;
    let total = setups.last().map_or(0, |s| s.range.end);
    let mut out = vec![[0.0f32; 6]; total];
    for s in setups {
        let pts = &s.scan.points;
        covariance_cloud(&s.kernel, &pts.x, &pts.y, &pts.z, &mut out[s.range.clone()]);
    }
    Ok(out)
}

type Outputs<'a> = (&'a mut [f32], &'a mut [f32], &'a mut [f32], &'a mut [f32]);

/// y = R p + t and tr(Ξ) for one LiDAR's points, in one pass.
fn transform_and_trace(
    r: &Matrix3<f64>,
    t: &nalgebra::Vector3<f64>,
    kernel: &TraceKernel,
    input: (&[f32], &[f32], &[f32]),
    out: Outputs<'_>,
) {
    let m: [[f32; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| r[(i, j)] as f32));
    let tv = [t.x as f32, t.y as f32, t.z as f32];
    let (px, py, pz) = input;
    let (ox, oy, oz, otr) = out;
    let run = |start: usize, ox: &mut [f32], oy: &mut [f32], oz: &mut [f32], otr: &mut [f32]| {
        for i in 0..ox.len() {
            let (a, b, c) = (px[start + i], py[start + i], pz[start + i]);
            ox[i] = m[0][0] * a + m[0][1] * b + m[0][2] * c + tv[0];
            oy[i] = m[1][0] * a + m[1][1] * b + m[1][2] * c + tv[1];
            oz[i] = m[2][0] * a + m[2][1] * b + m[2][2] * c + tv[2];
            otr[i] = kernel.trace(a, b, c);
        }
    };
    const CHUNK: usize = 4096;
    if ox.len() < PARALLEL_THRESHOLD {
        run(0, ox, oy, oz, otr);
    } else {
        ox.par_chunks_mut(CHUNK)
            .zip(oy.par_chunks_mut(CHUNK))
            .zip(oz.par_chunks_mut(CHUNK))
            .zip(otr.par_chunks_mut(CHUNK))
            .enumerate()
            .for_each(|(c, (((x, y), z), tr))| run(c * CHUNK, x, y, z, tr));
    }
}

/// Online calibration of a frame (the (OC) cases): every auxiliary LiDAR is aligned by
/// point-to-plane ICP to the top LiDAR's cloud, starting from the extrinsic `params` drifts it
/// to (the perturbation and manual offsets; any calibration already in `params` is ignored). The
/// target's kd-tree and normals are built once for all auxiliaries. Put the result in
/// [`FuseParams::calibration`] to fuse with the corrected extrinsics.
pub fn calibrate(
    frame: &Frame,
    params: &FuseParams,
    config: &IcpConfig,
    prior: OcPrior,
) -> Result<Calibration, PipelineError> {
    config.validate()?;
    let theta = params.prior.scaled(params.effective_prior_alpha())?;
    let mut theta6 = nalgebra::Matrix6::zeros();
    theta6.fixed_view_mut::<3, 3>(0, 0).copy_from(&theta.p);
    theta6.fixed_view_mut::<3, 3>(3, 3).copy_from(&theta.phi);
    let clock = std::time::Instant::now();
    let target = {
        let top = &frame.primary;
        let pts = &top.points;
        let local = calib::voxel_downsample(&pts.x, &pts.y, &pts.z, config.target_voxel, config.max_range);
        // The primary's extrinsic is the base frame (identity on Lyft data), applied anyway.
        let base: Vec<[f32; 3]> = local
            .iter()
            .map(|p| {
                let q = top.info.extrinsic.transform_point(&nalgebra::Point3::new(
                    p[0] as f64,
                    p[1] as f64,
                    p[2] as f64,
                ));
                [q.x as f32, q.y as f32, q.z as f32]
            })
            .collect();
        calib::Target::new(base, config).map_err(|e| with_channel(e, LidarChannel::Top))?
    };
    let target_ms = clock.elapsed().as_secs_f64() * 1e3;
    let mut lidars = Vec::new();
    for scan in &frame.auxiliaries {
        let channel = scan.info.channel;
        let start = params.noise_for(channel)?.apply(&scan.info.extrinsic);
        let pts = &scan.points;
        let source = calib::voxel_downsample(&pts.x, &pts.y, &pts.z, config.source_voxel, config.max_range);
        let out =
            calib::align(&source, &start, &target, &theta6, config).map_err(|e| with_channel(e, channel))?;
        lidars.push(LidarCalibration {
            channel,
            start,
            extrinsic: out.extrinsic,
            covariance: std::array::from_fn(|i| std::array::from_fn(|j| out.covariance[(i, j)])),
            converged: out.converged,
            iterations: out.iterations,
            fitness: out.fitness,
            rmse: out.rmse,
            correspondences: out.correspondences,
            source_points: source.len(),
            target_points: target.points.len(),
            eigenvalues: out.eigenvalues,
            degenerate: out.degenerate,
            ms: out.ms,
        });
    }
    Ok(Calibration {
        sample_token: frame.sample_token.clone(),
        prior,
        config: *config,
        lidars,
        target_ms,
    })
}

fn with_channel(e: CalibError, channel: LidarChannel) -> PipelineError {
    PipelineError::BadLidar {
        channel,
        what: e.to_string(),
    }
}

/// What the GUI's box tooltip shows about the fused points inside a box.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct BoxStats {
    /// Fused points inside the box.
    pub points: usize,
    /// Their mean tr(Ξ) (m²), 0 if none.
    pub mean_trace: f32,
    /// Their share with tr(Ξ) above the paper's 0.05 threshold.
    pub uncertain_fraction: f32,
}

/// Counts the fused points inside `b` (base frame) and averages their tr(Ξ).
pub fn box_stats(cloud: &FusedCloud, b: &crate::geometry::Box3d) -> BoxStats {
    let r = 0.5 * b.size_lwh[0].hypot(b.size_lwh[1]) as f32;
    let (cx, cy) = (b.center[0] as f32, b.center[1] as f32);
    let (count, sum, unc) = (0..cloud.len())
        .into_par_iter()
        .with_min_len(8192)
        .filter(|&i| {
            // Cheap circle reject first, exact oriented test after.
            (cloud.x[i] - cx).abs() <= r
                && (cloud.y[i] - cy).abs() <= r
                && b.contains([cloud.x[i] as f64, cloud.y[i] as f64, cloud.z[i] as f64], 0.0)
        })
        .map(|i| {
            (
                1usize,
                cloud.trace[i] as f64,
                (cloud.trace[i] > crate::uncertainty::UNCERTAIN_TRACE) as usize,
            )
        })
        .reduce(|| (0, 0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2));
    if count == 0 {
        return BoxStats::default();
    }
    BoxStats {
        points: count,
        mean_trace: (sum / count as f64) as f32,
        uncertain_fraction: unc as f32 / count as f32,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::{LidarScan, PointCloud};
    use crate::geometry::{pose_from_rt, rpy_to_matrix};
    use crate::uncertainty::Perturbation;
    use nalgebra::Vector3;

    fn scan(channel: LidarChannel, rpy: [f64; 3], t: [f64; 3], n: usize) -> LidarScan {
        let mut c = PointCloud::with_capacity(n);
        for i in 0..n {
            let a = i as f32 * 0.37;
            let r = 2.0 + (i % 97) as f32;
            c.push(a.cos() * r, a.sin() * r, (i % 9) as f32 * 0.3 - 1.2, 1.0, 0.0);
        }
        let pose = pose_from_rt(&rpy_to_matrix(rpy[0], rpy[1], rpy[2]), &Vector3::from(t));
        LidarScan::in_memory(channel, pose, c)
    }

    #[test]
    fn fused_covariance_traces_match_fuse() {
        let frame = Frame::in_memory(
            "s",
            scan(LidarChannel::Top, [0.0; 3], [0.0; 3], 3000),
            vec![
                scan(
                    LidarChannel::FrontLeft,
                    [3.1, -0.03, -1.5],
                    [-2.23, -0.97, -1.34],
                    2000,
                ),
                // Above the parallel threshold, so both paths are covered.
                scan(
                    LidarChannel::FrontRight,
                    [3.13, 0.005, 1.6],
                    [-2.28, 0.92, -1.33],
                    20_000,
                ),
            ],
            Vec::new(),
        );
        for (alpha, prior_alpha, linearization) in [
            (0.04, None, Linearization::Separate),
            (0.1, Some(0.02), Linearization::Se3Left),
            (0.0, None, Linearization::Separate),
        ] {
            let params = FuseParams {
                perturbation: Perturbation::new(alpha, 3).unwrap(),
                prior_alpha,
                linearization,
                ..Default::default()
            };
            let cloud = fuse(&frame, &params).unwrap();
            let cov = fused_covariance(&frame, &params).unwrap();
            assert_eq!(cov.len(), cloud.len());
            for (i, (c, &tr)) in cov.iter().zip(&cloud.trace).enumerate() {
                let sum = c[0] + c[1] + c[2];
                assert!(
                    (sum - tr).abs() <= 1e-5 * tr.abs(),
                    "alpha {alpha} {linearization}: point {i} tr {tr} vs {sum}"
                );
                // A covariance: non-negative diagonal.
                assert!(c[0] >= 0.0 && c[1] >= 0.0 && c[2] >= 0.0, "point {i}: {c:?}");
            }
        }
    }
}
