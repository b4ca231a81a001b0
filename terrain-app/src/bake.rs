//! `terrain bake`: a DEM (or a synthetic terrain streamed by rows) into an out-of-core block
//! store, with a plain-text progress bar on stderr, then the DSS paper's object-space errors
//! (`dss_errors.bin`, and per block in the index, unless `--no-dss`), the PVPS methods' roughness pyramids (`roughness.bin`,
//! unless `--no-roughness`; by bands of rows when the bake streams), geomorph's max-error
//! vertices per patch (`geomip.bin`, unless `--no-geomip`; computed by the bake with the
//! blocks, from the same bands of rows), the `tin` method's coarse tiles (`tin_tiles.bin`,
//! unless `--no-tin`; from the store's blocks, [`terrain_app::tin_scene`]) and the PVS files of the scene (`pvs.bin`,
//! `pvs_conservative.bin`, see `terrain pvs`): with `--pvs`, or where a spread sample of its
//! view cells says it pays (`crate::pvs::PVS_MIN_CULLED`); never with `--no-pvs`; and the
//! out-of-core method's calibration (`ooc-calibration.txt`, `terrain calibrate`) for grids of
//! more than `--calibrate-above` samples or with `--calibrate`.

use std::io::Write;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use terrain_core::dem::RowReader;
use terrain_core::quadtree::Quadtree;
use terrain_core::synth::FractalConfig;
use terrain_stream::{BakeConfig, BakeProgress, HeightEncoding, HeightSource};
use terrain_visibility::roughness::stream::RowGrid;

use crate::source::SourceArgs;
use terrain_app::methods::MethodConfig;

/// Largest synthetic side `terrain bake` holds in memory for the PVS, DSS errors and
/// roughness (a larger one is read by bands of rows: the DSS errors and roughness computed by
/// bands, the PVS against a coarse conservative grid).
const MAX_IN_MEMORY_SYNTHETIC: u64 = 8193;

