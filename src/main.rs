//! The `mlod` binary: `mlod` alone opens the debugger; subcommands produce every number the GUI
//! shows as JSON, CSV or PNG.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use nalgebra::{Matrix3, Vector3};

use mlod::geometry::rpy_to_matrix;
use mlod::uncertainty::plane::{plane_fit_experiment, PlaneCase, PlaneFitConfig};
use mlod::uncertainty::propagate::{covariance, extrinsic_covariance, worked_example};
use mlod::uncertainty::{Linearization, Prior};

mod cli_detect;

#[derive(Parser)]
#[command(
    name = "mlod",
    version,
    about = "MLOD debugger: multi-LiDAR 3D detection under extrinsic perturbation"
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Open the debugger window (the default).
    Gui {
        /// A Lyft-format dataset (root or version folder); default: the embedded sample_data/.
        #[arg(long)]
        dataset: Option<PathBuf>,
        /// A saved session (reproduces its view exactly; its dataset unless --dataset is given).
        #[arg(long)]
        session: Option<PathBuf>,
        /// Measure: repaint continuously for N frames, print frame times, exit.
        #[arg(long)]
        measure_frames: Option<usize>,
    },
    /// Render the viewport headlessly to a PNG (as File > Export viewport PNG does).
    Screenshot {
        #[arg(long)]
        dataset: Option<PathBuf>,
        #[arg(long)]
        session: Option<PathBuf>,
        #[arg(long)]
        out: PathBuf,
        /// WIDTHxHEIGHT in pixels.
        #[arg(long, default_value = "1280x800")]
        size: String,
    },
    /// Propagate the prior Θ(α) through an extrinsic to one point: Ξ = HΘHᵀ (paper eq. 5–8).
    Propagate(PropagateArgs),
    /// Generate a Lyft-format multi-LiDAR dataset with the ray-cast simulator.
    Synth(SynthArgs),
    /// Fuse a sample under a perturbation and print what the debugger shows: the applied ρ, φ and
    /// extrinsics, tr(Ξ) range, |P_u|/|P|, the tr(Ξ) histogram and per-box statistics.
    Fuse(FuseArgs),
    /// Show a sample of a Lyft-format dataset: LiDARs, extrinsics T^b_l and boxes in the base frame.
    Inspect(InspectArgs),
    /// Run the plane-fitting experiment of paper §III-C / Fig. 2; writes plane_fit.csv and plane_fit.png.
    PlaneFit(PlaneFitArgs),
    /// Train the stage-1 detectors, or calibrate Result Fusion's temperatures.
    #[command(subcommand)]
    Train(cli_detect::TrainCommand),
    /// Run a stage-1 detector (shipped weights) on one sample and print its boxes.
    Detect(cli_detect::DetectArgs),
    /// Score predictions against a dataset's ground truth: KITTI-style AP_3D as the paper reports it
    /// (§V-A-2, in percent) and Lyft's official mAP (devkit footprint and exact footprint).
    Eval(EvalArgs),
    /// The paper's Table I on a dataset: every stage-1 case run over the samples, car AP_3D
    /// easy/moderate/hard at IoU 0.7 and 0.5, as a Markdown table (and JSON with --out).
    Table1(Table1Args),
}

#[derive(clap::Args)]
struct Table1Args {
    /// A Lyft-format dataset (the held-out test split).
    #[arg(long)]
    dataset: PathBuf,
    /// Only these cases (comma separated; default: all six).
    #[arg(long, value_delimiter = ',')]
    cases: Vec<mlod::detect::Case>,
    /// Evaluate only the first N samples.
    #[arg(long)]
    samples: Option<usize>,
    /// Only the validation scenes of a training dataset (every 10th scene: the split training
    /// holds out), for tuning a setting without touching the test split.
    #[arg(long)]
    validation: bool,
    #[command(flatten)]
    run: cli_detect::DetectorRun,
    /// Write every case's whole evaluation report here as JSON (atomically).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Record each trained model's figures as `test_ap` in the models' manifest.json.
    #[arg(long)]
    update_manifest: bool,
    /// Also print each case's car recall per BEV range band: the bands' upper edges in m,
    /// increasing (e.g. 10,20,30 for 0–10, 10–20, 20–30 m).
    #[arg(long, value_delimiter = ',')]
    recall_bands: Vec<f64>,
    /// 3D IoU at which a car counts as found in the recall table.
    #[arg(long, default_value_t = 0.7, value_parser = parse_unit)]
    recall_iou: f64,
    /// Also print car moderate AP_3D@0.7 with parts of the boxes matched at 3D IoU ≥ 0.5 within
    /// 30 m (size, yaw, z/h, x/y, the whole box) taken from the truth (as `eval --attribution`).
    #[arg(long)]
    attribution: bool,
}

