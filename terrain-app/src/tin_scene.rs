//! The `tin` method's coarse tiles baked into a store (`tin_tiles.bin`): every tile whose own
//! stride is at least `2^BAKED_MIN_STRIDE_LOG2` (a tile spanning 1024 cells or more at the
//! store's 64-cell tiles), built by the builder `tin` from a store builds with at run time
//! ([`store_builder`]: the same function, the same bounds, the same samples), so a frame never
//! waits for a tile meshed from millions of samples: those are read (tens of kilobytes each),
//! and only tiles of at most 512 cells across (262 k samples) are built while flying. The
//! tiles are view-independent, so nothing is lost by building them once. (Baking the 512-cell
//! tiles too drew no more frames at their needed level over the 32769^2 synthetic store, for a
//! file of 997 instead of 361 MiB and 85 s more bake; leaving the 1024-cell ones to the flight
//! drew 94.7 % instead of 96.7 %: bench/ooc/README.md, "The tin method's coarse tiles baked".)
//!
//! `terrain bake` writes the file after the store's blocks (and after a sharded bake's merge),
//! unless `--no-tin`, for the default `tin` settings; a store read with other settings
//! (`--error-scale`, another finest tile size, a vertical exaggeration) builds every tile as
//! before, and so does a store without its table of decimation errors (the tiles' bounds come
//! from it). The file is tied to the store's blocks by their bake id: a file of another bake
//! of them, or a damaged tile, is an error naming the file.
//!
//! Layout (little-endian): a 64-byte header (`TINT`, version, the grid and tree, the
//! settings, the bake id, the tile count and the index's offset), the tiles one after the
//! other, then the index (per tile: level, column, row, stride, offset, length, CRC-32).

use std::collections::HashMap;
use std::io::{Seek, SeekFrom, Write};
use std::time::Instant;

use anyhow::Context;
use rayon::prelude::*;
use terrain_core::checksum::crc32;
use terrain_core::lod::TableReader;
use terrain_core::mesh::verify::MaxError;
use terrain_core::quadtree::{NodeId, NodeTree, TreeShape};
use terrain_core::tin::grid::{GridTile, level_errors, tile_window};
use terrain_stream::{BlockId, SideTable, Store, StoreTree};

use crate::decimation::DECIMATION_REGION;
use crate::method::{GridTileBuilder, TinConfig};
use crate::progress::Progress;
use crate::samples::StoreSamples;

/// The file's name in a store folder.
pub const TIN_TILES_FILE: &str = "tin_tiles.bin";

/// Tiles whose own stride (their 64 cells across at it) is at least `2^this` are baked: at
/// run time the rest are meshed from windows of at most 512 cells across.
pub const BAKED_MIN_STRIDE_LOG2: u32 = 4;

const MAGIC: &[u8; 4] = b"TINT";
const VERSION: u32 = 1;
const HEADER_BYTES: usize = 64;
const ENTRY_BYTES: usize = 32;
/// Tiles built between two writes of the bake (bounds the tiles held in memory).
const CHUNK_TILES: usize = 128;

/// What a file's tiles were built for: a reader uses them only where all of it matches (but
/// `min_stride_log2`, which only says which tiles the file holds).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Key {
    width: u32,
    height: u32,
    root_cells: u32,
    max_level: u32,
    error_scale: f64,
    max_tile_cells: u32,
    finer_strides: u32,
    min_stride_log2: u32,
    bake_id: u64,
}

