//! [`GeomorphRenderer`]: the heights (pages of a [`TerrainRenderer`]'s atlas: one page for a
//! whole heightmap, a store's blocks in paged mode), the lightmap and alpha maps of a whole
//! heightmap, the mesh library, the pipelines of `geomorph.wgsl` (an opaque base pass and
//! alpha-blended material passes; one pass with per-fragment normals in paged mode), and the
//! read-back hook the tests compare with the CPU reference.

use std::mem::size_of;
use std::time::Instant;

use bytemuck::{Pod, Zeroable};
use glam::{DVec2, DVec3};
use terrain_core::Heightmap;
use terrain_core::geometry::Camera;
use terrain_core::lightmap::{LightmapConfig, lightmap};
use terrain_core::lod::{GeomipRuns, PatchLod, PatchRun};

use super::materials::{MATERIALS, MaterialMaps};
use super::morph::{GpuMorphPatch, MeshLibrary, PATCH_SHIFT};
use crate::device::{GpuContext, GpuError, read_buffer, upload_texture};
use crate::paged::PageLayout;
use crate::render::{BACKGROUND, RenderError, TerrainRenderer};
use crate::target::{COLOR_FORMAT, OffscreenTarget, RgbaImage};

/// The shader module: `geomorph.wgsl` with the paged lookup (`paged_lookup.wgsl`, shared with
/// the tessellation renderer) after it.
pub const SHADER: &str =
    concat!(include_str!("geomorph.wgsl"), "\n", include_str!("../paged_lookup.wgsl"));

/// `Frame` in `geomorph.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
struct GpuFrame {
    view_proj: [[f32; 4]; 4],
    sun: [f32; 4],
    spacing: [f32; 2],
    grid_max: [u32; 2],
    height_offset: f32,
    skirt_depth: f32,
    patch_cells: u32,
    max_level: u32,
    patch_count: u32,
    flags: u32,
    height_min: f32,
    height_range: f32,
    run_count: u32,
    run_patches: u32,
    patches_x: u32,
    pad: u32,
    /// The LOD colour of each level (`lod_colour(2^level)`, rgb and 1; the last one for every
    /// coarser level), read when `FLAG_LOD_COLOURS` is set.
    level_colours: [[f32; 4]; LEVEL_COLOURS],
}

const _: () = assert!(size_of::<GpuFrame>() == 272);

/// `GmRun` in `geomorph.wgsl`: one [`PatchRun`] and the run patches before it.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
struct GpuRun {
    first: [u32; 2],
    width: u32,
    start: u32,
}

/// `RUN_INSTANCES` in `geomorph.wgsl`: instance indices from this on draw the runs' patches
/// (`RUN_INSTANCES + material * run patches + k`); below it the instance is the material of a
/// pass over the single patches.
const RUN_INSTANCES: u32 = 8;
const _: () = assert!(MATERIALS as u32 <= RUN_INSTANCES);

/// `FLAG_PAGED` in `geomorph.wgsl`.
const FLAG_PAGED: u32 = 1;
/// `FLAG_LOD_COLOURS` in `geomorph.wgsl`.
const FLAG_LOD_COLOURS: u32 = 2;
/// Entries of `Frame::level_colours` in `geomorph.wgsl`: levels 0..=7 (steps 1 to 128 cells;
/// the palette's last band starts at 64).
pub(crate) const LEVEL_COLOURS: usize = 8;

/// Grid cells per triangle edge of a geo-mipmapped patch drawn at `level`: `2^level` (the
/// level's lattice; the tween morphs its vertices towards level `level + 1` but draws the same
/// triangles). The step [`crate::render::lod_colour`] bands, as [`crate::render::lod_step`] is
/// for the tessellation renderer's patches, so a level-`k` patch has the colour of a
/// tessellated patch of `2^k` cells per edge.
pub fn lod_step(lod: &PatchLod) -> f32 {
    (1u32 << u32::from(lod.level).min(31)) as f32
}

/// The colours `Frame::level_colours` holds: the CPU reference [`crate::render::lod_colour`] of
/// each level's [`lod_step`].
fn level_colours() -> [[f32; 4]; LEVEL_COLOURS] {
    std::array::from_fn(|level| {
        let [r, g, b] = crate::render::lod_colour((1u32 << level) as f32);
        [r, g, b, 1.0]
    })
}

/// How the geomorph renderer is set up.
#[derive(Clone, Debug, PartialEq)]
pub struct GeomorphConfig {
    /// Target width in pixels. Default 1280.
    pub width: u32,
    /// Target height in pixels. Default 720.
    pub height: u32,
    /// Cells per patch side (a power of two; the selection's). Default 16.
    pub patch_cells: u32,
    /// The lightmap (sun, ambient, shadows). Default [`LightmapConfig::default`], the
    /// tessellation renderer's sun, with horizon shadows. In paged mode only its sun is used
    /// (per-fragment lambert with the renderer's ambient 0.3 and diffuse 0.7, no shadows).
    pub lightmap: LightmapConfig,
    /// Clear colour. Default [`BACKGROUND`] (magenta, never drawn).
    pub background: [u8; 4],
}

impl Default for GeomorphConfig {
    fn default() -> Self {
        Self {
            width: 1280,
            height: 720,
            patch_cells: 16,
            lightmap: LightmapConfig::default(),
            background: BACKGROUND,
        }
    }
}

/// Per-frame options.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GeomorphOptions {
    /// When positive, hang skirts of this depth (metres) below every patch edge another patch
    /// shares: the crack test's reference. Default 0.
    pub skirt_depth_m: f32,
    /// Colour every patch by its level ([`crate::render::lod_colour`] of [`lod_step`]: `2^level`
    /// cells per triangle edge) instead of the materials, still lit (the lightmap of a whole
    /// heightmap, the per-fragment sun in paged mode). Default off.
    pub lod_colours: bool,
}

