//! `tin` drawn from a baked store: the tiles of the TIN pyramid are built on demand, on a
//! small pool of worker threads, from the store's blocks ([`crate::samples::StoreSamples`],
//! the reader `terrain tiles` uses, through its byte-budgeted block cache) by the builder of
//! the pyramid in memory ([`super::GridTileBuilder`]: the stride each tile's level allows,
//! within its bound less the decimation error under it, checked against every sample under
//! it), and kept in a byte-budgeted LRU cache of built tiles
//! ([`TinTiles`]). Nothing of the full grid is in memory. The coarse tiles (512 cells or more
//! across) a store's bake built ([`crate::tin_scene`], `tin_tiles.bin`) are read instead of
//! built: the same tiles, bit for bit.
//!
//! Per frame: the tiles are selected over the store's index ([`select_tiles`], the same
//! function and bounds as from memory: the same tiles for the same camera), the missing ones
//! (and their missing ancestors, coarse first; a waiting frame queues its own tiles only) are
//! queued for the workers, and the frame draws
//! what is built: a tile not built yet is drawn by its nearest built ancestor (coarser; the
//! selected tiles under that ancestor go with it, so the drawn tiles stay disjoint), and
//! counted late ([`crate::ooc::StreamRecord::late_tiles`]). A real-time frame also selects
//! the tiles of the eye one look-ahead ahead (Eq. 8, [`terrain_stream::Streamer::camera_ahead`]):
//! they are queued after its own, and the carriers of the built tiles that would draw them
//! ([`TinTiles::peek`]) and of the tiles being built ([`TinTiles::planned_patches`]) are the
//! streamer's demand ahead. With that table no coarse tile reads every sample under it: a tile
//! is meshed at most [`terrain_core::tin::grid::GridTinConfig::finer_strides`] strides finer
//! than its own, its bound raised where that needs it ([`GridTileBuilder::tile_bound`], which
//! the selection uses). Selection never waits, except on the first frame and with `--wait`
//! ([`OocWait::EveryFrame`], the benchmark's warm mode), which waits until every selected tile
//! is built; a real-time run's first frame then also waits for the tiles of its start view (a
//! wider view at half the threshold, within the tile cache's budget: it knows no motion for
//! Eq. 8 yet, `start_camera`). The drawn surface ([`tin_surface`]: tiles and
//! stitches) takes every vertex's height from its tile; the paged renderer draws the same
//! triangles, at the same heights ([`ExtraTriangles::heights`]), as extra triangles over each
//! tile's hidden carrier patch, whose lattice at the tile's own stride (64 cells across) is
//! the streamer's demand ([`TinTiles::carriers`]): the pages shade the tiles, at their level
//! of detail, and never decide their geometry, so a coarse tile meshed from every sample under
//! it does not demand every sample (the demand of the first `fast_pass` frame over the
//! mirrored Everest was 1 GiB when it did).

use std::collections::{HashMap, HashSet, VecDeque};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use terrain_core::geometry::Camera;
use terrain_core::lod::{Patch, Selection, SelectionStats};
use terrain_core::quadtree::{NodeId, TreeShape};
use terrain_core::tin::grid::{
    GridTile, SurfaceSink, TinSelection, select_tiles, tin_surface, tin_surface_into,
};
use terrain_gpu::render::ExtraTriangles;
use terrain_gpu::tess::GpuDomainPoint;
use terrain_stream::{Store, StoreTree};

use super::memory::ms;
use super::ooc::paged_frame;
use super::{DrawSource, DrawnSurface, Frame, GridTileBuilder, Method, OocWait, TinConfig};
use crate::methods::{LodMethod, MethodScene};
use crate::ooc::{OocScene, StoreDraw};
use crate::samples::StoreSamples;
use crate::tin_scene::{BakedTiles, store_builder, store_tree};

/// How `tin` reads a store.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TinStoreConfig {
    /// Most bytes of built tiles kept (least recently drawn dropped first; the tiles of the
    /// frame being drawn are kept even past it). Default 128 MiB (a `fast_pass` frame over the
    /// 32769^2 synthetic store draws about 30 MB of them at 320 x 180).
    pub tile_cache_bytes: u64,
    /// Most bytes of decoded store blocks the tile builders keep. Default 256 MiB.
    pub block_cache_bytes: u64,
    /// The same where the store has its coarse tiles baked ([`crate::tin_scene`]): the tiles
    /// built while flying then span at most 256 cells (one to four blocks). Default 32 MiB.
    pub block_cache_bytes_baked: u64,
    /// Tile builder threads.
    pub threads: usize,
    /// Most cells across a tile's mesh input ([`terrain_core::tin::grid::tile_window`]).
    pub max_tile_cells: u32,
    /// Longest a waiting frame waits for its tiles.
    pub wait_timeout: Duration,
}

impl Default for TinStoreConfig {
    fn default() -> Self {
        Self {
            tile_cache_bytes: 128 << 20,
            block_cache_bytes: 256 << 20,
            block_cache_bytes_baked: 32 << 20,
            threads: 2,
            max_tile_cells: 64,
            wait_timeout: Duration::from_secs(600),
        }
    }
}

/// A built tile in the cache and the frame that last drew it.
#[derive(Debug)]
struct Entry {
    tile: Arc<GridTile>,
    used: u64,
}

/// The cache's state, under one lock.
#[derive(Debug, Default)]
struct State {
    tiles: HashMap<NodeId, Entry>,
    bytes: u64,
    /// Frames resolved so far; tiles used by the current one are not evicted.
    frame: u64,
    queue: VecDeque<NodeId>,
    building: HashSet<NodeId>,
    failed: HashMap<NodeId, String>,
    stop: bool,
    peak_bytes: u64,
    built: u64,
    /// Of `built`, tiles read from the store's baked tiles.
    read: u64,
    evicted: u64,
}

