//! Geo-mipmapping with geomorphing (Wagner 2003, "Terrain Geomorphing in the Vertex Shader"):
//! the CPU side. Which level each patch of `patch_cells + 1` squared samples is drawn at, with
//! which tween factor, and what its four borders follow; terrain-gpu's `geomorph` module
//! morphs and draws.
//!
//! **Patches.** Patch `(pi, pj)` covers samples `pi * P ..= pi * P + P` by `pj * P ..= pj * P +
//! P` (`P` = [`GeomipConfig::patch_cells`], 16 in the article: 17 x 17 vertices), overlapping its
//! neighbours by one sample ("value column 16 is shared by patch 0/0 and patch 1/0"). Level `L`
//! keeps every `2^L`-th vertex (5 levels for 16 cells: full geometry down to one quad). A lattice
//! position past the grid's east or north border is clamped onto it (the last patches of a grid
//! that `P` does not divide collapse there), like `lod::surface::patch_grid_point`.
//!
//! **Level choice (article, "Calculating the Tessellation Level of a Patch").** Per level, the
//! max-error vertex ([`crate::metrics::geomorph`], measured against the full-resolution
//! vertices as the article says, on the union-jack triangulation the renderer draws) is
//! projected: `a_L = lambda * delta_L / (tau * d_L)`, its screen error in units of the pixel
//! threshold `tau`, with `d_L` the eye's distance to that vertex. The article picks "the level
//! with the largest error below an application defined error bound" and, for geomorphing,
//! "a tessellation factor in form of a floating point value where the integer part means the
//! current level and the fractional part denotes the tweening factor", without saying how the
//! fraction is computed (a gap). We use the standard continuous choice: each level contributes
//! `w_L = clamp(2 - 2 a_L, 0, 1)` (fully present while its error is at most `tau / 2`, fading
//! out as it approaches `tau`), made monotone (`w_L <= w_{L-1}`), and the factor is
//! `c = sum w_L`. So the integer part `l` is a level whose error is at most `tau / 2`, the
//! fraction morphs towards level `l + 1` only while that level's own error is below `tau`, and
//! `c` is a continuous (Lipschitz) function of the eye: with a small camera step no vertex
//! moves far (the continuity test measures it).
//!
//! **Neighbours differ by at most one level** (the article's borders handle only that): the
//! factors are replaced by their lower envelope `c'_p = min_q (c_q + |p - q|_1)` over patches
//! (an exact two-pass distance transform), which is 1-Lipschitz across neighbours, still
//! continuous, and only ever finer than asked.
//!
//! **Cost follows the view.** The visible patches come from the one quadtree traversal
//! ([`crate::quadtree::traverse`], [`FrustumCull`] over a [`Quadtree`] whose leaves are the
//! patches: a rejected or wholly visible node decides its whole subtree). Since `c <= L` (`L`
//! = the coarsest level) and a source `q` can only lower `c'_p` when `|p - q|_1 < c_p <= L`,
//! the envelope of the drawn patches and their neighbours needs only the factors of patches
//! within `L` of a visible one: the factors and the two passes run over that window
//! (per-row spans, a dense index), so a frame costs `O(visible patches x L)`, not the grid.
//! The two-pass city-block transform (Rosenfeld & Pfaltz 1966, "Sequential operations in
//! digital picture processing"; for sampled functions, Felzenszwalb & Huttenlocher 2012) is
//! exact on the window because it holds every L-shaped path from such a source to `p`. Every
//! value is `c_q` plus `|p - q|_1` additions of `1.0` in `f32`, whatever the order, so the
//! output is bit-identical to the whole-grid transform (the tests keep it as a reference).
//!
//! **Borders.** Each shared edge is drawn at the coarser patch's level, and its vertices follow
//! the coarser patch's tween factor ("the finer patch allows the coarser one to dictate the
//! border vertices' position"); between two patches at the same level, the larger of the two
//! factors (a symmetric choice the article leaves open: both sides must compute the same). The
//! finer patch then leaves out its odd border vertices and draws adapting triangles there.
//! [`PatchLod::edge_level`] and [`PatchLod::edge_tween`] carry this per edge; edges on the
//! grid's border follow the patch itself.

use std::time::Instant;

use glam::DVec3;

