//! The entropy paper's comprehensive quadtree (Chen 2018, sections 3.2-3.4): Algorithm 1's
//! top-down segmentation by local curvature entropy, the edge-based node organisation (one
//! point list, edges as index lists), the three-pass crack elimination (Fig. 6), per-tile
//! constrained Delaunay triangulation (Fig. 7) and the view-dependent cut (Eq. 4-5).
//!
//! Coordinates. The root tile is the source's bounding rectangle in *plan* coordinates (grid
//! samples for a DEM, world metres for scattered points). A tree of depth `D` lives on a
//! lattice of `2^D` cells per side: node `(level, i, j)` covers lattice cells
//! `[i s, (i + 1) s] x [j s, (j + 1) s]` with `s = 2^(D - level)`. Every point is a lattice
//! vertex `(a, b)`, stored once in [`EntropyQuadtree::points`] (the paper's `ptList`), and
//! nodes hold only indices (Fig. 4e). For a DEM, lattice lines are snapped to the nearest
//! sample column or row (the depth is capped so the lattice is never finer than the grid),
//! so every vertex is a DEM sample and the mesh can be verified sample by sample.
//!
//! Children are stored contiguously in the order A = south-west, B = south-east,
//! C = north-east, D = north-west; a node's edges in the paper's order left, under, right,
//! upper, each sorted by increasing lattice coordinate along the edge.

use std::collections::HashMap;
use std::time::Instant;

use glam::{DVec2, DVec3};
use rayon::prelude::*;
use spade::{ConstrainedDelaunayTriangulation, HasPosition, Point2, Triangulation};

/// The deepest tree the lattice supports (`2^16 + 1` vertices per side).
pub const MAX_DEPTH: u32 = 16;

/// Left edge index (paper's `m_leftEdge`).
pub const LEFT: usize = 0;
/// Under (south) edge index (`m_underEdge`).
pub const UNDER: usize = 1;
/// Right edge index (`m_rightEdge`).
pub const RIGHT: usize = 2;
/// Upper (north) edge index (`m_upperEdge`).
pub const UPPER: usize = 3;

/// One point of the tree's point list: a lattice vertex and its height.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TreePoint {
    /// Lattice column (0..=2^D).
    pub a: u32,
    /// Lattice row (0..=2^D).
    pub b: u32,
    /// Height, metres.
    pub z: f64,
}

/// A quadtree node: a tile, its maximum entropy and its four edges as point indices.
#[derive(Debug, Clone, PartialEq)]
pub struct QuadNode {
    /// Depth (0 = root).
    pub level: u32,
    /// Column of the node at its level.
    pub i: u32,
    /// Row of the node at its level.
    pub j: u32,
    /// Largest local entropy over the tile (`maxE` of Algorithm 1), in the tree's units.
    pub max_e: f32,
    /// Index of the first of the four children (A, B, C, D), `None` for a leaf.
    pub children: Option<u32>,
    /// Left, under, right, upper: point indices along each edge, increasing coordinate.
    pub edges: [Vec<u32>; 4],
    /// The four corners' point indices: south-west, south-east, north-east, north-west.
    pub corners: [u32; 4],
}

/// The lattice and its mapping to plan and world coordinates.
#[derive(Debug, Clone, PartialEq)]
pub struct Lattice {
    /// Depth `D`: `2^D` cells per side.
    pub depth: u32,
    /// Plan x of every lattice column.
    pub x: Vec<f64>,
    /// Plan y of every lattice row.
    pub y: Vec<f64>,
    /// World position of plan `(0, 0)`.
    pub world_origin: DVec2,
    /// World metres per plan unit, per axis.
    pub world_scale: DVec2,
}

impl Lattice {
    /// Plan position of lattice vertex `(a, b)`.
    #[inline]
    pub fn plan(&self, a: u32, b: u32) -> DVec2 {
        DVec2::new(self.x[a as usize], self.y[b as usize])
    }

    /// World position of a plan position.
    #[inline]
    pub fn world(&self, p: DVec2) -> DVec2 {
        self.world_origin + p * self.world_scale
    }
}

/// Where the entropy values come from: a map over a regular grid of plan positions.
#[derive(Debug, Clone)]
pub struct EntropyGrid<'a> {
    /// The entropy map (in the tree's units), NaN where there is none.
    pub values: &'a [f32],
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Plan position of sample (0, 0).
    pub origin: DVec2,
    /// Plan distance between samples.
    pub spacing: DVec2,
}

