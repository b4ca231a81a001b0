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

use std::path::PathBuf;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::{Context, bail};
use clap::Args;
use glam::dvec2;
use rayon::prelude::*;
use serde::Serialize;
use terrain_core::tin::{self, GeoGrid, TileId, TileRange, quantized_mesh, warp};
use terrain_core::{Crs, Heightmap};

use terrain_app::progress::Progress;

use crate::source::SourceArgs;

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
    bytes: u64,
    /// The largest error measured against the DEM samples of a tile of this level, metres.
    max_measured_error_m: f64,
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

/// Runs `terrain tiles`.
pub(crate) fn run(args: &TilesArgs) -> anyhow::Result<()> {
    if !(args.error_scale.is_finite() && args.error_scale > 0.0) {
        bail!("--error-scale must be a positive number, got {}", args.error_scale);
    }
    let (hm, name) = match args.source.load_surface()? {
        Some(dem) => (dem.heightmap, dem.source.path.display().to_string()),
        None => (terrain_core::synth::default_terrain(), "the embedded synthetic terrain".into()),
    };
    let (width, height) = (hm.width(), hm.height());
    let (hm, reprojected_from) = geographic(args, hm)?;
    let grid = GeoGrid::new(&hm)?;
    let max_level = args.max_level.unwrap_or_else(|| grid.native_level(64.0));
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
            grid.tile_range(level)
        }
    };
    let tiles: Vec<TileId> =
        levels.clone().flat_map(|l| range(l).tiles(l).collect::<Vec<_>>()).collect();
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("creating {}", args.output.display()))?;
    let t0 = Instant::now();
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
    tiles.par_iter().try_for_each(|&tile| -> anyhow::Result<()> {
        let bound = tin::level_error(tile.level, args.error_scale);
        let mesh = tin::build_tile(&grid, tile, bound)?;
        let children =
            if tile.level < max_level { range(tile.level + 1).below(tile) } else { None };
        let mut bytes = quantized_mesh::encode(&mesh, children)
            .with_context(|| format!("encoding tile {}/{}/{}", tile.level, tile.x, tile.y))?;
        if args.gzip {
            bytes = quantized_mesh::gzip(&bytes);
        }
        let dir = args.output.join(tile.level.to_string()).join(tile.x.to_string());
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        let path = dir.join(format!("{}.terrain", tile.y));
        std::fs::write(&path, &bytes).with_context(|| format!("writing {}", path.display()))?;
        {
            let mut s = stats.lock().unwrap_or_else(|e| e.into_inner());
            let s = &mut s[(tile.level - args.min_level) as usize];
            s.tiles += 1;
            s.triangles += mesh.triangles.len();
            s.vertices += mesh.vertices.len();
            s.bytes += bytes.len() as u64;
            if let Some(m) = mesh.measured {
                s.max_measured_error_m = s.max_measured_error_m.max(m.max_error);
            }
        }
        let n = done.fetch_add(1, Ordering::Relaxed) + 1;
        bar.update(n as f64, tiles.len() as f64);
        Ok(())
    })?;
    bar.finish();
    let build_s = t0.elapsed().as_secs_f64();
    let available: Vec<Vec<TileRange>> = (0..=max_level)
        .map(|l| if l < args.min_level { Vec::new() } else { vec![range(l)] })
        .collect();
    let extent = grid.extent();
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
        "available": available,
    });
    let layer_path = args.output.join("layer.json");
    std::fs::write(&layer_path, serde_json::to_string_pretty(&layer)?)
        .with_context(|| format!("writing {}", layer_path.display()))?;
    let levels = stats.into_inner().unwrap_or_else(|e| e.into_inner());
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
        tiles: tiles.len(),
        triangles: levels.iter().map(|l| l.triangles).sum(),
        build_s,
        threads: rayon::current_num_threads(),
        levels,
    };
    let summary_path = args.output.join("tiles.json");
    std::fs::write(&summary_path, serde_json::to_string_pretty(&summary)?)
        .with_context(|| format!("writing {}", summary_path.display()))?;
    for l in &summary.levels {
        println!(
            "level {:2}: {:5} tiles, {:8} triangles, bound {:9.3} m, measured max {:9.3} m",
            l.level, l.tiles, l.triangles, l.bound_m, l.max_measured_error_m
        );
    }
    println!(
        "{} tiles, {} triangles in {build_s:.2} s on {} threads: {}",
        summary.tiles,
        summary.triangles,
        summary.threads,
        args.output.display()
    );
    Ok(())
}
