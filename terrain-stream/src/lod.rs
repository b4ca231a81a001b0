//! The out-of-core paper's rendering method (Qiu 2013, sections 3.1-3.3) over a store's index,
//! through terrain-core's one [`traverse`]: the store is a [`NodeSource`] ([`StoreTree`]: the
//! quadtree of the whole grid, per-node values from the index, no heights in memory), the
//! paper's dynamic LOD construction is an Eq. 7 split ([`BlockNodes::splits`], optionally
//! with a cost split: [`SplitRule`]) and its bounding-circle test is terrain-core's
//! [`BoundingCircleCull`].
//!
//! # Patches, not per-vertex nodes
//! The paper splits nodes down to single cells and draws each node as a fan of its corners
//! and edge midpoints. Here, as in the in-memory methods, the drawn unit is a *patch*: a
//! quadtree node of at least [`StoreTree::patch_cells`] cells inside one block (the nodes with
//! stored per-node values, so the split test reads the index only) or, far away, spanning
//! several blocks (below), drawn by the renderer's
//! tessellator with a power-of-two factor. The traversal splits while Eq. 7 says the node is
//! too coarse on screen (`rho > tau`, the paper's step 4) even when drawn at the largest
//! factor, [`MAX_FACTOR`] = 64: the error that decides is not the node's own `StaticE` (its
//! four corners) but that of its descendants six levels down, whose corners the patch's
//! tessellation draws ([`BlockNodes::patch_error`]: their largest `StaticE`, exact with the
//! index's fine maxima). The paper's node is one fan of vertices, so it splits
//! on its own `StaticE`; a tessellated patch refines inside itself, and splitting it on its
//! corners alone drew nearly every patch at the smallest size whatever `tau` (the patch count
//! grew with the grid: 370 / 5,410 / 67,716 patches at 1025^2 / 4097^2 / 16385^2 on the same
//! relative flight). A leaf patch then takes
//! as its factor the resolution the same recursion would reach inside it
//! ([`needed_vertex_level`]: the paper's split continued below the patch, every sub-node
//! evaluated at the patch's own distance and `beta`, which only overestimates), at most the
//! block's resident level and never finer than the data (a patch of `c` cells has a factor of
//! at most `c`), so no frame draws more triangles than the full-resolution grid in view.
//!
//! Eq. 7 alone never splits a node that factor 64 draws with every sample (64 cells with
//! `k` 8), so a patch near the eye draws its whole square at the level its roughest or nearest
//! corner needs. [`SplitRule::Cost`] (a [`Refinement`] of the tree and of the streamer) also
//! splits a node while its four children at their own Eq. 7 factors draw fewer triangles
//! (greedy cost-based refinement, as ROAM's split queue), down to [`Refinement::patch_cells`]
//! (16 cells: a node's children are then still stored nodes with their own boxes and
//! maxima); leaves keep Eq. 7's factor, the balance and the edge rule.
//!
//! # Far terrain: patches spanning several blocks
//! A node above the blocks (spanning `2^s x 2^s` of them) has no per-node values in the
//! index; [`StoreTree::new`] takes from the index (a version-4 index: its head's pyramid;
//! below the head's levels, for grids beyond `2^8` blocks a side, per node when first visited;
//! older indexes: computed once from every entry) a flat array per node above the
//! blocks of the largest per-level error of its blocks (`level_errors[l]`, the bound of every
//! block drawn with its level-`l` vertices) beside their min/max. Such a node stays one patch
//! when some factor of at most 64 (`2^(s + l)` segments across it: each block's level-`l`
//! vertices, `l <= 6 - s`) meets Eq. 7 at its box with that bound (`spanning_level`: the least
//! such `l`), and each of its blocks holds level `l` (else it splits). It is drawn as one
//! tessellated patch over its square of grid samples; the renderer reads each vertex from the
//! page of the block it lies in (pages at level `l` or finer hold it exactly), so a spanning
//! patch is one more node of the balanced leaf set, with edge factors like any other. This
//! is how CDLOD draws far terrain (Strugar 2009: one node of the quadtree per patch whatever
//! its size, the error bound a max over the node's area); without it every block in view
//! was at least one patch.
//!
//! # Crack-free selection ([`select_patches`])
//! Leaves are clamped to each block's resident level (the split stops there: the runtime
//! serves coarser levels while finer ones load), balanced across blocks (terrain-core's
//! [`LeafTree::balanced`]: neighbours within one level) and given outer factors by
//! terrain-core's one resolver with the [`WishEdges`](terrain_core::lod::WishEdges) rule, the
//! wishes beside the leaves ([`wish_outer_factors`] over the balance's tree: neighbours by
//! index, no hashing; a
//! shared edge takes the larger of the two sides' wishes, a coarse edge facing finer patches a
//! power of two that nests with all of them), so
//! `terrain_core::lod::check_shared_edges` holds and the tessellated surface is watertight
//! over pages of any level (the renderer's page lookup gives every shared sample one value).
//!
//! # Node values below the stored node levels
//! Blocks store per-node min/max and `StaticE` down to [`Header::node_levels`]; below, the
//! error is the smaller of the deepest stored ancestor's `StaticE` and, with the index's fine
//! maxima (version 3: per deepest stored node, its descendants' largest `StaticE` per finer
//! level), that maximum, else the block's per-level maximum (all bound it, Eq. 3), and the
//! height range is the ancestor's. With the fine maxima the factor walk's result equals the
//! one over node values stored to full depth (`StaticE` is monotone, so a level's largest
//! value decides whether any node there is over the threshold).

use std::cell::{Cell, RefCell};
use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;

use glam::{DVec2, DVec3};
use terrain_core::geometry::{Aabb, Camera, Frustum, GroundRegion, project_view_to_ground};
use terrain_core::hash::IdMap;
use terrain_core::lod::{MAX_FACTOR, Patch, Selection, SelectionStats, wish_outer_factors};
use terrain_core::metrics::screen::{self, SightLineEq7};
use terrain_core::quadtree::{
    BoundingCircleCull, Cull, CullPolicy, FrustumCull, GridRect, LeafTree, NodeId, NodeInfo,
    NodeSource, NodeTree, SplitPolicy, TreeShape, Visit, traverse,
};

use crate::format::{BlockEntry, BlockId, Header, max_up, node_count};
use crate::store::Store;
use crate::streamer::Streamer;

/// Default smallest patch, cells per side (clamped to a block's cells).
pub const DEFAULT_PATCH_CELLS: u32 = 32;

/// The view quantities of the screen error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    /// Eye position, world metres.
    pub eye: DVec3,
    /// Unit sight-line direction.
    pub dir: DVec3,
    /// Pixels per radian (`H / (2 tan(alpha/2))` of Eq. 6-7).
    pub lambda: f64,
    /// Screen-error threshold `tau`, pixels.
    pub tau: f64,
    /// The floor of Eq. 6-7's `cos(theta)` ([`Refinement::view_angle_floor`]).
    pub floor: f64,
    /// Eq. 7's per-view part (from `dir`, `lambda` and `floor`).
    pub(crate) eq7: SightLineEq7,
}

impl View {
    /// The view of `camera` with threshold `tau` pixels and the default view-angle floor
    /// ([`screen::MIN_VIEW_SIN`]).
    pub fn new(camera: &Camera, tau: f64) -> Self {
        Self::floored(camera, tau, screen::MIN_VIEW_SIN)
    }

    /// The view of `camera` with threshold `tau` pixels and view-angle floor `floor`.
    pub fn floored(camera: &Camera, tau: f64, floor: f64) -> Self {
        let (dir, lambda) = (camera.forward(), camera.lambda());
        let eq7 = SightLineEq7::floored(lambda, dir, floor);
        Self { eye: camera.position, dir, lambda, tau, floor, eq7 }
    }

    /// Eq. 7's `rho` per metre of error for a node with world box `aabb` (distance from the eye
    /// to the box, `beta` towards its centre): `rho(delta) = delta * per_metre` (Eq. 7 is linear
    /// in `delta`). Infinite when the eye is inside or on the box (`MUST_SPLIT`).
    fn rho_per_metre(&self, aabb: &Aabb) -> f64 {
        let (lo, hi) = (aabb.min, aabb.max);
        let to_centre = (lo - self.eye) + (hi - lo) * 0.5;
        self.eq7.rho(1.0, self.distance(aabb), to_centre)
    }

    /// Distance from the eye to the box `aabb` (0 inside it).
    fn distance(&self, aabb: &Aabb) -> f64 {
        (aabb.min - self.eye).max(self.eye - aabb.max).max(DVec3::ZERO).length()
    }

    /// Size on screen (pixels) of a length of `metres` at the nearest point of `aabb`
    /// (`lambda metres / d`); infinite when the eye is in the box.
    pub(crate) fn size_px(&self, metres: f64, aabb: &Aabb) -> f64 {
        let d = self.distance(aabb);
        if d > 0.0 { self.lambda * metres / d } else { f64::INFINITY }
    }

    /// Whether a node with error `err` (metres) whose box has Eq. 7 `rho` per metre
    /// `per_metre` ([`View::rho_per_metre`]) splits: Eq. 7 `rho > tau`.
    fn splits_at(&self, err: f32, per_metre: f64) -> bool {
        err > 0.0 && per_metre * f64::from(err) > self.tau
    }
}

/// Min, max and `StaticE` of block-local node `n` (level 0 = the whole block).
fn local_values(h: &Header, e: &BlockEntry, n: NodeId) -> (f32, f32, f32) {
    if n.level < h.node_levels
        && let Some(v) = e.node(n.level, n.i, n.j)
    {
        return (v.min, v.max, v.static_error);
    }
    let bound = if n.level >= h.k { 0.0 } else { below_bound(h, e, n, n.level) };
    // The deepest stored ancestor (none when the store keeps no node values).
    let stored = (h.node_levels > 0).then(|| n.ancestor(n.level.min(h.node_levels - 1)));
    match stored.and_then(|a| e.node(a.level, a.i, a.j)) {
        Some(v) => (v.min, v.max, bound.min(v.static_error)),
        None => (e.min, e.max, bound),
    }
}

/// A bound on the `StaticE` of every descendant at level `l` (below the stored node levels,
/// `l >= node_levels`) of block-local node `n`: with the fine maxima (index version 3), the
/// largest of theirs over `n`'s deepest stored descendants (or its deepest stored ancestor's
/// when `n` is below the stored levels), which is the exact maximum at `l`; without them, the
/// block's per-level maximum `level_errors[l]`.
fn below_bound(h: &Header, e: &BlockEntry, n: NodeId, l: u8) -> f32 {
    let block_wide = || e.level_errors.get(l as usize).copied().unwrap_or(0.0);
    if e.fine_errors.is_empty() || l < h.node_levels || l >= h.k {
        return block_wide();
    }
    let top = h.node_levels - 1;
    let fine = |a: NodeId| e.fine_error(h.node_levels, h.k, a.i, a.j, l);
    if n.level >= top {
        return fine(n.ancestor(top)).unwrap_or_else(block_wide);
    }
    e.fine_max_above(h.node_levels, h.k, [n.i, n.j], n.level, l)
        .unwrap_or_else(|| below_bound_sweep(h, e, n, l))
}

/// [`below_bound`] of a node `n` above the deepest stored level, sweeping its descendants'
/// fine maxima there (the entry's pyramid's reference, and what an entry without a whole
/// set of fine maxima takes).
fn below_bound_sweep(h: &Header, e: &BlockEntry, n: NodeId, l: u8) -> f32 {
    let block_wide = || e.level_errors.get(l as usize).copied().unwrap_or(0.0);
    let top = h.node_levels - 1;
    let fine = |a: NodeId| e.fine_error(h.node_levels, h.k, a.i, a.j, l);
    let s = top - n.level;
    let mut m = 0f32;
    for j in n.j << s..(n.j + 1) << s {
        for i in n.i << s..(n.i + 1) << s {
            match fine(NodeId { level: top, i, j }) {
                Some(v) => m = m.max(v),
                None => return block_wide(),
            }
        }
    }
    m
}

