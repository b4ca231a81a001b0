//! The quadtree shared by every LOD method: node addressing ([`NodeId`]), the per-node
//! min/max height pyramid ([`Quadtree`]), the single traversal ([`traverse`]) with pluggable
//! split and cull policies, the balanced post-pass ([`balance`]), and the papers' node
//! formulas: the PVPS paper's centre and span (Eq. 6, 7, 9, 10, in [`pvps`]) and the DSS
//! paper's M-block ids and neighbour-strip ids (Table 1, in [`dss`]).
//!
//! Conventions: level 0 is the root covering the whole grid rounded up to `2^L` cells;
//! `i` counts east, `j` north, row 0 is south (the heightmap's convention).

pub mod dss;
mod leaf_tree;
mod node;
pub mod pvps;
mod traverse;
mod tree;

pub use dss::{DSS_ROOT_ID, dss_block_id, dss_child_neighbours, dss_neighbours, dss_node};
pub use leaf_tree::{Across, LeafTree, SplitNode};
pub use node::{Direction, NodeId, Quadrant};
pub use pvps::{pvps_node_center, pvps_node_center_as_printed, pvps_patch_corners, pvps_span};
pub use traverse::{
    AlwaysSplit, BoundingCircleCull, Cull, CullPolicy, FrustumCull, LeafSet, NoCull, NodeSource,
    NodeTree, SplitPolicy, SplitToLevel, Visit, balance, balance_with, is_balanced, select,
    traverse, walk,
};
pub use tree::{GridRect, NodeInfo, Quadtree, TreeShape};
