//! Potential visible patch sets (PVPS paper, Zhang 2021, sections 2.2.1-2.2.2 and 2.3.1-2.3.3;
//! the geomorphing article's PVS layers, Wagner 2003): which terrain patches can be seen from
//! each view cell, baked once, then looked up per quadtree node at run time.
//!
//! # Layout (see [`PvsLayout`])
//! - **Patches.** The patch grid is the quadtree's node grid at [`PvsConfig::patch_level`]
//!   over the quadtree's root square (`root_cells`, the next power of two of cells covering the
//!   grid, see terrain-core's quadtree invariant): patch `(a, b)` is node `(L, a, b)`. Level 6
//!   gives the paper's 64 x 64 patches (of 64 cells on a 4096^2 DEM). Patches outside the grid
//!   hold no samples and are never visible.
//! - **View cells.** A `cells_x x cells_y` grid over the same root square (default 32 x 32),
//!   times [`PvsConfig::floors`] floors (default 3). Floors are *relative to the terrain under
//!   each cell* (the paper only says cells are "distributed over the surface of the terrain"):
//!   with `bottom`, `top` the min and max DEM height under the cell and `H` the floor height,
//!   floor 0 spans `[bottom, top + H]` and floor `k >= 1` spans `[top + k H, top + (k + 1) H]`.
//!   `H` defaults to the DEM's relief / floors, so the top floor ends one relief above the
//!   cell's highest point. The geomorphing article's variant ([`PvsConfig::article`]) puts
//!   the cells on the patch grid and uses 32 absolute layers up to three reliefs above the DEM's
//!   minimum ([`FloorRule::Layers`], the same formula with `bottom = top = min`).
//! - **Cell_other.** A camera outside the grid's plan extent or above the top floor is in the
//!   paper's `Cell_other`: no occlusion culling.
//! - **Lookup.** A camera at height `z` uses the lowest floor whose top is at or above `z`:
//!   visibility only grows with height (Fig. 5, first property), so a floor's set, baked from its
//!   top plane, holds for every point below it too.
//!
//! # Bits
//! 1 = visible, 0 = hidden, throughout (the bake, the file, the images). The paper contradicts
//! itself: section 2.2.2 says 1 (white) is visible and section 2.3.1 says 255 (white) is
//! visible, but section 2.3.3 says "if the pixel value is 0, we determine that this quadtree node
//! is visible". We follow 2.2.2 and 2.3.1. Per cell there is one bitset per pyramid level
//! `0..=L`; a level's bit is the OR of its four children (section 2.3.1), so a quadtree node at
//! level `l <= L` reads bit `(l, i, j)` in O(1), and a node below `L` reads its ancestor at `L`.
//!
//! # Modes
//! [`PvsMode::Sampled`] is the paper's: 7 x 7 test points per patch, key viewpoints on the
//! cell's top plane by Fig. 6, midpoint refinement up to 16 viewpoints, Eq. 4 line of sight
//! ([`los`]). It can cull visible patches (it samples). [`PvsMode::Conservative`] culls a
//! patch only when [`bake`] *proves* that no point of the cell sees any point of the patch's
//! max-height box (see `bake`'s module docs), so it never culls a visible patch.

pub mod bake;
pub mod coarse;
pub mod file;
pub mod los;
pub mod mip;
pub mod truth;

use glam::{DVec2, DVec3};
use terrain_core::Heightmap;
use terrain_core::lod::dss_file::heights_checksum;
use terrain_core::quadtree::{Cull, CullPolicy, NodeId, NodeInfo, TreeShape};

pub use bake::{
    BakeStats, CullEstimate, bake, bake_both, bake_both_with_progress, estimate_cull, spread_sample,
};
pub use file::{PvsFileError, read_pvs, write_pvs};