use super::patch::Edge;
use super::window::RowWindow;
use crate::geometry::Camera;
use crate::heightmap::Heightmap;
use crate::metrics::Region;
use crate::metrics::geomorph::{Reference, Triangulation, max_error_vertices_with};
use crate::quadtree::{AlwaysSplit, FrustumCull, NoCull, Quadtree, select};

/// Settings of the geo-mipmapping selection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GeomipConfig {
    /// Cells per patch side, a power of two from 2 to 64. Default 16 (the article's 17 x 17
    /// vertices and 5 levels).
    pub patch_cells: u32,
    /// The error bound `tau` in pixels: the projected max-error vertex of the drawn level stays
    /// below it. Default 1.
    pub pixel_threshold: f64,
    /// Geomorphing on (continuous tween factors) or off (integer levels: the popping
    /// baseline). Default on.
    pub morph: bool,
    /// Skip patches whose box is outside the view frustum. Default on.
    pub frustum_cull: bool,
}

impl Default for GeomipConfig {
    fn default() -> Self {
        Self { patch_cells: 16, pixel_threshold: 1.0, morph: true, frustum_cull: true }
    }
}

/// Per-patch precomputation: the max-error vertex of every level, and the quadtree whose
/// leaves are the patches (their boxes, for hierarchical frustum culling).
#[derive(Debug, Clone)]
pub struct GeomipScene {
    patch_cells: u32,
    levels: usize,
    nx: u32,
    ny: u32,
    /// Per patch (row-major, south first), per level (`levels` entries per patch, one
    /// contiguous array): monotone error (m) and the world position of the max-error vertex.
    errors: Vec<(f64, DVec3)>,
    /// Leaves of `patch_cells` cells: leaf `(i, j)` is patch `(i, j)`, its box the patch's
    /// samples' (min/max pyramid above).
    qt: Quadtree,
}

/// One patch as drawn this frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PatchLod {
    /// Patch column (east).
    pub i: u32,
    /// Patch row (north).
    pub j: u32,
    /// Level drawn (0 = every vertex).
    pub level: u8,
    /// Tween factor towards `level + 1`: 0 draws the level's true heights, 1 puts every vertex
    /// that level `level + 1` drops on the coarser surface. 0 at the coarsest level.
    pub tween: f32,
    /// Per edge ([`Edge`] order: south, east, north, west): the level the edge is drawn at
    /// (`level` or `level + 1`; the latter means the finer patch adapts to its coarser
    /// neighbour and leaves out its odd border vertices).
    pub edge_level: [u8; 4],
    /// Per edge: the tween factor its vertices follow.
    pub edge_tween: [f32; 4],
}

impl PatchLod {
    /// Bit `k` set when edge `k` ([`Edge`] order) leaves out its odd border vertices.
    pub fn adapt_mask(&self) -> u32 {
        (0..4).filter(|&k| self.edge_level[k] > self.level).map(|k| 1 << k).sum()
    }
}

/// The selection of one frame.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct GeomipSelection {
    /// Patches to draw (not culled), row-major, south first.
    pub patches: Vec<PatchLod>,
    /// The continuous factor `c'` of each drawn patch (parallel to `patches`; culled patches
    /// are not computed: the selection's cost follows the view).
    pub factors: Vec<f32>,
    /// Patches culled by the frustum.
    pub culled: usize,
    /// CPU time of the selection, milliseconds.
    pub cpu_ms: f64,
}

impl GeomipScene {
    /// Precomputes the max-error vertices of every patch of `hm`. `patch_cells` is rounded to
    /// a power of two in `2..=64`.
    pub fn new(hm: &Heightmap, patch_cells: u32) -> Self {
        let p = patch_cells.clamp(2, 64).next_power_of_two().min(64);
        let levels = p.trailing_zeros() as usize + 1;
        let (w, h) = (hm.width() as u32, hm.height() as u32);
        let nx = (w.saturating_sub(1)).div_ceil(p).max(1);
        let ny = (h.saturating_sub(1)).div_ceil(p).max(1);
        let mut errors = Vec::with_capacity((nx * ny) as usize * levels);
        for pj in 0..ny {
            for pi in 0..nx {
                let (x0, y0) = ((pi * p) as usize, (pj * p) as usize);
                let lv = max_error_vertices_with(
                    hm,
                    Region::new(x0, y0, p as usize),
                    Reference::FullResolution,
                    Triangulation::UnionJack,
                );
                let origin = hm.grid_to_world(x0 as f64, y0 as f64).extend(0.0);
                let mut running: f64 = 0.0;
                for l in 0..levels {
                    let (e, pos) = match lv.get(l).and_then(|e| e.vertex.map(|v| (e.error, v))) {
                        Some((e, vx)) => (e, origin + vx.offset),
                        None => (0.0, origin),
                    };
                    running = running.max(e);
                    errors.push((running, pos));
                }
            }
        }
        let qt = Quadtree::new(hm, p);
        debug_assert_eq!(qt.leaf_cells(), p);
        Self { patch_cells: p, levels, nx, ny, errors, qt }
    }

