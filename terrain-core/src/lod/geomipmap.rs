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
//! **Without the heightmap.** What the selection reads per patch is precomputed once
//! ([`GeomipTable`]: the max-error vertices, 10 bytes per patch and level) and the patches'
//! boxes come from a patch tree, any [`NodeTree`] whose leaves are the patches: the heightmap's
//! [`Quadtree`] ([`GeomipScene`]) or a baked store's tree (terrain-stream's `StoreTree` at the
//! patch size, with the table read from the store's `geomip.bin`). Same table, same boxes: the
//! same selection, bit for bit, from memory or from a store.
//!
//! **Cost follows the view.** The visible patches come from the one quadtree traversal
//! ([`crate::quadtree::traverse`], [`FrustumCull`] over the patch tree: a rejected or wholly
//! visible node decides its whole subtree). Since `c <= L` (`L`
//! = the coarsest level) and a source `q` can only lower `c'_p` when `|p - q|_1 < c_p <= L`,
//! the envelope of the drawn patches and their neighbours needs only the factors of patches
//! within `L` of a visible one: the factors and the two passes run over that window
//! (exactly the union of their city-block balls of radius `L`, as per-row spans densely
//! indexed; patches of the frame's runs there have `c = L`, see below, and are not
//! projected), so a frame costs `O(visible patches x L)`, not the grid.
//! The two-pass city-block transform (Rosenfeld & Pfaltz 1966, "Sequential operations in
//! digital picture processing"; for sampled functions, Felzenszwalb & Huttenlocher 2012) is
//! exact on the window because it holds every L-shaped path from such a source to `p`. Every
//! value is `c_q` plus `|p - q|_1` additions of `1.0` in `f32`, whatever the order, so the
//! output is bit-identical to the whole-grid transform (the tests keep it as a reference).
//!
//! **Runs: cost follows the view's detail.** Most patches in a far view are at the coarsest
//! level `L` (one quad): patch `p` is there with tween 0, every edge at `L`, exactly when
//! `c'_p = L`, which holds when every `q` with `|p - q|_1 = r < L` has `c_q >= L - r`, i.e.
//! `a_l <= 1/2` for its levels `l <= L - r` (`d >= 2 lambda delta_l / tau` for each of those
//! max-error vertices). A max pyramid over the patch grid, built with the table
//! (`CoarsePyramid`: per node and radius `r` the largest error `m_{L-r}` over its patches
//! dilated by `r`, and the projected vertices' height range), bounds that for a whole node of
//! the patch tree from the eye's distances to its dilated boxes. So
//! [`GeomipTable::select_runs`] walks the patch tree once (the frustum cull as before): a node
//! wholly in view that the bound proves all-coarsest is one [`PatchRun`] (a rectangle of
//! patches); a partly visible one goes down, unless it is at most
//! [`GeomipConfig::partial_run_patches`] wide (default 8), when it is one run too: its patches
//! outside the frustum are drawn as well (coarsest, 2 triangles each at 16 cells, clipped by the
//! GPU), so the frustum's sides cost a run per such node instead of a run or patch per visible
//! patch. Only the remaining patches get the factor window and envelope. The result expands
//! ([`GeomipRuns::expand`]) to the per-patch selection bit for bit ([`GeomipTable::select_each`]
//! computes that without runs), plus the partly visible runs' patches outside the frustum,
//! each at `L` with tween 0 and every edge at `L`, as the whole-grid selection draws it. The
//! tests check exactly that against the whole-grid reference (every patch it draws drawn the
//! same, bit for bit; every other patch drawn coarsest as it would draw it, and in a node of at
//! most `partial_run_patches` patches that the frustum does not reject), and a deliberately
//! loose bound must fail them.
//!
//! **Borders.** Each shared edge is drawn at the coarser patch's level, and its vertices follow
//! the coarser patch's tween factor ("the finer patch allows the coarser one to dictate the
//! border vertices' position"); between two patches at the same level, the larger of the two
//! factors (a symmetric choice the article leaves open: both sides must compute the same). The
//! finer patch then leaves out its odd border vertices and draws adapting triangles there.
//! [`PatchLod::edge_level`] and [`PatchLod::edge_tween`] carry this per edge; edges on the
//! grid's border follow the patch itself.

use std::cell::Cell;
use std::sync::Arc;
use std::time::Instant;

use glam::{DVec2, DVec3};

use super::geomip_pages::{PagedEntries, SelectionMemo};
use super::patch::Edge;
use super::window::SpanWindow;
use crate::geometry::Camera;
use crate::heightmap::Heightmap;
use crate::metrics::Region;
use crate::metrics::geomorph::{Reference, Triangulation, max_error_vertices_with};
use crate::quadtree::{Cull, NodeId, NodeInfo, NodeTree, Quadtree, TreeShape, select};

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
    /// A node of the patch tree at most this many patches wide that is only partly inside
    /// the frustum, and proved wholly at the coarsest level, is drawn whole as one run
    /// ([`GeomipTable::select_runs`]) instead of being split down to its visible patches: a
    /// few coarsest patches (2 triangles each at 16 cells) outside the frustum, which the GPU
    /// clips, for far fewer nodes visited and runs drawn along the frustum's sides. 0 (or
    /// 1): never, the runs hold exactly the patches the frustum keeps. Rounded down to a
    /// power of two. Default 8.
    pub partial_run_patches: u32,
}

impl Default for GeomipConfig {
    fn default() -> Self {
        Self {
            patch_cells: 16,
            pixel_threshold: 1.0,
            morph: true,
            frustum_cull: true,
            partial_run_patches: 8,
        }
    }
}

/// Per-patch precomputation without the heightmap: the max-error vertex of every level of
/// every patch (what the level choice projects), compact, so a baked store's runtime holds it
/// instead of the grid (`terrain bake` writes it as `geomip.bin`, see [`super::geomip_file`]).
///
/// Per patch and level `1..levels` (level 0 has no error: nothing is dropped): the monotone
/// error `m_L = max_{l <= L} delta_l` as an `f32` rounded *up* (never below the `f64` value, so
/// the level choice stays conservative), the vertex's true height (`f32`, as the grid holds it)
/// and its sample within the patch (`u16`: `dj (P + 1) + di`). 10 bytes per level: 40 bytes per
/// 16-cell patch (a 32769^2 grid has 2048^2 = 4.2 M patches: 168 MB; a 4097^2 grid 2.6 MB). The
/// vertex's world position is rebuilt from the patch tree's geometry at selection time
/// ([`TreeShape::grid_to_world`] of the patch's south-west sample plus the sample offsets), so
/// the table does not depend on the projected origin.
#[derive(Debug, Clone, PartialEq)]
pub struct GeomipTable {
    patch_cells: u32,
    levels: usize,
    width: u32,
    height: u32,
    nx: u32,
    ny: u32,
    /// Per patch (row-major, south first), per level `1..levels` (`levels - 1` entries per
    /// patch): the monotone error, rounded up.
    errors: Vec<f32>,
    /// Parallel to `errors`: the max-error vertex's true height (0 where there is none).
    heights: Vec<f32>,
    /// Parallel to `errors`: the vertex's sample within the patch, `dj (P + 1) + di`.
    vertices: Vec<u16>,
    /// What decides whole nodes of the patch tree at the coarsest level at once (built from
    /// the entries above whenever they change).
    pyramid: CoarsePyramid,
    /// A table read by pages from its file ([`GeomipTable::open_paged`]): the entries and
    /// the pyramid's lower levels come from there on demand, and the vectors above are empty.
    paged: Option<Arc<PagedEntries>>,
}

/// Most levels below the finest a patch has (64-cell patches: levels 1..=6).
pub(super) const MAX_LEVELS: usize = 6;

/// The first [`MAX_LEVELS`] values of `src` (at most that many levels), zero-padded: a copy
/// of fixed length, unrolled, where a `copy_from_slice` of the run's length `l` is a call to
/// `memcpy` per entry (12 % of geomorph's selection over the 32769^2 store, entries of 4-6
/// values copied 10^4-10^5 times a frame).
#[inline]
pub(super) fn first_levels<T: Copy + Default>(src: &[T]) -> [T; MAX_LEVELS] {
    std::array::from_fn(|e| src.get(e).copied().unwrap_or_default())
}

/// One patch's entries (levels `1..levels`, the first `n` slots), copied out of the table
/// whether it is held whole or read by pages.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct PatchEntries {
    pub(super) n: usize,
    pub(super) errors: [f32; MAX_LEVELS],
    pub(super) heights: [f32; MAX_LEVELS],
    pub(super) vertices: [u16; MAX_LEVELS],
    /// For a patch whose page is not here yet (a table read by pages from a remote store that
    /// does not wait): its errors are upper bounds (the coarse pyramid's) and its max-error
    /// vertices lie somewhere in the patch between these heights, so its factor is taken at
    /// the patch's box, never coarser than the entries' own factor.
    pub(super) bounded: Option<[f32; 2]>,
}

/// One node of the [`CoarsePyramid`] (its first `L` errors and its vertices' height range),
/// copied out of the table whether it is held whole or read by pages.
#[derive(Debug, Clone, Copy)]
pub(super) struct NodeBound {
    pub(super) errors: [f32; MAX_LEVELS],
    pub(super) z: [f32; 2],
}

