// Terrain drawing (render/mod.rs): the vertex stage maps a tessellated domain point into its
// patch's rect of the heightmap and samples the height; the fragment stage shades with a
// fixed sun, a height/slope colour ramp or a colour texture, and an optional wireframe.
//
// `grid_of`, `surface_at` and `normal_at` are the twins of `surface.rs` (the CPU reference),
// operation for operation in f32; change both. Heights are an R32Float texture read with
// textureLoad and filtered by hand (GL has no FLOAT32_FILTERABLE), one path for all backends.
//
// Paged heights: `lookup`, `height_sample`, `cell_of` and `normal_at` (the heights' atlas,
// bindings 1 and 9) are in paged_lookup.wgsl, concatenated after this file when the module
// is created (render::SHADER); the geomorph shader reads the same pages through it. The
// whole-heightmap renderer is one page of stride 1, resident.
//
// Camera-relative positions: `col_x[i]` and `row_y[j]` hold `world(i, j) - anchor` for every
// column and row, computed in f64 on the CPU and rounded once to f32, so a vertex's position
// is exact to f32 precision *relative to the camera* even at UTM coordinates, and two patches
// sharing an edge compute bit-identical positions there (same grid coordinates in, same
// operations).

struct Frame {
    view_proj: mat4x4<f32>,
    // Direction towards the sun (world frame, unit), w unused.
    sun: vec4<f32>,
    spacing: vec2<f32>,
    grid_max: vec2<u32>,
    // -anchor.z: heights plus this are camera-relative.
    height_offset: f32,
    skirt_depth: f32,
    height_min: f32,
    height_range: f32,
    flags: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

struct DomainPoint {
    uv: vec2<f32>,
    patch_index: u32,
    // 0 for tessellated points; 1 for the lower vertex of a skirt.
    skirt: u32,
}

const FLAG_WIREFRAME: u32 = 1u;
const FLAG_TEXTURE: u32 = 2u;
const FLAG_LOD: u32 = 4u;

// A patch: its rect of grid samples and its LOD colour (render::lod_colour, computed on the
// CPU per patch; drawn instead of the ramp with FLAG_LOD).
struct PatchRect {
    rect: vec4<u32>,
    lod_colour: vec4<f32>,
}

// Set by the pipelines of sRGB targets (render/renderer.rs): the colours below are already
// sRGB-encoded (an Rgba8Unorm target stores them as they are, and PNGs are sRGB), so for a
// target that encodes on store the fragment stage decodes them first; both targets then hold
// the same bytes (to within a rounding step).
override SRGB_TARGET: bool = false;

fn srgb_to_linear(c: vec3<f32>) -> vec3<f32> {
    let low = c / 12.92;
    let high = pow((c + 0.055) / 1.055, vec3<f32>(2.4));
    return select(high, low, c <= vec3<f32>(0.04045));
}

@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(2) var<storage, read> rects: array<PatchRect>;
@group(0) @binding(3) var<storage, read> col_x: array<f32>;
@group(0) @binding(4) var<storage, read> row_y: array<f32>;
@group(0) @binding(5) var color_tex: texture_2d<f32>;
@group(0) @binding(6) var color_sampler: sampler;
@group(0) @binding(7) var<storage, read> points: array<DomainPoint>;
@group(0) @binding(8) var<storage, read> indices: array<u32>;
// surface::grid_coords.
fn grid_of(uv: vec2<f32>, patch_index: u32) -> vec2<f32> {
    let r = rects[patch_index].rect;
    let lo = vec2<f32>(r.xy);
    let size = vec2<f32>(r.zw - r.xy);
    return lo + uv * size;
}

struct Surface {
    // Camera-relative position (world - anchor), metres.
    pos: vec3<f32>,
    // Absolute height, metres.
    height: f32,
}

// The camera-relative x and y of grid coordinates `g`'s cell `c` (the x and y of
// surface::position_at_height).
fn plane_at(c: Cell) -> vec2<f32> {
    let x = col_x[c.i0.x] + c.f.x * frame.spacing.x;
    let y = row_y[c.i0.y] + c.f.y * frame.spacing.y;
    return vec2<f32>(x, y);
}

// surface::surface_position (relative to the anchor) and surface::height_at.
fn surface_at(g: vec2<f32>) -> Surface {
    let c = cell_of(g);
    let h00 = height_sample(c.i0.x, c.i0.y);
    let h10 = height_sample(c.i1.x, c.i0.y);
    let h01 = height_sample(c.i0.x, c.i1.y);
    let h11 = height_sample(c.i1.x, c.i1.y);
    let a = h00 + (h10 - h00) * c.f.x;
    let b = h01 + (h11 - h01) * c.f.x;
    let h = a + (b - a) * c.f.y;
    return Surface(vec3<f32>(plane_at(c), h + frame.height_offset), h);
}

struct VsOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) grid: vec2<f32>,
    @location(1) height: f32,
    @location(2) bary: vec3<f32>,
    @location(3) @interpolate(flat) lod_colour: vec3<f32>,
}

