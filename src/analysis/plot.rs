//! PNG plots for the CLI reports (plotters on an in-memory bitmap, written atomically).
//! Text uses the Ubuntu Light font that egui also ships, so plots look the same everywhere.

use std::path::Path;
use std::sync::Once;

use plotters::prelude::*;
use plotters::style::FontStyle;

use crate::io::{write_atomic, IoError};
use crate::uncertainty::plane::PlaneFitRow;

/// A plotting failure.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("drawing the plot failed: {0}")]
    Draw(String),
    #[error(transparent)]
    Io(#[from] IoError),
    #[error("nothing to plot: {0}")]
    Empty(String),
}

fn draw_err<E: std::fmt::Display>(e: E) -> PlotError {
    PlotError::Draw(e.to_string())
}

static FONT: Once = Once::new();

fn register_fonts() {
    FONT.call_once(|| {
        // Fails only on a corrupt embedded font; text would then be missing, not wrong.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            epaint_default_fonts::UBUNTU_LIGHT,
        );
    });
}

/// Encodes an 8-bit RGB or RGBA buffer as PNG and writes it atomically.
pub fn write_png(
    path: &Path,
    width: u32,
    height: u32,
    pixels: &[u8],
    color: image::ExtendedColorType,
) -> Result<(), PlotError> {
    let mut bytes = Vec::new();
    let encoder = image::codecs::png::PngEncoder::new(&mut bytes);
    image::ImageEncoder::write_image(encoder, pixels, width, height, color).map_err(draw_err)?;
    write_atomic(path, &bytes)?;
    Ok(())
}

/// Fig. 2 of the paper: mean plane-fitting error against α, weighted and unweighted, one panel
/// per planar case, log-scale error axis.
pub fn plane_fit_png(rows: &[PlaneFitRow], path: &Path) -> Result<(), PlotError> {
    register_fonts();
    let mut cases: Vec<&str> = Vec::new();
    for r in rows {
        if !cases.contains(&r.case.as_str()) {
            cases.push(&r.case);
        }
    }
    if cases.is_empty() {
        return Err(PlotError::Empty("no plane-fit rows".into()));
    }
    let (w, h) = (520 * cases.len() as u32, 420u32);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let panels = root.split_evenly((1, cases.len()));
        for (panel, case) in panels.iter().zip(&cases) {
            let rs: Vec<&PlaneFitRow> = rows.iter().filter(|r| r.case == *case).collect();
            let a_max = rs.iter().map(|r| r.alpha).fold(0.0f64, f64::max).max(1e-3);
            let vals = rs.iter().flat_map(|r| [r.weighted_error, r.unweighted_error]);
            let (lo, hi) = vals.fold((f64::INFINITY, 0.0f64), |(lo, hi), v| (lo.min(v), hi.max(v)));
            let lo = (lo.max(1e-9) * 0.5).log10().floor();
            let hi = (hi.max(1e-8) * 2.0).log10().ceil();
            let mut chart = ChartBuilder::on(panel)
                .caption(format!("Plane fitting: {case}"), ("sans-serif", 22))
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(64)
                .build_cartesian_2d(0.0..a_max, (10f64.powf(lo)..10f64.powf(hi)).log_scale())
                .map_err(draw_err)?;
            chart
                .configure_mesh()
                .x_desc("α")
                .y_desc("mean ||x_gt − x_est||")
                .label_style(("sans-serif", 14))
                .axis_desc_style(("sans-serif", 16))
                .y_label_formatter(&|v| format!("{v:.0e}"))
                .draw()
                .map_err(draw_err)?;
            let series = [
                ("with weights (uncertainty prior)", RGBColor(214, 39, 40), true),
                ("without weights", RGBColor(31, 119, 180), false),
            ];
            for (label, color, weighted) in series {
                let pts: Vec<(f64, f64)> = rs
                    .iter()
                    .map(|r| {
                        (
                            r.alpha,
                            if weighted {
                                r.weighted_error
                            } else {
                                r.unweighted_error
                            },
                        )
                    })
                    .collect();
                chart
                    .draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))
                    .map_err(draw_err)?
                    .label(label)
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2)));
                chart
                    .draw_series(pts.into_iter().map(|p| Circle::new(p, 3, color.filled())))
                    .map_err(draw_err)?;
            }
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperLeft)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK.mix(0.3))
                .label_font(("sans-serif", 14))
                .draw()
                .map_err(draw_err)?;
        }
        root.present().map_err(draw_err)?;
    }
    write_png(path, w, h, &buf, image::ExtendedColorType::Rgb8)
}

