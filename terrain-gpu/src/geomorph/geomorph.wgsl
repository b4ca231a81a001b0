// Geomorphing in the vertex shader (Wagner 2003; geomorph/mod.rs): geo-mipmapped patches
// drawn by one indexed draw per material pass from a library of triangle lists (one per level and set of adapting borders), and the
// runs of coarsest patches by one instanced draw per pass (no per-patch list), each
// vertex morphed between its true height and the coarser level by the patch's tween factor and
// the four edges' factors; a precomputed lightmap and alpha-blended material passes.
//
// `true_h`, `edge_h`, `point_h` and `morph_h` are the twins of geomorph/morph.rs (the CPU
// reference), operation for operation in f32; change both. Positions are camera-relative as in
// render/terrain.wgsl: `col_x[i]` and `row_y[j]` are `world - anchor` rounded once to f32.
//
// Heights come from pages (`height_sample`, paged_lookup.wgsl, concatenated after this file
// when the module is created: the tessellation renderer's lookup, not a copy): a whole
// heightmap is one resident page; a store's blocks are pages of the paged renderer's atlas.
// In paged mode (FLAG_PAGED) the lightmap and alpha maps, which need the whole grid, are 1 x 1
// placeholders: the vertex stage takes the height gradient at its sample from the pages
// (`gradient_at_sample`, the central differences the lightmap's normals and the tessellation
// renderer's `normal_at` blend), the fragment stage (`fs_paged`) normalises the interpolated
// gradient and blends the materials by the same alphas per fragment in one pass.
struct Frame {
    view_proj: mat4x4<f32>,
    // Direction towards the sun (world frame, unit), w unused: paged mode's per-fragment light.
    sun: vec4<f32>,
    spacing: vec2<f32>,
    grid_max: vec2<u32>,
    // -anchor.z: heights plus this are camera-relative.
    height_offset: f32,
    skirt_depth: f32,
    patch_cells: u32,
    max_level: u32,
    // Patches this frame.
    patch_count: u32,
    flags: u32,
    // Paged mode: the material alphas' height range (lowest, highest - lowest).
    height_min: f32,
    height_range: f32,
    // Runs this frame (`runs`), the patches in them (at least 1), and patches along x (the
    // index of `pass_masks`).
    run_count: u32,
    run_patches: u32,
    patches_x: u32,
    pad: u32,
    // FLAG_LOD_COLOURS: the colour of each level (renderer.rs level_colours: the CPU reference
    // render::lod_colour of 2^level cells per triangle edge), the last for every coarser level.
    level_colours: array<vec4<f32>, 8>,
}

// Heights from a store's pages: no lightmap or alpha maps (geomorph/renderer.rs; the
// pipelines use `fs_paged`).
const FLAG_PAGED: u32 = 1u;
// Colour every patch by its level (GeomorphOptions::lod_colours): base pass only.
const FLAG_LOD_COLOURS: u32 = 2u;

struct GmPatch {
    origin: vec2<u32>,
    level: u32,
    tween: f32,
    // South, east, north, west.
    edge_level: vec4<u32>,
    edge_tween: vec4<f32>,
}

const SOUTH: u32 = 0u;
const EAST: u32 = 1u;
const NORTH: u32 = 2u;
const WEST: u32 = 3u;
// morph.rs SKIRT_BIT and PATCH_SHIFT: a drawn index is patch << 14 | skirt << 13 | local id.
const SKIRT_BIT: u32 = 8192u;
const PATCH_SHIFT: u32 = 14u;

@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(2) var<storage, read> patches: array<GmPatch>;
@group(0) @binding(3) var<storage, read> col_x: array<f32>;
@group(0) @binding(4) var<storage, read> row_y: array<f32>;
@group(0) @binding(6) var light_tex: texture_2d<f32>;
@group(0) @binding(7) var alpha_tex: texture_2d<f32>;
@group(0) @binding(8) var maps_sampler: sampler;

// A run (terrain_core::lod::PatchRun): a rectangle of patches drawn at the coarsest level
// (`frame.max_level`), tween 0, every edge at that level; `first` is its south-west patch and
// `start` the patches of the runs before it (a prefix sum: the run of a run-patch index is a
// binary search). Drawn by one instanced draw per pass over all runs (geomorph/renderer.rs).
struct GmRun {
    first: vec2<u32>,
    width: u32,
    start: u32,
}
@group(0) @binding(11) var<storage, read> runs: array<GmRun>;
// Per patch (row-major, `frame.patches_x` along x), 8 bits packed four to a word: bit k set
// when the patch draws material k (materials.rs MaterialMaps::masks; the run patches' pass
// skipping). A placeholder in paged mode (one pass).
@group(0) @binding(12) var<storage, read> pass_masks: array<u32>;