#[derive(Debug)]
struct Shared {
    builder: GridTileBuilder<StoreSamples>,
    /// The store's baked coarse tiles ([`crate::tin_scene`]), read instead of built.
    baked: Option<BakedTiles>,
    budget: u64,
    state: Mutex<State>,
    work: Condvar,
    done: Condvar,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Tile `node` from the store's samples: [`GridTileBuilder::build`], the builder of the
    /// pyramid in memory (its window's stride, the budget less the decimation error under it,
    /// checked against every sample under it); a baked tile is read instead
    /// ([`BakedTiles::read_within`] the bound the selection took), and the flag says so.
    ///
    /// A built tile is seeded by its parent's vertices ([`GridTileBuilder::build`], as the
    /// bake and the pyramid in memory seed it): the parent comes from the cache, else is read
    /// or built first (and kept).
    fn build(&self, node: NodeId) -> anyhow::Result<(GridTile, bool)> {
        let bound = || self.builder.tile_bound(node);
        let baked = self.baked.as_ref().map(|b| b.read_within(node, bound()));
        if let Some(tile) = baked.transpose()?.flatten() {
            return Ok((tile, true));
        }
        let parent = node.parent().map(|p| self.tile(p)).transpose()?;
        let seeds = parent.as_ref().map_or(&[][..], |t| &t.vertices[..]);
        Ok((self.builder.build(node, seeds)?, false))
    }

    /// Tile `node` from the cache, else read or built and kept. A tile another thread is
    /// reading or building (a queued tile a worker took, or another child's parent) is waited
    /// for, not built twice: each builder marks its tile in `building` as the workers do. (Until
    /// 2026-12-06 a parent fetched here was not marked, and a worker could take it from the
    /// queue meanwhile: read twice, which `baked_coarse_tiles_are_the_tiles_built_while_flying`
    /// caught about once in six runs.) Waits only go to ancestors (a builder asks for its
    /// tile's parent), so they cannot form a cycle.
    fn tile(&self, node: NodeId) -> anyhow::Result<Arc<GridTile>> {
        let mut st = self.lock();
        loop {
            if let Some(e) = st.tiles.get(&node) {
                return Ok(e.tile.clone());
            }
            if st.building.insert(node) {
                break;
            }
            st = self.done.wait(st).unwrap_or_else(|e| e.into_inner());
        }
        drop(st);
        let built = self.build(node);
        self.finish(&mut self.lock(), node, built)
    }

    /// Ends the build of `node` (marked in `building` by its builder, a worker or
    /// [`Shared::tile`]): unmarked, kept when built, and every waiter woken.
    fn finish(
        &self,
        st: &mut State,
        node: NodeId,
        built: anyhow::Result<(GridTile, bool)>,
    ) -> anyhow::Result<Arc<GridTile>> {
        st.building.remove(&node);
        let out = built.map(|(tile, read)| {
            let tile = Arc::new(tile);
            self.insert(st, node, tile.clone(), read);
            tile
        });
        self.done.notify_all();
        out
    }

    /// Keeps built tile `node` (read from the baked tiles when `read`), within the budget.
    fn insert(&self, st: &mut State, node: NodeId, tile: Arc<GridTile>, read: bool) {
        st.read += u64::from(read);
        let used = st.frame;
        if let Some(old) = st.tiles.insert(node, Entry { tile: tile.clone(), used }) {
            st.bytes -= old.tile.bytes();
        } else {
            st.built += 1;
        }
        st.bytes += tile.bytes();
        st.peak_bytes = st.peak_bytes.max(st.bytes);
        self.evict(st);
    }

    /// Drops least recently drawn tiles while over the budget: not the current frame's (the
    /// tiles it draws, and those built since the last frame was resolved).
    fn evict(&self, st: &mut State) {
        while st.bytes > self.budget {
            let frame = st.frame;
            let Some((&lru, _)) =
                st.tiles.iter().filter(|(_, e)| e.used < frame).min_by_key(|(_, e)| e.used)
            else {
                break;
            };
            if let Some(e) = st.tiles.remove(&lru) {
                st.bytes -= e.tile.bytes();
                st.evicted += 1;
            }
        }
    }

    fn worker(&self) {
        loop {
            let node = {
                let mut st = self.lock();
                loop {
                    if st.stop {
                        return;
                    }
                    if let Some(n) = st.queue.pop_front() {
                        if st.tiles.contains_key(&n) || !st.building.insert(n) {
                            continue;
                        }
                        break n;
                    }
                    st = self.work.wait(st).unwrap_or_else(|e| e.into_inner());
                }
            };
            let built = self.build(node);
            let mut st = self.lock();
            // (The waiters run once this thread lets go of the lock, the failure recorded.)
            if let Err(e) = self.finish(&mut st, node, built) {
                st.failed.insert(node, format!("{e:#}"));
            }
        }
    }
}

/// The tiles of a frame as drawn: built tiles (selected ones or their nearest built
/// ancestors), disjoint, in traversal order.
#[derive(Debug, Clone, Default)]
pub struct ResolvedTiles {
    /// The tiles drawn.
    pub tiles: Vec<Arc<GridTile>>,
    /// Selected tiles drawn by an ancestor, or not at all (nothing built above them).
    pub late: usize,
}