    /// Cells per patch side (a power of two).
    pub fn patch_cells(&self) -> u32 {
        self.patch_cells
    }

    /// Levels per patch (`log2(patch_cells) + 1`).
    pub fn levels(&self) -> usize {
        self.levels
    }

    /// Patches along x and y.
    pub fn patch_counts(&self) -> (u32, u32) {
        (self.nx, self.ny)
    }

    /// The monotone max error (metres) of `level` of patch `(i, j)`.
    pub fn level_error(&self, i: u32, j: u32, level: usize) -> f64 {
        self.errors[(j * self.nx + i) as usize * self.levels + level].0
    }

    /// The continuous factor of one patch before the neighbour envelope (see the module docs),
    /// for an eye at `eye` with `lambda = camera.lambda()`.
    fn factor(&self, k: usize, eye: DVec3, lambda: f64, tau: f64) -> f32 {
        let mut c = 0.0;
        let mut prev = 1.0f64;
        for &(delta, pos) in &self.errors[k * self.levels + 1..(k + 1) * self.levels] {
            let a = if delta <= 0.0 {
                0.0
            } else {
                let d = (pos - eye).length();
                if d <= 1e-9 { f64::INFINITY } else { lambda * delta / (tau * d) }
            };
            let w = (2.0 - 2.0 * a).clamp(0.0, 1.0).min(prev);
            prev = w;
            c += w;
        }
        c as f32
    }

    /// Levels, tween factors and border rules for `camera` (see the module docs).
    pub fn select(&self, camera: &Camera, cfg: &GeomipConfig) -> GeomipSelection {
        let start = Instant::now();
        let tau = cfg.pixel_threshold.max(1e-9);
        let (nx, ny) = (self.nx as usize, self.ny as usize);
        // The patches in view: the quadtree's leaves the frustum keeps, depth-first.
        let visible = if cfg.frustum_cull {
            select(&self.qt, &mut AlwaysSplit, &mut FrustumCull::new(camera.frustum()))
        } else {
            select(&self.qt, &mut AlwaysSplit, &mut NoCull)
        };
        let cells = visible.iter().map(|n| (n.i as usize, n.j as usize));
        // Every patch within `L` of a visible one (see the module docs), densely indexed.
        let max_level = self.levels - 1;
        let win = RowWindow::dilated(cells.clone(), max_level, nx, ny);
        let mut c = vec![0.0f32; win.len()];
        let (eye, lambda) = (camera.position, camera.lambda());
        for (j, lo, hi, off) in win.rows() {
            for i in lo..=hi {
                c[off + i - lo] = self.factor(j * nx + i, eye, lambda, tau);
            }
        }
        // Lower envelope c'_p = min_q (c_q + |p - q|_1): forward then backward pass.
        for (j, lo, hi, off) in win.rows() {
            for i in lo..=hi {
                let k = off + i - lo;
                if i > lo {
                    c[k] = c[k].min(c[k - 1] + 1.0);
                }
                if let Some(b) = j.checked_sub(1).and_then(|jb| win.index(i, jb)) {
                    c[k] = c[k].min(c[b] + 1.0);
                }
            }
        }
        for (j, lo, hi, off) in win.rows().rev() {
            for i in (lo..=hi).rev() {
                let k = off + i - lo;
                if i < hi {
                    c[k] = c[k].min(c[k + 1] + 1.0);
                }
                if let Some(a) = win.index(i, j + 1) {
                    c[k] = c[k].min(c[a] + 1.0);
                }
            }
        }
        let max_level = max_level as f32;
        let level_tween = |k: usize| -> (u8, f32) {
            let ck = c[k].clamp(0.0, max_level);
            let l = ck.floor();
            let t = if cfg.morph && l < max_level { ck - l } else { 0.0 };
            (l as u8, t)
        };
        // Row-major output: mark the visible patches in the window, then walk it in order.
        let mut shown = vec![false; win.len()];
        for (i, j) in cells {
            if let Some(k) = win.index(i, j) {
                shown[k] = true;
            }
        }
        let mut patches = Vec::with_capacity(visible.len());
        let mut factors = Vec::with_capacity(visible.len());
        for (j, lo, hi, off) in win.rows() {
            for i in lo..=hi {
                let k = off + i - lo;
                if !shown[k] {
                    continue;
                }
                let (level, tween) = level_tween(k);
                let mut edge_level = [level; 4];
                let mut edge_tween = [tween; 4];
                for e in Edge::ALL {
                    let (di, dj) = e.direction().step();
                    let (qi, qj) = (i as i64 + di, j as i64 + dj);
                    if qi < 0 || qj < 0 || qi >= nx as i64 || qj >= ny as i64 {
                        continue;
                    }
                    let q =
                        win.index(qi as usize, qj as usize).expect("neighbours are in the window");
                    let (ql, qt) = level_tween(q);
                    let k = e as usize;
                    edge_level[k] = level.max(ql);
                    edge_tween[k] = match ql.cmp(&level) {
                        std::cmp::Ordering::Greater => qt,
                        std::cmp::Ordering::Less => tween,
                        std::cmp::Ordering::Equal => tween.max(qt),
                    };
                }
                patches.push(PatchLod {
                    i: i as u32,
                    j: j as u32,
                    level,
                    tween,
                    edge_level,
                    edge_tween,
                });
                factors.push(c[k]);
            }
        }
        let culled = if cfg.frustum_cull { nx * ny - patches.len() } else { 0 };
        GeomipSelection { patches, factors, culled, cpu_ms: start.elapsed().as_secs_f64() * 1e3 }
    }
}

