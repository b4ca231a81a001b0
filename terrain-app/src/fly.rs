//! `terrain fly`: flies a camera flight over a DEM (or the embedded terrain) with one LOD method,
//! writing numbered PNG frames and per-frame statistics (stage timings, triangles, exact errors)
//! as CSV and JSON, with a progress bar on stderr. Over a baked store (a folder whose index
//! starts with the store's magic) the method draws from the store as `terrain render <store>
//! --flight` does (the same store method, the same frame loop): frames are not measured (no
//! full DEM in memory), and each record carries the stream's statistics, summarised at the end.

use std::io::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;
use glam::dvec2;
use terrain_app::bench::{BenchProgress, FrameRecord, frame_indices, print_progress};
use terrain_app::method::registry::ErrorView;
use terrain_app::method::{self, FrameLoop, MethodOptions, OocWait};
use terrain_app::methods::{LodMethod, MethodConfig, MethodScene};
use terrain_app::ooc::{self, OocConfig, StreamRecord, StreamSummary};
use terrain_core::flight::{FlightConfig, FlightSpec};
use terrain_core::geometry::Camera;
use terrain_core::measure::MeasureConfig;
use terrain_core::{Heightmap, synth};
use terrain_gpu::{BackendChoice, DeviceConfig, GpuContext, RenderConfig};

use crate::render::parse_size;
use crate::source::SourceArgs;

/// Arguments of `terrain fly`.
#[derive(Debug, Args)]
pub(crate) struct FlyArgs {
    #[command(flatten)]
    pub source: SourceArgs,
    /// Flight file (JSON; see flights/README.md).
    #[arg(long)]
    pub flight: PathBuf,
    #[command(flatten)]
    pub lod: crate::draw_args::MethodArgs,
    /// A scene folder from `terrain bake` of the same DEM: its PVS files and DSS errors are
    /// read instead of computed (a bad file is a warning; see `terrain bench --scene`).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Image size, WIDTHxHEIGHT (also the viewport of the pixel errors).
    #[arg(long, default_value = "640x360")]
    pub size: String,
    /// At most this many frames, evenly spaced over the flight; 0 = every frame.
    #[arg(long, default_value_t = 0)]
    pub frames: usize,
    #[command(flatten)]
    pub store: crate::draw_args::StoreArgs,
    /// A store: every frame waits until the levels it needs are resident (warm); by default
    /// only the first frame does, later ones draw the finest resident levels (real time).
    #[arg(long)]
    pub wait: bool,
    /// Output folder (created): frame_NNNNN.png, stats.csv, stats.json.
    #[arg(short, long)]
    pub output: PathBuf,
}

/// What a fly writes, besides the folder.
#[derive(Debug, Clone)]
pub(crate) struct FlyOptions {
    /// The method.
    pub method: LodMethod,
    /// Leaf cells.
    pub leaf_cells: u32,
    /// Image size.
    pub size: (u32, u32),
    /// At most this many frames (0 = all).
    pub max_frames: usize,
    /// A scene folder whose precomputed files the method reads ([`terrain_app::scene_files`]).
    pub scene: Option<PathBuf>,
    /// The methods' settings (its parameter from the quality options; `leaf_cells` is
    /// replaced by the field above).
    pub config: MethodConfig,
}

/// Flies `spec` over `hm` into `out` with the GPU `ctx`: PNG frames, stats.csv, stats.json.
/// Returns the frames' records.
pub(crate) fn fly(
    hm: Heightmap,
    spec: &FlightSpec,
    options: FlyOptions,
    ctx: &GpuContext,
    out: &Path,
) -> anyhow::Result<Vec<FrameRecord>> {
    let (width, height) = options.size;
    let flight_cfg = FlightConfig {
        viewport_px: dvec2(f64::from(width), f64::from(height)),
        ..FlightConfig::default()
    };
    let (flight, warnings) = spec.resolve(&hm, &flight_cfg);
    for w in &warnings {
        eprintln!("warning: flight {}: {w}", flight.name);
    }
    let scene =
        MethodScene::new(hm, MethodConfig { leaf_cells: options.leaf_cells, ..options.config });
    if let Some(dir) = &options.scene {
        for warning in terrain_app::scene_files::load(&scene, dir, &[options.method]) {
            eprintln!("warning: {warning}");
        }
    }
    let method = method::build(
        options.method,
        &scene,
        &MethodOptions { morph: true, ..MethodOptions::default() },
    )?;
    std::fs::create_dir_all(out).with_context(|| format!("could not create {}", out.display()))?;
    let mut renderer = method.renderer(
        ctx,
        &RenderConfig { width, height, background: [150, 185, 225, 255], ..Default::default() },
    )?;
    scene.prepare(&[options.method]);
    let measure = MeasureConfig { max_samples: 200_000, ..MeasureConfig::default() };
    let mut runner = FrameLoop::new(method)
        .measured(&scene.hm, &scene.qt, measure)
        .rendered(Some(&mut renderer));
    let indices = frame_indices(flight.frames().len(), options.max_frames);
    let cameras: Vec<Camera> = indices.iter().map(|&k| flight.frames()[k]).collect();
    let blind = terrain_app::camera::frames_without_terrain(&scene.hm, &cameras);
    if let Some(w) = terrain_app::camera::flight_warning(&flight.name, &blind, cameras.len()) {
        eprintln!("warning: {w}");
    }
    let label = format!("{} {}", flight.name, options.method.name());
    let records = write_frames(&mut runner, &indices, &cameras, out, &label)?;
    let json = serde_json::json!({
        "adapter": ctx.describe(),
        "flight": flight.name,
        "method": options.method,
        "size": [width, height],
        "total_frames": flight.frames().len(),
        "warnings": warnings.iter().map(ToString::to_string).collect::<Vec<_>>(),
        "frames": records,
    });
    write_stats(out, &records, &json)?;
    Ok(records)
}