/// Default [`Refinement::split`]: see [`SplitRule`].
pub const DEFAULT_SPLIT: SplitRule = SplitRule::Eq7;

/// How the selection splits the nodes inside a block (the nodes above the blocks split by
/// `spanning_level` whatever the rule).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SplitRule {
    /// Eq. 7 alone: a node splits while even its largest factor (64) misses `tau`
    /// ([`BlockNodes::patch_error`]); every other node is one patch at the factor Eq. 7 needs.
    #[default]
    Eq7,
    /// Eq. 7 as above, and besides a node splits while its four children, each drawn at the
    /// factor Eq. 7 needs at its own box, draw fewer triangles than the node at its own
    /// factor: greedy cost-based refinement (the split-priority queue of ROAM, Duchaineau et
    /// al. 1997, with the patch's triangle count as the priority and the split taken only
    /// where it pays; leaves keep Eq. 7's factor and the balance/edge rule, so the surface
    /// stays crack-free and every leaf still meets Eq. 7). Only nodes larger than the smallest
    /// patch split so; with patches of 16 cells (`patch_cells`) a node of 64 cells, which Eq. 7
    /// alone never splits (drawn at factor 64 it has every sample), can become four or
    /// sixteen smaller patches where only part of it is rough or near.
    Cost,
}

/// How a store's quadtree is refined into patches: what the selection ([`StoreTree`]) and the
/// streamer's needed levels (`StreamConfig::refinement`) share, so that what is loaded is
/// what is drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Refinement {
    /// Smallest patch, cells per side (a power of two, at most a block). Default
    /// [`DEFAULT_PATCH_CELLS`].
    pub patch_cells: u32,
    /// The split rule inside the blocks. Default [`DEFAULT_SPLIT`].
    pub split: SplitRule,
    /// [`SplitRule::Cost`] only: the cost split considers a node only while its children are
    /// at least this many pixels across on screen at the node's nearest point
    /// ([`View::size_px`]); 0: at every distance. A floor on a patch's screen size bounds the
    /// patches the cost split adds by the screen's area, whatever the grid's size (the bound
    /// CDLOD's and Chunked LOD's node counts have). Default [`DEFAULT_COST_SPLIT_PX`].
    pub cost_split_px: u32,
    /// The floor of Eq. 6-7's `cos(theta)` ([`screen::view_sin_floored`]; not the paper's,
    /// which has none: a straight-down view would see no error). Default
    /// [`screen::MIN_VIEW_SIN`] (0.25).
    pub view_angle_floor: f64,
    /// The coarsest segment a drawn patch may have, cells (not the paper's; 0: none, Eq. 7's
    /// least factors exactly). With a value, every patch inside a block is drawn with at least
    /// its block's vertices of segments of at most this many cells (clamped to what is
    /// resident), and a node above the blocks is one patch only if it meets `tau` with such
    /// segments, else it splits. Far patches may meet Eq. 7 with 32-cell or coarser segments,
    /// whose samples then set a flight's p99 (bench/ooc/README.md, issue 13); 16 is
    /// geomorph's own floor. Default [`DEFAULT_MAX_SEGMENT_CELLS`].
    pub max_segment_cells: u32,
}

impl Default for Refinement {
    fn default() -> Self {
        Self {
            patch_cells: DEFAULT_PATCH_CELLS,
            split: DEFAULT_SPLIT,
            cost_split_px: DEFAULT_COST_SPLIT_PX,
            view_angle_floor: screen::MIN_VIEW_SIN,
            max_segment_cells: DEFAULT_MAX_SEGMENT_CELLS,
        }
    }
}

impl Refinement {
    /// The coarsest block-local vertex level a patch may be drawn with under
    /// [`Refinement::max_segment_cells`] in blocks of `2^k` cells (segments of
    /// `2^(k - level)` cells): 0 when there is no floor.
    pub fn segment_floor_level(&self, k: u8) -> u8 {
        match self.max_segment_cells {
            0 => 0,
            cells => k.saturating_sub(cells.ilog2() as u8),
        }
    }
}

/// Default [`Refinement::max_segment_cells`]: 16, geomorph's floor (0 is the paper's Eq. 7
/// exactly). With it `ooc` draws 1.10x geomorph's triangles at p99 1 px on a 16385^2 grid
/// instead of 1.50x, 1.32x instead of 1.84x on Puget Sound 1k (bench/ooc/README.md, "The
/// segment floor as the default").
pub const DEFAULT_MAX_SEGMENT_CELLS: u32 = 16;

/// Default [`Refinement::cost_split_px`].
pub const DEFAULT_COST_SPLIT_PX: u32 = 0;

/// Levels a patch's tessellation adds below its node at the largest factor
/// ([`MAX_FACTOR`] = 64 = 2^6 segments per side).
const FACTOR_LEVELS: u8 = 6;

/// Triangles pairs (a factor's square) of a block-local node of level `node` drawn with the
/// vertices of level `vertices` (at least factor 2, at most [`MAX_FACTOR`]): the cost
/// [`SplitRule::Cost`] compares.
fn patch_cost(node: u8, vertices: u8) -> u32 {
    1 << (2 * vertices.saturating_sub(node).clamp(1, FACTOR_LEVELS))
}

/// The nodes of one block, block-local ids (level 0 = the block), rectangles in the whole
/// grid's samples.
#[derive(Debug, Clone, Copy)]
struct BlockNodes<'a> {
    header: &'a Header,
    entry: &'a BlockEntry,
    id: BlockId,
    /// Local level of the smallest patch (`is_finest`).
    patch_level: u8,
    /// This block's part of [`StoreTree`]'s `sub_max`, when the nodes come from a tree (the
    /// streamer's walk computes the same values from the index).
    sub: Option<&'a SubMax>,
}

impl<'a> BlockNodes<'a> {
    /// The largest `StaticE` per level under `n` (`StoreTree::sub_max`), if the tree has it:
    /// computed for the whole block when first asked for ([`LazySub::values`]).
    fn sub(&self, n: NodeId) -> Option<LazySub<'a>> {
        let sub = self.sub?;
        if n.level > self.patch_level || n.level >= self.header.node_levels {
            return None;
        }
        Some(LazySub { sub, header: self.header, entry: self.entry, node: n })
    }

    /// The largest `StaticE` of `n`'s descendants at level `l > n.level`: stored node values,
    /// then [`below_bound`] (exact with the fine maxima of index version 3, else the block's
    /// per-level maximum). From `sub_max` when the tree has it (the same values).
    fn level_max(&self, n: NodeId, l: u8) -> f32 {
        let (h, e) = (self.header, self.entry);
        // Below the stored levels `sub_max` holds `below_bound` itself (`fill_below`): looked
        // up here, a block whose patch errors lie there (every level `n.level + 6` of a
        // store whose nodes stop above it) is not worth its `sub_max` for them.
        if l >= h.node_levels || n.level >= l {
            return below_bound(h, e, n, l);
        }
        if let Some(&v) = self.sub(n).and_then(LazySub::values).and_then(|s| s.get(l as usize)) {
            return v;
        }
        let s = l - n.level;
        let mut m = 0f32;
        for j in n.j << s..(n.j + 1) << s {
            for i in n.i << s..(n.i + 1) << s {
                m = m.max(e.node(l, i, j).map_or(0.0, |v| v.static_error));
            }
        }
        m
    }

    /// The error of `n` (own `StaticE` `static_error`) drawn as one patch at the largest
    /// factor: that of its vertices [`FACTOR_LEVELS`] levels below it, i.e. the largest
    /// `StaticE` of its descendants there ([`BlockNodes::level_max`]; at most `n`'s own:
    /// monotone, Eq. 3-5); 0 at or below the block's finest level (every sample drawn).
    fn patch_error(&self, n: NodeId, static_error: f32) -> f32 {
        let level = n.level + FACTOR_LEVELS;
        if level >= self.header.k {
            return 0.0;
        }
        static_error.min(self.level_max(n, level))
    }

    /// The finest vertex level `n` needs ([`needed_vertex_level`]) at most `max_level`, with
    /// Eq. 7's `rho` per metre at its box `per_metre` (asked only when the walk needs it).
    fn needed_level(
        &self,
        n: NodeId,
        per_metre: impl FnOnce() -> f64,
        view: &View,
        max_level: u8,
    ) -> u8 {
        needed_at(self.header, self.entry, n, per_metre, view, max_level, self.sub(n))
    }

    /// Whether `n` (box `rho` per metre `per_metre`, [`BlockNodes::patch_error`] `patch_err`)
    /// splits under `rule`: Eq. 7 (the paper's step 4, `rho > tau`) on its patch error, and
    /// with [`SplitRule::Cost`] also when its children drawn at their own Eq. 7 factors cost
    /// fewer triangles than it does at its own ([`patch_cost`], each capped at the largest
    /// factor, needed levels at most the block's finest whatever is resident, so the split is
    /// the same for the streamer's needed levels as for the selection). Nodes of the smallest
    /// patch do not split.
    fn splits(
        &self,
        refine: Refinement,
        view: &View,
        n: NodeId,
        aabb: &Aabb,
        patch_err: f32,
        per_metre: f64,
    ) -> bool {
        if view.splits_at(patch_err, per_metre) {
            return true;
        }
        if refine.split != SplitRule::Cost || n.level >= self.patch_level.min(self.header.k) {
            return false;
        }
        // The screen-size floor: children smaller than `cost_split_px` on screen stay whole.
        let child_m = (aabb.max.x - aabb.min.x).max(aabb.max.y - aabb.min.y) * 0.5;
        if refine.cost_split_px > 0 && view.size_px(child_m, aabb) < f64::from(refine.cost_split_px)
        {
            return false;
        }
        let k = self.header.k;
        let own = patch_cost(n.level, self.needed_level(n, || per_metre, view, k));
        let mut children = 0;
        for c in n.children() {
            let Some((info, _)) = self.info(c) else { continue };
            let level = self.needed_level(c, || view.rho_per_metre(&info.aabb), view, k);
            children += patch_cost(c.level, level);
            if children >= own {
                return false;
            }
        }
        children < own
    }

    fn rect(&self, n: NodeId) -> Option<GridRect> {
        let h = self.header;
        if n.level > h.k {
            return None;
        }
        let c = h.block_cells() >> n.level;
        let (x0, y0) = (n.i * c, n.j * c);
        let (vw, vh) = (self.entry.valid_w.max(2) - 1, self.entry.valid_h.max(2) - 1);
        if x0 >= vw || y0 >= vh {
            return None;
        }
        let (bx, by) = (self.id.col * h.block_cells(), self.id.row * h.block_cells());
        Some(GridRect {
            x0: bx + x0,
            y0: by + y0,
            x1: bx + (x0 + c).min(vw),
            y1: by + (y0 + c).min(vh),
        })
    }

    fn info(&self, n: NodeId) -> Option<(NodeInfo, f32)> {
        let rect = self.rect(n)?;
        let (min, max, err) = local_values(self.header, self.entry, n);
        let g = &self.header.georef;
        let lo = g.grid_to_world(DVec2::new(rect.x0 as f64, rect.y0 as f64));
        let hi = g.grid_to_world(DVec2::new(rect.x1 as f64, rect.y1 as f64));
        let info = NodeInfo {
            rect,
            cells: self.header.block_cells() >> n.level,
            aabb: Aabb { min: lo.min(hi).extend(min.into()), max: lo.max(hi).extend(max.into()) },
            data_range: Some((min, max)),
            has_voids: false,
            is_finest: n.level >= self.patch_level.min(self.header.k),
        };
        Some((info, err))
    }
}

