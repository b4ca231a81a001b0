//! CPU side of the LOD methods: which quadtree patches to draw and with which tessellation
//! factors, so the GPU only tessellates and draws.
//!
//! Every method runs the one quadtree traversal ([`crate::quadtree::traverse`]) with its own
//! [`SplitPolicy`](crate::quadtree::SplitPolicy) and a [`FrustumCull`](crate::quadtree::FrustumCull),
//! balances the leaves ([`crate::quadtree::balance`]) where it mixes levels, then assigns each
//! leaf a [`Patch`] with four outer and two inner factors:
//!
//! - [`pvps`]: the PVPS paper's (Zhang 2021, section 2.3-2.4) method C (roughness-weighted split,
//!   Eq. 8-9; crack-free edge classification, Eq. 11 and Algorithm 1; inner levels, Eq. 12) and
//!   its comparison methods A and B, which only swap the roughness field ([`Method`]).
//! - [`dss_methods`]: the DSS paper's (Zhang 2019, section 4) comparison paths: Method I
//!   (quadtree, power-of-two factors) and Method II (uniform blocks, continuous factors).
//! - [`dss_file`]: the DSS errors' file (precomputed by `terrain bake`, stored with the scene).
//! - `dss_pages` (private): that file read by pages through a bounded cache
//!   ([`DssErrorTable::open_paged`]), so a large store's memory follows the view.
//! - [`dss_strips`]: the DSS paper's own method (section 3): M-blocks with their own
//!   continuous factors, P-blocks and stitching strips instead of matched edge factors (the
//!   crack-freedom invariant below does not apply to it: its blocks share no edge).
//! - [`edges`]: the one place outer factors are resolved across shared edges, and the checker
//!   of the crack-freedom invariant.
//! - [`geomipmap`]: the geomorphing article's (Wagner 2003) geo-mipmapped patches: a level and
//!   a continuous tween factor per patch, neighbours within one level, border rules; its
//!   per-patch [`GeomipTable`] selects over any patch tree (a heightmap's or a store's).
//! - [`geomip_file`]: that table's file (`geomip.bin`, written by `terrain bake` into a store).
//! - `geomip_pages` (private): that file read by pages through a bounded cache
//!   ([`GeomipTable::open_paged`]), so a store's open and memory follow the view.
//! - [`surface`]: rebuilds the drawn surface on the CPU from a selection and a tessellator.
//! - `window` (private): a dense per-row index over the patches a frame considers, so
//!   selections cost what is in view, not the grid's size.
//!
//! # The crack-freedom invariant
//! For every edge shared by two selected leaves, both patches assign that edge the same
//! factor; where a coarse patch's edge meets finer patches, each finer patch's factor is the
//! coarse factor divided by `2^(level difference)`, and those factors are powers of two
//! `>= 2`, so under fractional-even (or integer) spacing the finer patches' edge vertices are
//! exactly the coarse edge's. Domain points map onto the node's *unclipped* square and are
//! clamped to the grid afterwards ([`surface::patch_grid_point`]), so vertices that coincide
//! in the full quadtree still coincide at the east and north borders of grids that are not
//! `2^L + 1` samples. See [`edges`] for the proof sketch and [`edges::check_shared_edges`] for
//! the test.
//!
//! # Frames
//! The papers are OpenGL y-up; here x is east, y north, z up. A patch's domain is `(u, v)`
//! with `u` east and `v` north.

pub mod dss_file;
pub mod dss_methods;
mod dss_pages;
pub mod dss_strips;
pub mod edges;
pub mod geomip_file;
mod geomip_pages;
pub mod geomipmap;
pub mod patch;
pub mod pvps;
pub mod source;
pub mod surface;
mod window;

pub use dss_file::DssFileError;
pub use dss_methods::{
    DssConfig, DssErrorTable, DssParallel, RowsBudget, Sequential, select_dss_power_of_two,
    select_dss_uniform,
};
pub use dss_pages::{DssPaging, DssPagingStats};
pub use dss_strips::{
    DssStripFrame, DssStripsConfig, MBlock, PBlock, Strip, StripFactors, frame_from_leaves,
    select_dss_strips,
};
pub use edges::{
    EdgeMismatch, EdgeRule, WishEdges, check_shared_edges, outer_factors, outer_factors_all,
    wish_outer_factors,
};
pub use geomip_file::{GeomipEncoder, GeomipFileError, GeomipFor};
pub use geomip_pages::{GeomipPaging, GeomipPagingStats, TableReader};
pub use geomipmap::{
    GeomipConfig, GeomipRow, GeomipRuns, GeomipScene, GeomipSelection, GeomipTable, PatchLod,
    PatchRun,
};
pub use patch::{Edge, MAX_FACTOR, MIN_FACTOR, Patch, Selection, SelectionStats, clamp_factor};
pub use pvps::{Method, NodeDistance, PvpsConfig, select_pvps, select_pvps_with_cull};
pub use source::{GridSource, TerrainSource};
pub use surface::{SurfaceMesh, build_surface, edge_segment, patch_grid_point};

