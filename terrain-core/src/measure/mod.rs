//! Exact per-frame error of the drawn surface against the full-resolution DEM, on the CPU:
//! vertical and screen-space error, the DSS paper's height RMSE and popping, and false culls.
//!
//! The caller rebuilds the drawn surface with [`crate::lod::build_surface`], passing the
//! tessellator that the GPU runs (terrain-gpu's CPU reference, bit-identical to the GPU), so
//! this module measures exactly what is drawn without depending on terrain-gpu.
//!
//! # What is measured, per frame
//! The *measured samples* are the DEM's non-void samples `(i, j)` whose DEM point
//! `(x, y, z)` lies inside the camera's view frustum, on a stride (see
//! [`MeasureConfig::stride`]), and whose plan position is covered by a selected patch's
//! rectangle. For each:
//! - `delta = drawn(x, y) - z`: the drawn surface's height at the sample's plan position
//!   (linear in the containing triangle, located through a uniform grid over the triangles
//!   built once per frame), minus the DEM sample. This is the DSS paper's height difference
//!   "by performing ray casting along the height direction" between the coarse and the
//!   original model (Zhang 2019, section 1, Figure 1).
//! - its screen-space size `lambda |delta| / d` pixels, with `lambda` the frame's
//!   [`Camera::lambda`] and `d` the distance from the eye to the DEM point (the same
//!   `lambda delta / d` form as DSS Eq. 3 and the out-of-core paper's Eq. 6-7). Reported as
//!   the maximum and the 99th percentile (nearest rank, [`percentile`]).
//! - `rmse_m = sqrt(mean(delta^2))`: DSS Tables 2-3 ("RMSE values of coarse models",
//!   computed from the height-difference maps of Figure 17). The paper's maps cover the whole
//!   1024-sample model; ours cover the samples inside the frustum, since what is outside is
//!   not drawn by any method and a method's culling is scored separately (false culls).
//! - popping (DSS section 5: "the popping artefacts can be reflected by the height difference
//!   change between coarse models"): over the samples measured in this frame *and* the
//!   previous one, the change `delta_k - delta_{k-1}`, as RMS and maximum of its magnitude.
//!   The paper's own number in the text ("the change of RMSE is 40.62" = 57.72 - 17.10 in
//!   Table 3) is the change of the RMSE between the two frames: reported as `rmse_change_m`.
//!
//! # False culls
//! A sample inside the frustum that no selected patch's rectangle covers was culled. It is a
//! *false cull* when it is visible from the eye by exact line of sight ([`los`]): the ray
//! from the eye to the sample never passes below the terrain at any grid-line crossing.
//! Only culled samples are ray-cast, so the common case (frustum culling only) costs nothing.
//!
//! Everything is deterministic: samples are visited in row-major order, sums are taken in
//! that order, and the percentile is an exact order statistic.

pub mod locate;
pub mod los;

use glam::{DVec2, DVec3};

use crate::geometry::{Camera, Classification, Frustum};
use crate::heightmap::Heightmap;
use crate::lod::{Selection, SurfaceMesh};
use crate::quadtree::{NodeId, Quadtree};

pub use locate::TriangleGrid;
pub use los::LineOfSight;

/// How a frame is measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasureConfig {
    /// Measure one sample per `stride` x `stride` block, at an offset hashed from the block
    /// (stratified, not an aligned lattice, which would sit on tessellation vertices); `0` chooses automatically: 1 while the samples in quadtree leaves
    /// touching the frustum are fewer than `max_samples`, otherwise the smallest stride that
    /// brings them under it. Default 0. The stride used is reported in
    /// [`FrameErrors::stride`].
    pub stride: u32,
    /// The automatic stride's budget of samples per frame. Default 2,000,000.
    pub max_samples: usize,
    /// Terrain must be this far above a sight line to block it, metres. Default 1e-3.
    pub los_epsilon_m: f64,
    /// Whether to ray-cast culled samples for false culls. Default true.
    pub false_culls: bool,
}

impl Default for MeasureConfig {
    fn default() -> Self {
        Self { stride: 0, max_samples: 2_000_000, los_epsilon_m: 1e-3, false_culls: true }
    }
}

