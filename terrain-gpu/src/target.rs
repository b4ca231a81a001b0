//! Offscreen render target (RGBA8 colour + 32-bit float depth) with read-back to the host:
//! what tests and headless runs render into, as no window exists there. Its depth texture also
//! serves passes into a colour view the caller owns ([`OffscreenTarget::begin_pass_into`]: a
//! window surface's texture), and [`read_texture_8bit4`] reads back any 8-bit RGBA/BGRA texture.

use crate::device::{GpuContext, GpuError};

/// Colour format of [`OffscreenTarget`].
pub const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
/// Depth format of [`OffscreenTarget`].
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// An RGBA8 image read back from the device, rows top to bottom, no padding.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RgbaImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height` pixels, row-major, first row at the top.
    pub pixels: Vec<[u8; 4]>,
}

impl RgbaImage {
    /// Pixel `(x, y)`, `y = 0` at the top.
    pub fn get(&self, x: u32, y: u32) -> [u8; 4] {
        self.pixels[(y * self.width + x) as usize]
    }
}

/// Levels (0-255) by which a pixel's channel may differ before [`ImageDiff::far_off`] counts it.
pub const GOLDEN_LEVELS: u8 = 16;

/// How far two renders of one camera are apart, the two figures of the golden tolerance
/// (the project's render tests: the mean below 2 levels, under 1 % of pixels far off).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageDiff {
    /// Mean |difference| per colour channel (R, G, B), levels.
    pub mean: [f64; 3],
    /// Share of pixels (0-1) with a channel off by more than [`GOLDEN_LEVELS`].
    pub far_off: f64,
}

/// Compares two images' pixels pairwise (RGBA, alpha ignored), in order, as far as the shorter
/// one goes; callers check the sizes. With no pixels both figures are NaN, so that no
/// tolerance passes on an empty image.
pub fn image_diff(
    a: impl IntoIterator<Item = [u8; 4]>,
    b: impl IntoIterator<Item = [u8; 4]>,
) -> ImageDiff {
    let (mut sum, mut far_off, mut n) = ([0u64; 3], 0usize, 0usize);
    for (x, y) in a.into_iter().zip(b) {
        let mut off = false;
        for (c, s) in sum.iter_mut().enumerate() {
            let d = x[c].abs_diff(y[c]);
            *s += u64::from(d);
            off |= d > GOLDEN_LEVELS;
        }
        far_off += usize::from(off);
        n += 1;
    }
    let n = if n == 0 { f64::NAN } else { n as f64 };
    ImageDiff { mean: sum.map(|s| s as f64 / n), far_off: far_off as f64 / n }
}

/// A colour and a depth texture of the same size, both renderable, the colour copyable and
/// sampleable (`terrain view` copies it into a window with one `textureLoad` pass).
#[derive(Debug)]
pub struct OffscreenTarget {
    /// The colour texture ([`COLOR_FORMAT`]).
    pub color: wgpu::Texture,
    /// The depth texture ([`DEPTH_FORMAT`]).
    pub depth: wgpu::Texture,
    color_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
}

