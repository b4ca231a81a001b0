//! Where `terrain tiles` and the `tin` method over a store read heights from, one window at a time and at a power-of-two
//! stride: a DEM in memory ([`HeightmapSamples`]) or a baked store ([`StoreSamples`]), whose
//! blocks are read level by level (a stride of `2^s` needs only block levels `0..=k - s`,
//! the store's non-redundant levels, Qiu 2013 Eq. 1-2) through a byte-budgeted LRU cache of
//! decoded blocks, so the memory the tiles take is bounded by that cache, not by the DEM.
//!
//! Both sources answer the same question the same way (indices past the last row or column
//! read the last one, as the store's padding does), so a tileset built from a losslessly baked
//! store is the one built from its DEM in memory.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use terrain_core::Heightmap;
use terrain_core::heightmap::VoidMask;
use terrain_stream::{BlockId, BlockLevels, Store, vertex_level};

/// A window of samples: `width` x (`data.len() / width`) heights (row-major, south row first)
/// and voids.
#[derive(Debug, Clone)]
pub struct Window {
    /// Columns.
    pub width: usize,
    /// Heights, row-major, south row first.
    pub data: Vec<f32>,
    /// `None`: no void in the window.
    pub voids: Option<VoidMask>,
}

/// Heights of a grid, read by windows.
pub trait Samples: Sync {
    /// Columns and rows of the grid.
    fn size(&self) -> (usize, usize);
    /// The samples at columns `i0 + a t` and rows `j0 + b t` for `a < width`, `b < height`
    /// (`t = 2^stride_log2`); an index past the last column or row reads the last one.
    fn window(
        &self,
        i0: usize,
        j0: usize,
        width: usize,
        height: usize,
        stride_log2: u32,
    ) -> anyhow::Result<Window>;
}

/// A window's grid index along one axis: its `a`-th sample from `start` every `2^stride_log2`
/// samples, clamped to the last of `len` (the window's far edge lands on the grid's border).
fn strided(start: usize, stride_log2: u32, len: usize) -> impl Fn(usize) -> usize {
    move |a| (start + (a << stride_log2)).min(len - 1)
}

/// Any source with its voids read as data (the reader's fill): what the `tin` method meshes,
/// so that over a void it draws what every other method draws and what a store holds (a store
/// keeps no void mask).
#[derive(Debug)]
pub struct VoidsAsData<S>(pub S);

impl<S: Samples> Samples for VoidsAsData<S> {
    fn size(&self) -> (usize, usize) {
        self.0.size()
    }

    fn window(
        &self,
        i0: usize,
        j0: usize,
        width: usize,
        height: usize,
        stride_log2: u32,
    ) -> anyhow::Result<Window> {
        let mut w = self.0.window(i0, j0, width, height, stride_log2)?;
        w.voids = None;
        Ok(w)
    }
}

/// A DEM in memory.
#[derive(Debug)]
pub struct HeightmapSamples<'a>(pub &'a Heightmap);

impl Samples for HeightmapSamples<'_> {
    fn size(&self) -> (usize, usize) {
        (self.0.width(), self.0.height())
    }

    fn window(
        &self,
        i0: usize,
        j0: usize,
        width: usize,
        height: usize,
        stride_log2: u32,
    ) -> anyhow::Result<Window> {
        let hm = self.0;
        let w = hm.width();
        let col = strided(i0, stride_log2, w);
        let row = strided(j0, stride_log2, hm.height());
        let mut data = Vec::with_capacity(width * height);
        // At stride 1 a row is one slice unless it runs past the grid's last column.
        let contiguous = stride_log2 == 0 && i0 + width <= w;
        for b in 0..height {
            let r = row(b) * w;
            if contiguous {
                data.extend_from_slice(&hm.data()[r + i0..r + i0 + width]);
            } else {
                data.extend((0..width).map(|a| hm.data()[r + col(a)]));
            }
        }
        let voids = hm.voids().any().then(|| {
            let mut m = VoidMask::new(width, height);
            for b in 0..height {
                // Rows with no void between the window's first and last column are skipped.
                if !hm.voids().any_in_row(row(b), col(0), col(width.saturating_sub(1))) {
                    continue;
                }
                for a in 0..width {
                    if hm.voids().get(col(a), row(b)) {
                        m.set(a, b, true);
                    }
                }
            }
            m
        });
        Ok(Window { width, data, voids })
    }
}

/// A baked store, read through a byte-budgeted LRU cache of decoded block levels.
#[derive(Debug)]
pub struct StoreSamples {
    store: Store,
    cache: Mutex<BlockCache>,
}