/// Where a frame's drawn heights come from: the geomorphing article's Table 1 columns (Wagner
/// 2003, "Results"), each drawn by its own pipeline of `geomorph.wgsl` (`MORPH_MODE`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum MorphSource<'a> {
    /// Morphed in the vertex stage ("hardware morphing", the article's method).
    #[default]
    Shader,
    /// Every vertex at its true height, tween factors ignored ("static LOD": geo-mipmapping
    /// without geomorphing).
    Static,
    /// Heights morphed on the CPU by [`super::MorphGrid::patch_heights`] (the reference the
    /// vertex stage's morph is tested against) and uploaded every frame ("software
    /// morphing"): `(patch_cells + 1)^2` per patch, in the order of the patches; the pipeline
    /// reads them and does no morphing.
    Cpu(&'a [f32]),
}

impl MorphSource<'_> {
    /// `MORPH_MODE` in `geomorph.wgsl`.
    fn mode(&self) -> usize {
        match self {
            MorphSource::Shader => 0,
            MorphSource::Static => 1,
            MorphSource::Cpu(_) => 2,
        }
    }
}

/// What one frame drew and cost.
#[derive(Clone, Debug, PartialEq)]
pub struct GeomorphFrameStats {
    /// Patches drawn.
    pub patches: usize,
    /// Triangles of the base pass (each material pass redraws a subset of them).
    pub triangles: u64,
    /// Material passes drawn, over all patches (the base pass included).
    pub passes_drawn: usize,
    /// Material passes skipped because the material's alpha is zero over the patch.
    pub passes_skipped: usize,
    /// Bytes uploaded this frame: the frame uniform, the patches, the passes' index lists and,
    /// with [`MorphSource::Cpu`], the morphed heights (not the column/row offsets written
    /// when the anchor moves).
    pub upload_bytes: u64,
    /// CPU time to upload, encode and submit, milliseconds.
    pub cpu_ms: f64,
    /// The adapter.
    pub adapter: String,
}

/// Where a [`GeomorphRenderer`]'s heights come from.
#[derive(Debug)]
enum Heights {
    /// A whole heightmap as one R32Float texture (texel `(i, j)` = sample `(i, j)`: the one
    /// page of stride 1 the lookup would find at the atlas's origin, read directly, shader
    /// constant `PAGED` false; the page table bound is a placeholder), with the lightmap and
    /// alpha maps.
    Whole { heights: wgpu::TextureView, table: wgpu::Buffer, materials: MaterialMaps },
    /// The pages of a paged [`TerrainRenderer`] the caller owns and passes to
    /// [`GeomorphRenderer::render_paged`] (a store's blocks); its layout and height range.
    Paged(PageLayout, [f32; 2]),
}

/// The bind group and what it binds.
#[derive(Debug)]
struct Bound {
    atlas: wgpu::TextureView,
    table: wgpu::Buffer,
    patches: wgpu::Buffer,
    cpu: wgpu::Buffer,
    runs: wgpu::Buffer,
    group: wgpu::BindGroup,
}

/// The base and material pipelines of one [`MorphSource`].
#[derive(Debug)]
struct Pipelines {
    base: wgpu::RenderPipeline,
    overlay: wgpu::RenderPipeline,
}

/// Draws geo-mipmapped, geomorphed patches ([`PatchLod`]s from
/// `terrain_core::lod::GeomipScene::select`) into an offscreen RGBA8 target, from a whole
/// heightmap ([`GeomorphRenderer::new`]) or from the pages of a paged [`TerrainRenderer`]
/// ([`GeomorphRenderer::new_paged`]: a store's blocks, at whatever level each is resident).
#[derive(Debug)]
pub struct GeomorphRenderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: String,
    target: OffscreenTarget,
    layout: wgpu::BindGroupLayout,
    debug_layout: wgpu::BindGroupLayout,
    module: wgpu::ShaderModule,
    render_layout: wgpu::PipelineLayout,
    /// Per [`MorphSource::mode`]: built on first use (the shader's morph at creation).
    pipelines: [Option<Pipelines>; 3],
    debug: wgpu::ComputePipeline,
    /// [`MorphSource::Cpu`]'s heights (binding 10; 4 bytes when never used) and capacity.
    cpu_heights: (wgpu::Buffer, u64),
    frame: wgpu::Buffer,
    col_x: wgpu::Buffer,
    row_y: wgpu::Buffer,
    heights: Heights,
    light: wgpu::TextureView,
    alpha: wgpu::TextureView,
    sampler: wgpu::Sampler,
    patches: Option<(wgpu::Buffer, u64)>,
    /// The runs (`GmRun`, binding 11) and capacity.
    runs: Option<(wgpu::Buffer, u64)>,
    /// Per patch its material passes, four patches a word (binding 12; a placeholder in
    /// paged mode), and the patches along x.
    pass_masks: (wgpu::Buffer, u32),
    bound: Option<Bound>,
    indices: Option<wgpu::Buffer>,
    lib: MeshLibrary,
    sun: [f32; 4],
    grid: [u32; 2],
    origin: DVec2,
    spacing: DVec2,
    background: [u8; 4],
    anchor: Option<DVec3>,
}

fn entry(binding: u32, ty: wgpu::BindingType) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::VERTEX_FRAGMENT | wgpu::ShaderStages::COMPUTE,
        ty,
        count: None,
    }
}

fn storage(read_only: bool) -> wgpu::BindingType {
    wgpu::BindingType::Buffer {
        ty: wgpu::BufferBindingType::Storage { read_only },
        has_dynamic_offset: false,
        min_binding_size: None,
    }
}