#[derive(clap::Args)]
struct EvalArgs {
    /// A Lyft-format dataset (root or version folder).
    #[arg(long)]
    dataset: PathBuf,
    /// Predictions: a JSON list in the Lyft devkit format (sample_token, translation [global],
    /// size [w,l,h], rotation [w,x,y,z], name, score).
    #[arg(long, required_unless_present = "case", conflicts_with = "case")]
    pred: Option<PathBuf>,
    /// Instead of --pred: run this stage-1 detector (shipped weights) over the samples.
    #[arg(long)]
    case: Option<mlod::detect::Case>,
    // With --case: the perturbation and the models folder.
    #[command(flatten)]
    run: cli_detect::DetectorRun,
    /// Evaluate only the first N samples of the dataset.
    #[arg(long)]
    samples: Option<usize>,
    /// Only the validation scenes of a training dataset (every 10th scene: the split training
    /// holds out), for tuning a setting without touching the test split.
    #[arg(long)]
    validation: bool,
    /// KITTI recall points: r40 (default) or r11.
    #[arg(long, default_value = "r40", value_parser = ["r40", "r11"])]
    interpolation: String,
    /// Add every box's outcome (TP with its GT, IoU and residuals, FP, miss) to the JSON, and a
    /// localisation summary of the matches (mean |residual| and size correlation per class).
    #[arg(long)]
    per_box: bool,
    /// With --per-box: AP again with each part of the matched predictions (size, x/y, z/h, yaw,
    /// the whole box) taken from their ground truth: which residual costs how much AP.
    #[arg(long, requires = "per_box")]
    attribution: bool,
    /// IoU threshold of the per-box outcomes (3D IoU, ≥).
    #[arg(long, default_value_t = 0.7, value_parser = parse_unit)]
    match_iou: f64,
    /// Range of the per-box outcomes (m): boxes farther from the base origin are ignored.
    #[arg(long, default_value_t = 50.0)]
    match_range: f64,
    /// Print JSON instead of tables.
    #[arg(long)]
    json: bool,
    /// Also write the JSON to this file (atomically).
    #[arg(long)]
    out: Option<PathBuf>,
}

#[derive(clap::Args)]
struct PropagateArgs {
    /// The paper's worked example of §III-B (rpy 10°,10°,10°, t = 1,1,1 m, p = 10,10,10 m).
    #[arg(long, conflicts_with_all = ["point", "rpy_deg", "translation"])]
    example: bool,
    /// The point in the LiDAR frame, "x,y,z" in metres.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    point: Option<[f64; 3]>,
    /// The extrinsic's roll,pitch,yaw in degrees (R = Rz(yaw)·Ry(pitch)·Rx(roll)).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    rpy_deg: Option<[f64; 3]>,
    /// The extrinsic's translation "x,y,z" in metres.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    translation: Option<[f64; 3]>,
    /// α, the scale of the extrinsic blocks of Θ (default 0.02, the paper's moderate level).
    #[arg(long, default_value_t = 0.02, value_parser = parse_alpha, allow_hyphen_values = true)]
    alpha: f64,
    /// separate (H = [I, −(R̄p)^, R̄], eq. 6 as written) or se3-left (H = [I, −(R̄p+t̄)^, R̄]).
    #[arg(long, default_value = "separate")]
    linearization: Linearization,
    /// Your own prior instead of eq. 9: standard deviations "ρx,ρy,ρz;φx,φy,φz;ζx,ζy,ζz" (m, rad, m).
    #[arg(long)]
    prior_std: Option<String>,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
struct SynthArgs {
    /// Output folder (the dataset root: v1.01-train/, lidar/, maps/).
    #[arg(long)]
    out: PathBuf,
    /// Number of scenes.
    #[arg(long, default_value_t = 1)]
    scenes: usize,
    /// Key frames per scene (0.2 s apart).
    #[arg(long, default_value_t = 10)]
    samples_per_scene: usize,
    /// Seed of everything generated (layout, motion, noise, tokens).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Show a progress bar.
    #[arg(long)]
    progress: bool,
}

#[derive(clap::Args)]
struct FuseArgs {
    /// Dataset root or its version folder.
    #[arg(long)]
    dataset: PathBuf,
    /// Sample token (default: the first sample in scene order).
    #[arg(long)]
    sample: Option<String>,
    /// α of the injected perturbation.
    #[arg(long, default_value_t = 0.0, value_parser = parse_alpha, allow_hyphen_values = true)]
    alpha: f64,
    /// Seed of the perturbation draw.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The α the prior assumes for Ξ (default: --alpha).
    #[arg(long, value_parser = parse_alpha, allow_hyphen_values = true)]
    prior_alpha: Option<f64>,
    #[arg(long, default_value = "separate")]
    linearization: Linearization,
    /// Number of log-spaced tr(Ξ) histogram bins between 1e-3 and 1 m².
    #[arg(long, default_value_t = 64)]
    bins: usize,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
struct InspectArgs {
    /// Dataset root or its version folder (e.g. v1.01-train).
    #[arg(long)]
    dataset: PathBuf,
    /// Sample token (default: the first sample in scene order).
    #[arg(long, conflicts_with = "list")]
    sample: Option<String>,
    /// List all samples with their LiDAR channels and box counts.
    #[arg(long)]
    list: bool,
    /// Trim .bin files whose size is not a multiple of 20 bytes (with a warning) instead of failing.
    #[arg(long)]
    lenient: bool,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
struct PlaneFitArgs {
    /// Output folder (created if missing).
    #[arg(long)]
    out: PathBuf,
    /// Trials per α (the paper uses 100).
    #[arg(long, default_value_t = 100)]
    trials: usize,
    /// Seed of all random draws.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Linearisation used for the weights.
    #[arg(long, default_value = "separate")]
    linearization: Linearization,
}

fn parse_f64(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("'{s}' is not a number"))?;
    if !v.is_finite() {
        return Err(format!("'{s}' is not a finite number"));
    }
    Ok(v)
}

fn parse_vec3(s: &str) -> Result<[f64; 3], String> {
    let parts: Vec<&str> = s.split(',').collect();
    if parts.len() != 3 {
        return Err(format!("expected three comma-separated numbers, got '{s}'"));
    }
    Ok([parse_f64(parts[0])?, parse_f64(parts[1])?, parse_f64(parts[2])?])
}

fn parse_unit(s: &str) -> Result<f64, String> {
    let v = parse_f64(s)?;
    if !(0.0..=1.0).contains(&v) {
        return Err(format!("must be in [0, 1], got {v}"));
    }
    Ok(v)
}

fn parse_alpha(s: &str) -> Result<f64, String> {
    let a = parse_f64(s)?;
    if a < 0.0 {
        return Err(format!("alpha must be >= 0, got {a}"));
    }
    Ok(a)
}

fn parse_prior(s: &str) -> Result<Prior> {
    let blocks: Vec<&str> = s.split(';').collect();
    if blocks.len() != 3 {
        bail!("--prior-std needs three ';'-separated blocks (P; Phi; Z), got '{s}'");
    }
    let b = |i: usize| parse_vec3(blocks[i]).map_err(anyhow::Error::msg);
    Ok(Prior::from_std(b(0)?, b(1)?, b(2)?)?)
}

fn mat_rows(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)]))
}

