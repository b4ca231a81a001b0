//! Outer factors across shared edges: the one resolver every method uses, and the checker of
//! the crack-freedom invariant.
//!
//! # Why the resolver is crack-free
//! [`outer_factors`] looks at the selected leaves across each edge of a patch
//! ([`LeafSet::neighbours`]) and asks the method's [`EdgeRule`]:
//!
//! 1. **Same-level neighbour.** Both patches call [`EdgeRule::same_level`] for the same segment;
//!    rules compute it symmetrically (from the segment, or a symmetric combination of both
//!    sides), so both get the same `f32`. The tessellator's edge vertices depend only on the
//!    factor and the segment's endpoints, so they coincide.
//! 2. **Different levels** (at most one apart after [`crate::quadtree::balance`], but any
//!    difference works). The *coarse* patch's factor for the whole edge is
//!    [`EdgeRule::coarse_edge`] of the coarse node and the finer leaves across it; each finer
//!    patch finds the coarse neighbour, makes the *same call* (same node, same edge, same
//!    neighbour list, so the same `f32`) and divides by `2^(level difference)`. Rules return a
//!    power of two here, large enough that the quotient is a power of two `>= 2`. A coarse edge
//!    with `F = 2^k` segments has vertices at `n / 2^k`; a finer edge covering `[a, a + 2^-d]` of
//!    it with `2^(k-d)` equal segments has vertices at `a + m / 2^k`, with `a` a multiple of
//!    `2^-d`: the same set, exactly (dyadic, so exact in `f32`). Fractional-even spacing makes
//!    equal segments for even integers, and treats factors below 2 as 2, hence the `>= 2`.
//! 3. **No neighbour** (terrain border, culled region): [`EdgeRule::unshared`]; nothing to
//!    match.

use std::collections::HashMap;
use std::hash::{BuildHasher, RandomState};

use super::patch::{Edge, MAX_FACTOR, Selection};
use crate::quadtree::{Across, LeafSet, LeafTree, NodeId};

/// How a method assigns outer factors (see the module docs for the contract).
pub trait EdgeRule {
    /// Factor of edge `edge` of `a`, shared with the same-level leaf `b`. Must be symmetric:
    /// `same_level(a, e, b)` and `same_level(b, e.opposite(), a)` must be the same `f32`.
    fn same_level(&self, a: NodeId, edge: Edge, b: NodeId) -> f32;

    /// Factor of the whole edge `edge` of `coarse`, across which lie the finer leaves `finer`
    /// (non-empty). Must be a power of two, at least `2^(d + 1)` with `d` the largest level
    /// difference, and at most [`super::MAX_FACTOR`].
    fn coarse_edge(&self, coarse: NodeId, edge: Edge, finer: &[NodeId]) -> f32;

    /// Factor of an edge with no selected leaf across it (terrain border or culled region).
    fn unshared(&self, node: NodeId, edge: Edge) -> f32;
}

/// The smallest power of two `>= f`, within `[2, MAX_FACTOR]`.
pub(crate) fn pow2_up(f: f32) -> f32 {
    let f = f.clamp(2.0, MAX_FACTOR);
    (f.ceil() as u32).next_power_of_two() as f32
}

/// The edge rule of methods whose patches each wish for a factor (`want`; 2 for a node
/// without a wish): a same-level edge takes the larger wish; a coarse edge facing finer
/// patches the smallest power of two that is at least its own wish, every finer patch's wish
/// times `2^d` and `2^(d + 1)` (so each finer side gets a power of two of at least 2); an
/// unshared edge its own wish. Used by the DSS paper's Methods I and II and by the
/// out-of-core store's patches (terrain-stream).
///
/// The map's hasher `S` is std's by default; a caller that builds the map every frame may
/// pass a faster one (terrain-stream uses FxHash).
#[derive(Debug, Clone, Default)]
pub struct WishEdges<S = RandomState> {
    /// Each patch's wished factor.
    pub want: HashMap<NodeId, f32, S>,
}

