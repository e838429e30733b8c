//! `--ground-gate M`: cars stand on the ground. A detection whose bottom floats more than M
//! metres above the ground around it is dropped.
//!
//! On real frames a LiDAR-Top trained on the simulator puts confident car boxes on top of
//! hedges, garden walls and bushes, their bottoms 0.6–2 m above the road next to them
//! (docs/realism.md, "Walls at the curb"); on the simulator's own scenes such boxes are rare.
//! The ground around a box is the lower envelope of the cloud: the lowest point of each
//! 1 m × 1 m cell within 6 m of the box's centre (BEV), and of those the 10th percentile, so a
//! wall or hedge that fills a few cells does not lift it and a stray low point does not sink it.
//! A box with fewer than [`MIN_CELLS`] such cells (nothing around it to judge by) is kept.
//! Only the points of LiDARs fused where they truly are count (the primary, every LiDAR at
//! α = 0, one placed by online calibration): a LiDAR drawn off by α or a manual offset would
//! sink or lift the envelope and gate true cars — LiDAR-Top's boxes too, whose points are not
//! perturbed at all.

use rayon::prelude::*;

use crate::dataset::Frame;
use crate::detect::Case;
use crate::detect::{DetectError, Detection, Detector};
use crate::pipeline::{FuseParams, FusedCloud};
use crate::uncertainty::ExtrinsicNoise;

/// Cell size of the lower envelope (m).
pub const CELL_M: f64 = 1.0;
/// Radius around a box's centre whose cells give its ground (m).
pub const RADIUS_M: f64 = 6.0;
/// Which of the cells' lowest points is the ground: this quantile, from below.
pub const QUANTILE: f64 = 0.1;
/// Fewer cells with points than this around a box: no verdict, the box is kept.
pub const MIN_CELLS: usize = 5;
// The range a gate may take lives beside the manifest that records one (no module cycle).
pub use crate::detect::weights::{check_gate, MAX_GATE_M};

/// The lowest point of each cell of a grid covering some region of the cloud.
struct LowerEnvelope {
    /// The cell index of the grid's first cell along x and y.
    origin: [i64; 2],
    /// Cells along x and y.
    dims: [usize; 2],
    /// Row-major (x fastest); +∞ where a cell holds no point.
    min_z: Vec<f32>,
}

impl LowerEnvelope {
    /// The envelope over the cells within [`RADIUS_M`] of any of `boxes`' centres (their
    /// bounding rectangle), from every finite point of `cloud`.
    fn around(cloud: &FusedCloud, centres: &[[f64; 2]]) -> Option<Self> {
        let cell = |v: f64| (v / CELL_M).floor() as i64;
        let mut lo = [i64::MAX; 2];
        let mut hi = [i64::MIN; 2];
        for c in centres.iter().filter(|c| c[0].is_finite() && c[1].is_finite()) {
            for k in 0..2 {
                lo[k] = lo[k].min(cell(c[k] - RADIUS_M));
                hi[k] = hi[k].max(cell(c[k] + RADIUS_M));
            }
        }
        if lo[0] > hi[0] || lo[1] > hi[1] {
            return None;
        }
        let dims = [(hi[0] - lo[0] + 1) as usize, (hi[1] - lo[1] + 1) as usize];
        let n_cells = dims[0].checked_mul(dims[1])?;
        if n_cells > 4_000_000 {
            // Boxes spread over more than 2 km: an absurd frame, not worth a verdict.
            return None;
        }
        let index = |x: f32, y: f32| -> Option<usize> {
            if !(x.is_finite() && y.is_finite()) {
                return None;
            }
            let (i, j) = (cell(f64::from(x)) - lo[0], cell(f64::from(y)) - lo[1]);
            (i >= 0 && j >= 0 && (i as usize) < dims[0] && (j as usize) < dims[1])
                .then(|| j as usize * dims[0] + i as usize)
        };
        let n = cloud.x.len().min(cloud.y.len()).min(cloud.z.len());
        let trusted = trusted_lidars(cloud);
        let counts = |p: usize| match cloud.source.get(p) {
            Some(&s) => trusted.get(usize::from(s)).copied().unwrap_or(true),
            None => true,
        };
        let min_z = (0..n)
            .into_par_iter()
            .with_min_len(8192)
            .fold(
                || vec![f32::INFINITY; n_cells],
                |mut grid, p| {
                    let z = cloud.z[p];
                    if let (Some(c), true) = (index(cloud.x[p], cloud.y[p]), z.is_finite() && counts(p)) {
                        grid[c] = grid[c].min(z);
                    }
                    grid
                },
            )
            .reduce(
                || vec![f32::INFINITY; n_cells],
                |mut a, b| {
                    a.iter_mut().zip(&b).for_each(|(x, y)| *x = x.min(*y));
                    a
                },
            );
        Some(Self {
            origin: lo,
            dims,
            min_z,
        })
    }

