//! [`TerrainRenderer`]: the heightmap on the device, the pipelines of `terrain.wgsl`, the
//! tessellation of the last patch list (reused while the list is unchanged), timestamps, and
//! the read-back hooks the tests compare with the CPU reference.

use std::collections::HashMap;
use std::fmt;
use std::mem::size_of;
use std::time::Instant;

use bytemuck::{Pod, Zeroable};
use glam::{DVec2, DVec3, Vec3};
use terrain_core::Heightmap;
use terrain_core::geometry::Camera;

use super::{DrawPatch, ExtraTriangles, RenderConfig, RenderOptions};
use crate::device::{GpuContext, GpuError, GpuFeatures, read_buffer, upload_texture};
use crate::paged::{PageClass, PageError, PageLayout, check_page};
use crate::target::{COLOR_FORMAT, OffscreenTarget, RgbaImage};
use crate::tess::{
    EdgeSpacing, GpuDomainPoint, GpuTessOutput, GpuTessellator, PatchFactors, QuadLayout,
    tessellate,
};

/// The shader source.
/// The shader module: `terrain.wgsl` with the paged lookup (`paged_lookup.wgsl`) after it.
pub(crate) const SHADER: &str =
    concat!(include_str!("terrain.wgsl"), "\n", include_str!("../paged_lookup.wgsl"));

/// `Frame` in `terrain.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
struct GpuFrame {
    view_proj: [[f32; 4]; 4],
    sun: [f32; 4],
    spacing: [f32; 2],
    grid_max: [u32; 2],
    height_offset: f32,
    skirt_depth: f32,
    height_min: f32,
    height_range: f32,
    flags: u32,
    pad: [u32; 3],
}

/// Words of the page table before its entries: 8 of layout, then 8 per slot class (first
/// row in the atlas, slots per row, slot width, slot height, stride, 3 unused).
const TABLE_HEADER: usize = 8 + 8 * MAX_CLASSES;
/// Slot classes a paged renderer may have.
const MAX_CLASSES: usize = 16;

/// One class of slots of the page atlas, a band of rows of it.
#[derive(Debug)]
struct SlotClass {
    stride: u32,
    lattice: [u32; 2],
    /// First atlas row of the band.
    y0: u32,
    per_row: u32,
    capacity: u32,
    free: Vec<u32>,
}

const FLAG_WIREFRAME: u32 = 1;
const FLAG_TEXTURE: u32 = 2;
const FLAG_LOD: u32 = 4;

/// One patch as the shaders read it (`PatchRect` in terrain.wgsl): its rect and its LOD colour
/// ([`super::lod_colour`], drawn with [`RenderOptions::lod_colours`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
struct GpuPatchRect {
    rect: [u32; 4],
    lod_colour: [f32; 4],
}

const _: () = {
    assert!(size_of::<GpuFrame>() == 128);
    assert!(size_of::<GpuDomainPoint>() == 16);
};

/// What one call of [`TerrainRenderer::render`] or [`TerrainRenderer::render_to_view`] drew
/// and what it cost.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameStats {
    /// Patches drawn (culled ones included).
    pub patches: usize,
    /// Non-degenerate triangles (fractional-even layouts contain degenerate ones; those are
    /// drawn but not counted).
    pub triangles: u64,
    /// Vertices the tessellator generated (one per domain point).
    pub vertices: u64,
    /// Whether this frame ran the tessellator (false: the patch list was unchanged and its
    /// tessellation was reused).
    pub tessellated: bool,
    /// Compute + draw batches the frame was split into (1 unless its tessellated points or
    /// indices exceed the device's largest storage binding, see
    /// [`TerrainRenderer::batch_limit_bytes`]).
    pub batches: usize,
    /// CPU time to prepare, encode and submit the frame, milliseconds. On GL this includes
    /// most of the driver's work: wgpu's GL backend replays the commands at submission, and
    /// llvmpipe executes them there.
    pub cpu_ms: f64,
    /// GPU time of every pass of the frame, milliseconds: `None` without timestamp queries or
    /// when a pass's timestamps cannot be trusted (see [`FrameStats::gpu_note`]).
    pub gpu_ms: Option<f64>,
    /// GPU time of the tessellation (compute) pass, when it ran and its timestamps are trustworthy.
    pub gpu_tess_ms: Option<f64>,
    /// GPU time of the render pass, where timestamp queries exist.
    pub gpu_draw_ms: Option<f64>,
    /// Why a GPU time is missing, if one is.
    pub gpu_note: Option<&'static str>,
    /// The adapter ([`GpuContext::describe`]).
    pub adapter: String,
}

impl FrameStats {
    /// The GPU time as a user reads it: `"12.3 ms (tessellation 2.0 + draw 10.3)"`, or
    /// `"n/a (untrustworthy on lavapipe); draw pass 10.3 ms"`.
    pub fn gpu_text(&self) -> String {
        let f = |x: f64| format!("{x:.2}");
        match (self.gpu_ms, self.gpu_tess_ms, self.gpu_draw_ms) {
            (Some(t), Some(a), Some(b)) => {
                format!("{} ms (tessellation {} + draw {})", f(t), f(a), f(b))
            }
            (Some(t), None, _) => format!("{} ms (draw only; tessellation reused)", f(t)),
            (None, _, Some(b)) => {
                format!("n/a ({}); draw pass {} ms", self.gpu_note.unwrap_or("unknown"), f(b))
            }
            _ => format!("n/a ({})", self.gpu_note.unwrap_or("unknown")),
        }
    }
}

impl fmt::Display for FrameStats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "patches {}, triangles {}, vertices {}, CPU {:.2} ms, GPU {}, adapter {}",
            self.patches,
            self.triangles,
            self.vertices,
            self.cpu_ms,
            self.gpu_text(),
            self.adapter
        )
    }
}

/// Why the renderer could not be built or could not draw.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RenderError {
    /// A device error (limits, read-back).
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// A texture exceeds the device's 2D texture limit.
    #[error("{what} is {width} x {height} samples; the device allows {maximum} x {maximum}")]
    TextureTooLarge {
        /// Which texture.
        what: &'static str,
        /// Its width.
        width: u32,
        /// Its height.
        height: u32,
        /// The device's limit per side.
        maximum: u32,
    },
    /// A patch's rect is empty or starts outside the grid.
    #[error(
        "patch {index} has rect {rect:?}: empty or starting outside the {width} x {height} grid"
    )]
    BadPatch {
        /// Position in the list.
        index: usize,
        /// The rect.
        rect: [u32; 4],
        /// Grid width in samples.
        width: u32,
        /// Grid height in samples.
        height: u32,
    },
    /// Extra triangles name a patch or a vertex that does not exist.
    #[error("extra triangles: {0}")]
    BadExtra(String),
    /// The caller's configuration is unusable.
    #[error("invalid render configuration: {0}")]
    InvalidConfig(String),
    /// A page of heights was refused.
    #[error(transparent)]
    Page(#[from] PageError),
}