/// One row of patches of a [`GeomipTable`] being computed ([`GeomipTable::new_with`]): opaque.
#[derive(Debug, Clone, Default)]
pub struct GeomipRow {
    errors: Vec<f32>,
    heights: Vec<f32>,
    vertices: Vec<u16>,
}

/// A table's levels (the patch's finest included) and patches per row and column, for a
/// `width` x `height` grid of samples in patches of `patch_cells` (a power of two) cells.
fn patch_grid(width: u32, height: u32, patch_cells: u32) -> (usize, u32, u32) {
    let levels = patch_cells.trailing_zeros() as usize + 1;
    let nx = (width.saturating_sub(1)).div_ceil(patch_cells).max(1);
    let ny = (height.saturating_sub(1)).div_ceil(patch_cells).max(1);
    (levels, nx, ny)
}

/// An error times a vertical exaggeration `scale`, rounded up to `f32` (still a bound): the
/// one scaling of a table's errors, whole or read by pages, so both give the same bits.
pub(super) fn scaled_error(e: f32, scale: f64) -> f32 {
    f32_at_or_above(f64::from(e) * scale)
}

/// A height times a vertical exaggeration `scale`, to the nearest `f32` (see
/// [`scaled_error`]).
pub(super) fn scaled_height(z: f32, scale: f64) -> f32 {
    (f64::from(z) * scale) as f32
}

/// The smallest `f32` at or above `e` (a conservative error bound in single precision).
fn f32_at_or_above(e: f64) -> f32 {
    let f = e as f32;
    if f64::from(f) < e { f.next_up() } else { f }
}

/// Patch cells as the geo-mipmap uses them: a power of two in `2..=64`.
fn clamp_patch_cells(patch_cells: u32) -> u32 {
    patch_cells.clamp(2, 64).next_power_of_two().min(64)
}

/// Row `pj` of patches of `p` cells (`nx` per row, `levels` levels) from `hm`, which holds the
/// grid's rows from `y_off` on (the whole grid when 0, or a band of it).
fn patch_row(hm: &Heightmap, y_off: usize, pj: u32, p: u32, nx: u32, levels: usize) -> GeomipRow {
    let n = nx as usize * (levels - 1);
    let mut out = GeomipRow {
        errors: Vec::with_capacity(n),
        heights: Vec::with_capacity(n),
        vertices: Vec::with_capacity(n),
    };
    for pi in 0..nx {
        let (x0, y0) = ((pi * p) as usize, (pj * p) as usize - y_off);
        let lv = max_error_vertices_with(
            hm,
            Region::new(x0, y0, p as usize),
            Reference::FullResolution,
            Triangulation::UnionJack,
        );
        let mut running: f64 = 0.0;
        for l in 1..levels {
            let (e, z, v) = match lv.get(l).and_then(|e| e.vertex.map(|v| (e.error, v))) {
                Some((e, vx)) => {
                    let (di, dj) = (vx.i - x0, vx.j - y0);
                    (e, vx.offset.z as f32, (dj * (p as usize + 1) + di) as u16)
                }
                None => (0.0, 0.0, 0),
            };
            running = running.max(e);
            out.errors.push(f32_at_or_above(running));
            out.heights.push(z);
            out.vertices.push(v);
        }
    }
    out
}

/// Tables of bands of a grid's rows, south first, joined into the grid's table
/// ([`GeomipTable::stack`], or its file written band by band,
/// [`super::geomip_file::GeomipEncoder`]): checks that each band fits the ones before it (the
/// same width and patch size; every band but the last spans whole rows of patches and shares
/// its top row with the next band) and adds up the grid's rows.
#[derive(Debug, Clone, Default)]
pub(super) struct BandStack {
    /// The first band's width and patch cells.
    first: Option<(u32, u32)>,
    /// Cells (rows - 1) of the bands so far.
    cells: u32,
    bands: usize,
    /// The rows of the last band when they are not whole rows of patches: it must be the last.
    last_only: Option<u32>,
}

impl BandStack {
    /// Adds the next band; the error names the band that does not fit.
    pub(super) fn add(&mut self, t: &GeomipTable) -> Result<(), String> {
        let b = self.bands;
        let (width, p) = *self.first.get_or_insert((t.width, t.patch_cells));
        if (t.width, t.patch_cells) != (width, p) {
            return Err(format!(
                "band {b}: {} samples wide in {}-cell patches, the first band {width} in {p}",
                t.width, t.patch_cells
            ));
        }
        let not_whole = |b: usize, rows: u32| {
            format!("band {b}: {rows} rows are not whole rows of {p}-cell patches")
        };
        if let Some(rows) = self.last_only {
            return Err(not_whole(b - 1, rows));
        }
        let cells = t.height.saturating_sub(1);
        if cells == 0 && b > 0 {
            return Err(not_whole(b, t.height));
        }
        if cells == 0 || !cells.is_multiple_of(p) {
            self.last_only = Some(t.height);
        }
        self.cells = self
            .cells
            .checked_add(cells)
            .filter(|&c| c < u32::MAX)
            .ok_or_else(|| format!("band {b}: 2^32 rows or more in all"))?;
        self.bands += 1;
        Ok(())
    }

    /// The grid's width, height and patch cells.
    pub(super) fn grid(&self) -> Result<(u32, u32, u32), String> {
        let (width, p) = self.first.ok_or("no band to stack")?;
        Ok((width, self.cells + 1, p))
    }
}

impl GeomipTable {
    /// The max-error vertices of every patch of `hm` (one thread). `patch_cells` is rounded to
    /// a power of two in `2..=64`.
    pub fn new(hm: &Heightmap, patch_cells: u32) -> Self {
        Self::new_with(hm, patch_cells, |row, rows| (0..rows).map(row).collect())
    }

    /// [`GeomipTable::new`] with the caller's map over the rows of patches: `map(row, rows)`
    /// must return `row(pj)` for `pj` in `0..rows`, in order (the app spreads it over threads).
    pub fn new_with<M>(hm: &Heightmap, patch_cells: u32, map: M) -> Self
    where
        M: FnOnce(&(dyn Fn(u32) -> GeomipRow + Sync), u32) -> Vec<GeomipRow>,
    {
        let p = clamp_patch_cells(patch_cells);
        let (w, h) = (hm.width() as u32, hm.height() as u32);
        let (levels, nx, ny) = patch_grid(w, h, p);
        let row = |pj: u32| patch_row(hm, 0, pj, p, nx, levels);
        let rows = map(&row, ny);
        assert_eq!(rows.len(), ny as usize, "the map returns every row");
        let mut t = Self {
            patch_cells: p,
            levels,
            width: w,
            height: h,
            nx,
            ny,
            errors: Vec::with_capacity((nx * ny) as usize * (levels - 1)),
            heights: Vec::new(),
            vertices: Vec::new(),
            pyramid: CoarsePyramid::default(),
            paged: None,
        };
        t.heights.reserve(t.errors.capacity());
        t.vertices.reserve(t.errors.capacity());
        for r in rows {
            t.errors.extend(r.errors);
            t.heights.extend(r.heights);
            t.vertices.extend(r.vertices);
        }
        t.pyramid = CoarsePyramid::new(&t);
        t
    }

    /// The table of a `width` x `height` grid read band by band, for grids larger than
    /// memory (a baked store's blocks): `band(y0, rows)` returns grid rows `y0..y0 + rows`,
    /// every column, as a heightmap (south row first; its void mask decides which samples are
    /// measured). Bands hold `band_patch_rows` rows of patches (rounded up to 1) and the
    /// sample row they share with the next band. Equal to [`GeomipTable::new`] of the whole
    /// grid when the bands are its rows. `map(row, rows)` must return `row(pj)` for `pj` in
    /// `rows` (a band's patch rows), in order (the app spreads it over threads).
    ///
    /// # Errors
    /// The first error `band` returns.
    pub fn from_bands<E, B, M>(
        (width, height): (u32, u32),
        patch_cells: u32,
        band_patch_rows: u32,
        mut band: B,
        mut map: M,
    ) -> Result<Self, E>
    where
        B: FnMut(u32, u32) -> Result<Heightmap, E>,
        M: FnMut(&(dyn Fn(u32) -> GeomipRow + Sync), std::ops::Range<u32>) -> Vec<GeomipRow>,
    {
        let p = clamp_patch_cells(patch_cells);
        let (levels, nx, ny) = patch_grid(width, height, p);
        let per_band = band_patch_rows.max(1);
        let (mut errors, mut heights, mut vertices) = (Vec::new(), Vec::new(), Vec::new());
        let mut pj0 = 0;
        while pj0 < ny {
            let pj1 = (pj0 + per_band).min(ny);
            let y0 = pj0 * p;
            let rows = (pj1 * p + 1).min(height) - y0;
            let hm = band(y0, rows.max(1))?;
            let row = |pj: u32| patch_row(&hm, y0 as usize, pj, p, nx, levels);
            let out = map(&row, pj0..pj1);
            assert_eq!(out.len(), (pj1 - pj0) as usize, "the map returns every row");
            for r in out {
                errors.extend(r.errors);
                heights.extend(r.heights);
                vertices.extend(r.vertices);
            }
            pj0 = pj1;
        }
        Ok(Self::from_parts((width, height, p), errors, heights, vertices))
    }