/// Arguments of `terrain bake`.
#[derive(Debug, Args)]
pub(crate) struct BakeArgs {
    #[command(flatten)]
    pub source: SourceArgs,
    /// Output store folder.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Blocks of (2^K + 1)^2 vertices.
    #[arg(long, default_value_t = BakeConfig::default().k)]
    pub block_k: u8,
    /// Bake the synthetic fractal terrain of SIZE x SIZE samples (10 m) instead of a DEM,
    /// streamed by rows (e.g. 32769).
    #[arg(long)]
    pub synthetic: Option<u64>,
    /// Vertical error bound in metres for float sources (integer sources are lossless; not
    /// with --raw-f32).
    #[arg(long, default_value_t = 0.01, conflicts_with = "raw_f32")]
    pub max_error: f64,
    /// Store float heights as raw f32 instead.
    #[arg(long)]
    pub raw_f32: bool,
    /// Store levels uncompressed (fixed width) instead of the predictive codec with Deflate.
    #[arg(long)]
    pub no_compression: bool,
    /// Replace an existing store.
    #[arg(long)]
    pub overwrite: bool,
    /// Worker threads (0 = one per core).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Do not bake the scene's PVS, not even where it would pay (see --pvs).
    #[arg(long, conflicts_with = "force_pvs")]
    pub no_pvs: bool,
    /// Bake the scene's PVS (both files, sampled and conservative, written into the store
    /// folder after the blocks; see `terrain pvs`; read by `pvps-c-pvs` and `pvps-c-cons`)
    /// whatever it culls. By default it is baked only where it pays: when a spread sample of
    /// its view cells hides at least PVS_MIN_CULL_PCT % of the patches (see README.md,
    /// "Occlusion culling"); any `--pvs-*` option implies --pvs. Cells and patches are scaled
    /// to the grid (`--pvs-cells`, `--pvs-patch-level`). A grid read by rows gets its PVS from
    /// a coarse conservative version of it that fits a quarter of --max-memory (it never
    /// culls what the exact PVS sees; it culls less).
    #[arg(long = "pvs")]
    pub force_pvs: bool,
    /// Do not compute the DSS paper's 32 object-space errors per quadtree node
    /// (`dss_errors.bin`, read by `dss-1`, `dss-2` and `dss-strips` from the store; seconds
    /// per million samples on two cores) nor per block in the index (the library's
    /// `dss_errors` switch; `terrain info` then lists `dss errors: none` and those methods
    /// refuse the store).
    #[arg(long)]
    pub no_dss: bool,
    /// Do not compute the PVPS methods' roughness pyramids (`roughness.bin`, read by the
    /// `pvps-*` methods with `--scene`; computed by bands of rows, in bounded memory, when the
    /// bake streams).
    #[arg(long)]
    pub no_roughness: bool,
    /// Do not compute the geomorph method's max-error vertices per 16-cell patch
    /// (`geomip.bin`, 40 bytes per patch, read by `--method geomorph` from the store; computed
    /// with the blocks from the same bands of rows, and by each shard for its rows).
    #[arg(long)]
    pub no_geomip: bool,
    /// Do not build the tin method's coarse tiles (`tin_tiles.bin`: every tile spanning
    /// --tin-min-cells cells or more, built once from the store's blocks so that `--method
    /// tin` from the store reads them instead of meshing millions of samples while flying;
    /// they are then built while flying, as for a store baked before this file existed).
    #[arg(long)]
    pub no_tin: bool,
    /// Bake the tin method's tiles spanning at least this many cells (a power of two of at
    /// least 64). 64 bakes every tile, so `--method tin` never meshes while flying: a larger
    /// file and a longer bake (about the triangles of a full tileset).
    #[arg(long, value_name = "CELLS", default_value_t = terrain_app::tin_scene::BAKED_MIN_CELLS)]
    pub tin_min_cells: u32,
    #[command(flatten)]
    pub pvs: crate::pvs::PvsArgs,
    /// Read the DEM by bands of rows instead of whole (GeoTIFF and raw only): bounded memory
    /// for DEMs larger than memory. Automatic above --stream-above samples. Voids are then
    /// filled from the nearest valid samples along their row and column, not from the whole
    /// void's rim. (--synthetic is always streamed.)
    #[arg(long, conflicts_with = "synthetic")]
    pub stream: bool,
    /// Bake only shard K of N (K counts from 0): a contiguous range of block rows, into the
    /// part folder -o, with geomorph's table of its rows and no other scene table. `terrain
    /// bake` with the same DEM and options and `--merge` then joins the N parts into the store
    /// a single bake writes, byte for byte, and bakes the other tables. A part records the
    /// DEM's checksum and the options. The table options (--no-pvs, --no-roughness, --no-tin,
    /// --pvs-*) are accepted and apply to the merge, so shards and merge take one command line
    /// (--no-dss also drops the per-block errors the shards write into the index, --no-geomip
    /// the shards' geomorph tables).
    #[arg(long, value_name = "K/N", conflicts_with = "merge")]
    pub shard: Option<terrain_stream::Shard>,
    /// Join the parts of a sharded bake (part folders, or folders holding them) into the store
    /// -o, then bake the scene tables from the DEM (give the DEM and options of the shards:
    /// parts of another DEM or other options, missing or duplicated shards are refused).
    #[arg(long, value_name = "PART", num_args = 1..)]
    pub merge: Vec<PathBuf>,
    /// Write the out-of-core method's calibration (`ooc-calibration.txt`, see `terrain
    /// calibrate`) whatever the grid's size; by default only above --calibrate-above samples.
    #[arg(long, conflicts_with = "no_calibration")]
    pub calibrate: bool,
    /// Do not write the out-of-core method's calibration (`--error-px` then uses the shared
    /// one for this store).
    #[arg(long)]
    pub no_calibration: bool,
    /// Write the calibration for grids with more samples than this (default 2^22, 2049^2).
    #[arg(long, default_value_t = 1 << 22)]
    pub calibrate_above: u64,
    /// Stream GeoTIFF and raw DEMs with more samples than this (default 2^28: 1 GiB of f32), or
    /// whose whole read would need more than --max-memory.
    #[arg(long, default_value_t = 1 << 28, conflicts_with_all = ["stream", "synthetic"])]
    pub stream_above: u64,
}