impl OffscreenTarget {
    /// Creates a `width` x `height` target.
    pub fn new(device: &wgpu::Device, width: u32, height: u32) -> Self {
        let texture = |label, format, usage| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
        };
        use wgpu::TextureUsages as U;
        let color = texture(
            "offscreen colour",
            COLOR_FORMAT,
            U::RENDER_ATTACHMENT | U::COPY_SRC | U::TEXTURE_BINDING,
        );
        let depth = texture("offscreen depth", DEPTH_FORMAT, U::RENDER_ATTACHMENT);
        let color_view = color.create_view(&Default::default());
        let depth_view = depth.create_view(&Default::default());
        Self { color, depth, color_view, depth_view }
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.color.width()
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.color.height()
    }

    /// Begins a render pass that clears colour to `clear` and depth to 1 (far, with
    /// `CompareFunction::Less`).
    pub fn begin_pass<'e>(
        &self,
        encoder: &'e mut wgpu::CommandEncoder,
        clear: wgpu::Color,
    ) -> wgpu::RenderPass<'e> {
        self.begin_timed_pass(encoder, clear, None)
    }

    /// Like [`OffscreenTarget::begin_pass`], writing timestamps at the pass's start and end.
    pub fn begin_timed_pass<'e>(
        &self,
        encoder: &'e mut wgpu::CommandEncoder,
        clear: wgpu::Color,
        timestamp_writes: Option<wgpu::RenderPassTimestampWrites<'_>>,
    ) -> wgpu::RenderPass<'e> {
        self.begin_pass_into(encoder, &self.color_view, clear, timestamp_writes)
    }

    /// Like [`OffscreenTarget::begin_timed_pass`], drawing into `color` (a view of a texture of
    /// this target's size that the caller owns, such as a window surface's texture) instead of
    /// this target's colour texture; the depth texture is this target's.
    pub fn begin_pass_into<'e>(
        &self,
        encoder: &'e mut wgpu::CommandEncoder,
        color: &wgpu::TextureView,
        clear: wgpu::Color,
        timestamp_writes: Option<wgpu::RenderPassTimestampWrites<'_>>,
    ) -> wgpu::RenderPass<'e> {
        encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("terrain"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: color,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(clear),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &self.depth_view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(1.0),
                    store: wgpu::StoreOp::Store,
                }),
                stencil_ops: None,
            }),
            timestamp_writes,
            occlusion_query_set: None,
            multiview_mask: None,
        })
    }

    /// The depth-stencil state matching this target, for pipelines drawing into it.
    pub fn depth_state() -> wgpu::DepthStencilState {
        wgpu::DepthStencilState {
            format: DEPTH_FORMAT,
            depth_write_enabled: Some(true),
            depth_compare: Some(wgpu::CompareFunction::Less),
            stencil: Default::default(),
            bias: Default::default(),
        }
    }

    /// Copies the colour texture to the host (waits for all submitted work).
    pub fn read_color(&self, ctx: &GpuContext) -> Result<RgbaImage, GpuError> {
        self.read_color_with(&ctx.device, &ctx.queue)
    }

    /// [`OffscreenTarget::read_color`] for holders of a device and queue.
    pub fn read_color_with(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<RgbaImage, GpuError> {
        read_texture_8bit4(device, queue, &self.color)
    }
}

/// Copies mip level 0 of a 2D texture of four 8-bit channels (`Rgba8Unorm`, `Bgra8Unorm` and
/// their sRGB twins; it needs `COPY_SRC`) to the host, waiting for all submitted work. The
/// bytes of each texel are returned in the texture's own order: `[b, g, r, a]` for the BGRA
/// formats, whatever [`RgbaImage`]'s name says.
pub fn read_texture_8bit4(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    texture: &wgpu::Texture,
) -> Result<RgbaImage, GpuError> {
    assert_eq!(
        texture.format().block_copy_size(None),
        Some(4),
        "read_texture_8bit4 reads four bytes per texel, not {:?}",
        texture.format()
    );
    let (width, height) = (texture.width(), texture.height());
    // Rows of a texture-to-buffer copy are padded to 256 bytes.
    let row = width * 4;
    let padded_row = row.next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
    let size = u64::from(padded_row) * u64::from(height);
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("colour read-back"),
        size,
        usage: wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = device.create_command_encoder(&Default::default());
    encoder.copy_texture_to_buffer(
        texture.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &buffer,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(padded_row),
                rows_per_image: Some(height),
            },
        },
        wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
    );
    queue.submit([encoder.finish()]);
    let bytes = crate::device::read_buffer(device, queue, &buffer, size)?;
    let mut pixels = Vec::with_capacity((width * height) as usize);
    for y in 0..height as usize {
        let line = &bytes[y * padded_row as usize..][..row as usize];
        pixels.extend(line.chunks_exact(4).map(|p| [p[0], p[1], p[2], p[3]]));
    }
    Ok(RgbaImage { width, height, pixels })
}

#[cfg(test)]
mod diff_tests {
    use super::image_diff;

    #[test]
    fn image_diff_counts_means_and_far_off_pixels() {
        let a = [[10, 20, 30, 255]; 4];
        let mut b = a;
        b[1] = [10 + 17, 20, 30, 0]; // off by 17 in red: far off; alpha ignored
        b[2] = [10, 20 + 16, 30, 255]; // off by 16: not far off
        let d = image_diff(a, b);
        assert_eq!(d.mean, [17.0 / 4.0, 16.0 / 4.0, 0.0]);
        assert_eq!(d.far_off, 0.25);
        assert_eq!(image_diff(a, a).far_off, 0.0);
        let empty = image_diff([], []);
        assert!(empty.far_off.is_nan() && empty.mean.iter().all(|m| m.is_nan()));
    }
}
