//! The voxeliser and feature learning network (FLN) of the stage-1 detectors: points in the base
//! frame → a height-compressed bird's-eye-view (BEV) tensor.
//!
//! How it works: the range x, y ∈ [−51.2, 51.2) m (the paper's hard difficulty is < 50 m, §V-A-2)
//! and z ∈ [−3, 1) m (LIDAR_TOP sits ~1.8 m above the road) is cut into 0.4 m × 0.4 m columns of
//! `nz` 0.5 m voxels. As in SECOND v1.5 the voxel feature is the mean of its points: the mean
//! position inside the voxel (x, y and z, each 0 at the voxel's low side and 1 at its high side)
//! together with the point density ln(1 + n), and the mean intensity of the whole column. The
//! voxels of a column are stacked as channels, giving a dense `[4·nz + 1, ny, nx]` map that 2D
//! convolutions consume — the deviation from SECOND's sparse 3D middle layers (candle has no sparse
//! convolution). Channel order: density (nz), mean z (nz), column intensity (1), mean x (nz),
//! mean y (nz). Models trained before the in-voxel x/y means existed (`xy_means: false` in their
//! configuration) get the first `2·nz + 1` channels only. One pass over the points (a few hundred
//! thousand at most) takes about a millisecond, so it runs on one thread.

use serde::{Deserialize, Serialize};

/// The BEV grid shared by the voxeliser, the anchors and the network.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GridConfig {
    /// Lower x and y bound (m); the grid is square and centred on the base frame.
    pub xy_min: f32,
    /// Input cell size (m).
    pub cell: f32,
    /// Cells along x and along y.
    pub n: usize,
    pub z_min: f32,
    pub z_max: f32,
    /// Voxels per column.
    pub nz: usize,
    /// Whether the voxel feature holds the in-voxel mean x and y (absent, so false, in the
    /// configuration of models trained before they existed).
    #[serde(default)]
    pub xy_means: bool,
    /// Whether the column-intensity channel holds the mean intensity (true, and every model
    /// trained before the field existed) or stays zero (models trained with `--no-intensity`,
    /// for data whose intensity is not real or differs between sensors).
    #[serde(default = "yes", skip_serializing_if = "is_true")]
    pub intensity: bool,
    /// Whether the voxel feature also holds the mean tr(Ξ) of the voxel's points (m²): the
    /// `input-tr` experiment of issue 32, retired (docs/notes); no command trains it now, a weights
    /// file of it still loads. Absent, so false, in every other model.
    #[serde(default, skip_serializing_if = "is_false")]
    pub trace: bool,
}

fn is_false(v: &bool) -> bool {
    !*v
}

fn yes() -> bool {
    true
}

fn is_true(v: &bool) -> bool {
    *v
}

impl Default for GridConfig {
    fn default() -> Self {
        Self {
            xy_min: -51.2,
            cell: 0.4,
            n: 256,
            z_min: -3.0,
            z_max: 1.0,
            nz: 8,
            xy_means: true,
            intensity: true,
            trace: false,
        }
    }
}

impl GridConfig {
    /// Channels of the BEV tensor: density and mean height per voxel, the column intensity,
    /// with `xy_means` the mean x and y per voxel, and with `trace` the mean tr(Ξ) per voxel.
    pub fn channels(&self) -> usize {
        let base = if self.xy_means {
            4 * self.nz + 1
        } else {
            2 * self.nz + 1
        };
        base + if self.trace { self.nz } else { 0 }
    }

    /// The upper x and y bound (m).
    pub fn xy_max(&self) -> f32 {
        self.xy_min + self.cell * self.n as f32
    }

    /// The column index (row-major, y rows then x) of a point, if inside the grid.
    #[inline]
    pub fn column(&self, x: f32, y: f32) -> Option<usize> {
        let fx = (x - self.xy_min) / self.cell;
        let fy = (y - self.xy_min) / self.cell;
        if fx.is_nan() || fy.is_nan() || fx < 0.0 || fy < 0.0 {
            return None;
        }
        let (ix, iy) = (fx as usize, fy as usize);
        (ix < self.n && iy < self.n).then_some(iy * self.n + ix)
    }
}

/// A BEV tensor in channel-major order `[channels, n, n]`, with the number of points used.
#[derive(Debug, Clone, PartialEq)]
pub struct Bev {
    pub data: Vec<f32>,
    pub channels: usize,
    pub n: usize,
    /// Points that fell inside the grid.
    pub points_used: usize,
    /// Voxels holding at least one point.
    pub occupied_voxels: usize,
}

