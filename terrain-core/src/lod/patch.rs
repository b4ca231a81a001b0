//! What a LOD method hands to the GPU: patches with tessellation factors, and selection stats.

use std::time::Duration;

use crate::quadtree::{Direction, NodeId};

/// Smallest factor a method emits. (The fractional-even tessellator treats anything below 2 as
/// 2; the methods keep every factor that must nest across levels at 2 or more.)
pub const MIN_FACTOR: f32 = 1.0;

/// Largest factor a method emits (the hardware limit).
pub const MAX_FACTOR: f32 = 64.0;

/// Clamps a factor into [`MIN_FACTOR`]`..=`[`MAX_FACTOR`]; NaN gives [`MIN_FACTOR`].
pub fn clamp_factor(f: f64) -> f32 {
    if f.is_nan() { MIN_FACTOR } else { (f as f32).clamp(MIN_FACTOR, MAX_FACTOR) }
}

/// The four edges of a patch in [`Patch::outer`] order: anti-clockwise from the south, like the
/// DSS paper's `Idsneighbour` (its Table 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Edge {
    /// `v = 0`.
    South = 0,
    /// `u = 1`.
    East = 1,
    /// `v = 1`.
    North = 2,
    /// `u = 0`.
    West = 3,
}

impl Edge {
    /// All four in [`Patch::outer`] order.
    pub const ALL: [Edge; 4] = [Edge::South, Edge::East, Edge::North, Edge::West];

    /// The compass direction of the neighbour across this edge.
    pub fn direction(self) -> Direction {
        match self {
            Edge::South => Direction::South,
            Edge::East => Direction::East,
            Edge::North => Direction::North,
            Edge::West => Direction::West,
        }
    }

    /// The edge facing direction `d`.
    pub fn from_direction(d: Direction) -> Edge {
        match d {
            Direction::South => Edge::South,
            Direction::East => Edge::East,
            Direction::North => Edge::North,
            Direction::West => Edge::West,
        }
    }

    /// The same edge as seen from the neighbour across it.
    pub fn opposite(self) -> Edge {
        Edge::from_direction(self.direction().opposite())
    }
}

/// One quad patch to tessellate: a quadtree node and its factors.
///
/// **Domain.** `(u, v)` in `[0, 1]^2`, `u` east and `v` north, mapped onto the node's
/// *unclipped* square of `root_cells >> level` cells and clamped to the grid afterwards (see
/// [`crate::lod::surface::patch_grid_point`]).
///
/// **Factor order.** `outer` is `[south (v = 0), east (u = 1), north (v = 1), west (u = 0)]`
/// ([`Edge`] order). terrain-gpu's `PatchFactors::outer` uses Vulkan's
/// `[u = 0, v = 0, u = 1, v = 1]`, i.e. `[west, south, east, north]`: map with
/// `[outer[3], outer[0], outer[1], outer[2]]`. `inner[0]` subdivides along `u` (east-west),
/// `inner[1]` along `v` (north-south), the same as terrain-gpu.
///
/// Factors are finite and in [`MIN_FACTOR`]`..=`[`MAX_FACTOR`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Patch {
    /// The quadtree node the patch covers.
    pub node: NodeId,
    /// Outer factors: south, east, north, west.
    pub outer: [f32; 4],
    /// Inner factors: along `u` (east), along `v` (north).
    pub inner: [f32; 2],
}

impl Patch {
    /// The outer factor of `edge`.
    pub fn outer(&self, edge: Edge) -> f32 {
        self.outer[edge as usize]
    }
}

/// Counts and timing of one selection.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SelectionStats {
    /// Nodes the traversal classified (culled, split or selected).
    pub visited: usize,
    /// Nodes rejected by frustum culling (their subtrees are not visited).
    pub culled: usize,
    /// Nodes split by the method's split test.
    pub split: usize,
    /// Leaves selected by the traversal, before balancing.
    pub traversal_leaves: usize,
    /// Leaves the balancing pass added (net: patches minus traversal leaves).
    pub balance_added: usize,
    /// Patches in the selection.
    pub patches: usize,
    /// Finest level among the patches (0 when there are none).
    pub max_level: u8,
    /// CPU time of the whole selection (traversal, balance, factors).
    pub cpu_time: Duration,
}

/// The patches to draw this frame, in traversal order ([`NodeId::dfs_key`]), and stats.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Selection {
    /// Patches, depth-first in child order (deterministic).
    pub patches: Vec<Patch>,
    /// What the selection cost and did.
    pub stats: SelectionStats,
}

impl Selection {
    /// The patch of `node`, if selected (binary search on the traversal order).
    pub fn patch(&self, node: NodeId) -> Option<&Patch> {
        self.patches
            .binary_search_by_key(&node.dfs_key(), |p| p.node.dfs_key())
            .ok()
            .map(|k| &self.patches[k])
    }

    /// Every factor of every patch is finite and within [`MIN_FACTOR`]`..=`[`MAX_FACTOR`].
    pub fn factors_in_range(&self) -> bool {
        self.patches.iter().all(|p| {
            p.outer
                .iter()
                .chain(&p.inner)
                .all(|f| f.is_finite() && (MIN_FACTOR..=MAX_FACTOR).contains(f))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edge_order_and_clamp() {
        assert_eq!(Edge::ALL.map(|e| e as usize), [0, 1, 2, 3]);
        for e in Edge::ALL {
            assert_eq!(Edge::from_direction(e.direction()), e);
            assert_eq!(e.opposite().opposite(), e);
        }
        assert_eq!(Edge::East.opposite(), Edge::West);
        assert_eq!(clamp_factor(f64::NAN), 1.0);
        assert_eq!(clamp_factor(0.2), 1.0);
        assert_eq!(clamp_factor(1e9), 64.0);
        assert_eq!(clamp_factor(f64::INFINITY), 64.0);
        assert_eq!(clamp_factor(7.5), 7.5);
    }
}
