//! The `tin` method's coarse tiles baked into a store (`tin_tiles.bin`): every tile whose own
//! stride is at least `2^BAKED_MIN_STRIDE_LOG2` (a tile spanning 512 cells or more at the
//! store's 64-cell tiles), built by the builder `tin` from a store builds with at run time
//! ([`store_builder`]: the same function, the same bounds, the same samples, each tile seeded
//! by its parent's vertices), so a frame never waits for a tile meshed from hundreds of
//! thousands or millions of samples: those are read (tens of kilobytes each), and only tiles of
//! at most 256 cells across (66 k samples) are built while flying. The tiles are
//! view-independent, so nothing is lost by building them once. The 512-cell tiles are what a
//! 1280 x 720 view needs most of: `fast_pass` over the 32769^2 synthetic store at 2 px drew 27 %
//! of its frames at their needed level with them built while flying, 92-94 % with them baked
//! (1006 instead of 361 MiB, in 263 s of bake with the seeds, the time the 1024-cell ones took
//! before them); at 320 x 180 either draws 96-97 % (bench/ooc/README.md, "The tin method at
//! 1280 x 720").
//!
//! `terrain bake` writes the file after the store's blocks (and after a sharded bake's merge),
//! unless `--no-tin`, for the default `tin` settings; `--tin-min-cells` (there and on `terrain
//! tin-tiles`) bakes the tiles down to another size ([`min_stride_for_cells`]: 64 cells, every
//! tile, costs about the triangles of a full tileset: 10 GB on a 16385^2 DEM of real
//! relief). A store read with other settings
//! (`--error-scale`, another finest tile size, a vertical exaggeration) builds every tile as
//! before, and so does a store without its table of decimation errors (the tiles' bounds come
//! from it). The file is tied to the store's blocks by their bake id: a file of another bake
//! of them, or a damaged tile, is an error naming the file.
//!
//! The file's layout and its checked decoders are terrain-core's
//! ([`terrain_core::tin::tile_file`], which the fuzz harness runs on damaged files too).

use std::collections::HashMap;
use std::io::{Seek, SeekFrom, Write};
use std::time::Instant;

use anyhow::Context;
use rayon::prelude::*;
use terrain_core::lod::TableReader;
use terrain_core::quadtree::{NodeId, NodeTree, TreeShape};
use terrain_core::tin::grid::{GridTile, level_errors, tile_window};
use terrain_core::tin::tile_file::{
    self, ENTRY_BYTES, HEADER_BYTES, Slot, TileFileKey, encode_entry, encode_header, encode_tile,
    tile_origin,
};
use terrain_stream::{BlockId, SideTable, Store, StoreTree};

use crate::decimation::DECIMATION_REGION;
use crate::method::{GridTileBuilder, TinConfig};
use crate::progress::Progress;
use crate::samples::StoreSamples;

/// The file's name in a store folder.
pub const TIN_TILES_FILE: &str = "tin_tiles.bin";

/// Tiles whose own stride (their 64 cells across at it) is at least `2^this` are baked: at
/// run time the rest are meshed from windows of at most 256 cells across.
pub const BAKED_MIN_STRIDE_LOG2: u32 = 3;

/// The default of `--tin-min-cells`: the cells across of the finest tiles baked
/// (`64 << BAKED_MIN_STRIDE_LOG2`).
pub const BAKED_MIN_CELLS: u32 = 64 << BAKED_MIN_STRIDE_LOG2;

/// The least own stride (`log2`) of the tiles baked when every tile spanning at least `cells`
/// cells is (`--tin-min-cells`): a power of two of at least the tiles' 64 cells
/// (`TinStoreConfig::max_tile_cells`); 64 bakes every tile, so the method never meshes while
/// flying. Else an error naming the option.
pub fn min_stride_for_cells(cells: u32) -> anyhow::Result<u32> {
    let tile = TinConfig::default().store.max_tile_cells;
    if !cells.is_power_of_two() || cells < tile {
        anyhow::bail!(
            "--tin-min-cells {cells}: give a power of two of at least {tile} (the tiles' \
             cells across at their own stride; {tile} bakes every tile, the default \
             {BAKED_MIN_CELLS} the coarse ones)"
        );
    }
    Ok((cells / tile).trailing_zeros())
}

