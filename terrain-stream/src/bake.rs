//! The bake: a [`HeightSource`] streamed by bands of block rows into a store folder, blocks
//! encoded in parallel (rayon), written under a temporary name and renamed when complete.
//!
//! Memory: one band of `2^k + 1` source rows (f32 and a void flag per sample) plus, per
//! worker thread, one block's samples, its static-error pyramid and its payloads. Nothing of
//! the whole grid is allocated, so a 32769^2 float grid (4 GiB) bakes in a few hundred MiB.
//! With [`BakeConfig::geomip_patch_cells`], geomorph's table is computed from each band beside
//! its blocks (one more copy of the band, as a heightmap) and written into the store's
//! [`GEOMIP_FILE`] as the pass goes (`GeomipOut`), so it is never held whole (it is 40 bytes
//! per 16-cell patch: 168 MB at 32769^2): memory holds one band's table. The index's block
//! entries (7.3 KB a block with 5 node levels) go to disk as each band's blocks finish
//! ([`crate::entries::EntryFile`]), the index's header last, so memory holds one band's entries,
//! not the index (120 MB at 32769^2).

use std::fs;
use std::io::{Seek, SeekFrom, Write};
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use rayon::prelude::*;
use terrain_core::dem::{Format, LoadOptions, RawSampleType, RowReader, SourceInfo};
use terrain_core::georef::Georef;
use terrain_core::heightmap::{Heightmap, VoidMask};
use terrain_core::lod::dss_file::HeightsChecksum;
use terrain_core::lod::{GeomipEncoder, GeomipTable};
use terrain_core::metrics::Region;
use terrain_core::metrics::dss::object_errors;
use terrain_core::metrics::static_error::StaticErrorPyramid;

use crate::codec::encode_level;
use crate::decimation::{DecimationOut, block_errors};
use crate::entries::EntryFile;
use crate::error::BakeError;
use crate::format::{
    BLOCK_HEADER_LEN, BlockEntry, BlockId, Codec, DSS_FACTORS, DssBlockErrors, Header, INDEX_FILE,
    K_RANGE, LevelEntry, NodeValues, Quantizer, SampleEncoding, block_file_name, block_header,
    crc32, fine_count, node_count,
};
use crate::source::HeightSource;

/// How heights are stored.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HeightEncoding {
    /// Integer steps: `height = offset_m + q * step_m`. Lossless for sources whose heights lie
    /// on that lattice (integer DEMs, scaled grey images); the bake measures and records the
    /// largest difference, so a store says whether it is lossless.
    Quantized {
        /// Metres per step.
        step_m: f64,
        /// Height of step 0.
        offset_m: f64,
    },
    /// Float sources: quantized with a step of `1.8 * max_error_m`, and the bake verifies that
    /// no non-void sample moves by more than `max_error_m` (it fails otherwise).
    Bounded {
        /// The vertical error bound, metres.
        max_error_m: f64,
    },
    /// Raw IEEE f32 bits, 4 bytes a sample (no compression).
    F32,
}

impl Default for HeightEncoding {
    /// `Bounded { max_error_m: 0.01 }`: 1 cm.
    fn default() -> Self {
        HeightEncoding::Bounded { max_error_m: 0.01 }
    }
}

impl HeightEncoding {
    /// The lossless encoding for a DEM's source precision: integer samples (GeoTIFF and .hgt
    /// int16/int32/uint16, raw i16/u16) and 8/16-bit images map to their integer lattice; float
    /// sources get the default bound.
    pub fn for_source(info: &SourceInfo, options: &LoadOptions) -> Self {
        let integer = info.sample_type.starts_with("int") || info.sample_type.starts_with("uint");
        let scaled = || HeightEncoding::Quantized {
            step_m: options.vertical_scale,
            offset_m: options.vertical_offset,
        };
        match info.format {
            Format::GreyImage => scaled(),
            Format::TerrainRgb => HeightEncoding::Quantized { step_m: 0.1, offset_m: -10000.0 },
            Format::Terrarium => {
                HeightEncoding::Quantized { step_m: 1.0 / 256.0, offset_m: -32768.0 }
            }
            Format::Raw => match options.raw.map(|r| r.sample) {
                Some(RawSampleType::I16 | RawSampleType::U16) => scaled(),
                _ => HeightEncoding::default(),
            },
            // Integer GeoTIFF and .hgt samples, through their scale and offset (GDAL's band
            // scale/offset, a --vertical-scale): on that lattice.
            _ if integer && info.vertical.0.is_finite() && info.vertical.1.is_finite() => {
                HeightEncoding::Quantized { step_m: info.vertical.0, offset_m: info.vertical.1 }
            }
            _ => HeightEncoding::default(),
        }
    }
}

