//! The out-of-core paper's method (Qiu 2013) end to end over a baked store: per frame the
//! [`Streamer`] (regions M and N, Eq. 8 preloading one frame ahead on the workers, real time:
//! no frame waits for I/O after the first, late data counted; `warm` frames wait on purpose),
//! the projected-frustum block culling of 3.1 (the blocks of M), then
//! terrain-stream's crack-free patch selection ([`terrain_stream::select_patches`]:
//! terrain-core's one traversal over the store's index with the Eq. 7 split and the
//! bounding-circle cull, patches of at least [`OocConfig::patch_cells`] cells clamped to each
//! block's page level, balanced, tessellation factors from Eq. 7 and terrain-core's one
//! `EdgeRule` resolver), and the pages of heights the renderer needs. This module is only the
//! glue between the streamer, the selection and the renderer's pages.
//!
//! **Pages.** Each drawn block is one page of the renderer ([`terrain_gpu::paged`]) stored at
//! the resolution it is drawn at: its level-`L` lattice, `(2^L + 1)^2` samples at stride
//! `2^(k - L)`, in a slot of that stride's class (the renderer reads the samples between
//! lattice samples by bilinear interpolation, as [`terrain_gpu::paged::fill_from_level`]
//! would fill them), and moved to a finer class when a finer level arrives; pages of blocks no
//! longer drawn are dropped. The classes' slot counts come from a byte budget
//! ([`OocConfig::page_budget_bytes`], [`terrain_gpu::paged::classes_for_budget`]): blocks, in
//! the runtime's priority order (nearest first), take the finest resident level whose class
//! has a slot left, so a far block drawn at level 2 costs a 5 x 5 slot; a block with no slot
//! at any of its resident levels is not drawn (counted in [`OocFrame::blocks_dropped`]).
//! Heights never exist for the whole grid: the device (and the optional CPU mirror the
//! benchmark measures) holds the drawn blocks only.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::{DVec2, DVec3};
use terrain_core::geometry::Camera;
use terrain_core::hash::IdMap;
use terrain_core::lod::{GeomipRuns, PatchRun, TerrainSource};
use terrain_core::lod::{Patch, Selection, check_shared_edges};
use terrain_core::quadtree::{NodeId, NodeTree};
use terrain_core::{Crs, Georef, Heightmap};
use terrain_gpu::paged::{Page, PageClass, PageLayout, PagedHeights, classes_for_budget};
use terrain_gpu::render::{DrawPatch, ExtraTriangles};
use terrain_gpu::tess::PatchFactors;
use terrain_gpu::{RenderError, TerrainRenderer};
use terrain_stream::{
    BlockId, BlockLevelGrid, DEFAULT_COST_SPLIT_PX, DEFAULT_PATCH_CELLS, DEFAULT_SPLIT, Demand,
    Refinement, RemoteOptions, ScheduleConfig, SplitRule, Store, StoreError, StoreSource,
    StoreTree, StreamConfig, Streamer, TreeWarmer, coarsen_to_budget, demand_and_held, demand_of,
    select_patches,
};

use crate::MIB;
use crate::methods::{StripFrame, geomorph_patch, patch_factors};

/// Settings of the out-of-core method.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OocConfig {
    /// Screen-error threshold `tau` of Eq. 7, pixels. Default 2 (the paper's figures).
    pub tau: f64,
    /// The memory budget of the store's data, bytes: the stream cache's decoded blocks, the
    /// index entries the trees keep for the view and the store's decoded index pages
    /// ([`index_share`]; the blocks get what the entries and pages leave, at least half of
    /// it). Default 1 GiB ([`LOOKAHEAD_FRAMES`] says why).
    pub budget_bytes: u64,
    /// Worker threads; 0 (the default) = one per core.
    pub threads: usize,
    /// Bytes of page atlas on the device, shared by the slot classes of every stride
    /// ([`terrain_gpu::paged::classes_for_budget`]). Default 256 MiB.
    pub page_budget_bytes: u64,
    /// Full-resolution page slots (`(2^k + 1)^2` f32 each) at most, within the budget; blocks
    /// beyond them are drawn from coarser classes. Default 1024.
    pub page_capacity: u32,
    /// Load requests in flight at most: the workers keep loading while the frame thread draws
    /// (a software renderer's frame takes long). Default 0: the streamer's own default (1024 per
    /// worker; 32 left most frames of a fast flight short of their level, bench/ooc/README.md).
    pub max_in_flight: usize,
    /// A warm frame ([`OocScene::frame`] with `warm`) waits at most this long for its needed
    /// levels ([`Streamer::wait_until_resident`]). Default 60 s.
    pub warm_timeout: Duration,
    /// Smallest patch, cells per side (a power of two, at most a block); patches are drawn by
    /// the tessellator with factors up to their cells. Default
    /// [`terrain_stream::DEFAULT_PATCH_CELLS`].
    pub patch_cells: u32,
    /// Vertical exaggeration of the store's heights, applied by [`OocScene::open`] as the
    /// store is read ([`Store::exaggerated`]: heights, boxes and every selection error scale
    /// with it). Default 1. [`OocScene::new`] takes its store as opened.
    pub vertical_scale: f64,
    /// The split rule inside the blocks ([`SplitRule`]: Eq. 7 alone, or Eq. 7 with the cost
    /// split, which with 16-cell patches draws fewer triangles at equal error, see
    /// bench/ooc/README.md). Default [`terrain_stream::DEFAULT_SPLIT`].
    pub split: SplitRule,
    /// The cost split's screen-size floor ([`Refinement::cost_split_px`]). Default
    /// [`terrain_stream::DEFAULT_COST_SPLIT_PX`].
    pub cost_split_px: u32,
    /// The floor of Eq. 6-7's `cos(theta)` ([`Refinement::view_angle_floor`]). Default
    /// [`terrain_core::metrics::screen::MIN_VIEW_SIN`] (0.25).
    pub view_angle_floor: f64,
    /// The coarsest segment a drawn patch may have, cells ([`Refinement::max_segment_cells`];
    /// 0: none, Eq. 7's least factors). Default [`terrain_stream::DEFAULT_MAX_SEGMENT_CELLS`].
    pub max_segment_cells: u32,
    /// The store's measured map from a pixel target to `tau`
    /// ([`crate::ooc_calibration`], its file beside the store's index), used by `--error-px`
    /// and `--quality` ([`OocConfig::tau_for_error_px`]) when measured under this
    /// refinement; `None` (the default): the shared calibration. `tau` itself is not changed
    /// by it.
    pub calibration: Option<crate::ooc_calibration::Calibration>,
    /// The frame rate `f` of Eq. 8 the streamer's preloading assumes
    /// ([`ScheduleConfig::frame_rate_hz`]: the latency-aware look-ahead adds `latency x f`
    /// frames). Default 60 (the interactive viewer); where a flight is played (`terrain
    /// bench`, `render --flight`, `fly`) the flight's own rate ([`OocConfig::for_flight`]).
    pub frame_rate_hz: f64,
    /// Whether a real-time frame of the paper's method has its tree walked one frame ahead on
    /// a thread of its own ([`TreeWarmer`]), so the next frame's selection finds the blocks
    /// it enters already read (the same patches either way). Default true.
    pub warm_ahead: bool,
}

/// Frames the streamer preloads ahead (Eq. 8's `S` times this). The paper's Eq. 8 looks one
/// frame ahead; on the 32769^2 synthetic store's `fast_pass` (30 fps, two workers, an idle
/// 2-core machine, `stream_bench realtime`, 1 GiB budget, 2048 in flight) one frame drew 77 % of
/// the frames at their needed level, two frames 97 % and three 98-99 %: a worker's load takes
/// longer than one frame there. The working set of that flight peaked at 590 MiB resident,
/// which is why the cache's default budget is 1 GiB (256 MiB: 27-38 %, 512 MiB: 70-83 %).
pub const LOOKAHEAD_FRAMES: f64 = 2.0;

impl OocConfig {
    /// This configuration for playing a flight of `fps` frames a second: Eq. 8's frame rate
    /// ([`OocConfig::frame_rate_hz`]) is the flight's.
    pub fn for_flight(self, fps: f64) -> Self {
        Self { frame_rate_hz: fps, ..self }
    }

    /// The selection's refinement ([`OocConfig::patch_cells`], [`OocConfig::split`]), shared
    /// by the tree and the streamer's needed levels.
    pub fn refinement(&self) -> Refinement {
        Refinement {
            patch_cells: self.patch_cells,
            split: self.split,
            cost_split_px: self.cost_split_px,
            view_angle_floor: self.view_angle_floor,
            max_segment_cells: self.max_segment_cells,
        }
    }
}

impl Default for OocConfig {
    fn default() -> Self {
        Self {
            tau: 2.0,
            budget_bytes: 1 << 30,
            threads: 0,
            page_budget_bytes: 256 << 20,
            page_capacity: 1024,
            max_in_flight: 0,
            warm_timeout: Duration::from_secs(60),
            patch_cells: DEFAULT_PATCH_CELLS,
            vertical_scale: 1.0,
            split: DEFAULT_SPLIT,
            cost_split_px: DEFAULT_COST_SPLIT_PX,
            view_angle_floor: terrain_core::metrics::screen::MIN_VIEW_SIN,
            max_segment_cells: terrain_stream::DEFAULT_MAX_SEGMENT_CELLS,
            calibration: None,
            frame_rate_hz: 60.0,
            warm_ahead: true,
        }
    }
}

/// Whether `path` is a baked store: a folder whose index file starts with the store's magic,
/// or a URL (`s3://`, `gs://`, `az://`, `http(s)://`: opened, and checked, by [`open_store`]).
pub fn is_store(path: &Path) -> bool {
    store_url(path).is_some() || terrain_stream::is_store(path)
}

/// The URL a store path holds, when it is one (`s3://bucket/x`, `http://host/x`...).
pub fn store_url(path: &Path) -> Option<&str> {
    path.to_str().filter(|s| terrain_stream::is_url(s))
}

static DISK_CACHE: std::sync::OnceLock<(Option<std::path::PathBuf>, Option<u64>)> =
    std::sync::OnceLock::new();

