//! The geomorph method's per-patch table (the article's max-error vertices, terrain-core's
//! `GeomipTable`) in a store folder: `terrain bake` computes it on every core and writes
//! `geomip.bin` (unless `--no-geomip`); `geomorph` drawn from a store reads it instead of the
//! heightmap (see [`crate::method::store_method`]).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use anyhow::Context;
use rayon::prelude::*;
use terrain_core::Heightmap;
use terrain_core::lod::{GeomipFor, GeomipTable};
use terrain_core::quadtree::TreeShape;

use crate::progress::Progress;

/// The geo-mipmap table in a store folder.
pub const GEOMIP_FILE: &str = "geomip.bin";

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

/// Computes the table of `hm` for patches of `patch_cells` and writes it into store folder
/// `dir` (a temporary file renamed into place, so an interrupted write leaves no damaged
/// table). Returns the file's size in bytes.
pub fn bake_into_scene(hm: &Heightmap, patch_cells: u32, dir: &Path) -> anyhow::Result<u64> {
    let start = Instant::now();
    let table = compute(hm, patch_cells, true);
    let bytes = table.encode(hm);
    let path = geomip_path(dir);
    let tmp = dir.join(format!("{GEOMIP_FILE}.tmp"));
    std::fs::write(&tmp, &bytes).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, &path)
        .with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))?;
    let (nx, ny) = table.patch_counts();
    println!(
        "{}: geomorph's max-error vertices of {} x {} patches of {} cells, {:.2} MB, {:.2} s",
        path.display(),
        nx,
        ny,
        table.patch_cells(),
        bytes.len() as f64 / 1e6,
        start.elapsed().as_secs_f64()
    );
    Ok(bytes.len() as u64)
}

/// Reads store folder `dir`'s table for the patch tree `shape` (its grid, leaves = patches),
/// or fails saying what to bake.
pub fn read_for_store(dir: &Path, shape: &TreeShape) -> anyhow::Result<GeomipTable> {
    let path = geomip_path(dir);
    let bytes = std::fs::read(&path).with_context(|| {
        format!(
            "--method geomorph from a store reads the max-error vertices the bake writes ({}); \
             bake the store again without --no-geomip",
            path.display()
        )
    })?;
    let want = GeomipFor {
        width: shape.width(),
        height: shape.height(),
        patch_cells: shape.leaf_cells(),
        heights_crc: None,
    };
    GeomipTable::decode(&bytes, &want).with_context(|| {
        format!(
            "{} cannot be used (the bake writes it for {}-cell patches, the default \
             --leaf-cells)",
            path.display(),
            crate::methods::MethodConfig::default().leaf_cells
        )
    })
}
