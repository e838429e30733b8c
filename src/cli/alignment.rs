//! `mlod calibrate --alignment` and `--xi-check`: the auxiliary LiDARs on the primary's surfaces
//! at the dataset's extrinsics and at ICP's fixed point, and the χ² check of Ξ
//! (`mlod::analysis::alignment`; the measurements of docs/av2.md).

use anyhow::{Context, Result};
use serde::Serialize;

use mlod::analysis::alignment::{residual_table, xi_check, AlignConfig, ResidualRow, Surfaces, XiCheck};
use mlod::calib::{IcpConfig, OcPrior, PoseError};
use mlod::dataset::Dataset;
use mlod::pipeline::{calibrate, FuseParams};

#[derive(Serialize)]
struct Alignment {
    sample_token: String,
    channel: String,
    /// ICP's fixed point against the dataset's extrinsic.
    fixed_point_offset: PoseError,
    /// Per surface and range: the residuals at the dataset's extrinsic and at the fixed point.
    dataset: Vec<ResidualRow>,
    fixed_point: Vec<ResidualRow>,
}

#[derive(Serialize)]
struct Check {
    sample_token: String,
    channel: String,
    #[serde(flatten)]
    check: XiCheck,
}

/// What `mlod calibrate` asked for.
pub struct Request {
    pub alignment: bool,
    pub xi_check: bool,
    pub alpha: f64,
    pub seed: u64,
    pub draws: Option<usize>,
    pub json: bool,
}

pub fn run(dataset: &Dataset, tokens: &[String], args: &Request, config: &IcpConfig) -> Result<()> {
    let cfg = AlignConfig::default();
    let mut alignments = Vec::new();
    let mut checks = Vec::new();
    for token in tokens {
        let frame = dataset.frame(token).with_context(|| format!("sample {token}"))?;
        let surfaces = Surfaces::new(&frame, cfg).with_context(|| format!("surfaces of {token}"))?;
        if args.alignment {
            let cal = calibrate(&frame, &FuseParams::default(), config, OcPrior::Icp)
                .with_context(|| format!("calibrating sample {token} from its calibration"))?;
            for l in &cal.lidars {
                let nominal = nominal(&frame, l.channel)?;
                alignments.push(Alignment {
                    sample_token: token.clone(),
                    channel: l.channel.as_str().to_owned(),
                    fixed_point_offset: l.error(&nominal),
                    dataset: residual_table(&frame, &surfaces, l.channel, &nominal)?,
                    fixed_point: residual_table(&frame, &surfaces, l.channel, &l.extrinsic)?,
                });
            }
        }
        if args.xi_check {
            for scan in &frame.auxiliaries {
                let draws = args.draws.unwrap_or(20);
                checks.push(Check {
                    sample_token: token.clone(),
                    channel: scan.info.channel.as_str().to_owned(),
                    check: xi_check(&frame, &surfaces, scan.info.channel, args.alpha, draws, args.seed)?,
                });
            }
        }
    }
    if args.json {
        let out = serde_json::json!({ "config": cfg, "alignment": alignments, "xi_check": checks });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    for a in &alignments {
        println!(
            "{} {}: ICP's fixed point is {:.4} deg / {:.3} cm from the dataset's extrinsic",
            a.sample_token,
            a.channel,
            a.fixed_point_offset.rot_deg,
            a.fixed_point_offset.trans_m * 100.0
        );
        println!(
            "  {:<16} {:>9} {:>8}  {:>22}  {:>22}",
            "surface", "range m", "points", "dataset |d| / mean cm", "fixed pt |d| / mean cm"
        );
        for (d, f) in a.dataset.iter().zip(&a.fixed_point) {
            println!(
                "  {:<16} {:>4}-{:<4} {:>8}  {:>11.2} / {:>+7.2}  {:>11.2} / {:>+7.2}   ({} at the fixed point)",
                d.surface,
                d.range[0],
                if d.range[1].is_finite() { format!("{}", d.range[1]) } else { "".into() },
                d.points,
                d.median_abs_cm,
                d.mean_cm,
                f.median_abs_cm,
                f.mean_cm,
                f.points
            );
        }
    }
    for c in &checks {
        let x = &c.check;
        println!(
            "{} {}: alpha {} over {} draws, {} point-draws: median z^2 {:.3} (chi2_1: 0.455), within 1 sigma {:.1} % (68.3), \
             within 2 sigma {:.1} % (95.4); median predicted sigma {:.2} cm, median |dd| {:.2} cm",
            c.sample_token,
            c.channel,
            x.alpha,
            x.draws,
            x.pairs,
            x.median_z2,
            x.within_1sigma * 100.0,
            x.within_2sigma * 100.0,
            x.median_sigma_cm,
            x.median_abs_dd_cm
        );
    }
    Ok(())
}

/// The dataset's extrinsic of a LiDAR that calibrate returned (the nominal, what ICP is compared
/// with).
pub fn nominal(
    frame: &mlod::dataset::Frame,
    channel: mlod::dataset::LidarChannel,
) -> Result<mlod::geometry::Pose> {
    frame
        .lidar(channel)
        .map(|s| s.info.extrinsic)
        .context("calibrated LiDAR missing from its frame")
}
