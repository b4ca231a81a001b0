//! The selected leaves as an explicit quadtree (the leaves and their ancestors in one flat
//! array, children by index) with every node's neighbour across each edge found in one
//! top-down pass, no hashing: what the edge-factor resolver
//! ([`crate::lod::outer_factors_all`]) reads for every leaf of a frame.
//!
//! The pass is the standard neighbour propagation of pointer quadtrees (Samet 1982, "Neighbor
//! finding techniques for images represented by quadtrees", done top-down for all nodes at
//! once): a child's neighbour across an edge inside its parent is a sibling; across the
//! parent's edge it is the parent's neighbour if that is a leaf (the same or a coarser level),
//! else that neighbour's child facing back. Each node costs O(1), so the set's neighbours cost
//! O(nodes) instead of hash lookups per edge (`LeafSet::neighbours`, which answers the same:
//! test `leaf_tree_neighbours_equal_the_leaf_set_s`).

use super::node::{Direction, NodeId, Quadrant};
use super::traverse::facing_quadrants;

/// No node.
const NONE: u32 = u32::MAX;

/// One node of the tree: a leaf or an ancestor of leaves.
#[derive(Debug, Clone, Copy)]
struct TreeNode {
    id: NodeId,
    /// Index of each child in [`Quadrant::ALL`] order, or [`NONE`] (no leaf below).
    children: [u32; 4],
    /// The leaf's index in the input, or [`NONE`] for an ancestor (split node).
    leaf: u32,
    /// The parent ([`NONE`] for the root).
    parent: u32,
    /// Per [`Direction::ALL`]: the node at the same level across that edge, else the leaf
    /// covering that position (coarser), else [`NONE`] (root border or no leaf there); after
    /// [`LeafTree::balanced`] possibly a coarser node split since, which [`resolve`] follows
    /// down.
    across: [u32; 4],
}

/// What lies across one edge of a leaf of a [`LeafTree`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Across {
    /// No leaf: the root's border, or a region without leaves (culled, outside the grid).
    Nothing,
    /// One leaf (its index) at the same level or a coarser one.
    Leaf(usize),
    /// The same-level node across is split: its leaves touching the edge are finer
    /// ([`LeafTree::facing`]).
    Finer(SplitNode),
}

/// A split node of a [`LeafTree`] (an ancestor of leaves), for [`LeafTree::facing`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SplitNode(u32);

/// A set of quadtree leaves with neighbour lookup by index (see the module docs).
#[derive(Debug, Clone, Default)]
pub struct LeafTree {
    nodes: Vec<TreeNode>,
    /// Per input leaf, its node ([`NONE`] for a leaf inside another leaf, which is dropped).
    leaf_node: Vec<u32>,
    leaves: Vec<NodeId>,
}

impl LeafTree {
    /// The tree of `leaves` (any order; leaves inside another leaf are ignored, duplicates
    /// share one node). Leaf indices are positions in `leaves`.
    pub fn new(leaves: &[NodeId]) -> Self {
        let mut order: Vec<u32> = (0..leaves.len() as u32).collect();
        if !leaves.is_sorted_by_key(|n| n.dfs_key()) {
            order.sort_by_key(|&k| leaves[k as usize].dfs_key());
        }
        let mut nodes = vec![TreeNode {
            id: NodeId::ROOT,
            children: [NONE; 4],
            leaf: NONE,
            parent: NONE,
            across: [NONE; 4],
        }];
        let mut leaf_node = vec![NONE; leaves.len()];
        // The path from the root to the last leaf placed: in depth-first order each leaf
        // shares a prefix of it (ancestors sort before their descendants).
        let mut path: Vec<u32> = vec![0];
        for &k in &order {
            let n = leaves[k as usize];
            while path.len() > 1
                && !nodes[*path.last().unwrap_or(&0) as usize].id.is_ancestor_or_self_of(n)
            {
                path.pop();
            }
            let mut t = *path.last().unwrap_or(&0);
            let mut inside_leaf = nodes[t as usize].leaf != NONE && nodes[t as usize].id != n;
            while !inside_leaf && nodes[t as usize].id.level < n.level {
                let q = n.ancestor(nodes[t as usize].id.level + 1).quadrant() as usize;
                let c = match nodes[t as usize].children[q] {
                    NONE => {
                        let id = nodes[t as usize].id.child(Quadrant::ALL[q]);
                        nodes.push(TreeNode {
                            id,
                            children: [NONE; 4],
                            leaf: NONE,
                            parent: t,
                            across: [NONE; 4],
                        });
                        let c = (nodes.len() - 1) as u32;
                        nodes[t as usize].children[q] = c;
                        c
                    }
                    c => c,
                };
                t = c;
                path.push(t);
                inside_leaf = nodes[t as usize].leaf != NONE && nodes[t as usize].id != n;
            }
            if inside_leaf {
                continue;
            }
            if nodes[t as usize].leaf == NONE {
                // A node already split holds leaves below it: `n` would overlap them.
                if nodes[t as usize].children != [NONE; 4] {
                    continue;
                }
                nodes[t as usize].leaf = k;
            }
            leaf_node[k as usize] = t;
        }
        propagate(&mut nodes);
        Self { nodes, leaf_node, leaves: leaves.to_vec() }
    }