/// Node `node`'s part of its block's `sub_max` ([`BlockNodes::sub`]), not yet computed: the
/// block's values are worked out ([`block_sub_max`], every stored node read) at the first
/// [`LazySub::values`] of any of its nodes.
#[derive(Debug, Clone, Copy)]
struct LazySub<'a> {
    sub: &'a SubMax,
    header: &'a Header,
    entry: &'a BlockEntry,
    node: NodeId,
}

impl<'a> LazySub<'a> {
    /// Levels the values cover (`0..levels`, those above the node 0).
    fn levels(self) -> u8 {
        self.sub.per as u8
    }

    /// The node's values: for each level `l` (indexed by `l`), the largest `StaticE` of its
    /// descendants there.
    fn values(self) -> Option<&'a [f32]> {
        let values = self.sub.values(self.header, self.entry);
        let o = upper_index(self.node) * self.sub.per;
        values.get(o..o + self.sub.per)
    }
}

impl NodeSource for BlockNodes<'_> {
    fn node_info(&self, node: NodeId) -> Option<NodeInfo> {
        self.info(node).map(|(i, _)| i)
    }
}

/// The finest vertex level block-local node `n` (box `aabb`) needs, at most `max_level`: the
/// paper's Eq. 7 split (section 3.3, step 4) continued below `n`, every sub-node evaluated at
/// `n`'s distance and `beta` (closer than any sub-node, so the level is never too coarse).
/// A node drawn with its level-`l` corners has error `StaticE`; its sub-nodes whose `StaticE`
/// is still above the threshold need the next level's vertices. `StaticE` is monotone, so a
/// sub-node under the threshold has no descendant above it: only the over-threshold ones are
/// followed (the cost follows the detail drawn).
#[cfg(test)]
pub(crate) fn needed_vertex_level(
    h: &Header,
    e: &BlockEntry,
    n: NodeId,
    aabb: &Aabb,
    view: &View,
    max_level: u8,
) -> u8 {
    needed_at(h, e, n, || view.rho_per_metre(aabb), view, max_level, None)
}

/// [`needed_vertex_level`] with Eq. 7's `rho` per metre at `n`'s box from `per_metre` (asked
/// only when the walk needs it) and `n`'s per-level maxima `sub` when known
/// ([`needed_level_below`]).
fn needed_at(
    h: &Header,
    e: &BlockEntry,
    n: NodeId,
    per_metre: impl FnOnce() -> f64,
    view: &View,
    max_level: u8,
    sub: Option<LazySub<'_>>,
) -> u8 {
    let max_level = max_level.min(h.k);
    if n.level >= max_level {
        return n.level.min(max_level);
    }
    let per_metre = per_metre();
    if !per_metre.is_finite() {
        return max_level;
    }
    let limit = (view.tau / per_metre) as f32;
    needed_level_below(h, e, n, limit, max_level, sub)
}

/// [`needed_vertex_level`] once the node's error threshold `limit` (metres: `tau` over Eq. 7's
/// `rho` per metre at `n`) is known. A depth-first walk of the stored levels without
/// allocation: it finds the deepest stored level (at most `max_level`, at most the last
/// stored node level) holding a node over `limit` whose ancestors are all over it, and the
/// largest `StaticE` over `limit` there; the same result as the level-by-level frontier of the
/// paper's split (the frontier at a level is exactly the over-threshold nodes whose ancestors
/// are over it).
///
/// `sub`, when given, holds for each stored level `l` (indexed by `l`, entries above
/// `n.level` used) the largest `StaticE` of `n`'s descendants at `l` ([`StoreTree`]'s
/// per-patch arrays), with the fine maxima for every level below `k` (then the walk is exact
/// at every level, as with node values stored to full depth): the walk is then one look per
/// level instead of one per node. Below the levels it covers, [`below_bound`] bounds the
/// nodes.
fn needed_level_below(
    h: &Header,
    e: &BlockEntry,
    n: NodeId,
    limit: f32,
    max_level: u8,
    lazy: Option<LazySub<'_>>,
) -> u8 {
    let err = local_values(h, e, n).2;
    if err <= limit {
        return n.level;
    }
    // The deepest level the stored walk may reach.
    let walked = lazy.map_or(h.node_levels, |s| s.levels().max(h.node_levels));
    let last = max_level.min(walked.saturating_sub(1)).max(n.level);
    let mut stop = last;
    // A cheap bound first: no node at level `l` is over `limit` where the smaller of `n`'s
    // `StaticE` and the block's per-level maximum is not (both bound it, Eq. 3-5), so the walk
    // need not look at that level or below (the answer is at most `l`).
    if let Some(l) = (n.level + 1..=stop)
        .find(|&l| e.level_errors.get(l as usize).copied().unwrap_or(0.0).min(err) <= limit)
    {
        stop = l - 1;
    }
    // The per-level maxima cost the whole block's stored nodes once (`block_sub_max`) and
    // then one look per level; a walk no deeper than `n`'s children reads their four values.
    // Either gives the same level (`patch_factor_from_level_maxima_equals_the_walk`), so
    // a shallow walk goes without them: the far blocks a frame first sees, drawn coarse,
    // then never compute them (bench/ooc/README.md, "The block's level maxima when a walk
    // needs them").
    let sub = lazy.filter(|_| stop > n.level + 1).and_then(LazySub::values);
    if lazy.is_some() && sub.is_none() {
        // The walk without them, over the stored levels only.
        return needed_level_below(h, e, n, limit, max_level, None);
    }
    let mut deepest = n.level;
    let mut worst = err;
    match sub {
        // The largest `StaticE` per level under `n`: `StaticE` is monotone (Eq. 3-5: a node's
        // is at least each child's), so the nodes over `limit` at a level all have their
        // ancestors over it, and the walk's deepest level is the deepest whose maximum is over
        // `limit` (the maxima do not grow with the level), its `worst` that maximum.
        Some(sub) => {
            for l in n.level + 1..=stop {
                match sub.get(l as usize) {
                    Some(&m) if m > limit => {
                        deepest = l;
                        worst = m;
                    }
                    _ => break,
                }
            }
        }
        None if n.level < stop => over_walk(h, e, n, limit, stop, &mut deepest, &mut worst),
        None => {}
    }
    if deepest < last || deepest >= max_level {
        // No over-threshold node at the next level (or the cap is reached).
        return (deepest + 1).min(max_level);
    }
    // Below the walked levels every descendant has the same bound per level: the smaller of
    // the largest over-threshold StaticE there and `below_bound` (with the fine maxima the
    // largest StaticE under `n` at that level; without, the block's per-level maximum).
    let mut level = deepest;
    while level < max_level {
        let at = sub.and_then(|s| s.get(level as usize).copied());
        let bound = at.unwrap_or_else(|| below_bound(h, e, n, level)).min(worst);
        if bound <= limit {
            break;
        }
        level += 1;
    }
    level
}

/// The depth-first part of [`needed_level_below`]: the children of `m` (over `limit`) that
/// are over `limit`, down to level `stop`; recursion depth at most the stored node levels.
fn over_walk(
    h: &Header,
    e: &BlockEntry,
    m: NodeId,
    limit: f32,
    stop: u8,
    deepest: &mut u8,
    worst: &mut f32,
) {
    for c in m.children() {
        let v = local_values(h, e, c).2;
        if v <= limit {
            continue;
        }
        if c.level > *deepest {
            *deepest = c.level;
            *worst = v;
        } else if c.level == *deepest {
            *worst = worst.max(v);
        }
        if c.level < stop {
            over_walk(h, e, c, limit, stop, deepest, worst);
        }
    }
}

/// The split of one block's nodes ([`BlockNodes::splits`] under `rule`) as terrain-core's
/// [`SplitPolicy`]: the streamer's walk of a block for its needed level.
struct BlockSplit<'a> {
    nodes: BlockNodes<'a>,
    view: View,
    refine: Refinement,
}

impl SplitPolicy for BlockSplit<'_> {
    fn should_split(&mut self, node: NodeId, info: &NodeInfo) -> bool {
        let n = &self.nodes;
        let err = n.patch_error(node, local_values(n.header, n.entry, node).2);
        let per_metre = self.view.rho_per_metre(&info.aabb);
        n.splits(self.refine, &self.view, node, &info.aabb, err, per_metre)
    }
}

/// Largest size on screen (pixels) of a lattice cell of the level a block's page holds: the
/// renderer shades every fragment with central-difference normals of the page's samples, so a
/// page coarser than this draws visibly flat shading beside finer pages.
pub(crate) const SHADING_CELL_PX: f64 = 1.0;

/// The coarsest level of block `e` (of `b`) whose lattice cells are at most
/// [`SHADING_CELL_PX`] on screen at the block's nearest point: what the fragment stage's
/// normals need from the block's page, whatever its geometry needs (the criterion of texture
/// mip-level selection, applied to the height samples the normals are computed from).
pub(crate) fn shading_level(h: &Header, e: &BlockEntry, b: BlockId, view: &View) -> u8 {
    let lo = h.vertex_world(b, 0.0, 0.0);
    let hi = h.vertex_world(b, (e.valid_w.max(1) - 1) as f64, (e.valid_h.max(1) - 1) as f64);
    let b = Aabb { min: lo.min(hi).extend(e.min.into()), max: lo.max(hi).extend(e.max.into()) };
    shading_level_in(h, &b, view)
}

/// [`shading_level`] of a block whose box (its valid vertices' plan rectangle and its heights'
/// range) is `b`.
pub(crate) fn shading_level_in(h: &Header, b: &Aabb, view: &View) -> u8 {
    let d = (b.min - view.eye).max(view.eye - b.max).max(DVec3::ZERO).length();
    let spacing = h.georef.spacing_m.abs().max_element();
    // A level-L cell is 2^(k - L) samples: 2^(k - L) spacing lambda / d <= px.
    let room = d * SHADING_CELL_PX / (spacing * view.lambda);
    if !(room.is_finite() && room >= 1.0) {
        return h.k;
    }
    let coarser = (room.log2().floor() as i64).clamp(0, i64::from(h.k)) as u8;
    h.k - coarser
}

/// The finest level block `b` needs for `view`, or `None` when no node of it meets `region`:
/// its [`needed_geometry_level`], and at least its [`shading_level`]. What the streamer loads
/// for a block of the visual region M.
pub(crate) fn needed_level(
    h: &Header,
    e: &BlockEntry,
    b: BlockId,
    view: &View,
    region: &GroundRegion,
    refine: Refinement,
) -> Option<u8> {
    Some(needed_geometry_level(h, e, b, view, region, refine)?.max(shading_level(h, e, b, view)))
}

/// The deepest vertex level the patches of block `b` need for `view` ([`needed_vertex_level`]
/// of the patches terrain-core's [`traverse`] selects in the block with the selection's split
/// ([`BlockNodes::splits`] under `refine`, the patches of `refine.patch_cells`) and the
/// [`BoundingCircleCull`]), at least [`Refinement::segment_floor_level`], or `None` when no
/// node of it meets `region`.
pub(crate) fn needed_geometry_level(
    h: &Header,
    e: &BlockEntry,
    b: BlockId,
    view: &View,
    region: &GroundRegion,
    refine: Refinement,
) -> Option<u8> {
    let patch_level = patch_level(h, refine.patch_cells);
    let nodes = BlockNodes { header: h, entry: e, id: b, patch_level, sub: None };
    let mut split = BlockSplit { nodes, view: *view, refine };
    let mut cull = BoundingCircleCull::new(region.clone());
    let leaves = traverse(&nodes, &mut split, &mut cull, &mut |_, _| {});
    leaves
        .into_iter()
        .filter_map(|n| {
            let info = nodes.node_info(n)?;
            Some(nodes.needed_level(n, || view.rho_per_metre(&info.aabb), view, h.k))
        })
        .max()
        // The patches draw at least the segment floor's vertices.
        .map(|l| l.max(refine.segment_floor_level(h.k)))
}