fn texture(filterable: bool) -> wgpu::BindingType {
    wgpu::BindingType::Texture {
        sample_type: wgpu::TextureSampleType::Float { filterable },
        view_dimension: wgpu::TextureViewDimension::D2,
        multisampled: false,
    }
}

/// The lightmap (R8) and alpha maps (RGBA8) as uploaded: a whole heightmap's, or 1 x 1
/// placeholders in paged mode.
struct Maps<'a> {
    size: [u32; 2],
    light: &'a [u8],
    alpha: &'a [u8],
}

/// Refuses a target or patch size the renderer cannot draw.
fn check_config(ctx: &GpuContext, config: &GeomorphConfig) -> Result<(), RenderError> {
    let maximum = ctx.device.limits().max_texture_dimension_2d;
    if config.width == 0 || config.height == 0 || config.width > maximum || config.height > maximum
    {
        return Err(RenderError::InvalidConfig(format!(
            "target size {} x {} (allowed 1 to {maximum} per side)",
            config.width, config.height
        )));
    }
    let p = config.patch_cells;
    if !(p.is_power_of_two() && (2..=64).contains(&p)) {
        return Err(RenderError::InvalidConfig(format!(
            "patch_cells {p}: a power of two from 2 to 64"
        )));
    }
    Ok(())
}

impl GeomorphRenderer {
    /// Uploads `hm` (one resident page of a tessellation renderer's atlas), its lightmap and
    /// alpha maps, the mesh library, and builds the pipelines and a `config.width` x
    /// `config.height` target.
    pub fn new(
        ctx: &GpuContext,
        hm: &Heightmap,
        config: &GeomorphConfig,
    ) -> Result<Self, RenderError> {
        check_config(ctx, config)?;
        let (width, height) = (hm.width() as u32, hm.height() as u32);
        let maximum = ctx.device.limits().max_texture_dimension_2d;
        if width > maximum || height > maximum {
            return Err(RenderError::TextureTooLarge {
                what: "the heightmap",
                width,
                height,
                maximum,
            });
        }
        let light_values: Vec<u8> = lightmap(hm, &config.lightmap)
            .iter()
            .map(|&l| (l * 255.0).round().clamp(0.0, 255.0) as u8)
            .collect();
        let materials = MaterialMaps::new(hm, config.patch_cells);
        let alpha: Vec<u8> = bytemuck::cast_slice(&materials.alpha).to_vec();
        let maps = Maps { size: [width, height], light: &light_values, alpha: &alpha };
        let heights = upload_texture(
            ctx,
            "geomorph heights",
            [width, height],
            wgpu::TextureFormat::R32Float,
            bytemuck::cast_slice(hm.data()),
            4,
        );
        let table = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("geomorph page table (unused)"),
            size: 16,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        let layout = PageLayout::whole(hm);
        Self::build(ctx, &layout, Heights::Whole { heights, table, materials }, maps, config)
    }

    /// A renderer drawing from the pages of `pages`, a paged [`TerrainRenderer`]
    /// ([`TerrainRenderer::new_paged_classes`]: a store's blocks, each at its resident level)
    /// that the caller keeps and passes to every [`GeomorphRenderer::render_paged`]: the same
    /// atlas, page table and lookup (`paged_lookup.wgsl`) the tessellation renderer draws
    /// from, so both read every sample alike. No lightmap or alpha maps (they need the whole
    /// grid): normals per fragment from the pages and the materials blended per fragment by
    /// the same alphas, in one pass. Never allocates the grid (one `f32` per column and row).
    pub fn new_paged(
        ctx: &GpuContext,
        pages: &TerrainRenderer,
        config: &GeomorphConfig,
    ) -> Result<Self, RenderError> {
        check_config(ctx, config)?;
        let maps = Maps { size: [1, 1], light: &[255], alpha: &[0; 4] };
        let layout = *pages.page_layout();
        Self::build(ctx, &layout, Heights::Paged(layout, pages.height_range()), maps, config)
    }