/// The whole-grid selection this module replaced (every patch's factor, the envelope over the
/// whole grid, each patch's own box against the frustum), kept as the reference the fast one
/// must equal bit for bit.
#[cfg(test)]
mod reference {
    use super::*;
    use crate::geometry::{Aabb, Classification};

    /// Each patch's box, computed from the samples as before.
    pub(super) fn boxes(scene: &GeomipScene, hm: &Heightmap) -> Vec<Aabb> {
        let p = scene.patch_cells as usize;
        let mut boxes = Vec::new();
        for pj in 0..scene.ny as usize {
            for pi in 0..scene.nx as usize {
                let (x0, y0) = (pi * p, pj * p);
                let (x1, y1) = ((x0 + p).min(hm.width() - 1), (y0 + p).min(hm.height() - 1));
                let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
                for j in y0..=y1 {
                    for i in x0..=x1 {
                        let z = hm.get(i, j);
                        lo = lo.min(z);
                        hi = hi.max(z);
                    }
                }
                let a = hm.grid_to_world(x0 as f64, y0 as f64);
                let b = hm.grid_to_world(x1 as f64, y1 as f64);
                boxes.push(Aabb::new(a.extend(f64::from(lo)), b.extend(f64::from(hi))));
            }
        }
        boxes
    }

