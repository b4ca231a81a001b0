//! The PVPS methods' roughness pyramids (A: `d2`, B: height range, C: Eq. 5 roughness) in a
//! scene or store folder: `terrain bake` writes `roughness.bin`
//! ([`terrain_visibility::roughness::file`]) from the heightmap in memory, or by bands of rows
//! when the bake streams ([`terrain_visibility::roughness::stream`], bit-identical); the methods
//! read it instead of computing the pyramids from the whole grid.
//!
//! Two readers, for the two ways a method holds its terrain:
//! * [`load_into`]: an in-memory [`MethodScene`]; the file is checked against the heights'
//!   CRC-32. A missing, damaged or foreign file is a warning and the pyramids are computed in
//!   memory (the same values either way).
//! * [`load_from_store`]: a store folder and no heightmap (a store-backed method); the file is
//!   checked against the store's `bake_id` and a 32-bit hash of its index file, which the bake records
//!   in it ([`store_tie`]).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use terrain_core::Heightmap;
use terrain_core::lod::dss_file::heights_checksum;
use terrain_visibility::roughness::file::{self, Expected, TerrainTie};
use terrain_visibility::roughness::stream::{RowGrid, tables_by_rows};
use terrain_visibility::roughness::{RoughnessConfig, RoughnessTables, quadtree_levels};

use crate::methods::MethodScene;
use crate::progress::Progress;

/// The roughness pyramids' file in a scene folder.
pub const ROUGHNESS_FILE: &str = "roughness.bin";

/// Samples per band when the pyramids are computed by rows: about 38 MB of heights, void flags
/// and roughness per band, one band per rayon thread in flight, whatever the grid's size.
const BAND_SAMPLES: usize = 1 << 22;

/// Grids of at most this many samples keep their roughness between the two passes by rows (5
/// bytes per sample, at most 168 MB) instead of reading the rows again.
const KEEP_SAMPLES: usize = 1 << 25;

/// What ties a roughness file to the store in folder `dir`: the index header's `bake_id` and
/// a 32-bit hash of the index file's content (see [`terrain_visibility::roughness::file`] for why
/// both). Reads the index only.
pub fn store_tie(dir: &Path) -> anyhow::Result<(u64, u32)> {
    let store = terrain_stream::Store::open(dir)
        .with_context(|| format!("opening the store {}", dir.display()))?;
    store_tie_of(&store)
}

/// [`store_tie`] of an opened store (a remote one too: its index's pages are fetched).
pub fn store_tie_of(store: &terrain_stream::Store) -> anyhow::Result<(u64, u32)> {
    let content = store
        .index_content()
        .with_context(|| format!("reading the index of the store {}", store.location()))?;
    // The index ends with its own CRC-32 of everything before it; a CRC-32 over a message and
    // its CRC is the same constant for every message (and, CRCs being linear, so is any salted
    // one of a given length), so the tie hashes the index's content, without those four bytes.
    // Up to version 3 that content is one message and its CRC-32 is the tie. From version 4 the
    // content is itself a chain of pages each followed by its own CRC-32, and a CRC over such a
    // chain is blind to every page but the last, so the tie is the 64-bit FNV-1a of the content
    // folded to 32 bits (not linear, sees every byte). Stores baked before version 4 keep
    // their CRC tie, so their roughness files still open.
    let content = &content[..];
    let version = content.get(8..12).map_or(0, |v| u32::from_le_bytes([v[0], v[1], v[2], v[3]]));
    let tie = if version >= 4 {
        let h = terrain_core::checksum::fnv1a_update(terrain_core::checksum::FNV1A_START, content);
        (h ^ (h >> 32)) as u32
    } else {
        terrain_core::checksum::crc32(content)
    };
    Ok((store.header().bake_id, tie))
}

/// The roughness file's path in scene folder `dir`.
pub fn roughness_path(dir: &Path) -> PathBuf {
    dir.join(ROUGHNESS_FILE)
}

/// The pyramids of `hm` with the levels of a quadtree of `leaf_cells` leaves, written into
/// scene folder `dir`, tied to the heights and to the store in `dir` ([`store_tie`]; `store`
/// false: no store).
pub fn bake_from_heightmap(
    hm: &Heightmap,
    leaf_cells: u32,
    dir: &Path,
    store: bool,
) -> anyhow::Result<()> {
    let start = Instant::now();
    let store = store.then(|| store_tie(dir)).transpose()?;
    let levels = quadtree_levels(hm.width(), hm.height(), leaf_cells as usize);
    let config = RoughnessConfig::default();
    let tables = RoughnessTables::compute(hm, levels, &config);
    let bytes =
        file::encode(&tables, hm.width(), hm.height(), heights_checksum(hm), store, &config);
    write(dir, &bytes, levels, start, "in memory")
}

