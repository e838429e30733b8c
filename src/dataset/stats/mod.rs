//! Sensor statistics of a dataset: what its LiDARs deliver (points per sweep, rings, intensity,
//! ground height, ray drop, range) and how many points its labelled objects get against range.
//! They say how far a dataset is from the one a model was trained on ([`out_of_depth_notes`]) and
//! how close the simulator comes to a real sensor (docs/realism.md).
//!
//! How it works:
//! - The samples are all of the dataset's, or `samples` of them evenly spaced over the scene order
//!   (sample ⌊i·n/N⌋ for i < N). Each is read with [`Dataset::frame`]; a sample that fails to load
//!   is counted in `failed_samples` and skipped. Samples are processed in parallel (rayon); every
//!   result is independent of the order.
//! - Per LiDAR channel, over its sweeps: points per sweep (median, min, max); the number of
//!   distinct ring values ≥ 0 (null when every ring is −1, unknown); intensity and range (the 3D
//!   distance from the sensor) as histograms, and their quantiles from a 0.01-wide histogram (the
//!   k-th smallest value with k = ⌈q·n⌉, to 0.01); intensity's `constant` when every point has one
//!   value.
//! - Ground height below the sensor, per sweep: the points are turned by the sensor's rotation
//!   into the base frame's orientation (so z is up for the tilted bumper LiDARs too; LIDAR_TOP is
//!   unchanged), those at 3–20 m horizontal range are binned by z in 0.1 m bins, and the ground is
//!   the median z of the points in the densest bin and its two neighbours; the height is minus
//!   that. The dataset's value is the median over sweeps.
//! - Return ratio (share of emitted rays that returned), where rings are known: per ring, the
//!   azimuth step is the median positive difference of its sorted azimuths (rings with fewer than
//!   16 points take the sweep's median step); the ring emitted round(2π / step) rays and returned
//!   as many as it has azimuths more than half a step apart. Rings 0 … the highest ring seen count,
//!   so a ring that saw nothing (a beam into the sky) adds rays and no returns. The ratio pools
//!   returns over emitted rays of all rings and sweeps; null where no sweep has rings.
//! - Objects: every LiDAR's points are moved into the base frame with their nominal extrinsics,
//!   and each ground-truth box (all labelled boxes, also outside a KITTI eval region) counts the
//!   points inside it with [`Box3d::contains`] (the oriented test `mlod fuse`'s per-box
//!   statistics use). Boxes are binned by the horizontal distance of their centre from the
//!   base-frame origin: 0–10, 10–20, …, 60–70, 70+ m; each bin has its box count and the median of
//!   their point counts (the mean of the two middle values for an even count).
//! - [`StatsSummary`] keeps what a model's input depends on (LIDAR_TOP's rings, intensity, ground
//!   height and points per sweep; mean car size; the LiDARs seen) and is stored with the models.

#![deny(clippy::indexing_slicing)]

mod notes;
mod sensor;
#[cfg(test)]
mod tests;

pub use notes::out_of_depth_notes;

use std::collections::BTreeMap;
use std::path::PathBuf;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use self::sensor::{ground_height, returns};
use super::error::DatasetError;
use super::frame::{Frame, LidarScan};
use super::index::{Dataset, DatasetFormat, LidarChannel};
use crate::geometry::Box3d;

/// Object range bins: lower edges (m); the last bin is open.
pub const OBJECT_BIN_EDGES_M: [f64; 8] = [0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0];
/// Width (m) of the range histogram's bins.
pub const RANGE_BIN_M: f64 = 10.0;
/// Bins of the range histogram (0–150 m); farther points count in `above`.
pub const RANGE_BINS: usize = 15;
/// Bins of the intensity histogram over 0–256 (8 wide).
pub const INTENSITY_BINS: usize = 32;
/// Horizontal range (m) of the points the ground height is estimated from.
pub const GROUND_RANGE_M: (f64, f64) = (3.0, 20.0);
/// Height bin (m) of the ground estimate.
pub const GROUND_BIN_M: f64 = 0.1;
/// Rings with fewer points than this take the sweep's median azimuth step.
const MIN_RING_POINTS: usize = 16;
/// Resolution of the quantile histograms: 1 / 100.
const FINE_SCALE: f64 = 100.0;
/// Quantile histograms cover 0–256 (intensity) and 0–400 m (range); values outside are clamped.
const INTENSITY_FINE_MAX: f64 = 256.0;
const RANGE_FINE_MAX: f64 = 400.0;
/// How many load failures are kept with their message.
const KEPT_FAILURES: usize = 10;

