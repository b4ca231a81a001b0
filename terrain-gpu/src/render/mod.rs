//! Drawing a heightmap: [`TerrainRenderer`] tessellates a list of [`DrawPatch`]es with the
//! compute tessellator ([`crate::tess::GpuTessellator`]) and draws them with one indexed
//! indirect draw; the vertex stage (`terrain.wgsl`) maps each domain point into its patch's
//! rect of the heightmap ([`crate::surface`] is the CPU reference) and the fragment stage
//! shades it.
//!
//! **Boundary:** the renderer draws whatever patches it is given; choosing them (level of
//! detail) is the LOD methods' job. Until those land, [`uniform_patches`] covers the grid with
//! equal patches at one factor.
//!
//! Conventions: a patch's rect is `[x0, y0, x1, y1]` in grid samples, inclusive, row 0 south.
//! Its domain `u` runs east (`x0` to `x1`), `v` north (`y0` to `y1`), and its factors follow
//! [`PatchFactors`]: `outer = [west (u = 0), south (v = 0), east (u = 1), north (v = 1)]`.
//! Two patches that share an edge and agree on its factor draw it without cracks.
//!
//! Normals: central differences of the heightmap, computed per fragment from the height
//! texture and interpolated between samples ([`crate::surface::normal_at`]), so shading does
//! not depend on the tessellation and no second texture is needed.
//!
//! # Targets: offscreen, or a window's surface
//!
//! [`TerrainRenderer::render`] draws into the renderer's own RGBA8 + depth target, which
//! [`TerrainRenderer::read_image`] reads back (tests, PNGs, benchmarks).
//! [`TerrainRenderer::render_to_view`] runs the same frame (same passes, same encoding) into a
//! colour view the caller owns, with the renderer's depth buffer; this crate adds no window
//! crate, and a windowed viewer uses it like this:
//!
//! 1. Create the `wgpu::Surface` from the window with the [`GpuContext`](crate::GpuContext)'s
//!    `instance`, check `ctx.adapter.is_surface_supported(&surface)`, and build the renderer
//!    with [`RenderConfig::width`] and [`RenderConfig::height`] equal to the window's size.
//!    (`GpuContext` creates its instance without a display handle, which is enough for
//!    Vulkan; presenting through GL/EGL needs an instance given the window's display.)
//! 2. Configure the surface at the renderer's size ([`TerrainRenderer::size`]), with a format
//!    from `surface.get_capabilities(&adapter).formats` (usually `Bgra8UnormSrgb` or
//!    `Bgra8Unorm`) and `usage: RENDER_ATTACHMENT`.
//! 3. Per frame: `let frame = surface.get_current_texture()?`, then
//!    `let view = frame.texture.create_view(&Default::default())`, then
//!    `renderer.render_to_view(&camera, &patches, &options, &view, config.format)?`, then
//!    `frame.present()`.
//!
//! The pipelines of the surface's format are built on the first frame and kept. The image is
//! the same as the offscreen one: for an sRGB format the fragment stage decodes its (already
//! sRGB-encoded) colours and the clear colour is decoded likewise, so the store's encoding
//! gives back the offscreen bytes to within one level. A renderer has one size: after a window
//! resize, build a renderer of the new size (or keep drawing at the old size into a surface
//! configured at it).

pub mod crack;
mod framing;
mod renderer;

#[cfg(test)]
mod tests;

pub use framing::{ClipBoxes, clip_range, default_camera, near_far};
pub(crate) use renderer::SHADER;
pub use renderer::{FrameStats, RenderError, SurfaceReadBack, TerrainRenderer};

use terrain_core::Heightmap;

use crate::target::RgbaImage;
use crate::tess::PatchFactors;

/// The background colour (cleared to where no terrain is drawn): pure magenta, which the
/// terrain shader never outputs (it keeps green above zero), so a pixel of this colour is a
/// pixel no triangle covered.
pub const BACKGROUND: [u8; 4] = [255, 0, 255, 255];