/// Parameters of a bake.
#[derive(Debug, Clone, PartialEq)]
pub struct BakeConfig {
    /// Blocks are `(2^k + 1)^2` vertices, `k` in 2..=12. Default 8 (257^2, chosen by the
    /// stream bench; the paper used k = 10, 1025^2). A grid smaller than one block gets the
    /// smallest `k` whose block covers it (the store's quadtree is then the heightmap's); the
    /// header records the `k` used.
    pub k: u8,
    /// How heights are stored. Default: 1 cm bound.
    pub encoding: HeightEncoding,
    /// Payload codec. Default [`Codec::PredictiveDeflate`] (lossless; chosen by measurement).
    pub codec: Codec,
    /// Quadtree levels of per-node min/max/static error stored per block (clamped to `k`).
    /// Default 5 (1365 nodes, 16 KiB a block); deeper nodes use the per-level bounds.
    pub node_levels: u8,
    /// Worker threads; 0 = rayon's global pool (one per core). Default 0.
    pub threads: usize,
    /// Replace an existing output folder. Default false.
    pub overwrite: bool,
    /// Compute the DSS paper's 32 object-space errors of every block into the index. Default
    /// true; false skips them (most of a bake's CPU after the heights; no method reads them
    /// from the index) and the store says so (`Store::has_dss_errors`).
    pub dss_errors: bool,
    /// Compute geomorph's per-patch table (terrain-core's `GeomipTable`, patches of this many
    /// cells, rounded as it rounds them) from the bake's own bands of source rows, in the same
    /// pass as the blocks, and write it into the store as [`GEOMIP_FILE`] (tied to the source
    /// heights' checksum, `heights_checksum`): the bytes of `GeomipTable::new` of the whole
    /// grid, without reading the grid again. Not computed (`BakeReport::geomip_bytes` is
    /// `None`) when the blocks are smaller than a patch. Default `None`.
    pub geomip_patch_cells: Option<u32>,
}

/// Geomorph's table in a store folder ([`BakeConfig::geomip_patch_cells`]).
pub const GEOMIP_FILE: &str = "geomip.bin";

impl Default for BakeConfig {
    fn default() -> Self {
        Self {
            k: 8,
            encoding: HeightEncoding::default(),
            codec: Codec::PredictiveDeflate,
            node_levels: 5,
            threads: 0,
            overwrite: false,
            dss_errors: true,
            geomip_patch_cells: None,
        }
    }
}

/// Where a bake is, for progress bars.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BakeProgress {
    /// Blocks written.
    pub blocks_done: usize,
    /// Blocks in the store.
    pub blocks_total: usize,
    /// Source rows read so far (shared border rows count twice).
    pub rows_read: u64,
    /// Bytes written so far.
    pub bytes_written: u64,
}

/// What a finished bake did.
#[derive(Debug, Clone)]
pub struct BakeReport {
    /// The store's header.
    pub header: Header,
    /// Total bytes of the store (index and block files).
    pub store_bytes: u64,
    /// Bytes of the index file.
    pub index_bytes: u64,
    /// Source samples (`width * height`).
    pub source_samples: u64,
    /// Wall time.
    pub elapsed: Duration,
    /// Whether every non-void sample is stored bit-exactly.
    pub lossless: bool,
    /// Bytes of the [`GEOMIP_FILE`] written with the blocks ([`BakeConfig::geomip_patch_cells`]).
    pub geomip_bytes: Option<u64>,
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> BakeError + '_ {
    move |cause| BakeError::Io { path: path.to_path_buf(), cause }
}

/// Bakes `source` into the store folder `out`.
///
/// Writes to `.<name>.part` beside `out` and renames it to `out` only when the index (written
/// last) is complete, so an interrupted or failed bake never leaves a store that reads as
/// valid. `progress` is called after each row of blocks; returning `ControlFlow::Break(())`
/// cancels ([`BakeError::Cancelled`]). The output is deterministic: the same input and config
/// give the same bytes.
pub fn bake(
    source: &dyn HeightSource,
    out: &Path,
    config: &BakeConfig,
    progress: &mut (dyn FnMut(&BakeProgress) -> ControlFlow<()> + Send),
) -> Result<BakeReport, BakeError> {
    let start = Instant::now();
    let plan = Plan::new(source, config)?;
    publish(out, config.overwrite, config.threads, crate::store::is_store, |tmp| {
        let index = index_file(tmp, &plan.header(source))?;
        let rows = bake_rows(source, tmp, &plan, config, 0..plan.blocks_y, index, progress)?;
        finish(tmp, rows, start)
    })
}

/// Runs `work` on a fresh temporary folder beside `out` (on `threads` workers, 0 = rayon's
/// global pool) and renames it to `out` when it succeeds; removes it when it fails. An existing
/// `out` is replaced only with `overwrite` and only when `is_ours` says it is what this kind
/// of bake writes ([`check_output`]).
pub(crate) fn publish<T: Send>(
    out: &Path,
    overwrite: bool,
    threads: usize,
    is_ours: fn(&Path) -> bool,
    work: impl FnOnce(&Path) -> Result<T, BakeError> + Send,
) -> Result<T, BakeError> {
    check_output_of(out, overwrite, is_ours)?;
    let tmp = part_dir(out)?;
    // A `.NAME.part` folder is ours: left by a killed bake of the same output.
    if tmp.is_dir() {
        fs::remove_dir_all(&tmp).map_err(io_err(&tmp))?;
    }
    fs::create_dir_all(tmp.join("blocks")).map_err(|e| {
        let _ = fs::remove_dir_all(&tmp);
        io_err(&tmp)(e)
    })?;
    let run = || work(&tmp);
    let result = if threads > 0 {
        match rayon::ThreadPoolBuilder::new().num_threads(threads).build() {
            Ok(pool) => pool.install(run),
            Err(e) => Err(BakeError::InvalidConfig(format!("thread pool: {e}"))),
        }
    } else {
        run()
    };
    let report = match result {
        Ok(r) => r,
        Err(e) => {
            let _ = fs::remove_dir_all(&tmp);
            return Err(e);
        }
    };
    // Checked again: the output may have appeared while we baked.
    let replaced = check_output_of(out, overwrite, is_ours)
        .and_then(
            |()| if out.exists() { fs::remove_dir_all(out).map_err(io_err(out)) } else { Ok(()) },
        )
        .and_then(|()| fs::rename(&tmp, out).map_err(io_err(out)));
    if let Err(e) = replaced {
        let _ = fs::remove_dir_all(&tmp);
        return Err(e);
    }
    Ok(report)
}

