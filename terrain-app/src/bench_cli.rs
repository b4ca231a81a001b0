//! `terrain bench`: every LOD method over the given flights on one DEM, each method's threshold
//! swept; writes `<out>/<name>.json`, `.md` and `.svg` (see `terrain_app::bench`).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;
use terrain_app::bench::{BenchConfig, BenchReport, print_progress, run_bench};
use terrain_app::methods::{LodMethod, MethodConfig};
use terrain_core::flight::FlightSpec;
use terrain_core::synth;
use terrain_gpu::{BackendChoice, DeviceConfig, GpuContext};
use terrain_stream::SplitRule;

use crate::render::parse_size;
use crate::source::SourceArgs;

/// Arguments of `terrain bench`.
#[derive(Debug, Args)]
pub(crate) struct BenchArgs {
    #[command(flatten)]
    pub source: SourceArgs,
    /// Flight files (JSON), flown in this order.
    #[arg(long = "flight", required = true, num_args = 1..)]
    pub flights: Vec<PathBuf>,
    /// Methods, comma-separated (default: all but geomorph-static and geomorph-cpu, the
    /// geomorphing article's Table 1 paths).
    #[arg(long, value_enum, value_delimiter = ',')]
    pub methods: Vec<LodMethod>,
    /// The CI settings: 5 frames per flight, 3 sweep points, 320x180 images, the ooc
    /// method's frames warm (as --wait).
    #[arg(long)]
    pub quick: bool,
    /// At most this many frames per flight, evenly spaced (0 = all). Default 60 (quick: 5).
    #[arg(long)]
    pub frames: Option<usize>,
    /// Sweep points per method. Default 5 (quick: 3).
    #[arg(long)]
    pub sweep: Option<usize>,
    /// Rendered image size, WIDTHxHEIGHT. Default 640x360 (quick: 320x180).
    #[arg(long)]
    pub size: Option<String>,
    /// Measure only: do not render (no GPU times).
    #[arg(long)]
    pub no_render: bool,
    /// Cells per side of the finest patch.
    #[arg(long, default_value_t = 16)]
    pub leaf_cells: u32,
    /// Report name: the files are `<out>/<name>.{json,md,svg}`. Default: the DEM's file stem
    /// (`default` for the embedded terrain).
    #[arg(long)]
    pub name: Option<String>,
    /// Output folder (created).
    #[arg(short, long, visible_alias = "output", default_value = "out/bench")]
    pub out: PathBuf,
    /// A scene folder from `terrain bake` of the same DEM: its PVS files (for `pvps-c-pvs` and
    /// `pvps-c-cons`) and its DSS errors (for `dss-1`, `dss-2`, `dss-strips`) are read instead
    /// of computed. A bad PVS file is a warning (no occlusion culling); a bad DSS file is a
    /// warning (the errors are computed in memory). It is also the `ooc` method's store unless
    /// `--ooc-store` names another.
    #[arg(long, alias = "pvs-scene")]
    pub scene: Option<PathBuf>,
    /// The `ooc` method: a store baked from the same DEM (default: the `--scene` folder, else
    /// one baked to a temporary folder with blocks of 2^ooc-k + 1 vertices).
    #[arg(long)]
    pub ooc_store: Option<PathBuf>,
    /// The `ooc` method: k of the temporary store (not with `--ooc-store` or `--scene`, whose
    /// store is already baked) [default: 8].
    #[arg(long)]
    pub ooc_k: Option<u8>,
    /// The `ooc` method: the stream cache's budget, MiB (2^20 bytes) [default: 256].
    #[arg(long, alias = "ooc-cache-mb")]
    pub ooc_cache_mib: Option<u64>,
    /// The `ooc` method: the split rule inside the blocks, `eq7` (Eq. 7 alone) or `cost`
    /// (Eq. 7 and the cost split) [default: eq7].
    #[arg(long, value_parser = ["eq7", "cost"])]
    pub ooc_split: Option<String>,
    /// The `ooc` method: the smallest patch, cells per side (a power of two) [default: 32].
    #[arg(long)]
    pub ooc_patch_cells: Option<u32>,
    /// The `ooc` method: the cost split's screen-size floor, pixels (0: everywhere)
    /// [default: 0].
    #[arg(long)]
    pub ooc_cost_px: Option<u32>,
    /// The `ooc` method: the coarsest segment a drawn patch may have, cells (a power of two;
    /// 0: none, Eq. 7's least factors; 16: geomorph's floor, see bench/ooc/README.md)
    /// [default: 16].
    #[arg(long)]
    pub ooc_max_segment_cells: Option<u32>,
    /// The floor of the view-angle factor, in [0, 1]: DSS Eq. 3's `sin(theta)` (`dss-1`,
    /// `dss-2`, `dss-strips`, `dss-strips-pow2`) and the out-of-core Eq. 6-7's `cos(theta)`
    /// (`ooc`); not in the papers (0 is theirs: no error below a straight-down camera)
    /// [default: 0.25].
    #[arg(long)]
    pub view_angle_floor: Option<f64>,
    /// The `ooc` method: which calibration maps --error-px onto its tau: `auto` (the store's
    /// ooc-calibration.txt when it has one for the refinement, else the shared one), `shared`,
    /// or a calibration FILE of the benchmark's store (`terrain calibrate STORE -o FILE`)
    /// [default: auto].
    #[arg(long, value_name = "auto|shared|FILE")]
    pub ooc_calibration: Option<String>,
    /// The `ooc` method: every sampled frame waits until the levels it needs are resident
    /// (warm: the error is the selection's own). By default the flight is played in real
    /// time at its own frame rate, every frame, and late data is counted.
    #[arg(long)]
    pub wait: bool,
    /// Also run every in-memory method that can draw from a store (all but entropy) from the
    /// benchmark's store, side by side with the same method from memory (the report marks
    /// those runs `(store)`; the store gets the tables the methods read). With `--wait` their
    /// frames are warm, so they select and draw what the method does from memory.
    #[arg(long)]
    pub from_store: bool,
    /// Run every method from the store only (`--ooc-store` or `--scene`), none from memory,
    /// and prepare no in-memory tables: for DEMs whose in-memory methods would take too long
    /// to prepare (`tin`'s whole pyramid, geomorph's tables on 16385^2). The DEM is still
    /// read to measure the drawn surfaces against.
    #[arg(long)]
    pub store_only: bool,
    /// Rendered frames colour every patch by its level of detail: the geomorph methods then
    /// draw one pass (base colour and lightmap: the geomorphing article's "minimum scene")
    /// instead of their material passes.
    #[arg(long)]
    pub lod_colours: bool,
    /// Sweep these screen-space error targets, pixels, comma-separated, instead of each
    /// method's own parameter: every method at each target through the one mapping of
    /// `--error-px` (the report's notes give each method's mapped parameter). Not with --sweep.
    #[arg(long, value_delimiter = ',', conflicts_with = "sweep")]
    pub error_px: Vec<f64>,
    /// The swept parameter's values, comma-separated, for every method in `--methods` (each
    /// its own parameter: C1, rho_thr, tau, ...) instead of `--sweep` points of each method's
    /// list: how `cargo xtask papers` runs a paper's settings. Not with --sweep or --error-px.
    #[arg(long, value_delimiter = ',', conflicts_with_all = ["sweep", "error_px"])]
    pub values: Vec<f64>,
    /// PVPS methods: Eq. 12's adjustment coefficients as C3:C4 (default 10:1, the paper's
    /// Table 2); Algorithm 1's `Constant` follows as C3 x C4. The PVPS paper's Table 3 sweeps
    /// them.
    #[arg(long, value_name = "C3:C4")]
    pub pvps_c3_c4: Option<String>,
    /// The viewport of the flights' cameras, WIDTHxHEIGHT, for selection and pixel errors
    /// (default 1280x720); the papers' screens differ (PVPS 1200x800, out-of-core 1024x768).
    #[arg(long)]
    pub viewport: Option<String>,
}