impl<S: BuildHasher> WishEdges<S> {
    /// The factor `n` wishes for (2 without a wish).
    pub fn want(&self, n: NodeId) -> f32 {
        self.want.get(&n).copied().unwrap_or(2.0)
    }
}

impl<S: BuildHasher> EdgeRule for WishEdges<S> {
    fn same_level(&self, a: NodeId, _: Edge, b: NodeId) -> f32 {
        wish_same_level(self.want(a), self.want(b))
    }

    fn coarse_edge(&self, coarse: NodeId, _: Edge, finer: &[NodeId]) -> f32 {
        wish_coarse_edge(
            self.want(coarse),
            finer.iter().map(|&m| (self.want(m), m.level.saturating_sub(coarse.level))),
        )
    }

    fn unshared(&self, node: NodeId, _: Edge) -> f32 {
        self.want(node)
    }
}

/// [`WishEdges`]'s same-level edge: the larger of the two wishes.
fn wish_same_level(a: f32, b: f32) -> f32 {
    a.max(b)
}

/// [`WishEdges`]'s coarse edge: a coarse patch wishing `coarse` facing finer patches, each
/// `(wish, levels finer)`.
fn wish_coarse_edge(coarse: f32, finer: impl Iterator<Item = (f32, u8)>) -> f32 {
    let mut f = coarse;
    let mut dmax = 0u8;
    for (want, d) in finer {
        let d = d.min(5);
        dmax = dmax.max(d);
        f = f.max(want * (1u32 << d) as f32);
    }
    pow2_up(f).max((2u32 << dmax) as f32).min(MAX_FACTOR)
}

/// The outer factors of every leaf of `tree` (in [`LeafTree::leaves`] order) for `rule`: what
/// [`outer_factors`] gives for each leaf, from the tree's neighbours by index (no lookups) and
/// each coarse edge's factor computed once, its finer side dividing it (case 2 of the module
/// docs). What every method's selection uses (test
/// `the_batch_resolver_equals_the_per_node_one`).
pub fn outer_factors_all<R: EdgeRule + ?Sized>(tree: &LeafTree, rule: &R) -> Vec<[f32; 4]> {
    let leaves = tree.leaves();
    let mut finer = Vec::new();
    resolve_all(
        tree,
        |k, e, m| rule.same_level(leaves[k], e, leaves[m]),
        |k, e, across| {
            finer.clear();
            finer.extend(across.iter().map(|&m| leaves[m]));
            rule.coarse_edge(leaves[k], e, &finer)
        },
        |k, e| rule.unshared(leaves[k], e),
    )
}

/// [`outer_factors_all`] with [`WishEdges`]'s rule, the wishes beside the leaves (`want[k]` of
/// leaf `k` of `tree`; 2 where missing) instead of in a map.
pub fn wish_outer_factors(tree: &LeafTree, want: &[f32]) -> Vec<[f32; 4]> {
    let leaves = tree.leaves();
    let w = |k: usize| want.get(k).copied().unwrap_or(2.0);
    resolve_all(
        tree,
        |k, _, m| wish_same_level(w(k), w(m)),
        |k, _, finer| {
            let level = leaves[k].level;
            wish_coarse_edge(
                w(k),
                finer.iter().map(|&m| (w(m), leaves[m].level.saturating_sub(level))),
            )
        },
        |k, _| w(k),
    )
}

