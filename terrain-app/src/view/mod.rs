//! `terrain view <dem | store>`: an interactive window drawn by the engine. Every frame goes
//! through the one frame loop ([`FrameLoop`]) and the method's own renderer
//! ([`FrameRenderer`]), exactly as `terrain render` draws it; [`present::Presenter`] copies the
//! renderer's image into the window's surface and draws the egui panel over it.
//!
//! - Input ([`camera`]): fly mode (drag with a mouse button to look, WASD/QE, wheel = speed,
//!   shift = 4x) and orbit mode (O toggles); the eye stays above the ground. R records a
//!   flight ([`record`]), F freezes the selection, P hides the panel, Esc quits.
//! - Scripts ([`script`]): `--script FILE` drives the same actions without a person.
//! - Loading never blocks the event loop: a method switch or a vertical exaggeration over a
//!   DEM in memory prepares its tables on a worker thread while the old method keeps drawing;
//!   over a store a method, quality or exaggeration change builds the new runtime (the store
//!   read exaggerated) and renderer on a worker
//!   (which plays its first, waiting frame) while the old one draws, and so does the first
//!   method at start while the window shows the sky; a store is drawn in the streamer's
//!   real-time mode (no frame the event loop draws waits for I/O).
//! - `--stats-json` writes the per-frame log (times, triangles, a store's late and queued
//!   data, whether the frame waited) with the medians, p95, max and the slow frames' causes.

mod camera;
mod measure;
mod panel;
mod present;
mod record;
mod script;

use std::collections::{HashMap, HashSet, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Instant;

use anyhow::{Context, bail};
use clap::Args;
use glam::DVec3;
use terrain_app::method::registry::{self, ErrorPxParams, ErrorView, parameter};
use terrain_app::method::{
    self, FrameLoop, FrameRenderer, LoopFrame, MethodOptions, OocWait, RendererKind,
};
use terrain_app::methods::{LodMethod, MethodConfig, MethodScene};
use terrain_app::ooc;
use terrain_core::geometry::Camera;
use terrain_core::measure::MeasureConfig;
use terrain_core::{Heightmap, synth};
use terrain_gpu::render::ClipBoxes;
use terrain_gpu::{BackendChoice, DeviceConfig, GpuContext, RenderConfig, RenderOptions};
use winit::application::ApplicationHandler;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::{Window, WindowId};

use self::camera::{Motion, ViewCamera};
use self::script::{Command, Key, Toggle};
use crate::render::parse_size;
use crate::source::SourceArgs;
use terrain_app::camera::{self as camera_spec, Ground, ViewConfig};

/// Arguments of `terrain view`.
#[derive(Debug, Args)]
pub(crate) struct ViewArgs {
    #[command(flatten)]
    pub source: SourceArgs,
    /// The start camera, as `terrain render`'s.
    #[command(flatten)]
    pub eye: crate::draw_args::CameraArgs,
    /// Window size, WIDTHxHEIGHT (the renderer draws at this size; the window is not resizable).
    #[arg(long, default_value = "1280x720")]
    pub size: String,
    /// The method at start and its quality, as in `render` and `fly`: `--error-px`, a
    /// `--quality` preset (default balanced, 2 px) or the method's own `--method-param`. The
    /// panel's slider is the error target in pixels.
    #[command(flatten)]
    pub lod: crate::draw_args::MethodArgs,
    /// Drive the viewer from a script (one command per line; see README, "terrain view").
    #[arg(long)]
    pub script: Option<PathBuf>,
    /// Play this flight (JSON, see `flights/`) from the start, then fly freely.
    #[arg(long)]
    pub flight: Option<PathBuf>,
    /// Play `--flight` at its own clock: each drawn frame shows the flight's pose at the time
    /// elapsed since the flight began when the frame starts (frame k at k / fps), so slow frames
    /// skip flight time and the flight lasts its own duration. Without it every drawn frame
    /// shows the flight's next frame.
    #[arg(long, requires = "flight")]
    pub paced: bool,
    /// Where the R key (or the script's `record`) writes the recorded flight (its folder is
    /// created; `out/` is git-ignored).
    #[arg(long, default_value = "out/recorded_flight.json")]
    pub record_to: PathBuf,
    /// Write every frame's times (the viewer's frame period and its parts: engine frame,
    /// panel, present) as JSON to this file when the window closes: the viewer-overhead
    /// measurement against `terrain render --frames N --stats-json`.
    #[arg(long)]
    pub stats_json: Option<PathBuf>,
    #[command(flatten)]
    pub store: crate::draw_args::StoreArgs,
    /// A store: MiB the on-demand measurement (M) may hold for its reference, the store's
    /// full-resolution heights (4 bytes a sample of the whole grid); over it the panel says so
    /// instead of measuring [default: 1024].
    #[arg(long, alias = "measure-mb")]
    pub measure_mib: Option<u64>,
}

/// Runs `terrain view`.
pub(crate) fn run(args: &ViewArgs) -> anyhow::Result<()> {
    let size = parse_size(&args.size)?;
    let spec = args.eye.spec()?;
    args.lod.check()?;
    let script = match &args.script {
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("could not read the script {}", p.display()))?;
            script::parse(&text).with_context(|| format!("script {}", p.display()))?
        }
        None => Vec::new(),
    };
    let store = match args.source.dem.as_slice() {
        [one] if ooc::is_store(one) => Some(one.clone()),
        _ => None,
    };
    // Options the mode would ignore are refused before anything opens.
    if store.is_none() {
        let measure_mib = ("--measure-mib", args.measure_mib.is_some());
        let given: Vec<&str> = args
            .store
            .given()
            .iter()
            .chain([&measure_mib])
            .filter(|(_, g)| *g)
            .map(|(n, _)| *n)
            .collect();
        if !given.is_empty() {
            bail!("{} apply to a baked store, not to a DEM file", given.join(", "));
        }
    }
    // The window first: without a display there is nothing to do.
    let event_loop = EventLoop::new().context(
        "could not open a window: `terrain view` needs a display (X11: is DISPLAY set?)",
    )?;
    let ctx = Arc::new(
        GpuContext::new(&DeviceConfig::from_env(BackendChoice::Auto))
            .context("no GPU adapter (Vulkan or GL) is available")?,
    );
    println!("adapter: {}", ctx.describe());
    let mut config = MethodConfig { leaf_cells: args.lod.leaf_cells, ..MethodConfig::default() };
    let kind = args.lod.kind(store.is_some());
    config.ooc.tau = args.store.tau.unwrap_or(2.0);
    if let Some(dir) = &store {
        config.ooc.calibration = terrain_app::ooc_calibration::of_store(dir)?;
    }
    // The one quality knob (README "One quality knob"): the pixel target mapped onto the
    // method's own parameter for this window's height and field of view.
    let error_view = ErrorView { height_px: f64::from(size.1), fov_y_deg: args.eye.fov };
    let own = [("--tau", args.store.tau.is_some())];
    let mapped = args.lod.quality.apply(&mut config, kind, error_view, &own)?;
    if store.is_some() {
        config.ooc = ooc::OocConfig {
            vertical_scale: args.source.store_exaggeration()?,
            calibration: config.ooc.calibration,
            ..args.store.config(config.ooc.tau)?
        };
    }
    if let Some(p) = &mapped {
        println!("quality: {p}");
    }
    let render_config = RenderConfig {
        width: size.0,
        height: size.1,
        background: [150, 185, 225, 255],
        ..Default::default()
    };
    let terrain = match &store {
        Some(dir) => Terrain::Store(Box::new(StoreTerrain::open(
            dir,
            config,
            args.measure_mib.unwrap_or(self::measure::MEASURE_MIB),
        )?)),
        None => {
            let hm = match args.source.load_surface()? {
                Some(dem) => dem.heightmap,
                None => synth::default_terrain(),
            };
            let scene = MethodScene::new(hm, config);
            scene.prepare(&[kind]);
            Terrain::Memory(MemoryTerrain {
                scene: Arc::new(scene),
                renderers: HashMap::new(),
                last_kind: None,
                job: None,
                exaggeration: 1.0,
            })
        }
    };
    let ground = terrain.ground();
    let (lo, hi) = (f64::from(ground.min()), f64::from(ground.max()));
    let extent = ground.extent_m().max_element();
    let clearance = (0.002 * extent).clamp(1.0, 50.0);
    // `--camera` in any of `render`'s forms (world, lonlat:, agl), or the default framing
    // that fills the image with the terrain: the one camera module.
    let view = ViewConfig {
        size_px: glam::dvec2(f64::from(size.0), f64::from(size.1)),
        fov_y_deg: args.eye.fov,
    };
    let placed = camera_spec::place(spec.as_ref(), &terrain.camera_ground(), &view)?;
    if let Some(w) = placed.lift_warning() {
        eprintln!("warning: {w}");
    }
    let start = {
        let c = placed.camera;
        let (yaw, pitch) = yaw_pitch_of(c.forward());
        ViewCamera::new(c.position, yaw, pitch, extent / 20.0, clearance)
    };
    let flight = match &args.flight {
        Some(path) => {
            let spec = terrain_core::flight::FlightSpec::load(path)?;
            let cfg = terrain_core::flight::FlightConfig {
                viewport_px: glam::dvec2(f64::from(size.0), f64::from(size.1)),
                ..Default::default()
            };
            let (flight, warnings) = spec.resolve(ground, &cfg);
            for w in &warnings {
                eprintln!("warning: flight {}: {w}", flight.name);
            }
            println!(
                "flight {}: {} frames at {} fps{}",
                flight.name,
                flight.frames().len(),
                spec.fps,
                if args.paced { ", paced at its own clock" } else { "" }
            );
            FlightPlay {
                poses: flight
                    .frames()
                    .iter()
                    .map(|c| {
                        let (yaw, pitch) = yaw_pitch_of(c.forward());
                        (c.position, yaw, pitch)
                    })
                    .collect(),
                next: 0,
                fps: spec.fps,
                paced: args.paced,
                started: None,
            }
        }
        None => FlightPlay::default(),
    };
    println!("terrain: heights {lo:.1} to {hi:.1} m, extent {extent:.0} m");
    if let Some(path) = &args.stats_json {
        crate::render::check_writable(path)?;
    }
    let clip = ClipBoxes::new(ground);
    // The panel's exaggeration: a store's as read (its heights are metres), 1 for a DEM in
    // memory (its --vertical-scale, a unit or an exaggeration, is in its heights).
    let exaggeration = match &terrain {
        Terrain::Store(s) => s.config.ooc.vertical_scale,
        Terrain::Memory(_) => 1.0,
    };
    let mut terrain = terrain;
    if let Terrain::Store(s) = &mut terrain {
        // The method and its renderer are built, and the first frame (the one that waits for
        // the coarse levels) played, on a worker: the window opens and handles events
        // meanwhile.
        let config = s.config.clone();
        // The pose of the first frame drawn: the flight's first, else the start camera.
        let mut first = start.clone();
        if let Some(&(p, yaw, pitch)) = flight.poses.first() {
            (first.position, first.yaw, first.pitch) = (p, yaw, pitch);
        }
        let camera = first.camera(args.eye.fov, size, clip.range(first.position));
        s.rebuild(kind, config, None, camera, &ctx, &render_config)?;
    }
    let mut app = App {
        ctx,
        render_config,
        size,
        fov: args.eye.fov,
        clip,
        terrain,
        kind,
        error_view,
        mapped,
        camera: start,
        window: None,
        presenter: None,
        egui_state: None,
        egui_ctx: egui::Context::default(),
        held: HashSet::new(),
        dragging: false,
        cursor: None,
        drag: (0.0, 0.0),
        wheel: 0.0,
        ui: UiState { exaggeration, ..UiState::default() },
        frozen: None,
        sun: SUN_DEFAULT,
        script: script.into(),
        scripted: args.script.is_some(),
        script_wait: 0,
        flight,
        wait_flight: false,
        recorder: None,
        record_to: args.record_to.clone(),
        stats: Stats::default(),
        frame_index: 0,
        frame_times: Vec::new(),
        uploads: method::Uploads::default(),
        last_frame: None,
        measure_next: false,
        sky: None,
        error: None,
        quit: false,
    };
    event_loop.set_control_flow(ControlFlow::Poll);
    event_loop.run_app(&mut app).context("the window's event loop failed")?;
    let frames = app.frame_index;
    let error = app.error.take();
    let times = FrameTimes::of(&app.frame_times);
    if let Some(m) = &times.median {
        println!(
            "view: {frames} frames, median after the first: viewer frame {:.2} ms (period \
             {:.2} ms), engine frame {:.2} ms, panel {:.2} ms, present {:.2} ms, process CPU \
             {:.0} ms per period",
            m.viewer_ms, m.period_ms, m.engine_ms, m.panel_ms, m.present_ms, m.process_cpu_ms
        );
        let waited = times.frames.iter().skip(1).filter(|t| t.waited_for_io).count();
        let loading = times.slow.iter().filter(|s| s.cause == "loading").count();
        println!(
            "view: period p95 {:.2} ms, max {:.2} ms; {} frames over twice the median ({} by \
             loading); {waited} frames after the first waited for I/O",
            times.period_p95_ms,
            times.period_max_ms,
            times.slow.len(),
            loading
        );
    }
    let shown: Vec<usize> = times.frames.iter().filter_map(|t| t.flight_frame).collect();
    if let (Some(first), Some(last)) = (shown.first(), shown.last()) {
        println!(
            "view: flight: {} drawn frames showed its frames {first} to {last} of {}{}",
            shown.len(),
            app.flight.poses.len(),
            if app.flight.paced { " (paced: the others skipped)" } else { "" }
        );
    }
    if let Some(path) = &args.stats_json {
        let json = serde_json::json!({
            "adapter": app.ctx.describe(),
            "size": [size.0, size.1],
            "frames": times.frames,
            "median_after_first": times.median,
            "period_p95_ms": times.period_p95_ms,
            "period_max_ms": times.period_max_ms,
            "over_twice_the_median": times.slow,
        });
        std::fs::write(path, serde_json::to_string_pretty(&json)?)
            .with_context(|| format!("could not write {}", path.display()))?;
        println!("view: wrote {}", path.display());
    }
    if let Terrain::Store(s) = &mut app.terrain
        && let Some(m) = s.measure.take()
    {
        // A measurement in flight is waited for: its runtime's workers go with it.
        let _ = m.join();
    }
    let threads_before = threads();
    let had_store = matches!(app.terrain, Terrain::Store(_));
    drop(app);
    if had_store {
        // The store's runtime was dropped with the app: its workers are joined by now.
        eprintln!(
            "view: closed after {frames} frames; store runtime dropped, worker threads joined \
             ({} threads before, {} after)",
            threads_before.map_or("?".into(), |t| t.to_string()),
            threads().map_or("?".into(), |t| t.to_string())
        );
    } else {
        eprintln!("view: closed after {frames} frames");
    }
    match error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