fn vertex(p: DomainPoint, bary: vec3<f32>) -> VsOut {
    let g = grid_of(p.uv, p.patch_index);
    let s = surface_at(g);
    var pos = s.pos;
    if p.skirt != 0u {
        pos.z -= frame.skirt_depth;
    }
    var out: VsOut;
    out.clip = frame.view_proj * vec4<f32>(pos, 1.0);
    out.grid = g;
    out.height = s.height;
    out.bary = bary;
    out.lod_colour = rects[p.patch_index].lod_colour.rgb;
    return out;
}

struct VertexIn {
    @location(0) uv: vec2<f32>,
    @location(1) patch_index: u32,
    @location(2) skirt: u32,
}

// Indexed draw: the tessellator's points as a vertex buffer.
@vertex
fn vs_indexed(v: VertexIn) -> VsOut {
    return vertex(DomainPoint(v.uv, v.patch_index, v.skirt), vec3<f32>(1.0));
}

// Extra triangles with their own heights (render::ExtraTriangles::heights): each vertex at
// its point's x and y, as the sampled surface's, and at its given height
// (surface::position_at_height).
@vertex
fn vs_explicit(v: VertexIn, @location(3) height: f32) -> VsOut {
    let g = grid_of(v.uv, v.patch_index);
    let pos = vec3<f32>(plane_at(cell_of(g)), height + frame.height_offset);
    var out: VsOut;
    out.clip = frame.view_proj * vec4<f32>(pos, 1.0);
    out.grid = g;
    out.height = height;
    out.bary = vec3<f32>(1.0);
    out.lod_colour = rects[v.patch_index].lod_colour.rgb;
    return out;
}

// Non-indexed draw of the same triangles (wireframe): pulls the index and the point itself,
// so each corner knows its barycentric coordinate.
@vertex
fn vs_pulled(@builtin(vertex_index) k: u32) -> VsOut {
    let p = points[indices[k]];
    var bary = vec3<f32>(0.0);
    bary[k % 3u] = 1.0;
    return vertex(p, bary);
}

// Height and slope colour ramp: meadow, forest, rock, snow; steep slopes turn to rock.
fn ramp(height: f32, n: vec3<f32>) -> vec3<f32> {
    let t = clamp((height - frame.height_min) / max(frame.height_range, 1e-6), 0.0, 1.0);
    let meadow = vec3<f32>(0.36, 0.52, 0.24);
    let forest = vec3<f32>(0.22, 0.38, 0.18);
    let rock = vec3<f32>(0.50, 0.45, 0.40);
    let snow = vec3<f32>(0.93, 0.94, 0.96);
    var c = mix(meadow, forest, smoothstep(0.0, 0.35, t));
    c = mix(c, rock, smoothstep(0.45, 0.75, t));
    c = mix(c, snow, smoothstep(0.8, 0.95, t));
    let steep = smoothstep(0.55, 0.8, 1.0 - n.z);
    return mix(c, rock, steep);
}

@fragment
fn fs(in: VsOut) -> @location(0) vec4<f32> {
    let n = normal_at(in.grid);
    var albedo: vec3<f32>;
    if (frame.flags & FLAG_TEXTURE) != 0u {
        // The texture covers the whole DEM, its first row at the north edge.
        let st = vec2<f32>(in.grid.x, f32(frame.grid_max.y) - in.grid.y)
            / max(vec2<f32>(frame.grid_max), vec2<f32>(1.0));
        albedo = textureSampleLevel(color_tex, color_sampler, st, 0.0).rgb;
    } else {
        albedo = ramp(in.height, n);
    }
    if (frame.flags & FLAG_LOD) != 0u {
        albedo = in.lod_colour;
    }
    let lambert = max(dot(n, frame.sun.xyz), 0.0);
    var c = albedo * (0.3 + 0.7 * lambert);
    if (frame.flags & FLAG_WIREFRAME) != 0u {
        let fw = fwidth(in.bary);
        let d = in.bary / max(fw, vec3<f32>(1e-6));
        var edge = 1.0 - clamp(min(d.x, min(d.y, d.z)) - 0.5, 0.0, 1.0);
        // Fade the lines out where triangles are a few pixels across, or they hide the shading.
        edge *= 1.0 - smoothstep(0.15, 0.4, max(fw.x, max(fw.y, fw.z)));
        c = mix(c, vec3<f32>(0.05, 0.05, 0.08), edge * 0.85);
    }
    // Never the background colour (pure magenta): green is kept above zero, so the crack
    // test can tell terrain from background by colour alone.
    c = clamp(c, vec3<f32>(0.0), vec3<f32>(1.0));
    c.g = max(c.g, 0.03);
    if SRGB_TARGET {
        c = srgb_to_linear(c);
    }
    return vec4<f32>(c, 1.0);
}

// Test hook (render::debug): the surface position and normal of every tessellated point,
// through the same functions the vertex and fragment stages call.
@group(1) @binding(0) var<storage, read_write> debug_out: array<vec4<f32>>;

@compute @workgroup_size(64)
fn debug_surface(@builtin(global_invocation_id) gid: vec3<u32>) {
    let k = gid.x;
    if 2u * k + 1u >= arrayLength(&debug_out) {
        return;
    }
    let p = points[k];
    let g = grid_of(p.uv, p.patch_index);
    let s = surface_at(g);
    debug_out[2u * k] = vec4<f32>(s.pos, s.height);
    debug_out[2u * k + 1u] = vec4<f32>(normal_at(g), 0.0);
}
