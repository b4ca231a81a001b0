//! `terrain tiles`: a Cesium quantized-mesh-1.0 tileset of a DEM, every tile an error-bounded
//! TIN verified against the DEM ([`terrain_core::tin`]), built on every core.
//!
//! Writes `DIR/{z}/{x}/{y}.terrain` (TMS addressing, geographic tiling scheme, EPSG:4326),
//! `DIR/layer.json` (the TileJSON CesiumJS reads: format, scheme, extensions, available ranges)
//! and `DIR/tiles.json` (what was built: per level the bound, tiles, triangles and the largest
//! error measured against the DEM).
//!
//! Projected DEMs are resampled onto longitude/latitude first ([`terrain_core::tin::warp`]); a
//! DEM without a georeference (images, raw grids) is placed with `--lonlat` (the position of
//! its south-west sample) and `--spacing`, or refused: tiles must sit somewhere on the Earth,
//! and users of such files know where their terrain is while no default would be right.
//!
//! A baked store (`terrain bake`) is read tile by tile ([`terrain_app::samples::StoreSamples`]: each tile's
//! samples at the stride its level needs, from the store's levels, through a byte-budgeted
//! cache, `--cache`), so a DEM of any size is tiled in bounded memory; a store without a
//! georeference is placed with `--lonlat` as a bare heightmap is, a projected store is refused
//! (reprojection resamples the whole grid: tile its DEM, or bake a geographic one). Every
//! source goes through the same per-tile path ([`build`]), so a losslessly baked store gives
//! the tileset its DEM gives in memory.

mod build;
mod check;
mod walk;

use std::path::PathBuf;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::{Context, bail};
use clap::Args;
use glam::dvec2;
use serde::Serialize;
use terrain_core::tin::{self, GridLayout, TileId, TileMesh, TileRange, quantized_mesh, warp};
use terrain_core::{Crs, Heightmap};

use terrain_app::progress::Progress;

use crate::source::{SourceArgs, parse_memory};
use build::{MesherChoice, ResolutionConfig};
use terrain_app::decimation::{DECIMATION_REGION, Decimation};
use terrain_app::samples::{HeightmapSamples, Samples, StoreSamples};

/// Deepest `--max-level` accepted (tiles of about 5 m at the equator).
const MAX_LEVEL: u32 = 22;

/// Arguments of `terrain tiles`.
#[derive(Debug, Args)]
pub(crate) struct TilesArgs {
    #[command(flatten)]
    pub source: SourceArgs,
    /// Output folder (created; existing tiles in it are replaced).
    #[arg(short, long)]
    pub output: PathBuf,
    /// First level written (CesiumJS needs level 0; a higher one is for partial updates).
    #[arg(long, default_value_t = 0)]
    pub min_level: u32,
    /// Last level written. Default: the first level whose tiles span at most 64 DEM samples
    /// (a 65-sample tile at the DEM's resolution).
    #[arg(long)]
    pub max_level: Option<u32>,
    /// Multiplies every level's bound: the tile at level L is within
    /// SCALE x 77067 m / 2^L of every DEM sample in it (77067 m: CesiumJS's level-0 error).
    #[arg(long, default_value_t = 1.0)]
    pub error_scale: f64,
    /// Gzip every tile (serve them with `Content-Encoding: gzip`).
    #[arg(long)]
    pub gzip: bool,
    /// For a DEM without a georeference: LON,LAT (degrees) of its south-west sample; its
    /// spacing is --spacing metres.
    #[arg(long, allow_hyphen_values = true)]
    pub lonlat: Option<String>,
    /// For a baked store: most memory its decoded blocks may take (bytes, or a number with
    /// KiB, MiB, GiB or TiB); the tiles' memory is bounded by it, not by the DEM.
    #[arg(long, default_value = "512MiB", value_parser = parse_memory)]
    pub cache: u64,
    /// The mesher: `auto` (the default) meshes a tile from every sample (at most 256 cells
    /// across) as an RTIN where its parent kept at least --rtin-density of the DEM samples
    /// inside it, every other tile by the greedy Delaunay insertion (the fewest triangles).
    /// Why, measured on a rough synthetic 4097^2 store (bench/mesh/README.md, tiles16e): where
    /// the greedy mesh keeps most samples the RTIN draws a few % more triangles (1.03-1.10x at
    /// 76-98 % kept) for much less CPU (a whole tileset at a twentieth of the bounds: 0.65x);
    /// where it keeps few, the RTIN draws 1.3-1.8x the triangles for more CPU (at the default
    /// bounds, RTIN at the finest three levels: 1.2x the CPU, 1.44x the triangles), so there
    /// `auto` is the greedy mesher. `greedy` or `rtin` force one mesher everywhere
    /// (measurements).
    #[arg(long, value_enum, default_value_t = MesherChoice::Auto)]
    pub mesher: MesherChoice,
    /// `--mesher auto`'s threshold: the fraction of a tile's DEM samples its parent kept as
    /// vertices from which the tile is meshed as an RTIN (above 1: never).
    #[arg(long, default_value_t = build::RTIN_DENSITY)]
    pub rtin_density: f64,
    /// Most cells across a tile's samples meshed at once: a tile meshed from more samples
    /// (a coarse tile whose decimation error leaves too little of its bound, on rough
    /// terrain) is read and meshed in pieces of at most this many cells a side with locked
    /// shared sides, so the memory of a tile does not grow with the DEM (about 4 bytes a
    /// sample of a piece, per thread, plus the tile's mesh). Greedy mesher only.
    #[arg(long, default_value_t = ResolutionConfig::default().piece_cells as u32, value_parser = clap::value_parser!(u32).range(16..))]
    pub piece_cells: u32,
    /// No progress line.
    #[arg(long)]
    pub quiet: bool,
}

