//! View-independent triangle meshes of a heightmap with a guaranteed vertical error.
//!
//! Two builders approximate the grid by a triangle mesh whose vertices are grid samples and
//! whose vertical error at every non-void sample is at most a bound (`max_error`, metres):
//!
//! - [`rtin`]: a right-triangulated irregular network (Evans, Kirkpatrick & Townsend 2001,
//!   "Right-triangulated irregular networks"; the layout of mapbox/martini), with the *true*
//!   maximum error of each triangle made monotone, so the mesh is crack-free and the bound
//!   holds. Fast; more triangles.
//! - [`delaunay`]: greedy insertion into a Delaunay triangulation (Garland & Heckbert 1995,
//!   "Fast polygonal approximation of terrains and height fields", as in hmm / Delatin) into
//!   a purpose-built half-edge triangulation. Fewest triangles.
//!
//! [`verify`] measures a mesh against every non-void sample (max and RMS error) and refuses a
//! mesh that breaks the bound.
//!
//! ```
//! use terrain_core::mesh::{Algorithm, MeshConfig, build, verify};
//! use terrain_core::synth::HardCase;
//!
//! let hm = HardCase::Spike.build();
//! let config = MeshConfig { max_error: 1.0, algorithm: Algorithm::Delaunay };
//! let mesh = build(&hm, &config).unwrap();
//! let stats = verify::check(&hm, &mesh, config.max_error).unwrap();
//! assert!(stats.max_error <= 1.0);
//! assert!(mesh.triangles.len() < 20);
//! ```

pub mod delaunay;
pub(crate) mod raster;
pub mod rtin;
pub mod verify;

use glam::{DVec3, Vec3};

use crate::heightmap::Heightmap;

/// An indexed triangle mesh in the world frame (x east, y north, z up, metres, f64).
///
/// Triangles are counter-clockwise seen from above (+z). `normals` has one unit normal per
/// vertex (the area-weighted mean of its triangles' normals, pointing up).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions, world frame, metres.
    pub positions: Vec<DVec3>,
    /// Unit vertex normals (z > 0 for a height field).
    pub normals: Vec<Vec3>,
    /// Vertex indices, counter-clockwise from above.
    pub triangles: Vec<[u32; 3]>,
}

impl TriMesh {
    /// Builds a mesh from grid vertices `(i, j)` and counter-clockwise triangles over them:
    /// positions are the samples' world positions and heights; normals are computed.
    pub(crate) fn from_grid(
        hm: &Heightmap,
        vertices: &[[u32; 2]],
        triangles: Vec<[u32; 3]>,
    ) -> Self {
        let positions: Vec<DVec3> = vertices
            .iter()
            .map(|&[i, j]| {
                let xy = hm.grid_to_world(f64::from(i), f64::from(j));
                xy.extend(f64::from(hm.get(i as usize, j as usize)))
            })
            .collect();
        let normals = vertex_normals(&positions, &triangles);
        Self { positions, normals, triangles }
    }
}

/// Area-weighted vertex normals. Differences of positions are taken before any product, so
/// large projected coordinates do not cost precision.
pub fn vertex_normals(positions: &[DVec3], triangles: &[[u32; 3]]) -> Vec<Vec3> {
    let mut acc = vec![DVec3::ZERO; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|k| positions[k as usize]);
        // |(b - a) x (c - a)| is twice the area: the sum weights each face by its area.
        let n = (b - a).cross(c - a);
        for &k in t {
            acc[k as usize] += n;
        }
    }
    acc.into_iter().map(|n| n.try_normalize().unwrap_or(DVec3::Z).as_vec3()).collect()
}

/// Which builder to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Algorithm {
    /// Right-triangulated irregular network ([`rtin`]): fast, regular, more triangles.
    Rtin,
    /// Greedy Delaunay insertion ([`delaunay`]): fewest triangles.
    #[default]
    Delaunay,
}

/// What to build.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshConfig {
    /// The largest vertical error allowed at any non-void sample, metres (`>= 0`;
    /// `f64::INFINITY` gives the coarsest mesh: two triangles for a rectangle).
    pub max_error: f64,
    /// The builder.
    pub algorithm: Algorithm,
}

/// Why a mesh could not be built (caller misuse: the builders themselves cannot fail).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MeshError {
    /// `max_error` is negative or NaN.
    #[error("the maximum error must be a non-negative number of metres, got {0}")]
    InvalidMaxError(f64),
    /// The grid has no cell (width or height below 2).
    #[error("a mesh needs at least 2 x 2 samples, the grid has {width} x {height}")]
    GridTooSmall {
        /// Columns.
        width: usize,
        /// Rows.
        height: usize,
    },
    /// The grid is too large for `u32` vertex indices.
    #[error("the grid ({width} x {height} samples) is too large for u32 vertex indices")]
    GridTooLarge {
        /// Columns.
        width: usize,
        /// Rows.
        height: usize,
    },
}

/// Checks the arguments shared by the builders.
pub fn validate(hm: &Heightmap, max_error: f64) -> Result<(), MeshError> {
    if max_error.is_nan() || max_error < 0.0 {
        return Err(MeshError::InvalidMaxError(max_error));
    }
    let (width, height) = (hm.width(), hm.height());
    if width < 2 || height < 2 {
        return Err(MeshError::GridTooSmall { width, height });
    }
    if (width as u64) * (height as u64) > u64::from(u32::MAX) {
        return Err(MeshError::GridTooLarge { width, height });
    }
    Ok(())
}

/// Builds a mesh of `hm` within `config.max_error` of every non-void sample.
///
/// The bound holds by construction; [`verify::check`] measures it independently of the
/// builder's bookkeeping (exporters call it before writing).
pub fn build(hm: &Heightmap, config: &MeshConfig) -> Result<TriMesh, MeshError> {
    validate(hm, config.max_error)?;
    Ok(match config.algorithm {
        Algorithm::Rtin => rtin::build(hm, config.max_error),
        Algorithm::Delaunay => delaunay::build(hm, config.max_error),
    })
}

/// The vertices of a mesh built on `hm`'s grid as its samples `[i, j]` (rounded): the tests'
/// integer view of a mesh, for exact predicates on its output.
#[cfg(test)]
pub(crate) fn grid_vertices(hm: &Heightmap, mesh: &TriMesh) -> Vec<[i64; 2]> {
    mesh.positions
        .iter()
        .map(|p| {
            let q = hm.world_to_grid(p.truncate()).round();
            [q.x as i64, q.y as i64]
        })
        .collect()
}
