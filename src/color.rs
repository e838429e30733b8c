//! Point colouring for the viewport and the CLI's PNGs: per-LiDAR colours, height, intensity, and
//! tr(Ξ) through a sequential ramp (dim grey = certain to pale pink = uncertain), on a linear or
//! log scale, with an optional highlight of the paper's uncertain points (tr Ξ > 0.05). Also the
//! histogram and the legend ticks the GUI draws. Pure functions over slices, parallel for whole
//! clouds.
//!
//! The point palettes never use the box colours — blue (proposals), red (refined), green
//! (ground truth) and amber (selected) — so that a box stays visible over any point: the
//! standard palette keeps to greys, violet, magenta, pink and teal (the paper's blue / green /
//! red LiDARs and turbo's blue-green-red would hide the boxes), and the colour-blind-safe one
//! to greys only, leaving hue to the boxes alone.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::pipeline::FusedCloud;

/// An RGBA colour, 8 bits per channel.
pub type Rgba = [u8; 4];

/// The LiDAR colours of the standard palette: top warm light grey, front-left orchid, front-right teal
/// (the paper's blue / green / red are the box colours here).
pub const LIDAR_COLORS: [Rgba; 3] = [[185, 185, 170, 255], [210, 110, 220, 255], [60, 195, 200, 255]];

/// The LiDAR colours of the colour-blind-safe palette: three lightnesses of grey.
pub const LIDAR_GREYS: [Rgba; 3] = [[225, 225, 225, 255], [150, 150, 150, 255], [100, 100, 100, 255]];

/// The point palette. Both keep off the box colours (blue, red, green, amber).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Palette {
    /// Greys, orchid and teal for the LiDARs; grey → violet → magenta → pale pink for scalars.
    #[default]
    Standard,
    /// Greys only (lightness carries the value): safe for every kind of colour vision, and the
    /// boxes are the only hues on screen.
    ColorBlind,
}

impl Palette {
    pub const ALL: [Palette; 2] = [Palette::Standard, Palette::ColorBlind];

    pub fn label(self) -> &'static str {
        match self {
            Palette::Standard => "standard",
            Palette::ColorBlind => "colour-blind safe (greys)",
        }
    }

    /// The colour of a point of LiDAR `source` (0 top, 1 front-left, 2 front-right).
    pub fn lidar(self, source: usize) -> Rgba {
        let table = match self {
            Palette::Standard => &LIDAR_COLORS,
            Palette::ColorBlind => &LIDAR_GREYS,
        };
        table.get(source).copied().unwrap_or([200, 200, 200, 255])
    }

    /// The colour of a scalar at position `t` in [0, 1] of its range.
    pub fn ramp(self, t: f32) -> Rgba {
        let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 };
        let stops: &[(f32, [f32; 3])] = match self {
            Palette::Standard => &[
                (0.0, [95.0, 98.0, 115.0]),
                (0.35, [125.0, 82.0, 170.0]),
                (0.7, [210.0, 80.0, 180.0]),
                (1.0, [255.0, 195.0, 240.0]),
            ],
            Palette::ColorBlind => &[(0.0, [80.0, 80.0, 84.0]), (1.0, [245.0, 245.0, 245.0])],
        };
        let k = stops
            .iter()
            .position(|s| s.0 >= t)
            .unwrap_or(stops.len() - 1)
            .max(1);
        let (t0, c0) = stops[k - 1];
        let (t1, c1) = stops[k];
        let f = if t1 > t0 { (t - t0) / (t1 - t0) } else { 0.0 };
        let q = |i: usize| (c0[i] + (c1[i] - c0[i]) * f).round().clamp(0.0, 255.0) as u8;
        [q(0), q(1), q(2), 255]
    }
}

/// What the colour of a point shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ColorMode {
    /// The source LiDAR, in the paper's colours.
    Source,
    /// Height z in the base frame.
    Height,
    /// The LiDAR's intensity.
    Intensity,
    /// tr(Ξ), the trace of the propagated covariance (eq. 8).
    #[default]
    Trace,
}

impl ColorMode {
    pub const ALL: [ColorMode; 4] = [
        ColorMode::Source,
        ColorMode::Height,
        ColorMode::Intensity,
        ColorMode::Trace,
    ];

    pub fn label(self) -> &'static str {
        match self {
            ColorMode::Source => "source LiDAR",
            ColorMode::Height => "height",
            ColorMode::Intensity => "intensity",
            ColorMode::Trace => "tr(Ξ)",
        }
    }

    /// The unit of the scalar this mode maps (none for `Source`).
    pub fn unit(self) -> &'static str {
        match self {
            ColorMode::Source => "",
            ColorMode::Height => "m",
            ColorMode::Intensity => "",
            ColorMode::Trace => "m²",
        }
    }
}