// renderer.rs RUN_INSTANCES: an instance index from this on is a run patch's; below it, the
// material of a pass over the single patches.
const RUN_INSTANCES: u32 = 8u;

fn sample_of(p: GmPatch, x: u32, y: u32) -> vec2<u32> {
    return min(p.origin + vec2<u32>(x, y), frame.grid_max);
}

// Set per pipeline (geomorph/renderer.rs): false for a whole heightmap, whose one page of
// stride 1 sits at the atlas's origin, so the lookup of sample g reads texel g: the same
// value without the page table's reads (a software rasteriser's vertex stage pays for them).
override PAGED: bool = true;

// morph.rs MorphGrid::true_h: the sample's height from the pages (0 on no resident page).
fn true_h(p: GmPatch, x: u32, y: u32) -> f32 {
    let g = vec2<i32>(sample_of(p, x, y));
    if !PAGED {
        return textureLoad(heights, g, 0).r;
    }
    return height_sample(g.x, g.y);
}

// morph.rs MorphGrid::edge_h.
fn edge_h(p: GmPatch, edge: u32, x: u32, y: u32) -> f32 {
    let n = frame.patch_cells;
    let along_x = edge == SOUTH || edge == NORTH;
    let t = select(y, x, along_x);
    let s = 1u << p.edge_level[edge];
    let a = true_h(p, x, y);
    if t == 0u || t == n || t % (2u * s) == 0u || t % s != 0u {
        return a;
    }
    var b: f32;
    var c: f32;
    if along_x {
        b = true_h(p, x - s, y);
        c = true_h(p, x + s, y);
    } else {
        b = true_h(p, x, y - s);
        c = true_h(p, x, y + s);
    }
    let m = 0.5 * (b + c);
    return a + p.edge_tween[edge] * (m - a);
}

// morph.rs MorphGrid::point_h.
fn point_h(p: GmPatch, x: u32, y: u32) -> f32 {
    let n = frame.patch_cells;
    if (x == 0u || x == n) && (y == 0u || y == n) {
        return true_h(p, x, y);
    }
    if y == 0u {
        return edge_h(p, SOUTH, x, y);
    }
    if x == n {
        return edge_h(p, EAST, x, y);
    }
    if y == n {
        return edge_h(p, NORTH, x, y);
    }
    if x == 0u {
        return edge_h(p, WEST, x, y);
    }
    return true_h(p, x, y);
}

// morph.rs MorphGrid::height: the drawn height of local lattice point (x, y). The nested form
// of the article's PosFinal = PosBase + tweeningI dI + ... with tweeningA = (1 - tweeningL)
// tweeningI for the inner neighbours of border vertices (see morph.rs for the expansion).
fn morph_h(p: GmPatch, x: u32, y: u32) -> f32 {
    let n = frame.patch_cells;
    if x == 0u || x == n || y == 0u || y == n || p.level >= frame.max_level {
        return point_h(p, x, y);
    }
    let s = 1u << p.level;
    let xo = (x / s) % 2u == 1u;
    let yo = (y / s) % 2u == 1u;
    if !xo && !yo {
        return true_h(p, x, y);
    }
    var e1: vec2<u32>;
    var e2: vec2<u32>;
    if xo && !yo {
        // Case A.
        e1 = vec2<u32>(x - s, y);
        e2 = vec2<u32>(x + s, y);
    } else if !xo && yo {
        // Case C.
        e1 = vec2<u32>(x, y - s);
        e2 = vec2<u32>(x, y + s);
    } else if ((x - s) / (2u * s) + (y - s) / (2u * s)) % 2u == 0u {
        // Case B, coarse quad split south-west to north-east.
        e1 = vec2<u32>(x - s, y - s);
        e2 = vec2<u32>(x + s, y + s);
    } else {
        // Case B, coarse quad split south-east to north-west.
        e1 = vec2<u32>(x + s, y - s);
        e2 = vec2<u32>(x - s, y + s);
    }
    let a = true_h(p, x, y);
    let m = 0.5 * (point_h(p, e1.x, e1.y) + point_h(p, e2.x, e2.y));
    return a + p.tween * (m - a);
}

struct Morphed {
    // Camera-relative position.
    pos: vec3<f32>,
    // Absolute morphed height.
    height: f32,
    grid: vec2<f32>,
}

// Set per pipeline (geomorph/renderer.rs `MorphSource`), the article's Table 1 columns:
// 0 morphs in the vertex stage (hardware morphing); 1 draws every vertex at its true height
// (static geo-mipmapping: no tweening); 2 reads the height the CPU morphed and uploaded this
// frame (software morphing: `cpu_h[patch index * (patch_cells + 1)^2 + local]`, morph.rs
// `MorphGrid::patch_heights`, the same reference `morph_h` is tested against).
override MORPH_MODE: u32 = 0u;
@group(0) @binding(10) var<storage, read> cpu_h: array<f32>;

