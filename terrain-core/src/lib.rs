//! The bottom layer of the terrain engine: heightmaps and their georeference, DEM readers,
//! synthetic terrain, geometry (boxes, cameras, frusta), the quadtree shared by every LOD
//! method, and the error metrics of the five papers.
//!
//! **Architecture invariant:** this crate depends on no crate of ours and knows nothing about
//! wgpu, threads or files on disk other than the DEM readers in [`dem`].
//!
//! World frame: right-handed, x east, y north, z up, metres, f64 positions. Grids are stored
//! south row first, so grid -> world is `origin + (i * dx, j * dy)` (see [`heightmap`]).

#![deny(missing_docs)]

pub mod dem;
pub mod error;
pub mod geometry;
pub mod georef;
pub mod heightmap;
pub mod lod;
pub mod mesh;
pub mod metrics;
pub mod quadtree;
pub mod synth;

pub use error::{DemError, DemErrorKind};
pub use georef::{Crs, Georef};
pub use heightmap::{Heightmap, HeightmapError, VoidMask};
