//! What the viewport draws: points with colours and line segments, held in a cheap-to-clone
//! [`SceneHandle`] that the app rebuilds whenever its data changes.
//!
//! Each kind of data (positions, colours, lines) carries its own generation number; the renderer
//! keeps one GPU buffer per kind and re-uploads only the kinds whose generation changed since the
//! last frame (one `queue.write_buffer` each). Recolouring 150k points therefore uploads 600 kB and
//! nothing else.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use crate::render::ViewportError;

/// One end of a line segment. Lines come in pairs: vertices `2k` and `2k + 1` form segment `k`.
///
/// Keep in sync with the instance attributes of `vs_line` in `scene.wgsl` (a segment is read as
/// two consecutive `LineVertex`, 40 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct LineVertex {
    /// Base frame, metres.
    pub pos: [f32; 3],
    /// sRGB colour with alpha (alpha is ignored: lines are opaque).
    pub color: [u8; 4],
    /// Width as a multiple of the view's line width (a segment takes its first vertex's).
    pub width: f32,
}
const _: () = assert!(std::mem::size_of::<LineVertex>() == 20);

impl LineVertex {
    /// A vertex of the view's line width.
    pub const fn new(pos: [f32; 3], color: [u8; 4]) -> Self {
        Self {
            pos,
            color,
            width: 1.0,
        }
    }

    /// The same vertex, `width` times the view's line width.
    pub const fn with_width(self, width: f32) -> Self {
        Self { width, ..self }
    }
}

static NEXT_SCENE_ID: AtomicU64 = AtomicU64::new(1);

fn next_generation() -> u64 {
    // One counter for ids and generations: a new handle never reuses an old generation.
    NEXT_SCENE_ID.fetch_add(1, Ordering::Relaxed)
}

/// The data the viewport draws, shared with the paint callback by reference counting.
///
/// Cloning is cheap (three `Arc`s). Setters replace the data and bump its generation, so the
/// renderer uploads exactly what changed. Keep one handle per viewport (each handle owns GPU
/// buffers for as long as the renderer lives).
#[derive(Clone, Debug)]
pub struct SceneHandle {
    id: u64,
    positions: Arc<[[f32; 3]]>,
    colors: Arc<[[u8; 4]]>,
    lines: Arc<[LineVertex]>,
    /// Line vertices from this index on are boxes: drawn over the points with a dark outline.
    overlay_from: usize,
    positions_generation: u64,
    colors_generation: u64,
    lines_generation: u64,
    radius: f32,
}

impl Default for SceneHandle {
    fn default() -> Self {
        Self::new()
    }
}

impl SceneHandle {
    /// An empty scene (draws only the background).
    pub fn new() -> Self {
        let generation = next_generation();
        Self {
            id: next_generation(),
            positions: Arc::from(Vec::new()),
            colors: Arc::from(Vec::new()),
            lines: Arc::from(Vec::new()),
            overlay_from: 0,
            positions_generation: generation,
            colors_generation: generation,
            lines_generation: generation,
            radius: 0.0,
        }
    }

    /// Replaces the points (base frame, metres) and their sRGB colours (same length).
    pub fn set_points(
        &mut self,
        positions: impl Into<Arc<[[f32; 3]]>>,
        colors: impl Into<Arc<[[u8; 4]]>>,
    ) -> Result<(), ViewportError> {
        let (positions, colors) = (positions.into(), colors.into());
        if positions.len() != colors.len() {
            return Err(ViewportError::LengthMismatch {
                points: positions.len(),
                colors: colors.len(),
            });
        }
        self.positions = positions;
        self.colors = colors;
        self.positions_generation = next_generation();
        self.colors_generation = next_generation();
        self.update_radius();
        Ok(())
    }

    /// Replaces only the colours (e.g. a colour-mode change); the length must match the points.
    pub fn set_colors(&mut self, colors: impl Into<Arc<[[u8; 4]]>>) -> Result<(), ViewportError> {
        let colors = colors.into();
        if colors.len() != self.positions.len() {
            return Err(ViewportError::LengthMismatch {
                points: self.positions.len(),
                colors: colors.len(),
            });
        }
        self.colors = colors;
        self.colors_generation = next_generation();
        Ok(())
    }

    /// Replaces the line segments (pairs of vertices; an odd last vertex is ignored), all drawn
    /// in depth with the points (a grid, axes).
    pub fn set_lines(&mut self, lines: impl Into<Arc<[LineVertex]>>) {
        let lines = lines.into();
        let n = lines.len();
        self.set_lines_with_overlay(lines, n);
    }

    /// Replaces the line segments: those before vertex `overlay_from` in depth with the points
    /// (the grid), those from it on (boxes) over the points, each on a dark outline.
    pub fn set_lines_with_overlay(&mut self, lines: impl Into<Arc<[LineVertex]>>, overlay_from: usize) {
        self.lines = lines.into();
        // A whole number of segments before the overlay.
        self.overlay_from = overlay_from.min(self.lines.len()) & !1;
        self.lines_generation = next_generation();
        self.update_radius();
    }