    /// The table of a grid from the tables of its bands of rows, south first: `parts[b]` is
    /// the table of grid rows `y_b ..= y_b + h_b - 1` as a grid of its own (the rows of
    /// its patches: a patch reads only its own samples, so its entries are the whole grid's),
    /// where each band but the last spans whole rows of patches and shares its top row with
    /// the next band. Equal to the table of the whole grid (a bake's block rows, or a
    /// sharded bake's shards, computed apart). The error says which part does not fit.
    pub fn stack(parts: Vec<GeomipTable>) -> Result<Self, String> {
        let mut bands = BandStack::default();
        for t in &parts {
            bands.add(t)?;
        }
        let (width, height, p) = bands.grid()?;
        let (mut errors, mut heights, mut vertices) = (Vec::new(), Vec::new(), Vec::new());
        for t in parts {
            errors.extend(t.errors);
            heights.extend(t.heights);
            vertices.extend(t.vertices);
        }
        Ok(Self::from_parts((width, height, p), errors, heights, vertices))
    }

    /// The patch size a table asked for `patch_cells` has: rounded to a power of two in
    /// `2..=64`.
    pub fn patch_cells_for(patch_cells: u32) -> u32 {
        clamp_patch_cells(patch_cells)
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

    /// The grid's samples along x and y.
    pub fn grid_size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Bytes the table holds in memory: 10 per patch and level below the finest, and the
    /// coarsest-level pyramid's `4 (L + 2)` per node (about 32 per 16-cell patch); a table
    /// read by pages, its pyramid's upper levels and what its caches hold now.
    pub fn memory_bytes(&self) -> usize {
        let paged = self.paged.as_ref().map_or(0, |p| p.memory_bytes());
        self.errors.len() * 10 + self.pyramid.memory_bytes() + paged
    }

    /// The table of the heights times `scale` (a vertical exaggeration, positive): each level's
    /// error is a vertical distance and its max-error vertex stays the same vertex, so the
    /// errors and the vertices' heights are multiplied by `scale` (rounded up to `f32` as the
    /// computed errors are).
    pub fn exaggerated(mut self, scale: f64) -> Self {
        if let Some(p) = &self.paged {
            // The same values, scaled as each page is decoded (the pyramid's maxima and height
            // ranges commute with these monotone roundings).
            self.paged = Some(Arc::new(p.exaggerated(scale)));
            return self;
        }
        for e in &mut self.errors {
            *e = scaled_error(*e, scale);
        }
        for h in &mut self.heights {
            *h = scaled_height(*h, scale);
        }
        self.pyramid = CoarsePyramid::new(&self);
        self
    }

    /// Whether `shape` is a patch tree this table selects over: the same grid, leaves of
    /// [`GeomipTable::patch_cells`] cells.
    pub fn fits(&self, shape: &TreeShape) -> bool {
        (shape.width(), shape.height(), shape.leaf_cells())
            == (self.width, self.height, self.patch_cells)
    }

    /// The monotone max error (metres, rounded up to `f32`) of `level` of patch `(i, j)`.
    pub fn level_error(&self, i: u32, j: u32, level: usize) -> f64 {
        if level == 0 {
            return 0.0;
        }
        f64::from(self.patch((j * self.nx + i) as usize).errors[level - 1])
    }

    /// The entries as raw parts (file encoding).
    pub(super) fn parts(&self) -> (&[f32], &[f32], &[u16]) {
        (&self.errors, &self.heights, &self.vertices)
    }

    /// A table from raw parts (file decoding; the caller has checked the counts).
    pub(super) fn from_parts(
        (width, height, patch_cells): (u32, u32, u32),
        errors: Vec<f32>,
        heights: Vec<f32>,
        vertices: Vec<u16>,
    ) -> Self {
        let mut t = Self::assemble((width, height, patch_cells), (errors, heights, vertices), None);
        debug_assert_eq!(t.errors.len(), (t.nx * t.ny) as usize * (t.levels - 1));
        t.pyramid = CoarsePyramid::new(&t);
        t
    }

    /// A table of a `width` x `height` grid in patches of `patch_cells` cells from its entries
    /// (empty when `paged` reads them), its pyramid not built yet.
    fn assemble(
        (width, height, patch_cells): (u32, u32, u32),
        (errors, heights, vertices): (Vec<f32>, Vec<f32>, Vec<u16>),
        paged: Option<Arc<PagedEntries>>,
    ) -> Self {
        let (levels, nx, ny) = patch_grid(width, height, patch_cells);
        Self {
            patch_cells,
            levels,
            width,
            height,
            nx,
            ny,
            errors,
            heights,
            vertices,
            pyramid: CoarsePyramid::default(),
            paged,
        }
    }

    /// A table whose entries and lower pyramid levels `paged` reads on demand.
    pub(super) fn from_paged(
        (width, height, patch_cells): (u32, u32, u32),
        paged: PagedEntries,
    ) -> Self {
        let none = (Vec::new(), Vec::new(), Vec::new());
        Self::assemble((width, height, patch_cells), none, Some(Arc::new(paged)))
    }

    /// The table read by pages, when it is ([`GeomipTable::open_paged`]).
    pub(super) fn paged(&self) -> Option<&PagedEntries> {
        self.paged.as_deref()
    }

    /// Patch `k`'s entries (row-major index), from memory or through the page cache (a page
    /// that cannot be read gives infinite errors, the finest level everywhere it is needed,
    /// and the error is kept for [`GeomipTable::try_select_runs`]).
    #[inline]
    pub(super) fn patch(&self, k: usize) -> PatchEntries {
        if let Some(p) = &self.paged {
            return p.patch(k);
        }
        let l = self.levels - 1;
        let e = k * l..(k + 1) * l;
        PatchEntries {
            n: l,
            errors: first_levels(&self.errors[e.clone()]),
            heights: first_levels(&self.heights[e.clone()]),
            vertices: first_levels(&self.vertices[e]),
            bounded: None,
        }
    }

    /// [`GeomipTable::node_bound_memo`] without a selection's memo.
    #[cfg(test)]
    pub(super) fn node_bound(&self, m: usize, i: u32, j: u32) -> Option<NodeBound> {
        self.node_bound_memo(m, i, j, &SelectionMemo::default())
    }

    /// The pyramid's node `m` levels above the patches at `(i, j)`: `None` outside the grid
    /// (never all-coarsest); above the pyramid's top (a store's root covers more than the
    /// grid), the top. A table read by pages asks through one selection's `memo`.
    fn node_bound_memo(&self, m: usize, i: u32, j: u32, memo: &SelectionMemo) -> Option<NodeBound> {
        match &self.paged {
            Some(p) => p.node_memo(m, i, j, memo),
            None => self.pyramid.node(m, i, j),
        }
    }

    /// [`GeomipTable::patch`] through one selection's `memo` (a table read by pages).
    fn patch_memo(&self, k: usize, memo: &SelectionMemo) -> PatchEntries {
        match &self.paged {
            Some(p) => p.patch_memo(k, memo),
            None => self.patch(k),
        }
    }

    /// The continuous factor of patch `k` before the neighbour envelope (see the module docs),
    /// for an eye at `eye` with `lambda = camera.lambda()`; vertex positions from `shape`.
    fn factor(
        &self,
        shape: &TreeShape,
        k: usize,
        (eye, lambda, tau): (DVec3, f64, f64),
        memo: &SelectionMemo,
    ) -> f32 {
        let p = self.patch_cells;
        let (pi, pj) = (k as u32 % self.nx, k as u32 / self.nx);
        let origin =
            shape.grid_to_world(DVec2::new(f64::from(pi * p), f64::from(pj * p))).extend(0.0);
        let spacing = shape.spacing();
        let entries = self.patch_memo(k, memo);
        // A patch bounded by the pyramid (its page not here yet): every level's distance the
        // box's, the nearest its vertex could be.
        let boxed = entries.bounded.map(|[z0, z1]| {
            let far = origin + DVec3::new(f64::from(p) * spacing.x, f64::from(p) * spacing.y, 0.0);
            let patch =
                crate::geometry::Aabb::new(origin.with_z(f64::from(z0)), far.with_z(f64::from(z1)));
            patch.distance(eye)
        });
        let mut c = 0.0;
        let mut prev = 1.0f64;
        for e in 0..entries.n {
            let delta = f64::from(entries.errors[e]);
            let a = if delta <= 0.0 {
                0.0
            } else if let Some(d) = boxed {
                if d <= 1e-9 { f64::INFINITY } else { lambda * delta / (tau * d) }
            } else {
                let v = u32::from(entries.vertices[e]);
                let (di, dj) = (v % (p + 1), v / (p + 1));
                let offset = DVec3::new(
                    f64::from(di) * spacing.x,
                    f64::from(dj) * spacing.y,
                    f64::from(entries.heights[e]),
                );
                let d = (origin + offset - eye).length();
                if d <= 1e-9 { f64::INFINITY } else { lambda * delta / (tau * d) }
            };
            let w = (2.0 - 2.0 * a).clamp(0.0, 1.0).min(prev);
            // `w` only falls (`min(prev)`): once a level contributes 0 every coarser one
            // does, and adding 0.0 leaves `c` as it is.
            if w <= 0.0 {
                break;
            }
            prev = w;
            c += w;
        }
        c as f32
    }
}

/// One level of a [`CoarsePyramid`]: `nx` by `ny` nodes in tiles of [`PYRAMID_TILE`] squared
/// ([`PyramidLevel::index`]); per node `L` errors (`errors[node * L + r]`, see
/// [`CoarsePyramid`]) and the height range of the vertices.
#[derive(Debug, Clone, PartialEq, Default)]
pub(super) struct PyramidLevel {
    pub(super) nx: u32,
    pub(super) ny: u32,
    pub(super) errors: Vec<f32>,
    /// Per node: lowest and highest height of a vertex carrying a positive error within
    /// `L - 1` patches (`+inf, -inf` when none).
    pub(super) z: Vec<[f32; 2]>,
}

/// Nodes per side of a [`PyramidLevel`]'s tiles. The selection walks the patch tree depth
/// first: in a row-major level the four children of a node lie a row of the grid apart (on
/// `big32k`, 2048 patches of 16 bytes), in a tile (Z order inside) side by side, and a node
/// `PYRAMID_TILE` patches wide in one tile.
const PYRAMID_TILE: usize = 8;

/// The slot of node `(i, j)` of a level `nx` nodes wide: tiles row-major, nodes in Z order in
/// each (the four children of a node side by side, as the walk visits them).
#[inline]
fn tile_index(nx: u32, i: u32, j: u32) -> usize {
    let (nx, i, j) = (nx as usize, i as usize, j as usize);
    let tile = (j / PYRAMID_TILE) * nx.div_ceil(PYRAMID_TILE) + i / PYRAMID_TILE;
    // Bits 0-2 of x spread to 0, 2, 4.
    let spread = |x: usize| (x & 1) | ((x & 2) << 1) | ((x & 4) << 2);
    tile * PYRAMID_TILE * PYRAMID_TILE
        + (spread(i % PYRAMID_TILE) | (spread(j % PYRAMID_TILE) << 1))
}

impl PyramidLevel {
    /// A level of `nx` by `ny` nodes, `l` errors each, all 0, height ranges empty.
    pub(super) fn empty(nx: u32, ny: u32, l: usize) -> Self {
        let t = PYRAMID_TILE;
        let slots = (nx as usize).div_ceil(t) * (ny as usize).div_ceil(t) * t * t;
        Self {
            nx,
            ny,
            errors: vec![0.0; slots * l],
            z: vec![[f32::INFINITY, f32::NEG_INFINITY]; slots],
        }
    }

