//! The one quadtree traversal every LOD method uses, its split and cull policies, the
//! restricted (balanced) post-pass, and neighbour lookup in a selected leaf set.
//!
//! A method plugs in a [`SplitPolicy`] (its error metric: PVPS Eq. 8, the out-of-core
//! paper's Eq. 7, the DSS paper's Eq. 3, ...) and a [`CullPolicy`] ([`FrustumCull`],
//! [`BoundingCircleCull`], a PVS lookup, or several combined with a tuple `(a, b)`), and
//! [`traverse`] does the rest.

use rustc_hash::FxHashMap;

use super::leaf_tree::LeafTree;
use super::node::{Direction, NodeId, Quadrant};
use super::tree::{NodeInfo, Quadtree, TreeShape};
use crate::geometry::{Classification, Frustum, GroundRegion, circle_vs_region};

/// What [`traverse`] needs from a node space: the per-node values the policies read. The
/// quadtree's root is [`NodeId::ROOT`] (the whole grid rounded up to a power of two of
/// cells, see the crate's node addressing); a source answers for any node.
///
/// Implemented by the in-memory [`Quadtree`] (min/max pyramid over a heightmap) and by an
/// out-of-core store's index (terrain-stream: per-block node values, no heights in memory),
/// so every LOD method walks terrain through the same traversal whatever holds it.
pub trait NodeSource {
    /// Everything the policies need about `node`, or `None` when it holds no grid cell (the
    /// traversal skips it silently). [`NodeInfo::is_finest`] stops the descent.
    fn node_info(&self, node: NodeId) -> Option<NodeInfo>;
}

impl NodeSource for Quadtree {
    fn node_info(&self, node: NodeId) -> Option<NodeInfo> {
        Quadtree::node_info(self, node)
    }
}

impl<T: NodeSource + ?Sized> NodeSource for &T {
    fn node_info(&self, node: NodeId) -> Option<NodeInfo> {
        (**self).node_info(node)
    }
}

/// A [`NodeSource`] with the geometry of its quadtree ([`TreeShape`]: which nodes exist, how
/// they are clipped and placed): what a selection that reads no heights needs (the DSS
/// paper's methods). The in-memory [`Quadtree`] and a baked store's tree implement it; the
/// methods that also read heights take terrain-core's `lod::TerrainSource`.
pub trait NodeTree: NodeSource {
    /// The quadtree's geometry: every node the source answers for exists in it.
    fn shape(&self) -> &TreeShape;

    /// Calls `f` with this tree as the node source of one traversal. A source whose lookups
    /// share work between consecutive nodes (a baked store: the block entry of the node asked
    /// about last, which a depth-first walk asks about again and again) keeps it there for the
    /// length of `f`, which `&self` alone cannot; the answers are the same as
    /// [`NodeSource::node_info`]'s. The default passes the tree itself.
    fn with_traversal_source(&self, f: &mut dyn FnMut(&dyn NodeSource)) {
        f(&self)
    }
}

impl NodeTree for Quadtree {
    fn shape(&self) -> &TreeShape {
        Quadtree::shape(self)
    }
}

impl<T: NodeTree + ?Sized> NodeTree for &T {
    fn shape(&self) -> &TreeShape {
        (**self).shape()
    }

    fn with_traversal_source(&self, f: &mut dyn FnMut(&dyn NodeSource)) {
        (**self).with_traversal_source(f)
    }
}

/// What a cull policy says about a node.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Cull {
    /// Invisible: drop the node and its subtree.
    Reject,
    /// Possibly visible: keep it, and ask again for its children.
    Accept,
    /// Entirely visible: keep it and its whole subtree without asking again.
    AcceptAll,
}

impl From<Classification> for Cull {
    fn from(c: Classification) -> Self {
        match c {
            Classification::Outside => Cull::Reject,
            Classification::Intersecting => Cull::Accept,
            Classification::Inside => Cull::AcceptAll,
        }
    }
}