/// Triangles drawn after the patches' tessellation, in the same pass and pipeline (one extra
/// indexed draw): each vertex is a domain point of one of the frame's patches (`patch_index`
/// into the patch list, `pad` 0), mapped and displaced by the vertex stage exactly like the
/// tessellator's points, so an extra vertex on a patch's edge coincides bit for bit with the
/// tessellated vertex there. The DSS paper's stitching strips use it (`crate::strips`).
/// Drawn without the barycentric wireframe.
///
/// A mesh that carries its own heights (the `tin` method's tiles) gives them in `heights`, one
/// per point: its vertices are then placed at those heights, at the same `x`, `y` as a
/// sampled point's ([`crate::surface::position_at_height`], the shader's `vs_explicit`), so
/// its geometry does not depend on what the heightmap's pages hold; they shade it only.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct ExtraTriangles {
    /// Vertices.
    pub points: Vec<crate::tess::GpuDomainPoint>,
    /// Triangle list into `points`.
    pub indices: Vec<u32>,
    /// Empty: every vertex's height is sampled at its point, like the tessellator's. Else one
    /// height per point, metres: the vertex is drawn at it.
    pub heights: Vec<f32>,
}

/// One patch to draw: a rect of grid samples and its tessellation factors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DrawPatch {
    /// `[x0, y0, x1, y1]`: grid samples, inclusive, row 0 = south; `x0 < x1`, `y0 < y1`.
    pub rect: [u32; 4],
    /// Tessellation factors (Vulkan's edge order: west, south, east, north).
    pub factors: PatchFactors,
}

/// Covers the heightmap with patches of `patch_cells` x `patch_cells` cells (the last row and
/// column of patches are narrower where the grid does not divide evenly), every factor equal
/// to `factor`. Patches are ordered south to north, then west to east within a row.
///
/// A heightmap of one row or one column has no cell: the result is empty.
pub fn uniform_patches(hm: &Heightmap, patch_cells: u32, factor: f32) -> Vec<DrawPatch> {
    patches_with(hm, patch_cells, |_, _| PatchFactors::uniform(factor))
}

/// Like [`uniform_patches`], with every factor equal to the patch's number of cells along its
/// axis: one vertex per DEM sample wherever the patch's cell counts are even (fractional-even
/// spacing puts odd factors between samples), which holds when `patch_cells` is even and
/// divides both `width - 1` and `height - 1`. Factors are clamped to 64 by the tessellator,
/// so `patch_cells` above 64 is coarser than the DEM.
pub fn full_resolution_patches(hm: &Heightmap, patch_cells: u32) -> Vec<DrawPatch> {
    patches_with(hm, patch_cells, |w, h| {
        let (w, h) = (w as f32, h as f32);
        PatchFactors { inner: [w, h], outer: [h, w, h, w] }
    })
}

/// The patch rects of [`uniform_patches`], with factors from `factors(cells_x, cells_y)`.
pub fn patches_with(
    hm: &Heightmap,
    patch_cells: u32,
    mut factors: impl FnMut(u32, u32) -> PatchFactors,
) -> Vec<DrawPatch> {
    let cells = patch_cells.max(1);
    let (wmax, hmax) = (hm.width() as u32 - 1, hm.height() as u32 - 1);
    let mut out = Vec::new();
    let mut y0 = 0;
    while y0 < hmax {
        let y1 = (y0 + cells).min(hmax);
        let mut x0 = 0;
        while x0 < wmax {
            let x1 = (x0 + cells).min(wmax);
            out.push(DrawPatch { rect: [x0, y0, x1, y1], factors: factors(x1 - x0, y1 - y0) });
            x0 = x1;
        }
        y0 = y1;
    }
    out
}