/// One viewer frame's times (ms) and what it drew and streamed: a line of the per-frame log
/// (`--stats-json`).
#[derive(Debug, Clone, Default, serde::Serialize)]
struct FrameTime {
    /// Frame index.
    frame: usize,
    /// The method that drew it.
    method: &'static str,
    /// Start of this frame to the start of the next (the last frame: its own redraw): the
    /// frame time a user sees, event handling included.
    period_ms: f64,
    /// The redraw: script and input, the engine's frame, the panel, present.
    viewer_ms: f64,
    /// The frame loop's frame (selection to the GPU done), as `terrain render` times it.
    engine_ms: f64,
    /// The engine frame's CPU time (selection, conversion, the renderer's encoding).
    cpu_ms: f64,
    /// The selection's CPU time.
    selection_ms: f64,
    /// The streamer's time on the frame thread (a store): not part of `engine_ms`.
    stream_ms: f64,
    /// Uploading the pages that arrived (a store), on the frame thread.
    pages_ms: f64,
    /// The panel (egui's layout and tessellation).
    panel_ms: f64,
    /// The copy into the window's surface, the panel's draw and present.
    present_ms: f64,
    /// CPU time of the whole process over the period (every thread: the viewer's and the
    /// driver's; on lavapipe its rasterizer threads), ms, 10 ms ticks: the work of a frame,
    /// comparable with `terrain render --stats-json`'s `process_cpu_ms` whatever else runs.
    process_cpu_ms: f64,
    /// Patches and triangles drawn (the same work as `render`'s frame of the same camera).
    patches: usize,
    triangles: u64,
    /// Bytes uploaded by the renderer (pages, patch lists, uniforms), MiB.
    upload_mib: f64,
    /// Late data: needed by this frame, not resident when it was drawn (a store), MiB.
    late_mib: f64,
    /// Requested from the workers, not delivered yet (a store), MiB.
    queued_mib: f64,
    /// Whether the frame thread read from disk or waited for the workers (a store).
    waited_for_io: bool,
    /// The `--flight` frame shown (paced: frames between the shown ones were skipped).
    #[serde(skip_serializing_if = "Option::is_none")]
    flight_frame: Option<usize>,
    /// `--paced`: the flight time the pose was taken at, seconds (`flight_frame` is its
    /// frame, `floor(flight_s fps)`).
    #[serde(skip_serializing_if = "Option::is_none")]
    flight_s: Option<f64>,
    /// The store's streaming figures of this frame.
    #[serde(skip_serializing_if = "Option::is_none")]
    stream: Option<ooc::StreamRecord>,
    /// When the redraw started and the process's CPU seconds then, for the periods (not
    /// written).
    #[serde(skip)]
    start: Option<(Instant, f64)>,
}