/// The errors of one frame (see the module docs for the definitions).
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct FrameErrors {
    /// The sample stride used (1 = every sample).
    pub stride: u32,
    /// Non-void samples inside the frustum (on the stride).
    pub frustum_samples: usize,
    /// Measured samples: inside the frustum and drawn.
    pub samples: usize,
    /// Largest screen-space error, pixels.
    pub max_px: f64,
    /// 99th percentile (nearest rank) of the screen-space error, pixels.
    pub p99_px: f64,
    /// Root mean square of `delta`, metres (DSS Table 3).
    pub rmse_m: f64,
    /// Largest `|delta|`, metres.
    pub max_abs_m: f64,
    /// Mean `|delta|`, metres.
    pub mean_abs_m: f64,
    /// `|rmse_m - previous rmse_m|` (the DSS paper's "change of RMSE"); `None` on a first frame.
    pub rmse_change_m: Option<f64>,
    /// Samples measured in this frame and the previous one.
    pub popping_samples: usize,
    /// RMS of the change of `delta` since the previous frame, metres.
    pub popping_rms_m: f64,
    /// Largest change of `delta` since the previous frame, metres. The DEM sample is the same
    /// in both frames, so this is the largest jump of the *drawn* height at one sample,
    /// `max |drawn_k - drawn_(k-1)|`: what the eye sees as a pop.
    pub popping_max_m: f64,
    /// Samples inside the frustum not covered by any selected patch.
    pub culled_samples: usize,
    /// Culled samples visible by exact line of sight.
    pub false_culls: usize,
    /// Covered samples where no drawn triangle was found (holes or cracks; 0 when sound).
    pub unlocated: usize,
}

/// The `p`-quantile (`0 < p <= 1`) of `values` by nearest rank: the `ceil(p n)`-th smallest
/// (1-based), found with `select_nth_unstable_by(total_cmp)`; exact and deterministic. `values`
/// is reordered. `0.0` for an empty slice.
pub fn percentile(values: &mut [f64], p: f64) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let n = values.len();
    let rank = ((p * n as f64).ceil() as usize).clamp(1, n);
    *values.select_nth_unstable_by(rank - 1, f64::total_cmp).1
}

/// The height-difference field of the previous frame, for popping.
#[derive(Debug, Clone, Default)]
struct Field {
    /// Row-major sample indices `j * width + i`, ascending.
    keys: Vec<u64>,
    deltas: Vec<f64>,
    rmse: f64,
}

/// Measures frame after frame on one heightmap, remembering the previous frame for popping.
#[derive(Debug)]
pub struct Measurer<'a> {
    hm: &'a Heightmap,
    qt: &'a Quadtree,
    cfg: MeasureConfig,
    prev: Option<Field>,
}

impl<'a> Measurer<'a> {
    /// A measurer for `hm` and its quadtree `qt` (the one the selections are made on).
    pub fn new(hm: &'a Heightmap, qt: &'a Quadtree, cfg: MeasureConfig) -> Self {
        assert_eq!((hm.width() as u32, hm.height() as u32), (qt.width(), qt.height()));
        Self { hm, qt, cfg, prev: None }
    }

    /// Forgets the previous frame (the next frame reports no popping).
    pub fn reset(&mut self) {
        self.prev = None;
    }

