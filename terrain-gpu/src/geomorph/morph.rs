//! The CPU reference of the geomorph: where every drawn vertex of a geo-mipmapped patch lies
//! given the patch's level, tween factor and border rules ([`PatchLod`]), the triangles of
//! every (level, adapting borders) configuration, the drawn surface as a [`SurfaceMesh`], and
//! the largest per-vertex height jump between two frames. `geomorph.wgsl` repeats
//! [`MorphGrid::height`] operation for operation (`true_h`, `edge_h`, `point_h`,
//! `morph_h`); change both.
//!
//! # The morph (Wagner 2003, "Geo-morphing" and "Geomorphing in Hardware")
//! Patch at level `l` (vertex step `s = 2^l`) with tween `t`:
//! - A vertex on the `2s` lattice stays at its true height (the article: "vertices on even
//!   positions can stay fixed").
//! - A vertex dropped by level `l + 1` moves from its true height `a` towards the middle `m` of
//!   the two coarser vertices it lies between: `a + t (m - a)`. Cases A (odd x, even y: west and
//!   east), C (even x, odd y: south and north) and B (odd, odd: the coarse quad's diagonal).
//! - Border vertices follow the edge's own level and tween ([`PatchLod::edge_level`],
//!   [`PatchLod::edge_tween`]), along the edge only, so both patches sharing an edge compute
//!   the same heights from the same samples with the same operations: bit-identical.
//!
//! `m` is the mean of the two coarser vertices' *drawn* heights, and those may be border
//! vertices morphing with a neighbour's factor. That is the article's vertex 'A' beside a
//! border: with '1' the border vertex (true height `t1`, coarse `c1`, neighbour factor
//! `tweeningL`) and '2' the interior one (`t2`, fixed), our
//! `a + tweeningI ((h1 + t2) / 2 - a)` with `h1 = t1 + tweeningL (c1 - t1)` expands to
//! `a + tweeningI ((c1 + t2) / 2 - a) + tweeningA (t1 - c1) / 2` with
//! **`tweeningA = (1 - tweeningL) * tweeningI`**, the article's formula for the inner
//! neighbours of border vertices; `a` is the article's `PosBase` and the two brackets its
//! `yMove` values. We evaluate the nested form (fewer inputs than the article's nine
//! precomputed deltas per vertex, and the same numbers on CPU and GPU); the test
//! `tweening_a_is_the_articles_formula` checks the expansion.
//!
//! # Triangles: the union jack, and adapting triangles
//! The article splits every quad along one diagonal and adds "adapting triangles" on the
//! finer side of a border. With one diagonal everywhere the adapting triangles cannot match
//! the plain ones when the odd border vertex sits at its edge's midpoint, so a neighbour's
//! level change would pop (a gap in the article). The standard fix is the union-jack (4-8)
//! triangulation (Lindstrom et al. 1996; Pajarola 1998): quad `(a, b)` of a level splits
//! south-west to north-east when `a + b` is even, else the other way. Its levels nest (each
//! coarse triangle is a union of finer ones, so at `t = 1` a level *is* the next one), and
//! along every border each pair of quads is a fan around the inner vertex: leaving out the odd
//! border vertex merges that fan's two border triangles into one adapting triangle, the same
//! surface when the vertex sits at its edge's midpoint. Case B morphs along the coarse quad's
//! own diagonal accordingly. Level selection measures errors on the same triangulation
//! (`terrain_core::metrics::geomorph::Triangulation::UnionJack`).

use std::collections::HashMap;

use bytemuck::{Pod, Zeroable};
use glam::{DVec2, DVec3};
use terrain_core::lod::{PatchLod, SurfaceMesh};
use terrain_core::measure::TriangleGrid;

use crate::paged::HeightGrid;

/// Edge indices in `terrain_core::lod::Edge` order.
const SOUTH: usize = 0;
const EAST: usize = 1;
const NORTH: usize = 2;
const WEST: usize = 3;

