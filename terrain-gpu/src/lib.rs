//! The wgpu renderer: device selection (Vulkan first, then GL; software adapters such as
//! lavapipe and llvmpipe included), emulated quad-domain tessellation with fractional-even
//! spacing (WGSL has no tessellation stages), geomorphing in the vertex stage and the DSS
//! paper's stitching strips.
//!
//! **Boundary:** depends on `terrain-core` only; with `terrain-app`, the only crate that may
//! depend on wgpu. Every GPU computation has one CPU reference here, and tests compare the
//! GPU's read-back output with it. Shaders are `.wgsl` files beside the module that drives them.
//!
//! The principal types are [`GpuContext`] (an adapter, device and queue, with the feature
//! flags the renderer branches on) and, in [`tess`], the CPU reference tessellator
//! [`tess::tessellate`] and its compute-shader twin [`tess::GpuTessellator`], and
//! [`TerrainRenderer`], which draws a heightmap from a list of [`DrawPatch`]es (the surface it
//! draws has its CPU reference in [`surface`]).
//!
//! ```
//! use terrain_gpu::tess::{PatchFactors, tessellate};
//!
//! let mesh = tessellate(&PatchFactors { inner: [4.0, 4.0], outer: [4.0, 2.0, 4.0, 3.5] });
//! assert!(mesh.points.iter().all(|p| (0.0..=1.0).contains(&p[0]) && (0.0..=1.0).contains(&p[1])));
//! ```
pub mod device;
pub mod geomorph;
pub mod paged;
pub mod render;
pub mod strips;
pub mod surface;
pub mod target;
pub mod tess;
#[cfg(test)]
mod test_support;

pub use device::{BackendChoice, DeviceConfig, GpuContext, GpuError, GpuFeatures};
pub use paged::{HeightGrid, Page, PageError, PageLayout, PagedHeights};
pub use render::{
    BACKGROUND, DrawPatch, ExtraTriangles, FrameStats, RenderConfig, RenderError, RenderOptions,
    TerrainRenderer, uniform_patches,
};
pub use target::{OffscreenTarget, RgbaImage};

/// Every shader module made of several `.wgsl` files, as the renderers create it (a name and
/// the concatenated source): the tessellation renderer's and the geomorph renderer's, each
/// with the one paged lookup (`paged_lookup.wgsl`). `tests/shaders.rs` validates them with
/// naga.
pub const SHADER_MODULES: &[(&str, &str)] =
    &[("render/terrain.wgsl", render::SHADER), ("geomorph/geomorph.wgsl", geomorph::SHADER)];