/// Parses `C3:C4` (both positive and finite).
fn parse_c3_c4(s: &str) -> anyhow::Result<(f64, f64)> {
    let bad = || format!("--pvps-c3-c4 expects C3:C4 (e.g. 12.5:0.5), got `{s}`");
    let (a, b) = s.split_once(':').with_context(bad)?;
    let (c3, c4): (f64, f64) =
        (a.trim().parse().with_context(bad)?, b.trim().parse().with_context(bad)?);
    if !(c3.is_finite() && c4.is_finite() && c3 > 0.0 && c4 >= 0.0) {
        bail!("{}: C3 must be positive and C4 not negative", bad());
    }
    Ok((c3, c4))
}

/// Writes `<dir>/<name>.json`, `.md` and `.svg`; returns the three paths.
pub(crate) fn write_report(
    report: &BenchReport,
    dir: &Path,
    name: &str,
) -> anyhow::Result<[PathBuf; 3]> {
    std::fs::create_dir_all(dir).with_context(|| format!("could not create {}", dir.display()))?;
    let paths = ["json", "md", "svg"].map(|e| dir.join(format!("{name}.{e}")));
    let contents = [serde_json::to_string_pretty(report)?, report.to_markdown(), report.to_svg()];
    for (p, c) in paths.iter().zip(contents) {
        std::fs::write(p, c).with_context(|| format!("could not write {}", p.display()))?;
    }
    Ok(paths)
}