/// Set on a mesh id for the lower vertex of a skirt (local ids are below `65^2 < 2^13`).
pub const SKIRT_BIT: u32 = 1 << 13;

/// A drawn index is `patch << PATCH_SHIFT | id` (up to `2^18` single patches per frame; the
/// patches of runs are instances, not in the index, see `GeomorphRenderer::render_runs`).
pub const PATCH_SHIFT: u32 = 14;

/// `GmPatch` in `geomorph.wgsl`: one drawn patch.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuMorphPatch {
    /// Grid sample of the patch's south-west corner.
    pub origin: [u32; 2],
    /// Level drawn.
    pub level: u32,
    /// Tween factor towards `level + 1`.
    pub tween: f32,
    /// Per edge (south, east, north, west): its level.
    pub edge_level: [u32; 4],
    /// Per edge: its tween factor.
    pub edge_tween: [f32; 4],
}

const _: () = assert!(size_of::<GpuMorphPatch>() == 48);

impl GpuMorphPatch {
    /// The GPU form of a selected patch.
    pub fn from_lod(p: &PatchLod, patch_cells: u32) -> Self {
        Self {
            origin: [p.i * patch_cells, p.j * patch_cells],
            level: u32::from(p.level),
            tween: p.tween,
            edge_level: p.edge_level.map(u32::from),
            edge_tween: p.edge_tween,
        }
    }

    /// Bit `k` set when edge `k` is drawn coarser than the patch (adapting triangles).
    pub fn adapt_mask(&self) -> u32 {
        (0..4).filter(|&k| self.edge_level[k] > self.level).map(|k| 1 << k).sum()
    }
}

/// The morph over one grid of heights with patches of `patch_cells` cells: a whole
/// `Heightmap`, or the pages a paged renderer holds ([`crate::paged::PagedHeights`], the CPU
/// mirror of its atlas: a store's blocks at their resident levels), read through the same
/// [`HeightGrid::sample`] as the shader's `height_sample` (a sample on no resident page reads
/// 0, as on the GPU).
#[derive(Clone, Copy)]
pub struct MorphGrid<'a> {
    hm: &'a dyn HeightGrid,
    size: [u32; 2],
    patch_cells: u32,
    max_level: u32,
}

impl std::fmt::Debug for MorphGrid<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MorphGrid")
            .field("size", &self.size)
            .field("patch_cells", &self.patch_cells)
            .finish_non_exhaustive()
    }
}

impl<'a> MorphGrid<'a> {
    /// `patch_cells` must be a power of two.
    pub fn new(hm: &'a dyn HeightGrid, patch_cells: u32) -> Self {
        assert!(patch_cells.is_power_of_two() && patch_cells >= 2);
        Self { hm, size: hm.size(), patch_cells, max_level: patch_cells.trailing_zeros() }
    }

    /// Cells per patch side.
    pub fn patch_cells(&self) -> u32 {
        self.patch_cells
    }

    /// Grid sample of local lattice point `(x, y)` of `p`, clamped to the grid.
    pub fn sample_of(&self, p: &GpuMorphPatch, x: u32, y: u32) -> (u32, u32) {
        let gi = (p.origin[0] + x).min(self.size[0] - 1);
        let gj = (p.origin[1] + y).min(self.size[1] - 1);
        (gi, gj)
    }

    /// `true_h`: the sample's height (0 on no resident page, as `height_sample` reads it).
    fn true_h(&self, p: &GpuMorphPatch, x: u32, y: u32) -> f32 {
        let (i, j) = self.sample_of(p, x, y);
        self.hm.sample(i, j).unwrap_or(0.0)
    }

