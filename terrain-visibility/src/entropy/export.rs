//! The entropy mesh in the engine's other mesh types, and the maps as grey images.

use glam::DVec2;
use terrain_core::lod::SurfaceMesh;
use terrain_core::mesh::{TriMesh, vertex_normals};

use super::curvature::ScalarMap;
use super::quadtree::EntropyMesh;

impl EntropyMesh {
    /// As the benchmark's [`SurfaceMesh`]: world positions, grid coordinates, triangles.
    /// `plan_to_grid` maps plan coordinates to the grid the mesh is measured on (the identity
    /// for a DEM source; world to raster for scattered points).
    pub fn to_surface(&self, plan_to_grid: impl Fn(DVec2) -> DVec2) -> SurfaceMesh {
        SurfaceMesh {
            positions: self.positions.clone(),
            grid: self.plan.iter().map(|&p| plan_to_grid(p)).collect(),
            triangles: self.triangles.clone(),
        }
    }

    /// As an exportable [`TriMesh`] (vertex normals computed).
    pub fn to_trimesh(&self) -> TriMesh {
        TriMesh {
            normals: vertex_normals(&self.positions, &self.triangles),
            positions: self.positions.clone(),
            triangles: self.triangles.clone(),
        }
    }
}

/// An 8-bit grey image of `map` (row 0 of the image = north), values mapped linearly from
/// `[lo, hi]` to `1..=255`; samples without a value are 0 (black).
pub fn to_grey8(map: &ScalarMap, lo: f32, hi: f32) -> Vec<u8> {
    let (w, h) = (map.width(), map.height());
    let mut out = vec![0u8; w * h];
    for j in 0..h {
        for i in 0..w {
            if let Some(v) = map.get(i, j) {
                let t = if hi > lo { ((v - lo) / (hi - lo)).clamp(0.0, 1.0) } else { 0.0 };
                out[(h - 1 - j) * w + i] = 1 + (t * 254.0).round() as u8;
            }
        }
    }
    out
}