/// Exact `maxE` of any lattice tile: a max pyramid down to the depth where lattice cells are
/// about one sample wide, and a direct scan of the (at most 2x2) samples below that.
#[derive(Debug, Clone)]
struct MaxPyramid {
    base: u32,
    /// `levels[l]` has `4^l` cells, row-major.
    levels: Vec<Vec<f32>>,
}

/// Largest valued entropy sample in the closed plan rectangle `[p0, p1]` (or, when it holds
/// no sample, in the smallest sample rectangle around it); 0 when all are void.
fn scan_max(g: &EntropyGrid<'_>, p0: DVec2, p1: DVec2) -> f32 {
    let lo = (p0 - g.origin) / g.spacing;
    let hi = (p1 - g.origin) / g.spacing;
    const EPS: f64 = 1e-9;
    let clampi = |v: f64, n: usize| (v.max(0.0) as usize).min(n - 1);
    let (mut i0, mut i1) = ((lo.x - EPS).ceil(), (hi.x + EPS).floor());
    if i1 < i0 {
        (i0, i1) = (lo.x.floor(), hi.x.ceil());
    }
    let (mut j0, mut j1) = ((lo.y - EPS).ceil(), (hi.y + EPS).floor());
    if j1 < j0 {
        (j0, j1) = (lo.y.floor(), hi.y.ceil());
    }
    let (i0, i1) = (clampi(i0, g.width), clampi(i1, g.width));
    let (j0, j1) = (clampi(j0, g.height), clampi(j1, g.height));
    let mut m = 0.0f32;
    for j in j0..=j1 {
        for &v in &g.values[j * g.width + i0..=j * g.width + i1] {
            if v > m {
                m = v;
            }
        }
    }
    m
}

impl MaxPyramid {
    fn new(g: &EntropyGrid<'_>, lattice: &Lattice) -> Self {
        let cells = (g.width.max(g.height).max(2) - 1) as f64;
        let base = (cells.log2().ceil() as u32).min(lattice.depth).min(12);
        let n = 1usize << base;
        let step = 1u32 << (lattice.depth - base);
        let mut bottom = vec![0.0f32; n * n];
        bottom.par_chunks_mut(n).enumerate().for_each(|(j, row)| {
            for (i, v) in row.iter_mut().enumerate() {
                let (a, b) = (i as u32 * step, j as u32 * step);
                *v = scan_max(g, lattice.plan(a, b), lattice.plan(a + step, b + step));
            }
        });
        let mut levels = vec![bottom];
        for l in (0..base).rev() {
            let n = 1usize << l;
            let below = levels.last().expect("at least the base level");
            let mut up = vec![0.0f32; n * n];
            for j in 0..n {
                for i in 0..n {
                    let k = |di: usize, dj: usize| below[(2 * j + dj) * 2 * n + 2 * i + di];
                    up[j * n + i] = k(0, 0).max(k(1, 0)).max(k(0, 1)).max(k(1, 1));
                }
            }
            levels.push(up);
        }
        levels.reverse();
        Self { base, levels }
    }

    fn max_e(&self, g: &EntropyGrid<'_>, lattice: &Lattice, level: u32, i: u32, j: u32) -> f32 {
        if level <= self.base {
            let n = 1usize << level;
            return self.levels[level as usize][j as usize * n + i as usize];
        }
        let s = 1u32 << (lattice.depth - level);
        let (a, b) = (i * s, j * s);
        scan_max(g, lattice.plan(a, b), lattice.plan(a + s, b + s))
    }
}

/// Timings and counts of one build.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BuildStats {
    /// Algorithm 1 (segmentation, points, maxE), seconds.
    pub segmentation_s: f64,
    /// Heights at the new points (interpolation), seconds.
    pub heights_s: f64,
}

/// The comprehensive quadtree.
#[derive(Debug, Clone)]
pub struct EntropyQuadtree {
    /// The lattice and its plan / world mapping.
    pub lattice: Lattice,
    /// Every point once (the paper's `ptList`).
    pub points: Vec<TreePoint>,
    /// Nodes; index 0 is the root, children contiguous.
    pub nodes: Vec<QuadNode>,
    /// The threshold `E0` it was built with.
    pub e0: f64,
    /// Build timings.
    pub stats: BuildStats,
    /// Whether the three-pass update has run since the last change of leaves.
    cracks_eliminated: bool,
}