/// What happened to a node during [`traverse`] (reported to the visitor in traversal order).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Visit {
    /// Rejected by the cull policy; its subtree is not visited.
    Culled,
    /// Split; its children follow.
    Split,
    /// Selected as a leaf (drawn).
    Leaf,
}

/// Decides whether a node is refined. Only asked for nodes that can split (not at the
/// finest level) and that the cull policy kept.
pub trait SplitPolicy {
    /// Whether `node` should be replaced by its children.
    fn should_split(&mut self, node: NodeId, info: &NodeInfo) -> bool;
}

impl<F: FnMut(NodeId, &NodeInfo) -> bool> SplitPolicy for F {
    fn should_split(&mut self, node: NodeId, info: &NodeInfo) -> bool {
        self(node, info)
    }
}

/// Decides whether a node is visible. Not asked below a node that returned
/// [`Cull::AcceptAll`].
pub trait CullPolicy {
    /// Classifies `node`.
    fn classify(&mut self, node: NodeId, info: &NodeInfo) -> Cull;
}

impl<F: FnMut(NodeId, &NodeInfo) -> Cull> CullPolicy for F {
    fn classify(&mut self, node: NodeId, info: &NodeInfo) -> Cull {
        self(node, info)
    }
}

/// Both policies must keep a node: `Reject` if either rejects, `AcceptAll` only if both do.
impl<A: CullPolicy, B: CullPolicy> CullPolicy for (A, B) {
    fn classify(&mut self, node: NodeId, info: &NodeInfo) -> Cull {
        match self.0.classify(node, info) {
            Cull::Reject => Cull::Reject,
            a => match (a, self.1.classify(node, info)) {
                (_, Cull::Reject) => Cull::Reject,
                (Cull::AcceptAll, Cull::AcceptAll) => Cull::AcceptAll,
                _ => Cull::Accept,
            },
        }
    }
}

/// Splits every node down to the finest level.
#[derive(Debug, Clone, Copy, Default)]
pub struct AlwaysSplit;

impl SplitPolicy for AlwaysSplit {
    fn should_split(&mut self, _: NodeId, _: &NodeInfo) -> bool {
        true
    }
}

/// Splits every node above the given level (a uniform grid of nodes).
#[derive(Debug, Clone, Copy)]
pub struct SplitToLevel(pub u8);

impl SplitPolicy for SplitToLevel {
    fn should_split(&mut self, node: NodeId, _: &NodeInfo) -> bool {
        node.level < self.0
    }
}

/// Keeps everything.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoCull;

impl CullPolicy for NoCull {
    fn classify(&mut self, _: NodeId, _: &NodeInfo) -> Cull {
        Cull::AcceptAll
    }
}

/// Six-plane view-frustum culling of the node's world box ([`NodeInfo::aabb`], from the
/// min/max pyramid): the PVPS paper's section 2.3.2 and the DSS paper's hierarchical
/// frustum culling.
#[derive(Debug, Clone, Copy)]
pub struct FrustumCull {
    /// The frustum, world frame.
    pub frustum: Frustum,
}

impl FrustumCull {
    /// Culls against `frustum`.
    pub fn new(frustum: Frustum) -> Self {
        Self { frustum }
    }
}

impl CullPolicy for FrustumCull {
    fn classify(&mut self, _: NodeId, info: &NodeInfo) -> Cull {
        self.frustum.classify(&info.aabb).into()
    }
}

/// The out-of-core paper's culling (its sections 3.1 and 3.3): the node's bounding circle
/// (its plan diagonal as diameter) against the view region projected on the ground (see
/// [`crate::geometry::project_view_to_ground`]). Heights play no part.
#[derive(Debug, Clone)]
pub struct BoundingCircleCull {
    /// The projected view region.
    pub region: GroundRegion,
}

impl BoundingCircleCull {
    /// Culls against `region`.
    pub fn new(region: GroundRegion) -> Self {
        Self { region }
    }
}

