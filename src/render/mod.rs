//! The 3D viewport: a depth-correct wgpu renderer for point clouds and line wireframes inside an
//! egui panel, with an orbit / bird's-eye camera. It knows nothing of the panels: the app hands it
//! points, colours and lines (a [`SceneHandle`]) and a [`Viewport`] (camera + draw settings), and
//! gets back the egui response and any double-clicked point.
//!
//! # How it works
//!
//! * **Data.** [`SceneHandle`] holds positions (base frame, metres), sRGB colours and line pairs
//!   ([`LineVertex`]) behind `Arc`s, each with a generation number. The GPU keeps one buffer per
//!   kind per scene, grown on demand, and rewrites a kind with a single `queue.write_buffer` only
//!   when its generation changed — recolouring 150k points every α tick uploads 600 kB and
//!   allocates nothing. Scenes and views not drawn for 600 frames give their buffers back.
//! * **Points** are one draw call with no vertex buffer: positions (12 B) and colours (4 B) sit in
//!   two storage buffers holding the app's slices byte for byte; vertex `3i + k` reads point `i`
//!   and becomes corner `k` of a screen-aligned triangle circumscribing the point's disc (size in
//!   UI points × pixels per point), and the fragment shader cuts the circle out
//!   (alpha-to-coverage with MSAA for smooth rims). One triangle rather than rerun's two-triangle
//!   quad: software rasterisers pay per triangle, and it cut 150k points at 1280×800 on lavapipe
//!   from 137 to 83 ms. On devices without vertex-stage storage buffers (egui on GL runs with
//!   WebGL2 limits) the same slices are bound as per-instance vertex attributes instead.
//! * **Lines** are instanced draws, one segment per instance, expanded into quads of constant
//!   pixel width (the view's line width times the vertex's factor) after clipping the segment to
//!   the near plane. The grid is drawn in depth before the points; boxes (the scene's overlay
//!   lines) after them with no depth test, each on a dark outline, so they never sink into the
//!   points.
//! * **Depth.** egui's paint-callback pass has no depth attachment, so each view renders into its
//!   own colour (4× MSAA on GPUs, none on software rasterisers; resolved) + depth target in
//!   [`egui_wgpu::CallbackTrait::prepare`] with its own command encoder, and `paint` only blits
//!   the resolved texture, one texel per pixel, into egui's pass. Depth is reversed (1 near,
//!   0 far) with an infinite far plane.
//! * **Headless.** [`OffscreenRenderer`] records the very same pass and reads the texture back,
//!   so `mlod screenshot` and the tests see what the window shows; [`HeadlessGpu`] makes a
//!   device without a window.
//! * **Camera.** See [`camera`]: orbit (drag rotate, right/shift/middle-drag pan, scroll zoom
//!   bounded by the scene radius, double-click focuses the front-most point within
//!   [`camera::PICK_RADIUS`] of the cursor, found on the CPU) and bird's eye (orthographic,
//!   +x up on screen).
//!
//! # Usage
//!
//! ```ignore
//! // Once, at app creation (`cc: &eframe::CreationContext`):
//! if let Some(rs) = cc.wgpu_render_state.as_ref() { viewport::install(rs); }
//! // When data changes (bump = new Arc + new generation):
//! scene.set_points(positions, colors)?;          // or scene.set_colors(colors)? on a recolour
//! scene.set_lines(lines);                        // grid_lines(..) + box_lines(..) for each box
//! // Every frame, in the central panel:
//! let out = viewport::show(ui, &mut self.view, &self.scene);
//! if let Some(i) = out.picked { /* point i was double-clicked (and focused) */ }
//! ```

mod buffers;
pub mod camera;
mod offscreen;
mod renderer;
mod scene;

use egui_wgpu::wgpu;
use serde::{Deserialize, Serialize};

pub use camera::{Camera, Projection, View};
pub use offscreen::{render_offscreen, HeadlessGpu, OffscreenRenderer};
pub use scene::{box_lines, ego_lines, grid_lines, LineVertex, SceneHandle, GRID_WIDTH};

pub use renderer::GpuUsage;
use renderer::{EguiPass, FrameParams, PointSource, SceneRenderer, ViewportCallback, ViewportResources};

/// MSAA of the offscreen targets (screenshots), and of the window's on a real GPU.
pub const DEFAULT_MSAA_SAMPLES: u32 = 4;

/// The MSAA the window uses on an adapter: 4 on GPUs, 1 on software rasterisers (lavapipe
/// spends ~60 ms more per 1280×800 frame on 4× MSAA).
pub fn auto_msaa(info: &wgpu::AdapterInfo) -> u32 {
    if info.device_type == wgpu::DeviceType::Cpu {
        1
    } else {
        DEFAULT_MSAA_SAMPLES
    }
}

