//! The DSS paper's dynamic stitching strips (Zhang 2019, section 3.2) on the CPU: their
//! vertices from the tessellator's CPU reference, their triangulation (Algorithm 1,
//! [`triangulate`]), built every frame (in parallel with rayon from [`PARALLEL_MIN_STRIPS`]
//! strips on) and drawn by the renderer as extra triangles ([`crate::render::ExtraTriangles`])
//! after the M-blocks' tessellation.
//!
//! The structure (M-blocks, P-blocks, which blocks line which strip) comes from
//! `terrain_core::lod::dss_strips`; see its docs for the geometry (blocks shrunk by `s` cells,
//! strips `2 s` wide). Here:
//!
//! - **Blocks** are draw patches in the frame's block order ([`draw_patches`]): rect = the
//!   block's shrunk domain, every factor its `F_thr`; hidden (frustum-culled) blocks are kept
//!   in the list with outer factors 0, which the tessellator culls, so that strips can still
//!   name them.
//! - **Strip vertices** are [`GpuDomainPoint`]s: the block's patch index and the domain point
//!   `(u, v)` on its edge, `t = EdgeSpacing::new(F).place(k)` of [`crate::tess::reference`]
//!   (section 3.2.2: "we use the same tessellation manner as the fractional even spacing
//!   scheme"). These are the very values the tessellator emits for that edge (its points on an
//!   outer edge depend only on the edge's factor), and the vertex stage maps them with the
//!   block's rect like any tessellated point, so strip and block vertices coincide bit for bit
//!   on the GPU, and in the CPU reference ([`build_strip_surface`]), with no tolerance.
//! - **P-blocks**: two triangles between the four blocks' inner corners.
//!
//! Triangles are anti-clockwise seen from above (the renderer culls none; the CPU surface keeps
//! the convention of `terrain_core::lod::SurfaceMesh`).

pub mod triangulate;

#[cfg(test)]
mod gpu_tests;
#[cfg(test)]
mod tests;

use std::collections::HashMap;
use std::time::{Duration, Instant};

use glam::Vec2;
use rayon::prelude::*;
use terrain_core::Heightmap;
use terrain_core::lod::dss_strips::corner_uv;
use terrain_core::lod::{DssStripFrame, Edge, MBlock, PBlock, Strip, SurfaceMesh};

use crate::render::{DrawPatch, ExtraTriangles};
use crate::surface::grid_coords;
use crate::tess::{EdgeSpacing, GpuDomainPoint, PatchFactors, tessellate};

/// The strips and P-blocks of one frame, ready to upload.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct StripMesh {
    /// Vertices (patch index into [`draw_patches`]' list and domain point).
    pub triangles: ExtraTriangles,
    /// Strips built.
    pub strips: usize,
    /// P-blocks built.
    pub pblocks: usize,
    /// CPU time of the construction (vertices, triangulation, concatenation).
    pub cpu_time: Duration,
}

/// The tessellation factors of a block: its `F_thr` everywhere, or culled (outer factors 0)
/// when hidden.
pub fn block_factors(b: &MBlock) -> PatchFactors {
    if b.visible {
        PatchFactors::uniform(b.factor)
    } else {
        PatchFactors { inner: [0.0; 2], outer: [0.0; 4] }
    }
}

/// The renderer's patches of a frame: block `k` is patch `k`.
pub fn draw_patches(frame: &DssStripFrame) -> Vec<DrawPatch> {
    frame.blocks.iter().map(|b| DrawPatch { rect: b.rect, factors: block_factors(b) }).collect()
}

/// The domain point at parameter `t` along edge `e` (from its south or west end).
fn edge_uv(e: Edge, t: f32) -> [f32; 2] {
    match e {
        Edge::South => [t, 0.0],
        Edge::East => [1.0, t],
        Edge::North => [t, 1.0],
        Edge::West => [0.0, t],
    }
}

/// The vertices one side of a strip has: every edge point of its blocks.
fn side_point_count(frame: &DssStripFrame, blocks: &[usize]) -> usize {
    blocks.iter().map(|&k| EdgeSpacing::new(frame.blocks[k].factor).point_count() as usize).sum()
}

