//! `mlod stats`: a dataset's sensor statistics (points per sweep, rings, intensity, ground
//! height, ray drop, range, points per object against range) as text, JSON and PNG; its summary
//! into the models' manifest; and the notes `mlod detect` / `mlod eval` print when a dataset lies
//! outside the models' training data.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

use mlod::dataset::stats::{DatasetStats, LidarStats, StatsOptions, TrainingStats};
use mlod::dataset::Dataset;

/// Samples `mlod detect` and `mlod eval` summarise to compare a dataset with the training data.
pub const NOTE_SAMPLES: usize = 5;

#[derive(clap::Args)]
pub struct StatsArgs {
    /// The dataset (Lyft, nuScenes or KITTI folder).
    #[arg(long)]
    dataset: PathBuf,
    /// Use this many samples, evenly spaced over the scene order (default: all).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=10_000_000))]
    samples: Option<u64>,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
    /// Only the compact summary stored with the models (cheaper: no points-in-box counts and no
    /// return ratio).
    #[arg(long, conflicts_with_all = ["out", "compare", "per_box"])]
    summary: bool,
    /// Add every box (sample, category, range, size, points inside) to the JSON.
    #[arg(long)]
    per_box: bool,
    /// Also write stats.json and the plots (points_per_box.png, intensity.png, range.png) here.
    #[arg(long)]
    out: Option<PathBuf>,
    /// A second dataset, drawn beside the first in the plots (same --samples); with --out its
    /// statistics go to compare.json.
    #[arg(long)]
    compare: Option<PathBuf>,
    /// Store the summary as the training data's in DIR/manifest.json (`training_stats`), which
    /// `mlod detect` and `mlod eval` compare datasets with.
    #[arg(long, value_name = "MODELS_DIR")]
    update_manifest: Option<PathBuf>,
}

pub fn run(a: StatsArgs) -> Result<()> {
    if let Some(dir) = &a.update_manifest {
        // Fail before the work if the manifest cannot be read.
        mlod::detect::weights::Manifest::load(dir)?;
    }
    let opts = StatsOptions {
        samples: a.samples.map(|n| n as usize),
        points_in_boxes: !a.summary,
        return_ratio: !a.summary,
    };
    let stats = compute(&a.dataset, &opts)?;
    let compare = match &a.compare {
        Some(p) => Some(compute(p, &opts)?),
        None => None,
    };
    if let Some(dir) = &a.update_manifest {
        let mut m = mlod::detect::weights::Manifest::load(dir)?;
        m.training_stats = Some(TrainingStats {
            command: super::args::command_line(),
            summary: stats.summary(),
        });
        m.save(dir)?;
        eprintln!(
            "wrote the training data's summary ({} samples) to {}",
            stats.samples,
            dir.join(mlod::detect::weights::Manifest::FILE).display()
        );
    }
    if let Some(dir) = &a.out {
        let mut files = vec![dir.join("stats.json")];
        write_json(&files[0], &stats, a.per_box)?;
        let label_a = label(&a.dataset);
        let mut sets = vec![(label_a.as_str(), &stats)];
        let label_b = a.compare.as_deref().map(|p| {
            let l = label(p);
            if l == label_a {
                format!("{l} (2)")
            } else {
                l
            }
        });
        if let (Some(c), Some(l)) = (&compare, &label_b) {
            let p = dir.join("compare.json");
            write_json(&p, c, a.per_box)?;
            files.push(p);
            sets.push((l.as_str(), c));
        }
        files.extend(mlod::analysis::plot::stats_pngs(&sets, dir)?);
        for f in &files {
            eprintln!("wrote {}", f.display());
        }
    }
    if a.json {
        if a.summary {
            println!("{}", serde_json::to_string_pretty(&stats.summary())?);
        } else {
            println!("{}", to_json(&stats, a.per_box)?);
            if let Some(c) = &compare {
                println!("{}", to_json(c, a.per_box)?);
            }
        }
        return Ok(());
    }
    if a.summary {
        print_summary(&stats);
        return Ok(());
    }
    print_text(&stats);
    if let Some(c) = &compare {
        println!();
        print_text(c);
    }
    Ok(())
}

fn compute(path: &Path, opts: &StatsOptions) -> Result<DatasetStats> {
    let ds = super::open_dataset(path)?;
    let stats = mlod::dataset::dataset_stats(&ds, opts)
        .with_context(|| format!("statistics of {}", path.display()))?;
    for f in &stats.failures {
        eprintln!("warning: skipped sample {f}");
    }
    Ok(stats)
}

/// The dataset's folder name (`test`, `kitti`), for legends.
fn label(p: &Path) -> String {
    let p = if p
        .file_name()
        .is_some_and(|n| n == "training" || n.to_string_lossy().starts_with("v1."))
    {
        p.parent().unwrap_or(p)
    } else {
        p
    };
    p.file_name()
        .map_or_else(|| p.display().to_string(), |n| n.to_string_lossy().into_owned())
}

fn to_json(stats: &DatasetStats, per_box: bool) -> Result<String> {
    if per_box {
        return Ok(serde_json::to_string_pretty(stats)?);
    }
    let lean = DatasetStats {
        boxes: Vec::new(),
        ..stats.clone()
    };
    Ok(serde_json::to_string_pretty(&lean)?)
}

