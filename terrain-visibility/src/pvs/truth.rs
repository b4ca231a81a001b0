//! Dense ground truth for a baked PVS: for a sample of cells, many viewpoints filling each
//! cell's volume and every DEM sample of each culled patch, by exact line of sight
//! (terrain-core's `measure::LineOfSight`: interpolation along grid lines, max-height quadtree
//! early-out). A *false cull* is a (cell, patch) pair a PVS marks hidden while some viewpoint
//! of the cell sees some sample of the patch.

use glam::DVec3;
use rayon::prelude::*;
use terrain_core::Heightmap;
use terrain_core::measure::LineOfSight;
use terrain_core::quadtree::{NodeId, Quadtree};

use super::{CellId, Pvs};

/// How densely the truth samples a cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthConfig {
    /// Viewpoints per side of the cell's plan rectangle (ends included). Default 5.
    pub plan_viewpoints: u32,
    /// Viewpoint heights from the floor's bottom to its top (ends included). Default 3.
    pub heights: u32,
    /// Viewpoints closer than this above the ground are skipped (no camera goes there),
    /// metres. Default 1.
    pub clearance_m: f64,
    /// Terrain must be this far above a sight line to block it. Default 1e-3 (the benchmark's).
    pub epsilon_m: f64,
}

impl Default for TruthConfig {
    fn default() -> Self {
        Self { plan_viewpoints: 5, heights: 3, clearance_m: 1.0, epsilon_m: 1e-3 }
    }
}

/// The truth's counts over the cells checked, for one PVS.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct TruthCounts {
    /// (cell, finest patch with samples) pairs checked.
    pub pairs: usize,
    /// Pairs the PVS marks hidden.
    pub culled: usize,
    /// Culled pairs that some viewpoint sees.
    pub false_culls: usize,
}

impl TruthCounts {
    /// `false_culls / pairs`.
    pub fn false_cull_rate(&self) -> f64 {
        self.false_culls as f64 / self.pairs.max(1) as f64
    }

    /// `culled / pairs`.
    pub fn culled_fraction(&self) -> f64 {
        self.culled as f64 / self.pairs.max(1) as f64
    }
}

/// The viewpoints of `cell` in grid coordinates (z in metres), clear of the ground.
pub fn viewpoints(hm: &Heightmap, pvs: &Pvs, cell: CellId, cfg: &TruthConfig) -> Vec<DVec3> {
    let lay = &pvs.layout;
    let (Some((z0, z1)), Some((lo, hi))) =
        (lay.floor_bounds(cell), lay.cell_rect_clipped(cell.a, cell.b))
    else {
        return Vec::new();
    };
    let lerp = |a: f64, b: f64, k: u32, n: u32| {
        if n <= 1 { b } else { a + (b - a) * f64::from(k) / f64::from(n - 1) }
    };
    let (np, nh) = (cfg.plan_viewpoints.max(1), cfg.heights.max(1));
    let mut out = Vec::new();
    for y in 0..np {
        for x in 0..np {
            let (gx, gy) = (lerp(lo.x, hi.x, x, np), lerp(lo.y, hi.y, y, np));
            let ground = f64::from(hm.sample_grid(gx, gy));
            for k in 0..nh {
                let z = lerp(z0, z1, k, nh);
                if z >= ground + cfg.clearance_m {
                    out.push(DVec3::new(gx, gy, z));
                }
            }
        }
    }
    out
}

/// Whether any viewpoint sees any sample of the finest patch `(a, b)`.
pub fn patch_seen(
    los: &LineOfSight<'_>,
    hm: &Heightmap,
    pvs: &Pvs,
    views: &[DVec3],
    a: u32,
    b: u32,
) -> bool {
    let Some((x0, y0, x1, y1)) = pvs.layout.patch_samples(pvs.layout.patch_level, a, b) else {
        return false;
    };
    (y0..=y1).any(|y| {
        (x0..=x1).any(|x| {
            let t =
                DVec3::new(f64::from(x), f64::from(y), f64::from(hm.get(x as usize, y as usize)));
            views.iter().any(|&v| los.grid_visible(v, t))
        })
    })
}

/// Checks `pvss` (baked on `hm` with one layout) against the dense truth on `cells`: one
/// [`TruthCounts`] per PVS. The truth is computed only for pairs some PVS culls.
pub fn check(
    hm: &Heightmap,
    pvss: &[&Pvs],
    cells: &[CellId],
    cfg: &TruthConfig,
) -> Vec<TruthCounts> {
    let Some(first) = pvss.first() else { return Vec::new() };
    let lay = &first.layout;
    let qt = Quadtree::new(hm, 4);
    let los = LineOfSight::new(hm, &qt, cfg.epsilon_m);
    let l = lay.patch_level;
    let side = lay.patches_per_side();
    let per_cell: Vec<Vec<TruthCounts>> = cells
        .par_iter()
        .map(|&cell| {
            let mut counts = vec![TruthCounts::default(); pvss.len()];
            if lay.floor_bounds(cell).is_none() {
                return counts;
            }
            let views = viewpoints(hm, first, cell, cfg);
            for b in 0..side {
                for a in 0..side {
                    if lay.patch_samples(l, a, b).is_none() {
                        continue;
                    }
                    let node = NodeId::new(l, a, b);
                    let culled: Vec<bool> = pvss.iter().map(|p| !p.visible(cell, node)).collect();
                    let seen =
                        culled.iter().any(|&c| c) && patch_seen(&los, hm, first, &views, a, b);
                    for (c, &k) in counts.iter_mut().zip(&culled) {
                        c.pairs += 1;
                        c.culled += usize::from(k);
                        c.false_culls += usize::from(k && seen);
                    }
                }
            }
            counts
        })
        .collect();
    let mut total = vec![TruthCounts::default(); pvss.len()];
    for cell in per_cell {
        for (t, c) in total.iter_mut().zip(cell) {
            t.pairs += c.pairs;
            t.culled += c.culled;
            t.false_culls += c.false_culls;
        }
    }
    total
}

/// `n` cells spread deterministically over the layout's cells inside the grid (every floor).
pub fn sample_cells(pvs: &Pvs, n: usize) -> Vec<CellId> {
    let lay = &pvs.layout;
    let inside: Vec<CellId> = (0..lay.cell_count())
        .map(|k| lay.cell_at_index(k))
        .filter(|&c| lay.floor_bounds(c).is_some())
        .collect();
    if n >= inside.len() {
        return inside;
    }
    // A fixed odd stride through the list visits cells spread over rows, columns and floors.
    let stride = (inside.len() / n.max(1)).max(1) | 1;
    (0..n).map(|k| inside[(k * stride + stride / 2) % inside.len()]).collect()
}