    /// `edge_h`: a border vertex, morphing along its edge with the edge's level and tween.
    fn edge_h(&self, p: &GpuMorphPatch, edge: usize, x: u32, y: u32) -> f32 {
        let n = self.patch_cells;
        let t = if edge == SOUTH || edge == NORTH { x } else { y };
        let s = 1u32 << p.edge_level[edge];
        let a = self.true_h(p, x, y);
        if t == 0 || t == n || t % (2 * s) == 0 || t % s != 0 {
            return a;
        }
        let (b, c) = if edge == SOUTH || edge == NORTH {
            (self.true_h(p, x - s, y), self.true_h(p, x + s, y))
        } else {
            (self.true_h(p, x, y - s), self.true_h(p, x, y + s))
        };
        let m = 0.5 * (b + c);
        a + p.edge_tween[edge] * (m - a)
    }

    /// `point_h`: a lattice point's drawn height when it does not morph with the patch's own
    /// factor: border vertices follow their edge, interior ones stay true.
    fn point_h(&self, p: &GpuMorphPatch, x: u32, y: u32) -> f32 {
        let n = self.patch_cells;
        if (x == 0 || x == n) && (y == 0 || y == n) {
            return self.true_h(p, x, y);
        }
        if y == 0 {
            return self.edge_h(p, SOUTH, x, y);
        }
        if x == n {
            return self.edge_h(p, EAST, x, y);
        }
        if y == n {
            return self.edge_h(p, NORTH, x, y);
        }
        if x == 0 {
            return self.edge_h(p, WEST, x, y);
        }
        self.true_h(p, x, y)
    }

    /// `morph_h`: the drawn height of local lattice point `(x, y)` (a vertex of the patch's
    /// level, `0..=patch_cells`), metres.
    pub fn height(&self, p: &GpuMorphPatch, x: u32, y: u32) -> f32 {
        let n = self.patch_cells;
        if x == 0 || x == n || y == 0 || y == n || p.level >= self.max_level {
            return self.point_h(p, x, y);
        }
        let s = 1u32 << p.level;
        let xo = (x / s) % 2 == 1;
        let yo = (y / s) % 2 == 1;
        if !xo && !yo {
            return self.true_h(p, x, y);
        }
        let (e1, e2) = if xo && !yo {
            ((x - s, y), (x + s, y)) // case A
        } else if !xo && yo {
            ((x, y - s), (x, y + s)) // case C
        } else if ((x - s) / (2 * s) + (y - s) / (2 * s)).is_multiple_of(2) {
            ((x - s, y - s), (x + s, y + s)) // case B, coarse quad split SW-NE
        } else {
            ((x + s, y - s), (x - s, y + s)) // case B, coarse quad split SE-NW
        };
        let a = self.true_h(p, x, y);
        let m = 0.5 * (self.point_h(p, e1.0, e1.1) + self.point_h(p, e2.0, e2.1));
        a + p.tween * (m - a)
    }

    /// Every lattice point's [`MorphGrid::height`] of every patch, `(patch_cells + 1)^2` per
    /// patch in local-id order (`y (patch_cells + 1) + x`), patches in order: the article's
    /// "software morphing" (the CPU morphs, the renderer uploads the result every frame,
    /// `MorphSource::Cpu`). Points a patch's level does not draw are computed too (the
    /// article's CPU path also sends every vertex); `out` is cleared first and reused.
    pub fn patch_heights(&self, patches: &[GpuMorphPatch], out: &mut Vec<f32>) {
        let n1 = self.patch_cells + 1;
        out.clear();
        out.reserve(patches.len() * (n1 * n1) as usize);
        for p in patches {
            for y in 0..n1 {
                out.extend((0..n1).map(|x| self.height(p, x, y)));
            }
        }
    }

    /// World position (f64, metres) of local point `(x, y)` of `p`: the sample's plan position
    /// and [`MorphGrid::height`].
    pub fn world_position(&self, p: &GpuMorphPatch, x: u32, y: u32) -> DVec3 {
        let (i, j) = self.sample_of(p, x, y);
        let (origin, spacing) = self.hm.frame();
        let plan = origin + DVec2::new(f64::from(i), f64::from(j)) * spacing;
        plan.extend(f64::from(self.height(p, x, y)))
    }