/// What [`dataset_stats`] computes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StatsOptions {
    /// Use this many samples evenly spaced over the scene order (`None`: all).
    pub samples: Option<usize>,
    /// Count the points inside each box (the costliest part); without it `median_points` is null.
    pub points_in_boxes: bool,
    /// Estimate the return ratio; without it `return_ratio` is null.
    pub return_ratio: bool,
}

impl Default for StatsOptions {
    fn default() -> Self {
        Self {
            samples: None,
            points_in_boxes: true,
            return_ratio: true,
        }
    }
}

/// Median, minimum and maximum of a count.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Spread {
    pub median: f64,
    pub min: f64,
    pub max: f64,
}

/// Counts between consecutive edges; values below the first edge or at or above the last one are
/// counted in `below` / `above`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Histogram {
    pub edges: Vec<f64>,
    pub counts: Vec<u64>,
    pub below: u64,
    pub above: u64,
}

impl Histogram {
    fn uniform(lo: f64, width: f64, bins: usize) -> Self {
        Self {
            edges: (0..=bins).map(|k| lo + width * k as f64).collect(),
            counts: vec![0; bins],
            below: 0,
            above: 0,
        }
    }

    fn add(&mut self, v: f64) {
        let (Some(&lo), Some(&hi)) = (self.edges.first(), self.edges.last()) else {
            return;
        };
        if v < lo {
            self.below += 1;
        } else if v >= hi {
            self.above += 1;
        } else {
            let n = self.counts.len();
            let k = (((v - lo) / (hi - lo)) * n as f64).floor() as usize;
            if let Some(c) = self.counts.get_mut(k.min(n.saturating_sub(1))) {
                *c += 1;
            }
        }
    }

    fn merge(&mut self, o: &Self) {
        self.counts.iter_mut().zip(&o.counts).for_each(|(a, b)| *a += b);
        self.below += o.below;
        self.above += o.above;
    }

    /// All values counted.
    pub fn total(&self) -> u64 {
        self.counts.iter().sum::<u64>() + self.below + self.above
    }
}

/// A LiDAR's intensity over all its points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IntensityStats {
    /// Over 0–256 in 8-wide bins.
    pub histogram: Histogram,
    pub median: f64,
    pub p05: f64,
    pub p95: f64,
    pub min: f64,
    pub max: f64,
    /// The value every point has, if they all have one.
    pub constant: Option<f64>,
}

/// A LiDAR's range (3D distance from the sensor) over all its points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RangeStats {
    /// 10 m bins over 0–150 m; `above`: farther.
    pub histogram: Histogram,
    pub median: f64,
}

/// Statistics of one LiDAR channel over its sweeps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LidarStats {
    pub channel: LidarChannel,
    pub sweeps: usize,
    pub points_per_sweep: Spread,
    /// Distinct ring values ≥ 0; null when the ring is unknown.
    pub rings: Option<u32>,
    /// Fewest and most distinct rings in one sweep (they differ when the sweeps come from several
    /// sensors); null when the ring is unknown.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rings_per_sweep: Option<[u32; 2]>,
    pub intensity: IntensityStats,
    /// Ground height below the sensor (m), median over sweeps; null if no sweep had ground points.
    pub ground_height_m: Option<f64>,
    /// Share of emitted rays that returned; null where rings are unknown.
    pub return_ratio: Option<f64>,
    pub range: RangeStats,
}

/// Boxes of one category in one range bin.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RangeBin {
    pub from_m: f64,
    /// Null for the last, open bin.
    pub to_m: Option<f64>,
    pub boxes: usize,
    /// Median points inside a box (all LiDARs); null for an empty bin or when not counted.
    pub median_points: Option<f64>,
    /// The same with LIDAR_TOP's points only (what a single-LiDAR dataset such as KITTI compares
    /// with).
    pub median_points_top: Option<f64>,
}

