//! Headless rendering of the viewport: a GPU device without a window, and the same pipelines as
//! the window rendering into a texture that is copied back to an [`image::RgbaImage`].
//! `mlod screenshot` and the tests go through here.

use std::future::Future;
use std::pin::pin;
use std::sync::mpsc;
use std::sync::Arc;
use std::task::{Context, Poll, Wake, Waker};
use std::time::Duration;

use egui_wgpu::wgpu;

use crate::render::renderer::{FrameParams, PointSource, SceneRenderer, COLOR_FORMAT};
use crate::render::{SceneHandle, Viewport, ViewportError, DEFAULT_MSAA_SAMPLES};

/// How long to wait for the GPU (software rasterisers are slow with big frames).
const GPU_TIMEOUT: Duration = Duration::from_secs(30);

/// Minimal executor for wgpu's futures (they resolve immediately on native backends).
fn block_on<F: Future>(future: F) -> F::Output {
    struct Unpark(std::thread::Thread);
    impl Wake for Unpark {
        fn wake(self: Arc<Self>) {
            self.0.unpark();
        }
    }
    let waker = Waker::from(Arc::new(Unpark(std::thread::current())));
    let mut cx = Context::from_waker(&waker);
    let mut future = pin!(future);
    loop {
        match future.as_mut().poll(&mut cx) {
            Poll::Ready(out) => return out,
            Poll::Pending => std::thread::park_timeout(Duration::from_millis(1)),
        }
    }
}

/// A GPU device and queue created without a window.
#[derive(Clone, Debug)]
pub struct HeadlessGpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub adapter_info: wgpu::AdapterInfo,
}

impl HeadlessGpu {
    /// Default backends (overridable with `WGPU_BACKEND`, e.g. `vulkan` or `gl`), the adapter
    /// wgpu prefers, and a device with default limits. Without any adapter the error says to
    /// install `mesa-vulkan-drivers` (software Vulkan).
    pub fn new() -> Result<Self, ViewportError> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let adapter = block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            ..Default::default()
        }))
        .map_err(|e| ViewportError::NoAdapter(e.to_string()))?;
        let (device, queue) = block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("mlod headless"),
            required_limits: wgpu::Limits::default().using_resolution(adapter.limits()),
            ..Default::default()
        }))?;
        Ok(Self {
            device,
            queue,
            adapter_info: adapter.get_info(),
        })
    }
}

/// Renders views offscreen with the viewport's pipelines; keep one around to render many frames
/// (pipelines, scene buffers and the target are reused exactly as in the window).
pub struct OffscreenRenderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    renderer: SceneRenderer,
}

impl OffscreenRenderer {
    /// Pipelines for `DEFAULT_MSAA_SAMPLES`, as in the window.
    pub fn new(device: &wgpu::Device, queue: &wgpu::Queue) -> Self {
        Self::with_msaa(device, queue, DEFAULT_MSAA_SAMPLES)
    }

    /// `msaa_samples`: 1 or 4.
    pub fn with_msaa(device: &wgpu::Device, queue: &wgpu::Queue, msaa_samples: u32) -> Self {
        Self::with_source(device, queue, msaa_samples, PointSource::for_device(device))
    }

    pub(crate) fn with_source(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        msaa_samples: u32,
        source: PointSource,
    ) -> Self {
        Self {
            device: device.clone(),
            queue: queue.clone(),
            renderer: SceneRenderer::new(device, msaa_samples, None, source),
        }
    }

    /// Renders `scene` seen by `view` into a `size` (pixels) image; one UI point is one pixel.
    pub fn render(
        &mut self,
        scene: &SceneHandle,
        view: &Viewport,
        size: (u32, u32),
    ) -> Result<image::RgbaImage, ViewportError> {
        let (width, height) = size;
        let max = self.renderer.max_texture_side();
        if width == 0 || height == 0 || width > max || height > max {
            return Err(ViewportError::BadSize { width, height, max });
        }
        let params = FrameParams {
            size: [width, height],
            camera: view.camera.clone(),
            settings: view.settings.clone(),
            pixels_per_point: 1.0,
        };
        const TARGET: u64 = 0;
        let commands = self
            .renderer
            .render(&self.device, &self.queue, TARGET, scene, &params)
            .ok_or(ViewportError::BadSize { width, height, max })?;
        let texture = &self
            .renderer
            .target(TARGET)
            .ok_or_else(|| ViewportError::Readback("no render target".into()))?
            .resolved;
        read_back(&self.device, &self.queue, commands, texture)
    }
}

