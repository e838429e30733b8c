//! GPU side of the viewport: pipelines, per-scene buffers, per-view render targets, and the egui
//! paint callback that ties them together.
//!
//! How it works: a frame of one view is one render pass into the view's own colour (optionally
//! multisampled, resolved) + depth target: the grid's lines first (one instanced draw, a segment
//! per instance), then points (one draw of three vertices per point; the vertex shader reads the
//! point from storage buffers at `vertex_index / 3` and places corner `vertex_index % 3` of a
//! triangle around its disc), then the box lines over everything without a depth test — a dark,
//! wider copy of every segment first, then the coloured ones — so that a box is never hidden in
//! the points and its colour always sits on a dark rim. Devices without vertex-stage storage buffers (egui's GL backend
//! runs with WebGL2 limits) get the same points as per-instance attributes, one instance per
//! point, from the same slices. In the window that pass runs in [`egui_wgpu::CallbackTrait::prepare`] on its own
//! command encoder, and [`egui_wgpu::CallbackTrait::paint`] only blits the resolved texture into
//! egui's pass (which has no depth attachment). Offscreen rendering records the same pass and
//! copies the texture back to the CPU instead of blitting.

use std::collections::HashMap;

use egui_wgpu::wgpu;

use crate::render::buffers::{GrowBuffer, SceneBuffers};
use crate::render::{Camera, SceneHandle, ViewSettings};

/// Colour format of every view target; holds gamma-encoded (sRGB) bytes as they are.
pub(crate) const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// Where the point shader reads points from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum PointSource {
    /// Two read-only storage buffers, one non-instanced draw (the default).
    Storage,
    /// Per-instance vertex attributes, one instanced draw (no vertex-stage storage buffers).
    Instanced,
}

impl PointSource {
    /// Storage buffers where the device allows two of them in the vertex stage.
    pub(crate) fn for_device(device: &wgpu::Device) -> Self {
        if device.limits().max_storage_buffers_per_shader_stage >= 2 {
            Self::Storage
        } else {
            Self::Instanced
        }
    }

    fn shader(self) -> &'static str {
        match self {
            Self::Storage => concat!(include_str!("scene.wgsl"), include_str!("points_storage.wgsl")),
            Self::Instanced => {
                concat!(include_str!("scene.wgsl"), include_str!("points_instanced.wgsl"))
            }
        }
    }

    pub(crate) fn buffer_usage(self) -> wgpu::BufferUsages {
        match self {
            Self::Storage => wgpu::BufferUsages::STORAGE,
            Self::Instanced => wgpu::BufferUsages::VERTEX,
        }
    }
}

/// Per-frame constants of one view. Keep in sync with `FrameUniforms` in scene.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct FrameUniforms {
    view_proj: [[f32; 4]; 4],
    viewport_px: [f32; 2],
    point_radius_px: f32,
    line_half_width_px: f32,
    near_w: f32,
    alpha_to_coverage: u32,
    /// The dark rim around box lines, pixels on each side.
    outline_px: f32,
    _pad: f32,
}
const _: () = assert!(std::mem::size_of::<FrameUniforms>() == 96);

/// The dark rim drawn around box lines (UI points on each side): it separates a box's colour
/// from whatever points lie behind it.
const OUTLINE_WIDTH: f32 = 1.0;

/// Everything needed to draw one frame of one view.
#[derive(Clone, Debug)]
pub(crate) struct FrameParams {
    /// Target size in physical pixels.
    pub size: [u32; 2],
    pub camera: Camera,
    pub settings: ViewSettings,
    pub pixels_per_point: f32,
}

impl FrameParams {
    fn uniforms(&self, alpha_to_coverage: bool) -> FrameUniforms {
        let [w, h] = self.size.map(|v| v.max(1) as f32);
        let ppp = if self.pixels_per_point > 0.0 {
            self.pixels_per_point
        } else {
            1.0
        };
        let px = |pt: f32| (pt.max(0.0) * ppp).min(64.0);
        FrameUniforms {
            view_proj: self.camera.view_proj(w / h).to_cols_array_2d(),
            viewport_px: [w, h],
            point_radius_px: 0.5 * px(self.settings.point_size),
            line_half_width_px: 0.5 * px(self.settings.line_width),
            near_w: self.camera.near_w(),
            alpha_to_coverage: u32::from(alpha_to_coverage),
            outline_px: px(OUTLINE_WIDTH),
            _pad: 0.0,
        }
    }