impl CullPolicy for BoundingCircleCull {
    fn classify(&mut self, _: NodeId, info: &NodeInfo) -> Cull {
        let (lo, hi) = (info.aabb.min.truncate(), info.aabb.max.truncate());
        let radius = (hi - lo).length() * 0.5;
        circle_vs_region(&self.region, (lo + hi) * 0.5, radius).into()
    }
}

/// The traversal shared by every LOD method, over any [`NodeSource`]: top-down from the root, depth-first in child
/// order (SW, SE, NE, NW). For each node that holds grid cells: the cull policy classifies
/// it (unless an ancestor was [`Cull::AcceptAll`]); a rejected node is reported as
/// [`Visit::Culled`] and dropped; otherwise, if it is above the finest level and the split
/// policy says so, it is reported as [`Visit::Split`] and its children follow; else it is
/// reported as [`Visit::Leaf`] and selected. Nodes entirely outside the grid (past its
/// east or north edge) are skipped silently.
///
/// Returns the selected leaves in traversal order (deterministic; sorted by
/// [`NodeId::dfs_key`]).
pub fn traverse<Q, S, C, V>(qt: &Q, split: &mut S, cull: &mut C, visit: &mut V) -> Vec<NodeId>
where
    Q: NodeSource + ?Sized,
    S: SplitPolicy + ?Sized,
    C: CullPolicy + ?Sized,
    V: FnMut(NodeId, Visit) + ?Sized,
{
    let mut out = Vec::new();
    walk(qt, split, cull, &mut |node, v| {
        visit(node, v);
        if v == Visit::Leaf {
            out.push(node);
        }
    });
    out
}

/// [`traverse`] without the list of leaves: each is only reported to `visit`, in the same
/// order. For a caller that keeps its own list per leaf (`uniform`'s millions of patches over a
/// large store), so that the leaves are not listed twice.
pub fn walk<Q, S, C, V>(qt: &Q, split: &mut S, cull: &mut C, visit: &mut V)
where
    Q: NodeSource + ?Sized,
    S: SplitPolicy + ?Sized,
    C: CullPolicy + ?Sized,
    V: FnMut(NodeId, Visit) + ?Sized,
{
    // Explicit stack, children pushed in reverse so they pop in order.
    let mut stack = vec![(NodeId::ROOT, false)];
    while let Some((node, inside)) = stack.pop() {
        let Some(info) = qt.node_info(node) else { continue };
        let mut all = inside;
        if !all {
            match cull.classify(node, &info) {
                Cull::Reject => {
                    visit(node, Visit::Culled);
                    continue;
                }
                Cull::Accept => {}
                Cull::AcceptAll => all = true,
            }
        }
        if !info.is_finest && split.should_split(node, &info) {
            visit(node, Visit::Split);
            for c in node.children().into_iter().rev() {
                stack.push((c, all));
            }
        } else {
            visit(node, Visit::Leaf);
        }
    }
}

/// [`traverse`] without a visitor.
pub fn select<Q, S, C>(qt: &Q, split: &mut S, cull: &mut C) -> Vec<NodeId>
where
    Q: NodeSource + ?Sized,
    S: SplitPolicy + ?Sized,
    C: CullPolicy + ?Sized,
{
    traverse(qt, split, cull, &mut |_, _| {})
}

/// A set of selected leaves with neighbour lookup across level boundaries.
///
/// Holds the leaves and their ancestors (a linear quadtree's nodes, keyed by
/// [`NodeId::key`]), so the leaf across an edge is one lookup when it is at the same level or
/// finer, and a region without leaves (culled, outside the grid) is known at once instead of
/// by a search down to the finest level.
#[derive(Debug, Clone, Default)]
pub struct LeafSet {
    /// FxHash (rustc's hasher): the set is built and probed several times per leaf every
    /// frame, and std's SipHash showed in profiles of the store selection.
    nodes: ExistingNodes,
    len: usize,
}