/// The lattice keys' map (SipHash was a measurable share of the crack elimination).
type KeyMap = terrain_core::hash::KeyMap<u32>;

/// Lattice key of a point.
#[inline]
fn key(a: u32, b: u32) -> u64 {
    (u64::from(a) << 32) | u64::from(b)
}

/// Lattice key of a node.
#[inline]
fn node_key(level: u32, i: u32, j: u32) -> u64 {
    (u64::from(level) << 40) | (u64::from(i) << 20) | u64::from(j)
}

struct PointList {
    points: Vec<TreePoint>,
    index: KeyMap,
}

impl PointList {
    fn get_or_add(&mut self, a: u32, b: u32) -> u32 {
        *self.index.entry(key(a, b)).or_insert_with(|| {
            self.points.push(TreePoint { a, b, z: 0.0 });
            (self.points.len() - 1) as u32
        })
    }
}

fn new_node(pl: &mut PointList, depth: u32, level: u32, i: u32, j: u32, max_e: f32) -> QuadNode {
    let s = 1u32 << (depth - level);
    let (a0, b0) = (i * s, j * s);
    let sw = pl.get_or_add(a0, b0);
    let se = pl.get_or_add(a0 + s, b0);
    let ne = pl.get_or_add(a0 + s, b0 + s);
    let nw = pl.get_or_add(a0, b0 + s);
    QuadNode {
        level,
        i,
        j,
        max_e,
        children: None,
        edges: initial_edges([sw, se, ne, nw]),
        corners: [sw, se, ne, nw],
    }
}

/// "Every edge contains two points in this initial step" (section 3.2.1).
fn initial_edges([sw, se, ne, nw]: [u32; 4]) -> [Vec<u32>; 4] {
    [vec![sw, nw], vec![sw, se], vec![se, ne], vec![nw, ne]]
}

impl EntropyQuadtree {
    /// Algorithm 1: segments the root tile while `d < D` and `E0 < maxE`, then computes the
    /// heights of all points with `height` (called in parallel with plan positions).
    ///
    /// `lattice.depth` is `D`; `entropy` is the entropy map (in the units of `e0`).
    pub fn build(
        lattice: Lattice,
        entropy: &EntropyGrid<'_>,
        e0: f64,
        height: impl Fn(DVec2) -> f64 + Sync,
    ) -> Self {
        let t0 = Instant::now();
        let depth = lattice.depth;
        let pyramid = MaxPyramid::new(entropy, &lattice);
        let mut pl = PointList { points: Vec::new(), index: KeyMap::default() };
        // Line 1-3: the bounding rectangle's four corners and the root with its maxE.
        let root_e = pyramid.max_e(entropy, &lattice, 0, 0, 0);
        let mut nodes = vec![new_node(&mut pl, depth, 0, 0, 0, root_e)];
        let mut stack = vec![0u32];
        while let Some(n) = stack.pop() {
            let (level, i, j, max_e) = {
                let node = &nodes[n as usize];
                (node.level, node.i, node.j, node.max_e)
            };
            // Line 9: d < D and E0 < maxE.
            if level >= depth || f64::from(max_e) <= e0 {
                continue;
            }
            // Lines 5-8, 10-11: the four quarters, their maxE, the new points p5..p9.
            let first = nodes.len() as u32;
            for (ci, cj) in [(0, 0), (1, 0), (1, 1), (0, 1)] {
                let (ci, cj) = (2 * i + ci, 2 * j + cj);
                let e = pyramid.max_e(entropy, &lattice, level + 1, ci, cj);
                nodes.push(new_node(&mut pl, depth, level + 1, ci, cj, e));
            }
            nodes[n as usize].children = Some(first);
            // Lines 12-15, depth first (children pushed so A is processed first).
            stack.extend((first..first + 4).rev());
        }
        let segmentation_s = t0.elapsed().as_secs_f64();
        let t1 = Instant::now();
        let mut points = pl.points;
        points.par_iter_mut().for_each(|p| p.z = height(lattice.plan(p.a, p.b)));
        let stats = BuildStats { segmentation_s, heights_s: t1.elapsed().as_secs_f64() };
        Self { lattice, points, nodes, e0, stats, cracks_eliminated: false }
    }

