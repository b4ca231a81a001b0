//! `terrain render`: draws a DEM (or the embedded synthetic terrain) with the GPU tessellator
//! into a PNG, and prints what each frame drew and cost. A baked store (a folder whose index
//! starts with the store's magic) is drawn out of core: the out-of-core paper's method
//! ([`terrain_app::ooc`]) streams its blocks into a paged renderer, so a DEM larger than
//! memory renders; the stream statistics (the paper's Table 3) join the frame statistics.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;
use terrain_app::camera::{self, CameraSpec, Ground, ViewConfig};
use terrain_app::method::registry::ErrorView;
use terrain_app::method::{self, FrameLoop, FrameRenderer, MethodOptions, OocWait};
use terrain_app::methods::{LodMethod, MethodConfig, MethodScene};
use terrain_app::ooc;
use terrain_core::geometry::Camera;
use terrain_core::{Heightmap, synth};
use terrain_gpu::render::clip_range;
use terrain_gpu::{
    BackendChoice, DeviceConfig, GpuContext, RenderConfig, RenderOptions, RgbaImage,
};

use crate::source::SourceArgs;

/// Arguments of `terrain render`.
#[derive(Debug, Args)]
pub(crate) struct RenderArgs {
    #[command(flatten)]
    pub source: SourceArgs,
    #[command(flatten)]
    pub eye: crate::draw_args::CameraArgs,
    /// Image size, WIDTHxHEIGHT.
    #[arg(long, default_value = "1280x720")]
    pub size: String,
    #[command(flatten)]
    pub lod: crate::draw_args::MethodArgs,
    /// A scene folder from `terrain bake` of the same DEM: its PVS files and DSS errors are
    /// read instead of computed (a bad file is a warning; see `terrain bench --scene`).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// `--method uniform`: tessellation factor of every patch (fractional-even: 2 to 64)
    /// [default: from the quality preset balanced].
    #[arg(long)]
    pub factor: Option<f32>,
    /// Background colour R,G,B (0-255).
    #[arg(long, default_value = "150,185,225")]
    pub background: String,
    /// Also write the per-frame statistics as JSON to this file.
    #[arg(long)]
    pub stats_json: Option<PathBuf>,
    /// Darken triangle edges.
    #[arg(long)]
    pub wireframe: bool,
    /// Colour every patch by its level of detail (grid cells per triangle edge; the legend is
    /// in README, "terrain view") instead of the height ramp (geomorph: its patch's level, 2^level cells).
    #[arg(long)]
    pub lod_colours: bool,
    /// Colour texture (PNG or JPEG) stretched over the whole DEM, its first row at the north.
    #[arg(long)]
    pub texture: Option<PathBuf>,
    /// Frames to draw with the one camera (the tessellation is reused after the first): for
    /// timing; not with --flight [default: 1].
    #[arg(long)]
    pub frames: Option<u32>,
    #[command(flatten)]
    pub store: crate::draw_args::StoreArgs,
    /// A store: fly this camera flight (JSON, see `flights/`) instead of one camera, placed on
    /// an overview of the store's level-4 vertices; frames after the first do not wait for
    /// I/O (real time: blocks drawn at their finest resident level, late data counted) unless
    /// --wait. The PNG is the last frame.
    #[arg(long)]
    pub flight: Option<PathBuf>,
    /// A store: every frame waits until the levels it needs are resident (warm: for
    /// measurements and still images); by default only the first frame does.
    #[arg(long)]
    pub wait: bool,
    /// With --flight: frames drawn at most, evenly spaced (0 = every frame) [default: 0].
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Output image: .png (RGBA) or .jpg (RGB); checked before rendering.
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
    spec: Option<&CameraSpec>,
    hm: &Heightmap,
    width: u32,
    height: u32,
) -> anyhow::Result<Camera> {
    place_camera(spec, hm, (width, height), args.eye.fov)
}

