//! The PVPS paper's (Zhang 2021, sections 2.3-2.4) LOD: method C, and the paper's comparison
//! methods A and B, which differ from C only in the roughness the split test reads.
//!
//! Pipeline (occlusion culling, section 2.3.3: [`select_pvps_with_cull`] with a PVS lookup):
//! 1. The one quadtree traversal from the root, culling node boxes against the view frustum
//!    (section 2.3.2) and splitting while Eq. 8 gives `ratio < 1`:
//!    `ratio = C1 D / (Span (R + C2))`, `Span = Length / 2^l` (Eq. 9), down to
//!    [`PvpsConfig::max_level`] (the paper's level 6, 64 x 64 patches).
//! 2. [`crate::quadtree::balance`]: neighbours differ by at most one level.
//! 3. Outer factors by the paper's edge classification (Eq. 11, Algorithm 1): an edge shared
//!    with a patch of the same level gets `Constant x ScreenSpaceEdgeLength`; any other edge
//!    (a neighbour of another level, or none: "edges adjacent to no patches are seen as edges
//!    adjacent to different-sized patches") gets `EdgeLength / MinEdgeLength`, the ratio of the
//!    patch's edge to a finest-level patch's edge, `2^(L - l)`.
//! 4. Inner factors by Eq. 12: `InnerLevel_k = C3 x ScreenSpaceLength_k x (RoughnessValue + C4)`.
//!
//! **Reading Algorithm 1.** The prose says "when the value of Y-axis coordinates of Vertex_i
//! equals 0, `gl_TessLevelOuter[i]` is set as the ratio of the current edge length to the minimum
//! edge length", Algorithm 1 says the opposite (Y = 0, i.e. a same-level neighbour, gets the
//! screen-space length). We follow Algorithm 1: it is the only reading that is crack-free (a
//! same-level edge is the same segment on both sides, so both compute the same screen length;
//! a level change gets view-independent powers of two that nest). Eq. 11 also pairs Vertex1 with
//! `level_top` and Vertex3 with `level_bottom` while Algorithm 1 pairs `outer[1]` with the bottom
//! and `outer[3]` with the top edge; with explicit edges ([`Edge`]) there is nothing to pair.
//!
//! **Deviations, all documented in [`PvpsConfig`].**
//! - The level-change factor is `EdgeLength / MinEdgeLength` times
//!   [`PvpsConfig::finest_transition_factor`] (default 2; the paper is 1). A finest-level patch
//!   next to a coarser one gets the paper's factor 1 and the coarser one 2; fractional-even
//!   spacing treats 1 as 2, so the fine side would have twice the coarse side's vertices: a
//!   crack. Doubling keeps every level-change factor a power of two `>= 2`.
//! - The coarse side's factor is clamped to 64, and the finer side uses half the *coarse*
//!   side's (clamped) factor, which equals its own `EdgeLength / MinEdgeLength` unless the
//!   clamp bit.
//! - Screen-space lengths are the edge's bounding sphere projected (see `ScreenScale::length` in
//!   the module `run`), in NDC units of the viewport height (2 = full height): the paper's GLSL
//!   works in normalised coordinates, and with pixels its `C3 = 10` would pin every factor at
//!   64. Heights are the heightmap's at the edge's endpoints. Measured (docs/papers.md, Eq. 12
//!   units; Puget Sound 1k, `pvps_884`, viewport 1200x800): NDC 86 triangles per patch, p99
//!   4.5 px; pixels 8,128 per patch (all 64), p99 0.6 px, and the paper's Table 3 coefficients
//!   then change nothing; the paper's Table 2 has 1,163 per patch.
//! - `RoughnessValue` in Eq. 12 is `R / 255`: the paper samples its 8-bit roughness image
//!   in the shader, which returns 0..1.
//!
//! **Methods A and B** run this same pipeline with another [`NodeField`] as `R`: method A
//! (Zhai 2016, our documented stand-in: Röttger's d2, terrain-visibility's `d2_pyramid`) and
//! method B (Dong 2017: max - min elevation, `range_pyramid`). The paper normalises its
//! roughness image to 0..255 and gives no scale for A and B; put them on the same 0..255 scale
//! (terrain-visibility's `NodePyramid::normalized_255`) so one `C1`, `C2` serves all three.

use std::time::Instant;

use glam::{DVec2, DVec3};

