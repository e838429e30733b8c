//! `mlod propagate`, `mlod plane-fit` and `mlod fuse`: the uncertainty core (paper §III) on one
//! point, on the plane-fitting experiment, and on a whole fused sample.

use std::path::PathBuf;

use anyhow::{bail, Result};
use nalgebra::{Matrix3, Vector3};

use mlod::geometry::rpy_to_matrix;
use mlod::uncertainty::plane::{plane_fit_experiment, PlaneCase, PlaneFitConfig};
use mlod::uncertainty::propagate::{covariance, extrinsic_covariance, worked_example};
use mlod::uncertainty::{Linearization, Prior};

use super::args::{parse_alpha, parse_vec3, sample_token};

#[derive(clap::Args)]
pub struct PropagateArgs {
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
pub struct FuseArgs {
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
    /// Calibrate online first (point-to-plane ICP, as the window's "calibrate (ICP)") and fuse
    /// with the corrected extrinsics: the numbers of the corrected cloud.
    #[arg(long)]
    oc: bool,
    /// With --oc: the uncertainty of the calibrated points (icp: ICP's covariance; alpha: Θ(α)).
    #[arg(long, default_value = "icp", requires = "oc")]
    oc_prior: mlod::calib::OcPrior,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
pub struct PlaneFitArgs {
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

pub fn parse_prior(s: &str) -> Result<Prior> {
    let blocks: Vec<&str> = s.split(';').collect();
    if blocks.len() != 3 {
        bail!("--prior-std needs three ';'-separated blocks (P; Phi; Z), got '{s}'");
    }
    let b = |i: usize| parse_vec3(blocks[i]).map_err(anyhow::Error::msg);
    Ok(Prior::from_std(b(0)?, b(1)?, b(2)?)?)
}

pub fn mat_rows(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)]))
}

pub fn print_matrix(name: &str, m: &Matrix3<f64>) {
    println!("{name} =");
    for i in 0..3 {
        println!("  [{:>9.4} {:>9.4} {:>9.4}]", m[(i, 0)], m[(i, 1)], m[(i, 2)]);
    }
}

pub fn propagate(args: PropagateArgs) -> Result<()> {
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

pub fn plane_fit(args: PlaneFitArgs) -> Result<()> {
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
    mlod::analysis::plot::plane_fit_png(&rows, &png_path)?;
    print!("{csv}");
    eprintln!("wrote {} and {}", csv_path.display(), png_path.display());
    Ok(())
}

pub fn fuse_cmd(args: FuseArgs) -> Result<()> {
    use mlod::color::{histogram, ColorParams};
    use mlod::pipeline::{box_stats, fuse, FuseParams};
    let dataset = super::open_dataset(&args.dataset)?;
    let token = sample_token(&dataset, args.sample.as_deref())?;
    let frame = dataset.frame(&token)?;
    let params = FuseParams {
        perturbation: mlod::uncertainty::Perturbation::new(args.alpha, args.seed)?,
        prior_alpha: args.prior_alpha,
        linearization: args.linearization,
        ..Default::default()
    };
    let mut params = params;
    if args.oc {
        let cal =
            mlod::pipeline::calibrate(&frame, &params, &mlod::calib::IcpConfig::default(), args.oc_prior)?;
        params.calibration = Some(cal);
    }
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
                "calibrated": l.calibrated,
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