/// Sets the disk cache of remote stores for this process (`--cache-dir`, `--disk-cache-mib`);
/// the first call wins.
pub fn set_disk_cache(cache_dir: Option<std::path::PathBuf>, disk_cache_mib: Option<u64>) {
    let _ = DISK_CACHE.set((cache_dir, disk_cache_mib));
}

/// How remote stores are read: [`RemoteOptions`]' defaults (2 GiB disk cache, 30 s request
/// timeout, 3 retries), the disk cache as [`set_disk_cache`] set it, and a large side table
/// read where it lies, by chunks ([`RemoteOptions::side_tables_in_chunks`]): a session's first
/// frame fetches the chunks it reads, and a flight's later frames do not wait for the others,
/// which a background fill fetches (geomorph's store frames, `method::store`). No side table is
/// fetched at open: each reader asks [`Store::side_file`] or [`Store::side_table`] for the
/// table it reads (a method's table, e.g. geomorph's `geomip.bin`, comes only with that
/// method).
pub fn remote_options() -> RemoteOptions {
    let (dir, mib) = DISK_CACHE.get().cloned().unwrap_or_default();
    let mut o =
        RemoteOptions { cache_dir: dir, side_tables_in_chunks: true, ..RemoteOptions::default() };
    if let Some(m) = mib {
        o.disk_cache_bytes = m.saturating_mul(1 << 20);
    }
    o
}

type StoreKey = (std::path::PathBuf, Option<(u64, std::time::SystemTime)>);

/// The last store [`open_store`] opened (see there).
static LAST: std::sync::Mutex<Option<(StoreKey, Store)>> = std::sync::Mutex::new(None);

/// Drops the store [`open_store`] keeps (the process's end: a static is not dropped), so a
/// remote store's side tables read by chunks stop their background fill and remove an
/// incomplete part file, once their readers are gone too.
pub fn close_store() {
    let last = LAST.lock().unwrap_or_else(|e| e.into_inner()).take();
    drop(last);
}

/// Opens the store at `path`: a folder, or a URL ([`store_url`]) read through the disk cache.
///
/// The last store opened is kept (a clone shares its index), and opening the same one again
/// returns it: `render`, `fly` and `view` read the store's calibration before they open it to
/// draw, and each open reads the index (a version-3 index whole: 125 MB for a 32769^2 grid,
/// fetched again from a URL). A folder is the same store while its index file has the same
/// length and modification time (a bake in between opens it anew); a URL for the rest of the
/// process.
pub fn open_store(path: &Path) -> Result<Store, StoreError> {
    let url = store_url(path);
    let stamp = match url {
        Some(_) => None,
        None => {
            let meta = std::fs::metadata(path.join(terrain_stream::INDEX_FILE)).ok();
            meta.and_then(|m| Some((m.len(), m.modified().ok()?)))
        }
    };
    let key: StoreKey = (path.to_path_buf(), stamp);
    let mut last = LAST.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((k, store)) = &*last
        && *k == key
        && (url.is_some() || stamp.is_some())
    {
        return Ok(store.clone());
    }
    let store = match url {
        Some(url) => Store::open_location_with(url, &remote_options())?,
        None => Store::open(path)?,
    };
    *last = Some((key, store.clone()));
    Ok(store)
}

/// Bytes of a memory budget of `budget` the store's decoded index pages get
/// ([`Store::set_index_cache_bytes`]): an eighth, at least the store's default 32 MiB, at most
/// `whole` (the whole index decoded). At the default 32 MiB the 32769^2 store's `fast_pass`
/// decoded its 2,048 pages 4,255 times (the pages the view's entries come from outgrew the
/// cache, so the least recently used page was always the next one asked for), on the frame
/// thread too; with 128 MiB (the whole index) each once (bench/ooc/README.md, "The index's
/// pages within the one budget").
pub fn index_share(budget: u64, whole: u64) -> u64 {
    (budget / 8).max(32 << 20).min(whole)
}

/// The streaming columns of one frame: the paper's Table 3 (needed, real-time loaded and
/// prefetched data, I/O time), the cache's own, and the real-time runtime's: late data
/// (needed, not resident when the frame was drawn) and whether the frame was drawn at its
/// needed level.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct StreamRecord {
    /// Bytes of the levels the blocks of M need (MiB, 2^20 bytes, decoded).
    pub needed_mib: f64,
    /// Of those, resident when the frame was drawn (MiB).
    pub needed_resident_mib: f64,
    /// Late data: needed, not resident when the frame was drawn (MiB); the blocks were drawn
    /// at their finest resident level instead.
    pub late_mib: f64,
    /// Blocks of M lacking some needed level when the frame was drawn.
    pub late_blocks: usize,
    /// Levels short, summed over the blocks of M.
    pub late_levels: usize,
    /// Whether every block of M had its needed levels resident (drawn at its needed level).
    pub at_needed_level: bool,
    /// `tin` from a store: selected tiles not built yet, drawn by a coarser ancestor.
    pub late_tiles: usize,
    /// The exact demand held more than the cache budget, so patches whose vertices lie between
    /// lattice samples (continuous factors, the DSS strips' blocks) asked the power-of-two
    /// lattice covering their vertices, not their full resolution
    /// ([`terrain_stream::demand_within`]): heights within that level's error of memory's.
    pub demand_on_lattice: bool,
    /// `geomorph` from a remote store whose table is read where it lies: pages of the table
    /// the frame did not wait for (not fetched yet), their patches drawn by the coarse bounds
    /// (finer, never coarser).
    pub late_table_pages: u64,
    /// Loaded on the frame thread (the paper's real-time loaded data; only the first frame of
    /// a real-time session), MiB.
    pub sync_mib: f64,
    /// Arrived from the workers (prefetched data), MiB.
    pub prefetched_mib: f64,
    /// Read from disk, MiB.
    pub disk_mib: f64,
    /// I/O time (synchronous reads plus the workers' reads that arrived), ms.
    pub io_ms: f64,
    /// Blocks loaded synchronously.
    pub sync_loads: usize,
    /// Whether the frame thread read from disk or waited for the workers.
    pub waited_for_io: bool,
    /// Time the frame thread waited for the workers (warm frames only), ms.
    pub wait_ms: f64,
    /// Blocks of M with every needed level resident before the frame's loads.
    pub cache_hits: usize,
    /// Blocks of M lacking a needed level.
    pub cache_misses: usize,
    /// Levels unloaded to stay within the budget.
    pub evictions: usize,
    /// Stale requests cancelled (their blocks left the scheduling region).
    pub cancelled: usize,
    /// Resident bytes after the frame (MiB).
    pub resident_mib: f64,
    /// The budget, MiB.
    pub budget_mib: f64,
    /// Requests queued or loading.
    pub queue_depth: usize,
    /// Decoded data those requests have not delivered yet (MiB).
    pub queued_mib: f64,
    /// Blocks in M.
    pub blocks_visible: usize,
    /// Blocks in the scheduling region N (M included).
    pub blocks_scheduled: usize,
    /// Store faults met this frame (block levels that could not be read), repeats included.
    pub faults: usize,
    /// The faults new this session, one line each in the user's words: the block file, the
    /// block, its level and area, the cause, and what is drawn instead (a coarser level, or
    /// nothing). A fault that repeats (the block is retried) is not listed again.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub new_faults: Vec<String>,
    /// Time the streamer took on the frame thread (the wait of a warm frame included), ms.
    pub stream_ms: f64,
}

impl StreamRecord {
    fn new(s: &terrain_stream::FrameStats) -> Self {
        let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3;
        Self {
            needed_mib: s.needed_bytes as f64 / MIB,
            needed_resident_mib: s.needed_resident_bytes as f64 / MIB,
            late_mib: s.late_bytes as f64 / MIB,
            late_blocks: s.late_blocks,
            late_levels: s.late_levels,
            at_needed_level: s.at_needed_level(),
            late_tiles: 0,
            late_table_pages: 0,
            demand_on_lattice: false,
            sync_mib: s.sync_bytes as f64 / MIB,
            prefetched_mib: s.prefetched_bytes as f64 / MIB,
            disk_mib: s.disk_bytes as f64 / MIB,
            io_ms: ms(s.io_time),
            sync_loads: s.sync_loads,
            waited_for_io: s.waited_for_io(),
            wait_ms: ms(s.wait_time),
            cache_hits: s.cache_hits,
            cache_misses: s.cache_misses,
            evictions: s.evictions,
            cancelled: s.cancelled,
            resident_mib: s.resident_bytes as f64 / MIB,
            budget_mib: s.budget_bytes as f64 / MIB,
            queue_depth: s.queue_depth,
            queued_mib: s.queued_bytes as f64 / MIB,
            blocks_visible: s.blocks_visible,
            blocks_scheduled: s.blocks_scheduled,
            faults: s.faults.len(),
            new_faults: s.faults.iter().filter(|f| f.first).map(ToString::to_string).collect(),
            stream_ms: 0.0,
        }
    }
}

/// The streaming figures of a whole played flight (every frame, not only the measured ones).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct StreamSummary {
    /// Whether the frames ran in real time (else every frame waited until warm).
    pub real_time: bool,
    /// Frames played.
    pub frames: usize,
    /// Frames after the first that waited for I/O (0 in real time).
    pub waited_after_first: usize,
    /// Frames drawn with every needed level resident.
    pub at_needed_level: usize,
    /// Share of frames drawn at their needed level, 0..1.
    pub at_needed_level_share: f64,
    /// Late MiB per frame: median and maximum.
    pub late_mib_median: f64,
    /// Late MiB per frame, maximum.
    pub late_mib_max: f64,
    /// Needed MiB per frame, median.
    pub needed_mib_median: f64,
    /// Prefetched MiB per frame, mean.
    pub prefetched_mib_mean: f64,
    /// Frames whose start was already past their due time (the frame loop fell behind the
    /// flight's frame rate).
    pub behind_schedule: usize,
    /// Largest resident MiB.
    pub peak_resident_mib: f64,
}