fn print_matrix(name: &str, m: &Matrix3<f64>) {
    println!("{name} =");
    for i in 0..3 {
        println!("  [{:>9.4} {:>9.4} {:>9.4}]", m[(i, 0)], m[(i, 1)], m[(i, 2)]);
    }
}

fn propagate(args: PropagateArgs) -> Result<()> {
    let prior = match &args.prior_std {
        Some(s) => parse_prior(s)?,
        None => Prior::paper(),
    };
    let scaled = prior.scaled(args.alpha)?;
    let lin = args.linearization;
    if args.example {
        let (r, t, p) = worked_example();
        let per_alpha = extrinsic_covariance(&r, &t, &p, &prior, lin);
        let xi = covariance(&r, &t, &p, &scaled, lin);
        let std_m: Vec<f64> = (0..3).map(|i| xi[(i, i)].sqrt()).collect();
        if args.json {
            let v = serde_json::json!({
                "linearization": lin.name(),
                "extrinsic_per_alpha": mat_rows(&per_alpha),
                "alpha": args.alpha,
                "xi": mat_rows(&xi),
                "std_m": std_m,
            });
            println!("{}", serde_json::to_string_pretty(&v)?);
        } else {
            println!("Worked example of paper §III-B, linearization {lin}");
            print_matrix("extrinsic part of Xi per unit alpha", &per_alpha);
            print_matrix(&format!("Xi at alpha = {} (with Z)", args.alpha), &xi);
            println!("std (m) = [{:.4}, {:.4}, {:.4}]", std_m[0], std_m[1], std_m[2]);
        }
        return Ok(());
    }
    let (Some(p), Some(rpy), Some(t)) = (args.point, args.rpy_deg, args.translation) else {
        bail!("give --example, or all of --point, --rpy-deg and --translation");
    };
    let r = rpy_to_matrix(rpy[0].to_radians(), rpy[1].to_radians(), rpy[2].to_radians());
    let xi = covariance(&r, &Vector3::from(t), &Vector3::from(p), &scaled, lin);
    if args.json {
        let v = serde_json::json!({ "linearization": lin.name(), "alpha": args.alpha, "xi": mat_rows(&xi), "trace": xi.trace() });
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        print_matrix(&format!("Xi ({lin}, alpha = {})", args.alpha), &xi);
        println!("tr(Xi) = {:.6} m^2", xi.trace());
    }
    Ok(())
}

