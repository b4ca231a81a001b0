//! The DSS paper's (Zhang 2019, section 4) two comparison paths, with the paper's error metric
//! ("we used the same error control metric for the three methods"): per-node object-space
//! errors for the 32 even factors, the view-angle screen error (Eq. 3) and the continuous
//! factor `F_thr` (Eq. 4), from [`crate::metrics::dss`].
//!
//! - **Method I** ([`select_dss_power_of_two`], "a quadtree based algorithm using power of two
//!   as tessellation levels", after its ref. 9): the quadtree splits a node while even the
//!   finest factor misses the threshold (`rho_32 > rho_thr`, section 3.3.1); the leaves are
//!   balanced; each leaf's `F_thr` is rounded *up* to a power of two (2, 4, ..., 64), so the
//!   rounding never raises the error above the threshold.
//! - **Method II** ([`select_dss_uniform`], "a continuous LOD algorithm dividing the terrain
//!   with uniform patterns", after its ref. 60): every block at one level
//!   ([`DssConfig::uniform_block_cells`]), each with its continuous `F_thr` (64 when even 64
//!   misses the threshold: a uniform block cannot split).
//!
//! **Shared edges** (see [`super::edges`]). A same-level edge takes the **max** of the two
//! blocks' factors: each block's factor is the smallest that meets the threshold for that
//! block, so the max meets it on both sides, whereas the min would leave the finer block's
//! border coarser than its own error bound allows; the max of two continuous factors is still
//! continuous (no popping from the edge rule). Method I's factors are powers of two, so the max
//! is one too. Where levels differ (Method I only), the coarse edge takes the max of its own
//! factor and each finer neighbour's factor scaled to the coarse edge (`2^d F`), rounded up to a
//! power of two and at least `2^(d + 1)`, and the finer patches take it divided by `2^d`.
//! Edges with no neighbour keep the block's own factor. Inner factors are the block's own.
//!
//! `D` in Eq. 3 is the distance from the eye to the node's box (0 inside: must split), and the
//! view direction whose angle with the block normal (+z) Eq. 3's `sin(theta)` measures is the
//! direction from the eye to the box centre (the block as seen; the paper's Fig. 13 measures
//! `d` and `theta` per block). Straight-down views are floored by
//! [`crate::metrics::screen::MIN_VIEW_SIN`].

use crate::quadtree::{NodeTree, TreeShape};
use std::cell::RefCell;
use std::sync::Arc;
use std::time::Instant;

use super::dss_pages::{DssPages, DssPagingStats, Page};
use super::edges::pow2_up;
use super::edges::wish_outer_factors;
use super::patch::{Edge, MAX_FACTOR, Patch, Selection, SelectionStats};
use super::run;
use super::window::RowWindow;
use crate::geometry::Camera;
use crate::heightmap::Heightmap;
use crate::metrics::Region;
use crate::metrics::dss::{
    FACTORS, ObjectErrorsAcc, RowBand, SampleRows, Tessellation, object_errors,
    tessellation_factor_of,
};
use crate::metrics::screen;
use crate::quadtree::{NoCull, NodeId, NodeInfo, Quadtree, SplitToLevel};

/// Settings of the DSS comparison methods.
#[derive(Debug, Clone, PartialEq)]
pub struct DssConfig {
    /// Screen-space error threshold `rho_thr` in pixels. Default 1 (the paper's experiments).
    pub rho_thr: f64,
    /// Cells per side of a finest node, for [`DssConfig::quadtree`]. Default 16.
    pub leaf_cells: u32,
    /// Method II's block side in cells (a power of two; its level is
    /// `log2(root_cells / uniform_block_cells)`, capped at the quadtree's finest). Default 64.
    pub uniform_block_cells: u32,
    /// Whether to cull node boxes against the view frustum (the paper's hierarchical culling,
    /// section 3.3.2, first step). Default true.
    pub frustum_cull: bool,
    /// The floor of Eq. 3's `sin(theta)` ([`screen::view_sin_floored`]; not the paper's, which
    /// has none). Default [`screen::MIN_VIEW_SIN`] (0.25).
    pub view_angle_floor: f64,
}

impl Default for DssConfig {
    fn default() -> Self {
        Self {
            rho_thr: 1.0,
            leaf_cells: 16,
            uniform_block_cells: 64,
            frustum_cull: true,
            view_angle_floor: screen::MIN_VIEW_SIN,
        }
    }
}

impl DssConfig {
    /// The quadtree the selections run on: `Quadtree::new(hm, leaf_cells)`.
    pub fn quadtree(&self, hm: &Heightmap) -> Quadtree {
        Quadtree::new(hm, self.leaf_cells)
    }
}

/// The paper's preprocessing: the 32 mean object-space errors (`delta_i`, factors 2..=64) of
/// every node of a quadtree (section 3.3.1), from [`object_errors`] over the node's clipped
/// samples.
#[derive(Debug, Clone, PartialEq)]
pub struct DssErrorTable {
    pub(super) root_cells: u32,
    /// Per level: nodes per row, and the errors row-major (row 0 south). Empty when read by
    /// pages.
    pub(super) levels: Vec<(u32, Vec<[f64; FACTORS]>)>,
    /// A store's table read by pages ([`DssErrorTable::open_paged`]) instead of `levels`.
    pub(super) paged: Option<Arc<DssPages>>,
}