impl StreamSummary {
    /// The summary of `frames` (in order), `behind` of which started late.
    pub fn new(frames: &[StreamRecord], real_time: bool, behind: usize) -> Self {
        let n = frames.len();
        let median = |mut v: Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v.get(v.len() / 2).copied().unwrap_or(0.0)
        };
        let at = frames.iter().filter(|f| f.at_needed_level).count();
        Self {
            real_time,
            frames: n,
            waited_after_first: frames.iter().skip(1).filter(|f| f.waited_for_io).count(),
            at_needed_level: at,
            at_needed_level_share: if n == 0 { 0.0 } else { at as f64 / n as f64 },
            late_mib_median: median(frames.iter().map(|f| f.late_mib).collect()),
            late_mib_max: frames.iter().map(|f| f.late_mib).fold(0.0, f64::max),
            needed_mib_median: median(frames.iter().map(|f| f.needed_mib).collect()),
            prefetched_mib_mean: frames.iter().map(|f| f.prefetched_mib).sum::<f64>()
                / n.max(1) as f64,
            behind_schedule: behind,
            peak_resident_mib: frames.iter().map(|f| f.resident_mib).fold(0.0, f64::max),
        }
    }
}

/// A page to set (`Some`) or drop (`None`).
#[derive(Debug, Clone, PartialEq)]
pub struct PageUpdate {
    /// The page: `[column, row]` of its block.
    pub page: [u32; 2],
    /// Its new content.
    pub fill: Option<Page>,
}

/// One frame of the method.
#[derive(Debug, Clone)]
pub struct OocFrame {
    /// The patches (global quadtree nodes) with their factors.
    pub selection: Selection,
    /// The same, as the renderer draws them (`dss-strips`: every M-block, hidden ones with
    /// factors 0).
    pub patches: Vec<DrawPatch>,
    /// Triangles between the patches' domain points drawn in the same pass (`dss-strips`: the
    /// stitching strips and P-blocks); empty for the other methods.
    pub extra: ExtraTriangles,
    /// Page changes to apply before drawing.
    pub updates: Vec<PageUpdate>,
    /// Streaming statistics.
    pub stream: StreamRecord,
    /// Geomorph ([`StoreDraw::morph`]): its runs and single patches over the drawn blocks
    /// ([`morph_on_pages`]), drawn instead of [`OocFrame::patches`] (then empty).
    pub morph: Option<GeomipRuns>,
    /// The blocks drawn, each with the level its page holds.
    pub drawn: Vec<(BlockId, u8)>,
    /// Blocks drawn.
    pub blocks_drawn: usize,
    /// Blocks of M not drawn: nothing resident (a fault), or no slot left in the class of any
    /// of its resident levels.
    pub blocks_dropped: usize,
}

impl OocFrame {
    /// Bytes the frame's lists hold (their allocations: the selection, the draw patches, the
    /// extra triangles, geomorph's runs and the drawn blocks; not the page updates, which the
    /// renderer consumes). `uniform` over a 32769^2 store holds about 300 MB of them at 1 px
    /// (3.8 M patches, each listed as a [`Patch`] and a [`DrawPatch`]).
    pub fn list_bytes(&self) -> u64 {
        fn bytes<T>(v: &Vec<T>) -> u64 {
            (v.capacity() * std::mem::size_of::<T>()) as u64
        }
        let morph = self
            .morph
            .as_ref()
            .map_or(0, |m| bytes(&m.runs) + bytes(&m.patches) + bytes(&m.factors));
        bytes(&self.selection.patches)
            + bytes(&self.patches)
            + bytes(&self.extra.points)
            + bytes(&self.extra.indices)
            + bytes(&self.extra.heights)
            + bytes(&self.drawn)
            + morph
    }
}

/// A real-time frame's demand held to lattices has its exact demand preloaded last
/// ([`Streamer::set_demand_later`]) while that holds at most this share (1 / n) of the cache's
/// budget: the frame whose exact demand first fits [`REAL_TIME_EXACT_SHARE`] then finds most
/// of it resident. On `fast_pass` over the 32769^2 store, `pvps-b`'s exact demand fell under
/// the quarter at one frame and asked 183 MiB in 747 blocks at once: 16 frames late in a row.
pub const PRELOAD_EXACT_SHARE: u64 = 2;

/// What `draw` needs from the store ([`demand_of`]): its patches' levels exactly, and where
/// that holds more than `budget_bytes` and the patches' factors allow, the demand held to it
/// ([`demand_and_held`], as [`terrain_stream::demand_within`] holds it); with strips, exactly
/// the full resolution of every block a strip or P-block vertex lies on (the M-blocks are
/// shrunk for the strips, so their vertices fall between lattice samples; strips also reach
/// blocks that are hidden themselves), held to the lattice of each block's factor.
fn store_demands(
    tree: &StoreTree,
    draw: &StoreDraw,
    budget_bytes: u64,
) -> (Demand, Option<Demand>) {
    if let Some(m) = &draw.morph {
        return (morph_demand(tree, m), None);
    }
    // A mesh's vertices lie on the lattices its selection's factors say (`tin`).
    let Some(strips) = &draw.strips else {
        return demand_and_held(tree, &draw.selection, true, budget_bytes);
    };
    let used = &strips.lined;
    // Each carrier with its block's factor (a hidden block's is 2, its draw factors 0): what
    // the demand held to the budget asks of it (`demand_within`; the exact demand is its full
    // resolution whatever the factor).
    let mut all = draw.selection.clone();
    all.patches.extend(
        strips.nodes.iter().zip(&strips.patches).zip(used).filter(|(_, u)| **u).map(
            |((&node, p), _)| {
                let f = p.factors.outer.iter().chain(&p.factors.inner).fold(2f32, |m, &f| m.max(f));
                terrain_core::lod::Patch { node, outer: [f; 4], inner: [f; 2] }
            },
        ),
    );
    demand_and_held(tree, &all, false, budget_bytes)
}

/// [`store_demands`] held to `[lattice, coarsen]` bytes: to the first by the lattices
/// ([`terrain_stream::demand_within`]), and where that leaves more than the second, coarsened from
/// the blocks densest on screen from `eye` ([`coarsen_to_budget`]); the second value says whether
/// it was held either way. The coarsening's bound is the cache's whole budget (what it cannot evict
/// must fit), not a real-time frame's share: a coarsened demand moves with the eye, and a block
/// moved to a finer level is late unless predicted (`uniform` on `fast_pass` over the 16385^2
/// Everest store, whose exact demand fits the budget: 173 of 300 frames without late data coarsened
/// to the quarter, 300 before).
fn held_demand(
    tree: &StoreTree,
    draw: &StoreDraw,
    eye: DVec3,
    bounds: [u64; 2],
) -> (Vec<(BlockId, u8)>, bool) {
    let (demand, exact) = held_and_exact_demand(tree, draw, eye, bounds);
    (demand, exact.is_some())
}

/// [`held_demand`], with the exact demand beside it when it was held (`None`: the demand is
/// exact), from one pass over the patches.
fn held_and_exact_demand(
    tree: &StoreTree,
    draw: &StoreDraw,
    eye: DVec3,
    [lattice, coarsen]: [u64; 2],
) -> (Demand, Option<Demand>) {
    let (mut demand, mut exact) = match store_demands(tree, draw, lattice) {
        (exact, Some(held)) if held != exact => (held, Some(exact)),
        (exact, _) => (exact, None),
    };
    if exact.is_none() && terrain_stream::demand_bytes(&demand) > coarsen {
        exact = Some(demand.clone());
    }
    if coarsen_to_budget(tree, &mut demand, eye, coarsen) == 0 && exact.as_ref() == Some(&demand) {
        exact = None;
    }
    (demand, exact)
}

/// A real-time frame's demand is exact while it holds at most this share (1 / n) of the cache's
/// budget, else held to lattices ([`terrain_stream::demand_within`]; a warm frame's at most all of
/// it): `pvps-c` over the 32769^2 store on `fast_pass` drew 78.3 % of its frames at their needed
/// level when real-time frames were exact up to the whole budget (bench/ooc/README.md, "The patch
/// methods within the cache budget").
pub const REAL_TIME_EXACT_SHARE: u64 = 4;

/// A real-time frame whose selection took at most this share of the frame's period (the
/// flight's or viewer's frame rate, [`OocConfig::frame_rate_hz`]) selects again at the eye one
/// look-ahead ahead, so the streamer preloads the method's own levels
/// ([`Streamer::set_demand_ahead`]); a dearer one leaves the prediction to Eq. 7. On `fast_pass`
/// over the 32769^2 store, 30 fps: `pvps-c` (0.4-0.6 ms a selection) went from 78.3 % of its
/// frames at their needed level to 93-98 %, while `dss-2` (48 ms a selection) would have
/// spent 110 ms a frame instead of 65 (bench/ooc/README.md, "Eq. 8 with the method's own
/// levels").
pub const AHEAD_SELECTION_SHARE: f64 = 0.25;

/// That selection at the eye ahead is for a view this much wider at the same pixels per
/// radian ([`Camera::widened`]): the out-of-core paper's view frustum extension (section 4,
/// Fig. 9), so that what a turning view brings in at its sides is preloaded at the method's
/// own levels too. On `fast_pass` over the 32769^2 store (alternated, eight and six runs):
/// `pvps-b` at 0.5 px, frames not at their needed level median 5.5 -> 2 (4-29 -> 2-14), the
/// frame thread's CPU 9.8 -> 8.6 ms; `dss-strips` at 0.85 px 3-13 -> 3-4; `pvps-a`, `pvps-c`,
/// `dss-1` and geomorph unchanged within the runs' spread; peak RSS within +20 MiB
/// (bench/ooc/README.md, "The eyes ahead widened").
pub const AHEAD_WIDEN: f64 = 1.3;

/// What a LOD method drawn from a store selected ([`OocScene::frame_for`]).
#[derive(Debug, Clone, Default)]
pub struct StoreDraw {
    /// The patches as quadtree nodes with their factors (the streamer's demand, the
    /// measurement's coverage).
    pub selection: Selection,
    /// `dss-strips`: the draw patches (every M-block) and the strips' triangles, drawn instead of
    /// the selection's patches.
    pub strips: Option<StripFrame>,
    /// `tin`: triangles between lattice samples, drawn instead of the selection's patches, each
    /// point on the hidden carrier patch (factors 0) of its selection patch (same index). The
    /// selection's factors say which lattice each patch's points lie on (its demand).
    pub mesh: Option<ExtraTriangles>,
    /// Geomorph: its compact selection (runs and single patches), drawn instead of the
    /// selection's patches; the selection then holds no patches (its statistics only): the
    /// demand ([`morph_demand`]) and the drawn-block filter ([`morph_on_pages`]) work on the
    /// runs, and the coverage is built from them only when measured
    /// ([`crate::methods::geomorph_selection_runs`]).
    pub morph: Option<MorphDraw>,
}