/// Local level of a patch of `cells` cells (clamped to a power of two within the block).
fn patch_level(h: &Header, cells: u32) -> u8 {
    let cells = cells.clamp(1, h.block_cells()).next_power_of_two().min(h.block_cells());
    h.k - cells.trailing_zeros() as u8
}

/// Index of node `n` above the blocks in [`StoreTree`]'s flat per-node arrays (level-major,
/// row-major within a level, like `BlockEntry::nodes`).
fn upper_index(n: NodeId) -> usize {
    let side = 1usize << n.level;
    (side * side - 1) / 3 + n.j as usize * side + n.i as usize
}

/// The values of every node above the blocks of `store`, whose block level is `block_level`:
/// min/max over its blocks, and per block-local lattice level `0..=k` the largest of its
/// blocks' `level_errors` (`k + 1` per node), both in [`upper_index`] order. Computed once
/// from the index when the tree is built (no store format change): the blocks' values at the
/// block level, then each coarser level as the min/max and max of its four children.
/// A version-4 index holds the levels `0..levels` of its head's pyramid (every level above
/// the blocks when the grid has at most `2^HEAD_LEVELS` blocks a side; the same values: min/max
/// and max are exact in any order): they are taken as they are, no page read, and the levels
/// below them, if any, are computed per node when first visited ([`StoreTree`]'s `lower`).
/// Returns the arrays and the levels they hold.
fn upper_bounds(store: &Store, block_level: u8) -> (Vec<[f32; 2]>, Vec<f32>, u8) {
    if let Some(head) = store.block_pyramid() {
        return (head.upper.clone(), head.upper_err.clone(), head.levels);
    }
    let h = store.header();
    let per = h.k as usize + 1;
    let nodes = upper_index(NodeId { level: block_level, i: 0, j: 0 });
    let mut mm = vec![[f32::INFINITY, f32::NEG_INFINITY]; nodes];
    let mut err = vec![0f32; nodes * per];
    // The block level itself (not kept: the blocks' own entries hold it).
    let side = 1usize << block_level;
    let mut level_mm = vec![[f32::INFINITY, f32::NEG_INFINITY]; side * side];
    let mut level_err = vec![0f32; side * side * per];
    for id in store.block_ids() {
        if let Some(e) = store.entry(id) {
            let k = id.row as usize * side + id.col as usize;
            level_mm[k] = [e.min, e.max];
            for (l, v) in e.level_errors.iter().take(h.k as usize).enumerate() {
                level_err[k * per + l] = *v;
            }
        }
    }
    for level in (0..block_level).rev() {
        let m = 1usize << level;
        let base = upper_index(NodeId { level, i: 0, j: 0 });
        for j in 0..m {
            for i in 0..m {
                let (o, acc_e) = (base + j * m + i, (base + j * m + i) * per);
                for (ci, cj) in
                    [(2 * i, 2 * j), (2 * i + 1, 2 * j), (2 * i, 2 * j + 1), (2 * i + 1, 2 * j + 1)]
                {
                    let c = cj * (2 * m) + ci;
                    mm[o][0] = mm[o][0].min(level_mm[c][0]);
                    mm[o][1] = mm[o][1].max(level_mm[c][1]);
                    for l in 0..per {
                        err[acc_e + l] = err[acc_e + l].max(level_err[c * per + l]);
                    }
                }
            }
        }
        level_mm = mm[base..base + m * m].to_vec();
        level_err = err[base * per..(base + m * m) * per].to_vec();
    }
    (mm, err, block_level)
}

/// Nodes below the head's pyramid a [`StoreTree`] keeps at most (then it starts over).
const LOWER_NODES: usize = 1 << 16;

/// A node's min/max over its blocks and its `k + 1` per-level bounds.
type UpperNode = ([f32; 2], Arc<[f32]>);

/// How [`block_sub_max`] lays out one block's values: the deepest local level of the nodes
/// kept, the nodes per block and the values per node (0 nodes: none kept).
fn sub_layout(store: &Store, patch_level: u8) -> (u8, usize, usize) {
    let h = store.header();
    let levels = h.node_levels;
    if levels == 0 {
        return (0, 0, 0);
    }
    let top = patch_level.min(levels - 1);
    // With the fine maxima, every level below `k` (levels `node_levels..k` from them).
    let fine = store.has_fine_errors() && levels < h.k;
    let per = if fine { h.k as usize } else { levels as usize };
    (top, upper_index(NodeId { level: top + 1, i: 0, j: 0 }), per)
}

/// The per-level maxima of `StaticE` under every stored node of local level at most `top`
/// of the block whose entry is `e` (see `StoreTree::sub_max`; `nodes` and `per` from
/// [`sub_layout`]): for each such node and each deeper stored level, the maximum over its
/// descendants there, and below the stored levels the fine maxima's bound. Computed bottom
/// up (a node's maximum at a deeper level is its four children's largest there: one read of
/// each stored node and `O(nodes x levels)` maxima, where sweeping each node's descendants
/// per level read the deepest levels once per ancestor); the same maxima of the same values
/// (`block_sub_max_sweep`, the tests' reference). It is the cold part of a block's first
/// visit (`StoreTree::visited_block`).
fn block_sub_max(h: &Header, e: &BlockEntry, top: u8, nodes: usize, per: usize) -> Vec<f32> {
    let levels = h.node_levels;
    let fine = per == h.k as usize && levels < h.k;
    let lv = usize::from(levels);
    // Every stored node (levels `0..levels`), `lv` values each: at index `l`, the maximum at
    // level `l` under it (its own `StaticE` at its level, 0 without a node). A node's values
    // at its own level and coarser ones are 0 in its children (set at theirs and finer only),
    // and its own is at least 0, so the elementwise maximum with them leaves those as they are.
    let mut all = vec![0f32; node_count(levels) * lv];
    for level in (0..levels).rev() {
        let side = 1u32 << level;
        for j in 0..side {
            for i in 0..side {
                let o = upper_index(NodeId { level, i, j }) * lv;
                all[o + usize::from(level)] =
                    e.node(level, i, j).map_or(0.0, |v| 0f32.max(v.static_error));
            }
        }
        if level + 1 < levels {
            let (parents, children) = all.split_at_mut(node_count(level + 1) * lv);
            max_up(&mut parents[node_count(level) * lv..], children, level, lv);
        }
    }
    let mut block = vec![0f32; nodes * per];
    for n in nodes_to(top) {
        let (o, a) = (upper_index(n) * per, upper_index(n) * lv);
        let from = usize::from(n.level);
        block[o + from..o + lv].copy_from_slice(&all[a + from..a + lv]);
        if fine {
            fill_below(h, e, n, &mut block[o..o + per]);
        }
    }
    block
}

/// Every node of block-local levels `0..=top`, level by level, row by row.
fn nodes_to(top: u8) -> impl Iterator<Item = NodeId> {
    (0..=top).flat_map(|level| {
        let side = 1u32 << level;
        (0..side).flat_map(move |j| (0..side).map(move |i| NodeId { level, i, j }))
    })
}

/// Node `n`'s values below the stored node levels (`node_levels..k`, indexed by level in
/// `out`), from the fine maxima ([`below_bound`]).
fn fill_below(h: &Header, e: &BlockEntry, n: NodeId, out: &mut [f32]) {
    for l in h.node_levels..h.k {
        out[l as usize] = below_bound(h, e, n, l);
    }
}

/// [`block_sub_max`] by sweeping each node's descendants per level (the tests' reference).
#[cfg(test)]
pub(crate) fn block_sub_max_sweep(
    h: &Header,
    e: &BlockEntry,
    top: u8,
    nodes: usize,
    per: usize,
) -> Vec<f32> {
    let levels = h.node_levels;
    let fine = per == h.k as usize && levels < h.k;
    let mut block = vec![0f32; nodes * per];
    for n in nodes_to(top) {
        let o = upper_index(n) * per;
        for l in n.level..levels {
            let s = l - n.level;
            let mut m = 0f32;
            for dj in 0..1u32 << s {
                for di in 0..1u32 << s {
                    let (ci, cj) = ((n.i << s) + di, (n.j << s) + dj);
                    if let Some(v) = e.node(l, ci, cj) {
                        m = m.max(v.static_error);
                    }
                }
            }
            block[o + l as usize] = m;
        }
        if fine {
            fill_below(h, e, n, &mut block[o..o + per]);
        }
    }
    block
}

/// Per node above the deepest stored level of block `b` of `store` and per fine level:
/// [`below_bound`] (the entry's pyramid) and [`below_bound_sweep`] (the tests' comparison).
#[cfg(test)]
pub(crate) fn below_bound_both(store: &Store, b: BlockId) -> Option<Vec<(f32, f32)>> {
    let (h, e) = (store.header(), store.entry(b)?);
    let mut out = Vec::new();
    for level in 0..h.node_levels.saturating_sub(1) {
        for n in nodes_to(level).filter(|n| n.level == level) {
            for l in h.node_levels..h.k {
                out.push((below_bound(h, &e, n, l), below_bound_sweep(h, &e, n, l)));
            }
        }
    }
    Some(out)
}

/// [`block_sub_max`] and [`block_sub_max_sweep`] of block `b` of `store` at the layout a
/// tree of patch level `patch_level` uses (the tests' comparison).
#[cfg(test)]
pub(crate) fn block_sub_max_both(
    store: &Store,
    b: BlockId,
    patch_level: u8,
) -> Option<(Vec<f32>, Vec<f32>)> {
    let (top, nodes, per) = sub_layout(store, patch_level);
    let e = store.entry(b)?;
    let h = store.header();
    Some((block_sub_max(h, &e, top, nodes, per), block_sub_max_sweep(h, &e, top, nodes, per)))
}

/// Bytes of visited blocks (index entries and their `sub_max` values) a [`StoreTree`] keeps
/// beyond the blocks of its current selection ([`VisitedBlocks`]): computed when a block is
/// first visited, so a tree's memory and build time do not grow with the store. It must hold
/// a frame's view: `dss-2` and `uniform` over the 32769^2 store see 3,500 to 10,000 blocks a
/// frame; at 4,096 blocks and 16 MiB, cleared when full (until 2026-12-05), their selections took
/// 284 and 223 ms a frame (`store_frame`, 30 cameras over `pvps_884`), at 16,384 blocks 57 and
/// 118 ms (bench/ooc/README.md, "Every method from a 32769^2 store with every table, and the
/// tree's visited blocks sized for a frame's view"). That count held every block of the
/// 32769^2 store, about 200 MB with the entries' bytes it did not count; now the bytes are
/// counted and the least recently visited blocks leave first (bench/ooc/README.md, "The
/// tree's visited blocks counted in bytes").
const VISITED_BYTES: usize = 48 << 20;

/// Grid samples a [`crate::StoreSource`] read exact (their level resident in a block holding
/// them), by `(x << 32) | y`: what a selection asks of the store's heights again and again,
/// frame after frame (PVPS's patch corners: each a read of a resident block's level that
/// missed every CPU cache, about 40 % of `pvps-b`'s selection over a 32769^2 store). A
/// sample's stored value is the same in every block holding it (one quantization of the DEM's
/// sample for the whole store), and a store never changes, so a known sample is its exact
/// height for good, also after its level left the cache. At most [`KNOWN_SAMPLES`], all
/// forgotten when full.
#[derive(Debug, Default)]
pub(crate) struct KnownSamples {
    heights: terrain_core::hash::KeyMap<f32>,
}

/// Samples [`KnownSamples`] holds at most (a table of 2^19 slots of 17 bytes: about 9 MiB).
const KNOWN_SAMPLES: usize = 1 << 18;

impl KnownSamples {
    /// The key of grid sample `(x, y)`.
    pub(crate) fn key(x: u32, y: u32) -> u64 {
        (u64::from(x) << 32) | u64::from(y)
    }

    /// The sample of `key`, if known.
    pub(crate) fn get(&self, key: u64) -> Option<f32> {
        self.heights.get(&key).copied()
    }

