//! The renderer-facing half of the frame loop: [`FrameRenderer`] draws a method's [`Frame`]
//! with the renderer its [`Draw`] needs: terrain-gpu's tessellation renderer (patches and extra
//! triangles), its geomorph renderer (vertex-shader morph), or the paged renderer of a store
//! (page changes applied first), alone or read by a paged geomorph renderer (geomorph from a
//! store). It also counts the bytes a frame uploads.

use std::time::Instant;

use glam::DVec3;
use terrain_core::Heightmap;
use terrain_core::geometry::Camera;
use terrain_gpu::geomorph::{GeomorphConfig, GeomorphOptions, GeomorphRenderer, MorphSource};
use terrain_gpu::tess::{GpuPatchFactors, PatchRange};
use terrain_gpu::{GpuContext, RenderConfig, RenderOptions, RgbaImage, TerrainRenderer};

use super::{Draw, Frame, MorphHeights};
use crate::ooc::OocScene;

/// Which renderer a method's frames need.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RendererKind {
    /// The tessellation renderer over the whole heightmap (shareable between methods).
    Tessellation,
    /// The geomorph renderer over the whole heightmap (shareable between methods).
    Geomorph,
    /// A paged renderer tied to one store's runtime (one per method instance).
    Paged,
    /// A paged renderer holding one store's pages and a geomorph renderer drawing from them
    /// (one per method instance).
    PagedMorph,
}