impl DssErrorTable {
    /// The table of the heights times `scale` (a vertical exaggeration): every object-space
    /// error is a vertical distance (section 3.3.1's mean vertical deviation), linear in the
    /// heights, so each is multiplied by `scale`.
    pub fn exaggerated(mut self, scale: f64) -> Self {
        if let Some(p) = &self.paged {
            self.paged = Some(Arc::new(p.exaggerated(scale)));
        }
        for (_, nodes) in &mut self.levels {
            for e in nodes.iter_mut().flatten() {
                *e *= scale;
            }
        }
        self
    }

    /// Computes every node's errors. Cost: about `32 x samples x levels` sample updates
    /// (seconds for a 4097 x 4097 grid; see [`DssErrorTable::new_with`] to spread it over
    /// threads).
    pub fn new(hm: &Heightmap, qt: &Quadtree) -> Self {
        Self::new_with(hm, qt, |rows, f| rows.iter().map(f).collect())
    }

    /// As [`DssErrorTable::new`], with the caller's `map` over the rows of nodes: `map(rows,
    /// f)` must return `rows.iter().map(f).collect()`, in order, however it spreads the calls
    /// (terrain-core knows nothing of threads; the app passes a rayon `par_iter` and counts
    /// progress in `f`'s wrapper). A row is `(level, j)`: the nodes `(level, 0..nx, j)`.
    pub fn new_with<M>(hm: &Heightmap, qt: &Quadtree, map: M) -> Self
    where
        M: FnOnce(
            &[(u8, u32)],
            &(dyn Fn(&(u8, u32)) -> Vec<[f64; FACTORS]> + Sync),
        ) -> Vec<Vec<[f64; FACTORS]>>,
    {
        assert_eq!((hm.width() as u32, hm.height() as u32), (qt.width(), qt.height()));
        let dims = |level: u8| Self::level_dims(qt.shape(), level);
        let rows: Vec<(u8, u32)> = (0..=qt.max_level())
            .flat_map(|level| (0..dims(level).2).map(move |j| (level, j)))
            .collect();
        let row = |&(level, j): &(u8, u32)| -> Vec<[f64; FACTORS]> {
            let (c, nx, _) = dims(level);
            (0..nx)
                .map(|i| {
                    let r = Region::new((i * c) as usize, (j * c) as usize, c as usize);
                    object_errors(hm, r).avg
                })
                .collect()
        };
        let computed = map(&rows, &row);
        assert_eq!(computed.len(), rows.len(), "DssErrorTable::new_with: map dropped rows");
        let mut levels: Vec<(u32, Vec<[f64; FACTORS]>)> = Self::shape(qt.shape())
            .into_iter()
            .map(|(nx, n)| (nx, Vec::with_capacity(n)))
            .collect();
        for (&(level, _), v) in rows.iter().zip(computed) {
            levels[level as usize].1.extend(v);
        }
        Self { root_cells: qt.root_cells(), levels, paged: None }
    }