    /// Number of leaves (the paper's "tiles").
    pub fn tiles(&self) -> usize {
        self.nodes.iter().filter(|n| n.children.is_none()).count()
    }

    /// The leaves whose closed rectangle holds world point `p`, as `(level, i, j)`, sorted (one
    /// leaf inside a tile, up to four on a tile corner; none outside the lattice).
    pub fn leaves_at(&self, p: DVec2) -> Vec<(u32, u32, u32)> {
        let mut out: Vec<(u32, u32, u32)> = self
            .nodes
            .iter()
            .filter(|n| n.children.is_none())
            .filter(|n| {
                let r = self.rect(n);
                let a = self.lattice.world(self.lattice.plan(r[0], r[2]));
                let b = self.lattice.world(self.lattice.plan(r[1], r[3]));
                let (a, b) = (a.min(b), a.max(b));
                p.x >= a.x && p.x <= b.x && p.y >= a.y && p.y <= b.y
            })
            .map(|n| (n.level, n.i, n.j))
            .collect();
        out.sort_unstable();
        out
    }

    /// The deepest leaf's level.
    pub fn depth_reached(&self) -> u32 {
        self.nodes.iter().map(|n| n.level).max().unwrap_or(0)
    }

    /// Lattice rectangle `[a0, a1] x [b0, b1]` of a node.
    fn rect(&self, n: &QuadNode) -> [u32; 4] {
        let s = 1u32 << (self.lattice.depth - n.level);
        [n.i * s, n.i * s + s, n.j * s, n.j * s + s]
    }

    /// Lattice coordinate of point `p` along edge `e`.
    #[inline]
    fn along(&self, e: usize, p: u32) -> u32 {
        let q = &self.points[p as usize];
        if e == LEFT || e == RIGHT { q.b } else { q.a }
    }

    /// Merges the points of `src` lying within `[lo, hi]` along edge `e` into `dst` (sorted,
    /// without repeats: two points at the same coordinate of one edge line are one point).
    fn merge(&self, e: usize, dst: &mut Vec<u32>, src: &[u32], lo: u32, hi: u32) {
        for &p in src {
            let c = self.along(e, p);
            if c < lo || c > hi {
                continue;
            }
            if let Err(at) = dst.binary_search_by_key(&c, |&q| self.along(e, q)) {
                dst.insert(at, p);
            }
        }
    }

    /// Merges edge `src_edge` of node `src` into edge `e` of node `dst` (within `[lo, hi]`).
    fn merge_nodes(&mut self, dst: usize, e: usize, src: usize, src_edge: usize, lo: u32, hi: u32) {
        if dst == src {
            return;
        }
        let mut edge = std::mem::take(&mut self.nodes[dst].edges[e]);
        self.merge(e, &mut edge, &self.nodes[src].edges[src_edge], lo, hi);
        self.nodes[dst].edges[e] = edge;
    }