    /// The former `GeomipScene::select`; `factors` holds every patch's `c'` (row-major).
    pub(super) fn select_reference(
        scene: &GeomipScene,
        boxes: &[Aabb],
        camera: &Camera,
        cfg: &GeomipConfig,
    ) -> GeomipSelection {
        let tau = cfg.pixel_threshold.max(1e-9);
        let (nx, ny) = (scene.nx as usize, scene.ny as usize);
        let (eye, lambda) = (camera.position, camera.lambda());
        let mut c: Vec<f32> = (0..nx * ny).map(|k| scene.factor(k, eye, lambda, tau)).collect();
        for j in 0..ny {
            for i in 0..nx {
                let k = j * nx + i;
                if i > 0 {
                    c[k] = c[k].min(c[k - 1] + 1.0);
                }
                if j > 0 {
                    c[k] = c[k].min(c[k - nx] + 1.0);
                }
            }
        }
        for j in (0..ny).rev() {
            for i in (0..nx).rev() {
                let k = j * nx + i;
                if i + 1 < nx {
                    c[k] = c[k].min(c[k + 1] + 1.0);
                }
                if j + 1 < ny {
                    c[k] = c[k].min(c[k + nx] + 1.0);
                }
            }
        }
        let max_level = (scene.levels - 1) as f32;
        let level_tween = |k: usize| -> (u8, f32) {
            let ck = c[k].clamp(0.0, max_level);
            let l = ck.floor();
            let t = if cfg.morph && l < max_level { ck - l } else { 0.0 };
            (l as u8, t)
        };
        let frustum = camera.frustum();
        let mut patches = Vec::new();
        let mut culled = 0;
        for j in 0..ny {
            for i in 0..nx {
                let k = j * nx + i;
                if cfg.frustum_cull && frustum.classify(&boxes[k]) == Classification::Outside {
                    culled += 1;
                    continue;
                }
                let (level, tween) = level_tween(k);
                let mut edge_level = [level; 4];
                let mut edge_tween = [tween; 4];
                for e in Edge::ALL {
                    let (di, dj) = e.direction().step();
                    let (qi, qj) = (i as i64 + di, j as i64 + dj);
                    if qi < 0 || qj < 0 || qi >= nx as i64 || qj >= ny as i64 {
                        continue;
                    }
                    let (ql, qt) = level_tween(qj as usize * nx + qi as usize);
                    let k = e as usize;
                    edge_level[k] = level.max(ql);
                    edge_tween[k] = match ql.cmp(&level) {
                        std::cmp::Ordering::Greater => qt,
                        std::cmp::Ordering::Less => tween,
                        std::cmp::Ordering::Equal => tween.max(qt),
                    };
                }
                let (i, j) = (i as u32, j as u32);
                patches.push(PatchLod { i, j, level, tween, edge_level, edge_tween });
            }
        }
        GeomipSelection { patches, factors: c, culled, cpu_ms: 0.0 }
    }
}

#[cfg(test)]
mod tests {
    use super::reference::{boxes, select_reference};
    use super::*;
    use crate::synth::{FractalConfig, default_terrain};

    fn camera(hm: &Heightmap, x: f64, y: f64, z: f64) -> Camera {
        let p = hm.grid_to_world(x, y).extend(z);
        Camera::from_yaw_pitch(p, 45.0, -30.0).with_viewport(1280.0, 720.0)
    }

    #[test]
    fn neighbours_differ_by_at_most_one_level_and_borders_follow_the_coarser() {
        let hm = default_terrain();
        let scene = GeomipScene::new(&hm, 16);
        let cfg = GeomipConfig { frustum_cull: false, ..Default::default() };
        for (x, y, z) in [(10.0, 10.0, 300.0), (100.0, 60.0, 2000.0), (200.0, 200.0, 50.0)] {
            let sel = scene.select(&camera(&hm, x, y, z), &cfg);
            let (nx, ny) = scene.patch_counts();
            assert_eq!(sel.patches.len(), (nx * ny) as usize);
            let at = |i: u32, j: u32| sel.patches[(j * nx + i) as usize];
            let mut levels = std::collections::BTreeSet::new();
            for p in &sel.patches {
                levels.insert(p.level);
                assert!((0.0..1.0).contains(&p.tween));
                for e in Edge::ALL {
                    let (di, dj) = e.direction().step();
                    let (qi, qj) = (p.i as i64 + di, p.j as i64 + dj);
                    if qi < 0 || qj < 0 || qi >= nx as i64 || qj >= ny as i64 {
                        continue;
                    }
                    let q = at(qi as u32, qj as u32);
                    assert!(p.level.abs_diff(q.level) <= 1, "{p:?} {q:?}");
                    // Both sides of the edge agree on its level and tween factor.
                    let back = e.opposite() as usize;
                    assert_eq!(p.edge_level[e as usize], q.edge_level[back]);
                    assert_eq!(p.edge_tween[e as usize], q.edge_tween[back]);
                }
            }
            assert!(levels.len() >= 2, "a view should mix levels: {levels:?}");
        }
    }

    #[test]
    fn farther_is_coarser_and_no_morph_has_integer_levels() {
        let hm = default_terrain();
        let scene = GeomipScene::new(&hm, 16);
        let cfg = GeomipConfig { frustum_cull: false, ..Default::default() };
        let near = scene.select(&camera(&hm, 64.0, 64.0, 200.0), &cfg);
        let far = scene.select(&camera(&hm, 64.0, 64.0, 20000.0), &cfg);
        let sum = |s: &GeomipSelection| s.factors.iter().map(|&c| f64::from(c)).sum::<f64>();
        assert!(sum(&far) > sum(&near));
        let off =
            scene.select(&camera(&hm, 64.0, 64.0, 200.0), &GeomipConfig { morph: false, ..cfg });
        assert!(off.patches.iter().all(|p| p.tween == 0.0 && p.edge_tween == [0.0; 4]));
    }