    /// [`DssErrorTable::new`] for a grid that is not in memory: its rows are read through
    /// `read(j0, rows, heights, voids)` (full-width rows `j0..j0 + rows`, south first) in
    /// bands of at most `budget.band_rows` rows, and the result is the same table bit for bit
    /// (every node is an [`ObjectErrorsAcc`], which gives [`object_errors`]'s bits whatever the
    /// bands). Also returns the heights' checksum ([`super::dss_file::heights_checksum`] of
    /// the rows read), which [`DssErrorTable::encode_for`] writes.
    ///
    /// One sweep over the rows, in bands of the coarsest *small* level's node rows (a small
    /// level's nodes fit a band: `cells + 2 <= band_rows`, the node's rows and the row above
    /// its top vertices), computes every small level's nodes whole from the band and, at the
    /// same time, accumulates the node rows of every coarser level that the band crosses: a
    /// coarse node row is created when the sweep reaches its first row and its samples added
    /// band by band; its tessellated vertices are filled from the bands as they pass, and the
    /// few a band needs above it (per factor, the top of the cell row the band ends in:
    /// [`ObjectErrorsAcc::vertex_rows_until`]) are read ahead, once, in sparse bands shared by
    /// every level. So the grid is read about once, plus those rows, whatever the number of
    /// levels (the former per-level passes read it about twice per coarse level). The coarse node rows
    /// held at once take about `budget.coarse_bytes` ([`ObjectErrorsAcc::bytes_estimate`]);
    /// levels beyond that get a further sweep (at least one level per sweep). `par` spreads the
    /// nodes over threads (terrain-core has none; [`Sequential`] runs them in order; every
    /// node's sums run in the same order either way), `progress` gets the done fraction.
    pub fn from_rows<E>(
        shape: &TreeShape,
        budget: &RowsBudget,
        read: &mut ReadRows<'_, E>,
        par: &dyn DssParallel,
        progress: &mut dyn FnMut(f64),
    ) -> Result<(Self, u32), E> {
        let (w, h) = (shape.width() as usize, shape.height() as usize);
        let band_rows = budget.band_rows.max(2);
        let levels = shape.max_level() as usize + 1;
        let mut table: Vec<(u32, Vec<[f64; FACTORS]>)> =
            Self::shape(shape).into_iter().map(|(nx, n)| (nx, vec![[0.0; FACTORS]; n])).collect();
        let cells = |level: usize| (shape.root_cells() >> level) as usize;
        // Levels whose node rows fit half a band (computed whole from the sweep's window), and
        // the others (coarsest first), accumulated.
        let small: Vec<usize> = (0..levels).filter(|&l| 2 * cells(l) + 2 <= band_rows).collect();
        let coarse: Vec<usize> = (0..levels).filter(|&l| 2 * cells(l) + 2 > band_rows).collect();
        // The sweep's step: the coarsest small level's node side, or the largest power of two
        // under half a band. Node sides are powers of two, so it divides every coarse node
        // side: a coarse node row starts at a step. The window the sweep holds is a band of
        // `band_rows` rows from the step's first row: the step, the row above the small nodes'
        // top vertices, and at least a step of look-ahead for the coarse nodes' vertices.
        let step = small.first().map_or_else(
            || 1usize << (usize::BITS - 1 - ((band_rows - 1) / 2).max(1).leading_zeros()),
            |&l| cells(l),
        );
        // The coarse levels in groups whose node rows fit `coarse_bytes` together.
        let mut groups: Vec<Vec<usize>> = vec![Vec::new()];
        let mut group_bytes = 0usize;
        for &l in &coarse {
            let c = cells(l);
            let nx = shape.level_dims(l as u8).0 as usize;
            let bytes = nx.saturating_mul(ObjectErrorsAcc::bytes_estimate(c.min(w - 1), c));
            let last = groups.last_mut().expect("one group at least");
            if !last.is_empty() && group_bytes.saturating_add(bytes) > budget.coarse_bytes {
                groups.push(Vec::new());
                group_bytes = 0;
            }
            groups.last_mut().expect("one group at least").push(l);
            group_bytes = group_bytes.saturating_add(bytes);
        }
        let sweeps = groups.len() as f64;
        let mut checksum = super::dss_file::HeightsChecksum::new();
        let mut summed = 0usize; // rows added to the checksum
        // The sweep's window (rows `held.0..held.1`) and the look-ahead reads' band.
        let (mut heights, mut voids) = (Vec::new(), Vec::new());
        let (mut ahead_h, mut ahead_v) = (Vec::new(), Vec::new());
        for (sweep, group) in groups.iter().enumerate() {
            // Live coarse nodes: key = position in its level's table * 64 + level.
            let mut live: Vec<(usize, ObjectErrorsAcc)> = Vec::new();
            let mut start = 0;
            let mut held = (0usize, 0usize);
            heights.clear();
            voids.clear();
            while start + 1 < h {
                let end = (start + band_rows - 1).min(h - 1);
                // The coarse node rows starting here.
                for &l in group.iter().filter(|&&l| start.is_multiple_of(cells(l))) {
                    let (c, t) = (cells(l), start / cells(l));
                    let nx = table[l].0 as usize;
                    live.extend((0..nx).filter_map(|i| {
                        ObjectErrorsAcc::new(Region::new(i * c, start, c), w, h)
                            .map(|a| (((t * nx + i) << 6) | l, a))
                    }));
                }
                // Slide the window to `start..=end`: keep the rows held, read the new ones.
                let drop = (start.min(held.1) - held.0) * w;
                heights.drain(..drop);
                voids.drain(..drop);
                held = (start, held.1.max(start));
                if end + 1 > held.1 {
                    let (old, n) = (heights.len(), end + 1 - held.1);
                    heights.resize(old + n * w, 0.0);
                    voids.resize(old + n * w, false);
                    read(held.1, n, &mut heights[old..], &mut voids[old..])?;
                    held.1 = end + 1;
                }
                let band = RowBand::new(start, w, &heights, &voids);
                par.for_each_acc(&mut live, &|acc| acc.fill_vertices(&band));
                // The coarse nodes take the step's rows (the rest of the window is look-ahead
                // for their vertices).
                let top = (start + step).min(h - 1);
                let rows = (top + 1 - start) * w;
                let samples = RowBand::new(start, w, &heights[..rows], &voids[..rows]);
                // The tessellated vertices the step's rows need above the window (for each
                // factor, at most the top of the cell row the step ends in, when that cell row
                // is taller than the look-ahead), read ahead in bands of consecutive wanted
                // rows at most VERTEX_GAP apart.
                let mut wanted: Vec<usize> =
                    live.iter().flat_map(|(_, a)| a.vertex_rows_until(top)).collect();
                wanted.sort_unstable();
                wanted.dedup();
                let mut k = 0;
                while k < wanted.len() {
                    let j0 = wanted[k];
                    let mut last = k;
                    while last + 1 < wanted.len()
                        && wanted[last + 1] - wanted[last] <= VERTEX_GAP
                        && wanted[last + 1] + 1 < j0 + band_rows
                    {
                        last += 1;
                    }
                    let n = (wanted[last] + 1).min(h - 1) - j0 + 1;
                    ahead_h.resize(n * w, 0.0);
                    ahead_v.resize(n * w, false);
                    read(j0, n, &mut ahead_h, &mut ahead_v)?;
                    let ahead = RowBand::new(j0, w, &ahead_h, &ahead_v);
                    par.for_each_acc(&mut live, &|acc| acc.fill_vertices(&ahead));
                    k = last + 1;
                }
                if sweep == 0 {
                    // Every row of the grid enters the checksum once, in order.
                    let upto = if start + step + 1 >= h { h } else { start + step };
                    for j in summed.max(start)..upto {
                        checksum.add_heights(band.row(j));
                        checksum.add_voids(band.void_row(j));
                    }
                    summed = summed.max(upto);
                    // The small levels' nodes in this band, each whole.
                    let mut regions = Vec::new();
                    for &l in &small {
                        let c = cells(l);
                        let (nx, _) = shape.level_dims(l as u8);
                        for y0 in (start..start + step).step_by(c).take_while(|&y| y + 1 < h) {
                            regions
                                .extend((0..nx as usize).map(|i| (l, Region::new(i * c, y0, c))));
                        }
                    }
                    let errors = par.map_regions(&regions, &|&(_, r)| {
                        ObjectErrorsAcc::new(r, w, h).map_or([0.0; FACTORS], |mut acc| {
                            acc.fill_vertices(&band);
                            acc.add_rows(&band);
                            acc.finish().avg
                        })
                    });
                    for (&(l, r), e) in regions.iter().zip(errors) {
                        let c = cells(l);
                        let (nx, v) = &mut table[l];
                        v[(r.y0 / c) * *nx as usize + r.x0 / c] = e;
                    }
                }
                par.for_each_acc(&mut live, &|acc| acc.add_rows(&samples));
                for (key, acc) in live.iter().filter(|(_, a)| a.is_complete()) {
                    table[key & 63].1[key >> 6] = acc.finish().avg;
                }
                live.retain(|(_, a)| !a.is_complete());
                progress((sweep as f64 + (end + 1) as f64 / h as f64) / sweeps);
                start += step;
            }
            debug_assert!(live.is_empty(), "every coarse node row was completed");
        }
        assert_eq!(summed, h, "every row enters the heights' checksum once");
        Ok((Self { root_cells: shape.root_cells(), levels: table, paged: None }, checksum.finish()))
    }

