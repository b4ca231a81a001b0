//! [`GeomorphRenderer`]: the heightmap, lightmap and alpha maps on the device, the mesh
//! library, the pipelines of `geomorph.wgsl` (an opaque base pass and alpha-blended material
//! passes), and the read-back hook the tests compare with the CPU reference.

use std::mem::size_of;
use std::time::Instant;

use bytemuck::{Pod, Zeroable};
use glam::{DVec2, DVec3};
use terrain_core::Heightmap;
use terrain_core::geometry::Camera;
use terrain_core::lightmap::{LightmapConfig, lightmap};
use terrain_core::lod::PatchLod;

use super::materials::{MATERIALS, MaterialMaps};
use super::morph::{GpuMorphPatch, MeshLibrary, PATCH_SHIFT};
use crate::device::{GpuContext, GpuError, read_buffer};
use crate::render::{BACKGROUND, RenderError, TerrainRenderer};
use crate::target::{COLOR_FORMAT, OffscreenTarget, RgbaImage};

/// The shader source.
pub const SHADER: &str = include_str!("geomorph.wgsl");

/// `Frame` in `geomorph.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
struct GpuFrame {
    view_proj: [[f32; 4]; 4],
    spacing: [f32; 2],
    grid_max: [u32; 2],
    height_offset: f32,
    skirt_depth: f32,
    patch_cells: u32,
    max_level: u32,
    patch_count: u32,
    pad: [u32; 3],
}

const _: () = assert!(size_of::<GpuFrame>() == 112);

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
    /// tessellation renderer's sun, with horizon shadows.
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
    /// Bytes uploaded this frame: the frame uniform, the patches and the passes' index lists
    /// (not the column/row offsets written when the anchor moves).
    pub upload_bytes: u64,
    /// CPU time to upload, encode and submit, milliseconds.
    pub cpu_ms: f64,
    /// The adapter.
    pub adapter: String,
}

/// Draws geo-mipmapped, geomorphed patches ([`PatchLod`]s from
/// `terrain_core::lod::GeomipScene::select`) into an offscreen RGBA8 target.
#[derive(Debug)]
pub struct GeomorphRenderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: String,
    target: OffscreenTarget,
    layout: wgpu::BindGroupLayout,
    debug_layout: wgpu::BindGroupLayout,
    base: wgpu::RenderPipeline,
    overlay: wgpu::RenderPipeline,
    debug: wgpu::ComputePipeline,
    frame: wgpu::Buffer,
    col_x: wgpu::Buffer,
    row_y: wgpu::Buffer,
    heights: wgpu::TextureView,
    light: wgpu::TextureView,
    alpha: wgpu::TextureView,
    sampler: wgpu::Sampler,
    patches: Option<(wgpu::Buffer, u64, wgpu::BindGroup)>,
    indices: Option<wgpu::Buffer>,
    lib: MeshLibrary,
    materials: MaterialMaps,
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