    /// Keeps `z` as the exact height of `key`.
    pub(crate) fn keep(&mut self, key: u64, z: f32) {
        if self.heights.len() >= KNOWN_SAMPLES {
            self.heights.clear();
        }
        self.heights.insert(key, z);
    }

    /// Bytes held: the table's slots (its capacity is 7/8 of them), each a key and its
    /// value, padded, and a control byte.
    fn bytes(&self) -> u64 {
        let slots = self.heights.capacity() * 8 / 7;
        (slots * (std::mem::size_of::<(u64, f32)>() + 1)) as u64
    }
}

/// A visited block in [`StoreTree`]'s `sub_max`: its index entry and its values.
type VisitedBlock = (Arc<BlockEntry>, Option<Arc<SubMax>>);

/// A block's part of [`StoreTree`]'s `sub_max` ([`block_sub_max`] with the tree's layout),
/// computed when first read: only the factor walk of the paper's method (`needed_level_below`,
/// the cost split) reads it, and the other methods' selections visit every block in view
/// without (over the 32769^2 store, 11 KB a block, more than its index entry's 8.5 KB).
#[derive(Debug)]
struct SubMax {
    values: OnceLock<Box<[f32]>>,
    top: u8,
    nodes: usize,
    per: usize,
    /// The tree's bytes of computed values ([`VisitedBlocks::values`]): these values' bytes
    /// from when they are computed until they are dropped.
    counter: Arc<AtomicUsize>,
}

impl SubMax {
    /// The values, computed (and counted) at the first call.
    fn values(&self, header: &Header, entry: &BlockEntry) -> &[f32] {
        self.values.get_or_init(|| {
            let v: Box<[f32]> = block_sub_max(header, entry, self.top, self.nodes, self.per).into();
            self.counter.fetch_add(std::mem::size_of_val(&*v), Ordering::Relaxed);
            v
        })
    }
}

impl Drop for SubMax {
    fn drop(&mut self) {
        if let Some(v) = self.values.get() {
            self.counter.fetch_sub(std::mem::size_of_val(&**v), Ordering::Relaxed);
        }
    }
}

/// The blocks a [`StoreTree`] has visited, by row-major position, each with the selection
/// that last visited it (each [`NodeTree::with_traversal_source`] and each of the paper's
/// selections is one), and their bytes.
/// Beyond [`VISITED_BYTES`] the blocks the current selection has not visited leave, least
/// recently visited first, down to three quarters of it; the current selection's own are
/// kept, so a view larger than the bound is held whole while it is drawn (memory follows the
/// view, not the store) and never visited cold twice in one selection.
#[derive(Debug, Default)]
struct VisitedBlocks {
    /// Each block: the selection that last visited it, its bytes as counted when it came in
    /// (its entry's fine maxima may be built later), the block.
    blocks: IdMap<usize, (u64, usize, VisitedBlock)>,
    /// The blocks' bytes as counted when they came in, their `sub_max` values aside.
    bytes: usize,
    /// Bytes of the `sub_max` values computed so far and not dropped ([`SubMax`]).
    values: Arc<AtomicUsize>,
    /// The current selection's number.
    now: u64,
    /// The part of `bytes` the current selection has visited: while it is all of them there
    /// is nothing to evict, and a view above the bound does not scan the map at every block.
    current: usize,
}

impl VisitedBlocks {
    fn block_bytes(v: &VisitedBlock) -> usize {
        // The map's slot and the two allocations' headers, roughly, besides the data.
        64 + v.0.heap_bytes() + v.1.as_ref().map_or(0, |_| std::mem::size_of::<SubMax>())
    }

    /// Every byte held: the blocks' and their computed values'.
    fn all_bytes(&self) -> usize {
        self.bytes + self.values.load(Ordering::Relaxed)
    }

    /// A new selection starts.
    fn next(&mut self) {
        self.now += 1;
        self.current = 0;
    }

    fn get(&mut self, p: usize) -> Option<VisitedBlock> {
        let (now, current) = (self.now, &mut self.current);
        self.blocks.get_mut(&p).map(|(at, bytes, v)| {
            if *at < now {
                *current += *bytes;
            }
            *at = now;
            v.clone()
        })
    }

    fn insert(&mut self, p: usize, v: VisitedBlock, bound: usize) {
        let bytes = Self::block_bytes(&v);
        self.bytes += bytes;
        self.current += bytes;
        if let Some((at, old, _)) = self.blocks.insert(p, (self.now, bytes, v)) {
            self.bytes -= old;
            if at == self.now {
                self.current -= old;
            }
        }
        if self.all_bytes() > bound && self.bytes > self.current {
            let mut old: Vec<(u64, usize)> = self
                .blocks
                .iter()
                .filter(|(_, (at, ..))| *at < self.now)
                .map(|(&p, (at, ..))| (*at, p))
                .collect();
            old.sort_unstable();
            for (_, p) in old {
                if self.all_bytes() <= bound / 4 * 3 {
                    break;
                }
                let (_, bytes, _) = self.blocks.remove(&p).expect("a visited block");
                self.bytes -= bytes;
            }
        }
    }
}

/// The quadtree of a whole store's grid as a [`NodeSource`]: the root covers the blocks
/// rounded up to a power of two per side (block `(row, col)` is node `(block_level, col,
/// row)`), nodes inside a block read the block's index entry, nodes above the blocks flat
/// arrays built once from the index (min/max and per-level error bounds over their blocks).
/// No heights in memory.
#[derive(Debug, Clone)]
pub struct StoreTree {
    store: Arc<Store>,
    /// The geometry: the grid, the root over whole blocks, leaves of the smallest patch.
    shape: TreeShape,
    block_level: u8,
    root_cells: u32,
    patch_level: u8,
    /// Per node above the blocks, flat and level-major like `BlockEntry::nodes` (node `(l, i,
    /// j)` at `(4^l - 1) / 3 + j 2^l + i`): min/max over its blocks.
    upper: Vec<[f32; 2]>,
    /// Per node above the blocks (same order), `k + 1` values: for each block-local lattice
    /// level `l`, the largest `BlockEntry::level_errors[l]` of its blocks (0 at `l = k`), the
    /// bound on the error of every block under it drawn with its level-`l` vertices.
    upper_err: Vec<f32>,
    /// Levels `upper` and `upper_err` hold (`0..upper_levels`): every level above the blocks,
    /// or a version-4 head's when the grid has more than `2^HEAD_LEVELS` blocks a side.
    upper_levels: u8,
    /// The nodes above the blocks below `upper_levels`, computed when first visited from
    /// their children down to the blocks' entries (at most [`LOWER_NODES`] kept), shared by
    /// the tree's clones: the tree never reads every entry to build itself.
    lower: Arc<Mutex<HashMap<NodeId, UpperNode>>>,
    /// Per block (row-major position) and per stored node of local level at most the patch
    /// level (`BlockEntry::nodes` order), `sub_per` values: at index `l`, the largest
    /// `StaticE` of the node's descendants at level `l` (its own at its level; unused above
    /// it), stored levels and, with the fine maxima, every level below `k`. The leaves' factor walk (`needed_level_below`) reads one value per level.
    /// Kept per block from its first visit (within `visited_bytes` beyond the current
    /// selection's blocks, [`VisitedBlocks`]), the values computed when first read
    /// ([`SubMax`]), shared by the tree's clones.
    /// Beside each block's values, its index entry: a block visited again (the next frame)
    /// is found here, in one lookup, without asking the store (a version-4 index's page
    /// cache and its lock).
    sub_max: Arc<Mutex<VisitedBlocks>>,
    /// Grid samples read exact through a [`crate::StoreSource`] ([`KnownSamples`]), shared by
    /// the tree's clones.
    known: Arc<Mutex<KnownSamples>>,
    /// Bytes `sub_max` keeps beyond the current selection's blocks ([`VISITED_BYTES`]).
    visited_bytes: usize,
    /// Deepest local level of the nodes in `sub_max`.
    sub_top: u8,
    /// Nodes per block in `sub_max`.
    sub_nodes: usize,
    /// Values per node in `sub_max`: `node_levels`, or `k` with the fine maxima.
    sub_per: usize,
    /// The split rule inside the blocks and its screen-size floor.
    refine: Refinement,
}

impl StoreTree {
    /// The tree of `store` with patches of at least `patch_cells` cells (a power of two, at
    /// most a block; e.g. [`DEFAULT_PATCH_CELLS`]) and the default split rule.
    pub fn new(store: Arc<Store>, patch_cells: u32) -> Self {
        Self::with_refinement(store, Refinement { patch_cells, ..Refinement::default() })
    }

    /// The tree of `store` refined by `refine` (give the streamer the same:
    /// `StreamConfig::refinement`).
    pub fn with_refinement(store: Arc<Store>, refine: Refinement) -> Self {
        let patch_cells = refine.patch_cells;
        let h = store.header();
        let blocks = h.blocks_x.max(h.blocks_y).next_power_of_two();
        let block_level = blocks.trailing_zeros() as u8;
        let root_cells = blocks * h.block_cells();
        let patch_level = patch_level(h, patch_cells);
        let (upper, upper_err, upper_levels) = upper_bounds(&store, block_level);
        let shape = TreeShape::with_root(
            (h.width as u32).max(1),
            (h.height as u32).max(1),
            root_cells,
            h.block_cells() >> patch_level,
            h.georef.world_origin,
            h.georef.spacing_m,
        );
        let (sub_top, sub_nodes, sub_per) = sub_layout(&store, patch_level);
        Self {
            store,
            shape,
            block_level,
            root_cells,
            patch_level,
            upper,
            upper_err,
            upper_levels,
            lower: Arc::default(),
            sub_max: Arc::default(),
            known: Arc::default(),
            visited_bytes: VISITED_BYTES,
            sub_top,
            sub_nodes,
            sub_per,
            refine,
        }
    }

    /// How the tree is refined.
    pub fn refinement(&self) -> Refinement {
        Refinement { patch_cells: self.patch_cells(), ..self.refine }
    }

    /// The store.
    pub fn store(&self) -> &Arc<Store> {
        &self.store
    }

    /// Cells per side of the root (the whole grid rounded up to a power of two of blocks).
    pub fn root_cells(&self) -> u32 {
        self.root_cells
    }

    /// Global level of a whole block.
    pub fn block_level(&self) -> u8 {
        self.block_level
    }

    /// Cells per side of the smallest patch.
    pub fn patch_cells(&self) -> u32 {
        self.store.header().block_cells() >> self.patch_level
    }

    /// The block holding global node `n` and `n`'s id local to it (level 0 = the block), or
    /// `None` above the block level.
    pub fn block_of(&self, n: NodeId) -> Option<(BlockId, NodeId)> {
        let s = n.level.checked_sub(self.block_level)?;
        let mask = (1u32 << s) - 1;
        Some((BlockId::new(n.j >> s, n.i >> s), NodeId { level: s, i: n.i & mask, j: n.j & mask }))
    }

    /// The global id of block-local node `local` of block `b`.
    pub fn global(&self, b: BlockId, local: NodeId) -> NodeId {
        NodeId {
            level: self.block_level + local.level,
            i: (b.col << local.level) + local.i,
            j: (b.row << local.level) + local.j,
        }
    }

    /// The blocks global node `n` lies in: its block, or every block of the grid under a node
    /// larger than a block.
    pub fn blocks_under(&self, n: NodeId) -> Vec<BlockId> {
        if let Some((b, _)) = self.block_of(n) {
            return vec![b];
        }
        let h = self.store.header();
        let s = self.block_level - n.level;
        let (c0, r0, side) = (n.i << s, n.j << s, 1u32 << s);
        (r0..(r0 + side).min(h.blocks_y))
            .flat_map(|r| (c0..(c0 + side).min(h.blocks_x)).map(move |c| BlockId::new(r, c)))
            .collect()
    }