/// A histogram of `values` over `range` in `bins` bins, with vertical marks (dashed) at `marks`
/// and a caption; bars outside the range are counted in the edge bins.
pub fn histogram_png(
    values: &[f64],
    range: (f64, f64),
    bins: usize,
    marks: &[f64],
    caption: &str,
    x_desc: &str,
    path: &Path,
) -> Result<(), PlotError> {
    register_fonts();
    let bins = bins.max(1);
    let (lo, hi) = range;
    if !(lo.is_finite() && hi.is_finite() && hi > lo) {
        return Err(PlotError::Empty(format!("bad range {lo}..{hi}")));
    }
    let mut counts = vec![0usize; bins];
    for v in values.iter().filter(|v| v.is_finite()) {
        let k = (((v - lo) / (hi - lo)) * bins as f64)
            .floor()
            .clamp(0.0, bins as f64 - 1.0) as usize;
        counts[k] += 1;
    }
    let top = counts.iter().copied().max().unwrap_or(0).max(1) as f64 * 1.1;
    let (w, h) = (720u32, 440u32);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(caption, ("sans-serif", 20))
            .margin(14)
            .x_label_area_size(44)
            .y_label_area_size(56)
            .build_cartesian_2d(lo..hi, 0.0..top)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc(x_desc)
            .y_desc("samples")
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 16))
            .draw()
            .map_err(draw_err)?;
        let width = (hi - lo) / bins as f64;
        chart
            .draw_series(counts.iter().enumerate().map(|(k, &c)| {
                let x0 = lo + k as f64 * width;
                Rectangle::new(
                    [(x0, 0.0), (x0 + width * 0.92, c as f64)],
                    RGBColor(31, 119, 180).filled(),
                )
            }))
            .map_err(draw_err)?;
        for &m in marks {
            chart
                .draw_series(DashedLineSeries::new(
                    vec![(m, 0.0), (m, top)],
                    6,
                    4,
                    RGBColor(214, 39, 40).stroke_width(2),
                ))
                .map_err(draw_err)?;
        }
        root.present().map_err(draw_err)?;
    }
    write_png(path, w, h, &buf, image::ExtendedColorType::Rgb8)
}

/// How each of a plot's series is drawn: its colour (an index into [`SERIES_COLOURS`], one per
/// family) and whether it is dashed. A series labelled "X (OC)" is dashed in the colour of "X"; families are
/// numbered in the order they first appear. The sweep PNG and the sweep window both use this.
pub fn series_styles<'a>(labels: impl IntoIterator<Item = &'a str>) -> Vec<(usize, bool)> {
    let mut families: Vec<&str> = Vec::new();
    labels
        .into_iter()
        .map(|label| {
            let family = label.strip_suffix(" (OC)").unwrap_or(label);
            let k = families.iter().position(|f| *f == family).unwrap_or_else(|| {
                families.push(family);
                families.len() - 1
            });
            (k, family.len() != label.len())
        })
        .collect()
}

pub const TAB10: [[u8; 3]; 10] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [127, 127, 127],
    [188, 189, 34],
    [23, 190, 207],
];

/// The sweep plot's curve colours, here and in the window: tab10, then six more of mid luminance
/// (readable on the PNG's white and the window's dark background), so that a sweep of up to 16
/// case families (Table II's seven with the cases beyond the paper) never repeats a colour.
pub const SERIES_COLOURS: [[u8; 3]; 16] = [
    TAB10[0],
    TAB10[1],
    TAB10[2],
    TAB10[3],
    TAB10[4],
    TAB10[5],
    TAB10[6],
    TAB10[7],
    TAB10[8],
    TAB10[9],
    [100, 130, 255],
    [230, 0, 230],
    [0, 200, 110],
    [205, 130, 40],
    [255, 200, 0],
    [255, 110, 110],
];

