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
    /// Measure: repaint continuously for N frames, print frame times, exit.
    #[arg(long)]
    measure_frames: Option<usize>,
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
pub fn gui(args: GuiArgs) -> Result<()> {
    let mut options = app_options(args.dataset, args.session)?;
    options.measure_frames = args.measure_frames.filter(|n| *n > 0);
    mlod::gui::run(options).context("the debugger window failed")
}

#[cfg(feature = "gui")]
pub fn screenshot(args: ScreenshotArgs) -> Result<()> {
    let size = &args.size;
    let (w, h) = size
        .split_once('x')
        .and_then(|(w, h)| Some((w.trim().parse::<u32>().ok()?, h.trim().parse::<u32>().ok()?)))
        .filter(|(w, h)| (16..=8192).contains(w) && (16..=8192).contains(h))
        .with_context(|| format!("--size must be WIDTHxHEIGHT with sides in 16..=8192, got '{size}'"))?;
    let options = app_options(args.dataset, args.session)?;
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