impl Key {
    fn new(store: &Store, shape: &TreeShape, config: &TinConfig) -> Self {
        Self {
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

/// What [`bake_from_store`] wrote.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TinBakeReport {
    /// Tiles written.
    pub tiles: usize,
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
            "{}: {} of the tin method's coarse tiles ({} triangles), {:.2} MiB, {:.1} s",
            dir.join(TIN_TILES_FILE).display(),
            self.tiles,
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

/// Builds `store`'s coarse `tin` tiles (the default settings, [`TinConfig::default`]; those
/// of `2^BAKED_MIN_STRIDE_LOG2` x 64 cells or more) on every core and writes them into its
/// folder (a temporary file renamed into place, so an interrupted bake leaves no damaged
/// file), with a progress bar when `progress`. `Ok(None)` when the store gets none: no table
/// of decimation errors (a store baked before it), blocks of another size, a vertical
/// exaggeration ([`not_bakeable`]), or a grid with no tile that large.
pub fn bake_from_store(store: &Store, progress: bool) -> anyhow::Result<Option<TinBakeReport>> {
    bake_tiles(store, BAKED_MIN_STRIDE_LOG2, progress)
}

/// [`bake_from_store`] for the tiles whose own stride is at least `2^min_stride_log2` (a
/// reader uses whichever tiles the file holds).
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
    let key = Key { min_stride_log2, ..Key::new(store, &shape, &config) };
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
    key: &Key,
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
    // Progress in samples read: a coarse tile reads up to 4 M of them, a 1024-cell one 1 M.
    let weight = |n: NodeId| -> u64 {
        let s = builder.finest_stride(builder.own_stride(n).unwrap_or(0));
        shape.clipped_rect(n).map_or(0, |r| {
            (u64::from((r.x1 - r.x0) >> s) + 1) * (u64::from((r.y1 - r.y0) >> s) + 1)
        })
    };
    let total = nodes.iter().map(|&n| weight(n)).sum::<u64>() as f64;
    let done = std::sync::atomic::AtomicU64::new(0);
    for chunk in nodes.chunks(CHUNK_TILES) {
        let built: Vec<(NodeId, u32, usize, Vec<u8>)> = chunk
            .par_iter()
            .map(|&n| {
                let t = builder.build(n).with_context(|| format!("tin tile {n:?}"))?;
                let w = weight(n);
                let d = done.fetch_add(w, std::sync::atomic::Ordering::Relaxed) + w;
                bar.update(d as f64, total);
                Ok((n, t.stride_log2, t.triangles.len(), encode_tile(&t, origin(&shape, n)?)))
            })
            .collect::<anyhow::Result<_>>()?;
        for (n, stride, tris, bytes) in built {
            out.write_all(&bytes).with_context(|| io("writing"))?;
            index.extend_from_slice(&entry(n, stride, offset, &bytes));
            offset += bytes.len() as u64;
            triangles += tris as u64;
        }
    }
    bar.finish();
    out.write_all(&index).with_context(|| io("writing"))?;
    let head = header(key, nodes.len() as u32, offset);
    let mut file = out.into_inner().map_err(|e| e.into_error()).with_context(|| io("writing"))?;
    file.seek(SeekFrom::Start(0)).with_context(|| io("writing"))?;
    file.write_all(&head).with_context(|| io("writing"))?;
    file.sync_all().with_context(|| io("writing"))?;
    Ok((triangles, offset + index.len() as u64))
}

/// The south-west sample of tile `n`'s clipped rectangle.
fn origin(shape: &TreeShape, n: NodeId) -> anyhow::Result<[u32; 2]> {
    let r = shape.clipped_rect(n).with_context(|| format!("tile {n:?} lies outside the grid"))?;
    Ok([r.x0, r.y0])
}

fn header(key: &Key, tiles: u32, index_offset: u64) -> Vec<u8> {
    let mut h = Vec::with_capacity(HEADER_BYTES);
    h.extend_from_slice(MAGIC);
    for v in [VERSION, key.width, key.height, key.root_cells, key.max_level] {
        h.extend_from_slice(&v.to_le_bytes());
    }
    h.extend_from_slice(&key.error_scale.to_le_bytes());
    for v in [key.max_tile_cells, key.finer_strides, key.min_stride_log2] {
        h.extend_from_slice(&v.to_le_bytes());
    }
    h.extend_from_slice(&key.bake_id.to_le_bytes());
    h.extend_from_slice(&tiles.to_le_bytes());
    h.extend_from_slice(&index_offset.to_le_bytes());
    h.resize(HEADER_BYTES, 0);
    h
}

fn entry(n: NodeId, stride: u32, offset: u64, bytes: &[u8]) -> [u8; ENTRY_BYTES] {
    let mut e = [0u8; ENTRY_BYTES];
    e[0..4].copy_from_slice(&u32::from(n.level).to_le_bytes());
    e[4..8].copy_from_slice(&n.i.to_le_bytes());
    e[8..12].copy_from_slice(&n.j.to_le_bytes());
    e[12..16].copy_from_slice(&stride.to_le_bytes());
    e[16..24].copy_from_slice(&offset.to_le_bytes());
    e[24..28].copy_from_slice(&(bytes.len() as u32).to_le_bytes());
    e[28..32].copy_from_slice(&crc32(bytes).to_le_bytes());
    e
}

/// Tile `t` in bytes, its vertices as offsets from `origin` (16 bits each where they fit)
/// and its indices in 16 bits where it has at most 65,536 vertices.
fn encode_tile(t: &GridTile, origin: [u32; 2]) -> Vec<u8> {
    let span = t.vertices.iter().map(|v| (v[0] - origin[0]).max(v[1] - origin[1])).max();
    let wide_xy = span.unwrap_or(0) > u32::from(u16::MAX);
    let wide_idx = t.vertices.len() > 1 << 16;
    let sides: usize = t.sides.iter().map(Vec::len).sum();
    let mut b = Vec::with_capacity(64 + t.vertices.len() * 8 + t.triangles.len() * 6 + sides * 2);
    let put32 = |b: &mut Vec<u8>, v: u32| b.extend_from_slice(&v.to_le_bytes());
    let idx = |b: &mut Vec<u8>, v: u32| {
        if wide_idx {
            b.extend_from_slice(&v.to_le_bytes())
        } else {
            b.extend_from_slice(&(v as u16).to_le_bytes())
        }
    };
    b.push(u8::from(wide_xy) | u8::from(wide_idx) << 1);
    b.push(t.stride_log2 as u8);
    put32(&mut b, t.vertices.len() as u32);
    put32(&mut b, t.triangles.len() as u32);
    for s in &t.sides {
        put32(&mut b, s.len() as u32);
    }
    b.extend_from_slice(&t.bound.to_le_bytes());
    b.extend_from_slice(&t.range[0].to_le_bytes());
    b.extend_from_slice(&t.range[1].to_le_bytes());
    b.extend_from_slice(&t.measured.max_error.to_le_bytes());
    b.extend_from_slice(&(t.measured.samples as u64).to_le_bytes());
    let worst = t.measured.worst.map_or([u64::MAX; 2], |(i, j)| [i as u64, j as u64]);
    b.extend_from_slice(&worst[0].to_le_bytes());
    b.extend_from_slice(&worst[1].to_le_bytes());
    for v in &t.vertices {
        for (c, o) in v.iter().zip(origin) {
            if wide_xy {
                put32(&mut b, c - o)
            } else {
                b.extend_from_slice(&((c - o) as u16).to_le_bytes())
            }
        }
    }
    for z in &t.heights {
        b.extend_from_slice(&z.to_le_bytes());
    }
    for tri in &t.triangles {
        for &v in tri {
            idx(&mut b, v);
        }
    }
    for s in &t.sides {
        for &v in s {
            idx(&mut b, v);
        }
    }
    b
}

/// Reads values off a tile's bytes, failing on a short one.
struct Cursor<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Cursor<'_> {
    fn take(&mut self, n: usize) -> anyhow::Result<&[u8]> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        let end = end.context("a tile shorter than its counts")?;
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn u8(&mut self) -> anyhow::Result<u8> {
        Ok(self.take(1)?[0])
    }
    fn u16(&mut self) -> anyhow::Result<u16> {
        Ok(u16::from_le_bytes(self.take(2)?.try_into()?))
    }
    fn u32(&mut self) -> anyhow::Result<u32> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into()?))
    }
    fn u64(&mut self) -> anyhow::Result<u64> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into()?))
    }
    fn f32(&mut self) -> anyhow::Result<f32> {
        Ok(f32::from_le_bytes(self.take(4)?.try_into()?))
    }
    fn f64(&mut self) -> anyhow::Result<f64> {
        Ok(f64::from_le_bytes(self.take(8)?.try_into()?))
    }
}