/// A labelled curve: points (x, mean, std).
pub type Curve = (String, Vec<(f64, f64, f64)>);

/// One curve per series (label, points (x, mean, std)) with error bars of ±std, for the sweep's
/// AP-against-α plot; [`SERIES_COLOURS`], the legend outside the curves.
pub fn curves_with_error_bars_png(
    series: &[Curve],
    title: &str,
    x_desc: &str,
    y_desc: &str,
    path: &Path,
) -> Result<(), PlotError> {
    register_fonts();
    let pts = series.iter().flat_map(|(_, p)| p.iter());
    let (mut x0, mut x1, mut y0, mut y1) =
        (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for &(x, m, s) in pts {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(m - s);
        y1 = y1.max(m + s);
    }
    if !x0.is_finite() || !y0.is_finite() {
        return Err(PlotError::Empty("no points to plot".into()));
    }
    let pad = ((x1 - x0) * 0.05).max(0.002);
    let (y0, y1) = ((y0 - 2.0).max(0.0).floor(), (y1 + 2.0).min(100.0).ceil());
    let (w, h) = (900u32, 560u32);
    let palette = SERIES_COLOURS.map(|[r, g, b]| RGBColor(r, g, b));
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 22))
            .margin(14)
            .x_label_area_size(44)
            .y_label_area_size(56)
            .build_cartesian_2d((x0 - pad)..(x1 + pad), y0..y1)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc(x_desc)
            .y_desc(y_desc)
            .label_style(("sans-serif", 15))
            .axis_desc_style(("sans-serif", 17))
            .draw()
            .map_err(draw_err)?;
        let styles = series_styles(series.iter().map(|(l, _)| l.as_str()));
        for ((label, p), (k, dashed)) in series.iter().zip(styles) {
            let color = palette[k % palette.len()];
            let line: Vec<(f64, f64)> = p.iter().map(|&(x, m, _)| (x, m)).collect();
            // Legend marks are drawn relative to the legend entry's anchor.
            let legend = move |(x, y): (i32, i32)| {
                let (a, b) = if dashed {
                    (vec![(0, 0), (7, 0)], vec![(11, 0), (18, 0)])
                } else {
                    (vec![(0, 0), (18, 0)], vec![(0, 0), (0, 0)])
                };
                EmptyElement::at((x, y))
                    + PathElement::new(a, color.stroke_width(2))
                    + PathElement::new(b, color.stroke_width(2))
            };
            if dashed {
                chart
                    .draw_series(DashedLineSeries::new(line.clone(), 8, 5, color.stroke_width(2)))
                    .map_err(draw_err)?
                    .label(label.as_str())
                    .legend(legend);
            } else {
                chart
                    .draw_series(LineSeries::new(line.clone(), color.stroke_width(2)))
                    .map_err(draw_err)?
                    .label(label.as_str())
                    .legend(legend);
            }
            // Error bars: a vertical segment of ±std with short caps.
            let cap = pad * 0.25;
            chart
                .draw_series(p.iter().flat_map(|&(x, m, s)| {
                    [
                        PathElement::new(vec![(x, m - s), (x, m + s)], color.stroke_width(2)),
                        PathElement::new(vec![(x - cap, m - s), (x + cap, m - s)], color.stroke_width(2)),
                        PathElement::new(vec![(x - cap, m + s), (x + cap, m + s)], color.stroke_width(2)),
                    ]
                }))
                .map_err(draw_err)?;
            chart
                .draw_series(line.into_iter().map(|q| Circle::new(q, 3, color.filled())))
                .map_err(draw_err)?;
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerLeft)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.3))
            .label_font(("sans-serif", 15))
            .draw()
            .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    write_png(path, w, h, &buf, image::ExtendedColorType::Rgb8)
}

/// A dataset's statistics with the label its series carry.
pub type LabelledStats<'a> = (&'a str, &'a crate::dataset::DatasetStats);