    /// The first line vertex drawn over the points.
    pub fn overlay_from(&self) -> usize {
        self.overlay_from
    }

    pub fn points(&self) -> &[[f32; 3]] {
        &self.positions
    }

    pub fn colors(&self) -> &[[u8; 4]] {
        &self.colors
    }

    pub fn lines(&self) -> &[LineVertex] {
        &self.lines
    }

    /// Radius (m) of the smallest origin-centred ball holding every finite point and line vertex;
    /// bounds the camera's zoom.
    pub fn radius(&self) -> f32 {
        self.radius
    }

    pub(crate) fn id(&self) -> u64 {
        self.id
    }

    pub(crate) fn generations(&self) -> [u64; 3] {
        [
            self.positions_generation,
            self.colors_generation,
            self.lines_generation,
        ]
    }

    fn update_radius(&mut self) {
        let points = self.positions.iter().copied();
        let lines = self.lines.iter().map(|v| v.pos);
        self.radius = points
            .chain(lines)
            .map(|[x, y, z]| (x * x + y * y + z * z).sqrt())
            .filter(|r| r.is_finite())
            .fold(0.0, f32::max);
    }
}

/// Width of the grid's lines, as a multiple of the view's line width (boxes are 1).
pub const GRID_WIDTH: f32 = 0.45;

/// A ground grid on the plane `z = ground_z_m`: rings every `ring_step_m` metres out to
/// `radius_m` (every fifth ring brighter), faint radial spokes every 30°, and the base frame's
/// axes (+x and +y in neutral greys: red and green are box colours), thinner than box lines.
pub fn grid_lines(radius_m: f32, ring_step_m: f32, ground_z_m: f32) -> Vec<LineVertex> {
    let mut out = grid_segments(radius_m, ring_step_m, ground_z_m);
    for v in &mut out {
        v.width = GRID_WIDTH;
    }
    out
}

fn grid_segments(radius_m: f32, ring_step_m: f32, ground_z_m: f32) -> Vec<LineVertex> {
    const RING: [u8; 4] = [58, 64, 76, 255];
    const RING_MAJOR: [u8; 4] = [86, 94, 110, 255];
    const SPOKE: [u8; 4] = [46, 51, 61, 255];
    const X_AXIS: [u8; 4] = [150, 150, 160, 255];
    const Y_AXIS: [u8; 4] = [110, 110, 120, 255];
    let mut out = Vec::new();
    if !(radius_m.is_finite() && ring_step_m.is_finite() && radius_m > 0.0 && ring_step_m > 0.0) {
        return out;
    }
    let z = ground_z_m;
    let rings = ((radius_m / ring_step_m).floor() as usize).min(1000);
    for k in 1..=rings {
        let r = k as f32 * ring_step_m;
        let color = if k % 5 == 0 { RING_MAJOR } else { RING };
        // Enough segments that a ring looks round up close: about one per metre, 64..=512.
        let segments = ((std::f32::consts::TAU * r) as usize).clamp(64, 512);
        for s in 0..segments {
            let a0 = std::f32::consts::TAU * s as f32 / segments as f32;
            let a1 = std::f32::consts::TAU * (s + 1) as f32 / segments as f32;
            out.push(LineVertex::new([r * a0.cos(), r * a0.sin(), z], color));
            out.push(LineVertex::new([r * a1.cos(), r * a1.sin(), z], color));
        }
    }
    for s in 0..12 {
        if s % 3 == 0 {
            continue; // the axes are drawn below
        }
        let a = std::f32::consts::TAU * s as f32 / 12.0;
        let inner = ring_step_m.min(radius_m);
        out.push(LineVertex::new([inner * a.cos(), inner * a.sin(), z], SPOKE));
        out.push(LineVertex::new(
            [radius_m * a.cos(), radius_m * a.sin(), z],
            SPOKE,
        ));
    }
    out.push(LineVertex::new([-radius_m, 0.0, z], RING));
    out.push(LineVertex::new([0.0, 0.0, z], RING));
    out.push(LineVertex::new([0.0, 0.0, z], X_AXIS));
    out.push(LineVertex::new([radius_m, 0.0, z], X_AXIS));
    out.push(LineVertex::new([0.0, -radius_m, z], RING));
    out.push(LineVertex::new([0.0, 0.0, z], RING));
    out.push(LineVertex::new([0.0, 0.0, z], Y_AXIS));
    out.push(LineVertex::new([0.0, radius_m, z], Y_AXIS));
    out
}

