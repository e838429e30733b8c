//! The desktop debugger (eframe + egui on wgpu): a sample browser, the 3D viewport with points
//! coloured by source LiDAR, height, intensity or tr(Ξ), the perturbation panel, ground-truth
//! boxes, sessions and screenshots. The GUI holds state and draws; every number comes from the
//! library (`pipeline`, `color`, `session`). `viewport` is a renderer that knows nothing of the
//! panels.

pub mod app;
pub mod clip;
mod consent;
mod jobs;
mod overlay;
mod panels;
mod state;

use std::path::{Path, PathBuf};

use eframe::egui;
use egui_wgpu::wgpu;

pub use app::{AppOptions, MlodApp};
pub use state::{
    DetectionCounts, DetectionView, Refinement, SelectionDetails, ACTIVE_POINT_COLOR, FALSE_POSITIVE_COLOR,
    GT_COLOR, LINK_COLOR, PROPOSAL_COLOR, REFINED_COLOR, REFINED_FALSE_POSITIVE_COLOR, SELECTED_COLOR,
    SELECTED_HALO_COLOR,
};

/// The window title (screenshots find the window by it).
pub const TITLE: &str = "MLOD debugger";

/// The embedded sample dataset next to the crate.
pub fn default_dataset() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("sample_data")
}

/// Errors of the GUI entry points.
#[derive(Debug, thiserror::Error)]
pub enum GuiError {
    #[error(
        "could not open the window: {0}. Without a GPU install software Vulkan \
         (`apt-get install mesa-vulkan-drivers libvulkan1`) or try WGPU_BACKEND=gl; \
         without a display use Xvfb (`xvfb-run -a mlod`)"
    )]
    Window(#[from] eframe::Error),
    #[error(transparent)]
    Viewport(#[from] crate::render::ViewportError),
    #[error("cannot write {path}: {message}")]
    Write { path: PathBuf, message: String },
    #[error("{0}")]
    Load(String),
}

/// Opens the window.
pub fn run(options: AppOptions) -> Result<(), GuiError> {
    let mut native = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default()
            .with_title(TITLE)
            .with_inner_size([1280.0, 800.0])
            .with_drag_and_drop(true),
        ..Default::default()
    };
    if options.measure_frames.is_some() {
        native.wgpu_options.surface.present_mode = wgpu::PresentMode::AutoNoVsync;
    }
    eframe::run_native(
        TITLE,
        native,
        Box::new(move |cc| Ok(Box::new(MlodApp::new(cc, options)))),
    )?;
    Ok(())
}

/// Writes an RGBA image as PNG, atomically.
pub fn write_png(path: &Path, img: &image::RgbaImage) -> Result<(), GuiError> {
    crate::analysis::plot::write_png(
        path,
        img.width(),
        img.height(),
        img.as_raw(),
        image::ExtendedColorType::Rgba8,
    )
    .map_err(|e| GuiError::Write {
        path: path.to_path_buf(),
        message: format!("{e:#}"),
    })
}

/// Renders the viewport of a dataset/session headlessly (what File > Export viewport PNG writes).
/// In compare mode, the two halves side by side (the main case left, the compare case right, one
/// camera, a 3-pixel grey gap), as the window splits its viewport.
pub fn screenshot(options: AppOptions, size: (u32, u32)) -> Result<image::RgbaImage, GuiError> {
    let app = headless_loaded(options)?;
    let gpu = crate::render::HeadlessGpu::new()?;
    let mut renderer = crate::render::OffscreenRenderer::new(&gpu.device, &gpu.queue);
    let (view, scene) = app.viewport();
    let Some(scene_b) = app.compare_scene() else {
        return Ok(renderer.render(scene, view, size)?);
    };
    const GAP: u32 = 3;
    let (w, h) = size;
    let half = (w.saturating_sub(GAP) / 2).max(1);
    let a = renderer.render(scene, view, (half, h))?;
    let b = renderer.render(scene_b, view, (half, h))?;
    let mut out = image::RgbaImage::from_pixel(w, h, image::Rgba([90, 90, 90, 255]));
    image::imageops::replace(&mut out, &a, 0, 0);
    image::imageops::replace(&mut out, &b, i64::from(w - half), 0);
    Ok(out)
}

/// The app without a window, its dataset and sample loaded (jobs run inline); the first error
/// toast, or no sample at all, is an error.
pub(crate) fn headless_loaded(options: AppOptions) -> Result<MlodApp, GuiError> {
    let app = MlodApp::headless(
        AppOptions {
            synchronous: true,
            ..options
        },
        None,
    );
    if let Some(t) = app.first_error() {
        return Err(GuiError::Load(t.to_string()));
    }
    if app.fused().is_none() {
        return Err(GuiError::Load("no sample could be loaded".into()));
    }
    Ok(app)
}
