//! "Play α" as a file: the session's view rendered headlessly at α = 0, …, `alpha_to` in equal
//! steps (the session's seed, so the same perturbation direction is scaled up), re-fused,
//! recoloured and — when the session runs its case on every change — re-detected at each step,
//! then written as a looping animated GIF. A thin amber bar along the bottom edge shows α against
//! its maximum. `mlod clip` and the window's "Export clip" both call [`render_clip`] and
//! [`write_gif`].

use std::path::Path;

use crate::gui::{AppOptions, GuiError};

/// Steps of "play α" in the window, and of a clip by default.
pub const PLAY_FRAMES: usize = 40;

/// α of step `k` of `frames` equal steps from 0 to `alpha_to` (the first and last included).
pub fn step_alpha(alpha_to: f64, frames: usize, k: usize) -> f64 {
    alpha_to * k as f64 / (frames.max(2) - 1) as f64
}

/// Where "play α" goes from the α on screen: to that α, or from α = 0 to the paper's largest
/// level, 0.1.
pub fn play_target(alpha: f64) -> f64 {
    if alpha > 0.0 {
        alpha
    } else {
        0.1
    }
}

/// What a clip covers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClipOptions {
    /// The last frame's α (the first is 0).
    pub alpha_to: f64,
    /// Frames, first and last included.
    pub frames: usize,
    /// Image size in pixels.
    pub size: (u32, u32),
    /// Playback speed, frames per second.
    pub fps: u32,
}

impl Default for ClipOptions {
    fn default() -> Self {
        Self {
            alpha_to: 0.1,
            frames: PLAY_FRAMES,
            size: (640, 400),
            fps: 10,
        }
    }
}

impl ClipOptions {
    /// Refuses absurd settings, naming the setting.
    pub fn validate(&self) -> Result<(), GuiError> {
        let bad = |what: String| Err(GuiError::Load(format!("clip: {what}")));
        if !(self.alpha_to.is_finite() && self.alpha_to > 0.0 && self.alpha_to <= 1.0) {
            return bad(format!("--alpha-to {} must be in (0, 1]", self.alpha_to));
        }
        if !(2..=600).contains(&self.frames) {
            return bad(format!("--frames {} must be in 2..=600", self.frames));
        }
        let (w, h) = self.size;
        if !((16..=4096).contains(&w) && (16..=4096).contains(&h)) {
            return bad(format!("size {w}x{h}: each side must be in 16..=4096"));
        }
        if !(1..=50).contains(&self.fps) {
            return bad(format!("--fps {} must be in 1..=50", self.fps));
        }
        Ok(())
    }

    /// α of frame `k`.
    pub fn alpha(&self, k: usize) -> f64 {
        step_alpha(self.alpha_to, self.frames, k)
    }
}

/// Renders the clip's frames; `progress(done, total)` after each.
pub fn render_clip(
    options: AppOptions,
    clip: &ClipOptions,
    progress: &dyn Fn(usize, usize),
) -> Result<Vec<image::RgbaImage>, GuiError> {
    clip.validate()?;
    let mut app = super::headless_loaded(options)?;
    let gpu = crate::render::HeadlessGpu::new()?;
    let mut renderer = crate::render::OffscreenRenderer::new(&gpu.device, &gpu.queue);
    let mut frames = Vec::with_capacity(clip.frames);
    for k in 0..clip.frames {
        let alpha = clip.alpha(k);
        app.session_mut().fuse.perturbation.alpha = alpha;
        app.mark_fuse();
        app.process_jobs(0.0);
        if let Some(t) = app.first_error() {
            return Err(GuiError::Load(format!("at α = {alpha}: {t}")));
        }
        let (view, scene) = app.viewport();
        let mut img = renderer.render(scene, view, clip.size)?;
        alpha_bar(&mut img, alpha / clip.alpha_to);
        frames.push(img);
        progress(k + 1, clip.frames);
    }
    Ok(frames)
}

/// The α bar: the bottom 5 rows, amber over `share` of the width on a dark track.
fn alpha_bar(img: &mut image::RgbaImage, share: f64) {
    let (w, h) = img.dimensions();
    let filled = (share.clamp(0.0, 1.0) * w as f64).round() as u32;
    for y in h.saturating_sub(5)..h {
        for x in 0..w {
            let c = if x < filled {
                [255, 200, 40, 255]
            } else {
                [45, 48, 56, 255]
            };
            img.put_pixel(x, y, image::Rgba(c));
        }
    }
}

/// Writes frames as a looping animated GIF (each frame quantised to its own 256 colours),
/// atomically.
pub fn write_gif(path: &Path, frames: &[image::RgbaImage], fps: u32) -> Result<(), GuiError> {
    let err = |message: String| GuiError::Write {
        path: path.to_path_buf(),
        message,
    };
    let first = frames.first().ok_or_else(|| err("no frames".into()))?;
    let (w, h) = first.dimensions();
    let (w16, h16) = (
        u16::try_from(w).map_err(|_| err(format!("width {w} too large for a GIF")))?,
        u16::try_from(h).map_err(|_| err(format!("height {h} too large for a GIF")))?,
    );
    let mut bytes = Vec::new();
    {
        let mut enc = gif::Encoder::new(&mut bytes, w16, h16, &[]).map_err(|e| err(e.to_string()))?;
        enc.set_repeat(gif::Repeat::Infinite)
            .map_err(|e| err(e.to_string()))?;
        let delay = (100 / fps.max(1)) as u16;
        for img in frames {
            if img.dimensions() != (w, h) {
                return Err(err("frames of different sizes".into()));
            }
            let mut rgba = img.as_raw().clone();
            let mut frame = gif::Frame::from_rgba_speed(w16, h16, &mut rgba, 10);
            frame.delay = delay;
            enc.write_frame(&frame).map_err(|e| err(e.to_string()))?;
        }
    }
    crate::io::write_atomic(path, &bytes).map_err(|e| err(e.to_string()))
}
