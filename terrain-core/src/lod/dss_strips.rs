//! The DSS paper's own method (Zhang 2019, section 3): M-blocks that tessellate with their own
//! continuous factor, P-blocks at the centre of every split, and dynamic stitching strips
//! (DSS) between them. This module is the multilevel update (section 3.3.1) and the block and
//! strip *structure*; the strips' vertices and triangles (section 3.2.2-3.2.3, Algorithm 1)
//! need the tessellator's CPU reference and are built in terrain-gpu (`strips`).
//!
//! # Geometry: blocks shrink, strips fill the gap
//! The paper draws M-blocks "with gaps between them" and fills the gaps with strips (its
//! Fig. 4-6), without giving the gap's width. Ours: every M-block's *domain* is its quadtree
//! node's (unclipped) square shrunk by [`DssStripsConfig::half_width_cells`] = `s` whole cells
//! on each side that faces another block, and not at all on a side on the terrain border (the
//! grid's west and south edges, and east and north sides reaching the grid's last column or
//! row). So every shared quadtree edge becomes a corridor `2 s` cells wide, which is a strip,
//! and where four blocks' corners meet at the centre of a split a `2 s x 2 s` square remains,
//! which is the P-block. Whole cells keep the renderer's integer patch rects; `s = 1` is the
//! default (narrow strips, most of the surface drawn by the blocks).
//!
//! **Shared vertices.** A block is tessellated with all four outer factors and both inner
//! factors equal to its own `F_thr`, so its edge vertices are the fractional-even points of
//! `F_thr` along its shrunk edge. A strip's vertices *are* those points, named by the block
//! and the domain point `(u, v)` on its edge (not recomputed positions), so the GPU computes
//! the strip's vertices with the same arithmetic as the block's and they coincide bit for bit
//! (terrain-gpu's `strips`). The P-block's four corners are the four blocks' inner corners.
//!
//! # Strips and `Idsneighbour` (section 3.1.3, Table 1)
//! When block `n` splits, its four children are separated by four strips, "arms" of a cross
//! around the P-block; the arm on a child's anti-clockwise side has that child's id
//! ([`crate::quadtree::dss`]): child `4(n + 1)` (south-west) owns the south arm (between
//! south-west and south-east), `+1` the east arm, `+2` the north arm, `+3` the west arm. Every
//! M-block carries `Idsneighbour` (Table 1, [`dss_neighbours`]): the strip on each edge. A
//! strip's two sides are found, as the paper says, "by searching for the index of the DSS in
//! the Idsneighbour" of the blocks: a block whose east (north) edge names strip `k` lies on
//! its low side, one whose west (south) edge does on its high side. Neighbours several levels
//! apart need nothing special: a side is the sequence of every block edge on it, in order.
//! Between two consecutive blocks along a side lies the end of a narrower strip (their own
//! split's arm), whose end cap is that segment: strips meet strips edge to edge.
//!
//! # Per frame (section 3.3)
//! The quadtree (min/max boxes) and the 32 object-space errors per node ([`DssErrorTable`])
//! are built in advance; per frame [`select_dss_strips`] walks it top-down, splitting while
//! `rho_32 > rho_thr` (Eq. 3, straight-down views floored by
//! [`crate::metrics::screen::MIN_VIEW_SIN`]), and gives each leaf its continuous factor
//! `F_thr` (Eq. 4). No balancing: strips join any two factors and level differences.
//! Hierarchical frustum culling (section 3.3.2): a node whose box is outside the frustum is not
//! refined; its leaf stays in the structure as a *hidden* block (factor 2, not drawn) so strips
//! next to it keep both sides; then each visible block's four edges are tested, and a strip
//! none of whose visible blocks' edges is in the frustum is discarded (a strip is built whole
//! or not at all: dropping single edges would open it).

use crate::hash::KeyMap;
use crate::quadtree::NodeTree;
use std::collections::HashMap;
use std::ops::Range;
use std::time::Instant;

use glam::{DVec2, DVec3};

use super::dss_methods::{DssConfig, DssErrorTable, Metric};
use super::edges::pow2_up;
use super::patch::{Edge, Patch, Selection, SelectionStats};
use crate::geometry::{Aabb, Camera, Classification, Frustum};
use crate::quadtree::{
    FrustumCull, NoCull, NodeId, NodeInfo, Quadrant, Quadtree, Visit, dss_block_id, dss_neighbours,
    traverse,
};