    /// Whether global node `n` holds a grid cell and is no finer than a block's finest level.
    pub fn contains(&self, n: NodeId) -> bool {
        let h = self.store.header();
        if n.level > self.block_level + h.k {
            return false;
        }
        let (x0, y0, _) = n.grid_rect(self.root_cells);
        x0 < (h.width as u32).max(2) - 1 && y0 < (h.height as u32).max(2) - 1
    }

    /// `f` of block `b`'s nodes (its index entry and its part of `sub_max`), through `memo`:
    /// the block looked up once while the caller stays in it.
    fn with_block_nodes<R>(
        &self,
        memo: &BlockMemo,
        b: BlockId,
        f: impl FnOnce(BlockNodes<'_>) -> R,
    ) -> Option<R> {
        let header = self.store.header();
        let hit = matches!(&*memo.last.borrow(), Some((m, ..)) if *m == b);
        if !hit {
            let (entry, values) = self.visited_block(b)?;
            *memo.last.borrow_mut() = Some((b, (entry, values)));
        }
        let last = memo.last.borrow();
        let (_, (entry, values)) = last.as_ref()?;
        let sub = values.as_deref();
        Some(f(BlockNodes { header, entry, id: b, patch_level: self.patch_level, sub }))
    }

    /// A selection starts: the blocks it visits are its own in `sub_max` ([`VisitedBlocks`]).
    fn next_visit(&self) {
        self.sub_max.lock().expect("sub_max").next();
    }

    /// Bytes of the visited blocks the tree holds (their index entries and `sub_max` values,
    /// shared by its clones): at most 48 MiB beyond its last selection's blocks. One memory
    /// budget for a store's data counts these beside the stream cache's blocks
    /// ([`crate::Streamer::set_budget_bytes`]).
    pub fn visited_bytes(&self) -> u64 {
        let known = self.known.lock().unwrap_or_else(|e| e.into_inner()).bytes();
        self.sub_max.lock().expect("sub_max").all_bytes() as u64 + known
    }

    /// The samples read exact so far ([`KnownSamples`]).
    pub(crate) fn known_samples(&self) -> std::sync::MutexGuard<'_, KnownSamples> {
        self.known.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Whether `other` shares this tree's visited blocks (it is a clone of it).
    pub fn shares_visited_with(&self, other: &StoreTree) -> bool {
        Arc::ptr_eq(&self.sub_max, &other.sub_max)
    }

    /// The blocks `sub_max` holds and their bytes ([`VisitedBlocks`]).
    #[cfg(test)]
    pub(crate) fn visited(&self) -> (usize, usize) {
        let m = self.sub_max.lock().expect("sub_max");
        (m.blocks.len(), m.all_bytes())
    }

    /// This tree keeping `bytes` of visited blocks beyond the current selection's.
    #[cfg(test)]
    pub(crate) fn with_visited_bytes(self, bytes: usize) -> Self {
        Self { visited_bytes: bytes, ..self }
    }

    /// Block `b`'s index entry and part of `sub_max`: from the tree's shared cache, else read,
    /// computed and kept; `None` outside the grid or when the entry cannot be read.
    fn visited_block(&self, b: BlockId) -> Option<VisitedBlock> {
        let header = self.store.header();
        let p = header.block_position(b)?;
        if let Some(v) = self.sub_max.lock().expect("sub_max").get(p) {
            return Some(v);
        }
        let entry = self.store.entry(b)?;
        let mut m = self.sub_max.lock().expect("sub_max");
        let values = (self.sub_nodes > 0).then(|| {
            Arc::new(SubMax {
                values: OnceLock::new(),
                top: self.sub_top,
                nodes: self.sub_nodes,
                per: self.sub_per,
                counter: m.values.clone(),
            })
        });
        let v = (entry, values);
        m.insert(p, v.clone(), self.visited_bytes);
        Some(v)
    }

    /// The least and greatest heights of the node above block `b` in the tree's pyramid (its
    /// parent; on a grid of more than `2^HEAD_LEVELS` blocks a side, its ancestor in the
    /// index's head, since below the head a node's values come from its blocks' entries): a
    /// range holding every one of `b`'s heights, with no index entry read. `None` above the
    /// grid or for a store of one block.
    fn heights_over(&self, b: BlockId) -> Option<[f32; 2]> {
        self.store.header().block_position(b)?;
        let parent = self.block_level.checked_sub(1)?;
        let level = parent.min(self.upper_levels.saturating_sub(1));
        let s = self.block_level - level;
        Some(self.with_upper(NodeId { level, i: b.col >> s, j: b.row >> s }, |mm, _| mm))
    }

    /// A box holding block `b`'s (its nominal plan square, the heights over it,
    /// [`StoreTree::heights_over`]: no index entry read), `None` above the grid or for a store
    /// of one block.
    pub(crate) fn block_box_bound(&self, b: BlockId) -> Option<Aabb> {
        let h = self.store.header();
        let [lo_z, hi_z] = self.heights_over(b)?;
        let cells = f64::from(h.block_cells());
        let (a, z) = (h.vertex_world(b, 0.0, 0.0), h.vertex_world(b, cells, cells));
        Some(Aabb { min: a.min(z).extend(f64::from(lo_z)), max: a.max(z).extend(f64::from(hi_z)) })
    }

    /// A height at or below every one of block `b`'s: the least height over it
    /// ([`StoreTree::heights_over`]), with no index entry read; the block's own entry's for a
    /// store of one block. A stand-in for a block without a resident level
    /// ([`crate::StoreSource`]): the frame thread asks it for patch corners in blocks nobody
    /// has visited (far patches spanning blocks, blocks just entering the view). Through the
    /// block's own entry those asks decoded index pages inside `pvps-b`'s selection, 14 % of
    /// its samples over the 32769^2 store's `fast_pass`.
    pub(crate) fn block_floor(&self, b: BlockId) -> Option<f32> {
        self.store.header().block_position(b)?;
        if self.block_level == 0 {
            return self.visited_block(b).map(|(e, _)| e.min);
        }
        let [lo, _] = self.heights_over(b)?;
        // `+inf` over blocks without a valid vertex.
        lo.is_finite().then_some(lo)
    }

    /// The box of every block's valid vertices (world metres: their plan rectangles and
    /// least and greatest heights), from the four corner blocks' entries and the root's
    /// min/max (no other entry read); `None` for a store without blocks.
    pub fn blocks_box(&self) -> Option<(DVec3, DVec3)> {
        let h = self.store.header();
        let (bx, by) = (h.blocks_x.checked_sub(1)?, h.blocks_y.checked_sub(1)?);
        let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
        // The grid maps to the world axis by axis, so the extremes lie in the corner blocks.
        for id in
            [BlockId::new(0, 0), BlockId::new(0, bx), BlockId::new(by, 0), BlockId::new(by, bx)]
        {
            let (a, b) = self.store.block_rect(id)?;
            lo = lo.min(a);
            hi = hi.max(b);
        }
        let [zlo, zhi] = if self.block_level == 0 {
            let e = self.store.entry(BlockId::new(0, 0))?;
            [e.min, e.max]
        } else {
            self.with_upper(NodeId { level: 0, i: 0, j: 0 }, |mm, _| mm)
        };
        Some((lo.extend(zlo.into()), hi.extend(zhi.into())))
    }

    /// The distance from `p` to the nearest block's box (its valid plan rectangle, its least
    /// and greatest heights: [`Store::block_rect`] and the entry's min/max), infinite for a
    /// store without blocks. Descends from the root nearest node first and skips every node
    /// whose box (which holds its blocks' boxes) is farther than the best block so far, so only
    /// the blocks near `p` read their index entries.
    pub fn nearest_block_distance(&self, p: DVec3) -> f64 {
        use std::cmp::Reverse;
        use std::collections::BinaryHeap;
        let dist = |lo: DVec3, hi: DVec3| (p.clamp(lo, hi) - p).length();
        let mut best = f64::INFINITY;
        // Non-negative distances order as their bits.
        let mut heap = BinaryHeap::from([Reverse((0u64, NodeId { level: 0, i: 0, j: 0 }))]);
        while let Some(Reverse((d, n))) = heap.pop() {
            // A node's box is computed in other arithmetic than its blocks' rectangles: a
            // margin keeps the skip exact.
            if f64::from_bits(d) > best + 1e-6 * (1.0 + best) {
                break;
            }
            if n.level == self.block_level {
                let b = BlockId::new(n.j, n.i);
                if let (Some(e), Some((a, c))) = (self.store.entry(b), self.store.block_rect(b)) {
                    best = best.min(dist(a.extend(e.min.into()), c.extend(e.max.into())));
                }
                continue;
            }
            for (di, dj) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let c = NodeId { level: n.level + 1, i: 2 * n.i + di, j: 2 * n.j + dj };
                let d = if c.level == self.block_level {
                    let h = self.store.header();
                    if c.i >= h.blocks_x || c.j >= h.blocks_y {
                        continue;
                    }
                    f64::from_bits(d)
                } else {
                    let [lo, hi] = self.with_upper(c, |mm, _| mm);
                    if lo > hi || !self.contains(c) {
                        continue;
                    }
                    let a = self.upper_info(c).aabb;
                    dist(a.min, a.max)
                };
                heap.push(Reverse((d.to_bits(), c)));
            }
        }
        best
    }

    /// `StaticE` of global node `n` (metres), or `None` above the blocks or outside the grid.
    pub fn static_error(&self, n: NodeId) -> Option<f32> {
        let (b, local) = self.block_of(n)?;
        let e = self.store.entry(b)?;
        Some(local_values(self.store.header(), &e, local).2)
    }

    /// [`BlockNodes::patch_error`] of global node `n` (metres), or `None` above the blocks or outside the
    /// grid.
    fn patch_error(&self, memo: &BlockMemo, n: NodeId) -> Option<f32> {
        let (b, local) = self.block_of(n)?;
        self.with_block_nodes(memo, b, |nodes| {
            nodes.patch_error(local, local_values(nodes.header, nodes.entry, local).2)
        })
    }

    /// [`NodeSource::node_info`] of global node `n` with its [`BlockNodes::patch_error`] (`None` above
    /// the blocks), from one read of the block's index entry.
    fn info_and_patch_error(&self, memo: &BlockMemo, n: NodeId) -> Option<(NodeInfo, Option<f32>)> {
        if !self.contains(n) {
            return None;
        }
        match self.block_of(n) {
            Some((b, local)) => self.with_block_nodes(memo, b, |nodes| {
                let (info, err) = nodes.info(local)?;
                Some((info, Some(nodes.patch_error(local, err))))
            })?,
            None => Some((self.upper_info(n), None)),
        }
    }

    /// The values of global node `n` above the block level (min/max over its blocks).
    fn upper_info(&self, n: NodeId) -> NodeInfo {
        let h = self.store.header();
        let (x0, y0, c) = n.grid_rect(self.root_cells);
        let (w, hh) = ((h.width as u32).max(2) - 1, (h.height as u32).max(2) - 1);
        let rect = GridRect { x0, y0, x1: (x0 + c).min(w), y1: (y0 + c).min(hh) };
        let [min, max] = self.with_upper(n, |mm, _| mm);
        let (min, max) = if min <= max { (min, max) } else { (0.0, 0.0) };
        let g = &h.georef;
        let lo = g.grid_to_world(DVec2::new(rect.x0 as f64, rect.y0 as f64));
        let hi = g.grid_to_world(DVec2::new(rect.x1 as f64, rect.y1 as f64));
        NodeInfo {
            rect,
            cells: c,
            aabb: Aabb { min: lo.min(hi).extend(min.into()), max: lo.max(hi).extend(max.into()) },
            data_range: Some((min, max)),
            has_voids: false,
            is_finest: false,
        }
    }

