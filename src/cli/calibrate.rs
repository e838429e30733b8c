//! `mlod calibrate`: online calibration (point-to-plane ICP) of the auxiliary LiDARs of one or
//! more samples under the perturbation of `mlod fuse`/`mlod eval` with the same α and seed: per
//! sample and LiDAR the error against the true extrinsic before and after, fitness, RMSE,
//! iterations, convergence, degenerate directions, the estimated covariance and the time; over
//! several samples also the median, p90 and worst errors.

use std::path::PathBuf;

use anyhow::{Context, Result};
use serde::Serialize;

use mlod::calib::report::{CalibrationRun, Estimate};
use mlod::calib::{IcpConfig, OcPrior, PoseError};
use mlod::dataset::{Dataset, Frame};
use mlod::pipeline::{calibrate, FuseParams};
use mlod::uncertainty::Perturbation;

use super::args::parse_alpha;

#[derive(clap::Args)]
pub struct CalibrateArgs {
    /// Dataset root or its version folder.
    #[arg(long)]
    pub dataset: PathBuf,
    /// One sample (default: the first in scene order).
    #[arg(long, conflicts_with = "samples")]
    pub sample: Option<String>,
    /// The first N samples in scene order (with --spread: N samples spread evenly over the
    /// dataset, every scene's share).
    #[arg(long)]
    pub samples: Option<usize>,
    #[arg(long, requires = "samples")]
    pub spread: bool,
    /// Only the validation scenes (every 10th scene, as `mlod eval --validation`): where the
    /// ICP settings are chosen.
    #[arg(long)]
    pub validation: bool,
    /// α of the injected perturbation (as `mlod fuse --alpha`).
    #[arg(long, default_value_t = 0.0, value_parser = parse_alpha, allow_hyphen_values = true)]
    pub alpha: f64,
    /// Seed of the perturbation draw (as `mlod fuse --seed`).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Draw the perturbation anew for every sample (seed + sample index) instead of one drift for
    /// all samples, as on one car: more distinct starts for an accuracy table.
    #[arg(long)]
    pub per_sample: bool,
    /// N perturbation draws per sample (seeds seed … seed+N−1), each started from its own drifted
    /// extrinsic, plus one run started from the dataset's calibration (α = 0): that run's result
    /// is ICP's fixed point, and every draw's distance to it is reported (repeatability; on real
    /// data, where the factory calibration is not the truth).
    #[arg(long, conflicts_with = "per_sample")]
    pub draws: Option<usize>,
    /// Instead of calibrating from the perturbation: the auxiliary LiDARs' point-to-plane
    /// residuals on the primary's surfaces, per surface and range, at the dataset's extrinsics
    /// and at ICP's fixed point (which of the two aligns the surfaces better).
    #[arg(long)]
    pub alignment: bool,
    /// Instead of calibrating: the χ² check of Ξ at --alpha over --draws (default 20) unbounded
    /// draws: how far each auxiliary point moves off the primary's surfaces against √(nᵀΞn).
    #[arg(long)]
    pub xi_check: bool,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    /// Override an ICP setting, e.g. `--icp source_voxel=0.4 --icp max_range=40` (the fields of
    /// `mlod::calib::IcpConfig`; defaults in docs/calibration.md).
    #[arg(long = "icp", value_name = "KEY=VALUE")]
    pub icp: Vec<String>,
    /// Also write, per sample, the downsampled clouds and the start/true extrinsics ICP worked
    /// on (`<token>.target.xyz`, `<token>.<channel>.source.xyz`, `<token>.json`), e.g. for the
    /// Open3D reference (`tests/open3d/icp_reference.py`).
    #[arg(long)]
    pub dump: Option<PathBuf>,
}

#[derive(Serialize, Default)]
struct Quantiles {
    median: f64,
    p90: f64,
    p95: f64,
    worst: f64,
}

/// With `--draws`: where the draws landed against ICP's fixed point.
#[derive(Serialize)]
struct Repeatability {
    /// The runs started from the dataset's calibration, one per sample and LiDAR.
    fixed_points: Vec<FixedPoint>,
    rot_deg: Quantiles,
    trans_m: Quantiles,
    /// Draws within 0.01° and 1 mm of their fixed point.
    within_001deg_1mm: usize,
    /// Draws farther than that without a flag (not converged or degenerate).
    off_unflagged: usize,
}