    /// The slot of node `(i, j)` ([`tile_index`]).
    #[inline]
    pub(super) fn index(&self, i: u32, j: u32) -> usize {
        tile_index(self.nx, i, j)
    }
}

/// A max pyramid over the patch grid that proves whole nodes of the patch tree coarsest.
///
/// Patch `p` is drawn at the coarsest level `L` with tween 0 (and every edge at `L`, tween
/// 0) exactly when `c'_p = min_q (c_q + |p - q|_1) >= L`. Every factor is at least 0, so
/// only `q` with `|p - q|_1 = r < L` matter, and each needs `c_q >= L - r`, which holds when
/// its levels `1..=L - r` all have `a_l <= 1/2` (then `w_1 = ... = w_{L-r} = 1`): with the
/// monotone error `m_{L-r}` (the largest of those levels'), `d >= 2 lambda m_{L-r} / tau` for
/// each of their max-error vertices (the article's `a_L = lambda delta_L / (tau d_L)`). So
/// level 0 holds, per patch and `r` in `0..L`, the largest `m_{L-r}` over the square of
/// radius `r` patches around it (which holds the city-block ball), and the height range of
/// the projected vertices over radius `L - 1`; level `m` merges 2 x 2 nodes of level `m - 1`,
/// so a node of the patch tree at depth `max_level - m` reads one entry. The eye's distance
/// to the node's patches' plan rectangle widened by `r` patches, with that height range,
/// bounds every `d` of radius `r` from below. `4 (L + 2)` bytes per node (24 for 16-cell
/// patches, about 32 per patch).
#[derive(Debug, Clone, PartialEq, Default)]
struct CoarsePyramid {
    /// `L`, the coarsest level: errors per node.
    coarsest: usize,
    /// Level 0: one node per patch; the last level has one node.
    levels: Vec<PyramidLevel>,
}

/// `out[k] = max(v[k - r ..= k + r])` along rows (`step` 1) or columns (`step` = `nx`) of an
/// `nx` by `ny` grid, clipped to it.
pub(super) fn dilate<T: Copy>(
    v: &[T],
    (nx, ny): (usize, usize),
    r: usize,
    rows: bool,
    merge: impl Fn(T, T) -> T,
) -> Vec<T> {
    let mut out = v.to_vec();
    for j in 0..ny {
        for i in 0..nx {
            let (k, lo, hi) = if rows {
                (j * nx + i, j * nx + i.saturating_sub(r), j * nx + (i + r).min(nx - 1))
            } else {
                (j * nx + i, j.saturating_sub(r) * nx + i, (j + r).min(ny - 1) * nx + i)
            };
            let step = if rows { 1 } else { nx };
            let mut acc = v[lo];
            let mut q = lo + step;
            while q <= hi {
                acc = merge(acc, v[q]);
                q += step;
            }
            out[k] = acc;
        }
    }
    out
}

impl CoarsePyramid {
    fn new(t: &GeomipTable) -> Self {
        let l = t.levels - 1;
        let (nx, ny) = (t.nx as usize, t.ny as usize);
        let dims = (nx, ny);
        let n = nx * ny;
        // Per radius r: the largest m_{L-r} over the square of radius r, written tiled.
        let mut base = PyramidLevel::empty(t.nx, t.ny, l);
        // Allocated again once the row-major ranges below are built (peak memory).
        let z_slots = std::mem::take(&mut base.z).len();
        let slot = |k: usize| tile_index(t.nx, (k % nx) as u32, (k / nx) as u32);
        for r in 0..l {
            let own: Vec<f32> = (0..n).map(|k| t.errors[k * l + (l - r) - 1]).collect();
            let d = dilate(&dilate(&own, dims, r, true, f32::max), dims, r, false, f32::max);
            for (k, &v) in d.iter().enumerate() {
                base.errors[slot(k) * l + r] = v;
            }
        }
        let own: Vec<[f32; 2]> = (0..n)
            .map(|k| {
                let e = k * l..(k + 1) * l;
                vertex_range(&t.errors[e.clone()], &t.heights[e])
            })
            .collect();
        let r = l.saturating_sub(1);
        let z = dilate(&dilate(&own, dims, r, true, z_union), dims, r, false, z_union);
        drop(own);
        base.z = vec![[f32::INFINITY, f32::NEG_INFINITY]; z_slots];
        for (k, &v) in z.iter().enumerate() {
            base.z[slot(k)] = v;
        }
        drop(z);
        Self { coarsest: l, levels: merge_up(base, l) }
    }

    fn memory_bytes(&self) -> usize {
        levels_bytes(&self.levels)
    }

    /// The node `m` levels above the patches at `(i, j)`: `None` outside the grid (or no
    /// pyramid); above the pyramid's top (a store's root covers more than the grid), the top.
    fn node(&self, m: usize, i: u32, j: u32) -> Option<NodeBound> {
        let top = self.levels.last()?;
        let (lv, k) = match self.levels.get(m) {
            Some(lv) if i < lv.nx && j < lv.ny => (lv, lv.index(i, j)),
            Some(_) => return None,
            None => (top, 0),
        };
        Some(lv.bound(k, self.coarsest))
    }
}

/// The pyramid's levels from `base` up to one node, each merging 2 x 2 nodes of the one
/// below (`l` errors per node: their maxima; the height ranges' union).
pub(super) fn merge_up(base: PyramidLevel, l: usize) -> Vec<PyramidLevel> {
    let mut levels = vec![base];
    loop {
        let prev = levels.last().expect("level 0");
        if prev.nx == 1 && prev.ny == 1 {
            break;
        }
        let (px, py) = (prev.nx, prev.ny);
        let mut next = PyramidLevel::empty(px.div_ceil(2), py.div_ceil(2), l);
        for j in 0..next.ny {
            for i in 0..next.nx {
                let k = next.index(i, j);
                for (di, dj) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let (ci, cj) = (2 * i + di, 2 * j + dj);
                    if ci < px && cj < py {
                        next.absorb(k, prev, prev.index(ci, cj), l);
                    }
                }
            }
        }
        levels.push(next);
    }
    levels
}

/// Bytes the pyramid levels hold.
pub(super) fn levels_bytes(levels: &[PyramidLevel]) -> usize {
    levels.iter().map(|l| l.errors.len() * 4 + l.z.len() * 8).sum()
}

/// The height range (`[lowest, highest]`, `[+inf, -inf]` when none) of a patch's max-error
/// vertices that carry a positive error (`errors[k]` and `heights[k]` of one vertex each).
pub(super) fn vertex_range(errors: &[f32], heights: &[f32]) -> [f32; 2] {
    let mut z = [f32::INFINITY, f32::NEG_INFINITY];
    for (&e, &h) in errors.iter().zip(heights) {
        if e > 0.0 {
            z = [z[0].min(h), z[1].max(h)];
        }
    }
    z
}