/// Geomorph's compact selection over a store's patch tree ([`StoreDraw::morph`]).
#[derive(Debug, Clone)]
pub struct MorphDraw {
    /// The runs and single patches.
    pub runs: GeomipRuns,
    /// Cells per patch side (the patch tree's leaves).
    pub patch_cells: u32,
}

/// The streamer's demand of geomorph's compact selection: the same as [`demand_of`] over its
/// patches one by one (`geomorph_selection_runs`), computed in O(runs + single patches +
/// blocks the runs touch): every patch of a run asks the same level (its coarsest, every edge
/// at it), so one patch of each run in each block it touches stands for the others.
pub fn morph_demand(tree: &StoreTree, morph: &MorphDraw) -> Vec<(BlockId, u8)> {
    let (runs, n) = (&morph.runs, morph.patch_cells);
    let leaf = tree.shape().max_level();
    let mut standing = Selection::default();
    standing.patches.extend(runs.patches.iter().map(|p| geomorph_patch(p, n, leaf)));
    for r in &runs.runs {
        for_run_blocks(tree, r, |_, i, j| {
            standing.patches.push(geomorph_patch(&runs.run_patch(i, j), n, leaf));
        });
    }
    demand_of(tree, &standing, true)
}

/// `f(block, i, j)` for every block run `r` touches, `(i, j)` one of the run's patches in it
/// (its south-west one there); with patches larger than blocks, every patch of the run
/// (`block` its first block).
fn for_run_blocks(tree: &StoreTree, r: &PatchRun, mut f: impl FnMut(BlockId, u32, u32)) {
    let leaf = tree.shape().max_level();
    let (i1, j1) = (r.i + r.width, r.j + r.height);
    let Some(s) = leaf.checked_sub(tree.block_level()) else {
        for j in r.j..j1 {
            for i in r.i..i1 {
                let b = tree.blocks_under(NodeId::new(leaf, i, j));
                f(b[0], i, j);
            }
        }
        return;
    };
    for row in (r.j >> s)..=((j1 - 1) >> s) {
        for col in (r.i >> s)..=((i1 - 1) >> s) {
            f(BlockId::new(row, col), r.i.max(col << s), r.j.max(row << s));
        }
    }
}

/// Geomorph's compact selection kept to the patches over `drawn` blocks (every block under a
/// patch drawn), as the per-patch filter keeps them: a run whose blocks are all drawn stays
/// one (checked per block it touches); the kept patches of another run become single patches
/// (row by row, after the single patches kept, factor `L`). Empty runs are never produced.
pub fn morph_on_pages(
    tree: &StoreTree,
    mut runs: GeomipRuns,
    drawn: &IdMap<BlockId, u8>,
) -> GeomipRuns {
    let leaf = tree.shape().max_level();
    // A patch no larger than a block lies in one block (no list of blocks to build); the
    // single patches come row by row, so most lie in the block of the one before (its
    // verdict kept, no hash per patch).
    let last = std::cell::Cell::new(None::<(BlockId, bool)>);
    let on = |i: u32, j: u32| {
        let n = NodeId::new(leaf, i, j);
        match tree.block_of(n) {
            Some((b, _)) => match last.get() {
                Some((m, v)) if m == b => v,
                _ => {
                    let v = drawn.contains_key(&b);
                    last.set(Some((b, v)));
                    v
                }
            },
            None => tree.blocks_under(n).iter().all(|b| drawn.contains_key(b)),
        }
    };
    let keep: Vec<bool> = runs.patches.iter().map(|p| on(p.i, p.j)).collect();
    let mut k = keep.iter();
    runs.patches.retain(|_| *k.next().expect("parallel"));
    if runs.factors.len() == keep.len() {
        let mut k = keep.iter();
        runs.factors.retain(|_| *k.next().expect("parallel"));
    }
    let mut split = Vec::new();
    runs.runs.retain(|r| {
        let mut whole = true;
        for_run_blocks(tree, r, |b, _, _| whole &= drawn.contains_key(&b));
        // With patches larger than blocks, the per-block check above saw only each patch's
        // first block: check the patches themselves.
        if whole && tree.shape().max_level() < tree.block_level() {
            whole = (r.j..r.j + r.height).all(|j| (r.i..r.i + r.width).all(|i| on(i, j)));
        }
        if !whole {
            for j in r.j..r.j + r.height {
                split.extend((r.i..r.i + r.width).filter(|&i| on(i, j)).map(|i| (i, j)));
            }
        }
        whole
    });
    let l = f32::from(runs.coarsest);
    for (i, j) in split {
        let p = runs.run_patch(i, j);
        runs.patches.push(p);
        runs.factors.push(l);
    }
    runs
}

#[derive(Debug)]
pub struct OocScene {
    store: Arc<Store>,
    streamer: Streamer,
    config: OocConfig,
    layout: PageLayout,
    /// The store's quadtree (the selection's node source).
    tree: StoreTree,
    height_range: [f32; 2],
    /// Level each page currently holds.
    pages: BTreeMap<[u32; 2], u8>,
    /// The renderer's slot classes, finest (stride 1) first: class `c` holds level `k - c`.
    classes: Vec<PageClass>,
    mirror: Option<PagedHeights>,
    /// Whether the note that the demand was held to the budget was printed.
    warned_lattice: bool,
    /// Whether the demand of [`OocScene::frame_for`] is always exact ([`demand_of`]), never
    /// held to the budget ([`terrain_stream::demand_within`]): see
    /// [`OocScene::with_exact_demand`].
    exact_demand: bool,
    /// A real-time run ([`OocScene::with_real_time`]): its first, waiting frame holds the
    /// demand to the real-time share of the budget like every later frame.
    real_time: bool,
    /// Bytes of the budget the method keeps in its own caches ([`OocScene::with_reserved`]).
    reserved: u64,
    /// Bytes of the last frame's lists ([`OocFrame::list_bytes`]), or of this frame's selection
    /// where larger: the blocks get what they leave of the budget ([`OocScene::blocks_budget`]).
    frame_bytes: u64,
    /// The paper's method's tree walked one frame ahead ([`OocConfig::warm_ahead`]): started
    /// by the first real-time [`OocScene::frame`] (`Some(None)`: off, or the system could not
    /// start its thread; the frames run without it).
    warmer: Option<Option<TreeWarmer>>,
}

impl OocScene {
    /// Opens the store in `dir`, exaggerated by [`OocConfig::vertical_scale`], and starts its
    /// runtime.
    pub fn open(dir: &Path, config: OocConfig) -> Result<Self, StoreError> {
        let mut store = open_store(dir)?;
        if config.vertical_scale != 1.0 {
            store = store.exaggerated(config.vertical_scale)?;
        }
        Ok(Self::new(Arc::new(store), config))
    }

    /// The method over an opened store (exaggerated as it was opened:
    /// [`OocConfig::vertical_scale`] is not read here).
    pub fn new(store: Arc<Store>, config: OocConfig) -> Self {
        let h = store.header().clone();
        let refinement = config.refinement();
        let cells = h.block_cells();
        let tree = StoreTree::with_refinement(store.clone(), refinement);
        let [lo, hi] = tree
            .blocks_box()
            .map_or([f32::INFINITY, f32::NEG_INFINITY], |(lo, hi)| [lo.z as f32, hi.z as f32]);
        let layout = PageLayout {
            grid: [h.width as u32, h.height as u32],
            page_cells: [cells; 2],
            origin: h.georef.world_origin,
            spacing: h.georef.spacing_m,
        };
        let stream = StreamConfig {
            refinement,
            budget_bytes: config.budget_bytes,
            threads: config.threads,
            tau: config.tau,
            max_in_flight: config.max_in_flight,
            schedule: ScheduleConfig {
                lookahead_frames: LOOKAHEAD_FRAMES,
                frame_rate_hz: config.frame_rate_hz,
                ..ScheduleConfig::default()
            },
            ..StreamConfig::default()
        };
        if let Some((_, whole)) = store.index_cache_bytes() {
            store.set_index_cache_bytes(index_share(config.budget_bytes, whole));
        }
        let streamer = Streamer::new(store.clone(), stream);
        let mut classes = classes_for_budget(&layout, config.page_budget_bytes);
        classes[0].capacity = classes[0].capacity.min(config.page_capacity.max(1));
        Self {
            tree,
            store,
            streamer,
            config,
            layout,
            height_range: [lo, hi],
            pages: BTreeMap::new(),
            classes,
            mirror: None,
            warned_lattice: false,
            exact_demand: false,
            real_time: false,
            reserved: 0,
            frame_bytes: 0,
            warmer: None,
        }
    }

    /// Keeps a CPU copy of the pages ([`OocScene::mirror`]): the CPU reference of what the
    /// renderer draws (tests, the benchmark's error measurement).
    pub fn with_mirror(mut self) -> Self {
        self.mirror = Some(PagedHeights::new(self.layout));
        self
    }

    /// Makes every demand of [`OocScene::frame_for`] exact, above the budget if need be: for a
    /// measurement that takes a warm frame's heights to be the DEM's (no mirror: each patch on
    /// pages of its level or finer), which a demand held to the budget breaks (patches
    /// between lattice samples drawn from coarser lattices).
    pub fn with_exact_demand(mut self) -> Self {
        self.exact_demand = true;
        self
    }

    /// This runtime for a real-time run, whose frames after the first draw what is resident:
    /// the first frame, which waits, holds its demand to the same share of the budget as the
    /// later frames ([`REAL_TIME_EXACT_SHARE`]) instead of the whole budget, so it neither
    /// waits for, nor fills the cache with, full-resolution levels the next frames would not
    /// ask for (`pvps-c` on `fast_pass` over a 16385^2 Everest store: 1018 MiB loaded for the
    /// first frame against at most a quarter of the 1 GiB budget asked afterwards).
    pub fn with_real_time(mut self) -> Self {
        self.real_time = true;
        self
    }