/// How the renderer is set up: target size, colours, sun.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderConfig {
    /// Target width in pixels. Default 1280.
    pub width: u32,
    /// Target height in pixels. Default 720.
    pub height: u32,
    /// A colour texture mapped over the whole DEM (its first row at the north edge), instead
    /// of the height/slope ramp. Default none.
    pub texture: Option<RgbaImage>,
    /// Direction towards the sun in the world frame (x east, y north, z up); normalised by
    /// the renderer. Default: from the north-west, 45 degrees up (the cartographers' light).
    pub sun_direction: [f64; 3],
    /// Clear colour where no terrain is drawn. Default [`BACKGROUND`] (magenta, which the shader
    /// never produces, so tests can tell terrain from background); the CLI uses a sky colour.
    pub background: [u8; 4],
}

impl Default for RenderConfig {
    fn default() -> Self {
        Self {
            width: 1280,
            height: 720,
            texture: None,
            sun_direction: [-1.0, 1.0, 2f64.sqrt()],
            background: BACKGROUND,
        }
    }
}

/// Per-frame drawing options.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RenderOptions {
    /// Darken triangle edges (barycentric edges in the fragment stage: no extra pass, no
    /// depth fighting, no optional feature). Default off.
    pub wireframe: bool,
    /// When positive, hang a vertical skirt of this depth (metres) below every patch edge
    /// that another patch shares (not below the grid's border). Skirts hide cracks; the crack
    /// test uses them to build a reference image that has none. Default 0 (no skirts).
    pub skirt_depth_m: f32,
    /// Colour every patch by its level of detail ([`lod_colour`] of [`lod_step`]: grid cells
    /// per triangle edge) instead of the height ramp or texture, still shaded by the sun.
    /// Default off.
    pub lod_colours: bool,
}

/// Grid cells per triangle edge of a patch: its rect's cells over its inner factor, the
/// coarser of its two axes (1 = every sample drawn); `f32::INFINITY` for a patch drawn with
/// no triangles of its own (factor 0: the entropy mesh's carrier). The level of detail
/// [`lod_colour`] shows.
pub fn lod_step(patch: &DrawPatch) -> f32 {
    let [x0, y0, x1, y1] = patch.rect;
    let [fu, fv] = patch.factors.inner;
    if fu <= 0.0 || fv <= 0.0 {
        return f32::INFINITY;
    }
    ((x1 - x0) as f32 / fu).max((y1 - y0) as f32 / fv)
}

/// The LOD colours (sRGB, 0-1) by band, finest first, and the legend's names: band `k` holds
/// steps of about `2^k` cells per triangle edge (see [`lod_band`]).
pub const LOD_PALETTE: [([f32; 3], &str); 7] = [
    ([0.85, 0.15, 0.15], "1 cell (every sample)"),
    ([0.95, 0.55, 0.10], "2 cells"),
    ([0.90, 0.85, 0.15], "4 cells"),
    ([0.25, 0.70, 0.25], "8 cells"),
    ([0.15, 0.70, 0.80], "16 cells"),
    ([0.20, 0.35, 0.90], "32 cells"),
    ([0.60, 0.25, 0.80], "64+ cells"),
];

/// The colour of a mesh that has no patches of its own (the entropy method's triangles).
pub const LOD_NO_PATCH: [f32; 3] = [0.60, 0.60, 0.60];

/// The palette band of a step (cells per triangle edge): `log2(step)` rounded to the nearest
/// band, clamped to the palette; `None` for a patch without triangles of its own.
pub fn lod_band(step: f32) -> Option<usize> {
    if !step.is_finite() || step <= 0.0 {
        return None;
    }
    Some((step.log2() + 0.5).floor().clamp(0.0, (LOD_PALETTE.len() - 1) as f32) as usize)
}

/// A patch's LOD colour (sRGB, 0-1): the CPU reference of what the renderers draw with
/// [`RenderOptions::lod_colours`] (the colour is computed here and uploaded per patch; the
/// fragment stage shades it like the height ramp).
pub fn lod_colour(step: f32) -> [f32; 3] {
    lod_band(step).map_or(LOD_NO_PATCH, |k| LOD_PALETTE[k].0)
}
