//! The geomorph method's per-patch table (the article's max-error vertices, terrain-core's
//! `GeomipTable`) in a store folder: `terrain bake` computes it on every core and writes
//! `geomip.bin` (unless `--no-geomip`); `geomorph` drawn from a store reads it instead of the
//! heightmap (see [`crate::method::store_method`]): whole up to 64 MiB, by pages above
//! ([`read_for_store`]). From the heightmap when the bake holds it in memory
//! ([`bake_into_scene`]), else from the store's blocks one block row at a time
//! ([`bake_from_store`]: a DEM read by rows, a synthetic grid above what fits in memory; the
//! store keeps no void mask, so every sample is measured there).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use anyhow::Context;
use rayon::prelude::*;
use terrain_core::Heightmap;
use terrain_core::checksum::crc32_update;
use terrain_core::heightmap::VoidMask;
use terrain_core::lod::{GeomipFor, GeomipPaging, GeomipTable};
use terrain_core::quadtree::TreeShape;
use terrain_stream::{BlockId, Store};

use crate::progress::Progress;

/// The geo-mipmap table in a store folder (the bake writes it with the blocks when it can:
/// `terrain_stream::BakeConfig::geomip_patch_cells`).
pub const GEOMIP_FILE: &str = terrain_stream::GEOMIP_FILE;

/// The geo-mipmap table's path in store folder `dir`.
pub fn geomip_path(dir: &Path) -> PathBuf {
    dir.join(GEOMIP_FILE)
}

/// Computes the table of `hm` for patches of `patch_cells` on rayon's threads, with a
/// progress line on stderr when `progress`.
pub fn compute(hm: &Heightmap, patch_cells: u32, progress: bool) -> GeomipTable {
    let bar = Progress::new("geomip table", progress);
    let done = AtomicU64::new(0);
    let table = GeomipTable::new_with(hm, patch_cells, |row, rows| {
        (0..rows)
            .into_par_iter()
            .map(|pj| {
                let out = row(pj);
                let now = done.fetch_add(1, Ordering::Relaxed) + 1;
                bar.update(now as f64, f64::from(rows));
                out
            })
            .collect()
    });
    bar.finish();
    table
}

/// Computes the table of the store's grid from its blocks at full resolution, one block row
/// (a band of `2^k + 1` grid rows) at a time, on rayon's threads; with the checksum of the
/// stored heights (the grid's rows in order, as `heights_checksum` of a heightmap without
/// voids).
pub fn compute_from_store(
    store: &Store,
    patch_cells: u32,
    progress: bool,
) -> anyhow::Result<(GeomipTable, u32)> {
    let h = store.header();
    let (b, k) = (h.block_cells(), h.k);
    anyhow::ensure!(
        b >= patch_cells,
        "blocks of {b} cells are smaller than the geomorph patches ({patch_cells} cells)"
    );
    let bar = Progress::new("geomip table", progress);
    let (width, height) = (
        u32::try_from(h.width).context("grid width")?,
        u32::try_from(h.height).context("grid height")?,
    );
    let mut crc = 0u32;
    let mut buf: Vec<u8> = Vec::new();
    let band = |y0: u32, rows: u32| -> anyhow::Result<Heightmap> {
        let w = width as usize;
        let mut data = vec![0f32; w * rows as usize];
        let row = y0 / b;
        for col in 0..h.blocks_x {
            let id = BlockId::new(row, col);
            let grid = store
                .read_block(id, k)
                .with_context(|| format!("reading block {id:?} of {}", store.dir().display()))?
                .grid(k)
                .context("a block's full resolution")?;
            let n = (b + 1) as usize;
            let x0 = (col * b) as usize;
            for j in 0..rows as usize {
                for i in 0..n.min(w - x0) {
                    data[j * w + x0 + i] = grid[j * n + i];
                }
            }
        }
        // The checksum: every row once (the band's last row is the next band's first).
        let last = if y0 + rows >= height { rows } else { rows - 1 };
        for r in data.chunks(w).take(last as usize) {
            buf.clear();
            buf.extend(r.iter().flat_map(|z| z.to_bits().to_le_bytes()));
            crc = crc32_update(crc, &buf);
        }
        bar.update(f64::from(y0 + rows), f64::from(height));
        Heightmap::new(w, rows as usize, data, VoidMask::new(w, rows as usize), h.georef.clone())
            .context("a band of the store's heights")
    };
    let table = GeomipTable::from_bands((width, height), patch_cells, b / patch_cells, band, {
        |row, rows| rows.into_par_iter().map(row).collect()
    })?;
    bar.finish();
    Ok((table, crc))
}

/// [`compute_from_store`] for the store in folder `dir`, written into it like
/// [`bake_into_scene`]. Returns the file's size in bytes.
pub fn bake_from_store(store: &Store, patch_cells: u32) -> anyhow::Result<u64> {
    let start = Instant::now();
    let (table, crc) = compute_from_store(store, patch_cells, true)?;
    write_table(&table, &table.encode_for(crc), store.dir(), start)
}