    /// This runtime for a method that keeps `bytes` of the memory budget
    /// ([`OocConfig::budget_bytes`]) in caches of its own (`tin`'s built tiles and its
    /// builders' blocks): the stream cache gets what those and the view's index entries leave
    /// ([`OocScene::blocks_budget`]), so the one budget bounds them all.
    pub fn with_reserved(mut self, bytes: u64) -> Self {
        self.set_reserved(bytes);
        self
    }

    /// [`OocScene::with_reserved`] from the next frame on: for a cache whose size changes
    /// (a table read by pages, whose cache fills as the views need it).
    pub fn set_reserved(&mut self, bytes: u64) {
        self.reserved = bytes;
    }

    /// The CPU copy of the pages, if kept.
    pub fn mirror(&self) -> Option<&PagedHeights> {
        self.mirror.as_ref()
    }

    /// The store.
    pub fn store(&self) -> &Arc<Store> {
        &self.store
    }

    /// The runtime.
    pub fn streamer(&self) -> &Streamer {
        &self.streamer
    }

    /// Holds or releases the runtime's I/O ([`Streamer::hold_io`]).
    pub fn hold_io(&mut self, held: bool) {
        self.streamer.hold_io(held);
    }

    /// The page layout (one page per block).
    pub fn layout(&self) -> PageLayout {
        self.layout
    }

    /// Lowest and highest height of the store.
    pub fn height_range(&self) -> [f32; 2] {
        self.height_range
    }

    /// Cells per side of the root of the whole grid's quadtree the patches live in.
    pub fn root_cells(&self) -> u32 {
        self.tree.root_cells()
    }

    /// The settings.
    pub fn config(&self) -> &OocConfig {
        &self.config
    }

    /// The page slot classes the renderer holds (finest first), from the settings.
    pub fn page_classes(&self) -> &[PageClass] {
        &self.classes
    }

    /// A paged renderer for this store (slot classes from the settings).
    pub fn renderer(
        &self,
        ctx: &terrain_gpu::GpuContext,
        config: &terrain_gpu::RenderConfig,
    ) -> Result<TerrainRenderer, RenderError> {
        TerrainRenderer::new_paged_classes(
            ctx,
            self.layout,
            &self.classes,
            self.height_range,
            config,
        )
    }

    /// One frame for `camera`, real time by default: the streamer never waits for I/O after
    /// the session's first frame (which loads the visible blocks' coarse levels), each block is
    /// drawn at its finest resident level, and what arrived late is counted in the
    /// [`StreamRecord`]. With `warm`, waits (up to [`OocConfig::warm_timeout`]) until every
    /// level the frame needs is resident ([`Streamer::wait_until_resident`]) and draws each
    /// block at most at its needed level, so that what else the cache holds changes nothing:
    /// still images, and measurements of the selection's own error (`--wait`).
    pub fn frame(&mut self, camera: &Camera, warm: bool) -> OocFrame {
        let t0 = Instant::now();
        self.streamer.set_demand(None);
        self.streamer.set_budget_bytes(self.blocks_budget(None));
        // Eq. 8's eye ahead and the next frame's camera (from the step to this camera: asked
        // before the update), for the tree's walks.
        let (ahead, next) = match warm {
            true => (None, None),
            false => (self.streamer.camera_ahead(camera), self.streamer.camera_next(camera)),
        };
        let s = if warm {
            self.streamer.wait_until_resident(camera, self.config.warm_timeout).stats
        } else {
            self.streamer.update(camera)
        };
        let mut stream = StreamRecord::new(&s);
        stream.stream_ms = t0.elapsed().as_secs_f64() * 1e3;
        let (drawn, dropped) = self.assign_pages(warm);
        // The crack-free patches over the drawn blocks, each at most at its page's level.
        let page_level = BlockLevelGrid::new(&drawn);
        let selection = select_patches(&self.tree, camera, self.config.tau, |b| page_level.get(b));
        debug_assert!(check_shared_edges(&selection).is_empty());
        // The next frames' walks, beside this frame's drawing (the same patches either way).
        if let (Some(ahead), Some(next)) = (ahead, next) {
            let (tree, on) = (&self.tree, self.config.warm_ahead);
            let warmer = self
                .warmer
                .get_or_insert_with(|| on.then(|| TreeWarmer::spawn(tree).ok()).flatten());
            if let Some(w) = warmer {
                w.ahead(&ahead, &next, self.config.tau, drawn.clone());
            }
        }
        self.finish_frame(selection, None, &drawn, dropped, stream)
    }

    /// One frame of another LOD method drawn from this store: `select` chooses the patches
    /// over the store's terrain (nodes of `tree`, the store's tree at the method's leaf size;
    /// heights from the resident levels, [`StoreSource`]), the streamer loads what those
    /// patches need ([`demand_of`], [`Streamer::set_demand`]; Eq. 8 preloading around it as
    /// for `ooc`), and every block a patch lies in is drawn from its finest resident level
    /// (at most its needed one when `warm`).
    /// Real time unless `warm`: then it waits until the patches' levels are resident and
    /// selects again with the exact heights (the patch corners' heights enter PVPS's edge
    /// factors), until the demand holds still (at most three rounds), so a warm frame draws
    /// the patches the method selects from the heightmap in memory. Patches over a block with
    /// no page (no slot left) are not drawn; the block is counted in
    /// [`OocFrame::blocks_dropped`]. Geomorph's compact selection ([`StoreDraw::morph`]) is
    /// never expanded here: its demand is [`morph_demand`], its filter [`morph_on_pages`], and
    /// it comes back as [`OocFrame::morph`].
    pub fn frame_for(
        &mut self,
        camera: &Camera,
        warm: bool,
        tree: &StoreTree,
        select: &mut dyn FnMut(&dyn TerrainSource, &Camera) -> StoreDraw,
    ) -> OocFrame {
        let t0 = Instant::now();
        let mut draw = select(&StoreSource::new(tree, &self.streamer), camera);
        let mut select_time = draw.selection.stats.cpu_time;
        // This frame's lists count from now: each selected patch is listed once more as a
        // draw patch (a run's first frame has no last frame to go by).
        let listed = std::mem::size_of::<Patch>() + std::mem::size_of::<DrawPatch>();
        self.frame_bytes = self.frame_bytes.max((draw.selection.patches.len() * listed) as u64);
        let blocks = self.blocks_budget(Some(tree));
        self.streamer.set_budget_bytes(blocks);
        // The bytes the exact demand may hold (`demand_within`): a warm frame's the cache's
        // budget, a real-time frame's (and a real-time run's first, waiting one's) a quarter
        // of it (the rest is the next frame's need and Eq. 8's preloading, which a frame
        // asking most of the budget at full resolution leaves late), a measurement's no limit.
        let budget = match (self.exact_demand, warm && !self.real_time) {
            (true, _) => u64::MAX,
            (false, true) => blocks,
            (false, false) => blocks / REAL_TIME_EXACT_SHARE,
        };
        // The lattices hold the demand to `budget`, the coarsening to the whole budget (none
        // when exact).
        let bounds = [budget, budget.max(blocks)];
        let (mut demand, exact) = held_and_exact_demand(tree, &draw, camera.position, bounds);
        let mut on_lattice = exact.is_some();
        self.streamer.set_demand(Some(demand.clone()));
        // Eq. 8 with the method's own levels: its selection at the eye one look-ahead ahead,
        // over the same resident heights, says where its level boundaries will be (Eq. 7's
        // prediction alone leaves every block crossing one a level late). Its time is the
        // streamer's (`stream_ms`), not the frame's selection; a selection dearer than
        // `AHEAD_SELECTION_SHARE` of the frame is not run twice.
        let period_s = 1.0 / self.config.frame_rate_hz.max(1e-3);
        let cheap = select_time.as_secs_f64() <= AHEAD_SELECTION_SHARE * period_s;
        let ahead = match self.streamer.camera_ahead(camera) {
            Some(next) if !warm && cheap => {
                let next = next.widened(AHEAD_WIDEN);
                let draw = select(&StoreSource::new(tree, &self.streamer), &next);
                Some(held_demand(tree, &draw, next.position, bounds).0)
            }
            _ => None,
        };
        self.streamer.set_demand_ahead(ahead);
        // A real-time demand held to lattices while its exact demand fits
        // `PRELOAD_EXACT_SHARE` of the budget: the exact levels are preloaded last, so that the
        // frame whose exact demand first fits the real-time share finds them resident.
        let later = exact
            .filter(|_| !warm && !self.exact_demand)
            .filter(|exact| terrain_stream::demand_bytes(exact) <= blocks / PRELOAD_EXACT_SHARE);
        self.streamer.set_demand_later(later);
        let s = if warm {
            let mut s = self.streamer.wait_until_resident(camera, self.config.warm_timeout).stats;
            for _ in 0..3 {
                draw = select(&StoreSource::new(tree, &self.streamer), camera);
                select_time += draw.selection.stats.cpu_time;
                let (again, lattice) = held_demand(tree, &draw, camera.position, bounds);
                if again == demand {
                    break;
                }
                (demand, on_lattice) = (again, lattice);
                self.streamer.set_demand(Some(demand.clone()));
                s = self.streamer.wait_until_resident(camera, self.config.warm_timeout).stats;
            }
            s
        } else {
            self.streamer.update(camera)
        };
        let mut stream = StreamRecord::new(&s);
        stream.stream_ms = t0.elapsed().saturating_sub(select_time).as_secs_f64() * 1e3;
        stream.demand_on_lattice = on_lattice;
        if on_lattice && !self.warned_lattice {
            self.warned_lattice = true;
            eprintln!(
                "note: this view's patches need {:.1} MiB of the store at full resolution, more \
                 than {:.2} MiB ({}the cache's budget, --cache-mib; the benchmark's \
                 --ooc-cache-mib): patches whose vertices lie between the samples are drawn \
                 from the power-of-two level that covers them, and where that is still more, \
                 the blocks whose samples are densest on screen from coarser levels (heights \
                 within that level's error); the frames are counted in the streaming summary",
                terrain_stream::demand_bytes(&store_demands(tree, &draw, u64::MAX).0) as f64 / MIB,
                budget as f64 / MIB,
                if budget == blocks { "" } else { "a real-time frame's share of " }
            );
        }
        let (drawn, dropped) = self.assign_pages(warm);
        let paged: IdMap<BlockId, u8> = drawn.iter().copied().collect();
        let on_pages = |n: NodeId| tree.blocks_under(n).iter().all(|b| paged.contains_key(b));
        let StoreDraw { mut selection, strips, mesh, morph } = draw;
        if let Some(m) = morph {
            let runs = morph_on_pages(tree, m.runs, &paged);
            selection.stats.patches = runs.drawn_patches() as usize;
            let mut frame = self.finish_frame(selection, None, &drawn, dropped, stream);
            frame.morph = Some(runs);
            self.frame_bytes = frame.list_bytes();
            return frame;
        }
        if let Some(mut extra) = mesh {
            let root = tree.root_cells();
            let off: Vec<bool> = selection.patches.iter().map(|p| !on_pages(p.node)).collect();
            let patches: Vec<DrawPatch> = selection
                .patches
                .iter()
                .map(|p| {
                    let (x0, y0, c) = p.node.grid_rect(root);
                    let factors = PatchFactors { inner: [0.0; 2], outer: [0.0; 4] };
                    DrawPatch { rect: [x0, y0, x0 + c, y0 + c], factors }
                })
                .collect();
            drop_triangles_of(&mut extra, &off);
            return self.finish_frame(selection, Some((patches, extra)), &drawn, dropped, stream);
        }
        match strips {
            None => {
                selection.patches.retain(|p| on_pages(p.node));
                selection.stats.patches = selection.patches.len();
                self.finish_frame(selection, None, &drawn, dropped, stream)
            }
            Some(StripFrame { mut patches, nodes, mesh, .. }) => {
                let mut extra = mesh.triangles;
                // Blocks on no page are not drawn, nor the strip triangles that reach them.
                let off: Vec<bool> = nodes.iter().map(|&n| !on_pages(n)).collect();
                for (p, &off) in patches.iter_mut().zip(&off) {
                    if off {
                        p.factors = PatchFactors { inner: [0.0; 2], outer: [0.0; 4] };
                    }
                }
                drop_triangles_of(&mut extra, &off);
                self.finish_frame(selection, Some((patches, extra)), &drawn, dropped, stream)
            }
        }
    }