/// `--camera`/`--look-at` placed on the DEM `hm` (the default framing without them), its near
/// and far planes fitted to the DEM; a lifted eye and a view without terrain are said on
/// stderr (a warning naming `--camera`: the image is still drawn, and the exit code is 0).
pub(crate) fn place_camera(
    spec: Option<&CameraSpec>,
    hm: &Heightmap,
    (width, height): (u32, u32),
    fov: f64,
) -> anyhow::Result<Camera> {
    let view =
        ViewConfig { size_px: glam::dvec2(f64::from(width), f64::from(height)), fov_y_deg: fov };
    let placed = camera::place(spec, &Ground::of(hm), &view)?;
    let (near, far) = clip_range(hm, placed.camera.position);
    let c = placed.camera.with_clip(near, far);
    say_view(&placed, hm, &c);
    Ok(c)
}

/// The `camera:` line: position, view direction, near and far.
fn print_camera(camera: &Camera) {
    let (p, f) = (camera.position, camera.forward());
    println!(
        "camera: {:.1},{:.1},{:.1} looking along {:.2},{:.2},{:.2} (east, north, up), near {:.2} m, far {:.0} m",
        p.x, p.y, p.z, f.x, f.y, f.z, camera.near, camera.far
    );
}

/// Warns when the camera was lifted out of the ground or sees no terrain of `heights`.
fn say_view(placed: &camera::Placed, heights: &Heightmap, c: &Camera) {
    if let Some(w) = placed.lift_warning() {
        eprintln!("warning: {w}");
    }
    if let Some(no) = camera::check_view(heights, c) {
        eprintln!("warning: {no}");
    }
}

/// One frame's statistics, as `--stats-json` writes them (a store's frames add the threshold,
/// the block figures and the stream's).
#[derive(Debug, serde::Serialize)]
struct FrameRecord {
    frame: u32,
    method: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    tau: Option<f64>,
    patches: usize,
    triangles: u64,
    vertices: u64,
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    blocks: Option<method::BlockStats>,
    selection_ms: f64,
    encode_ms: f64,
    gpu_ms: Option<f64>,
    draw_pass_ms: Option<f64>,
    wall_ms: f64,
    /// The frame loop's whole frame: selection, building and converting what is drawn, and
    /// the renderer's wall time (what `terrain view --stats-json` calls `engine_ms`).
    frame_ms: f64,
    /// CPU time of the whole process over the frame (every thread: the frame loop's and the
    /// driver's; on lavapipe its rasterizer threads), ms, 10 ms ticks: the frame's work,
    /// which unlike `frame_ms` does not grow when other processes take the cores.
    process_cpu_ms: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    stream: Option<ooc::StreamRecord>,
}