/// How the floors of view cells are placed (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FloorRule {
    /// Floors above the terrain under each cell: floor 0 from the cell's lowest sample to `H`
    /// above its highest, then `H` per floor. `height_m: None` takes the DEM's relief divided
    /// by the number of floors.
    AboveTerrain {
        /// The floor height `H`, metres.
        height_m: Option<f64>,
    },
    /// Absolute layers from the DEM's minimum up to `relief_multiple x relief` above it (the
    /// geomorphing article: 32 layers up to three times the landscape's height).
    Layers {
        /// The layers' total height in units of the DEM's relief.
        relief_multiple: f64,
    },
}

/// Which visibility test a bake runs (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PvsMode {
    /// The PVPS paper's sampled key-viewpoint test.
    Sampled,
    /// Never culls a visible patch: culls only what is proven hidden.
    Conservative,
}

impl PvsMode {
    /// A short name (`sampled`, `conservative`).
    pub fn name(self) -> &'static str {
        match self {
            PvsMode::Sampled => "sampled",
            PvsMode::Conservative => "conservative",
        }
    }
}

/// Settings of a PVS bake. The defaults are the PVPS paper's configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct PvsConfig {
    /// View cells per side in x and y over the quadtree's root square. Default (32, 32).
    pub cells: (u32, u32),
    /// Floors (vertical layers) of cells. Default 3.
    pub floors: u32,
    /// Where floors are. Default [`FloorRule::AboveTerrain`] with the relief / floors.
    pub floor_rule: FloorRule,
    /// The patch grid's quadtree level `L` (`2^L x 2^L` patches, `L + 1` pyramid levels).
    /// Default 6 (the paper's 64 x 64).
    pub patch_level: u8,
    /// Test points per patch side (section 2.2.2). Default 7.
    pub test_points: u32,
    /// Key viewpoints per test point after midpoint refinement (section 2.2.2). Default 16.
    pub max_viewpoints: u32,
    /// Which test. Default [`PvsMode::Sampled`].
    pub mode: PvsMode,
    /// Terrain must be this far above a sight line to block it, metres. Default 0.01 (the
    /// conservative proof then holds for every line-of-sight tolerance up to 1 cm).
    pub epsilon_m: f64,
    /// Worker threads for the bake (rayon); 0 = rayon's default (one per core). Default 0.
    pub threads: usize,
}

impl Default for PvsConfig {
    fn default() -> Self {
        Self {
            cells: (32, 32),
            floors: 3,
            floor_rule: FloorRule::AboveTerrain { height_m: None },
            patch_level: 6,
            test_points: 7,
            max_viewpoints: 16,
            mode: PvsMode::Sampled,
            epsilon_m: 0.01,
            threads: 0,
        }
    }
}

/// The PVPS paper's patch side in grid cells: 64 x 64 patches over its 4096^2 DEM (section
/// 2.2.1, Eq. 2). [`PvsConfig::scaled`] keeps patches this size on other grids.
pub const PAPER_PATCH_CELLS: u32 = 64;

/// The PVPS paper's patches per view cell side: 64 x 64 patches (Eq. 2) under 32 x 32 view
/// cells per floor (Eq. 3).
pub const PAPER_PATCHES_PER_CELL: u32 = 2;

/// The quadtree root square's side in cells of a `width x height` grid (the next power of two
/// of its larger side in cells, see terrain-core's quadtree invariant).
pub fn root_cells(width: u32, height: u32) -> u32 {
    (width.saturating_sub(1)).max(height.saturating_sub(1)).max(1).next_power_of_two()
}

/// View cells per side over `2^patch_level` patches per side at the paper's ratio
/// ([`PAPER_PATCHES_PER_CELL`] patches a cell side), at least 1.
pub fn cells_per_side(patch_level: u8) -> u32 {
    ((1u32 << patch_level) / PAPER_PATCHES_PER_CELL).max(1)
}