    /// Measures one frame: `sel` is what was drawn and `mesh` its surface,
    /// `build_surface(hm, qt, sel, tessellator)`.
    pub fn measure(&mut self, camera: &Camera, sel: &Selection, mesh: &SurfaceMesh) -> FrameErrors {
        let (hm, qt) = (self.hm, self.qt);
        let (w, h) = (hm.width(), hm.height());
        let frustum = camera.frustum();
        let leaves = LeafGrid::new(qt);
        let touched = leaves.frustum_leaves(qt, &frustum);
        let stride = match self.cfg.stride {
            0 => {
                let candidates: u64 = touched.iter().map(|l| leaves.owned_samples(l, w, h)).sum();
                auto_stride(candidates, self.cfg.max_samples as u64)
            }
            s => s,
        } as usize;
        let covered = leaves.coverage(qt, sel);
        let tri = TriangleGrid::new(mesh);
        let los = LineOfSight::new(hm, qt, self.cfg.los_epsilon_m);
        let (eye, lambda) = (camera.position, camera.lambda());
        let voids = hm.voids();

        let mut out = FrameErrors { stride: stride as u32, ..Default::default() };
        let mut field = Field::default();
        let mut px: Vec<f64> = Vec::new();
        let (mut sum_sq, mut sum_abs) = (0.0f64, 0.0f64);
        // Row-major: leaf rows in order, rows within, leaves in column order within a row.
        let mut k = 0;
        while k < touched.len() {
            let row_leaf = touched[k].j;
            let end = k + touched[k..].iter().take_while(|l| l.j == row_leaf).count();
            let (y0, y1) = leaves.owned_range(row_leaf, h, leaves.ny);
            for y in y0..=y1 {
                let (by, row_in_block) = (y / stride, y % stride);
                for leaf in &touched[k..end] {
                    let (x0, x1) = leaves.owned_range(leaf.i, w, leaves.nx);
                    // Stratified sampling: one sample per stride x stride block, at an offset
                    // hashed from the block (see `block_offset`), visited on its own row.
                    let blocks = (x0 / stride)..=(x1 / stride);
                    let xs = blocks.filter_map(|bx| {
                        let (ox, oy) = block_offset(bx, by, stride);
                        let x = bx * stride + ox;
                        (oy == row_in_block && (x0..=x1).contains(&x)).then_some(x)
                    });
                    for x in xs {
                        if voids.any() && voids.get(x, y) {
                            continue;
                        }
                        let z = f64::from(hm.get(x, y));
                        let p = hm.grid_to_world(x as f64, y as f64).extend(z);
                        if !leaf.inside && !frustum.contains_point(p) {
                            continue;
                        }
                        out.frustum_samples += 1;
                        if !leaves.sample_covered(&covered, x, y) {
                            out.culled_samples += 1;
                            if self.cfg.false_culls && los.sample_visible(eye, x, y) {
                                out.false_culls += 1;
                            }
                            continue;
                        }
                        let Some(drawn) = tri.height_at(DVec2::new(x as f64, y as f64)) else {
                            out.unlocated += 1;
                            continue;
                        };
                        let delta = drawn - z;
                        let d = (p - eye).length().max(f64::MIN_POSITIVE);
                        px.push(lambda * delta.abs() / d);
                        sum_sq += delta * delta;
                        sum_abs += delta.abs();
                        out.max_abs_m = out.max_abs_m.max(delta.abs());
                        field.keys.push((y * w + x) as u64);
                        field.deltas.push(delta);
                    }
                }
            }
            k = end;
        }
        out.samples = px.len();
        if out.samples > 0 {
            let n = out.samples as f64;
            out.rmse_m = (sum_sq / n).sqrt();
            out.mean_abs_m = sum_abs / n;
            out.max_px = px.iter().copied().fold(0.0, f64::max);
            out.p99_px = percentile(&mut px, 0.99);
        }
        field.rmse = out.rmse_m;
        if let Some(prev) = &self.prev {
            out.rmse_change_m = Some((out.rmse_m - prev.rmse).abs());
            let (mut a, mut b, mut sq) = (0, 0, 0.0f64);
            while a < field.keys.len() && b < prev.keys.len() {
                match field.keys[a].cmp(&prev.keys[b]) {
                    std::cmp::Ordering::Less => a += 1,
                    std::cmp::Ordering::Greater => b += 1,
                    std::cmp::Ordering::Equal => {
                        let c = field.deltas[a] - prev.deltas[b];
                        sq += c * c;
                        out.popping_max_m = out.popping_max_m.max(c.abs());
                        out.popping_samples += 1;
                        a += 1;
                        b += 1;
                    }
                }
            }
            if out.popping_samples > 0 {
                out.popping_rms_m = (sq / out.popping_samples as f64).sqrt();
            }
        }
        self.prev = Some(field);
        out
    }
}

/// Measures a single frame (no popping): see [`Measurer::measure`].
pub fn measure_frame(
    hm: &Heightmap,
    qt: &Quadtree,
    camera: &Camera,
    sel: &Selection,
    mesh: &SurfaceMesh,
    cfg: &MeasureConfig,
) -> FrameErrors {
    Measurer::new(hm, qt, *cfg).measure(camera, sel, mesh)
}