/// The one frame loop of `render`: every camera through `frames` (the method's frame, drawn),
/// a line per frame (every 50th of long flights) and the records. `parameter` names the
/// method's threshold in the lines and records (a store's tau).
fn draw_frames(
    frames: &mut FrameLoop<'_>,
    cameras: &[Camera],
    parameter: Option<f64>,
) -> anyhow::Result<Vec<FrameRecord>> {
    let name = frames.method().kind().name();
    let mut records = Vec::with_capacity(cameras.len());
    for (frame, camera) in (1u32..).zip(cameras) {
        let cpu = terrain_app::bench::process_cpu_s();
        let f = frames.frame(frame as usize - 1, camera, None)?;
        let process_cpu_ms = (terrain_app::bench::process_cpu_s() - cpu) * 1e3;
        let s = f.drawn.as_ref().expect("render draws every frame");
        say_batches(frames, s.batches);
        let r = &f.record;
        // What the frame computed before drawing: the selection (and the entropy mesh's build).
        let selection_ms = r.selection_ms + r.cpu_tess_ms;
        for fault in r.stream.iter().flat_map(|st| &st.new_faults) {
            eprintln!("warning: store fault: {fault}");
        }
        let verbose = cameras.len() <= 20 || frame % 50 == 1 || frame as usize == cameras.len();
        if verbose {
            let blocks = f
                .blocks
                .map(|b| {
                    format!(", blocks drawn {} (dropped {})", b.blocks_drawn, b.blocks_dropped)
                })
                .unwrap_or_default();
            println!(
                "frame {frame}: method {name}{}, patches {}, triangles {}, vertices {}{blocks}, \
                 selection {:.2} ms, CPU {:.2} ms, GPU {}, adapter {}",
                parameter.map(|t| format!(" (tau {t})")).unwrap_or_default(),
                s.patches,
                s.triangles,
                s.vertices.unwrap_or(0),
                selection_ms,
                s.cpu_ms,
                s.gpu_text,
                s.adapter
            );
            if let Some(st) = &r.stream {
                println!(
                    "  stream: needed {:.3} MiB ({:.3} resident, late {:.3} MiB in {} blocks), \
                     synchronous {:.3} MiB ({} loads), \
                     prefetched {:.3} MiB, I/O {:.2} ms, cache hits {} misses {}, evictions {}, \
                     resident {:.3} / {:.0} MiB, queue {} ({:.3} MiB), waited {:.1} ms, faults {}{}",
                    st.needed_mib,
                    st.needed_resident_mib,
                    st.late_mib,
                    st.late_blocks,
                    st.sync_mib,
                    st.sync_loads,
                    st.prefetched_mib,
                    st.io_ms,
                    st.cache_hits,
                    st.cache_misses,
                    st.evictions,
                    st.resident_mib,
                    st.budget_mib,
                    st.queue_depth,
                    st.queued_mib,
                    st.wait_ms,
                    st.faults,
                    match (st.late_table_pages, st.demand_on_lattice) {
                        (0, false) => String::new(),
                        (0, true) => ", demand held to the budget".to_string(),
                        (n, held) => format!(
                            ", table pages late {n}{}",
                            if held { ", demand held to the budget" } else { "" }
                        ),
                    }
                );
            }
        }
        records.push(FrameRecord {
            frame,
            method: name,
            tau: parameter,
            patches: s.patches,
            triangles: s.triangles,
            vertices: s.vertices.unwrap_or(0),
            blocks: f.blocks,
            selection_ms,
            encode_ms: s.cpu_ms,
            gpu_ms: s.gpu_ms,
            draw_pass_ms: s.gpu_draw_ms,
            // The renderer waits for the GPU before returning, so this is the frame's whole
            // cost after selection: encode, tessellate (when the patches changed), draw.
            wall_ms: s.wall_ms,
            frame_ms: r.frame_ms,
            process_cpu_ms,
            stream: r.stream.clone(),
        });
    }
    Ok(records)
}