use super::NodeField;
use super::edges::{EdgeRule, resolve_all};
use super::patch::{Edge, MAX_FACTOR, Patch, Selection, SelectionStats, clamp_factor};
use super::run;
use super::source::TerrainSource;
use super::surface::{CORNERS_UV, edge_corners, patch_grid_point, patch_world_point};
use crate::geometry::Camera;
use crate::hash::KeyMap;
use crate::heightmap::Heightmap;
use crate::metrics::pvps::{span, split_ratio};
use crate::quadtree::{CullPolicy, LeafTree, NoCull, NodeId, NodeInfo, Quadtree};

/// Which of the PVPS paper's three methods a selection runs (section 3). They share the
/// pipeline; the method names the roughness field passed in, and is kept for reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Method {
    /// Zhai 2016 (ref. 18): quadtree with a roughness; ours is Röttger's d2 (terrain-visibility's
    /// `d2_pyramid`), the documented stand-in.
    A,
    /// Dong 2017 (ref. 21): roughness = max - min elevation of the node (`range_pyramid`).
    B,
    /// The PVPS paper's own: Eq. 5 roughness, normalised 0..255, mean per node
    /// (`roughness_pyramid`).
    C,
}

impl Method {
    /// A short name for reports.
    pub fn name(self) -> &'static str {
        match self {
            Method::A => "pvps-a",
            Method::B => "pvps-b",
            Method::C => "pvps-c",
        }
    }
}

/// What Eq. 8's `D`, "the node's distance to camera", measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum NodeDistance {
    /// To the node's world box ([`NodeInfo::aabb`], heights included); 0 when the camera is
    /// inside it, so the node splits. Conservative: never farther than any point of the node.
    #[default]
    Aabb,
    /// To the box's centre (the paper's node position, Eq. 6-7, lifted to mid-height).
    Centre,
}

/// Settings of the PVPS methods. The paper gives `C3 = 10`, `C4 = 1` (section 3) and no
/// values for `C1`, `C2` or Algorithm 1's `Constant`.
#[derive(Debug, Clone, PartialEq)]
pub struct PvpsConfig {
    /// Eq. 8's `C1`, the degree of subdivision (in the numerator: a larger `C1` splits less).
    /// Default 50: with `C2 = 100` a flat node (`R = 0`) splits within `2 Span` of the camera
    /// and the roughest (`R = 255`) within `7.1 Span`.
    pub c1: f64,
    /// Eq. 8's `C2`, how little roughness matters. Default 100 (see `c1`).
    pub c2: f64,
    /// Eq. 12's `C3`. Default 10 (the paper's experiments).
    pub c3: f64,
    /// Eq. 12's `C4`. Default 1 (the paper's experiments).
    pub c4: f64,
    /// Algorithm 1's `Constant` for same-level edges. Default 10: equal to `C3 C4`, so a flat
    /// patch (`R = 0`) among same-level neighbours has equal inner and outer factors.
    pub outer_constant: f64,
    /// Full scale of the roughness field; Eq. 12 reads `RoughnessValue = R / roughness_max`.
    /// Default 255 (the paper's grey image).
    pub roughness_max: f64,
    /// Level-change factor of a finest-level patch's edge (Algorithm 1's
    /// `EdgeLength / MinEdgeLength` is multiplied by it). A power of two `>= 2` (other values
    /// are rounded up to one). Default 2; the paper's is 1 (see the module docs).
    pub finest_transition_factor: u32,
    /// Cells per side of a finest patch, for [`PvpsConfig::quadtree`]. Default 16: the default
    /// 1025 x 1025 terrain then has the paper's 64 x 64 patches at level 6.
    pub leaf_cells: u32,
    /// Deepest level the split test may reach (the paper: 6); the quadtree's finest level caps
    /// it too. `MinEdgeLength` is the edge at this level. Default 6.
    pub max_level: u8,
    /// What `D` measures. Default [`NodeDistance::Aabb`].
    pub distance: NodeDistance,
    /// Whether to cull node boxes against the view frustum (section 2.3.2). Default true.
    pub frustum_cull: bool,
}

impl Default for PvpsConfig {
    fn default() -> Self {
        Self {
            c1: 50.0,
            c2: 100.0,
            c3: 10.0,
            c4: 1.0,
            outer_constant: 10.0,
            roughness_max: 255.0,
            finest_transition_factor: 2,
            leaf_cells: 16,
            max_level: 6,
            distance: NodeDistance::Aabb,
            frustum_cull: true,
        }
    }
}