impl GeomorphRenderer {
    /// Uploads `hm`, its lightmap and alpha maps, the mesh library, and builds the pipelines
    /// and a `config.width` x `config.height` target.
    pub fn new(
        ctx: &GpuContext,
        hm: &Heightmap,
        config: &GeomorphConfig,
    ) -> Result<Self, RenderError> {
        let device = &ctx.device;
        let maximum = device.limits().max_texture_dimension_2d;
        let (width, height) = (hm.width() as u32, hm.height() as u32);
        if width > maximum || height > maximum {
            return Err(RenderError::TextureTooLarge {
                what: "the heightmap",
                width,
                height,
                maximum,
            });
        }
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
        let p = config.patch_cells;
        if !(p.is_power_of_two() && (2..=64).contains(&p)) {
            return Err(RenderError::InvalidConfig(format!(
                "patch_cells {p}: a power of two from 2 to 64"
            )));
        }
        let size = |w, h| wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 };
        let upload = |label, format: wgpu::TextureFormat, bytes: &[u8], texel: u32| {
            let tex = device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: size(width, height),
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            });
            ctx.queue.write_texture(
                tex.as_image_copy(),
                bytes,
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(width * texel),
                    rows_per_image: Some(height),
                },
                size(width, height),
            );
            tex.create_view(&Default::default())
        };
        let heights = upload(
            "geomorph heights",
            wgpu::TextureFormat::R32Float,
            bytemuck::cast_slice(hm.data()),
            4,
        );
        let light_values: Vec<u8> = lightmap(hm, &config.lightmap)
            .iter()
            .map(|&l| (l * 255.0).round().clamp(0.0, 255.0) as u8)
            .collect();
        let light = upload("lightmap", wgpu::TextureFormat::R8Unorm, &light_values, 1);
        let materials = MaterialMaps::new(hm, p);
        let alpha = upload(
            "alpha maps",
            wgpu::TextureFormat::Rgba8Unorm,
            bytemuck::cast_slice(&materials.alpha),
            4,
        );
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
        let pipeline = |label, depth: wgpu::DepthStencilState, target: wgpu::ColorTargetState| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(label),
                layout: Some(&render_layout),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some("vs"),
                    compilation_options: Default::default(),
                    buffers: &[],
                },
                // No culling: skirts are seen from both sides.
                primitive: wgpu::PrimitiveState::default(),
                depth_stencil: Some(depth),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some("fs"),
                    compilation_options: Default::default(),
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
        let debug_pipeline_layout =
            device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("geomorph debug"),
                bind_group_layouts: &[Some(&layout), Some(&debug_layout)],
                immediate_size: 0,
            });
        let debug = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("debug_morph"),
            layout: Some(&debug_pipeline_layout),
            module: &module,
            entry_point: Some("debug_morph"),
            compilation_options: Default::default(),
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
        let lib = MeshLibrary::new(p);
        let geo = hm.georef();
        Ok(Self {
            device: ctx.device.clone(),
            queue: ctx.queue.clone(),
            adapter: ctx.describe(),
            target: OffscreenTarget::new(device, config.width, config.height),
            layout,
            debug_layout,
            base,
            overlay,
            debug,
            frame,
            col_x,
            row_y,
            heights,
            light,
            alpha,
            sampler,
            patches: None,
            indices: None,
            lib,
            materials,
            grid: [width, height],
            origin: geo.world_origin,
            spacing: geo.spacing_m,
            background: config.background,
            anchor: None,
        })
    }

    /// The target's width and height in pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.target.width(), self.target.height())
    }

    /// The adapter, as [`GpuContext::describe`] says.
    pub fn adapter(&self) -> &str {
        &self.adapter
    }

    /// The material maps and per-patch pass masks.
    pub fn materials(&self) -> &MaterialMaps {
        &self.materials
    }

    /// The mesh library.
    pub fn library(&self) -> &MeshLibrary {
        &self.lib
    }

    /// Uploads `lods` (growing the patch buffer when needed) and the frame uniform.
    fn upload(
        &mut self,
        camera: &Camera,
        lods: &[GpuMorphPatch],
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
        let bytes = (lods.len().max(1) * size_of::<GpuMorphPatch>()) as u64;
        if self.patches.as_ref().is_none_or(|(_, cap, _)| *cap < bytes) {
            let cap = bytes.next_power_of_two();
            let buf = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("geomorph patches"),
                size: cap,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let bind = |binding, resource| wgpu::BindGroupEntry { binding, resource };
            let group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("geomorph"),
                layout: &self.layout,
                entries: &[
                    bind(0, self.frame.as_entire_binding()),
                    bind(1, wgpu::BindingResource::TextureView(&self.heights)),
                    bind(2, buf.as_entire_binding()),
                    bind(3, self.col_x.as_entire_binding()),
                    bind(4, self.row_y.as_entire_binding()),
                    bind(6, wgpu::BindingResource::TextureView(&self.light)),
                    bind(7, wgpu::BindingResource::TextureView(&self.alpha)),
                    bind(8, wgpu::BindingResource::Sampler(&self.sampler)),
                ],
            });
            self.patches = Some((buf, cap, group));
        }
        let (buf, _, _) = self.patches.as_ref().expect("allocated above");
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
        let frame = GpuFrame {
            view_proj: camera.view_proj_for_anchor(anchor).to_cols_array_2d(),
            spacing: self.spacing.as_vec2().to_array(),
            grid_max: [w - 1, h - 1],
            height_offset: (-anchor.z) as f32,
            skirt_depth: options.skirt_depth_m.max(0.0),
            patch_cells: self.lib.patch_cells,
            max_level: self.lib.patch_cells.trailing_zeros(),
            patch_count: lods.len().max(1) as u32,
            pad: [0; 3],
        };
        self.queue.write_buffer(&self.frame, 0, bytemuck::bytes_of(&frame));
        Ok(())
    }

    /// Draws `lods` as seen by `camera` (its viewport is replaced by the target's size): the
    /// base material on every patch, then each further material on the patches whose alpha
    /// map is not zero there. Waits for the device.
    pub fn render(
        &mut self,
        camera: &Camera,
        lods: &[PatchLod],
        options: &GeomorphOptions,
    ) -> Result<GeomorphFrameStats, RenderError> {
        let start = Instant::now();
        let (tw, th) = self.size();
        let camera = camera.with_viewport(f64::from(tw), f64::from(th));
        let n = self.lib.patch_cells;
        let gpu: Vec<GpuMorphPatch> = lods.iter().map(|p| GpuMorphPatch::from_lod(p, n)).collect();
        self.upload(&camera, &gpu, options)?;
        let [w, h] = self.grid;
        let mut stats = GeomorphFrameStats {
            patches: lods.len(),
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
        for material in 0..MATERIALS {
            let first = indices.len() as u32;
            for (k, (p, lod)) in gpu.iter().zip(lods).enumerate() {
                if !self.materials.draws(lod.i, lod.j, material) {
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
        stats.upload_bytes = (size_of::<GpuFrame>()
            + gpu.len() * size_of::<GpuMorphPatch>()
            + indices.len() * 4) as u64;
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
        let (_, _, group) = self.patches.as_ref().expect("uploaded");
        let mut encoder = self.device.create_command_encoder(&Default::default());
        {
            let [r, g, b, a] = self.background.map(|c| f64::from(c) / 255.0);
            let mut pass = self.target.begin_pass(&mut encoder, wgpu::Color { r, g, b, a });
            pass.set_bind_group(0, group, &[]);
            pass.set_index_buffer(index_buffer.slice(..), wgpu::IndexFormat::Uint32);
            for &(material, first, count) in passes.iter().filter(|p| p.2 > 0) {
                pass.set_pipeline(if material == 0 { &self.base } else { &self.overlay });
                // The instance index is the material.
                pass.draw_indexed(first..first + count, 0, material as u32..material as u32 + 1);
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
        let camera = Camera::from_yaw_pitch(camera_position, 0.0, 0.0);
        self.upload(&camera, lods, &GeomorphOptions::default())?;
        let (_, _, group) = self.patches.as_ref().expect("uploaded");
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
