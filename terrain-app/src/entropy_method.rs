//! The entropy paper's (Chen 2018) view-dependent quadtree as a benchmark method (`entropy`):
//! the full tree is built once per terrain with `E0 = 0` (so every node keeps its `maxE`), and
//! each frame cuts it with Eq. 5, `E = E0 + c1 r + c2 d`, around the visual centre `O` of
//! Eq. 4, removes the cracks (three-pass update) and triangulates the tiles.
//!
//! The result is a triangle mesh, not tessellated patches: it is measured on the CPU (its
//! [`SurfaceMesh`] through `terrain_core::measure`, with a root-node selection so every sample
//! counts as covered) and drawn by the benchmark as the renderer's extra triangles
//! (`bench::entropy_extra`).

use std::time::Instant;

use terrain_core::Heightmap;
use terrain_core::geometry::Camera;
use terrain_core::lod::{Patch, Selection, SelectionStats, SurfaceMesh};
use terrain_core::quadtree::NodeId;
use terrain_visibility::entropy::source::{build_from_grid_with_map, entropy_map};
use terrain_visibility::entropy::{EntropyQuadtree, TreeConfig, ViewThreshold};

/// Settings of the `entropy` method.
#[derive(Debug, Clone, PartialEq)]
pub struct EntropyMethodConfig {
    /// The base threshold `E0` of Eq. 5 (percent of the largest entropy). Default 50.
    pub e0: f64,
    /// Maximum depth `D` (capped at the grid's depth). Default 9: 512 tiles per side, the
    /// finest the benchmark keeps in memory for every frame's cut.
    pub max_depth: u32,
    /// `c1` of Eq. 5 in percent per terrain diagonal (converted to per metre): a tile one
    /// diagonal from the visual centre needs this much more entropy to split. Default 100.
    pub c1_per_diagonal: f64,
    /// `c2` of Eq. 5 in percent per terrain diagonal of eye-to-centre distance. Default 50.
    pub c2_per_diagonal: f64,
}

impl Default for EntropyMethodConfig {
    fn default() -> Self {
        Self { e0: 50.0, max_depth: 9, c1_per_diagonal: 100.0, c2_per_diagonal: 50.0 }
    }
}

/// The full tree of a terrain (E0 = 0), built once.
#[derive(Debug)]
pub struct EntropyScene {
    tree: EntropyQuadtree,
    diagonal_m: f64,
    mean_height: f64,
}

/// One frame of the method.
#[derive(Debug)]
pub struct EntropyFrame {
    /// The triangulated, crack-free cut.
    pub surface: SurfaceMesh,
    /// Tiles in the cut.
    pub tiles: usize,
    /// Time to cut the tree (Eq. 4-5), ms.
    pub cut_ms: f64,
    /// Time of the three-pass update, ms.
    pub crack_ms: f64,
    /// Time to triangulate the tiles, ms.
    pub triangulate_ms: f64,
}

impl EntropyScene {
    /// Builds the full tree of `hm` to `config.max_depth`.
    pub fn new(hm: &Heightmap, config: &EntropyMethodConfig) -> Self {
        let cfg = TreeConfig { e0: 0.0, max_depth: config.max_depth, ..TreeConfig::default() };
        let emap = entropy_map(hm, &cfg);
        let tree = build_from_grid_with_map(hm, &emap, &cfg);
        let diagonal_m = hm.extent_m().length().max(1.0);
        let mean_height = 0.5 * (f64::from(hm.min()) + f64::from(hm.max()));
        Self { tree, diagonal_m, mean_height }
    }

    /// The crack-free mesh the method draws from `camera` with `config`.
    pub fn frame(&self, camera: &Camera, config: &EntropyMethodConfig) -> EntropyFrame {
        let t = Instant::now();
        let eye = camera.position;
        let dir = camera.forward();
        // Eq. 4 against the horizontal plane at the terrain's mid height.
        let centre = ViewThreshold::visual_centre(eye, dir, self.mean_height);
        let zoom = fov_zoom(camera.fov_y);
        let view = ViewThreshold {
            e0: config.e0,
            c1: zoom * config.c1_per_diagonal / self.diagonal_m,
            c2: zoom * config.c2_per_diagonal / self.diagonal_m,
            centre,
            eye,
        };
        let mut cut = self.tree.schedule(&view);
        let cut_ms = t.elapsed().as_secs_f64() * 1e3;
        let crack_ms = cut.eliminate_cracks() * 1e3;
        let t = Instant::now();
        let mesh = cut.mesh();
        let surface = mesh.to_surface(|p| p);
        let triangulate_ms = t.elapsed().as_secs_f64() * 1e3;
        EntropyFrame { surface, tiles: cut.tiles(), cut_ms, crack_ms, triangulate_ms }
    }
}

/// The field of view in Eq. 5 (issue 17: the paper's `E = E0 + c1 r + c2 d` has none): the
/// distances `r` and `d` count as `tan(fov / 2) / tan(30 deg)` times their length, so a view
/// of vertical field `fov` refines a tile as the reference 60 degree view refines one whose
/// projection is as large on screen (the standard zoom compensation of distance-based LOD:
/// projected size goes as `1 / (d tan(fov / 2))`). 1 at 60 degrees, where `c1` and `c2` were
/// chosen; narrower views (zoomed in) refine further out.
fn fov_zoom(fov_y: f64) -> f64 {
    let z = (0.5 * fov_y).tan() / 30f64.to_radians().tan();
    if z.is_finite() && z > 0.0 { z } else { 1.0 }
}

/// A selection that covers the whole terrain (the root node), for the measurement's coverage.
pub fn whole_terrain_selection(tiles: usize, cpu_ms: f64) -> Selection {
    let f = 1.0;
    Selection {
        patches: vec![Patch { node: NodeId::ROOT, outer: [f; 4], inner: [f; 2] }],
        stats: SelectionStats {
            traversal_leaves: tiles,
            patches: tiles,
            cpu_time: std::time::Duration::from_secs_f64(cpu_ms / 1e3),
            ..SelectionStats::default()
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use terrain_core::synth::FractalConfig;
    use terrain_gpu::render::default_camera;

    /// Eq. 5 with the field of view: the 60 degree view cuts as before (zoom 1), a narrower
    /// one keeps more tiles (the same terrain looks larger), a wider one fewer.
    #[test]
    fn narrower_views_refine_more() {
        assert!((fov_zoom(60f64.to_radians()) - 1.0).abs() < 1e-12);
        let hm = FractalConfig::with_size(257, 257, 10.0).to_heightmap().unwrap();
        let config = EntropyMethodConfig { max_depth: 6, e0: 30.0, ..Default::default() };
        let scene = EntropyScene::new(&hm, &config);
        let base = default_camera(&hm, 320, 180, 60.0);
        let tiles = |deg: f64| scene.frame(&base.with_fov_y_deg(deg), &config).tiles;
        let (narrow, normal, wide) = (tiles(30.0), tiles(60.0), tiles(90.0));
        println!("tiles at 30 / 60 / 90 degrees: {narrow} / {normal} / {wide}");
        assert!(narrow > normal && normal > wide, "{narrow} {normal} {wide}");
        assert_eq!(fov_zoom(f64::NAN), 1.0);
    }
}
