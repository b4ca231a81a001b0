//! Local curvature entropy and the entropy quadtree (the entropy paper, Chen 2018).
//!
//! * [`curvature`]: profile curvature (Zevenbergen & Thorne 1987, the ArcGIS formula) with
//!   defined borders and voids.
//! * [`local`]: local Shannon entropy of the classified curvature over a window (Eq. 1-3).
//! * [`compare`]: the paper's claim that entropy is smoother and less sensitive than
//!   curvature (Fig. 3, 18), as numbers.
//! * [`quadtree`]: Algorithm 1, the edge-based quadtree, the three-pass crack elimination,
//!   per-tile constrained Delaunay triangulation and the view-dependent cut (Eq. 4-5).
//! * [`source`]: building the tree from a grid DEM or from scattered points (IDW or natural
//!   neighbour), and its settings.
//! * [`export`]: the mesh as the benchmark's `SurfaceMesh` and the exporters' `TriMesh`, and
//!   the maps as 8-bit images.

pub mod compare;
pub mod curvature;
pub mod export;
pub mod local;
pub mod quadtree;
pub mod source;

pub use curvature::{ScalarMap, profile_curvature};
pub use local::{EntropyConfig, local_entropy};
pub use quadtree::{EntropyMesh, EntropyQuadtree, FocusThreshold, MAX_DEPTH, ViewThreshold};
pub use source::{
    EntropyError, EntropyScale, Interpolation, ScatteredPoints, TreeConfig, build_from_grid,
    build_from_points,
};
