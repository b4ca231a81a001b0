//! The bottom layer of the terrain engine: heightmaps and their georeference, DEM readers,
//! synthetic terrain, geometry (boxes, cameras, frusta), the quadtree shared by every LOD
//! method, the error metrics of the five papers, the LOD methods' patch selection, flights,
//! and the exact measurement of a drawn surface's error.
//!
//! **Architecture invariant:** this crate depends on no crate of ours and knows nothing about
//! wgpu or threads; it reads files only in the DEM readers ([`dem`]), the scattered-points
//! reader ([`points`]) and the flight loader ([`flight`]).
//!
//! World frame: right-handed, x east, y north, z up, metres, f64 positions. Grids are stored
//! south row first, so grid -> world is `origin + (i * dx, j * dy)` (see [`heightmap`]).

#![deny(missing_docs)]

pub mod bytes;
pub mod checksum;
pub mod dem;
pub mod error;
pub mod flight;
pub mod geometry;
pub mod georef;
pub mod hash;
pub mod heightmap;
pub mod lightmap;
pub mod lod;
pub mod lonlat;
pub mod measure;
pub mod mesh;
pub mod metrics;
pub mod points;
pub mod quadtree;
pub mod synth;
#[cfg(test)]
mod test_support;
pub mod tin;

pub use error::{DemError, DemErrorKind};
pub use georef::{Crs, Georef};
pub use heightmap::{Heightmap, HeightmapError, VoidMask, bilinear_clamped};