use crate::quadtree::NodeId;

/// A scalar per quadtree node, e.g. a roughness pyramid. terrain-core cannot depend on
/// terrain-visibility, so the LOD methods read roughness through this trait (terrain-visibility
/// implements it for its `NodePyramid`).
///
/// Nodes are addressed like [`NodeId`]: level 0 is the root, `i` east, `j` north, over the
/// quadtree's `root_cells`.
pub trait NodeField {
    /// The value of `node`.
    fn value(&self, node: NodeId) -> f32;
}

impl<F: Fn(NodeId) -> f32> NodeField for F {
    fn value(&self, node: NodeId) -> f32 {
        self(node)
    }
}

/// The same value for every node (e.g. a flat terrain's roughness, or to disable roughness).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConstantField(pub f32);

impl NodeField for ConstantField {
    fn value(&self, _: NodeId) -> f32 {
        self.0
    }
}

/// Shared plumbing of the methods: the traversal with stats, balancing, and patch assembly.
pub(crate) mod run {
    use glam::DVec3;

    use super::patch::SelectionStats;
    use crate::geometry::Camera;
    use crate::metrics::screen::{MAX_FOV_Y, MIN_DISTANCE_M, MIN_FOV_Y};
    use crate::quadtree::{
        CullPolicy, FrustumCull, LeafTree, NoCull, NodeId, NodeInfo, NodeTree, SplitPolicy, Visit,
        traverse,
    };

    /// Runs the one traversal with `split` and (optionally) frustum culling. Returns the
    /// leaves in traversal order and the counts so far ([`balanced_tree`] balances them).
    pub(crate) fn leaves(
        qt: &dyn NodeTree,
        camera: &Camera,
        split: &mut dyn SplitPolicy,
        frustum_cull: bool,
    ) -> (Vec<NodeId>, SelectionStats) {
        leaves_with_cull(qt, camera, split, frustum_cull, &mut NoCull)
    }

    /// [`leaves`] with a second cull policy (an occlusion lookup) after the frustum's.
    pub(crate) fn leaves_with_cull(
        qt: &dyn NodeTree,
        camera: &Camera,
        split: &mut dyn SplitPolicy,
        frustum_cull: bool,
        extra: &mut dyn CullPolicy,
    ) -> (Vec<NodeId>, SelectionStats) {
        let mut stats = SelectionStats::default();
        let mut visit = |_: NodeId, v: Visit| {
            stats.visited += 1;
            match v {
                Visit::Culled => stats.culled += 1,
                Visit::Split => stats.split += 1,
                Visit::Leaf => stats.traversal_leaves += 1,
            }
        };
        let mut cull: Box<dyn CullPolicy> = if frustum_cull {
            Box::new(FrustumCull::new(camera.frustum()))
        } else {
            Box::new(NoCull)
        };
        let first = |n: NodeId, i: &NodeInfo| cull.classify(n, i);
        let second = |n: NodeId, i: &NodeInfo| extra.classify(n, i);
        let mut both = (first, second);
        let mut out = Vec::new();
        qt.with_traversal_source(&mut |src| out = traverse(src, split, &mut both, &mut visit));
        (out, stats)
    }

    /// [`leaves`] balanced, as the balanced tree itself (its leaves depth first), for a
    /// selection that resolves its edges on it rather than building it again.
    /// With a second cull policy `extra` as [`leaves_with_cull`].
    pub(crate) fn balanced_tree(
        qt: &dyn NodeTree,
        camera: &Camera,
        split: &mut dyn SplitPolicy,
        frustum_cull: bool,
        extra: &mut dyn CullPolicy,
    ) -> (LeafTree, SelectionStats) {
        let (leaves, mut stats) = leaves_with_cull(qt, camera, split, frustum_cull, extra);
        // Balancing adds only children of selected leaves that exist in the tree.
        let shape = qt.shape();
        let tree = LeafTree::balanced(&leaves, |n| shape.contains_node(n));
        stats.balance_added = tree.leaves().len().saturating_sub(stats.traversal_leaves);
        (tree, stats)
    }