/// The DEM opened for reading by rows, when `--stream` asks for it or the grid is larger
/// than `--stream-above` samples (GeoTIFF and raw files, one file; others are read whole).
fn streamed(args: &BakeArgs) -> anyhow::Result<Option<RowReader>> {
    let [path] = args.source.dem.as_slice() else {
        if args.stream && args.source.dem.len() > 1 {
            anyhow::bail!("--stream reads one DEM file, not a mosaic");
        }
        return Ok(None);
    };
    let options = args.source.load_options()?;
    match RowReader::open(path, &options) {
        // Also by rows when reading the whole file would pass --max-memory (12 bytes a sample
        // while decoding: float64 and its f32 copy, the most a GeoTIFF or raw file takes).
        Ok(r)
            if args.stream
                || r.width() * r.height() > args.stream_above
                || terrain_core::dem::bytes_to_read(r.width(), r.height(), 12)
                    > options.max_memory_bytes =>
        {
            Ok(Some(r))
        }
        Ok(_) => Ok(None),
        Err(e) if args.stream => Err(e.into()),
        // Not a streamable format (PNG, .hgt...) or unreadable: the whole-file reader says why.
        Err(_) => Ok(None),
    }
}

/// Whether the synthetic terrain of `n x n` samples is held in memory for the tables: it fits
/// ([`MAX_IN_MEMORY_SYNTHETIC`]) and the PVS or the DSS errors are baked (the exact PVS needs
/// the whole grid; the DSS errors and roughness are then computed from it in memory too,
/// faster than by rows); a larger one gets the PVS of a coarse conservative grid.
fn synthetic_held(args: &BakeArgs, n: u64) -> bool {
    n <= MAX_IN_MEMORY_SYNTHETIC && !(args.no_pvs && args.no_dss)
}

/// The synthetic terrain as a heightmap, its rows generated on every core
/// (`FractalConfig::to_heightmap`'s samples and georeference, bit for bit).
fn in_memory(synthetic: &FractalConfig) -> anyhow::Result<terrain_core::Heightmap> {
    let (w, h) = (synthetic.width() as usize, synthetic.height() as usize);
    let mut data = vec![0f32; w * h];
    let mut voids = vec![false; w * h];
    terrain_stream::read_rows_parallel(synthetic, 0, &mut data, &mut voids)?;
    drop(voids);
    let mask = terrain_core::heightmap::VoidMask::new(w, h);
    Ok(terrain_core::Heightmap::new(w, h, data, mask, synthetic.georef())?)
}