/// The cache's figures.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TileCacheStats {
    /// Bytes of built tiles held now.
    pub bytes: u64,
    /// Most bytes held at once.
    pub peak_bytes: u64,
    /// The budget.
    pub budget: u64,
    /// Tiles built so far (read from the store's baked tiles included).
    pub built: u64,
    /// Of those, tiles read from the store's baked tiles ([`crate::tin_scene`]).
    pub read: u64,
    /// Tiles dropped for the budget.
    pub evicted: u64,
    /// Tiles held now.
    pub tiles: usize,
}

/// `tin`'s tiles of one store, built on demand by worker threads (see the module docs).
#[derive(Debug)]
pub struct TinTiles {
    shared: Arc<Shared>,
    workers: Vec<JoinHandle<()>>,
}

impl TinTiles {
    /// The tiles of `store` (its tree `shape`, leaves of the pyramid's finest tiles) under
    /// `config`'s pyramid and store settings; starts the workers. A store's table of
    /// decimation errors that cannot be read, and a damaged `tin_tiles.bin` or one of another
    /// bake, are errors.
    pub fn new(store: Store, shape: TreeShape, config: &TinConfig) -> anyhow::Result<Self> {
        let baked = BakedTiles::open(&store, &shape, config)?;
        let blocks = Self::block_cache_bytes(config, baked.is_some());
        let builder = store_builder(store, shape, config, blocks)?;
        let s = &config.store;
        let shared = Arc::new(Shared {
            builder,
            baked,
            budget: s.tile_cache_bytes,
            state: Mutex::new(State::default()),
            work: Condvar::new(),
            done: Condvar::new(),
        });
        let workers = (0..s.threads.max(1))
            .map(|k| {
                let shared = shared.clone();
                std::thread::Builder::new()
                    .name(format!("tin-tiles-{k}"))
                    .spawn(move || shared.worker())
                    .expect("a tile builder thread")
            })
            .collect();
        Ok(Self { shared, workers })
    }

    /// The block cache of the tile builders under `config`, for a store with its coarse tiles
    /// `baked` or not.
    fn block_cache_bytes(config: &TinConfig, baked: bool) -> u64 {
        let s = &config.store;
        if baked { s.block_cache_bytes_baked } else { s.block_cache_bytes }
    }

    /// The bytes the tile cache and the builders' block cache may hold: what they take of the
    /// run's memory budget ([`OocScene::with_reserved`]).
    pub fn cache_bytes(&self) -> u64 {
        self.shared.budget + self.shared.builder.samples().budget()
    }

    /// Every level's bound, metres.
    pub fn errors(&self) -> &[f64] {
        self.shared.builder.errors()
    }

    /// Tile `node`'s bound, metres ([`GridTileBuilder::tile_bound`]): what it is selected by.
    pub fn tile_bound(&self, node: NodeId) -> f64 {
        self.shared.builder.tile_bound(node)
    }

    /// Queues what `nodes` need that is not built: their missing ancestors (coarse first, the
    /// fallback of a frame that cannot wait) and themselves. Replaces the previous request.
    pub fn request(&self, nodes: &[NodeId]) {
        self.request_in_turn(&[nodes]);
    }

    /// [`TinTiles::request`] for several groups of tiles, built in turn: each group's missing
    /// tiles and ancestors (coarse first) after the previous group's (a frame's own tiles,
    /// then those of the eyes ahead).
    pub fn request_in_turn(&self, groups: &[&[NodeId]]) {
        self.queue(groups, true);
    }

    /// Queues the missing tiles of `groups` in turn, with their missing ancestors when
    /// `ancestors` (a waiting frame draws its own tiles only: their ancestors, coarse tiles
    /// meshed from many samples once their decimation error is counted, would only delay it).
    fn queue(&self, groups: &[&[NodeId]], ancestors: bool) {
        let mut st = self.shared.lock();
        let mut queued: HashSet<NodeId> = HashSet::new();
        let mut queue: Vec<NodeId> = Vec::new();
        for nodes in groups {
            let from = queue.len();
            for &n in *nodes {
                let mut c = Some(n);
                while let Some(m) = c {
                    if st.tiles.contains_key(&m) || st.failed.contains_key(&m) {
                        break;
                    }
                    if queued.insert(m) {
                        queue.push(m);
                    }
                    c = if ancestors { m.parent() } else { None };
                }
            }
            queue[from..].sort_by_key(|n| (n.level, n.dfs_key()));
        }
        st.queue = queue.into();
        drop(st);
        self.shared.work.notify_all();
    }

    /// Waits until every one of `nodes` is built (at most `timeout`); the first failure or
    /// the timeout is an error.
    pub fn wait_for(&self, nodes: &[NodeId], timeout: Duration) -> anyhow::Result<()> {
        self.wait_for_then(nodes, &[], timeout)
    }

    /// [`TinTiles::wait_for`] `nodes`, then waits for `more` (queued after them) until each
    /// is built or failed, or the cache holds its budget (tiles past it would be dropped
    /// again once drawn tiles need the room), at most `timeout` in all. `more`'s tiles left
    /// unbuilt stay queued until the next request replaces the queue; their failures are not
    /// errors (no frame draws them yet).
    pub fn wait_for_then(
        &self,
        nodes: &[NodeId],
        more: &[NodeId],
        timeout: Duration,
    ) -> anyhow::Result<()> {
        self.queue(&[nodes, more], false);
        let deadline = Instant::now() + timeout;
        self.wait_built(nodes, deadline, timeout)?;
        let mut st = self.shared.lock();
        loop {
            let missing = more
                .iter()
                .filter(|n| !st.tiles.contains_key(n) && !st.failed.contains_key(n))
                .count();
            let idle = st.queue.is_empty() && st.building.is_empty();
            if missing == 0 || idle || st.bytes >= self.shared.budget {
                return Ok(());
            }
            let now = Instant::now();
            if now >= deadline {
                anyhow::bail!("{missing} tin tiles not built within {timeout:?}");
            }
            st = self
                .shared
                .done
                .wait_timeout(st, deadline - now)
                .map_or_else(|e| e.into_inner().0, |(g, _)| g);
        }
    }