/// Settings of the stitching-strip method.
#[derive(Debug, Clone, PartialEq)]
pub struct DssStripsConfig {
    /// The DSS metric's settings (`rho_thr`, leaf size, frustum culling); Method II's block
    /// size is not used. Default [`DssConfig::default`].
    pub dss: DssConfig,
    /// Half the width of a strip in grid cells (`s`, see the module docs; at least 1). A node
    /// is split only while its children keep at least two cells inside their strips
    /// (`cells / 2 >= 2 s + 2`). Default 1.
    pub half_width_cells: u32,
    /// How each block's factor follows Eq. 4. Default [`StripFactors::Sliding`] (the
    /// paper's).
    pub factors: StripFactors,
}

impl Default for DssStripsConfig {
    fn default() -> Self {
        Self { dss: DssConfig::default(), half_width_cells: 1, factors: StripFactors::Sliding }
    }
}

/// The factor a block tessellates with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum StripFactors {
    /// The paper's: the continuous `F_thr` of Eq. 4 (fractional-even spacing), which changes
    /// with every move of the camera and slides every tessellated vertex of the block.
    #[default]
    Sliding,
    /// Not the paper's (issue 17's test of why the strips pop): `F_thr` rounded *up* to a power
    /// of two (2, 4, ..., 64), as Method I's, so a block's surface changes only when its factor
    /// doubles or halves (or the block splits or merges); the strips still join any two
    /// factors. Rounding up keeps every block within the threshold.
    PowerOfTwo,
}

/// One M-block: a quadtree leaf with the paper's M-block data (MBD, section 3.1.1).
///
/// MBD fields: `Id` = [`MBlock::id`]; `Position` and `Size` = [`MBlock::node`]'s square (and
/// the drawn, shrunk [`MBlock::rect`]); `Ftessellation` = [`MBlock::factor`]; `Lquadtree` =
/// `node.level`; `Ptschild` is implicit (the quadtree is addressed by [`NodeId`], children by
/// [`NodeId::children`]); `Idsneighbour` = [`MBlock::neighbours`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MBlock {
    /// The paper's block id ([`dss_block_id`]).
    pub id: i64,
    /// The quadtree node.
    pub node: NodeId,
    /// The tessellated domain `[x0, y0, x1, y1]` in grid samples: the node's unclipped square
    /// shrunk by `s` on every side that is not [`MBlock::border`] (may reach past the grid's
    /// east and north edges, where positions are clamped, as for every patch).
    pub rect: [u32; 4],
    /// `Ftessellation`: the continuous factor `F_thr` (Eq. 4), within `[2, 64]`; 2 for hidden
    /// blocks.
    pub factor: f32,
    /// Whether the block is drawn (false: frustum-culled, kept for its strips).
    pub visible: bool,
    /// `Idsneighbour` (Table 1): the strip on each edge, south, east, north, west.
    pub neighbours: [Option<i64>; 4],
    /// Per edge (south, east, north, west): on the terrain border, so not shrunk and on no
    /// strip.
    pub border: [bool; 4],
}

/// One corner of a block's domain, as a domain point `(u, v)`.
pub fn corner_uv(corner: Quadrant) -> [f32; 2] {
    let (a, b) = corner.offset();
    [a as f32, b as f32]
}

/// A P-block (section 3.1.2): the `2 s x 2 s` square at the centre of a split, drawn as two
/// triangles between the four blocks' inner corners.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PBlock {
    /// The split node.
    pub split: NodeId,
    /// Its corners, anti-clockwise from the south-west: `(block index, corner of that block)`:
    /// the north-east corner of the block in the split's south-west child, and so on.
    pub corners: [(usize, Quadrant); 4],
}

/// A stitching strip (section 3.1.3): the corridor along one arm of a split.
#[derive(Debug, Clone, PartialEq)]
pub struct Strip {
    /// Its id: the id of the child that owns it (Table 1).
    pub id: i64,
    /// Whether it runs north-south (its sides are east and west block edges).
    pub vertical: bool,
    /// Blocks on its low side (west of a vertical strip, south of a horizontal one) in order
    /// along it (south to north, or west to east), as a range of the frame's `strip_blocks`
    /// ([`DssStripFrame::low`]); their east (north) edges face the strip.
    pub low: Range<u32>,
    /// Blocks on its high side, in order, likewise ([`DssStripFrame::high`]); their west
    /// (south) edges face the strip.
    pub high: Range<u32>,
}

