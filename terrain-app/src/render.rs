//! `terrain render`: draws a DEM (or the embedded synthetic terrain) with the GPU tessellator
//! into a PNG, and prints what each frame drew and cost.

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::Args;
use glam::DVec3;
use terrain_core::geometry::Camera;
use terrain_core::{Heightmap, synth};
use terrain_gpu::render::{clip_range, default_camera};
use terrain_gpu::{
    BackendChoice, DeviceConfig, GpuContext, RenderConfig, RenderOptions, RgbaImage,
    TerrainRenderer, uniform_patches,
};

use crate::source::SourceArgs;

/// Arguments of `terrain render`.
#[derive(Debug, Args)]
pub struct RenderArgs {
    #[command(flatten)]
    pub source: SourceArgs,
    /// Camera as x,y,z,yaw,pitch: position in the DEM's world coordinates (metres; the CRS's
    /// coordinates for projected DEMs), compass yaw in degrees (0 north, 90 east), pitch in
    /// degrees (negative looks down). Default: the whole terrain from the south-west, 35
    /// degrees down.
    #[arg(long, allow_hyphen_values = true)]
    pub camera: Option<String>,
    /// Vertical field of view, degrees.
    #[arg(long, default_value_t = 60.0)]
    pub fov: f64,
    /// Image size, WIDTHxHEIGHT.
    #[arg(long, default_value = "1280x720")]
    pub size: String,
    /// Cells per side of the (uniform) patches.
    #[arg(long, default_value_t = 32)]
    pub patch_cells: u32,
    /// Tessellation factor of every patch edge and axis (fractional-even: 2 to 64).
    #[arg(long, default_value_t = 16.0)]
    pub factor: f32,
    /// Darken triangle edges.
    #[arg(long)]
    pub wireframe: bool,
    /// Colour texture (PNG or JPEG) stretched over the whole DEM, its first row at the north.
    #[arg(long)]
    pub texture: Option<PathBuf>,
    /// Frames to draw (the tessellation is reused after the first): for timing.
    #[arg(long, default_value_t = 1)]
    pub frames: u32,
    /// Output PNG.
    #[arg(short, long)]
    pub output: PathBuf,
}

fn parse_size(s: &str) -> anyhow::Result<(u32, u32)> {
    let bad = || format!("--size expects WIDTHxHEIGHT (e.g. 1280x720), got `{s}`");
    let (w, h) = s.split_once(['x', 'X']).with_context(bad)?;
    let (w, h): (u32, u32) =
        (w.trim().parse().with_context(bad)?, h.trim().parse().with_context(bad)?);
    if w == 0 || h == 0 {
        bail!("{}: both must be positive", bad());
    }
    Ok((w, h))
}

/// `x,y,z,yaw,pitch` -> position, yaw, pitch.
fn parse_camera(s: &str) -> anyhow::Result<(DVec3, f64, f64)> {
    let bad = || format!("--camera expects x,y,z,yaw,pitch (metres, degrees), got `{s}`");
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(bad)?;
    match v[..] {
        [x, y, z, yaw, pitch] if v.iter().all(|x| x.is_finite()) => {
            Ok((DVec3::new(x, y, z), yaw, pitch))
        }
        _ => bail!("{}", bad()),
    }
}

fn load_texture(path: &PathBuf) -> anyhow::Result<RgbaImage> {
    let image = image::open(path)
        .with_context(|| format!("could not read the texture {}", path.display()))?
        .to_rgba8();
    let (width, height) = image.dimensions();
    let pixels = image.pixels().map(|p| p.0).collect();
    Ok(RgbaImage { width, height, pixels })
}

fn camera_for(
    args: &RenderArgs,
    hm: &Heightmap,
    width: u32,
    height: u32,
) -> anyhow::Result<Camera> {
    if !(args.fov.is_finite() && args.fov > 0.0 && args.fov < 180.0) {
        bail!("--fov must be between 0 and 180 degrees, got {}", args.fov);
    }
    Ok(match &args.camera {
        None => default_camera(hm, width, height, args.fov),
        Some(s) => {
            let (position, yaw, pitch) = parse_camera(s)?;
            let (near, far) = clip_range(hm, position);
            Camera::from_yaw_pitch(position, yaw, pitch)
                .with_fov_y_deg(args.fov)
                .with_viewport(f64::from(width), f64::from(height))
                .with_clip(near, far)
        }
    })
}

/// Runs `terrain render`.
pub fn run(args: &RenderArgs) -> anyhow::Result<()> {
    let (width, height) = parse_size(&args.size)?;
    if args.patch_cells == 0 {
        bail!("--patch-cells must be at least 1");
    }
    if !(args.factor.is_finite() && args.factor > 0.0) {
        bail!("--factor must be a positive number, got {}", args.factor);
    }
    let hm = match args.source.load()? {
        Some(dem) => dem.heightmap,
        None => synth::default_terrain(),
    };
    let texture = args.texture.as_ref().map(load_texture).transpose()?;
    let camera = camera_for(args, &hm, width, height)?;

    let ctx = GpuContext::new(&DeviceConfig::from_env(BackendChoice::Auto))
        .context("no GPU adapter (Vulkan or GL) is available")?;
    println!("adapter: {}", ctx.describe());
    let config = RenderConfig { width, height, texture, ..Default::default() };
    let mut renderer = TerrainRenderer::new(&ctx, &hm, &config)?;
    let patches = uniform_patches(&hm, args.patch_cells, args.factor);
    let options = RenderOptions { wireframe: args.wireframe, ..Default::default() };
    let p = camera.position;
    println!(
        "camera: {:.1},{:.1},{:.1} looking {:.1?}, near {:.2} m, far {:.0} m",
        p.x,
        p.y,
        p.z,
        camera.forward(),
        camera.near,
        camera.far
    );
    for frame in 1..=args.frames.max(1) {
        let s = renderer.render(&camera, &patches, &options)?;
        println!(
            "frame {frame}: patches {}, triangles {}, vertices {}, CPU {:.2} ms, GPU {}, adapter {}",
            s.patches,
            s.triangles,
            s.vertices,
            s.cpu_ms,
            s.gpu_text(),
            s.adapter
        );
    }
    let image = renderer.read_image()?;
    let raw: Vec<u8> = image.pixels.iter().flatten().copied().collect();
    image::save_buffer(&args.output, &raw, image.width, image.height, image::ColorType::Rgba8)
        .with_context(|| format!("could not write {}", args.output.display()))?;
    println!("wrote {} ({} x {})", args.output.display(), image.width, image.height);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_and_cameras_parse_and_reject() {
        assert_eq!(parse_size("160x90").unwrap(), (160, 90));
        assert_eq!(parse_size(" 3X2 ").unwrap(), (3, 2));
        for bad in ["160", "0x10", "ax9", "-1x5"] {
            assert!(parse_size(bad).unwrap_err().to_string().contains(bad), "{bad}");
        }
        let (p, yaw, pitch) = parse_camera("429000.5,5000000,450,90,-35").unwrap();
        assert_eq!((p, yaw, pitch), (DVec3::new(429000.5, 5000000.0, 450.0), 90.0, -35.0));
        for bad in ["1,2,3,4", "1,2,3,4,x", "1,2,3,4,5,6", "1,2,NaN,4,5"] {
            assert!(parse_camera(bad).unwrap_err().to_string().contains(bad), "{bad}");
        }
    }
}