impl PvpsConfig {
    /// The quadtree the selection runs on: `Quadtree::new(hm, leaf_cells)`.
    pub fn quadtree(&self, hm: &Heightmap) -> Quadtree {
        Quadtree::new(hm, self.leaf_cells)
    }
}

/// Algorithm 1's edge classification as an [`EdgeRule`].
struct PvpsEdges<'a> {
    src: &'a dyn TerrainSource,
    /// The camera's terms of the screen lengths, worked out once.
    screen_scale: run::ScreenScale,
    constant: f64,
    /// Deepest level (`MinEdgeLength`'s).
    finest: u8,
    /// `finest_transition_factor` as a power of two.
    scale: u32,
}

impl<'a> PvpsEdges<'a> {
    fn new(
        src: &'a dyn TerrainSource,
        camera: &Camera,
        constant: f64,
        finest: u8,
        scale: u32,
    ) -> Self {
        Self { src, screen_scale: run::ScreenScale::new(camera), constant, finest, scale }
    }

    /// `scale x EdgeLength / MinEdgeLength = scale x 2^(finest - level)`, clamped to 64.
    fn transition(&self, level: u8) -> f32 {
        let shift = self.finest.saturating_sub(level).min(12) as u32;
        (f64::from(self.scale) * f64::from(1u32 << shift)).min(f64::from(MAX_FACTOR)) as f32
    }

    /// The screen length of `node`'s `edge`: the segment between its end corners, the same
    /// points as [`edge_segment`](super::surface::edge_segment)'s (so two same-level patches
    /// sharing an edge agree).
    fn screen(&self, node: NodeId, edge: Edge) -> f64 {
        self.lengths(node)[edge as usize]
    }

    /// [`PvpsEdges::screen`] of `node`'s four edges ([`Edge::ALL`]'s order), its corners'
    /// heights asked one by one (the edge rule's and the tests' path; a selection asks every
    /// leaf's at once, [`PvpsEdges::all_lengths`]).
    fn lengths(&self, node: NodeId) -> [f64; 4] {
        self.edge_lengths(CORNERS_UV.map(|uv| patch_world_point(self.src, node, uv)))
    }

    /// The screen lengths of the four edges of a patch with world corners `c`
    /// ([`CORNERS_UV`]'s order), in [`Edge::ALL`]'s order.
    fn edge_lengths(&self, c: [DVec3; 4]) -> [f64; 4] {
        Edge::ALL.map(|e| {
            let (a, b) = edge_corners(e);
            self.screen_scale.length(c[a], c[b])
        })
    }

    /// [`PvpsEdges::lengths`] of every one of `leaves`, in their order: the corners' heights
    /// asked of the source in one call ([`TerrainSource::heights`]), each grid sample once (a
    /// corner is shared by up to four leaves). Over a store, one call each was a quarter of
    /// `pvps-b`'s selection: a lock and a lookup that missed the CPU's caches per corner, one
    /// after the other. The same values as [`PvpsEdges::lengths`] leaf by leaf (tested).
    fn all_lengths(&self, leaves: &[NodeId]) -> Vec<[f64; 4]> {
        let shape = self.src.shape();
        // Each leaf's corners as indices into `points`, grid samples listed once.
        let mut slot_of: KeyMap<u32> = KeyMap::default();
        slot_of.reserve(leaves.len() + leaves.len() / 2 + 4);
        let mut points: Vec<DVec2> = Vec::with_capacity(leaves.len() + leaves.len() / 2 + 4);
        // A corner is a grid sample: `patch_grid_point` at `CORNERS_UV` (a node's rectangle
        // clamped to the grid), in integers.
        let (w, h) = (u64::from(shape.width() - 1), u64::from(shape.height() - 1));
        let root = shape.root_cells();
        let slots: Vec<[u32; 4]> = leaves
            .iter()
            .map(|&node| {
                let (x0, y0, c) = node.grid_rect(root);
                let (x0, y0, c) = (u64::from(x0), u64::from(y0), u64::from(c));
                CORNERS_UV.map(|[u, v]| {
                    let x = (x0 + u as u64 * c).min(w);
                    let y = (y0 + v as u64 * c).min(h);
                    let next = points.len() as u32;
                    let slot = *slot_of.entry((x << 32) | y).or_insert(next);
                    if slot == next {
                        let g = DVec2::new(x as f64, y as f64);
                        debug_assert_eq!(g, patch_grid_point(shape, node, [u, v]));
                        points.push(g);
                    }
                    slot
                })
            })
            .collect();
        let mut z = Vec::with_capacity(points.len());
        self.src.heights(&points, &mut z);
        let world =
            |s: u32| shape.grid_to_world(points[s as usize]).extend(f64::from(z[s as usize]));
        slots.iter().map(|s| self.edge_lengths(s.map(world))).collect()
    }