    fn clear_color(&self) -> wgpu::Color {
        let [r, g, b] = self.settings.background.map(|c| f64::from(c) / 255.0);
        wgpu::Color { r, g, b, a: 1.0 }
    }
}

/// What the viewport holds on the GPU ([`crate::render::gpu_usage`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GpuUsage {
    /// Scenes with buffers (evicted after a while unused).
    pub scenes: usize,
    /// Offscreen render targets (one per viewport, evicted likewise).
    pub targets: usize,
    /// Bytes of the scenes' point, colour and line buffers.
    pub buffer_bytes: u64,
}

/// The colour + depth target of one view, with its uniform buffer and bind groups.
pub(crate) struct RenderTarget {
    size: [u32; 2],
    msaa_view: Option<wgpu::TextureView>,
    pub(crate) resolved: wgpu::Texture,
    depth_view: wgpu::TextureView,
    uniforms: wgpu::Buffer,
    uniform_bind_group: wgpu::BindGroup,
    blit_bind_group: Option<wgpu::BindGroup>,
    /// The renderer's frame counter when this view was last drawn.
    last_used: u64,
}

impl RenderTarget {
    fn new(device: &wgpu::Device, renderer: &SceneRenderer, size: [u32; 2]) -> Self {
        let extent = wgpu::Extent3d {
            width: size[0],
            height: size[1],
            depth_or_array_layers: 1,
        };
        let texture = |label: &str, format, samples, usage| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: extent,
                mip_level_count: 1,
                sample_count: samples,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
        };
        let samples = renderer.sample_count;
        let resolved = texture(
            "mlod viewport colour",
            COLOR_FORMAT,
            1,
            wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::COPY_SRC,
        );
        let msaa_view = (samples > 1).then(|| {
            texture(
                "mlod viewport colour (msaa)",
                COLOR_FORMAT,
                samples,
                wgpu::TextureUsages::RENDER_ATTACHMENT,
            )
            .create_view(&wgpu::TextureViewDescriptor::default())
        });
        let depth_view = texture(
            "mlod viewport depth",
            DEPTH_FORMAT,
            samples,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        )
        .create_view(&wgpu::TextureViewDescriptor::default());
        let uniforms = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("mlod viewport uniforms"),
            size: std::mem::size_of::<FrameUniforms>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let uniform_bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("mlod viewport uniforms"),
            layout: &renderer.uniform_layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: uniforms.as_entire_binding(),
            }],
        });
        let resolved_view = resolved.create_view(&wgpu::TextureViewDescriptor::default());
        let blit_bind_group = renderer.blit.as_ref().map(|blit| {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("mlod viewport blit"),
                layout: &blit.layout,
                entries: &[wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(&resolved_view),
                }],
            })
        });
        Self {
            size,
            msaa_view,
            resolved,
            depth_view,
            uniforms,
            uniform_bind_group,
            blit_bind_group,
            last_used: 0,
        }
    }
}

/// The pipeline that copies a view's texture into egui's render pass.
struct BlitPipeline {
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
}

/// How egui's own render pass is set up (the blit pipeline must match it).
#[derive(Clone, Copy, Debug)]
pub(crate) struct EguiPass {
    pub format: wgpu::TextureFormat,
    pub msaa_samples: u32,
    pub depth_format: Option<wgpu::TextureFormat>,
}

impl BlitPipeline {
    fn new(device: &wgpu::Device, egui: EguiPass) -> Self {
        let module = device.create_shader_module(wgpu::include_wgsl!("blit.wgsl"));
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("mlod viewport blit"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Float { filterable: false },
                    view_dimension: wgpu::TextureViewDimension::D2,
                    multisampled: false,
                },
                count: None,
            }],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("mlod viewport blit"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("mlod viewport blit"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_blit"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: egui.depth_format.map(|format| wgpu::DepthStencilState {
                format,
                depth_write_enabled: Some(false),
                depth_compare: Some(wgpu::CompareFunction::Always),
                stencil: wgpu::StencilState::default(),
                bias: wgpu::DepthBiasState::default(),
            }),
            multisample: wgpu::MultisampleState {
                count: egui.msaa_samples.max(1),
                ..Default::default()
            },
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some(if egui.format.is_srgb() {
                    "fs_blit_linear"
                } else {
                    "fs_blit_gamma"
                }),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format: egui.format,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });
        Self { pipeline, layout }
    }
}