/// A decoded block in the cache.
#[derive(Debug, Clone)]
enum Cached {
    /// Levels `0..n`, `n <= k` (a strided window needs no finer one): read vertex by vertex,
    /// and a finer level is decoded on top of them.
    Levels(Arc<BlockLevels>),
    /// Every level: the block's `(2^k + 1)^2` heights, row-major from its south-west vertex
    /// (`BlockLevels::grid(k)`, the same bytes as the levels it replaces). Nothing finer can be
    /// asked for, so the levels are dropped and a window copies rows instead of finding each
    /// vertex's level and order (most of the samples of a tileset are read at stride 1).
    Grid(Arc<[f32]>),
}

impl Cached {
    fn bytes(&self) -> u64 {
        match self {
            Cached::Levels(b) => b.bytes(),
            Cached::Grid(g) => std::mem::size_of_val::<[f32]>(g) as u64,
        }
    }
}

/// Decoded blocks (levels `0..n`), least recently used dropped first while over the budget.
#[derive(Debug)]
struct BlockCache {
    budget: u64,
    resident: u64,
    clock: u64,
    blocks: HashMap<BlockId, (Cached, u64)>,
    /// Most bytes resident at once.
    peak: u64,
    /// Block levels decoded.
    decoded: u64,
}

impl StoreSamples {
    /// Reads `store` with at most `budget` bytes of decoded blocks resident (one block more
    /// while a read that needs it is under way per thread).
    pub fn new(store: Store, budget: u64) -> Self {
        let cache = BlockCache {
            budget,
            resident: 0,
            clock: 0,
            blocks: HashMap::new(),
            peak: 0,
            decoded: 0,
        };
        Self { store, cache: Mutex::new(cache) }
    }

    /// Cells per block side: windows aligned to blocks read each block once.
    pub fn block_cells(&self) -> usize {
        self.store.header().block_cells() as usize
    }

    /// The most bytes of decoded blocks kept (one block more per thread reading).
    pub fn budget(&self) -> u64 {
        self.cache.lock().unwrap_or_else(|e| e.into_inner()).budget
    }

    /// The most bytes of decoded blocks resident at once, and the block levels decoded.
    pub fn cache_stats(&self) -> (u64, u64) {
        let c = self.cache.lock().unwrap_or_else(|e| e.into_inner());
        (c.peak, c.decoded)
    }

    /// Block `id` with levels `0..=level` decoded.
    fn block(&self, id: BlockId, level: u8) -> anyhow::Result<Cached> {
        let have = {
            let mut c = self.cache.lock().unwrap_or_else(|e| e.into_inner());
            c.clock += 1;
            let now = c.clock;
            match c.blocks.get_mut(&id) {
                Some((b, used)) => {
                    *used = now;
                    match b {
                        Cached::Grid(_) => return Ok(b.clone()),
                        Cached::Levels(l) if l.count() > level as usize => return Ok(b.clone()),
                        Cached::Levels(l) => Some(l.clone()),
                    }
                }
                None => None,
            }
        };
        // Decode outside the lock, on top of the coarser levels already decoded.
        let k = self.store.header().k;
        let mut b = match have {
            Some(b) => (*b).clone(),
            None => BlockLevels::new(self.store.header()),
        };
        let from = b.count() as u8;
        for l in from..=level {
            let loaded = self.store.load_level(id, l, b.levels())?;
            b.push(loaded.samples);
        }
        let b = match b.grid(k) {
            Some(g) => Cached::Grid(g.into()),
            None => Cached::Levels(Arc::new(b)),
        };
        let mut c = self.cache.lock().unwrap_or_else(|e| e.into_inner());
        c.decoded += u64::from(level + 1 - from);
        c.clock += 1;
        let now = c.clock;
        let bytes = b.bytes();
        if let Some((old, _)) = c.blocks.insert(id, (b.clone(), now)) {
            c.resident -= old.bytes();
        }
        c.resident += bytes;
        c.peak = c.peak.max(c.resident);
        while c.resident > c.budget && c.blocks.len() > 1 {
            let Some((&lru, _)) =
                c.blocks.iter().filter(|(k, _)| **k != id).min_by_key(|(_, (_, used))| *used)
            else {
                break;
            };
            if let Some((gone, _)) = c.blocks.remove(&lru) {
                c.resident -= gone.bytes();
            }
        }
        Ok(b)
    }
}

impl Samples for StoreSamples {
    fn size(&self) -> (usize, usize) {
        let h = self.store.header();
        (h.width as usize, h.height as usize)
    }