/// `mlod stats --out`'s plots of one or more datasets (one colour each): `points_per_box.png`
/// (points inside each box against its range, a panel per category, the median per range bin
/// joined), `intensity.png` and `range.png` (each LiDAR's share of points per bin). Axes are
/// fixed (0–80 m, 0–256, 0–160 m) so that plots of different datasets compare. Returns the files.
pub fn stats_pngs(sets: &[LabelledStats<'_>], dir: &Path) -> Result<Vec<std::path::PathBuf>, PlotError> {
    let mut written = Vec::new();
    let p = dir.join("points_per_box.png");
    points_per_box_png(sets, &p)?;
    written.push(p);
    let share = |h: &crate::dataset::stats::Histogram, overflow_at: Option<f64>| {
        let total = h.total().max(1) as f64;
        let mut pts: Vec<(f64, f64)> = h
            .edges
            .windows(2)
            .zip(&h.counts)
            .map(|(e, &c)| (0.5 * (e[0] + e[1]), c as f64 / total))
            .collect();
        if let Some(x) = overflow_at {
            pts.push((x, h.above as f64 / total));
        }
        pts
    };
    let series = |pick: &dyn Fn(&crate::dataset::stats::LidarStats) -> Vec<(f64, f64)>| {
        sets.iter()
            .flat_map(|(label, s)| {
                s.lidars
                    .iter()
                    .map(move |l| (format!("{label} {}", l.channel), pick(l)))
            })
            .collect::<Vec<_>>()
    };
    let p = dir.join("intensity.png");
    lines_png(
        &series(&|l| share(&l.intensity.histogram, None)),
        "Intensity",
        "intensity (8-wide bins)",
        "share of the LiDAR's points",
        (0.0, 256.0),
        &p,
    )?;
    written.push(p);
    let p = dir.join("range.png");
    lines_png(
        &series(&|l| share(&l.range.histogram, Some(155.0))),
        "Range from the sensor (150+ m at 155)",
        "range (m, 10 m bins)",
        "share of the LiDAR's points",
        (0.0, 160.0),
        &p,
    )?;
    written.push(p);
    Ok(written)
}

/// Series (label, points) as lines with markers, one TAB10 colour each, the legend top right.
fn lines_png(
    series: &[(String, Vec<(f64, f64)>)],
    title: &str,
    x_desc: &str,
    y_desc: &str,
    x_range: (f64, f64),
    path: &Path,
) -> Result<(), PlotError> {
    register_fonts();
    let top = series
        .iter()
        .flat_map(|(_, p)| p.iter().map(|q| q.1))
        .fold(0.0f64, f64::max);
    if series.is_empty() || top <= 0.0 {
        return Err(PlotError::Empty(format!("{title}: no points")));
    }
    let (w, h) = (900u32, 520u32);
    let palette = TAB10.map(|[r, g, b]| RGBColor(r, g, b));
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 22))
            .margin(14)
            .x_label_area_size(44)
            .y_label_area_size(64)
            .build_cartesian_2d(x_range.0..x_range.1, 0.0..top * 1.1)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc(x_desc)
            .y_desc(y_desc)
            .label_style(("sans-serif", 15))
            .axis_desc_style(("sans-serif", 17))
            .x_label_formatter(&|v| format!("{v:.0}"))
            .draw()
            .map_err(draw_err)?;
        for (k, (label, pts)) in series.iter().enumerate() {
            let color = palette[k % palette.len()];
            chart
                .draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))
                .map_err(draw_err)?
                .label(label.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2)));
            chart
                .draw_series(pts.iter().map(|&q| Circle::new(q, 3, color.filled())))
                .map_err(draw_err)?;
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.3))
            .label_font(("sans-serif", 15))
            .draw()
            .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    write_png(path, w, h, &buf, image::ExtendedColorType::Rgb8)
}

