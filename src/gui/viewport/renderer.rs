//! GPU side of the viewport: pipelines, per-scene buffers, per-view render targets, and the egui
//! paint callback that ties them together.
//!
//! How it works: a frame of one view is one render pass into the view's own colour (optionally
//! multisampled, resolved) + depth target: lines first (one instanced draw, a segment per
//! instance), then points (one draw of three vertices per point; the vertex shader reads the
//! point from storage buffers at `vertex_index / 3` and places corner `vertex_index % 3` of a
//! triangle around its disc). Devices without vertex-stage storage buffers (egui's GL backend
//! runs with WebGL2 limits) get the same points as per-instance attributes, one instance per
//! point, from the same slices. In the window that pass runs in [`egui_wgpu::CallbackTrait::prepare`] on its own
//! command encoder, and [`egui_wgpu::CallbackTrait::paint`] only blits the resolved texture into
//! egui's pass (which has no depth attachment). Offscreen rendering records the same pass and
//! copies the texture back to the CPU instead of blitting.

use std::collections::HashMap;

use egui_wgpu::wgpu;

use super::{Camera, SceneHandle, ViewSettings};

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

    fn buffer_usage(self) -> wgpu::BufferUsages {
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
    _pad: [f32; 2],
}
const _: () = assert!(std::mem::size_of::<FrameUniforms>() == 96);

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
            _pad: [0.0; 2],
        }
    }

    fn clear_color(&self) -> wgpu::Color {
        let [r, g, b] = self.settings.background.map(|c| f64::from(c) / 255.0);
        wgpu::Color { r, g, b, a: 1.0 }
    }
}

/// What the viewport holds on the GPU ([`super::gpu_usage`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GpuUsage {
    /// Scenes with buffers (evicted after a while unused).
    pub scenes: usize,
    /// Offscreen render targets (one per viewport, evicted likewise).
    pub targets: usize,
    /// Bytes of the scenes' point, colour and line buffers.
    pub buffer_bytes: u64,
}

/// A GPU buffer that grows on demand (to the next power of two) and is rewritten in place.
struct GrowBuffer {
    label: &'static str,
    usage: wgpu::BufferUsages,
    buffer: Option<wgpu::Buffer>,
    len: u64,
}

impl GrowBuffer {
    fn new(label: &'static str, usage: wgpu::BufferUsages) -> Self {
        Self {
            label,
            usage: usage | wgpu::BufferUsages::COPY_DST,
            buffer: None,
            len: 0,
        }
    }

    /// One `queue.write_buffer`; a new buffer only when the old one is too small. Returns
    /// whether the buffer was replaced (bind groups that name it must be rebuilt).
    fn upload(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, bytes: &[u8]) -> bool {
        let len = bytes.len() as u64;
        self.len = len;
        if len == 0 {
            return false;
        }
        let fits = self.buffer.as_ref().is_some_and(|b| b.size() >= len);
        if !fits {
            self.buffer = Some(device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(self.label),
                size: len.next_power_of_two().max(4096),
                usage: self.usage,
                mapped_at_creation: false,
            }));
        }
        if let Some(buffer) = &self.buffer {
            queue.write_buffer(buffer, 0, bytes);
        }
        !fits
    }

    /// The written part, `None` when empty (never slices a zero-sized buffer).
    fn slice(&self) -> Option<wgpu::BufferSlice<'_>> {
        match &self.buffer {
            Some(buffer) if self.len > 0 => Some(buffer.slice(..self.len)),
            _ => None,
        }
    }
}

/// GPU copies of one [`SceneHandle`].
struct SceneBuffers {
    positions: GrowBuffer,
    colors: GrowBuffer,
    lines: GrowBuffer,
    /// Binds `positions` and `colors` for the point shader (rebuilt when either is replaced).
    points_bind_group: Option<wgpu::BindGroup>,
    uploaded: [u64; 3],
    /// The renderer's frame counter when this scene was last drawn.
    last_used: u64,
    points: u32,
    segments: u32,
}

impl SceneBuffers {
    fn new(source: PointSource) -> Self {
        Self {
            positions: GrowBuffer::new("mlod viewport positions", source.buffer_usage()),
            colors: GrowBuffer::new("mlod viewport colours", source.buffer_usage()),
            lines: GrowBuffer::new("mlod viewport lines", wgpu::BufferUsages::VERTEX),
            points_bind_group: None,
            uploaded: [0; 3],
            last_used: 0,
            points: 0,
            segments: 0,
        }
    }

    /// Uploads whatever changed since the last call (by generation).
    fn sync(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        points_layout: Option<&wgpu::BindGroupLayout>,
        max_points: usize,
        scene: &SceneHandle,
    ) {
        let generations = scene.generations();
        // Points beyond the buffer limit (11M with default limits) are not drawn.
        let count = scene.points().len().min(scene.colors().len()).min(max_points);
        let (positions, colors) = (
            scene.points().get(..count).unwrap_or_default(),
            scene.colors().get(..count).unwrap_or_default(),
        );
        let mut replaced = false;
        if generations[0] != self.uploaded[0] {
            replaced |= self
                .positions
                .upload(device, queue, bytemuck::cast_slice(positions));
        }
        if generations[1] != self.uploaded[1] {
            replaced |= self.colors.upload(device, queue, bytemuck::cast_slice(colors));
        }
        if replaced || self.points_bind_group.is_none() {
            self.points_bind_group = match (points_layout, &self.positions.buffer, &self.colors.buffer) {
                (Some(points_layout), Some(positions), Some(colors)) => {
                    Some(device.create_bind_group(&wgpu::BindGroupDescriptor {
                        label: Some("mlod viewport points"),
                        layout: points_layout,
                        entries: &[
                            wgpu::BindGroupEntry {
                                binding: 0,
                                resource: positions.as_entire_binding(),
                            },
                            wgpu::BindGroupEntry {
                                binding: 1,
                                resource: colors.as_entire_binding(),
                            },
                        ],
                    }))
                }
                _ => None,
            };
        }
        if generations[2] != self.uploaded[2] {
            self.lines
                .upload(device, queue, bytemuck::cast_slice(scene.lines()));
        }
        self.uploaded = generations;
        self.points = u32::try_from(count).unwrap_or(u32::MAX / 3);
        self.segments = u32::try_from(scene.lines().len() / 2).unwrap_or(u32::MAX);
    }
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
                        buffers: &[Option<wgpu::VertexBufferLayout>]| {
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
                    depth_write_enabled: Some(true),
                    depth_compare: Some(wgpu::CompareFunction::GreaterEqual),
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
        );
        // A segment is two consecutive `LineVertex` (2 × 16 bytes).
        let lines = pipeline(
            "mlod viewport lines",
            &lines_pipeline_layout,
            "vs_line",
            "fs_line",
            &[Some(wgpu::VertexBufferLayout {
                array_stride: 32,
                step_mode: wgpu::VertexStepMode::Instance,
                attributes: &wgpu::vertex_attr_array![
                    0 => Float32x3, 1 => Unorm8x4, 2 => Float32x3, 3 => Unorm8x4
                ],
            })],
        );
        Self {
            sample_count,
            uniform_layout,
            source,
            points_layout,
            points,
            lines,
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
            .or_insert_with(|| SceneBuffers::new(source));
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
        if frame % 64 == 0 {
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
            if let (Some(lines), true) = (buffers.lines.slice(), buffers.segments > 0) {
                pass.set_pipeline(&self.lines);
                pass.set_vertex_buffer(0, lines);
                pass.draw(0..6, 0..buffers.segments);
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

/// The renderer stored in egui's `callback_resources` by [`super::install`].
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