/// Boxes of one category.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CategoryStats {
    pub category: String,
    pub boxes: usize,
    /// Mean size (l, w, h) in m.
    pub size_mean_lwh: [f64; 3],
    pub range_bins: Vec<RangeBin>,
}

/// One ground-truth box: where it is and how many points it holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BoxRecord {
    pub sample_token: String,
    pub category: String,
    /// Horizontal distance of the centre from the base-frame origin (m).
    pub range_m: f64,
    pub size_lwh: [f64; 3],
    /// Points inside (all LiDARs); null when not counted.
    pub points: Option<usize>,
    /// Of those, LIDAR_TOP's.
    pub points_top: Option<usize>,
}

/// Everything [`dataset_stats`] measures.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DatasetStats {
    pub dataset: PathBuf,
    pub format: DatasetFormat,
    /// Samples used.
    pub samples: usize,
    /// Samples that failed to load (skipped).
    pub failed_samples: usize,
    /// The first failures, `token: error`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub failures: Vec<String>,
    /// LIDAR_TOP, LIDAR_FRONT_LEFT, LIDAR_FRONT_RIGHT, those seen.
    pub lidars: Vec<LidarStats>,
    /// Categories by name.
    pub objects: Vec<CategoryStats>,
    /// Every box, in sample then file order (left empty before serialising unless asked for).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub boxes: Vec<BoxRecord>,
}

impl DatasetStats {
    /// The statistics of a channel, if it was seen.
    pub fn lidar(&self, channel: LidarChannel) -> Option<&LidarStats> {
        self.lidars.iter().find(|l| l.channel == channel)
    }

    /// The statistics of a category, if it has boxes.
    pub fn category(&self, name: &str) -> Option<&CategoryStats> {
        self.objects.iter().find(|c| c.category == name)
    }

    /// The compact summary stored with the models.
    pub fn summary(&self) -> StatsSummary {
        let top = self.lidar(LidarChannel::Top);
        StatsSummary {
            samples: self.samples,
            rings: top.and_then(|l| l.rings),
            rings_per_sweep: top.and_then(|l| l.rings_per_sweep),
            intensity_median: top.map_or(0.0, |l| l.intensity.median),
            intensity_p05: top.map_or(0.0, |l| l.intensity.p05),
            intensity_p95: top.map_or(0.0, |l| l.intensity.p95),
            intensity_constant: top.and_then(|l| l.intensity.constant),
            ground_height_m: top.and_then(|l| l.ground_height_m),
            points_per_sweep_median: top.map_or(0.0, |l| l.points_per_sweep.median),
            points_per_sweep_range: top
                .filter(|l| l.sweeps > 0)
                .map(|l| [l.points_per_sweep.min, l.points_per_sweep.max]),
            car_size_mean_lwh: self.category("car").map(|c| c.size_mean_lwh),
            lidars: self
                .lidars
                .iter()
                .map(|l| l.channel.as_str().to_owned())
                .collect(),
        }
    }
}

/// What a model's input depends on, in a few numbers: LIDAR_TOP's rings, intensity, ground
/// height and points per sweep, the mean car size and the LiDAR channels seen.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StatsSummary {
    pub samples: usize,
    /// LIDAR_TOP's distinct rings; `None`: unknown.
    pub rings: Option<u32>,
    /// Fewest and most distinct LIDAR_TOP rings in one sweep: a range when the data mixes sensors
    /// (absent in summaries written before it existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rings_per_sweep: Option<[u32; 2]>,
    pub intensity_median: f64,
    pub intensity_p05: f64,
    pub intensity_p95: f64,
    pub intensity_constant: Option<f64>,
    pub ground_height_m: Option<f64>,
    pub points_per_sweep_median: f64,
    /// Fewest and most LIDAR_TOP points in one sweep: wide when the data mixes sensors (absent in
    /// summaries written before it existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub points_per_sweep_range: Option<[f64; 2]>,
    pub car_size_mean_lwh: Option<[f64; 3]>,
    /// Channels seen, LIDAR_TOP first.
    pub lidars: Vec<String>,
}