    /// The stream cache's share of the one memory budget ([`OocConfig::budget_bytes`]): what
    /// the index entries the trees keep for the view leave (this scene's tree and the method's
    /// `tree`, unless one is the other's clone; [`StoreTree::visited_bytes`]), the store's
    /// decoded index pages ([`index_share`]), the method's own caches
    /// ([`OocScene::with_reserved`]) and the frame's lists (`frame_bytes`: the last frame's
    /// [`OocFrame::list_bytes`], or this frame's selection where larger), at least half of it.
    /// A selection over a 32769^2 store keeps 139 MB of entries for its view (`dss-2` on
    /// `fast_pass`), which a budget of blocks alone left above it (bench/ooc/README.md, "One
    /// memory budget for the blocks and the view's index entries"); `uniform`'s lists at 1 px
    /// are about 300 MB ("One memory budget for the frame's lists too").
    fn blocks_budget(&self, tree: Option<&StoreTree>) -> u64 {
        let index = self.store.index_cache_bytes().map_or(0, |(b, whole)| b.min(whole));
        let mut entries = self.tree.visited_bytes() + self.reserved + index + self.frame_bytes;
        if let Some(t) = tree.filter(|t| !t.shares_visited_with(&self.tree)) {
            entries += t.visited_bytes();
        }
        let all = self.config.budget_bytes;
        all.saturating_sub(entries).max(all / 2)
    }

    /// The blocks of the last update's visual region M drawn this frame, nearest first, each at
    /// the finest of its resident levels (at most its needed level when `warm`) whose page
    /// class has a slot left; and how many blocks of M got none.
    fn assign_pages(&self, warm: bool) -> (Vec<(BlockId, u8)>, usize) {
        let header = self.store.header();
        let mut drawn: Vec<(BlockId, u8)> = Vec::new();
        let mut dropped = 0;
        // Slots taken per class this frame: each block, nearest first, takes the finest of its
        // resident levels whose class has a slot left. A warm frame takes none beyond the
        // block's needed level: what else is resident (Eq. 8's prefetches, earlier frames'
        // levels) depends on the workers' timing and the frames before, and would change the
        // slots and, through them and the spanning patches' resident test, the selection.
        let mut used = vec![0u32; self.classes.len()];
        for s in self.streamer.scheduled().iter().filter(|s| s.visible) {
            let mut levels = self.streamer.block(s.block).map_or(0, |b| b.count());
            if warm {
                levels = levels.min(usize::from(s.needed) + 1);
            }
            let fits = (0..levels).rev().find(|&l| {
                let c = (header.k as usize).checked_sub(l);
                c.is_some_and(|c| c < used.len() && used[c] < self.classes[c].capacity)
            });
            let Some(level) = fits else {
                dropped += 1;
                continue;
            };
            used[header.k as usize - level] += 1;
            drawn.push((s.block, level as u8));
        }
        (drawn, dropped)
    }

    /// The frame of `selection` over the `drawn` blocks' pages: page changes (refill where the
    /// drawn level changed, drop blocks no longer drawn), the mirror kept in step.
    fn finish_frame(
        &mut self,
        selection: Selection,
        strips: Option<(Vec<DrawPatch>, ExtraTriangles)>,
        drawn: &[(BlockId, u8)],
        dropped: usize,
        stream: StreamRecord,
    ) -> OocFrame {
        let (draw, extra) = match strips {
            Some((patches, extra)) => (patches, extra),
            None => (
                selection
                    .patches
                    .iter()
                    .map(|p| {
                        let (x0, y0, c) = p.node.grid_rect(self.tree.root_cells());
                        DrawPatch { rect: [x0, y0, x0 + c, y0 + c], factors: patch_factors(p) }
                    })
                    .collect(),
                ExtraTriangles::default(),
            ),
        };
        let mut updates = Vec::new();
        let want: BTreeMap<[u32; 2], (BlockId, u8)> =
            drawn.iter().map(|&(id, l)| ([id.col, id.row], (id, l))).collect();
        let gone: Vec<[u32; 2]> =
            self.pages.keys().filter(|p| !want.contains_key(*p)).copied().collect();
        for page in gone {
            self.pages.remove(&page);
            updates.push(PageUpdate { page, fill: None });
        }
        for (&page, &(id, level)) in &want {
            if self.pages.get(&page) == Some(&level) {
                continue;
            }
            let Some(fill) = self.page_fill(id, level) else { continue };
            self.pages.insert(page, level);
            updates.push(PageUpdate { page, fill: Some(fill) });
        }
        if let Some(m) = self.mirror.as_mut() {
            for u in &updates {
                match &u.fill {
                    Some(p) => m.insert(u.page, p.clone()).expect("a page of the layout"),
                    None => {
                        m.remove(u.page);
                    }
                }
            }
        }
        let frame = OocFrame {
            selection,
            patches: draw,
            extra,
            updates,
            stream,
            morph: None,
            drawn: drawn.to_vec(),
            blocks_drawn: drawn.len(),
            blocks_dropped: dropped,
        };
        self.frame_bytes = frame.list_bytes();
        frame
    }

    /// Block `id`'s page at its resident `level`: the level's lattice (see the module docs).
    fn page_fill(&self, id: BlockId, level: u8) -> Option<Page> {
        let header = self.store.header();
        let grid = self.streamer.block(id)?.grid(level)?;
        let stride = 1u32 << (header.k - level);
        // `grid` is the level's own, new vector: moved into the page, not copied.
        if stride > 1 {
            return Some(Page { samples: grid, stride });
        }
        let cells = header.block_cells();
        let [w, h] = self.layout.page_samples();
        let side = (cells + 1) as usize;
        let samples = if w as usize == side && h as usize == side {
            grid
        } else {
            (0..h as usize)
                .flat_map(|b| grid[b * side..b * side + w as usize].iter().copied())
                .collect()
        };
        Some(Page { samples, stride })
    }

    /// Applies a frame's page changes to a renderer built by [`OocScene::renderer`].
    /// Every changed page leaves its slot first, so pages trading classes within the frame
    /// always find one (the frame took no more slots of a class than it has).
    pub fn apply(renderer: &mut TerrainRenderer, frame: &OocFrame) -> Result<(), RenderError> {
        for u in &frame.updates {
            renderer.remove_page(u.page);
        }
        for u in &frame.updates {
            if let Some(p) = &u.fill {
                renderer.set_page_lattice(u.page, &p.samples, p.stride)?;
            }
        }
        Ok(())
    }

    /// An overview heightmap of the whole store from every block's levels `0..=level` (every
    /// `2^(k - level)`-th sample, the grid's extent rounded down to that step): what a flight is
    /// placed on (relief, clearance) without reading the full grid. Reads each block's coarse
    /// levels once ([`store_heightmap`] over every block).
    pub fn overview(&self, level: u8) -> Result<Heightmap, StoreError> {
        let h = self.store.header();
        let mid = 0.5 * (self.height_range[0] + self.height_range[1]);
        store_heightmap(&self.store, level, [0..h.blocks_x, 0..h.blocks_y], mid)
    }

    /// A heightmap of 2 x 2 samples with the store's extent and height range: enough for the
    /// renderer's framing ([`terrain_gpu::render::default_camera`]).
    pub fn bounds_heightmap(&self) -> Heightmap {
        let h = self.store.header();
        let [w, hh] = self.layout.grid;
        let extent = DVec2::new(
            f64::from(w.max(2) - 1) * h.georef.spacing_m.x,
            f64::from(hh.max(2) - 1) * h.georef.spacing_m.y,
        );
        let g = Georef::projected(Crs::Unknown, h.georef.world_origin, extent);
        let [lo, hi] = self.height_range;
        Heightmap::from_fn(2, 2, g, |i, j| if (i + j) % 2 == 0 { lo } else { hi })
            .expect("a 2 x 2 grid")
    }

