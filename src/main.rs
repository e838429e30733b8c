//! The `mlod` binary: `mlod` alone opens the debugger; subcommands produce every number the GUI
//! shows as JSON, CSV or PNG. This file only parses and dispatches; each subcommand lives in
//! `src/cli/`.

use anyhow::Result;
use clap::{Parser, Subcommand};

mod cli;

use cli::{
    analyze, calibrate, data, detect, eval, export, failures, stats, sweep, table1, train, uncertainty,
    window,
};

#[derive(Parser)]
#[command(
    name = "mlod",
    version,
    about = "MLOD debugger: multi-LiDAR 3D detection under extrinsic perturbation",
    long_about = "MLOD debugger: multi-LiDAR 3D detection under extrinsic perturbation.\n\n\
                  Without a subcommand it opens the debugger window on the embedded sample_data/. \
                  The subcommands print every number the window shows, as text, JSON, CSV or PNG.",
    after_help = cli::MAIN_EXAMPLES
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Open the debugger window (the default).
    #[command(after_help = cli::GUI_EXAMPLES)]
    Gui(window::GuiArgs),
    /// Render the viewport headlessly to a PNG (as File > Export viewport PNG does).
    #[command(after_help = cli::SCREENSHOT_EXAMPLES)]
    Screenshot(window::ScreenshotArgs),
    /// A case's worst samples and boxes at a perturbation (the window's failure browser).
    #[command(after_help = cli::FAILURES_EXAMPLES)]
    Failures(failures::FailuresArgs),
    /// Render "play α" headlessly as an animated GIF: the session's view from α = 0 to --alpha-to.
    #[command(after_help = cli::CLIP_EXAMPLES)]
    Clip(window::ClipArgs),
    /// Propagate the prior Θ(α) through an extrinsic to one point: Ξ = HΘHᵀ (paper eq. 5–8).
    #[command(after_help = cli::PROPAGATE_EXAMPLES)]
    Propagate(uncertainty::PropagateArgs),
    /// Generate a Lyft-format multi-LiDAR dataset with the ray-cast simulator.
    #[command(after_help = cli::SYNTH_EXAMPLES)]
    Synth(data::SynthArgs),
    /// Fuse a sample under a perturbation and print what the debugger shows: the applied ρ, φ and
    /// extrinsics, tr(Ξ) range, |P_u|/|P|, the tr(Ξ) histogram and per-box statistics.
    #[command(after_help = cli::FUSE_EXAMPLES)]
    Fuse(uncertainty::FuseArgs),
    /// Write the fused, perturbed cloud of one sample with tr(Ξ) (and Ξ) per point as PLY or PCD.
    #[command(after_help = cli::EXPORT_EXAMPLES)]
    Export(export::ExportArgs),
    /// Online calibration: re-estimate the auxiliary LiDARs' drifted extrinsics by point-to-plane
    /// ICP and report the error before and after, degenerate directions and the covariance.
    #[command(after_help = cli::CALIBRATE_EXAMPLES)]
    Calibrate(calibrate::CalibrateArgs),
    /// Show a sample of a Lyft-format dataset: LiDARs, extrinsics T^b_l and boxes in the base frame.
    #[command(after_help = cli::INSPECT_EXAMPLES)]
    Inspect(data::InspectArgs),
    /// Run the plane-fitting experiment of paper §III-C / Fig. 2; writes plane_fit.csv and plane_fit.png.
    #[command(after_help = cli::PLANE_FIT_EXAMPLES)]
    PlaneFit(uncertainty::PlaneFitArgs),
    /// Train the stage-1 detectors and the refiner, calibrate Result Fusion's temperatures, tune
    /// box voting.
    #[command(subcommand, after_help = cli::TRAIN_EXAMPLES)]
    Train(train::TrainCommand),
    /// Run a stage-1 detector (shipped weights) on one sample and print its boxes.
    #[command(after_help = cli::detect_help())]
    Detect(detect::DetectArgs),
    /// Score predictions against a dataset's ground truth: KITTI-style AP_3D as the paper reports it
    /// (§V-A-2, in percent) and Lyft's official mAP (devkit footprint and exact footprint).
    #[command(after_help = cli::EVAL_EXAMPLES)]
    Eval(eval::EvalArgs),
    /// The paper's Table I on a dataset: every stage-1 case run over the samples, car AP_3D
    /// easy/moderate/hard at IoU 0.7 and 0.5, as a Markdown table (and JSON with --out).
    #[command(after_help = cli::TABLE1_EXAMPLES)]
    Table1(table1::Table1Args),
    /// The paper's Table II: cases × α × perturbation trials, car AP_3D@0.7 mean ± std, resumable
    /// and shardable (`mlod sweep merge` unites shards).
    #[command(after_help = cli::SWEEP_EXAMPLES)]
    Sweep(sweep::SweepArgs),
    /// A dataset's sensor statistics: points per sweep, rings, intensity, ground height, ray drop,
    /// range, and points per object against range; text, JSON and PNG plots.
    #[command(after_help = cli::STATS_EXAMPLES)]
    Stats(stats::StatsArgs),
    /// Analyses of the refiner: its active points (§V-C, Fig. 5).
    #[command(subcommand, after_help = cli::ANALYZE_EXAMPLES)]
    Analyze(analyze::AnalyzeCommand),
}

fn main() -> std::process::ExitCode {
    // `mlod … | head` ends quietly, as other command-line tools do, instead of a panic on the
    // closed pipe (Rust ignores SIGPIPE by default).
    #[cfg(unix)]
    // SAFETY: restoring the default disposition of one signal before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    match run(Cli::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", message(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// The error and its causes on one line, no backtrace (a user-facing message); a cause whose
/// text the message already holds (a library error that prints its source) is not repeated.
fn message(e: &anyhow::Error) -> String {
    let mut msg = e.to_string();
    for cause in e.chain().skip(1) {
        let c = cause.to_string();
        if !msg.contains(&c) {
            msg.push_str(": ");
            msg.push_str(&c);
        }
    }
    msg
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        None => window::gui(window::GuiArgs::default()),
        Some(Command::Gui(a)) => window::gui(a),
        Some(Command::Screenshot(a)) => window::screenshot(a),
        Some(Command::Clip(a)) => window::clip(a),
        Some(Command::Failures(a)) => failures::run(a),
        Some(Command::Propagate(a)) => uncertainty::propagate(a),
        Some(Command::PlaneFit(a)) => uncertainty::plane_fit(a),
        Some(Command::Fuse(a)) => uncertainty::fuse_cmd(a),
        Some(Command::Export(a)) => export::run(a),
        Some(Command::Calibrate(a)) => calibrate::run(a),
        Some(Command::Inspect(a)) => data::inspect(a),
        Some(Command::Synth(a)) => data::synth(a),
        Some(Command::Train(c)) => train::train(c),
        Some(Command::Detect(a)) => detect::detect(a),
        Some(Command::Eval(a)) => eval::eval_cmd(a),
        Some(Command::Table1(a)) => table1::table1_cmd(a),
        Some(Command::Sweep(a)) => sweep::run(a),
        Some(Command::Analyze(c)) => analyze::analyze(c),
        Some(Command::Stats(a)) => stats::run(a),
    }
}
