//! The DSS paper's precomputed object-space errors (section 3.3.1: 32 per M-block, factors
//! 2..64) in a scene folder: `terrain bake` computes them on every core and writes
//! `dss_errors.bin`; the benchmark reads them instead of computing them. A missing or bad file
//! is a warning, and the errors are computed in memory (the selections are the same either way:
//! the file holds the computed values bit for bit). A grid that is not in memory (a bake by
//! rows, a large synthetic terrain) gets the same table by bands of rows ([`bake_by_rows`]).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use anyhow::Context;
use glam::DVec2;
use rayon::prelude::*;
use terrain_core::Heightmap;
use terrain_core::lod::{DssErrorTable, DssPaging, DssParallel, RowsBudget};
use terrain_core::metrics::Region;
use terrain_core::metrics::dss::{FACTORS, ObjectErrorsAcc};
use terrain_core::quadtree::{Quadtree, TreeShape};

use crate::methods::MethodScene;
use crate::progress::Progress;

/// The DSS error table in a scene folder.
pub const DSS_FILE: &str = "dss_errors.bin";

/// The DSS error table's path in scene folder `dir`.
pub fn dss_path(dir: &Path) -> PathBuf {
    dir.join(DSS_FILE)
}

/// Computes the table on rayon's threads, with a progress line on stderr when `progress`
/// (the cost is the same per level: every level covers every sample 32 times).
pub fn compute(hm: &Heightmap, qt: &Quadtree, progress: bool) -> DssErrorTable {
    let bar = Progress::new("DSS errors", progress);
    let done = AtomicU64::new(0);
    let levels = u64::from(qt.max_level()) + 1;
    let table = DssErrorTable::new_with(hm, qt, |rows, f| {
        // Work per row: its samples, so each level weighs the same.
        let per_level: Vec<u64> = (0..=qt.max_level())
            .map(|level| rows.iter().filter(|r| r.0 == level).count().max(1) as u64)
            .collect();
        rows.par_iter()
            .map(|row| {
                let out = f(row);
                let step = 1_000_000 / per_level[row.0 as usize];
                let now = done.fetch_add(step, Ordering::Relaxed) + step;
                bar.update(now as f64, (1_000_000 * levels) as f64);
                out
            })
            .collect()
    });
    bar.finish();
    table
}

/// Computes the table of `hm` for quadtree `qt` and writes it into scene folder `dir` (through
/// a temporary file renamed into place, so an interrupted write never leaves a damaged table).
pub fn bake_into_scene(hm: &Heightmap, qt: &Quadtree, dir: &Path) -> anyhow::Result<()> {
    let start = Instant::now();
    let table = compute(hm, qt, true);
    write(dir, &table.encode(hm), qt.max_level(), start, "in memory")
}

/// Samples per band when the table is computed by rows (about 40 MB (10^6 bytes) of heights and void flags
/// per band; the finer quadtree levels are computed from windows of up to a band's rows).
const BAND_SAMPLES: usize = 1 << 23;

/// Nodes spread over rayon's threads.
struct Rayon;

impl DssParallel for Rayon {
    fn map_regions(
        &self,
        regions: &[(usize, Region)],
        f: &(dyn Fn(&(usize, Region)) -> [f64; FACTORS] + Sync),
    ) -> Vec<[f64; FACTORS]> {
        regions.par_iter().map(f).collect()
    }
    fn for_each_acc(
        &self,
        accs: &mut [(usize, ObjectErrorsAcc)],
        f: &(dyn Fn(&mut ObjectErrorsAcc) + Sync),
    ) {
        accs.par_iter_mut().for_each(|(_, a)| f(a));
    }
}