    /// The ground under `centre`: the [`QUANTILE`] of the lowest points of the cells within
    /// [`RADIUS_M`], or `None` with fewer than [`MIN_CELLS`] cells holding points.
    fn ground(&self, centre: [f64; 2]) -> Option<f64> {
        let mut lows = Vec::new();
        let r_cells = (RADIUS_M / CELL_M).ceil() as i64;
        let (ci, cj) = (
            (centre[0] / CELL_M).floor() as i64,
            (centre[1] / CELL_M).floor() as i64,
        );
        for j in cj - r_cells..=cj + r_cells {
            for i in ci - r_cells..=ci + r_cells {
                let (gi, gj) = (i - self.origin[0], j - self.origin[1]);
                if gi < 0 || gj < 0 || gi as usize >= self.dims[0] || gj as usize >= self.dims[1] {
                    continue;
                }
                let (cx, cy) = ((i as f64 + 0.5) * CELL_M, (j as f64 + 0.5) * CELL_M);
                if (cx - centre[0]).hypot(cy - centre[1]) > RADIUS_M {
                    continue;
                }
                let z = self.min_z[gj as usize * self.dims[0] + gi as usize];
                if z.is_finite() {
                    lows.push(z);
                }
            }
        }
        if lows.len() < MIN_CELLS {
            return None;
        }
        lows.sort_unstable_by(f32::total_cmp);
        let k = ((lows.len() - 1) as f64 * QUANTILE).round() as usize;
        Some(f64::from(lows[k]))
    }
}

/// Per LiDAR of `cloud`: whether its points lie where they truly are, so that they may set
/// the ground — fused unperturbed (the primary; every LiDAR at α = 0) or placed by online
/// calibration. A cloud that names no LiDAR is trusted whole.
fn trusted_lidars(cloud: &FusedCloud) -> Vec<bool> {
    cloud
        .lidars
        .iter()
        .map(|l| l.calibrated || l.noise == ExtrinsicNoise::ZERO)
        .collect()
}

/// How far each detection's bottom lies above the ground around it (m); `None` where there
/// are too few points around it to tell.
pub fn ground_lift(cloud: &FusedCloud, dets: &[Detection]) -> Vec<Option<f64>> {
    let centres: Vec<[f64; 2]> = dets
        .iter()
        .map(|d| [d.box3d.center[0], d.box3d.center[1]])
        .collect();
    let Some(env) = LowerEnvelope::around(cloud, &centres) else {
        return vec![None; dets.len()];
    };
    dets.iter()
        .map(|d| {
            let b = &d.box3d;
            let bottom = b.center[2] - 0.5 * b.size_lwh[2];
            env.ground([b.center[0], b.center[1]])
                .map(|g| bottom - g)
                .filter(|v| v.is_finite())
        })
        .collect()
}

/// Which gate a run uses: the models folder's (`mlod train tune-gate`), none, or this one (m).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum GateChoice {
    /// As the manifest says, for the stage-1 cases (none when it says nothing).
    #[default]
    Manifest,
    Off,
    Metres(f32),
}

impl std::str::FromStr for GateChoice {
    type Err = String;

    /// `manifest`, `off`, or a height in (0, 5] m.
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "manifest" => Ok(Self::Manifest),
            "off" => Ok(Self::Off),
            _ => {
                let v: f32 = s
                    .parse()
                    .map_err(|_| format!("expected manifest, off or a ground gate in metres, got {s:?}"))?;
                check_gate(v).map(Self::Metres)
            }
        }
    }
}

impl std::fmt::Display for GateChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Manifest => f.write_str("manifest"),
            Self::Off => f.write_str("off"),
            Self::Metres(v) => write!(f, "{v}"),
        }
    }
}

/// The gate `choice` gives `case` of the models folder `dir` (m), if any: the manifest's only
/// for the stage-1 cases (it was chosen on them), an explicit one for every case.
pub fn resolve(choice: GateChoice, dir: &std::path::Path, case: Case) -> Option<f32> {
    match choice {
        GateChoice::Off => None,
        GateChoice::Metres(v) => Some(v),
        GateChoice::Manifest if case.is_mlod() => None,
        GateChoice::Manifest => manifest_gate(dir),
    }
}