    /// Algorithm 1, Y = 0, of an edge of screen length `screen`.
    fn same_level_factor(&self, screen: f64) -> f32 {
        clamp_factor(self.constant * screen)
    }

    /// The selection of `tree`'s leaves: [`run::assemble`] with this rule and Eq. 12's inner
    /// factors (`inner(k, lengths)` of leaf `k`), each leaf's four screen lengths worked out
    /// once, beside it, in the leaves' depth-first order (they are asked up to eight times a
    /// leaf; in a map by node, and before 2026-12-06 again per ask, they were half of
    /// `pvps-b`'s selection over the 32769^2 store). The same patches as [`run::assemble`]
    /// (`selection_equals_the_rule_through_run_assemble`).
    fn assemble(
        &self,
        tree: &LeafTree,
        stats: SelectionStats,
        inner: impl Fn(usize, &[f64; 4]) -> [f32; 2],
        start: Instant,
    ) -> Selection {
        let leaves = tree.leaves();
        let lengths = self.all_lengths(leaves);
        let transition = |k: usize| self.transition(leaves[k].level);
        let outer = resolve_all(
            tree,
            |k, e, _| self.same_level_factor(lengths[k][e as usize]),
            |k, _, _| transition(k),
            |k, _| transition(k),
        );
        let patches: Vec<Patch> = leaves
            .iter()
            .zip(outer)
            .enumerate()
            .map(|(k, (&node, outer))| Patch { node, outer, inner: inner(k, &lengths[k]) })
            .collect();
        run::finish(patches, stats, start)
    }
}

impl EdgeRule for PvpsEdges<'_> {
    /// Algorithm 1, Y = 0: `Constant x ScreenSpaceEdgeLength` of the shared segment.
    fn same_level(&self, a: NodeId, edge: Edge, _: NodeId) -> f32 {
        self.same_level_factor(self.screen(a, edge))
    }

    /// Algorithm 1, Y != 0: `EdgeLength / MinEdgeLength` (scaled) of the coarse patch.
    fn coarse_edge(&self, coarse: NodeId, _: Edge, _: &[NodeId]) -> f32 {
        self.transition(coarse.level)
    }

    /// "Edges adjacent to no patches are seen as edges adjacent to different-sized patches."
    fn unshared(&self, node: NodeId, _: Edge) -> f32 {
        self.transition(node.level)
    }
}

/// Selects the patches of a PVPS method for `camera` over terrain `src` (a heightmap in
/// memory, [`super::GridSource`], or a store's resident pages): the method (A, B or C, see
/// [`Method`]) is the choice of the roughness `field` (0..255, see the module docs);
/// everything else is shared.
pub fn select_pvps(
    src: &dyn TerrainSource,
    camera: &Camera,
    field: &dyn NodeField,
    cfg: &PvpsConfig,
) -> Selection {
    select_pvps_with_cull(src, camera, field, cfg, &mut NoCull)
}

