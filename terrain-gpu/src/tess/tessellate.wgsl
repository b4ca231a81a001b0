// Quad-domain tessellation with fractional-even spacing, emulated in compute.
//
// The twin of `reference.rs`: every function below has a namesake there and repeats its f32
// arithmetic operation for operation (the D3D11 reference tessellator, restated in f32), so
// the read-back agrees with the CPU to a few ulps and the topology exactly. Change both.
//
// Three entry points, run in order over the same bind group (see `tess/mod.rs`):
//   count: one invocation per patch; point and index counts, in closed form.
//   scan:  one workgroup; exclusive prefix sums into each patch's range, and the draw args.
//   emit:  one invocation per patch; writes its points and its indices (global point ids).

struct Factors {
    outer: vec4<f32>,
    inner: vec2<f32>,
    pad: vec2<f32>,
}

struct PatchRange {
    point_offset: u32,
    point_count: u32,
    index_offset: u32,
    index_count: u32,
}

struct DomainPoint {
    uv: vec2<f32>,
    patch_index: u32,
    pad: u32,
}

struct DrawArgs {
    index_count: u32,
    instance_count: u32,
    first_index: u32,
    base_vertex: i32,
    first_instance: u32,
}

struct Params {
    patch_count: u32,
    point_capacity: u32,
    index_capacity: u32,
    pad: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> factors: array<Factors>;
@group(0) @binding(2) var<storage, read_write> ranges: array<PatchRange>;
@group(0) @binding(3) var<storage, read_write> points: array<DomainPoint>;
@group(0) @binding(4) var<storage, read_write> indices: array<u32>;
@group(0) @binding(5) var<storage, read_write> draw: DrawArgs;

const MIN_FACTOR: f32 = 2.0;
const MAX_FACTOR: f32 = 64.0;

// reference::RULER_ORDER.
var<private> RULER_ORDER: array<u32, 33> = array<u32, 33>(
    0u, 32u, 16u, 8u, 17u, 4u, 18u, 9u, 19u, 2u, 20u, 10u, 21u, 5u, 22u, 11u, 23u, 1u, 24u, 12u,
    25u, 6u, 26u, 13u, 27u, 3u, 28u, 14u, 29u, 7u, 30u, 15u, 31u,
);

struct Spacing {
    half_points: u32,
    split: u32,
    frac: f32,
    inv_floor: f32,
    inv_ceil: f32,
}

fn clamp_factor(factor: f32) -> f32 {
    if factor > MAX_FACTOR {
        return MAX_FACTOR;
    } else if factor > MIN_FACTOR {
        return factor;
    }
    return MIN_FACTOR;
}

fn remove_msb(x: u32) -> u32 {
    if x == 0u {
        return 0u;
    }
    return x & ~(1u << (31u - countLeadingZeros(x)));
}

fn spacing_new(factor: f32) -> Spacing {
    let t = clamp_factor(factor);
    let half = t * 0.5;
    let lo = floor(half);
    let hi = ceil(half);
    let half_points = u32(hi);
    var split = half_points + 1u;
    if lo != hi {
        split = remove_msb(u32(lo)) * 2u + 1u;
    }
    return Spacing(half_points, split, half - lo, 1.0 / (2.0 * lo), 1.0 / (2.0 * hi));
}

fn point_count_of(s: Spacing) -> u32 {
    return 2u * s.half_points + 1u;
}

fn place(s: Spacing, point: u32) -> f32 {
    let flip = point >= s.half_points;
    var p = point;
    if flip {
        p = 2u * s.half_points - point;
    }
    if p == s.half_points {
        return 0.5;
    }
    var on_floor = p;
    if p > s.split {
        on_floor = p - 1u;
    }
    let at_floor = f32(on_floor) * s.inv_floor;
    let at_ceil = f32(p) * s.inv_ceil;
    let at = at_floor * (1.0 - s.frac) + at_ceil * s.frac;
    if flip {
        return 1.0 - at;
    }
    return at;
}

// The QuadLayout of the patch this invocation works on.
var<private> culled: bool;
var<private> outer_sp: array<Spacing, 4>;
var<private> inner_sp: array<Spacing, 2>;
var<private> rings: u32;

fn load_layout(patch_index: u32) {
    let f = factors[patch_index];
    culled = false;
    for (var e = 0u; e < 4u; e++) {
        // Not `!(x > 0)`: shader compilers may assume there is no NaN.
        culled = culled || f.outer[e] <= 0.0;
        outer_sp[e] = spacing_new(f.outer[e]);
    }
    inner_sp[0] = spacing_new(f.inner.x);
    inner_sp[1] = spacing_new(f.inner.y);
    rings = min(inner_sp[0].half_points, inner_sp[1].half_points);
}

fn inner_count(axis: u32) -> u32 {
    return point_count_of(inner_sp[axis]);
}

fn side_axis(side: u32) -> u32 {
    return select(0u, 1u, side % 2u == 0u);
}

fn side_len(ring: u32, side: u32) -> u32 {
    if ring == 0u {
        return point_count_of(outer_sp[side]);
    }
    return inner_count(side_axis(side)) - 2u * ring;
}

fn outer_ring_points() -> u32 {
    var n = 0u;
    for (var e = 0u; e < 4u; e++) {
        n += point_count_of(outer_sp[e]) - 1u;
    }
    return n;
}

fn ring_base(ring: u32) -> u32 {
    let r1 = ring - 1u;
    let n = inner_count(0u) + inner_count(1u);
    return outer_ring_points() + r1 * (2u * n - 4u * ring - 4u);
}

fn centre_is_row() -> bool {
    return inner_count(0u) > inner_count(1u);
}

fn layout_point_count() -> u32 {
    if culled {
        return 0u;
    }
    return outer_ring_points() + (inner_count(0u) - 2u) * (inner_count(1u) - 2u);
}

fn band_triangles(ring: u32, side: u32) -> u32 {
    return side_len(ring - 1u, side) + side_len(ring, side) - 2u;
}

fn layout_triangle_count() -> u32 {
    if culled {
        return 0u;
    }
    var n = 0u;
    for (var r = 1u; r <= rings; r++) {
        for (var e = 0u; e < 4u; e++) {
            n += band_triangles(r, e);
        }
    }
    return n;
}

fn side_point(ring: u32, side: u32, k: u32) -> u32 {
    let len = side_len(ring, side);
    if ring == 0u || ring < rings {
        var base = 0u;
        if ring != 0u {
            base = ring_base(ring);
        }
        var start = 0u;
        for (var s = 0u; s < side; s++) {
            start += side_len(ring, s) - 1u;
        }
        if side == 3u && k == len - 1u {
            return base;
        }
        return base + start + k;
    }
    let base = ring_base(ring);
    if centre_is_row() {
        let last = inner_count(0u) - 2u * ring - 1u;
        switch side {
            case 0u: { return base; }
            case 1u: { return base + k; }
            case 2u: { return base + last; }
            default: { return base + last - k; }
        }
    }
    let last = inner_count(1u) - 2u * ring - 1u;
    switch side {
        case 0u: { return base + k; }
        case 1u: { return base + last; }
        case 2u: { return base + last - k; }
        default: { return base; }
    }
}

// Output cursors of the emit pass.
var<private> patch_id: u32;
var<private> point_base: u32;
var<private> point_cursor: u32;
var<private> index_cursor: u32;

fn push_point(u: f32, v: f32) {
    points[point_cursor] = DomainPoint(vec2<f32>(u, v), patch_id, 0u);
    point_cursor += 1u;
}

fn generate_points() {
    for (var e = 0u; e < 4u; e++) {
        let s = outer_sp[e];
        let end = point_count_of(s) - 1u;
        for (var p = 0u; p < end; p++) {
            var q = end - p;
            if e == 1u || e == 2u {
                q = p;
            }
            let t = place(s, q);
            switch e {
                case 0u: { push_point(0.0, t); }
                case 1u: { push_point(t, 0.0); }
                case 2u: { push_point(1.0, t); }
                default: { push_point(t, 1.0); }
            }
        }
    }
    for (var r = 1u; r < rings; r++) {
        for (var e = 0u; e < 4u; e++) {
            let along = side_axis(e);
            let across = 1u - along;
            let end = inner_count(along) - 1u - r;
            var across_point = inner_count(across) - 1u - r;
            if e < 2u {
                across_point = r;
            }
            let c = place(inner_sp[across], across_point);
            for (var p = r; p < end; p++) {
                var q = end - (p - r);
                if e == 1u || e == 2u {
                    q = p;
                }
                let t = place(inner_sp[along], q);
                if along == 1u {
                    push_point(c, t);
                } else {
                    push_point(t, c);
                }
            }
        }
    }
    let m = rings;
    if centre_is_row() {
        for (var p = m; p <= inner_count(0u) - 1u - m; p++) {
            push_point(place(inner_sp[0], p), 0.5);
        }
    } else {
        for (var p = inner_count(1u) - 1u - m; p >= m; p--) {
            push_point(0.5, place(inner_sp[1], p));
        }
    }
}

// The Band of reference.rs.
var<private> band_ring: u32;
var<private> band_side: u32;
var<private> band_o: u32;
var<private> band_i: u32;

fn outside(k: u32) -> u32 {
    return side_point(band_ring - 1u, band_side, k);
}

fn inside(k: u32) -> u32 {
    return side_point(band_ring, band_side, k);
}

fn tri(a: u32, b: u32, c: u32) {
    indices[index_cursor] = point_base + a;
    indices[index_cursor + 1u] = point_base + b;
    indices[index_cursor + 2u] = point_base + c;
    index_cursor += 3u;
}

fn advance_outside() {
    tri(outside(band_o), outside(band_o + 1u), inside(band_i));
    band_o += 1u;
}

fn advance_inside() {
    tri(inside(band_i), outside(band_o), inside(band_i + 1u));
    band_i += 1u;
}

fn stitch_transition(outer_half: u32, inner_half: u32) {
    if RULER_ORDER[0] < outer_half {
        advance_outside();
    }
    for (var k = 1u; k < 33u; k++) {
        let pos = RULER_ORDER[k];
        if pos < inner_half {
            advance_inside();
        }
        if pos < outer_half {
            advance_outside();
        }
    }
    for (var k = 32u; k >= 1u; k--) {
        let pos = RULER_ORDER[k];
        if pos < outer_half {
            advance_outside();
        }
        if pos < inner_half {
            advance_inside();
        }
    }
    if RULER_ORDER[0] < outer_half {
        advance_outside();
    }
}

fn stitch_regular(inside_len: u32) {
    advance_outside();
    for (var p = 0u; p + 1u < inside_len; p++) {
        let o0 = outside(band_o);
        let o1 = outside(band_o + 1u);
        let i0 = inside(band_i);
        let i1 = inside(band_i + 1u);
        if p < inside_len / 2u {
            tri(o0, i1, i0);
            tri(o0, o1, i1);
        } else {
            tri(i0, o0, o1);
            tri(i0, o1, i1);
        }
        band_o += 1u;
        band_i += 1u;
    }
    advance_outside();
}

fn generate_triangles() {
    for (var r = 1u; r <= rings; r++) {
        for (var e = 0u; e < 4u; e++) {
            band_ring = r;
            band_side = e;
            band_o = 0u;
            band_i = 0u;
            if r == 1u {
                stitch_transition(outer_sp[e].half_points, inner_sp[side_axis(e)].half_points);
            } else {
                stitch_regular(side_len(r, e));
            }
        }
    }
}

@compute @workgroup_size(64)
fn count(@builtin(global_invocation_id) gid: vec3<u32>) {
    let p = gid.x;
    if p >= params.patch_count {
        return;
    }
    load_layout(p);
    ranges[p].point_count = layout_point_count();
    ranges[p].index_count = 3u * layout_triangle_count();
}

const SCAN_THREADS: u32 = 256u;
var<workgroup> wg_points: array<u32, 256>;
var<workgroup> wg_indices: array<u32, 256>;

@compute @workgroup_size(256)
fn scan(@builtin(local_invocation_index) lid: u32) {
    // Each thread sums a contiguous chunk of patches; a Hillis-Steele scan over the chunk
    // sums gives each chunk its start; the chunk is then walked again to hand out offsets.
    let n = params.patch_count;
    let chunk = (n + SCAN_THREADS - 1u) / SCAN_THREADS;
    let begin = min(lid * chunk, n);
    let end = min(begin + chunk, n);
    var sum_points = 0u;
    var sum_indices = 0u;
    for (var k = begin; k < end; k++) {
        sum_points += ranges[k].point_count;
        sum_indices += ranges[k].index_count;
    }
    wg_points[lid] = sum_points;
    wg_indices[lid] = sum_indices;
    workgroupBarrier();
    for (var offset = 1u; offset < SCAN_THREADS; offset <<= 1u) {
        var add_points = 0u;
        var add_indices = 0u;
        if lid >= offset {
            add_points = wg_points[lid - offset];
            add_indices = wg_indices[lid - offset];
        }
        workgroupBarrier();
        wg_points[lid] += add_points;
        wg_indices[lid] += add_indices;
        workgroupBarrier();
    }
    var at_point = wg_points[lid] - sum_points;
    var at_index = wg_indices[lid] - sum_indices;
    for (var k = begin; k < end; k++) {
        ranges[k].point_offset = at_point;
        ranges[k].index_offset = at_index;
        at_point += ranges[k].point_count;
        at_index += ranges[k].index_count;
    }
    if lid == SCAN_THREADS - 1u {
        // Patches past the capacity are not emitted (see `emit`); never draw past it.
        draw = DrawArgs(min(wg_indices[lid], params.index_capacity), 1u, 0u, 0, 0u);
    }
}

@compute @workgroup_size(64)
fn emit(@builtin(global_invocation_id) gid: vec3<u32>) {
    let p = gid.x;
    if p >= params.patch_count {
        return;
    }
    let r = ranges[p];
    if r.point_offset + r.point_count > params.point_capacity
        || r.index_offset + r.index_count > params.index_capacity {
        return;
    }
    load_layout(p);
    if culled {
        return;
    }
    patch_id = p;
    point_base = r.point_offset;
    point_cursor = r.point_offset;
    index_cursor = r.index_offset;
    generate_points();
    generate_triangles();
}