    /// The least balanced refinement of `leaves` (every two leaves sharing an edge differ by
    /// at most one level; the restricted quadtree of Von Herzen & Barr 1987) as a tree, its
    /// leaves in depth-first order ([`NodeId::dfs_key`]); `contains(child)` says whether a
    /// child of a split leaf holds a grid cell (those that do not are dropped; the new
    /// children are not culled again).
    ///
    /// A sweep from the finest level to the coarsest over the leaves bucketed by level (Moore
    /// 1995, "The cost of balancing quadtrees"; Sundar, Sampath & Biros 2008 balance linear
    /// octrees level by level the same way): a leaf `f` at level `l` needs the node at level
    /// `l - 1` across each of its parent's edges to exist; where a leaf coarser than that
    /// covers it, that leaf is split down to it. Splits only create leaves coarser than `l`,
    /// so one pass reaches the fixed point; every split is forced, so the result is the least
    /// balanced refinement (test `balance_equals_the_hash_walk_on_random_trees` against the
    /// former per-ancestor hash walk). The node across is the parent's neighbour pointer,
    /// followed down through nodes split since it was set (no hashing); the output is the
    /// tree's leaves in child order.
    pub fn balanced(leaves: &[NodeId], contains: impl Fn(NodeId) -> bool) -> Self {
        let Self { mut nodes, .. } = Self::new(leaves);
        let max_level = nodes.iter().map(|n| n.id.level).max().unwrap_or(0);
        let mut buckets: Vec<Vec<u32>> = vec![Vec::new(); usize::from(max_level) + 1];
        for (k, n) in nodes.iter().enumerate() {
            if n.leaf != NONE {
                buckets[usize::from(n.id.level)].push(k as u32);
            }
        }
        for l in (2..=max_level).rev() {
            // Leaves at level `l` are only created while sweeping finer levels, so the bucket
            // is complete; entries split since are no longer leaves and are skipped.
            let bucket = std::mem::take(&mut buckets[usize::from(l)]);
            for &f in &bucket {
                let TreeNode { id: fid, leaf, parent, .. } = nodes[f as usize];
                if leaf == NONE || parent == NONE {
                    continue;
                }
                for d in Direction::ALL {
                    let Some(g) = fid.neighbour(d) else { continue };
                    let p = NodeId { level: l - 1, i: g.i >> 1, j: g.j >> 1 };
                    if p == nodes[parent as usize].id {
                        continue; // across an edge inside the parent, which exists
                    }
                    // The deepest node at level `l - 1` or above covering `p`: `p` itself
                    // (balanced across this edge), a leaf two or more levels coarser (split
                    // it down to `p`), or none (a hole: culled, outside the grid).
                    let mut a = resolve(&nodes, parent, d);
                    if a == NONE || nodes[a as usize].id.level == p.level {
                        continue;
                    }
                    loop {
                        let aid = nodes[a as usize].id;
                        nodes[a as usize].leaf = NONE;
                        let next = p.ancestor(aid.level + 1);
                        let mut go = NONE;
                        for (q, c) in aid.children().into_iter().enumerate() {
                            if contains(c) {
                                nodes.push(TreeNode {
                                    id: c,
                                    children: [NONE; 4],
                                    leaf: 0,
                                    parent: a,
                                    across: [NONE; 4],
                                });
                                let k = (nodes.len() - 1) as u32;
                                nodes[a as usize].children[q] = k;
                                buckets[usize::from(c.level)].push(k);
                                if c == next {
                                    go = k;
                                }
                            }
                        }
                        set_children_across(&mut nodes, a);
                        if go == NONE || next.level == p.level {
                            break;
                        }
                        a = go;
                    }
                }
            }
        }
        // The leaves in child order, indexed in that order.
        let mut out = Vec::new();
        let mut leaf_node = Vec::new();
        let mut stack = vec![0u32];
        while let Some(m) = stack.pop() {
            let n = &mut nodes[m as usize];
            if n.leaf != NONE {
                n.leaf = out.len() as u32;
                out.push(n.id);
                leaf_node.push(m);
            } else {
                stack.extend(n.children.iter().rev().filter(|&&c| c != NONE));
            }
        }
        // Pointers to nodes split since they were set are followed down by `across`.
        Self { nodes, leaf_node, leaves: out }
    }