/// Plays `cameras` (frames `indices` of the flight) through `runner`, writing each drawn frame
/// as `frame_NNNNN.png` into `out`, with a progress bar labelled `label`; returns the records.
fn write_frames(
    runner: &mut FrameLoop<'_>,
    indices: &[usize],
    cameras: &[Camera],
    out: &Path,
    label: &str,
) -> anyhow::Result<Vec<FrameRecord>> {
    let mut records = Vec::with_capacity(indices.len());
    for (n, (&k, camera)) in indices.iter().zip(cameras).enumerate() {
        let record = runner.frame(k, camera, None)?.record;
        let image = runner.renderer().expect("rendering").read_image()?;
        let raw: Vec<u8> = image.pixels.iter().flatten().copied().collect();
        let path = out.join(format!("frame_{k:05}.png"));
        image::save_buffer(&path, &raw, image.width, image.height, image::ColorType::Rgba8)
            .with_context(|| format!("could not write {}", path.display()))?;
        records.push(record);
        print_progress(&BenchProgress {
            done: n + 1,
            total: indices.len(),
            label: label.to_string(),
        });
    }
    Ok(records)
}

/// Writes `stats.csv` (one row per record) and `stats.json` (`json`) into `out`.
fn write_stats(
    out: &Path,
    records: &[FrameRecord],
    json: &serde_json::Value,
) -> anyhow::Result<()> {
    let csv_path = out.join("stats.csv");
    let mut csv = std::io::BufWriter::new(
        std::fs::File::create(&csv_path)
            .with_context(|| format!("could not write {}", csv_path.display()))?,
    );
    writeln!(csv, "{}", FrameRecord::CSV_HEADER)?;
    for r in records {
        writeln!(csv, "{}", r.csv_row())?;
    }
    csv.flush()?;
    let json_path = out.join("stats.json");
    std::fs::write(&json_path, serde_json::to_string_pretty(json)?)
        .with_context(|| format!("could not write {}", json_path.display()))?;
    Ok(())
}

/// `terrain fly <store>`: `args.flight` over the store in `dir` with a store method (default
/// `ooc`), through the same store method and frame loop as `terrain render <store>`; frames
/// are drawn, not measured, and their stream statistics summarised. Returns the records.
fn fly_store(
    args: &FlyArgs,
    dir: &Path,
    size: (u32, u32),
    spec: &FlightSpec,
    config: OocConfig,
    method_config: MethodConfig,
) -> anyhow::Result<Vec<FrameRecord>> {
    let scene = crate::render::open_store(dir, config)?;
    let flight = crate::render::store_flight(&scene, dir, spec, size, args.frames)?;
    let ctx = GpuContext::new(&DeviceConfig::from_env(BackendChoice::Auto))
        .context("no GPU adapter (Vulkan or GL) is available")?;
    println!("adapter: {}", ctx.describe());
    let kind = args.lod.kind(true);
    println!("method: {}", kind.name());
    let method_config = MethodConfig { ooc: config, ..method_config };
    let wait = if args.wait { OocWait::EveryFrame } else { OocWait::FirstFrame };
    let method = method::store_method(kind, scene, &method_config, wait, None)?;
    let (width, height) = size;
    let mut renderer = method.renderer(
        &ctx,
        &RenderConfig { width, height, background: [150, 185, 225, 255], ..Default::default() },
    )?;
    let mut runner = FrameLoop::new(method).rendered(Some(&mut renderer));
    let label = format!("{} {}", flight.name, kind.name());
    let records =
        write_frames(&mut runner, &flight.indices, &flight.cameras, &args.output, &label)?;
    drop(runner);
    let streams: Vec<StreamRecord> =
        records.iter().map(|r| r.stream.clone().unwrap_or_default()).collect();
    let json = serde_json::json!({
        "adapter": ctx.describe(),
        "store": dir.display().to_string(),
        "flight": flight.name,
        "method": kind,
        "size": [width, height],
        "total_frames": flight.total_frames,
        "warnings": flight.warnings,
        "real_time": !args.wait,
        "stream_summary": StreamSummary::new(&streams, !args.wait, 0),
        "frames": records,
    });
    write_stats(&args.output, &records, &json)?;
    let max_triangles = records.iter().map(|r| r.triangles).max().unwrap_or(0);
    crate::render::print_stream_summary(&streams, max_triangles, args.wait, args.store.cache_mib());
    Ok(records)
}