/// A frame longer than twice the median period, and whether loading caused it.
#[derive(Debug, Clone, serde::Serialize)]
struct SlowFrame {
    frame: usize,
    period_ms: f64,
    /// The frame thread waited for I/O (read from disk or waited for the workers).
    waited_for_io: bool,
    /// The streamer's and the page uploads' share of the frame, ms.
    stream_ms: f64,
    pages_ms: f64,
    /// Late and queued data of the frame, MiB.
    late_mib: f64,
    queued_mib: f64,
    /// What made it slow, by the figures: `loading` when it waited for I/O or its streamer
    /// and page uploads took more than half its period, else `drawing` (the engine's frame
    /// without the page uploads; the streamer's update is outside it) or `viewer` (event
    /// handling, the panel, present).
    cause: &'static str,
}

/// The frames' times, their medians after the first (which builds pipelines and, over a
/// store, waits for the coarse levels), the period's 95th percentile and maximum, and the
/// frames longer than twice the median period.
struct FrameTimes {
    frames: Vec<FrameTime>,
    median: Option<FrameTime>,
    period_p95_ms: f64,
    period_max_ms: f64,
    slow: Vec<SlowFrame>,
}

impl FrameTimes {
    fn of(times: &[FrameTime]) -> Self {
        let mut frames = times.to_vec();
        for k in 0..frames.len() {
            // The last frame's period is its own redraw (its CPU figure was taken at its end).
            if let (Some(a), Some(b)) = (frames[k].start, frames.get(k + 1).and_then(|f| f.start)) {
                frames[k].period_ms = (b.0 - a.0).as_secs_f64() * 1e3;
                frames[k].process_cpu_ms = (b.1 - a.1) * 1e3;
            } else {
                frames[k].period_ms = frames[k].viewer_ms;
            }
        }
        let later = &frames[1.min(frames.len())..];
        let m = |f: fn(&FrameTime) -> f64| {
            let mut v: Vec<f64> = later.iter().map(f).collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let median = (!later.is_empty()).then(|| FrameTime {
            frame: later.len(),
            method: "",
            period_ms: m(|t| t.period_ms),
            viewer_ms: m(|t| t.viewer_ms),
            engine_ms: m(|t| t.engine_ms),
            cpu_ms: m(|t| t.cpu_ms),
            selection_ms: m(|t| t.selection_ms),
            stream_ms: m(|t| t.stream_ms),
            pages_ms: m(|t| t.pages_ms),
            panel_ms: m(|t| t.panel_ms),
            present_ms: m(|t| t.present_ms),
            process_cpu_ms: m(|t| t.process_cpu_ms),
            patches: m(|t| t.patches as f64) as usize,
            triangles: m(|t| t.triangles as f64) as u64,
            upload_mib: m(|t| t.upload_mib),
            late_mib: m(|t| t.late_mib),
            queued_mib: m(|t| t.queued_mib),
            ..FrameTime::default()
        });
        let mut periods: Vec<f64> = later.iter().map(|t| t.period_ms).collect();
        let period_max_ms = periods.iter().copied().fold(0.0, f64::max);
        let period_p95_ms = terrain_core::measure::percentile(&mut periods, 0.95);
        let limit = 2.0 * median.as_ref().map_or(f64::INFINITY, |m| m.period_ms);
        let slow = later
            .iter()
            .filter(|t| t.period_ms > limit)
            .map(|t| {
                let loading = t.stream_ms + t.pages_ms;
                let cause = if t.waited_for_io || loading > 0.5 * t.period_ms {
                    "loading"
                } else if t.engine_ms - t.pages_ms > 0.5 * t.period_ms {
                    "drawing"
                } else {
                    "viewer"
                };
                SlowFrame {
                    frame: t.frame,
                    period_ms: t.period_ms,
                    waited_for_io: t.waited_for_io,
                    stream_ms: t.stream_ms,
                    pages_ms: t.pages_ms,
                    late_mib: t.late_mib,
                    queued_mib: t.queued_mib,
                    cause,
                }
            })
            .collect();
        Self { frames, median, period_p95_ms, period_max_ms, slow }
    }
}

/// The sun at start (azimuth and elevation in degrees): the renderer's default, from the
/// north-west 45 degrees up.
const SUN_DEFAULT: (f64, f64) = (315.0, 45.0);

fn check_exaggeration(q: f64) -> anyhow::Result<()> {
    if !(q.is_finite() && q > 0.0) {
        bail!("the vertical exaggeration must be a positive number, got {q}");
    }
    Ok(())
}

/// `hm` with every height times `k`: a DEM in memory exaggerated anew, or a store's overview
/// following its store's exaggeration.
fn rescaled(hm: &Heightmap, k: f32) -> anyhow::Result<Heightmap> {
    let data: Vec<f32> = hm.data().iter().map(|h| h * k).collect();
    Heightmap::new(hm.width(), hm.height(), data, hm.voids().clone(), hm.georef().clone())
        .context("the exaggerated heights")
}

/// Compass yaw and pitch (degrees) of a view direction.
fn yaw_pitch_of(f: DVec3) -> (f64, f64) {
    let yaw = f.x.atan2(f.y).to_degrees().rem_euclid(360.0);
    let pitch = f.z.clamp(-1.0, 1.0).asin().to_degrees();
    (yaw, pitch)
}

/// Threads of this process (Linux), to show the store's workers are gone after closing.
fn threads() -> Option<usize> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    s.lines().find_map(|l| l.strip_prefix("Threads:")).and_then(|v| v.trim().parse().ok())
}

/// A flight pose: position, yaw and pitch (degrees).
type Pose = (DVec3, f64, f64);

/// `--flight` played by the window: every drawn frame shows the next pose, or, `paced`, the
/// pose at the flight time elapsed since its first frame (frames between are skipped).
#[derive(Debug, Default)]
struct FlightPlay {
    /// The flight's poses: position, yaw, pitch; frame `k` at `k / fps` seconds.
    poses: Vec<Pose>,
    /// The first pose not shown yet.
    next: usize,
    fps: f64,
    paced: bool,
    /// When the first pose was shown (paced).
    started: Option<Instant>,
}

impl FlightPlay {
    /// The pose of a frame starting now, its index in the flight and (paced) the flight time
    /// it was taken at, seconds; `None` once the flight has ended. Paced, frame
    /// `floor(t fps)` of the flight time `t`: a fast frame may show the pose of the frame
    /// before it again, a slow one skips poses.
    fn pose(&mut self) -> Option<(usize, Option<f64>, Pose)> {
        let (k, t) = if self.paced {
            let t = self.started.get_or_insert_with(Instant::now).elapsed().as_secs_f64();
            ((t * self.fps).floor() as usize, Some(t))
        } else {
            (self.next, None)
        };
        let pose = *self.poses.get(k)?;
        self.next = k + 1;
        Some((k, t, pose))
    }

    /// Whether every pose has been shown or skipped.
    fn ended(&self) -> bool {
        self.next >= self.poses.len()
            || self.paced
                && self.started.is_some_and(|t| {
                    t.elapsed().as_secs_f64() * self.fps >= self.poses.len() as f64
                })
    }
}