/// Points inside each box (+1, log scale) against its range, a panel per category (the six with
/// most boxes), one colour per dataset; the median per 10 m bin (70+ at 75 m) joined by a line.
fn points_per_box_png(sets: &[LabelledStats<'_>], path: &Path) -> Result<(), PlotError> {
    register_fonts();
    let mut cats: Vec<(String, usize)> = Vec::new();
    for (_, s) in sets {
        for c in &s.objects {
            match cats.iter_mut().find(|(n, _)| *n == c.category) {
                Some(e) => e.1 += c.boxes,
                None => cats.push((c.category.clone(), c.boxes)),
            }
        }
    }
    cats.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    cats.truncate(6);
    if cats.is_empty() {
        return Err(PlotError::Empty("no boxes".into()));
    }
    let y_max = sets
        .iter()
        .flat_map(|(_, s)| s.boxes.iter().filter_map(|b| b.points))
        .max()
        .unwrap_or(1) as f64;
    let y_top = 10f64.powf((y_max + 1.0).log10().ceil().max(1.0));
    let cols = cats.len().min(3);
    let rows = cats.len().div_ceil(cols);
    let (w, h) = (460 * cols as u32, 400 * rows as u32 + 40);
    let palette = TAB10.map(|[r, g, b]| RGBColor(r, g, b));
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let legend: Vec<String> = sets
            .iter()
            .map(|(label, s)| format!("{label}: {} samples", s.samples))
            .collect();
        let root = root
            .titled(
                &format!("Points inside each box against range ({})", legend.join(", ")),
                ("sans-serif", 20),
            )
            .map_err(draw_err)?;
        let panels = root.split_evenly((rows, cols));
        for (panel, (cat, _)) in panels.iter().zip(&cats) {
            let mut chart = ChartBuilder::on(panel)
                .caption(cat.as_str(), ("sans-serif", 18))
                .margin(10)
                .x_label_area_size(38)
                .y_label_area_size(56)
                .build_cartesian_2d(0.0..80.0, (1.0..y_top).log_scale())
                .map_err(draw_err)?;
            chart
                .configure_mesh()
                .x_desc("box centre range (m)")
                .y_desc("points in box + 1")
                .x_label_formatter(&|v| format!("{v:.0}"))
                .label_style(("sans-serif", 13))
                .axis_desc_style(("sans-serif", 14))
                .y_label_formatter(&|v| format!("{v:.0}"))
                .draw()
                .map_err(draw_err)?;
            for (k, (label, s)) in sets.iter().enumerate() {
                let color = palette[k % palette.len()];
                let pts: Vec<(f64, f64)> = s
                    .boxes
                    .iter()
                    .filter(|b| b.category == *cat)
                    .filter_map(|b| b.points.map(|p| (b.range_m.min(79.5), p as f64 + 1.0)))
                    .collect();
                chart
                    .draw_series(pts.iter().map(|&q| Circle::new(q, 2, color.mix(0.35).filled())))
                    .map_err(draw_err)?;
                let medians: Vec<(f64, f64)> = s
                    .category(cat)
                    .map(|c| {
                        c.range_bins
                            .iter()
                            .filter_map(|b| b.median_points.map(|m| (b.from_m + 5.0, m + 1.0)))
                            .collect()
                    })
                    .unwrap_or_default();
                chart
                    .draw_series(LineSeries::new(medians.clone(), color.stroke_width(3)))
                    .map_err(draw_err)?
                    .label(format!("{label} median"))
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(3)));
                chart
                    .draw_series(medians.iter().map(|&q| Circle::new(q, 5, color.filled())))
                    .map_err(draw_err)?;
            }
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperRight)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK.mix(0.3))
                .label_font(("sans-serif", 13))
                .draw()
                .map_err(draw_err)?;
        }
        root.present().map_err(draw_err)?;
    }
    write_png(path, w, h, &buf, image::ExtendedColorType::Rgb8)
}

#[cfg(test)]
mod tests {
    #[test]
    fn an_oc_series_is_dashed_in_its_family_colour() {
        let styles = super::series_styles([
            "Input Fusion",
            "MLOD-I",
            "MLOD-I (OC)",
            "Input Fusion (OC)",
            "LiDAR-Top",
        ]);
        assert_eq!(styles, [(0, false), (1, false), (1, true), (0, true), (2, false)]);
    }

    #[test]
    fn sixteen_families_get_sixteen_colours() {
        let mut seen = super::SERIES_COLOURS.to_vec();
        seen.sort_unstable();
        seen.dedup();
        assert_eq!(seen.len(), 16);
    }
}