    /// Waits until every one of `nodes` is built, queued already (`deadline`; `timeout` the
    /// wait it ends, for the message).
    fn wait_built(
        &self,
        nodes: &[NodeId],
        deadline: Instant,
        timeout: Duration,
    ) -> anyhow::Result<()> {
        let mut st = self.shared.lock();
        loop {
            if let Some((n, e)) = nodes.iter().find_map(|n| st.failed.get(n).map(|e| (n, e))) {
                anyhow::bail!("tin tile {n:?}: {e}");
            }
            let missing: Vec<NodeId> =
                nodes.iter().copied().filter(|n| !st.tiles.contains_key(n)).collect();
            if missing.is_empty() {
                return Ok(());
            }
            let now = Instant::now();
            if now >= deadline {
                anyhow::bail!("{} tin tiles not built within {timeout:?}", missing.len());
            }
            // Tiles evicted while waiting (a budget smaller than the frame) are asked again.
            if st.queue.is_empty() && st.building.is_empty() {
                drop(st);
                self.queue(&[&missing], false);
                st = self.shared.lock();
                continue;
            }
            st = self
                .shared
                .done
                .wait_timeout(st, deadline - now)
                .map_or_else(|e| e.into_inner().0, |(g, _)| g);
        }
    }

    /// A frame's drawn tiles for the selected `nodes` (see [`ResolvedTiles`]); starts a new
    /// frame of the cache (its tiles are kept while it is drawn).
    pub fn resolve(&self, nodes: &[NodeId]) -> ResolvedTiles {
        let mut st = self.shared.lock();
        st.frame += 1;
        let frame = st.frame;
        let (keep, late) = drawn_tiles(&st, nodes);
        let tiles = keep
            .iter()
            .filter_map(|n| {
                let e = st.tiles.get_mut(n)?;
                e.used = frame;
                Some(e.tile.clone())
            })
            .collect();
        // What the previous frames drew and this one does not may go now.
        self.shared.evict(&mut st);
        ResolvedTiles { tiles, late }
    }

    /// The tiles [`TinTiles::resolve`] would draw for `nodes` now, without starting a frame
    /// of the cache (nothing is marked used, nothing evicted): what Eq. 8's selection one
    /// look-ahead ahead would draw with the tiles built so far.
    pub fn peek(&self, nodes: &[NodeId]) -> Vec<Arc<GridTile>> {
        let st = self.shared.lock();
        let (keep, _) = drawn_tiles(&st, nodes);
        keep.iter().filter_map(|n| Some(st.tiles.get(n)?.tile.clone())).collect()
    }

    /// The stride (log2) tile `node` will be built at, where known before building
    /// ([`GridTileBuilder::planned_stride`]: a store with its table of decimation errors).
    pub fn planned_stride(&self, node: NodeId) -> Option<u32> {
        if let Some(s) = self.shared.baked.as_ref().and_then(|b| b.stride(node)) {
            return Some(s);
        }
        self.shared.builder.planned_stride(node)
    }

    /// The carrier patches of those of `nodes` not built yet ([`TinTiles::carriers`]): what
    /// they will ask of the streamer once built, so that it can load it while they are built
    /// (a tile built between two frames otherwise finds its lattice not resident in the frame
    /// that first draws it).
    pub fn planned_patches(&self, nodes: &[NodeId], root: u32) -> Vec<Patch> {
        let missing: Vec<NodeId> = {
            let st = self.shared.lock();
            nodes.iter().copied().filter(|n| !st.tiles.contains_key(n)).collect()
        };
        self.carriers(&missing, root)
    }

    /// The carrier patch of each of `nodes` (one each, in order) under a tree of `root` cells, its factor putting
    /// its points on the lattice of the tile's own stride (its 64 cells across): the streamer's
    /// demand. The tiles' vertices are drawn at their own heights
    /// ([`ExtraTriangles::heights`]), so the pages only shade them, at the tile's level of
    /// detail: a coarse tile meshed from every sample under it does not demand them all.
    pub fn carriers(&self, nodes: &[NodeId], root: u32) -> Vec<Patch> {
        nodes
            .iter()
            .map(|&n| tile_patch(n, self.shared.builder.own_stride(n).unwrap_or(0), root))
            .collect()
    }

    /// The cache's figures now.
    pub fn stats(&self) -> TileCacheStats {
        let st = self.shared.lock();
        TileCacheStats {
            bytes: st.bytes,
            peak_bytes: st.peak_bytes,
            budget: self.shared.budget,
            built: st.built,
            read: st.read,
            evicted: st.evicted,
            tiles: st.tiles.len(),
        }
    }
}

/// The carrier patch of tile `node` with its points on the lattice of stride `2^stride_log2`,
/// under a tree of `root` cells.
fn tile_patch(node: NodeId, stride_log2: u32, root: u32) -> Patch {
    let f = ((root >> node.level) >> stride_log2).max(1) as f32;
    Patch { node, outer: [f; 4], inner: [f; 2] }
}