    /// The block-local lattice level at which node `n` above the blocks (`s` levels above
    /// them), box `aabb`, drawn as one patch spanning its blocks, meets Eq. 7's `tau` for
    /// `view`: the least `l` whose bound (the largest `level_errors[l]` of its blocks, each
    /// block drawn with its level-`l` vertices) times Eq. 7's `rho` per metre at `n`'s box is
    /// at most `tau`, among the levels a factor of at most [`MAX_FACTOR`] reaches (`2^(s + l)`
    /// segments across `n`: `l <= 6 - s`); `None` when none does (the node splits), when `n`
    /// is at or below the blocks, or when the eye is in its box.
    pub(crate) fn spanning_level(&self, n: NodeId, aabb: &Aabb, view: &View) -> Option<u8> {
        let s = self.block_level.checked_sub(n.level).filter(|&s| s > 0)?;
        let top = FACTOR_LEVELS.checked_sub(s)?.min(self.store.header().k);
        let per_metre = view.rho_per_metre(aabb);
        if !per_metre.is_finite() {
            return None;
        }
        let floor = self.refine.segment_floor_level(self.store.header().k);
        self.with_upper(n, |_, errs| {
            (floor..=top).find(|&l| per_metre * f64::from(errs[l as usize]) <= view.tau)
        })
    }

    /// `f` of node `n`'s (above the blocks) min/max over its blocks and its `k + 1` per-level
    /// bounds (the largest `level_errors[l]` of its blocks).
    fn with_upper<R>(&self, n: NodeId, f: impl FnOnce([f32; 2], &[f32]) -> R) -> R {
        if n.level < self.upper_levels {
            let per = self.store.header().k as usize + 1;
            let o = upper_index(n);
            return f(self.upper[o], &self.upper_err[o * per..(o + 1) * per]);
        }
        let (mm, errs) = self.lower_node(n);
        f(mm, &errs)
    }

    /// Node `n` below `upper_levels` (above the blocks): from its four children, down to the
    /// blocks' entries, as [`upper_bounds`] computes every level (empty nodes `+inf, -inf`,
    /// 0), kept in `lower`.
    fn lower_node(&self, n: NodeId) -> UpperNode {
        if let Some(v) = self.lower.lock().expect("lower").get(&n) {
            return v.clone();
        }
        let h = self.store.header();
        let per = h.k as usize + 1;
        let (mut mm, mut errs) = ([f32::INFINITY, f32::NEG_INFINITY], vec![0f32; per]);
        for (di, dj) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let c = NodeId { level: n.level + 1, i: 2 * n.i + di, j: 2 * n.j + dj };
            // Outside the grid: no block under it.
            let s = self.block_level - c.level;
            if c.i << s >= h.blocks_x || c.j << s >= h.blocks_y {
                continue;
            }
            if s == 0 {
                if let Some(e) = self.store.entry(BlockId::new(c.j, c.i)) {
                    mm = [mm[0].min(e.min), mm[1].max(e.max)];
                    for (o, v) in errs.iter_mut().zip(e.level_errors.iter().take(h.k as usize)) {
                        *o = o.max(*v);
                    }
                }
            } else {
                let (cm, ce) = self.lower_node(c);
                mm = [mm[0].min(cm[0]), mm[1].max(cm[1])];
                for (o, v) in errs.iter_mut().zip(ce.iter()) {
                    *o = o.max(*v);
                }
            }
        }
        let v: UpperNode = (mm, errs.into());
        let mut m = self.lower.lock().expect("lower");
        if m.len() >= LOWER_NODES {
            m.clear();
        }
        m.insert(n, v.clone());
        v
    }

    /// The least of `resident` over the blocks under node `n` (its block at or below the
    /// block level), or `None` when one of them has nothing resident. Stops early (`Some` of
    /// a value below `at_least`) once a block holds less than `at_least`.
    fn least_resident(
        &self,
        n: NodeId,
        at_least: u8,
        resident: &impl Fn(BlockId) -> Option<u8>,
    ) -> Option<u8> {
        if let Some((b, _)) = self.block_of(n) {
            return resident(b);
        }
        let h = self.store.header();
        let s = self.block_level - n.level;
        let (c0, r0, side) = (n.i << s, n.j << s, 1u32 << s);
        let mut least = u8::MAX;
        for r in r0..(r0 + side).min(h.blocks_y) {
            for c in c0..(c0 + side).min(h.blocks_x) {
                least = least.min(resident(BlockId::new(r, c))?);
                if least < at_least {
                    return Some(least);
                }
            }
        }
        Some(least)
    }

    /// `needed_vertex_level` of global node `n` with box `aabb` (at most `max_level`, a
    /// block-local level), as a global level; `None` above the blocks.
    pub fn needed_vertex_level(
        &self,
        n: NodeId,
        aabb: &Aabb,
        view: &View,
        max_level: u8,
    ) -> Option<u8> {
        let memo = BlockMemo::default();
        self.needed_vertex_level_at(&memo, n, || view.rho_per_metre(aabb), view, max_level)
    }

    /// [`StoreTree::needed_vertex_level`] with Eq. 7's `rho` per metre at the node's box from
    /// `per_metre` (the split test's when it computed it), asked only when the walk needs it.
    fn needed_vertex_level_at(
        &self,
        memo: &BlockMemo,
        n: NodeId,
        per_metre: impl FnOnce() -> f64,
        view: &View,
        max_level: u8,
    ) -> Option<u8> {
        let (b, local) = self.block_of(n)?;
        self.with_block_nodes(memo, b, |nodes| {
            self.block_level + nodes.needed_level(local, per_metre, view, max_level)
        })
    }
}

impl NodeTree for StoreTree {
    fn shape(&self) -> &TreeShape {
        &self.shape
    }

    /// The tree through a [`BlockMemo`] for the length of `f`: a traversal's nodes of one
    /// block find its entry and `sub_max` once, not through `sub_max`'s lock, hash and
    /// reference counts per node (what [`NodeSource::node_info`] alone does).
    fn with_traversal_source(&self, f: &mut dyn FnMut(&dyn NodeSource)) {
        self.next_visit();
        f(&MemoNodes { tree: self, memo: BlockMemo::default() })
    }
}

/// [`StoreTree`]'s nodes through one traversal's [`BlockMemo`]
/// ([`NodeTree::with_traversal_source`]).
struct MemoNodes<'a> {
    tree: &'a StoreTree,
    memo: BlockMemo,
}

impl NodeSource for MemoNodes<'_> {
    fn node_info(&self, n: NodeId) -> Option<NodeInfo> {
        self.tree.node_info_in(&self.memo, n)
    }
}

impl StoreTree {
    /// [`NodeSource::node_info`] through `memo`.
    fn node_info_in(&self, memo: &BlockMemo, n: NodeId) -> Option<NodeInfo> {
        if !self.contains(n) {
            return None;
        }
        if let Some((b, local)) = self.block_of(n) {
            return self.with_block_nodes(memo, b, |nodes| nodes.node_info(local))?;
        }
        Some(self.upper_info(n))
    }
}

impl NodeSource for StoreTree {
    fn node_info(&self, n: NodeId) -> Option<NodeInfo> {
        self.node_info_in(&BlockMemo::default(), n)
    }
}

/// The block a selection last asked [`StoreTree`] about, with its index entry and its part of
/// `sub_max`: the traversal visits one block's nodes one after another (depth first), and the
/// leaves come in the same order, so each block's entry is looked up (a page of a version-4
/// index: the page cache's lock) and its `sub_max` found once per run of its nodes, not once
/// per node.
#[derive(Default)]
struct BlockMemo {
    last: RefCell<Option<(BlockId, VisitedBlock)>>,
}

/// The traversal's node space for one selection: the [`StoreTree`], remembering the node it
/// was last asked about with its box and [`BlockNodes::patch_error`], so that the split test and the
/// leaf's factor reuse the index values [`traverse`] just read (it asks for a node's info, then
/// culls it, splits it or reports it, before it asks for the next node).
struct FrameNodes<'a> {
    tree: &'a StoreTree,
    last: Cell<Option<(NodeId, NodeInfo, Option<f32>)>>,
    /// The block of the nodes last asked about.
    memo: BlockMemo,
}

impl FrameNodes<'_> {
    /// The info and patch error of `n` if it was the last node asked about.
    fn cached(&self, n: NodeId) -> Option<(NodeInfo, Option<f32>)> {
        match self.last.get() {
            Some((m, info, err)) if m == n => Some((info, err)),
            _ => None,
        }
    }

    /// The patch error of `n` (`None` above the blocks or outside the grid).
    fn patch_error(&self, n: NodeId) -> Option<f32> {
        match self.cached(n) {
            Some((_, err)) => err,
            None => self.tree.patch_error(&self.memo, n),
        }
    }
}

impl NodeSource for FrameNodes<'_> {
    fn node_info(&self, n: NodeId) -> Option<NodeInfo> {
        let (info, err) = self.tree.info_and_patch_error(&self.memo, n)?;
        self.last.set(Some((n, info, err)));
        Some(info)
    }
}

/// The traversal part of [`select_patches`]: terrain-core's [`traverse`] over `tree` with the
/// split and the culls, before the balance; its leaves in traversal order with their boxes
/// and, inside blocks, their needed vertex levels (`StoreTree::needed_vertex_level_at`, at
/// most the block's resident level; global levels), worked out when the traversal reports the
/// leaf, while its block's entry is at hand; above the blocks, the block-local level their
/// split test found each of their blocks holds (`StoreTree::spanning_level`).
fn traverse_store(
    tree: &StoreTree,
    camera: &Camera,
    view: &View,
    resident: &impl Fn(BlockId) -> Option<u8>,
    walk: Walk,
) -> (Vec<(NodeId, Aabb, Option<u8>)>, SelectionStats) {
    let view = *view;
    let mut circle = BoundingCircleCull::new(project_view_to_ground(camera));
    let mut frustum = FrustumCull::new(Frustum::from_camera(camera));
    let mut cull = |n: NodeId, info: &NodeInfo| {
        let c = match tree.block_of(n) {
            // Above the blocks: never "all inside", so every block is asked whether it is drawn.
            None => match circle.classify(n, info) {
                Cull::AcceptAll => Cull::Accept,
                c => c,
            },
            Some((b, local)) if local.level == 0 && resident(b).is_none() => Cull::Reject,
            Some(_) => circle.classify(n, info),
        };
        match (c, frustum.classify(n, info)) {
            (Cull::Reject, _) | (_, Cull::Reject) => Cull::Reject,
            (Cull::AcceptAll, Cull::AcceptAll) => Cull::AcceptAll,
            _ => Cull::Accept,
        }
    };
    if walk == Walk::Frame {
        tree.next_visit();
    }
    let nodes = FrameNodes { tree, last: Cell::new(None), memo: BlockMemo::default() };
    // Eq. 7 (the paper's step 4: split while `rho > tau`) on each node's patch error, stopped
    // at its block's resident level. A node above the blocks stays one patch spanning its
    // blocks when some factor of at most 64 meets `tau` (`spanning_level`, from the largest
    // per-level error of its blocks) and each of its blocks holds that level; else it splits.
    // Eq. 7's `rho` per metre of the last node the split test asked about: a leaf's factor
    // (`needed_vertex_level`) reuses it.
    let last_rho: Cell<Option<(NodeId, f64)>> = Cell::new(None);
    // The spanning level of the last node above the blocks the split test kept whole (each of
    // its blocks holds it): the leaf's level.
    let last_span: Cell<Option<(NodeId, u8)>> = Cell::new(None);
    let mut split = |n: NodeId, info: &NodeInfo| -> bool {
        match tree.block_of(n) {
            Some((b, local)) => {
                if local.level >= resident(b).unwrap_or(0) {
                    return false;
                }
                let Some(err) = nodes.patch_error(n) else { return true };
                tree.with_block_nodes(&nodes.memo, b, |block| {
                    let per_metre = view.rho_per_metre(&info.aabb);
                    last_rho.set(Some((n, per_metre)));
                    block.splits(tree.refine, &view, local, &info.aabb, err, per_metre)
                })
                .unwrap_or(true)
            }
            None => match tree.spanning_level(n, &info.aabb, &view) {
                Some(l) => {
                    let splits = tree.least_resident(n, l, &resident).is_none_or(|r| r < l);
                    if !splits {
                        last_span.set(Some((n, l)));
                    }
                    splits
                }
                None => true,
            },
        }
    };
    let mut stats = SelectionStats::default();
    // The leaves with their boxes, in traversal order: inside blocks (with their needed
    // levels), and above them the patches spanning several blocks (with their spanning
    // levels).
    let mut boxed: Vec<(NodeId, Aabb, Option<u8>)> = Vec::new();
    traverse(&nodes, &mut split, &mut cull, &mut |n, v| {
        stats.visited += 1;
        match v {
            Visit::Culled => stats.culled += 1,
            Visit::Split => stats.split += 1,
            Visit::Leaf => {
                if let Some((info, _)) = nodes.cached(n) {
                    // Eq. 7's `rho` per metre where the split test computed it.
                    let rho = last_rho.get().filter(|&(m, _)| m == n).map(|(_, r)| r);
                    let per_metre = || rho.unwrap_or_else(|| view.rho_per_metre(&info.aabb));
                    let level = match tree.block_of(n) {
                        Some((b, _)) => {
                            let max = resident(b).unwrap_or(0);
                            tree.needed_vertex_level_at(&nodes.memo, n, per_metre, &view, max)
                        }
                        None => last_span.get().filter(|&(m, _)| m == n).map(|(_, l)| l),
                    };
                    boxed.push((n, info.aabb, level));
                }
            }
        }
    });
    stats.traversal_leaves = boxed.len();
    (boxed, stats)
}