    /// Near and far distances for a camera at `position`: far reaches the farthest corner of
    /// the store's box, near is half the distance to the nearest block's box (at least
    /// `far / 1e6` and 0.05 m).
    pub fn clip_range(&self, position: DVec3) -> (f64, f64) {
        // The blocks' boxes through the tree (the head's pyramid of a version-4 index): only
        // the corner blocks and those near the eye read their entries.
        let (lo, hi) = self
            .tree
            .blocks_box()
            .unwrap_or((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)));
        let nearest = self.tree.nearest_block_distance(position);
        terrain_gpu::render::near_far(lo, hi, nearest, position)
    }
}

/// Bakes `hm` into the folder `dir` (replaced) with blocks of `2^k` cells, for a measurement:
/// lossless where the heights lie on a 0.1 m lattice (scaled grey images, integer DEMs), else
/// the store's default 1 cm bound. The benchmark's temporary store and a calibration's window
/// ([`crate::ooc_calibration`]).
pub fn bake_temporary(hm: &Heightmap, k: u8, dir: &Path) -> anyhow::Result<()> {
    use terrain_stream::{BakeConfig, BakeProgress, HeightEncoding, bake};
    let lattice = hm.data().iter().all(|&h| ((h * 10.0).round() - h * 10.0).abs() < 1e-3);
    let encoding = if lattice {
        HeightEncoding::Quantized { step_m: 0.1, offset_m: 0.0 }
    } else {
        HeightEncoding::default()
    };
    let config = BakeConfig { k, encoding, overwrite: true, ..Default::default() };
    bake(hm, dir, &config, &mut |_: &BakeProgress| std::ops::ControlFlow::Continue(()))
        .map_err(|e| anyhow::anyhow!("could not bake {}: {e}", dir.display()))?;
    Ok(())
}

/// The heights of `store`'s blocks in columns `blocks[0]` and rows `blocks[1]` at `level` (every
/// `2^(k - level)`-th sample; `k` gives the full grid; the ranges are of existing blocks, not
/// empty), as a heightmap placed where those
/// samples lie in the world, clipped to the grid's extent (rounded down to the step): the
/// overview of [`OocScene::overview`] (every block) and the window a calibration is measured
/// on ([`crate::ooc_calibration`]). A damaged block (checksum, truncation) gives its finest
/// readable coarser level, sampled nearest; with no level readable, `fill` metres. Heights as
/// `store` reads them (its exaggeration).
pub fn store_heightmap(
    store: &Store,
    level: u8,
    blocks: [std::ops::Range<u32>; 2],
    fill: f32,
) -> Result<Heightmap, StoreError> {
    let (w, h, data, georef) = assemble(store, level, blocks, Some(fill))?;
    Ok(Heightmap::from_fn(w, h, georef, |i, j| data[j * w + i]).expect("finite store heights"))
}

/// The whole grid of `store` at full resolution (its level `k`), exactly as stored: a
/// measurement's reference (`terrain view`'s on-demand p99 over a store). Unlike
/// [`store_heightmap`] nothing is made up: a block that cannot be read at full resolution is an
/// error, and so is a sample no block covers. Heights as `store` reads them (its exaggeration,
/// its quantization).
pub fn store_heightmap_exact(store: &Store) -> anyhow::Result<Heightmap> {
    let h = store.header();
    let (w, hh, data, georef) = assemble(store, h.k, [0..h.blocks_x, 0..h.blocks_y], None)
        .map_err(|e| anyhow::anyhow!("could not read the store at full resolution: {e}"))?;
    Heightmap::new(w, hh, data, terrain_core::VoidMask::new(w, hh), georef).map_err(|e| {
        anyhow::anyhow!(
            "the store {} does not cover its grid at full resolution ({e}): bake it again",
            store.dir().display()
        )
    })
}

/// The samples of [`store_heightmap`] (`fill: Some`) or [`store_heightmap_exact`] (`None`:
/// only `level` itself is read, a failed read is an error, and uncovered samples are NaN):
/// width, height, row-major heights and the window's georeference.
fn assemble(
    store: &Store,
    level: u8,
    blocks: [std::ops::Range<u32>; 2],
    fill: Option<f32>,
) -> Result<(usize, usize, Vec<f32>, Georef), StoreError> {
    let h = store.header();
    let level = level.min(h.k);
    let d = 1u64 << (h.k - level);
    let per_block = 1usize << level;
    let [cols, rows] = blocks;
    let (i0, j0) = (cols.start as usize * per_block, rows.start as usize * per_block);
    let (full_w, full_h) = (((h.width - 1) / d + 1) as usize, ((h.height - 1) / d + 1) as usize);
    let w = full_w.saturating_sub(i0).min(cols.len() * per_block + 1);
    let hh = full_h.saturating_sub(j0).min(rows.len() * per_block + 1);
    // A baked grid is at least 2 x 2 samples, and so is every block's share of it at `k`.
    let (w, hh) = (w.max(2), hh.max(2));
    let mut data = vec![fill.unwrap_or(f32::NAN); w * hh];
    for id in store.block_ids().filter(|b| cols.contains(&b.col) && rows.contains(&b.row)) {
        let read = match fill {
            // Exact: this level or an error.
            None => store.read_block(id, level)?.grid(level).map(|g| (level, g)),
            // The overview only places cameras and frames views: the renderer reports each
            // fault itself when it streams the block, so nothing is said here.
            Some(_) => (0..=level).rev().find_map(|l| {
                let b = store.read_block(id, l).ok()?;
                Some((l, b.grid(l)?))
            }),
        };
        let Some((l, grid)) = read else { continue };
        let side = per_block + 1;
        let (ls, shift) = ((1usize << l) + 1, level - l);
        for bj in 0..side {
            let j = (id.row - rows.start) as usize * per_block + bj;
            if j >= hh {
                break;
            }
            for bi in 0..side {
                let i = (id.col - cols.start) as usize * per_block + bi;
                if i < w {
                    data[j * w + i] = grid[(bj >> shift) * ls + (bi >> shift)];
                }
            }
        }
    }
    let spacing = h.georef.spacing_m * d as f64;
    let origin = h.georef.world_origin + DVec2::new(i0 as f64, j0 as f64) * h.georef.spacing_m;
    let g = Georef::projected(Crs::Unknown, origin, spacing);
    Ok((w, hh, data, g))
}

/// Drops from `extra` every triangle with a vertex on a patch marked `off` (indexed by the
/// points' `patch_index`): a block on no page is not drawn, nor what reaches it.
fn drop_triangles_of(extra: &mut ExtraTriangles, off: &[bool]) {
    if !off.iter().any(|&o| o) {
        return;
    }
    let pts = &extra.points;
    extra.indices = extra
        .indices
        .chunks_exact(3)
        .filter(|t| t.iter().all(|&i| !off[pts[i as usize].patch_index as usize]))
        .flatten()
        .copied()
        .collect();
}

#[cfg(test)]
mod tests {
    use super::*;
    use terrain_stream::{BakeConfig, BakeProgress, HeightEncoding, bake};

    /// A `side` x `side` ramp with a sawtooth (10 m spacing) baked into a store of 32-cell
    /// blocks in a temporary folder, removed when the folder is dropped (also when the test
    /// panics).
    fn ramp_store(prefix: &str, side: usize) -> (tempfile::TempDir, Arc<Store>) {
        let tmp = tempfile::Builder::new().prefix(prefix).tempdir().unwrap();
        let dir = tmp.path().join("store");
        let hm = Heightmap::from_fn(side, side, Georef::local(10.0), |i, j| {
            ((i * 7 + j * 13) % 97) as f32 + 0.3 * i as f32
        })
        .unwrap();
        let cfg = BakeConfig { k: 5, ..Default::default() };
        bake(&hm, &dir, &cfg, &mut |_: &BakeProgress| std::ops::ControlFlow::Continue(())).unwrap();
        let store = Arc::new(Store::open(&dir).unwrap());
        (tmp, store)
    }

    /// One memory budget: the stream cache gets what the index entries the view keeps, the
    /// store's decoded index pages, the method's own caches and the frame's lists leave of it,
    /// and at least half of it when they would take more.
    #[test]
    fn the_blocks_get_what_the_views_entries_and_the_frames_lists_leave_of_the_budget() {
        let (_tmp, store) = ramp_store("terrain-app-budget-", 513);
        let camera = Camera::from_yaw_pitch(glam::dvec3(-300.0, -300.0, 900.0), 45.0, -25.0)
            .with_viewport(320.0, 180.0);
        // The view's entries, the last frame's lists and the blocks' budget after the second
        // frame of the same view.
        let reserved = |all: u64, reserved: u64| {
            let config = OocConfig { threads: 1, budget_bytes: all, ..OocConfig::default() };
            let mut scene = OocScene::new(store.clone(), config).with_reserved(reserved);
            let lists = scene.frame(&camera, false).list_bytes();
            let entries = scene.tree.visited_bytes();
            scene.frame(&camera, false);
            (entries, lists, scene.streamer().budget_bytes())
        };
        let budget = |all: u64| reserved(all, 0);
        let (entries, lists, blocks) = budget(64 << 20);
        assert!(entries > 10_000, "the view's entries: {entries} bytes");
        assert!(lists > 1_000, "the frame's lists: {lists} bytes");
        // The store's decoded index pages: the whole index, smaller than the 32 MiB floor.
        let (cache, whole) = store.index_cache_bytes().expect("a paged index");
        assert!(whole > 10_000 && whole < 8 << 20, "{whole} bytes");
        assert_eq!((cache, index_share(64 << 20, whole)), (whole, whole));
        assert_eq!(blocks, (64 << 20) - entries - whole - lists);
        // A method's own caches (`tin`'s tiles) come off the blocks' share too.
        let (_, _, blocks) = reserved(64 << 20, 8 << 20);
        assert_eq!(blocks, (56 << 20) - entries - whole - lists);
        // A cache that fills as the views need it (geomorph's or the DSS table read by pages)
        // is set before each frame and counts from that frame on.
        let config = OocConfig { threads: 1, budget_bytes: 64 << 20, ..OocConfig::default() };
        let mut scene = OocScene::new(store.clone(), config);
        let lists = scene.frame(&camera, false).list_bytes();
        scene.set_reserved(4 << 20);
        let next = scene.frame(&camera, false).list_bytes();
        assert_eq!(scene.streamer().budget_bytes(), (60 << 20) - entries - whole - lists);
        scene.set_reserved(0);
        scene.frame(&camera, false);
        assert_eq!(scene.streamer().budget_bytes(), (64 << 20) - entries - whole - next);
        let (entries, _, blocks) = budget(entries);
        assert_eq!(blocks, entries / 2, "at least half for the blocks");

        // Another method's frame: its selection's patches count from the frame that selects
        // them, each listed twice (as a patch and as a draw patch), on a run's first frame too.
        let config = OocConfig { threads: 1, budget_bytes: 64 << 20, ..OocConfig::default() };
        let mut scene = OocScene::new(store.clone(), config);
        let tree = scene.tree.clone();
        let max = tree.shape().max_level();
        let many = |src: &dyn TerrainSource, camera: &Camera| {
            let mut selection = crate::methods::select_uniform(src, camera, 4.0);
            // Every patch listed again: a selection as large as a view over a big store.
            let each = selection.patches.clone();
            for _ in 0..40 {
                selection.patches.extend_from_slice(&each);
            }
            StoreDraw { selection, ..Default::default() }
        };
        let frame = scene.frame_for(&camera, false, &tree, &mut { many });
        let n = frame.selection.patches.len();
        assert!(n > 10_000 && frame.selection.patches.iter().all(|p| p.node.level == max));
        let listed = (n * (std::mem::size_of::<Patch>() + std::mem::size_of::<DrawPatch>())) as u64;
        let entries = scene.tree.visited_bytes();
        assert_eq!(scene.streamer().budget_bytes(), (64 << 20) - entries - whole - listed);
        assert_eq!(frame.list_bytes(), scene.frame_bytes);
        assert!(frame.list_bytes() >= listed, "{} against {listed}", frame.list_bytes());
    }