/// The temporary folder a bake of `out` writes to: `.NAME.part` beside it.
fn part_dir(out: &Path) -> Result<PathBuf, BakeError> {
    let name = out
        .file_name()
        .ok_or_else(|| BakeError::InvalidConfig(format!("{} has no file name", out.display())))?;
    Ok(out.with_file_name(format!(".{}.part", name.to_string_lossy())))
}

/// Checks, before any work, that a bake may write the store folder `out`: it does not exist,
/// or it is an empty folder, or it is a store ([`crate::is_store`]) and `overwrite`
/// is set. A file, or a folder that is not a store, is refused whatever `overwrite` says
/// ([`BakeError::NotAStore`]): it may hold the user's files.
pub fn check_output(out: &Path, overwrite: bool) -> Result<(), BakeError> {
    check_output_of(out, overwrite, crate::store::is_store)
}

/// [`check_output`] for an output that `is_ours` recognises (a store, a shard's part).
pub(crate) fn check_output_of(
    out: &Path,
    overwrite: bool,
    is_ours: fn(&Path) -> bool,
) -> Result<(), BakeError> {
    part_dir(out)?;
    let Ok(meta) = fs::metadata(out) else {
        // Nothing there (or a dangling link, which the rename replaces).
        return Ok(());
    };
    let not_a_store =
        |what: &str| BakeError::NotAStore { path: out.to_path_buf(), what: what.into() };
    // A folder, or a link to one.
    if !out.is_dir() {
        return Err(not_a_store(if meta.is_file() {
            "is a file, not a store folder"
        } else {
            "exists and is not a folder"
        }));
    }
    let empty = fs::read_dir(out).map(|mut d| d.next().is_none()).unwrap_or(false);
    if empty {
        return Ok(());
    }
    if !is_ours(out) {
        return Err(not_a_store("is a folder that is not a store"));
    }
    if !overwrite {
        return Err(BakeError::Exists { path: out.to_path_buf() });
    }
    Ok(())
}

/// Quantization parameters in force.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Quant {
    encoding: SampleEncoding,
    bound: Option<f64>,
}

/// What encoding one block produced.
struct BakedBlock {
    entry: BlockEntry,
    max_err: f64,
    max_void_err: f64,
    lossless: bool,
    /// Its decimation errors (`decimation.bin`), stride `2^1` first.
    decimation: Vec<f32>,
}

/// Samples above which [`bake_file`] reads a GeoTIFF or raw file by bands of rows: 2^28 (1 GiB
/// of f32), the `terrain bake` default.
pub const STREAM_ABOVE_SAMPLES: u64 = 1 << 28;

/// Bakes the DEM file `path` into a store at `out` in one call: the embedder's entry point.
/// Any format terrain-core reads (GeoTIFF, SRTM .hgt, grey and Terrain-RGB/Terrarium images,
/// raw with `options.raw`), read as `options` says (no-data, vertical scale, spacing). GeoTIFF
/// and raw files larger than [`STREAM_ABOVE_SAMPLES`] are read by bands of rows (memory stays
/// bounded whatever the file's size; voids are then filled along rows and columns, see
/// `terrain_core::dem::rows`); others are read whole. Integer sources are stored losslessly
/// (their lattice, [`HeightEncoding::for_source`]); float sources with `config.encoding`.
pub fn bake_file(
    path: &Path,
    options: &LoadOptions,
    out: &Path,
    config: &BakeConfig,
    progress: &mut (dyn FnMut(&BakeProgress) -> ControlFlow<()> + Send),
) -> Result<BakeReport, BakeError> {
    let lossless =
        |info: &SourceInfo, config: &BakeConfig| match HeightEncoding::for_source(info, options) {
            q @ HeightEncoding::Quantized { .. } => BakeConfig { encoding: q, ..config.clone() },
            _ => config.clone(),
        };
    if let Ok(rows) = RowReader::open(path, options)
        && rows.width() * rows.height() > STREAM_ABOVE_SAMPLES
    {
        let config = lossless(rows.source(), config);
        return bake(&rows, out, &config, progress);
    }
    let dem = terrain_core::dem::load(path, options)?;
    let config = lossless(&dem.source, config);
    bake(&dem.heightmap, out, &config, progress)
}

/// The block exponent of a `w x h` grid: `k`, or smaller for a grid smaller than one block, so
/// that the store's quadtree is the heightmap's (its root the next power of two of cells at or
/// above the larger side; a block larger than that root would give the tree a larger root and
/// other node ids). At least the smallest block of [`K_RANGE`]. The header records the `k` used.
pub(crate) fn block_k(k: u8, w: u64, h: u64) -> u8 {
    let cells = (w.max(h).max(2) - 1).next_power_of_two();
    k.min(cells.trailing_zeros() as u8).max(*K_RANGE.start())
}

/// The block grid and quantization of a bake: what every shard of it must agree on.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Plan {
    pub k: u8,
    pub blocks_x: u64,
    pub blocks_y: u64,
    width: usize,
    node_levels: u8,
    quant: Quant,
    codec: Codec,
    /// Geomorph's patch cells, when its table is computed in the pass (they divide a block).
    pub geomip: Option<u32>,
}