/// Runs `terrain render`.
pub(crate) fn run(args: &RenderArgs) -> anyhow::Result<()> {
    let (width, height) = parse_size(&args.size)?;
    let background = parse_rgb(&args.background)?;
    args.lod.check()?;
    let factor = args.factor.unwrap_or(DEFAULT_FACTOR);
    if !(factor.is_finite() && factor > 0.0) {
        bail!("--factor must be a positive number, got {factor}");
    }
    let spec = args.eye.spec()?;
    let store = match args.source.dem.as_slice() {
        [one] if ooc::is_store(one) => Some(one),
        _ => None,
    };
    refuse_ignored(args, store.is_some())?;
    // The arguments are fine: now the output, before any loading or rendering.
    let kind = check_image_output(&args.output)?;
    if let Some(one) = store {
        return run_store(args, spec.as_ref(), one, (width, height), background, kind);
    }
    let method_kind = args.lod.kind(false);
    let hm = match args.source.load_surface()? {
        Some(dem) => dem.heightmap,
        None => synth::default_terrain(),
    };
    let texture = args.texture.as_ref().map(load_texture).transpose()?;
    let camera = camera_for(args, spec.as_ref(), &hm, width, height)?;

    let mut method_config = MethodConfig {
        leaf_cells: args.lod.leaf_cells,
        uniform_factor: factor,
        ..MethodConfig::default()
    };
    let view = ErrorView { height_px: f64::from(height), fov_y_deg: args.eye.fov };
    let own = [("--factor", args.factor.is_some())];
    if let Some(p) = args.lod.quality.apply(&mut method_config, method_kind, view, &own)? {
        println!("quality: {p}");
    }
    let scene = MethodScene::new(hm, method_config);
    if let Some(dir) = &args.scene {
        for warning in terrain_app::scene_files::load(&scene, dir, &[method_kind]) {
            eprintln!("warning: {warning}");
        }
    }
    let method = method::build(
        method_kind,
        &scene,
        &MethodOptions { morph: true, ..MethodOptions::default() },
    )?;
    scene.prepare(&[method_kind]);
    let ctx = GpuContext::new(&DeviceConfig::from_env(BackendChoice::Auto))
        .context("no GPU adapter (Vulkan or GL) is available")?;
    println!("adapter: {}", ctx.describe());
    let config = RenderConfig { width, height, texture, background, ..Default::default() };
    let mut renderer = method.renderer(&ctx, &config)?;
    let options = RenderOptions {
        wireframe: args.wireframe,
        lod_colours: args.lod_colours,
        ..Default::default()
    };
    print_camera(&camera);
    let cameras = vec![camera; args.frames.unwrap_or(1).max(1) as usize];
    let mut frames = FrameLoop::new(method).rendered(Some(&mut renderer)).with_options(options);
    let records = draw_frames(&mut frames, &cameras, None)?;
    drop(frames);
    if let Some(path) = &args.stats_json {
        let json = serde_json::json!({ "adapter": ctx.describe(), "frames": records });
        std::fs::write(path, serde_json::to_string_pretty(&json)?)
            .with_context(|| format!("could not write {}", path.display()))?;
    }
    save_image(&renderer, &args.output, kind)
}

/// `--factor` when not given.
const DEFAULT_FACTOR: f32 = 16.0;