/// Work on a worker thread whose result the next frames pick up.
enum Job {
    /// The tables of a method (the scene's lazily computed ones).
    Prepare(LodMethod, JoinHandle<()>),
    /// A scene with heights exaggerated by the factor, prepared for the method.
    Rescale(f64, JoinHandle<anyhow::Result<MethodScene>>),
}

/// A DEM in memory.
struct MemoryTerrain {
    scene: Arc<MethodScene>,
    /// One renderer per kind (shared by the methods of that kind).
    renderers: HashMap<RendererKind, FrameRenderer>,
    /// The renderer kind of the last frame (its upload bookkeeping carries over).
    last_kind: Option<RendererKind>,
    job: Option<Job>,
    /// The scene's vertical exaggeration.
    exaggeration: f64,
}

/// A baked store, drawn in real time.
struct StoreTerrain {
    dir: PathBuf,
    config: MethodConfig,
    /// The method (its streaming runtime) and its paged renderer, in one loop for the session.
    frames: Option<FrameLoop<'static>>,
    /// Level-4 overview: the ground under the camera and the clip range.
    overview: Heightmap,
    /// The store's georeference (its CRS places `lonlat:` cameras).
    georef: terrain_core::Georef,
    /// A method or quality change being built on a worker while the current one draws (at
    /// start: the first method, while the window shows the sky).
    job: Option<StoreJob>,
    /// The runtime opened at start, until the first method's worker takes it.
    scene: Option<ooc::OocScene>,
    /// The on-demand measurement in flight on its worker ([`measure`]).
    measure: Option<measure::StoreMeasure>,
    /// `--measure-mib`: the measurement's reference budget.
    measure_mib: u64,
}

/// A store's method (its new runtime) and renderer, built on a worker thread with its first
/// frame played (the one that waits for the coarse levels), so the event loop never waits.
type Built = anyhow::Result<(Box<dyn method::Method + Send>, FrameRenderer)>;

/// A store rebuild in flight.
struct StoreJob {
    kind: LodMethod,
    config: MethodConfig,
    /// The pixel target's mapping the new method takes (`None`: its own parameter rules).
    mapped: Option<ErrorPxParams>,
    /// Frames drawn by the old method while the worker built the new one.
    frames_meanwhile: usize,
    handle: JoinHandle<Built>,
}

impl StoreTerrain {
    /// Opens the store (its index and level-4 overview, read before the window opens); no
    /// method yet: [`StoreTerrain::rebuild`] builds the first one on a worker.
    fn open(dir: &Path, config: MethodConfig, measure_mib: u64) -> anyhow::Result<Self> {
        let scene = crate::render::open_store(dir, config.ooc)?;
        let overview = scene
            .overview(4)
            .with_context(|| format!("could not read the store {}", dir.display()))?;
        let georef = scene.store().header().georef.clone();
        Ok(Self {
            dir: dir.to_path_buf(),
            config,
            frames: None,
            overview,
            georef,
            job: None,
            scene: Some(scene),
            measure: None,
            measure_mib,
        })
    }

    /// Starts building `kind` with `config` on a worker thread over the runtime opened at
    /// start (the first method) or a new runtime of the same store (a new method or
    /// parameter); the current method, if any, keeps drawing until [`App::poll_store_job`]
    /// swaps it in. Both runtimes' caches are resident meanwhile.
    fn rebuild(
        &mut self,
        kind: LodMethod,
        config: MethodConfig,
        mapped: Option<ErrorPxParams>,
        camera: Camera,
        ctx: &Arc<GpuContext>,
        render_config: &RenderConfig,
    ) -> anyhow::Result<()> {
        if self.job.is_some() {
            bail!("still preparing; try again in a moment");
        }
        let (dir, ctx, rc, c) =
            (self.dir.clone(), ctx.clone(), render_config.clone(), config.clone());
        let scene = self.scene.take();
        let handle = std::thread::Builder::new().name("view-store".into()).spawn(move || {
            let scene = match scene {
                Some(s) => s,
                None => ooc::OocScene::open(&dir, c.ooc)
                    .with_context(|| format!("could not open the store {}", dir.display()))?,
            };
            let mut method = method::store_method(kind, scene, &c, OocWait::FirstFrame, None)?;
            let mut renderer = method.renderer(&ctx, &rc)?;
            renderer.set_sun_direction(rc.sun_direction)?;
            // The frame that waits for the coarse levels, played here.
            let first = method.frame(&camera);
            renderer.apply(&first)?;
            Ok((method, renderer))
        })?;
        self.job = Some(StoreJob { kind, config, mapped, frames_meanwhile: 0, handle });
        Ok(())
    }
}

enum Terrain {
    Memory(MemoryTerrain),
    Store(Box<StoreTerrain>),
}

impl Terrain {
    fn ground(&self) -> &Heightmap {
        match self {
            Terrain::Memory(m) => &m.scene.hm,
            Terrain::Store(s) => &s.overview,
        }
    }

    /// The ground cameras are placed on, with the georeference that converts lon/lat.
    fn camera_ground(&self) -> Ground<'_> {
        match self {
            Terrain::Memory(m) => Ground::of(&m.scene.hm),
            Terrain::Store(s) => Ground { heights: &s.overview, georef: &s.georef },
        }
    }

    fn config(&self) -> &MethodConfig {
        match self {
            Terrain::Memory(m) => &m.scene.config,
            Terrain::Store(s) => &s.config,
        }
    }
}

/// What the panel shows and the user changes (see [`panel`]).
#[derive(Debug, Clone)]
pub(crate) struct UiState {
    pub show: bool,
    pub wireframe: bool,
    pub colour_levels: bool,
    pub freeze: bool,
    pub exaggeration: f64,
    pub measured_p99: Option<String>,
    pub message: Option<String>,
}

impl Default for UiState {
    fn default() -> Self {
        Self {
            show: true,
            wireframe: false,
            colour_levels: false,
            freeze: false,
            exaggeration: 1.0,
            measured_p99: None,
            message: None,
        }
    }
}

/// Live figures.
#[derive(Debug, Clone, Default)]
pub(crate) struct Stats {
    /// Seconds between the last frames (exponential mean).
    pub frame_s: f64,
    /// The last frame's CPU ms (selection, conversion, encoding).
    pub cpu_ms: f64,
    /// The last frame's engine wall ms (selection to GPU done) and whole viewer frame ms.
    pub engine_ms: f64,
    pub viewer_ms: f64,
    /// GPU time as the renderer reads it ("n/a ..." where not available).
    pub gpu: String,
    pub triangles: u64,
    pub patches: usize,
    pub stream: Option<ooc::StreamRecord>,
}

/// What the user (panel, keys, script) asks for; every source goes through [`App::apply`].
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Action {
    Method(LodMethod),
    Quality(f64),
    Set(Toggle, bool),
    Exaggeration(f64),
    Sun(f64, f64),
    Measure,
    Record,
    Orbit,
    Quit,
}