/// The leaves of [`select_patches`]' traversal, before the balance (tests).
#[cfg(test)]
pub(crate) fn traversal_leaves(
    tree: &StoreTree,
    camera: &Camera,
    tau: f64,
    resident: impl Fn(BlockId) -> Option<u8>,
) -> Vec<NodeId> {
    traverse_store(
        tree,
        camera,
        &View::floored(camera, tau, tree.refine.view_angle_floor),
        &resident,
        Walk::Frame,
    )
    .0
    .into_iter()
    .map(|l| l.0)
    .collect()
}

/// The crack-free patches of a store for `camera`: terrain-core's [`traverse`] over the
/// [`StoreTree`] with the Eq. 7 split and two culls, only over blocks with a level resident
/// (`resident(block)`: the finest level that may be drawn, `None` = not drawn), the split
/// stopped at that level; then balanced, factors from `needed_vertex_level` (clamped to the
/// resident level, at least 2) and outer factors by terrain-core's [`wish_outer_factors`]. The culls:
/// the paper's [`BoundingCircleCull`] against the view projected on the ground (section 3.3,
/// steps 2-3), and terrain-core's [`FrustumCull`] of each node's world box (its min/max
/// heights): the circle keeps nodes beside and behind the view triangle's sides, and a node
/// whose box is outside the frustum cannot be seen (the standard six-plane box test, exact for
/// "outside"). Patches are global nodes of the tree (`NodeId::grid_rect(tree.root_cells())` is
/// their square of grid samples), in traversal order; `terrain_core::lod::check_shared_edges`
/// holds.
pub fn select_patches(
    tree: &StoreTree,
    camera: &Camera,
    tau: f64,
    resident: impl Fn(BlockId) -> Option<u8>,
) -> Selection {
    select_patches_in(tree, camera, tau, resident, Walk::Frame)
}

/// Whose selection a walk of the tree is: a frame's, which starts the tree's visit of its
/// blocks ([`VisitedBlocks`]: the blocks it visits are the current selection's), or a
/// [`crate::TreeWarmer`]'s one frame ahead, which computes the same blocks' values for the
/// next frame and leaves the current visit as it is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Walk {
    Frame,
    Ahead,
}

/// [`select_patches`] as a frame's walk or one ahead ([`Walk`]).
pub(crate) fn select_patches_in(
    tree: &StoreTree,
    camera: &Camera,
    tau: f64,
    resident: impl Fn(BlockId) -> Option<u8>,
    walk: Walk,
) -> Selection {
    let start = Instant::now();
    let view = View::floored(camera, tau, tree.refine.view_angle_floor);
    let bl = tree.block_level;
    let seg_floor = tree.refine.segment_floor_level(tree.store.header().k);
    let (boxed, mut stats) = traverse_store(tree, camera, &view, &resident, walk);
    let traversed: Vec<NodeId> = boxed.iter().map(|&(n, ..)| n).collect();
    // Balanced leaves, sorted by `dfs_key` like the traversal's: a leaf the balance kept is
    // found by walking both lists together.
    let set = LeafTree::balanced(&traversed, |n| tree.contains(n));
    let leaves = set.leaves();
    // Each leaf's wished factor, beside it (index-aligned with `leaves`).
    let mut want = Vec::with_capacity(leaves.len());
    let memo = BlockMemo::default();
    let mut k = 0;
    for &n in leaves {
        let key = n.dfs_key();
        while k < boxed.len() && boxed[k].0.dfs_key() < key {
            k += 1;
        }
        // A traversal leaf's box and needed level; a leaf the balance added, its box.
        let (aabb, level) = match boxed.get(k) {
            Some(&(m, aabb, level)) if m == n => (Some(aabb), level),
            _ => (tree.node_info_in(&memo, n).map(|i| i.aabb), None),
        };
        let m = match tree.block_of(n) {
            Some((b, local)) => {
                let max = resident(b).unwrap_or(0);
                let level = level
                    .or_else(|| {
                        let aabb = aabb?;
                        let per_metre = || view.rho_per_metre(&aabb);
                        tree.needed_vertex_level_at(&memo, n, per_metre, &view, max)
                    })
                    .unwrap_or(n.level);
                // The segment floor, at most what is resident.
                let level = level.max(bl + seg_floor.min(max));
                level.saturating_sub(bl + local.level).min(FACTOR_LEVELS)
            }
            // A patch spanning `2^s` blocks per side: `2^(s + l)` segments put the level-`l`
            // vertices of each block (a balance-added child of a spanning leaf may miss `tau`
            // at any factor: then its largest), at most its blocks' least resident level.
            // A traversal leaf's level is its spanning level: the split test kept it whole
            // because each of its blocks holds that level, so their least is no lower.
            None => {
                let s = bl - n.level;
                let l = level.unwrap_or_else(|| {
                    let top = FACTOR_LEVELS.saturating_sub(s);
                    let l = aabb.and_then(|a| tree.spanning_level(n, &a, &view)).unwrap_or(top);
                    l.min(tree.least_resident(n, 0, &resident).unwrap_or(0))
                });
                (s + l).min(FACTOR_LEVELS)
            }
        };
        want.push(((1u32 << m) as f32).clamp(2.0, MAX_FACTOR));
    }
    let patches: Vec<Patch> = wish_outer_factors(&set, &want)
        .into_iter()
        .zip(leaves.iter().zip(&want))
        .map(|(outer, (&node, &w))| Patch { node, outer, inner: [w, w] })
        .collect();
    stats.patches = patches.len();
    stats.balance_added = patches.len().saturating_sub(stats.traversal_leaves);
    stats.max_level = patches.iter().map(|p| p.node.level).max().unwrap_or(0);
    stats.cpu_time = start.elapsed();
    Selection { patches, stats }
}

/// The level of each of a set of blocks (a frame's drawn blocks and their page levels), for
/// [`select_patches`]' `resident`: by position in the blocks' bounding rectangle of the block
/// grid, so that a lookup is an array read. The selection asks it about every block under
/// each node above the blocks that may be drawn as one patch (`least_resident`): over the
/// 32769^2 store, 5,000-24,000 blocks a selection, each a hash lookup until 2026-12-07. A set
/// spread thinly over a large rectangle (more than `SPARSE_BLOCKS` slots per block, a long
/// diagonal view over a huge grid) keeps a hash map instead: the same answers.
#[derive(Debug, Clone)]
pub struct BlockLevelGrid {
    /// The rectangle's south-west block and its columns.
    col0: u32,
    row0: u32,
    cols: u32,
    rows: u32,
    /// Row-major over the rectangle, [`NO_LEVEL`] for a block not in the set.
    levels: Vec<u8>,
    /// The set itself, when the rectangle is too sparse.
    sparse: Option<IdMap<BlockId, u8>>,
}

/// Slots of [`BlockLevelGrid`]'s rectangle per block of the set beyond which it keeps a map.
const SPARSE_BLOCKS: usize = 16;

/// [`BlockLevelGrid`]'s empty slot (a block's level is at most its store's `k`).
const NO_LEVEL: u8 = u8::MAX;

impl BlockLevelGrid {
    /// The levels of `blocks` (a block listed twice keeps its last level).
    pub fn new(blocks: &[(BlockId, u8)]) -> Self {
        let (mut c0, mut r0, mut c1, mut r1) = (u32::MAX, u32::MAX, 0, 0);
        for &(b, _) in blocks {
            (c0, r0, c1, r1) = (c0.min(b.col), r0.min(b.row), c1.max(b.col), r1.max(b.row));
        }
        let (cols, rows) = if blocks.is_empty() { (0, 0) } else { (c1 - c0 + 1, r1 - r0 + 1) };
        let area = cols as usize * rows as usize;
        let sparse = area > SPARSE_BLOCKS * blocks.len() + 4096;
        let mut grid = Self {
            col0: c0,
            row0: r0,
            cols,
            rows,
            levels: Vec::new(),
            sparse: sparse.then(|| blocks.iter().copied().collect()),
        };
        if !sparse {
            grid.levels = vec![NO_LEVEL; area];
            for &(b, level) in blocks {
                let k = grid.slot(b).expect("a block of the set lies in its rectangle");
                // A level of `NO_LEVEL` itself cannot be stored: none is (levels <= k).
                grid.levels[k] = level;
            }
        }
        grid
    }

    fn slot(&self, b: BlockId) -> Option<usize> {
        let (c, r) = (b.col.wrapping_sub(self.col0), b.row.wrapping_sub(self.row0));
        (c < self.cols && r < self.rows).then(|| r as usize * self.cols as usize + c as usize)
    }

    /// Whether the set is kept as a map (tests).
    #[cfg(test)]
    pub(crate) fn is_sparse(&self) -> bool {
        self.sparse.is_some()
    }

    /// The level of block `b`, `None` when it is not in the set.
    pub fn get(&self, b: BlockId) -> Option<u8> {
        if let Some(map) = &self.sparse {
            return map.get(&b).copied();
        }
        let level = *self.levels.get(self.slot(b)?)?;
        (level != NO_LEVEL).then_some(level)
    }
}

/// [`select_patches`] over what `streamer` holds: the blocks of its last frame's visual region
/// M, each drawn at most at the coarser of its finest resident level and the level it needs
/// (blocks with nothing resident are not drawn). Call after [`Streamer::update`] or
/// [`Streamer::wait_until_resident`] for the same camera. Levels beyond the needed ones (Eq.
/// 8's prefetches, earlier frames' leftovers) depend on the workers' timing and are not used:
/// after a wait that returns `resident: true` the selection is a function of the camera.
pub fn select_streamed(
    tree: &StoreTree,
    camera: &Camera,
    tau: f64,
    streamer: &Streamer,
) -> Selection {
    let levels: Vec<(BlockId, u8)> = streamer
        .scheduled()
        .iter()
        .filter(|s| s.visible)
        .filter_map(|s| {
            let count = streamer.block(s.block)?.count();
            Some((s.block, (count.checked_sub(1)? as u8).min(s.needed)))
        })
        .collect();
    let levels = BlockLevelGrid::new(&levels);
    select_patches(tree, camera, tau, |b| levels.get(b))
}