    fn build(
        ctx: &GpuContext,
        grid: &PageLayout,
        heights: Heights,
        maps: Maps<'_>,
        config: &GeomorphConfig,
    ) -> Result<Self, RenderError> {
        let device = &ctx.device;
        let [width, height] = grid.grid;
        let p = config.patch_cells;
        let light =
            upload_texture(ctx, "lightmap", maps.size, wgpu::TextureFormat::R8Unorm, maps.light, 1);
        let alpha = upload_texture(
            ctx,
            "alpha maps",
            maps.size,
            wgpu::TextureFormat::Rgba8Unorm,
            maps.alpha,
            4,
        );
        let sun = glam::DVec3::from(config.lightmap.sun_direction);
        if !(sun.length() > 0.0 && sun.is_finite()) {
            return Err(RenderError::InvalidConfig(format!("sun direction {sun}")));
        }
        let sun = sun.normalize().as_vec3().extend(0.0).to_array();
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("geomorph maps"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("geomorph"),
            entries: &[
                entry(
                    0,
                    wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                ),
                entry(1, texture(false)),
                entry(2, storage(true)),
                entry(3, storage(true)),
                entry(4, storage(true)),
                entry(6, texture(true)),
                entry(7, texture(true)),
                entry(8, wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering)),
                entry(9, storage(true)),
                entry(10, storage(true)),
                entry(11, storage(true)),
                entry(12, storage(true)),
            ],
        });
        let debug_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("geomorph debug"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: storage(true),
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: storage(false),
                    count: None,
                },
            ],
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("geomorph.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let render_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("geomorph"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let paged = matches!(heights, Heights::Paged(..));
        let shader = make_pipelines(device, &module, &render_layout, paged, 0);
        let debug_pipeline_layout =
            device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("geomorph debug"),
                bind_group_layouts: &[Some(&layout), Some(&debug_layout)],
                immediate_size: 0,
            });
        let constants = [("PAGED", if paged { 1.0 } else { 0.0 })];
        let debug = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("debug_morph"),
            layout: Some(&debug_pipeline_layout),
            module: &module,
            entry_point: Some("debug_morph"),
            compilation_options: wgpu::PipelineCompilationOptions {
                constants: &constants,
                ..Default::default()
            },
            cache: None,
        });
        use wgpu::BufferUsages as U;
        let buffer = |label, size: u64, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        let frame =
            buffer("geomorph frame", size_of::<GpuFrame>() as u64, U::UNIFORM | U::COPY_DST);
        let col_x = buffer("geomorph columns", 4 * u64::from(width), U::STORAGE | U::COPY_DST);
        let row_y = buffer("geomorph rows", 4 * u64::from(height), U::STORAGE | U::COPY_DST);
        let cpu_heights = buffer("geomorph cpu heights", 4, U::STORAGE | U::COPY_DST);
        // The pass masks of a whole heightmap's patches, four a word (little-endian bytes).
        let (words, patches_x) = match &heights {
            Heights::Whole { materials, .. } => {
                let words: Vec<u32> = materials
                    .masks
                    .chunks(4)
                    .map(|c| c.iter().rev().fold(0u32, |w, &m| (w << 8) | u32::from(m)))
                    .collect();
                (words, materials.patches.0)
            }
            Heights::Paged(..) => (vec![1], 1),
        };
        let masks =
            buffer("geomorph pass masks", 4 * words.len().max(1) as u64, U::STORAGE | U::COPY_DST);
        ctx.queue.write_buffer(&masks, 0, bytemuck::cast_slice(&words));
        let lib = MeshLibrary::new(p);
        Ok(Self {
            device: ctx.device.clone(),
            queue: ctx.queue.clone(),
            adapter: ctx.describe(),
            target: OffscreenTarget::new(device, config.width, config.height),
            layout,
            debug_layout,
            module,
            render_layout,
            pipelines: [Some(shader), None, None],
            debug,
            cpu_heights: (cpu_heights, 4),
            frame,
            col_x,
            row_y,
            heights,
            light,
            alpha,
            sampler,
            patches: None,
            runs: None,
            pass_masks: (masks, patches_x),
            bound: None,
            indices: None,
            lib,
            sun,
            grid: [width, height],
            origin: grid.origin,
            spacing: grid.spacing,
            background: config.background,
            anchor: None,
        })
    }

    /// The target's width and height in pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.target.width(), self.target.height())
    }

    /// The offscreen colour texture the last frame was drawn into (RGBA8 unorm, `COPY_SRC`):
    /// a windowed viewer copies it to its surface.
    pub fn color_texture(&self) -> &wgpu::Texture {
        &self.target.color
    }

    /// The adapter, as [`GpuContext::describe`] says.
    pub fn adapter(&self) -> &str {
        &self.adapter
    }

    /// The material maps and per-patch pass masks (a whole heightmap's; `None` in paged
    /// mode, which blends the materials per fragment in one pass).
    pub fn materials(&self) -> Option<&MaterialMaps> {
        match &self.heights {
            Heights::Whole { materials, .. } => Some(materials),
            Heights::Paged(..) => None,
        }
    }

    /// Whether it draws from a paged renderer's pages ([`GeomorphRenderer::new_paged`]).
    pub fn is_paged(&self) -> bool {
        matches!(self.heights, Heights::Paged(..))
    }

    /// The mesh library.
    pub fn library(&self) -> &MeshLibrary {
        &self.lib
    }

    /// The page atlas and page table to bind: the own tessellation renderer's (whole
    /// heightmap, `pages` `None`) or those of `pages` (paged mode), page-table changes written
    /// to the device first.
    fn page_resources(
        &mut self,
        pages: Option<&mut TerrainRenderer>,
    ) -> Result<(wgpu::TextureView, wgpu::Buffer), RenderError> {
        match (&mut self.heights, pages) {
            (Heights::Whole { heights, table, .. }, None) => Ok((heights.clone(), table.clone())),
            (Heights::Paged(layout, _), Some(p)) if p.page_layout() == layout => {
                Ok(p.page_resources())
            }
            (Heights::Paged(..), Some(_)) => Err(RenderError::InvalidConfig(
                "the pages given are of another layout than the renderer was made for".into(),
            )),
            (Heights::Paged(..), None) => Err(RenderError::InvalidConfig(
                "a paged geomorph renderer draws the pages given to render_paged".into(),
            )),
            (Heights::Whole { .. }, Some(_)) => Err(RenderError::InvalidConfig(
                "a whole-heightmap geomorph renderer draws its own heights: call render".into(),
            )),
        }
    }

    /// Uploads `lods` and `runs` (growing their buffers when needed) and the frame uniform,
    /// and binds the heights of `pages` (see [`GeomorphRenderer::page_resources`]).
    fn upload(
        &mut self,
        pages: Option<&mut TerrainRenderer>,
        camera: &Camera,
        lods: &[GpuMorphPatch],
        (runs, run_patches): (&[GpuRun], u32),
        cpu_heights: Option<&[f32]>,
        options: &GeomorphOptions,
    ) -> Result<(), RenderError> {
        let [w, h] = self.grid;
        for (index, p) in lods.iter().enumerate() {
            if p.origin[0] + 1 >= w
                || p.origin[1] + 1 >= h
                || p.level > self.lib.patch_cells.trailing_zeros()
            {
                return Err(RenderError::BadPatch {
                    index,
                    rect: [
                        p.origin[0],
                        p.origin[1],
                        p.origin[0] + self.lib.patch_cells,
                        p.origin[1] + self.lib.patch_cells,
                    ],
                    width: w,
                    height: h,
                });
            }
        }
        if lods.len() > 1 << (32 - PATCH_SHIFT) {
            return Err(RenderError::InvalidConfig(format!(
                "{} patches; the geomorph renderer draws at most {}",
                lods.len(),
                1u64 << (32 - PATCH_SHIFT)
            )));
        }
        let (atlas, table) = self.page_resources(pages)?;
        let bytes = (lods.len().max(1) * size_of::<GpuMorphPatch>()) as u64;
        if self.patches.as_ref().is_none_or(|(_, cap)| *cap < bytes) {
            let cap = bytes.next_power_of_two();
            let buf = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("geomorph patches"),
                size: cap,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            self.patches = Some((buf, cap));
        }
        if let Some(hs) = cpu_heights {
            let n1 = self.lib.patch_cells as usize + 1;
            if hs.len() != lods.len() * n1 * n1 {
                return Err(RenderError::InvalidConfig(format!(
                    "{} CPU-morphed heights for {} patches of {n1} x {n1} vertices",
                    hs.len(),
                    lods.len()
                )));
            }
            let bytes = (hs.len().max(1) * 4) as u64;
            if self.cpu_heights.1 < bytes {
                let cap = bytes.next_power_of_two();
                let buf = self.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("geomorph cpu heights"),
                    size: cap,
                    usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                });
                self.cpu_heights = (buf, cap);
            }
            if !hs.is_empty() {
                self.queue.write_buffer(&self.cpu_heights.0, 0, bytemuck::cast_slice(hs));
            }
        }
        let bytes = (runs.len().max(1) * size_of::<GpuRun>()) as u64;
        if self.runs.as_ref().is_none_or(|(_, cap)| *cap < bytes) {
            let cap = bytes.next_power_of_two();
            let buf = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("geomorph runs"),
                size: cap,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            self.runs = Some((buf, cap));
        }
        let (runs_buf, _) = self.runs.as_ref().expect("allocated above");
        if !runs.is_empty() {
            self.queue.write_buffer(runs_buf, 0, bytemuck::cast_slice(runs));
        }
        let cpu = &self.cpu_heights.0;
        let (buf, _) = self.patches.as_ref().expect("allocated above");
        if self.bound.as_ref().is_none_or(|b| {
            b.atlas != atlas
                || b.table != table
                || b.patches != *buf
                || b.cpu != *cpu
                || b.runs != *runs_buf
        }) {
            let bind = |binding, resource| wgpu::BindGroupEntry { binding, resource };
            let group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("geomorph"),
                layout: &self.layout,
                entries: &[
                    bind(0, self.frame.as_entire_binding()),
                    bind(1, wgpu::BindingResource::TextureView(&atlas)),
                    bind(2, buf.as_entire_binding()),
                    bind(3, self.col_x.as_entire_binding()),
                    bind(4, self.row_y.as_entire_binding()),
                    bind(6, wgpu::BindingResource::TextureView(&self.light)),
                    bind(7, wgpu::BindingResource::TextureView(&self.alpha)),
                    bind(8, wgpu::BindingResource::Sampler(&self.sampler)),
                    bind(9, table.as_entire_binding()),
                    bind(10, cpu.as_entire_binding()),
                    bind(11, runs_buf.as_entire_binding()),
                    bind(12, self.pass_masks.0.as_entire_binding()),
                ],
            });
            self.bound = Some(Bound {
                atlas,
                table,
                patches: buf.clone(),
                cpu: cpu.clone(),
                runs: runs_buf.clone(),
                group,
            });
        }
        if !lods.is_empty() {
            self.queue.write_buffer(buf, 0, bytemuck::cast_slice(lods));
        }
        let anchor = TerrainRenderer::anchor_for(camera.position);
        if self.anchor != Some(anchor) {
            let offsets = |n: u32, origin: f64, step: f64, at: f64| -> Vec<f32> {
                (0..n).map(|k| (origin + f64::from(k) * step - at) as f32).collect()
            };
            let cols = offsets(w, self.origin.x, self.spacing.x, anchor.x);
            let rows = offsets(h, self.origin.y, self.spacing.y, anchor.y);
            self.queue.write_buffer(&self.col_x, 0, bytemuck::cast_slice(&cols));
            self.queue.write_buffer(&self.row_y, 0, bytemuck::cast_slice(&rows));
            self.anchor = Some(anchor);
        }
        let (mut flags, [lo, hi]) = match self.heights {
            Heights::Whole { .. } => (0, [0.0, 0.0]),
            Heights::Paged(_, range) => (FLAG_PAGED, range),
        };
        if options.lod_colours {
            flags |= FLAG_LOD_COLOURS;
        }
        let frame = GpuFrame {
            view_proj: camera.view_proj_for_anchor(anchor).to_cols_array_2d(),
            sun: self.sun,
            spacing: self.spacing.as_vec2().to_array(),
            grid_max: [w - 1, h - 1],
            height_offset: (-anchor.z) as f32,
            skirt_depth: options.skirt_depth_m.max(0.0),
            patch_cells: self.lib.patch_cells,
            max_level: self.lib.patch_cells.trailing_zeros(),
            patch_count: lods.len().max(1) as u32,
            flags,
            height_min: lo,
            height_range: (hi - lo).max(0.0),
            run_count: runs.len() as u32,
            run_patches: run_patches.max(1),
            patches_x: self.pass_masks.1,
            pad: 0,
            level_colours: level_colours(),
        };
        self.queue.write_buffer(&self.frame, 0, bytemuck::bytes_of(&frame));
        Ok(())
    }

    /// Draws `lods` as seen by `camera` (its viewport is replaced by the target's size): the
    /// base material on every patch, then each further material on the patches whose alpha
    /// map is not zero there. Waits for the device. A whole-heightmap renderer's
    /// ([`GeomorphRenderer::new`]); a paged one draws with [`GeomorphRenderer::render_paged`].
    pub fn render(
        &mut self,
        camera: &Camera,
        lods: &[PatchLod],
        options: &GeomorphOptions,
    ) -> Result<GeomorphFrameStats, RenderError> {
        self.draw(None, camera, lods, &[], MorphSource::Shader, options)
    }

    /// Draws a compact selection (`terrain_core::lod::GeomipTable::select_runs`): its single
    /// patches as [`GeomorphRenderer::render_with`] does, and the patches of its runs (each at
    /// the coarsest level, tween 0, every edge at that level) by one instanced draw per pass
    /// over all runs, without a per-patch list: the same image as the runs expanded
    /// ([`GeomipRuns::expand`]) drawn one by one. `runs.coarsest` must be this renderer's
    /// coarsest level (`log2(patch_cells)`). With [`MorphSource::Cpu`] the heights are those
    /// of the single patches (the CPU's morph of a run's patch is its true heights, which the
    /// vertex stage reads).
    pub fn render_runs(
        &mut self,
        camera: &Camera,
        runs: &GeomipRuns,
        source: MorphSource<'_>,
        options: &GeomorphOptions,
    ) -> Result<GeomorphFrameStats, RenderError> {
        self.check_coarsest(runs)?;
        self.draw(None, camera, &runs.patches, &runs.runs, source, options)
    }

    /// [`GeomorphRenderer::render_runs`] from the pages of `pages`
    /// ([`GeomorphRenderer::render_paged`]).
    pub fn render_paged_runs(
        &mut self,
        pages: &mut TerrainRenderer,
        camera: &Camera,
        runs: &GeomipRuns,
        options: &GeomorphOptions,
    ) -> Result<GeomorphFrameStats, RenderError> {
        self.check_coarsest(runs)?;
        self.draw(Some(pages), camera, &runs.patches, &runs.runs, MorphSource::Shader, options)
    }

    /// Refuses runs of another coarsest level than the renderer's.
    fn check_coarsest(&self, runs: &GeomipRuns) -> Result<(), RenderError> {
        let coarsest = self.lib.patch_cells.trailing_zeros();
        if !runs.runs.is_empty() && u32::from(runs.coarsest) != coarsest {
            return Err(RenderError::InvalidConfig(format!(
                "runs at level {}; patches of {} cells are coarsest at level {coarsest}",
                runs.coarsest, self.lib.patch_cells
            )));
        }
        Ok(())
    }

    /// [`GeomorphRenderer::render`] with the heights from `source`: the vertex stage's morph,
    /// the true heights (static geo-mipmapping) or heights morphed on the CPU and uploaded.
    pub fn render_with(
        &mut self,
        camera: &Camera,
        lods: &[PatchLod],
        source: MorphSource<'_>,
        options: &GeomorphOptions,
    ) -> Result<GeomorphFrameStats, RenderError> {
        self.draw(None, camera, lods, &[], source, options)
    }

    /// Draws `lods` as seen by `camera` from the resident pages of `pages` (the paged
    /// renderer given to [`GeomorphRenderer::new_paged`]; a sample on no resident page reads
    /// 0, so callers draw only patches over resident pages): one pass, materials blended per
    /// fragment. Waits for the device.
    pub fn render_paged(
        &mut self,
        pages: &mut TerrainRenderer,
        camera: &Camera,
        lods: &[PatchLod],
        options: &GeomorphOptions,
    ) -> Result<GeomorphFrameStats, RenderError> {
        self.draw(Some(pages), camera, lods, &[], MorphSource::Shader, options)
    }

    /// The runs as `GmRun`s (each with the run patches before it) and their patch count;
    /// refuses a run that is empty or reaches past the grid, and more run patches than the
    /// instance indices hold.
    fn gpu_runs(&self, runs: &[PatchRun]) -> Result<(Vec<GpuRun>, u32), RenderError> {
        let n = u64::from(self.lib.patch_cells);
        let [w, h] = self.grid.map(u64::from);
        let mut out = Vec::with_capacity(runs.len());
        let mut total = 0u64;
        let limit = (u64::from(u32::MAX) - u64::from(RUN_INSTANCES)) / MATERIALS as u64;
        for (index, r) in runs.iter().enumerate() {
            let x = (u64::from(r.i) + u64::from(r.width)).saturating_sub(1) * n;
            let y = (u64::from(r.j) + u64::from(r.height)).saturating_sub(1) * n;
            if r.width == 0 || r.height == 0 || x + 1 >= w || y + 1 >= h {
                return Err(RenderError::InvalidConfig(format!(
                    "run {index} ({r:?}) is empty or reaches past the {w} x {h} grid"
                )));
            }
            out.push(GpuRun { first: [r.i, r.j], width: r.width, start: total as u32 });
            total += r.patches();
            if total > limit {
                return Err(RenderError::InvalidConfig(format!(
                    "more than {limit} patches in runs"
                )));
            }
        }
        Ok((out, total as u32))
    }

    fn draw(
        &mut self,
        pages: Option<&mut TerrainRenderer>,
        camera: &Camera,
        lods: &[PatchLod],
        runs: &[PatchRun],
        source: MorphSource<'_>,
        options: &GeomorphOptions,
    ) -> Result<GeomorphFrameStats, RenderError> {
        let start = Instant::now();
        let (tw, th) = self.size();
        let camera = camera.with_viewport(f64::from(tw), f64::from(th));
        let n = self.lib.patch_cells;
        let gpu: Vec<GpuMorphPatch> = lods.iter().map(|p| GpuMorphPatch::from_lod(p, n)).collect();
        let (gpu_runs, run_patches) = self.gpu_runs(runs)?;
        let cpu_heights = match source {
            MorphSource::Cpu(h) => Some(h),
            _ => None,
        };
        self.upload(pages, &camera, &gpu, (&gpu_runs, run_patches), cpu_heights, options)?;
        let mode = source.mode();
        if self.pipelines[mode].is_none() {
            let paged = matches!(self.heights, Heights::Paged(..));
            self.pipelines[mode] =
                Some(make_pipelines(&self.device, &self.module, &self.render_layout, paged, mode));
        }
        // Paged mode: the base pass only (it blends every material per fragment).
        let materials = match &self.heights {
            Heights::Whole { materials, .. } => Some(materials),
            Heights::Paged(..) => None,
        };
        // LOD colours replace the materials: the base pass only.
        let passes_of = if materials.is_some() && !options.lod_colours { MATERIALS } else { 1 };
        let [w, h] = self.grid;
        let mut stats = GeomorphFrameStats {
            patches: lods.len() + run_patches as usize,
            triangles: 0,
            passes_drawn: 0,
            passes_skipped: 0,
            upload_bytes: 0,
            cpu_ms: 0.0,
            adapter: self.adapter.clone(),
        };
        // One index list per pass: every drawn patch's configuration (and, in the base pass,
        // its skirts) with the patch's index in the high bits, so a pass is one indexed draw
        // (software rasterisers pay per draw) and vertex_index carries patch and local id.
        let mut indices: Vec<u32> = Vec::new();
        let mut passes: Vec<(usize, u32, u32)> = Vec::new();
        for material in 0..passes_of {
            let first = indices.len() as u32;
            for (k, (p, lod)) in gpu.iter().zip(lods).enumerate() {
                if materials.is_some_and(|m| !m.draws(lod.i, lod.j, material)) {
                    stats.passes_skipped += 1;
                    continue;
                }
                stats.passes_drawn += 1;
                let tag = (k as u32) << PATCH_SHIFT;
                let tris = self.lib.triangles(p);
                indices.extend(tris.iter().map(|&id| id | tag));
                if material == 0 {
                    stats.triangles += (tris.len() / 3) as u64;
                    if options.skirt_depth_m > 0.0 {
                        let (x1, y1) = (p.origin[0] + n, p.origin[1] + n);
                        // South, east, north, west: skirts only below shared edges.
                        let interior = [p.origin[1] > 0, x1 < w - 1, y1 < h - 1, p.origin[0] > 0];
                        for (edge, _) in interior.iter().enumerate().filter(|e| *e.1) {
                            let (s0, c) = self.lib.skirts[MeshLibrary::config(p)][edge];
                            let ids = &self.lib.ids[s0 as usize..(s0 + c) as usize];
                            indices.extend(ids.iter().map(|&id| id | tag));
                        }
                    }
                }
            }
            passes.push((material, first, indices.len() as u32 - first));
        }
        // The runs' patches: one triangle list (the coarsest level's, every edge at it) and,
        // in the base pass, its four skirts, each skirt's ids tagged with 1 + its edge (the
        // vertex stage hides those below the grid's border), drawn per pass once per run patch
        // (instances).
        let coarse = GpuMorphPatch {
            level: n.trailing_zeros(),
            edge_level: [n.trailing_zeros(); 4],
            ..GpuMorphPatch::default()
        };
        let run_first = indices.len() as u32;
        let mesh = self.lib.triangles(&coarse);
        indices.extend_from_slice(mesh);
        if options.skirt_depth_m > 0.0 {
            for (edge, &(s0, c)) in self.lib.skirts[MeshLibrary::config(&coarse)].iter().enumerate()
            {
                let tag = (edge as u32 + 1) << PATCH_SHIFT;
                let ids = &self.lib.ids[s0 as usize..(s0 + c) as usize];
                indices.extend(ids.iter().map(|&id| id | tag));
            }
        }
        let run_ids = indices.len() as u32 - run_first;
        if run_patches > 0 {
            stats.triangles += u64::from(run_patches) * (mesh.len() / 3) as u64;
            match materials.filter(|_| passes_of > 1) {
                Some(m) => {
                    for r in runs {
                        for j in r.j..r.j + r.height {
                            for i in r.i..r.i + r.width {
                                let drawn = (0..passes_of).filter(|&k| m.draws(i, j, k)).count();
                                stats.passes_drawn += drawn;
                                stats.passes_skipped += passes_of - drawn;
                            }
                        }
                    }
                }
                None => stats.passes_drawn += run_patches as usize,
            }
        }
        stats.upload_bytes = (size_of::<GpuFrame>()
            + gpu.len() * size_of::<GpuMorphPatch>()
            + gpu_runs.len() * size_of::<GpuRun>()
            + indices.len() * 4
            + cpu_heights.map_or(0, |h| h.len() * 4)) as u64;
        let bytes = (indices.len().max(4) * 4) as u64;
        if self.indices.as_ref().is_none_or(|b| b.size() < bytes) {
            self.indices = Some(self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("geomorph frame indices"),
                size: bytes.next_power_of_two(),
                usage: wgpu::BufferUsages::INDEX | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }));
        }
        let index_buffer = self.indices.as_ref().expect("allocated above");
        if !indices.is_empty() {
            self.queue.write_buffer(index_buffer, 0, bytemuck::cast_slice(&indices));
        }
        let group = &self.bound.as_ref().expect("uploaded").group;
        let pipelines = self.pipelines[mode].as_ref().expect("built above");
        let mut encoder = self.device.create_command_encoder(&Default::default());
        {
            let [r, g, b, a] = self.background.map(|c| f64::from(c) / 255.0);
            let mut pass = self.target.begin_pass(&mut encoder, wgpu::Color { r, g, b, a });
            pass.set_bind_group(0, group, &[]);
            pass.set_index_buffer(index_buffer.slice(..), wgpu::IndexFormat::Uint32);
            for &(material, first, count) in &passes {
                pass.set_pipeline(if material == 0 { &pipelines.base } else { &pipelines.overlay });
                if count > 0 {
                    // The instance index is the material.
                    pass.draw_indexed(
                        first..first + count,
                        0,
                        material as u32..material as u32 + 1,
                    );
                }
                if run_patches > 0 {
                    // Instance RUN_INSTANCES + material * run_patches + k: run patch k.
                    let i0 = RUN_INSTANCES + material as u32 * run_patches;
                    let ids = if material == 0 { run_ids } else { mesh.len() as u32 };
                    pass.draw_indexed(run_first..run_first + ids, 0, i0..i0 + run_patches);
                }
            }
        }
        self.queue.submit([encoder.finish()]);
        stats.cpu_ms = start.elapsed().as_secs_f64() * 1e3;
        self.device.poll(wgpu::PollType::wait_indefinitely()).map_err(GpuError::from)?;
        Ok(stats)
    }

    /// The colour image of the last [`GeomorphRenderer::render`].
    pub fn read_image(&self) -> Result<RgbaImage, GpuError> {
        self.target.read_color_with(&self.device, &self.queue)
    }

    /// Test hook: the morphed position of every `(patch index, local id)` in `items`, computed
    /// on the device by the vertex stage's own functions, for the anchor a camera at
    /// `camera_position` uses. Compare with [`super::morph::MorphGrid::relative_position`].
    pub fn morph_read_back(
        &mut self,
        camera_position: DVec3,
        lods: &[GpuMorphPatch],
        items: &[[u32; 2]],
    ) -> Result<Vec<[f32; 4]>, RenderError> {
        self.read_back(None, camera_position, lods, items)
    }

    /// Test hook: [`GeomorphRenderer::morph_read_back`] of a paged renderer over the pages of
    /// `pages`. Compare with [`super::morph::MorphGrid::relative_position`] over the pages'
    /// CPU mirror ([`crate::paged::PagedHeights`]).
    pub fn morph_read_back_paged(
        &mut self,
        pages: &mut TerrainRenderer,
        camera_position: DVec3,
        lods: &[GpuMorphPatch],
        items: &[[u32; 2]],
    ) -> Result<Vec<[f32; 4]>, RenderError> {
        self.read_back(Some(pages), camera_position, lods, items)
    }

    fn read_back(
        &mut self,
        pages: Option<&mut TerrainRenderer>,
        camera_position: DVec3,
        lods: &[GpuMorphPatch],
        items: &[[u32; 2]],
    ) -> Result<Vec<[f32; 4]>, RenderError> {
        let camera = Camera::from_yaw_pitch(camera_position, 0.0, 0.0);
        self.upload(pages, &camera, lods, (&[], 0), None, &GeomorphOptions::default())?;
        let group = &self.bound.as_ref().expect("uploaded").group;
        let n = items.len().max(1) as u64;
        let groups = (n as u32).div_ceil(64);
        let items_buf = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("morph items"),
            size: 8 * n,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        self.queue.write_buffer(&items_buf, 0, bytemuck::cast_slice(items));
        let out = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("morph read-back"),
            size: 16 * n,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let debug_group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("geomorph debug"),
            layout: &self.debug_layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: items_buf.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: out.as_entire_binding() },
            ],
        });
        let mut encoder = self.device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.debug);
            pass.set_bind_group(0, group, &[]);
            pass.set_bind_group(1, &debug_group, &[]);
            pass.dispatch_workgroups(groups, 1, 1);
        }
        self.queue.submit([encoder.finish()]);
        let bytes = read_buffer(&self.device, &self.queue, &out, 16 * n)?;
        let mut v: Vec<[f32; 4]> = bytemuck::pod_collect_to_vec(&bytes);
        v.truncate(items.len());
        Ok(v)
    }
}