/// Linear or logarithmic mapping of a scalar to the colormap.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Scale {
    #[default]
    Linear,
    Log,
}

/// How scalars become colours.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ColorParams {
    pub mode: ColorMode,
    pub scale: Scale,
    /// The mapped range; values outside are clamped. Ignored for `Source`.
    pub range: (f32, f32),
    /// Draw points with tr(Ξ) above this threshold in [`HIGHLIGHT`] (None: off).
    pub highlight_above: Option<f32>,
    /// The point palette (sessions written before it existed: the standard one).
    #[serde(default)]
    pub palette: Palette,
}

impl Default for ColorParams {
    fn default() -> Self {
        Self {
            mode: ColorMode::Trace,
            scale: Scale::Log,
            range: (1e-3, 1.0),
            highlight_above: None,
            palette: Palette::Standard,
        }
    }
}

/// The highlight colour for uncertain points: cyan, in neither palette nor a box colour.
pub const HIGHLIGHT: Rgba = [0, 235, 235, 255];

/// Turbo (Mikhailov 2019, polynomial approximation), t in [0, 1]. The darkest 10 % of turbo is
/// skipped so that the lowest values — most points — stay a readable blue on a dark background.
pub fn turbo(t: f32) -> Rgba {
    let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 };
    let t = 0.1 + 0.9 * t;
    let poly = |c: [f32; 7]| -> f32 {
        let mut v = c[6];
        for k in (0..6).rev() {
            v = v * t + c[k];
        }
        v
    };
    let r = poly([
        0.135_721_38,
        4.615_392_6,
        -42.660_324,
        132.131_08,
        -152.942_4,
        59.286_38,
        0.0,
    ]);
    let g = poly([
        0.091_402_61,
        2.194_188_4,
        4.842_966_6,
        -14.185_033,
        4.277_298_6,
        2.829_566,
        0.0,
    ]);
    let b = poly([
        0.106_673_3,
        12.641_946,
        -60.582_05,
        110.362_77,
        -89.903_11,
        27.348_25,
        0.0,
    ]);
    let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    [q(r), q(g), q(b), 255]
}

/// CIE L*a*b* (D65 white) of an sRGB colour (alpha ignored).
pub fn lab(c: Rgba) -> [f32; 3] {
    let lin = |v: u8| {
        let v = f32::from(v) / 255.0;
        if v <= 0.04045 {
            v / 12.92
        } else {
            ((v + 0.055) / 1.055).powf(2.4)
        }
    };
    let (r, g, b) = (lin(c[0]), lin(c[1]), lin(c[2]));
    let x = (0.4124 * r + 0.3576 * g + 0.1805 * b) / 0.95047;
    let y = 0.2126 * r + 0.7152 * g + 0.0722 * b;
    let z = (0.0193 * r + 0.1192 * g + 0.9505 * b) / 1.08883;
    let f = |t: f32| {
        if t > 0.008856 {
            t.cbrt()
        } else {
            7.787 * t + 16.0 / 116.0
        }
    };
    [116.0 * f(y) - 16.0, 500.0 * (f(x) - f(y)), 200.0 * (f(y) - f(z))]
}

/// CIE76 colour difference of two sRGB colours: about 2.3 is just noticeable, 20 and more reads
/// as another colour. How the GUI tests that boxes stand out from the points.
pub fn delta_e(a: Rgba, b: Rgba) -> f32 {
    let (p, q) = (lab(a), lab(b));
    ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
}

/// The position in [0, 1] of value `v` in `range` on `scale` (log needs a positive range).
pub fn normalize(v: f32, range: (f32, f32), scale: Scale) -> f32 {
    let (lo, hi) = range;
    let t = match scale {
        Scale::Linear => (v - lo) / (hi - lo),
        Scale::Log => {
            let (l, h) = (lo.max(1e-12).ln(), hi.max(lo.max(1e-12) * 1.0001).ln());
            (v.max(1e-12).ln() - l) / (h - l)
        }
    };
    if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// The scalar a mode maps, for every point (empty for `Source`).
pub fn scalars(cloud: &FusedCloud, mode: ColorMode) -> &[f32] {
    match mode {
        ColorMode::Source => &[],
        ColorMode::Height => &cloud.z,
        ColorMode::Intensity => &cloud.intensity,
        ColorMode::Trace => &cloud.trace,
    }
}

/// A palette's ramp sampled at 1024 steps (the per-point path looks colours up).
fn ramp_lut(palette: Palette) -> &'static [Rgba; 1024] {
    static LUTS: [std::sync::OnceLock<[Rgba; 1024]>; 2] =
        [std::sync::OnceLock::new(), std::sync::OnceLock::new()];
    LUTS[palette as usize].get_or_init(|| std::array::from_fn(|i| palette.ramp(i as f32 / 1023.0)))
}

