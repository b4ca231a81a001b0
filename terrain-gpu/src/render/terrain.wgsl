// Terrain drawing (render/mod.rs): the vertex stage maps a tessellated domain point into its
// patch's rect of the heightmap and samples the height; the fragment stage shades with a
// fixed sun, a height/slope colour ramp or a colour texture, and an optional wireframe.
//
// `grid_of`, `surface_at` and `normal_at` are the twins of `surface.rs` (the CPU reference),
// operation for operation in f32; change both. Heights are an R32Float texture read with
// textureLoad and filtered by hand (GL has no FLOAT32_FILTERABLE), one path for all backends.
//
// Paged heights (paged.rs is the CPU reference of `lookup`): the texture is an atlas of page
// slots in classes (one band of rows per class, each class's pages stored as their lattice
// at a stride) and `page_table` maps each page of the grid to its class and slot (0: not
// resident, else class << 24 | slot + 1), after a header (8 words of layout, 8 per class).
// A sample on a page border is read from the finest resident page among the page it falls in
// and the west/south neighbours that share it (the first of them among equals); in a page of stride d > 1 it is the bilinear
// interpolation in its lattice cell (paged::lattice_bilinear). A sample on no resident page
// reads 0 and is left out of the normals' central differences. The whole-heightmap renderer
// is one page of stride 1, resident.
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
@group(0) @binding(1) var heights: texture_2d<f32>;
@group(0) @binding(2) var<storage, read> rects: array<vec4<u32>>;
@group(0) @binding(3) var<storage, read> col_x: array<f32>;
@group(0) @binding(4) var<storage, read> row_y: array<f32>;
@group(0) @binding(5) var color_tex: texture_2d<f32>;
@group(0) @binding(6) var color_sampler: sampler;
@group(0) @binding(7) var<storage, read> points: array<DomainPoint>;
@group(0) @binding(8) var<storage, read> indices: array<u32>;
// Header: cells per page x, y; pages x, y; 4 unused; then per class (16): first atlas row,
// slots per row, slot width, slot height, stride, 3 unused. Entries from word 136.
@group(0) @binding(9) var<storage, read> page_table: array<u32>;

struct Lookup {
    h: f32,
    found: bool,
}

fn page_entry(px: u32, py: u32) -> u32 {
    return page_table[136u + py * page_table[2] + px];
}

// Stride of the class of page-table entry `s` (non-zero).
fn entry_stride(s: u32) -> u32 {
    return page_table[8u + 8u * (s >> 24u) + 4u];
}

// Whether entry `t` is resident and finer than the best so far (`s`, 0 = none).
fn finer(t: u32, s: u32) -> bool {
    return t != 0u && (s == 0u || entry_stride(t) < entry_stride(s));
}

// paged::PagedHeights::locate and HeightGrid::sample: of the resident pages among the four
// candidates, the one of the smallest stride (the first in order among equals), straight-line
// code (no loop).
fn lookup(i: i32, j: i32) -> Lookup {
    let g = vec2<u32>(clamp(vec2<i32>(i, j), vec2<i32>(0), vec2<i32>(frame.grid_max)));
    let c = vec2<u32>(page_table[0], page_table[1]);
    let n = vec2<u32>(page_table[2], page_table[3]);
    let p0 = min(g / c, n - vec2<u32>(1u));
    let back = (g == p0 * c) & (p0 > vec2<u32>(0u));
    let p1 = select(p0, p0 - vec2<u32>(1u), back);
    var p = p0;
    var s = page_entry(p0.x, p0.y);
    if back.x {
        let q = vec2<u32>(p1.x, p0.y);
        let t = page_entry(q.x, q.y);
        if finer(t, s) {
            p = q;
            s = t;
        }
    }
    if back.y {
        let q = vec2<u32>(p0.x, p1.y);
        let t = page_entry(q.x, q.y);
        if finer(t, s) {
            p = q;
            s = t;
        }
    }
    if back.x && back.y {
        let t = page_entry(p1.x, p1.y);
        if finer(t, s) {
            p = p1;
            s = t;
        }
    }
    if s == 0u {
        return Lookup(0.0, false);
    }
    let cls = 8u + 8u * (s >> 24u);
    let slot = (s & 0xffffffu) - 1u;
    let per_row = page_table[cls + 1u];
    let size = vec2<u32>(page_table[cls + 2u], page_table[cls + 3u]);
    let base = vec2<u32>(slot % per_row, page_table[cls] + slot / per_row * size.y);
    let corner = vec2<u32>(base.x * size.x, base.y);
    let q = g - p * c;
    let d = page_table[cls + 4u];
    if d == 1u {
        return Lookup(textureLoad(heights, vec2<i32>(corner + q), 0).r, true);
    }
    // paged::lattice_bilinear, operation for operation.
    let a = min(q / d, c / d - vec2<u32>(1u));
    let f = vec2<f32>(q - a * d) / f32(d);
    let t = vec2<i32>(corner + a);
    let h00 = textureLoad(heights, t, 0).r;
    let h10 = textureLoad(heights, t + vec2<i32>(1, 0), 0).r;
    let h01 = textureLoad(heights, t + vec2<i32>(0, 1), 0).r;
    let h11 = textureLoad(heights, t + vec2<i32>(1, 1), 0).r;
    let lo = h00 + (h10 - h00) * f.x;
    let hi = h01 + (h11 - h01) * f.x;
    return Lookup(lo + (hi - lo) * f.y, true);
}