/// The gate the models folder `dir` records for its stage-1 cases (m; `mlod train tune-gate`),
/// if it has a readable manifest with one.
pub fn manifest_gate(dir: &std::path::Path) -> Option<f32> {
    crate::detect::weights::Manifest::load(dir)
        .ok()
        .and_then(|m| m.ground_gate_m())
}

/// `inner` behind the gate `choice` gives its case in the models folder `dir`.
pub fn gated(
    inner: Box<dyn Detector>,
    choice: GateChoice,
    dir: &std::path::Path,
) -> Result<Box<dyn Detector>, DetectError> {
    Ok(match resolve(choice, dir, inner.case()) {
        Some(m) => Box::new(GroundGate::new(inner, m)?),
        None => inner,
    })
}

/// A detector whose boxes floating more than `max_lift_m` above the ground are dropped.
pub struct GroundGate {
    inner: Box<dyn Detector>,
    pub max_lift_m: f32,
}

impl GroundGate {
    pub fn new(inner: Box<dyn Detector>, max_lift_m: f32) -> Result<Self, DetectError> {
        let max_lift_m = check_gate(max_lift_m).map_err(DetectError::BadParameter)?;
        Ok(Self { inner, max_lift_m })
    }
}

impl Detector for GroundGate {
    fn case(&self) -> Case {
        self.inner.case()
    }

    fn categories(&self) -> Vec<String> {
        self.inner.categories()
    }

    fn fuse_params(&self, frame: &Frame, params: &FuseParams) -> Result<FuseParams, DetectError> {
        self.inner.fuse_params(frame, params)
    }