/// The built tiles that draw `nodes` (each selected tile or its nearest built ancestor; an
/// ancestor drawn for a late tile covers the selected tiles under it), disjoint, in traversal
/// order, and how many selected tiles are late (drawn by an ancestor, or not at all).
fn drawn_tiles(st: &State, nodes: &[NodeId]) -> (Vec<NodeId>, usize) {
    let mut late = 0;
    let mut drawn: HashSet<NodeId> = HashSet::new();
    for &n in nodes {
        let mut c = Some(n);
        while let Some(m) = c {
            if st.tiles.contains_key(&m) {
                break;
            }
            c = m.parent();
        }
        late += usize::from(c != Some(n));
        if let Some(m) = c {
            drawn.insert(m);
        }
    }
    // An ancestor drawn for a late tile covers the selected tiles under it.
    let mut keep: Vec<NodeId> = drawn
        .iter()
        .copied()
        .filter(|n| {
            let mut p = n.parent();
            while let Some(a) = p {
                if drawn.contains(&a) {
                    return false;
                }
                p = a.parent();
            }
            true
        })
        .collect();
    keep.sort_by_key(|n| n.dfs_key());
    (keep, late)
}

impl Drop for TinTiles {
    fn drop(&mut self) {
        self.shared.lock().stop = true;
        self.shared.work.notify_all();
        for w in self.workers.drain(..) {
            let _ = w.join();
        }
    }
}

/// How much further ahead than the streamer's look-ahead eye (Eq. 8) the tiles are queued for
/// ([`TinTiles::request_in_turn`], after the frame's own and the look-ahead eye's).
const TILES_AHEAD: f64 = 8.0;

/// The eye whose tiles are queued last in a frame at `camera` whose look-ahead eye (Eq. 8) is
/// `ahead`: `TILES_AHEAD` times as far along the motion, looking as `ahead` does, with its
/// view (widened by [`crate::ooc::AHEAD_WIDEN`] at the same pixels per radian, the view
/// frustum extension), so that the tiles a turning view brings in at its sides are queued
/// before they are drawn too. Over the mirrored Everest store (`fast_pass` paced at 1280 x
/// 720, `tau_px` 1) the frames drawing a tile not built yet went from a median of 47 of 299
/// (unwidened, thirteen runs) to 22 with this eye's view alone 1.3x wider (twelve runs) and
/// 17.5 with the look-ahead eye's too (six runs); 1.2 and 1.6 did no better than 1.3 (more
/// tiles queued than the builders finish at 1.6); bench/ooc/README.md.
fn tiles_ahead_camera(camera: &Camera, ahead: &Camera) -> Camera {
    Camera {
        position: camera.position + (ahead.position - camera.position) * TILES_AHEAD,
        ..*ahead
    }
}

/// The threshold of a real-time run's start view, times the run's (see [`start_camera`]).
const START_FINER: f64 = 0.5;

/// The view whose tiles a real-time run's first frame waits for after its own: `camera`'s,
/// widened by [`crate::ooc::AHEAD_WIDEN`] at the same pixels per radian, its tiles selected
/// at [`START_FINER`] times the threshold. The first frame knows no motion yet, so Eq. 8 has
/// no eye ahead for it, and a flight's first frames each need new tiles, more than the
/// builders finish in a frame: the backlog left frames 1-30 drawing tiles not built. A tile
/// selected at half the threshold still meets the threshold from half its distance, so this
/// view's tiles serve an eye approaching or turning for many frames, until Eq. 8's preloading
/// has the eyes ahead. Over the mirrored Everest store (`fast_pass` paced at 1280 x 720,
/// `tau_px` 1) the frames not at their needed level went from 6-15 of 299 (median 8) to 1-9
/// (median 2) in five alternated pairs, the first frame waiting for 372 tiles instead of 99
/// (0.6 s instead of 0.3); 0.35 and an unwidened view did as well as this in a throw-away
/// build; bench/ooc/README.md, "A real-time run's start view".
fn start_camera(camera: &Camera) -> Camera {
    camera.widened(crate::ooc::AHEAD_WIDEN)
}

/// `tin` over a store's runtime (see the module docs).
#[derive(Debug)]
pub struct TinStoreMethod<'a> {
    scene: OocScene,
    /// The store's tree with leaves of the pyramid's finest tiles.
    tree: StoreTree,
    tiles: TinTiles,
    config: TinConfig,
    wait: OocWait,
    frames: usize,
    reference: Option<&'a MethodScene>,
    /// The tiles the last frame drew (its measured surface is joined from them on demand).
    drawn: Vec<Arc<GridTile>>,
}

/// Per drawn tile, its carrier rectangle in a tree of `root` cells: what [`CarrierSink`]
/// places each tile's vertices on.
fn carrier_rects(tiles: &[&GridTile], root: u32) -> Vec<CarrierRect> {
    tiles.iter().map(|t| CarrierRect::of(t.node, root)).collect()
}

/// A drawn tile's carrier patch: its node's south-west grid sample and the reciprocal of its
/// side in cells.
#[derive(Debug, Clone, Copy)]
struct CarrierRect {
    x0: i64,
    y0: i64,
    inv_cells: f32,
}

impl CarrierRect {
    fn of(node: NodeId, root: u32) -> Self {
        let (x0, y0, cells) = node.grid_rect(root);
        // A tree's root is a power of two cells across (`TreeShape`), so is every node.
        debug_assert!(cells.is_power_of_two(), "a node of {cells} cells");
        Self { x0: i64::from(x0), y0: i64::from(y0), inv_cells: 1.0 / cells as f32 }
    }