/// The sample measured in stride block `(bx, by)`: an offset in `[0, stride)^2` hashed from the
/// block (SplitMix64), the same in every frame so popping compares the same samples. An aligned
/// lattice (`i % stride == 0`) would be biased: its samples coincide with the vertices of
/// power-of-two tessellations, where the drawn surface is exact, and report errors that are
/// too low. One hashed sample per block is stratified sampling: unbiased, deterministic.
fn block_offset(bx: usize, by: usize, stride: usize) -> (usize, usize) {
    if stride <= 1 {
        return (0, 0);
    }
    let key = (bx as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (by as u64).rotate_left(32);
    let z = crate::hash::mix64(key.wrapping_add(0x9E37_79B9_7F4A_7C15));
    let s = stride as u64;
    ((z % s) as usize, ((z >> 32) % s) as usize)
}

/// The smallest stride `s` with `ceil(candidates / s^2) <= budget` (1 when it fits).
fn auto_stride(candidates: u64, budget: u64) -> u32 {
    let budget = budget.max(1);
    let mut s = 1u64;
    while candidates.div_ceil(s * s) > budget {
        s += 1;
    }
    s as u32
}

/// A finest-level quadtree leaf touching the frustum.
#[derive(Debug, Clone, Copy)]
struct Leaf {
    i: usize,
    j: usize,
    /// Entirely inside the frustum: no per-sample test needed.
    inside: bool,
}

/// The finest quadtree level as a grid of leaves. Each sample is *owned* by one leaf: leaf
/// `(i, j)` owns columns `i c .. (i + 1) c - 1` (the last leaf column also owns the grid's
/// last column), likewise rows.
#[derive(Debug)]
struct LeafGrid {
    cells: usize,
    level: u8,
    nx: usize,
    ny: usize,
}

impl LeafGrid {
    fn new(qt: &Quadtree) -> Self {
        let cells = qt.leaf_cells() as usize;
        let nx = (qt.width() as usize - 1).max(1).div_ceil(cells);
        let ny = (qt.height() as usize - 1).max(1).div_ceil(cells);
        Self { cells, level: qt.max_level(), nx, ny }
    }

    fn owned_range(&self, leaf: usize, samples: usize, leaves: usize) -> (usize, usize) {
        let a = leaf * self.cells;
        let b = if leaf + 1 == leaves { samples - 1 } else { a + self.cells - 1 };
        (a, b.min(samples - 1))
    }

    fn owned_samples(&self, l: &Leaf, w: usize, h: usize) -> u64 {
        let (x0, x1) = self.owned_range(l.i, w, self.nx);
        let (y0, y1) = self.owned_range(l.j, h, self.ny);
        ((x1 - x0 + 1) * (y1 - y0 + 1)) as u64
    }

    /// Leaves whose box is not outside the frustum, sorted row-major `(j, i)`.
    fn frustum_leaves(&self, qt: &Quadtree, frustum: &Frustum) -> Vec<Leaf> {
        let mut out = Vec::new();
        let mut stack = vec![(NodeId::ROOT, false)];
        while let Some((n, inside)) = stack.pop() {
            let Some(info) = qt.node_info(n) else { continue };
            let inside = inside || {
                match frustum.classify(&info.aabb) {
                    Classification::Outside => continue,
                    Classification::Inside => true,
                    Classification::Intersecting => false,
                }
            };
            if n.level == self.level {
                out.push(Leaf { i: n.i as usize, j: n.j as usize, inside });
            } else {
                stack.extend(n.children().into_iter().map(|c| (c, inside)));
            }
        }
        out.sort_unstable_by_key(|l| (l.j, l.i));
        out
    }

    /// Per leaf: whether a selected patch covers it.
    fn coverage(&self, qt: &Quadtree, sel: &Selection) -> Vec<bool> {
        let mut cov = vec![false; self.nx * self.ny];
        for p in &sel.patches {
            // A patch finer than the quadtree's leaves (the out-of-core method's block nodes
            // go down to single cells) covers its ancestor leaf; samples of that leaf no patch
            // covers are then counted as unlocated instead of culled.
            let n = p.node.ancestor(p.node.level.min(self.level));
            if !qt.contains_node(n) {
                continue;
            }
            let shift = self.level - n.level;
            let (i0, j0) = ((n.i as usize) << shift, (n.j as usize) << shift);
            let span = 1usize << shift;
            for j in j0..(j0 + span).min(self.ny) {
                for i in i0..(i0 + span).min(self.nx) {
                    cov[j * self.nx + i] = true;
                }
            }
        }
        cov
    }

    /// Whether sample `(x, y)` lies in a covered leaf's (inclusive) rectangle.
    fn sample_covered(&self, cov: &[bool], x: usize, y: usize) -> bool {
        let c = self.cells;
        let cols = [Some(x / c), (x.is_multiple_of(c) && x > 0).then(|| x / c - 1)];
        let rows = [Some(y / c), (y.is_multiple_of(c) && y > 0).then(|| y / c - 1)];
        rows.iter().flatten().filter(|&&j| j < self.ny).any(|&j| {
            cols.iter().flatten().filter(|&&i| i < self.nx).any(|&i| cov[j * self.nx + i])
        })
    }
}

/// Distance-weighted screen-space size of a vertical error: `lambda |delta| / d` pixels.
pub fn screen_error_px(camera: &Camera, point: DVec3, delta: f64) -> f64 {
    camera.lambda() * delta.abs() / (point - camera.position).length()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentile_is_the_nearest_rank() {
        // 1..=1000 in a scrambled (deterministic) order.
        let mut v: Vec<f64> = (0..1000u64).map(|k| ((k * 7919) % 1000 + 1) as f64).collect();
        assert_eq!(percentile(&mut v.clone(), 0.99), 990.0);
        assert_eq!(percentile(&mut v.clone(), 0.5), 500.0);
        assert_eq!(percentile(&mut v.clone(), 1.0), 1000.0);
        assert_eq!(percentile(&mut v, 0.0001), 1.0);
        let mut w = vec![3.0, 1.0, 2.0];
        assert_eq!(percentile(&mut w, 0.99), 3.0);
        assert_eq!(percentile(&mut [], 0.99), 0.0);
    }

    #[test]
    fn auto_stride_fits_the_budget() {
        assert_eq!(auto_stride(1_000, 2_000), 1);
        assert_eq!(auto_stride(2_000, 2_000), 1);
        assert_eq!(auto_stride(2_001, 2_000), 2);
        assert_eq!(auto_stride(16_000_000, 2_000_000), 3);
    }
}