    /// A patch's every field as bits (f32 `==` would equate 0.0 and -0.0).
    fn bits(p: &PatchLod) -> (u32, u32, u8, u32, [u8; 4], [u32; 4]) {
        (p.i, p.j, p.level, p.tween.to_bits(), p.edge_level, p.edge_tween.map(f32::to_bits))
    }

    /// Asserts the fast selection equals the whole-grid reference for many cameras: inside,
    /// above and outside the grid, looking every way, near and far clip planes that leave
    /// holes and empty views, several thresholds, morph on and off, culling on and off.
    fn assert_matches_reference(hm: &Heightmap, patch_cells: u32, cameras: usize) {
        let scene = GeomipScene::new(hm, patch_cells);
        let boxes = boxes(&scene, hm);
        let (w, h) = (hm.width() as f64, hm.height() as f64);
        let zmax = f64::from(hm.data().iter().copied().fold(f32::MIN, f32::max));
        let mut x = 0x2545_f491_4f6c_dd1du64;
        let mut unit = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut drawn, mut some_culled, mut some_empty) = (0, false, false);
        for k in 0..cameras {
            let gx = -0.3 * w + 1.6 * w * unit();
            let gy = -0.3 * h + 1.6 * h * unit();
            let z = zmax * (0.1 + 3.0 * unit() * unit()) + 5.0;
            let p = hm.grid_to_world(gx, gy).extend(z);
            let mut cam = Camera::from_yaw_pitch(p, 360.0 * unit(), -85.0 * unit() + 5.0)
                .with_viewport(1280.0, 720.0);
            if k % 3 == 1 {
                let span = hm.grid_to_world(w, h) - hm.grid_to_world(0.0, 0.0);
                cam = cam.with_clip(1.0, span.length() * (0.05 + 0.5 * unit()));
            }
            let cfg = GeomipConfig {
                patch_cells,
                pixel_threshold: [1.0, 0.25, 4.0, 0.05][k % 4],
                morph: k % 5 != 3,
                frustum_cull: k % 7 != 6,
            };
            let fast = scene.select(&cam, &cfg);
            let slow = select_reference(&scene, &boxes, &cam, &cfg);
            assert_eq!(fast.culled, slow.culled, "camera {k}");
            assert_eq!(fast.patches.len(), slow.patches.len(), "camera {k}");
            let nx = scene.nx as usize;
            for (a, b) in fast.patches.iter().zip(&slow.patches) {
                assert_eq!(bits(a), bits(b), "camera {k}: {a:?} vs {b:?}");
            }
            let want: Vec<u32> = slow
                .patches
                .iter()
                .map(|p| slow.factors[p.j as usize * nx + p.i as usize].to_bits())
                .collect();
            let got: Vec<u32> = fast.factors.iter().map(|f| f.to_bits()).collect();
            assert_eq!(got, want, "camera {k}: factors");
            drawn += fast.patches.len();
            some_culled |= fast.culled > 0 && !fast.patches.is_empty();
            some_empty |= fast.patches.is_empty();
        }
        // The cameras exercised partial views and empty ones.
        assert!(drawn > 0 && some_culled && some_empty, "{drawn} {some_culled} {some_empty}");
    }

    #[test]
    fn view_bounded_selection_equals_the_whole_grid_reference_on_a_fractal_grid() {
        let hm = FractalConfig::with_size(513, 513, 10.0).to_heightmap().unwrap();
        assert_matches_reference(&hm, 16, 120);
        assert_matches_reference(&hm, 8, 40);
    }

    #[test]
    fn view_bounded_selection_equals_the_whole_grid_reference_on_an_odd_grid() {
        // Neither side a multiple of the patch: the last patches are clipped.
        let hm = FractalConfig::with_size(301, 203, 30.0).to_heightmap().unwrap();
        assert_matches_reference(&hm, 16, 120);
        assert_matches_reference(&hm, 32, 40);
    }
}