/// `--ooc-max-segment-cells`: 0 or a power of two.
pub(crate) fn max_segment_cells(cells: u32) -> anyhow::Result<u32> {
    if cells != 0 && !cells.is_power_of_two() {
        bail!("--ooc-max-segment-cells must be 0 or a power of two, got {cells}");
    }
    Ok(cells)
}

/// Refuses the store options no run would use: they apply to the `ooc` method (in `--methods`,
/// or by default) or to `--from-store`; `--ooc-k` only to the temporary store baked when
/// neither `--ooc-store` nor `--scene` names one.
fn refuse_unused_store_options(args: &BenchArgs, cfg: &BenchConfig) -> anyhow::Result<()> {
    let uses_store =
        args.from_store || args.store_only || cfg.methods.contains(&LodMethod::OutOfCore);
    let given: Vec<&str> = [
        ("--ooc-store", args.ooc_store.is_some()),
        ("--ooc-k", args.ooc_k.is_some()),
        ("--ooc-cache-mib", args.ooc_cache_mib.is_some()),
        ("--ooc-split", args.ooc_split.is_some()),
        ("--ooc-cost-px", args.ooc_cost_px.is_some()),
        ("--ooc-max-segment-cells", args.ooc_max_segment_cells.is_some()),
        ("--ooc-patch-cells", args.ooc_patch_cells.is_some()),
        ("--ooc-calibration", args.ooc_calibration.is_some()),
        ("--wait", args.wait),
    ]
    .iter()
    .filter(|(_, g)| *g)
    .map(|(name, _)| *name)
    .collect();
    if !uses_store && !given.is_empty() {
        bail!(
            "{} {} to the ooc method and --from-store, and --methods has no ooc",
            given.join(", "),
            if given.len() == 1 { "applies" } else { "apply" }
        );
    }
    // --scene is also the ooc method's store.
    if args.scene.is_some() && !uses_store {
        terrain_app::scene_files::check_used(&cfg.methods).map_err(anyhow::Error::msg)?;
    }
    if args.ooc_k.is_some() && cfg.ooc_store.is_some() {
        bail!(
            "--ooc-k applies to the store the benchmark bakes for itself; the store named by \
             {} is already baked",
            if args.ooc_store.is_some() { "--ooc-store" } else { "--scene" }
        );
    }
    Ok(())
}