    /// Cells per node side, nodes per row and rows of nodes at `level` of `qt`.
    fn level_dims(qt: &TreeShape, level: u8) -> (u32, u32, u32) {
        let (nx, ny) = qt.level_dims(level);
        (qt.root_cells() >> level, nx, ny)
    }

    /// Per level of `qt`: nodes per row and nodes (what a table for `qt` holds).
    pub(super) fn shape(qt: &TreeShape) -> Vec<(u32, usize)> {
        (0..=qt.max_level())
            .map(|l| {
                let (_, nx, ny) = Self::level_dims(qt, l);
                (nx, (nx * ny) as usize)
            })
            .collect()
    }

    /// The errors of `node` (`delta_i` at index `i - 1`), or `None` outside the table. Read
    /// by pages, a node whose page cannot be had has infinite errors ([`super::dss_pages`]).
    pub fn get(&self, node: NodeId) -> Option<[f64; FACTORS]> {
        self.get_with(node, &PageMemo::default())
    }

    /// [`DssErrorTable::get`] keeping the page read last in `memo` (node after node in one
    /// page: one cache lookup).
    pub(super) fn get_with(&self, node: NodeId, memo: &PageMemo) -> Option<[f64; FACTORS]> {
        self.map_with(node, memo, |d| *d)
    }

    /// `f` of [`DssErrorTable::get_with`]'s errors, read in place (a selection that needs one
    /// of the 32 does not copy all of them).
    pub(super) fn map_with<R>(
        &self,
        node: NodeId,
        memo: &PageMemo,
        f: impl FnOnce(&[f64; FACTORS]) -> R,
    ) -> Option<R> {
        let Some(p) = &self.paged else {
            let (nx, v) = self.levels.get(node.level as usize)?;
            if node.i >= *nx {
                return None;
            }
            return v.get((node.j * nx + node.i) as usize).map(f);
        };
        paged_node(p, node, memo, |page, k| match page {
            Some(page) => f(&page.errors[k]),
            None => f(&[f64::INFINITY; FACTORS]),
        })
    }

    /// `node`'s finest error (`delta_32`, [`DssErrorTable::map_with`]'s last), from the row of
    /// finest errors a page keeps beside its entries when read by pages.
    pub(super) fn finest_with(&self, node: NodeId, memo: &PageMemo) -> Option<f64> {
        let Some(p) = &self.paged else {
            return self.map_with(node, memo, |d| d[FACTORS - 1]);
        };
        paged_node(p, node, memo, |page, k| page.map_or(f64::INFINITY, |page| page.finest[k]))
    }

    /// Whether the table is read by pages ([`DssErrorTable::open_paged`]).
    pub fn is_paged(&self) -> bool {
        self.paged.is_some()
    }

    /// A table read by pages: what it read so far; `None` for a table in memory.
    pub fn paging_stats(&self) -> Option<DssPagingStats> {
        self.paged.as_ref().map(|p| p.stats())
    }

    /// A table read by pages: the first page that could not be used since the last call (its
    /// nodes were given infinite errors: drawn finest), if any.
    pub fn take_error(&self) -> Option<super::dss_file::DssFileError> {
        self.paged.as_ref().and_then(|p| p.take_error())
    }

    /// Cells per side of the root it was built for.
    pub fn root_cells(&self) -> u32 {
        self.root_cells
    }
}

/// `f` of the page holding `node` in a table read by pages and the node's index in it (the
/// page `None` when it cannot be had: its nodes' errors are infinite), the page read last kept
/// in `memo`; `None` outside the table.
fn paged_node<R>(
    p: &DssPages,
    node: NodeId,
    memo: &PageMemo,
    f: impl FnOnce(Option<&super::dss_pages::PageData>, usize) -> R,
) -> Option<R> {
    let slot = p.slot(node)?;
    let mut last = memo.0.borrow_mut();
    if last.as_ref().is_none_or(|(q, _)| *q != slot.page) {
        *last = p.page(slot.page).map(|page| (slot.page, page));
    }
    Some(f(last.as_ref().map(|(_, page)| &**page), slot.index))
}

/// The page of a table read by pages that was read last ([`DssErrorTable::get_with`]); one
/// selection's, on its thread. (Eight pages kept in turn did not select `dss-2` faster on the
/// 32769^2 store: its cost over the table read whole is the pages it reads, not the lookups.)
#[derive(Default)]
pub(super) struct PageMemo(RefCell<Option<(u64, Page)>>);