/// [`select_pvps`] with occlusion culling (section 2.3.3): `occlusion` is asked after the
/// frustum test for every node the traversal reaches (terrain-visibility's PVS lookup,
/// `PvsCull`); a rejected node and its subtree are not drawn. Balancing afterwards only splits
/// selected leaves, so it never brings back a culled area. With [`NoCull`] this is
/// [`select_pvps`].
pub fn select_pvps_with_cull(
    src: &dyn TerrainSource,
    camera: &Camera,
    field: &dyn NodeField,
    cfg: &PvpsConfig,
    occlusion: &mut dyn CullPolicy,
) -> Selection {
    let start = Instant::now();
    let finest = cfg.max_level.min(src.shape().max_level());
    let root = src.shape().root_length_m();
    let length = root.x.max(root.y);
    let eye = camera.position;
    let mut split = |node: NodeId, info: &NodeInfo| -> bool {
        if node.level >= finest {
            return false;
        }
        let d = match cfg.distance {
            NodeDistance::Aabb => info.aabb.distance(eye),
            NodeDistance::Centre => (info.aabb.center() - eye).length(),
        };
        // Eq. 8 and 9.
        let r = f64::from(field.value(node)).max(0.0);
        split_ratio(d, span(length, node.level as u32), r, cfg.c1, cfg.c2) < 1.0
    };
    let (tree, stats) = run::balanced_tree(src, camera, &mut split, cfg.frustum_cull, occlusion);
    let rule = PvpsEdges::new(
        src,
        camera,
        cfg.outer_constant,
        finest,
        cfg.finest_transition_factor.clamp(2, 64).next_power_of_two(),
    );
    let leaves = tree.leaves();
    let inner = |k: usize, l: &[f64; 4]| inner_factors(cfg, field.value(leaves[k]), l);
    rule.assemble(&tree, stats, inner, start)
}

