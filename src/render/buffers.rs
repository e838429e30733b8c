//! The GPU copies of a [`SceneHandle`]: one growable buffer per kind of data (positions, colours,
//! lines), rewritten in place only when the scene's generation for that kind changed.

use egui_wgpu::wgpu;

use crate::render::SceneHandle;

/// A GPU buffer that grows on demand (to the next power of two) and is rewritten in place.
pub(crate) struct GrowBuffer {
    label: &'static str,
    usage: wgpu::BufferUsages,
    pub(crate) buffer: Option<wgpu::Buffer>,
    len: u64,
}

impl GrowBuffer {
    pub(crate) fn new(label: &'static str, usage: wgpu::BufferUsages) -> Self {
        Self {
            label,
            usage: usage | wgpu::BufferUsages::COPY_DST,
            buffer: None,
            len: 0,
        }
    }

    /// One `queue.write_buffer`; a new buffer only when the old one is too small. Returns
    /// whether the buffer was replaced (bind groups that name it must be rebuilt).
    pub(crate) fn upload(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, bytes: &[u8]) -> bool {
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
    pub(crate) fn slice(&self) -> Option<wgpu::BufferSlice<'_>> {
        match &self.buffer {
            Some(buffer) if self.len > 0 => Some(buffer.slice(..self.len)),
            _ => None,
        }
    }
}

/// GPU copies of one [`SceneHandle`].
pub(crate) struct SceneBuffers {
    pub(crate) positions: GrowBuffer,
    pub(crate) colors: GrowBuffer,
    pub(crate) lines: GrowBuffer,
    /// Binds `positions` and `colors` for the point shader (rebuilt when either is replaced).
    pub(crate) points_bind_group: Option<wgpu::BindGroup>,
    uploaded: [u64; 3],
    /// The renderer's frame counter when this scene was last drawn.
    pub(crate) last_used: u64,
    pub(crate) points: u32,
    pub(crate) segments: u32,
    /// Segments from this index on are drawn over the points (boxes), with an outline.
    pub(crate) overlay_from: u32,
}

impl SceneBuffers {
    /// `point_usage`: how the point buffers are bound (storage or vertex buffers).
    pub(crate) fn new(point_usage: wgpu::BufferUsages) -> Self {
        Self {
            positions: GrowBuffer::new("mlod viewport positions", point_usage),
            colors: GrowBuffer::new("mlod viewport colours", point_usage),
            lines: GrowBuffer::new("mlod viewport lines", wgpu::BufferUsages::VERTEX),
            points_bind_group: None,
            uploaded: [0; 3],
            last_used: 0,
            points: 0,
            segments: 0,
            overlay_from: 0,
        }
    }

    /// Uploads whatever changed since the last call (by generation).
    pub(crate) fn sync(
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
        self.overlay_from = u32::try_from(scene.overlay_from() / 2)
            .unwrap_or(u32::MAX)
            .min(self.segments);
    }
}