impl Strip {
    /// The edge of a block on side `high` that faces the strip.
    pub fn facing_edge(&self, high: bool) -> Edge {
        match (self.vertical, high) {
            (true, false) => Edge::East,
            (true, true) => Edge::West,
            (false, false) => Edge::North,
            (false, true) => Edge::South,
        }
    }
}

/// One frame of the method: blocks, P-blocks, strips and what the update cost.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DssStripFrame {
    /// Every M-block (visible and hidden), depth-first ([`NodeId::dfs_key`] order).
    pub blocks: Vec<MBlock>,
    /// P-blocks of splits with four children in the grid, one at least of them visible.
    pub pblocks: Vec<PBlock>,
    /// Strips with a visible edge, by id.
    pub strips: Vec<Strip>,
    /// The blocks lining the strips, strip after strip, each strip's low side then its high
    /// side (one vector for the frame, not two per strip).
    pub strip_blocks: Vec<usize>,
    /// Selection stats of the multilevel update (patches = visible blocks).
    pub stats: SelectionStats,
    /// Strips discarded by edge culling.
    pub culled_strips: usize,
}

impl DssStripFrame {
    /// The blocks on strip `s`'s low side, in order along it.
    pub fn low(&self, s: &Strip) -> &[usize] {
        &self.strip_blocks[s.low.start as usize..s.low.end as usize]
    }

    /// The blocks on strip `s`'s high side, in order along it.
    pub fn high(&self, s: &Strip) -> &[usize] {
        &self.strip_blocks[s.high.start as usize..s.high.end as usize]
    }

    /// Whether a strip or P-block vertex lies on each block (`blocks[k]`): the blocks lining a
    /// strip, hidden ones too, and the P-blocks' corner blocks. What a store must hold at full
    /// resolution besides the visible blocks (the strips' vertices are the blocks' edge points).
    pub fn lined_blocks(&self) -> Vec<bool> {
        let mut lined = vec![false; self.blocks.len()];
        for &k in &self.strip_blocks {
            lined[k] = true;
        }
        for p in &self.pblocks {
            for &(k, _) in &p.corners {
                lined[k] = true;
            }
        }
        lined
    }

    /// The visible blocks as a [`Selection`] (every factor the block's `F_thr`): what the
    /// measurement's coverage and the statistics read. The drawn surface is *not*
    /// `build_surface` of this (blocks are shrunk and strips are added): terrain-gpu's
    /// `strips::build_strip_surface` builds it.
    pub fn selection(&self) -> Selection {
        let patches = self
            .blocks
            .iter()
            .filter(|b| b.visible)
            .map(|b| Patch { node: b.node, outer: [b.factor; 4], inner: [b.factor; 2] })
            .collect();
        Selection { patches, stats: self.stats }
    }
}

/// The multilevel update (section 3.3.1) and the block/strip structure of one frame; see the
/// module docs.
pub fn select_dss_strips(
    qt: &dyn NodeTree,
    camera: &Camera,
    table: &DssErrorTable,
    cfg: &DssStripsConfig,
) -> DssStripFrame {
    let start = Instant::now();
    assert_eq!(table.root_cells(), qt.shape().root_cells(), "error table of another quadtree");
    let s = cfg.half_width_cells.max(1);
    let metric = Metric::new(table, camera, &cfg.dss);
    let mut stats = SelectionStats::default();
    let mut hidden: Vec<NodeId> = Vec::new();
    let mut splits: Vec<NodeId> = Vec::new();
    let leaves = {
        let mut visit = |n: NodeId, v: Visit| {
            stats.visited += 1;
            match v {
                Visit::Culled => {
                    stats.culled += 1;
                    hidden.push(n);
                }
                Visit::Split => {
                    stats.split += 1;
                    splits.push(n);
                }
                Visit::Leaf => stats.traversal_leaves += 1,
            }
        };
        // Zhang 2019 (DSS), section 3.3.1: split while rho_32 > rho_thr (Eq. 3 on delta_32),
        // as long as the children keep two cells inside their strips.
        let mut split = |n: NodeId, info: &NodeInfo| {
            (info.cells / 2) >= 2 * s + 2 && metric.must_split(n, info)
        };
        if cfg.dss.frustum_cull {
            let mut cull = FrustumCull::new(camera.frustum());
            traverse(qt, &mut split, &mut cull, &mut visit)
        } else {
            traverse(qt, &mut split, &mut NoCull, &mut visit)
        }
    };
    let mut nodes: Vec<(NodeId, bool)> = leaves.iter().map(|&n| (n, true)).collect();
    nodes.extend(hidden.iter().map(|&n| (n, false)));
    let frustum = cfg.dss.frustum_cull.then(|| camera.frustum());
    // Zhang 2019 (DSS), Eq. 4: the continuous factor F_thr from the 32 screen errors (Eq. 3);
    // rounded up to a power of two for [`StripFactors::PowerOfTwo`] (not the paper's).
    let factor = |n: NodeId, info: &NodeInfo| match cfg.factors {
        StripFactors::Sliding => metric.factor(n, info),
        StripFactors::PowerOfTwo => pow2_up(metric.factor(n, info)),
    };
    let mut frame = assemble(qt, nodes, &splits, factor, s, frustum.as_ref());
    let blocks = &frame.blocks;
    stats.patches = blocks.iter().filter(|b| b.visible).count();
    stats.max_level = blocks.iter().filter(|b| b.visible).map(|b| b.node.level).max().unwrap_or(0);
    stats.cpu_time = start.elapsed();
    frame.stats = stats;
    frame
}