/// Writes one side's vertices to the start of `points` (which holds at least
/// [`side_point_count`]) and appends their positions along the strip to `along`; returns the
/// vertices written.
fn write_side(
    frame: &DssStripFrame,
    blocks: &[usize],
    e: Edge,
    points: &mut [GpuDomainPoint],
    along: &mut Vec<f64>,
) -> usize {
    let vertical = matches!(e, Edge::East | Edge::West);
    let mut n = 0;
    for &k in blocks {
        let b = &frame.blocks[k];
        let spacing = EdgeSpacing::new(b.factor);
        let [x0, y0, x1, y1] = b.rect.map(f64::from);
        let (lo, len) = if vertical { (y0, y1 - y0) } else { (x0, x1 - x0) };
        for q in 0..spacing.point_count() {
            let t = spacing.place(q);
            points[n] = GpuDomainPoint { uv: edge_uv(e, t), patch_index: k as u32, pad: 0 };
            along.push(lo + f64::from(t) * len);
            n += 1;
        }
    }
    n
}

/// The vertices and indices strip `strip` has: every edge point of its blocks on both sides,
/// and three indices per triangle, `n_a - 1 + n_b - 1` triangles
/// ([`triangulate::bisector_triangles`]).
fn strip_size(frame: &DssStripFrame, strip: &Strip) -> (usize, usize) {
    let (na, nb) =
        (side_point_count(frame, frame.low(strip)), side_point_count(frame, frame.high(strip)));
    (na + nb, if na == 0 || nb == 0 { 0 } else { 3 * (na + nb - 2) })
}

/// Writes strip `strip` into the starts of `points` and `indices` (which hold at least
/// [`strip_size`]), its indices offset by `base`, with `low` and `high` as scratch space:
/// [`build_strip`] without allocating. Returns the points and indices written.
fn write_strip(
    frame: &DssStripFrame,
    strip: &Strip,
    base: u32,
    (points, indices): (&mut [GpuDomainPoint], &mut [u32]),
    (low, high): (&mut Vec<f64>, &mut Vec<f64>),
) -> (usize, usize) {
    low.clear();
    high.clear();
    let nl = write_side(frame, frame.low(strip), strip.facing_edge(false), points, low);
    let nh = write_side(frame, frame.high(strip), strip.facing_edge(true), &mut points[nl..], high);
    let na = base + nl as u32;
    let mut n = 0;
    triangulate::for_each_bisector_triangle(low, high, |tri| {
        let [a, b, c] = tri.map(|(hi, k)| if hi { na + k } else { base + k });
        // A base on the low side of a vertical strip (or the high side of a horizontal one)
        // runs clockwise with its apex: swap to keep every triangle anti-clockwise.
        let t = if strip.vertical != tri[0].0 { [a, c, b] } else { [a, b, c] };
        indices[n..n + 3].copy_from_slice(&t);
        n += 3;
    });
    (nl + nh, n)
}

/// The vertices and triangles (local indices) of one strip.
pub fn build_strip(frame: &DssStripFrame, strip: &Strip) -> (Vec<GpuDomainPoint>, Vec<u32>) {
    let (np, ni) = strip_size(frame, strip);
    let (mut points, mut indices) = (vec![GpuDomainPoint::default(); np], vec![0; ni]);
    write_strip(frame, strip, 0, (&mut points, &mut indices), (&mut Vec::new(), &mut Vec::new()));
    (points, indices)
}

/// Frames with fewer strips are built on the calling thread: a strip costs about a
/// microsecond, less than waking rayon's workers (milliseconds on a loaded machine).
pub const PARALLEL_MIN_STRIPS: usize = 512;

/// Builds every strip and P-block of `frame` (section 3.2, once per frame), in parallel with
/// rayon from [`PARALLEL_MIN_STRIPS`] strips on ("several worker threads", section 3.2.3).
pub fn build_strips(frame: &DssStripFrame) -> StripMesh {
    build_strips_with(frame, frame.strips.len() >= PARALLEL_MIN_STRIPS)
}