struct App {
    /// Shared with the worker that builds a store's method.
    ctx: Arc<GpuContext>,
    render_config: RenderConfig,
    size: (u32, u32),
    fov: f64,
    /// The ground's block boxes for the near and far planes (computed once per terrain, not
    /// every frame).
    clip: ClipBoxes,
    terrain: Terrain,
    kind: LodMethod,
    /// The view the pixel target refers to (the window's height and field of view).
    error_view: ErrorView,
    /// The pixel target's mapping onto the current method's own parameter; `None` while the
    /// method's own parameter (`--method-param`) rules, until the slider or a script moves.
    mapped: Option<ErrorPxParams>,
    camera: ViewCamera,
    window: Option<Arc<Window>>,
    presenter: Option<present::Presenter>,
    egui_state: Option<egui_winit::State>,
    egui_ctx: egui::Context,
    held: HashSet<Key>,
    dragging: bool,
    cursor: Option<(f64, f64)>,
    /// Mouse drag and wheel steps since the last frame.
    drag: (f64, f64),
    wheel: f64,
    ui: UiState,
    /// The camera the selection was frozen at.
    frozen: Option<Camera>,
    sun: (f64, f64),
    script: VecDeque<Command>,
    scripted: bool,
    script_wait: u32,
    /// `--flight` being played.
    flight: FlightPlay,
    /// The script waits until the flight has played to its end (`wait-flight`).
    wait_flight: bool,
    recorder: Option<record::Recorder>,
    record_to: PathBuf,
    stats: Stats,
    frame_index: usize,
    /// Every frame's times, for the closing summary and `--stats-json`.
    frame_times: Vec<FrameTime>,
    /// The upload bookkeeping carried from frame to frame over a DEM in memory (whose frame
    /// loop is built per frame).
    uploads: method::Uploads,
    last_frame: Option<Instant>,
    measure_next: bool,
    /// The sky shown while a store's first method is built (made on first use).
    sky: Option<wgpu::Texture>,
    error: Option<anyhow::Error>,
    quit: bool,
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.window.is_some() {
            return;
        }
        let attrs = Window::default_attributes()
            .with_title("terrain view")
            .with_inner_size(winit::dpi::PhysicalSize::new(self.size.0, self.size.1))
            .with_resizable(false);
        let made = event_loop
            .create_window(attrs)
            .context("could not create the window")
            .map(Arc::new)
            .and_then(|w| Ok((present::Presenter::new(&self.ctx, w.clone())?, w)));
        match made {
            Ok((presenter, window)) => {
                println!("window: {:?}, surface {:?}", window.inner_size(), presenter.format());
                if !presenter.readable() {
                    eprintln!("warning: this surface cannot be read back: no screenshots");
                }
                self.egui_state = Some(egui_winit::State::new(
                    self.egui_ctx.clone(),
                    egui::ViewportId::ROOT,
                    &*window,
                    Some(window.scale_factor() as f32),
                    None,
                    None,
                ));
                self.presenter = Some(presenter);
                window.request_redraw();
                self.window = Some(window);
            }
            Err(e) => self.fail(event_loop, e),
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        let Some(window) = self.window.clone() else { return };
        let consumed = match self.egui_state.as_mut() {
            Some(s) if self.ui.show => s.on_window_event(&window, &event).consumed,
            _ => false,
        };
        match event {
            WindowEvent::CloseRequested => self.quit = true,
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.redraw() {
                    self.fail(event_loop, e);
                    return;
                }
                if self.quit {
                    event_loop.exit();
                }
            }
            WindowEvent::KeyboardInput { event, .. } if !consumed => {
                let down = event.state == ElementState::Pressed;
                let PhysicalKey::Code(code) = event.physical_key else { return };
                if let Some(key) = key_of(code) {
                    if down {
                        self.held.insert(key);
                    } else {
                        self.held.remove(&key);
                    }
                } else if down && !event.repeat {
                    let action = match code {
                        KeyCode::KeyO => Some(Action::Orbit),
                        KeyCode::KeyR => Some(Action::Record),
                        KeyCode::KeyF => Some(Action::Set(Toggle::Freeze, !self.ui.freeze)),
                        KeyCode::KeyP => Some(Action::Set(Toggle::Panel, !self.ui.show)),
                        KeyCode::KeyM => Some(Action::Measure),
                        KeyCode::KeyL => {
                            Some(Action::Set(Toggle::ColourLevels, !self.ui.colour_levels))
                        }
                        KeyCode::Escape => Some(Action::Quit),
                        _ => None,
                    };
                    if let Some(a) = action {
                        self.apply(a);
                    }
                }
            }
            WindowEvent::MouseInput { state, button, .. } => {
                if matches!(button, MouseButton::Left | MouseButton::Right) {
                    self.dragging = state == ElementState::Pressed && !consumed;
                }
            }
            WindowEvent::CursorMoved { position, .. } => {
                let p = (position.x, position.y);
                if let (true, Some(c)) = (self.dragging, self.cursor) {
                    self.drag.0 += p.0 - c.0;
                    self.drag.1 += p.1 - c.1;
                }
                self.cursor = Some(p);
            }
            WindowEvent::MouseWheel { delta, .. } if !consumed => {
                self.wheel += match delta {
                    MouseScrollDelta::LineDelta(_, y) => f64::from(y),
                    MouseScrollDelta::PixelDelta(p) => p.y / 40.0,
                };
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        if self.quit {
            event_loop.exit();
        } else if let Some(w) = &self.window {
            w.request_redraw();
        }
    }
}

fn key_of(code: KeyCode) -> Option<Key> {
    Some(match code {
        KeyCode::KeyW => Key::W,
        KeyCode::KeyA => Key::A,
        KeyCode::KeyS => Key::S,
        KeyCode::KeyD => Key::D,
        KeyCode::KeyQ => Key::Q,
        KeyCode::KeyE => Key::E,
        KeyCode::ShiftLeft | KeyCode::ShiftRight => Key::Shift,
        _ => return None,
    })
}

impl App {
    fn fail(&mut self, event_loop: &ActiveEventLoop, e: anyhow::Error) {
        self.error.get_or_insert(e);
        self.quit = true;
        event_loop.exit();
    }

    /// The quality slider's value: the error target in pixels (`None`: the method's own
    /// parameter was given with `--method-param`).
    fn error_px(&self) -> Option<f64> {
        self.mapped.map(|p| p.error_px)
    }

    /// The current method's own parameter as set: its name and value (PVPS under a pixel
    /// target: Eq. 12's C3, which the mapping sets; otherwise the swept parameter).
    fn own_parameter(&self) -> (&'static str, f64) {
        match self.mapped {
            Some(p) if p.method == self.kind => (p.parameter, p.value),
            _ => (
                registry::sweep_values(self.kind, self.terrain.config().leaf_cells).0,
                parameter(self.terrain.config(), self.kind),
            ),
        }
    }

    /// Sets the quality slider's value, an error target in pixels: mapped onto the current
    /// method's own parameter through [`registry::params_for_error_px`] for the window's view
    /// (the one mapping of `--error-px` and `--quality`).
    fn set_quality(&mut self, error_px: f64) -> anyhow::Result<()> {
        if !(error_px.is_finite() && error_px > 0.0) {
            bail!("the error target must be a positive number of pixels, got {error_px}");
        }
        let mut params = registry::params_for_error_px(self.kind, error_px, self.error_view);
        match &mut self.terrain {
            Terrain::Memory(m) => {
                let Some(scene) = Arc::get_mut(&mut m.scene) else {
                    bail!("the quality cannot change while a method is being prepared");
                };
                params.apply_recorded(&mut scene.config);
            }
            Terrain::Store(s) => {
                let mut config = s.config.clone();
                params.apply_recorded(&mut config);
                let camera =
                    self.camera.camera(self.fov, self.size, self.clip.range(self.camera.position));
                s.rebuild(self.kind, config, Some(params), camera, &self.ctx, &self.render_config)?;
                self.ui.message = Some(format!("preparing {} at {error_px} px", self.kind.name()));
                return Ok(());
            }
        }
        self.mapped = Some(params);
        println!("view: quality: {params}");
        Ok(())
    }

    /// Whether a worker thread is preparing something.
    fn busy(&self) -> bool {
        match &self.terrain {
            Terrain::Memory(m) => m.job.is_some(),
            Terrain::Store(s) => s.job.is_some(),
        }
    }

    fn apply(&mut self, action: Action) {
        let result = self.try_apply(action);
        if let Err(e) = result {
            eprintln!("warning: {e:#}");
            self.ui.message = Some(format!("{e:#}"));
        }
    }