    /// Grid sample `g` on the carrier: `(g - corner) / cells` per axis, rounded to `f32` once.
    /// The side being a power of two, scaling by its reciprocal is exact and commutes with the
    /// rounding, so this is the quotient `((g - x0) as f64 / cells as f64) as f32` bit for bit
    /// (`carrier_uv_is_the_quotient_rounded_once`) without two divisions a vertex: the join
    /// writes every vertex of every drawn tile each frame.
    #[inline]
    fn uv(&self, g: [u32; 2]) -> [f32; 2] {
        let (dx, dy) = (i64::from(g[0]) - self.x0, i64::from(g[1]) - self.y0);
        [dx as f32 * self.inv_cells, dy as f32 * self.inv_cells]
    }
}

/// [`tin_surface_into`]'s sink writing the renderer's buffers: each vertex on its tile's
/// carrier patch (`rects`, per drawn tile) at its tile's height.
struct CarrierSink<'r> {
    rects: &'r [CarrierRect],
    extra: ExtraTriangles,
}

impl SurfaceSink for CarrierSink<'_> {
    fn reserve(&mut self, vertices: usize, triangles: usize) {
        self.extra.points.reserve(vertices);
        self.extra.heights.reserve(vertices);
        self.extra.indices.reserve(3 * triangles);
    }
    fn vertex(&mut self, g: [u32; 2], z: f32, tile: u32) {
        let uv = self.rects[tile as usize].uv(g);
        self.extra.points.push(GpuDomainPoint { uv, patch_index: tile, pad: 0 });
        self.extra.heights.push(z);
    }
    fn triangle(&mut self, t: [u32; 3]) {
        self.extra.indices.extend_from_slice(&t);
    }
    // A tile's vertices and triangles written in bulk: about half the frame thread's CPU
    // over the 32769^2 store at 2 px went to one push per vertex and per triangle.
    fn vertices(&mut self, g: &[[u32; 2]], z: &[f32], tile: u32) {
        let rect = self.rects[tile as usize];
        let n = g.len().min(z.len());
        self.extra.points.extend(g[..n].iter().map(|&g| GpuDomainPoint {
            uv: rect.uv(g),
            patch_index: tile,
            pad: 0,
        }));
        self.extra.heights.extend_from_slice(&z[..n]);
    }
    fn triangles(&mut self, t: &[[u32; 3]], base: u32) {
        self.extra.indices.extend(t.as_flattened().iter().map(|&v| v + base));
    }
}

impl<'a> TinStoreMethod<'a> {
    /// `tin` over `scene`'s store under `config`; measured against `reference` (the same DEM
    /// in memory) when given.
    pub fn new(
        scene: OocScene,
        config: &TinConfig,
        wait: OocWait,
        reference: Option<&'a MethodScene>,
    ) -> anyhow::Result<Self> {
        let store = scene.store().clone();
        let tree = store_tree(&store, config);
        let shape = *terrain_core::quadtree::NodeTree::shape(&tree);
        if let Some(r) = reference
            && (r.qt.root_cells(), r.qt.width(), r.qt.height())
                != (shape.root_cells(), shape.width(), shape.height())
        {
            return Err(super::store::not_the_reference(store.dir(), "grid", &shape, r));
        }
        if let Some(r) = reference {
            super::store::check_same_heights(&store, &r.hm)?;
        }
        let tiles = TinTiles::new((*store).clone(), shape, config)?;
        // One memory budget: the stream cache gets what the tiles' caches leave of it.
        let scene = scene.with_reserved(tiles.cache_bytes());
        Ok(Self {
            scene,
            tree,
            tiles,
            config: *config,
            wait,
            frames: 0,
            reference,
            drawn: Vec::new(),
        })
    }

    /// The tile cache.
    pub fn tiles(&self) -> &TinTiles {
        &self.tiles
    }

    /// The tiles `camera` selects over the store's index (no tile built).
    pub fn select(&self, camera: &Camera) -> TinSelection {
        self.select_at(camera, 1.0)
    }

    /// The tiles `camera` selects at `finer` times the threshold (no tile built).
    fn select_at(&self, camera: &Camera, finer: f64) -> TinSelection {
        let tau_px = self.config.tau_px * finer;
        select_tiles(&self.tree, |n| self.tiles.tile_bound(n), camera, tau_px)
    }
}

