//! The PVS of a grid that is not held in memory: baked against a coarser, *conservative*
//! version of the terrain gathered by bands of rows (a DEM read by rows, a synthetic terrain
//! generated again), in memory bounded by the coarse grid.
//!
//! # Technique
//! Conservative occluder simplification ("occluder shrinking"; Cohen-Or, Chrysanthou, Silva
//! and Durand 2003, "A survey of visibility for walkthrough applications", IEEE TVCG 9(3),
//! sections 4-5: a from-region visibility test stays conservative when it runs against
//! occluders that lie inside the true ones): the occluders are never *higher* than the true
//! surface and the targets never *lower*, so every sight line the coarse bake finds blocked
//! is blocked on the true terrain too, and nothing visible is culled. The PVPS paper (Zhang
//! 2021) has no variant for terrain larger than memory; it bakes from the whole DEM.
//!
//! With a factor `f` (a power of two), coarse sample `(I, J)` stands at fine sample
//! `(I f, J f)` and covers the window `[I f - f, I f + f] x [J f - f, J f + f]` (clipped): every
//! coarse cell that touches the sample lies in it.
//! - **Occluders** ([`CoarseTerrain::occluders`]): the window's *min*. A point of a coarse cell
//!   is a convex combination of its four corners, each at most the min of the fine samples of
//!   that cell, so the coarse surface (any interpolation that stays within its corners'
//!   range, and the samples the proofs and Eq. 4 read) is at or below every fine sample and
//!   every point of the fine surface over that cell.
//! - **Targets** ([`CoarseTerrain::targets`]): the window's *max*, read for a patch's max
//!   height `Hp` (the conservative proof of [`super::bake`]), its test points and the
//!   witnesses: every fine sample of a patch is within `f` of a coarse sample of the same
//!   patch (patches are whole coarse cells, `f <= patch cells`), so a patch's coarse max is at
//!   least its true max.
//! - **View cells** keep the fine grid's floors ([`PvsLayout::bases`] from the fine samples'
//!   ranges, the relief from the fine min and max): the top planes the bake tests from are the
//!   ones [`PvsLayout::locate`] looks up, never lower.
//!
//! So the conservative PVS baked this way never culls a patch that any point of a cell sees
//! (exact line of sight on the fine grid), and it contains every patch the paper's sampled
//! test finds visible on the fine grid (that test's sight lines are Eq. 4 lines over fine
//! samples, which the proofs cover as they cover the coarse ones). The sampled PVS baked this
//! way is the paper's test run on the coarse terrain (test points at coarse samples, at their
//! windows' max). Both files carry the fine grid's layout and the CRC-32 of its full
//! resolution heights (computed by rows), so a stale PVS is refused as one baked in memory.

use terrain_core::lod::dss_file::HeightsChecksum;
use terrain_core::{Heightmap, HeightmapError};

use super::bake::{BakeStats, CullEstimate, bake_grids, estimate_grids};
use super::mip::HeightMip;
use super::{GridStats, Pvs, PvsConfig, PvsLayout};

/// Bytes the coarse bake holds per coarse sample: two grids (4 bytes and a void flag each),
/// their min/max mips with column-major copies (about 4 + 8 / 3 bytes each) and the
/// occluders' per-grid-line min pyramids (about 8 bytes).
pub const BYTES_PER_COARSE_SAMPLE: u64 = 32;

/// Why the coarse terrain could not be built.
#[derive(Debug, thiserror::Error)]
pub enum CoarseError {
    /// The coarse grid is not a heightmap (non-finite heights read).
    #[error("the coarse conservative terrain of the PVS bake (factor {factor}): {source}")]
    Grid {
        /// The reduction factor.
        factor: u32,
        /// What the heightmap refused.
        #[source]
        source: HeightmapError,
    },
    /// Rows read do not fit the grid.
    #[error("the PVS bake read rows {j0}..{} of a grid of {height} rows", j0 + rows)]
    Rows {
        /// First row of the band.
        j0: usize,
        /// Rows in the band.
        rows: usize,
        /// Rows of the grid.
        height: usize,
    },
}

/// The reduction factor for a `width x height` grid whose coarse bake must fit `max_bytes`
/// ([`BYTES_PER_COARSE_SAMPLE`] per coarse sample): the least power of two that fits, at
/// most the patch side in cells (`root_cells >> patch_level`: a patch keeps at least one
/// coarse cell). Returns `(factor, fits)`; `fits` is false when even that factor does not fit.
pub fn factor_for(width: u64, height: u64, cfg: &PvsConfig, max_bytes: u64) -> (u32, bool) {
    let cells = (width.saturating_sub(1)).max(height.saturating_sub(1)).max(1);
    let root = cells.next_power_of_two();
    let level = u32::from(cfg.patch_level).min(root.trailing_zeros());
    let cap = (root >> level).max(1);
    let bytes = |f: u64| {
        let (cw, ch) =
            (width.saturating_sub(1).div_ceil(f) + 1, height.saturating_sub(1).div_ceil(f) + 1);
        cw * ch * BYTES_PER_COARSE_SAMPLE
    };
    let mut f = 1u64;
    while f < cap && bytes(f) > max_bytes {
        f *= 2;
    }
    (f as u32, bytes(f) <= max_bytes)
}