    fn try_apply(&mut self, action: Action) -> anyhow::Result<()> {
        match action {
            Action::Method(kind) => {
                if kind == self.kind {
                    return Ok(());
                }
                match &mut self.terrain {
                    Terrain::Memory(m) => {
                        if registry::needs_store(kind) {
                            bail!("{}", registry::OOC_NEEDS_STORE);
                        }
                        if m.job.is_some() {
                            bail!("still preparing; try again in a moment");
                        }
                        let scene = m.scene.clone();
                        let handle = std::thread::Builder::new()
                            .name("view-prepare".into())
                            .spawn(move || scene.prepare(&[kind]))?;
                        m.job = Some(Job::Prepare(kind, handle));
                        self.ui.message = Some(format!("preparing {}", kind.name()));
                    }
                    Terrain::Store(s) => {
                        // The pixel target carries over: mapped onto the new method's own
                        // parameter before its runtime is built (on a worker).
                        let mut config = s.config.clone();
                        let mapped = self.mapped.map(|p| {
                            let mut q =
                                registry::params_for_error_px(kind, p.error_px, self.error_view);
                            q.apply_recorded(&mut config);
                            q
                        });
                        let camera = self.camera.camera(
                            self.fov,
                            self.size,
                            self.clip.range(self.camera.position),
                        );
                        s.rebuild(kind, config, mapped, camera, &self.ctx, &self.render_config)?;
                        self.ui.message = Some(format!("preparing {}", kind.name()));
                    }
                }
            }
            Action::Quality(v) => self.set_quality(v)?,
            Action::Set(t, on) => match t {
                Toggle::Wireframe => self.ui.wireframe = on,
                Toggle::Panel => self.ui.show = on,
                Toggle::ColourLevels => {
                    self.ui.colour_levels = on;
                    println!("view: LOD colours {}", if on { "on" } else { "off" });
                }
                Toggle::Freeze => {
                    self.ui.freeze = on;
                    self.frozen = None;
                }
            },
            Action::Exaggeration(v) => {
                check_exaggeration(v)?;
                let m = match &mut self.terrain {
                    Terrain::Memory(m) => m,
                    Terrain::Store(s) => {
                        // A new runtime over the store read exaggerated `v` times (heights,
                        // boxes and selection errors), built on a worker as a method change.
                        let mut config = s.config.clone();
                        config.ooc.vertical_scale = v;
                        let camera = self.camera.camera(
                            self.fov,
                            self.size,
                            self.clip.range(self.camera.position),
                        );
                        s.rebuild(self.kind, config, None, camera, &self.ctx, &self.render_config)?;
                        self.ui.message = Some(format!("exaggerating x{v}"));
                        return Ok(());
                    }
                };
                if m.job.is_some() {
                    bail!("still preparing; try again in a moment");
                }
                let (scene, kind, old) = (m.scene.clone(), self.kind, m.exaggeration);
                let handle =
                    std::thread::Builder::new().name("view-rescale".into()).spawn(move || {
                        let scaled = rescaled(&scene.hm, (v / old) as f32)?;
                        let s = MethodScene::new(scaled, scene.config.clone());
                        s.prepare(&[kind]);
                        Ok(s)
                    })?;
                m.job = Some(Job::Rescale(v, handle));
                self.ui.message = Some(format!("exaggerating x{v}"));
            }
            Action::Sun(az, el) => {
                self.sun = (az, el);
                let dir = sun_direction(az, el);
                let renderers: Vec<&mut FrameRenderer> = match &mut self.terrain {
                    Terrain::Memory(m) => m.renderers.values_mut().collect(),
                    Terrain::Store(s) => {
                        s.frames.as_mut().and_then(|f| f.renderer()).into_iter().collect()
                    }
                };
                let mut all = true;
                for r in renderers {
                    all &= r.set_sun_direction(dir)?;
                }
                self.render_config.sun_direction = dir;
                if !all {
                    self.ui.message =
                        Some("the geomorph renderer bakes its sun: not changed there".into());
                }
            }
            Action::Measure => self.measure_next = true,
            Action::Record => match self.recorder.take() {
                None => {
                    self.recorder = Some(record::Recorder::default());
                    println!("view: recording a flight");
                }
                Some(r) => {
                    if let Some(dir) = self.record_to.parent().filter(|d| !d.as_os_str().is_empty())
                    {
                        std::fs::create_dir_all(dir)
                            .with_context(|| format!("could not create {}", dir.display()))?;
                    }
                    r.save(&self.record_to, 30.0, self.fov)?;
                    println!(
                        "view: wrote the flight {} ({} keyframes)",
                        self.record_to.display(),
                        r.len()
                    );
                }
            },
            Action::Orbit => {
                let extent = self.terrain.ground().extent_m().max_element();
                let ground = self.terrain.ground();
                self.camera.toggle_mode(ground, extent / 2.0);
            }
            Action::Quit => self.quit = true,
        }
        Ok(())
    }

    /// Runs script commands until one waits. Returns the screenshot path to take this frame.
    fn run_script(&mut self) -> anyhow::Result<Option<PathBuf>> {
        if !self.scripted {
            return Ok(None);
        }
        let measuring = matches!(&self.terrain, Terrain::Store(s) if s.measure.is_some());
        if self.busy() || measuring {
            return Ok(None); // a `method`, `exaggeration` or `measure` waits until done
        }
        if self.script_wait > 0 {
            self.script_wait -= 1;
            return Ok(None);
        }
        if self.wait_flight {
            if !self.flight.ended() {
                return Ok(None);
            }
            self.wait_flight = false;
        }
        while let Some(cmd) = self.script.pop_front() {
            match cmd {
                Command::Key(k, down) => {
                    if down {
                        self.held.insert(k);
                    } else {
                        self.held.remove(&k);
                    }
                }
                Command::Mouse(dx, dy) => self.camera.look(dx, dy, self.terrain.ground()),
                Command::Wheel(n) => self.camera.wheel(n, self.terrain.ground()),
                Command::Orbit => self.apply(Action::Orbit),
                Command::Method(k) => {
                    self.try_apply(Action::Method(k))?;
                    return Ok(None);
                }
                Command::Quality(v) => self.try_apply(Action::Quality(v))?,
                Command::Set(t, on) => self.try_apply(Action::Set(t, on))?,
                Command::Exaggeration(v) => {
                    self.try_apply(Action::Exaggeration(v))?;
                    return Ok(None);
                }
                Command::Camera(s) => {
                    let spec = camera_spec::parse(&s, None)?;
                    let view = ViewConfig {
                        size_px: glam::dvec2(f64::from(self.size.0), f64::from(self.size.1)),
                        fov_y_deg: self.fov,
                    };
                    let c = camera_spec::place(Some(&spec), &self.terrain.camera_ground(), &view)?
                        .camera;
                    let (yaw, pitch) = yaw_pitch_of(c.forward());
                    self.camera.position = c.position;
                    self.camera.yaw = yaw;
                    self.camera.pitch = pitch;
                }
                Command::Record => self.try_apply(Action::Record)?,
                Command::Measure => {
                    self.apply(Action::Measure);
                    return Ok(None);
                }
                Command::Screenshot(p) => return Ok(Some(p)),
                Command::WaitFlight => {
                    self.wait_flight = true;
                    return Ok(None);
                }
                Command::Wait(n) => {
                    self.script_wait = n.saturating_sub(1);
                    return Ok(None);
                }
                Command::Quit => {
                    self.quit = true;
                    return Ok(None);
                }
            }
        }
        Ok(None)
    }

    /// Picks up a finished store rebuild: the new method and renderer replace the old ones (a
    /// failed one is a message, and the old method keeps drawing).
    fn poll_store_job(&mut self) -> anyhow::Result<()> {
        let Terrain::Store(s) = &mut self.terrain else { return Ok(()) };
        let Some(job) = s.job.as_mut() else { return Ok(()) };
        if !job.handle.is_finished() {
            job.frames_meanwhile += 1;
            return Ok(());
        }
        let job = s.job.take().context("the store job")?;
        let built = job
            .handle
            .join()
            .map_err(|_| anyhow::anyhow!("building {} panicked", job.kind.name()))?;
        match built {
            Ok((method, renderer)) => {
                // The old runtime goes (its workers joined), the new one draws.
                s.frames = None;
                s.frames = Some(FrameLoop::new(method).rendered_by(renderer));
                let (old, new) = (s.config.ooc.vertical_scale, job.config.ooc.vertical_scale);
                if new != old {
                    // The ground the camera stays above follows the exaggeration.
                    s.overview = rescaled(&s.overview, (new / old) as f32)?;
                    self.clip = ClipBoxes::new(&s.overview);
                    self.ui.exaggeration = new;
                    println!("view: exaggeration x{new}");
                }
                s.config = job.config;
                self.kind = job.kind;
                if job.mapped.is_some() {
                    self.mapped = job.mapped;
                }
                if let Some(p) = &job.mapped {
                    println!("view: quality: {p}");
                }
                println!(
                    "view: store method {} ready; {} frames shown meanwhile",
                    job.kind.name(),
                    job.frames_meanwhile
                );
                self.ui.message = Some(format!("{} ready", job.kind.name()));
            }
            Err(e) => {
                eprintln!("warning: {e:#}");
                self.ui.message = Some(format!("{e:#}"));
            }
        }
        Ok(())
    }