    /// What the vertex stage computes for local point `(x, y)` of `p` with camera-relative
    /// positions about `anchor`: `[x, y, z]` relative to the anchor (the columns' and rows'
    /// f64 offsets rounded once to f32, as the renderer uploads them) and the absolute morphed
    /// height.
    pub fn relative_position(&self, p: &GpuMorphPatch, x: u32, y: u32, anchor: DVec3) -> [f32; 4] {
        let (i, j) = self.sample_of(p, x, y);
        let (origin, spacing) = self.hm.frame();
        let cx = (origin.x + f64::from(i) * spacing.x - anchor.x) as f32;
        let cy = (origin.y + f64::from(j) * spacing.y - anchor.y) as f32;
        let h = self.height(p, x, y);
        [cx, cy, h + (-anchor.z) as f32, h]
    }
}

/// Local id of lattice point `(x, y)` in a patch of `n` cells.
fn id(n: u32, x: u32, y: u32) -> u32 {
    y * (n + 1) + x
}

/// The triangles of a patch of `n` cells at `level` whose edges in `adapt` (bit `k` = edge `k`,
/// south, east, north, west) leave out their odd border vertices: local ids, anti-clockwise
/// seen from above.
pub fn triangulate(n: u32, level: u32, adapt: u32) -> Vec<[u32; 3]> {
    let s = 1u32 << level;
    let q = n / s;
    let mut tris: Vec<[u32; 3]> = Vec::with_capacity((2 * q * q) as usize);
    for b in 0..q {
        for a in 0..q {
            let (x0, y0, x1, y1) = (a * s, b * s, a * s + s, b * s + s);
            let (sw, se, ne, nw) = (id(n, x0, y0), id(n, x1, y0), id(n, x1, y1), id(n, x0, y1));
            if (a + b) % 2 == 0 {
                tris.push([sw, se, ne]);
                tris.push([sw, ne, nw]);
            } else {
                tris.push([sw, se, nw]);
                tris.push([se, ne, nw]);
            }
        }
    }
    if q < 2 {
        return tris;
    }
    // Adapting triangles: each left-out vertex v lies in exactly two triangles, (p, c, v) and
    // (v, w, c) with c the inner fan centre; replace v by w in the first, drop the second.
    for edge in 0..4 {
        if adapt & (1 << edge) == 0 {
            continue;
        }
        for k in (1..q).step_by(2) {
            let t = k * s;
            let (v, w_options) = match edge {
                SOUTH => (id(n, t, 0), [id(n, t - s, 0), id(n, t + s, 0)]),
                EAST => (id(n, n, t), [id(n, n, t - s), id(n, n, t + s)]),
                NORTH => (id(n, t, n), [id(n, t - s, n), id(n, t + s, n)]),
                _ => (id(n, 0, t), [id(n, 0, t - s), id(n, 0, t + s)]),
            };
            let with_v: Vec<usize> = (0..tris.len()).filter(|&i| tris[i].contains(&v)).collect();
            debug_assert_eq!(with_v.len(), 2);
            let (first, second) = (with_v[0], with_v[1]);
            let w = *w_options.iter().find(|w| tris[second].contains(w)).expect("a fan");
            for c in tris[first].iter_mut() {
                if *c == v {
                    *c = w;
                }
            }
            tris.remove(second);
        }
    }
    tris
}

/// Every configuration's triangles and skirts in one id list (what the GPU's mesh buffer
/// holds): configuration `level * 16 + adapt`.
#[derive(Debug, Clone)]
pub struct MeshLibrary {
    /// Cells per patch side.
    pub patch_cells: u32,
    /// Local ids (with [`SKIRT_BIT`] on skirts' lower vertices), three per triangle.
    pub ids: Vec<u32>,
    /// Per configuration: `(first id, id count)` of its triangles.
    pub ranges: Vec<(u32, u32)>,
    /// Per configuration, per edge: `(first id, id count)` of the skirt hanging below it.
    pub skirts: Vec<[(u32, u32); 4]>,
}