    /// The paper's three-pass Quadtree update (section 3.3, Fig. 6), which removes cracks by
    /// adding the finer side's points to coarser edges. Returns the time it took, seconds.
    ///
    /// 1. Bottom-up: each parent edge takes the extra points on its children's edges.
    /// 2. Top-down: each node's edge takes the extra points of the same-level node across it
    ///    ("brother" nodes). The paper lists non-leaf nodes; we include leaves, which a leaf
    ///    needs when the node across is its own sibling (their shared edge is inside the
    ///    parent, so pass 3 cannot bring those points).
    /// 3. Top-down: each child edge on its parent's border takes the parent edge's points in
    ///    its span.
    pub fn eliminate_cracks(&mut self) -> f64 {
        let t0 = Instant::now();
        for n in &mut self.nodes {
            let [sw, se, ne, nw] = n.corners;
            for (edge, ends) in n.edges.iter_mut().zip([[sw, nw], [sw, se], [se, ne], [nw, ne]]) {
                edge.clear();
                edge.extend_from_slice(&ends);
            }
        }
        let by_key: KeyMap = self
            .nodes
            .iter()
            .enumerate()
            .map(|(k, n)| (node_key(n.level, n.i, n.j), k as u32))
            .collect();
        let mut order: Vec<u32> = (0..self.nodes.len() as u32).collect();
        order.sort_by_key(|&k| self.nodes[k as usize].level);
        // Child edges that lie on each parent edge: (edge, [children]).
        const ON_EDGE: [[usize; 2]; 4] = [[0, 3], [0, 1], [1, 2], [3, 2]];
        // Pass 1: bottom-up.
        for &k in order.iter().rev() {
            let Some(first) = self.nodes[k as usize].children else { continue };
            for (e, on_edge) in ON_EDGE.iter().enumerate() {
                for &c in on_edge {
                    self.merge_nodes(k as usize, e, first as usize + c, e, 0, u32::MAX);
                }
            }
        }
        // Pass 2: top-down, same-level neighbours.
        for &k in &order {
            let n = &self.nodes[k as usize];
            let (level, i, j) = (n.level, n.i, n.j);
            let across = [
                (LEFT, i.checked_sub(1).map(|x| (x, j)), RIGHT),
                (UNDER, j.checked_sub(1).map(|y| (i, y)), UPPER),
                (RIGHT, Some((i + 1, j)), LEFT),
                (UPPER, Some((i, j + 1)), UNDER),
            ];
            for (e, other, oe) in across {
                let Some((x, y)) = other else { continue };
                let Some(&m) = by_key.get(&node_key(level, x, y)) else { continue };
                self.merge_nodes(k as usize, e, m as usize, oe, 0, u32::MAX);
            }
        }
        // Pass 3: top-down, parent edges into children.
        for &k in &order {
            let Some(first) = self.nodes[k as usize].children else { continue };
            for (e, on_edge) in ON_EDGE.iter().enumerate() {
                for &c in on_edge {
                    let child = first as usize + c;
                    let r = self.rect(&self.nodes[child]);
                    let (lo, hi) =
                        if e == LEFT || e == RIGHT { (r[2], r[3]) } else { (r[0], r[1]) };
                    self.merge_nodes(child, e, k as usize, e, lo, hi);
                }
            }
        }
        self.cracks_eliminated = true;
        t0.elapsed().as_secs_f64()
    }

    /// The view-dependent cut (section 3.4): a copy of the tree where every node with
    /// `E >= maxE` loses its children, `E` from [`ViewThreshold::threshold_tile`] (Eq. 5).
    /// [`Self::mesh`] eliminates the cracks of the result again.
    pub fn schedule(&self, view: &ViewThreshold) -> EntropyQuadtree {
        self.schedule_by(|lo, hi| view.threshold_tile(lo, hi))
    }

    /// The cut of [`Self::schedule`] under any threshold `E(tile)` of a tile spanning
    /// `[lo, hi]` (world metres): every node with `E >= maxE` loses its children. The static
    /// scheduling with several focuses of the paper's Fig. 13 is [`FocusThreshold`].
    pub fn schedule_by(&self, threshold: impl Fn(DVec2, DVec2) -> f64) -> EntropyQuadtree {
        let mut nodes: Vec<QuadNode> = Vec::with_capacity(self.nodes.len());
        // Edges are rebuilt by the crack elimination: copy nodes without them (no allocation).
        let bare = |n: &QuadNode| QuadNode { children: None, edges: Default::default(), ..*n };
        nodes.push(bare(&self.nodes[0]));
        // (old index, new index)
        let mut stack = vec![(0u32, 0u32)];
        while let Some((old, new)) = stack.pop() {
            let n = &self.nodes[old as usize];
            let Some(first) = n.children else { continue };
            let r = self.rect(n);
            let lo = self.lattice.world(self.lattice.plan(r[0], r[2]));
            let hi = self.lattice.world(self.lattice.plan(r[1], r[3]));
            if threshold(lo, hi) >= f64::from(n.max_e) {
                continue;
            }
            let nf = nodes.len() as u32;
            for c in 0..4 {
                nodes.push(bare(&self.nodes[first as usize + c]));
                stack.push((first + c as u32, nf + c as u32));
            }
            nodes[new as usize].children = Some(nf);
        }
        EntropyQuadtree {
            lattice: self.lattice.clone(),
            points: self.points.clone(),
            nodes,
            e0: self.e0,
            stats: self.stats,
            cracks_eliminated: false,
        }
    }

    /// Triangulates every leaf (section 3.3, Fig. 7): a tile whose edges hold only its corners
    /// is two triangles; any other tile is a constrained Delaunay triangulation (spade) of its
    /// boundary points with the boundary as constraint edges. Eliminates cracks first if that
    /// has not been done.
    pub fn mesh(&mut self) -> EntropyMesh {
        if !self.cracks_eliminated {
            self.eliminate_cracks();
        }
        self.triangulate()
    }

