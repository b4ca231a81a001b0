//! Geomorphing in the vertex shader (Wagner 2003, "Terrain Geomorphing in the Vertex Shader"):
//! geo-mipmapped patches of `patch_cells + 1` squared vertices (17 x 17 and 5 levels by
//! default) whose levels and tween factors come from `terrain_core::lod::GeomipScene::select`,
//! drawn from a library of triangle lists (one per level and set of adapting borders), every
//! vertex morphed continuously between its true height and the coarser level's surface.
//!
//! - [`morph`]: the CPU reference of the morph (the shader repeats it), the triangle lists
//!   (union jack, adapting triangles), the drawn surface as a `SurfaceMesh` for measurement
//!   and crack checks, and the largest per-vertex height jump between two frames.
//! - [`materials`]: alpha maps of the materials and the per-patch skipping of passes.
//! - [`GeomorphRenderer`] (`renderer.rs`, `geomorph.wgsl`): the lightmap
//!   (`terrain_core::lightmap`) and the alpha maps as textures, an opaque base pass and
//!   alpha-blended material passes, camera-relative f32 positions like
//!   [`crate::TerrainRenderer`], magenta [`crate::BACKGROUND`], skirts for the crack test, and
//!   a compute entry point (`debug_morph`) that evaluates the vertex stage's morph for the tests.
//!
//! A compact selection (`terrain_core::lod::GeomipRuns`: runs of patches at the coarsest level
//! and single patches) is drawn without expanding it ([`GeomorphRenderer::render_runs`]): the
//! single patches as a list, the runs' patches by one instanced draw per pass of the coarsest
//! level's triangles over a small buffer of runs (the vertex stage finds a patch's run by a
//! binary search over the runs' patch counts): the expanded list's image, pixel for pixel.
//!
//! **Boundary:** the renderer draws the patches it is given; choosing levels and tween factors
//! is `terrain_core::lod::geomipmap`'s job.

pub mod materials;
pub mod morph;
mod renderer;

#[cfg(test)]
mod tests;

pub use materials::MaterialMaps;
pub use morph::{GpuMorphPatch, MeshLibrary, MorphGrid, build_surface, max_vertex_jump};
pub use renderer::{
    GeomorphConfig, GeomorphFrameStats, GeomorphOptions, GeomorphRenderer, MorphSource, SHADER,
    lod_step,
};