#[derive(Serialize)]
struct FixedPoint {
    sample_token: String,
    channel: String,
    estimate: Estimate,
    /// Its distance to the dataset's calibration.
    from_dataset: PoseError,
    converged: bool,
    degenerate: Vec<String>,
}

#[derive(Serialize)]
struct Summary {
    alpha: f64,
    seed: u64,
    runs: usize,
    converged: usize,
    flagged: usize,
    /// Runs that ended farther from the truth (rotation or translation) than they started
    /// without being flagged (not converged or degenerate).
    worse_unflagged: usize,
    rot_deg_before: Quantiles,
    rot_deg_after: Quantiles,
    trans_m_before: Quantiles,
    trans_m_after: Quantiles,
    median_mahalanobis2: f64,
    mean_ms: f64,
}

fn quantiles(mut v: Vec<f64>) -> Quantiles {
    if v.is_empty() {
        return Quantiles::default();
    }
    v.sort_by(f64::total_cmp);
    let at = |q: f64| v[((q * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)];
    Quantiles {
        median: at(0.5),
        p90: at(0.9),
        p95: at(0.95),
        worst: v[v.len() - 1],
    }
}

fn tokens(dataset: &Dataset, args: &CalibrateArgs) -> Result<Vec<String>> {
    let all: Vec<String> = if args.validation {
        mlod::dataset::train_validation_split(dataset).1
    } else {
        dataset.sample_tokens().into_iter().map(String::from).collect()
    };
    if all.is_empty() {
        anyhow::bail!("{}: the dataset has no samples", args.dataset.display());
    }
    Ok(match (&args.sample, args.samples) {
        (Some(t), _) => vec![t.clone()],
        (None, None) => vec![all[0].clone()],
        (None, Some(0)) => anyhow::bail!("--samples must be at least 1"),
        (None, Some(n)) if args.spread => {
            let n = n.min(all.len());
            (0..n).map(|i| all[i * all.len() / n].clone()).collect()
        }
        (None, Some(n)) => all.into_iter().take(n).collect(),
    })
}

pub fn run(args: CalibrateArgs) -> Result<()> {
    let dataset = super::open_dataset(&args.dataset)?;
    let tokens = tokens(&dataset, &args)?;
    let config = IcpConfig::with_overrides(&args.icp)?;
    if args.alignment || args.xi_check {
        let request = super::alignment::Request {
            alignment: args.alignment,
            xi_check: args.xi_check,
            alpha: args.alpha,
            seed: args.seed,
            draws: args.draws,
            json: args.json,
        };
        return super::alignment::run(&dataset, &tokens, &request, &config);
    }
    let mut runs = Vec::new();
    let mut fixed_points = Vec::new();
    for (i, token) in tokens.iter().enumerate() {
        let frame = dataset.frame(token).with_context(|| format!("sample {token}"))?;
        // With --draws: the run from the dataset's calibration first (the fixed point).
        let mut fixed = std::collections::BTreeMap::new();
        if args.draws.is_some() {
            let params = FuseParams::default();
            let cal = calibrate(&frame, &params, &config, OcPrior::Icp)
                .with_context(|| format!("calibrating sample {token} from its calibration"))?;
            for l in &cal.lidars {
                let truth = super::alignment::nominal(&frame, l.channel)?;
                fixed.insert(l.channel, l.extrinsic);
                fixed_points.push(FixedPoint {
                    sample_token: token.clone(),
                    channel: l.channel.as_str().to_string(),
                    estimate: Estimate::from(&l.extrinsic),
                    from_dataset: l.error(&truth),
                    converged: l.converged,
                    degenerate: l.degenerate_axes(),
                });
            }
        }
        let seeds: Vec<u64> = match args.draws {
            Some(n) => (0..n as u64).map(|k| args.seed + k).collect(),
            None if args.per_sample => vec![args.seed + i as u64],
            None => vec![args.seed],
        };
        for seed in seeds {
            let params = FuseParams {
                perturbation: Perturbation::new(args.alpha, seed)?,
                ..Default::default()
            };
            let cal = calibrate(&frame, &params, &config, OcPrior::Icp)
                .with_context(|| format!("calibrating sample {token}"))?;
            if let Some(dir) = &args.dump {
                dump(dir, &frame, &params, &cal, &config)?;
            }
            for l in &cal.lidars {
                let truth = super::alignment::nominal(&frame, l.channel)?;
                let fixed_point = fixed.get(&l.channel);
                runs.push(CalibrationRun::new(token, seed, l, &truth, fixed_point));
            }
        }
    }
    let flagged = |r: &CalibrationRun| !r.converged || !r.degenerate.is_empty();
    let mut maha: Vec<f64> = runs
        .iter()
        .map(|r| r.mahalanobis2)
        .filter(|m| m.is_finite())
        .collect();
    maha.sort_by(f64::total_cmp);
    let summary = Summary {
        alpha: args.alpha,
        seed: args.seed,
        runs: runs.len(),
        converged: runs.iter().filter(|r| r.converged).count(),
        flagged: runs.iter().filter(|r| flagged(r)).count(),
        worse_unflagged: runs
            .iter()
            .filter(|r| {
                !flagged(r)
                    && (r.error_after.rot_deg > r.error_before.rot_deg
                        || r.error_after.trans_m > r.error_before.trans_m)
            })
            .count(),
        rot_deg_before: quantiles(runs.iter().map(|r| r.error_before.rot_deg).collect()),
        rot_deg_after: quantiles(runs.iter().map(|r| r.error_after.rot_deg).collect()),
        trans_m_before: quantiles(runs.iter().map(|r| r.error_before.trans_m).collect()),
        trans_m_after: quantiles(runs.iter().map(|r| r.error_after.trans_m).collect()),
        median_mahalanobis2: maha.get(maha.len() / 2).copied().unwrap_or(f64::NAN),
        mean_ms: runs.iter().map(|r| r.ms).sum::<f64>() / runs.len().max(1) as f64,
    };
    let repeatability = args.draws.map(|_| {
        let to: Vec<PoseError> = runs.iter().filter_map(|r| r.to_fixed_point).collect();
        let close = |e: &PoseError| e.rot_deg <= 0.01 && e.trans_m <= 0.001;
        Repeatability {
            fixed_points,
            rot_deg: quantiles(to.iter().map(|e| e.rot_deg).collect()),
            trans_m: quantiles(to.iter().map(|e| e.trans_m).collect()),
            within_001deg_1mm: to.iter().filter(|e| close(e)).count(),
            off_unflagged: runs
                .iter()
                .filter(|r| !flagged(r) && r.to_fixed_point.is_some_and(|e| !close(&e)))
                .count(),
        }
    });
    if args.json {
        let mut out = serde_json::json!({ "runs": runs, "summary": summary });
        if let Some(r) = &repeatability {
            out["repeatability"] = serde_json::to_value(r)?;
        }
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!(
        "{:<34} {:<18} {:>16} {:>16} {:>5} {:>4} {:>6} {:>7} {:>7}  degenerate",
        "sample", "lidar", "before deg / cm", "after deg / cm", "conv", "it", "fit", "rmse cm", "ms"
    );
    for r in &runs {
        println!(
            "{:<34} {:<18} {:>7.3} / {:>6.2} {:>7.4} / {:>6.3} {:>5} {:>4} {:>6.3} {:>7.2} {:>7.1}  {}",
            r.sample_token,
            r.channel,
            r.error_before.rot_deg,
            r.error_before.trans_m * 100.0,
            r.error_after.rot_deg,
            r.error_after.trans_m * 100.0,
            if r.converged { "yes" } else { "NO" },
            r.iterations,
            r.fitness,
            r.rmse * 100.0,
            r.ms,
            if r.degenerate.is_empty() {
                "-".to_string()
            } else {
                r.degenerate.join(",")
            }
        );
    }
    if runs.len() > 1 {
        let q = |name: &str, b: &Quantiles, a: &Quantiles, scale: f64, unit: &str| {
            println!(
                "{name:<12} before median {:.4} p90 {:.4} worst {:.4} {unit}  ->  after median {:.4} p90 {:.4} worst {:.4} {unit}",
                b.median * scale,
                b.p90 * scale,
                b.worst * scale,
                a.median * scale,
                a.p90 * scale,
                a.worst * scale
            )
        };
        println!("\n{} runs at alpha {}: {} converged, {} flagged, {} worse without a flag, mean {:.1} ms, median Mahalanobis^2 {:.2}",
            summary.runs, summary.alpha, summary.converged, summary.flagged, summary.worse_unflagged, summary.mean_ms, summary.median_mahalanobis2);
        q(
            "rotation",
            &summary.rot_deg_before,
            &summary.rot_deg_after,
            1.0,
            "deg",
        );
        q(
            "translation",
            &summary.trans_m_before,
            &summary.trans_m_after,
            100.0,
            "cm",
        );
    }
    if let Some(r) = &repeatability {
        println!("\nICP's fixed points (started from the dataset's calibration):");
        for f in &r.fixed_points {
            println!(
                "  {} {}: {:.4} deg / {:.3} cm from the dataset's calibration, converged {}{}",
                f.sample_token,
                f.channel,
                f.from_dataset.rot_deg,
                f.from_dataset.trans_m * 100.0,
                f.converged,
                if f.degenerate.is_empty() {
                    String::new()
                } else {
                    format!(", degenerate {}", f.degenerate.join(","))
                }
            );
        }
        println!(
            "draws to their fixed point: rotation median {:.5} p95 {:.5} max {:.5} deg; translation median {:.4} p95 {:.4} max {:.4} cm; \
             {} of {} within 0.01 deg and 1 mm; {} farther without a flag",
            r.rot_deg.median,
            r.rot_deg.p95,
            r.rot_deg.worst,
            r.trans_m.median * 100.0,
            r.trans_m.p95 * 100.0,
            r.trans_m.worst * 100.0,
            r.within_001deg_1mm,
            runs.len(),
            r.off_unflagged
        );
    }
    Ok(())
}

/// Writes the clouds ICP worked on and the extrinsics, for an outside reference implementation.
fn dump(
    dir: &std::path::Path,
    frame: &Frame,
    params: &FuseParams,
    cal: &mlod::calib::Calibration,
    config: &IcpConfig,
) -> Result<()> {
    use std::fmt::Write as _;
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let xyz = |pts: &[[f32; 3]]| {
        let mut s = String::with_capacity(pts.len() * 30);
        for p in pts {
            let _ = writeln!(s, "{} {} {}", p[0], p[1], p[2]);
        }
        s
    };
    let token = &frame.sample_token;
    let top = &frame.primary.points;
    let target = mlod::calib::voxel_downsample(&top.x, &top.y, &top.z, config.target_voxel, config.max_range);
    mlod::io::write_atomic(&dir.join(format!("{token}.target.xyz")), xyz(&target).as_bytes())?;
    let mut lidars = Vec::new();
    for l in &cal.lidars {
        let scan = frame.lidar(l.channel).context("calibrated LiDAR missing")?;
        let p = &scan.points;
        let source = mlod::calib::voxel_downsample(&p.x, &p.y, &p.z, config.source_voxel, config.max_range);
        let name = format!("{token}.{}.source.xyz", l.channel.as_str());
        mlod::io::write_atomic(&dir.join(&name), xyz(&source).as_bytes())?;
        let m = |pose: &mlod::geometry::Pose| {
            let h = pose.to_homogeneous();
            (0..4)
                .map(|i| (0..4).map(|j| h[(i, j)]).collect::<Vec<_>>())
                .collect::<Vec<_>>()
        };
        lidars.push(serde_json::json!({
            "channel": l.channel.as_str(),
            "source": name,
            "start": m(&l.start),
            "truth": m(&scan.info.extrinsic),
            "ours": m(&l.extrinsic),
            "ours_ms": l.ms + cal.target_ms,
        }));
    }
    let meta = serde_json::json!({
        "sample_token": token,
        "alpha": params.perturbation.alpha,
        "seed": params.perturbation.seed,
        "target": format!("{token}.target.xyz"),
        "config": config,
        "lidars": lidars,
    });
    mlod::io::write_atomic(
        &dir.join(format!("{token}.json")),
        serde_json::to_string_pretty(&meta)?.as_bytes(),
    )?;
    Ok(())
}