    /// Triangulates every leaf with its edges as they are now: before [`Self::eliminate_cracks`]
    /// the result has the cracks of the paper's Fig. 5b (what the crack tests check against).
    pub fn triangulate(&self) -> EntropyMesh {
        let leaves: Vec<&QuadNode> = self.nodes.iter().filter(|n| n.children.is_none()).collect();
        let per_leaf: Vec<Vec<[u32; 3]>> =
            leaves.par_iter().map(|n| self.triangulate_tile(n)).collect();
        // Compact the points the leaves use, in point-list order (deterministic).
        let mut used = vec![u32::MAX; self.points.len()];
        for t in per_leaf.iter().flatten() {
            for &p in t {
                used[p as usize] = 0;
            }
        }
        let mut plan = Vec::new();
        let mut positions = Vec::new();
        let mut lattice = Vec::new();
        for (k, p) in self.points.iter().enumerate() {
            if used[k] == 0 {
                used[k] = plan.len() as u32;
                let q = self.lattice.plan(p.a, p.b);
                plan.push(q);
                positions.push(self.lattice.world(q).extend(p.z));
                lattice.push([p.a, p.b]);
            }
        }
        let triangles =
            per_leaf.into_iter().flatten().map(|t| t.map(|p| used[p as usize])).collect();
        EntropyMesh { positions, plan, lattice, triangles, tiles: leaves.len() }
    }

    /// The boundary polygon of a leaf, anticlockwise from the south-west corner.
    fn polygon(&self, n: &QuadNode) -> Vec<u32> {
        let mut poly: Vec<u32> = Vec::with_capacity(16);
        let mut push = |p: u32| {
            if poly.last() != Some(&p) {
                poly.push(p);
            }
        };
        n.edges[UNDER].iter().for_each(|&p| push(p));
        n.edges[RIGHT].iter().for_each(|&p| push(p));
        n.edges[UPPER].iter().rev().for_each(|&p| push(p));
        n.edges[LEFT].iter().rev().for_each(|&p| push(p));
        if poly.len() > 1 && poly.first() == poly.last() {
            poly.pop();
        }
        poly
    }

    fn triangulate_tile(&self, n: &QuadNode) -> Vec<[u32; 3]> {
        let poly = self.polygon(n);
        if poly.len() == 4 {
            return vec![[poly[0], poly[1], poly[2]], [poly[0], poly[2], poly[3]]];
        }
        let vertices: Vec<TileVertex> = poly
            .iter()
            .map(|&p| {
                let q = &self.points[p as usize];
                TileVertex { a: f64::from(q.a), b: f64::from(q.b), index: p }
            })
            .collect();
        let k = poly.len();
        let edges: Vec<[usize; 2]> = (0..k).map(|s| [s, (s + 1) % k]).collect();
        // Lattice coordinates are small integers, exact in f64: the triangulation is exact.
        let cdt = ConstrainedDelaunayTriangulation::<TileVertex>::bulk_load_cdt(vertices, edges)
            .expect("a tile's boundary is a simple convex polygon of distinct lattice points");
        cdt.inner_faces().map(|f| f.vertices().map(|v| v.data().index)).collect()
    }
}

/// A tile boundary vertex for spade, in lattice coordinates.
#[derive(Debug, Clone, Copy)]
struct TileVertex {
    a: f64,
    b: f64,
    index: u32,
}

impl HasPosition for TileVertex {
    type Scalar = f64;
    fn position(&self) -> Point2<f64> {
        Point2::new(self.a, self.b)
    }
}

/// The triangulated leaves of a tree: one shared vertex list, anticlockwise triangles.
#[derive(Debug, Clone, PartialEq)]
pub struct EntropyMesh {
    /// World positions (x east, y north, z up), metres.
    pub positions: Vec<DVec3>,
    /// Plan positions (grid samples for a DEM source).
    pub plan: Vec<DVec2>,
    /// Lattice vertex of each position.
    pub lattice: Vec<[u32; 2]>,
    /// Triangles, anticlockwise seen from above.
    pub triangles: Vec<[u32; 3]>,
    /// Number of leaves triangulated.
    pub tiles: usize,
}