/// One level of `tiles.json`.
#[derive(Debug, Default, Serialize)]
struct LevelStats {
    level: u32,
    /// The bound every tile of the level meets, metres.
    bound_m: f64,
    tiles: usize,
    triangles: usize,
    vertices: usize,
    /// DEM samples the level's tiles were meshed from (at their strides): the full grid
    /// would draw about two triangles a sample.
    samples: usize,
    bytes: u64,
    /// The largest error measured against the DEM samples of a tile of this level, metres.
    max_measured_error_m: f64,
    /// The largest decimation error a tile of this level was meshed under (0: every tile
    /// meshed from every sample), metres.
    decimation_error_m: f64,
    /// Seconds the level's meshes took (built and checked), summed over the threads.
    mesh_s: f64,
    /// Seconds encoding and writing the level's tiles took, summed over the threads.
    write_s: f64,
    /// Tiles meshed as an RTIN (the rest greedy Delaunay).
    rtin_tiles: usize,
}

/// `tiles.json`.
#[derive(Debug, Serialize)]
struct Summary {
    dem: String,
    width: usize,
    height: usize,
    reprojected_from: Option<String>,
    extent: tin::LonLatRect,
    error_scale: f64,
    min_level: u32,
    max_level: u32,
    gzip: bool,
    tiles: usize,
    triangles: usize,
    build_s: f64,
    threads: usize,
    levels: Vec<LevelStats>,
    /// Decimated tiles (meshed from every 2^s-th sample within their bound less the measured
    /// decimation error, at least this fraction of it, then checked against every sample) and
    /// their rebuilds after failing that check.
    min_budget_fraction: f64,
    decimated_tiles: usize,
    /// The mesher (`--mesher`).
    mesher: MesherChoice,
    /// `--mesher auto`'s threshold (`--rtin-density`).
    rtin_density: f64,
    /// Most cells across a tile's samples meshed at once (`--piece-cells`).
    piece_cells: usize,
    retries: usize,
    /// Measuring the decimation error (once per region and stride): seconds, and the largest
    /// error found at any stride, metres.
    decimation_s: f64,
    decimation_error_m: f64,
    /// The samples' minima and maxima the checks prove most of a coarse tile's bound with
    /// (measured in the decimation pass's read, `decimation_s`): seconds merging them into
    /// their pyramid, and bytes held.
    sample_range_s: f64,
    sample_range_bytes: usize,
    /// Most tiles whose mesh was held at once by the depth-first walk.
    peak_pending_tiles: usize,
    /// For a store: the most bytes of decoded blocks resident at once, and block levels decoded.
    cache_peak_bytes: Option<u64>,
    block_levels_decoded: Option<u64>,
}

fn parse_lonlat(s: &str) -> anyhow::Result<glam::DVec2> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let [lon, lat] = parts.as_slice() else {
        bail!("--lonlat takes LON,LAT in degrees (e.g. --lonlat=-122.5,46.5), got `{s}`");
    };
    let num =
        |v: &str| v.parse::<f64>().with_context(|| format!("--lonlat: `{v}` is not a number"));
    Ok(dvec2(num(lon)?, num(lat)?))
}