    /// A real-time frame's method selects at the eye ahead (Eq. 8) for a view `AHEAD_WIDEN`
    /// times wider at the same pixels per radian; a waiting frame selects only for its camera.
    #[test]
    fn the_method_selects_ahead_for_a_wider_view() {
        let (_tmp, store) = ramp_store("terrain-app-ahead-", 513);
        let config = OocConfig { threads: 1, budget_bytes: 64 << 20, ..OocConfig::default() };
        let mut scene = OocScene::new(store.clone(), config);
        let tree = scene.tree.clone();
        let seen = std::cell::RefCell::new(Vec::new());
        let mut select = |src: &dyn TerrainSource, camera: &Camera| {
            seen.borrow_mut().push(*camera);
            let selection = crate::methods::select_uniform(src, camera, 4.0);
            StoreDraw { selection, ..Default::default() }
        };
        let at = |x: f64| {
            Camera::from_yaw_pitch(glam::dvec3(x, -300.0, 900.0), 45.0, -25.0)
                .with_viewport(320.0, 180.0)
        };
        scene.frame_for(&at(-300.0), true, &tree, &mut select);
        assert!(seen.borrow().iter().all(|c| *c == at(-300.0)), "a waiting frame");
        // Moving: the eye ahead is further along x, its view wider.
        for k in 1..4 {
            seen.borrow_mut().clear();
            let camera = at(-300.0 + 40.0 * f64::from(k));
            scene.frame_for(&camera, false, &tree, &mut select);
            let seen = seen.borrow();
            assert_eq!(seen[0], camera);
            let ahead = seen.iter().find(|c| **c != camera).expect("a selection ahead");
            assert!(ahead.position.x > camera.position.x, "{}", ahead.position);
            assert!((ahead.fov_y - AHEAD_WIDEN * camera.fov_y).abs() < 1e-12);
            assert!((ahead.lambda() - camera.lambda()).abs() < 1e-9 * camera.lambda());
        }
    }

    /// The demand a frame asks and the exact demand preloaded last come from one pass: the
    /// exact demand is given beside the held one whenever the lattices or the coarsening changed
    /// it, and not when the demand is exact.
    #[test]
    fn the_exact_demand_is_given_beside_the_held_one() {
        let (_tmp, store) = ramp_store("terrain-app-exact-", 257);
        let tree = StoreTree::new(store, 8);
        let camera = Camera::from_yaw_pitch(glam::dvec3(-300.0, -300.0, 900.0), 45.0, -25.0)
            .with_viewport(320.0, 180.0);
        // Factors 3: the exact demand is every block's full resolution, the held one the
        // lattice of 4 (two levels coarser).
        let selection = crate::methods::select_uniform(&tree, &camera, 3.0);
        let draw = StoreDraw { selection, ..Default::default() };
        let exact = demand_of(&tree, &draw.selection, true);
        let bytes = terrain_stream::demand_bytes(&exact);
        let eye = camera.position;
        // Within both bounds: exact, nothing beside it.
        assert_eq!(held_and_exact_demand(&tree, &draw, eye, [bytes, bytes]), (exact.clone(), None));
        // Held to the lattices.
        let (held, beside) = held_and_exact_demand(&tree, &draw, eye, [bytes - 1, u64::MAX]);
        assert!(held != exact && terrain_stream::demand_bytes(&held) < bytes);
        assert_eq!(beside.as_ref(), Some(&exact));
        assert_eq!(held_demand(&tree, &draw, eye, [bytes - 1, u64::MAX]), (held.clone(), true));
        // Coarsened only (the lattice bound is not reached).
        let (coarse, beside) = held_and_exact_demand(&tree, &draw, eye, [u64::MAX, bytes / 2]);
        assert!(terrain_stream::demand_bytes(&coarse) <= bytes / 2);
        assert_eq!(beside, Some(exact));
    }

    /// The index pages' share: an eighth of the budget, at least 32 MiB, at most the whole
    /// index decoded.
    #[test]
    fn the_index_pages_get_an_eighth_of_the_budget_within_the_index() {
        const MIB: u64 = 1 << 20;
        assert_eq!(index_share(1 << 30, 1 << 40), 128 * MIB);
        assert_eq!(index_share(1 << 30, 122 * MIB), 122 * MIB);
        assert_eq!(index_share(64 * MIB, 1 << 40), 32 * MIB);
        assert_eq!(index_share(64 * MIB, 5 * MIB), 5 * MIB);
        assert_eq!(index_share(8 << 30, 1 << 40), 1 << 30);
    }

    /// `open_store` returns the store it opened last only while that folder holds the same
    /// bake: a store baked again into the folder (another grid, another index) is opened anew.
    #[test]
    fn open_store_reopens_a_folder_baked_again() {
        // Removed when dropped, also when the test panics.
        let tmp = tempfile::Builder::new().prefix("terrain-app-reopen-").tempdir().unwrap();
        let dir = tmp.path().join("store");
        let cfg = BakeConfig { k: 5, ..Default::default() };
        let mut sizes = Vec::new();
        for (w, h) in [(65, 33), (97, 65), (97, 65)] {
            let hm =
                Heightmap::from_fn(w, h, Georef::local(10.0), |i, j| (i * 3 + j) as f32).unwrap();
            let _ = std::fs::remove_dir_all(&dir);
            bake(&hm, &dir, &cfg, &mut |_: &BakeProgress| std::ops::ControlFlow::Continue(()))
                .unwrap();
            for _ in 0..2 {
                let h = open_store(&dir).unwrap().header().clone();
                sizes.push((h.width, h.height, h.bake_id));
            }
        }
        let dims: Vec<_> = sizes.iter().map(|&(w, h, _)| (w, h)).collect();
        assert_eq!(dims, [(65, 33), (65, 33), (97, 65), (97, 65), (97, 65), (97, 65)]);
        // The same grid baked again is another bake: its id, not the kept store's.
        assert_eq!(sizes[2].2, sizes[3].2);
        assert_eq!(sizes[4].2, sizes[5].2);
        let again = Store::open(&dir).unwrap().header().bake_id;
        assert_eq!(sizes[5].2, again, "the folder's bake");
    }

    /// A store's exact full-resolution grid is the DEM it was baked from: bit for bit from a
    /// raw-f32 store, within the bake's bound (and not equal: the check can fail) from a
    /// quantized one; a store whose block file is gone is an error, not made-up heights.
    #[test]
    fn the_exact_grid_is_the_baked_dem() {
        let f = |i: usize, j: usize| 100.0 + 0.37 * j as f32 + ((i * 7 + j * 13) % 11) as f32 * 0.3;
        let hm = Heightmap::from_fn(129, 97, Georef::local(10.0), f).unwrap();
        // Removed when dropped, also when the test panics.
        let tmp = tempfile::Builder::new().prefix("terrain-app-exact-").tempdir().unwrap();
        let base = tmp.path();
        for (name, encoding) in [
            ("f32", HeightEncoding::F32),
            ("bounded", HeightEncoding::Bounded { max_error_m: 0.05 }),
        ] {
            let dir = base.join(name);
            let cfg = BakeConfig { k: 5, encoding, ..Default::default() };
            bake(&hm, &dir, &cfg, &mut |_: &BakeProgress| std::ops::ControlFlow::Continue(()))
                .unwrap();
            let store = Store::open(&dir).unwrap();
            let exact = store_heightmap_exact(&store).unwrap();
            assert_eq!((exact.width(), exact.height()), (129, 97));
            assert_eq!(exact.georef().world_origin, hm.georef().world_origin);
            let off = exact
                .data()
                .iter()
                .zip(hm.data())
                .map(|(a, b)| f64::from((a - b).abs()))
                .fold(0.0, f64::max);
            match encoding {
                HeightEncoding::F32 => assert_eq!(off, 0.0, "{name}"),
                _ => assert!(off > 0.0 && off <= 0.05 + 1e-4, "{name}: {off}"),
            }
        }
        // Negative control: the block files gone, the grid cannot be read.
        let dir = base.join("f32");
        let store = Store::open(&dir).unwrap();
        std::fs::remove_dir_all(dir.join("blocks")).unwrap();
        let err = store_heightmap_exact(&store).map(|_| ()).unwrap_err().to_string();
        assert!(err.contains("could not read the store at full resolution"), "{err}");
    }
}