/// A dataset summary with the command that made it, as the models' manifest stores it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainingStats {
    /// As a user types it (`mlod stats --dataset data/train --samples 200 --update-manifest …`).
    pub command: String,
    pub summary: StatsSummary,
}

/// The samples used: all, or `n` evenly spaced over the scene order.
pub fn pick_samples(ds: &Dataset, n: Option<usize>) -> Vec<String> {
    let all = ds.sample_tokens();
    match n {
        Some(n) if n < all.len() => (0..n)
            .filter_map(|i| all.get(i * all.len() / n))
            .map(|s| (*s).to_owned())
            .collect(),
        _ => all.into_iter().map(str::to_owned).collect(),
    }
}

/// Statistics of the dataset's samples (see the module doc). Samples that fail to load are
/// counted and skipped; an error only when no sample is selected or none loads.
pub fn dataset_stats(ds: &Dataset, opts: &StatsOptions) -> Result<DatasetStats, DatasetError> {
    let tokens = pick_samples(ds, opts.samples);
    if tokens.is_empty() {
        return Err(DatasetError::NoSamples {
            path: ds.root().to_path_buf(),
        });
    }
    let acc = tokens
        .par_iter()
        .enumerate()
        .fold(Acc::default, |mut acc, (i, tok)| {
            match ds.frame(tok) {
                Ok(frame) => acc.add_frame(i, &frame, opts),
                Err(e) => {
                    acc.failed.push((i, format!("{tok}: {e}")));
                }
            }
            acc
        })
        .reduce(Acc::default, Acc::merge);
    let used = acc.samples;
    let mut failed = acc.failed;
    failed.sort_by_key(|f| f.0);
    if used == 0 {
        return Err(DatasetError::NoUsableSamples {
            path: ds.root().to_path_buf(),
            failed: failed.len(),
            first: failed.first().map(|f| f.1.clone()).unwrap_or_default(),
        });
    }
    let lidars = acc
        .lidars
        .into_iter()
        .map(|(channel, a)| a.finish(channel, opts))
        .collect();
    let mut boxes = acc.boxes;
    boxes.sort_by_key(|b| (b.0, b.1));
    let boxes: Vec<BoxRecord> = boxes.into_iter().map(|b| b.2).collect();
    Ok(DatasetStats {
        dataset: ds.root().to_path_buf(),
        format: ds.format(),
        samples: used,
        failed_samples: failed.len(),
        failures: failed.into_iter().take(KEPT_FAILURES).map(|f| f.1).collect(),
        lidars,
        objects: object_stats(&boxes),
        boxes,
    })
}

/// The summary of `samples` evenly spaced samples (no points-in-box counts, no return ratio:
/// cheap enough to run before a detection).
pub fn summarize(ds: &Dataset, samples: usize) -> Result<StatsSummary, DatasetError> {
    let opts = StatsOptions {
        samples: Some(samples),
        points_in_boxes: false,
        return_ratio: false,
    };
    Ok(dataset_stats(ds, &opts)?.summary())
}

/// The median of values (the mean of the two middle ones for an even count); `None` if empty.
pub fn median(values: &mut [f64]) -> Option<f64> {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    if n == 0 {
        return None;
    }
    let hi = values.get(n / 2).copied()?;
    if n % 2 == 1 {
        Some(hi)
    } else {
        Some(0.5 * (values.get(n / 2 - 1).copied()? + hi))
    }
}

/// The range bin of an object at horizontal distance `r`.
fn object_bin(r: f64) -> usize {
    OBJECT_BIN_EDGES_M.iter().rposition(|&e| r >= e).unwrap_or(0)
}