/// The DEM on longitude/latitude, and the CRS it was reprojected from, if it was.
fn geographic(args: &TilesArgs, hm: Heightmap) -> anyhow::Result<(Heightmap, Option<String>)> {
    let crs = hm.georef().crs.clone();
    match (&crs, &args.lonlat) {
        (Crs::Unknown, None) => bail!(
            "the DEM has no georeference, so its tiles cannot be placed on the Earth: give \
             --lonlat LON,LAT (its south-west sample) and --spacing METRES"
        ),
        (Crs::Unknown, Some(s)) => Ok((warp::place(&hm, parse_lonlat(s)?)?, None)),
        (_, Some(_)) => {
            bail!("--lonlat places a DEM without a georeference; this one is georeferenced ({crs})")
        }
        (_, None) if hm.georef().units == terrain_core::georef::AngularOrLinear::Degrees => {
            Ok((hm, None))
        }
        (_, None) => {
            let t = Instant::now();
            let geo = warp::to_geographic(&hm).context("reprojecting to longitude/latitude")?;
            eprintln!(
                "reprojected {crs} to EPSG:4326: {} x {} samples in {:.1} s",
                geo.width(),
                geo.height(),
                t.elapsed().as_secs_f64()
            );
            Ok((geo, Some(crs.to_string())))
        }
    }
}

/// Where the heights come from: a DEM in memory or a store read by windows.
enum Source {
    Memory(Heightmap),
    Store(Box<StoreSamples>),
}

/// Opens the input: a store folder (read by windows) or DEM file(s) (loaded, put on
/// longitude/latitude): its layout, name, size as given and the CRS it was reprojected from.
fn open(args: &TilesArgs) -> anyhow::Result<(Source, GridLayout, String, Option<String>)> {
    if let [one] = args.source.dem.as_slice()
        && terrain_app::ooc::is_store(one)
    {
        args.source.refuse_reading_options("a baked store (its heights are stored)")?;
        // A folder, or a URL (`s3://`, `http(s)://`...) read through the disk cache.
        let store = terrain_app::ooc::open_store(one)
            .with_context(|| format!("opening the store {}", one.display()))?;
        let h = store.header();
        let size = (h.width as usize, h.height as usize);
        let georef = match (&h.georef.crs, &args.lonlat) {
            (Crs::Unknown, None) => bail!(
                "the store has no georeference, so its tiles cannot be placed on the Earth: give \
                 --lonlat LON,LAT (its south-west sample)"
            ),
            (Crs::Unknown, Some(s)) => warp::place_georef(&h.georef, size, parse_lonlat(s)?)?,
            (crs, Some(_)) => bail!(
                "--lonlat places a store without a georeference; this one is georeferenced ({crs})"
            ),
            (_, None) if h.georef.units == terrain_core::georef::AngularOrLinear::Degrees => {
                h.georef.clone()
            }
            (crs, None) => bail!(
                "the store is in {crs}, a projected CRS: tiles from a store need one in degrees \
                 (reprojecting resamples the whole grid in memory); give `terrain tiles` its DEM \
                 file, or bake a store from a DEM in longitude/latitude"
            ),
        };
        let layout = GridLayout::new(size.0, size.1, &georef)?;
        let name = one.display().to_string();
        return Ok((
            Source::Store(Box::new(StoreSamples::new(store, args.cache))),
            layout,
            name,
            None,
        ));
    }
    let (hm, name) = match args.source.load_surface()? {
        Some(dem) => (dem.heightmap, dem.source.path.display().to_string()),
        None => (terrain_core::synth::default_terrain(), "the embedded synthetic terrain".into()),
    };
    let (hm, reprojected_from) = geographic(args, hm)?;
    let layout = GridLayout::new(hm.width(), hm.height(), hm.georef())?;
    Ok((Source::Memory(hm), layout, name, reprojected_from))
}