impl LeafSet {
    /// The set of `leaves` (assumed disjoint: no leaf is an ancestor of another).
    pub fn new(leaves: impl IntoIterator<Item = NodeId>) -> Self {
        let mut nodes = ExistingNodes::default();
        let mut len = 0;
        for n in leaves {
            if nodes.get(n) != Some(Exists::Leaf) {
                len += 1;
            }
            nodes.add_leaf(n);
        }
        Self { nodes, len }
    }

    /// Whether `n` is a selected leaf.
    pub fn contains(&self, n: NodeId) -> bool {
        self.nodes.get(n) == Some(Exists::Leaf)
    }

    /// Number of leaves.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there are no leaves.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The leaves in traversal order.
    pub fn sorted(&self) -> Vec<NodeId> {
        let mut v: Vec<NodeId> = self
            .nodes
            .map
            .iter()
            .filter(|&(_, &e)| e == Exists::Leaf)
            .map(|(&k, _)| NodeId::from_key(k))
            .collect();
        v.sort_by_key(|n| n.dfs_key());
        v
    }

    /// The selected leaf that contains `n` (is `n` or an ancestor of it), if any.
    pub fn leaf_covering(&self, n: NodeId) -> Option<NodeId> {
        // The deepest node of the set at or above `n`: a leaf covers `n`; a split node has
        // its leaves below (finer than `n`, or none in `n`: a hole).
        let mut a = n;
        loop {
            match self.nodes.get(a) {
                Some(Exists::Leaf) => return Some(a),
                Some(Exists::Split) => return None,
                None => a = a.parent()?,
            }
        }
    }

    /// The selected leaves across edge `d` of `node`: a single leaf at the same or a
    /// coarser level, or the finer leaves along that edge (ordered west to east or south
    /// to north); empty at the root's border or where the neighbour region holds no leaf
    /// (culled).
    pub fn neighbours(&self, node: NodeId, d: Direction) -> Vec<NodeId> {
        let Some(g) = node.neighbour(d) else { return Vec::new() };
        if let Some(l) = self.leaf_covering(g) {
            return vec![l];
        }
        let mut out = Vec::new();
        self.collect_facing(g, d.opposite(), &mut out);
        out
    }

    /// The coarsest level among [`LeafSet::neighbours`] and the finest, or `None`.
    pub fn neighbour_levels(&self, node: NodeId, d: Direction) -> Option<(u8, u8)> {
        let v = self.neighbours(node, d);
        let lo = v.iter().map(|n| n.level).min()?;
        Some((lo, v.iter().map(|n| n.level).max()?))
    }

    /// Leaves inside `n` touching its side `side`, in west->east / south->north order.
    fn collect_facing(&self, n: NodeId, side: Direction, out: &mut Vec<NodeId>) {
        match self.nodes.get(n) {
            Some(Exists::Leaf) => {
                out.push(n);
                return;
            }
            Some(Exists::Split) => {}
            None => return,
        }
        for q in facing_quadrants(side) {
            self.collect_facing(n.child(q), side, out);
        }
    }
}

/// The restricted-quadtree post-pass: splits selected leaves until every two leaves that
/// share an edge differ by at most one level (what the crack-free methods need: PVPS Alg. 1,
/// DSS strips, geomorphing neighbour factors). Leaves are only ever split (detail is
/// added, never removed); children of a split leaf that hold no grid cell are dropped; the
/// new children are *not* re-culled (conservative: the parent was visible). Returns the
/// leaves in traversal order.
pub fn balance(qt: &Quadtree, leaves: &[NodeId]) -> Vec<NodeId> {
    balance_with(leaves, |n| qt.contains_node(n))
}

/// [`balance`] without a [`Quadtree`]: `contains(node)` says whether a child holds a grid cell
/// (an out-of-core store's node space, whose heights are not in memory).
///
/// The restricted quadtree by one sweep from the finest level to the coarsest over an explicit
/// tree of the leaves ([`LeafTree::balanced`], which documents the algorithm); the output is
/// sorted by [`NodeId::dfs_key`].
pub fn balance_with(leaves: &[NodeId], contains: impl Fn(NodeId) -> bool) -> Vec<NodeId> {
    LeafTree::balanced(leaves, contains).into_leaves()
}