/// Eq. 12: the inner factors of a patch of roughness `roughness` whose edges have the screen
/// lengths `l` ([`Edge::ALL`]'s order); `ScreenSpaceLength_1` runs along u (the south and
/// north edges), `_2` along v.
fn inner_factors(cfg: &PvpsConfig, roughness: f32, l: &[f64; 4]) -> [f32; 2] {
    let r = f64::from(roughness).max(0.0);
    let rv = if cfg.roughness_max > 0.0 { r / cfg.roughness_max } else { 0.0 };
    let k = cfg.c3 * (rv + cfg.c4);
    let u = 0.5 * (l[Edge::South as usize] + l[Edge::North as usize]);
    let v = 0.5 * (l[Edge::West as usize] + l[Edge::East as usize]);
    [clamp_factor(k * u), clamp_factor(k * v)]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::georef::Georef;
    use crate::lod::{ConstantField, GridSource, check_shared_edges};
    use glam::dvec3;

    fn bumpy(n: usize) -> Heightmap {
        Heightmap::from_fn(n, n, Georef::local(10.0), |i, j| {
            ((i as f32 * 0.3).sin() * 40.0 + (j as f32 * 0.21).cos() * 30.0) + 100.0
        })
        .unwrap()
    }

    #[test]
    fn near_patches_are_finer_and_factors_match() {
        let hm = bumpy(257);
        let cfg = PvpsConfig { leaf_cells: 8, ..Default::default() };
        let qt = cfg.quadtree(&hm);
        assert_eq!(qt.max_level(), 5);
        let cam = Camera::from_yaw_pitch(dvec3(100.0, 100.0, 400.0), 45.0, -20.0);
        let sel = select_pvps(&GridSource::new(&qt, &hm), &cam, &ConstantField(100.0), &cfg);
        assert!(sel.stats.patches > 4 && sel.stats.patches == sel.patches.len());
        assert!(sel.factors_in_range());
        assert_eq!(check_shared_edges(&sel), []);
        assert!(crate::quadtree::is_balanced(
            &sel.patches.iter().map(|p| p.node).collect::<Vec<_>>()
        ));
        // Near the camera at the finest level, far away coarser.
        assert!(sel.patches.iter().any(|p| p.node.level == 5));
        assert!(sel.patches.iter().any(|p| p.node.level <= 3));
        // Sorted in traversal order.
        assert!(sel.patches.windows(2).all(|w| w[0].node.dfs_key() < w[1].node.dfs_key()));
    }

    /// The selection (each leaf's screen lengths beside it, edges resolved on the leaves'
    /// indices) equals Algorithm 1's rule asked per node through [`run::assemble`], bit for
    /// bit, for cameras inside and outside the grid, with and without frustum culling.
    #[test]
    fn selection_equals_the_rule_through_run_assemble() {
        let hm = crate::synth::FractalConfig::with_size(257, 193, 20.0).to_heightmap().unwrap();
        let field = |n: NodeId| ((n.i * 37 + n.j * 11 + u32::from(n.level) * 5) % 256) as f32;
        let mut unit = crate::test_support::unit_rng(0x9e37_79b9_7f4a_7c15);
        let (mut transitions, mut coarse_faced) = (0, 0);
        for k in 0..30 {
            let cfg = PvpsConfig {
                leaf_cells: [8, 16][k % 2],
                max_level: 5,
                frustum_cull: k % 5 != 4,
                ..Default::default()
            };
            let qt = cfg.quadtree(&hm);
            let src = GridSource::new(&qt, &hm);
            let eye =
                dvec3(7000.0 * unit() - 1000.0, 5000.0 * unit() - 500.0, 50.0 + 2000.0 * unit());
            let cam = Camera::from_yaw_pitch(eye, 360.0 * unit(), -60.0 * unit())
                .with_viewport(1280.0, 720.0);
            let fast = select_pvps(&src, &cam, &field, &cfg);
            let start = Instant::now();
            let finest = cfg.max_level.min(qt.max_level());
            let mut split = |node: NodeId, info: &NodeInfo| {
                node.level < finest
                    && split_ratio(
                        info.aabb.distance(eye),
                        span(qt.root_length_m().max_element(), node.level as u32),
                        f64::from(field(node)),
                        cfg.c1,
                        cfg.c2,
                    ) < 1.0
            };
            let (tree, stats) =
                run::balanced_tree(&src, &cam, &mut split, cfg.frustum_cull, &mut NoCull);
            let leaves = tree.into_leaves();
            let rule = PvpsEdges::new(&src, &cam, cfg.outer_constant, finest, 2);
            let inner = |n: NodeId, _: &[f32; 4]| inner_factors(&cfg, field(n), &rule.lengths(n));
            let slow = run::assemble(&LeafTree::new(&leaves), stats, &rule, inner, start);
            crate::test_support::assert_same_selection(&fast, &slow, &format!("camera {k}"));
            let levels: Vec<u8> = fast.patches.iter().map(|p| p.node.level).collect();
            transitions += fast.patches.iter().flat_map(|p| p.outer).filter(|&f| f > 2.0).count();
            coarse_faced += usize::from(levels.iter().min() != levels.iter().max());
        }
        assert!(transitions > 0 && coarse_faced > 0, "{transitions} {coarse_faced}");
    }

    /// Algorithm 1's rule with the defaults' constant, a finest level of 4 and scale 2.
    fn rule_of<'a>(src: &'a dyn TerrainSource, camera: &'a Camera) -> PvpsEdges<'a> {
        PvpsEdges::new(src, camera, 10.0, 4, 2)
    }

    #[test]
    fn edge_screen_lengths_from_the_remembered_corners_are_the_edge_segments() {
        let hm = bumpy(129);
        let qt = Quadtree::new(&hm, 8);
        let src = GridSource::new(&qt, &hm);
        let cam = Camera::from_yaw_pitch(dvec3(-50.0, -80.0, 300.0), 40.0, -25.0);
        let rule = rule_of(&src, &cam);
        // The last two share an edge (its corners' heights are looked up once).
        let nodes = [
            NodeId::new(0, 0, 0),
            NodeId::new(2, 1, 3),
            NodeId::new(4, 9, 2),
            NodeId::new(4, 10, 2),
        ];
        // Each node's edges in turn and interleaved with another node's, so the remembered
        // lengths are both computed and read again, against the reference that works every
        // term out from the camera at each edge.
        for (k, &n) in nodes.iter().enumerate() {
            for e in Edge::ALL {
                let other = nodes[(k + 1) % nodes.len()];
                for node in [n, other, n] {
                    let (a, b) = crate::lod::surface::edge_segment(&src, node, e);
                    let want = run::screen_length(&cam, a, b);
                    assert!(want > 0.0);
                    assert_eq!(rule.screen(node, e).to_bits(), want.to_bits(), "{node:?} {e:?}");
                }
            }
        }
    }

    #[test]
    fn transition_factors_are_the_papers_ratio_doubled() {
        let hm = bumpy(65);
        let qt = Quadtree::new(&hm, 4);
        let src = GridSource::new(&qt, &hm);
        let cam = Camera::from_yaw_pitch(dvec3(0.0, 0.0, 100.0), 0.0, -30.0);
        let rule = rule_of(&src, &cam);
        assert_eq!(rule.transition(4), 2.0);
        assert_eq!(rule.transition(3), 4.0);
        assert_eq!(rule.transition(0), 32.0);
        let rule = PvpsEdges { finest: 9, ..rule };
        assert_eq!(rule.transition(0), 64.0);
        assert_eq!(rule.transition(3), 64.0);
        assert_eq!(rule.transition(4), 64.0);
        assert_eq!(rule.transition(5), 32.0);
    }
}
