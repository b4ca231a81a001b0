//! `terrain fly`: flies a camera flight over a DEM (or the embedded terrain) with one LOD method,
//! writing numbered PNG frames and per-frame statistics (stage timings, triangles, exact errors)
//! as CSV and JSON, with a progress bar on stderr.

use std::io::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;
use glam::dvec2;
use terrain_app::bench::{BenchProgress, FrameRecord, frame_indices, print_progress};
use terrain_app::method::{self, FrameLoop, MethodOptions};
use terrain_app::methods::{LodMethod, MethodConfig, MethodScene};
use terrain_core::flight::{FlightConfig, FlightSpec};
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
    /// LOD method.
    #[arg(long, value_enum, default_value_t = LodMethod::PvpsC)]
    pub method: LodMethod,
    /// Cells per side of the finest patch.
    #[arg(long, default_value_t = 16)]
    pub leaf_cells: u32,
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
    let scene = MethodScene::new(
        hm,
        MethodConfig { leaf_cells: options.leaf_cells, ..MethodConfig::default() },
    );
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
    let mut records = Vec::with_capacity(indices.len());
    let label = format!("{} {}", flight.name, options.method.name());
    for (n, &k) in indices.iter().enumerate() {
        let record = runner.frame(k, &flight.frames()[k], None)?.record;
        let image = runner.renderer().expect("rendering").read_image()?;
        let raw: Vec<u8> = image.pixels.iter().flatten().copied().collect();
        let path = out.join(format!("frame_{k:05}.png"));
        image::save_buffer(&path, &raw, image.width, image.height, image::ColorType::Rgba8)
            .with_context(|| format!("could not write {}", path.display()))?;
        records.push(record);
        print_progress(&BenchProgress { done: n + 1, total: indices.len(), label: label.clone() });
    }

    let csv_path = out.join("stats.csv");
    let mut csv = std::io::BufWriter::new(
        std::fs::File::create(&csv_path)
            .with_context(|| format!("could not write {}", csv_path.display()))?,
    );
    writeln!(csv, "{}", FrameRecord::CSV_HEADER)?;
    for r in &records {
        writeln!(csv, "{}", r.csv_row())?;
    }
    csv.flush()?;
    let json = serde_json::json!({
        "adapter": ctx.describe(),
        "flight": flight.name,
        "method": options.method,
        "size": [width, height],
        "total_frames": flight.frames().len(),
        "warnings": warnings.iter().map(ToString::to_string).collect::<Vec<_>>(),
        "frames": records,
    });
    let json_path = out.join("stats.json");
    std::fs::write(&json_path, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("could not write {}", json_path.display()))?;
    Ok(records)
}

/// Runs `terrain fly`.
pub(crate) fn run(args: &FlyArgs) -> anyhow::Result<()> {
    let size = parse_size(&args.size)?;
    if args.leaf_cells == 0 {
        bail!("--leaf-cells must be at least 1");
    }
    if args.scene.is_some() {
        terrain_app::scene_files::check_used(&[args.method]).map_err(anyhow::Error::msg)?;
    }
    // The inputs first (the flight's errors name its file): nothing is created when one is bad.
    let spec = FlightSpec::load(&args.flight).context("could not load the flight")?;
    let hm = match args.source.load_surface()? {
        Some(dem) => dem.heightmap,
        None => synth::default_terrain(),
    };
    // Then the output folder, before the GPU and any frame: created, and a frame can be
    // written there.
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("could not create the output folder {}", args.output.display()))?;
    crate::render::check_writable(&args.output.join("frame_00000.png"))?;
    let ctx = GpuContext::new(&DeviceConfig::from_env(BackendChoice::Auto))
        .context("no GPU adapter (Vulkan or GL) is available")?;
    println!("adapter: {}", ctx.describe());
    let options = FlyOptions {
        method: args.method,
        leaf_cells: args.leaf_cells,
        size,
        max_frames: args.frames,
        scene: args.scene.clone(),
    };
    let records = fly(hm, &spec, options, &ctx, &args.output)?;
    let median = |f: fn(&FrameRecord) -> f64| {
        let mut v: Vec<f64> = records.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    };
    println!(
        "wrote {} frames, stats.csv and stats.json to {}: median triangles {:.0}, CPU {:.2} ms, \
         frame {:.2} ms, p99 {:.3} px",
        records.len(),
        args.output.display(),
        median(|r| r.triangles as f64),
        median(|r| r.cpu_ms),
        median(|r| r.frame_ms),
        median(|r| r.errors.p99_px),
    );
    Ok(())
}
