// Points from storage buffers: one non-instanced draw of 3 vertices per point; vertex_index / 3
// picks the point (positions as packed f32 triples, colours as packed RGBA8 — the app's slices
// byte for byte), vertex_index % 3 the triangle corner. Appended to scene.wgsl.

@group(1) @binding(0) var<storage, read> positions: array<f32>;
@group(1) @binding(1) var<storage, read> colors: array<u32>;

@vertex
fn vs_point(@builtin(vertex_index) vertex_index: u32) -> PointOut {
    let i = vertex_index / 3u;
    let position = vec3<f32>(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
    return expand_point(vertex_index, position, unpack4x8unorm(colors[i]));
}