/// Why a mesh is not watertight.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum WatertightError {
    /// An edge is shared by more than two triangles.
    #[error("edge {0:?} is used by {1} triangles")]
    OverShared([u32; 2], usize),
    /// An edge used by one triangle does not lie on the domain's border (a crack).
    #[error("edge {0:?} is used once but is not on the border (a crack)")]
    OpenInterior([u32; 2]),
    /// A vertex lies strictly inside a triangle's edge.
    #[error("vertex {vertex} lies inside edge {edge:?} (a T-junction)")]
    TJunction {
        /// The vertex.
        vertex: u32,
        /// The edge.
        edge: [u32; 2],
    },
    /// A triangle has zero or negative area seen from above.
    #[error("triangle {0} is degenerate or clockwise")]
    BadTriangle(usize),
    /// The triangles do not cover the domain exactly once.
    #[error("the triangles cover {covered} lattice cells², the domain is {domain}")]
    Coverage {
        /// Sum of triangle areas (lattice units).
        covered: f64,
        /// Domain area.
        domain: f64,
    },
}

impl EntropyMesh {
    /// Checks that the mesh is watertight on the lattice `[0, n]²` (`n = 2^D`): every triangle
    /// anticlockwise, every interior edge shared by exactly two triangles, edges used once only
    /// on the border, no vertex strictly inside an axis-parallel edge (all tile edges are),
    /// and the triangles' areas add up to the domain's.
    pub fn check_watertight(&self, depth: u32) -> Result<(), WatertightError> {
        let n = 1i64 << depth;
        let l = |k: u32| {
            let [a, b] = self.lattice[k as usize];
            (i64::from(a), i64::from(b))
        };
        let mut count: HashMap<[u32; 2], usize> = HashMap::new();
        let mut area2 = 0i64;
        for (t, tri) in self.triangles.iter().enumerate() {
            let [p, q, r] = tri.map(l);
            let cross = (q.0 - p.0) * (r.1 - p.1) - (q.1 - p.1) * (r.0 - p.0);
            if cross <= 0 {
                return Err(WatertightError::BadTriangle(t));
            }
            area2 += cross;
            for (x, y) in [(tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])] {
                *count.entry([x.min(y), x.max(y)]).or_default() += 1;
            }
        }
        let domain = (n * n) as f64;
        if area2 as f64 / 2.0 != domain {
            return Err(WatertightError::Coverage { covered: area2 as f64 / 2.0, domain });
        }
        // Vertices per lattice line, for the T-junction test.
        let mut cols: HashMap<i64, Vec<i64>> = HashMap::new();
        let mut rows: HashMap<i64, Vec<i64>> = HashMap::new();
        for k in 0..self.lattice.len() as u32 {
            let (a, b) = l(k);
            cols.entry(a).or_default().push(b);
            rows.entry(b).or_default().push(a);
        }
        cols.values_mut().chain(rows.values_mut()).for_each(|v| v.sort_unstable());
        let mut edges: Vec<([u32; 2], usize)> = count.into_iter().collect();
        edges.sort_unstable();
        for (e, c) in edges {
            if c > 2 {
                return Err(WatertightError::OverShared(e, c));
            }
            let (p, q) = (l(e[0]), l(e[1]));
            if c == 1 {
                let border = (p.0 == q.0 && (p.0 == 0 || p.0 == n))
                    || (p.1 == q.1 && (p.1 == 0 || p.1 == n));
                if !border {
                    return Err(WatertightError::OpenInterior(e));
                }
            }
            let inside = |line: &Vec<i64>, lo: i64, hi: i64| {
                let k = line.partition_point(|&v| v <= lo.min(hi));
                k < line.len() && line[k] < lo.max(hi)
            };
            let hit = if p.0 == q.0 {
                inside(&cols[&p.0], p.1, q.1)
            } else if p.1 == q.1 {
                inside(&rows[&p.1], p.0, q.0)
            } else {
                false
            };
            if hit {
                let vertex = (0..self.lattice.len() as u32)
                    .find(|&k| {
                        let v = l(k);
                        if p.0 == q.0 {
                            v.0 == p.0 && v.1 > p.1.min(q.1) && v.1 < p.1.max(q.1)
                        } else {
                            v.1 == p.1 && v.0 > p.0.min(q.0) && v.0 < p.0.max(q.0)
                        }
                    })
                    .unwrap_or(0);
                return Err(WatertightError::TJunction { vertex, edge: e });
            }
        }
        Ok(())
    }
}