/// Tiles built between two writes of the bake (bounds the tiles held in memory).
const CHUNK_TILES: usize = 128;

/// What the tiles of `store`'s tree `shape` are built for under `config` (a file holding
/// the tiles from `2^BAKED_MIN_STRIDE_LOG2` on).
fn key_for(store: &Store, shape: &TreeShape, config: &TinConfig) -> TileFileKey {
    TileFileKey {
        width: shape.width(),
        height: shape.height(),
        root_cells: shape.root_cells(),
        max_level: u32::from(shape.max_level()),
        error_scale: config.pyramid.error_scale,
        max_tile_cells: config.store.max_tile_cells,
        finer_strides: config.pyramid.finer_strides,
        min_stride_log2: BAKED_MIN_STRIDE_LOG2,
        bake_id: store.header().bake_id,
    }
}

/// The tree `tin` selects over a store: leaves of the pyramid's finest tiles (no finer than
/// the store's blocks).
pub fn store_tree(store: &std::sync::Arc<Store>, config: &TinConfig) -> StoreTree {
    let cells = config.pyramid.finest_cells.clamp(2, 1 << 15).next_power_of_two();
    let cells = cells.min(store.header().block_cells());
    StoreTree::new(store.clone(), cells)
}

/// The builder of `store`'s tiles for tree `shape` under `config`: the store's samples through
/// a block cache of `block_cache_bytes`, and the bake's table of decimation errors
/// per block, read once, which caps the tiles' strides without reading samples
/// ([`GridTileBuilder::with_table`]). A store without one (baked before it existed) or with
/// blocks of another size builds as before, each region measured on first need; a damaged
/// table is an error (bake the store again).
pub fn store_builder(
    store: Store,
    shape: TreeShape,
    config: &TinConfig,
    block_cache_bytes: u64,
) -> anyhow::Result<GridTileBuilder<StoreSamples>> {
    let table = store
        .decimation_errors()
        .with_context(|| format!("the tin method's table of {}", store.dir().display()))?;
    let cells = 1usize << store.header().k;
    let builder = GridTileBuilder::new(
        StoreSamples::new(store, block_cache_bytes),
        shape,
        level_errors(&shape, config.pyramid.error_scale),
        Some(config.store.max_tile_cells),
    );
    Ok(match table {
        Some(t) if cells == DECIMATION_REGION => builder
            .with_table(config.pyramid.finer_strides, |x, y| {
                t.errors(BlockId::new(y as u32, x as u32))
            }),
        _ => builder,
    })
}

/// The tiles of tree `shape` the bake builds: those whose own stride is at least
/// `2^min_stride_log2`, coarse first.
fn baked_nodes(shape: &TreeShape, max_cells: u32, min_stride_log2: u32) -> Vec<NodeId> {
    let mut nodes = Vec::new();
    for level in 0..=shape.max_level() {
        let (nx, ny) = shape.level_dims(level);
        for j in 0..ny {
            for i in 0..nx {
                let n = NodeId::new(level, i, j);
                if tile_window(shape, n, Some(max_cells))
                    .is_some_and(|w| w.stride_log2 >= min_stride_log2)
                {
                    nodes.push(n);
                }
            }
        }
    }
    nodes
}

/// What [`bake_tiles`] wrote.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TinBakeReport {
    /// Tiles written: every tile spanning `min_cells` cells or more.
    pub tiles: usize,
    /// The cells across of the finest tiles written.
    pub min_cells: u32,
    /// Their triangles.
    pub triangles: u64,
    /// The file's bytes.
    pub bytes: u64,
    /// Wall seconds.
    pub secs: f64,
}