impl MeshLibrary {
    /// The library of patches of `patch_cells` cells (a power of two).
    pub fn new(patch_cells: u32) -> Self {
        let n = patch_cells;
        let levels = n.trailing_zeros() + 1;
        let mut ids = Vec::new();
        let mut ranges = Vec::new();
        let mut skirts = Vec::new();
        for level in 0..levels {
            for adapt in 0..16u32 {
                let adapt = if level + 1 < levels { adapt } else { 0 };
                let start = ids.len() as u32;
                for t in triangulate(n, level, adapt) {
                    ids.extend_from_slice(&t);
                }
                ranges.push((start, ids.len() as u32 - start));
                let mut per_edge = [(0, 0); 4];
                for (edge, slot) in per_edge.iter_mut().enumerate() {
                    let step = 1u32 << (level + (adapt >> edge & 1));
                    let start = ids.len() as u32;
                    let at = |t: u32| match edge {
                        SOUTH => id(n, t, 0),
                        EAST => id(n, n, t),
                        NORTH => id(n, t, n),
                        _ => id(n, 0, t),
                    };
                    let mut t = 0;
                    while t < n {
                        let (a, b) = (at(t), at(t + step));
                        ids.extend_from_slice(&[
                            a,
                            b,
                            a | SKIRT_BIT,
                            b,
                            b | SKIRT_BIT,
                            a | SKIRT_BIT,
                        ]);
                        t += step;
                    }
                    *slot = (start, ids.len() as u32 - start);
                }
                skirts.push(per_edge);
            }
        }
        Self { patch_cells, ids, ranges, skirts }
    }

    /// The configuration index of `p`.
    pub fn config(p: &GpuMorphPatch) -> usize {
        (p.level * 16 + p.adapt_mask()) as usize
    }

    /// The triangles (local ids) of `p`'s configuration.
    pub fn triangles(&self, p: &GpuMorphPatch) -> &[u32] {
        let (start, count) = self.ranges[Self::config(p)];
        &self.ids[start as usize..(start + count) as usize]
    }
}

/// The drawn (morphed) surface of `patches`, welded by grid sample, and its number of
/// triangles of non-zero plan area: what the GPU draws, for measurement and crack checks.
pub fn build_surface(
    grid: &MorphGrid<'_>,
    lib: &MeshLibrary,
    patches: &[GpuMorphPatch],
) -> (SurfaceMesh, u64) {
    let n = grid.patch_cells;
    let mut mesh = SurfaceMesh::default();
    let mut weld: HashMap<(u32, u32), u32> = HashMap::new();
    let mut live = 0u64;
    for p in patches {
        let mut local: HashMap<u32, u32> = HashMap::new();
        for tri in lib.triangles(p).chunks_exact(3) {
            let t: [u32; 3] = [tri[0], tri[1], tri[2]].map(|lid| {
                *local.entry(lid).or_insert_with(|| {
                    let (x, y) = (lid % (n + 1), lid / (n + 1));
                    let key = grid.sample_of(p, x, y);
                    *weld.entry(key).or_insert_with(|| {
                        mesh.positions.push(grid.world_position(p, x, y));
                        mesh.grid.push(DVec2::new(f64::from(key.0), f64::from(key.1)));
                        (mesh.positions.len() - 1) as u32
                    })
                })
            });
            let [a, b, c] = t.map(|k| mesh.grid[k as usize]);
            if (b - a).perp_dot(c - a) != 0.0 {
                live += 1;
            }
            mesh.triangles.push(t);
        }
    }
    (mesh, live)
}