fn object_stats(boxes: &[BoxRecord]) -> Vec<CategoryStats> {
    let mut by_cat: BTreeMap<&str, Vec<&BoxRecord>> = BTreeMap::new();
    for b in boxes {
        by_cat.entry(b.category.as_str()).or_default().push(b);
    }
    by_cat
        .into_iter()
        .map(|(category, bs)| {
            let n = bs.len().max(1) as f64;
            let mut size = [0.0; 3];
            for b in &bs {
                size.iter_mut().zip(b.size_lwh).for_each(|(s, v)| *s += v);
            }
            let range_bins = OBJECT_BIN_EDGES_M
                .iter()
                .enumerate()
                .map(|(k, &from_m)| {
                    let in_bin: Vec<&&BoxRecord> = bs.iter().filter(|b| object_bin(b.range_m) == k).collect();
                    let mut pts: Vec<f64> =
                        in_bin.iter().filter_map(|b| b.points.map(|p| p as f64)).collect();
                    let mut top: Vec<f64> = in_bin
                        .iter()
                        .filter_map(|b| b.points_top.map(|p| p as f64))
                        .collect();
                    RangeBin {
                        from_m,
                        to_m: OBJECT_BIN_EDGES_M.get(k + 1).copied(),
                        boxes: in_bin.len(),
                        median_points: median(&mut pts),
                        median_points_top: median(&mut top),
                    }
                })
                .collect();
            CategoryStats {
                category: category.to_owned(),
                boxes: bs.len(),
                size_mean_lwh: size.map(|s| s / n),
                range_bins,
            }
        })
        .collect()
}

/// A histogram at 0.01 resolution for quantiles; values outside [0, max) are clamped.
#[derive(Debug, Clone)]
struct FineHist {
    counts: Vec<u64>,
    n: u64,
}

impl FineHist {
    fn new(max: f64) -> Self {
        Self {
            counts: vec![0; (max * FINE_SCALE) as usize],
            n: 0,
        }
    }

    fn add(&mut self, v: f64) {
        let last = self.counts.len().saturating_sub(1);
        let k = (v * FINE_SCALE).floor().clamp(0.0, last as f64) as usize;
        if let Some(c) = self.counts.get_mut(k) {
            *c += 1;
            self.n += 1;
        }
    }

    fn merge(&mut self, o: &Self) {
        if self.counts.len() == o.counts.len() {
            self.counts.iter_mut().zip(&o.counts).for_each(|(a, b)| *a += b);
            self.n += o.n;
        }
    }

    /// The k-th smallest value (k = ⌈q·n⌉, at least 1) to 0.01; 0 when empty.
    fn quantile(&self, q: f64) -> f64 {
        if self.n == 0 {
            return 0.0;
        }
        let k = ((q * self.n as f64).ceil() as u64).clamp(1, self.n);
        let mut seen = 0u64;
        for (i, &c) in self.counts.iter().enumerate() {
            seen += c;
            if seen >= k {
                return i as f64 / FINE_SCALE;
            }
        }
        0.0
    }
}

/// One channel's running statistics.
#[derive(Debug, Clone)]
struct LidarAcc {
    points: Vec<usize>,
    rings: Vec<bool>,
    /// Distinct rings of each sweep whose rings are known.
    sweep_rings: Vec<u32>,
    ring_known: bool,
    intensity: Histogram,
    intensity_fine: FineHist,
    intensity_min: f64,
    intensity_max: f64,
    range: Histogram,
    range_fine: FineHist,
    ground: Vec<f64>,
    returned: u64,
    emitted: u64,
}

impl Default for LidarAcc {
    fn default() -> Self {
        Self {
            points: Vec::new(),
            rings: Vec::new(),
            sweep_rings: Vec::new(),
            ring_known: false,
            intensity: Histogram::uniform(0.0, 256.0 / INTENSITY_BINS as f64, INTENSITY_BINS),
            intensity_fine: FineHist::new(INTENSITY_FINE_MAX),
            intensity_min: f64::INFINITY,
            intensity_max: f64::NEG_INFINITY,
            range: Histogram::uniform(0.0, RANGE_BIN_M, RANGE_BINS),
            range_fine: FineHist::new(RANGE_FINE_MAX),
            ground: Vec::new(),
            returned: 0,
            emitted: 0,
        }
    }
}