/// The three cases of the module docs for every edge of every leaf of `tree`: `same(k, e, m)`
/// for a same-level leaf `m`, `coarse(k, e, finer)` for the whole edge of `k` facing finer
/// leaves, `unshared(k, e)`; a leaf facing a coarser one takes that one's factor for the
/// shared edge divided by `2^(level difference)`.
pub(crate) fn resolve_all(
    tree: &LeafTree,
    mut same: impl FnMut(usize, Edge, usize) -> f32,
    mut coarse: impl FnMut(usize, Edge, &[usize]) -> f32,
    mut unshared: impl FnMut(usize, Edge) -> f32,
) -> Vec<[f32; 4]> {
    let leaves = tree.leaves();
    let mut out = vec![[0f32; 4]; leaves.len()];
    let mut finer = Vec::new();
    // Edges facing a coarser leaf: filled once every coarse edge is known.
    let mut later: Vec<(usize, Edge, usize)> = Vec::new();
    for (k, factors) in out.iter_mut().enumerate() {
        for e in Edge::ALL {
            factors[e as usize] = match tree.across(k, e.direction()) {
                Across::Nothing => unshared(k, e),
                Across::Leaf(m) if leaves[m].level >= leaves[k].level => same(k, e, m),
                Across::Leaf(m) => {
                    later.push((k, e, m));
                    0.0
                }
                Across::Finer(s) => {
                    finer.clear();
                    tree.facing(s, e.direction().opposite(), &mut finer);
                    // The split node's leaves may all lie away from the edge (a hole).
                    if finer.is_empty() { unshared(k, e) } else { coarse(k, e, &finer) }
                }
            };
        }
    }
    for (k, e, m) in later {
        let d = leaves[k].level - leaves[m].level;
        out[k][e as usize] = out[m][e.opposite() as usize] / (1u32 << d) as f32;
    }
    out
}

/// The outer factors of `node` (in [`Edge`] order) among the selected `leaves`, one node at a
/// time (by hash lookups; [`outer_factors_all`] gives every leaf's from one pass).
pub fn outer_factors<R: EdgeRule + ?Sized>(leaves: &LeafSet, node: NodeId, rule: &R) -> [f32; 4] {
    Edge::ALL.map(|e| {
        let across = leaves.neighbours(node, e.direction());
        match across.as_slice() {
            [] => rule.unshared(node, e),
            [m] if m.level == node.level => rule.same_level(node, e, *m),
            [m] if m.level < node.level => {
                // The coarse side's factor for its whole edge, computed exactly as it does.
                let back = e.opposite();
                let finer = leaves.neighbours(*m, back.direction());
                let f = rule.coarse_edge(*m, back, &finer);
                f / (1u32 << (node.level - m.level)) as f32
            }
            finer => rule.coarse_edge(node, e, finer),
        }
    })
}

/// A shared edge whose factors would leave a crack.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeMismatch {
    /// The finer patch (for equal levels, either: such mismatches are reported from both sides).
    pub node: NodeId,
    /// Its edge.
    pub edge: Edge,
    /// Its factor for that edge.
    pub factor: f32,
    /// The patch across the edge.
    pub other: NodeId,
    /// The other patch's factor for the shared edge.
    pub other_factor: f32,
}

/// Whether `f` is a power of two of at least 2 (an exact `f32`).
fn nests(f: f32) -> bool {
    f >= 2.0 && f.fract() == 0.0 && (f as u32).is_power_of_two()
}