/// Runs `terrain fly`.
pub(crate) fn run(args: &FlyArgs) -> anyhow::Result<()> {
    let size = parse_size(&args.size)?;
    args.lod.check()?;
    let store = match args.source.dem.as_slice() {
        [one] if ooc::is_store(one) => Some(one.as_path()),
        _ => None,
    };
    if let Some(dir) = store {
        if args.scene.is_some() {
            bail!(
                "--scene is for a DEM file: a store folder holds its own tables ({} reads them)",
                dir.display()
            );
        }
        args.source.store_exaggeration()?;
    } else if args.scene.is_some() {
        let method = args.lod.kind(false);
        terrain_app::scene_files::check_used(&[method]).map_err(anyhow::Error::msg)?;
    }
    // The inputs first (the flight's errors name its file): nothing is created when one is bad.
    let spec = FlightSpec::load(&args.flight).context("could not load the flight")?;
    let kind = args.lod.kind(store.is_some());
    let mut method_config =
        MethodConfig { leaf_cells: args.lod.leaf_cells, ..MethodConfig::default() };
    method_config.ooc.tau = args.store.tau.unwrap_or(2.0);
    if let Some(dir) = store {
        method_config.ooc.calibration = terrain_app::ooc_calibration::of_store(dir)?;
    }
    let view = ErrorView { height_px: f64::from(size.1), fov_y_deg: spec.fov_y_deg };
    // --tau is the store's (Eq. 7); a DEM's fly does not read it.
    let own = [("--tau", args.store.tau.is_some() && store.is_some())];
    if let Some(p) = args.lod.quality.apply(&mut method_config, kind, view, &own)? {
        println!("quality: {p}");
    }
    /// What the flight is drawn from.
    enum Input<'a> {
        Store(&'a Path, OocConfig),
        Dem(Heightmap),
    }
    let input = match store {
        Some(dir) => Input::Store(
            dir,
            // The flight's frames come at its own rate: Eq. 8's `f`.
            OocConfig {
                vertical_scale: args.source.store_exaggeration()?,
                calibration: method_config.ooc.calibration,
                ..args.store.config(method_config.ooc.tau)?
            }
            .for_flight(spec.fps),
        ),
        None => Input::Dem(match args.source.load_surface()? {
            Some(dem) => dem.heightmap,
            None => synth::default_terrain(),
        }),
    };
    // Then the output folder, before the GPU and any frame: created, and a frame can be
    // written there.
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("could not create the output folder {}", args.output.display()))?;
    crate::render::check_writable(&args.output.join("frame_00000.png"))?;
    let records = match input {
        Input::Store(dir, config) => fly_store(args, dir, size, &spec, config, method_config)?,
        Input::Dem(hm) => {
            let ctx = GpuContext::new(&DeviceConfig::from_env(BackendChoice::Auto))
                .context("no GPU adapter (Vulkan or GL) is available")?;
            println!("adapter: {}", ctx.describe());
            let options = FlyOptions {
                method: args.lod.kind(false),
                leaf_cells: args.lod.leaf_cells,
                size,
                max_frames: args.frames,
                scene: args.scene.clone(),
                config: method_config,
            };
            fly(hm, &spec, options, &ctx, &args.output)?
        }
    };
    let median = |f: fn(&FrameRecord) -> f64| {
        let mut v: Vec<f64> = records.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    };
    println!(
        "wrote {} frames, stats.csv and stats.json to {}: median triangles {:.0}, CPU {:.2} ms, \
         frame {:.2} ms, {}",
        records.len(),
        args.output.display(),
        median(|r| r.triangles as f64),
        median(|r| r.cpu_ms),
        median(|r| r.frame_ms),
        if store.is_some() {
            "errors not measured (no DEM in memory)".to_string()
        } else {
            format!("p99 {:.3} px", median(|r| r.errors.p99_px))
        },
    );
    Ok(())
}