/// The tile [`encode_tile`] wrote for `node` at `origin`.
fn decode_tile(node: NodeId, bytes: &[u8], origin: [u32; 2]) -> anyhow::Result<GridTile> {
    let mut c = Cursor { bytes, at: 0 };
    let flags = c.u8()?;
    let (wide_xy, wide_idx) = (flags & 1 != 0, flags & 2 != 0);
    let stride_log2 = u32::from(c.u8()?);
    let (nv, nt) = (c.u32()? as usize, c.u32()? as usize);
    let mut side_lens = [0usize; 4];
    for s in &mut side_lens {
        *s = c.u32()? as usize;
    }
    // Counts checked against the bytes before anything is allocated by them.
    let (xy, ix) = (if wide_xy { 4 } else { 2 }, if wide_idx { 4 } else { 2 });
    let need = nv
        .checked_mul(2 * xy + 4)
        .zip(nt.checked_mul(3 * ix))
        .and_then(|(a, b)| a.checked_add(b)?.checked_add(side_lens.iter().sum::<usize>() * ix));
    // (After the counts: the bound, the range, the measured error, its samples and worst.)
    let left = bytes.len() - c.at;
    anyhow::ensure!(
        need.and_then(|n| n.checked_add(48)).is_some_and(|n| n <= left),
        "a tile's counts exceed its bytes"
    );
    let bound = c.f64()?;
    let range = [c.f32()?, c.f32()?];
    let max_error = c.f64()?;
    let samples = c.u64()? as usize;
    let worst = [c.u64()?, c.u64()?];
    let worst = (worst != [u64::MAX; 2]).then(|| (worst[0] as usize, worst[1] as usize));
    let mut vertices = Vec::with_capacity(nv);
    for _ in 0..nv {
        let mut v = [0u32; 2];
        for (k, o) in origin.iter().enumerate() {
            let d = if wide_xy { c.u32()? } else { u32::from(c.u16()?) };
            v[k] = o.checked_add(d).context("a vertex past the grid")?;
        }
        vertices.push(v);
    }
    let heights = (0..nv).map(|_| c.f32()).collect::<anyhow::Result<Vec<f32>>>()?;
    let index = |c: &mut Cursor<'_>| -> anyhow::Result<u32> {
        let v = if wide_idx { c.u32()? } else { u32::from(c.u16()?) };
        anyhow::ensure!((v as usize) < nv, "a vertex index past the tile's vertices");
        Ok(v)
    };
    let mut triangles = Vec::with_capacity(nt);
    for _ in 0..nt {
        triangles.push([index(&mut c)?, index(&mut c)?, index(&mut c)?]);
    }
    let mut sides: [Vec<u32>; 4] = Default::default();
    for (s, &n) in sides.iter_mut().zip(&side_lens) {
        *s = (0..n).map(|_| index(&mut c)).collect::<anyhow::Result<_>>()?;
    }
    anyhow::ensure!(c.at == bytes.len(), "a tile longer than its counts");
    Ok(GridTile {
        node,
        vertices,
        heights,
        stride_log2,
        range,
        triangles,
        sides,
        bound,
        measured: MaxError { max_error, samples, worst },
    })
}