/// The tessellation of one patch list, with what draws it: one or more batches (consecutive
/// runs of patches whose points and indices each fit the device's largest storage binding).
#[derive(Debug)]
struct Tessellation {
    patches: Vec<DrawPatch>,
    batches: Vec<Batch>,
    triangles: u64,
    vertices: u64,
    skirts: Option<Skirts>,
    /// Every patch's rect (binding 2; extra triangles and skirts name patches by their
    /// position in the whole list).
    rects: wgpu::Buffer,
    /// Binds `rects` with the first batch's points and indices: for extra triangles, skirts
    /// and read-backs of arbitrary points.
    whole_group: wgpu::BindGroup,
}

/// One compute + draw batch of a [`Tessellation`].
#[derive(Debug)]
struct Batch {
    /// Position of the batch's first patch in the whole list.
    first: usize,
    out: GpuTessOutput,
    bind_group: wgpu::BindGroup,
}

#[derive(Debug)]
struct Skirts {
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    index_count: u32,
}

#[derive(Debug)]
struct Timer {
    tess: wgpu::QuerySet,
    draw: wgpu::QuerySet,
    tess_resolve: wgpu::Buffer,
    draw_resolve: wgpu::Buffer,
    period_ns: f64,
}

/// The surface of every tessellated point, computed on the device by the shader's own
/// functions ([`TerrainRenderer::surface_read_back`]).
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceReadBack {
    /// The tessellator's points.
    pub points: Vec<GpuDomainPoint>,
    /// Per point: position relative to the anchor (xyz) and absolute height (w).
    pub positions: Vec<[f32; 4]>,
    /// Per point: unit normal (xyz).
    pub normals: Vec<[f32; 4]>,
}

/// The two render pipelines of one colour format.
#[derive(Debug)]
struct Pipelines {
    /// Vertices from the tessellator's point buffer, indexed.
    indexed: wgpu::RenderPipeline,
    /// Vertices pulled from the index buffer by the vertex stage (wireframe's barycentrics).
    pulled: wgpu::RenderPipeline,
    /// Extra triangles with their own heights: the points' buffer and a buffer of heights.
    explicit: wgpu::RenderPipeline,
}

impl Pipelines {
    /// Builds both pipelines for colour targets of `format`; sRGB formats get the shader's
    /// `SRGB_TARGET` (decode before the store re-encodes).
    fn new(
        device: &wgpu::Device,
        module: &wgpu::ShaderModule,
        layout: &wgpu::PipelineLayout,
        format: wgpu::TextureFormat,
    ) -> Self {
        let srgb = [("SRGB_TARGET", 1.0)];
        let fragment_options = wgpu::PipelineCompilationOptions {
            constants: if format.is_srgb() { &srgb } else { &[] },
            ..Default::default()
        };
        let attributes = wgpu::vertex_attr_array![0 => Float32x2, 1 => Uint32, 2 => Uint32];
        let vertex_buffers = [Some(wgpu::VertexBufferLayout {
            array_stride: size_of::<GpuDomainPoint>() as u64,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &attributes,
        })];
        let pipeline = |entry_point: &str, buffers: &[Option<wgpu::VertexBufferLayout<'_>>]| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(entry_point),
                layout: Some(layout),
                vertex: wgpu::VertexState {
                    module,
                    entry_point: Some(entry_point),
                    compilation_options: Default::default(),
                    buffers,
                },
                // No culling: skirts are seen from both sides, and a view from below is legal.
                primitive: wgpu::PrimitiveState::default(),
                depth_stencil: Some(OffscreenTarget::depth_state()),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module,
                    entry_point: Some("fs"),
                    compilation_options: fragment_options.clone(),
                    targets: &[Some(format.into())],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let height_attribute = wgpu::vertex_attr_array![3 => Float32];
        let with_heights = [
            vertex_buffers[0].clone(),
            Some(wgpu::VertexBufferLayout {
                array_stride: size_of::<f32>() as u64,
                step_mode: wgpu::VertexStepMode::Vertex,
                attributes: &height_attribute,
            }),
        ];
        Self {
            indexed: pipeline("vs_indexed", &vertex_buffers),
            pulled: pipeline("vs_pulled", &[]),
            explicit: pipeline("vs_explicit", &with_heights),
        }
    }
}

/// Where a frame's colour goes: the renderer's own RGBA8 texture, or a caller's view.
#[derive(Clone, Copy, Debug)]
enum ColorTarget<'a> {
    Offscreen,
    View(&'a wgpu::TextureView, wgpu::TextureFormat),
}

/// Draws a heightmap from a list of patches into an offscreen RGBA8 target
/// ([`TerrainRenderer::render`]) or into a colour view the caller owns, such as a window
/// surface's texture ([`TerrainRenderer::render_to_view`]).
#[derive(Debug)]
pub struct TerrainRenderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    /// For the format capabilities of [`TerrainRenderer::render_to_view`]'s targets.
    gpu_adapter: wgpu::Adapter,
    features: GpuFeatures,
    adapter: String,
    target: OffscreenTarget,
    tessellator: GpuTessellator,
    layout: wgpu::BindGroupLayout,
    debug_layout: wgpu::BindGroupLayout,
    module: wgpu::ShaderModule,
    render_layout: wgpu::PipelineLayout,
    /// Per colour format; [`COLOR_FORMAT`]'s built with the renderer, others on first use.
    pipelines: HashMap<wgpu::TextureFormat, Pipelines>,
    debug: wgpu::ComputePipeline,
    frame: wgpu::Buffer,
    col_x: wgpu::Buffer,
    row_y: wgpu::Buffer,
    heights: wgpu::TextureView,
    /// The page atlas (`heights` views it).
    atlas: wgpu::Texture,
    page_table: wgpu::Buffer,
    /// The page table as uploaded (header, then slot + 1 per page, 0 = not resident).
    table: Vec<u32>,
    table_dirty: bool,
    page_layout: PageLayout,
    /// Resident page to (class, slot).
    slot_of: HashMap<[u32; 2], (usize, u32)>,
    classes: Vec<SlotClass>,
    color: wgpu::TextureView,
    sampler: wgpu::Sampler,
    has_texture: bool,
    grid: [u32; 2],
    origin: DVec2,
    spacing: DVec2,
    height_min: f32,
    height_max: f32,
    sun: Vec3,
    background: [u8; 4],
    anchor: Option<DVec3>,
    tess: Option<Tessellation>,
    counts: HashMap<[u32; 6], (u64, u64)>,
    timer: Option<Timer>,
    /// A smaller batch limit than the device's (tests).
    forced_batch_limit: Option<u64>,
}