fn plane_fit(args: PlaneFitArgs) -> Result<()> {
    if args.trials == 0 {
        bail!("--trials must be at least 1");
    }
    let cfg = PlaneFitConfig {
        trials: args.trials,
        seed: args.seed,
        linearization: args.linearization,
        ..Default::default()
    };
    let rows = plane_fit_experiment(&cfg, &PlaneCase::paper_cases())?;
    let mut csv = String::from("case,alpha,weighted_error,unweighted_error\n");
    for r in &rows {
        csv.push_str(&format!(
            "{},{:.2},{:.9e},{:.9e}\n",
            r.case, r.alpha, r.weighted_error, r.unweighted_error
        ));
    }
    let csv_path = args.out.join("plane_fit.csv");
    mlod::io::write_atomic(&csv_path, csv.as_bytes())?;
    let png_path = args.out.join("plane_fit.png");
    mlod::plot::plane_fit_png(&rows, &png_path)?;
    print!("{csv}");
    eprintln!("wrote {} and {}", csv_path.display(), png_path.display());
    Ok(())
}

fn synth(args: SynthArgs) -> Result<()> {
    let cfg = mlod::synth::SynthConfig {
        seed: args.seed,
        scenes: args.scenes,
        samples_per_scene: args.samples_per_scene,
        ..Default::default()
    };
    let bar = args.progress.then(|| {
        let bar = indicatif::ProgressBar::new((args.scenes * args.samples_per_scene) as u64);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{bar:40.cyan/blue} {pos}/{len} samples  {elapsed_precise} (eta {eta})",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar
    });
    let start = std::time::Instant::now();
    let summary = mlod::synth::generate(&cfg, &args.out, |done, total| {
        if let Some(bar) = &bar {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        }
    })?;
    if let Some(bar) = bar {
        bar.finish();
    }
    eprintln!(
        "wrote {} samples ({} scenes, {} annotations, {} points, {:.1} MB) to {} in {:.1} s",
        summary.samples,
        summary.scenes,
        summary.annotations,
        summary.points,
        summary.bytes as f64 / 1e6,
        args.out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

fn fuse_cmd(args: FuseArgs) -> Result<()> {
    use mlod::color::{histogram, ColorParams};
    use mlod::pipeline::{box_stats, fuse, FuseParams};
    let dataset = mlod::lyft::Dataset::open(&args.dataset)?;
    let token = match &args.sample {
        Some(t) => t.clone(),
        None => dataset
            .first_sample_token()
            .context("the dataset has no samples")?
            .to_string(),
    };
    let frame = dataset.frame(&token)?;
    let params = FuseParams {
        perturbation: mlod::uncertainty::Perturbation::new(args.alpha, args.seed)?,
        prior_alpha: args.prior_alpha,
        linearization: args.linearization,
        ..Default::default()
    };
    let cloud = fuse(&frame, &params)?;
    let range = ColorParams::default().range;
    let hist = histogram(
        &cloud.trace,
        range,
        mlod::color::Scale::Log,
        args.bins.clamp(1, 4096),
    );
    let (lo, hi) = cloud.trace_range().unwrap_or((0.0, 0.0));
    let lidars: Vec<serde_json::Value> = cloud
        .lidars
        .iter()
        .map(|l| {
            let q = l.applied.rotation;
            serde_json::json!({
                "channel": l.channel.as_str(),
                "num_points": l.range.len(),
                "rho_m": l.noise.rho,
                "phi_rad": l.noise.phi,
                "applied_extrinsic": {
                    "translation": l.applied.translation.vector.as_slice(),
                    "rotation_wxyz": mlod::geometry::quat_to_wxyz(&q),
                },
            })
        })
        .collect();
    let boxes: Vec<serde_json::Value> = frame
        .boxes
        .iter()
        .map(|b| {
            let s = box_stats(&cloud, &b.box3d);
            serde_json::json!({
                "category": b.category, "center": b.box3d.center, "distance_m": b.box3d.bev_range(),
                "points_inside": s.points, "mean_trace": s.mean_trace, "uncertain_fraction": s.uncertain_fraction,
            })
        })
        .collect();
    let report = serde_json::json!({
        "sample_token": token,
        "alpha": args.alpha,
        "prior_alpha": params.effective_prior_alpha(),
        "seed": args.seed,
        "linearization": args.linearization.name(),
        "num_points": cloud.len(),
        "trace_min": lo,
        "trace_max": hi,
        "uncertain_threshold": mlod::uncertainty::UNCERTAIN_TRACE,
        "uncertain_fraction": cloud.uncertain_fraction(mlod::uncertainty::UNCERTAIN_TRACE),
        "histogram": { "scale": "log", "range": [range.0, range.1], "counts": hist },
        "lidars": lidars,
        "boxes": boxes,
    });
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "sample {}  alpha {}  {} points  tr(Xi) {:.4}..{:.4} m^2  uncertain {:.1} %",
            token,
            args.alpha,
            cloud.len(),
            lo,
            hi,
            100.0 * cloud.uncertain_fraction(mlod::uncertainty::UNCERTAIN_TRACE)
        );
        for l in &cloud.lidars {
            let (r, p) = (l.noise.rho, l.noise.phi);
            println!(
                "  {:<18} rho = ({:+.3}, {:+.3}, {:+.3}) m  phi = ({:+.4}, {:+.4}, {:+.4}) rad",
                l.channel.as_str(),
                r[0],
                r[1],
                r[2],
                p[0],
                p[1],
                p[2]
            );
        }
    }
    Ok(())
}