/// Where a baked tile lies in the file.
#[derive(Debug, Clone, Copy)]
struct Slot {
    stride_log2: u32,
    offset: u64,
    len: u32,
    crc: u32,
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
        if &head[0..4] != MAGIC {
            return Err(bad("not a table of tin tiles".into()));
        }
        let u32_at = |o: usize| u32::from_le_bytes(head[o..o + 4].try_into().unwrap());
        let u64_at = |o: usize| u64::from_le_bytes(head[o..o + 8].try_into().unwrap());
        if u32_at(4) != VERSION {
            return Err(bad(format!("version {}, this build reads {VERSION}", u32_at(4))));
        }
        let found = Key {
            width: u32_at(8),
            height: u32_at(12),
            root_cells: u32_at(16),
            max_level: u32_at(20),
            error_scale: f64::from_le_bytes(head[24..32].try_into().unwrap()),
            max_tile_cells: u32_at(32),
            finer_strides: u32_at(36),
            min_stride_log2: u32_at(40),
            bake_id: u64_at(44),
        };
        let want = Key::new(store, shape, config);
        if found.bake_id != want.bake_id {
            return Err(bad("written for another bake of the store's blocks".into()));
        }
        if found != (Key { min_stride_log2: found.min_stride_log2, ..want }) {
            return Ok(None);
        }
        let (tiles, index_offset) = (u32_at(52) as u64, u64_at(56));
        let index_len = tiles * ENTRY_BYTES as u64;
        if index_offset.checked_add(index_len) != Some(reader.len()) {
            return Err(bad(format!(
                "{} bytes, its index says {}",
                reader.len(),
                index_offset + index_len
            )));
        }
        let mut index = vec![0u8; index_len as usize];
        reader.read_at(index_offset, &mut index).with_context(|| format!("reading {name}"))?;
        let mut slots = HashMap::with_capacity(tiles as usize);
        for e in index.chunks_exact(ENTRY_BYTES) {
            let u = |o: usize| u32::from_le_bytes(e[o..o + 4].try_into().unwrap());
            let level = u8::try_from(u(0)).map_err(|_| bad("a tile of a level past 255".into()))?;
            let node = NodeId::new(level, u(4), u(8));
            let slot = Slot {
                stride_log2: u(12),
                offset: u64::from_le_bytes(e[16..24].try_into().unwrap()),
                len: u(24),
                crc: u(28),
            };
            if slot.offset.checked_add(u64::from(slot.len)).is_none_or(|end| end > index_offset)
                || shape.clipped_rect(node).is_none()
            {
                return Err(bad(format!("tile {node:?} lies outside the file or the grid")));
            }
            slots.insert(node, slot);
        }
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
        let damaged =
            |why: String| anyhow::anyhow!("{name}: tile {node:?} {why}; bake the store again");
        if crc32(&bytes) != slot.crc {
            return Err(damaged("fails its checksum".into()));
        }
        let tile = decode_tile(node, &bytes, origin(&self.shape, node)?)
            .map_err(|e| damaged(format!("is damaged ({e:#})")))?;
        if tile.stride_log2 != slot.stride_log2 {
            return Err(damaged("has another stride than its index says".into()));
        }
        Ok(Some(tile))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tile() -> GridTile {
        GridTile {
            node: NodeId::new(1, 1, 0),
            vertices: vec![[512, 0], [1024, 0], [512, 512], [1024, 512]],
            heights: vec![1.0, -2.5, 3.25, 8848.0],
            stride_log2: 3,
            range: [-2.5, 8848.0],
            triangles: vec![[0, 1, 3], [0, 3, 2]],
            sides: [vec![2, 3], vec![1, 3], vec![0, 1], vec![0, 2]],
            bound: 12.5,
            measured: MaxError { max_error: 3.0, samples: 4225, worst: Some((700, 3)) },
        }
    }