/// One block's edge facing a strip, as [`assemble`] groups them.
struct Side {
    /// The strip's id.
    id: i64,
    /// Bit 32: the block is on the strip's high side; bits 0-31: its position along the strip.
    place: u64,
    /// The block (index into the frame's blocks).
    block: usize,
    /// Whether the strip runs north-south.
    vertical: bool,
}

impl Side {
    /// Whether the block is on the strip's high side.
    fn high(&self) -> bool {
        self.place >> 32 != 0
    }
}

/// Blocks, P-blocks and strips of a set of leaves (`(node, visible)`, covering the grid) and
/// the nodes split to reach them; edges are culled against `frustum` when given. The frame's
/// statistics are left empty.
fn assemble(
    qt: &dyn NodeTree,
    mut nodes: Vec<(NodeId, bool)>,
    splits: &[NodeId],
    factor: impl Fn(NodeId, &NodeInfo) -> f32,
    s: u32,
    frustum: Option<&Frustum>,
) -> DssStripFrame {
    // A stable sort: the traversal's leaves and hidden nodes come as two runs in depth-first
    // order, which it merges in one pass.
    nodes.sort_by_key(|(n, _)| n.dfs_key());
    let shape = qt.shape();
    let (w1, h1) = (shape.width() - 1, shape.height() - 1);
    // Each block's box heights, for its edges' frustum test below. The nodes' boxes through
    // the tree's traversal source (a store's looks each block up once per run of its nodes,
    // which come depth first).
    let mut heights: Vec<(f64, f64)> = Vec::with_capacity(nodes.len());
    let mut blocks: Vec<MBlock> = Vec::with_capacity(nodes.len());
    qt.with_traversal_source(&mut |src| {
        blocks.extend(nodes.iter().map(|&(node, visible)| {
            let info = src.node_info(node).expect("selected nodes exist");
            heights.push((info.aabb.min.z, info.aabb.max.z));
            let neighbours = dss_neighbours(node);
            let (x0, y0, c) = node.grid_rect(shape.root_cells());
            let border = [
                neighbours[0].is_none() || y0 == 0,
                neighbours[1].is_none() || x0 + c >= w1,
                neighbours[2].is_none() || y0 + c >= h1,
                neighbours[3].is_none() || x0 == 0,
            ];
            let inset = |k: usize| if border[k] { 0 } else { s };
            // A node holding `s` cells or fewer of the grid (its square mostly past the east or
            // north edge) would start past the grid's last cell once shrunk: start it at that
            // cell instead (a narrower strip on its west or south side; positions past the
            // grid are clamped for every patch anyway).
            let rect = [
                (x0 + inset(3)).min(w1.saturating_sub(1).max(x0)),
                (y0 + inset(0)).min(h1.saturating_sub(1).max(y0)),
                x0 + c - inset(1),
                y0 + c - inset(2),
            ];
            let factor = if visible { factor(node, &info) } else { 2.0 };
            MBlock { id: dss_block_id(node), node, rect, factor, visible, neighbours, border }
        }));
    });
    let index: KeyMap<usize> = blocks.iter().enumerate().map(|(k, b)| (b.node.key(), k)).collect();

    // P-blocks: at the centre of every split with four children in the grid.
    let mut pblocks = Vec::new();
    for &n in splits {
        let children = n.children();
        if !children.iter().all(|&c| shape.contains_node(c)) {
            continue;
        }
        // The block at child q's corner next to the centre: descend towards the centre.
        let corner = |q: Quadrant| {
            let toward = Quadrant::ALL[(q as usize + 2) % 4];
            let mut m = n.child(q);
            loop {
                if let Some(&k) = index.get(&m.key()) {
                    return (k, toward);
                }
                m = m.child(toward);
            }
        };
        let corners = Quadrant::ALL.map(corner);
        if corners.iter().any(|&(k, _)| blocks[k].visible) {
            pblocks.push(PBlock { split: n, corners });
        }
    }

    // Strips: group the blocks' interior edges by the strip their Idsneighbour names, sorted
    // by (strip id, side, position along): the side and position packed in one integer.
    let mut sides: Vec<Side> = Vec::with_capacity(4 * blocks.len());
    for (k, b) in blocks.iter().enumerate() {
        for e in Edge::ALL {
            if b.border[e as usize] {
                continue;
            }
            let id = b.neighbours[e as usize].expect("interior edges have a strip");
            let (high, along) = match e {
                Edge::East => (false, b.rect[1]),
                Edge::West => (true, b.rect[1]),
                Edge::North => (false, b.rect[0]),
                Edge::South => (true, b.rect[0]),
            };
            sides.push(Side {
                id,
                place: (u64::from(high) << 32) | u64::from(along),
                block: k,
                vertical: matches!(e, Edge::East | Edge::West),
            });
        }
    }
    sides.sort_unstable_by_key(|t| (t.id, t.place));
    let edge_visible = |k: usize, e: Edge| -> bool {
        let b = &blocks[k];
        if !b.visible {
            return false;
        }
        let Some(frustum) = frustum else { return true };
        let (z0, z1) = heights[k];
        let [x0, y0, x1, y1] = b.rect.map(f64::from);
        let sf = f64::from(s);
        let (a, c) = match e {
            Edge::South => (DVec2::new(x0, y0 - sf), DVec2::new(x1, y0 + sf)),
            Edge::East => (DVec2::new(x1 - sf, y0), DVec2::new(x1 + sf, y1)),
            Edge::North => (DVec2::new(x0, y1 - sf), DVec2::new(x1, y1 + sf)),
            Edge::West => (DVec2::new(x0 - sf, y0), DVec2::new(x0 + sf, y1)),
        };
        let world = |g: DVec2| shape.grid_to_world(g);
        let (wa, wc) = (world(a), world(c));
        let bx = Aabb::new(DVec3::new(wa.x, wa.y, z0), DVec3::new(wc.x, wc.y, z1));
        frustum.classify(&bx) != Classification::Outside
    };
    let mut strips = Vec::new();
    let mut strip_blocks = Vec::with_capacity(sides.len());
    let mut culled_strips = 0;
    let mut k = 0;
    while k < sides.len() {
        let id = sides[k].id;
        let end = k + sides[k..].iter().take_while(|t| t.id == id).count();
        let group = &sides[k..end];
        k = end;
        // Sorted by side: the low side's blocks first, then the high side's.
        let n_low = group.iter().take_while(|t| !t.high()).count();
        if n_low == 0 || n_low == group.len() {
            continue; // cannot happen for interior edges; nothing to stitch
        }
        let vertical = group[0].vertical;
        debug_assert!(group.iter().all(|t| t.vertical == vertical));
        let at = strip_blocks.len() as u32;
        let mid = at + n_low as u32;
        let strip = Strip { id, vertical, low: at..mid, high: mid..at + group.len() as u32 };
        let seen = group.iter().any(|t| edge_visible(t.block, strip.facing_edge(t.high())));
        if seen {
            strip_blocks.extend(group.iter().map(|t| t.block));
            strips.push(strip);
        } else {
            culled_strips += 1;
        }
    }

    DssStripFrame {
        blocks,
        pblocks,
        strips,
        strip_blocks,
        stats: SelectionStats::default(),
        culled_strips,
    }
}