/// Runs `terrain bake`: into a local folder, or with `-o URL` (`s3://`, `gs://`, `az://`)
/// into a temporary folder, uploaded to the URL when complete (the index last) and removed.
pub(crate) fn run(args: &BakeArgs) -> anyhow::Result<()> {
    // Before any work: a bad --tin-min-cells would otherwise end a long bake.
    terrain_app::tin_scene::min_stride_for_cells(args.tin_min_cells)?;
    let Some(url) = terrain_app::ooc::store_url(&args.output) else {
        return run_into(args, &args.output, &args.output.display().to_string());
    };
    if args.shard.is_some() {
        anyhow::bail!(
            "--shard writes a part folder on this machine: give a local -o, then join the parts \
             with `terrain bake --merge PARTS -o {url}`"
        );
    }
    // Before any work, as for a local folder: a store at the URL is replaced only with
    // --overwrite, and a prefix holding other objects never.
    terrain_stream::check_remote_output(url, args.overwrite, &terrain_app::ooc::remote_options())?;
    let tmp = std::env::temp_dir().join(format!("terrain-bake-upload-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
    let local = tmp.join("store");
    let result = run_into(args, &local, url).and_then(|()| {
        let t = std::time::Instant::now();
        let r = terrain_stream::upload_store(&local, url, &terrain_app::ooc::remote_options())
            .with_context(|| format!("uploading the store to {url}"))?;
        println!(
            "{url}: uploaded {} files, {:.1} MiB ({} as multipart uploads), the index last, {:.1} s",
            r.files,
            r.bytes as f64 / terrain_app::MIB,
            r.multipart,
            t.elapsed().as_secs_f64()
        );
        Ok(())
    });
    let _ = std::fs::remove_dir_all(&tmp);
    result
}

/// `terrain bake` into the local folder `out` (every table and the blocks: one folder),
/// naming the output `shown` in messages.
fn run_into(args: &BakeArgs, out: &Path, shown: &str) -> anyhow::Result<()> {
    // Before any work: a file or a folder of the user's files is never replaced (a shard's
    // part folder is checked by its bake).
    if args.shard.is_none() {
        terrain_stream::check_output(out, args.overwrite)?;
    }
    if args.no_pvs
        && let Some(first) = args.pvs.given().first()
    {
        anyhow::bail!("{first} applies to the PVS, and --no-pvs bakes none");
    }
    // Ctrl-C / SIGTERM: checked after each row of blocks and between the tables.
    crate::interrupt::install()?;
    let mut stages = terrain_app::progress::Stages::new();
    let leaf = MethodConfig::default().leaf_cells;
    let bounded = HeightEncoding::Bounded { max_error_m: args.max_error };
    let mut config = BakeConfig {
        k: args.block_k,
        encoding: bounded,
        overwrite: args.overwrite,
        threads: args.threads,
        dss_errors: !args.no_dss,
        // Geomorph's table from the blocks' own bands of rows, in the same pass.
        geomip_patch_cells: (!args.no_geomip).then_some(leaf),
        ..BakeConfig::default()
    };
    if args.no_compression {
        config.codec = terrain_stream::Codec::Plain;
    }
    let synthetic;
    let synthetic_hm;
    let dem;
    let mut rows: Option<RowReader> = None;
    let mut source_hm: Option<&terrain_core::Heightmap> = None;
    let source: &dyn HeightSource = if let Some(n) = args.synthetic {
        synthetic = FractalConfig::with_size(n, n, 10.0);
        synthetic.validate().map_err(anyhow::Error::msg)?;
        if synthetic_held(args, n) && args.shard.is_none() && args.merge.is_empty() {
            // The tables will need the whole grid: generated once, and the blocks baked from it.
            synthetic_hm = in_memory(&synthetic)?;
            stages.end("grid in memory");
            source_hm = Some(&synthetic_hm);
            &synthetic_hm
        } else {
            &synthetic
        }
    } else if let Some(reader) = streamed(args)? {
        let options = args.source.load_options()?;
        eprintln!(
            "{}: {} x {} samples, read by bands of rows",
            reader.source().path.display(),
            reader.width(),
            reader.height()
        );
        config.encoding = HeightEncoding::for_source(reader.source(), &options);
        if matches!(config.encoding, HeightEncoding::Bounded { .. }) {
            config.encoding = bounded;
        }
        let g = reader.georef();
        crate::source::check_surface(
            &reader.source().path.display().to_string(),
            (reader.width(), reader.height()),
            g.spacing_m,
            None,
            g.crs == terrain_core::Crs::Unknown,
        )?;
        rows = Some(reader);
        rows.as_ref().expect("just set")
    } else {
        let options = args.source.load_options()?;
        dem = args.source.load_surface()?.context("give a DEM file or --synthetic SIZE")?;
        config.encoding = HeightEncoding::for_source(&dem.source, &options);
        if matches!(config.encoding, HeightEncoding::Bounded { .. }) {
            config.encoding = bounded;
        }
        source_hm = Some(&dem.heightmap);
        &dem.heightmap
    };
    if args.raw_f32 {
        config.encoding = HeightEncoding::F32;
    }
    if source_hm.is_some() && args.synthetic.is_none() {
        stages.end("read");
    }
    let start = std::time::Instant::now();
    let mut err = std::io::stderr();
    let terminal = terrain_app::progress::on_terminal();
    let mut quarter = 0;
    let mut bar = |p: &BakeProgress| {
        let frac = p.blocks_done as f64 / p.blocks_total.max(1) as f64;
        let filled = (frac * 40.0).round() as usize;
        let line = format!(
            "{:5.1}% {}/{} blocks, {:.1} MiB written, {:.0} s",
            frac * 100.0,
            p.blocks_done,
            p.blocks_total,
            p.bytes_written as f64 / terrain_app::MIB,
            start.elapsed().as_secs_f64()
        );
        if terminal {
            let _ = write!(err, "\r[{}{}] {line}", "#".repeat(filled), " ".repeat(40 - filled));
        } else if (frac * 4.0) as u32 > quarter {
            // A log: a plain line at each quarter, no carriage returns.
            quarter = (frac * 4.0) as u32;
            let _ = writeln!(err, "blocks: {line}");
        }
        let _ = err.flush();
        if crate::interrupt::interrupted() {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    };
    if let Some(shard) = args.shard {
        return crate::shard::run_shard(args, source, &config, shard, rows.is_some(), &mut bar);
    }
    let report =
        match crate::shard::bake_or_merge(args, out, source, &config, rows.is_some(), &mut bar)? {
            // The library removed its `.NAME.part` folder; an existing store was not touched.
            Err(terrain_stream::BakeError::Cancelled) => {
                return Err(crate::interrupt::Interrupted(format!(
                    "no store written, {shown} is as it was"
                ))
                .into());
            }
            r => r.with_context(|| format!("baking {shown}"))?,
        };
    // After the blocks the store is complete: an interruption stops before the next table.
    let stop_before = |table: &str| -> anyhow::Result<()> {
        if crate::interrupt::interrupted() {
            return Err(crate::interrupt::Interrupted(format!(
                "the store {shown} is written, without its {table} and the tables after it: bake \
                 again with --overwrite for them"
            ))
            .into());
        }
        Ok(())
    };
    if terminal {
        eprintln!();
    }
    for w in rows.as_ref().map(RowReader::warnings).unwrap_or_default() {
        eprintln!("warning: {w}");
    }
    if let Some(zero) = rows.as_ref().map(RowReader::zero_filled).filter(|&z| z > 0) {
        eprintln!(
            "warning: {zero} void samples had no valid sample in their row or within {} rows of their column: set to 0 m",
            terrain_core::dem::rows::FILL_REACH_ROWS
        );
    }
    let (_, blocks_cpu) =
        stages.end(if args.merge.is_empty() { "blocks" } else { "merge of the parts" });
    let h = &report.header;
    let secs = report.elapsed.as_secs_f64();
    println!(
        "{}: {} x {} samples in {} x {} blocks of {}^2, {:.1} MiB ({:.2} bytes/sample), {}, {:.1} s, {:.1} MiB/s of f32 input",
        shown,
        h.width,
        h.height,
        h.blocks_x,
        h.blocks_y,
        h.block_side(),
        report.store_bytes as f64 / terrain_app::MIB,
        report.store_bytes as f64 / report.source_samples as f64,
        if report.lossless {
            "lossless".to_string()
        } else {
            format!("max vertical error {:.4} m", h.max_error_m)
        },
        secs,
        report.source_samples as f64 * 4.0 / terrain_app::MIB / secs.max(1e-9)
    );
    if let Some(cpu) = blocks_cpu.filter(|_| args.merge.is_empty()) {
        println!(
            "blocks: {:.1} CPU s, {:.1} MiB/s of f32 input per CPU second",
            cpu,
            report.source_samples as f64 * 4.0 / terrain_app::MIB / cpu.max(1e-9)
        );
    }
    if let Some(bytes) = report.geomip_bytes {
        println!(
            "{}: geomorph's max-error vertices of {leaf}-cell patches, computed with the blocks \
             from the same bands of rows, {:.2} MiB",
            terrain_app::geomip_scene::geomip_path(out).display(),
            bytes as f64 / terrain_app::MIB
        );
    }
    let merged_hm;
    let hm = match (source_hm, args.synthetic) {
        (Some(hm), _) => Some(hm),
        (None, Some(n)) if synthetic_held(args, n) => {
            // A merge of a synthetic terrain that fits (a single bake generated it above).
            merged_hm = in_memory(&FractalConfig::with_size(n, n, 10.0))?;
            stages.end("grid in memory");
            Some(&merged_hm)
        }
        (None, _) => None,
    };
    // The grid by bands of rows, when it is not in memory: the DEM's rows again, or the
    // synthetic terrain generated again, each band in chunks of rows on every core.
    let read = |j0: usize, n: usize, heights: &mut [f32], voids: &mut [bool]| {
        debug_assert_eq!(heights.len(), n * source.width() as usize);
        terrain_stream::read_rows_parallel(source, j0 as u64, heights, voids)?;
        anyhow::Ok(())
    };
    if !args.no_roughness {
        stop_before("roughness pyramids")?;
        // The benchmark's default leaf size (the pyramids' levels are the quadtree's).
        match hm {
            Some(hm) => terrain_app::roughness_scene::bake_from_heightmap(hm, leaf, out, true)?,
            None => {
                let grid = RowGrid {
                    width: source.width() as usize,
                    height: source.height() as usize,
                    spacing_m: source.georef().spacing_m,
                };
                terrain_app::roughness_scene::bake_by_rows(&grid, leaf, out, true, read)?
            }
        }
        stages.end("roughness");
    }
    if !args.no_geomip && report.geomip_bytes.is_none() {
        stop_before("geomorph table")?;
        match hm {
            Some(hm) => {
                terrain_app::geomip_scene::bake_into_scene(hm, leaf, out)?;
            }
            // Geomorph's table needs only a band of rows: from the store's blocks.
            None => {
                let store =
                    terrain_stream::Store::open(out).with_context(|| format!("opening {shown}"))?;
                terrain_app::geomip_scene::bake_from_store(&store, leaf)?;
            }
        }
        stages.end("geomorph");
    }
    if !args.no_tin {
        stop_before("tin tiles")?;
        // From the store's blocks and its table of decimation errors, as `tin` builds them
        // while flying: every tile of --tin-min-cells (512) cells or more across.
        let store = terrain_stream::Store::open(out).with_context(|| format!("opening {shown}"))?;
        let min_stride_log2 = terrain_app::tin_scene::min_stride_for_cells(args.tin_min_cells)?;
        if let Some(r) = terrain_app::tin_scene::bake_tiles(&store, min_stride_log2, true)? {
            println!("{}", r.line(out));
        }
        stages.end("tin tiles");
    }
    if !args.no_dss {
        stop_before("DSS errors")?;
        // The benchmark's default leaf size; a table serves any coarser leaf size too.
        match hm {
            Some(hm) => {
                let qt = Quadtree::new(hm, leaf);
                terrain_app::dss_scene::bake_into_scene(hm, &qt, out)?;
            }
            // From the same rows as the roughness (the source's heights, bit for bit the table
            // the grid in memory gives), a band at a time.
            None => {
                let (w, h) = (source.width() as u32, source.height() as u32);
                let band_bytes = args.source.load_options()?.max_memory_bytes / 4;
                terrain_app::dss_scene::bake_by_rows(w, h, leaf, band_bytes, out, true, read)?;
            }
        }
        stages.end("DSS errors");
    }
    if !args.no_calibration && (args.calibrate || h.width * h.height > args.calibrate_above) {
        stop_before("ooc calibration")?;
        let options = terrain_app::ooc_calibration::CalibrateOptions::default();
        let config = terrain_app::ooc::OocConfig::default();
        // The store is complete without it: a terrain the measurement cannot fit (drawn
        // exactly at every tau) keeps the shared calibration, said as a warning.
        if let Err(e) = crate::calibrate::calibrate_and_write(&args.output, None, &config, &options)
        {
            eprintln!(
                "warning: no ooc calibration written ({e:#}): --error-px uses the shared one"
            );
        }
        stages.end("ooc calibration");
    }
    if args.no_pvs {
        println!("{}", stages.summary());
        return Ok(());
    }
    // `--pvs` or any `--pvs-*` option: baked whatever it culls; otherwise where it pays.
    let when = if args.force_pvs || !args.pvs.given().is_empty() {
        crate::pvs::When::Always
    } else {
        crate::pvs::When::IfItPays
    };
    let (w, h) = (source.width() as usize, source.height() as usize);
    let cfg = args.pvs.config(w as u32, h as u32)?;
    stop_before("PVS")?;
    let Some(hm) = hm else {
        // The grid is not in memory: the PVS against a coarse conservative version of it,
        // gathered by bands of rows (the DEM's rows again, or the synthetic terrain generated
        // again) in a quarter of --max-memory.
        let georef = source.georef();
        let budget = args.source.load_options()?.max_memory_bytes / 4;
        crate::pvs::bake_by_rows_into_scene((w, h, &georef), &cfg, budget, out, when, read)?;
        stages.end("PVS");
        println!("{}", stages.summary());
        return Ok(());
    };
    crate::pvs::bake_into_scene(hm, &cfg, out, when)?;
    stages.end("PVS");
    println!("{}", stages.summary());
    Ok(())
}