/// Computes the table of `hm` for patches of `patch_cells` and writes it into store folder
/// `dir` (a temporary file renamed into place, so an interrupted write leaves no damaged
/// table). Returns the file's size in bytes.
pub fn bake_into_scene(hm: &Heightmap, patch_cells: u32, dir: &Path) -> anyhow::Result<u64> {
    let start = Instant::now();
    let table = compute(hm, patch_cells, true);
    write_table(&table, &table.encode(hm), dir, start)
}

/// Writes `table`, already computed from `hm` (a `MethodScene`'s), into store folder `dir`
/// like [`bake_into_scene`]. Returns the file's size in bytes.
pub fn write_into_scene(table: &GeomipTable, hm: &Heightmap, dir: &Path) -> anyhow::Result<u64> {
    write_table(table, &table.encode(hm), dir, Instant::now())
}

fn write_table(
    table: &GeomipTable,
    bytes: &[u8],
    dir: &Path,
    start: Instant,
) -> anyhow::Result<u64> {
    let path = geomip_path(dir);
    let tmp = dir.join(format!("{GEOMIP_FILE}.tmp"));
    std::fs::write(&tmp, bytes).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, &path)
        .with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))?;
    let (nx, ny) = table.patch_counts();
    println!(
        "{}: geomorph's max-error vertices of {} x {} patches of {} cells, {:.2} MiB, {:.2} s",
        path.display(),
        nx,
        ny,
        table.patch_cells(),
        bytes.len() as f64 / crate::MIB,
        start.elapsed().as_secs_f64()
    );
    Ok(bytes.len() as u64)
}

/// The largest `geomip.bin` [`read_for_store`] reads whole at open; a larger one is read by
/// pages. Whole, a table costs its size in memory and its read at open (41 MB and 0.3 s on the
/// 16385^2 store) but selects fastest; by pages, open reads the header and tail only and the
/// memory follows the view, but each view's pages and pyramid tiles are read and built on
/// first use (the 16385^2 store's selection 2.1x slower cold and 1.3x over consecutive
/// frames, the 32769^2 store's 2.3x cold for 455 MB less; bench/ooc/README.md, "`geomip.bin`
/// read by pages"). 64 MiB: a grid up to about 20,000^2 samples at 16-cell patches.
pub const READ_WHOLE_MAX_BYTES: u64 = 64 << 20;

/// Reads `store`'s table for the patch tree `shape` (its grid, leaves = patches), or fails
/// saying what to bake: read whole when it is at most [`READ_WHOLE_MAX_BYTES`] (a remote
/// store's fetched into its mirror first, one GET), else opened for reading by pages
/// ([`GeomipTable::open_paged`]: the header and tail at open, each page of entries when a
/// frame first needs it, through a cache of [`GeomipPaging::default`]'s bytes; a remote
/// store's from its mirror's copy, fetched whole first, or, when the store reads its tables by
/// chunks (the app's stores: `ooc::remote_options`), where it lies, by the chunks those pages
/// lie in ([`Store::side_table`]; a frame that does not wait, [`GeomipTable::set_waiting`],
/// leaves the missing ones to the background fill)), or read whole, with a warning, when the
/// store was baked before `geomip.bin` version 2.
pub fn read_for_store(store: &Store, shape: &TreeShape) -> anyhow::Result<GeomipTable> {
    read_for_store_with(store, shape, &GeomipPaging::default(), READ_WHOLE_MAX_BYTES)
}

/// [`read_for_store`] for a store method whose memory budget is `budget_bytes`: the table's
/// page cache [`crate::scene_files::table_cache_bytes`] of it (what the method's scene then
/// reserves from the blocks' share each frame).
pub fn read_for_store_within(
    store: &Store,
    shape: &TreeShape,
    budget_bytes: u64,
) -> anyhow::Result<GeomipTable> {
    let paging = GeomipPaging { cache_bytes: crate::scene_files::table_cache_bytes(budget_bytes) };
    read_for_store_with(store, shape, &paging, READ_WHOLE_MAX_BYTES)
}

/// [`read_for_store`] with its page cache's settings, reading a table of at most
/// `read_whole_max` bytes whole (0: every version-2 table by pages).
pub fn read_for_store_with(
    store: &Store,
    shape: &TreeShape,
    paging: &GeomipPaging,
    read_whole_max: u64,
) -> anyhow::Result<GeomipTable> {
    let want = GeomipFor {
        width: shape.width(),
        height: shape.height(),
        patch_cells: shape.leaf_cells(),
        heights_crc: None,
    };
    let hint = format!(
        " (the bake writes it for {}-cell patches, the default --leaf-cells)",
        crate::methods::MethodConfig::default().leaf_cells
    );
    crate::scene_files::read_store_table(
        store,
        &crate::scene_files::StoreTable {
            file: GEOMIP_FILE,
            read_whole_max,
            missing: &|expected| {
                format!(
                    "--method geomorph from a store reads the max-error vertices the bake \
                     writes ({expected}); bake the store again without --no-geomip"
                )
            },
            unusable_hint: &hint,
            decode: &|bytes| GeomipTable::decode(bytes, &want),
            open_paged: &|location, reader, len| {
                GeomipTable::open_paged(location, reader, len, &want, paging)
            },
        },
    )
}