/// The per-node screen errors of Eq. 3 for a camera (shared with [`super::dss_strips`]).
pub(super) struct Metric<'a> {
    pub(super) table: &'a DssErrorTable,
    /// The page of a paged table read last.
    memo: PageMemo,
    pub(super) lambda: f64,
    pub(super) eye: glam::DVec3,
    pub(super) thr: f64,
    /// The floor of Eq. 3's `sin(theta)`.
    pub(super) floor: f64,
}

impl<'a> Metric<'a> {
    /// The metric of `camera` with `cfg`'s threshold `rho_thr` (pixels) and view-angle floor.
    pub(super) fn new(table: &'a DssErrorTable, camera: &Camera, cfg: &DssConfig) -> Self {
        Self {
            table,
            memo: PageMemo::default(),
            lambda: screen::lambda(camera.viewport_px.y, camera.fov_y),
            eye: camera.position,
            thr: cfg.rho_thr,
            floor: cfg.view_angle_floor,
        }
    }

    /// `f` of `node`'s 32 object-space errors, in place (0 for a node the table lacks).
    fn with_delta<R>(&self, node: NodeId, f: impl Fn(&[f64; FACTORS]) -> R) -> R {
        match self.table.map_with(node, &self.memo, &f) {
            Some(r) => r,
            None => f(&[0.0; FACTORS]),
        }
    }

    /// Eq. 3 for the finest factor: split when `rho_32 > rho_thr`.
    pub(super) fn must_split(&self, node: NodeId, info: &NodeInfo) -> bool {
        let rho = screen::dss_floored(
            self.lambda,
            self.table.finest_with(node, &self.memo).unwrap_or(0.0),
            info.aabb.distance(self.eye),
            info.aabb.center() - self.eye,
            self.floor,
        );
        rho > self.thr
    }

    /// Eq. 3 and 4: the continuous factor `F_thr` (64 where even 64 misses the threshold).
    /// Eq. 3's view-angle factor once per node, and only the errors Eq. 4's scan reaches
    /// (the same bits as [`crate::metrics::dss::screen_errors_floored`] then
    /// [`crate::metrics::dss::tessellation_factor`]: `dss_factor_equals_all_32_errors_then_eq4`).
    pub(super) fn factor(&self, node: NodeId, info: &NodeInfo) -> f32 {
        let d = info.aabb.distance(self.eye);
        let sin = screen::view_sin_floored(info.aabb.center() - self.eye, self.floor);
        let t = self.with_delta(node, |delta| {
            tessellation_factor_of(|k| screen::dss_at_sin(self.lambda, delta[k], d, sin), self.thr)
        });
        match t {
            Tessellation::MustSplit => MAX_FACTOR,
            Tessellation::Factor(f) => f.clamp(2.0, f64::from(MAX_FACTOR)) as f32,
        }
    }
}

fn select_dss(
    src: &dyn NodeTree,
    camera: &Camera,
    table: &DssErrorTable,
    cfg: &DssConfig,
    uniform: Option<u8>,
) -> Selection {
    let start = Instant::now();
    assert_eq!(table.root_cells(), src.shape().root_cells(), "error table of another quadtree");
    let metric = Metric::new(table, camera, cfg);
    if let Some(level) = uniform {
        let mut split = SplitToLevel(level);
        let (leaves, stats) = run::leaves(src, camera, &mut split, cfg.frustum_cull);
        return assemble_uniform(src, &metric, leaves, stats, start);
    }
    let mut split = |n: NodeId, info: &NodeInfo| metric.must_split(n, info);
    // The balanced tree is kept for the edges (not built again from its leaves).
    let (tree, stats) = run::balanced_tree(src, camera, &mut split, cfg.frustum_cull, &mut NoCull);
    let leaves = tree.leaves();
    // Each leaf's wish beside it rather than in a map keyed by node (SipHash): the map's
    // build and lookups were 40 % of Method I's samples over a 32769^2 store; the same
    // patches as the map's (`methods_one_and_two_equal_the_hash_map_reference`).
    let want: Vec<f32> = per_leaf(src, leaves, |n, info| pow2_up(metric.factor(n, info)));
    let patches: Vec<Patch> = leaves
        .iter()
        .zip(wish_outer_factors(&tree, &want))
        .zip(&want)
        .map(|((&node, outer), &w)| Patch { node, outer, inner: [w; 2] })
        .collect();
    run::finish(patches, stats, start)
}

/// How much of a grid [`DssErrorTable::from_rows`] holds at once.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RowsBudget {
    /// Rows per band read (at least 2).
    pub band_rows: usize,
    /// Bytes of the coarse levels' node rows accumulated at once, by
    /// [`ObjectErrorsAcc::bytes_estimate`] (at least one level is, whatever this says).
    pub coarse_bytes: usize,
}

/// Largest gap between vertex rows that [`DssErrorTable::from_rows`] reads through rather than
/// starting a new band.
const VERTEX_GAP: usize = 4;

/// What [`DssErrorTable::from_rows`] reads rows with: `read(j0, rows, heights, voids)` fills
/// full-width rows `j0..j0 + rows`, south first.
pub type ReadRows<'a, E> = dyn FnMut(usize, usize, &mut [f32], &mut [bool]) -> Result<(), E> + 'a;