/// Submits `commands`, copies `texture` (RGBA8) to a buffer and returns it as an image.
fn read_back(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    commands: wgpu::CommandBuffer,
    texture: &wgpu::Texture,
) -> Result<image::RgbaImage, ViewportError> {
    debug_assert_eq!(texture.format(), COLOR_FORMAT);
    let (width, height) = (texture.width(), texture.height());
    let unpadded = width * 4;
    let align = wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    let padded = unpadded.div_ceil(align) * align;
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("mlod viewport readback"),
        size: u64::from(padded) * u64::from(height),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
        label: Some("mlod viewport readback"),
    });
    encoder.copy_texture_to_buffer(
        texture.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &buffer,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(padded),
                rows_per_image: None,
            },
        },
        wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        },
    );
    let submission = queue.submit([commands, encoder.finish()]);
    let slice = buffer.slice(..);
    let (sender, receiver) = mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |result| {
        // The receiver outlives this callback unless we already returned with an error.
        let _ = sender.send(result);
    });
    device
        .poll(wgpu::PollType::Wait {
            submission_index: Some(submission),
            timeout: Some(GPU_TIMEOUT),
        })
        .map_err(|e| ViewportError::Readback(e.to_string()))?;
    receiver
        .recv_timeout(GPU_TIMEOUT)
        .map_err(|e| ViewportError::Readback(e.to_string()))?
        .map_err(|e| ViewportError::Readback(e.to_string()))?;
    let data = slice
        .get_mapped_range()
        .map_err(|e| ViewportError::Readback(e.to_string()))?;
    let mut pixels = Vec::with_capacity(unpadded as usize * height as usize);
    for row in data.chunks_exact(padded as usize) {
        pixels.extend_from_slice(row.get(..unpadded as usize).unwrap_or_default());
    }
    drop(data);
    buffer.unmap();
    image::RgbaImage::from_raw(width, height, pixels)
        .ok_or_else(|| ViewportError::Readback("image size mismatch".into()))
}

/// One-shot convenience: renders `scene` seen by `view` into a `size` image. For many frames keep
/// an [`OffscreenRenderer`] instead (this one compiles the pipelines every call).
pub fn render_offscreen(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    scene: &SceneHandle,
    view: &Viewport,
    size: (u32, u32),
) -> Result<image::RgbaImage, ViewportError> {
    OffscreenRenderer::new(device, queue).render(scene, view, size)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{grid_lines, Camera, View};

    /// Both ways of feeding points to the shader draw the same pixels (needs a GPU or lavapipe).
    #[test]
    fn storage_and_instanced_points_render_identically() {
        let gpu = match HeadlessGpu::new() {
            Ok(gpu) => gpu,
            Err(e) => panic!("{e}"),
        };
        let mut scene = SceneHandle::new();
        let points: Vec<[f32; 3]> = (0..2000)
            .map(|i| {
                let a = i as f32 * 0.05;
                [a.cos() * (3.0 + a), a.sin() * (3.0 + a), (i % 5) as f32 * 0.2]
            })
            .collect();
        let colors: Vec<[u8; 4]> = (0..2000u32).map(|i| [(i % 256) as u8, 120, 200, 255]).collect();
        assert!(scene.set_points(points, colors).is_ok());
        scene.set_lines(grid_lines(30.0, 5.0, -1.0));
        let view = Viewport {
            camera: Camera::preset(View::Overview, scene.radius()),
            ..Viewport::default()
        };
        for msaa in [1, 4] {
            let render = |source| {
                OffscreenRenderer::with_source(&gpu.device, &gpu.queue, msaa, source)
                    .render(&scene, &view, (160, 120))
                    .map_err(|e| e.to_string())
            };
            let storage = render(PointSource::Storage);
            let instanced = render(PointSource::Instanced);
            assert!(
                storage.is_ok() && storage == instanced,
                "msaa {msaa}: images differ"
            );
        }
    }
}