/// The largest change of the drawn height between two frames' surfaces, metres, over every
/// vertex of either frame that both surfaces cover (vertices appearing or disappearing are
/// compared with the other frame's surface there, so a vertex popping in counts). Both
/// surfaces' vertices lie on the grid's samples and levels nest, so this is the largest change
/// anywhere on the surface.
pub fn max_vertex_jump(prev: &SurfaceMesh, next: &SurfaceMesh) -> f64 {
    let (gp, gn) = (TriangleGrid::new(prev), TriangleGrid::new(next));
    let mut worst: f64 = 0.0;
    for (mesh, other) in [(next, &gp), (prev, &gn)] {
        for (g, p) in mesh.grid.iter().zip(&mesh.positions) {
            if let Some(z) = other.height_at(*g) {
                worst = worst.max((z - p.z).abs());
            }
        }
    }
    worst
}

#[cfg(test)]
mod tests {
    use super::*;
    use terrain_core::{Georef, Heightmap};

    fn patch(level: u32, tween: f32, edge_level: [u32; 4], edge_tween: [f32; 4]) -> GpuMorphPatch {
        GpuMorphPatch { origin: [0, 0], level, tween, edge_level, edge_tween }
    }

    fn bumpy() -> Heightmap {
        Heightmap::from_fn(17, 17, Georef::local(1.0), |i, j| {
            ((i * 7 + j * 13) % 11) as f32 + 0.25 * (i * j % 5) as f32
        })
        .unwrap()
    }

    #[test]
    fn tweening_a_is_the_articles_formula() {
        // Level 2 (step 4), the west edge drawn at level 3 (step 8) following its coarser
        // neighbour's factor tL; vertex 'A' at (4, 8) lies between border vertex '1' = (0, 8)
        // and interior vertex '2' = (8, 8).
        let hm = bumpy();
        let g = MorphGrid::new(&hm, 16);
        let (t_l, t_i) = (0.3f32, 0.6f32);
        let p = patch(2, t_i, [2, 2, 2, 3], [t_i, t_i, t_i, t_l]);
        let h = |i: usize, j: usize| f64::from(hm.get(i, j));
        let a = h(4, 8);
        let t1 = h(0, 8);
        let c1 = 0.5 * (h(0, 0) + h(0, 16)); // '1' on its neighbour's level-4 edge
        let t2 = h(8, 8);
        let (tl, ti) = (f64::from(t_l), f64::from(t_i));
        let tweening_a = (1.0 - tl) * ti;
        let article = a + ti * ((c1 + t2) / 2.0 - a) + tweening_a * (t1 - c1) / 2.0;
        let ours = f64::from(g.height(&p, 4, 8));
        assert!((ours - article).abs() < 1e-4, "{ours} vs {article}");
        // And '1' itself follows the neighbour's factor.
        let one = f64::from(g.height(&p, 0, 8));
        assert!((one - (t1 + tl * (c1 - t1))).abs() < 1e-4);
    }

    #[test]
    fn tween_one_is_the_next_level_and_adapting_triangles_cover_the_patch() {
        let hm = bumpy();
        let g = MorphGrid::new(&hm, 16);
        for level in 0..4 {
            for adapt in 0..16 {
                let tris = triangulate(16, level, adapt);
                // Plan area: the whole patch, every triangle anti-clockwise.
                let area: i64 = tris
                    .iter()
                    .map(|t| {
                        let [a, b, c] = t.map(|k| ((k % 17) as i64, (k / 17) as i64));
                        let cr = (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0);
                        assert!(cr > 0, "level {level} adapt {adapt}: {t:?}");
                        cr
                    })
                    .sum();
                assert_eq!(area, 2 * 256);
            }
            // At tween 1 every vertex of level L lies on level L + 1's surface.
            let fine = patch(level, 1.0, [level; 4], [1.0; 4]);
            let coarse = patch(level + 1, 0.0, [level + 1; 4], [0.0; 4]);
            let lib = MeshLibrary::new(16);
            let (a, _) = build_surface(&g, &lib, &[fine]);
            let (b, _) = build_surface(&g, &lib, &[coarse]);
            assert!(max_vertex_jump(&a, &b) < 1e-4, "level {level}");
        }
    }
}