impl TinBakeReport {
    /// The line `terrain bake` and `terrain tin-tiles` print for the tiles written into store
    /// folder `dir`.
    pub fn line(&self, dir: &std::path::Path) -> String {
        format!(
            "{}: {} of the tin method's tiles, those spanning {} cells or more ({} triangles), \
             {:.2} MiB, {:.1} s",
            dir.join(TIN_TILES_FILE).display(),
            self.tiles,
            self.min_cells,
            self.triangles,
            self.bytes as f64 / crate::MIB,
            self.secs
        )
    }
}

/// Why `store`'s tiles cannot be baked nor read, or `None` when they can: it must be read
/// without a vertical exaggeration (the tiles' meshes depend on the heights' scale), have
/// blocks of the decimation table's regions and that table (it caps the tiles' strides and
/// raises their bounds; without it the selection would take the levels' own bounds).
pub fn not_bakeable(store: &Store) -> anyhow::Result<Option<String>> {
    let h = store.header();
    Ok(if h.vertical_scale != 1.0 {
        Some(format!("it is read with a vertical exaggeration ({})", h.vertical_scale))
    } else if (1usize << h.k) != DECIMATION_REGION {
        Some(format!(
            "it has blocks of {} cells; the tin method's baked tiles need {DECIMATION_REGION} \
             (bake it with the default --block-k 8)",
            h.block_cells()
        ))
    } else if store.decimation_errors()?.is_none() {
        Some(format!(
            "it has no table of decimation errors ({}: baked before it existed), which the \
             tiles need: bake the store again (that writes the tiles too)",
            terrain_stream::DECIMATION_FILE
        ))
    } else {
        None
    })
}

/// Builds `store`'s `tin` tiles under the default settings ([`TinConfig::default`]), those
/// whose own stride is at least `2^min_stride_log2` ([`min_stride_for_cells`];
/// [`BAKED_MIN_STRIDE_LOG2`] for the bake's default, the tiles of [`BAKED_MIN_CELLS`] or more),
/// on every core, and writes them into its folder (a temporary file renamed into place, so an
/// interrupted bake leaves no damaged file), with a progress bar when `progress`. A reader uses
/// whichever tiles the file holds. `Ok(None)` when the store gets none: no table of decimation
/// errors (a store baked before it), blocks of another size, a vertical exaggeration
/// ([`not_bakeable`]), or a grid with no tile that large.
pub fn bake_tiles(
    store: &Store,
    min_stride_log2: u32,
    progress: bool,
) -> anyhow::Result<Option<TinBakeReport>> {
    let start = Instant::now();
    let config = TinConfig::default();
    let arc = std::sync::Arc::new(store.clone());
    let shape = *NodeTree::shape(&store_tree(&arc, &config));
    if not_bakeable(store)?.is_some() {
        return Ok(None);
    }
    let builder = store_builder(store.clone(), shape, &config, config.store.block_cache_bytes)?;
    let key = TileFileKey { min_stride_log2, ..key_for(store, &shape, &config) };
    let nodes = baked_nodes(&shape, config.store.max_tile_cells, min_stride_log2);
    if nodes.is_empty() {
        return Ok(None);
    }
    let dir = store.dir();
    let path = dir.join(TIN_TILES_FILE);
    let tmp = dir.join(format!("{TIN_TILES_FILE}.tmp"));
    // A failed bake leaves the store as it was: no temporary file, any earlier file intact.
    let written = write_tiles(&builder, &shape, &key, &nodes, &tmp, progress);
    let (triangles, bytes) = match written {
        Ok(w) => w,
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            return Err(e);
        }
    };
    std::fs::rename(&tmp, &path)
        .with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))?;
    Ok(Some(TinBakeReport {
        tiles: nodes.len(),
        min_cells: config.store.max_tile_cells << min_stride_log2,
        triangles,
        bytes,
        secs: start.elapsed().as_secs_f64(),
    }))
}