fn inspect(args: InspectArgs) -> Result<()> {
    let dataset = mlod::lyft::Dataset::open(&args.dataset)?;
    if args.list {
        let samples = mlod::lyft::list(&dataset);
        if args.json {
            println!("{}", serde_json::to_string_pretty(&samples)?);
        } else {
            for s in &samples {
                println!(
                    "{}  {}  {:>3} boxes  {}",
                    s.sample_token,
                    s.scene_name,
                    s.num_boxes,
                    s.lidar_channels.join(",")
                );
            }
        }
        return Ok(());
    }
    let opts = mlod::lyft::LoadOptions {
        lenient: args.lenient,
    };
    let report = mlod::lyft::inspect_with(&dataset, args.sample.as_deref(), opts)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!("sample {}", report.sample_token);
        for l in &report.lidars {
            let n = l.num_points.map_or("-".to_string(), |n| n.to_string());
            let t = l.extrinsic.translation;
            println!(
                "  {:<18} {:>7} points  t = ({:.3}, {:.3}, {:.3})  {}",
                l.channel, n, t[0], t[1], t[2], l.file
            );
        }
        for b in &report.boxes {
            let c = b.center;
            println!(
                "  {:<12} centre ({:.2}, {:.2}, {:.2})  yaw {:.3}",
                b.category, c[0], c[1], c[2], b.yaw
            );
        }
    }
    for w in &report.warnings {
        eprintln!("warning: {w}");
    }
    if !report.is_complete() {
        for e in &report.errors {
            eprintln!("error: {e}");
        }
        bail!(
            "{} of the sample's LiDAR files could not be read",
            report.errors.len()
        );
    }
    Ok(())
}

#[cfg(feature = "gui")]
fn app_options(dataset: Option<PathBuf>, session: Option<PathBuf>) -> Result<mlod::gui::AppOptions> {
    let session = session.map(|p| mlod::session::Session::load(&p)).transpose()?;
    let dataset = dataset
        .or_else(|| session.as_ref().map(|s| s.dataset.clone()))
        .unwrap_or_else(mlod::gui::default_dataset);
    let session = session.map(|mut s| {
        s.dataset = dataset.clone();
        s
    });
    Ok(mlod::gui::AppOptions {
        dataset,
        session,
        synchronous: false,
        measure_frames: None,
        models: None,
    })
}

#[cfg(feature = "gui")]
fn gui(dataset: Option<PathBuf>, session: Option<PathBuf>, measure_frames: Option<usize>) -> Result<()> {
    let mut options = app_options(dataset, session)?;
    options.measure_frames = measure_frames.filter(|n| *n > 0);
    mlod::gui::run(options).context("the debugger window failed")
}

#[cfg(feature = "gui")]
fn screenshot(dataset: Option<PathBuf>, session: Option<PathBuf>, out: PathBuf, size: &str) -> Result<()> {
    let (w, h) = size
        .split_once('x')
        .and_then(|(w, h)| Some((w.trim().parse::<u32>().ok()?, h.trim().parse::<u32>().ok()?)))
        .filter(|(w, h)| (16..=8192).contains(w) && (16..=8192).contains(h))
        .with_context(|| format!("--size must be WIDTHxHEIGHT with sides in 16..=8192, got '{size}'"))?;
    let options = app_options(dataset, session)?;
    let img = mlod::gui::screenshot(options, (w, h))?;
    mlod::gui::write_png(&out, &img)?;
    eprintln!("wrote {}", out.display());
    Ok(())
}

#[cfg(not(feature = "gui"))]
fn gui(_dataset: Option<PathBuf>, _session: Option<PathBuf>, _measure: Option<usize>) -> Result<()> {
    bail!("this build has no GUI (built without the `gui` feature); use a subcommand, see --help")
}

#[cfg(not(feature = "gui"))]
fn screenshot(_: Option<PathBuf>, _: Option<PathBuf>, _: PathBuf, _: &str) -> Result<()> {
    bail!("this build has no GUI (built without the `gui` feature)")
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // One line per cause, no backtrace: these are user-facing messages.
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        None => gui(None, None, None),
        Some(Command::Gui {
            dataset,
            session,
            measure_frames,
        }) => gui(dataset, session, measure_frames),
        Some(Command::Screenshot {
            dataset,
            session,
            out,
            size,
        }) => screenshot(dataset, session, out, &size),
        Some(Command::Propagate(a)) => propagate(a),
        Some(Command::PlaneFit(a)) => plane_fit(a),
        Some(Command::Inspect(a)) => inspect(a),
        Some(Command::Fuse(a)) => fuse_cmd(a),
        Some(Command::Synth(a)) => synth(a),
        Some(Command::Train(c)) => cli_detect::train(c),
        Some(Command::Detect(a)) => cli_detect::detect(a),
        Some(Command::Eval(a)) => eval_cmd(a),
        Some(Command::Table1(a)) => table1_cmd(a),
    }
}