    /// [`LeafTree::leaves`], by value.
    pub fn into_leaves(self) -> Vec<NodeId> {
        self.leaves
    }

    /// The leaves, in the order given to [`LeafTree::new`] (depth-first for
    /// [`LeafTree::balanced`]).
    pub fn leaves(&self) -> &[NodeId] {
        &self.leaves
    }

    /// What lies across edge `d` of leaf `leaf` (an index into [`LeafTree::leaves`]).
    pub fn across(&self, leaf: usize, d: Direction) -> Across {
        let Some(&t) = self.leaf_node.get(leaf).filter(|&&t| t != NONE) else {
            return Across::Nothing;
        };
        match resolve(&self.nodes, t, d) {
            NONE => Across::Nothing,
            m => match self.nodes[m as usize].leaf {
                NONE => Across::Finer(SplitNode(m)),
                l => Across::Leaf(l as usize),
            },
        }
    }

    /// The leaves inside split node `s` touching its side `side`, west to east or south to
    /// north, appended to `out` (indices into [`LeafTree::leaves`]).
    pub fn facing(&self, s: SplitNode, side: Direction, out: &mut Vec<usize>) {
        let n = &self.nodes[s.0 as usize];
        if n.leaf != NONE {
            out.push(n.leaf as usize);
            return;
        }
        for q in facing_quadrants(side) {
            let c = n.children[q as usize];
            if c != NONE {
                self.facing(SplitNode(c), side, out);
            }
        }
    }

    /// The leaves across edge `d` of leaf `leaf`: one at the same or a coarser level, or the
    /// finer ones along the edge, or none (what `LeafSet::neighbours` answers, by index).
    pub fn neighbours(&self, leaf: usize, d: Direction) -> Vec<usize> {
        match self.across(leaf, d) {
            Across::Nothing => Vec::new(),
            Across::Leaf(m) => vec![m],
            Across::Finer(s) => {
                let mut out = Vec::new();
                self.facing(s, d.opposite(), &mut out);
                out
            }
        }
    }
}

/// Every node's neighbour pointers from its parent's, top-down (parents precede their children
/// in `nodes`): exact when the parents' are.
fn propagate(nodes: &mut [TreeNode]) {
    for p in 0..nodes.len() {
        set_children_across(nodes, p as u32);
    }
}

/// The neighbour pointers of `p`'s children from `p`'s (the module docs' rule). Where `p`'s
/// pointer is a node split after it was set (coarser than `p`), the child keeps that node:
/// still the deepest known node covering the position, which [`resolve`] follows down.
fn set_children_across(nodes: &mut [TreeNode], p: u32) {
    let parent = nodes[p as usize];
    for (q, &c) in parent.children.iter().enumerate() {
        if c == NONE {
            continue;
        }
        let (di, dj) = Quadrant::ALL[q].offset();
        let mut across = [NONE; 4];
        for (a, d) in Direction::ALL.into_iter().enumerate() {
            // The quadrant across `d`, inside the parent or inside its neighbour.
            let (inside, fi, fj) = match d {
                Direction::East => (di == 0, 1 - di, dj),
                Direction::West => (di == 1, 1 - di, dj),
                Direction::North => (dj == 0, di, 1 - dj),
                Direction::South => (dj == 1, di, 1 - dj),
            };
            let f = Quadrant::from_offset(fi, fj) as usize;
            across[a] = if inside {
                parent.children[f]
            } else {
                match parent.across[a] {
                    NONE => NONE,
                    m if nodes[m as usize].leaf != NONE => m,
                    m if nodes[m as usize].id.level < parent.id.level => m,
                    m => nodes[m as usize].children[f],
                }
            };
        }
        nodes[c as usize].across = across;
    }
}

/// The deepest node at `nodes[from]`'s level or coarser covering its same-level neighbour
/// across `d` ([`NONE`]: none, a hole or the root's border): its pointer, followed down through
/// nodes split since it was set.
fn resolve(nodes: &[TreeNode], from: u32, d: Direction) -> u32 {
    let id = nodes[from as usize].id;
    let Some(g) = id.neighbour(d) else { return NONE };
    let mut m = nodes[from as usize].across[d as usize];
    while m != NONE && nodes[m as usize].leaf == NONE && nodes[m as usize].id.level < id.level {
        let q = g.ancestor(nodes[m as usize].id.level + 1).quadrant() as usize;
        m = nodes[m as usize].children[q];
    }
    m
}