impl PvsConfig {
    /// The paper's configuration scaled to a `width x height` grid (what `terrain bake` uses
    /// unless told otherwise). The paper fixes 64 x 64 patches and 32 x 32 x 3 view cells for
    /// its 4096^2 DEM; a fixed count makes a small grid's patches and cells tiny (on a 2 x 2
    /// grid, 3,072 view cells over 4 one-cell patches) and its bake as long as a large one's.
    /// Scaled, the rule keeps the paper's *sizes* instead:
    /// - patches of [`PAPER_PATCH_CELLS`] cells a side: `patch_level = log2(root_cells / 64)`,
    ///   at most 6 (the paper's 64 x 64; a larger grid gets larger patches, as the paper's
    ///   default does today) and at least 0 (one patch);
    /// - view cells of [`PAPER_PATCHES_PER_CELL`] patches a side: `2^patch_level / 2` cells
    ///   per side, at least 1;
    /// - the paper's 3 floors, 7 x 7 test points and 16 key viewpoints.
    ///
    /// On a 4096^2 grid this is exactly [`PvsConfig::default`] (the paper's); on a 1201^2
    /// grid (root 2048 cells) 32 x 32 patches under 16 x 16 x 3 cells; on a 429 x 279 grid
    /// (root 512) 8 x 8 patches under 4 x 4 x 3 cells.
    pub fn scaled(width: u32, height: u32) -> Self {
        let root = root_cells(width, height);
        let patch_level = (root / PAPER_PATCH_CELLS).max(1).trailing_zeros().min(6) as u8;
        let cells = cells_per_side(patch_level);
        Self { cells: (cells, cells), patch_level, ..Self::default() }
    }

    /// The geomorphing article's variant: view cells on the patch grid itself (`2^L x 2^L`),
    /// 32 layers up to three times the terrain's relief, the same bake.
    pub fn article(patch_level: u8) -> Self {
        let n = 1u32 << patch_level;
        Self {
            cells: (n, n),
            floors: 32,
            floor_rule: FloorRule::Layers { relief_multiple: 3.0 },
            patch_level,
            ..Self::default()
        }
    }
}

/// A view cell: plan indices and floor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct CellId {
    /// Column, west to east.
    pub a: u32,
    /// Row, south to north.
    pub b: u32,
    /// Floor, bottom up.
    pub k: u32,
}

/// What a [`PvsLayout`] needs of a grid besides its cells' ranges: its size, height range
/// (of the samples that are not void, as [`Heightmap::min`]), georeference and heights'
/// checksum.
#[derive(Debug, Clone, PartialEq)]
pub struct GridStats {
    /// Samples per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// The least height (not void).
    pub min: f32,
    /// The greatest height (not void).
    pub max: f32,
    /// Where the grid is.
    pub georef: terrain_core::georef::Georef,
    /// CRC-32 of the heights and void mask ([`PvsLayout::heights`]).
    pub heights: u32,
}

/// Where cells and patches are (everything but the bits); stored in the PVS file's header.
#[derive(Debug, Clone, PartialEq)]
pub struct PvsLayout {
    /// Grid width in samples of the DEM baked.
    pub width: u32,
    /// Grid height in samples.
    pub height: u32,
    /// The quadtree root square's side in cells.
    pub root_cells: u32,
    /// The patch grid's level `L`.
    pub patch_level: u8,
    /// View cells in x.
    pub cells_x: u32,
    /// View cells in y.
    pub cells_y: u32,
    /// Floors.
    pub floors: u32,
    /// The floor height `H`, metres.
    pub floor_height_m: f64,
    /// World position of sample (0, 0).
    pub origin: DVec2,
    /// Metres per sample in x and y.
    pub spacing: DVec2,
    /// Per plan cell (row-major, `b * cells_x + a`): the `bottom` and `top` of its floors'
    /// formula; NaN for a cell outside the grid.
    pub bases: Vec<(f32, f32)>,
    /// CRC-32 of the heights and void mask baked (terrain-core's `heights_checksum`, as the DSS
    /// table keeps): a PVS is tied to its terrain, and a stale one (the DEM re-read with other
    /// options, edited, re-cropped at the same size) is refused rather than used.
    pub heights: u32,
}