/// The samples `opts` evaluates; an error naming the dataset when it asks for the validation
/// scenes and there are none.
fn evaluated_tokens(
    dataset: &mlod::lyft::Dataset,
    path: &std::path::Path,
    opts: &mlod::eval::EvalOptions,
) -> Result<Vec<String>> {
    let tokens = mlod::eval::sample_tokens(dataset, opts);
    if opts.validation_only && tokens.is_empty() {
        bail!(
            "{}: no validation samples (the validation split is every 10th scene)",
            path.display()
        );
    }
    Ok(tokens)
}

/// Runs a shipped detector over `tokens` (samples in parallel): its detections per sample.
fn detect_case(
    dataset: &mlod::lyft::Dataset,
    tokens: &[String],
    run: &cli_detect::DetectorRun,
    case: mlod::detect::Case,
    params: &mlod::pipeline::FuseParams,
) -> Result<std::collections::HashMap<String, Vec<mlod::detect::Detection>>> {
    use rayon::prelude::*;
    let detector = run.load(case)?;
    let bar = indicatif::ProgressBar::new(tokens.len() as u64);
    let dets = tokens
        .par_iter()
        .map(|tok| -> Result<(String, Vec<mlod::detect::Detection>)> {
            let frame = dataset.frame(tok)?;
            let d = detector
                .detect(&frame, params)
                .with_context(|| format!("{} on sample {tok}", case.paper_name()))?;
            bar.inc(1);
            Ok((tok.clone(), d))
        })
        .collect::<Result<std::collections::HashMap<_, _>>>()?;
    bar.finish_and_clear();
    Ok(dets)
}

/// Runs a shipped detector over `tokens` and evaluates it.
fn run_case(
    dataset: &mlod::lyft::Dataset,
    tokens: &[String],
    run: &cli_detect::DetectorRun,
    case: mlod::detect::Case,
    params: &mlod::pipeline::FuseParams,
    opts: &mlod::eval::EvalOptions,
) -> Result<mlod::eval::EvalReport> {
    let dets = detect_case(dataset, tokens, run, case, params)?;
    Ok(mlod::eval::evaluate_detections(dataset, &dets, opts)?)
}