/// Points as structure-of-arrays slices (base frame, intensity 0–255).
#[derive(Debug, Clone, Copy)]
pub struct PointsRef<'a> {
    pub x: &'a [f32],
    pub y: &'a [f32],
    pub z: &'a [f32],
    pub intensity: &'a [f32],
    /// tr(Ξ) per point (m²), read only by grids with `trace`; shorter (e.g. empty): 0 for the
    /// points it lacks.
    pub trace: &'a [f32],
}

impl PointsRef<'_> {
    pub fn len(&self) -> usize {
        self.x
            .len()
            .min(self.y.len())
            .min(self.z.len())
            .min(self.intensity.len())
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Voxelises points into the BEV tensor of `grid` (see the module doc).
pub fn voxelize(grid: &GridConfig, pts: PointsRef<'_>) -> Bev {
    let cols = grid.n * grid.n;
    let nz = grid.nz;
    let dz = (grid.z_max - grid.z_min) / nz as f32;
    let mut count = vec![0u32; nz * cols];
    let mut zsum = vec![0f32; nz * cols];
    let xy = grid.xy_means;
    let mut xsum = vec![0f32; if xy { nz * cols } else { 0 }];
    let mut ysum = vec![0f32; if xy { nz * cols } else { 0 }];
    let mut col_count = vec![0u32; cols];
    let mut isum = vec![0f32; cols];
    let tr = grid.trace;
    let mut tsum = vec![0f32; if tr { nz * cols } else { 0 }];
    let mut used = 0;
    for i in 0..pts.len() {
        let z = pts.z[i];
        let fz = (z - grid.z_min) / dz;
        if !(0.0..(nz as f32)).contains(&fz) {
            continue;
        }
        let Some(c) = grid.column(pts.x[i], pts.y[i]) else {
            continue;
        };
        let iz = fz as usize;
        let v = iz * cols + c;
        count[v] += 1;
        zsum[v] += fz - iz as f32;
        if xy {
            let fx = (pts.x[i] - grid.xy_min) / grid.cell;
            let fy = (pts.y[i] - grid.xy_min) / grid.cell;
            xsum[v] += fx - fx.floor();
            ysum[v] += fy - fy.floor();
        }
        if tr {
            tsum[v] += pts.trace.get(i).copied().filter(|t| t.is_finite()).unwrap_or(0.0);
        }
        col_count[c] += 1;
        if grid.intensity {
            isum[c] += pts.intensity[i];
        }
        used += 1;
    }
    let mut data = vec![0f32; grid.channels() * cols];
    let (density, rest) = data.split_at_mut(nz * cols);
    let (height, rest) = rest.split_at_mut(nz * cols);
    let (intensity, rest) = rest.split_at_mut(cols);
    let (xmean, rest) = rest.split_at_mut(if xy { nz * cols } else { 0 });
    let (ymean, tmean) = rest.split_at_mut(if xy { nz * cols } else { 0 });
    let mut occupied = 0;
    for v in 0..nz * cols {
        let n = count[v];
        if n > 0 {
            occupied += 1;
            density[v] = (n as f32).ln_1p();
            height[v] = zsum[v] / n as f32;
            if xy {
                xmean[v] = xsum[v] / n as f32;
                ymean[v] = ysum[v] / n as f32;
            }
            if tr {
                tmean[v] = tsum[v] / n as f32;
            }
        }
    }
    for c in 0..cols {
        if col_count[c] > 0 {
            intensity[c] = isum[c] / (255.0 * col_count[c] as f32);
        }
    }
    Bev {
        data,
        channels: grid.channels(),
        n: grid.n,
        points_used: used,
        occupied_voxels: occupied,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_points_per_voxel_and_drops_out_of_range() {
        let g = GridConfig::default();
        // Two points in one voxel, one in the voxel above it, one outside in x, one below z_min.
        let x = [0.1, 0.2, 0.1, 60.0, 0.0];
        let y = [0.1, 0.3, 0.1, 0.0, 0.0];
        let z = [-2.9, -2.7, -2.4, -1.0, -3.5];
        let i = [255.0, 0.0, 255.0, 10.0, 10.0];
        let bev = voxelize(
            &g,
            PointsRef {
                x: &x,
                y: &y,
                z: &z,
                intensity: &i,
                trace: &[],
            },
        );
        assert_eq!(bev.points_used, 3);
        assert_eq!(bev.occupied_voxels, 2);
        let cols = g.n * g.n;
        let c = g.column(0.1, 0.1).unwrap();
        assert_eq!(c, 128 * 256 + 128);
        assert!((bev.data[c] - 3f32.ln()).abs() < 1e-6, "two points: ln(1+2)");
        assert!((bev.data[cols + c] - 2f32.ln()).abs() < 1e-6, "one point above");
        // Mean height in the first voxel: (0.2 + 0.6) / 2 of its 0.5 m.
        assert!((bev.data[g.nz * cols + c] - 0.4).abs() < 1e-5);
        // Column intensity: (255 + 0 + 255) / 3 / 255.
        assert!((bev.data[2 * g.nz * cols + c] - 2.0 / 3.0).abs() < 1e-6);
        // In-voxel mean x and y (fractions of the 0.4 m cell): x at 0.25 and 0.5 of the cell,
        // y at 0.25 and 0.75; the voxel above holds one point at (0.25, 0.25).
        let (xm, ym) = ((2 * g.nz + 1) * cols, (3 * g.nz + 1) * cols);
        assert!((bev.data[xm + c] - 0.375).abs() < 1e-4, "{}", bev.data[xm + c]);
        assert!((bev.data[ym + c] - 0.5).abs() < 1e-4, "{}", bev.data[ym + c]);
        assert!((bev.data[xm + cols + c] - 0.25).abs() < 1e-4);
        assert!((bev.data[ym + cols + c] - 0.25).abs() < 1e-4);
        assert_eq!(bev.data.iter().filter(|v| **v != 0.0).count(), 9);
        assert_eq!(bev.channels, 4 * g.nz + 1);
    }

    #[test]
    fn models_without_xy_means_keep_their_channels() {
        let g = GridConfig {
            xy_means: false,
            ..GridConfig::default()
        };
        let p = [0.1f32];
        let bev = voxelize(
            &g,
            PointsRef {
                x: &p,
                y: &p,
                z: &[-2.9],
                intensity: &[255.0],
                trace: &[],
            },
        );
        assert_eq!(bev.channels, 2 * g.nz + 1);
        assert_eq!(bev.data.len(), (2 * g.nz + 1) * g.n * g.n);
        assert_eq!(bev.data.iter().filter(|v| **v != 0.0).count(), 3);
        // A configuration written before the field existed reads as `xy_means: false`.
        let old = r#"{"xy_min":-51.2,"cell":0.4,"n":256,"z_min":-3.0,"z_max":1.0,"nz":8}"#;
        let parsed: GridConfig = serde_json::from_str(old).unwrap();
        assert_eq!(parsed, g);
    }

    #[test]
    fn trace_channels_hold_each_voxels_mean_trace() {
        use rand::{Rng, SeedableRng};
        let g = GridConfig {
            n: 16,
            cell: 0.5,
            xy_min: -4.0,
            nz: 4,
            trace: true,
            ..GridConfig::default()
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let n = 3000;
        let mut gen = |lo: f32, hi: f32| (0..n).map(|_| rng.random_range(lo..hi)).collect::<Vec<f32>>();
        let (x, y, z) = (gen(-4.5, 4.5), gen(-4.5, 4.5), gen(-3.2, 1.2));
        let i = vec![100.0; n];
        let mut t = gen(0.0, 0.3);
        t[7] = f32::NAN; // a NaN trace counts as 0, the point still counts
        let bev = voxelize(
            &g,
            PointsRef {
                x: &x,
                y: &y,
                z: &z,
                intensity: &i,
                trace: &t,
            },
        );
        assert_eq!(bev.channels, 5 * g.nz + 1);
        // Brute force: for every voxel, the points in it and their mean trace.
        let cols = g.n * g.n;
        let dz = (g.z_max - g.z_min) / g.nz as f32;
        let base = (4 * g.nz + 1) * cols;
        let mut checked = 0;
        for iz in 0..g.nz {
            for c in 0..cols {
                let inside: Vec<usize> = (0..n)
                    .filter(|&k| {
                        let fz = (z[k] - g.z_min) / dz;
                        fz >= 0.0
                            && (fz as usize) == iz
                            && fz < g.nz as f32
                            && g.column(x[k], y[k]) == Some(c)
                    })
                    .collect();
                let want = if inside.is_empty() {
                    0.0
                } else {
                    inside
                        .iter()
                        .map(|&k| if t[k].is_nan() { 0.0 } else { t[k] })
                        .sum::<f32>()
                        / inside.len() as f32
                };
                let got = bev.data[base + iz * cols + c];
                assert!((got - want).abs() < 1e-5, "voxel {iz}/{c}: {got} vs {want}");
                checked += usize::from(!inside.is_empty());
            }
        }
        assert!(checked > 200, "only {checked} voxels held points");
        // The other channels are those of the same grid without the trace.
        let plain = voxelize(
            &GridConfig { trace: false, ..g },
            PointsRef {
                x: &x,
                y: &y,
                z: &z,
                intensity: &i,
                trace: &[],
            },
        );
        assert_eq!(&bev.data[..base], &plain.data[..]);
    }
}