/// Checks the crack-freedom invariant on every edge between two selected patches:
/// same-level neighbours have bit-identical factors; where levels differ, the finer factor
/// times `2^(difference)` equals the coarser factor and the finer factor is a power of two
/// `>= 2`. Returns every violation (empty: crack-free), in traversal order.
pub fn check_shared_edges(sel: &Selection) -> Vec<EdgeMismatch> {
    let leaves = LeafSet::new(sel.patches.iter().map(|p| p.node));
    let mut bad = Vec::new();
    for p in &sel.patches {
        for e in Edge::ALL {
            for m in leaves.neighbours(p.node, e.direction()) {
                if m.level > p.node.level {
                    continue; // checked from the finer side
                }
                let q = sel.patch(m).expect("neighbour is a selected patch");
                let (f, g) = (p.outer(e), q.outer(e.opposite()));
                let ok = if m.level == p.node.level {
                    f.to_bits() == g.to_bits()
                } else {
                    nests(f) && f * (1u32 << (p.node.level - m.level)) as f32 == g
                };
                if !ok {
                    bad.push(EdgeMismatch {
                        node: p.node,
                        edge: e,
                        factor: f,
                        other: m,
                        other_factor: g,
                    });
                }
            }
        }
    }
    bad
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lod::patch::Patch;

    /// A deliberately careless rule: same-level edges use the caller's own level, so they agree,
    /// but coarse edges return 2 (too small to halve).
    struct Careless;
    impl EdgeRule for Careless {
        fn same_level(&self, a: NodeId, _: Edge, _: NodeId) -> f32 {
            a.level as f32 + 1.0
        }
        fn coarse_edge(&self, _: NodeId, _: Edge, _: &[NodeId]) -> f32 {
            2.0
        }
        fn unshared(&self, _: NodeId, _: Edge) -> f32 {
            1.0
        }
    }

    fn selection(leaves: &[NodeId], rule: &dyn EdgeRule) -> Selection {
        let set = LeafSet::new(leaves.iter().copied());
        let patches = set
            .sorted()
            .into_iter()
            .map(|n| Patch { node: n, outer: outer_factors(&set, n, rule), inner: [1.0; 2] })
            .collect();
        Selection { patches, ..Default::default() }
    }

    #[test]
    fn the_batch_resolver_equals_the_per_node_one() {
        let mut unit = crate::test_support::unit_rng(0x9e37_79b9_7f4a_7c15);
        let (mut coarse, mut finer) = (0, 0);
        for seed in 0..200u64 {
            let max = 3 + (seed % 7) as u8;
            // Random leaves with culled holes, then balanced on even seeds.
            let side = 1u32 << max;
            let (raw, contains) = crate::test_support::random_tree(
                seed.wrapping_mul(0xbf58_476d_1ce4_e5b9),
                max,
                side,
                side,
            );
            let leaves =
                if seed % 2 == 0 { crate::quadtree::balance_with(&raw, contains) } else { raw };
            let mut rule = WishEdges::<RandomState>::default();
            let want: Vec<f32> = leaves
                .iter()
                .map(|_| [2.0, 4.0, 8.0, 16.0, 64.0][(unit() * 5.0) as usize])
                .collect();
            for (&n, &w) in leaves.iter().zip(&want) {
                rule.want.insert(n, w);
            }
            let set = LeafSet::new(leaves.iter().copied());
            let tree = LeafTree::new(&leaves);
            let all = outer_factors_all(&tree, &rule);
            let wished = wish_outer_factors(&tree, &want);
            let careless = outer_factors_all(&tree, &Careless);
            for (k, &n) in leaves.iter().enumerate() {
                let per_node = outer_factors(&set, n, &rule);
                assert_eq!(all[k], per_node, "seed {seed} {n:?}");
                assert_eq!(wished[k], per_node, "seed {seed} {n:?}");
                assert_eq!(careless[k], outer_factors(&set, n, &Careless), "seed {seed} {n:?}");
                for e in Edge::ALL {
                    match set.neighbours(n, e.direction()).as_slice() {
                        [m] if m.level < n.level => coarse += 1,
                        [m] if m.level == n.level => {}
                        [] => {}
                        _ => finer += 1,
                    }
                }
            }
        }
        assert!(coarse > 500 && finer > 500, "{coarse} {finer}");
    }

    #[test]
    fn checker_catches_unnestable_and_mismatched_factors() {
        // Root split once, the south-west child split again: level-2 leaves meet level-1 ones.
        let mut leaves: Vec<NodeId> = NodeId::new(1, 0, 0).children().to_vec();
        leaves.extend([NodeId::new(1, 1, 0), NodeId::new(1, 1, 1), NodeId::new(1, 0, 1)]);
        let sel = selection(&leaves, &Careless);
        let bad = check_shared_edges(&sel);
        // Coarse edges 2 halve to 1 on the four finer patches' outward edges: not nestable.
        assert_eq!(bad.len(), 4, "{bad:?}");
        assert!(bad.iter().all(|m| m.factor == 1.0 && m.other_factor == 2.0));
        // A hand-broken same-level edge is caught too.
        let mut sel2 = sel.clone();
        let k = sel2.patches.iter().position(|p| p.node == NodeId::new(1, 1, 0)).unwrap();
        sel2.patches[k].outer[Edge::North as usize] += 0.5;
        // Reported from both sides.
        assert_eq!(check_shared_edges(&sel2).len(), 6);
    }
}