impl PvsLayout {
    /// The layout of `cfg` on `hm`.
    pub fn new(hm: &Heightmap, cfg: &PvsConfig) -> Self {
        let stats = GridStats {
            width: hm.width() as u32,
            height: hm.height() as u32,
            min: hm.min(),
            max: hm.max(),
            georef: hm.georef().clone(),
            heights: heights_checksum(hm),
        };
        Self::from_stats(&stats, cfg, |x0, y0, x1, y1| {
            let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
            for y in y0..=y1 {
                for x in x0..=x1 {
                    let z = hm.get(x as usize, y as usize);
                    lo = lo.min(z);
                    hi = hi.max(z);
                }
            }
            (lo, hi)
        })
    }

    /// The layout of `cfg` on a grid known by its [`GridStats`], with `range(x0, y0, x1, y1)`
    /// the min and max of the samples of an inclusive rectangle (a plan cell's, for its
    /// floors; a bake by rows gathers them beforehand, see [`coarse`]).
    pub fn from_stats(
        stats: &GridStats,
        cfg: &PvsConfig,
        mut range: impl FnMut(u32, u32, u32, u32) -> (f32, f32),
    ) -> Self {
        let (w, h) = (stats.width, stats.height);
        let root_cells = root_cells(w, h);
        let (cx, cy) = (cfg.cells.0.max(1), cfg.cells.1.max(1));
        let floors = cfg.floors.max(1);
        let relief = f64::from(stats.max - stats.min).max(1.0);
        let g = &stats.georef;
        let mut layout = Self {
            width: w,
            height: h,
            root_cells,
            patch_level: cfg.patch_level.min(root_cells.trailing_zeros() as u8),
            cells_x: cx,
            cells_y: cy,
            floors,
            floor_height_m: 0.0,
            origin: g.world_origin,
            spacing: g.spacing_m,
            bases: Vec::with_capacity((cx * cy) as usize),
            heights: stats.heights,
        };
        layout.floor_height_m = match cfg.floor_rule {
            FloorRule::AboveTerrain { height_m } => height_m.unwrap_or(relief / f64::from(floors)),
            FloorRule::Layers { relief_multiple } => relief_multiple * relief / f64::from(floors),
        }
        .max(1e-3);
        for b in 0..cy {
            for a in 0..cx {
                let base = match layout.cell_samples(a, b) {
                    None => (f32::NAN, f32::NAN),
                    Some((x0, y0, x1, y1)) => match cfg.floor_rule {
                        FloorRule::Layers { .. } => (stats.min, stats.min),
                        FloorRule::AboveTerrain { .. } => range(x0, y0, x1, y1),
                    },
                };
                layout.bases.push(base);
            }
        }
        layout
    }

    /// Patches per side, `2^L`.
    pub fn patches_per_side(&self) -> u32 {
        1 << self.patch_level
    }

    /// Cells in all (`cells_x cells_y floors`).
    pub fn cell_count(&self) -> usize {
        (self.cells_x * self.cells_y * self.floors) as usize
    }

    /// Index of a cell in the bake's order (floor, then row, then column).
    pub fn cell_index(&self, c: CellId) -> usize {
        ((c.k * self.cells_y + c.b) * self.cells_x + c.a) as usize
    }

    /// The cell at index `n` (inverse of [`PvsLayout::cell_index`]).
    pub fn cell_at_index(&self, n: usize) -> CellId {
        let n = n as u32;
        let a = n % self.cells_x;
        let b = (n / self.cells_x) % self.cells_y;
        CellId { a, b, k: n / (self.cells_x * self.cells_y) }
    }

    /// A plan cell's rectangle in grid coordinates (unclipped).
    pub fn cell_rect(&self, a: u32, b: u32) -> (DVec2, DVec2) {
        let r = f64::from(self.root_cells);
        let lo = DVec2::new(
            f64::from(a) * r / f64::from(self.cells_x),
            f64::from(b) * r / f64::from(self.cells_y),
        );
        let hi = DVec2::new(
            f64::from(a + 1) * r / f64::from(self.cells_x),
            f64::from(b + 1) * r / f64::from(self.cells_y),
        );
        (lo, hi)
    }