/// The union of two height ranges (`[lowest, highest]`; `[+inf, -inf]` is empty).
pub(super) fn z_union(a: [f32; 2], b: [f32; 2]) -> [f32; 2] {
    [a[0].min(b[0]), a[1].max(b[1])]
}

impl PyramidLevel {
    /// Merges node slot `c` of `child` (the level below, `l` errors per node) into slot `k`:
    /// the errors' maxima and the height ranges' union.
    pub(super) fn absorb(&mut self, k: usize, child: &PyramidLevel, c: usize, l: usize) {
        for r in 0..l {
            self.errors[k * l + r] = self.errors[k * l + r].max(child.errors[c * l + r]);
        }
        self.z[k] = z_union(self.z[k], child.z[c]);
    }

    /// Node slot `k`'s bound (`l` errors).
    pub(super) fn bound(&self, k: usize, l: usize) -> NodeBound {
        NodeBound { errors: first_levels(&self.errors[k * l..(k + 1) * l]), z: self.z[k] }
    }
}

impl GeomipTable {
    /// Whether every patch of the node `m` levels above the patches at `(i, j)` (patch tree
    /// level `max_level - m`) is provably at the coarsest level with tween 0 for an eye at
    /// `eye` (see [`CoarsePyramid`]): for each radius `r < L`, `2 lambda e_r / tau <= d_r`
    /// (with a relative margin of `1e-6` for rounding), `d_r` the distance from the eye to the
    /// node's box widened by `r` patches. `scale` multiplies the bound's left side (1 in the
    /// selection; the tests' negative control lowers it).
    fn all_coarsest(
        &self,
        shape: &TreeShape,
        (m, i, j): (usize, u32, u32),
        eye: DVec3,
        (lambda, tau): (f64, f64),
        scale: f64,
        memo: &SelectionMemo,
    ) -> bool {
        let Some(node) = self.node_bound_memo(m, i, j, memo) else { return false };
        let errors = &node.errors[..self.levels - 1];
        if errors.iter().all(|&e| e <= 0.0) {
            return true;
        }
        let [z_lo, z_hi] = node.z;
        let p = f64::from(self.patch_cells);
        let gap = |v: f64, a: f64, b: f64| (a.min(b) - v).max(v - a.max(b)).max(0.0);
        let dz = gap(eye.z, f64::from(z_lo), f64::from(z_hi));
        errors.iter().enumerate().all(|(r, &e)| {
            if e <= 0.0 {
                return true;
            }
            let r = r as f64;
            let span = |k: u32, n: u32| -> (f64, f64) {
                let lo = (u64::from(k) << m).min(u64::from(n)) as f64;
                let hi = ((u64::from(k) + 1) << m).min(u64::from(n)) as f64;
                ((lo - r) * p, (hi + r) * p)
            };
            let (x0, x1) = span(i, self.nx);
            let (y0, y1) = span(j, self.ny);
            let lo = shape.grid_to_world(DVec2::new(x0, y0));
            let hi = shape.grid_to_world(DVec2::new(x1, y1));
            let d = DVec3::new(gap(eye.x, lo.x, hi.x), gap(eye.y, lo.y, hi.y), dz).length();
            let need = 2.0 * lambda * f64::from(e) * scale * (1.0 + 1e-6);
            need.is_finite() && need <= tau * d
        })
    }
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
    /// Patches culled: by the frustum here; a caller that culls further (a PVS) adds its own.
    pub culled: usize,
    /// CPU time of the selection, milliseconds.
    pub cpu_ms: f64,
}

/// A rectangle of patches all drawn at the coarsest level with tween 0, every edge at that
/// level (a node of the patch tree that the [`CoarsePyramid`] bound decided at once).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct PatchRun {
    /// First patch column.
    pub i: u32,
    /// First patch row.
    pub j: u32,
    /// Patches along x (at least 1).
    pub width: u32,
    /// Patches along y (at least 1).
    pub height: u32,
}

impl PatchRun {
    /// Patches in the run.
    pub fn patches(&self) -> u64 {
        u64::from(self.width) * u64::from(self.height)
    }
}

/// The selection of one frame, compact: rectangles of patches at the coarsest level
/// ([`PatchRun`]) and every other drawn patch one by one. [`GeomipRuns::expand`] gives the
/// per-patch [`GeomipSelection`], bit for bit what the per-patch computation gives.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct GeomipRuns {
    /// Runs, in the patch tree's depth-first order.
    pub runs: Vec<PatchRun>,
    /// The other drawn patches, row-major, south first.
    pub patches: Vec<PatchLod>,
    /// `c'` of each of `patches` (parallel).
    pub factors: Vec<f32>,
    /// The coarsest level `L` (every run's patches are drawn at it).
    pub coarsest: u8,
    /// Patches culled by the frustum (none are when culling is off).
    pub culled: usize,
    /// CPU time of the selection, milliseconds.
    pub cpu_ms: f64,
}

impl GeomipRuns {
    /// Patches in runs.
    pub fn run_patches(&self) -> u64 {
        self.runs.iter().map(PatchRun::patches).sum()
    }

    /// Patches drawn: in runs and one by one.
    pub fn drawn_patches(&self) -> u64 {
        self.run_patches() + self.patches.len() as u64
    }

    /// What a run's patch `(i, j)` is drawn as.
    pub fn run_patch(&self, i: u32, j: u32) -> PatchLod {
        let l = self.coarsest;
        PatchLod { i, j, level: l, tween: 0.0, edge_level: [l; 4], edge_tween: [0.0; 4] }
    }

    /// Every drawn patch one by one, row-major (costs the patches in view: for references
    /// and the renderers that take a patch list). A run's patches have `c' = L` exactly.
    pub fn expand(&self) -> GeomipSelection {
        // Bucketed by row (counts, offsets, fill), each row then ordered by column: linear in
        // the patches plus a sort of each row's few entries, no sort of the whole list.
        let Some(rows) = self
            .runs
            .iter()
            .map(|r| r.j + r.height)
            .chain(self.patches.iter().map(|p| p.j + 1))
            .max()
        else {
            return GeomipSelection {
                culled: self.culled,
                cpu_ms: self.cpu_ms,
                ..Default::default()
            };
        };
        let mut start = vec![0usize; rows as usize + 1];
        for r in &self.runs {
            for j in r.j..r.j + r.height {
                start[j as usize + 1] += r.width as usize;
            }
        }
        for p in &self.patches {
            start[p.j as usize + 1] += 1;
        }
        for j in 0..rows as usize {
            start[j + 1] += start[j];
        }
        let total = start[rows as usize];
        let l = f32::from(self.coarsest);
        let mut all = vec![(self.run_patch(0, 0), l); total];
        let mut fill = start.clone();
        for (p, &f) in self.patches.iter().zip(&self.factors) {
            all[fill[p.j as usize]] = (*p, f);
            fill[p.j as usize] += 1;
        }
        for r in &self.runs {
            for j in r.j..r.j + r.height {
                for i in r.i..r.i + r.width {
                    all[fill[j as usize]] = (self.run_patch(i, j), l);
                    fill[j as usize] += 1;
                }
            }
        }
        for j in 0..rows as usize {
            all[start[j]..start[j + 1]].sort_unstable_by_key(|(p, _)| p.i);
        }
        let (patches, factors) = all.into_iter().unzip();
        GeomipSelection { patches, factors, culled: self.culled, cpu_ms: self.cpu_ms }
    }
}

/// The geo-mipmap of a heightmap in memory: its [`GeomipTable`] and the quadtree whose leaves
/// are the patches (their boxes, for hierarchical frustum culling).
#[derive(Debug, Clone)]
pub struct GeomipScene {
    table: GeomipTable,
    /// Leaves of `patch_cells` cells: leaf `(i, j)` is patch `(i, j)`, its box the patch's
    /// samples' (min/max pyramid above).
    qt: Quadtree,
}

impl GeomipScene {
    /// Precomputes the max-error vertices of every patch of `hm`. `patch_cells` is rounded to
    /// a power of two in `2..=64`.
    pub fn new(hm: &Heightmap, patch_cells: u32) -> Self {
        Self::with_table(hm, GeomipTable::new(hm, patch_cells))
    }

    /// The scene of `hm` with a table computed (or read) elsewhere.
    ///
    /// # Panics
    /// If `table` was made for another grid size.
    pub fn with_table(hm: &Heightmap, table: GeomipTable) -> Self {
        let qt = Quadtree::new(hm, table.patch_cells());
        assert!(table.fits(qt.shape()), "a geo-mipmap table of another grid");
        Self { table, qt }
    }

    /// The per-patch table.
    pub fn table(&self) -> &GeomipTable {
        &self.table
    }

    /// The patch tree (leaves = patches).
    pub fn patch_tree(&self) -> &Quadtree {
        &self.qt
    }

    /// Cells per patch side (a power of two).
    pub fn patch_cells(&self) -> u32 {
        self.table.patch_cells()
    }

    /// Levels per patch (`log2(patch_cells) + 1`).
    pub fn levels(&self) -> usize {
        self.table.levels()
    }