/// A buffer of `usage` (plus `COPY_DST`) holding `bytes`, at least 16 bytes long (wgpu refuses
/// empty bindings), written through the queue.
fn upload(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    label: &str,
    bytes: &[u8],
    usage: wgpu::BufferUsages,
) -> wgpu::Buffer {
    let buf = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: (bytes.len() as u64).max(16),
        usage: usage | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    queue.write_buffer(&buf, 0, bytes);
    buf
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

/// The clear colour of `background` (sRGB-encoded bytes, as the shader's colours are): as it is
/// for a unorm target, decoded to linear for an sRGB target (which encodes it again).
fn clear_color(background: [u8; 4], srgb: bool) -> wgpu::Color {
    let [r, g, b, a] = background.map(|c| f64::from(c) / 255.0);
    let decode = |c: f64| {
        if !srgb {
            c
        } else if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    };
    wgpu::Color { r: decode(r), g: decode(g), b: decode(b), a }
}

/// Factor bits: the cache key of a patch's counts.
fn factor_key(f: &PatchFactors) -> [u32; 6] {
    let [a, b, c, d] = f.outer.map(f32::to_bits);
    let [e, g] = f.inner.map(f32::to_bits);
    [a, b, c, d, e, g]
}

impl TerrainRenderer {
    /// Uploads `hm` (as an R32Float texture; it must fit the device's 2D texture limit) and the
    /// colour texture, if any, and builds the pipelines and a `config.width` x `config.height`
    /// target. This is the paged renderer with one page covering the grid
    /// ([`PageLayout::whole`]), resident.
    pub fn new(
        ctx: &GpuContext,
        hm: &Heightmap,
        config: &RenderConfig,
    ) -> Result<Self, RenderError> {
        let whole = [PageClass { stride: 1, capacity: 1 }];
        let mut r = Self::build(ctx, PageLayout::whole(hm), &whole, [hm.min(), hm.max()], config)?;
        r.set_page([0, 0], hm.data())?;
        Ok(r)
    }

    /// A renderer of a paged grid (see [`crate::paged`]): an atlas of `capacity` page slots
    /// (it must fit the device's 2D texture limit) and a page table, no page resident. Pages
    /// come and go with [`TerrainRenderer::set_page`] and [`TerrainRenderer::remove_page`];
    /// `height_range` (lowest, highest) scales the colour ramp. Never allocates the grid: the
    /// device holds the resident pages and one `f32` per column and per row.
    pub fn new_paged(
        ctx: &GpuContext,
        layout: PageLayout,
        capacity: u32,
        height_range: [f32; 2],
        config: &RenderConfig,
    ) -> Result<Self, RenderError> {
        Self::build(ctx, layout, &[PageClass { stride: 1, capacity }], height_range, config)
    }

    /// A paged renderer whose atlas holds slots of several classes ([`PageClass`]: pages
    /// stored at a stride, see [`crate::paged::classes_for_budget`]), one region of the atlas
    /// per class; at most 16 classes, strides the layout allows, each at most once.
    pub fn new_paged_classes(
        ctx: &GpuContext,
        layout: PageLayout,
        classes: &[PageClass],
        height_range: [f32; 2],
        config: &RenderConfig,
    ) -> Result<Self, RenderError> {
        Self::build(ctx, layout, classes, height_range, config)
    }

    fn build(
        ctx: &GpuContext,
        pages: PageLayout,
        classes: &[PageClass],
        height_range: [f32; 2],
        config: &RenderConfig,
    ) -> Result<Self, RenderError> {
        let device = &ctx.device;
        let maximum = device.limits().max_texture_dimension_2d;
        let [width, height] = pages.grid;
        if width == 0 || height == 0 || !(pages.spacing.x > 0.0 && pages.spacing.y > 0.0) {
            return Err(RenderError::InvalidConfig(format!(
                "a grid of {width} x {height} samples with spacing {}",
                pages.spacing
            )));
        }
        let single = classes.len() == 1 && classes[0].capacity <= 1;
        if classes.is_empty() || classes.len() > MAX_CLASSES {
            return Err(RenderError::InvalidConfig(format!(
                "{} page slot classes (allowed 1 to {MAX_CLASSES})",
                classes.len()
            )));
        }
        let mut slot_classes: Vec<SlotClass> = Vec::new();
        for c in classes {
            let lattice = pages.lattice(c.stride).filter(|_| {
                !slot_classes.iter().any(|s| s.stride == c.stride)
                    && u64::from(c.capacity) <= crate::paged::MAX_CLASS_SLOTS
            });
            let Some(lattice) = lattice else {
                return Err(RenderError::InvalidConfig(format!(
                    "page slot class of stride {} and {} slots (strides allowed: {:?}, each once)",
                    c.stride,
                    c.capacity,
                    pages.strides()
                )));
            };
            slot_classes.push(SlotClass {
                stride: c.stride,
                lattice,
                y0: 0,
                per_row: 1,
                capacity: c.capacity.max(1),
                free: Vec::new(),
            });
        }
        // One atlas: each class a band of rows of slots, as wide as the widest class needs.
        let atlas_w = slot_classes
            .iter()
            .map(|c| (maximum / c.lattice[0].max(1)).max(1).min(c.capacity) * c.lattice[0])
            .max()
            .unwrap_or(1);
        let mut atlas_h = 0u64;
        for c in &mut slot_classes {
            c.per_row = (atlas_w / c.lattice[0]).max(1).min(c.capacity);
            c.y0 = atlas_h.min(u64::from(u32::MAX)) as u32;
            atlas_h += u64::from(c.capacity.div_ceil(c.per_row)) * u64::from(c.lattice[1]);
            c.free = (0..c.capacity).rev().collect();
        }
        if slot_classes.iter().any(|c| c.lattice[0] > maximum) || atlas_h > u64::from(maximum) {
            return Err(RenderError::TextureTooLarge {
                what: if single { "the heightmap" } else { "the page atlas" },
                width: atlas_w,
                height: atlas_h.min(u64::from(u32::MAX)) as u32,
                maximum,
            });
        }
        let atlas_h = atlas_h as u32;
        if config.width == 0
            || config.height == 0
            || config.width > maximum
            || config.height > maximum
        {
            return Err(RenderError::InvalidConfig(format!(
                "target size {} x {} (allowed 1 to {maximum} per side)",
                config.width, config.height
            )));
        }
        let sun = glam::DVec3::from(config.sun_direction);
        if !(sun.length() > 0.0 && sun.is_finite()) {
            return Err(RenderError::InvalidConfig(format!("sun direction {sun}")));
        }

        let size = |w, h| wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 };
        let upload = |label, format, w: u32, h: u32, bytes: &[u8], texel| {
            upload_texture(ctx, label, [w, h], format, bytes, texel)
        };
        let atlas = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("height pages"),
            size: size(atlas_w, atlas_h),
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::R32Float,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        let heights = atlas.create_view(&Default::default());
        let [pages_x, pages_y] = pages.pages();
        let cells = pages.cells();
        let mut table = vec![0u32; TABLE_HEADER + pages_x as usize * pages_y as usize];
        table[..4].copy_from_slice(&[cells[0], cells[1], pages_x, pages_y]);
        for (k, c) in slot_classes.iter().enumerate() {
            table[8 + 8 * k..8 + 8 * k + 5].copy_from_slice(&[
                c.y0,
                c.per_row,
                c.lattice[0],
                c.lattice[1],
                c.stride,
            ]);
        }
        let white = RgbaImage { width: 1, height: 1, pixels: vec![[255; 4]] };
        let image = config.texture.as_ref().unwrap_or(&white);
        if image.width > maximum || image.height > maximum {
            return Err(RenderError::TextureTooLarge {
                what: "the colour texture",
                width: image.width,
                height: image.height,
                maximum,
            });
        }
        if image.pixels.len() != (image.width * image.height) as usize || image.pixels.is_empty() {
            return Err(RenderError::InvalidConfig(format!(
                "colour texture of {} x {} has {} pixels",
                image.width,
                image.height,
                image.pixels.len()
            )));
        }
        let color = upload(
            "colour texture",
            wgpu::TextureFormat::Rgba8Unorm,
            image.width,
            image.height,
            bytemuck::cast_slice(&image.pixels),
            4,
        );
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("colour texture"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });

        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("terrain"),
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
                entry(5, texture(true)),
                entry(6, wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering)),
                entry(7, storage(true)),
                entry(8, storage(true)),
                entry(9, storage(true)),
            ],
        });
        let debug_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("terrain debug"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: storage(false),
                count: None,
            }],
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("terrain.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let render_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("terrain"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipelines = HashMap::from([(
            COLOR_FORMAT,
            Pipelines::new(device, &module, &render_layout, COLOR_FORMAT),
        )]);
        let debug_pipeline_layout =
            device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("terrain debug"),
                bind_group_layouts: &[Some(&layout), Some(&debug_layout)],
                immediate_size: 0,
            });
        let debug = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("debug_surface"),
            layout: Some(&debug_pipeline_layout),
            module: &module,
            entry_point: Some("debug_surface"),
            compilation_options: Default::default(),
            cache: None,
        });

        let buffer = |label, size: u64, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        use wgpu::BufferUsages as U;
        let frame = buffer("terrain frame", size_of::<GpuFrame>() as u64, U::UNIFORM | U::COPY_DST);
        let col_x = buffer("terrain columns", 4 * u64::from(width), U::STORAGE | U::COPY_DST);
        let row_y = buffer("terrain rows", 4 * u64::from(height), U::STORAGE | U::COPY_DST);
        let page_table = buffer("page table", 4 * table.len() as u64, U::STORAGE | U::COPY_DST);

        let timer = ctx.features.timestamp_query.then(|| {
            let set = |label| {
                device.create_query_set(&wgpu::QuerySetDescriptor {
                    label: Some(label),
                    ty: wgpu::QueryType::Timestamp,
                    count: 2,
                })
            };
            let resolve = |label| buffer(label, 16, U::QUERY_RESOLVE | U::COPY_SRC);
            Timer {
                tess: set("tessellation timestamps"),
                draw: set("draw timestamps"),
                tess_resolve: resolve("tessellation timestamps"),
                draw_resolve: resolve("draw timestamps"),
                period_ns: f64::from(ctx.queue.get_timestamp_period()),
            }
        });

        Ok(Self {
            device: ctx.device.clone(),
            queue: ctx.queue.clone(),
            gpu_adapter: ctx.adapter.clone(),
            features: ctx.features,
            adapter: ctx.describe(),
            target: OffscreenTarget::new(device, config.width, config.height),
            background: config.background,
            tessellator: GpuTessellator::new(device),
            layout,
            debug_layout,
            module,
            render_layout,
            pipelines,
            debug,
            frame,
            col_x,
            row_y,
            heights,
            atlas,
            page_table,
            table,
            table_dirty: true,
            page_layout: pages,
            slot_of: HashMap::new(),
            classes: slot_classes,
            color,
            sampler,
            has_texture: config.texture.is_some(),
            grid: [width, height],
            origin: pages.origin,
            spacing: pages.spacing,
            height_min: height_range[0],
            height_max: height_range[1].max(height_range[0]),
            sun: sun.normalize().as_vec3(),
            anchor: None,
            tess: None,
            counts: HashMap::new(),
            timer,
            forced_batch_limit: None,
        })
    }

    /// Makes `page` resident with `samples` ([`PageLayout::page_samples`] wide and high,
    /// row-major, south row first; see [`crate::paged`] for filling one from a coarse level),
    /// replacing what it held: [`TerrainRenderer::set_page_lattice`] with stride 1.
    pub fn set_page(&mut self, page: [u32; 2], samples: &[f32]) -> Result<(), PageError> {
        self.set_page_lattice(page, samples, 1)
    }

    /// Makes `page` resident with its lattice at `stride` ([`crate::paged::Page`]), in a slot
    /// of the class of that stride (a page changing stride moves class), replacing what it
    /// held. The page table reaches the device with the next frame.
    pub fn set_page_lattice(
        &mut self,
        page: [u32; 2],
        samples: &[f32],
        stride: u32,
    ) -> Result<(), PageError> {
        check_page(&self.page_layout, page, samples, stride)?;
        let Some(class) = self.classes.iter().position(|c| c.stride == stride) else {
            return Err(PageError::BadStride {
                page,
                stride,
                allowed: self.classes.iter().map(|c| c.stride).collect(),
            });
        };
        let slot = match self.slot_of.get(&page) {
            Some(&(c, s)) if c == class => s,
            held => {
                let c = &mut self.classes[class];
                let s =
                    c.free.pop().ok_or(PageError::Full { page, capacity: c.capacity, stride })?;
                if let Some(&(old, old_slot)) = held {
                    self.classes[old].free.push(old_slot);
                }
                self.slot_of.insert(page, (class, s));
                s
            }
        };
        let c = &self.classes[class];
        let [w, h] = c.lattice;
        let origin =
            wgpu::Origin3d { x: slot % c.per_row * w, y: c.y0 + slot / c.per_row * h, z: 0 };
        self.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &self.atlas,
                mip_level: 0,
                origin,
                aspect: wgpu::TextureAspect::All,
            },
            bytemuck::cast_slice(samples),
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(4 * w),
                rows_per_image: Some(h),
            },
            wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        );
        let index = TABLE_HEADER + (page[1] * self.table[2] + page[0]) as usize;
        let entry = ((class as u32) << 24) | (slot + 1);
        if self.table[index] != entry {
            self.table[index] = entry;
            self.table_dirty = true;
        }
        Ok(())
    }

    /// Drops `page` (its slot becomes free); returns whether it was resident.
    pub fn remove_page(&mut self, page: [u32; 2]) -> bool {
        let Some((class, slot)) = self.slot_of.remove(&page) else { return false };
        self.classes[class].free.push(slot);
        let index = TABLE_HEADER + (page[1] * self.table[2] + page[0]) as usize;
        self.table[index] = 0;
        self.table_dirty = true;
        true
    }

    /// The pages resident on the device, sorted.
    pub fn resident_pages(&self) -> Vec<[u32; 2]> {
        let mut v: Vec<[u32; 2]> = self.slot_of.keys().copied().collect();
        v.sort_unstable_by_key(|p| (p[1], p[0]));
        v
    }

    /// The page layout.
    pub fn page_layout(&self) -> &PageLayout {
        &self.page_layout
    }

    /// The page atlas's view and the page table, as `paged_lookup.wgsl` binds them (bindings
    /// 1 and 9), page-table changes written to the device first: the geomorph renderer draws
    /// from the same pages ([`crate::geomorph::GeomorphRenderer::new_paged`]).
    pub(crate) fn page_resources(&mut self) -> (wgpu::TextureView, wgpu::Buffer) {
        if self.table_dirty {
            self.queue.write_buffer(&self.page_table, 0, bytemuck::cast_slice(&self.table));
            self.table_dirty = false;
        }
        (self.heights.clone(), self.page_table.clone())
    }

    /// Lowest and highest height the colour ramp spans.
    pub fn height_range(&self) -> [f32; 2] {
        [self.height_min, self.height_max]
    }

    /// Page slots in the atlas, all classes.
    pub fn page_capacity(&self) -> u32 {
        self.classes.iter().map(|c| c.capacity).sum()
    }

    /// The atlas's slot classes (stride and slots each).
    pub fn page_classes(&self) -> Vec<PageClass> {
        self.classes.iter().map(|c| PageClass { stride: c.stride, capacity: c.capacity }).collect()
    }

    /// Bytes of the page atlas on the device.
    pub fn page_atlas_bytes(&self) -> u64 {
        u64::from(self.atlas.width()) * u64::from(self.atlas.height()) * 4
    }

    /// The target's width and height in pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.target.width(), self.target.height())
    }

    /// Sets the direction towards the sun (world frame, normalised here) for the next frames:
    /// the shading is per fragment, so nothing is rebuilt. Refuses a zero or non-finite one.
    pub fn set_sun_direction(&mut self, direction: [f64; 3]) -> Result<(), RenderError> {
        let sun = glam::DVec3::from(direction);
        if !(sun.length() > 0.0 && sun.is_finite()) {
            return Err(RenderError::InvalidConfig(format!("sun direction {sun}")));
        }
        self.sun = sun.normalize().as_vec3();
        Ok(())
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

    /// Where camera-relative positions are measured from for a camera at `position`: the
    /// position rounded to whole metres (so the anchor's own f32 part is exact).
    pub fn anchor_for(position: DVec3) -> DVec3 {
        position.round()
    }

    fn check_patches(&self, patches: &[DrawPatch]) -> Result<(), RenderError> {
        let [w, h] = self.grid;
        for (index, p) in patches.iter().enumerate() {
            let [x0, y0, x1, y1] = p.rect;
            // A rect may reach past the east and north border (quadtree nodes of a grid that is
            // not 2^k + 1 samples wide): domain points are clamped to the grid, as in
            // `terrain_core::lod::surface::patch_grid_point`. It must start inside the grid.
            if !(x0 < x1 && y0 < y1 && x0 + 1 < w && y0 + 1 < h) {
                return Err(RenderError::BadPatch { index, rect: p.rect, width: w, height: h });
            }
        }
        Ok(())
    }

    /// Counts (non-degenerate triangles, points) of the patch list, cached per factor set.
    fn count(&mut self, patches: &[DrawPatch]) -> (u64, u64) {
        let (mut triangles, mut points) = (0, 0);
        for p in patches {
            let (t, v) = *self.counts.entry(factor_key(&p.factors)).or_insert_with(|| {
                let mesh = tessellate(&p.factors);
                (mesh.non_degenerate_triangle_count() as u64, mesh.points.len() as u64)
            });
            triangles += t;
            points += v;
        }
        (triangles, points)
    }

    /// Bytes one batch's tessellated points or indices may take: the device's largest storage
    /// binding and buffer (or a smaller limit set by [`TerrainRenderer::force_batch_limit`]).
    /// A frame whose points or indices need more is drawn in several compute + draw batches
    /// ([`FrameStats::batches`]), never refused.
    pub fn batch_limit_bytes(&self) -> u64 {
        let l = self.device.limits();
        let device = l.max_storage_buffer_binding_size.min(l.max_buffer_size);
        self.forced_batch_limit.map_or(device, |f| f.min(device))
    }

    /// Test hook: splits frames into batches of at most `bytes` of points or indices (`None`:
    /// the device's limit). The next frame tessellates again.
    pub fn force_batch_limit(&mut self, bytes: Option<u64>) {
        self.forced_batch_limit = bytes;
        self.tess = None;
    }

    /// Consecutive runs of `patches` whose points (16 bytes each) and indices (4 bytes each)
    /// fit [`TerrainRenderer::batch_limit_bytes`]; `[start, end)` ranges, at least one.
    fn batch_ranges(&self, patches: &[DrawPatch]) -> Vec<(usize, usize)> {
        let limit = self.batch_limit_bytes();
        let mut out = Vec::new();
        let (mut start, mut points, mut indices) = (0, 0u64, 0u64);
        for (k, p) in patches.iter().enumerate() {
            let l = QuadLayout::new(&p.factors);
            let (pp, ii) = (16 * u64::from(l.point_count()), 12 * u64::from(l.triangle_count()));
            if k > start && (points + pp > limit || indices + ii > limit) {
                out.push((start, k));
                (start, points, indices) = (k, 0, 0);
            }
            points += pp;
            indices += ii;
        }
        out.push((start, patches.len()));
        out
    }

    fn rects_buffer(&self, label: &str, patches: &[DrawPatch]) -> wgpu::Buffer {
        let mut rects: Vec<GpuPatchRect> = patches
            .iter()
            .map(|p| {
                let [r, g, b] = super::lod_colour(super::lod_step(p));
                GpuPatchRect { rect: p.rect, lod_colour: [r, g, b, 1.0] }
            })
            .collect();
        if rects.is_empty() {
            rects.push(GpuPatchRect::default());
        }
        let buf = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: (rects.len() * size_of::<GpuPatchRect>()) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        self.queue.write_buffer(&buf, 0, bytemuck::cast_slice(&rects));
        buf
    }

    /// Makes `patches` the current tessellation (allocating its buffers, split into batches
    /// where the device's binding limit requires) unless it already is; returns whether the
    /// tessellator must run.
    fn prepare(&mut self, patches: &[DrawPatch]) -> Result<bool, RenderError> {
        if self.tess.as_ref().is_some_and(|t| t.patches == patches) {
            return Ok(false);
        }
        self.check_patches(patches)?;
        let mut batches = Vec::new();
        for (a, b) in self.batch_ranges(patches) {
            let part = &patches[a..b];
            let factors: Vec<PatchFactors> = part.iter().map(|p| p.factors).collect();
            let out = self.prepare_output(&factors)?;
            let rects = self.rects_buffer("patch rects", part);
            let bind_group = self.terrain_bind_group("terrain", &rects, &out.points, &out.indices);
            batches.push(Batch { first: a, out, bind_group });
        }
        let rects = self.rects_buffer("all patch rects", patches);
        let first = &batches[0].out;
        let whole_group =
            self.terrain_bind_group("terrain, all patches", &rects, &first.points, &first.indices);
        let (triangles, vertices) = self.count(patches);
        self.tess = Some(Tessellation {
            patches: patches.to_vec(),
            batches,
            triangles,
            vertices,
            skirts: None,
            rects,
            whole_group,
        });
        Ok(true)
    }

    fn prepare_output(&self, factors: &[PatchFactors]) -> Result<GpuTessOutput, GpuError> {
        self.tessellator.prepare_on(&self.device, &self.queue, factors)
    }

    /// Writes the per-frame uniform and, when the anchor moved, the column and row offsets.
    fn write_frame(&mut self, camera: &Camera, options: &RenderOptions) {
        if self.table_dirty {
            self.queue.write_buffer(&self.page_table, 0, bytemuck::cast_slice(&self.table));
            self.table_dirty = false;
        }
        let anchor = Self::anchor_for(camera.position);
        if self.anchor != Some(anchor) {
            let offsets = |n: u32, origin: f64, step: f64, at: f64| -> Vec<f32> {
                (0..n).map(|k| (origin + f64::from(k) * step - at) as f32).collect()
            };
            let cols = offsets(self.grid[0], self.origin.x, self.spacing.x, anchor.x);
            let rows = offsets(self.grid[1], self.origin.y, self.spacing.y, anchor.y);
            self.queue.write_buffer(&self.col_x, 0, bytemuck::cast_slice(&cols));
            self.queue.write_buffer(&self.row_y, 0, bytemuck::cast_slice(&rows));
            self.anchor = Some(anchor);
        }
        let mut flags = 0;
        if options.wireframe {
            flags |= FLAG_WIREFRAME;
        }
        if self.has_texture {
            flags |= FLAG_TEXTURE;
        }
        if options.lod_colours {
            flags |= FLAG_LOD;
        }
        let frame = GpuFrame {
            view_proj: camera.view_proj_for_anchor(anchor).to_cols_array_2d(),
            sun: self.sun.extend(0.0).to_array(),
            spacing: self.spacing.as_vec2().to_array(),
            grid_max: [self.grid[0] - 1, self.grid[1] - 1],
            height_offset: (-anchor.z) as f32,
            skirt_depth: options.skirt_depth_m.max(0.0),
            height_min: self.height_min,
            height_range: self.height_max - self.height_min,
            flags,
            pad: [0; 3],
        };
        self.queue.write_buffer(&self.frame, 0, bytemuck::bytes_of(&frame));
    }

    /// Draws `patches` as seen by `camera` (its viewport is replaced by the target's size) into
    /// the offscreen RGBA8 target ([`TerrainRenderer::read_image`] reads it back) and, where
    /// timestamp queries exist, waits for the device, so the returned GPU times are final. The
    /// tessellation is reused while `patches` is unchanged from the previous call.
    pub fn render(
        &mut self,
        camera: &Camera,
        patches: &[DrawPatch],
        options: &RenderOptions,
    ) -> Result<FrameStats, RenderError> {
        self.draw(camera, patches, None, options, ColorTarget::Offscreen)
    }

    /// Like [`TerrainRenderer::render`], then draws `extra` (uploaded in this call) in the
    /// same pass: see [`ExtraTriangles`]. Fails with [`RenderError::BadExtra`] when a vertex
    /// names a patch past `patches` or an index a vertex past `extra.points`.
    pub fn render_with_extra(
        &mut self,
        camera: &Camera,
        patches: &[DrawPatch],
        extra: &ExtraTriangles,
        options: &RenderOptions,
    ) -> Result<FrameStats, RenderError> {
        if let Some(p) = extra.points.iter().find(|p| p.patch_index as usize >= patches.len()) {
            return Err(RenderError::BadExtra(format!(
                "a vertex names patch {} of {}",
                p.patch_index,
                patches.len()
            )));
        }
        if !extra.heights.is_empty() && extra.heights.len() != extra.points.len() {
            return Err(RenderError::BadExtra(format!(
                "{} heights for {} vertices (none, or one per vertex, expected)",
                extra.heights.len(),
                extra.points.len()
            )));
        }
        if !extra.indices.len().is_multiple_of(3)
            || extra.indices.iter().any(|&k| k as usize >= extra.points.len())
        {
            return Err(RenderError::BadExtra(format!(
                "{} indices (a multiple of 3 below {} expected)",
                extra.indices.len(),
                extra.points.len()
            )));
        }
        self.draw(camera, patches, Some(extra), options, ColorTarget::Offscreen)
    }

    /// Like [`TerrainRenderer::render`], drawing into `target`, a colour view the caller owns
    /// whose texture is [`TerrainRenderer::size`] large, has `RENDER_ATTACHMENT` usage and is
    /// viewed as `format` (a window surface's texture: see [the module docs](super)). Depth is
    /// the renderer's own. The pipelines of a format other than RGBA8 are built on its first
    /// use and kept; for an sRGB format the shader decodes its colours so that the stored
    /// bytes match [`TerrainRenderer::render`]'s (to within a rounding step), background
    /// included. [`TerrainRenderer::read_image`] does not see these frames. Fails with
    /// [`RenderError::InvalidConfig`] when the view's texture has another size, is not
    /// renderable, or `format` is not a float colour format the adapter can render to.
    pub fn render_to_view(
        &mut self,
        camera: &Camera,
        patches: &[DrawPatch],
        options: &RenderOptions,
        target: &wgpu::TextureView,
        format: wgpu::TextureFormat,
    ) -> Result<FrameStats, RenderError> {
        let texture = target.texture();
        let (w, h) = self.size();
        if (texture.width(), texture.height()) != (w, h) {
            return Err(RenderError::InvalidConfig(format!(
                "the target view's texture is {} x {}, the renderer draws {w} x {h}",
                texture.width(),
                texture.height()
            )));
        }
        if !texture.usage().contains(wgpu::TextureUsages::RENDER_ATTACHMENT) {
            return Err(RenderError::InvalidConfig(
                "the target view's texture lacks RENDER_ATTACHMENT usage".into(),
            ));
        }
        if texture.format().remove_srgb_suffix() != format.remove_srgb_suffix() {
            return Err(RenderError::InvalidConfig(format!(
                "the target view's texture is {:?}, not viewable as {format:?}",
                texture.format()
            )));
        }
        self.draw(camera, patches, None, options, ColorTarget::View(target, format))
    }

    /// Test hook: the colour formats whose pipelines exist, sorted by name.
    #[cfg(test)]
    pub(super) fn pipeline_formats(&self) -> Vec<wgpu::TextureFormat> {
        let mut formats: Vec<_> = self.pipelines.keys().copied().collect();
        formats.sort_by_key(|f| format!("{f:?}"));
        formats
    }

    /// Builds the pipelines of `format` unless they exist.
    fn ensure_pipelines(&mut self, format: wgpu::TextureFormat) -> Result<(), RenderError> {
        if self.pipelines.contains_key(&format) {
            return Ok(());
        }
        let float = matches!(
            format.sample_type(None, Some(self.device.features())),
            Some(wgpu::TextureSampleType::Float { .. })
        );
        let renderable = self
            .gpu_adapter
            .get_texture_format_features(format)
            .allowed_usages
            .contains(wgpu::TextureUsages::RENDER_ATTACHMENT);
        if !(float && renderable && !format.is_depth_stencil_format()) {
            return Err(RenderError::InvalidConfig(format!(
                "{format:?} is not a float colour format this adapter renders to"
            )));
        }
        let pipelines = Pipelines::new(&self.device, &self.module, &self.render_layout, format);
        self.pipelines.insert(format, pipelines);
        Ok(())
    }

    /// The one frame path of [`TerrainRenderer::render`] and
    /// [`TerrainRenderer::render_to_view`].
    fn draw(
        &mut self,
        camera: &Camera,
        patches: &[DrawPatch],
        extra: Option<&ExtraTriangles>,
        options: &RenderOptions,
        color: ColorTarget<'_>,
    ) -> Result<FrameStats, RenderError> {
        let start = Instant::now();
        let format = match color {
            ColorTarget::Offscreen => COLOR_FORMAT,
            ColorTarget::View(_, format) => format,
        };
        self.ensure_pipelines(format)?;
        let (w, h) = self.size();
        let camera = camera.with_viewport(f64::from(w), f64::from(h));
        let tessellate_now = self.prepare(patches)?;
        if options.skirt_depth_m > 0.0 {
            self.build_skirts();
        }
        self.write_frame(&camera, options);
        // Uploaded once per frame: the strips change every frame.
        let extra_buffers = extra.filter(|e| !e.indices.is_empty()).map(|e| {
            let buffer =
                |label, bytes: &[u8], usage| upload(&self.device, &self.queue, label, bytes, usage);
            let v =
                buffer("extra points", bytemuck::cast_slice(&e.points), wgpu::BufferUsages::VERTEX);
            let i = buffer(
                "extra indices",
                bytemuck::cast_slice(&e.indices),
                wgpu::BufferUsages::INDEX,
            );
            let heights = (!e.heights.is_empty()).then(|| {
                buffer(
                    "extra heights",
                    bytemuck::cast_slice(&e.heights),
                    wgpu::BufferUsages::VERTEX,
                )
            });
            (v, i, e.indices.len() as u32, heights)
        });
        let tess = self.tess.as_ref().expect("prepared above");
        let mut encoder = self.device.create_command_encoder(&Default::default());
        let timer = self.timer.as_ref();
        if tessellate_now {
            let last = tess.batches.len() - 1;
            for (k, batch) in tess.batches.iter().enumerate() {
                // One timestamp at the first batch's start, one at the last one's end.
                let writes = timer.filter(|_| k == 0 || k == last).map(|t| {
                    wgpu::ComputePassTimestampWrites {
                        query_set: &t.tess,
                        beginning_of_pass_write_index: (k == 0).then_some(0),
                        end_of_pass_write_index: (k == last).then_some(1),
                    }
                });
                self.tessellator.encode_timed(&mut encoder, &batch.out, writes);
            }
        }
        {
            let pipelines = &self.pipelines[&format];
            let clear = clear_color(self.background, format.is_srgb());
            let writes = timer.map(|t| wgpu::RenderPassTimestampWrites {
                query_set: &t.draw,
                beginning_of_pass_write_index: Some(0),
                end_of_pass_write_index: Some(1),
            });
            let mut pass = match color {
                ColorTarget::Offscreen => self.target.begin_timed_pass(&mut encoder, clear, writes),
                ColorTarget::View(view, _) => {
                    self.target.begin_pass_into(&mut encoder, view, clear, writes)
                }
            };
            for batch in &tess.batches {
                pass.set_bind_group(0, &batch.bind_group, &[]);
                if options.wireframe {
                    // The non-indexed draw reads the indexed arguments: their first four words
                    // (index count, 1, 0, 0) are (vertex count, instances, first vertex, first
                    // instance).
                    pass.set_pipeline(&pipelines.pulled);
                    pass.draw_indirect(&batch.out.draw_args, 0);
                } else {
                    pass.set_pipeline(&pipelines.indexed);
                    pass.set_vertex_buffer(0, batch.out.points.slice(..));
                    pass.set_index_buffer(batch.out.indices.slice(..), wgpu::IndexFormat::Uint32);
                    pass.draw_indexed_indirect(&batch.out.draw_args, 0);
                }
            }
            // Skirts and extra triangles name patches in the whole list.
            pass.set_bind_group(0, &tess.whole_group, &[]);
            if let Some(s) =
                tess.skirts.as_ref().filter(|s| options.skirt_depth_m > 0.0 && s.index_count > 0)
            {
                pass.set_pipeline(&pipelines.indexed);
                pass.set_vertex_buffer(0, s.vertices.slice(..));
                pass.set_index_buffer(s.indices.slice(..), wgpu::IndexFormat::Uint32);
                pass.draw_indexed(0..s.index_count, 0, 0..1);
            }
            if let Some((v, i, n, heights)) = &extra_buffers {
                match heights {
                    Some(h) => {
                        pass.set_pipeline(&pipelines.explicit);
                        pass.set_vertex_buffer(1, h.slice(..));
                    }
                    None => pass.set_pipeline(&pipelines.indexed),
                }
                pass.set_vertex_buffer(0, v.slice(..));
                pass.set_index_buffer(i.slice(..), wgpu::IndexFormat::Uint32);
                pass.draw_indexed(0..*n, 0, 0..1);
            }
        }
        if let Some(t) = timer {
            if tessellate_now {
                encoder.resolve_query_set(&t.tess, 0..2, &t.tess_resolve, 0);
            }
            encoder.resolve_query_set(&t.draw, 0..2, &t.draw_resolve, 0);
        }
        self.queue.submit([encoder.finish()]);
        let cpu_ms = start.elapsed().as_secs_f64() * 1e3;

        let mut stats = FrameStats {
            patches: patches.len(),
            triangles: tess.triangles + extra.map_or(0, |e| (e.indices.len() / 3) as u64),
            vertices: tess.vertices + extra.map_or(0, |e| e.points.len() as u64),
            tessellated: tessellate_now,
            batches: tess.batches.len(),
            cpu_ms,
            gpu_ms: None,
            gpu_tess_ms: None,
            gpu_draw_ms: None,
            gpu_note: Some("no timestamp queries on this adapter"),
            adapter: self.adapter.clone(),
        };
        if let Some(t) = timer {
            let read = |buf: &wgpu::Buffer| -> Result<f64, GpuError> {
                let bytes = read_buffer(&self.device, &self.queue, buf, 16)?;
                let [begin, end]: [u64; 2] = bytemuck::pod_read_unaligned(&bytes);
                Ok(end.saturating_sub(begin) as f64 * t.period_ns * 1e-6)
            };
            let draw = read(&t.draw_resolve)?;
            stats.gpu_draw_ms = Some(draw);
            stats.gpu_note = None;
            if !tessellate_now {
                stats.gpu_ms = Some(draw);
            } else if self.features.compute_timestamps_trustworthy {
                let tess_ms = read(&t.tess_resolve)?;
                stats.gpu_tess_ms = Some(tess_ms);
                stats.gpu_ms = Some(tess_ms + draw);
            } else {
                stats.gpu_note = Some("untrustworthy on lavapipe");
            }
        }
        Ok(stats)
    }

    /// Builds the skirts of the current tessellation (once): below every patch edge that is
    /// not on the grid's border, a strip from the edge's points (top) to the same points
    /// dropped by the frame's skirt depth (bottom; the vertex stage does the dropping).
    fn build_skirts(&mut self) {
        let [w, h] = self.grid;
        let Some(tess) = self.tess.as_mut() else { return };
        if tess.skirts.is_some() {
            return;
        }
        let mut vertices: Vec<GpuDomainPoint> = Vec::new();
        let mut indices: Vec<u32> = Vec::new();
        for (k, p) in tess.patches.iter().enumerate() {
            if QuadLayout::new(&p.factors).culled {
                continue;
            }
            let [x0, y0, x1, y1] = p.rect;
            let interior = [x0 > 0, y0 > 0, x1 < w - 1, y1 < h - 1];
            for (edge, _) in interior.iter().enumerate().filter(|&(_, &inside)| inside) {
                let spacing = EdgeSpacing::new(p.factors.outer[edge]);
                let base = vertices.len() as u32;
                for q in 0..spacing.point_count() {
                    let t = spacing.place(q);
                    let uv = match edge {
                        0 => [0.0, t],
                        1 => [t, 0.0],
                        2 => [1.0, t],
                        _ => [t, 1.0],
                    };
                    for skirt in [0, 1] {
                        vertices.push(GpuDomainPoint { uv, patch_index: k as u32, pad: skirt });
                    }
                }
                for q in 0..spacing.point_count() - 1 {
                    let (a, b) = (base + 2 * q, base + 2 * q + 2);
                    indices.extend_from_slice(&[a, b, a + 1, b, b + 1, a + 1]);
                }
            }
        }
        let buffer =
            |label, bytes: &[u8], usage| upload(&self.device, &self.queue, label, bytes, usage);
        tess.skirts = Some(Skirts {
            vertices: buffer(
                "skirt points",
                bytemuck::cast_slice(&vertices),
                wgpu::BufferUsages::VERTEX,
            ),
            indices: buffer(
                "skirt indices",
                bytemuck::cast_slice(&indices),
                wgpu::BufferUsages::INDEX,
            ),
            index_count: indices.len() as u32,
        });
    }

    /// The colour image of the last [`TerrainRenderer::render`] (waits for the device).
    pub fn read_image(&self) -> Result<RgbaImage, GpuError> {
        self.target.read_color_with(&self.device, &self.queue)
    }

    /// Test hook: tessellates `patches` and evaluates, on the device, the shader's own surface
    /// functions (those the vertex and fragment stages call) at every tessellated point, for
    /// the anchor a camera at `camera_position` would use ([`TerrainRenderer::anchor_for`]).
    /// Compare with [`crate::surface::vertex_position`] and [`crate::surface::normal_at`].
    pub fn surface_read_back(
        &mut self,
        camera_position: DVec3,
        patches: &[DrawPatch],
    ) -> Result<SurfaceReadBack, RenderError> {
        let tessellate_now = self.prepare(patches)?;
        let camera = Camera::from_yaw_pitch(camera_position, 0.0, 0.0);
        self.write_frame(&camera, &RenderOptions::default());
        let tess = self.tess.as_ref().expect("prepared above");
        let mut all =
            SurfaceReadBack { points: Vec::new(), positions: Vec::new(), normals: Vec::new() };
        // Batch by batch; points name their patch in the whole list.
        for batch in &tess.batches {
            let n = batch.out.point_capacity;
            let groups = n.div_ceil(64);
            let limit = self.device.limits().max_compute_workgroups_per_dimension;
            if groups > limit {
                return Err(GpuError::LimitExceeded {
                    what: "surface read-back workgroups",
                    requested: u64::from(groups),
                    maximum: u64::from(limit),
                }
                .into());
            }
            let out_size = (u64::from(n) * 32).max(32);
            let out = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("surface read-back"),
                size: out_size,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            let debug_group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("terrain debug"),
                layout: &self.debug_layout,
                entries: &[wgpu::BindGroupEntry { binding: 0, resource: out.as_entire_binding() }],
            });
            let mut encoder = self.device.create_command_encoder(&Default::default());
            if tessellate_now {
                self.tessellator.encode(&mut encoder, &batch.out);
            }
            {
                let mut pass = encoder.begin_compute_pass(&Default::default());
                pass.set_pipeline(&self.debug);
                pass.set_bind_group(0, &batch.bind_group, &[]);
                pass.set_bind_group(1, &debug_group, &[]);
                if groups > 0 {
                    pass.dispatch_workgroups(groups, 1, 1);
                }
            }
            self.queue.submit([encoder.finish()]);
            let points =
                read_buffer(&self.device, &self.queue, &batch.out.points, u64::from(n) * 16)?;
            let values: Vec<[f32; 4]> = bytemuck::pod_collect_to_vec(&read_buffer(
                &self.device,
                &self.queue,
                &out,
                u64::from(n) * 32,
            )?);
            let mut points: Vec<GpuDomainPoint> = bytemuck::pod_collect_to_vec(&points);
            for p in &mut points {
                p.patch_index += batch.first as u32;
            }
            all.points.extend(points);
            all.positions.extend(values.iter().step_by(2).copied());
            all.normals.extend(values.iter().skip(1).step_by(2).copied());
        }
        Ok(all)
    }

    /// The bind group of `terrain.wgsl`'s group 0 (one place, so every pass that uses the
    /// layout binds the same resources): the frame, heights, page table, columns and rows,
    /// colour texture and sampler of this renderer, with `rects`, `points` and `indices`.
    fn terrain_bind_group(
        &self,
        label: &str,
        rects: &wgpu::Buffer,
        points: &wgpu::Buffer,
        indices: &wgpu::Buffer,
    ) -> wgpu::BindGroup {
        let bind = |binding, resource| wgpu::BindGroupEntry { binding, resource };
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout: &self.layout,
            entries: &[
                bind(0, self.frame.as_entire_binding()),
                bind(1, wgpu::BindingResource::TextureView(&self.heights)),
                bind(2, rects.as_entire_binding()),
                bind(3, self.col_x.as_entire_binding()),
                bind(4, self.row_y.as_entire_binding()),
                bind(5, wgpu::BindingResource::TextureView(&self.color)),
                bind(6, wgpu::BindingResource::Sampler(&self.sampler)),
                bind(7, points.as_entire_binding()),
                bind(8, indices.as_entire_binding()),
                bind(9, self.page_table.as_entire_binding()),
            ],
        })
    }

    /// Test hook: evaluates, on the device, the shader's surface position (relative to the
    /// anchor of a camera at `camera_position`; w = absolute height) at arbitrary domain
    /// points of `patches`, as the vertex stage does for [`ExtraTriangles`]' vertices.
    pub fn points_read_back(
        &mut self,
        camera_position: DVec3,
        patches: &[DrawPatch],
        points: &[GpuDomainPoint],
    ) -> Result<Vec<[f32; 4]>, RenderError> {
        self.prepare(patches)?;
        let camera = Camera::from_yaw_pitch(camera_position, 0.0, 0.0);
        self.write_frame(&camera, &RenderOptions::default());
        let tess = self.tess.as_ref().expect("prepared above");
        let n = points.len() as u32;
        let storage = |label, size: u64, usage| {
            self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size.max(32),
                usage,
                mapped_at_creation: false,
            })
        };
        use wgpu::BufferUsages as U;
        let input = storage("read-back points", u64::from(n) * 16, U::STORAGE | U::COPY_DST);
        self.queue.write_buffer(&input, 0, bytemuck::cast_slice(points));
        let out = storage("read-back surface", u64::from(n) * 32, U::STORAGE | U::COPY_SRC);
        let group = self.terrain_bind_group(
            "read-back points",
            &tess.rects,
            &input,
            &tess.batches[0].out.indices,
        );
        let debug_group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("terrain debug"),
            layout: &self.debug_layout,
            entries: &[wgpu::BindGroupEntry { binding: 0, resource: out.as_entire_binding() }],
        });
        let mut encoder = self.device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.debug);
            pass.set_bind_group(0, &group, &[]);
            pass.set_bind_group(1, &debug_group, &[]);
            if n > 0 {
                pass.dispatch_workgroups(n.div_ceil(64), 1, 1);
            }
        }
        self.queue.submit([encoder.finish()]);
        let values: Vec<[f32; 4]> = bytemuck::pod_collect_to_vec(&read_buffer(
            &self.device,
            &self.queue,
            &out,
            u64::from(n) * 32,
        )?);
        Ok(values.iter().step_by(2).copied().collect())
    }
}
