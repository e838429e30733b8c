//! The points of a proposal (paper §IV-B, eq. 12–13): the fused cloud's points inside the proposal
//! box enlarged by a margin, in the proposal's canonical frame, with their tr(Ξ).
//!
//! How it works: [`CloudIndex`] buckets the fused cloud once per frame into a uniform grid of
//! `cell`-metre squares in x–y (a counting sort: one pass to count, one to place, so the points of
//! a cell are contiguous). A proposal visits only the cells under the bounding square of its
//! enlarged footprint and keeps the points whose canonical coordinates lie inside the enlarged box.
//! Each kept point is normalised by eq. 12–13: translated by −(x, y, z) of the proposal, rotated by
//! −γ about z, divided by (l, w, h). [`sample`] then draws a fixed number of them with a seeded
//! generator: a subset without repetition when there are more, every point plus random repeats when
//! there are fewer. A proposal with no point at all gets no sample ([`Sampled::empty`]): the refiner
//! leaves it as stage 1 made it (see [`super::model`]).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::geometry::Box3d;
use crate::pipeline::FusedCloud;

/// The per-point features the refiner sees, after the normalised coordinates x_n, y_n, z_n.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct PointFeatures {
    /// tr(Ξ) (the paper's), as (log10(clamp(tr, 1e-3, 10)) + 3) / 4 ∈ [0, 1]: tr(Ξ) spans four
    /// decades (1e-3 m² for the primary LiDAR's points, up to ~10 m² far from a perturbed one).
    pub trace: bool,
    /// Intensity / 255.
    pub intensity: bool,
    /// The source LiDAR as three one-hot channels (top, front-left, front-right).
    pub lidar: bool,
}

impl Default for PointFeatures {
    fn default() -> Self {
        Self {
            trace: true,
            intensity: false,
            lidar: false,
        }
    }
}

impl PointFeatures {
    /// Channels per point: 3 coordinates + the chosen features.
    pub fn channels(&self) -> usize {
        3 + usize::from(self.trace) + usize::from(self.intensity) + 3 * usize::from(self.lidar)
    }
}

/// How the points of a proposal are gathered.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GatherConfig {
    /// Enlargement of the proposal on each side, m: the box grows by 2·margin along x, y and z
    /// (the paper's "2 m margin along x, y and z", read as PointRCNN's extra width).
    pub margin: f64,
    /// Points per proposal.
    pub points: usize,
    pub features: PointFeatures,
}

impl Default for GatherConfig {
    fn default() -> Self {
        Self {
            margin: 1.0,
            points: 1024,
            features: PointFeatures::default(),
        }
    }
}

/// The trace feature: log-scaled tr(Ξ) in [0, 1].
pub fn trace_feature(tr: f32) -> f32 {
    (tr.clamp(1e-3, 10.0).log10() + 3.0) / 4.0
}

/// A uniform x–y grid over the fused cloud: the points of each cell are contiguous in `order`.
#[derive(Debug, Clone)]
pub struct CloudIndex {
    cell: f64,
    origin: [f64; 2],
    dims: [usize; 2],
    /// `start[c]..start[c + 1]` are the positions in `order` of cell c's points.
    start: Vec<u32>,
    order: Vec<u32>,
}