fn table1_cmd(args: Table1Args) -> Result<()> {
    use mlod::detect::Case;
    let bands = &args.recall_bands;
    if bands.iter().any(|b| !b.is_finite() || *b <= 0.0) || bands.windows(2).any(|w| w[1] <= w[0]) {
        bail!("--recall-bands must be positive and increasing, got {bands:?}");
    }
    let dataset = mlod::lyft::Dataset::open(&args.dataset)?;
    let opts = mlod::eval::EvalOptions {
        samples: args.samples,
        validation_only: args.validation,
        per_box: bands.last().map(|&max_range| mlod::eval::MatchRule {
            iou_threshold: args.recall_iou,
            kind: mlod::geometry::IouKind::ThreeD,
            max_range,
        }),
        ..Default::default()
    };
    let tokens = evaluated_tokens(&dataset, &args.dataset, &opts)?;
    let models = args.run.models_dir();
    let params = args.run.fuse_params()?;
    let cases = if args.cases.is_empty() {
        Case::ALL.to_vec()
    } else {
        args.cases.clone()
    };
    let mut reports = serde_json::Map::new();
    let mut rows = Vec::new();
    let mut recalls = Vec::new();
    let mut attributions = Vec::new();
    for case in cases {
        let start = std::time::Instant::now();
        let dets = detect_case(&dataset, &tokens, &args.run, case, &params)?;
        let mut report = mlod::eval::evaluate_detections(&dataset, &dets, &opts)?;
        if args.attribution {
            let att_opts = mlod::eval::EvalOptions {
                per_box: Some(mlod::eval::MatchRule {
                    iou_threshold: 0.5,
                    kind: mlod::geometry::IouKind::ThreeD,
                    max_range: 30.0,
                }),
                attribution: true,
                ..opts.clone()
            };
            let att = mlod::eval::evaluate_detections(&dataset, &dets, &att_opts)?.attribution;
            attributions.push((
                case,
                att.iter()
                    .flatten()
                    .map(|a| (a.fixed, mlod::eval::kitti::car_moderate_07(&a.kitti)))
                    .collect::<Vec<_>>(),
            ));
            report.attribution = att;
        }
        let cell = |t: &str, d: &str| mlod::eval::kitti::ap_cell(&report.kitti, "car", t, d);
        let figures: Vec<(String, Option<f64>)> = ["iou_0.7", "iou_0.5"]
            .iter()
            .flat_map(|t| ["easy", "moderate", "hard"].map(|d| (format!("{d}_ap3d_{}", &t[4..]), cell(t, d))))
            .collect();
        eprintln!(
            "{}: {} samples in {:.0} s",
            case.paper_name(),
            report.samples,
            start.elapsed().as_secs_f64()
        );
        let recall = report
            .per_box
            .as_deref()
            .map(|pb| mlod::eval::recall_by_range(pb, "car", bands))
            .unwrap_or_default();
        recalls.push((case, recall));
        rows.push((case, figures));
        reports.insert(case.as_str().to_string(), serde_json::to_value(&report)?);
    }
    println!(
        "Car AP_3D (%), R40, {} samples of {}, α = {}",
        tokens.len(),
        args.dataset.display(),
        args.run.alpha
    );
    println!();
    println!("| Method | Easy@0.7 | Mod.@0.7 | Hard@0.7 | Easy@0.5 | Mod.@0.5 | Hard@0.5 |");
    println!("|---|---:|---:|---:|---:|---:|---:|");
    for (case, figures) in &rows {
        let cells: Vec<String> = figures
            .iter()
            .map(|(_, v)| v.map_or_else(|| "–".to_string(), |x| format!("{x:.2}")))
            .collect();
        println!("| {} | {} |", case.paper_name(), cells.join(" | "));
    }
    if !bands.is_empty() {
        println!();
        println!(
            "Cars found at 3D IoU ≥ {} (any score), by BEV range",
            args.recall_iou
        );
        println!();
        let heads: Vec<String> = std::iter::once(0.0)
            .chain(bands.iter().copied())
            .collect::<Vec<f64>>()
            .windows(2)
            .map(|w| format!("{}–{} m", w[0], w[1]))
            .collect();
        println!("| Method | {} |", heads.join(" | "));
        println!("|---|{}", "---:|".repeat(heads.len()));
        for (case, recall) in &recalls {
            let cells: Vec<String> = recall
                .iter()
                .map(|&(n, found)| match n {
                    0 => "–".to_string(),
                    n => format!("{:.1} % ({found}/{n})", 100.0 * found as f64 / n as f64),
                })
                .collect();
            println!("| {} | {} |", case.paper_name(), cells.join(" | "));
        }
    }
    if let Some((_, first)) = attributions.first() {
        println!();
        println!(
            "Car AP_3D mod.@0.7 with the boxes matched at 3D IoU ≥ 0.5 (< 30 m) given part of the truth"
        );
        println!();
        let heads: Vec<&str> = first.iter().map(|(f, _)| f.label()).collect();
        println!("| Method | {} |", heads.join(" | "));
        println!("|---|{}", "---:|".repeat(heads.len()));
        for (case, row) in &attributions {
            let cells: Vec<String> = row
                .iter()
                .map(|(_, v)| v.map_or_else(|| "–".to_string(), |x| format!("{x:.2}")))
                .collect();
            println!("| {} | {} |", case.paper_name(), cells.join(" | "));
        }
    }
    if let Some(out) = &args.out {
        let doc = serde_json::json!({
            "dataset": args.dataset,
            "samples": tokens.len(),
            "alpha": args.run.alpha,
            "seed": args.run.seed,
            "reports": reports,
        });
        mlod::io::write_atomic(
            out,
            format!("{}\n", serde_json::to_string_pretty(&doc)?).as_bytes(),
        )?;
    }
    if args.update_manifest {
        let mut manifest = mlod::detect::Manifest::load(&models)?;
        for (case, figures) in &rows {
            if let Some(entry) = manifest.models.get_mut(case) {
                entry.test_ap = figures
                    .iter()
                    .filter_map(|(k, v)| v.map(|v| (k.clone(), v)))
                    .collect();
            }
        }
        manifest.save(&models)?;
        eprintln!("test_ap recorded in {}", models.join("manifest.json").display());
    }
    Ok(())
}

fn eval_cmd(args: EvalArgs) -> Result<()> {
    use mlod::eval::{EvalOptions, Interpolation, MatchRule};
    if args.match_range.is_nan() || args.match_range <= 0.0 {
        bail!("--match-range must be positive, got {}", args.match_range);
    }
    let dataset = mlod::lyft::Dataset::open(&args.dataset)?;
    let mut opts = EvalOptions {
        samples: args.samples,
        validation_only: args.validation,
        ..Default::default()
    };
    if args.interpolation == "r11" {
        opts.kitti.interpolation = Interpolation::R11;
    }
    if args.per_box {
        opts.per_box = Some(MatchRule {
            iou_threshold: args.match_iou,
            max_range: args.match_range,
            ..Default::default()
        });
        opts.attribution = args.attribution;
    }
    let tokens = evaluated_tokens(&dataset, &args.dataset, &opts)?;
    let Some(pred_path) = &args.pred else {
        let case = args.case.context("give --pred FILE or --case CASE")?;
        let params = args.run.fuse_params()?;
        let report = run_case(&dataset, &tokens, &args.run, case, &params, &opts)?;
        return print_eval(&args, &report);
    };
    let known: std::collections::HashSet<&str> = tokens.iter().map(String::as_str).collect();
    let raw = mlod::eval::read_predictions(pred_path)?;
    let preds = mlod::eval::parse_predictions(&raw, &known);
    if !preds.rejected.is_empty() {
        eprintln!(
            "warning: {} of {} predictions in {} rejected and skipped; first:",
            preds.rejected.len(),
            preds.total,
            pred_path.display()
        );
        for r in preds.rejected.iter().take(5) {
            let tok = r.sample_token.as_deref().unwrap_or("?");
            eprintln!("  #{} (sample {tok}): {}", r.index, r.reason);
        }
    }
    let report = mlod::eval::evaluate(&dataset, &preds, &opts)?;
    print_eval(&args, &report)
}

