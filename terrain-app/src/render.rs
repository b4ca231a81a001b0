//! `terrain render`: draws a DEM (or the embedded synthetic terrain) with the GPU tessellator
//! into a PNG, and prints what each frame drew and cost.

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::Args;
use glam::DVec3;
use terrain_app::methods::{LodMethod, MethodConfig, MethodScene};
use terrain_core::geometry::Camera;
use terrain_core::{Heightmap, synth};
use terrain_gpu::render::{clip_range, default_camera};
use terrain_gpu::{
    BackendChoice, DeviceConfig, GpuContext, RenderConfig, RenderOptions, RgbaImage,
    TerrainRenderer,
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
    /// LOD method: which patches to draw with which tessellation factors.
    #[arg(long, value_enum, default_value_t = LodMethod::PvpsC)]
    pub method: LodMethod,
    /// Cells per side of the finest patch (the PVPS paper: a 64 x 64 patch grid).
    #[arg(long, default_value_t = 16)]
    pub leaf_cells: u32,
    /// `--method uniform`: tessellation factor of every patch (fractional-even: 2 to 64).
    #[arg(long, default_value_t = 16.0)]
    pub factor: f32,
    /// Background colour R,G,B (0-255).
    #[arg(long, default_value = "150,185,225")]
    pub background: String,
    /// Also write the per-frame statistics as JSON to this file.
    #[arg(long)]
    pub stats_json: Option<PathBuf>,
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

pub(crate) fn parse_size(s: &str) -> anyhow::Result<(u32, u32)> {
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
pub(crate) fn parse_camera(s: &str) -> anyhow::Result<(DVec3, f64, f64)> {
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

/// `r,g,b` -> an opaque colour.
fn parse_rgb(s: &str) -> anyhow::Result<[u8; 4]> {
    let bad = || format!("--background expects R,G,B with each 0-255, got `{s}`");
    let v: Vec<u8> =
        s.split(',').map(|p| p.trim().parse::<u8>()).collect::<Result<_, _>>().with_context(bad)?;
    match v[..] {
        [r, g, b] => Ok([r, g, b, 255]),
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

/// One frame's statistics, as `--stats-json` writes them.
#[derive(Debug, serde::Serialize)]
struct FrameRecord {
    frame: u32,
    method: &'static str,
    patches: usize,
    triangles: u64,
    vertices: u64,
    selection_ms: f64,
    encode_ms: f64,
    gpu_ms: Option<f64>,
    draw_pass_ms: Option<f64>,
    wall_ms: f64,
}

/// Runs `terrain render`.
pub fn run(args: &RenderArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.method != LodMethod::Entropy,
        "the entropy method makes a triangle mesh the renderer cannot draw yet: use \
         `terrain mesh --entropy` or `terrain bench --no-render`"
    );
    let (width, height) = parse_size(&args.size)?;
    let background = parse_rgb(&args.background)?;
    if args.leaf_cells == 0 {
        bail!("--leaf-cells must be at least 1");
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
    let config = RenderConfig { width, height, texture, background, ..Default::default() };
    let mut renderer = TerrainRenderer::new(&ctx, &hm, &config)?;
    let method_config = MethodConfig {
        leaf_cells: args.leaf_cells,
        uniform_factor: args.factor,
        ..MethodConfig::default()
    };
    let scene = MethodScene::new(hm, method_config);
    scene.prepare(&[args.method]);
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
    let mut records = Vec::new();
    for frame in 1..=args.frames.max(1) {
        let drawn = scene.frame(args.method, &camera);
        let selection = &drawn.selection;
        let (patches, extra) = scene.frame_draw(&drawn);
        let start = std::time::Instant::now();
        let s = renderer.render_with_extra(&camera, &patches, &extra, &options)?;
        // The renderer waits for the GPU before returning, so this is the frame's whole cost
        // after selection: encode, tessellate (when the patches changed), draw.
        let wall_ms = start.elapsed().as_secs_f64() * 1e3;
        let selection_ms = selection.stats.cpu_time.as_secs_f64() * 1e3;
        println!(
            "frame {frame}: method {}, patches {}, triangles {}, vertices {}, selection {:.2} ms, \
             CPU {:.2} ms, GPU {}, adapter {}",
            args.method.name(),
            s.patches,
            s.triangles,
            s.vertices,
            selection_ms,
            s.cpu_ms,
            s.gpu_text(),
            s.adapter
        );
        records.push(FrameRecord {
            frame,
            method: args.method.name(),
            patches: s.patches,
            triangles: s.triangles,
            vertices: s.vertices,
            selection_ms,
            encode_ms: s.cpu_ms,
            gpu_ms: s.gpu_ms,
            draw_pass_ms: s.gpu_draw_ms,
            wall_ms,
        });
    }
    if let Some(path) = &args.stats_json {
        let json = serde_json::json!({ "adapter": ctx.describe(), "frames": records });
        std::fs::write(path, serde_json::to_string_pretty(&json)?)
            .with_context(|| format!("could not write {}", path.display()))?;
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
