//! `mlod gui` and `mlod screenshot`: the debugger window, and its viewport rendered headlessly.

use std::path::PathBuf;

#[cfg(not(feature = "gui"))]
use anyhow::bail;
#[cfg(feature = "gui")]
use anyhow::Context;
use anyhow::Result;

#[derive(clap::Args, Default)]
pub struct GuiArgs {
    /// A Lyft-format dataset (root or version folder); default: the embedded sample_data/.
    #[arg(long)]
    dataset: Option<PathBuf>,
    /// A saved session (reproduces its view exactly; its dataset unless --dataset is given).
    #[arg(long)]
    session: Option<PathBuf>,
    /// Models folder with manifest.json (default: $MLOD_MODELS, else the shipped assets/models),
    /// e.g. your own `mlod train` output.
    #[arg(long)]
    models: Option<PathBuf>,
    /// Measure: repaint continuously for N frames, print frame times, exit.
    #[arg(long)]
    measure_frames: Option<usize>,
    /// With --measure-frames: then press Run and scan the scene for failure cases, printing the
    /// frame times while each is in flight and the time from Run to the boxes on screen.
    #[arg(long, requires = "measure_frames")]
    measure_run: bool,
    #[command(flatten)]
    external: super::external::ExternalArgs,
}

#[derive(clap::Args)]
pub struct ScreenshotArgs {
    #[arg(long)]
    dataset: Option<PathBuf>,
    #[arg(long)]
    session: Option<PathBuf>,
    #[arg(long)]
    out: PathBuf,
    /// WIDTHxHEIGHT in pixels.
    #[arg(long, default_value = "1280x800")]
    size: String,
    #[command(flatten)]
    external: super::external::ExternalArgs,
}

#[derive(clap::Args)]
pub struct ClipArgs {
    /// The view, case and overlays to animate (default: the embedded sample data, first sight).
    #[arg(long)]
    session: Option<PathBuf>,
    #[arg(long)]
    dataset: Option<PathBuf>,
    /// α of the last frame (the first is 0); the session's seed fixes the drift's direction.
    #[arg(long, default_value_t = 0.1)]
    alpha_to: f64,
    /// Frames, first and last included.
    #[arg(long, default_value_t = 40)]
    frames: usize,
    /// Frames per second.
    #[arg(long, default_value_t = 10)]
    fps: u32,
    /// WIDTHxHEIGHT in pixels.
    #[arg(long, default_value = "640x400")]
    size: String,
    /// The GIF to write (atomically).
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    external: super::external::ExternalArgs,
}

/// WIDTHxHEIGHT with sides in 16..=8192.
fn parse_size(size: &str) -> Result<(u32, u32)> {
    size.split_once('x')
        .and_then(|(w, h)| Some((w.trim().parse::<u32>().ok()?, h.trim().parse::<u32>().ok()?)))
        .filter(|(w, h)| (16..=8192).contains(w) && (16..=8192).contains(h))
        .with_context(|| format!("--size must be WIDTHxHEIGHT with sides in 16..=8192, got '{size}'"))
}

#[cfg(feature = "gui")]
pub fn clip(args: ClipArgs) -> Result<()> {
    let clip = mlod::gui::clip::ClipOptions {
        alpha_to: args.alpha_to,
        frames: args.frames,
        size: parse_size(&args.size)?,
        fps: args.fps,
    };
    clip.validate()?;
    let options = app_options(args.dataset, args.session, &args.external, true)?;
    let start = std::time::Instant::now();
    let frames = mlod::gui::clip::render_clip(options, &clip, &|done, total| {
        eprint!("\rframe {done}/{total}");
    })?;
    eprintln!();
    mlod::gui::clip::write_gif(&args.out, &frames, clip.fps)?;
    let bytes = std::fs::metadata(&args.out).map(|m| m.len()).unwrap_or(0);
    eprintln!(
        "wrote {} ({} frames, {:.0} kB, {:.1} s)",
        args.out.display(),
        frames.len(),
        bytes as f64 / 1e3,
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

#[cfg(not(feature = "gui"))]
pub fn clip(_: ClipArgs) -> Result<()> {
    bail!("this build has no GUI (built without the `gui` feature)")
}

/// The window's options: the session (its dataset unless `dataset` is given) and the external
/// detectors the command line defines, which replace the session's of the same name (the user
/// typed them). `headless` (clip, screenshot): nobody can be asked, so a session's external case
/// must be named on the command line.
#[cfg(feature = "gui")]
fn app_options(
    dataset: Option<PathBuf>,
    session: Option<PathBuf>,
    external: &super::external::ExternalArgs,
    headless: bool,
) -> Result<mlod::gui::AppOptions> {
    let specs = external.define()?;
    let session_file = session.clone();
    let mut session = session.map(|p| mlod::session::Session::load(&p)).transpose()?;
    if let Some(s) = session.as_mut() {
        for spec in &specs {
            s.external.retain(|e| e.name != spec.name);
            s.external.push(spec.clone());
        }
        let cases = [Some(s.detection.case), s.compare];
        for case in cases.into_iter().flatten() {
            if let Some(name) = case
                .external_name()
                .filter(|n| headless && !specs.iter().any(|e| e.name == *n))
            {
                anyhow::bail!(
                    "the session's case {case} runs the external detector '{name}': the command line runs only detectors it names: give --detector {name}=COMMAND or --detectors FILE"
                );
            }
        }
    }
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
        measure_run: false,
        models: None,
        session_file,
    })
}

#[cfg(feature = "gui")]
pub fn gui(args: GuiArgs) -> Result<()> {
    let mut options = app_options(args.dataset, args.session, &args.external, false)?;
    options.measure_frames = args.measure_frames.filter(|n| *n > 0);
    options.measure_run = args.measure_run;
    if let Some(m) = args.models {
        mlod::detect::weights::Manifest::load(&m).with_context(|| format!("--models {}", m.display()))?;
        options.models = Some(m);
    }
    mlod::gui::run(options).context("the debugger window failed")
}

#[cfg(feature = "gui")]
pub fn screenshot(args: ScreenshotArgs) -> Result<()> {
    let (w, h) = parse_size(&args.size)?;
    let options = app_options(args.dataset, args.session, &args.external, true)?;
    let img = mlod::gui::screenshot(options, (w, h))?;
    mlod::gui::write_png(&args.out, &img)?;
    eprintln!("wrote {}", args.out.display());
    Ok(())
}

#[cfg(not(feature = "gui"))]
pub fn gui(_: GuiArgs) -> Result<()> {
    bail!("this build has no GUI (built without the `gui` feature); use a subcommand, see --help")
}

#[cfg(not(feature = "gui"))]
pub fn screenshot(_: ScreenshotArgs) -> Result<()> {
    bail!("this build has no GUI (built without the `gui` feature)")
}