/// A grid reduced by a factor for the PVS bake (see the module docs).
#[derive(Debug, Clone)]
pub struct CoarseTerrain {
    /// The reduction factor `f` (a power of two; 1 keeps the grid).
    pub factor: u32,
    /// Per coarse sample, the min of its window: never above the terrain.
    pub occluders: Heightmap,
    /// Per coarse sample, the max of its window: never below the terrain.
    pub targets: Heightmap,
    /// The fine grid's layout (floors from its samples, its heights' CRC-32).
    pub layout: PvsLayout,
}

impl CoarseTerrain {
    /// Gathers the coarse terrain of a `width x height` grid at `georef` by reading it through
    /// `read(j0, rows, heights, voids)` (row `j0` first, south first, as a heightmap holds
    /// them) in bands of `band_rows` rows, once. `factor` is rounded up to a power of two and
    /// clamped to the patch side ([`factor_for`] chooses one for a memory budget). Memory: the
    /// coarse grids and one band.
    pub fn from_rows<E: From<CoarseError>>(
        width: usize,
        height: usize,
        georef: &terrain_core::georef::Georef,
        cfg: &PvsConfig,
        factor: u32,
        band_rows: usize,
        mut read: impl FnMut(usize, usize, &mut [f32], &mut [bool]) -> Result<(), E>,
    ) -> Result<Self, E> {
        let (w, h) = (width.max(1), height.max(1));
        // The layout's geometry first (the cells' sample rectangles do not depend on heights).
        let shape = GridStats {
            width: w as u32,
            height: h as u32,
            min: 0.0,
            max: 0.0,
            georef: georef.clone(),
            heights: 0,
        };
        let probe = PvsLayout::from_stats(&shape, cfg, |_, _, _, _| (0.0, 0.0));
        let cap = (probe.root_cells >> probe.patch_level).max(1);
        let f = factor.max(1).next_power_of_two().min(cap) as usize;
        let rects: Vec<Option<(u32, u32, u32, u32)>> = (0..probe.cells_y)
            .flat_map(|b| (0..probe.cells_x).map(move |a| (a, b)))
            .map(|(a, b)| probe.cell_samples(a, b))
            .collect();
        let mut ranges = vec![(f32::INFINITY, f32::NEG_INFINITY); rects.len()];
        // Segments: fine cells [I f, (I + 1) f] per axis (clipped), both ends inclusive.
        let (nx, ny) = ((w - 1).div_ceil(f).max(1), (h - 1).div_ceil(f).max(1));
        let mut seg_min = vec![f32::INFINITY; nx * ny];
        let mut seg_max = vec![f32::NEG_INFINITY; nx * ny];
        let mut row_min = vec![0f32; nx];
        let mut row_max = vec![0f32; nx];
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        let mut crc = HeightsChecksum::new();
        // Factor 1: the grid itself (it fits), for the exact bake.
        let mut whole: Vec<f32> = Vec::with_capacity(if f == 1 { w * h } else { 0 });
        let band = band_rows.clamp(1, h);
        let (mut heights, mut voids) = (vec![0f32; band * w], vec![false; band * w]);
        let mut j0 = 0;
        while j0 < h {
            let n = band.min(h - j0);
            read(j0, n, &mut heights[..n * w], &mut voids[..n * w])?;
            for r in 0..n {
                let y = j0 + r;
                let row = &heights[r * w..(r + 1) * w];
                let vrow = &voids[r * w..(r + 1) * w];
                crc.add_heights(row);
                crc.add_voids(vrow);
                for (&z, &v) in row.iter().zip(vrow) {
                    if !v {
                        lo = lo.min(z);
                        hi = hi.max(z);
                    }
                }
                for (c, rect) in rects.iter().enumerate() {
                    if let Some((x0, y0, x1, y1)) = *rect
                        && (y0 as usize..=y1 as usize).contains(&y)
                    {
                        for &z in &row[x0 as usize..=x1 as usize] {
                            ranges[c].0 = ranges[c].0.min(z);
                            ranges[c].1 = ranges[c].1.max(z);
                        }
                    }
                }
                if f == 1 {
                    whole.extend_from_slice(row);
                    continue;
                }
                for i in 0..nx {
                    let seg = &row[(i * f).min(w - 1)..=((i + 1) * f).min(w - 1)];
                    row_min[i] = seg.iter().copied().fold(f32::INFINITY, f32::min);
                    row_max[i] = seg.iter().copied().fold(f32::NEG_INFINITY, f32::max);
                }
                // Row y belongs to segment rows J with J f <= y <= (J + 1) f.
                let below = (y % f == 0 && y >= f).then(|| y / f - 1);
                for jj in below.into_iter().chain(std::iter::once(y / f)).filter(|&jj| jj < ny) {
                    let base = jj * nx;
                    for i in 0..nx {
                        seg_min[base + i] = seg_min[base + i].min(row_min[i]);
                        seg_max[base + i] = seg_max[base + i].max(row_max[i]);
                    }
                }
            }
            j0 += n;
        }
        if lo > hi {
            // Every sample void: the heightmap would refuse it; keep the layout defined.
            (lo, hi) = (0.0, 0.0);
        }
        let stats = GridStats {
            width: w as u32,
            height: h as u32,
            min: lo,
            max: hi,
            georef: georef.clone(),
            heights: crc.finish(),
        };
        let by_rect: std::collections::HashMap<_, _> =
            rects.iter().zip(&ranges).filter_map(|(r, &v)| r.map(|r| (r, v))).collect();
        let layout = PvsLayout::from_stats(&stats, cfg, |x0, y0, x1, y1| {
            by_rect.get(&(x0, y0, x1, y1)).copied().unwrap_or((lo, hi))
        });
        // Coarse samples: the segments around each, (I - 1..=I) x (J - 1..=J).
        let (cw, ch) = (if w == 1 { 1 } else { nx + 1 }, if h == 1 { 1 } else { ny + 1 });
        let window = |segs: &[f32], i: usize, j: usize, pick: fn(f32, f32) -> f32, init: f32| {
            let mut v = init;
            for jj in j.saturating_sub(1)..=j.min(ny - 1) {
                for ii in i.saturating_sub(1)..=i.min(nx - 1) {
                    v = pick(v, segs[jj * nx + ii]);
                }
            }
            v
        };
        let mut g = georef.clone();
        g.spacing_m *= f as f64;
        g.native_spacing *= f as f64;
        let grid = |segs: &[f32], pick: fn(f32, f32) -> f32, init: f32| {
            Heightmap::from_fn(cw, ch, g.clone(), |i, j| window(segs, i, j, pick, init))
                .map_err(|source| CoarseError::Grid { factor: f as u32, source })
        };
        if f == 1 {
            // Moved, not copied; the void flags are not needed (the layout and CRC-32 have
            // them, the bake reads heights only).
            let voids = terrain_core::VoidMask::new(w, h);
            let hm = Heightmap::new(w, h, whole, voids, georef.clone())
                .map_err(|source| CoarseError::Grid { factor: 1, source })?;
            return Ok(Self { factor: 1, occluders: hm.clone(), targets: hm, layout });
        }
        let occluders = grid(&seg_min, f32::min, f32::INFINITY)?;
        let targets = grid(&seg_max, f32::max, f32::NEG_INFINITY)?;
        Ok(Self { factor: f as u32, occluders, targets, layout })
    }

