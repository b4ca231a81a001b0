//! Putting a frame on the window: the engine's renderer draws into its offscreen target (the
//! same passes `terrain render` runs); [`Presenter`] copies that image into the window's
//! surface texture with one full-screen pass (`textureLoad`, texel for texel, so the bytes
//! are the offscreen ones), draws the egui panel over it, and on demand reads the surface
//! texture back (the screenshot is the window's content, not a separate render) before
//! presenting.

use std::sync::Arc;

use anyhow::{Context, bail};
use terrain_gpu::{GpuContext, RgbaImage};
use winit::window::Window;

/// The copy pass: a full-screen triangle that loads the source texel under each pixel. An sRGB
/// surface encodes what the fragment stage writes, so `fs_srgb` decodes first (the offscreen
/// bytes are already sRGB-encoded colours).
const BLIT: &str = r"
@group(0) @binding(0) var src: texture_2d<f32>;

@vertex
fn vs(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let x = f32((i << 1u) & 2u);
    let y = f32(i & 2u);
    return vec4<f32>(x * 2.0 - 1.0, 1.0 - y * 2.0, 0.0, 1.0);
}

fn load(p: vec4<f32>) -> vec4<f32> {
    let size = vec2<i32>(textureDimensions(src)) - vec2<i32>(1, 1);
    return textureLoad(src, clamp(vec2<i32>(p.xy), vec2<i32>(0, 0), size), 0);
}

@fragment
fn fs(@builtin(position) p: vec4<f32>) -> @location(0) vec4<f32> {
    return load(p);
}

fn decode(c: f32) -> f32 {
    if c <= 0.04045 { return c / 12.92; }
    return pow((c + 0.055) / 1.055, 2.4);
}

@fragment
fn fs_srgb(@builtin(position) p: vec4<f32>) -> @location(0) vec4<f32> {
    let c = load(p);
    return vec4<f32>(decode(c.r), decode(c.g), decode(c.b), c.a);
}
";

/// egui's texture changes of a frame, cleared when dropped (egui refuses to drop unapplied
/// changes; a frame that fails before presenting drops them).
pub(crate) struct Textures(pub egui::TexturesDelta);

impl Drop for Textures {
    fn drop(&mut self) {
        self.0.clear();
    }
}

/// What the panel draws this frame.
pub(crate) struct Overlay<'a> {
    /// egui's triangles.
    pub primitives: &'a [egui::ClippedPrimitive],
    /// Its texture changes.
    pub textures: &'a egui::TexturesDelta,
    /// Points to pixels.
    pub pixels_per_point: f32,
}

/// The window's surface and the passes that draw into it.
pub(crate) struct Presenter {
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    layout: wgpu::BindGroupLayout,
    blit: wgpu::RenderPipeline,
    egui: egui_wgpu::Renderer,
    /// Whether the surface texture can be copied (read back for screenshots).
    readable: bool,
}

impl std::fmt::Debug for Presenter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Presenter").field("format", &self.config.format).finish_non_exhaustive()
    }
}