fn height_sample(i: i32, j: i32) -> f32 {
    return lookup(i, j).h;
}

// surface::grid_coords.
fn grid_of(uv: vec2<f32>, patch_index: u32) -> vec2<f32> {
    let r = rects[patch_index];
    let lo = vec2<f32>(r.xy);
    let size = vec2<f32>(r.zw - r.xy);
    return lo + uv * size;
}

struct Cell {
    i0: vec2<i32>,
    i1: vec2<i32>,
    f: vec2<f32>,
}

fn cell_of(g: vec2<f32>) -> Cell {
    let gc = clamp(g, vec2<f32>(0.0), vec2<f32>(frame.grid_max));
    let cell = floor(gc);
    let i0 = vec2<i32>(cell);
    let i1 = min(i0 + vec2<i32>(1), vec2<i32>(frame.grid_max));
    return Cell(i0, i1, gc - cell);
}

struct Surface {
    // Camera-relative position (world - anchor), metres.
    pos: vec3<f32>,
    // Absolute height, metres.
    height: f32,
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
    let x = col_x[c.i0.x] + c.f.x * frame.spacing.x;
    let y = row_y[c.i0.y] + c.f.y * frame.spacing.y;
    return Surface(vec3<f32>(x, y, h + frame.height_offset), h);
}

// One-sided at the border and next to a sample on no resident page (surface.rs).
fn gradient_at_sample(i: i32, j: i32) -> vec2<f32> {
    let gm = vec2<i32>(frame.grid_max);
    let c = height_sample(i, j);
    var l = Lookup(c, false);
    var r = Lookup(c, false);
    var d = Lookup(c, false);
    var u = Lookup(c, false);
    if i > 0 {
        l = lookup(i - 1, j);
    }
    if i < gm.x {
        r = lookup(i + 1, j);
    }
    if j > 0 {
        d = lookup(i, j - 1);
    }
    if j < gm.y {
        u = lookup(i, j + 1);
    }
    let il = select(i, i - 1, l.found);
    let ir = select(i, i + 1, r.found);
    let jd = select(j, j - 1, d.found);
    let ju = select(j, j + 1, u.found);
    let hl = select(c, l.h, l.found);
    let hr = select(c, r.h, r.found);
    let hd = select(c, d.h, d.found);
    let hu = select(c, u.h, u.found);
    let dx = (hr - hl) / (f32(max(ir - il, 1)) * frame.spacing.x);
    let dy = (hu - hd) / (f32(max(ju - jd, 1)) * frame.spacing.y);
    return vec2<f32>(dx, dy);
}

// surface::normal_at.
fn normal_at(g: vec2<f32>) -> vec3<f32> {
    let c = cell_of(g);
    let g00 = gradient_at_sample(c.i0.x, c.i0.y);
    let g10 = gradient_at_sample(c.i1.x, c.i0.y);
    let g01 = gradient_at_sample(c.i0.x, c.i1.y);
    let g11 = gradient_at_sample(c.i1.x, c.i1.y);
    let a = g00 + (g10 - g00) * c.f.x;
    let b = g01 + (g11 - g01) * c.f.x;
    let grad = a + (b - a) * c.f.y;
    return normalize(vec3<f32>(-grad.x, -grad.y, 1.0));
}

struct VsOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) grid: vec2<f32>,
    @location(1) height: f32,
    @location(2) bary: vec3<f32>,
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
