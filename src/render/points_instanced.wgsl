// Points from per-instance vertex attributes (devices without vertex-stage storage buffers):
// one instanced draw, an instance per point, 3 vertices per instance. Appended to scene.wgsl.

@vertex
fn vs_point(
    @builtin(vertex_index) vertex_index: u32,
    @location(0) position: vec3<f32>,
    @location(1) color: vec4<f32>,
) -> PointOut {
    return expand_point(vertex_index, position, color);
}