/// The structure of a given partition into leaves, every block visible with its given factor
/// (`factors[k]` for `leaves[k]`, used as is: 1 tessellates like 2), no culling: for tests and
/// tools that choose blocks themselves. The leaves must tile the grid (every node that holds
/// cells is covered by exactly one leaf); each must keep at least two cells inside its strips.
pub fn frame_from_leaves(
    qt: &Quadtree,
    leaves: &[NodeId],
    factors: &[f32],
    half_width_cells: u32,
) -> DssStripFrame {
    assert_eq!(leaves.len(), factors.len());
    let start = Instant::now();
    let by_node: HashMap<NodeId, f32> =
        leaves.iter().copied().zip(factors.iter().copied()).collect();
    let mut splits: Vec<NodeId> =
        leaves.iter().flat_map(|n| (0..n.level).map(move |l| n.ancestor(l))).collect();
    splits.sort_unstable_by_key(|n| n.dfs_key());
    splits.dedup();
    let nodes = leaves.iter().map(|&n| (n, true)).collect();
    let mut frame = assemble(qt, nodes, &splits, |n, _| by_node[&n], half_width_cells.max(1), None);
    let visible = frame.blocks.len();
    frame.stats = SelectionStats {
        traversal_leaves: visible,
        patches: visible,
        split: splits.len(),
        max_level: frame.blocks.iter().map(|b| b.node.level).max().unwrap_or(0),
        cpu_time: start.elapsed(),
        ..SelectionStats::default()
    };
    frame
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::georef::Georef;
    use crate::heightmap::Heightmap;
    use glam::dvec3;

    fn bumpy(w: usize, h: usize) -> Heightmap {
        Heightmap::from_fn(w, h, Georef::local(10.0), |i, j| {
            let noise = ((i * 7919 + j * 104_729) % 97) as f32 * 0.3;
            ((i as f32 * 0.37).sin() * 25.0 + (j as f32 * 0.23).cos() * 20.0) + 100.0 + noise
        })
        .unwrap()
    }

    #[test]
    fn structure_follows_table_one_and_covers_every_interior_edge() {
        // A 64-cell node at factor 64 is exact, so levels come from a grid of 256 cells.
        let hm = bumpy(257, 257);
        let cfg = DssStripsConfig {
            dss: DssConfig {
                leaf_cells: 8,
                rho_thr: 0.5,
                frustum_cull: false,
                ..Default::default()
            },
            half_width_cells: 1,
            factors: StripFactors::Sliding,
        };
        let qt = cfg.dss.quadtree(&hm);
        let table = DssErrorTable::new(&hm, &qt);
        let cam = Camera::from_yaw_pitch(dvec3(100.0, 100.0, 200.0), 30.0, -25.0);
        // The first threshold that mixes levels.
        let levels_of = |f: &DssStripFrame| -> std::collections::BTreeSet<u8> {
            f.blocks.iter().map(|b| b.node.level).collect()
        };
        let f = [1.0, 2.0, 4.0, 8.0, 16.0, 32.0]
            .iter()
            .map(|&rho_thr| {
                let c = DssStripsConfig { dss: DssConfig { rho_thr, ..cfg.dss.clone() }, ..cfg };
                select_dss_strips(&qt, &cam, &table, &c)
            })
            .find(|f| levels_of(f).len() >= 2)
            .expect("some threshold mixes levels");
        assert!(f.blocks.iter().all(|b| b.visible));
        // Continuous factors, not all powers of two.
        assert!(f.blocks.iter().any(|b| b.factor.fract() != 0.0));
        assert!(f.blocks.iter().all(|b| (2.0..=64.0).contains(&b.factor)));
        // Every block's interior edge lies on exactly one strip side.
        let mut seen = vec![0usize; f.blocks.len()];
        for s in &f.strips {
            assert!(!f.low(s).is_empty() && !f.high(s).is_empty());
            for (hi, side) in [(false, f.low(s)), (true, f.high(s))] {
                let e = s.facing_edge(hi);
                for &b in side.iter() {
                    assert_eq!(f.blocks[b].neighbours[e as usize], Some(s.id));
                    seen[b] += 1;
                }
                // Ordered along the strip, without overlap.
                for w in side.windows(2) {
                    let (a, b) = (f.blocks[w[0]].rect, f.blocks[w[1]].rect);
                    if s.vertical {
                        assert!(a[3] < b[1], "{a:?} {b:?}");
                    } else {
                        assert!(a[2] < b[0], "{a:?} {b:?}");
                    }
                }
            }
        }
        for (k, b) in f.blocks.iter().enumerate() {
            assert_eq!(seen[k], b.border.iter().filter(|&&x| !x).count(), "{b:?}");
            assert_eq!(b.id, dss_block_id(b.node));
        }
        // P-blocks at every split: splits = (blocks - 1) / 3 on a 2^k + 1 grid.
        assert_eq!(f.pblocks.len(), (f.blocks.len() - 1) / 3);
        for p in &f.pblocks {
            let (x0, y0, c) = p.split.grid_rect(qt.root_cells());
            let (xm, ym) = (x0 + c / 2, y0 + c / 2);
            let want = [(xm - 1, ym - 1), (xm + 1, ym - 1), (xm + 1, ym + 1), (xm - 1, ym + 1)];
            for ((k, q), want) in p.corners.iter().zip(want) {
                let r = f.blocks[*k].rect;
                let (a, b) = q.offset();
                let at = (if a == 1 { r[2] } else { r[0] }, if b == 1 { r[3] } else { r[1] });
                assert_eq!(at, want);
            }
        }
        // Shrunk by one cell inside, not at the border.
        for b in &f.blocks {
            let (x0, y0, c) = b.node.grid_rect(qt.root_cells());
            assert_eq!(b.rect[0], if x0 == 0 { 0 } else { x0 + 1 });
            assert_eq!(b.rect[3], if y0 + c == 256 { 256 } else { y0 + c - 1 });
        }
    }

    #[test]
    fn culling_hides_blocks_and_strips() {
        let hm = bumpy(257, 257);
        let cfg = DssStripsConfig {
            dss: DssConfig { leaf_cells: 8, ..Default::default() },
            ..Default::default()
        };
        let qt = cfg.dss.quadtree(&hm);
        let table = DssErrorTable::new(&hm, &qt);
        // Low, looking east from the west border: most of the terrain is behind or aside.
        let cam = Camera::from_yaw_pitch(dvec3(50.0, 1280.0, 160.0), 90.0, -10.0);
        let f = select_dss_strips(&qt, &cam, &table, &cfg);
        let hidden = f.blocks.iter().filter(|b| !b.visible).count();
        assert!(hidden > 0 && f.stats.patches > 0);
        assert!(f.culled_strips > 0);
        assert_eq!(f.selection().patches.len(), f.stats.patches);
        // Every kept strip has a visible block.
        for s in &f.strips {
            assert!(f.low(s).iter().chain(f.high(s)).any(|&b| f.blocks[b].visible));
        }
        // Each visible block's factor is Eq. 4's for its own node (worked out during the
        // traversal, in the leaves' order), hidden blocks' 2; the factors differ, so a block
        // given another's fails.
        // A second view over a tree of 64-cell leaves draws blocks at its finest level, whose
        // split the traversal does not ask, beside coarser ones it asked.
        let near = Camera::from_yaw_pitch(dvec3(50.0, 1280.0, 200.0), 90.0, -10.0);
        let fine = DssStripsConfig {
            dss: DssConfig { leaf_cells: 64, rho_thr: 4.0, ..cfg.dss.clone() },
            ..cfg.clone()
        };
        let (qt_fine, table_fine) = {
            let qt = fine.dss.quadtree(&hm);
            let table = DssErrorTable::new(&hm, &qt);
            (qt, table)
        };
        let g = select_dss_strips(&qt_fine, &near, &table_fine, &fine);
        let finest = qt_fine.shape().max_level();
        let levels: std::collections::BTreeSet<u8> =
            g.blocks.iter().filter(|b| b.visible).map(|b| b.node.level).collect();
        assert!(levels.contains(&finest) && levels.len() > 1, "{levels:?}, finest {finest}");
        for (cam, f, cfg, qt, table) in
            [(&cam, &f, &cfg, &qt, &table), (&near, &g, &fine, &qt_fine, &table_fine)]
        {
            let metric = Metric::new(table, cam, &cfg.dss);
            let mut factors = std::collections::BTreeSet::new();
            for b in &f.blocks {
                let want = match b.visible {
                    true => metric.factor(b.node, &qt.node_info(b.node).expect("a node")),
                    false => 2.0,
                };
                assert_eq!(b.factor.to_bits(), want.to_bits(), "{:?}", b.node);
                factors.insert(b.factor.to_bits());
            }
            assert!(factors.len() > 3, "{} distinct factors", factors.len());
        }
    }
}