    fn window(
        &self,
        i0: usize,
        j0: usize,
        width: usize,
        height: usize,
        stride_log2: u32,
    ) -> anyhow::Result<Window> {
        let h = self.store.header();
        let (w, ht) = (h.width as usize, h.height as usize);
        let k = h.k;
        let cells = 1usize << k;
        let col = strided(i0, stride_log2, w);
        let row = strided(j0, stride_log2, ht);
        // A sample on a block border belongs to both blocks; read it from the one west or
        // south of it only past the last block.
        let block_of = |g: usize, n: u32| ((g / cells) as u32).min(n - 1);
        let mut data = vec![0f32; width * height];
        // Per block row and column: which window rows/columns fall in it.
        let group = |len: usize, at: &dyn Fn(usize) -> usize, n: u32| {
            let mut spans: Vec<(u32, Vec<usize>)> = Vec::new();
            for a in 0..len {
                let blk = block_of(at(a), n);
                match spans.last_mut() {
                    Some((b, v)) if *b == blk => v.push(a),
                    _ => spans.push((blk, vec![a])),
                }
            }
            spans
        };
        let cols = group(width, &col, h.blocks_x);
        let rows = group(height, &row, h.blocks_y);
        for (brow, bs) in &rows {
            for (bcol, as_) in &cols {
                let (ox, oy) = (*bcol as usize * cells, *brow as usize * cells);
                let local = |g: usize, o: usize| (g - o) as u32;
                // The finest level any of these samples needs.
                let lx = as_.iter().map(|&a| vertex_level(k, local(col(a), ox), 0)).max();
                let ly = bs.iter().map(|&b| vertex_level(k, 0, local(row(b), oy))).max();
                let level = lx.unwrap_or(0).max(ly.unwrap_or(0));
                let id = BlockId::new(*brow, *bcol);
                match self.block(id, level)? {
                    Cached::Grid(g) => {
                        let n = cells + 1;
                        let lis: Vec<usize> = as_.iter().map(|&a| col(a) - ox).collect();
                        for &b in bs {
                            let src = &g[(row(b) - oy) * n..][..n];
                            let out = &mut data[b * width..][..width];
                            for (&a, &li) in as_.iter().zip(&lis) {
                                out[a] = src[li];
                            }
                        }
                    }
                    Cached::Levels(blk) => {
                        for &b in bs {
                            let lj = local(row(b), oy);
                            for &a in as_ {
                                let li = local(col(a), ox);
                                data[b * width + a] = blk.height(li, lj).ok_or_else(|| {
                                    anyhow::anyhow!(
                                        "store block {id}: vertex ({li}, {lj}) not decoded"
                                    )
                                })?;
                            }
                        }
                    }
                }
            }
        }
        Ok(Window { width, data, voids: None })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::ops::ControlFlow;
    use terrain_core::Georef;
    use terrain_stream::{BakeConfig, HeightEncoding};

    /// A losslessly baked store reads every window as the DEM in memory does, bit for bit: at
    /// every stride, over block borders and past the grid's last row and column, through a
    /// cache so small that blocks are dropped and read again, and whether a block is held as
    /// its coarse levels (strided windows first) or as its whole grid (stride 1).
    #[test]
    fn a_store_reads_every_window_as_its_dem_in_memory() {
        let hm = Heightmap::from_fn(75, 53, Georef::local(10.0), |i, j| {
            let (x, y) = (i as f32 * 0.11, j as f32 * 0.07);
            900.0 + 80.0 * x.sin() * y.cos() + 2.7 * (i as f32 * 1.9).sin() + j as f32 * 0.37
        })
        .unwrap();
        // Removed when dropped, also when the test panics.
        let tmp = tempfile::Builder::new().prefix("terrain-app-samples-").tempdir().unwrap();
        let dir = tmp.path().join("store");
        let cfg = BakeConfig { k: 4, encoding: HeightEncoding::F32, ..Default::default() };
        terrain_stream::bake(&hm, &dir, &cfg, &mut |_| ControlFlow::Continue(())).unwrap();
        let memory = HeightmapSamples(&hm);
        // About three decoded 17^2 blocks resident.
        let store = StoreSamples::new(Store::open(&dir).unwrap(), 3 * 17 * 17 * 4);
        assert_eq!(store.size(), memory.size());
        let mut windows = 0;
        for stride in [3u32, 2, 1, 0] {
            for (i0, j0) in [(0, 0), (5, 9), (16, 16), (31, 2), (60, 40), (74, 52)] {
                for (w, h) in [(1, 1), (9, 4), (17, 17), (40, 23), (80, 60)] {
                    let a = memory.window(i0, j0, w, h, stride).unwrap();
                    let b = store.window(i0, j0, w, h, stride).unwrap();
                    assert_eq!(a.width, b.width);
                    let bits = |d: &[f32]| d.iter().map(|z| z.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&a.data), bits(&b.data), "({i0}, {j0}) {w}x{h} 2^{stride}");
                    windows += 1;
                }
            }
        }
        assert_eq!(windows, 120);
        let (peak, decoded) = store.cache_stats();
        assert!(peak <= 4 * 17 * 17 * 4, "the budget and one block more: {peak}");
        // 5 x 4 blocks: more block levels decoded than the store holds (blocks dropped and read
        // again), so both the levels and the grids were read.
        assert!(decoded > 20 * 5, "{decoded} block levels decoded");
    }
}