    /// Patches along x and y.
    pub fn patch_counts(&self) -> (u32, u32) {
        self.table.patch_counts()
    }

    /// The monotone max error (metres) of `level` of patch `(i, j)`.
    pub fn level_error(&self, i: u32, j: u32, level: usize) -> f64 {
        self.table.level_error(i, j, level)
    }

    /// Levels, tween factors and border rules for `camera` (see the module docs):
    /// [`GeomipTable::select`] over the heightmap's patch tree.
    pub fn select(&self, camera: &Camera, cfg: &GeomipConfig) -> GeomipSelection {
        self.table.select(&self.qt, camera, cfg)
    }

    /// The compact selection ([`GeomipTable::select_runs`]) over the heightmap's patch tree.
    pub fn select_runs(&self, camera: &Camera, cfg: &GeomipConfig) -> GeomipRuns {
        self.table.select_runs(&self.qt, camera, cfg)
    }
}

/// Which nodes the selection may decide at once (the tests' negative control loosens it).
#[derive(Debug, Clone, Copy, PartialEq)]
enum RunBound {
    /// The proved bound ([`CoarsePyramid::all_coarsest`]).
    Proved,
    /// No runs: every visible patch one by one (the per-patch selection).
    Never,
    /// The proved bound with its left side times this (below 1: too optimistic).
    #[cfg(test)]
    Scaled(f64),
}

impl GeomipTable {
    /// Levels, tween factors and border rules for `camera` (see the module docs), the visible
    /// patches from `tree`, one by one: [`GeomipTable::select_runs`] expanded
    /// ([`GeomipRuns::expand`]), so its cost follows the patches in view. `cpu_ms` counts the
    /// expansion.
    ///
    /// # Panics
    /// If `tree` does not fit the table ([`GeomipTable::fits`]).
    pub fn select(
        &self,
        tree: &dyn NodeTree,
        camera: &Camera,
        cfg: &GeomipConfig,
    ) -> GeomipSelection {
        let start = Instant::now();
        let mut s = self.select_runs(tree, camera, cfg).expand();
        s.cpu_ms = start.elapsed().as_secs_f64() * 1e3;
        s
    }

    /// [`GeomipTable::select`] computing every visible patch's factor window and envelope
    /// (no runs): the per-patch computation, `O(patches in view)`; what the runs must equal.
    ///
    /// # Panics
    /// If `tree` does not fit the table ([`GeomipTable::fits`]).
    pub fn select_each(
        &self,
        tree: &dyn NodeTree,
        camera: &Camera,
        cfg: &GeomipConfig,
    ) -> GeomipSelection {
        let start = Instant::now();
        let mut s = self.select_runs_with(tree, camera, cfg, RunBound::Never).expand();
        s.cpu_ms = start.elapsed().as_secs_f64() * 1e3;
        s
    }

    /// Levels, tween factors and border rules for `camera` (see the module docs), compact:
    /// the visible patches from `tree` (a patch tree of this grid whose leaves are the
    /// patches: the heightmap's [`Quadtree`] with leaves of `patch_cells`, or a baked store's
    /// tree at that size), as runs of patches provably at the coarsest level and the other
    /// patches one by one. The one traversal ([`crate::quadtree::traverse`]) walks the tree
    /// with its frustum cull; a node wholly inside the frustum (or the leaf of a patch) that
    /// the coarsest-level pyramid proves all-coarsest (every patch at distance `r < L` of it
    /// has `c >= L - r`, see `CoarsePyramid`) is one run; so is a partly visible one at most
    /// [`GeomipConfig::partial_run_patches`] wide (its patches outside the frustum are drawn
    /// too: each at the coarsest level with tween 0, as the whole-grid selection would draw
    /// it, and within such a node that the frustum does not reject); a wider partly visible
    /// node goes down (with `partial_run_patches` 0 the runs hold exactly the patches the
    /// frustum keeps, no extra triangles). The remaining patches get
    /// the exact computation (factor window within `L` of them, envelope). The cost follows
    /// the view's detail: the nodes along the frustum's sides and the patches near the eye.
    /// The same table and tree boxes give the same selection whatever holds them.
    ///
    /// # Panics
    /// If `tree` does not fit the table ([`GeomipTable::fits`]).
    pub fn select_runs(
        &self,
        tree: &dyn NodeTree,
        camera: &Camera,
        cfg: &GeomipConfig,
    ) -> GeomipRuns {
        self.select_runs_with(tree, camera, cfg, RunBound::Proved)
    }

    fn select_runs_with(
        &self,
        tree: &dyn NodeTree,
        camera: &Camera,
        cfg: &GeomipConfig,
        bound: RunBound,
    ) -> GeomipRuns {
        let start = Instant::now();
        if let Some(p) = &self.paged {
            p.new_frame();
        }
        let shape = tree.shape();
        assert!(
            self.fits(shape),
            "a patch tree of {} x {} samples with {}-cell leaves for a geo-mipmap table of {} x \
             {} samples with {}-cell patches",
            shape.width(),
            shape.height(),
            shape.leaf_cells(),
            self.width,
            self.height,
            self.patch_cells
        );
        let tau = cfg.pixel_threshold.max(1e-9);
        let (nx, ny) = (self.nx as usize, self.ny as usize);
        let (eye, lambda) = (camera.position, camera.lambda());
        let top = shape.max_level();
        // The page and pyramid tile asked last, for the next node or patch (a table read by
        // pages: its cache's lock and map asked once per run of them, not per node).
        let memo = SelectionMemo::default();
        let coarse = |n: NodeId| -> bool {
            let scale = match bound {
                RunBound::Proved => 1.0,
                RunBound::Never => return false,
                #[cfg(test)]
                RunBound::Scaled(s) => s,
            };
            let m = usize::from(top - n.level);
            self.all_coarsest(shape, (m, n.i, n.j), eye, (lambda, tau), scale, &memo)
        };
        // The cull policy notes its verdict on the node the split policy is asked about next
        // (a node below a wholly visible one is not classified: it is inside).
        let verdict = Cell::new(None::<(NodeId, Cull)>);
        let frustum = camera.frustum();
        let mut cull = |n: NodeId, info: &NodeInfo| -> Cull {
            let c = if cfg.frustum_cull {
                Cull::from(frustum.classify(&info.aabb))
            } else {
                Cull::AcceptAll
            };
            verdict.set(Some((n, c)));
            c
        };
        // Partly visible nodes up to this level above the patches may be runs whole.
        let partial_levels = cfg.partial_run_patches.max(1).ilog2();
        let mut split = |n: NodeId, _: &NodeInfo| -> bool {
            let partly = matches!(verdict.get(), Some((v, c)) if v == n && c != Cull::AcceptAll);
            if partly && u32::from(top - n.level) > partial_levels {
                return true;
            }
            !coarse(n)
        };
        let mut nodes = Vec::new();
        tree.with_traversal_source(&mut |src| nodes = select(src, &mut split, &mut cull));
        let mut runs = Vec::new();
        let mut cells = Vec::new();
        for n in nodes {
            if n.level < top || coarse(n) {
                let m = u32::from(top - n.level);
                let clip = |k: u32, cnt: usize| {
                    let lo = (u64::from(k) << m).min(cnt as u64);
                    let hi = ((u64::from(k) + 1) << m).min(cnt as u64);
                    (lo as u32, (hi - lo) as u32)
                };
                let ((i, width), (j, height)) = (clip(n.i, nx), clip(n.j, ny));
                if width > 0 && height > 0 {
                    runs.push(PatchRun { i, j, width, height });
                }
            } else {
                cells.push((n.i as usize, n.j as usize));
            }
        }
        let view = (eye, lambda, tau);
        let (patches, factors) = self.exact_patches(shape, (&cells, &runs), view, cfg, &memo);
        let mut out = GeomipRuns {
            runs,
            patches,
            factors,
            coarsest: (self.levels - 1) as u8,
            culled: 0,
            cpu_ms: 0.0,
        };
        if cfg.frustum_cull {
            out.culled = nx * ny - out.drawn_patches() as usize;
        }
        out.cpu_ms = start.elapsed().as_secs_f64() * 1e3;
        out
    }

