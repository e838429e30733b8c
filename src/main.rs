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
    },
    /// Propagate the prior Θ(α) through an extrinsic to one point: Ξ = HΘHᵀ (paper eq. 5–8).
    Propagate(PropagateArgs),
    /// Show a sample of a Lyft-format dataset: LiDARs, extrinsics T^b_l and boxes in the base frame.
    Inspect(InspectArgs),
    /// Run the plane-fitting experiment of paper §III-C / Fig. 2; writes plane_fit.csv and plane_fit.png.
    PlaneFit(PlaneFitArgs),
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
fn gui(dataset: Option<PathBuf>) -> Result<()> {
    let dataset = dataset.unwrap_or_else(mlod::gui::default_dataset);
    mlod::gui::run(dataset).context("the debugger window failed")
}

#[cfg(not(feature = "gui"))]
fn gui(_dataset: Option<PathBuf>) -> Result<()> {
    bail!("this build has no GUI (built without the `gui` feature); use a subcommand, see --help")
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
        None => gui(None),
        Some(Command::Gui { dataset }) => gui(dataset),
        Some(Command::Propagate(a)) => propagate(a),
        Some(Command::PlaneFit(a)) => plane_fit(a),
        Some(Command::Inspect(a)) => inspect(a),
    }
}