/// The view-dependent threshold of section 3.4.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewThreshold {
    /// Base threshold `E0`.
    pub e0: f64,
    /// `c1`: threshold added per metre of distance `r` from a tile to the visual centre.
    pub c1: f64,
    /// `c2`: threshold added per metre of distance `d` from the eye to the visual centre.
    pub c2: f64,
    /// The visual centre `O` (Eq. 4), world metres.
    pub centre: DVec3,
    /// The eye `V0`, world metres.
    pub eye: DVec3,
}

impl ViewThreshold {
    /// The visual centre of Eq. 4 for an eye `V0` looking along `dir` at a horizontal plane
    /// `P` at height `plane_z`: `O = V2 (1 - cos α) + V1 cos α`, with `V2` the eye's foot on
    /// `P`, `V1` where the sight line meets `P` and `α` the angle between the sight line and
    /// the vertical `V0V2`. The paper leaves the sight line that never meets `P` (looking at or
    /// above the horizon) open; there `cos α <= 0` and we take `O = V2`, the limit of Eq. 4 as
    /// the view becomes horizontal. An eye below `P` looks at `P` from beneath; we mirror the
    /// same rule (cos α of the downward angle).
    pub fn visual_centre(eye: DVec3, dir: DVec3, plane_z: f64) -> DVec3 {
        let v2 = DVec3::new(eye.x, eye.y, plane_z);
        let dir = dir.normalize_or_zero();
        let h = eye.z - plane_z;
        // cos α between the sight line and the downward vertical.
        let cos_a = if h >= 0.0 { -dir.z } else { dir.z };
        if cos_a <= 1e-9 || h == 0.0 {
            return v2;
        }
        let t = h.abs() / cos_a;
        let v1 = eye + dir * t;
        let v1 = DVec3::new(v1.x, v1.y, plane_z);
        v2 * (1.0 - cos_a) + v1 * cos_a
    }

    /// Eq. 5 for a tile spanning `[lo, hi]` (world metres): `r` is the distance from the visual
    /// centre to the nearest point of the tile, 0 inside it. The paper says only "the distance
    /// between one tile and the visual centre"; the distance to the tile's centre would make a
    /// large tile that contains `O` look far away and never be refined.
    pub fn threshold_tile(&self, lo: DVec2, hi: DVec2) -> f64 {
        let o = self.centre.truncate();
        self.threshold(o.clamp(lo.min(hi), lo.max(hi)))
    }

    /// Eq. 5 at a point `tile` (world metres; `r` is the horizontal distance to the visual
    /// centre, `d` the eye's distance to it).
    pub fn threshold(&self, tile: DVec2) -> f64 {
        let r = (tile - self.centre.truncate()).length();
        let d = (self.eye - self.centre).length();
        self.e0 + self.c1 * r + self.c2 * d
    }
}

/// The static scheduling of the entropy paper's Fig. 13 ("static scheduling ... by setting the
/// focus areas"): `E = E0 + c1 r`, with `r` the distance from a tile to the nearest of several
/// focus centres (0 inside a tile holding one). The paper gives the rule only in words ("the
/// grid cells in the four focus areas maintained the highest resolution, while other places
/// were simplified according to the distance to the centers of focuses"); this is Eq. 5
/// without its eye term (a static cut has no eye) and with the nearest focus as its centre.
#[derive(Debug, Clone, PartialEq)]
pub struct FocusThreshold {
    /// Base threshold `E0`: the initial tree's, so a tile holding a focus keeps its leaves.
    pub e0: f64,
    /// Threshold added per metre from the nearest focus.
    pub c1: f64,
    /// The focus centres, world metres.
    pub foci: Vec<DVec2>,
}

impl FocusThreshold {
    /// `E` of a tile spanning `[lo, hi]` (world metres); `E0` when there is no focus.
    pub fn threshold_tile(&self, lo: DVec2, hi: DVec2) -> f64 {
        let (a, b) = (lo.min(hi), lo.max(hi));
        let r =
            self.foci.iter().map(|f| (*f - f.clamp(a, b)).length()).fold(f64::INFINITY, f64::min);
        if r.is_finite() { self.e0 + self.c1 * r } else { self.e0 }
    }
}
