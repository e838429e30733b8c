//! `mlod analyze active-points`: the shares of uncertain points among the refiner's input and its
//! active points, per sample (paper §V-C, Fig. 5).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};

use super::detect::DetectorRun;
use mlod::analysis::active::{active_points, write_report};

#[derive(clap::Subcommand)]
pub enum AnalyzeCommand {
    /// Per sample, |P_u|/|P| of the refiner's input points and of its active points (the points
    /// that win its max-pool) and their difference: DIR/active_points.csv, and the histogram of
    /// the differences (Fig. 5(b)) as DIR/active_points.png.
    ActivePoints(ActiveArgs),
}

#[derive(clap::Args)]
pub struct ActiveArgs {
    #[arg(long)]
    dataset: PathBuf,
    /// An MLOD case (mlod-i, mlod-f or mlod-r).
    #[arg(long, default_value = "mlod-i")]
    case: mlod::detect::Case,
    #[command(flatten)]
    run: DetectorRun,
    /// Only the first N samples.
    #[arg(long)]
    samples: Option<usize>,
    /// Output folder (created if missing).
    #[arg(long)]
    out: PathBuf,
}

pub fn analyze(cmd: AnalyzeCommand) -> Result<()> {
    match cmd {
        AnalyzeCommand::ActivePoints(a) => {
            if !a.case.is_mlod() {
                bail!(
                    "--case must be an MLOD case (mlod-i, mlod-f, mlod-r), got {}",
                    a.case
                );
            }
            // What the refiner sees is measured before any gate, on the points as read: refuse
            // the flags that would change nothing here rather than ignore them.
            if a.run.ground_gate != mlod::cases::ground_gate::GateChoice::Manifest {
                bail!("--ground-gate does not apply to active points: a gate drops boxes after the refiner has seen its points");
            }
            if a.run.set_intensity.is_some() {
                bail!("--set-intensity does not apply to active points (the refiner's points are counted as read)");
            }
            let dataset = super::open_dataset(&a.dataset)?;
            let mlod_det =
                mlod::cases::load_mlod_with(&a.run.models_dir(), a.case, a.run.vote_iou, a.run.drop_trace)?;
            let params = a.run.fuse_params()?;
            let rows = active_points(&dataset, &mlod_det, &params, a.samples)?;
            if rows.is_empty() {
                bail!("no sample had a refined proposal with active points");
            }
            let caption = format!(
                "{} at α = {}, seed {}",
                a.case.paper_name(),
                a.run.alpha,
                a.run.seed
            );
            let s = write_report(&rows, &a.out, &caption)
                .with_context(|| format!("writing into {}", a.out.display()))?;
            println!(
                "{} samples  mean difference {:+.4}  > +0.04: {:.1} %  < −0.04: {:.1} %",
                s.samples,
                s.mean_difference,
                100.0 * s.above_004,
                100.0 * s.below_minus_004
            );
            eprintln!(
                "wrote {}/active_points.csv and active_points.png",
                a.out.display()
            );
            Ok(())
        }
    }
}