// `pi` is the patch's index in `patches`, or RUN_PATCH for a run's patch: the CPU's morph of a
// patch at the coarsest level with tween 0 is its true heights (none are uploaded for it).
const RUN_PATCH: u32 = 0xffffffffu;

fn morphed_vertex(p: GmPatch, pi: u32, local: u32) -> Morphed {
    let n1 = frame.patch_cells + 1u;
    let x = local % n1;
    let y = local / n1;
    let g = sample_of(p, x, y);
    var h: f32;
    if MORPH_MODE == 1u || (MORPH_MODE == 2u && pi == RUN_PATCH) {
        h = true_h(p, x, y);
    } else if MORPH_MODE == 2u {
        h = cpu_h[pi * n1 * n1 + local];
    } else {
        h = morph_h(p, x, y);
    }
    return Morphed(vec3<f32>(col_x[g.x], row_y[g.y], h + frame.height_offset), h, vec2<f32>(g));
}

struct VsOut {
    @builtin(position) @invariant clip: vec4<f32>,
    @location(0) grid: vec2<f32>,
    @location(1) @interpolate(flat) material: u32,
    // Absolute morphed height (paged mode's material alphas).
    @location(2) height: f32,
    // Paged mode: the height gradient (dz/dx, dz/dy) at the vertex's sample, interpolated.
    @location(3) grad: vec2<f32>,
    // FLAG_LOD_COLOURS: the patch's level colour.
    @location(4) @interpolate(flat) lod_colour: vec3<f32>,
}