    /// The selection of `patches`, its counts (patches, deepest level) and its time since
    /// `start` added to `stats`.
    pub(crate) fn finish(
        patches: Vec<super::patch::Patch>,
        mut stats: SelectionStats,
        start: std::time::Instant,
    ) -> super::patch::Selection {
        stats.patches = patches.len();
        stats.max_level = patches.iter().map(|p| p.node.level).max().unwrap_or(0);
        stats.cpu_time = start.elapsed();
        super::patch::Selection { patches, stats }
    }

    /// Builds the selection of `tree`'s leaves: outer factors from `rule`, inner factors from
    /// `inner`. The tests' reference of the selections, which resolve their edges on the
    /// leaves' indices instead (no rule asked per node).
    #[cfg(test)]
    pub(crate) fn assemble(
        tree: &LeafTree,
        stats: SelectionStats,
        rule: &dyn super::edges::EdgeRule,
        inner: impl Fn(NodeId, &[f32; 4]) -> [f32; 2],
        start: std::time::Instant,
    ) -> super::patch::Selection {
        use super::edges::outer_factors_all;
        use super::patch::Patch;
        let patches: Vec<Patch> = tree
            .leaves()
            .iter()
            .zip(outer_factors_all(tree, rule))
            .map(|(&node, outer)| Patch { node, outer, inner: inner(node, &outer) })
            .collect();
        finish(patches, stats, start)
    }

    /// [`ScreenScale::length`] of one segment, every term from the camera in place: the
    /// tests' reference (the selections' form before 2026-12-06, which worked the camera's
    /// terms out at every edge).
    #[cfg(test)]
    pub(crate) fn screen_length(camera: &Camera, a: DVec3, b: DVec3) -> f64 {
        let len = (b - a).length();
        let mid = (a + b) * 0.5;
        let near =
            if camera.near.is_finite() && camera.near > 0.0 { camera.near } else { MIN_DISTANCE_M };
        let d = (mid - camera.position).length().max(near);
        let fov = if camera.fov_y.is_nan() {
            MAX_FOV_Y
        } else {
            camera.fov_y.clamp(MIN_FOV_Y, MAX_FOV_Y)
        };
        let s = len / (d * (fov * 0.5).tan());
        if s.is_finite() { s } else { 0.0 }
    }

    /// The camera's terms of [`ScreenScale::length`], worked out once for a selection's many
    /// edges.
    #[derive(Debug, Clone, Copy)]
    pub(crate) struct ScreenScale {
        eye: DVec3,
        near: f64,
        tan_half_fov: f64,
    }

    impl ScreenScale {
        pub(crate) fn new(camera: &Camera) -> Self {
            let near = if camera.near.is_finite() && camera.near > 0.0 {
                camera.near
            } else {
                MIN_DISTANCE_M
            };
            let fov = if camera.fov_y.is_nan() {
                MAX_FOV_Y
            } else {
                camera.fov_y.clamp(MIN_FOV_Y, MAX_FOV_Y)
            };
            Self { eye: camera.position, near, tan_half_fov: (fov * 0.5).tan() }
        }

        /// Screen-space length of the segment `a`-`b` in NDC units of the viewport's height (2 =
        /// the full height): the segment's bounding sphere (diameter `|b - a|`, centred at the
        /// midpoint) projected at its distance, `|b - a| / (max(d, near) tan(fov_y / 2))`.
        ///
        /// Why the sphere and not the projected endpoints: it is defined for segments behind the
        /// eye or crossing the eye plane (projection is not), it does not collapse for segments
        /// seen end-on at grazing angles, and it depends only on the segment and the eye, so both
        /// patches sharing an edge compute the same value. It equals the projected length for a
        /// segment square to the view at the screen centre.
        pub(crate) fn length(&self, a: DVec3, b: DVec3) -> f64 {
            let len = (b - a).length();
            let mid = (a + b) * 0.5;
            let d = (mid - self.eye).length().max(self.near);
            let s = len / (d * self.tan_half_fov);
            if s.is_finite() { s } else { 0.0 }
        }
    }
}