/// The most points one buffer (storage binding or vertex buffer) can hold on `device`.
fn max_points(device: &wgpu::Device, source: PointSource) -> usize {
    let limits = device.limits();
    let bytes = match source {
        PointSource::Storage => limits.max_storage_buffer_binding_size,
        PointSource::Instanced => limits.max_buffer_size,
    };
    usize::try_from((bytes / 12).min(u64::from(u32::MAX / 3))).unwrap_or(usize::MAX)
}

/// Pipelines plus the GPU state of every scene and view drawn so far.
pub(crate) struct SceneRenderer {
    sample_count: u32,
    uniform_layout: wgpu::BindGroupLayout,
    source: PointSource,
    /// The storage buffers of the points (`PointSource::Storage` only).
    points_layout: Option<wgpu::BindGroupLayout>,
    points: wgpu::RenderPipeline,
    lines: wgpu::RenderPipeline,
    /// Box lines over the points: first their dark outline, then their colour (no depth test).
    overlay_outline: wgpu::RenderPipeline,
    overlay: wgpu::RenderPipeline,
    blit: Option<BlitPipeline>,
    scenes: HashMap<u64, SceneBuffers>,
    targets: HashMap<u64, RenderTarget>,
    max_texture_side: u32,
    max_points: usize,
    /// Counts `render` calls; scenes and views unused for `EVICT_AFTER` calls are dropped.
    frame: u64,
}

/// Scenes and views not drawn for this many `render` calls give their GPU memory back (they are
/// re-uploaded in full if they come back).
const EVICT_AFTER: u64 = 600;