    /// Picks up a finished store measurement: its figures (or why there are none) in the
    /// panel and on stdout.
    fn poll_store_measure(&mut self) {
        let Terrain::Store(s) = &mut self.terrain else { return };
        let Some(done) = measure::StoreMeasure::poll(&mut s.measure) else { return };
        let text = match done {
            Ok(outcome) => outcome.text(),
            Err(e) => format!("n/a: {e:#}"),
        };
        println!("view: measured {text}");
        self.ui.measured_p99 = Some(text);
    }

    /// Picks up a finished worker job.
    fn poll_job(&mut self) -> anyhow::Result<()> {
        self.poll_store_job()?;
        self.poll_store_measure();
        let Terrain::Memory(m) = &mut self.terrain else { return Ok(()) };
        let finished = match &m.job {
            Some(Job::Prepare(_, h)) => h.is_finished(),
            Some(Job::Rescale(_, h)) => h.is_finished(),
            None => false,
        };
        if !finished {
            return Ok(());
        }
        match m.job.take() {
            Some(Job::Prepare(kind, h)) => {
                h.join().map_err(|_| anyhow::anyhow!("preparing {} panicked", kind.name()))?;
                self.kind = kind;
                // The pixel target carries over to the new method (its own parameter mapped).
                if let Some(px) = self.error_px() {
                    self.set_quality(px)?;
                }
                self.ui.message = Some(format!("{} ready", kind.name()));
                println!("view: method {}", kind.name());
            }
            Some(Job::Rescale(v, h)) => {
                let scene = h.join().map_err(|_| anyhow::anyhow!("rescaling panicked"))??;
                m.scene = Arc::new(scene);
                m.exaggeration = v;
                self.ui.exaggeration = v;
                // The renderers hold the old heights.
                m.renderers.clear();
                self.uploads = method::Uploads::default();
                self.clip = ClipBoxes::new(&m.scene.hm);
                self.ui.message = Some(format!("exaggeration x{v}"));
            }
            None => {}
        }
        Ok(())
    }

    /// One frame: script, input, the method's frame through the frame loop, the panel, present.
    fn redraw(&mut self) -> anyhow::Result<()> {
        let t0 = Instant::now();
        let cpu0 = terrain_app::bench::process_cpu_s();
        let dt = match (self.scripted, self.last_frame) {
            (true, _) | (false, None) => 1.0 / 60.0,
            (false, Some(t)) => t.elapsed().as_secs_f64().min(0.1),
        };
        if let Some(t) = self.last_frame {
            let s = t.elapsed().as_secs_f64();
            self.stats.frame_s =
                if self.stats.frame_s == 0.0 { s } else { 0.9 * self.stats.frame_s + 0.1 * s };
        }
        self.last_frame = Some(t0);
        self.poll_job()?;
        let shot = self.run_script()?;
        // Input: flight playback, then keys, drag and wheel.
        let ground: &Heightmap = self.terrain.ground();
        // The flight waits for the store's first method (built on a worker at start).
        let loading = matches!(&self.terrain, Terrain::Store(s) if s.frames.is_none());
        let (mut flight_frame, mut flight_s) = (None, None);
        if !loading && let Some((k, t, (p, yaw, pitch))) = self.flight.pose() {
            self.camera.position = p;
            self.camera.yaw = yaw;
            self.camera.pitch = pitch;
            (flight_frame, flight_s) = (Some(k), t);
        }
        let axis = |a: Key, b: Key| {
            f64::from(u8::from(self.held.contains(&a)))
                - f64::from(u8::from(self.held.contains(&b)))
        };
        let boost = if self.held.contains(&Key::Shift) { 4.0 } else { 1.0 };
        let motion = Motion {
            forward: axis(Key::W, Key::S) * boost,
            right: axis(Key::D, Key::A) * boost,
            up: axis(Key::E, Key::Q) * boost,
        };
        self.camera.step(motion, dt, ground);
        let (dx, dy) = std::mem::take(&mut self.drag);
        if dx != 0.0 || dy != 0.0 {
            self.camera.look(dx, dy, ground);
        }
        let wheel = std::mem::take(&mut self.wheel);
        if wheel != 0.0 {
            self.camera.wheel(wheel, ground);
        }
        if let Some(r) = &mut self.recorder {
            r.tick(dt, self.camera.position, self.camera.yaw, self.camera.pitch);
        }
        let eye = self.camera.camera(self.fov, self.size, self.clip.range(self.camera.position));
        if self.ui.freeze && self.frozen.is_none() {
            self.frozen = Some(eye);
        }
        let select = self.frozen.filter(|_| self.ui.freeze).unwrap_or(eye);
        // The engine's frame.
        let options = RenderOptions {
            wireframe: self.ui.wireframe,
            lod_colours: self.ui.colour_levels,
            ..Default::default()
        };
        let measure = std::mem::take(&mut self.measure_next);
        let index = self.frame_index;
        let (frame, measured, drawn_kind) = match &mut self.terrain {
            Terrain::Memory(m) => {
                let scene: &MethodScene = &m.scene;
                let method = method::build(
                    self.kind,
                    scene,
                    &MethodOptions { morph: true, ..MethodOptions::default() },
                )?;
                let kind = method.renderer_kind();
                let renderer = match m.renderers.entry(kind) {
                    std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
                    std::collections::hash_map::Entry::Vacant(e) => {
                        let mut r = method.renderer(&self.ctx, &self.render_config)?;
                        r.set_sun_direction(self.render_config.sun_direction)?;
                        e.insert(r)
                    }
                };
                // A new renderer starts its upload bookkeeping afresh.
                let uploads =
                    if m.last_kind == Some(kind) { self.uploads } else { Default::default() };
                m.last_kind = Some(kind);
                let mut frames = FrameLoop::new(method)
                    .rendered(Some(renderer))
                    .with_options(options)
                    .with_uploads(uploads);
                if measure {
                    frames = frames.measured(&scene.hm, &scene.qt, MeasureConfig::default());
                }
                let f = frames.frame_drawn_from(index, &select, &eye, None)?;
                self.uploads = frames.uploads();
                (Some(f), measure, Some(kind))
            }
            Terrain::Store(s) if s.frames.is_none() => {
                // The first method is still being built on a worker: the sky is shown.
                if measure {
                    self.measure_next = true;
                }
                (None, false, None)
            }
            Terrain::Store(s) => {
                let frames = s.frames.as_mut().context("the store's method was lost")?;
                frames.set_options(options);
                let f = frames.frame_drawn_from(index, &select, &eye, None);
                if measure && s.measure.is_none() {
                    // Measured on a worker against the store's own full-resolution heights.
                    s.measure = Some(self::measure::StoreMeasure::start(
                        s.dir.clone(),
                        self.kind,
                        s.config.clone(),
                        select,
                        s.measure_mib,
                    )?);
                    self.ui.measured_p99 =
                        Some("measuring against the store's full-resolution heights...".into());
                }
                (Some(f?), false, None)
            }
        };
        if let Some(f) = &frame {
            self.record_stats(f, measured);
        }
        // The panel, then present.
        let t_panel = Instant::now();
        let overlay = if self.ui.show { Some(self.panel()?) } else { None };
        let panel_ms = t_panel.elapsed().as_secs_f64() * 1e3;
        let t_present = Instant::now();
        let image = match &mut self.terrain {
            Terrain::Memory(m) => {
                // The renderer this frame drew with.
                let r = drawn_kind.and_then(|k| m.renderers.get(&k)).context("no renderer")?;
                r.color_texture()
            }
            Terrain::Store(s) => match s.frames.as_mut().and_then(|f| f.renderer()) {
                Some(r) => r.color_texture(),
                None => self.sky.get_or_insert_with(|| sky_texture(&self.ctx, &self.render_config)),
            },
        };
        let presenter = self.presenter.as_mut().context("no window")?;
        let shot_image = presenter.present(
            &self.ctx,
            image,
            overlay.as_ref().map(|o| present::Overlay {
                primitives: &o.0,
                textures: &o.1.0,
                pixels_per_point: o.2,
            }),
            shot.is_some(),
        )?;
        let present_ms = t_present.elapsed().as_secs_f64() * 1e3;
        if let (Some(path), Some(img)) = (&shot, shot_image) {
            let raw: Vec<u8> = img.pixels.iter().flatten().copied().collect();
            image::save_buffer(path, &raw, img.width, img.height, image::ColorType::Rgba8)
                .with_context(|| format!("could not write {}", path.display()))?;
            println!(
                "view: screenshot {} camera {} method {} error-px {} param {}={} frame {}",
                path.display(),
                self.camera.spec(),
                self.kind.name(),
                self.error_px().map_or("own".into(), |px| px.to_string()),
                self.own_parameter().0,
                self.own_parameter().1,
                index
            );
        }
        self.stats.viewer_ms = t0.elapsed().as_secs_f64() * 1e3;
        let Some(frame) = frame else {
            // No engine frame (the store's first method is being built): not logged.
            return Ok(());
        };
        let r = &frame.record;
        let stream = r.stream.clone();
        self.frame_times.push(FrameTime {
            frame: index,
            method: self.kind.name(),
            period_ms: 0.0,
            viewer_ms: self.stats.viewer_ms,
            engine_ms: r.frame_ms,
            cpu_ms: r.cpu_ms,
            selection_ms: r.selection_ms,
            stream_ms: stream.as_ref().map_or(0.0, |s| s.stream_ms),
            pages_ms: frame.drawn.as_ref().map_or(0.0, |d| d.pages_ms),
            panel_ms,
            present_ms,
            process_cpu_ms: (terrain_app::bench::process_cpu_s() - cpu0) * 1e3,
            patches: self.stats.patches,
            triangles: r.triangles,
            upload_mib: r.upload_bytes.unwrap_or(0) as f64 / terrain_app::MIB,
            late_mib: stream.as_ref().map_or(0.0, |s| s.late_mib),
            queued_mib: stream.as_ref().map_or(0.0, |s| s.queued_mib),
            waited_for_io: stream.as_ref().is_some_and(|s| s.waited_for_io),
            flight_frame,
            flight_s,
            stream,
            start: Some((t0, cpu0)),
        });
        self.frame_index += 1;
        Ok(())
    }