impl Plan {
    /// Checks the config and the source's size, and lays out the blocks.
    pub(crate) fn new(source: &dyn HeightSource, config: &BakeConfig) -> Result<Self, BakeError> {
        if !K_RANGE.contains(&config.k) {
            return Err(BakeError::InvalidConfig(format!(
                "k = {} is outside {K_RANGE:?}",
                config.k
            )));
        }
        match config.encoding {
            HeightEncoding::Quantized { step_m, offset_m }
                if !(step_m.is_finite() && step_m > 0.0 && offset_m.is_finite()) =>
            {
                return Err(BakeError::InvalidConfig(format!(
                    "quantization step {step_m} / offset {offset_m}"
                )));
            }
            HeightEncoding::Bounded { max_error_m }
                if !(max_error_m.is_finite() && max_error_m > 0.0) =>
            {
                return Err(BakeError::InvalidConfig(format!("error bound {max_error_m} m")));
            }
            _ => {}
        }
        let (w, h) = (source.width(), source.height());
        if w == 0 || h == 0 {
            return Err(BakeError::InvalidConfig(format!("empty source ({w} x {h})")));
        }
        let k = block_k(config.k, w, h);
        let cells = 1u64 << k;
        let blocks_x = (w - 1).div_ceil(cells).max(1);
        let blocks_y = (h - 1).div_ceil(cells).max(1);
        if blocks_x > u32::MAX as u64 || blocks_y > u32::MAX as u64 {
            return Err(BakeError::InvalidConfig("too many blocks".into()));
        }
        let width =
            usize::try_from(w).map_err(|_| BakeError::InvalidConfig("width too large".into()))?;
        let quant = match config.encoding {
            HeightEncoding::Quantized { step_m, offset_m } => {
                Quant { encoding: SampleEncoding::Quantized { step_m, offset_m }, bound: None }
            }
            HeightEncoding::Bounded { max_error_m } => Quant {
                encoding: SampleEncoding::Quantized { step_m: 1.8 * max_error_m, offset_m: 0.0 },
                bound: Some(max_error_m),
            },
            HeightEncoding::F32 => Quant { encoding: SampleEncoding::F32, bound: None },
        };
        let geomip = config
            .geomip_patch_cells
            .map(GeomipTable::patch_cells_for)
            .filter(|&p| u64::from(p) <= cells);
        let node_levels = config.node_levels.min(k);
        Ok(Self { k, blocks_x, blocks_y, width, node_levels, quant, codec: config.codec, geomip })
    }

    /// The store's header before its blocks are baked: errors and bake id 0.
    pub(crate) fn header(&self, source: &dyn HeightSource) -> Header {
        Header {
            width: source.width(),
            height: source.height(),
            k: self.k,
            blocks_x: self.blocks_x as u32,
            blocks_y: self.blocks_y as u32,
            encoding: self.quant.encoding,
            codec: self.codec,
            max_error_m: 0.0,
            max_void_error_m: 0.0,
            error_bound_m: 0.0,
            node_levels: self.node_levels,
            georef: source.georef(),
            bake_id: 0,
            vertical_scale: 1.0,
        }
    }
}

/// The store's index in `dir`, to be written entry by entry as the blocks finish (its header,
/// whose length `header` gives, is written last, by [`finish`]).
pub(crate) fn index_file(dir: &Path, header: &Header) -> Result<EntryFile, BakeError> {
    EntryFile::create_index(dir.join(INDEX_FILE), header)
}

/// Blocks baked for some rows of the block grid: their entries (row-major, written into a file
/// as they were baked) and what their encoding measured. The header's `bake_id` is 0 and its
/// error fields are these rows' own: [`finish`] sets them for the whole store.
#[derive(Debug)]
pub(crate) struct BakedRows {
    pub header: Header,
    pub entries: EntryFile,
    pub lossless: bool,
    /// The error bound the encoding promised (`HeightEncoding::Bounded`), metres.
    pub bound: Option<f64>,
    /// Geomorph's table of these rows ([`Plan::geomip`]): the file its bands' tables are
    /// written into as they are computed, and the checksum of the rows' source heights, each
    /// row once (a shared top row belongs to the rows above).
    pub geomip: Option<(GeomipOut, HeightsChecksum)>,
    /// The blocks' decimation errors, written as they were baked (`None`: a merge of parts
    /// without them, and then no table).
    pub decimation: Option<DecimationOut>,
}