/// One run of strips to write: the strips, the index of their first vertex, and the slices of
/// the output their vertices and indices go to.
type StripRun<'a> = (&'a [Strip], u32, &'a mut [GpuDomainPoint], &'a mut [u32]);

/// [`build_strips`], in parallel or not: the same output either way.
pub fn build_strips_with(frame: &DssStripFrame, parallel: bool) -> StripMesh {
    let start = Instant::now();
    if !parallel {
        return build_strips_serial(frame, start);
    }
    // Every strip's place in the output, from its blocks' factors: runs of strips write into
    // their own slices of one buffer, and nothing is copied or grown afterwards (the strips'
    // own vectors, allocated on rayon's workers and freed here, then the runs' buffers copied
    // into one, were most of the build's samples on this thread).
    let sizes: Vec<(usize, usize)> = frame.strips.iter().map(|s| strip_size(frame, s)).collect();
    let (np, ni) = sizes.iter().fold((0, 0), |(p, i), &(a, b)| (p + a, i + b));
    let mut points = vec![GpuDomainPoint::default(); np + 4 * frame.pblocks.len()];
    let mut indices = vec![0u32; ni + 6 * frame.pblocks.len()];
    let run = frame.strips.len().div_ceil(4 * rayon::current_num_threads()).max(32);
    let (strip_points, pblock_points) = points.split_at_mut(np);
    let (strip_indices, pblock_indices) = indices.split_at_mut(ni);
    let mut runs: Vec<StripRun<'_>> = Vec::with_capacity(frame.strips.len().div_ceil(run));
    let (mut points_left, mut indices_left) = (strip_points, strip_indices);
    let mut base = 0usize;
    for (strips, sizes) in frame.strips.chunks(run).zip(sizes.chunks(run)) {
        let (p, i) = sizes.iter().fold((0, 0), |(p, i), &(a, b)| (p + a, i + b));
        let (run_points, rest) = std::mem::take(&mut points_left).split_at_mut(p);
        points_left = rest;
        let (run_indices, rest) = std::mem::take(&mut indices_left).split_at_mut(i);
        indices_left = rest;
        runs.push((strips, base as u32, run_points, run_indices));
        base += p;
    }
    let write_run = |(strips, base, points, indices): StripRun<'_>| {
        let (mut low, mut high) = (Vec::new(), Vec::new());
        let (mut p, mut i) = (0, 0);
        for s in strips {
            let (sp, si) = write_strip(
                frame,
                s,
                base + p as u32,
                (&mut points[p..], &mut indices[i..]),
                (&mut low, &mut high),
            );
            p += sp;
            i += si;
        }
        debug_assert_eq!((p, i), (points.len(), indices.len()));
    };
    runs.into_par_iter().for_each(write_run);
    for (k, p) in frame.pblocks.iter().enumerate() {
        let base = (np + 4 * k) as u32;
        pblock_points[4 * k..4 * k + 4].copy_from_slice(&pblock_corners(p));
        pblock_indices[6 * k..6 * k + 6].copy_from_slice(&pblock_triangles(base));
    }
    StripMesh {
        triangles: ExtraTriangles { points, indices, heights: Vec::new() },
        strips: frame.strips.len(),
        pblocks: frame.pblocks.len(),
        cpu_time: start.elapsed(),
    }
}