impl Presenter {
    /// The surface of `window` on `ctx`'s adapter, configured at the window's size.
    pub(crate) fn new(ctx: &GpuContext, window: Arc<Window>) -> anyhow::Result<Self> {
        let size = window.inner_size();
        let surface = ctx
            .instance
            .create_surface(window)
            .context("could not create a surface for the window")?;
        if !ctx.adapter.is_surface_supported(&surface) {
            bail!(
                "the adapter {} cannot present to this window (try TERRAIN_GPU_BACKEND=vulkan)",
                ctx.describe()
            );
        }
        let caps = surface.get_capabilities(&ctx.adapter);
        // A unorm format takes the offscreen bytes as they are; sRGB only when nothing else.
        let format = caps
            .formats
            .iter()
            .copied()
            .find(|f| {
                matches!(f, wgpu::TextureFormat::Bgra8Unorm | wgpu::TextureFormat::Rgba8Unorm)
            })
            .or_else(|| caps.formats.first().copied())
            .context("the surface offers no format")?;
        let readable = caps.usages.contains(wgpu::TextureUsages::COPY_SRC);
        let mut usage = wgpu::TextureUsages::RENDER_ATTACHMENT;
        if readable {
            usage |= wgpu::TextureUsages::COPY_SRC;
        }
        let present_mode = if caps.present_modes.contains(&wgpu::PresentMode::Immediate) {
            // Frame times are the engine's, not the display's refresh.
            wgpu::PresentMode::Immediate
        } else {
            wgpu::PresentMode::Fifo
        };
        let config = wgpu::SurfaceConfiguration {
            usage,
            format,
            width: size.width.max(1),
            height: size.height.max(1),
            present_mode,
            desired_maximum_frame_latency: 1,
            alpha_mode: caps.alpha_modes[0],
            view_formats: vec![],
            color_space: wgpu::SurfaceColorSpace::Auto,
        };
        surface.configure(&ctx.device, &config);
        let device = &ctx.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("view blit"),
            source: wgpu::ShaderSource::Wgsl(BLIT.into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("view blit"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Float { filterable: false },
                    view_dimension: wgpu::TextureViewDimension::D2,
                    multisampled: false,
                },
                count: None,
            }],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("view blit"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let blit = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("view blit"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some(if format.is_srgb() { "fs_srgb" } else { "fs" }),
                compilation_options: Default::default(),
                targets: &[Some(format.into())],
            }),
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: None,
            multisample: wgpu::MultisampleState::default(),
            multiview_mask: None,
            cache: None,
        });
        let egui = egui_wgpu::Renderer::new(device, format, egui_wgpu::RendererOptions::default());
        Ok(Self { surface, config, layout, blit, egui, readable })
    }

    /// The surface's pixel format.
    pub(crate) fn format(&self) -> wgpu::TextureFormat {
        self.config.format
    }

    /// Whether screenshots can be read from the surface.
    pub(crate) fn readable(&self) -> bool {
        self.readable
    }

    /// Copies `image` (the renderer's offscreen colour texture) into the next surface texture,
    /// draws `overlay` over it, reads the result back when `read_back`, and presents.
    pub(crate) fn present(
        &mut self,
        ctx: &GpuContext,
        image: &wgpu::Texture,
        overlay: Option<Overlay<'_>>,
        read_back: bool,
    ) -> anyhow::Result<Option<RgbaImage>> {
        let frame = match self.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(f)
            | wgpu::CurrentSurfaceTexture::Suboptimal(f) => f,
            other => {
                // Lost or outdated: configure again and skip this frame.
                self.surface.configure(&ctx.device, &self.config);
                if read_back {
                    bail!("the window's surface could not be acquired ({other:?})");
                }
                return Ok(None);
            }
        };
        let view = frame.texture.create_view(&Default::default());
        let device = &ctx.device;
        let source = image.create_view(&Default::default());
        let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("view blit"),
            layout: &self.layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::TextureView(&source),
            }],
        });
        let mut encoder = device.create_command_encoder(&Default::default());
        let screen = egui_wgpu::ScreenDescriptor {
            size_in_pixels: [self.config.width, self.config.height],
            pixels_per_point: overlay.as_ref().map_or(1.0, |o| o.pixels_per_point),
        };
        if let Some(o) = &overlay {
            for (id, deltas) in &o.textures.set {
                for delta in deltas {
                    self.egui.update_texture(device, &ctx.queue, *id, delta);
                }
            }
            let extra =
                self.egui.update_buffers(device, &ctx.queue, &mut encoder, o.primitives, &screen);
            // Paint callbacks' command buffers (the panel has none): no empty submission.
            if !extra.is_empty() {
                ctx.queue.submit(extra);
            }
        }
        {
            let mut pass = encoder
                .begin_render_pass(&wgpu::RenderPassDescriptor {
                    label: Some("view present"),
                    color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                        view: &view,
                        depth_slice: None,
                        resolve_target: None,
                        ops: wgpu::Operations {
                            load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                            store: wgpu::StoreOp::Store,
                        },
                    })],
                    depth_stencil_attachment: None,
                    timestamp_writes: None,
                    occlusion_query_set: None,
                    multiview_mask: None,
                })
                .forget_lifetime();
            pass.set_pipeline(&self.blit);
            pass.set_bind_group(0, &bind, &[]);
            pass.draw(0..3, 0..1);
            if let Some(o) = &overlay {
                self.egui.render(&mut pass, o.primitives, &screen);
            }
        }
        ctx.queue.submit([encoder.finish()]);
        if let Some(o) = &overlay {
            for id in &o.textures.free {
                self.egui.free_texture(id);
            }
        }
        let shot = if read_back {
            if !self.readable {
                bail!("this surface cannot be read back (no COPY_SRC usage on this adapter)");
            }
            let mut img =
                terrain_gpu::target::read_texture_8bit4(device, &ctx.queue, &frame.texture)
                    .context("could not read the window's surface back")?;
            if matches!(
                self.config.format,
                wgpu::TextureFormat::Bgra8Unorm | wgpu::TextureFormat::Bgra8UnormSrgb
            ) {
                for p in &mut img.pixels {
                    p.swap(0, 2);
                }
            }
            Some(img)
        } else {
            None
        };
        ctx.queue.present(frame);
        Ok(shot)
    }
}
