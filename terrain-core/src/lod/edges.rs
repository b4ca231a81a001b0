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
use crate::quadtree::{LeafSet, NodeId};

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
        self.want(a).max(self.want(b))
    }

    fn coarse_edge(&self, coarse: NodeId, _: Edge, finer: &[NodeId]) -> f32 {
        let mut f = self.want(coarse);
        let mut dmax = 0u8;
        for &m in finer {
            let d = m.level.saturating_sub(coarse.level).min(5);
            dmax = dmax.max(d);
            f = f.max(self.want(m) * (1u32 << d) as f32);
        }
        pow2_up(f).max((2u32 << dmax) as f32).min(MAX_FACTOR)
    }

    fn unshared(&self, node: NodeId, _: Edge) -> f32 {
        self.want(node)
    }
}

/// The outer factors of `node` (in [`Edge`] order) among the selected `leaves`.
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