/// [`build_strips_with`] on the calling thread: the output grows strip by strip, each
/// strip's slots zeroed just before it writes them (in the CPU's cache), where the parallel
/// build zeroes its whole buffer first (over the 32769^2 store's `fast_pass`, 1,500 strips a
/// frame, 5-6 MB: that zeroing was two thirds of the parallel build and a fifth of
/// `dss-strips`' selection). The same output as the parallel build.
fn build_strips_serial(frame: &DssStripFrame, start: Instant) -> StripMesh {
    let sizes: Vec<(usize, usize)> = frame.strips.iter().map(|s| strip_size(frame, s)).collect();
    let (np, ni) = sizes.iter().fold((0, 0), |(p, i), &(a, b)| (p + a, i + b));
    let mut points = Vec::with_capacity(np + 4 * frame.pblocks.len());
    let mut indices = Vec::with_capacity(ni + 6 * frame.pblocks.len());
    let (mut low, mut high) = (Vec::new(), Vec::new());
    for (s, &(sp, si)) in frame.strips.iter().zip(&sizes) {
        let (p, i) = (points.len(), indices.len());
        points.resize(p + sp, GpuDomainPoint::default());
        indices.resize(i + si, 0);
        let out = (&mut points[p..], &mut indices[i..]);
        let written = write_strip(frame, s, p as u32, out, (&mut low, &mut high));
        debug_assert_eq!(written, (sp, si));
    }
    for p in &frame.pblocks {
        let base = points.len() as u32;
        points.extend(pblock_corners(p));
        indices.extend(pblock_triangles(base));
    }
    StripMesh {
        triangles: ExtraTriangles { points, indices, heights: Vec::new() },
        strips: frame.strips.len(),
        pblocks: frame.pblocks.len(),
        cpu_time: start.elapsed(),
    }
}

/// A P-block's four vertices: its blocks' inner corners.
fn pblock_corners(p: &PBlock) -> [GpuDomainPoint; 4] {
    p.corners.map(|(b, corner)| GpuDomainPoint {
        uv: corner_uv(corner),
        patch_index: b as u32,
        pad: 0,
    })
}

/// A P-block's two triangles, its first vertex at `base`.
fn pblock_triangles(base: u32) -> [u32; 6] {
    [0, 1, 2, 0, 2, 3].map(|q| base + q)
}

/// The CPU reference of what the renderer draws for `patches` plus `extra`: every patch
/// tessellated by [`tessellate`] (the GPU's reference), every point mapped by
/// [`grid_coords`] in f32 as the vertex stage does and clamped to the grid, the extra
/// triangles' points likewise through their patch; vertices welded by exact grid position;
/// heights bilinear ([`Heightmap::sample_grid`]). Also returns the drawn triangle count
/// (non-degenerate tessellated triangles plus every extra triangle), as the renderer counts.
pub fn build_strip_surface(
    hm: &Heightmap,
    patches: &[DrawPatch],
    extra: &ExtraTriangles,
) -> (SurfaceMesh, u64) {
    let gmax = Vec2::new((hm.width() - 1) as f32, (hm.height() - 1) as f32);
    let mut mesh = SurfaceMesh::default();
    let mut weld: HashMap<(u32, u32), u32> = HashMap::new();
    let mut add = |g: Vec2, mesh: &mut SurfaceMesh| -> u32 {
        let g = g.clamp(Vec2::ZERO, gmax);
        *weld.entry((g.x.to_bits(), g.y.to_bits())).or_insert_with(|| {
            let (x, y) = (f64::from(g.x), f64::from(g.y));
            mesh.positions.push(hm.grid_to_world(x, y).extend(f64::from(hm.sample_grid(x, y))));
            mesh.grid.push(glam::DVec2::new(x, y));
            (mesh.positions.len() - 1) as u32
        })
    };
    let mut count = 0u64;
    for p in patches {
        let m = tessellate(&p.factors);
        count += m.non_degenerate_triangle_count() as u64;
        let ids: Vec<u32> = m.points.iter().map(|&uv| add(grid_coords(p, uv), &mut mesh)).collect();
        mesh.triangles
            .extend(m.indices.chunks_exact(3).map(|c| [c[0], c[1], c[2]].map(|k| ids[k as usize])));
    }
    let ids: Vec<u32> = extra
        .points
        .iter()
        .map(|pt| add(grid_coords(&patches[pt.patch_index as usize], pt.uv), &mut mesh))
        .collect();
    mesh.triangles
        .extend(extra.indices.chunks_exact(3).map(|c| [c[0], c[1], c[2]].map(|k| ids[k as usize])));
    count += (extra.indices.len() / 3) as u64;
    (mesh, count)
}