/// The ego vehicle on the ground plane `z = ground_z_m`: its outline (a 4.7 × 1.9 m rectangle
/// centred on the base frame's origin, turned by `heading`, the yaw of the car's forward
/// direction in the base frame) and an arrow `arrow_m` long from its front along its forward
/// direction. Returns the lines and the arrow's tip (where a "forward" label goes).
pub fn ego_lines(heading: f32, ground_z_m: f32, arrow_m: f32) -> (Vec<LineVertex>, [f32; 3]) {
    const EGO: [u8; 4] = [215, 215, 225, 255];
    let (s, c) = if heading.is_finite() {
        heading.sin_cos()
    } else {
        (0.0, 1.0)
    };
    let z = ground_z_m;
    let at = |fwd: f32, left: f32| [fwd * c - left * s, fwd * s + left * c, z];
    let (half_l, half_w) = (2.35, 0.95);
    let outline = [
        at(half_l, half_w),
        at(-half_l, half_w),
        at(-half_l, -half_w),
        at(half_l, -half_w),
    ];
    let mut out = Vec::new();
    let mut seg = |a: [f32; 3], b: [f32; 3]| {
        out.push(LineVertex::new(a, EGO).with_width(0.8));
        out.push(LineVertex::new(b, EGO).with_width(0.8));
    };
    for k in 0..4 {
        seg(outline[k], outline[(k + 1) % 4]);
    }
    // The windscreen, so that the outline alone says which end is the front.
    seg(at(0.9, half_w), at(0.9, -half_w));
    let tip_fwd = half_l + arrow_m.max(0.5);
    let tip = at(tip_fwd, 0.0);
    seg(at(half_l, 0.0), tip);
    seg(tip, at(tip_fwd - 1.2, 0.7));
    seg(tip, at(tip_fwd - 1.2, -0.7));
    (out, tip)
}

/// The 12 edges of a box as line pairs, plus (when `heading`) a cross on the front face and a
/// line from the top-face centre to the middle of the top front edge.
///
/// Corner order as `geometry::Box3d::corners`: bottom face counter-clockwise from front-left
/// (front-left, rear-left, rear-right, front-right), then the top face in the same order.
pub fn box_lines(corners: [[f64; 3]; 8], color: [u8; 4], heading: bool) -> Vec<LineVertex> {
    let c = corners.map(|[x, y, z]| [x as f32, y as f32, z as f32]);
    let mut out = Vec::with_capacity(if heading { 30 } else { 24 });
    let mut seg = |a: [f32; 3], b: [f32; 3]| {
        out.push(LineVertex::new(a, color));
        out.push(LineVertex::new(b, color));
    };
    for k in 0..4 {
        let next = (k + 1) % 4;
        seg(c[k], c[next]); // bottom
        seg(c[k + 4], c[next + 4]); // top
        seg(c[k], c[k + 4]); // vertical
    }
    if heading {
        let mid = |a: [f32; 3], b: [f32; 3]| [(a[0] + b[0]) * 0.5, (a[1] + b[1]) * 0.5, (a[2] + b[2]) * 0.5];
        // Front face: corners 0, 3 (bottom) and 4, 7 (top).
        seg(c[0], c[7]);
        seg(c[3], c[4]);
        let top_centre = mid(mid(c[4], c[6]), mid(c[5], c[7]));
        seg(top_centre, mid(c[4], c[7]));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mismatched_lengths_are_an_error_and_keep_the_old_data() {
        let mut scene = SceneHandle::new();
        scene
            .set_points(vec![[1.0, 0.0, 0.0]], vec![[255, 0, 0, 255]])
            .unwrap();
        let before = scene.generations();
        assert!(scene.set_points(vec![[0.0; 3]; 2], vec![[0; 4]]).is_err());
        assert!(scene.set_colors(vec![[0; 4]; 3]).is_err());
        assert_eq!(scene.generations(), before);
        assert_eq!(scene.points().len(), 1);
    }

    #[test]
    fn setters_bump_only_their_generation() {
        let mut scene = SceneHandle::new();
        scene
            .set_points(vec![[3.0, 4.0, 0.0]], vec![[1, 2, 3, 255]])
            .unwrap();
        assert_eq!(scene.radius(), 5.0);
        let [p, c, l] = scene.generations();
        scene.set_colors(vec![[9, 9, 9, 255]]).unwrap();
        let [p2, c2, l2] = scene.generations();
        assert_eq!((p, l), (p2, l2));
        assert_ne!(c, c2);
    }

    #[test]
    fn grid_and_box_lines_come_in_pairs() {
        let grid = grid_lines(50.0, 10.0, -1.8);
        assert_eq!(grid.len() % 2, 0);
        assert!(grid.iter().all(|v| v.pos[2] == -1.8));
        assert!(grid_lines(0.0, 10.0, 0.0).is_empty());
        let corners = [[0.0; 3]; 8];
        assert_eq!(box_lines(corners, [0, 255, 0, 255], false).len(), 24);
        assert_eq!(box_lines(corners, [0, 255, 0, 255], true).len(), 30);
        let (ego, tip) = ego_lines(std::f32::consts::PI, -1.8, 6.0);
        assert_eq!(ego.len() % 2, 0);
        assert!(tip[0] < -8.0 && tip[1].abs() < 1e-4, "forward along -x: {tip:?}");
    }

    #[test]
    fn the_overlay_starts_on_a_segment_boundary() {
        let mut scene = SceneHandle::new();
        let v = LineVertex::new([0.0; 3], [1, 1, 1, 255]);
        scene.set_lines_with_overlay(vec![v; 6], 3);
        assert_eq!(scene.overlay_from(), 2);
        scene.set_lines(vec![v; 4]);
        assert_eq!(scene.overlay_from(), 4, "plain lines are all drawn in depth");
    }
}