/// The controls, for a help overlay.
pub const CONTROLS_HELP: &str = "\
Drag: rotate (bird's eye: pan)
Right-drag, Shift+drag or middle-drag: pan (bird's eye: right-drag rotates)
Scroll or pinch: zoom
Double-click a point: focus on it
Click a box: select it (details in the right panel); F: focus it; Esc: clear";

/// Errors of the viewport's library side (device creation, data handed over, read-back).
#[derive(Debug, thiserror::Error)]
pub enum ViewportError {
    #[error(
        "no GPU adapter found ({0}). Without a GPU install software Vulkan \
         (`apt-get install mesa-vulkan-drivers libvulkan1`) or try WGPU_BACKEND=gl"
    )]
    NoAdapter(String),
    #[error("could not create the GPU device: {0}")]
    RequestDevice(#[from] wgpu::RequestDeviceError),
    #[error("{points} points but {colors} colours: they must have the same length")]
    LengthMismatch { points: usize, colors: usize },
    #[error("image size {width}x{height} is not renderable (each side 1..={max} pixels)")]
    BadSize { width: u32, height: u32, max: u32 },
    #[error("reading the rendered image back from the GPU failed: {0}")]
    Readback(String),
}

/// Default box line width, UI points.
pub const DEFAULT_LINE_WIDTH: f32 = 2.5;

/// How the scene is drawn (stored in sessions along with the camera).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ViewSettings {
    /// Point diameter in UI points (pixels × pixels-per-point).
    pub point_size: f32,
    /// Box line width in UI points (the grid's lines are [`GRID_WIDTH`] of it).
    pub line_width: f32,
    /// Clear colour, sRGB.
    pub background: [u8; 3],
}

impl Default for ViewSettings {
    fn default() -> Self {
        Self {
            point_size: 2.5,
            line_width: DEFAULT_LINE_WIDTH,
            background: [20, 23, 30],
        }
    }
}

/// One view: camera and draw settings. Serialisable for sessions.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Viewport {
    pub camera: Camera,
    pub settings: ViewSettings,
}

/// The viewport's MSAA, and how egui's render pass is configured (the blit into it must match).
/// The egui defaults match eframe's and egui_kittest's (`multisampling: 0`, `depth_buffer: 0`).
#[derive(Clone, Copy, Debug)]
pub struct InstallOptions {
    /// MSAA of the viewport's own targets: 1 or 4.
    pub msaa_samples: u32,
    /// `NativeOptions::multisampling` (0 or 1 = none).
    pub egui_msaa_samples: u32,
    /// The depth format eframe gives its pass when `NativeOptions::depth_buffer > 0`.
    pub egui_depth_format: Option<wgpu::TextureFormat>,
}

impl InstallOptions {
    /// [`auto_msaa`] for the adapter, egui's pass as eframe sets it up by default.
    pub fn for_adapter(info: &wgpu::AdapterInfo) -> Self {
        Self {
            msaa_samples: auto_msaa(info),
            egui_msaa_samples: 1,
            egui_depth_format: None,
        }
    }
}

/// Creates the pipelines and stores them in egui's callback resources. Call once with
/// `cc.wgpu_render_state` (window and egui_kittest alike); calling again replaces them.
pub fn install(render_state: &egui_wgpu::RenderState) {
    let options = InstallOptions::for_adapter(&render_state.adapter.get_info());
    install_with(render_state, options);
}

/// [`install`] for an egui pass with MSAA or a depth buffer.
pub fn install_with(render_state: &egui_wgpu::RenderState, options: InstallOptions) {
    let egui = EguiPass {
        format: render_state.target_format,
        msaa_samples: options.egui_msaa_samples,
        depth_format: options.egui_depth_format,
    };
    let source = PointSource::for_device(&render_state.device);
    let renderer = SceneRenderer::new(&render_state.device, options.msaa_samples, Some(egui), source);
    render_state
        .renderer
        .write()
        .callback_resources
        .insert(ViewportResources(renderer));
}

/// What the viewport renderer holds on the GPU of `render_state`; `None` before [`install`].
pub fn gpu_usage(render_state: &egui_wgpu::RenderState) -> Option<GpuUsage> {
    let renderer = render_state.renderer.read();
    renderer
        .callback_resources
        .get::<ViewportResources>()
        .map(|ViewportResources(r)| r.usage())
}

/// What [`show`] hands back.
pub struct ViewportOutput {
    /// The viewport's response (hover it for tooltips; `rect` for [`Camera::project`]).
    pub response: egui::Response,
    /// The point double-clicked this frame (index into the scene's points); the camera has
    /// already focused on it.
    pub picked: Option<usize>,
}

/// Fills the rest of `ui` with the 3D view of `scene`, handles camera input, and adds the paint
/// callback. Without [`install`] (or without wgpu) the area stays empty.
pub fn show(ui: &mut egui::Ui, viewport: &mut Viewport, scene: &SceneHandle) -> ViewportOutput {
    let size = ui.available_size().max(egui::Vec2::splat(1.0));
    let (rect, response) = ui.allocate_exact_size(size, egui::Sense::click_and_drag());
    let picked = viewport.camera.handle_input(&response, ui, scene);
    let ppp = ui.ctx().pixels_per_point();
    // The same rounding egui uses for the callback's viewport, so texels map 1:1 to pixels.
    let px = |a: f32, b: f32| ((b * ppp).round() - (a * ppp).round()).max(0.0) as u32;
    let params = FrameParams {
        size: [px(rect.min.x, rect.max.x), px(rect.min.y, rect.max.y)],
        camera: viewport.camera.clone(),
        settings: viewport.settings.clone(),
        pixels_per_point: ppp,
    };
    ui.painter().add(egui_wgpu::Callback::new_paint_callback(
        rect,
        ViewportCallback {
            target_id: response.id.value(),
            scene: scene.clone(),
            params,
        },
    ));
    ViewportOutput { response, picked }
}