/// The colour of every point.
pub fn colorize(cloud: &FusedCloud, params: &ColorParams) -> Vec<Rgba> {
    let lut = ramp_lut(params.palette);
    let n = cloud.len();
    let mut out = vec![[0u8; 4]; n];
    let values = scalars(cloud, params.mode);
    out.par_chunks_mut(8192).enumerate().for_each(|(c, chunk)| {
        let start = c * 8192;
        for (i, o) in chunk.iter_mut().enumerate() {
            let k = start + i;
            *o = match params.mode {
                ColorMode::Source => {
                    let s = cloud.source.get(k).copied().unwrap_or(0) as usize;
                    params.palette.lidar(s)
                }
                _ => {
                    let t = normalize(values.get(k).copied().unwrap_or(0.0), params.range, params.scale);
                    lut[(t * 1023.0).round() as usize]
                }
            };
            if let (Some(th), Some(t)) = (params.highlight_above, cloud.trace.get(k)) {
                if *t > th {
                    *o = HIGHLIGHT;
                }
            }
        }
    });
    out
}

/// A robust automatic range of a scalar: the 1st and 99th percentiles (min/max for few points),
/// widened if degenerate; positive for the log scale.
pub fn auto_range(values: &[f32], scale: Scale) -> (f32, f32) {
    let mut v: Vec<f32> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if scale == Scale::Log {
        v.retain(|x| *x > 0.0);
    }
    if v.is_empty() {
        return if scale == Scale::Log {
            (1e-3, 1.0)
        } else {
            (0.0, 1.0)
        };
    }
    let pick = |q: f64, v: &mut Vec<f32>| {
        let k = ((v.len() - 1) as f64 * q).round() as usize;
        *v.select_nth_unstable_by(k, |a, b| a.total_cmp(b)).1
    };
    let (mut lo, mut hi) = (pick(0.01, &mut v), pick(0.99, &mut v));
    if hi <= lo {
        let pad = if lo.abs() > 0.0 { lo.abs() * 0.1 } else { 1.0 };
        if scale == Scale::Log {
            lo /= 1.5;
            hi = hi * 1.5 + f32::EPSILON;
        } else {
            lo -= pad;
            hi += pad;
        }
    }
    (lo, hi)
}

/// A histogram of `values` over `range` with `bins` bins on `scale` (values outside are clamped
/// into the first/last bin). Returns the counts.
pub fn histogram(values: &[f32], range: (f32, f32), scale: Scale, bins: usize) -> Vec<u32> {
    let bins = bins.max(1);
    values
        .par_chunks(16_384)
        .map(|chunk| {
            let mut h = vec![0u32; bins];
            for &v in chunk {
                if v.is_finite() {
                    let b = (normalize(v, range, scale) * bins as f32) as usize;
                    h[b.min(bins - 1)] += 1;
                }
            }
            h
        })
        .reduce(
            || vec![0u32; bins],
            |mut a, b| {
                for (x, y) in a.iter_mut().zip(b) {
                    *x += y;
                }
                a
            },
        )
}