impl LidarAcc {
    fn add_scan(&mut self, scan: &LidarScan, opts: &StatsOptions) {
        let p = &scan.points;
        self.points.push(p.len());
        let mut this_sweep: Vec<bool> = Vec::new();
        for &r in &p.ring {
            if (0.0..65536.0).contains(&r) {
                let k = r.round() as usize;
                if this_sweep.len() <= k {
                    this_sweep.resize(k + 1, false);
                }
                if let Some(s) = this_sweep.get_mut(k) {
                    *s = true;
                }
            }
        }
        if this_sweep.iter().any(|&s| s) {
            self.ring_known = true;
            self.sweep_rings
                .push(this_sweep.iter().filter(|&&s| s).count() as u32);
            if self.rings.len() < this_sweep.len() {
                self.rings.resize(this_sweep.len(), false);
            }
            self.rings.iter_mut().zip(&this_sweep).for_each(|(a, b)| *a |= *b);
        }
        for &i in &p.intensity {
            let v = f64::from(i);
            self.intensity.add(v);
            self.intensity_fine.add(v);
            self.intensity_min = self.intensity_min.min(v);
            self.intensity_max = self.intensity_max.max(v);
        }
        for ((&x, &y), &z) in p.x.iter().zip(&p.y).zip(&p.z) {
            let r = f64::from(x).hypot(f64::from(y)).hypot(f64::from(z));
            self.range.add(r);
            self.range_fine.add(r);
        }
        if let Some(g) = ground_height(scan) {
            self.ground.push(g);
        }
        if opts.return_ratio {
            if let Some((returned, emitted)) = returns(&p.x, &p.y, &p.ring) {
                self.returned += returned;
                self.emitted += emitted;
            }
        }
    }

    fn merge(mut self, o: Self) -> Self {
        self.points.extend(o.points);
        if self.rings.len() < o.rings.len() {
            self.rings.resize(o.rings.len(), false);
        }
        self.rings.iter_mut().zip(&o.rings).for_each(|(a, b)| *a |= *b);
        self.sweep_rings.extend(o.sweep_rings);
        self.ring_known |= o.ring_known;
        self.intensity.merge(&o.intensity);
        self.intensity_fine.merge(&o.intensity_fine);
        self.intensity_min = self.intensity_min.min(o.intensity_min);
        self.intensity_max = self.intensity_max.max(o.intensity_max);
        self.range.merge(&o.range);
        self.range_fine.merge(&o.range_fine);
        self.ground.extend(o.ground);
        self.returned += o.returned;
        self.emitted += o.emitted;
        self
    }

    fn finish(self, channel: LidarChannel, opts: &StatsOptions) -> LidarStats {
        let mut pts: Vec<f64> = self.points.iter().map(|&n| n as f64).collect();
        let min = pts.iter().copied().fold(f64::INFINITY, f64::min);
        let max = pts.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let med = median(&mut pts).unwrap_or(0.0);
        let mut ground = self.ground;
        let any_points = self.intensity_fine.n > 0;
        LidarStats {
            channel,
            sweeps: self.points.len(),
            points_per_sweep: Spread {
                median: med,
                min: if min.is_finite() { min } else { 0.0 },
                max: if max.is_finite() { max } else { 0.0 },
            },
            rings: self
                .ring_known
                .then(|| self.rings.iter().filter(|&&s| s).count() as u32),
            rings_per_sweep: match (self.sweep_rings.iter().min(), self.sweep_rings.iter().max()) {
                (Some(&lo), Some(&hi)) => Some([lo, hi]),
                _ => None,
            },
            intensity: IntensityStats {
                median: self.intensity_fine.quantile(0.5),
                p05: self.intensity_fine.quantile(0.05),
                p95: self.intensity_fine.quantile(0.95),
                min: if any_points { self.intensity_min } else { 0.0 },
                max: if any_points { self.intensity_max } else { 0.0 },
                constant: (any_points && self.intensity_min == self.intensity_max)
                    .then_some(self.intensity_min),
                histogram: self.intensity,
            },
            ground_height_m: median(&mut ground),
            return_ratio: (opts.return_ratio && self.emitted > 0)
                .then(|| self.returned as f64 / self.emitted as f64),
            range: RangeStats {
                median: self.range_fine.quantile(0.5),
                histogram: self.range,
            },
        }
    }
}