    fn same(a: &GridTile, b: &GridTile) {
        assert_eq!(a.node, b.node);
        assert_eq!(a.vertices, b.vertices);
        assert_eq!(
            a.heights.iter().map(|z| z.to_bits()).collect::<Vec<_>>(),
            b.heights.iter().map(|z| z.to_bits()).collect::<Vec<_>>()
        );
        assert_eq!(
            (a.stride_log2, a.range, &a.triangles, &a.sides),
            (b.stride_log2, b.range, &b.triangles, &b.sides)
        );
        assert_eq!((a.bound.to_bits(), a.measured), (b.bound.to_bits(), b.measured));
    }

    #[test]
    fn a_tile_decodes_to_itself_narrow_and_wide() {
        let t = tile();
        let bytes = encode_tile(&t, [512, 0]);
        same(&decode_tile(t.node, &bytes, [512, 0]).unwrap(), &t);
        // Offsets past 16 bits and no worst sample.
        let mut w = t.clone();
        w.vertices[3] = [512 + 70_000, 70_000];
        w.measured.worst = None;
        let bytes = encode_tile(&w, [512, 0]);
        assert_eq!(bytes[0] & 1, 1, "wide offsets");
        same(&decode_tile(w.node, &bytes, [512, 0]).unwrap(), &w);
    }

    /// Every byte of a tile set to each of a few values (its counts, flags and offsets among
    /// them): decoding returns a tile or an error, never panics, and never allocates by a count
    /// its bytes cannot hold.
    #[test]
    fn mutated_tiles_decode_or_fail_without_panicking() {
        let t = tile();
        let bytes = encode_tile(&t, [512, 0]);
        let (mut ok, mut failed) = (0, 0);
        for at in 0..bytes.len() {
            for v in [0u8, 1, 0x7f, 0x80, 0xff] {
                let mut m = bytes.clone();
                m[at] = v;
                match decode_tile(t.node, &m, [512, 0]) {
                    Ok(d) => {
                        ok += 1;
                        assert_eq!(d.heights.len(), d.vertices.len());
                    }
                    Err(_) => failed += 1,
                }
            }
        }
        assert!(ok > 0 && failed > 0, "{ok} decoded, {failed} refused");
        // Offsets past the grid's coordinates.
        assert!(decode_tile(t.node, &bytes, [u32::MAX - 10, 0]).is_err());
    }

    #[test]
    fn a_truncated_or_lengthened_tile_is_an_error_not_a_panic() {
        let t = tile();
        let bytes = encode_tile(&t, [512, 0]);
        for n in 0..bytes.len() {
            assert!(decode_tile(t.node, &bytes[..n], [512, 0]).is_err(), "cut at {n}");
        }
        let mut long = bytes.clone();
        long.push(0);
        assert!(decode_tile(t.node, &long, [512, 0]).is_err());
        // A count far past the bytes.
        let mut huge = bytes;
        huge[2..6].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(decode_tile(t.node, &huge, [512, 0]).is_err());
    }
}