    /// [`CoarseTerrain::from_rows`] over a heightmap in memory (for tests and comparisons: the
    /// coarse bake of a grid whose exact bake is known).
    pub fn from_heightmap(
        hm: &Heightmap,
        cfg: &PvsConfig,
        factor: u32,
    ) -> Result<Self, CoarseError> {
        let w = hm.width();
        Self::from_rows(w, hm.height(), hm.georef(), cfg, factor, 64, |j0, n, heights, voids| {
            heights.copy_from_slice(&hm.data()[j0 * w..(j0 + n) * w]);
            for (r, row) in voids.chunks_mut(w).enumerate() {
                for (i, v) in row.iter_mut().enumerate() {
                    *v = hm.voids().get(i, j0 + r);
                }
            }
            Ok::<_, CoarseError>(())
        })
    }

    /// The layout the coarse bake runs on: the fine layout's cells and floors over the coarse
    /// grid (same root square in metres, `f` times fewer cells per side).
    fn coarse_layout(&self) -> PvsLayout {
        let f = self.factor;
        let mut l = self.layout.clone();
        l.width = self.occluders.width() as u32;
        l.height = self.occluders.height() as u32;
        l.root_cells = (self.layout.root_cells / f).max(1);
        l.spacing *= f64::from(f);
        l
    }

    /// What a spread sample of the coarse bake's view cells culls ([`super::estimate_cull`]
    /// against this coarse terrain).
    pub fn estimate_cull(&self, cfg: &PvsConfig, stride: u32) -> CullEstimate {
        let start = std::time::Instant::now();
        let occ = HeightMip::new(&self.occluders);
        let tgt = HeightMip::new(&self.targets);
        estimate_grids(&occ, &tgt, &self.coarse_layout(), cfg, stride, start)
    }

    /// Bakes both PVS modes against the coarse terrain: `(sampled, conservative, stats)`, each
    /// with the fine grid's layout (see the module docs). `progress(done, total)` as
    /// [`super::bake_both_with_progress`].
    pub fn bake_both(
        &self,
        cfg: &PvsConfig,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> (Pvs, Pvs, BakeStats) {
        let start = std::time::Instant::now();
        let occ = HeightMip::new(&self.occluders);
        let tgt = HeightMip::new(&self.targets);
        let (mut s, mut c, stats) =
            bake_grids(&occ, &tgt, self.coarse_layout(), cfg, true, true, progress, start);
        s.layout = self.layout.clone();
        c.layout = self.layout.clone();
        (s, c, stats)
    }
}