    fn record_stats(&mut self, f: &LoopFrame, measured: bool) {
        let r = &f.record;
        self.stats.cpu_ms = r.cpu_ms;
        self.stats.engine_ms = r.frame_ms;
        self.stats.triangles = r.triangles;
        self.stats.patches = r.patches;
        self.stats.stream = r.stream.clone();
        self.stats.gpu = f.drawn.as_ref().map_or_else(|| "n/a".into(), |d| d.gpu_text.clone());
        if !self.ctx.features.compute_timestamps_trustworthy && self.ctx.features.timestamp_query {
            self.stats.gpu.push_str(" [lavapipe: timestamps untrustworthy]");
        }
        if measured {
            self.ui.measured_p99 = Some(format!(
                "p99 {:.3} px, max {:.3} px ({} samples)",
                r.errors.p99_px, r.errors.max_px, r.errors.samples
            ));
            println!("view: measured {}", self.ui.measured_p99.as_deref().unwrap_or(""));
        }
    }

    /// Runs the panel; returns egui's triangles, texture changes and scale.
    fn panel(&mut self) -> anyhow::Result<(Vec<egui::ClippedPrimitive>, present::Textures, f32)> {
        let window = self.window.clone().context("no window")?;
        let view = panel::PanelView {
            kind: self.kind,
            store: matches!(self.terrain, Terrain::Store(_)),
            error_px: self.error_px(),
            own: self.own_parameter(),
            pixels: registry::parameter_is_pixels(self.kind),
            sun: self.sun,
            busy: self.busy(),
            recording: self.recorder.as_ref().map(record::Recorder::len),
            adapter: self.ctx.describe(),
            orbit: self.camera.mode == camera::Mode::Orbit,
            speed: self.camera.speed,
        };
        let state = self.egui_state.as_mut().context("no panel state")?;
        let raw = state.take_egui_input(&window);
        let mut actions = Vec::new();
        let (ui, stats) = (&self.ui, &self.stats);
        let out = self.egui_ctx.run_ui(raw, |root| {
            panel::ui(root.ctx(), &view, ui, stats, &mut actions);
        });
        state.handle_platform_output(&window, out.platform_output);
        let prims = self.egui_ctx.tessellate(out.shapes, out.pixels_per_point);
        for a in actions {
            self.apply(a);
        }
        Ok((prims, present::Textures(out.textures_delta), out.pixels_per_point))
    }
}

/// The quality slider's range, pixels of screen-space error: a quarter of the finest preset
/// to four times the coarsest.
pub(crate) const ERROR_PX_RANGE: (f64, f64) = (0.25, 16.0);

/// The slider's value when the method's own parameter rules (`--method-param`): the default
/// preset's target.
pub(crate) const ERROR_PX_DEFAULT: f64 = 2.0;

/// A texture of the renderer's size in its background colour (the renderers' colour format):
/// what the window shows before a store's first frame is ready.
fn sky_texture(ctx: &GpuContext, config: &RenderConfig) -> wgpu::Texture {
    let size =
        wgpu::Extent3d { width: config.width, height: config.height, depth_or_array_layers: 1 };
    let texture = ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("view sky"),
        size,
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: terrain_gpu::target::COLOR_FORMAT,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    let pixels = (config.width * config.height) as usize;
    let data: Vec<u8> = config.background.iter().copied().cycle().take(4 * pixels).collect();
    ctx.queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture: &texture,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        &data,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(4 * config.width),
            rows_per_image: Some(config.height),
        },
        size,
    );
    texture
}

/// The direction towards the sun from its compass azimuth and elevation, degrees.
fn sun_direction(az: f64, el: f64) -> [f64; 3] {
    let (a, e) = (az.to_radians(), el.to_radians());
    [a.sin() * e.cos(), a.cos() * e.cos(), e.sin()]
}

#[cfg(test)]
mod tests {
    use super::*;
    use terrain_app::method::registry::Quality;

    #[test]
    fn the_default_sun_is_the_renderers() {
        let d = DVec3::from(sun_direction(SUN_DEFAULT.0, SUN_DEFAULT.1));
        let want = DVec3::from(RenderConfig::default().sun_direction).normalize();
        assert!((d - want).length() < 1e-12, "{d} vs {want}");
    }

    #[test]
    fn yaw_pitch_round_trip_through_the_camera() {
        for (yaw, pitch) in [(0.0, -30.0), (90.0, 0.0), (225.5, 12.0), (359.0, -89.0)] {
            let c = Camera::from_yaw_pitch(DVec3::ZERO, yaw, pitch);
            let (y, p) = yaw_pitch_of(c.forward());
            assert!((y - yaw).abs() < 1e-9 && (p - pitch).abs() < 1e-9, "{yaw},{pitch}: {y},{p}");
        }
    }

    /// The slider covers every preset, and across its range the mapping gives every method
    /// a finite positive parameter that moves with the target (a slider that changes nothing
    /// for some method would fail here).
    #[test]
    fn the_pixel_slider_reaches_every_methods_parameter() {
        let (lo, hi) = ERROR_PX_RANGE;
        for q in [Quality::Fast, Quality::Balanced, Quality::Best] {
            assert!(lo <= q.error_px() && q.error_px() <= hi, "{q:?}");
        }
        assert_eq!(ERROR_PX_DEFAULT, Quality::DEFAULT.error_px());
        let view = ErrorView { height_px: 720.0, fov_y_deg: 60.0 };
        for &m in LodMethod::ALL.iter() {
            let at = |px: f64| registry::params_for_error_px(m, px, view);
            let (a, b) = (at(1.0), at(8.0));
            assert!(a.value.is_finite() && a.value > 0.0, "{m:?}: {a}");
            assert!(b.value.is_finite() && b.value > 0.0, "{m:?}: {b}");
            assert_ne!(a.value, b.value, "{m:?}: 1 px and 8 px give the same {}", a.parameter);
            let mut config = MethodConfig::default();
            b.apply(&mut config);
            if !matches!(a.parameter, "C3") {
                let set = parameter(&config, m);
                // Uniform's factor is stored as f32.
                assert!((set - b.value).abs() <= 1e-6 * b.value, "{m:?}: {set} set for {b}");
            }
        }
    }
}