// The patch `k` of the runs (0 <= k < frame.run_patches): the run is the last whose `start` is
// at most k; the patch's place in it is row-major from its south-west patch. The patch as the
// per-patch path would have it: terrain_core GeomipRuns::run_patch through
// GpuMorphPatch::from_lod (origin = patch (i, j) times patch_cells).
fn run_patch(k: u32) -> GmPatch {
    var lo = 0u;
    var hi = frame.run_count;
    while hi - lo > 1u {
        let mid = (lo + hi) / 2u;
        if runs[mid].start <= k {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let r = runs[lo];
    let o = k - r.start;
    let ij = r.first + vec2<u32>(o % r.width, o / r.width);
    let l = frame.max_level;
    return GmPatch(ij * frame.patch_cells, l, 0.0, vec4<u32>(l), vec4<f32>(0.0));
}

// Whether a run patch at `origin` draws `material` (`pass_masks`).
fn run_draws(origin: vec2<u32>, material: u32) -> bool {
    if material == 0u {
        return true;
    }
    let ij = origin / frame.patch_cells;
    let k = ij.y * frame.patches_x + ij.x;
    return ((pass_masks[k / 4u] >> (8u * (k % 4u))) & (1u << material)) != 0u;
}

@vertex
fn vs(@builtin(vertex_index) vi: u32, @builtin(instance_index) ii: u32) -> VsOut {
    // One indexed draw per material pass over the single patches (the instance index is the
    // material; the index holds the patch and the local lattice id), and one instanced draw
    // per pass over the runs' patches (instance RUN_INSTANCES + material * run_patches + k;
    // the index holds the local id and, on a skirt's triangles, 1 + its edge): see
    // geomorph/renderer.rs.
    let id = vi & ((1u << PATCH_SHIFT) - 1u);
    var p: GmPatch;
    var pi: u32;
    var material = ii;
    // A run patch's triangles it does not draw: its skirts below the grid's border (the
    // per-patch path leaves them out of the index list) and the material passes it skips.
    var hidden = false;
    if ii < RUN_INSTANCES {
        pi = vi >> PATCH_SHIFT;
        p = patches[pi];
    } else {
        let r = ii - RUN_INSTANCES;
        let count = max(frame.run_patches, 1u);
        material = r / count;
        p = run_patch(r % count);
        pi = RUN_PATCH;
        hidden = !run_draws(p.origin, material);
        let tag = vi >> PATCH_SHIFT;
        if tag > 0u {
            // South, east, north, west: skirts only below shared edges (renderer.rs).
            let far = p.origin + vec2<u32>(frame.patch_cells);
            var interior = p.origin.x > 0u;
            if tag == 1u + SOUTH {
                interior = p.origin.y > 0u;
            } else if tag == 1u + EAST {
                interior = far.x < frame.grid_max.x;
            } else if tag == 1u + NORTH {
                interior = far.y < frame.grid_max.y;
            }
            hidden = hidden || !interior;
        }
    }
    let v = morphed_vertex(p, pi, id & (SKIRT_BIT - 1u));
    var pos = v.pos;
    if (id & SKIRT_BIT) != 0u {
        pos.z -= frame.skirt_depth;
    }
    var out: VsOut;
    out.clip = frame.view_proj * vec4<f32>(pos, 1.0);
    if hidden {
        // Every vertex of the triangle here: outside the clip volume, nothing drawn.
        out.clip = vec4<f32>(2.0, 2.0, 2.0, 1.0);
    }
    out.grid = v.grid;
    out.material = material;
    out.height = v.height;
    out.lod_colour = frame.level_colours[min(p.level, 7u)].rgb;
    // Paged mode's normal per vertex: gradient_at_sample at the vertex's own sample (5 lookups,
    // the centre being the one true_h read), interpolated over the triangle. At the samples it
    // is the lightmap's normal (the whole heightmap's `fs`, also per sample and filtered
    // between them); per fragment (`normal_at`) it took 20 lookups per fragment, 4.99x the
    // whole heightmap's render time on lavapipe, this 1.89x (README, geomorph from a store).
    out.grad = vec2<f32>(0.0);
    if PAGED {
        let g = vec2<i32>(v.grid);
        out.grad = gradient_at_sample(g.x, g.y);
    }
    return out;
}

// The tessellation renderer's ramp colours (render/terrain.wgsl), one per pass.
fn material_colour(k: u32) -> vec3<f32> {
    switch k {
        case 1u: { return vec3<f32>(0.22, 0.38, 0.18); }
        case 2u, 4u: { return vec3<f32>(0.50, 0.45, 0.40); }
        case 3u: { return vec3<f32>(0.93, 0.94, 0.96); }
        default: { return vec3<f32>(0.36, 0.52, 0.24); }
    }
}

// materials.rs MaterialMaps::new, per fragment: the alpha of material k (1..=4) for a height
// and a normal.
fn material_alpha(k: u32, height: f32, n: vec3<f32>) -> f32 {
    let t = clamp((height - frame.height_min) / max(frame.height_range, 1e-6), 0.0, 1.0);
    switch k {
        case 1u: { return smoothstep(0.0, 0.35, t); }
        case 2u: { return smoothstep(0.45, 0.75, t); }
        case 3u: { return smoothstep(0.8, 0.95, t); }
        default: { return smoothstep(0.55, 0.8, 1.0 - n.z); }
    }
}

// Paged mode's fragment stage (its own pipeline, so the whole heightmap's pays nothing for
// it): one pass, the materials blended in pass order with their alphas, lambert from the
// normal of the interpolated per-vertex gradient (at least the ambient 0.3, green above zero:
// never the background); no page lookups per fragment.
@fragment
fn fs_paged(in: VsOut) -> @location(0) vec4<f32> {
    let n = normalize(vec3<f32>(-in.grad.x, -in.grad.y, 1.0));
    var c = material_colour(0u);
    for (var k = 1u; k < 5u; k++) {
        c = mix(c, material_colour(k), material_alpha(k, in.height, n));
    }
    if (frame.flags & FLAG_LOD_COLOURS) != 0u {
        c = in.lod_colour;
    }
    let light = 0.3 + 0.7 * max(dot(n, frame.sun.xyz), 0.0);
    return vec4<f32>(c * light, 1.0);
}

@fragment
fn fs(in: VsOut) -> @location(0) vec4<f32> {
    // Texel (i, j) holds sample (i, j) (south row first): its centre is at (g + 0.5) / size.
    let st = (in.grid + 0.5) / vec2<f32>(frame.grid_max + vec2<u32>(1u));
    let light = textureSampleLevel(light_tex, maps_sampler, st, 0.0).r;
    var alpha = 1.0;
    if in.material > 0u {
        alpha = textureSampleLevel(alpha_tex, maps_sampler, st, 0.0)[in.material - 1u];
    }
    // Every material has green above zero and light is at least the ambient 0.3, so the
    // magenta background never comes out of this shader.
    if (frame.flags & FLAG_LOD_COLOURS) != 0u {
        return vec4<f32>(in.lod_colour * light, 1.0);
    }
    return vec4<f32>(material_colour(in.material) * light, alpha);
}

// Test hook: the morphed position of (patch, local id) pairs, through the vertex stage's own
// functions; out[k] = (x, y, z) relative to the anchor and the absolute height.
@group(1) @binding(0) var<storage, read> items: array<vec2<u32>>;
@group(1) @binding(1) var<storage, read_write> morph_out: array<vec4<f32>>;

@compute @workgroup_size(64)
fn debug_morph(@builtin(global_invocation_id) gid: vec3<u32>) {
    let k = gid.x;
    if k >= arrayLength(&items) || k >= arrayLength(&morph_out) {
        return;
    }
    let item = items[k];
    let v = morphed_vertex(patches[item.x], item.x, item.y);
    morph_out[k] = vec4<f32>(v.pos, v.height);
}