/// Bakes block rows `rows` (a range of `0..plan.blocks_y`) of `source` into `dir/blocks`, their
/// block files with a bake id of 0 (patched by [`finish`]), and their entries into `entries`
/// band by band (memory holds one band's entries).
pub(crate) fn bake_rows(
    source: &dyn HeightSource,
    dir: &Path,
    plan: &Plan,
    config: &BakeConfig,
    rows: std::ops::Range<u64>,
    mut entries: EntryFile,
    progress: &mut (dyn FnMut(&BakeProgress) -> ControlFlow<()> + Send),
) -> Result<BakedRows, BakeError> {
    let h = source.height();
    let Plan { k, blocks_x, width, node_levels, quant, geomip: patch, .. } = *plan;
    let cells = 1u64 << k;
    let side = cells as usize + 1;
    let total = (blocks_x * (rows.end - rows.start)) as usize;
    let mut band = vec![0f32; if total == 0 { 0 } else { width * side }];
    let mut voids = vec![false; band.len()];
    let (mut max_err, mut max_void_err, mut lossless) = (0f64, 0f64, true);
    let mut prog =
        BakeProgress { blocks_done: 0, blocks_total: total, rows_read: 0, bytes_written: 0 };
    let mut geomip = patch.map(|_| (GeomipOut::new(dir), HeightsChecksum::new()));
    let mut decimation = DecimationOut::create(dir, k)?;
    for by in rows {
        let j0 = by * cells;
        let rows = (h - j0).min(side as u64) as usize;
        let band = &mut band[..width * rows];
        let voids = &mut voids[..width * rows];
        // Read the band in parallel chunks of rows, heights and void flags in one read.
        crate::source::read_rows_parallel(source, j0, band, voids)?;
        if let Some(p) = band.iter().position(|z| !z.is_finite()) {
            return Err(BakeError::Encoding(format!(
                "sample ({}, {}) is not finite",
                p % width,
                j0 + (p / width) as u64
            )));
        }
        prog.rows_read += rows as u64;
        let band: &[f32] = band;
        let voids: &[bool] = voids;
        // The blocks and, beside them on the same threads, the band's geomorph patches.
        let blocks = || {
            (0..blocks_x as u32)
                .into_par_iter()
                .map(|bx| {
                    let id = BlockId::new(by as u32, bx);
                    bake_block(dir, id, k, band, voids, width, rows, quant, config, node_levels)
                })
                .collect::<Result<Vec<BakedBlock>, _>>()
        };
        let patches = || patch.map(|p| band_geomip(band, voids, width, rows, p, source.georef()));
        let (baked, table) = rayon::join(blocks, patches);
        let baked = baked?;
        // A band with no valid sample has no heightmap: then the table is left to the caller.
        let table = match table.transpose()? {
            Some(None) => {
                if let Some((out, _)) = geomip.take() {
                    out.abandon()?;
                }
                None
            }
            t => t.flatten(),
        };
        if let (Some((out, sum)), Some(table)) = (geomip.as_mut(), table) {
            out.push(&table)?;
            // Every row once: the band's top row is the next band's first.
            let own = if j0 + rows as u64 >= h { rows } else { rows - 1 };
            for j in 0..own {
                sum.add_heights(&band[j * width..(j + 1) * width]);
                sum.add_voids(&voids[j * width..(j + 1) * width]);
            }
        }
        for b in baked {
            max_err = max_err.max(b.max_err);
            max_void_err = max_void_err.max(b.max_void_err);
            lossless &= b.lossless;
            prog.bytes_written += b.entry.file_len;
            entries.push(&b.entry)?;
            decimation.push(&b.decimation)?;
        }
        if let Some(bound) = quant.bound
            && max_err > bound
        {
            return Err(BakeError::Encoding(format!(
                "measured error {max_err} m exceeds the bound {bound} m"
            )));
        }
        prog.blocks_done = entries.count();
        if progress(&prog).is_break() {
            return Err(BakeError::Cancelled);
        }
    }
    let header =
        Header { max_error_m: max_err, max_void_error_m: max_void_err, ..plan.header(source) };
    Ok(BakedRows {
        header,
        entries,
        lossless,
        bound: quant.bound,
        geomip,
        decimation: Some(decimation),
    })
}

/// Geomorph's table of one band of source rows (`rows` rows of `width` samples and their void
/// flags) as a grid of its own, its rows of patches on rayon's threads; `None` when every
/// sample of the band is void (no heightmap has no valid sample).
fn band_geomip(
    band: &[f32],
    voids: &[bool],
    width: usize,
    rows: usize,
    patch_cells: u32,
    georef: Georef,
) -> Result<Option<GeomipTable>, BakeError> {
    let n = width * rows;
    let mut mask = VoidMask::new(width, rows);
    let void = voids[..n].iter().filter(|&&v| v).count();
    if void == n {
        return Ok(None);
    }
    if void > 0 {
        for (p, _) in voids[..n].iter().enumerate().filter(|(_, v)| **v) {
            mask.set(p % width, p / width, true);
        }
    }
    let hm = Heightmap::new(width, rows, band[..n].to_vec(), mask, georef)
        .map_err(|e| BakeError::Encoding(format!("a band of {rows} rows for geomorph: {e}")))?;
    let map = |row: &(dyn Fn(u32) -> _ + Sync), n| (0..n).into_par_iter().map(row).collect();
    Ok(Some(GeomipTable::new_with(&hm, patch_cells, map)))
}

/// Geomorph's table written into `dir/`[`GEOMIP_FILE`] band by band as it is computed
/// (terrain-core's `GeomipEncoder`): the file is created at the first band with its header's
/// bytes reserved, each band's entries are appended, and [`GeomipOut::finish`] writes the
/// header (which needs the checksum of every row's heights) and the tail. Memory holds one
/// band's entries (and the encoder's page checksums and pyramid summary, 1.7 MB at 32769^2),
/// whatever the grid's size; the file is the bytes of `GeomipTable::encode_for` of the whole
/// grid's table.
#[derive(Debug)]
pub(crate) struct GeomipOut {
    path: PathBuf,
    file: Option<fs::File>,
    encoder: GeomipEncoder,
    /// One band's entries, reused.
    buf: Vec<u8>,
}

impl GeomipOut {
    /// A table to be written into `dir` (nothing is written before the first band).
    pub(crate) fn new(dir: &Path) -> Self {
        Self {
            path: dir.join(GEOMIP_FILE),
            file: None,
            encoder: GeomipEncoder::new(),
            buf: Vec::new(),
        }
    }

    /// Appends the next band's table (rows of the grid as a grid of their own, south first,
    /// as `GeomipTable::stack` takes them).
    pub(crate) fn push(&mut self, band: &GeomipTable) -> Result<(), BakeError> {
        self.buf.clear();
        self.encoder
            .push(band, &mut self.buf)
            .map_err(|e| BakeError::Encoding(format!("geomorph's table: {e}")))?;
        let file = match &mut self.file {
            Some(f) => f,
            None => {
                let mut f = fs::File::create(&self.path).map_err(io_err(&self.path))?;
                f.write_all(&[0; GeomipEncoder::HEADER_LEN]).map_err(io_err(&self.path))?;
                self.file.insert(f)
            }
        };
        file.write_all(&self.buf).map_err(io_err(&self.path))
    }