/// How [`DssErrorTable::from_rows`] spreads its nodes over threads (terrain-core spawns
/// none): both functions must apply `f` to every item once, and `map_regions` return the
/// results in order.
pub trait DssParallel {
    /// `regions.iter().map(f).collect()`.
    fn map_regions(
        &self,
        regions: &[(usize, Region)],
        f: &(dyn Fn(&(usize, Region)) -> [f64; FACTORS] + Sync),
    ) -> Vec<[f64; FACTORS]>;
    /// `accs.iter_mut().for_each(|(_, a)| f(a))`.
    fn for_each_acc(
        &self,
        accs: &mut [(usize, ObjectErrorsAcc)],
        f: &(dyn Fn(&mut ObjectErrorsAcc) + Sync),
    );
}

/// [`DssParallel`] on the calling thread, in order.
#[derive(Debug, Clone, Copy, Default)]
pub struct Sequential;

impl DssParallel for Sequential {
    fn map_regions(
        &self,
        regions: &[(usize, Region)],
        f: &(dyn Fn(&(usize, Region)) -> [f64; FACTORS] + Sync),
    ) -> Vec<[f64; FACTORS]> {
        regions.iter().map(f).collect()
    }
    fn for_each_acc(
        &self,
        accs: &mut [(usize, ObjectErrorsAcc)],
        f: &(dyn Fn(&mut ObjectErrorsAcc) + Sync),
    ) {
        accs.iter_mut().for_each(|(_, a)| f(a));
    }
}

/// `f` of every selected leaf and its box, collected, the boxes read through the traversal's
/// node source: a store's looks each block up once per run of its leaves (they come depth
/// first), not once per leaf.
fn per_leaf<T, C: FromIterator<T>>(
    src: &dyn NodeTree,
    leaves: &[NodeId],
    f: impl Fn(NodeId, &NodeInfo) -> T,
) -> C {
    let mut out = None;
    src.with_traversal_source(&mut |nodes| {
        out = Some(
            leaves
                .iter()
                .map(|&n| f(n, &nodes.node_info(n).expect("selected nodes exist")))
                .collect(),
        );
    });
    out.expect("`with_traversal_source` calls `f`")
}

/// Method II's patches: [`run::assemble`] with [`WishEdges`](super::edges::WishEdges), without its per-frame hash maps.
/// Every leaf is at the one uniform level, so the leaf across an edge is the same-level
/// neighbour when it is selected (edge at the max of both factors) and none otherwise (the
/// block's own factor); the selected leaves are indexed densely by row ([`RowWindow`]), so
/// the cost is linear in the blocks in view. Same output as the general path (the tests
/// compare them bit for bit).
fn assemble_uniform(
    src: &dyn NodeTree,
    metric: &Metric<'_>,
    leaves: Vec<NodeId>,
    stats: SelectionStats,
    start: Instant,
) -> Selection {
    let want: Vec<f32> = per_leaf(src, &leaves, |n, info| metric.factor(n, info));
    let side = leaves.first().map_or(1, |n| n.nodes_per_side() as usize);
    let win =
        RowWindow::dilated(leaves.iter().map(|n| (n.i as usize, n.j as usize)), 0, side, side);
    // Slot -> position in `leaves` + 1 (0: not selected).
    let mut slot = vec![0u32; win.len()];
    for (k, n) in leaves.iter().enumerate() {
        let s = win.index(n.i as usize, n.j as usize).expect("a leaf is in its own window");
        slot[s] = k as u32 + 1;
    }
    let patches: Vec<Patch> = leaves
        .iter()
        .zip(&want)
        .map(|(&node, &f)| {
            debug_assert_eq!(node.level, leaves[0].level, "Method II leaves share one level");
            let outer = Edge::ALL.map(|e| {
                let across = node.neighbour(e.direction()).and_then(|m| {
                    let s = win.index(m.i as usize, m.j as usize)?;
                    slot[s].checked_sub(1)
                });
                match across {
                    Some(k) => f.max(want[k as usize]),
                    None => f,
                }
            });
            Patch { node, outer, inner: [f; 2] }
        })
        .collect();
    run::finish(patches, stats, start)
}

/// The DSS paper's Method I: quadtree split by Eq. 3 on `delta_32`, balanced, factors from
/// Eq. 4 rounded up to powers of two, shared edges matched (see the module docs).
pub fn select_dss_power_of_two(
    src: &dyn NodeTree,
    camera: &Camera,
    table: &DssErrorTable,
    cfg: &DssConfig,
) -> Selection {
    select_dss(src, camera, table, cfg, None)
}

