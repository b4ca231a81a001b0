// Paged heights, one snippet for every shader that draws from them (paged.rs is the CPU
// reference of `lookup`, surface.rs of `normal_at`): terrain.wgsl (render/) and geomorph.wgsl
// (geomorph/) are each concatenated with this file when their module is created
// (`render::SHADER`, `geomorph::SHADER`), so the lookup exists once.
//
// The including shader declares `frame` (its uniform) with `grid_max: vec2<u32>` (the last
// sample's column and row) and `spacing: vec2<f32>` (metres), and binds the page atlas at
// binding 1 and the page table at binding 9 of group 0 (declared here).
//
// The atlas holds page slots in classes (one band of rows per class, each class's pages stored
// as their lattice at a stride) and `page_table` maps each page of the grid to its class and
// slot (0: not resident, else class << 24 | slot + 1), after a header (8 words of layout, 8
// per class). A sample on a page border is read from the finest resident page among the page
// it falls in and the west/south neighbours that share it (the first of them among equals); in
// a page of stride d > 1 it is the bilinear interpolation in its lattice cell
// (paged::lattice_bilinear). A sample on no resident page reads 0 and is left out of the
// normals' central differences. A whole heightmap is one page of stride 1, resident.

@group(0) @binding(1) var heights: texture_2d<f32>;
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

// A sample of the normals' stencil: not found outside the grid (the differences turn
// one-sided at the border) nor on no resident page (surface::stencil).
fn stencil(i: i32, j: i32) -> Lookup {
    let gm = vec2<i32>(frame.grid_max);
    if i < 0 || j < 0 || i > gm.x || j > gm.y {
        return Lookup(0.0, false);
    }
    return lookup(i, j);
}

// The central difference across a sample of height `c` from `a` (before it) to `b` (after it),
// one-sided where one of them is not found, per metre of `spacing` (surface::difference).
fn difference(a: Lookup, c: f32, b: Lookup, spacing: f32) -> f32 {
    let ha = select(c, a.h, a.found);
    let hb = select(c, b.h, b.found);
    return (hb - ha) / (f32(max(i32(a.found) + i32(b.found), 1)) * spacing);
}

// The gradient at sample (i, j) from its four neighbours (one-sided at the border and next to
// a sample on no resident page): a vertex's (geomorph.wgsl).
fn gradient_at_sample(i: i32, j: i32) -> vec2<f32> {
    let c = height_sample(i, j);
    let dx = difference(stencil(i - 1, j), c, stencil(i + 1, j), frame.spacing.x);
    let dy = difference(stencil(i, j - 1), c, stencil(i, j + 1), frame.spacing.y);
    return vec2<f32>(dx, dy);
}

// surface::normal_at: the bilinear blend of the gradients at the cell's four corners, whose
// central differences share their samples: rows j and j + 1 at columns i - 1 .. i + 2, and
// columns i and i + 1 at rows j - 1 and j + 2, 12 lookups (not 4 x 5 = 20). At the grid's last
// column (row) the corners i + 1 (j + 1) lie outside it, and their gradients are weighted 0
// (the fraction there is 0); the corners inside read what gradient_at_sample reads.
fn normal_at(g: vec2<f32>) -> vec3<f32> {
    let c = cell_of(g);
    let i = c.i0.x;
    let j = c.i0.y;
    let a0 = stencil(i - 1, j);
    let a1 = stencil(i, j);
    let a2 = stencil(i + 1, j);
    let a3 = stencil(i + 2, j);
    let b0 = stencil(i - 1, j + 1);
    let b1 = stencil(i, j + 1);
    let b2 = stencil(i + 1, j + 1);
    let b3 = stencil(i + 2, j + 1);
    let d0 = stencil(i, j - 1);
    let d1 = stencil(i + 1, j - 1);
    let u0 = stencil(i, j + 2);
    let u1 = stencil(i + 1, j + 2);
    let sx = frame.spacing.x;
    let sy = frame.spacing.y;
    let g00 = vec2<f32>(difference(a0, a1.h, a2, sx), difference(d0, a1.h, b1, sy));
    let g10 = vec2<f32>(difference(a1, a2.h, a3, sx), difference(d1, a2.h, b2, sy));
    let g01 = vec2<f32>(difference(b0, b1.h, b2, sx), difference(a1, b1.h, u0, sy));
    let g11 = vec2<f32>(difference(b1, b2.h, b3, sx), difference(a2, b2.h, u1, sy));
    let a = g00 + (g10 - g00) * c.f.x;
    let b = g01 + (g11 - g01) * c.f.x;
    let grad = a + (b - a) * c.f.y;
    return normalize(vec3<f32>(-grad.x, -grad.y, 1.0));
}