/// As [`bake_into_scene`], for a `width x height` grid read through `read(j0, rows, heights,
/// voids)` by bands of rows ([`DssErrorTable::from_rows`]: the same bytes as from the grid in
/// memory, in memory bounded by a band and a coarse node row), with the quadtree of
/// `leaf_cells` leaves; a band holds at most `max_band_bytes` of heights and void flags (5 bytes
/// a sample; `terrain bake` gives a quarter of `--max-memory`), and at least two leaves' rows,
/// and the coarse levels' node rows accumulated at once take what the band leaves of it.
/// Returns the table's path.
pub fn bake_by_rows(
    width: u32,
    height: u32,
    leaf_cells: u32,
    max_band_bytes: u64,
    dir: &Path,
    progress: bool,
    mut read: impl FnMut(usize, usize, &mut [f32], &mut [bool]) -> anyhow::Result<()>,
) -> anyhow::Result<PathBuf> {
    let start = Instant::now();
    let shape = TreeShape::new(width, height, leaf_cells, DVec2::ZERO, DVec2::ONE);
    let by_budget = usize::try_from(max_band_bytes / 5).unwrap_or(usize::MAX);
    let band =
        (BAND_SAMPLES.min(by_budget) / width.max(1) as usize).max(2 * leaf_cells as usize + 2);
    // The coarse levels' node rows, accumulated in one sweep, in what the band leaves of the
    // budget.
    let band_bytes = (band * width as usize).saturating_mul(5);
    let coarse_bytes =
        usize::try_from(max_band_bytes).unwrap_or(usize::MAX).saturating_sub(band_bytes);
    let budget = RowsBudget { band_rows: band, coarse_bytes };
    let bar = Progress::new("DSS errors", progress);
    // Rows read, to say how many times the grid was read.
    let mut rows_read = 0usize;
    let mut counted = |j0: usize, n: usize, heights: &mut [f32], voids: &mut [bool]| {
        rows_read += n;
        read(j0, n, heights, voids)
    };
    let (table, crc) = DssErrorTable::from_rows(&shape, &budget, &mut counted, &Rayon, &mut |f| {
        bar.update(f, 1.0)
    })?;
    bar.finish();
    let bytes = table.encode_for(width, height, crc);
    let how = format!(
        "by bands of rows, the grid read {:.2} times",
        rows_read as f64 / f64::from(height.max(1))
    );
    write(dir, &bytes, shape.max_level(), start, &how)?;
    Ok(dss_path(dir))
}

/// Writes the table's bytes into `dir` through a temporary file and says so.
fn write(dir: &Path, bytes: &[u8], max_level: u8, start: Instant, how: &str) -> anyhow::Result<()> {
    let path = dss_path(dir);
    let tmp = dir.join(format!("{DSS_FILE}.tmp"));
    std::fs::write(&tmp, bytes).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, &path)
        .with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))?;
    println!(
        "{}: the DSS paper's 32 object-space errors of {} quadtree levels ({how}), {:.1} MiB, {:.1} s",
        path.display(),
        max_level + 1,
        bytes.len() as f64 / crate::MIB,
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Reads `store`'s table for the quadtree `shape` (a store's: no heights checked, see
/// [`DssErrorTable::decode_for`]), or fails saying what to bake (`method` names the method in
/// the message): read whole when it is at most `read_whole_max` bytes (a remote store's
/// fetched into its mirror first), else opened for reading by pages
/// ([`DssErrorTable::open_paged`]: the header and the page checksums at open, each page when a
/// selection first asks one of its nodes, through a cache of `cache_bytes`;
/// a remote store's from its mirror's copy, or where it lies by chunks when the store reads
/// its tables so), or whole with a warning when it was baked before `dss_errors.bin` version 2.
/// [`crate::geomip_scene::READ_WHOLE_MAX_BYTES`] is the store methods' threshold: 64 MiB, a
/// grid up to about 8,000^2 samples at 16-cell leaves (the 32769^2 store's table is 1.43 GB).
pub fn read_for_store(
    store: &terrain_stream::Store,
    shape: &TreeShape,
    method: &str,
    read_whole_max: u64,
    cache_bytes: u64,
) -> anyhow::Result<DssErrorTable> {
    let paging = DssPaging { cache_bytes };
    crate::scene_files::read_store_table(
        store,
        &crate::scene_files::StoreTable {
            file: DSS_FILE,
            read_whole_max,
            missing: &|expected| {
                format!(
                    "--method {method} from a store reads the DSS errors the bake writes \
                     ({expected}); bake the store again without --no-dss (a grid read by rows \
                     gets them too, computed by bands of rows), or use ooc or uniform on the \
                     store"
                )
            },
            unusable_hint: "",
            decode: &|bytes| DssErrorTable::decode_for(bytes, shape, None),
            open_paged: &|location, reader, len| {
                DssErrorTable::open_paged(location, reader, len, shape, None, &paging)
            },
        },
    )
}

/// Reads scene folder `dir`'s table into `scene`: `Ok(path)` when used, or `Err(warning)` when
/// it cannot be used (missing, damaged, another terrain); the errors are then computed on
/// first use.
pub fn load_into(scene: &MethodScene, dir: &Path) -> Result<PathBuf, String> {
    let path = dss_path(dir);
    std::fs::read(&path)
        .map_err(|e| e.to_string())
        .and_then(|b| DssErrorTable::decode(&b, &scene.hm, &scene.qt).map_err(|e| e.to_string()))
        .map(|table| {
            scene.set_dss_errors(table);
            path.clone()
        })
        .map_err(|e| format!("{}: {e}; computing the DSS errors in memory instead", path.display()))
}