/// Runs `terrain tiles`.
pub(crate) fn run(args: &TilesArgs) -> anyhow::Result<()> {
    if !(args.error_scale.is_finite() && args.error_scale > 0.0) {
        bail!("--error-scale must be a positive number, got {}", args.error_scale);
    }
    let (source, layout, name, reprojected_from) = open(args)?;
    let samples: &dyn Samples = match &source {
        Source::Memory(hm) => &HeightmapSamples(hm),
        Source::Store(s) => s.as_ref(),
    };
    let (width, height) = samples.size();
    let max_level = args.max_level.unwrap_or_else(|| layout.native_level(64.0));
    if max_level > MAX_LEVEL || args.min_level > max_level {
        bail!(
            "levels {}..={max_level}: need --min-level <= --max-level <= {MAX_LEVEL}",
            args.min_level
        );
    }
    let levels = args.min_level..=max_level;
    let range = |level: u32| {
        if level == 0 {
            TileRange { start_x: 0, start_y: 0, end_x: 1, end_y: 0 }
        } else {
            layout.tile_range(level)
        }
    };
    if !(args.rtin_density.is_finite() && args.rtin_density >= 0.0) {
        bail!(
            "--rtin-density must be a fraction >= 0 (above 1: never RTIN), got {}",
            args.rtin_density
        );
    }
    let resolution = ResolutionConfig {
        mesher: args.mesher,
        rtin_density: args.rtin_density,
        piece_cells: args.piece_cells as usize,
        ..ResolutionConfig::default()
    };
    let total: usize = levels.clone().map(|l| range(l).len() as usize).sum();
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("creating {}", args.output.display()))?;
    let t0 = Instant::now();
    // The strides the decimated tiles may use: up to the coarsest level's.
    let max_s = range(args.min_level)
        .tiles(args.min_level)
        .map(|t| build::stride_log2(&layout, t, &resolution))
        .max()
        .unwrap_or(0);
    let (w, h) = samples.size();
    let decimation = Decimation::new(w, h, DECIMATION_REGION, max_s);
    // One read of every sample for both: the decimation error per region and the samples'
    // minima and maxima the checks prune with.
    let leaf_log2 = check::leaf_log2_for(w, h);
    let leaves = decimation
        .measure_all(samples, |i0, j0, win| check::LeafBoxes::of(leaf_log2, i0, j0, win))?;
    let decimation_s = t0.elapsed().as_secs_f64();
    let sample_range = check::SampleRange::from_leaves(w, h, leaf_log2, &leaves);
    drop(leaves);
    let range_s = t0.elapsed().as_secs_f64() - decimation_s;
    let bar = Progress::new("tiles", !args.quiet);
    let done = AtomicUsize::new(0);
    let stats: Mutex<Vec<LevelStats>> = Mutex::new(
        levels
            .clone()
            .map(|level| LevelStats {
                level,
                bound_m: tin::level_error(level, args.error_scale),
                ..LevelStats::default()
            })
            .collect(),
    );
    let made_dirs: Mutex<std::collections::HashSet<(u32, u32)>> = Mutex::default();
    let write = |mesh: &TileMesh, built: &walk::Done| -> anyhow::Result<()> {
        let started = Instant::now();
        let tile = mesh.tile;
        let children =
            if tile.level < max_level { range(tile.level + 1).below(tile) } else { None };
        let mut bytes = quantized_mesh::encode(mesh, children)
            .with_context(|| format!("encoding tile {}/{}/{}", tile.level, tile.x, tile.y))?;
        if args.gzip {
            bytes = quantized_mesh::gzip(&bytes);
        }
        let dir = args.output.join(tile.level.to_string()).join(tile.x.to_string());
        // Each column's folder made once (a `create_dir_all` per tile costs a failed `mkdir`
        // and a `stat` on the disk for each of the 141,812 tiles of a 16385^2 tileset).
        let column = (tile.level, tile.x);
        if !made_dirs.lock().unwrap_or_else(|e| e.into_inner()).contains(&column) {
            std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
            made_dirs.lock().unwrap_or_else(|e| e.into_inner()).insert(column);
        }
        let path = dir.join(format!("{}.terrain", tile.y));
        std::fs::write(&path, &bytes).with_context(|| format!("writing {}", path.display()))?;
        {
            let mut s = stats.lock().unwrap_or_else(|e| e.into_inner());
            let s = &mut s[(tile.level - args.min_level) as usize];
            s.tiles += 1;
            s.triangles += mesh.triangles.len();
            s.vertices += mesh.vertices.len();
            s.samples += built.samples;
            s.bytes += bytes.len() as u64;
            s.max_measured_error_m = s.max_measured_error_m.max(built.measured);
            s.decimation_error_m = s.decimation_error_m.max(built.decimation);
            s.mesh_s += built.mesh_s;
            s.rtin_tiles += usize::from(built.rtin);
            s.write_s += started.elapsed().as_secs_f64();
        }
        let n = done.fetch_add(1, Ordering::Relaxed) + 1;
        bar.update(n as f64, total as f64);
        Ok(())
    };
    let bound_of = |tile: TileId| tin::level_error(tile.level, args.error_scale);
    let walk = walk::Walk {
        samples,
        layout: &layout,
        resolution,
        decimation: &decimation,
        range: &sample_range,
        max_level,
        tiles: &range,
        bound: &bound_of,
        write: &write,
    };
    let roots: Vec<TileId> = range(args.min_level).tiles(args.min_level).collect();
    let walked = walk.run(&roots)?;
    bar.finish();
    let build_s = t0.elapsed().as_secs_f64();
    let available: Vec<Vec<TileRange>> = (0..=max_level)
        .map(|l| if l < args.min_level { Vec::new() } else { vec![range(l)] })
        .collect();
    let extent = layout.extent();
    let layer = serde_json::json!({
        "tilejson": "2.1.0",
        "name": name,
        "description": format!(
            "error-bounded TIN tiles by `terrain tiles`: level L within {} x {:.2} m / 2^L of the DEM",
            args.error_scale, tin::LEVEL_ZERO_ERROR_M
        ),
        "version": "1.0.0",
        "format": "quantized-mesh-1.0",
        "attribution": "",
        "scheme": "tms",
        "tiles": ["{z}/{x}/{y}.terrain?v={version}"],
        "projection": "EPSG:4326",
        "bounds": [extent.west, extent.south, extent.east, extent.north],
        "minzoom": args.min_level,
        "maxzoom": max_level,
        "extensions": ["octvertexnormals", "metadata"],
        // Every tile's metadata lists its children (the next level): CesiumJS reads a tile's
        // availability from its parent's then. Without this key CesiumJS takes `available`
        // alone and fails on the first tile's metadata ("Cannot read properties of undefined
        // (reading 'addAvailableTileRange')", seen in headless Chromium with cesium 1.145).
        "metadataAvailability": 1,
        "available": available,
    });
    let layer_path = args.output.join("layer.json");
    std::fs::write(&layer_path, serde_json::to_string_pretty(&layer)?)
        .with_context(|| format!("writing {}", layer_path.display()))?;
    let levels = stats.into_inner().unwrap_or_else(|e| e.into_inner());
    let cache = match &source {
        Source::Store(s) => Some(s.cache_stats()),
        Source::Memory(_) => None,
    };
    let summary = Summary {
        dem: name,
        width,
        height,
        reprojected_from,
        extent,
        error_scale: args.error_scale,
        min_level: args.min_level,
        max_level,
        gzip: args.gzip,
        tiles: done.load(Ordering::Relaxed),
        triangles: levels.iter().map(|l| l.triangles).sum(),
        build_s,
        threads: rayon::current_num_threads(),
        levels,
        min_budget_fraction: resolution.policy.min_budget_fraction,
        decimated_tiles: walked.decimated_tiles,
        mesher: resolution.mesher,
        rtin_density: resolution.rtin_density,
        piece_cells: resolution.piece_cells,
        retries: walked.retries,
        decimation_s,
        decimation_error_m: decimation.max(),
        sample_range_s: range_s,
        sample_range_bytes: sample_range.bytes(),
        peak_pending_tiles: walked.peak_pending_tiles,
        cache_peak_bytes: cache.map(|c| c.0),
        block_levels_decoded: cache.map(|c| c.1),
    };
    let summary_path = args.output.join("tiles.json");
    std::fs::write(&summary_path, serde_json::to_string_pretty(&summary)?)
        .with_context(|| format!("writing {}", summary_path.display()))?;
    for l in &summary.levels {
        println!(
            "level {:2}: {:5} tiles ({:5} RTIN), {:9} triangles, {:10} bytes, bound {:9.3} m, \
             measured max {:9.3} m, {:7.2} s meshing, {:6.2} s writing",
            l.level,
            l.tiles,
            l.rtin_tiles,
            l.triangles,
            l.bytes,
            l.bound_m,
            l.max_measured_error_m,
            l.mesh_s,
            l.write_s
        );
    }
    println!(
        "{} tiles ({} decimated, {} retries, at most {} pending), {} triangles in {build_s:.2} s \
         on {} threads: {}",
        summary.tiles,
        summary.decimated_tiles,
        summary.retries,
        summary.peak_pending_tiles,
        summary.triangles,
        summary.threads,
        args.output.display()
    );
    Ok(())
}