/// Runs `terrain bench`.
pub(crate) fn run(args: &BenchArgs) -> anyhow::Result<()> {
    let mut cfg = if args.quick { BenchConfig::quick() } else { BenchConfig::default() };
    if !args.methods.is_empty() {
        cfg.methods = args.methods.clone();
    }
    if let Some(f) = args.frames {
        cfg.max_frames = f;
    }
    if let Some(s) = args.sweep {
        if s == 0 {
            bail!("--sweep must be at least 1");
        }
        cfg.sweep_points = s;
    }
    if let Some(s) = &args.size {
        cfg.render_size = Some(parse_size(s)?);
    }
    if args.no_render {
        if args.size.is_some() {
            bail!("--size applies to the rendered images, and --no-render draws none");
        }
        cfg.render_size = None;
    }
    if args.leaf_cells == 0 {
        bail!("--leaf-cells must be at least 1");
    }
    cfg.method = MethodConfig { leaf_cells: args.leaf_cells, ..MethodConfig::default() };
    if let Some(pair) = &args.pvps_c3_c4 {
        let (c3, c4) = parse_c3_c4(pair)?;
        cfg.method.pvps.c3 = c3;
        cfg.method.pvps.c4 = c4;
        cfg.method.pvps.outer_constant = c3 * c4;
    }
    if let Some(v) = &args.viewport {
        cfg.measure_viewport = parse_size(v).context("--viewport")?;
    }
    if !args.values.is_empty() {
        if let Some(v) = args.values.iter().find(|v| !v.is_finite()) {
            bail!("--values takes finite numbers, got {v}");
        }
        cfg.sweep_override = cfg.methods.iter().map(|&m| (m, args.values.clone())).collect();
    }
    cfg.scene = args.scene.clone();
    cfg.ooc_store = args.ooc_store.clone().or_else(|| args.scene.clone());
    refuse_unused_store_options(args, &cfg)?;
    cfg.ooc_k = args.ooc_k.unwrap_or(cfg.ooc_k);
    if let Some(mib) = args.ooc_cache_mib {
        cfg.ooc.budget_bytes = mib << 20;
    }
    if let Some(split) = &args.ooc_split {
        cfg.ooc.split = if split == "cost" { SplitRule::Cost } else { SplitRule::Eq7 };
    }
    if let Some(px) = args.ooc_cost_px {
        cfg.ooc.cost_split_px = px;
    }
    if let Some(cells) = args.ooc_max_segment_cells {
        cfg.ooc.max_segment_cells = max_segment_cells(cells)?;
    }
    if let Some(floor) = args.view_angle_floor {
        if !(0.0..=1.0).contains(&floor) {
            bail!("--view-angle-floor takes a number in [0, 1], got {floor}");
        }
        cfg.method.dss.view_angle_floor = floor;
        cfg.ooc.view_angle_floor = floor;
    }
    if let Some(cells) = args.ooc_patch_cells {
        if !cells.is_power_of_two() {
            bail!("--ooc-patch-cells must be a power of two, got {cells}");
        }
        cfg.ooc.patch_cells = cells;
    }
    if let Some(c) = &args.ooc_calibration {
        if args.error_px.is_empty() {
            bail!("--ooc-calibration maps --error-px onto ooc's tau: give --error-px too");
        }
        cfg.ooc_calibration = terrain_app::bench::OocCalibration::parse(c);
    }
    cfg.ooc_wait |= args.wait;
    cfg.lod_colours = args.lod_colours;
    cfg.from_store = args.from_store || args.store_only;
    cfg.store_only = args.store_only;
    if !args.error_px.is_empty() {
        if let Some(px) = args.error_px.iter().find(|p| !(p.is_finite() && **p > 0.0)) {
            bail!("--error-px takes positive numbers of pixels, got {px}");
        }
        cfg.error_px = Some(args.error_px.clone());
    }
    let flights = args
        .flights
        .iter()
        // The flight's errors name its file.
        .map(|p| FlightSpec::load(p).context("could not load the flight"))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let (hm, default_name) = match args.source.load_surface()? {
        Some(dem) => {
            let stem = args.source.dem[0].file_stem().map(|s| s.to_string_lossy().into_owned());
            (dem.heightmap, stem.unwrap_or_else(|| "dem".to_string()))
        }
        None => (synth::default_terrain(), "default".to_string()),
    };
    let name = args.name.clone().unwrap_or(default_name);
    let ctx = if cfg.render_size.is_some() {
        let ctx = GpuContext::try_new(&DeviceConfig::from_env(BackendChoice::Auto))?;
        match &ctx {
            Some(c) => println!("adapter: {}", c.describe()),
            None => eprintln!("no GPU adapter: measuring without rendering (no GPU times)"),
        }
        ctx
    } else {
        None
    };
    let start = std::time::Instant::now();
    let report = run_bench(&name, hm, &flights, &cfg, ctx.as_ref(), &mut print_progress)?;
    let paths = write_report(&report, &args.out, &name)?;
    println!("{}", report.to_markdown());
    for p in &paths {
        println!("wrote {}", p.display());
    }
    println!("bench took {:.1} s", start.elapsed().as_secs_f64());
    Ok(())
}