impl Method for TinStoreMethod<'_> {
    fn kind(&self) -> LodMethod {
        LodMethod::Tin
    }

    /// The selection and the tile lookup are the selection time (a wait for tiles is not);
    /// joining the tiles and stitches the build time.
    fn frame(&mut self, camera: &Camera) -> Frame {
        let start = self.frames == 0 && self.wait == OocWait::FirstFrame;
        let warm = self.wait.next_is_warm(&mut self.frames);
        let sel = self.select(camera);
        let t = Instant::now();
        let waited = if warm {
            // A real-time run's first frame also waits for the tiles of its start view (see
            // `start_camera`), after its own and within the cache's budget.
            let more = match start {
                true => self.select_at(&start_camera(camera), START_FINER).tiles,
                false => Vec::new(),
            };
            let timeout = self.config.store.wait_timeout;
            let r = self.tiles.wait_for_then(&sel.tiles, &more, timeout);
            if let Err(e) = &r {
                eprintln!("warning: {e:#}; drawing the tiles built");
            }
            true
        } else {
            self.tiles.request(&sel.tiles);
            false
        };
        let wait_ms = if waited { ms(t) } else { 0.0 };
        let t = Instant::now();
        let resolved = self.tiles.resolve(&sel.tiles);
        let resolve_ms = ms(t);
        let t = Instant::now();
        let drawn: Vec<&GridTile> = resolved.tiles.iter().map(|t| &**t).collect();
        let shape = *terrain_core::quadtree::NodeTree::shape(&self.tree);
        let root = shape.root_cells();
        // Each tile's points on its node's carrier (its factor is the streamer's demand), at
        // the tile's heights: the drawn geometry is the tiles', whatever the pages hold (they
        // shade it). Joined straight into the renderer's buffers; the measured surface is
        // built from the same tiles only when asked ([`Method::surface`]).
        let rects = carrier_rects(&drawn, root);
        let mut sink = CarrierSink { rects: &rects, extra: ExtraTriangles::default() };
        tin_surface_into(&drawn, self.config.stitch, &mut sink);
        let extra = sink.extra;
        let build_ms = ms(t);
        let t = Instant::now();
        let drawn_nodes: Vec<NodeId> = drawn.iter().map(|t| t.node).collect();
        let patches = self.tiles.carriers(&drawn_nodes, root);
        let convert_ms = ms(t);
        let selection_time = sel.cpu_time + Duration::from_secs_f64(resolve_ms / 1e3);
        let stats = SelectionStats {
            traversal_leaves: sel.tiles.len(),
            patches: patches.len(),
            culled: sel.culled,
            max_level: patches.iter().map(|p| p.node.level).max().unwrap_or(0),
            cpu_time: selection_time,
            ..SelectionStats::default()
        };
        let draw = StoreDraw {
            selection: Selection { patches, stats },
            mesh: Some(extra),
            ..Default::default()
        };
        // A waiting frame selects again once its levels are resident: the same tiles. For the
        // eye one look-ahead ahead (Eq. 8) the tiles it selects are queued after this frame's
        // (their builds start before they are drawn), and the lattices of the tiles built so
        // far that would draw them are the streamer's demand ahead.
        let (tree, tiles, tau_px) = (&self.tree, &self.tiles, self.config.tau_px);
        let mut own = Some(draw);
        let mut select = |_: &dyn terrain_core::lod::TerrainSource, c: &Camera| -> StoreDraw {
            if c == camera {
                // A real-time frame selects for its camera once: its draw is moved, not
                // copied (its mesh is the frame's triangles, tens of MB at 1280 x 720); a
                // waiting frame selects again once its levels are resident (the same tiles).
                return match warm {
                    true => own.clone().unwrap_or_default(),
                    false => own.take().unwrap_or_default(),
                };
            }
            let ahead = select_tiles(tree, |n| tiles.tile_bound(n), c, tau_px);
            // A tile takes longer to build than a frame lasts (10-25 ms from every sample of
            // a 256-512 cell window), and a view's new tiles come in bursts: the tiles of the
            // eye further ahead (`TILES_AHEAD` times the streamer's look-ahead) are queued
            // last, so a burst starts building frames before it is drawn.
            let far = tiles_ahead_camera(camera, c);
            let further = select_tiles(tree, |n| tiles.tile_bound(n), &far, tau_px);
            tiles.request_in_turn(&[&sel.tiles, &ahead.tiles, &further.tiles]);
            // The frame's and the look-ahead eye's tiles, each once (their lattices are the
            // demand ahead once built).
            let now: HashSet<NodeId> = sel.tiles.iter().copied().collect();
            let mut queued = sel.tiles.clone();
            queued.extend(ahead.tiles.iter().filter(|n| !now.contains(n)));
            let built = tiles.peek(&ahead.tiles);
            let built: Vec<NodeId> = built.iter().map(|t| t.node).collect();
            let mut patches = tiles.carriers(&built, root);
            // And the lattices of the tiles being built for this frame and the next, which
            // the frames after will draw.
            patches.extend(tiles.planned_patches(&queued, root));
            StoreDraw {
                selection: Selection { patches, stats: SelectionStats::default() },
                mesh: Some(ExtraTriangles::default()),
                ..Default::default()
            }
        };
        let f = self.scene.frame_for(camera, warm, &self.tree, &mut select);
        let mut frame = paged_frame(f);
        frame.stats.selection_ms = selection_time.as_secs_f64() * 1e3;
        frame.stats.build_ms = build_ms;
        frame.stats.convert_ms = convert_ms;
        if let Some(s) = frame.stats.stream.as_mut() {
            s.late_tiles = resolved.late;
            s.at_needed_level &= resolved.late == 0;
            s.wait_ms += wait_ms;
            s.waited_for_io |= waited && wait_ms > 0.0;
        }
        for p in &mut frame.selection.patches {
            *p = Patch { node: p.node, outer: [1.0; 4], inner: [1.0; 2] };
        }
        self.drawn = resolved.tiles;
        frame
    }

    /// The last frame's surface, joined from its tiles again (the CPU twin of what it drew).
    fn surface(&self, _frame: &mut Frame) -> anyhow::Result<DrawnSurface> {
        let _ = self.reference;
        let shape = *terrain_core::quadtree::NodeTree::shape(&self.tree);
        let drawn: Vec<&GridTile> = self.drawn.iter().map(|t| &**t).collect();
        let s = tin_surface(&drawn, |g| shape.grid_to_world(g), self.config.stitch);
        Ok(DrawnSurface { mesh: s.mesh, triangles: s.tile_triangles + s.stitch_triangles })
    }

    fn draws_on(&self) -> DrawSource<'_> {
        DrawSource::Paged(&self.scene)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DQuat, dvec3};

    /// A sink that writes through [`CarrierSink`] one vertex and one triangle at a time (the
    /// trait's default bulk methods).
    struct OneByOne<'r>(CarrierSink<'r>);

    impl SurfaceSink for OneByOne<'_> {
        fn reserve(&mut self, vertices: usize, triangles: usize) {
            self.0.reserve(vertices, triangles);
        }
        fn vertex(&mut self, g: [u32; 2], z: f32, tile: u32) {
            self.0.vertex(g, z, tile);
        }
        fn triangle(&mut self, t: [u32; 3]) {
            self.0.triangle(t);
        }
    }

    /// The carrier sink's bulk writes put in the renderer's buffers exactly what its writes
    /// one by one do: every point, height and index, stitches included.
    #[test]
    fn the_carrier_sinks_bulk_writes_equal_its_writes_one_by_one() {
        let hm =
            terrain_core::synth::FractalConfig::with_size(257, 193, 10.0).to_heightmap().unwrap();
        let scene = crate::methods::MethodScene::new(hm, crate::methods::MethodConfig::default());
        let p = scene.tin_pyramid().unwrap();
        let hm = &scene.hm;
        let xy = hm.grid_to_world(0.3 * hm.width() as f64, 0.2 * hm.height() as f64);
        let camera = Camera::from_yaw_pitch(xy.extend(f64::from(hm.max()) + 300.0), 40.0, -20.0)
            .with_fov_y_deg(60.0)
            .with_viewport(640.0, 360.0);
        let sel = p.select(&camera, 0.5);
        let tiles: Vec<&GridTile> = sel.tiles.iter().filter_map(|&n| p.tile(n)).collect();
        let levels: HashSet<u8> = tiles.iter().map(|t| t.node.level).collect();
        assert!(tiles.len() > 10 && levels.len() > 1, "tiles of several levels: stitched");
        let rects = carrier_rects(&tiles, p.tree().root_cells());
        let mut bulk = CarrierSink { rects: &rects, extra: ExtraTriangles::default() };
        let counts = tin_surface_into(&tiles, true, &mut bulk);
        let mut one = OneByOne(CarrierSink { rects: &rects, extra: ExtraTriangles::default() });
        assert_eq!(tin_surface_into(&tiles, true, &mut one), counts);
        assert!(counts.stitch_triangles > 0, "{counts:?}");
        let (a, b) = (&bulk.extra, &one.0.extra);
        assert_eq!(a.indices, b.indices);
        assert_eq!(a.heights, b.heights);
        let points = |e: &ExtraTriangles| -> Vec<(u32, u32, u32)> {
            e.points.iter().map(|q| (q.uv[0].to_bits(), q.uv[1].to_bits(), q.patch_index)).collect()
        };
        assert_eq!(points(a), points(b));
        assert_eq!(3 * (counts.tile_triangles + counts.stitch_triangles) as usize, a.indices.len());
    }

    /// A vertex's carrier position is the quotient of its offset by the node's side, computed
    /// in f64 and rounded to f32 once (what the join computed before), bit for bit: at every
    /// level of a 2^31-cell root, offsets across the node and beyond 2^24 (where f32 rounds).
    #[test]
    fn carrier_uv_is_the_quotient_rounded_once() {
        let root = 1u32 << 31;
        let mut checked = 0;
        for level in 0..=NodeId::MAX_LEVEL {
            let cells = root >> level;
            for (i, j) in [(0u32, 0u32), (1, 0), (3, 5), ((1 << level) - 1, 1 << level >> 1)] {
                let node = NodeId::new(level, i.min((1 << level) - 1), j.min((1 << level) - 1));
                let rect = CarrierRect::of(node, root);
                let (x0, y0, _) = node.grid_rect(root);
                let offsets = [0, 1, 2, 3, 7, cells / 3, cells / 2 + 1, cells - 1, cells]
                    .into_iter()
                    .chain([(1 << 24) + 1, (1 << 25) + 3, (1 << 27) + 5, 0x7654_3211])
                    .filter(|&d| {
                        d <= cells && u64::from(x0.max(y0)) + u64::from(d) <= u64::from(u32::MAX)
                    });
                for d in offsets {
                    let g = [x0 + d, y0 + d / 2];
                    let want = [
                        ((f64::from(g[0]) - f64::from(x0)) / f64::from(cells)) as f32,
                        ((f64::from(g[1]) - f64::from(y0)) / f64::from(cells)) as f32,
                    ];
                    let got = rect.uv(g);
                    assert_eq!(got.map(f32::to_bits), want.map(f32::to_bits), "{node:?} {g:?}");
                    checked += 1;
                }
            }
        }
        assert!(checked > 300, "{checked}");
    }

    #[test]
    fn the_tiles_are_queued_for_a_wider_view_further_along_the_motion() {
        let camera = Camera::from_yaw_pitch(dvec3(1000.0, 2000.0, 900.0), 40.0, -15.0)
            .with_viewport(1280.0, 720.0);
        // The eye ahead as `OocScene::frame_for` gives it: moved, turned, widened.
        let ahead = Camera {
            position: camera.position + dvec3(30.0, -10.0, 2.0),
            orientation: camera.orientation * DQuat::from_rotation_y(0.05),
            ..camera
        }
        .widened(crate::ooc::AHEAD_WIDEN);
        let far = tiles_ahead_camera(&camera, &ahead);
        let want = camera.position + dvec3(30.0, -10.0, 2.0) * TILES_AHEAD;
        assert!((far.position - want).length() < 1e-9, "{}", far.position);
        assert_eq!(far.orientation, ahead.orientation);
        // Its wider view, at the same pixels per radian: the same tiles where the view was,
        // and those at its sides.
        assert_eq!((far.fov_y, far.viewport_px), (ahead.fov_y, ahead.viewport_px));
        assert!(far.fov_y > camera.fov_y * 1.2);
        assert!((far.lambda() - camera.lambda()).abs() < 1e-9 * camera.lambda());
    }
}