    /// A plan cell's rectangle clipped to the grid, in grid coordinates; `None` outside.
    pub fn cell_rect_clipped(&self, a: u32, b: u32) -> Option<(DVec2, DVec2)> {
        let (lo, hi) = self.cell_rect(a, b);
        let max = DVec2::new(f64::from(self.width - 1), f64::from(self.height - 1));
        let hi = hi.min(max);
        (lo.x <= hi.x && lo.y <= hi.y).then_some((lo, hi))
    }

    /// The integer sample rectangle touching a plan cell (inclusive), `None` outside.
    pub fn cell_samples(&self, a: u32, b: u32) -> Option<(u32, u32, u32, u32)> {
        let (lo, hi) = self.cell_rect_clipped(a, b)?;
        Some((lo.x.floor() as u32, lo.y.floor() as u32, hi.x.ceil() as u32, hi.y.ceil() as u32))
    }

    /// A cell's vertical extent `(z0, z1)`, metres; `None` for a cell outside the grid.
    pub fn floor_bounds(&self, c: CellId) -> Option<(f64, f64)> {
        let (bottom, top) = self.bases[(c.b * self.cells_x + c.a) as usize];
        if bottom.is_nan() {
            return None;
        }
        let (bottom, top, hh) = (f64::from(bottom), f64::from(top), self.floor_height_m);
        let k = f64::from(c.k);
        let z0 = if c.k == 0 { bottom } else { top + k * hh };
        Some((z0, top + (k + 1.0) * hh))
    }

    /// Patch `(a, b)`'s inclusive sample rectangle (clipped), `None` outside the grid.
    pub fn patch_samples(&self, level: u8, a: u32, b: u32) -> Option<(u32, u32, u32, u32)> {
        let c = self.root_cells >> level;
        let (x0, y0) = (a * c, b * c);
        if x0 > self.width - 1 || y0 > self.height - 1 {
            return None;
        }
        Some((x0, y0, (x0 + c).min(self.width - 1), (y0 + c).min(self.height - 1)))
    }

    /// The cell the camera at world position `p` is in; `None` is the paper's `Cell_other`
    /// (outside the grid's plan extent or above the top floor): no occlusion culling.
    pub fn locate(&self, p: DVec3) -> Option<CellId> {
        let g = (p.truncate() - self.origin) / self.spacing;
        let max = DVec2::new(f64::from(self.width - 1), f64::from(self.height - 1));
        if !(g.x >= 0.0 && g.y >= 0.0 && g.x <= max.x && g.y <= max.y) {
            return None;
        }
        let r = f64::from(self.root_cells);
        let a = ((g.x / r * f64::from(self.cells_x)) as u32).min(self.cells_x - 1);
        let b = ((g.y / r * f64::from(self.cells_y)) as u32).min(self.cells_y - 1);
        (0..self.floors).map(|k| CellId { a, b, k }).find(|&c| match self.floor_bounds(c) {
            Some((_, z1)) => p.z <= z1,
            None => false,
        })
    }

    /// Bit offset of pyramid level `l` within a cell's bitset: `(4^l - 1) / 3`.
    pub fn level_offset(l: u8) -> usize {
        ((1usize << (2 * l as usize)) - 1) / 3
    }

    /// How many of the finest patches holding samples a cell's bits (`bytes_per_cell` bytes,
    /// see [`Pvs::bits`]) hide: `(hidden, patches)`; `None` for a cell outside the grid.
    pub fn hidden_patches(&self, c: CellId, bits: &[u8]) -> Option<(u64, u64)> {
        self.floor_bounds(c)?;
        let (l, side) = (self.patch_level, self.patches_per_side());
        let (mut hidden, mut total) = (0u64, 0u64);
        for j in 0..side {
            for i in 0..side {
                if self.patch_samples(l, i, j).is_some() {
                    let n = Self::level_offset(l) + (j * side + i) as usize;
                    total += 1;
                    hidden += u64::from(bits[n / 8] >> (n % 8) & 1 == 0);
                }
            }
        }
        Some((hidden, total))
    }

    /// Bits per cell (all pyramid levels).
    pub fn bits_per_cell(&self) -> usize {
        Self::level_offset(self.patch_level + 1)
    }

    /// Bytes per cell.
    pub fn bytes_per_cell(&self) -> usize {
        self.bits_per_cell().div_ceil(8)
    }
}