/// As [`bake_from_heightmap`], for a grid read through `read(j0, rows, heights, voids)` by
/// bands of rows (twice, on rayon's threads; see [`terrain_visibility::roughness::stream`])
/// with bounded memory.
pub fn bake_by_rows(
    grid: &RowGrid,
    leaf_cells: u32,
    dir: &Path,
    store: bool,
    read: impl Fn(usize, usize, &mut [f32], &mut [bool]) -> anyhow::Result<()> + Sync,
) -> anyhow::Result<()> {
    let start = Instant::now();
    let store = store.then(|| store_tie(dir)).transpose()?;
    let levels = quadtree_levels(grid.width, grid.height, leaf_cells as usize);
    let config = RoughnessConfig::default();
    let bar = Progress::new("roughness", true);
    let band = (BAND_SAMPLES / grid.width.max(1)).max(1);
    let out =
        tables_by_rows(grid, levels, &config, band, KEEP_SAMPLES, read, |f| bar.update(f, 1.0))?;
    bar.finish();
    let bytes =
        file::encode(&out.tables, grid.width, grid.height, out.heights_checksum, store, &config);
    write(dir, &bytes, levels, start, "by bands of rows")
}

/// Writes the file through a temporary file renamed into place (an interrupted write never
/// leaves a damaged file) and says so.
fn write(dir: &Path, bytes: &[u8], levels: usize, start: Instant, how: &str) -> anyhow::Result<()> {
    let path = roughness_path(dir);
    let tmp = dir.join(format!("{ROUGHNESS_FILE}.tmp"));
    std::fs::write(&tmp, bytes).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, &path)
        .with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))?;
    println!(
        "{}: the PVPS methods' roughness pyramids A, B, C of {levels} quadtree levels ({how}), {:.2} MiB, {:.1} s",
        path.display(),
        bytes.len() as f64 / crate::MIB,
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Reads scene folder `dir`'s pyramids into `scene`: `Ok(path)` when used, or `Err(warning)`
/// (naming the file) when they cannot be used (missing, damaged, another terrain or leaf
/// size); the pyramids are then computed in memory on first use.
pub fn load_into(scene: &MethodScene, dir: &Path) -> Result<PathBuf, String> {
    let path = roughness_path(dir);
    let expected = Expected {
        width: scene.hm.width(),
        height: scene.hm.height(),
        levels: scene.qt.max_level() as usize + 1,
        config: RoughnessConfig::default(),
        tie: TerrainTie::Heights(heights_checksum(&scene.hm)),
    };
    std::fs::read(&path)
        .map_err(|e| e.to_string())
        .and_then(|b| file::decode_for(&b, &expected).map_err(|e| e.to_string()))
        .and_then(|tables| {
            if scene.set_roughness(tables) {
                Ok(path.clone())
            } else {
                Err("the pyramids were already computed".to_string())
            }
        })
        .map_err(|e| {
            format!("{}: {e}; computing the roughness pyramids in memory instead", path.display())
        })
}

/// Reads the pyramids of the store in folder `dir` for a quadtree of `leaf_cells` leaves,
/// without its heights: the file must have been baked into this store ([`store_tie`], see
/// [`terrain_visibility::roughness::file`]). The error names the file and says why.
pub fn load_from_store(dir: &Path, leaf_cells: u32) -> anyhow::Result<RoughnessTables> {
    let store = terrain_stream::Store::open(dir)
        .with_context(|| format!("opening the store {}", dir.display()))?;
    load_from_opened(&store, leaf_cells)
}

/// [`load_from_store`] of an opened store (a remote one: the file from its mirror folder).
pub fn load_from_opened(
    store: &terrain_stream::Store,
    leaf_cells: u32,
) -> anyhow::Result<RoughnessTables> {
    let dir = store.dir();
    let h = store.header();
    let (width, height) = (h.width as usize, h.height as usize);
    let (bake_id, index_crc) = store_tie_of(store)?;
    // A remote store's table is fetched into its mirror now (only a pvps method reads it).
    let path = store.side_file(ROUGHNESS_FILE)?.unwrap_or_else(|| roughness_path(dir));
    let bytes = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
    let expected = Expected {
        width,
        height,
        levels: quadtree_levels(width, height, leaf_cells as usize),
        config: RoughnessConfig::default(),
        tie: TerrainTie::Store { bake_id, index_crc },
    };
    file::decode_for(&bytes, &expected).with_context(|| format!("reading {}", path.display()))
}
