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
use crate::geometry::{Aabb, Camera, Classification};
use crate::heightmap::Heightmap;
use crate::metrics::Region;
use crate::metrics::geomorph::{Reference, Triangulation, max_error_vertices_with};

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

/// Per-patch precomputation: the max-error vertex of every level and the patch's box.
#[derive(Debug, Clone)]
pub struct GeomipScene {
    patch_cells: u32,
    levels: usize,
    nx: u32,
    ny: u32,
    /// Per patch (row-major, south first), per level: monotone error (m) and the world
    /// position of the max-error vertex.
    errors: Vec<Vec<(f64, DVec3)>>,
    boxes: Vec<Aabb>,
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
    /// The continuous factor `c'` of every patch, culled ones included (row-major).
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
        let mut errors = Vec::with_capacity((nx * ny) as usize);
        let mut boxes = Vec::with_capacity((nx * ny) as usize);
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
                let mut v = Vec::with_capacity(levels);
                let mut running: f64 = 0.0;
                for l in 0..levels {
                    let (e, pos) = match lv.get(l).and_then(|e| e.vertex.map(|v| (e.error, v))) {
                        Some((e, vx)) => (e, origin + vx.offset),
                        None => (0.0, origin),
                    };
                    running = running.max(e);
                    v.push((running, pos));
                }
                errors.push(v);
                let (x1, y1) =
                    ((x0 + p as usize).min(hm.width() - 1), (y0 + p as usize).min(hm.height() - 1));
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
        Self { patch_cells: p, levels, nx, ny, errors, boxes }
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
        self.errors[(j * self.nx + i) as usize][level].0
    }

    /// The continuous factor of one patch before the neighbour envelope (see the module docs).
    fn factor(&self, k: usize, camera: &Camera, tau: f64) -> f32 {
        let lambda = camera.lambda();
        let mut c = 0.0;
        let mut prev = 1.0f64;
        for &(delta, pos) in &self.errors[k][1..] {
            let a = if delta <= 0.0 {
                0.0
            } else {
                let d = (pos - camera.position).length();
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
        let mut c: Vec<f32> = (0..nx * ny).map(|k| self.factor(k, camera, tau)).collect();
        // Lower envelope c'_p = min_q (c_q + |p - q|_1): forward then backward pass.
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
        let max_level = (self.levels - 1) as f32;
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
                if cfg.frustum_cull && frustum.classify(&self.boxes[k]) == Classification::Outside {
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
                patches.push(PatchLod {
                    i: i as u32,
                    j: j as u32,
                    level,
                    tween,
                    edge_level,
                    edge_tween,
                });
            }
        }
        GeomipSelection { patches, factors: c, culled, cpu_ms: start.elapsed().as_secs_f64() * 1e3 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::default_terrain;

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
}