/// A baked PVS: the layout, the mode that made it, and one pyramid of bitsets per cell.
#[derive(Debug, Clone, PartialEq)]
pub struct Pvs {
    /// Where cells and patches are.
    pub layout: PvsLayout,
    /// The test that baked it.
    pub mode: PvsMode,
    /// `bytes_per_cell` bytes per cell, in [`PvsLayout::cell_index`] order; bit `n` of a cell
    /// is byte `n / 8`, bit `n % 8`; level `l`'s bit `(i, j)` is `level_offset(l) + j 2^l + i`.
    pub bits: Vec<u8>,
}

impl Pvs {
    /// Whether node `(l, i, j)` of the pyramid (clamped to level `L`: a deeper node reads its
    /// ancestor) is visible from `cell`.
    pub fn visible(&self, cell: CellId, node: NodeId) -> bool {
        let l = self.layout.patch_level;
        let n = if node.level > l { node.ancestor(l) } else { node };
        let side = 1u32 << n.level;
        if n.i >= side || n.j >= side {
            return false;
        }
        let bit = PvsLayout::level_offset(n.level) + (n.j * side + n.i) as usize;
        let base = self.layout.cell_index(cell) * self.layout.bytes_per_cell();
        self.bits[base + bit / 8] >> (bit % 8) & 1 == 1
    }

    /// Level `l`'s image of `cell`: `2^l x 2^l` values, 1 = visible, row-major south row first.
    pub fn level_image(&self, cell: CellId, l: u8) -> Vec<u8> {
        let side = 1u32 << l;
        (0..side * side)
            .map(|n| u8::from(self.visible(cell, NodeId::new(l, n % side, n / side))))
            .collect()
    }

    /// Fraction of (cell, finest patch holding samples) pairs that are hidden, over the cells
    /// inside the grid: what culling can save.
    pub fn culled_fraction(&self) -> f64 {
        let lay = &self.layout;
        let per = lay.bytes_per_cell();
        let (mut hidden, mut total) = (0u64, 0u64);
        for n in 0..lay.cell_count() {
            let bits = &self.bits[n * per..(n + 1) * per];
            if let Some((h, t)) = lay.hidden_patches(lay.cell_at_index(n), bits) {
                (hidden, total) = (hidden + h, total + t);
            }
        }
        hidden as f64 / total.max(1) as f64
    }

    /// Whether this PVS indexes nodes the way a quadtree of geometry `qt` does (same grid and
    /// root square): the heightmap's or a baked store's.
    pub fn matches(&self, qt: &TreeShape) -> bool {
        (self.layout.width, self.layout.height, self.layout.root_cells)
            == (qt.width(), qt.height(), qt.root_cells())
    }

    /// Whether this PVS was baked from exactly these heights (and void mask): the CRC-32 it
    /// stores against `hm`'s ([`PvsLayout::heights`]).
    pub fn matches_heights(&self, hm: &Heightmap) -> bool {
        self.layout.heights == heights_checksum(hm)
    }

    /// The cull policy for a camera at `eye` (see [`PvsCull`]).
    pub fn cull_for(&self, eye: DVec3) -> PvsCull<'_> {
        PvsCull { pvs: self, cell: self.layout.locate(eye) }
    }
}

/// Occlusion culling by a PVS lookup (the PVPS paper's section 2.3.3), as a quadtree
/// [`CullPolicy`]: `Reject` for a node hidden from the camera's cell, `Accept` otherwise
/// (and always in `Cell_other`). O(1) per node.
#[derive(Debug, Clone, Copy)]
pub struct PvsCull<'a> {
    pvs: &'a Pvs,
    /// The camera's cell; `None` = `Cell_other`.
    pub cell: Option<CellId>,
}

impl CullPolicy for PvsCull<'_> {
    fn classify(&mut self, node: NodeId, _: &NodeInfo) -> Cull {
        match self.cell {
            Some(c) if !self.pvs.visible(c, node) => Cull::Reject,
            _ => Cull::Accept,
        }
    }
}