fn write_json(path: &Path, stats: &DatasetStats, per_box: bool) -> Result<()> {
    let mut s = to_json(stats, per_box)?;
    s.push('\n');
    mlod::io::write_atomic(path, s.as_bytes())?;
    Ok(())
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "-".to_owned(), |v| format!("{v:.digits$}"))
}

fn print_summary(stats: &DatasetStats) {
    let s = stats.summary();
    println!(
        "{} ({}), {} samples",
        stats.dataset.display(),
        stats.format.name(),
        s.samples
    );
    println!("  LiDARs                {}", s.lidars.join(", "));
    println!(
        "  LIDAR_TOP rings       {}",
        match (s.rings, s.rings_per_sweep) {
            (None, _) => "unknown".to_owned(),
            (Some(r), Some([lo, hi])) if lo < hi => format!("{r} ({lo}–{hi} per sweep)"),
            (Some(r), _) => r.to_string(),
        }
    );
    match s.intensity_constant {
        Some(v) => println!("  intensity             constant {v}"),
        None => println!(
            "  intensity             median {:.1} (5th–95th percentile {:.1}–{:.1})",
            s.intensity_median, s.intensity_p05, s.intensity_p95
        ),
    }
    println!("  ground height (m)     {}", opt(s.ground_height_m, 2));
    let span = s
        .points_per_sweep_range
        .map_or(String::new(), |[lo, hi]| format!("; {lo:.0}–{hi:.0}"));
    println!(
        "  points per sweep      {:.0} (median{span})",
        s.points_per_sweep_median
    );
    if let Some([l, w, h]) = s.car_size_mean_lwh {
        println!("  car size (m, mean)    l {l:.2}  w {w:.2}  h {h:.2}");
    }
}

fn print_text(stats: &DatasetStats) {
    println!(
        "{} ({}): {} samples used, {} failed",
        stats.dataset.display(),
        stats.format.name(),
        stats.samples,
        stats.failed_samples
    );
    println!(
        "\n{:<18} {:>6} {:>22} {:>6} {:>24} {:>8} {:>8} {:>8}",
        "LiDAR",
        "sweeps",
        "points/sweep (min–max)",
        "rings",
        "intensity med (p05–p95)",
        "ground",
        "returns",
        "range"
    );
    for l in &stats.lidars {
        print_lidar(l);
    }
    println!(
        "  ground: height of the sensor above the densest 0.1 m height bin at 3–20 m (median over sweeps);"
    );
    println!("  returns: share of emitted rays that returned; range: median distance from the sensor (m)");
    println!("\nobjects: boxes, mean size (l × w × h, m), then per range bin: boxes / median points inside");
    let head: Vec<String> = mlod::dataset::stats::OBJECT_BIN_EDGES_M
        .iter()
        .enumerate()
        .map(
            |(k, e)| match mlod::dataset::stats::OBJECT_BIN_EDGES_M.get(k + 1) {
                Some(t) => format!("{e:.0}–{t:.0}"),
                None => format!("{e:.0}+"),
            },
        )
        .collect();
    println!(
        "{:<18} {:>6} {:>18}  {}",
        "category",
        "boxes",
        "size",
        head.iter().map(|h| format!("{h:>10}")).collect::<String>()
    );
    for c in &stats.objects {
        let [l, w, h] = c.size_mean_lwh;
        let bins: String = c
            .range_bins
            .iter()
            .map(|b| {
                let cell = if b.boxes == 0 {
                    "-".to_owned()
                } else {
                    format!("{}/{}", b.boxes, opt(b.median_points, 0))
                };
                format!("{cell:>10}")
            })
            .collect();
        println!(
            "{:<18} {:>6} {:>18}  {bins}",
            c.category,
            c.boxes,
            format!("{l:.2}×{w:.2}×{h:.2}")
        );
    }
}

fn print_lidar(l: &LidarStats) {
    let p = &l.points_per_sweep;
    let i = &l.intensity;
    let intensity = match i.constant {
        Some(v) => format!("constant {v}"),
        None => format!("{:.1} ({:.1}–{:.1})", i.median, i.p05, i.p95),
    };
    println!(
        "{:<18} {:>6} {:>22} {:>6} {:>24} {:>8} {:>8} {:>8.1}",
        l.channel.as_str(),
        l.sweeps,
        format!("{:.0} ({:.0}–{:.0})", p.median, p.min, p.max),
        l.rings.map_or("-".to_owned(), |r| r.to_string()),
        intensity,
        opt(l.ground_height_m, 2),
        opt(l.return_ratio, 3),
        l.range.median
    );
}

/// Prints on stderr, as `note: …`, what differs between `dataset` (summarised over
/// [`NOTE_SAMPLES`] samples) and the training data's summary in `models_dir`'s manifest. Silent
/// when the manifest has no summary or the dataset cannot be summarised (the command's own work
/// reports such errors).
pub fn print_training_notes(dataset: &Dataset, models_dir: &Path) {
    let Ok(Some(trained)) = mlod::detect::weights::read_training_stats(models_dir) else {
        return;
    };
    let Ok(data) = mlod::dataset::summarize(dataset, NOTE_SAMPLES) else {
        return;
    };
    let notes = mlod::detect::weights::training_notes(models_dir, &data);
    if notes.is_empty() {
        return;
    }
    eprintln!(
        "note: this dataset differs from the models' training data ({} samples of it against {} of the training data; `mlod stats` for more):",
        data.samples, trained.samples
    );
    for n in notes {
        eprintln!("note: {n}");
    }
}