    /// The exact computation for the patches `cells` (column, row): factors over the window
    /// within `L` of them, the envelope there, levels, tweens and borders (module docs).
    /// Returns them row-major with their `c'`. `runs` are the frame's runs: their patches
    /// have `c = L` (the bound that made them runs proves every level's `w = 1`), so the
    /// window's patches in them take `L` without the projection.
    fn exact_patches(
        &self,
        shape: &TreeShape,
        (cells, runs): (&[(usize, usize)], &[PatchRun]),
        view: (DVec3, f64, f64),
        cfg: &GeomipConfig,
        memo: &SelectionMemo,
    ) -> (Vec<PatchLod>, Vec<f32>) {
        let (nx, ny) = (self.nx as usize, self.ny as usize);
        // Every patch within `L` of a visible one (see the module docs), densely indexed: the
        // union of their city-block balls, per row as spans (a row's hull would hold, between
        // visible patches on both sides of the view, every run patch between them).
        let max_level = self.levels - 1;
        let (win, cells) = SpanWindow::dilated(cells, max_level, nx, ny);
        let coarsest = max_level as f32;
        // NaN: not known yet (a factor is never NaN: each `w` is clamped, then `min(prev)`).
        let mut c = vec![f32::NAN; win.len()];
        for r in runs {
            let (i0, i1) = (r.i as usize, (r.i + r.width) as usize - 1);
            for j in r.j as usize..(r.j + r.height) as usize {
                let row = win.row(j);
                let first = row.partition_point(|&(_, hi, _)| hi < i0);
                for &(lo, hi, off) in row[first..].iter().take_while(|&&(lo, _, _)| lo <= i1) {
                    let (a, b) = (lo.max(i0), hi.min(i1));
                    c[off + a - lo..=off + b - lo].fill(coarsest);
                }
            }
        }
        for (j, row) in win.rows() {
            for &(lo, hi, off) in row {
                for i in lo..=hi {
                    let k = off + i - lo;
                    if c[k].is_nan() {
                        c[k] = self.factor(shape, j * nx + i, view, memo);
                    }
                }
            }
        }
        // Lower envelope c'_p = min_q (c_q + |p - q|_1): forward then backward pass. Spans are
        // maximal, so a slot's west (east) neighbour in the window is the slot before (after).
        for (j, row) in win.rows() {
            let mut below = 0;
            for &(lo, hi, off) in row {
                for i in lo..=hi {
                    let k = off + i - lo;
                    if i > lo {
                        c[k] = c[k].min(c[k - 1] + 1.0);
                    }
                    if let Some(b) = j.checked_sub(1).and_then(|jb| win.index_up(i, jb, &mut below))
                    {
                        c[k] = c[k].min(c[b] + 1.0);
                    }
                }
            }
        }
        for (j, row) in win.rows().rev() {
            let mut above = usize::MAX;
            for &(lo, hi, off) in row.iter().rev() {
                for i in (lo..=hi).rev() {
                    let k = off + i - lo;
                    if i < hi {
                        c[k] = c[k].min(c[k + 1] + 1.0);
                    }
                    if let Some(a) = win.index_down(i, j + 1, &mut above) {
                        c[k] = c[k].min(c[a] + 1.0);
                    }
                }
            }
        }
        let level_tween = |k: usize| -> (u8, f32) {
            let ck = c[k].clamp(0.0, coarsest);
            // `ck >= 0`: truncation is `floor` (without the libm call `floor` is here).
            let l = f32::from(ck as u8);
            let t = if cfg.morph && l < coarsest { ck - l } else { 0.0 };
            (l as u8, t)
        };
        // Row-major output: the visible patches sorted, their rows and the two beside them
        // looked up through cursors (columns ascending within a row).
        let mut patches = Vec::with_capacity(cells.len());
        let mut factors = Vec::with_capacity(cells.len());
        let mut row_j = usize::MAX;
        let mut cursors = [0usize; 3];
        let mut last = None;
        for &(i, j) in &cells {
            if last == Some((i, j)) {
                continue;
            }
            last = Some((i, j));
            if j != row_j {
                (row_j, cursors) = (j, [0; 3]);
            }
            let k = win.index_up(i, j, &mut cursors[1]).expect("a visible patch is in the window");
            let (level, tween) = level_tween(k);
            let mut edge_level = [level; 4];
            let mut edge_tween = [tween; 4];
            for e in Edge::ALL {
                let (di, dj) = e.direction().step();
                let (qi, qj) = (i as i64 + di, j as i64 + dj);
                if qi < 0 || qj < 0 || qi >= nx as i64 || qj >= ny as i64 {
                    continue;
                }
                let q = match dj {
                    0 => Some((k as i64 + di) as usize),
                    -1 => win.index_up(i, j - 1, &mut cursors[0]),
                    _ => win.index_up(i, j + 1, &mut cursors[2]),
                };
                let q = q.expect("neighbours are in the window");
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
        (patches, factors)
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
        let p = scene.patch_cells() as usize;
        let mut boxes = Vec::new();
        for pj in 0..scene.patch_counts().1 as usize {
            for pi in 0..scene.patch_counts().0 as usize {
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
        let (nx, ny) = scene.patch_counts();
        let (nx, ny) = (nx as usize, ny as usize);
        let (eye, lambda) = (camera.position, camera.lambda());
        let shape = scene.patch_tree().shape();
        let mut c: Vec<f32> = (0..nx * ny)
            .map(|k| scene.table().factor(shape, k, (eye, lambda, tau), &Default::default()))
            .collect();
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
        let max_level = (scene.levels() - 1) as f32;
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

    /// Rows `y0..y0 + rows` of `hm` as a grid of their own (with their voids).
    fn rows_of(hm: &Heightmap, y0: usize, rows: usize) -> Heightmap {
        let w = hm.width();
        let data = hm.data()[y0 * w..(y0 + rows) * w].to_vec();
        let mut voids = crate::heightmap::VoidMask::new(w, rows);
        for j in 0..rows {
            for i in 0..w {
                voids.set(i, j, hm.voids().get(i, y0 + j));
            }
        }
        Heightmap::new(w, rows, data, voids, hm.georef().clone()).unwrap()
    }

    #[test]
    fn the_tables_of_bands_stacked_are_the_whole_grids_table() {
        // 97 x 75 samples: the last band is not whole patches; some voids.
        let mut hm = FractalConfig::with_size(97, 75, 10.0).to_heightmap().unwrap();
        let (w, h, data, mut voids, g) = hm.clone().into_parts();
        for i in 20..30 {
            voids.set(i, 40, true);
        }
        hm = Heightmap::new(w, h, data, voids, g).unwrap();
        let whole = GeomipTable::new(&hm, 8);
        for band in [8usize, 16, 32, 64] {
            let mut parts = Vec::new();
            let mut y0 = 0;
            while y0 + 1 < h {
                let rows = (band + 1).min(h - y0);
                parts.push(GeomipTable::new(&rows_of(&hm, y0, rows), 8));
                y0 += band;
            }
            assert_eq!(GeomipTable::stack(parts).unwrap(), whole, "bands of {band} rows");
        }
        // Negative control: a band whose rows are not whole patches is refused, and a band of
        // other heights gives another table.
        let parts = vec![
            GeomipTable::new(&rows_of(&hm, 0, 13), 8),
            GeomipTable::new(&rows_of(&hm, 12, 63), 8),
        ];
        assert!(GeomipTable::stack(parts).unwrap_err().contains("band 0"));
        let parts = vec![
            GeomipTable::new(&rows_of(&hm, 0, 33), 8),
            GeomipTable::new(&rows_of(&hm, 0, 43), 8),
        ];
        assert_ne!(GeomipTable::stack(parts).unwrap(), whole);
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

    /// Checks a selection `fast` that draws partly visible nodes whole against the per-patch
    /// one: `slow` (what the frustum keeps, with each patch's `c'` in `slow_factors`) and
    /// `all` (every patch of the grid row-major, culling off, `c'` parallel). Every patch
    /// `slow` draws, `fast` draws with the same level, tween, edge levels and tweens and `c'`,
    /// bit for bit; every other patch `fast` draws is one `slow` culls, drawn as `all` draws
    /// it, at the coarsest level `L` with tween 0, every edge at `L` (`c' = L`), and lies in
    /// the node `cfg.partial_run_patches` patches wide around it, whose box the frustum does
    /// not reject (the extra patches touch the frustum). Returns the extra patches.
    #[allow(clippy::too_many_arguments)]
    fn check_covers(
        fast: &GeomipSelection,
        slow: &GeomipSelection,
        slow_factors: &[f32],
        all: &GeomipSelection,
        tree: &dyn NodeTree,
        cam: &Camera,
        cfg: &GeomipConfig,
        coarsest: u8,
    ) -> Result<usize, String> {
        let nx = all.patches.iter().take_while(|p| p.j == 0).count();
        let want: std::collections::HashMap<(u32, u32), _> = slow
            .patches
            .iter()
            .zip(slow_factors)
            .map(|(p, f)| ((p.i, p.j), (bits(p), f.to_bits())))
            .collect();
        let (mut seen, mut extra) = (0, 0);
        let top = tree.shape().max_level();
        let lg = cfg.partial_run_patches.max(1).ilog2();
        let frustum = cam.frustum();
        for (p, f) in fast.patches.iter().zip(&fast.factors) {
            let got = (bits(p), f.to_bits());
            if let Some(w) = want.get(&(p.i, p.j)) {
                if *w != got {
                    return Err(format!("{p:?}: {got:?} where the per-patch selection has {w:?}"));
                }
                seen += 1;
                continue;
            }
            extra += 1;
            let k = p.j as usize * nx + p.i as usize;
            let whole = (bits(&all.patches[k]), all.factors[k].to_bits());
            let l = coarsest;
            let coarse = PatchLod { level: l, tween: 0.0, edge_level: [l; 4], ..*p };
            if got != whole || got != (bits(&coarse), f32::from(l).to_bits()) {
                return Err(format!("extra patch {p:?} (c' {f}) is not the coarsest {whole:?}"));
            }
            if lg == 0 || top < lg as u8 {
                return Err(format!("extra patch {p:?} without partly visible runs"));
            }
            let node = NodeId::new(top - lg as u8, p.i >> lg, p.j >> lg);
            let b = tree.node_info(node).ok_or("no node")?.aabb;
            if frustum.classify(&b) == crate::geometry::Classification::Outside {
                return Err(format!("extra patch {p:?} in {node:?}, outside the frustum"));
            }
        }
        if seen != slow.patches.len() {
            return Err(format!("{} of {} patches drawn", seen, slow.patches.len()));
        }
        if fast.culled + extra != slow.culled {
            return Err(format!("culled {} + {extra} extra, not {}", fast.culled, slow.culled));
        }
        Ok(extra)
    }

    /// Asserts the fast selection equals the whole-grid reference for many cameras: inside,
    /// above and outside the grid, looking every way, near and far clip planes that leave
    /// holes and empty views, several thresholds, morph on and off, culling on and off.
    /// Returns the patches drawn in runs and the extra (partly visible runs') patches.
    fn assert_matches_reference(hm: &Heightmap, patch_cells: u32, cameras: usize) -> (u64, usize) {
        let scene = GeomipScene::new(hm, patch_cells);
        let boxes = boxes(&scene, hm);
        let (w, h) = (hm.width() as f64, hm.height() as f64);
        let zmax = f64::from(hm.data().iter().copied().fold(f32::MIN, f32::max));
        let mut unit = crate::test_support::unit_rng(0x2545_f491_4f6c_dd1d);
        let (mut drawn, mut some_culled, mut some_empty) = (0, false, false);
        let (mut in_runs, mut one_by_one, mut extras) = (0u64, 0usize, 0usize);
        for k in 0..cameras {
            let gx = -0.3 * w + 1.6 * w * unit();
            let gy = -0.3 * h + 1.6 * h * unit();
            let mut z = zmax * (0.1 + 3.0 * unit() * unit()) + 5.0;
            if k % 11 == 5 {
                z *= 300.0; // far above: most of the grid at the coarsest level
            }
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
                // Partly visible nodes as runs up to 1 (never), 2, 8 and 64 patches wide.
                partial_run_patches: [8, 1, 2, 64][k % 4],
            };
            let runs = scene.select_runs(&cam, &cfg);
            in_runs += runs.run_patches();
            one_by_one += runs.patches.len();
            let fast = runs.expand();
            let slow = select_reference(&scene, &boxes, &cam, &cfg);
            let all = select_reference(
                &scene,
                &boxes,
                &cam,
                &GeomipConfig { frustum_cull: false, ..cfg },
            );
            let nx = scene.patch_counts().0 as usize;
            let slow_factors: Vec<f32> = slow
                .patches
                .iter()
                .map(|p| slow.factors[p.j as usize * nx + p.i as usize])
                .collect();
            let tree = scene.patch_tree();
            let coarsest = (scene.levels() - 1) as u8;
            let extra = check_covers(&fast, &slow, &slow_factors, &all, tree, &cam, &cfg, coarsest)
                .unwrap_or_else(|e| panic!("camera {k}: {e}"));
            if cfg.partial_run_patches <= 1 {
                assert_eq!(extra, 0, "camera {k}");
            }
            extras += extra;
            drawn += fast.patches.len();
            some_culled |= fast.culled > 0 && !fast.patches.is_empty();
            some_empty |= fast.patches.is_empty();
        }
        // The cameras exercised partial views and empty ones, runs and single patches.
        assert!(drawn > 0 && some_culled && some_empty, "{drawn} {some_culled} {some_empty}");
        assert!(one_by_one > 0, "no patch outside runs");
        (in_runs, extras)
    }

    /// A real DEM of the shared data folder (`$TERRAIN_DATA`, else `../shared/data` beside
    /// the workspace).
    fn real_dem(rel: &str) -> Heightmap {
        let dir = std::env::var_os("TERRAIN_DATA").map_or_else(
            || std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"),
            std::path::PathBuf::from,
        );
        let path = dir.join(rel);
        crate::dem::load(&path, &crate::dem::LoadOptions::default())
            .unwrap_or_else(|e| panic!("{} (set TERRAIN_DATA): {e}", path.display()))
            .heightmap
    }

    #[test]
    fn runs_expand_to_the_per_patch_selection_on_real_dems_with_voids() {
        // Non-square, projected, with voids; and a steep geographic grid with voids.
        let a = assert_matches_reference(&real_dem("big_tujunga/bigtujunga.tif"), 16, 60);
        let b = assert_matches_reference(&real_dem("srtm/mt_rainier_90m.tif"), 16, 40);
        assert!(a.0 > 0 && b.0 > 0, "runs were exercised: {a:?} {b:?}");
        assert!(a.1 + b.1 > 0, "partly visible runs were exercised: {a:?} {b:?}");
    }

    /// `select_runs` of `cfg` expanded, checked against `select_each` (no runs: the per-patch
    /// computation) with [`check_covers`]; a `bound` other than the proved one for the
    /// negative control. Returns the patches in runs and the extra patches.
    fn check_against_each(
        scene: &GeomipScene,
        cam: &Camera,
        cfg: &GeomipConfig,
        bound: RunBound,
    ) -> Result<(u64, usize), String> {
        let tree = scene.patch_tree();
        let runs = scene.table().select_runs_with(tree, cam, cfg, bound);
        let fast = runs.expand();
        let slow = scene.table().select_each(tree, cam, cfg);
        let all =
            scene.table().select_each(tree, cam, &GeomipConfig { frustum_cull: false, ..*cfg });
        let coarsest = (scene.levels() - 1) as u8;
        check_covers(&fast, &slow, &slow.factors, &all, tree, cam, cfg, coarsest)
            .map(|extra| (runs.run_patches(), extra))
    }

    #[test]
    fn runs_expand_to_the_per_patch_selection_without_the_shortcut() {
        // select_each (no runs) and select (runs expanded) agree on a large flat-ish grid.
        let hm = FractalConfig::with_size(1025, 769, 10.0).to_heightmap().unwrap();
        let scene = GeomipScene::new(&hm, 16);
        let mut unit = crate::test_support::unit_rng(0x9e37_79b9_7f4a_7c15);
        let (mut in_runs, mut extras) = (0, 0);
        for k in 0..30 {
            let z = [60.0, 600.0, 6000.0, 60000.0][k % 4];
            let p = hm.grid_to_world(1100.0 * unit() - 40.0, 820.0 * unit() - 30.0).extend(z);
            let cam = Camera::from_yaw_pitch(p, 360.0 * unit(), -60.0 * unit())
                .with_viewport(1280.0, 720.0);
            let cfg =
                GeomipConfig { partial_run_patches: [8, 0, 32][k % 3], ..GeomipConfig::default() };
            let (r, e) = check_against_each(&scene, &cam, &cfg, RunBound::Proved)
                .unwrap_or_else(|e| panic!("camera {k}: {e}"));
            in_runs += r;
            extras += e;
        }
        assert!(in_runs > 0 && extras > 0, "{in_runs} {extras}");
    }

    #[test]
    fn a_too_optimistic_bound_breaks_the_equality() {
        // Negative control: claiming nodes coarsest at a fiftieth of the proved distance
        // must give a selection that differs from the per-patch one for some camera, with
        // partly visible nodes drawn whole or not.
        let hm = FractalConfig::with_size(513, 513, 10.0).to_heightmap().unwrap();
        let scene = GeomipScene::new(&hm, 16);
        for partial_run_patches in [0, 8] {
            let cfg = GeomipConfig { partial_run_patches, ..GeomipConfig::default() };
            let mut differs = 0;
            for (x, y, z) in [
                (10.0, 10.0, 300.0),
                (256.0, 256.0, 2000.0),
                (-50.0, 100.0, 800.0),
                (0.0, 0.0, 20000.0),
            ] {
                let p = hm.grid_to_world(x, y).extend(z);
                let cam = Camera::from_yaw_pitch(p, 45.0, -20.0).with_viewport(1280.0, 720.0);
                check_against_each(&scene, &cam, &cfg, RunBound::Proved).unwrap();
                let loose = check_against_each(&scene, &cam, &cfg, RunBound::Scaled(0.02));
                differs += usize::from(loose.is_err());
            }
            assert!(differs > 0, "a loose bound went unnoticed ({partial_run_patches})");
        }
    }

    #[test]
    fn view_bounded_selection_equals_the_whole_grid_reference_on_a_fractal_grid() {
        let hm = FractalConfig::with_size(513, 513, 10.0).to_heightmap().unwrap();
        let a = assert_matches_reference(&hm, 16, 120);
        let b = assert_matches_reference(&hm, 8, 40);
        assert!(a.0 > 0 && b.0 > 0, "runs were exercised: {a:?} {b:?}");
        assert!(a.1 + b.1 > 0, "partly visible runs were exercised: {a:?} {b:?}");
    }

    #[test]
    fn view_bounded_selection_equals_the_whole_grid_reference_on_an_odd_grid() {
        // Neither side a multiple of the patch: the last patches are clipped.
        let hm = FractalConfig::with_size(301, 203, 30.0).to_heightmap().unwrap();
        // (32-cell patches: 5 levels over a grid of 10 x 7 patches, too small for runs.)
        let a = assert_matches_reference(&hm, 16, 120);
        assert_matches_reference(&hm, 32, 40);
        assert!(a.0 > 0, "runs were exercised");
    }
}