    /// Completes the file, tied to heights whose checksum is `heights_crc`: its length, or
    /// `None` (and no file) when no band was pushed.
    pub(crate) fn finish(self, heights_crc: u32) -> Result<Option<u64>, BakeError> {
        let Some(mut file) = self.file else {
            return Ok(None);
        };
        let (header, tail) = self
            .encoder
            .finish(heights_crc)
            .map_err(|e| BakeError::Encoding(format!("geomorph's table: {e}")))?;
        let path = &self.path;
        file.write_all(&tail).map_err(io_err(path))?;
        let len = file.stream_position().map_err(io_err(path))?;
        file.seek(SeekFrom::Start(0)).map_err(io_err(path))?;
        file.write_all(&header).map_err(io_err(path))?;
        Ok(Some(len))
    }

    /// Drops the table and removes what was written of it (a band without a valid sample has
    /// no table: the table is then left to the caller).
    pub(crate) fn abandon(self) -> Result<(), BakeError> {
        match self.file {
            Some(file) => {
                drop(file);
                fs::remove_file(&self.path).map_err(io_err(&self.path))
            }
            None => Ok(()),
        }
    }
}

/// Completes a store in `dir` whose block files (bake id 0) and entries, every row of the
/// grid, are in `baked`: the bake id, an FNV-1a hash over every level's checksum, patched
/// into every block file, then the index's header, written last (its entries are in the file
/// already, after zeros where the header goes: not an index until then).
pub(crate) fn finish(
    dir: &Path,
    baked: BakedRows,
    start: Instant,
) -> Result<BakeReport, BakeError> {
    let BakedRows { mut header, entries, lossless, bound, geomip, decimation } = baked;
    if entries.count() != header.block_count() {
        return Err(BakeError::Encoding(format!(
            "{} block entries for {} blocks",
            entries.count(),
            header.block_count()
        )));
    }
    let id = entries.bake_id();
    let bytes_written = entries.block_bytes();
    (0..header.block_count()).into_par_iter().try_for_each(|pos| {
        let path = dir.join(block_file_name(header.block_at(pos)));
        let mut f = fs::OpenOptions::new().write(true).open(&path).map_err(io_err(&path))?;
        f.seek(SeekFrom::Start(12)).map_err(io_err(&path))?;
        f.write_all(&id.to_le_bytes()).map_err(io_err(&path))
    })?;
    header.bake_id = id;
    header.error_bound_m = bound.unwrap_or(if lossless { 0.0 } else { header.max_error_m });
    let geomip_bytes = match geomip {
        Some((out, heights)) => out.finish(heights.finish())?,
        None => None,
    };
    let index_bytes = entries.finish_index(&header)?;
    // The blocks' decimation errors, tied to the index by its bake id.
    let decimation_bytes = match decimation {
        Some(table) => table.finish(id, 0)?,
        None => 0,
    };
    // The coarsest levels of every block again in one file, after the index it is checked
    // against (`overview.rs`): a reader of the whole grid's coarse levels opens one file.
    let overview_bytes = crate::overview::write(dir)?;
    let source_samples = header.width * header.height;
    Ok(BakeReport {
        header,
        store_bytes: bytes_written + index_bytes + overview_bytes + decimation_bytes,
        index_bytes,
        source_samples,
        elapsed: start.elapsed(),
        lossless,
        geomip_bytes,
    })
}