/// The DSS paper's Method II: uniform blocks of [`DssConfig::uniform_block_cells`], each with
/// its continuous `F_thr` (Eq. 4), shared edges at the max of both sides.
pub fn select_dss_uniform(
    src: &dyn NodeTree,
    camera: &Camera,
    table: &DssErrorTable,
    cfg: &DssConfig,
) -> Selection {
    let block = cfg.uniform_block_cells.max(1);
    let shape = src.shape();
    let level = (shape.root_cells() / block.min(shape.root_cells())).max(1).ilog2() as u8;
    select_dss(src, camera, table, cfg, Some(level.min(shape.max_level())))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::georef::Georef;
    use crate::lod::WishEdges;
    use crate::lod::check_shared_edges;
    use crate::metrics::dss::tessellation_factor;
    use crate::quadtree::LeafTree;
    use glam::dvec3;

    fn bumpy(n: usize) -> Heightmap {
        Heightmap::from_fn(n, n, Georef::local(10.0), |i, j| {
            ((i as f32 * 0.37).sin() * 25.0 + (j as f32 * 0.23).cos() * 20.0) + 100.0
        })
        .unwrap()
    }
    /// `Metric::factor` (the view angle once, only the errors Eq. 4's scan reaches) gives the
    /// bits of all 32 screen errors of Eq. 3 followed by Eq. 4, for every node of a table and
    /// cameras from inside the terrain's box to far above it, with thresholds that make
    /// nodes split, draw at every factor and at the coarsest.
    #[test]
    fn dss_factor_equals_all_32_errors_then_eq4() {
        // Leaves of 64 cells: every factor below a leaf's cells has an error of its own.
        let hm = crate::synth::FractalConfig::with_size(257, 257, 10.0).to_heightmap().unwrap();
        let cfg = DssConfig { leaf_cells: 64, ..Default::default() };
        let qt = cfg.quadtree(&hm);
        let table = DssErrorTable::new(&hm, &qt);
        let mut unit = crate::test_support::unit_rng(0x2545_f491_4f6c_dd1d);
        let (mut split, mut coarsest, mut between, mut inside) = (0, 0, 0, 0);
        for k in 0..40 {
            let z = [60.0, 130.0, 400.0, 3000.0][k % 4] * (0.5 + unit());
            let eye = dvec3(2560.0 * unit(), 2560.0 * unit(), z);
            let cam = Camera::from_yaw_pitch(eye, 360.0 * unit(), -80.0 * unit())
                .with_viewport(1280.0, 720.0);
            let cfg = DssConfig {
                rho_thr: [0.25, 1.0, 4.0, 30.0, f64::NAN][k % 5],
                view_angle_floor: [screen::MIN_VIEW_SIN, 0.0, 1.0][k % 3],
                ..cfg.clone()
            };
            let metric = Metric::new(&table, &cam, &cfg);
            let mut stack = vec![NodeId::ROOT];
            while let Some(n) = stack.pop() {
                let Some(info) = qt.node_info(n) else { continue };
                stack.extend(n.children());
                let d = info.aabb.distance(eye);
                let rho = crate::metrics::dss::screen_errors_floored(
                    &table.get(n).unwrap_or([0.0; FACTORS]),
                    metric.lambda,
                    d,
                    info.aabb.center() - eye,
                    cfg.view_angle_floor,
                );
                let want = match tessellation_factor(&rho, cfg.rho_thr) {
                    Tessellation::MustSplit => {
                        split += 1;
                        MAX_FACTOR
                    }
                    Tessellation::Factor(f) => {
                        if f == 2.0 {
                            coarsest += 1
                        } else {
                            between += 1
                        }
                        f.clamp(2.0, f64::from(MAX_FACTOR)) as f32
                    }
                };
                inside += usize::from(d <= screen::MIN_DISTANCE_M);
                assert_eq!(metric.factor(n, &info).to_bits(), want.to_bits(), "camera {k} {n:?}");
            }
        }
        assert!(
            split > 0 && coarsest > 0 && between > 0 && inside > 0,
            "{split} {coarsest} {between} {inside}"
        );
    }

    /// The view-angle floor of Eq. 3 (`DssConfig::view_angle_floor`): a node seen at
    /// `sin(theta)` at or above both floors gets the same split decision and factor under
    /// either; only nodes seen steeper than a floor can change, and some do (negative
    /// control: a camera looking down at the middle sees nodes steeper than 0.25).
    #[test]
    fn the_view_angle_floor_changes_only_blocks_seen_steeper_than_it() {
        let hm = bumpy(129);
        let cfg = DssConfig { leaf_cells: 8, ..Default::default() };
        let qt = cfg.quadtree(&hm);
        let table = DssErrorTable::new(&hm, &qt);
        let cam = Camera::from_yaw_pitch(dvec3(640.0, 640.0, 400.0), 0.0, -89.0);
        let with = |floor: f64| DssConfig { view_angle_floor: floor, ..cfg.clone() };
        let (low, high) = (with(0.1), with(screen::MIN_VIEW_SIN));
        assert_eq!(DssConfig::default().view_angle_floor, screen::MIN_VIEW_SIN);
        let (ml, mh) = (Metric::new(&table, &cam, &low), Metric::new(&table, &cam, &high));
        let (mut steep_changed, mut shallow) = (0, 0);
        let mut stack = vec![NodeId::ROOT];
        while let Some(n) = stack.pop() {
            let Some(info) = qt.node_info(n) else { continue };
            let raw = screen::view_sin_floored(info.aabb.center() - cam.position, 0.0);
            let same = ml.factor(n, &info) == mh.factor(n, &info)
                && ml.must_split(n, &info) == mh.must_split(n, &info);
            if raw >= screen::MIN_VIEW_SIN {
                assert!(same, "{n:?} seen at sin {raw:.3} changed with the floor");
                shallow += 1;
            } else if !same {
                steep_changed += 1;
            }
            if n.level < qt.max_level() {
                stack.extend(n.children());
            }
        }
        assert!(shallow > 0, "no node seen shallower than the floor: nothing compared");
        assert!(steep_changed > 0, "no node seen steeper than the floor changed");
        // Through the selection: the floor changes what a straight-down view draws.
        let a = select_dss_power_of_two(&qt, &cam, &table, &with(0.0));
        let b = select_dss_power_of_two(&qt, &cam, &table, &with(1.0));
        assert!(a.patches.len() < b.patches.len(), "{} vs {}", a.patches.len(), b.patches.len());
    }

    #[test]
    fn pow2_rounds_up() {
        assert_eq!(
            [1.0, 2.0, 2.1, 4.0, 5.0, 33.0, 64.0, 90.0].map(pow2_up),
            [2.0, 2.0, 4.0, 4.0, 8.0, 64.0, 64.0, 64.0]
        );
    }

    #[test]
    fn method_one_is_powers_of_two_and_method_two_is_uniform() {
        let hm = bumpy(129);
        let cfg = DssConfig { leaf_cells: 8, uniform_block_cells: 32, ..Default::default() };
        let qt = cfg.quadtree(&hm);
        let table = DssErrorTable::new(&hm, &qt);
        let cam = Camera::from_yaw_pitch(dvec3(50.0, 50.0, 300.0), 30.0, -25.0);
        let one = select_dss_power_of_two(&qt, &cam, &table, &cfg);
        assert!(one.stats.patches > 1);
        assert!(one.factors_in_range());
        assert!(one.patches.iter().all(|p| {
            p.outer
                .iter()
                .chain(&p.inner)
                .all(|f| (*f as u32).is_power_of_two() && f.fract() == 0.0)
        }));
        assert_eq!(check_shared_edges(&one), []);
        let two = select_dss_uniform(&qt, &cam, &table, &cfg);
        assert!(two.patches.iter().all(|p| p.node.level == 2));
        assert_eq!(check_shared_edges(&two), []);
        assert!(two.factors_in_range());
        // Continuous: some factor is not an integer.
        assert!(two.patches.iter().any(|p| p.inner[0].fract() != 0.0));
        // A stricter threshold never lowers a factor (Method II, same blocks).
        let strict = select_dss_uniform(&qt, &cam, &table, &DssConfig { rho_thr: 0.25, ..cfg });
        for (a, b) in two.patches.iter().zip(&strict.patches) {
            assert_eq!(a.node, b.node);
            assert!(b.inner[0] >= a.inner[0]);
        }
    }

    /// Methods I and II as they were: factors into a hash map, patches through
    /// [`run::assemble`] (the general `LeafSet` neighbour search) with [`WishEdges`].
    fn select_dss_reference(
        qt: &Quadtree,
        camera: &Camera,
        table: &DssErrorTable,
        cfg: &DssConfig,
        uniform: bool,
    ) -> Selection {
        let start = Instant::now();
        let metric = Metric::new(table, camera, cfg);
        let (leaves, stats) = if uniform {
            let block = cfg.uniform_block_cells.max(1);
            let level = (qt.root_cells() / block.min(qt.root_cells())).max(1).ilog2() as u8;
            let mut split = SplitToLevel(level.min(qt.max_level()));
            run::leaves(qt, camera, &mut split, cfg.frustum_cull)
        } else {
            let mut split = |n: NodeId, info: &NodeInfo| metric.must_split(n, info);
            let (tree, stats) =
                run::balanced_tree(qt, camera, &mut split, cfg.frustum_cull, &mut NoCull);
            (tree.into_leaves(), stats)
        };
        let want = leaves
            .iter()
            .map(|&n| {
                let f = metric.factor(n, &qt.node_info(n).expect("selected"));
                (n, if uniform { f } else { pow2_up(f) })
            })
            .collect();
        let rule: WishEdges = WishEdges { want };
        let inner = |n: NodeId, _: &[f32; 4]| [rule.want(n); 2];
        run::assemble(&LeafTree::new(&leaves), stats, &rule, inner, start)
    }

    fn assert_matches_reference(hm: &Heightmap, cfg: &DssConfig, cameras: usize, uniform: bool) {
        let qt = cfg.quadtree(hm);
        let table = DssErrorTable::new(hm, &qt);
        let (w, h) = (hm.width() as f64, hm.height() as f64);
        let mut unit = crate::test_support::unit_rng(0x853c_49e6_748f_ea9b);
        let (mut drawn, mut partial, mut empty) = (0, false, false);
        for k in 0..cameras {
            let g = hm.grid_to_world(-0.3 * w + 1.6 * w * unit(), -0.3 * h + 1.6 * h * unit());
            let z = 30.0 + 3000.0 * unit() * unit();
            let mut cam = Camera::from_yaw_pitch(g.extend(z), 360.0 * unit(), 5.0 - 85.0 * unit())
                .with_viewport(1280.0, 720.0);
            if k % 3 == 1 {
                cam = cam.with_clip(1.0, (w + h) * hm.georef().spacing_m.x * (0.05 + 0.5 * unit()));
            }
            let cfg = DssConfig {
                rho_thr: [1.0, 0.25, 4.0][k % 3],
                frustum_cull: k % 7 != 6,
                ..cfg.clone()
            };
            let fast = match uniform {
                true => select_dss_uniform(&qt, &cam, &table, &cfg),
                false => select_dss_power_of_two(&qt, &cam, &table, &cfg),
            };
            let slow = select_dss_reference(&qt, &cam, &table, &cfg, uniform);
            crate::test_support::assert_same_selection(&fast, &slow, &format!("camera {k}"));
            drawn += fast.patches.len();
            partial |= fast.stats.culled > 0 && !fast.patches.is_empty();
            empty |= fast.patches.is_empty();
        }
        assert!(drawn > 0 && partial && empty, "{drawn} {partial} {empty}");
    }

    #[test]
    fn methods_one_and_two_equal_the_hash_map_reference() {
        for uniform in [true, false] {
            let fractal =
                crate::synth::FractalConfig::with_size(513, 513, 10.0).to_heightmap().unwrap();
            let cfg = DssConfig { uniform_block_cells: 16, ..Default::default() };
            assert_matches_reference(&fractal, &cfg, 80, uniform);
            // Odd, non-square: the east and north blocks are clipped.
            let odd =
                crate::synth::FractalConfig::with_size(301, 203, 30.0).to_heightmap().unwrap();
            let cfg = DssConfig { leaf_cells: 8, uniform_block_cells: 16, ..Default::default() };
            assert_matches_reference(&odd, &cfg, 80, uniform);
        }
    }
}