impl CloudIndex {
    /// Indexes the finite points of `cloud` in cells of `cell` metres (points with a NaN or an
    /// infinite coordinate are left out).
    pub fn new(cloud: &FusedCloud, cell: f64) -> Self {
        let cell = if cell.is_finite() && cell > 0.0 { cell } else { 1.0 };
        let n = cloud.x.len().min(cloud.y.len()).min(cloud.z.len());
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for i in 0..n {
            let (x, y, z) = (cloud.x[i] as f64, cloud.y[i] as f64, cloud.z[i] as f64);
            if x.is_finite() && y.is_finite() && z.is_finite() {
                lo = [lo[0].min(x), lo[1].min(y)];
                hi = [hi[0].max(x), hi[1].max(y)];
            }
        }
        if lo[0] > hi[0] {
            return Self {
                cell,
                origin: [0.0; 2],
                dims: [0, 0],
                start: vec![0],
                order: Vec::new(),
            };
        }
        // At most 4096 cells a side: a cloud wider than that gets coarser cells.
        let cell = cell.max((hi[0] - lo[0]).max(hi[1] - lo[1]) / 4096.0);
        let dims = [
            ((hi[0] - lo[0]) / cell) as usize + 1,
            ((hi[1] - lo[1]) / cell) as usize + 1,
        ];
        let cell_of = |i: usize| -> Option<usize> {
            let (x, y, z) = (cloud.x[i] as f64, cloud.y[i] as f64, cloud.z[i] as f64);
            if !(x.is_finite() && y.is_finite() && z.is_finite()) {
                return None;
            }
            let cx = (((x - lo[0]) / cell) as usize).min(dims[0] - 1);
            let cy = (((y - lo[1]) / cell) as usize).min(dims[1] - 1);
            Some(cy * dims[0] + cx)
        };
        let cells: Vec<Option<usize>> = (0..n).into_par_iter().map(cell_of).collect();
        let mut start = vec![0u32; dims[0] * dims[1] + 1];
        for c in cells.iter().flatten() {
            start[c + 1] += 1;
        }
        for k in 1..start.len() {
            start[k] += start[k - 1];
        }
        let mut next = start.clone();
        let mut order = vec![0u32; start[start.len() - 1] as usize];
        for (i, c) in cells.iter().enumerate() {
            if let Some(c) = c {
                order[next[*c] as usize] = i as u32;
                next[*c] += 1;
            }
        }
        Self {
            cell,
            origin: lo,
            dims,
            start,
            order,
        }
    }

    /// Indices of the points whose x–y lies in the square of half-side `half` around `center`
    /// (a superset: whole cells), cell by cell.
    pub(crate) fn candidates(&self, center: [f64; 2], half: f64) -> impl Iterator<Item = u32> + '_ {
        let range = |k: usize| -> (usize, usize) {
            let lo = ((center[k] - half - self.origin[k]) / self.cell).floor();
            let hi = ((center[k] + half - self.origin[k]) / self.cell).floor();
            let max = self.dims[k] as f64 - 1.0;
            if self.dims[k] == 0 || hi < 0.0 || lo > max || !lo.is_finite() || !hi.is_finite() {
                (1, 0)
            } else {
                (lo.max(0.0) as usize, hi.min(max) as usize)
            }
        };
        let (x0, x1) = range(0);
        let (y0, y1) = range(1);
        (y0..=y1).filter(move |_| x0 <= x1).flat_map(move |cy| {
            let a = self.start[cy * self.dims[0] + x0] as usize;
            let b = self.start[cy * self.dims[0] + x1 + 1] as usize;
            self.order[a..b].iter().copied()
        })
    }
}

/// The points of one proposal in its canonical frame (eq. 12–13), one row of `channels` values
/// per point: x_n, y_n, z_n, then the features.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ProposalPoints {
    /// Row-major, `len() × channels`.
    pub rows: Vec<f32>,
    pub channels: usize,
    /// Index of each row's point in the fused cloud.
    pub index: Vec<u32>,
    /// The largest raw tr(Ξ) among the points (0 without points): L_uct's max_j tr(Ξ_j).
    pub max_trace: f32,
}

impl ProposalPoints {
    pub fn len(&self) -> usize {
        self.index.len()
    }

    pub fn is_empty(&self) -> bool {
        self.index.is_empty()
    }
}

/// Appends point `k` of `cloud` to `out` as one row: its normalised coordinates `n` (eq. 12–13),
/// then the features `f` asks for.
pub(crate) fn push_row(
    out: &mut ProposalPoints,
    cloud: &FusedCloud,
    k: usize,
    n: [f64; 3],
    f: &PointFeatures,
) {
    let tr = cloud.trace.get(k).copied().unwrap_or(0.0);
    out.rows.extend([n[0] as f32, n[1] as f32, n[2] as f32]);
    if f.trace {
        out.rows.push(trace_feature(tr));
    }
    if f.intensity {
        out.rows
            .push(cloud.intensity.get(k).copied().unwrap_or(0.0) / 255.0);
    }
    if f.lidar {
        let src = cloud.source.get(k).copied().unwrap_or(0) as usize;
        let ch = cloud.lidars.get(src).map_or(0, |l| l.channel as usize);
        out.rows.extend((0..3).map(|j| if j == ch { 1.0 } else { 0.0 }));
    }
    out.index.push(k as u32);
    if tr.is_finite() {
        out.max_trace = out.max_trace.max(tr);
    }
}

