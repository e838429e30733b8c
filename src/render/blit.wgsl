// Draws the viewport's resolved colour texture into egui's render pass, one texel per pixel.
// egui has already set the pass viewport to the callback rectangle.

@group(0) @binding(0) var scene: texture_2d<f32>;

struct BlitOut {
    @builtin(position) position: vec4<f32>,
    @location(0) uv: vec2<f32>,
};

// One triangle covering the viewport.
@vertex
fn vs_blit(@builtin(vertex_index) vertex_index: u32) -> BlitOut {
    let x = f32((vertex_index << 1u) & 2u);
    let y = f32(vertex_index & 2u);
    var out: BlitOut;
    out.position = vec4<f32>(x * 2.0 - 1.0, 1.0 - y * 2.0, 0.0, 1.0);
    out.uv = vec2<f32>(x, y);
    return out;
}

fn load(uv: vec2<f32>) -> vec3<f32> {
    let dims = vec2<i32>(textureDimensions(scene));
    let texel = clamp(vec2<i32>(floor(uv * vec2<f32>(dims))), vec2<i32>(0), dims - vec2<i32>(1));
    return textureLoad(scene, texel, 0).rgb;
}

// egui's preferred (non-sRGB) framebuffer: the texture already holds gamma-encoded colour.
@fragment
fn fs_blit_gamma(in: BlitOut) -> @location(0) vec4<f32> {
    return vec4<f32>(load(in.uv), 1.0);
}

fn srgb_to_linear(c: vec3<f32>) -> vec3<f32> {
    let cutoff = c < vec3<f32>(0.04045);
    let lower = c / vec3<f32>(12.92);
    let higher = pow((c + vec3<f32>(0.055)) / vec3<f32>(1.055), vec3<f32>(2.4));
    return select(higher, lower, cutoff);
}

// An sRGB framebuffer encodes on write, so hand it linear colour.
@fragment
fn fs_blit_linear(in: BlitOut) -> @location(0) vec4<f32> {
    return vec4<f32>(srgb_to_linear(load(in.uv)), 1.0);
}