/// The base and material pipelines of `geomorph.wgsl` with `MORPH_MODE = mode`
/// ([`MorphSource::mode`]). Paged mode shades per fragment from the pages (`fs_paged`); a whole
/// heightmap from its lightmap and alpha maps (`fs`).
fn make_pipelines(
    device: &wgpu::Device,
    module: &wgpu::ShaderModule,
    layout: &wgpu::PipelineLayout,
    paged: bool,
    mode: usize,
) -> Pipelines {
    let fragment = if paged { "fs_paged" } else { "fs" };
    let constants = [("PAGED", if paged { 1.0 } else { 0.0 }), ("MORPH_MODE", mode as f64)];
    let options =
        || wgpu::PipelineCompilationOptions { constants: &constants, ..Default::default() };
    let pipeline = |label, depth: wgpu::DepthStencilState, target: wgpu::ColorTargetState| {
        device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some(label),
            layout: Some(layout),
            vertex: wgpu::VertexState {
                module,
                entry_point: Some("vs"),
                compilation_options: options(),
                buffers: &[],
            },
            // No culling: skirts are seen from both sides.
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: Some(depth),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module,
                entry_point: Some(fragment),
                compilation_options: options(),
                targets: &[Some(target)],
            }),
            multiview_mask: None,
            cache: None,
        })
    };
    let base = pipeline("geomorph base", OffscreenTarget::depth_state(), COLOR_FORMAT.into());
    // Material passes: the same vertices (the position is @invariant), depth equal or
    // nearer, no depth writes, blended over the colour, alpha kept from the base pass.
    let overlay = pipeline(
        "geomorph material",
        wgpu::DepthStencilState {
            depth_write_enabled: Some(false),
            depth_compare: Some(wgpu::CompareFunction::LessEqual),
            ..OffscreenTarget::depth_state()
        },
        wgpu::ColorTargetState {
            format: COLOR_FORMAT,
            blend: Some(wgpu::BlendState::ALPHA_BLENDING),
            write_mask: wgpu::ColorWrites::COLOR,
        },
    );
    Pipelines { base, overlay }
}