/// The canonical coordinates of `p` for a proposal (eq. 12–13): rotate by −γ about z around the
/// centre, then divide by l, w, h.
pub fn normalize(b: &Box3d, p: [f64; 3]) -> [f64; 3] {
    let q = b.to_local(p);
    [q[0] / b.size_lwh[0], q[1] / b.size_lwh[1], q[2] / b.size_lwh[2]]
}

/// Gathers the points of `proposal` (enlarged by `cfg.margin` on each side) from `cloud`.
pub fn gather(
    cloud: &FusedCloud,
    index: &CloudIndex,
    proposal: &Box3d,
    cfg: &GatherConfig,
) -> ProposalPoints {
    let f = cfg.features;
    let channels = f.channels();
    let mut out = ProposalPoints {
        channels,
        ..Default::default()
    };
    let [l, w, h] = proposal.size_lwh;
    if !proposal.is_valid() {
        return out;
    }
    let m = cfg.margin.max(0.0);
    let half = [l / 2.0 + m, w / 2.0 + m, h / 2.0 + m];
    let reach = (half[0] * half[0] + half[1] * half[1]).sqrt();
    let (s, c) = proposal.yaw.sin_cos();
    let [cx, cy, cz] = proposal.center;
    for i in index.candidates([cx, cy], reach) {
        let k = i as usize;
        let (dx, dy, dz) = (
            cloud.x[k] as f64 - cx,
            cloud.y[k] as f64 - cy,
            cloud.z[k] as f64 - cz,
        );
        let lx = c * dx + s * dy;
        let ly = -s * dx + c * dy;
        if lx.abs() > half[0] || ly.abs() > half[1] || dz.abs() > half[2] {
            continue;
        }
        push_row(&mut out, cloud, k, [lx / l, ly / w, dz / h], &f);
    }
    out
}

/// A fixed-size draw of a proposal's points.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Sampled {
    /// `n × channels`, row-major (zeros when [`Self::empty`]).
    pub rows: Vec<f32>,
    /// Position of each row in the gathered [`ProposalPoints`].
    pub pick: Vec<u32>,
    /// The proposal had no point at all.
    pub empty: bool,
}

