// Test shader (gpu_tests.rs): draws the tessellated patches of a 2 x 2 grid flat over the
// whole viewport, pulling (u, v) and the patch index from the emitted points.

struct VertexIn {
    @location(0) uv: vec2<f32>,
    @location(1) patch_index: u32,
}

@vertex
fn vs(v: VertexIn) -> @builtin(position) vec4<f32> {
    let cell = vec2<f32>(f32(v.patch_index % 2u), f32(v.patch_index / 2u));
    let p = (cell + v.uv) * 0.5;
    return vec4<f32>(p * 2.0 - 1.0, 0.5, 1.0);
}

@fragment
fn fs() -> @location(0) vec4<f32> {
    return vec4<f32>(1.0, 0.0, 0.0, 1.0);
}
