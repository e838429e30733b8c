// Points and lines of the 3D viewport, rendered into the viewport's own colour + depth target.
// Depth is reversed (1 = near plane, 0 = infinitely far): compare GreaterEqual, clear to 0.

// Keep in sync with `FrameUniforms` in renderer.rs.
struct FrameUniforms {
    view_proj: mat4x4<f32>,
    viewport_px: vec2<f32>,
    point_radius_px: f32,
    line_half_width_px: f32,
    // Clip-space w of the near plane; segments are clipped there before expansion.
    near_w: f32,
    // 1 when the target is multisampled and coverage goes to alpha-to-coverage.
    alpha_to_coverage: u32,
    // The dark rim around box lines, pixels on each side.
    outline_px: f32,
    _pad: f32,
};

@group(0) @binding(0) var<uniform> u: FrameUniforms;

// Corner k of a quad drawn as two triangles, in [-1, 1]².
fn quad_corner(k: u32) -> vec2<f32> {
    var corners = array<vec2<f32>, 6>(
        vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, -1.0), vec2<f32>(1.0, 1.0),
        vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, 1.0), vec2<f32>(-1.0, 1.0),
    );
    return corners[k % 6u];
}

// Corner k of an equilateral triangle whose inscribed circle is the unit circle.
fn triangle_corner(k: u32) -> vec2<f32> {
    var corners = array<vec2<f32>, 3>(
        vec2<f32>(0.0, 2.0), vec2<f32>(-1.7320508, -1.0), vec2<f32>(1.7320508, -1.0),
    );
    return corners[k % 3u];
}

// Keeps or drops a fragment by its coverage (0..1), the same rule for points and lines.
fn keep(coverage: f32) -> bool {
    if u.alpha_to_coverage != 0u {
        return coverage > 0.0;
    }
    return coverage >= 0.5;
}

const CULLED: vec4<f32> = vec4<f32>(2.0, 2.0, 2.0, 1.0);

// ---------------------------------------------------------------------------------------------
// Points: three vertices per point, expanded into a screen-aligned triangle circumscribing the
// point's disc (one triangle, not a quad: software rasterisers pay per triangle). Where the point
// comes from is in points_storage.wgsl (storage buffers, the default) or points_instanced.wgsl
// (per-instance attributes, for devices without vertex-stage storage buffers, e.g. GL); one of
// them is appended to this file.

struct PointOut {
    @builtin(position) position: vec4<f32>,
    @location(0) color: vec4<f32>,
    // Offset from the point's centre in pixels.
    @location(1) offset_px: vec2<f32>,
};

fn expand_point(corner_index: u32, position: vec3<f32>, color: vec4<f32>) -> PointOut {
    var out: PointOut;
    let clip = u.view_proj * vec4<f32>(position, 1.0);
    if !(clip.w > 0.0) {
        out.position = CULLED;
        return out;
    }
    // Half a pixel of margin so the anti-aliased rim is not cut by the triangle.
    let r = u.point_radius_px + 0.5;
    let corner = triangle_corner(corner_index);
    let ndc_offset = corner * r * 2.0 / u.viewport_px;
    out.position = clip + vec4<f32>(ndc_offset * clip.w, 0.0, 0.0);
    out.color = color;
    out.offset_px = corner * r;
    return out;
}

@fragment
fn fs_point(in: PointOut) -> @location(0) vec4<f32> {
    let coverage = clamp(u.point_radius_px + 0.5 - length(in.offset_px), 0.0, 1.0);
    if !keep(coverage) {
        discard;
    }
    return vec4<f32>(in.color.rgb, coverage);
}

// ---------------------------------------------------------------------------------------------
// Lines: one instance per segment (two consecutive LineVertex), expanded into a quad of constant
// pixel width (the view's line width times the vertex's width factor), extended by half the width
// at both ends so that box corners close. The outline variant draws the same quad wider by the
// rim on each side, in a dark colour, under the coloured one.

struct LineOut {
    @builtin(position) position: vec4<f32>,
    @location(0) color: vec4<f32>,
    // Signed distance from the centre line in pixels.
    @location(1) side_px: f32,
    // Half the drawn width in pixels.
    @location(2) @interpolate(flat) half_width_px: f32,
};

const OUTLINE_COLOR: vec4<f32> = vec4<f32>(0.02, 0.02, 0.03, 1.0);

fn expand_line(
    vertex_index: u32,
    pos_a: vec3<f32>,
    color_a: vec4<f32>,
    width_a: f32,
    pos_b: vec3<f32>,
    color_b: vec4<f32>,
    extra_px: f32,
) -> LineOut {
    var out: LineOut;
    var a = u.view_proj * vec4<f32>(pos_a, 1.0);
    var b = u.view_proj * vec4<f32>(pos_b, 1.0);
    if a.w < u.near_w && b.w < u.near_w {
        out.position = CULLED;
        return out;
    }
    // Clip the segment to the near plane (clip space is linear along the segment).
    if a.w < u.near_w {
        a = mix(a, b, (u.near_w - a.w) / (b.w - a.w));
    } else if b.w < u.near_w {
        b = mix(b, a, (u.near_w - b.w) / (a.w - b.w));
    }
    let half_viewport = 0.5 * u.viewport_px;
    let sa = a.xy / a.w * half_viewport;
    let sb = b.xy / b.w * half_viewport;
    var dir = sb - sa;
    let len = length(dir);
    if len > 1e-4 {
        dir = dir / len;
    } else {
        dir = vec2<f32>(1.0, 0.0);
    }
    let normal = vec2<f32>(-dir.y, dir.x);
    let corner = quad_corner(vertex_index);
    // corner.x: -1 = end a, +1 = end b; corner.y: side of the line.
    let at_b = corner.x > 0.0;
    let end = select(a, b, at_b);
    // One width per segment (its first vertex's), so that both ends match.
    let half_width = u.line_half_width_px * max(width_a, 0.0) + extra_px;
    let hw = half_width + 0.5;
    let offset_px = normal * corner.y * hw + dir * corner.x * hw;
    out.position = end + vec4<f32>(offset_px / half_viewport * end.w, 0.0, 0.0);
    out.color = select(color_a, color_b, at_b);
    out.side_px = corner.y * hw;
    out.half_width_px = half_width;
    return out;
}

@vertex
fn vs_line(
    @builtin(vertex_index) vertex_index: u32,
    @location(0) pos_a: vec3<f32>,
    @location(1) color_a: vec4<f32>,
    @location(2) width_a: f32,
    @location(3) pos_b: vec3<f32>,
    @location(4) color_b: vec4<f32>,
    @location(5) width_b: f32,
) -> LineOut {
    return expand_line(vertex_index, pos_a, color_a, width_a, pos_b, color_b, 0.0);
}

@vertex
fn vs_line_outline(
    @builtin(vertex_index) vertex_index: u32,
    @location(0) pos_a: vec3<f32>,
    @location(1) color_a: vec4<f32>,
    @location(2) width_a: f32,
    @location(3) pos_b: vec3<f32>,
    @location(4) color_b: vec4<f32>,
    @location(5) width_b: f32,
) -> LineOut {
    var out = expand_line(vertex_index, pos_a, color_a, width_a, pos_b, color_b, u.outline_px);
    out.color = OUTLINE_COLOR;
    return out;
}

@fragment
fn fs_line(in: LineOut) -> @location(0) vec4<f32> {
    let coverage = clamp(in.half_width_px + 0.5 - abs(in.side_px), 0.0, 1.0);
    if !keep(coverage) {
        discard;
    }
    return vec4<f32>(in.color.rgb, coverage);
}