/// Whether a node of a leaf set is a leaf or split (an ancestor of leaves).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Exists {
    Leaf,
    Split,
}

/// The nodes of a leaf set (leaves and their ancestors), keyed by [`NodeId::key`].
#[derive(Debug, Clone, Default)]
struct ExistingNodes {
    map: FxHashMap<u64, Exists>,
}

impl ExistingNodes {
    fn get(&self, n: NodeId) -> Option<Exists> {
        self.map.get(&n.key()).copied()
    }

    /// Adds leaf `n` and marks its ancestors split (stops at the first one already there).
    fn add_leaf(&mut self, n: NodeId) {
        self.map.insert(n.key(), Exists::Leaf);
        let mut a = n;
        while let Some(p) = a.parent() {
            if self.map.insert(p.key(), Exists::Split).is_some() {
                break;
            }
            a = p;
        }
    }
}

/// Whether every two leaves that share an edge differ by at most one level.
pub fn is_balanced(leaves: &[NodeId]) -> bool {
    let set = LeafSet::new(leaves.iter().copied());
    leaves.iter().all(|&n| {
        Direction::ALL
            .iter()
            .all(|&d| set.neighbours(n, d).iter().all(|m| m.level.abs_diff(n.level) <= 1))
    })
}

/// The two children of a node that touch its `side`.
pub(super) fn facing_quadrants(side: Direction) -> [Quadrant; 2] {
    match side {
        Direction::North => [Quadrant::NorthWest, Quadrant::NorthEast],
        Direction::South => [Quadrant::SouthWest, Quadrant::SouthEast],
        Direction::East => [Quadrant::SouthEast, Quadrant::NorthEast],
        Direction::West => [Quadrant::SouthWest, Quadrant::NorthWest],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::random_tree;
    use rustc_hash::FxHashSet;

    /// The former `balance_with`, kept as the reference: a work list popped deepest first,
    /// one hash lookup per coarser ancestor level of each neighbour, a sort at the end.
    fn balance_reference(leaves: &[NodeId], contains: impl Fn(NodeId) -> bool) -> Vec<NodeId> {
        let mut set: FxHashSet<NodeId> = leaves.iter().copied().collect();
        let mut work: Vec<NodeId> = leaves.to_vec();
        work.sort_by_key(|n| n.level);
        while let Some(f) = work.pop() {
            if !set.contains(&f) || f.level < 2 {
                continue;
            }
            for d in Direction::ALL {
                let Some(g) = f.neighbour(d) else { continue };
                loop {
                    let coarse =
                        (0..f.level - 1).rev().map(|l| g.ancestor(l)).find(|a| set.contains(a));
                    let Some(a) = coarse else { break };
                    set.remove(&a);
                    for c in a.children() {
                        if contains(c) {
                            set.insert(c);
                            work.push(c);
                        }
                    }
                }
            }
        }
        let mut v: Vec<NodeId> = set.into_iter().collect();
        v.sort_by_key(|n| n.dfs_key());
        v
    }

    /// The former `LeafSet` neighbour search: one lookup per ancestor level, then down to the
    /// finest level.
    fn neighbours_reference(set: &FxHashSet<NodeId>, node: NodeId, d: Direction) -> Vec<NodeId> {
        fn facing(
            set: &FxHashSet<NodeId>,
            max: u8,
            n: NodeId,
            side: Direction,
            out: &mut Vec<NodeId>,
        ) {
            if set.contains(&n) {
                out.push(n);
                return;
            }
            if n.level >= max {
                return;
            }
            for q in super::facing_quadrants(side) {
                facing(set, max, n.child(q), side, out);
            }
        }
        let Some(g) = node.neighbour(d) else { return Vec::new() };
        if let Some(l) = (0..=g.level).rev().map(|l| g.ancestor(l)).find(|a| set.contains(a)) {
            return vec![l];
        }
        let max = set.iter().map(|n| n.level).max().unwrap_or(0);
        let mut out = Vec::new();
        facing(set, max, g, d.opposite(), &mut out);
        out
    }

    #[test]
    fn balance_equals_the_hash_walk_on_random_trees() {
        let (mut changed, mut holes) = (0, 0);
        for seed in 0..400u64 {
            let max = 3 + (seed % 9) as u8;
            let side = 1u32 << max;
            let (w, h) = (
                side - (seed as u32 * 7) % (side / 2),
                side - (seed as u32 * 3) % (side / 3).max(1),
            );
            let (leaves, contains) =
                random_tree(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15), max, w, h);
            let want = balance_reference(&leaves, &contains);
            let got = balance_with(&leaves, &contains);
            assert_eq!(got, want, "seed {seed}");
            assert!(is_balanced(&got), "seed {seed}");
            // Input order does not matter.
            let mut rev = leaves.clone();
            rev.reverse();
            assert_eq!(balance_with(&rev, &contains), want, "seed {seed} reversed");
            changed += usize::from(got != leaves);
            // The neighbour search of the new `LeafSet` against the old one on the result.
            let set = LeafSet::new(got.iter().copied());
            let old: FxHashSet<NodeId> = got.iter().copied().collect();
            assert_eq!(set.len(), got.len());
            assert_eq!(set.sorted(), got);
            for &n in &got {
                for d in Direction::ALL {
                    let r = neighbours_reference(&old, n, d);
                    holes += usize::from(r.is_empty() && n.neighbour(d).is_some());
                    assert_eq!(set.neighbours(n, d), r, "seed {seed} {n:?} {d:?}");
                }
            }
        }
        // The trees exercise the balance and the holes (else the test could not fail).
        assert!(changed > 200, "{changed} of 400 trees needed balancing");
        assert!(holes > 100, "{holes} edges face a hole");
    }

    #[test]
    fn leaf_tree_neighbours_equal_the_leaf_set_s() {
        let (mut finer, mut coarser, mut holes) = (0, 0, 0);
        for seed in 0..300u64 {
            let max = 3 + (seed % 8) as u8;
            let side = 1u32 << max;
            let (w, h) = (side - (seed as u32 * 5) % (side / 2), side);
            let (raw, contains) = random_tree(seed.wrapping_mul(0x2545_f491_4f6c_dd1d), max, w, h);
            let balanced = balance_with(&raw, &contains);
            // Unbalanced and balanced sets, in depth-first and in reversed order.
            for leaves in [raw.clone(), balanced] {
                let mut rev = leaves.clone();
                rev.reverse();
                for input in [leaves.clone(), rev] {
                    let set = LeafSet::new(input.iter().copied());
                    let tree = super::super::leaf_tree::LeafTree::new(&input);
                    assert_eq!(tree.leaves(), &input[..]);
                    for (k, &n) in input.iter().enumerate() {
                        for d in Direction::ALL {
                            let want = set.neighbours(n, d);
                            let got: Vec<NodeId> =
                                tree.neighbours(k, d).into_iter().map(|m| input[m]).collect();
                            assert_eq!(got, want, "seed {seed} {n:?} {d:?}");
                            match want.as_slice() {
                                [] => holes += usize::from(n.neighbour(d).is_some()),
                                [m] if m.level < n.level => coarser += 1,
                                [m] if m.level == n.level => {}
                                _ => finer += 1,
                            }
                        }
                    }
                }
            }
        }
        // Every case is exercised (else the comparison could pass vacuously).
        assert!(finer > 1000 && coarser > 1000 && holes > 100, "{finer} {coarser} {holes}");
    }

    #[test]
    fn node_keys_round_trip() {
        for n in [NodeId::ROOT, NodeId::new(30, (1 << 30) - 1, 5), NodeId::new(7, 100, 3)] {
            assert_eq!(NodeId::from_key(n.key()), n);
        }
        assert_ne!(NodeId::new(1, 0, 1).key(), NodeId::new(2, 0, 1).key());
    }
}
