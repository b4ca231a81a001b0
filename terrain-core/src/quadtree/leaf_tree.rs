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
    /// Per [`Direction::ALL`]: the node at the same level across that edge, else the leaf
    /// covering that position (coarser), else [`NONE`] (root border or no leaf there).
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
        let mut nodes =
            vec![TreeNode { id: NodeId::ROOT, children: [NONE; 4], leaf: NONE, across: [NONE; 4] }];
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
        // Parents precede their children in `nodes` (each was pushed before its child).
        for p in 0..nodes.len() {
            let parent = nodes[p];
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
                            m => nodes[m as usize].children[f],
                        }
                    };
                }
                nodes[c as usize].across = across;
            }
        }
        Self { nodes, leaf_node, leaves: leaves.to_vec() }
    }

    /// The leaves, in the order given to [`LeafTree::new`].
    pub fn leaves(&self) -> &[NodeId] {
        &self.leaves
    }

    /// What lies across edge `d` of leaf `leaf` (an index into [`LeafTree::leaves`]).
    pub fn across(&self, leaf: usize, d: Direction) -> Across {
        let Some(&t) = self.leaf_node.get(leaf).filter(|&&t| t != NONE) else {
            return Across::Nothing;
        };
        match self.nodes[t as usize].across[d as usize] {
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