/// Legend tick values for a range: "nice" steps on a linear scale, powers of ten (with 2 and 5
/// in between when the range is narrow) on a log scale.
pub fn ticks(range: (f32, f32), scale: Scale) -> Vec<f32> {
    let (lo, hi) = range;
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo {
        return vec![lo];
    }
    match scale {
        Scale::Linear => {
            let raw = (hi - lo) / 5.0;
            let mag = 10f32.powf(raw.log10().floor());
            let step = [1.0, 2.0, 5.0, 10.0]
                .iter()
                .map(|m| m * mag)
                .find(|s| *s >= raw)
                .unwrap_or(10.0 * mag);
            let mut t = (lo / step).ceil() * step;
            let mut out = Vec::new();
            while t <= hi + step * 1e-3 && out.len() < 20 {
                out.push(if t.abs() < step * 1e-6 { 0.0 } else { t });
                t += step;
            }
            out
        }
        Scale::Log => {
            let lo = lo.max(1e-12);
            let (a, b) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
            let mults: &[f32] = if b - a <= 2 { &[1.0, 2.0, 5.0] } else { &[1.0] };
            let mut out = Vec::new();
            for e in a..=b {
                for m in mults {
                    let v = m * 10f32.powi(e);
                    if v >= lo * 0.999 && v <= hi * 1.001 {
                        out.push(v);
                    }
                }
            }
            out
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turbo_runs_from_blue_to_red() {
        let lo = turbo(0.0);
        let hi = turbo(1.0);
        let mid = turbo(0.5);
        assert!(lo[2] > lo[0], "low end is blue-ish: {lo:?}");
        assert!(hi[0] > hi[2], "high end is red-ish: {hi:?}");
        assert!(mid[1] > 200, "middle is green/yellow: {mid:?}");
        assert_eq!(turbo(f32::NAN), turbo(0.0));
    }

    #[test]
    fn no_point_colour_is_near_a_box_colour() {
        // The GUI's box colours: proposal blue, refined red, ground-truth green, selected amber
        // (ΔE ≥ 25), and the greyed blue and red of false positives (ΔE ≥ 20).
        let boxes = [
            ([70, 150, 255, 255], 25.0),
            ([235, 60, 60, 255], 25.0),
            ([70, 230, 110, 255], 25.0),
            ([255, 200, 40, 255], 25.0),
            ([150, 160, 200, 255], 20.0),
            ([200, 150, 150, 255], 20.0),
        ];
        for palette in Palette::ALL {
            let points = (0..=100)
                .map(|i| palette.ramp(i as f32 / 100.0))
                .chain((0..3).map(|s| palette.lidar(s)))
                .chain([HIGHLIGHT]);
            for p in points {
                for (b, min) in boxes {
                    let d = delta_e(p, b);
                    assert!(d >= min, "{palette:?}: point {p:?} vs box {b:?}: ΔE {d:.1}");
                }
            }
        }
        assert_eq!(Palette::Standard.ramp(f32::NAN), Palette::Standard.ramp(0.0));
        let lum = |c: Rgba| u32::from(c[0]) + u32::from(c[1]) + u32::from(c[2]);
        for palette in Palette::ALL {
            let l: Vec<u32> = (0..=20).map(|i| lum(palette.ramp(i as f32 / 20.0))).collect();
            assert!(l.first() < l.last(), "{palette:?} gets lighter with the value");
        }
    }

    #[test]
    fn normalize_and_ticks() {
        assert_eq!(normalize(5.0, (0.0, 10.0), Scale::Linear), 0.5);
        assert!((normalize(0.01, (0.001, 0.1), Scale::Log) - 0.5).abs() < 1e-5);
        assert_eq!(normalize(-1.0, (0.0, 1.0), Scale::Linear), 0.0);
        assert_eq!(
            normalize(1.0, (1.0, 1.0), Scale::Linear),
            0.0,
            "degenerate range does not give NaN"
        );
        let lin = ticks((0.0, 1.0), Scale::Linear);
        assert_eq!(lin.len(), 6);
        assert!(lin
            .iter()
            .zip([0.0, 0.2, 0.4, 0.6, 0.8, 1.0])
            .all(|(a, b)| (a - b).abs() < 1e-5));
        let t = ticks((1e-3, 1.0), Scale::Log);
        assert_eq!(t.len(), 4);
        assert!((t[0] - 1e-3).abs() < 1e-9 && (t[3] - 1.0).abs() < 1e-6);
        assert!(ticks((0.01, 0.2), Scale::Log).len() >= 4);
    }

    #[test]
    fn lookup_table_matches_the_colormap() {
        let lut = ramp_lut(Palette::Standard);
        for i in [0usize, 1, 511, 1023] {
            assert_eq!(lut[i], Palette::Standard.ramp(i as f32 / 1023.0));
        }
        // Neighbouring entries differ by at most a few levels: the table is fine enough.
        let max_step = lut
            .windows(2)
            .flat_map(|w| (0..3).map(move |c| w[0][c].abs_diff(w[1][c])))
            .max()
            .unwrap();
        assert!(max_step <= 4, "{max_step}");
    }

    #[test]
    fn histogram_counts_every_finite_value() {
        let v: Vec<f32> = (0..100_000)
            .map(|i| (i % 100) as f32 / 100.0)
            .chain([f32::NAN, 5.0])
            .collect();
        let h = histogram(&v, (0.0, 1.0), Scale::Linear, 10);
        assert_eq!(h.iter().sum::<u32>(), 100_001);
        assert_eq!(h[0], 10_000);
        assert_eq!(h[9], 10_001, "5.0 is clamped into the last bin");
    }

    #[test]
    fn auto_range_ignores_outliers() {
        let mut v: Vec<f32> = (0..1000).map(|i| i as f32 / 1000.0).collect();
        v.push(1e6);
        let (lo, hi) = auto_range(&v, Scale::Linear);
        assert!(lo < 0.02 && (0.98..1.0).contains(&hi));
        let (lo, hi) = auto_range(&[0.5, 0.5], Scale::Log);
        assert!(lo < 0.5 && hi > 0.5);
        assert_eq!(auto_range(&[], Scale::Linear), (0.0, 1.0));
    }
}