/// Builds `nodes` and writes them with their index and header `key` to `tmp`; returns their
/// triangles and the file's bytes.
fn write_tiles(
    builder: &GridTileBuilder<StoreSamples>,
    shape: &TreeShape,
    key: &TileFileKey,
    nodes: &[NodeId],
    tmp: &std::path::Path,
    progress: bool,
) -> anyhow::Result<(u64, u64)> {
    let shape = *shape;
    let io = |what: &str| format!("{what} {}", tmp.display());
    let file = std::fs::File::create(tmp).with_context(|| io("creating"))?;
    let mut out = std::io::BufWriter::new(file);
    out.write_all(&[0u8; HEADER_BYTES]).with_context(|| io("writing"))?;
    let bar = Progress::new("tin tiles", progress);
    let mut index: Vec<u8> = Vec::with_capacity(nodes.len() * ENTRY_BYTES);
    let (mut offset, mut triangles) = (HEADER_BYTES as u64, 0u64);
    // Progress in samples read: a coarse tile reads up to 4 M of them, a 512-cell one 263 k.
    let weight = |n: NodeId| -> u64 {
        let s = builder.finest_stride(builder.own_stride(n).unwrap_or(0));
        shape.clipped_rect(n).map_or(0, |r| {
            (u64::from((r.x1 - r.x0) >> s) + 1) * (u64::from((r.y1 - r.y0) >> s) + 1)
        })
    };
    let total = nodes.iter().map(|&n| weight(n)).sum::<u64>() as f64;
    let done = std::sync::atomic::AtomicU64::new(0);
    // Each tile seeded by its parent's vertices (as at run time): the previous level's kept
    // (vertices only) while a level is built, level by level (`nodes` come coarse first).
    let mut parents: HashMap<NodeId, Vec<[u32; 2]>> = HashMap::new();
    for level in nodes.chunk_by(|a, b| a.level == b.level) {
        let mut this: HashMap<NodeId, Vec<[u32; 2]>> = HashMap::new();
        for chunk in level.chunks(CHUNK_TILES) {
            let built: Vec<(GridTile, Vec<u8>)> = chunk
                .par_iter()
                .map(|&n| {
                    let seeds = n.parent().and_then(|p| parents.get(&p));
                    let t = builder
                        .build(n, seeds.map_or(&[][..], |v| &v[..]))
                        .with_context(|| format!("tin tile {n:?}"))?;
                    let w = weight(n);
                    let d = done.fetch_add(w, std::sync::atomic::Ordering::Relaxed) + w;
                    bar.update(d as f64, total);
                    let bytes = encode_tile(&t, tile_origin(&shape, n)?);
                    Ok((t, bytes))
                })
                .collect::<anyhow::Result<_>>()?;
            for (t, bytes) in built {
                out.write_all(&bytes).with_context(|| io("writing"))?;
                index.extend_from_slice(&encode_entry(t.node, t.stride_log2, offset, &bytes));
                offset += bytes.len() as u64;
                triangles += t.triangles.len() as u64;
                this.insert(t.node, t.vertices);
            }
        }
        parents = this;
    }
    bar.finish();
    out.write_all(&index).with_context(|| io("writing"))?;
    let head = encode_header(key, nodes.len() as u32, offset);
    let mut file = out.into_inner().map_err(|e| e.into_error()).with_context(|| io("writing"))?;
    file.seek(SeekFrom::Start(0)).with_context(|| io("writing"))?;
    file.write_all(&head).with_context(|| io("writing"))?;
    file.sync_all().with_context(|| io("writing"))?;
    Ok((triangles, offset + index.len() as u64))
}