#[allow(clippy::too_many_arguments)]
fn bake_block(
    dir: &Path,
    id: BlockId,
    k: u8,
    band: &[f32],
    voids: &[bool],
    width: usize,
    rows: usize,
    quant: Quant,
    config: &BakeConfig,
    node_levels: u8,
) -> Result<BakedBlock, BakeError> {
    let codec = config.codec;
    let cells = 1usize << k;
    let side = cells + 1;
    let x0 = id.col as usize * cells;
    let valid_w = (width - x0).min(side);
    let valid_h = rows.min(side);
    // Samples, padding repeating the last valid column / row.
    let mut q = vec![0i32; side * side];
    let mut z = vec![0f32; side * side];
    let mut mask = VoidMask::new(side, side);
    let (mut max_err, mut max_void_err, mut lossless) = (0f64, 0f64, true);
    // By rows of the band's slice (no index arithmetic or bounds check per sample).
    let encoding = quant.encoding;
    let quantizer = match encoding {
        SampleEncoding::Quantized { step_m, offset_m } => {
            Some((Quantizer::new(step_m, offset_m), step_m))
        }
        SampleEncoding::F32 => None,
    };
    for (j, (q_row, z_row)) in q.chunks_exact_mut(side).zip(z.chunks_exact_mut(side)).enumerate() {
        let sj = j.min(valid_h - 1);
        let src_row = &band[sj * width + x0..][..valid_w];
        let void_row = &voids[sj * width + x0..][..valid_w];
        // A row of the block's valid rows without voids (most rows): by lanes, without a
        // branch per sample; the same values as the loop below.
        if j < valid_h && !void_row.contains(&true) {
            let q_valid = &mut q_row[..valid_w];
            match quantizer {
                Some((qz, step_m)) => qz.steps_row(src_row, q_valid).map_err(|ii| {
                    BakeError::Encoding(format!(
                        "height {} m at ({}, {}) does not fit 32-bit steps of {step_m} m",
                        src_row[ii],
                        x0 + ii,
                        id.row as usize * cells + sj
                    ))
                })?,
                None => {
                    for (v, src) in q_valid.iter_mut().zip(src_row) {
                        *v = src.to_bits() as i32;
                    }
                }
            }
            for (back, &v) in z_row.iter_mut().zip(q_valid.iter()) {
                *back = encoding.height(v);
            }
            let (m, same) = row_error(&z_row[..valid_w], src_row, max_err);
            (max_err, lossless) = (m, lossless & same);
            // Padding columns repeat the last valid one.
            let (v, back) = (q_row[valid_w - 1], z_row[valid_w - 1]);
            for i in valid_w..side {
                q_row[i] = v;
                z_row[i] = back;
                mask.set(i, j, true);
            }
            continue;
        }
        for i in 0..side {
            let ii = i.min(valid_w - 1);
            let (src, void) = (src_row[ii], void_row[ii]);
            let padding = i >= valid_w || j >= valid_h;
            let v = match quantizer {
                Some((qz, step_m)) => qz.steps(src).ok_or_else(|| {
                    BakeError::Encoding(format!(
                        "height {src} m at ({}, {}) does not fit 32-bit steps of {step_m} m",
                        x0 + ii,
                        id.row as usize * cells + sj
                    ))
                })?,
                None => src.to_bits() as i32,
            };
            let back = encoding.height(v);
            if !padding {
                let err = (back as f64 - src as f64).abs();
                if void {
                    max_void_err = max_void_err.max(err);
                } else {
                    max_err = max_err.max(err);
                    lossless &= back.to_bits() == src.to_bits();
                }
            }
            if padding || void {
                mask.set(i, j, true);
            }
            q_row[i] = v;
            z_row[i] = back;
        }
    }
    let dss = config.dss_errors.then(|| dss_errors(&z, &mask, side, valid_w, valid_h));
    // The decimation errors of the stored heights, padding and void flags aside.
    let y0 = id.row as usize * cells;
    let decimation = block_errors(&z, k, (x0, y0), valid_w, valid_h);
    // Node values from the stored heights (what the runtime draws).
    let all_void = mask.count() == side * side;
    let hm = Heightmap::new(
        side,
        side,
        z,
        if all_void { VoidMask::new(side, side) } else { mask },
        Georef::local(1.0),
    )
    .map_err(|e| BakeError::Encoding(format!("block {id}: {e}")))?;
    let pyr = StaticErrorPyramid::build(&hm, k as usize);
    let level_errors: Vec<f32> = (0..k as usize)
        .map(|l| {
            let n = pyr.nodes_per_side(l.min(pyr.levels() - 1));
            let mut m = 0f64;
            if l < pyr.levels() {
                for j in 0..n {
                    for i in 0..n {
                        m = m.max(pyr.get(l, i, j));
                    }
                }
            }
            m as f32
        })
        .collect();
    let valid_range = |x0: usize, y0: usize, c: usize| {
        let (x1, y1) = ((x0 + c).min(valid_w - 1), (y0 + c).min(valid_h - 1));
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        if x0 < valid_w && y0 < valid_h {
            for j in y0..=y1 {
                for zz in &hm.data()[j * side + x0..=j * side + x1] {
                    lo = lo.min(*zz);
                    hi = hi.max(*zz);
                }
            }
        }
        (lo, hi)
    };
    // Each stored node's valid samples' range (its edges shared with its neighbours), the
    // deepest stored level by scanning and each coarser node from its four children, whose
    // closed ranges cover its own exactly (min and max are exact: the same values as a scan).
    let mut ranges: Vec<Vec<(f32, f32)>> = vec![Vec::new(); node_levels as usize];
    for l in (0..node_levels as usize).rev() {
        let n = 1usize << l;
        let c = cells >> l;
        ranges[l] = if l + 1 == node_levels as usize {
            (0..n * n).map(|p| valid_range(p % n * c, p / n * c, c)).collect()
        } else {
            let fine = &ranges[l + 1];
            (0..n * n)
                .map(|p| {
                    let (i, j) = (2 * (p % n), 2 * (p / n));
                    let r = |di: usize, dj: usize| fine[(j + dj) * 2 * n + i + di];
                    let q = [r(0, 0), r(1, 0), r(0, 1), r(1, 1)];
                    q.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &(a, b)| {
                        (lo.min(a), hi.max(b))
                    })
                })
                .collect()
        };
    }
    let (bmin, bmax) = ranges.first().map_or_else(|| valid_range(0, 0, cells), |r| r[0]);
    let mut nodes = Vec::with_capacity(node_count(node_levels));
    for (l, ranges) in ranges.iter().enumerate() {
        let n = 1usize << l;
        for (p, &(lo, hi)) in ranges.iter().enumerate() {
            let (lo, hi) = if lo <= hi { (lo, hi) } else { (bmin, bmax) };
            let e = if l < pyr.levels() { pyr.get(l, p % n, p / n) } else { 0.0 };
            nodes.push(NodeValues { min: lo, max: hi, static_error: e as f32 });
        }
    }
    // The fine maxima: per deepest stored node, its descendants' largest StaticE per finer level.
    let fine_errors = match node_levels.checked_sub(1) {
        Some(top) if node_levels < k => {
            let side = 1usize << top;
            let mut out = Vec::with_capacity(fine_count(k, node_levels));
            for j in 0..side {
                for i in 0..side {
                    for l in node_levels as usize..k as usize {
                        let s = l - top as usize;
                        let mut m = 0f64;
                        if l < pyr.levels() {
                            for dj in 0..1usize << s {
                                for di in 0..1usize << s {
                                    m = m.max(pyr.get(l, (i << s) + di, (j << s) + dj));
                                }
                            }
                        }
                        out.push(m as f32);
                    }
                }
            }
            out
        }
        _ => Vec::new(),
    };
    // Payloads, written after a header whose bake id is patched in at the end of the bake.
    let predictive_ok = !matches!(quant.encoding, SampleEncoding::F32);
    let mut file = block_header(0, id);
    let mut levels = Vec::with_capacity(k as usize + 1);
    for n in 0..=k {
        let payload = encode_level(k, n, &q, codec, predictive_ok);
        levels.push(LevelEntry {
            offset: file.len() as u64,
            len: payload.len() as u32,
            crc32: crc32(&payload),
        });
        file.extend_from_slice(&payload);
    }
    debug_assert_eq!(levels[0].offset, BLOCK_HEADER_LEN);
    let path: PathBuf = dir.join(block_file_name(id));
    fs::write(&path, &file).map_err(io_err(&path))?;
    Ok(BakedBlock {
        entry: BlockEntry {
            valid_w: valid_w as u32,
            valid_h: valid_h as u32,
            file_len: file.len() as u64,
            min: bmin,
            max: bmax,
            levels,
            nodes,
            level_errors,
            fine_errors,
            dss,
            fine_max: Default::default(),
        },
        max_err,
        max_void_err,
        lossless,
        decimation,
    })
}