    fn detect_fused(&self, frame: &Frame, cloud: &FusedCloud) -> Result<Vec<Detection>, DetectError> {
        let dets = self.inner.detect_fused(frame, cloud)?;
        let lifts = ground_lift(cloud, &dets);
        let gate = f64::from(self.max_lift_m);
        Ok(dets
            .into_iter()
            .zip(lifts)
            .filter(|(_, lift)| lift.is_none_or(|l| l <= gate))
            .map(|(d, _)| d)
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::box3d::Box3d;

    /// Flat ground at z = -1.7 every 0.25 m over ±20 m, and a hedge (z up to -0.2) filling
    /// the strip 8 ≤ y ≤ 9 m.
    fn street() -> FusedCloud {
        let mut c = FusedCloud::default();
        for i in -80..80 {
            for j in -80..80 {
                let (x, y) = (i as f32 * 0.25, j as f32 * 0.25);
                let hedge = (8.0..=9.0).contains(&y);
                for z in if hedge {
                    vec![-1.0f32, -0.6, -0.2]
                } else {
                    vec![-1.7]
                } {
                    c.x.push(x);
                    c.y.push(y);
                    c.z.push(z);
                }
            }
        }
        c
    }

    fn car(x: f64, y: f64, bottom: f64) -> Detection {
        Detection {
            box3d: Box3d::new([x, y, bottom + 0.8], [4.6, 1.9, 1.6], 0.0),
            score: 0.5,
            category: "car".into(),
        }
    }

    #[test]
    fn lift_is_measured_from_the_road_beside_a_hedge() {
        let c = street();
        let dets = [car(5.0, 3.0, -1.7), car(5.0, 8.5, -0.2), car(100.0, 0.0, -1.7)];
        let lifts = ground_lift(&c, &dets);
        assert!(lifts[0].is_some_and(|l| l.abs() < 1e-6), "{lifts:?}");
        // On top of the hedge: the road cells around it set the ground.
        assert!(lifts[1].is_some_and(|l| (l - 1.5).abs() < 1e-6), "{lifts:?}");
        // Nothing around it: no verdict.
        assert_eq!(lifts[2], None);
        // Brute force for the first box: the 10th percentile of the cells' lowest points.
        let mut lows = std::collections::BTreeMap::new();
        for p in 0..c.x.len() {
            let (x, y) = (f64::from(c.x[p]), f64::from(c.y[p]));
            let (i, j) = ((x / CELL_M).floor() as i64, (y / CELL_M).floor() as i64);
            let (cx, cy) = ((i as f64 + 0.5) * CELL_M, (j as f64 + 0.5) * CELL_M);
            if (cx - 5.0).hypot(cy - 3.0) <= RADIUS_M {
                let e = lows.entry((i, j)).or_insert(f32::INFINITY);
                *e = e.min(c.z[p]);
            }
        }
        let mut v: Vec<f32> = lows.into_values().collect();
        v.sort_by(f32::total_cmp);
        let g = f64::from(v[((v.len() - 1) as f64 * QUANTILE).round() as usize]);
        assert!((lifts[0].unwrap_or(f64::NAN) - (-1.7 - g)).abs() < 1e-9);
    }

    #[test]
    fn a_perturbed_lidar_does_not_move_the_ground() {
        use crate::dataset::LidarChannel;
        use crate::pipeline::FusedLidar;
        // The street from the primary LiDAR, then a second LiDAR drawn off by α whose points
        // lie 1 m under the road everywhere.
        let mut c = street();
        let n = c.x.len();
        c.source = vec![0; n];
        for p in 0..n {
            let (x, y) = (c.x[p], c.y[p]);
            c.x.push(x);
            c.y.push(y);
            c.z.push(-2.7);
            c.source.push(1);
        }
        let mut aux = FusedLidar::identity(LidarChannel::FrontLeft, n..2 * n);
        aux.noise = ExtrinsicNoise {
            rho: [0.0, 0.0, -1.0],
            phi: [0.0; 3],
        };
        c.lidars = vec![FusedLidar::identity(LidarChannel::Top, 0..n), aux];
        let dets = [car(5.0, 3.0, -1.7)];
        // Perturbed: only the primary's points count, and the car stands on the road.
        assert!(ground_lift(&c, &dets)[0].is_some_and(|l| l.abs() < 1e-6));
        // At α = 0 (or calibrated) the second LiDAR's points count as before: 1 m of lift.
        c.lidars[1].noise = ExtrinsicNoise::ZERO;
        assert!(ground_lift(&c, &dets)[0].is_some_and(|l| (l - 1.0).abs() < 1e-6));
        c.lidars[1].noise.rho[2] = -1.0;
        c.lidars[1].calibrated = true;
        assert!(ground_lift(&c, &dets)[0].is_some_and(|l| (l - 1.0).abs() < 1e-6));
    }

    #[test]
    fn absurd_gates_are_refused_and_nan_points_ignored() {
        for bad in [0.0, -1.0, f32::NAN, 6.0] {
            assert!(check_gate(bad).is_err(), "{bad}");
        }
        for (s, want) in [
            ("manifest", Some(GateChoice::Manifest)),
            ("off", Some(GateChoice::Off)),
            ("0.5", Some(GateChoice::Metres(0.5))),
            ("7", None),
            ("NaN", None),
            ("low", None),
        ] {
            assert_eq!(s.parse::<GateChoice>().ok(), want, "{s}");
        }
        let mut c = street();
        c.x.push(f32::NAN);
        c.y.push(3.0);
        c.z.push(-50.0);
        c.x.push(5.0);
        c.y.push(3.0);
        c.z.push(f32::NAN);
        let lifts = ground_lift(&c, &[car(5.0, 3.0, -1.7)]);
        assert!(lifts[0].is_some_and(|l| l.abs() < 1e-6), "{lifts:?}");
        assert!(ground_lift(&c, &[]).is_empty());
    }

    #[test]
    fn the_gate_fuses_as_the_detector_it_wraps_says() {
        // An (OC) case fuses with its calibration in the parameters: behind the gate it must
        // still (a gated `input-oc` once fused the drifted cloud and was refused).
        struct Marks;
        impl Detector for Marks {
            fn case(&self) -> Case {
                Case::InputOc
            }
            fn categories(&self) -> Vec<String> {
                vec!["car".into()]
            }
            fn fuse_params(&self, _: &Frame, p: &FuseParams) -> Result<FuseParams, DetectError> {
                let mut p = p.clone();
                p.prior_alpha = Some(0.123);
                Ok(p)
            }
            fn detect_fused(&self, _: &Frame, _: &FusedCloud) -> Result<Vec<Detection>, DetectError> {
                Ok(Vec::new())
            }
        }
        let gate = GroundGate::new(Box::new(Marks), 0.5).unwrap();
        let ds = crate::dataset::Dataset::open(concat!(env!("CARGO_MANIFEST_DIR"), "/sample_data")).unwrap();
        let frame = ds.frame(ds.first_sample_token().unwrap()).unwrap();
        let p = gate.fuse_params(&frame, &FuseParams::default()).unwrap();
        assert_eq!(p.prior_alpha, Some(0.123));
        assert!(gate.detect(&frame, &FuseParams::default()).unwrap().is_empty());
    }
}