/// Per-thread accumulation over samples.
#[derive(Debug, Default)]
struct Acc {
    samples: usize,
    failed: Vec<(usize, String)>,
    lidars: BTreeMap<LidarChannel, LidarAcc>,
    /// (sample index, box index, record).
    boxes: Vec<(usize, usize, BoxRecord)>,
}

impl Acc {
    fn add_frame(&mut self, index: usize, frame: &Frame, opts: &StatsOptions) {
        self.samples += 1;
        for scan in frame.lidars() {
            self.lidars
                .entry(scan.info.channel)
                .or_default()
                .add_scan(scan, opts);
        }
        let cloud = opts.points_in_boxes.then(|| base_frame_points(frame));
        let n_top = frame.primary.points.len();
        let counts: Vec<Option<(usize, usize)>> = frame
            .boxes
            .par_iter()
            .map(|b| cloud.as_ref().map(|c| points_in_box(c, n_top, &b.box3d)))
            .collect();
        for (k, (b, counts)) in frame.boxes.iter().zip(counts).enumerate() {
            self.boxes.push((
                index,
                k,
                BoxRecord {
                    sample_token: frame.sample_token.clone(),
                    category: b.category.clone(),
                    range_m: b.box3d.bev_range(),
                    size_lwh: b.box3d.size_lwh,
                    points: counts.map(|c| c.0),
                    points_top: counts.map(|c| c.1),
                },
            ));
        }
    }

    fn merge(mut self, o: Self) -> Self {
        self.samples += o.samples;
        self.failed.extend(o.failed);
        for (c, a) in o.lidars {
            let merged = match self.lidars.remove(&c) {
                Some(mine) => mine.merge(a),
                None => a,
            };
            self.lidars.insert(c, merged);
        }
        self.boxes.extend(o.boxes);
        self
    }
}

/// All of a frame's points in the base frame (nominal extrinsics), as x, y, z columns.
pub fn base_frame_points(frame: &Frame) -> [Vec<f32>; 3] {
    let n = frame.num_points();
    let mut out = [
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    ];
    for scan in frame.lidars() {
        let t = &scan.info.extrinsic;
        let p = &scan.points;
        for ((&x, &y), &z) in p.x.iter().zip(&p.y).zip(&p.z) {
            let q = t.transform_point(&nalgebra::Point3::new(f64::from(x), f64::from(y), f64::from(z)));
            let [xs, ys, zs] = &mut out;
            xs.push(q.x as f32);
            ys.push(q.y as f32);
            zs.push(q.z as f32);
        }
    }
    out
}

/// Points of `cloud` (base frame) inside `b`, all of them and among the first `n_top` (LIDAR_TOP's
/// in [`base_frame_points`]' order): a cheap square reject, then the oriented test.
pub fn points_in_box(cloud: &[Vec<f32>; 3], n_top: usize, b: &Box3d) -> (usize, usize) {
    let [xs, ys, zs] = cloud;
    let n_top = n_top.min(xs.len());
    let part = |r: std::ops::Range<usize>| match (xs.get(r.clone()), ys.get(r.clone()), zs.get(r)) {
        (Some(x), Some(y), Some(z)) => count_inside(x, y, z, b),
        _ => 0,
    };
    let top = part(0..n_top);
    (top + part(n_top..xs.len()), top)
}

fn count_inside(xs: &[f32], ys: &[f32], zs: &[f32], b: &Box3d) -> usize {
    let r = 0.5 * b.size_lwh[0].hypot(b.size_lwh[1]);
    let (cx, cy) = (b.center[0], b.center[1]);
    xs.iter()
        .zip(ys)
        .zip(zs)
        .filter(|((&x, &y), &z)| {
            let (x, y) = (f64::from(x), f64::from(y));
            (x - cx).abs() <= r && (y - cy).abs() <= r && b.contains([x, y, f64::from(z)], 0.0)
        })
        .count()
}