/// Refuses the options this mode would ignore, naming each and where it applies: the store
/// options with a DEM, `--scene` with a store (its tables are in its own folder), `--frames`
/// with `--flight`, `--max-frames` without it, `--factor` with a method other than uniform.
fn refuse_ignored(args: &RenderArgs, store: bool) -> anyhow::Result<()> {
    let given = |list: &[(&'static str, bool)]| -> Vec<&'static str> {
        list.iter().filter(|(_, g)| *g).map(|(name, _)| *name).collect()
    };
    let refuse = |names: Vec<&str>, why: &str| -> anyhow::Result<()> {
        match names.as_slice() {
            [] => Ok(()),
            [one] => bail!("{one} applies {why}"),
            many => bail!("{} apply {why}", many.join(", ")),
        }
    };
    if store {
        args.source.store_exaggeration()?;
    }
    if !store {
        refuse(
            given(&[
                args.store.given()[0],
                args.store.given()[1],
                args.store.given()[2],
                args.store.given()[3],
                ("--flight", args.flight.is_some()),
                ("--wait", args.wait),
                ("--max-frames", args.max_frames.is_some()),
            ]),
            "to a baked store (`terrain render STORE`, a folder from `terrain bake`), not to a \
             DEM file",
        )?;
        if args.scene.is_some() {
            let method = args.lod.kind(false);
            terrain_app::scene_files::check_used(&[method]).map_err(anyhow::Error::msg)?;
        }
    } else if args.scene.is_some() {
        bail!(
            "--scene applies to a DEM file: a store's tables (from `terrain bake`) are read \
             from the store folder itself"
        );
    }
    if args.flight.is_some() {
        refuse(
            given(&[
                ("--frames", args.frames.is_some()),
                ("--camera", args.eye.camera.is_some()),
                ("--look-at", args.eye.look_at.is_some()),
            ]),
            "to one camera, not to --flight",
        )?;
    } else if store {
        refuse(given(&[("--max-frames", args.max_frames.is_some())]), "only with --flight")?;
    }
    let uniform = args.lod.method == Some(LodMethod::Uniform);
    if !uniform && args.factor.is_some() {
        bail!("--factor applies only to --method uniform");
    }
    Ok(())
}

/// The image formats `-o` writes, from its extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ImageOut {
    /// `.png`: RGBA.
    Png,
    /// `.jpg` / `.jpeg`: RGB (JPEG has no alpha).
    Jpeg,
}

/// Checks `-o` before any work: an extension we write (`.png`, `.jpg`, `.jpeg`) and a place we
/// can write to, so a typo fails at once instead of after the rendering.
pub(crate) fn check_image_output(path: &Path) -> anyhow::Result<ImageOut> {
    if path.is_dir() {
        bail!("-o {}: is a folder; give an image file name (.png or .jpg)", path.display());
    }
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    let kind = match ext.as_deref() {
        Some("png") => ImageOut::Png,
        Some("jpg" | "jpeg") => ImageOut::Jpeg,
        Some(e) => bail!(
            "-o {}: .{e} images are not written; give a file name ending in .png or .jpg",
            path.display()
        ),
        None => {
            bail!("-o {}: no extension; give a file name ending in .png or .jpg", path.display())
        }
    };
    check_writable(path)?;
    Ok(kind)
}

/// Checks a file can be written at `path` before the work that produces it: an existing file
/// is opened for writing (not truncated); a new one is created and removed again.
pub(crate) fn check_writable(path: &Path) -> anyhow::Result<()> {
    let existed = path.exists();
    let parent = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    if !parent.is_dir() {
        bail!("cannot write {}: the folder {} does not exist", path.display(), parent.display());
    }
    std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(false)
        .open(path)
        .map_err(|e| anyhow::anyhow!("cannot write {}: {}", path.display(), e.kind()))?;
    if !existed {
        let _ = std::fs::remove_file(path);
    }
    Ok(())
}

fn save_image(renderer: &FrameRenderer, output: &Path, kind: ImageOut) -> anyhow::Result<()> {
    let image = renderer.read_image()?;
    let written = match kind {
        ImageOut::Png => {
            let raw: Vec<u8> = image.pixels.iter().flatten().copied().collect();
            image::save_buffer_with_format(
                output,
                &raw,
                image.width,
                image.height,
                image::ColorType::Rgba8,
                image::ImageFormat::Png,
            )
        }
        ImageOut::Jpeg => {
            let rgb: Vec<u8> = image.pixels.iter().flat_map(|p| [p[0], p[1], p[2]]).collect();
            image::save_buffer_with_format(
                output,
                &rgb,
                image.width,
                image.height,
                image::ColorType::Rgb8,
                image::ImageFormat::Jpeg,
            )
        }
    };
    written.with_context(|| format!("could not write {}", output.display()))?;
    println!("wrote {} ({} x {})", output.display(), image.width, image.height);
    Ok(())
}

/// `terrain render <store>`: a method drawn from a baked store (default the out-of-core
/// paper's, `ooc`; see [`method::store_method`] for the others).
fn run_store(
    args: &RenderArgs,
    spec: Option<&CameraSpec>,
    dir: &std::path::Path,
    (width, height): (u32, u32),
    background: [u8; 4],
    kind: ImageOut,
) -> anyhow::Result<()> {
    let method_kind = args.lod.kind(true);
    let mut method_config = MethodConfig {
        leaf_cells: args.lod.leaf_cells,
        uniform_factor: args.factor.unwrap_or(DEFAULT_FACTOR),
        ..MethodConfig::default()
    };
    method_config.ooc.tau = args.store.tau.unwrap_or(2.0);
    method_config.ooc.calibration = terrain_app::ooc_calibration::of_store(dir)?;
    let view = ErrorView { height_px: f64::from(height), fov_y_deg: args.eye.fov };
    let own = [("--factor", args.factor.is_some()), ("--tau", args.store.tau.is_some())];
    if let Some(p) = args.lod.quality.apply(&mut method_config, method_kind, view, &own)? {
        println!("quality: {p}");
    }
    let tau = method_config.ooc.tau;
    let cache_mib = args.store.cache_mib();
    let flight = args.flight.as_ref().map(terrain_core::flight::FlightSpec::load).transpose()?;
    let mut config = ooc::OocConfig {
        vertical_scale: args.source.store_exaggeration()?,
        calibration: method_config.ooc.calibration,
        ..args.store.config(tau)?
    };
    // A flight's frames come at its own rate: Eq. 8's `f`.
    if let Some(flight) = &flight {
        config = config.for_flight(flight.fps);
    }
    let scene = open_store(dir, config)?;
    let cameras: Vec<Camera> = match &flight {
        None => {
            let camera = store_camera(&scene, dir, spec, (width, height), args.eye.fov)?;
            vec![camera; args.frames.unwrap_or(1).max(1) as usize]
        }
        Some(flight) => {
            let size = (width, height);
            store_flight(&scene, dir, flight, size, args.max_frames.unwrap_or(0))?.cameras
        }
    };
    let texture = args.texture.as_ref().map(load_texture).transpose()?;
    let ctx = GpuContext::new(&DeviceConfig::from_env(BackendChoice::Auto))
        .context("no GPU adapter (Vulkan or GL) is available")?;
    println!("adapter: {}", ctx.describe());
    let render_config = RenderConfig { width, height, texture, background, ..Default::default() };
    let wait = if args.wait { OocWait::EveryFrame } else { OocWait::FirstFrame };
    let method_config = MethodConfig { ooc: config, ..method_config };
    println!("method: {}", method_kind.name());
    let method = method::store_method(method_kind, scene, &method_config, wait, None)?;
    let mut renderer = method.renderer(&ctx, &render_config)?;
    if let Some(r) = renderer.terrain_renderer() {
        println!(
            "pages: {} slots ({} full resolution), {:.1} MiB of page atlas on the device",
            r.page_capacity(),
            r.page_classes().first().map_or(0, |c| c.capacity),
            r.page_atlas_bytes() as f64 / terrain_app::MIB
        );
    }
    let options = RenderOptions {
        wireframe: args.wireframe,
        lod_colours: args.lod_colours,
        ..Default::default()
    };
    let mut frames = FrameLoop::new(method).rendered(Some(&mut renderer)).with_options(options);
    let records =
        draw_frames(&mut frames, &cameras, (method_kind == LodMethod::OutOfCore).then_some(tau))?;
    drop(frames);
    check_something_drawn(&records, dir)?;
    let streams: Vec<ooc::StreamRecord> =
        records.iter().map(|r| r.stream.clone().unwrap_or_default()).collect();
    let max_triangles = records.iter().map(|r| r.triangles).max().unwrap_or(0);
    print_stream_summary(&streams, max_triangles, args.wait, cache_mib);
    if let Some(path) = &args.stats_json {
        let json = serde_json::json!({
            "adapter": ctx.describe(),
            "store": dir.display().to_string(),
            "frames": records,
        });
        std::fs::write(path, serde_json::to_string_pretty(&json)?)
            .with_context(|| format!("could not write {}", path.display()))?;
    }
    save_image(&renderer, &args.output, kind)
}

/// `--camera`/`--look-at` placed over the store of `scene` (folder `dir`), with the ground
/// and the default framing from an overview of its level-4 vertices (no heightmap is in
/// memory) and lon/lat in the store's CRS; near and far fitted to the store's blocks; warnings
/// as for a DEM ([`place_camera`]).
fn store_camera(
    scene: &ooc::OocScene,
    dir: &Path,
    spec: Option<&CameraSpec>,
    (width, height): (u32, u32),
    fov: f64,
) -> anyhow::Result<Camera> {
    let overview =
        scene.overview(4).with_context(|| format!("could not read the store {}", dir.display()))?;
    let georef = &scene.store().header().georef;
    let view =
        ViewConfig { size_px: glam::dvec2(f64::from(width), f64::from(height)), fov_y_deg: fov };
    let placed = camera::place(spec, &Ground { heights: &overview, georef }, &view)?;
    let (near, far) = scene.clip_range(placed.camera.position);
    let c = placed.camera.with_clip(near, far);
    print_camera(&c);
    say_view(&placed, &overview, &c);
    Ok(c)
}

/// Fails when the image's frame (the last of `records`) drew nothing of the store although
/// blocks were in view: every one of them failed to load (the faults were reported above as
/// they happened), or found no page slot. There is no picture to write, only the background.
fn check_something_drawn(records: &[FrameRecord], dir: &Path) -> anyhow::Result<()> {
    let Some(b) = records.last().and_then(|r| r.blocks) else { return Ok(()) };
    if b.blocks_drawn > 0 || b.blocks_dropped == 0 {
        return Ok(());
    }
    let faults: usize = records.iter().filter_map(|r| r.stream.as_ref()).map(|s| s.faults).sum();
    if faults > 0 {
        bail!(
            "nothing could be drawn from the store {}: none of the {} blocks in view has a level \
             that could be read ({faults} store fault(s), each described above); no image \
             written. Bake the store again (`terrain bake DEM -o {} --overwrite`)",
            dir.display(),
            b.blocks_dropped,
            dir.display()
        );
    }
    bail!(
        "nothing could be drawn from the store {}: none of the {} blocks in view found a page \
         slot on the device; no image written. Give more page memory (--page-mib)",
        dir.display(),
        b.blocks_dropped
    );
}

/// Opens the store in `dir` for drawing with `config` and says what it holds.
pub(crate) fn open_store(dir: &Path, config: ooc::OocConfig) -> anyhow::Result<ooc::OocScene> {
    let scene = ooc::OocScene::open(dir, config)
        .with_context(|| format!("could not open the store {}", dir.display()))?;
    let h = scene.store().header().clone();
    println!(
        "store: {} ({} x {} samples, blocks of {} x {} vertices, {} x {} blocks)",
        dir.display(),
        h.width,
        h.height,
        h.block_side(),
        h.block_side(),
        h.blocks_x,
        h.blocks_y
    );
    if h.vertical_scale != 1.0 {
        println!("store: heights exaggerated x{}", h.vertical_scale);
    }
    Ok(scene)
}

/// A flight resolved over a store (placed on an overview of its level-4 vertices, since no
/// heightmap is in memory): the frames drawn and their cameras, clipped to the store's range.
pub(crate) struct StoreFlight {
    /// The flight's name.
    pub name: String,
    /// Its frames in all.
    pub total_frames: usize,
    /// The flight's index of every drawn frame.
    pub indices: Vec<usize>,
    /// The drawn frames' cameras.
    pub cameras: Vec<Camera>,
    /// What resolving the flight warned about.
    pub warnings: Vec<String>,
}

/// Resolves `spec` over the store of `scene` (folder `dir`) for `size` images: at most
/// `max_frames` frames, evenly spaced (0 = every frame). Warnings are printed too.
pub(crate) fn store_flight(
    scene: &ooc::OocScene,
    dir: &Path,
    spec: &terrain_core::flight::FlightSpec,
    (width, height): (u32, u32),
    max_frames: usize,
) -> anyhow::Result<StoreFlight> {
    let overview =
        scene.overview(4).with_context(|| format!("could not read the store {}", dir.display()))?;
    let cfg = terrain_core::flight::FlightConfig {
        viewport_px: glam::dvec2(f64::from(width), f64::from(height)),
        ..Default::default()
    };
    let (flight, warnings) = spec.resolve(&overview, &cfg);
    for w in &warnings {
        eprintln!("warning: flight {}: {w}", flight.name);
    }
    let indices = terrain_app::bench::frame_indices(flight.frames().len(), max_frames);
    println!("flight {}: {} of {} frames", flight.name, indices.len(), flight.frames().len());
    let cameras = indices
        .iter()
        .map(|&k| {
            let c = flight.frames()[k];
            let (near, far) = scene.clip_range(c.position);
            c.with_clip(near, far)
        })
        .collect::<Vec<Camera>>();
    let blind = camera::frames_without_terrain(&overview, &cameras);
    if let Some(w) = camera::flight_warning(&flight.name, &blind, cameras.len()) {
        eprintln!("warning: {w}");
    }
    Ok(StoreFlight {
        name: flight.name.clone(),
        total_frames: flight.frames().len(),
        indices,
        cameras,
        warnings: warnings.iter().map(ToString::to_string).collect(),
    })
}

/// Prints the streaming summary of frames drawn from a store: their stream records (`wait`:
/// every frame waited until warm; `cache_mib`: the stream cache's budget) and their largest
/// triangle count.
pub(crate) fn print_stream_summary(
    streams: &[ooc::StreamRecord],
    max_triangles: u64,
    wait: bool,
    cache_mib: u64,
) {
    let total = |g: &dyn Fn(&ooc::StreamRecord) -> f64| streams.iter().map(g).sum::<f64>();
    let summary = ooc::StreamSummary::new(streams, !wait, 0);
    println!(
        "summary: {} frames ({}), frames that waited for I/O after frame 1: {}, \
         drawn at their needed level: {:.1} %, late {:.3} MiB per frame (median), \
         synchronous loads after frame 1: {}, synchronous {:.2} MiB, \
         prefetched {:.2} MiB, I/O {:.1} ms, peak resident {:.1} MiB (budget {} MiB), max triangles {}{}{}{}",
        streams.len(),
        if wait { "warm: every frame waits" } else { "real time" },
        summary.waited_after_first,
        100.0 * summary.at_needed_level_share,
        summary.late_mib_median,
        streams.iter().skip(1).map(|s| s.sync_loads).sum::<usize>(),
        total(&|s| s.sync_mib),
        total(&|s| s.prefetched_mib),
        total(&|s| s.io_ms),
        streams.iter().map(|s| s.resident_mib).fold(0.0, f64::max),
        cache_mib,
        max_triangles,
        match streams.iter().filter(|s| s.late_table_pages > 0).count() {
            0 => String::new(),
            n => format!(
                ", frames drawing table pages not fetched yet: {n} ({} pages)",
                streams.iter().map(|s| s.late_table_pages).sum::<u64>()
            ),
        },
        match streams.iter().filter(|s| s.late_tiles > 0).count() {
            0 => String::new(),
            n => format!(
                ", frames drawing tiles not built yet (by a coarser ancestor): {n} ({} tiles)",
                streams.iter().map(|s| s.late_tiles).sum::<usize>()
            ),
        },
        match streams.iter().filter(|s| s.demand_on_lattice).count() {
            0 => String::new(),
            n => format!(
                ", frames whose demand was held to the budget (patches between lattice \
                 samples drawn from the power-of-two lattice above their factors): {n}"
            ),
        }
    );
}

/// Says when a frame was drawn in several batches (its tessellated points or indices exceed
/// the device's largest storage binding; the renderer splits the frame rather than refusing it).
fn say_batches(frames: &mut FrameLoop<'_>, batches: usize) {
    if batches > 1 {
        let limit = frames
            .renderer()
            .and_then(|r| r.terrain_renderer().map(|t| t.batch_limit_bytes()))
            .unwrap_or(0);
        println!(
            "  the frame's tessellated points or indices exceed the device's {limit} byte binding \
             limit: drawn in {batches} compute + draw batches"
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_and_reject() {
        assert_eq!(parse_size("160x90").unwrap(), (160, 90));
        assert_eq!(parse_size(" 3X2 ").unwrap(), (3, 2));
        for bad in ["160", "0x10", "ax9", "-1x5"] {
            assert!(parse_size(bad).unwrap_err().to_string().contains(bad), "{bad}");
        }
        // `--camera` forms are parsed and tested in `terrain_app::camera`.
    }
}