/// The largest of `m` and each `|back - src|` of a row (in f64), and whether every stored
/// height `back` has its source's bits: by four interleaved running maxima, so the comparisons
/// do not wait on each other. The same value as a scan left to right: the largest of a set of
/// values (a NaN error would lose every comparison in either order; the bake's are finite).
fn row_error(back: &[f32], src: &[f32], m: f64) -> (f64, bool) {
    let (mut lanes, mut same) = ([m; 4], true);
    let (mut b4, mut s4) = (back.chunks_exact(4), src.chunks_exact(4));
    for (b, s) in (&mut b4).zip(&mut s4) {
        for l in 0..4 {
            let e = (f64::from(b[l]) - f64::from(s[l])).abs();
            lanes[l] = if e > lanes[l] { e } else { lanes[l] };
            same &= b[l].to_bits() == s[l].to_bits();
        }
    }
    for (b, s) in b4.remainder().iter().zip(s4.remainder()) {
        let e = (f64::from(*b) - f64::from(*s)).abs();
        lanes[0] = if e > lanes[0] { e } else { lanes[0] };
        same &= b.to_bits() == s.to_bits();
    }
    let m = lanes.iter().fold(lanes[0], |m, &e| if e > m { e } else { m });
    (m, same)
}

/// The DSS paper's 32 object-space errors of a block's valid extent (padding excluded, source
/// voids not measured), from the stored heights `z` (row-major `side x side`).
fn dss_errors(
    z: &[f32],
    mask: &VoidMask,
    side: usize,
    valid_w: usize,
    valid_h: usize,
) -> DssBlockErrors {
    let mut out = DssBlockErrors { avg: [0.0; DSS_FACTORS], max: [0.0; DSS_FACTORS] };
    let mut voids = VoidMask::new(valid_w, valid_h);
    for j in 0..valid_h {
        for i in 0..valid_w {
            if mask.get(i, j) {
                voids.set(i, j, true);
            }
        }
    }
    if valid_w < 2 || valid_h < 2 || voids.count() == valid_w * valid_h {
        return out;
    }
    let crop: Vec<f32> =
        (0..valid_h).flat_map(|j| z[j * side..j * side + valid_w].iter().copied()).collect();
    let Ok(hm) = Heightmap::new(valid_w, valid_h, crop, voids, Georef::local(1.0)) else {
        return out;
    };
    let e = object_errors(&hm, Region::new(0, 0, side - 1));
    for f in 0..DSS_FACTORS {
        out.avg[f] = e.avg[f] as f32;
        out.max[f] = e.max[f] as f32;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::row_error;

    #[test]
    fn the_row_error_by_lanes_is_a_plain_scan() {
        // Rows of every length 0..30 (the lanes' remainder included), stored heights within a
        // few steps of the source's or equal to them, a NaN among them in some: the same
        // maximum bits and losslessness as a scan left to right, from several starting maxima.
        let mut next = crate::tests::xorshift64_star(0x9E37_79B9_7F4A_7C15);
        let mut lossy = 0;
        for case in 0..600 {
            let n = case % 30;
            let src: Vec<f32> = (0..n).map(|_| (next() % 20_000) as f32 * 0.37 - 900.0).collect();
            let back: Vec<f32> = src
                .iter()
                .enumerate()
                .map(|(k, &z)| match (case / 30 % 4, next() % 5) {
                    (0, _) => z,
                    (3, 0) if k == n / 2 => f32::NAN,
                    (_, d) => z + (d as f32 - 2.0) * 0.25,
                })
                .collect();
            let m0 = [0.0, 0.1, 7.0][case % 3];
            let (mut m, mut same) = (m0, true);
            for (&b, &s) in back.iter().zip(&src) {
                let e = (f64::from(b) - f64::from(s)).abs();
                m = if e > m { e } else { m };
                same &= b.to_bits() == s.to_bits();
            }
            let (lm, lsame) = row_error(&back, &src, m0);
            assert_eq!((lm.to_bits(), lsame), (m.to_bits(), same), "case {case}");
            lossy += usize::from(!same && m > m0);
        }
        assert!(lossy > 100, "{lossy} rows with an error above the start");
    }
}