/// Draws `n` rows of `pts` with `seed`: without repetition when there are at least `n`, else every
/// point once and random repeats for the rest.
pub fn sample(pts: &ProposalPoints, n: usize, seed: u64) -> Sampled {
    let m = pts.len();
    let ch = pts.channels;
    if m == 0 || n == 0 {
        return Sampled {
            rows: vec![0.0; n * ch],
            pick: Vec::new(),
            empty: true,
        };
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let pick: Vec<u32> = if m >= n {
        // Partial Fisher–Yates over the first n positions.
        let mut all: Vec<u32> = (0..m as u32).collect();
        for i in 0..n {
            let j = rng.random_range(i..m);
            all.swap(i, j);
        }
        all.truncate(n);
        all
    } else {
        let mut p: Vec<u32> = (0..m as u32).collect();
        p.extend((m..n).map(|_| rng.random_range(0..m as u32)));
        p
    };
    let mut rows = Vec::with_capacity(n * ch);
    for &k in &pick {
        let k = k as usize;
        rows.extend_from_slice(&pts.rows[k * ch..(k + 1) * ch]);
    }
    Sampled {
        rows,
        pick,
        empty: false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud(points: &[[f32; 3]], trace: f32) -> FusedCloud {
        FusedCloud {
            x: points.iter().map(|p| p[0]).collect(),
            y: points.iter().map(|p| p[1]).collect(),
            z: points.iter().map(|p| p[2]).collect(),
            intensity: vec![100.0; points.len()],
            source: vec![0; points.len()],
            trace: vec![trace; points.len()],
            lidars: Vec::new(),
        }
    }

    #[test]
    fn normalisation_is_eq_12_13() {
        let b = Box3d::new([10.0, 5.0, 1.0], [4.0, 2.0, 1.5], std::f64::consts::FRAC_PI_2);
        // A point 1 m ahead along the heading (+y in the world), 0.5 m to its left (−x), 0.3 up.
        let n = normalize(&b, [9.5, 6.0, 1.3]);
        assert!(
            (n[0] - 0.25).abs() < 1e-12 && (n[1] - 0.25).abs() < 1e-12 && (n[2] - 0.2).abs() < 1e-12,
            "{n:?}"
        );
    }

    #[test]
    fn gather_keeps_the_enlarged_box_and_matches_a_scan() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let pts: Vec<[f32; 3]> = (0..20_000)
            .map(|_| {
                [
                    rng.random_range(-40.0..40.0),
                    rng.random_range(-40.0..40.0),
                    rng.random_range(-3.0..3.0),
                ]
            })
            .collect();
        let c = cloud(&pts, 0.01);
        let index = CloudIndex::new(&c, 1.0);
        let cfg = GatherConfig::default();
        for (i, b) in [
            Box3d::new([3.0, -7.0, 0.0], [4.5, 1.9, 1.6], 0.7),
            Box3d::new([-39.0, 39.5, 1.0], [4.5, 1.9, 1.6], -2.0),
            Box3d::new([100.0, 0.0, 0.0], [4.5, 1.9, 1.6], 0.0),
        ]
        .iter()
        .enumerate()
        {
            let got = gather(&c, &index, b, &cfg);
            let mut want: Vec<u32> = (0..pts.len() as u32)
                .filter(|&k| {
                    let q = b.to_local([
                        c.x[k as usize] as f64,
                        c.y[k as usize] as f64,
                        c.z[k as usize] as f64,
                    ]);
                    q.iter().zip(b.size_lwh).all(|(v, s)| v.abs() <= s / 2.0 + 1.0)
                })
                .collect();
            let mut have = got.index.clone();
            have.sort();
            want.sort();
            assert_eq!(have, want, "box {i}");
            for r in got.rows.chunks(4) {
                assert!(r[0].abs() <= 0.5 + 1.0 / 4.5 + 1e-5 && r[2].abs() <= 0.5 + 1.0 / 1.6 + 1e-5);
            }
        }
    }

    #[test]
    fn zero_one_and_many_points() {
        let cfg = GatherConfig::default();
        let b = Box3d::new([0.0, 0.0, 0.0], [4.0, 2.0, 1.5], 0.0);
        // None.
        let c = cloud(&[[50.0, 50.0, 0.0]], 0.2);
        let got = gather(&c, &CloudIndex::new(&c, 1.0), &b, &cfg);
        assert!(got.is_empty() && got.max_trace == 0.0);
        let s = sample(&got, 1024, 1);
        assert!(s.empty && s.rows.len() == 1024 * 4 && s.rows.iter().all(|v| *v == 0.0));
        // One: repeated 1024 times.
        let c = cloud(&[[1.0, 0.5, 0.2]], 0.2);
        let got = gather(&c, &CloudIndex::new(&c, 1.0), &b, &cfg);
        assert_eq!(got.len(), 1);
        assert_eq!(got.max_trace, 0.2);
        let s = sample(&got, 1024, 1);
        assert!(!s.empty && s.pick.iter().all(|&k| k == 0));
        assert_eq!(&s.rows[..4], &[0.25, 0.25, 0.2 / 1.5, trace_feature(0.2)]);
        // 10^5 points in the box: 1024 distinct ones, the same for the same seed.
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let pts: Vec<[f32; 3]> = (0..100_000)
            .map(|_| {
                [
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-0.7..0.7),
                ]
            })
            .collect();
        let c = cloud(&pts, 0.01);
        let got = gather(&c, &CloudIndex::new(&c, 1.0), &b, &cfg);
        assert_eq!(got.len(), 100_000);
        let s = sample(&got, 1024, 5);
        let mut p = s.pick.clone();
        p.sort();
        p.dedup();
        assert_eq!(p.len(), 1024);
        assert_eq!(sample(&got, 1024, 5), s);
        assert_ne!(sample(&got, 1024, 6).pick, s.pick);
    }

    #[test]
    fn nan_points_and_empty_clouds_are_skipped() {
        let c = cloud(
            &[[f32::NAN, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, f32::INFINITY, 0.0]],
            0.1,
        );
        let index = CloudIndex::new(&c, 1.0);
        let b = Box3d::new([0.0, 0.0, 0.0], [4.0, 2.0, 1.5], 0.0);
        assert_eq!(gather(&c, &index, &b, &GatherConfig::default()).index, vec![1]);
        let e = cloud(&[], 0.0);
        assert!(gather(&e, &CloudIndex::new(&e, 1.0), &b, &GatherConfig::default()).is_empty());
    }
}