impl SceneRenderer {
    /// `sample_count`: MSAA of the view targets (1 or 4); `egui`: set up the blit into egui's
    /// pass (`None` for offscreen use).
    pub(crate) fn new(
        device: &wgpu::Device,
        sample_count: u32,
        egui: Option<EguiPass>,
        source: PointSource,
    ) -> Self {
        let sample_count = if sample_count >= 4 { 4 } else { 1 };
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("mlod viewport scene"),
            source: wgpu::ShaderSource::Wgsl(source.shader().into()),
        });
        let uniform_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("mlod viewport uniforms"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: wgpu::BufferSize::new(std::mem::size_of::<FrameUniforms>() as u64),
                },
                count: None,
            }],
        });
        let storage = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::VERTEX,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: true },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let points_layout = (source == PointSource::Storage).then(|| {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("mlod viewport points"),
                entries: &[storage(0), storage(1)],
            })
        });
        let lines_pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("mlod viewport lines"),
            bind_group_layouts: &[Some(&uniform_layout)],
            immediate_size: 0,
        });
        let points_pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("mlod viewport points"),
            bind_group_layouts: &[Some(&uniform_layout), points_layout.as_ref()],
            immediate_size: 0,
        });
        let pipeline = |label: &str,
                        layout: &wgpu::PipelineLayout,
                        vs: &str,
                        fs: &str,
                        buffers: &[Option<wgpu::VertexBufferLayout>],
                        on_top: bool| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(label),
                layout: Some(layout),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some(vs),
                    compilation_options: Default::default(),
                    buffers,
                },
                primitive: wgpu::PrimitiveState::default(),
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: DEPTH_FORMAT,
                    depth_write_enabled: Some(!on_top),
                    depth_compare: Some(if on_top {
                        wgpu::CompareFunction::Always
                    } else {
                        wgpu::CompareFunction::GreaterEqual
                    }),
                    stencil: wgpu::StencilState::default(),
                    bias: wgpu::DepthBiasState::default(),
                }),
                multisample: wgpu::MultisampleState {
                    count: sample_count,
                    mask: !0,
                    alpha_to_coverage_enabled: sample_count > 1,
                },
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some(fs),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format: COLOR_FORMAT,
                        blend: None,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let instanced = [
            Some(wgpu::VertexBufferLayout {
                array_stride: 12,
                step_mode: wgpu::VertexStepMode::Instance,
                attributes: &wgpu::vertex_attr_array![0 => Float32x3],
            }),
            Some(wgpu::VertexBufferLayout {
                array_stride: 4,
                step_mode: wgpu::VertexStepMode::Instance,
                attributes: &wgpu::vertex_attr_array![1 => Unorm8x4],
            }),
        ];
        let points = pipeline(
            "mlod viewport points",
            &points_pipeline_layout,
            "vs_point",
            "fs_point",
            match source {
                PointSource::Storage => &[],
                PointSource::Instanced => &instanced,
            },
            false,
        );
        // A segment is two consecutive `LineVertex` (2 × 20 bytes).
        let segment = [Some(wgpu::VertexBufferLayout {
            array_stride: 40,
            step_mode: wgpu::VertexStepMode::Instance,
            attributes: &wgpu::vertex_attr_array![
                0 => Float32x3, 1 => Unorm8x4, 2 => Float32,
                3 => Float32x3, 4 => Unorm8x4, 5 => Float32
            ],
        })];
        let layout = &lines_pipeline_layout;
        let lines = pipeline(
            "mlod viewport lines",
            layout,
            "vs_line",
            "fs_line",
            &segment,
            false,
        );
        let overlay_outline = pipeline(
            "mlod viewport box outlines",
            layout,
            "vs_line_outline",
            "fs_line",
            &segment,
            true,
        );
        let overlay = pipeline(
            "mlod viewport boxes",
            layout,
            "vs_line",
            "fs_line",
            &segment,
            true,
        );
        Self {
            sample_count,
            uniform_layout,
            source,
            points_layout,
            points,
            lines,
            overlay_outline,
            overlay,
            blit: egui.map(|egui| BlitPipeline::new(device, egui)),
            scenes: HashMap::new(),
            targets: HashMap::new(),
            max_texture_side: device.limits().max_texture_dimension_2d,
            max_points: max_points(device, source),
            frame: 0,
        }
    }

    pub(crate) fn max_texture_side(&self) -> u32 {
        self.max_texture_side
    }

    /// Uploads what changed, (re)creates the target, and records the view's render pass.
    /// Scenes and render targets held, and the bytes of the scenes' GPU buffers (what a soak
    /// watches for growth).
    pub(crate) fn usage(&self) -> GpuUsage {
        let bytes = |b: &GrowBuffer| b.buffer.as_ref().map_or(0, |b| b.size());
        GpuUsage {
            scenes: self.scenes.len(),
            targets: self.targets.len(),
            buffer_bytes: self
                .scenes
                .values()
                .map(|s| bytes(&s.positions) + bytes(&s.colors) + bytes(&s.lines))
                .sum(),
        }
    }

    /// Returns `None` (draws nothing) for an empty target size.
    pub(crate) fn render(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        target_id: u64,
        scene: &SceneHandle,
        params: &FrameParams,
    ) -> Option<wgpu::CommandBuffer> {
        let max = self.max_texture_side;
        let size = params.size.map(|v| v.min(max));
        if size.contains(&0) {
            return None;
        }
        let source = self.source;
        let buffers = self
            .scenes
            .entry(scene.id())
            .or_insert_with(|| SceneBuffers::new(source.buffer_usage()));
        buffers.sync(device, queue, self.points_layout.as_ref(), self.max_points, scene);

        self.frame += 1;
        let frame = self.frame;
        buffers.last_used = frame;
        let stale = self.targets.get(&target_id).is_none_or(|t| t.size != size);
        if stale {
            let target = RenderTarget::new(device, self, size);
            self.targets.insert(target_id, target);
        }
        if let Some(target) = self.targets.get_mut(&target_id) {
            target.last_used = frame;
        }
        if frame.is_multiple_of(64) {
            self.scenes.retain(|_, s| frame - s.last_used < EVICT_AFTER);
            self.targets.retain(|_, t| frame - t.last_used < EVICT_AFTER);
        }
        let target = self.targets.get(&target_id)?;
        let buffers = self.scenes.get(&scene.id())?;
        let params = FrameParams {
            size,
            ..params.clone()
        };
        let uniforms = params.uniforms(self.sample_count > 1);
        queue.write_buffer(&target.uniforms, 0, bytemuck::bytes_of(&uniforms));

        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("mlod viewport"),
        });
        {
            let resolved_view = target
                .resolved
                .create_view(&wgpu::TextureViewDescriptor::default());
            let (view, resolve_target, store) = match &target.msaa_view {
                Some(msaa) => (msaa, Some(&resolved_view), wgpu::StoreOp::Discard),
                None => (&resolved_view, None, wgpu::StoreOp::Store),
            };
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("mlod viewport scene"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view,
                    depth_slice: None,
                    resolve_target,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(params.clear_color()),
                        store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &target.depth_view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(0.0),
                        store: wgpu::StoreOp::Discard,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_bind_group(0, &target.uniform_bind_group, &[]);
            let lines = buffers.lines.slice().filter(|_| buffers.segments > 0);
            if let (Some(lines), true) = (lines, buffers.overlay_from > 0) {
                pass.set_pipeline(&self.lines);
                pass.set_vertex_buffer(0, lines);
                pass.draw(0..6, 0..buffers.overlay_from);
            }
            if buffers.points > 0 {
                match (self.source, &buffers.points_bind_group) {
                    (PointSource::Storage, Some(points)) => {
                        pass.set_pipeline(&self.points);
                        pass.set_bind_group(1, points, &[]);
                        pass.draw(0..buffers.points.saturating_mul(3), 0..1);
                    }
                    (PointSource::Instanced, _) => {
                        if let (Some(positions), Some(colors)) =
                            (buffers.positions.slice(), buffers.colors.slice())
                        {
                            pass.set_pipeline(&self.points);
                            pass.set_vertex_buffer(0, positions);
                            pass.set_vertex_buffer(1, colors);
                            pass.draw(0..3, 0..buffers.points);
                        }
                    }
                    (PointSource::Storage, None) => {}
                }
            }
            // Boxes last, over everything: all outlines first so that no outline cuts a colour.
            if let (Some(lines), true) = (lines, buffers.overlay_from < buffers.segments) {
                pass.set_vertex_buffer(0, lines);
                for pipeline in [&self.overlay_outline, &self.overlay] {
                    pass.set_pipeline(pipeline);
                    pass.draw(0..6, buffers.overlay_from..buffers.segments);
                }
            }
        }
        Some(encoder.finish())
    }

    pub(crate) fn target(&self, target_id: u64) -> Option<&RenderTarget> {
        self.targets.get(&target_id)
    }

    /// Draws a view's last rendered frame into egui's pass (set up by `egui` in [`Self::new`]).
    fn blit(&self, target_id: u64, pass: &mut wgpu::RenderPass<'static>) {
        let (Some(blit), Some(target)) = (&self.blit, self.targets.get(&target_id)) else {
            return;
        };
        let Some(bind_group) = &target.blit_bind_group else {
            return;
        };
        pass.set_pipeline(&blit.pipeline);
        pass.set_bind_group(0, bind_group, &[]);
        pass.draw(0..3, 0..1);
    }
}