/// What a method's frames are drawn over ([`super::Method::draws_on`]): a renderer kind
/// with the terrain it reads.
#[derive(Debug, Clone, Copy)]
pub enum DrawSource<'a> {
    /// The tessellation renderer over a heightmap in memory.
    Tessellation(&'a Heightmap),
    /// The geomorph renderer over a heightmap in memory, patches of `.1` cells.
    Geomorph(&'a Heightmap, u32),
    /// The paged renderer over a store's runtime.
    Paged(&'a OocScene),
    /// The geomorph renderer over a store's pages, patches of `.1` cells.
    PagedMorph(&'a OocScene, u32),
}

impl DrawSource<'_> {
    /// The renderer kind.
    pub fn kind(self) -> RendererKind {
        match self {
            DrawSource::Tessellation(_) => RendererKind::Tessellation,
            DrawSource::Geomorph(..) => RendererKind::Geomorph,
            DrawSource::Paged(_) => RendererKind::Paged,
            DrawSource::PagedMorph(..) => RendererKind::PagedMorph,
        }
    }

    /// A renderer of [`DrawSource::kind`] over this terrain.
    pub fn renderer(
        self,
        ctx: &GpuContext,
        config: &RenderConfig,
    ) -> anyhow::Result<FrameRenderer> {
        match self {
            DrawSource::Tessellation(hm) => FrameRenderer::tessellation(ctx, hm, config),
            DrawSource::Geomorph(hm, n) => FrameRenderer::geomorph(ctx, hm, n, config),
            DrawSource::Paged(scene) => FrameRenderer::paged(scene, ctx, config),
            DrawSource::PagedMorph(scene, n) => FrameRenderer::paged_morph(scene, ctx, n, config),
        }
    }
}

impl RendererKind {
    /// Whether one renderer of this kind can draw the frames of several method instances in
    /// turn (it holds only the terrain); a paged renderer holds one runtime's pages.
    pub fn shareable(self) -> bool {
        !matches!(self, RendererKind::Paged | RendererKind::PagedMorph)
    }
}

#[derive(Debug)]
enum Inner {
    Tessellation(TerrainRenderer),
    Geomorph(GeomorphRenderer),
    Paged(TerrainRenderer),
    /// The pages (a paged tessellation renderer's atlas, never drawn itself) and the geomorph
    /// renderer reading them.
    PagedMorph {
        pages: Box<TerrainRenderer>,
        morph: Box<GeomorphRenderer>,
    },
}

/// A renderer that draws [`Frame`]s.
#[derive(Debug)]
pub struct FrameRenderer {
    inner: Inner,
    /// Bytes of the per-column and per-row anchor offsets, uploaded when the anchor moves
    /// (whole-heightmap renderers).
    anchor_bytes: u64,
    /// Bytes of one page (paged renderer).
    page_bytes: u64,
}

/// What drawing one frame cost and drew.
#[derive(Debug, Clone, PartialEq)]
pub struct DrawStats {
    /// Patches drawn.
    pub patches: usize,
    /// Non-degenerate triangles drawn.
    pub triangles: u64,
    /// Vertices the tessellator generated (tessellation renderers).
    pub vertices: Option<u64>,
    /// Renderer CPU time to upload, encode and submit, ms.
    pub cpu_ms: f64,
    /// Wall time of the renderer's call, including the wait for the GPU, ms.
    pub wall_ms: f64,
    /// GPU time where trustworthy, ms.
    pub gpu_ms: Option<f64>,
    /// GPU time of the draw pass, ms.
    pub gpu_draw_ms: Option<f64>,
    /// Whether the GPU tessellation pass ran (tessellation renderers).
    pub tessellated: Option<bool>,
    /// Compute + draw batches the frame was split into (1 unless its tessellated points or
    /// indices exceed the device's largest storage binding).
    pub batches: usize,
    /// Bytes uploaded this frame.
    pub upload_bytes: u64,
    /// Wall time of applying a store's page changes (uploading the pages that arrived, on the
    /// frame thread), ms; part of `wall_ms`. 0 for the whole-heightmap renderers.
    pub pages_ms: f64,
    /// Material passes skipped (geomorph renderer).
    pub passes_skipped: Option<usize>,
    /// The GPU time as a user reads it.
    pub gpu_text: String,
    /// The adapter.
    pub adapter: String,
}

/// Upload bookkeeping of one run of frames (the frame loop's): the anchor last uploaded and
/// whether anything was drawn yet. A caller that builds a [`super::FrameLoop`] per frame over
/// the same renderer (`terrain view` over a DEM in memory) carries it from loop to loop
/// ([`super::FrameLoop::with_uploads`]), so the anchor offsets count only when they move.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Uploads {
    last_anchor: Option<DVec3>,
    drawn: bool,
}

impl FrameRenderer {
    /// The tessellation renderer over `hm`.
    pub fn tessellation(
        ctx: &GpuContext,
        hm: &Heightmap,
        config: &RenderConfig,
    ) -> anyhow::Result<Self> {
        Ok(Self {
            inner: Inner::Tessellation(TerrainRenderer::new(ctx, hm, config)?),
            anchor_bytes: 4 * (hm.width() + hm.height()) as u64,
            page_bytes: 0,
        })
    }

    /// The geomorph renderer over `hm` with patches of `patch_cells` cells.
    pub fn geomorph(
        ctx: &GpuContext,
        hm: &Heightmap,
        patch_cells: u32,
        config: &RenderConfig,
    ) -> anyhow::Result<Self> {
        let config = GeomorphConfig {
            width: config.width,
            height: config.height,
            patch_cells,
            background: config.background,
            ..Default::default()
        };
        Ok(Self {
            inner: Inner::Geomorph(GeomorphRenderer::new(ctx, hm, &config)?),
            anchor_bytes: 4 * (hm.width() + hm.height()) as u64,
            page_bytes: 0,
        })
    }

    /// The paged renderer of a store's runtime (see [`OocScene::renderer`]).
    pub fn paged(
        scene: &OocScene,
        ctx: &GpuContext,
        config: &RenderConfig,
    ) -> anyhow::Result<Self> {
        Ok(Self {
            inner: Inner::Paged(scene.renderer(ctx, config)?),
            anchor_bytes: 0,
            page_bytes: scene.layout().page_len() as u64 * 4,
        })
    }

    /// The geomorph renderer over the pages of a store's runtime, with patches of
    /// `patch_cells` cells: the paged renderer holds the pages ([`OocScene::renderer`], its
    /// own target 1 x 1, never drawn) and [`GeomorphRenderer::new_paged`] draws from them.
    pub fn paged_morph(
        scene: &OocScene,
        ctx: &GpuContext,
        patch_cells: u32,
        config: &RenderConfig,
    ) -> anyhow::Result<Self> {
        let pages = scene.renderer(ctx, &RenderConfig { width: 1, height: 1, ..config.clone() })?;
        let gc = GeomorphConfig {
            width: config.width,
            height: config.height,
            patch_cells,
            background: config.background,
            ..Default::default()
        };
        let morph = GeomorphRenderer::new_paged(ctx, &pages, &gc)?;
        Ok(Self {
            inner: Inner::PagedMorph { pages: Box::new(pages), morph: Box::new(morph) },
            anchor_bytes: 4 * u64::from(scene.layout().grid[0] + scene.layout().grid[1]),
            page_bytes: scene.layout().page_len() as u64 * 4,
        })
    }

    /// Its kind.
    pub fn kind(&self) -> RendererKind {
        match self.inner {
            Inner::Tessellation(_) => RendererKind::Tessellation,
            Inner::Geomorph(_) => RendererKind::Geomorph,
            Inner::Paged(_) => RendererKind::Paged,
            Inner::PagedMorph { .. } => RendererKind::PagedMorph,
        }
    }

    /// The geomorph renderer and the paged renderer whose pages it reads (geomorph from a
    /// store), to draw with directly (tests' crack checks over a frame's pages).
    pub fn paged_morph_mut(&mut self) -> Option<(&mut GeomorphRenderer, &mut TerrainRenderer)> {
        match &mut self.inner {
            Inner::PagedMorph { pages, morph } => Some((morph, pages)),
            _ => None,
        }
    }

    /// The tessellation (or paged) renderer inside, for its figures (page classes, capacity).
    pub fn terrain_renderer(&self) -> Option<&TerrainRenderer> {
        match &self.inner {
            Inner::Tessellation(r) | Inner::Paged(r) => Some(r),
            Inner::PagedMorph { pages, .. } => Some(pages),
            Inner::Geomorph(_) => None,
        }
    }

    /// The tessellation (or paged) renderer inside, to draw with directly (tests' crack
    /// checks over a frame's pages).
    pub fn terrain_renderer_mut(&mut self) -> Option<&mut TerrainRenderer> {
        match &mut self.inner {
            Inner::Tessellation(r) | Inner::Paged(r) => Some(r),
            Inner::Geomorph(_) | Inner::PagedMorph { .. } => None,
        }
    }

    /// The last frame's image.
    pub fn read_image(&self) -> anyhow::Result<RgbaImage> {
        Ok(match &self.inner {
            Inner::Tessellation(r) | Inner::Paged(r) => r.read_image()?,
            Inner::Geomorph(r) => r.read_image()?,
            Inner::PagedMorph { morph, .. } => morph.read_image()?,
        })
    }

    /// The offscreen colour texture the last frame was drawn into (RGBA8 unorm): what
    /// `terrain view` copies to its window's surface.
    pub fn color_texture(&self) -> &wgpu::Texture {
        match &self.inner {
            Inner::Tessellation(r) | Inner::Paged(r) => r.color_texture(),
            Inner::Geomorph(r) => r.color_texture(),
            Inner::PagedMorph { morph, .. } => morph.color_texture(),
        }
    }

    /// Sets the sun direction of the next frames where the renderer shades per fragment (the
    /// tessellation and paged renderers); `false` where it cannot (the geomorph renderers bake
    /// their sun into a lightmap).
    pub fn set_sun_direction(&mut self, direction: [f64; 3]) -> anyhow::Result<bool> {
        match &mut self.inner {
            Inner::Tessellation(r) | Inner::Paged(r) => {
                r.set_sun_direction(direction)?;
                Ok(true)
            }
            Inner::Geomorph(_) | Inner::PagedMorph { .. } => Ok(false),
        }
    }

    /// Applies what `frame` changes in the renderer's state without drawing (a store's page
    /// changes); nothing for the other renderers, which hold no per-frame state.
    pub fn apply(&mut self, frame: &Frame) -> anyhow::Result<()> {
        match (&mut self.inner, &frame.draw) {
            (Inner::Paged(r), Draw::Paged(f)) => OocScene::apply(r, f)?,
            (Inner::PagedMorph { pages, .. }, Draw::PagedMorph(f, _)) => OocScene::apply(pages, f)?,
            _ => {}
        }
        Ok(())
    }

    /// Draws `frame` from `camera`.
    pub(crate) fn draw(
        &mut self,
        camera: &Camera,
        frame: &Frame,
        options: &RenderOptions,
        uploads: &mut Uploads,
    ) -> anyhow::Result<DrawStats> {
        let anchor = TerrainRenderer::anchor_for(camera.position);
        let moved = uploads.last_anchor != Some(anchor);
        let first = !uploads.drawn;
        let anchor_bytes = if moved { self.anchor_bytes } else { 0 };
        let stats = match (&mut self.inner, &frame.draw) {
            (Inner::Tessellation(r), Draw::Tessellated { patches, extra }) => {
                let t = Instant::now();
                let s = r.render_with_extra(camera, patches, extra, options)?;
                let wall_ms = ms(t);
                let mut bytes = 128u64;
                if s.tessellated || first {
                    let per_patch = size_of::<GpuPatchFactors>() + size_of::<PatchRange>() + 16;
                    bytes += (patches.len() * per_patch) as u64;
                }
                // Extra triangles (strips, the entropy mesh) are uploaded every frame.
                bytes += (extra.points.len() * 16 + extra.indices.len() * 4) as u64;
                DrawStats::of_terrain(s, wall_ms, bytes + anchor_bytes)
            }
            (Inner::Geomorph(r), Draw::Morph(lods, heights)) => {
                let source = match heights {
                    MorphHeights::Shader => MorphSource::Shader,
                    MorphHeights::Static => MorphSource::Static,
                    MorphHeights::Cpu(h) => MorphSource::Cpu(h),
                };
                let t = Instant::now();
                let s = r.render_runs(camera, lods, source, &morph_options(options))?;
                DrawStats::of_geomorph(s, ms(t), anchor_bytes)
            }
            (Inner::PagedMorph { pages, morph }, Draw::PagedMorph(f, lods)) => {
                let t = Instant::now();
                OocScene::apply(pages, f)?;
                let pages_ms = ms(t);
                let s = morph.render_paged_runs(pages, camera, lods, &morph_options(options))?;
                let uploaded = f.updates.iter().filter(|u| u.fill.is_some()).count() as u64;
                let mut d =
                    DrawStats::of_geomorph(s, ms(t), uploaded * self.page_bytes + anchor_bytes);
                d.pages_ms = pages_ms;
                d
            }
            (Inner::Paged(r), Draw::Paged(f)) => {
                // The page changes are part of the frame's wall time: the pages that arrived
                // are uploaded on the frame thread.
                let t = Instant::now();
                OocScene::apply(r, f)?;
                let pages_ms = ms(t);
                let s = r.render_with_extra(camera, &f.patches, &f.extra, options)?;
                let wall_ms = ms(t);
                let pages = f.updates.iter().filter(|u| u.fill.is_some()).count() as u64;
                let extra = (f.extra.points.len() * 16 + f.extra.indices.len() * 4) as u64;
                let mut d =
                    DrawStats::of_terrain(s, wall_ms, 128 + pages * self.page_bytes + extra);
                d.pages_ms = pages_ms;
                d
            }
            (_, draw) => anyhow::bail!(
                "the {:?} renderer cannot draw a {} frame",
                self.kind(),
                match draw {
                    Draw::Tessellated { .. } => "tessellated",
                    Draw::Morph(..) => "geomorph",
                    Draw::Paged(_) => "paged",
                    Draw::PagedMorph(..) => "paged geomorph",
                }
            ),
        };
        uploads.last_anchor = Some(anchor);
        uploads.drawn = true;
        Ok(stats)
    }
}

impl DrawStats {
    /// The figures of a frame the geomorph renderer drew, its wall time and the bytes
    /// uploaded besides its own (anchor offsets, pages).
    fn of_geomorph(
        s: terrain_gpu::geomorph::GeomorphFrameStats,
        wall_ms: f64,
        more_bytes: u64,
    ) -> Self {
        Self {
            patches: s.patches,
            triangles: s.triangles,
            vertices: None,
            cpu_ms: s.cpu_ms,
            wall_ms,
            gpu_ms: None,
            gpu_draw_ms: None,
            tessellated: None,
            upload_bytes: s.upload_bytes + more_bytes,
            passes_skipped: Some(s.passes_skipped),
            pages_ms: 0.0,
            batches: 1,
            gpu_text: "n/a (the geomorph renderer has no timestamps)".to_string(),
            adapter: s.adapter,
        }
    }

    /// The figures of a frame the tessellation renderer drew (whole heightmap or pages), its
    /// wall time and the bytes it uploaded.
    fn of_terrain(s: terrain_gpu::render::FrameStats, wall_ms: f64, upload_bytes: u64) -> Self {
        let gpu_text = s.gpu_text();
        Self {
            patches: s.patches,
            triangles: s.triangles,
            vertices: Some(s.vertices),
            cpu_ms: s.cpu_ms,
            wall_ms,
            gpu_ms: s.gpu_ms,
            gpu_draw_ms: s.gpu_draw_ms,
            tessellated: Some(s.tessellated),
            upload_bytes,
            passes_skipped: None,
            pages_ms: 0.0,
            batches: s.batches,
            gpu_text,
            adapter: s.adapter,
        }
    }
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// The geomorph renderer's options for a frame drawn with `options`: its LOD colours (the
/// patch's level through the same `lod_colour`); wireframe and skirts are the tessellation
/// renderer's only.
fn morph_options(options: &RenderOptions) -> GeomorphOptions {
    GeomorphOptions { lod_colours: options.lod_colours, ..Default::default() }
}