fn print_eval(args: &EvalArgs, report: &mlod::eval::EvalReport) -> Result<()> {
    let json = serde_json::to_string_pretty(report)?;
    if let Some(out) = &args.out {
        mlod::io::write_atomic(out, format!("{json}\n").as_bytes())?;
    }
    if args.json {
        println!("{json}");
        return Ok(());
    }
    println!(
        "{} samples, {} predictions used ({} rejected)",
        report.samples, report.predictions.accepted, report.predictions.rejected
    );
    println!("\nKITTI-style AP_3D (%), {} interpolation", args.interpolation);
    println!(
        "{:<20} {:>7} {:>7} {:>7}   {:>7} {:>7} {:>7}",
        "class", "easy", "mod.", "hard", "easy", "mod.", "hard"
    );
    println!("{:<20} {:^23}   {:^23}", "", "IoU >= 0.7", "IoU >= 0.5");
    let cell = |v: Option<&Option<f64>>| match v {
        Some(Some(x)) => format!("{x:>7.2}"),
        _ => format!("{:>7}", "-"),
    };
    // One class's easy / moderate / hard cells at threshold key `t`.
    let row = |per_t: &mlod::eval::kitti::Ordered<mlod::eval::kitti::Ordered<Option<f64>>>, t: &str| {
        let d = per_t.get(t);
        ["easy", "moderate", "hard"]
            .iter()
            .map(|k| cell(d.and_then(|d| d.get(k))))
            .collect::<Vec<_>>()
            .join(" ")
    };
    for (class, per_t) in &report.kitti.0 {
        println!(
            "{class:<20} {}   {}",
            row(per_t, "iou_0.7"),
            row(per_t, "iou_0.5")
        );
    }
    println!("\nLyft mAP (IoU > t)   devkit   exact footprint");
    for (t, m) in &report.lyft.per_threshold {
        let e = report
            .lyft_exact
            .per_threshold
            .get(t)
            .copied()
            .unwrap_or(f64::NAN);
        println!("  t = {t:<5}          {m:.4}   {e:.4}");
    }
    println!(
        "  mean                {:.4}   {:.4}",
        report.lyft.map, report.lyft_exact.map
    );
    if let Some(att) = &report.attribution {
        println!(
            "\nAP_3D (%) with the matched boxes (3D IoU >= {}, range < {} m) partly replaced by the truth",
            args.match_iou, args.match_range
        );
        println!(
            "{:<20} {:<14} {:>7} {:>7} {:>7}   {:>7} {:>7} {:>7}",
            "class", "boxes", "easy", "mod.", "hard", "easy", "mod.", "hard"
        );
        println!(
            "{:<20} {:<14} {:^23}   {:^23}",
            "", "", "IoU >= 0.7", "IoU >= 0.5"
        );
        let classes: Vec<&String> = att
            .first()
            .map(|a| a.kitti.0.iter().map(|(c, _)| c).collect())
            .unwrap_or_default();
        for class in classes {
            for a in att {
                let Some(per_t) = a.kitti.get(class) else { continue };
                println!(
                    "{class:<20} {:<14} {}   {}",
                    a.fixed.label(),
                    row(per_t, "iou_0.7"),
                    row(per_t, "iou_0.5")
                );
            }
        }
    }
    if let Some(loc) = &report.localization {
        println!(
            "\nLocalisation of the matches (3D IoU >= {}, range < {} m): mean |prediction - truth|",
            args.match_iou, args.match_range
        );
        println!(
            "{:<20} {:>7} {:>7} {:>7} {:>7} {:>7} {:>7} {:>7} {:>7}   size corr. l / w / h",
            "class", "matched", "along", "lateral", "z", "l", "w", "h", "yaw (°)"
        );
        let corr = |c: Option<f64>| c.map_or("-".to_string(), |c| format!("{c:.2}"));
        for l in loc {
            let e = &l.mean_abs;
            println!(
                "{:<20} {:>7} {:>7.3} {:>7.3} {:>7.3} {:>7.3} {:>7.3} {:>7.3} {:>7.2}   {} / {} / {}",
                l.category,
                l.matched,
                e.along,
                e.lateral,
                e.dz,
                e.dl,
                e.dw,
                e.dh,
                e.dyaw.to_degrees(),
                corr(l.size_corr[0]),
                corr(l.size_corr[1]),
                corr(l.size_corr[2])
            );
        }
    }
    Ok(())
}