/// The renderer stored in egui's `callback_resources` by [`crate::render::install`].
pub(crate) struct ViewportResources(pub(crate) SceneRenderer);

/// One view's paint callback: renders in `prepare`, blits in `paint`.
pub(crate) struct ViewportCallback {
    pub target_id: u64,
    pub scene: SceneHandle,
    pub params: FrameParams,
}

impl egui_wgpu::CallbackTrait for ViewportCallback {
    fn prepare(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        _screen_descriptor: &egui_wgpu::ScreenDescriptor,
        _egui_encoder: &mut wgpu::CommandEncoder,
        resources: &mut egui_wgpu::CallbackResources,
    ) -> Vec<wgpu::CommandBuffer> {
        let Some(ViewportResources(renderer)) = resources.get_mut::<ViewportResources>() else {
            return Vec::new();
        };
        renderer
            .render(device, queue, self.target_id, &self.scene, &self.params)
            .into_iter()
            .collect()
    }

    fn paint(
        &self,
        _info: egui::PaintCallbackInfo,
        render_pass: &mut wgpu::RenderPass<'static>,
        resources: &egui_wgpu::CallbackResources,
    ) {
        if let Some(ViewportResources(renderer)) = resources.get::<ViewportResources>() {
            renderer.blit(self.target_id, render_pass);
        }
    }
}