/// A store's baked tiles (see the module docs), for reading by tile.
#[derive(Debug)]
pub struct BakedTiles {
    reader: SideTable,
    shape: TreeShape,
    slots: HashMap<NodeId, Slot>,
}

impl BakedTiles {
    /// `store`'s baked tiles for tree `shape` under `config`: `Ok(None)` when it has none, or
    /// they were built for other settings (then every tile is built at run time, as without
    /// them); an error naming the file when it is damaged or belongs to another bake of the
    /// store (bake it again).
    pub fn open(
        store: &Store,
        shape: &TreeShape,
        config: &TinConfig,
    ) -> anyhow::Result<Option<Self>> {
        // (Without the decimation table the selection's bounds are the levels' own, not the
        // raised ones the baked tiles were built within.)
        if not_bakeable(store)?.is_some() {
            return Ok(None);
        }
        let Some(reader) = store.side_table(TIN_TILES_FILE)? else { return Ok(None) };
        let name = reader.location().to_string();
        let bad = |why: String| {
            anyhow::anyhow!(
                "{name}: {why}; bake the store again (or delete the file: the tiles are then \
                 built while flying)"
            )
        };
        let mut head = [0u8; HEADER_BYTES];
        if reader.len() < HEADER_BYTES as u64 {
            return Err(bad("shorter than its header".into()));
        }
        reader.read_at(0, &mut head).with_context(|| format!("reading {name}"))?;
        let header =
            tile_file::parse_header(&head, reader.len()).map_err(|e| bad(e.to_string()))?;
        let (found, want) = (header.key, key_for(store, shape, config));
        if found.bake_id != want.bake_id {
            return Err(bad("written for another bake of the store's blocks".into()));
        }
        if found != (TileFileKey { min_stride_log2: found.min_stride_log2, ..want }) {
            return Ok(None);
        }
        let mut index = vec![0u8; header.tiles as usize * ENTRY_BYTES];
        reader
            .read_at(header.index_offset, &mut index)
            .with_context(|| format!("reading {name}"))?;
        let slots =
            tile_file::parse_index(&index, &header, shape).map_err(|e| bad(e.to_string()))?;
        Ok(Some(Self { reader, shape: *shape, slots }))
    }

    /// Tiles in the file.
    pub fn len(&self) -> usize {
        self.slots.len()
    }

    /// Whether the file holds no tile.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// The stride (log2) tile `node` was built at, if it is baked.
    pub fn stride(&self, node: NodeId) -> Option<u32> {
        self.slots.get(&node).map(|s| s.stride_log2)
    }

    /// Baked tile `node`: `Ok(None)` when it is not baked; an error naming the file when its
    /// bytes are damaged.
    pub fn read(&self, node: NodeId) -> anyhow::Result<Option<GridTile>> {
        let Some(slot) = self.slots.get(&node) else { return Ok(None) };
        let name = self.reader.location();
        let mut bytes = vec![0u8; slot.len as usize];
        self.reader.read_at(slot.offset, &mut bytes).with_context(|| format!("reading {name}"))?;
        tile_file::read_tile(node, slot, &bytes, &self.shape)
            .map(Some)
            .map_err(|e| anyhow::anyhow!("{name}: {e}; bake the store again"))
    }

    /// [`BakedTiles::read`] for a tile the selection takes to lie within `bound` (the
    /// builder's [`GridTileBuilder::tile_bound`]): a tile built within another bound (a
    /// decimation table changed since the tiles were baked) is an error naming the file.
    pub fn read_within(&self, node: NodeId, bound: f64) -> anyhow::Result<Option<GridTile>> {
        let tile = self.read(node)?;
        if let Some(t) = &tile
            && t.bound.to_bits() != bound.to_bits()
        {
            anyhow::bail!(
                "{}: tile {node:?} was built within {} m, but the store's decimation table \
                 gives it {bound} m; bake the store again",
                self.reader.location(),
                t.bound
            );
        }
        Ok(tile)
    }
}
