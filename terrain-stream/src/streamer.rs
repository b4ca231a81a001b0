//! The runtime (Qiu 2013, section 4), real time by default: per frame, the scheduler's
//! regions M and N, the level each block needs (dynamic LOD, Eq. 7), load requests to the
//! workers in priority order, stale requests cancelled, and eviction to the budget that never
//! touches what the frame needs.
//!
//! **Real time.** After a session's first frame, [`Streamer::update`] never reads a block on
//! the frame thread and never waits for a worker: it applies what has arrived, queues what is
//! missing and returns. The caller draws each block at its finest resident level
//! ([`Streamer::block`]); what the frame needed but did not have is counted as late data
//! ([`FrameStats::late_bytes`], `late_blocks`, `late_levels`). The **first frame** of a
//! session waits while the workers load the coarse levels (`0..=min(needed, coarse_level)`) of
//! every visible block and, with [`StreamConfig::pin_level_zero`], level 0 of every block of the
//! store (kept resident from then on, so no block is ever a hole; not on a large remote store,
//! see [`StreamConfig::pin_level_zero`]), so the first image is not
//! empty (the paper's Table 3: "all the needed data are loaded from external memory" in frame
//! 1). These count as the frame's synchronous (real-time loaded) data.
//!
//! **By the frustum.** The visual region M is the blocks of the paper's projected view
//! triangle whose box (plan rectangle, min/max heights) meets the view frustum: the triangle
//! alone keeps blocks under a pitched camera that the frustum's lower plane leaves out, which
//! the selection never draws. The pre-loading region N - M is the Eq. 8 extension (the paper's
//! margin around the view, for motion and turning) less the blocks outside the frustum and
//! wholly behind the eye (behind the vertical plane through it across the plan view
//! direction): nothing behind the camera is loaded.
//!
//! **Priorities.** Requests go to the workers in four tiers, at most `max_in_flight` at a
//! time: (0) the coarse levels of visible blocks with nothing resident, nearest first (every
//! visible block soon has something to draw); (1) the missing levels of visible blocks, nearest
//! first; (2) the pre-loading region N - M, nearest first, within the budget; (3) the levels a
//! method may need later ([`Streamer::set_demand_later`]), within the budget once the blocks
//! outside the schedule are evicted. Tiers 2 and 3 fill the queue to half the in-flight cap at
//! most, keeping the rest for M (bench/ooc/README.md, "The streamer's update: half the queue
//! for the view"). The workers take the waiting request of the lowest tier first, in order of
//! submission within a tier, and a waiting request whose visible block now lacks a level it
//! needs or will need one frame ahead is raised to tier 0 or 1: so the view's levels overtake
//! the preloads that earlier frames queued (bench/ooc/README.md, "The workers' queue by
//! priority"). A request whose block has left N is cancelled (the worker drops it before its
//! next level).
//!
//! **Eq. 8 preloading, one frame ahead.** N comes from the view frustum extension (Eq. 8's `S`
//! times [`ScheduleConfig::lookahead_frames`], default 1: the paper's one frame). Besides the
//! blocks of N - M, the level a block of N will need one frame ahead is prefetched: the
//! block's `target` level is the finer of what it needs now and what it needs from the eye
//! moved on by the last frame's motion times the look-ahead (the same extrapolation Eq. 8
//! makes), so a block the camera approaches is refined before it is late. A step longer than
//! the last view reached is a cut (a teleport, a new shot), not a motion: that frame preloads
//! as if the eye held still. For a method with its own levels ahead
//! ([`Streamer::set_demand_ahead`]) a block of its demand is preloaded to those and to the
//! level its shading needs from the eye ahead, not to Eq. 7's: Eq. 7 is another method's
//! prediction, finer than a coarse method asks near the eye (the `tin` method's tiles shade at
//! their own stride), and its walk cost the frame thread (bench/ooc/README.md, "Eq. 8 without
//! Eq. 7 for a method's own levels"). The region N - M around the view keeps Eq. 7's levels:
//! a method selects its eye ahead with the current view direction, so only they cover a turn.
//!
//! **Cost.** Both levels of a block come from [`needed_level`]'s Eq. 7 walk only where the walk
//! can decide them: a bound from the block's box and its per-level `StaticE` maxima (no walk)
//! says when the walk cannot ask for more than the shading level (or the level needed now),
//! which then is the answer, the same one the walk gives.
//!
//! **Waiting on purpose.** [`Streamer::wait_until_resident`] is the documented way to wait
//! until warm (still images, measurements that want the selection's own error): it requests
//! every missing needed level of the frame's blocks and waits until all are resident, a fault
//! makes that impossible, or a timeout.
//!
//! **Holding the I/O.** [`Streamer::hold_io`] stops the workers from starting reads while a
//! benchmark does what a real-time frame does not (measuring, software drawing), so a flight
//! paced at its frame rate gives the workers the flight's time only.

use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use glam::{DVec2, DVec3};
use terrain_core::geometry::{Aabb, Camera, Classification, Frustum, GroundRegion};
use terrain_core::hash::IdMap;
use terrain_core::metrics::screen::{MIN_DISTANCE_M, view_sin_floored};

use crate::cache::Cache;
use crate::format::{BlockEntry, BlockId, Header};
use crate::lod::{Refinement, View, needed_level, shading_level_in};
use crate::schedule::{
    Regions, ScheduleConfig, block_rect, blocks_under_bbox, in_visual_region, polygon_meets_rect,
    regions,
};
use crate::stats::{Fault, FrameStats};
use crate::store::{BlockLevels, Store};
use crate::workers::{LevelReader, LoadRequest, LoadResult, Outcome, RequestFlags, WorkerPool};

/// Parameters of the runtime.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StreamConfig {
    /// Cache budget in decoded bytes. Default 256 MiB. What the visible blocks need (and a
    /// pinned level 0, [`StreamConfig::pin_level_zero`]) is kept even above it.
    pub budget_bytes: u64,
    /// Worker threads; 0 (the default) = one per available core, and for a store on object
    /// storage or HTTP ([`Store::is_remote`]) at least [`StreamConfig::REMOTE_THREADS`]: a
    /// worker waits out each range request, so the requests in the air are the worker count,
    /// and with 2 workers and 50 ms a request the stream moved at most 40 requests a second;
    /// 256 workers fetched 4.5-5x what 32 did on `fast_pass` over nginx + 50 ms
    /// (bench/remote/README.md). They wait, not compute: the decoding is the same work.
    /// This is the most workers the runtime runs: they are started as the requests in flight
    /// need them ([`Streamer::threads_started`]), so a few frames start a few threads.
    pub threads: usize,
    /// The scheduler's `L`, frame rate and look-ahead (Eq. 8).
    pub schedule: ScheduleConfig,
    /// Screen-error threshold `tau` of Eq. 7, pixels. Default 2 (the paper's figures).
    pub tau: f64,
    /// A block with nothing resident is first requested up to this level (or its needed level
    /// if coarser), before any block is refined; the first frame waits for these levels of
    /// the visible blocks. Default 3 (81 samples).
    pub coarse_level: u8,
    /// Keep level 0 (the block's 4 corner samples, 16 bytes) of every block of the store
    /// resident from the first frame on, so no block is ever a hole while its finer levels
    /// load, when all of them take at most 1/8 of the budget (a 32769^2 store with k = 8:
    /// 256 KiB). Default true. Pinned levels are never evicted: resident bytes stay within
    /// `max(budget, needed + 16 bytes per block)`. The standard "coarsest level always resident" of out-of-core
    /// terrain (e.g. geometry clipmaps' coarsest level, Losasso & Hoppe 2004). For a store on
    /// object storage or HTTP of more than [`StreamConfig::REMOTE_PIN_BLOCKS`] blocks the first
    /// frame does not fetch every block's level 0 (a request each); level 0 is kept from the
    /// first load of each block on.
    pub pin_level_zero: bool,
    /// Requests in flight at most; 0 (the default) = 1024 per worker thread. A short queue lets
    /// the current frame's priorities decide what loads next, but starves the workers between
    /// frames: on the 32769^2 synthetic store's `fast_pass` (1 GiB budget, two-frame look-ahead,
    /// an idle 2-core machine, `stream_bench realtime`) the share of frames drawn at their needed
    /// level was 0.3 % with 4 in flight (the old default; the workers idled at 78 % of one core),
    /// 84 % with 256, 95 % with 512 and 97 % with 2048 (bench/ooc/README.md). Stale requests are
    /// cancelled when their block leaves N, so a long queue does not keep loading what left the view.
    pub max_in_flight: usize,
    /// Frames before a block whose load failed is tried again. Default 120.
    pub retry_after_frames: u64,
    /// How the selection refines the store (its smallest patch and split rule): the needed
    /// level of a block is the deepest level the selection's patches need in it, so give the
    /// [`crate::StoreTree`] the same ([`crate::StoreTree::with_refinement`]).
    pub refinement: Refinement,
}

impl StreamConfig {
    /// The fewest worker threads a store on object storage or HTTP gets by default
    /// ([`StreamConfig::threads`] 0): requests waiting on the network in parallel.
    pub const REMOTE_THREADS: usize = 256;

    /// The most blocks of a store on object storage or HTTP whose level 0 the first frame
    /// fetches ([`StreamConfig::pin_level_zero`]): a range request each, about 1.6 s at 50 ms a
    /// request with 32 workers.
    pub const REMOTE_PIN_BLOCKS: usize = 1024;
}

impl Default for StreamConfig {
    fn default() -> Self {
        Self {
            budget_bytes: 256 << 20,
            threads: 0,
            schedule: ScheduleConfig::default(),
            tau: 2.0,
            coarse_level: 3,
            pin_level_zero: true,
            max_in_flight: 0,
            retry_after_frames: 120,
            refinement: Refinement::default(),
        }
    }
}

/// A block of this frame and the level it needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScheduledBlock {
    /// The block.
    pub block: BlockId,
    /// The finest level it needs now (levels `0..=needed` resident).
    pub needed: u8,
    /// The finest level prefetched for it: `needed`, or finer when the eye one frame ahead
    /// (Eq. 8's extrapolation) needs more.
    pub target: u8,
    /// The finest level preloaded for it last, after every other request
    /// ([`Streamer::set_demand_later`]): at least `target`.
    pub later: u8,
    /// Whether it is in the visual region M (else only in the pre-loading region N - M).
    pub visible: bool,
    /// Plan distance from the eye to the block, metres.
    pub distance_m: f64,
}

/// What [`Streamer::wait_until_resident`] found.
#[derive(Debug)]
pub struct WaitReport {
    /// Whether every needed level of the frame's visible blocks is resident.
    pub resident: bool,
    /// The frame's statistics, the wait included (`wait_time`, arrivals).
    pub stats: FrameStats,
}

/// The streaming runtime over one store: cache, scheduler and worker pool.
#[derive(Debug)]
pub struct Streamer {
    store: Arc<Store>,
    config: StreamConfig,
    /// Levels kept resident for every block (1 with level 0 pinned, else 0).
    pinned: usize,
    cache: Cache,
    pool: WorkerPool,
    frame: u64,
    last_eye: Option<DVec3>,
    last_camera: Option<Camera>,
    scheduled: Vec<ScheduledBlock>,
    regions: Option<Regions>,
    /// The levels a LOD method other than Eq. 7 needs per block ([`Streamer::set_demand`]).
    demand: Option<Vec<(BlockId, u8)>>,
    /// The levels the method needs at the eye one look-ahead ahead
    /// ([`Streamer::set_demand_ahead`]).
    demand_ahead: Option<Vec<(BlockId, u8)>>,
    /// The levels the method may need later, preloaded last ([`Streamer::set_demand_later`]).
    demand_later: Option<Vec<(BlockId, u8)>>,
    /// Block levels that have failed this session ([`Fault::first`]).
    faulted: BTreeSet<(BlockId, u8)>,
    /// Moving average of the workers' request latency, seconds (latency-aware Eq. 8).
    latency_s: Option<f64>,
    /// What the schedule reads of each block's index entry every frame, kept once read.
    summaries: Summaries,
}

/// What the schedule reads of a block's index entry every frame ([`BlockSummary`]), kept per
/// block visited, so a frame's schedule does not read the index again: a version-4 store's
/// entries come through a bounded cache of decoded pages (32 MiB, about 5,800 entries of a
/// 32769^2 store), which a view of more blocks would decode again every frame. The summaries
/// are kept by value in chunks of [`SUMMARY_CHUNK`]^2 blocks, allocated when first asked, at
/// most [`MAX_SUMMARY_CHUNKS`] (then it starts over): a wide view's schedule asks for up to
/// every block of a 32769^2 store each frame, row by row, and one heap object per summary made
/// each lookup a cache miss (the `Arc`'s count: most of the lookup's time). The whole
/// entries of the blocks whose level needs the Eq. 7 walk (those near the eye, thousands in a
/// wide view of a 32769^2 store) are kept for the frame that walked them and the next: what a
/// view walks, not what the store has.
#[derive(Debug, Default)]
struct Summaries {
    summaries: Mutex<KeptSummaries>,
    /// The entries walked this frame and in the last one.
    walked: Mutex<[IdMap<BlockId, Arc<BlockEntry>>; 2]>,
}

/// The kept summaries: chunks of `SUMMARY_CHUNK`^2 blocks by row-major chunk position, each
/// by row-major block position within it; and how many chunks are allocated.
#[derive(Debug, Default)]
struct KeptSummaries {
    chunks: Vec<Option<Box<[Option<BlockSummary>]>>>,
    allocated: usize,
}

/// Blocks per side of a chunk of kept summaries (1,024 blocks of 112 bytes, 112 KiB).
const SUMMARY_CHUNK: u32 = 32;

/// Chunks of summaries a streamer keeps at most (28 MiB; and a pointer per chunk of the
/// store). Before the chunks, 2^18 summaries of about 100 bytes were kept at most.
const MAX_SUMMARY_CHUNKS: usize = 256;

impl Summaries {
    /// Block `id`'s summary: kept, or read from its entry (`None` when it cannot be read).
    fn get(&self, store: &Store, id: BlockId) -> Option<BlockSummary> {
        let h = store.header();
        h.block_position(id)?;
        let chunks_x = h.blocks_x.div_ceil(SUMMARY_CHUNK) as usize;
        let c = (id.row / SUMMARY_CHUNK) as usize * chunks_x + (id.col / SUMMARY_CHUNK) as usize;
        let within = ((id.row % SUMMARY_CHUNK) * SUMMARY_CHUNK + id.col % SUMMARY_CHUNK) as usize;
        let mut kept = self.summaries.lock().unwrap_or_else(|e| e.into_inner());
        if kept.chunks.is_empty() {
            let rows = h.blocks_y.div_ceil(SUMMARY_CHUNK) as usize;
            kept.chunks = vec![None; chunks_x * rows];
        }
        if let Some(s) = kept.chunks[c].as_ref().and_then(|chunk| chunk[within]) {
            return Some(s);
        }
        let s = BlockSummary::of(h, &*store.entry(id)?, id);
        if kept.chunks[c].is_none() {
            if kept.allocated >= MAX_SUMMARY_CHUNKS {
                kept.chunks.iter_mut().for_each(|k| *k = None);
                kept.allocated = 0;
            }
            let side = SUMMARY_CHUNK as usize;
            kept.chunks[c] = Some(vec![None; side * side].into_boxed_slice());
            kept.allocated += 1;
        }
        if let Some(chunk) = kept.chunks[c].as_mut() {
            chunk[within] = Some(s);
        }
        Some(s)
    }

    /// Block `id`'s whole entry for the walk: walked this frame or the last, else read.
    fn entry(&self, store: &Store, id: BlockId) -> Option<Arc<BlockEntry>> {
        let mut walked = self.walked.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(e) = walked[0].get(&id) {
            return Some(e.clone());
        }
        let e = match walked[1].remove(&id) {
            Some(e) => e,
            None => store.entry(id)?,
        };
        walked[0].insert(id, e.clone());
        Some(e)
    }

    /// Starts a frame: the entries walked in the frame before the last are dropped.
    fn new_frame(&self) {
        let mut walked = self.walked.lock().unwrap_or_else(|e| e.into_inner());
        let [now, last] = &mut *walked;
        std::mem::swap(now, last);
        now.clear();
    }
}

/// What the schedule needs of block `id`'s entry every frame: its rectangle, boxes and
/// per-level maxima of `StaticE`. The walk of [`needed_level`] (where these bounds do not
/// decide a level) reads the entry itself.
#[derive(Debug, Clone, Copy, PartialEq)]
struct BlockSummary {
    /// Its valid vertices' plan rectangle ([`block_rect`]).
    lo: DVec2,
    hi: DVec2,
    /// Its valid heights' range ([`BlockEntry::min`], `max`).
    z: [f32; 2],
    /// The range with the root node's (every node's box lies in it).
    z_nodes: [f32; 2],
    /// [`BlockEntry::level_errors`], inline (a store's `k` is at most 12, one per level), the
    /// first `levels` of them.
    level_errors: [f32; MAX_K],
    levels: u8,
}

/// Most levels of a block ([`crate::format::K_RANGE`]).
const MAX_K: usize = *crate::format::K_RANGE.end() as usize;

impl BlockSummary {
    fn of(h: &Header, e: &BlockEntry, id: BlockId) -> Self {
        let (lo, hi) = block_rect(h, e, id);
        let levels = e.level_errors.len().min(MAX_K);
        let mut level_errors = [0.0; MAX_K];
        level_errors[..levels].copy_from_slice(&e.level_errors[..levels]);
        let (mut zmin, mut zmax) = (e.min, e.max);
        if let Some(root) = e.node(0, 0, 0) {
            zmin = zmin.min(root.min);
            zmax = zmax.max(root.max);
        }
        Self {
            lo,
            hi,
            z: [e.min, e.max],
            z_nodes: [zmin, zmax],
            level_errors,
            levels: levels as u8,
        }
    }

    /// [`BlockEntry::level_errors`].
    fn level_errors(&self) -> &[f32] {
        &self.level_errors[..usize::from(self.levels)]
    }

    /// Its box (the rectangle and the valid heights' range): the frustum's and Eq. 8's test,
    /// and the box [`shading_level_in`] measures (an entry's `valid_w`, `valid_h` are at
    /// least 1, so it is `lod::shading_level`'s).
    fn aabb(&self) -> Aabb {
        Aabb { min: self.lo.extend(self.z[0].into()), max: self.hi.extend(self.z[1].into()) }
    }
}

impl Streamer {
    /// Starts the runtime (spawns the workers), reading blocks from the store.
    pub fn new(store: Arc<Store>, config: StreamConfig) -> Self {
        let reader: Arc<dyn LevelReader> = store.clone();
        Self::with_reader(store, config, reader)
    }

    /// Starts the runtime with every block read going through `reader` (a wrapper of the
    /// store: latency injected in tests, throttling, counting). `store` gives the header and
    /// the index.
    pub fn with_reader(
        store: Arc<Store>,
        config: StreamConfig,
        reader: Arc<dyn LevelReader>,
    ) -> Self {
        let threads = if config.threads == 0 && store.is_remote() {
            let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
            cores.max(StreamConfig::REMOTE_THREADS)
        } else {
            config.threads
        };
        let pool = WorkerPool::spawn(reader, threads);
        let base = store.header().block_count() as u64 * BlockEntry::resident_bytes(0);
        let pinned = usize::from(config.pin_level_zero && base <= config.budget_bytes / 8);
        Self {
            cache: Cache::new(config.budget_bytes),
            store,
            pinned,
            config,
            pool,
            frame: 0,
            last_eye: None,
            last_camera: None,
            scheduled: Vec::new(),
            regions: None,
            demand: None,
            demand_ahead: None,
            demand_later: None,
            faulted: BTreeSet::new(),
            latency_s: None,
            summaries: Summaries::default(),
        }
    }

    /// What the next frames need, when a LOD method other than the paper's chooses what is
    /// drawn: `Some(levels)` lists every block the method draws and the finest level its
    /// patches there need (its patch level plus the tessellation factor's levels); those
    /// blocks are the visual region M (each also at least at its shading level, whose cells
    /// are a pixel or less on screen), nearest first, and the scheduling region N - M is preloaded as before (Eq. 8 with Eq. 7's
    /// levels). `None` (the default): M and its levels from Eq. 7 (the out-of-core paper's
    /// method). Takes effect at the next [`Streamer::update`] or
    /// [`Streamer::wait_until_resident`].
    pub fn set_demand(&mut self, demand: Option<Vec<(BlockId, u8)>>) {
        self.demand = demand;
    }

    /// Eq. 8 for a LOD method other than the paper's: the levels its selection needs at the eye
    /// one look-ahead ahead ([`Streamer::camera_ahead`]), in the form of
    /// [`Streamer::set_demand`]'s. Each block of the demand is preloaded to the finer of that
    /// level and the level its shading needs from that eye; a block only here is preloaded as
    /// part of N - M. Without it (`None`, the default) the prediction is Eq. 7's, which knows
    /// nothing of where another method's level boundaries lie: the blocks crossing one are late
    /// by a level. Takes effect with the demand.
    pub fn set_demand_ahead(&mut self, ahead: Option<Vec<(BlockId, u8)>>) {
        self.demand_ahead = ahead;
    }

    /// Levels the method may need later, in [`Streamer::set_demand`]'s form, preloaded for the
    /// blocks of its demand after every other request (the pre-loading region N - M
    /// included) and within the budget: a method whose demand is held to coarser lattices
    /// gives its exact demand here, so that the frame whose exact demand first fits finds it
    /// resident instead of asking it all at once (bench/ooc/README.md, "The workers' queue by
    /// priority"). What is preloaded here is the first to be evicted. Takes effect with the
    /// demand; `None` (the default) preloads nothing more.
    pub fn set_demand_later(&mut self, later: Option<Vec<(BlockId, u8)>>) {
        self.demand_later = later;
    }

    /// The eye Eq. 8 preloads for at the next [`Streamer::update`] with `camera`: moved by
    /// its step since the last update times the look-ahead in frames (grown by the measured
    /// request latency); `None` on the first frame, while the eye holds still and after a cut
    /// (a step beyond the last view's reach: see `step_to`).
    pub fn camera_ahead(&self, camera: &Camera) -> Option<Camera> {
        let step = self.step_to(camera);
        if step == DVec3::ZERO {
            return None;
        }
        let lookahead = self.config.schedule.effective_lookahead(self.latency_s.unwrap_or(0.0));
        Some(Camera { position: camera.position + step * lookahead, ..*camera })
    }

    /// The camera of the frame after the next [`Streamer::update`] with `camera`, as far as the
    /// motion tells: `camera` moved by its step since the last update, once (a
    /// [`crate::TreeWarmer`] walks there); `None` when [`Streamer::camera_ahead`] is.
    pub fn camera_next(&self, camera: &Camera) -> Option<Camera> {
        let step = self.step_to(camera);
        (step != DVec3::ZERO).then(|| Camera { position: camera.position + step, ..*camera })
    }

    /// The eye's step since the last update, the one motion Eq. 8 extrapolates; zero on the
    /// first frame and after a cut. A cut is a step longer than the last frame's view reached
    /// (the farthest vertex of its projected view region from its eye, in plan): a teleport,
    /// a new shot, a flight's restart. Its new view shares nothing with the old one, and the
    /// step is not a velocity: extrapolated, it would preload the look-ahead times that jump
    /// beyond the new view, the frame when every request is for the new view. After a cut the
    /// frame preloads as if the eye held still, and the next step is measured from the new
    /// eye (the cut detection of camera-driven streaming: a jump beyond the streaming radius
    /// resets the motion prediction rather than extrapolating it).
    fn step_to(&self, camera: &Camera) -> DVec3 {
        let Some(last) = self.last_eye else { return DVec3::ZERO };
        let step = camera.position - last;
        let reach = self.regions.as_ref().map_or(f64::INFINITY, |r| {
            let eye = last.truncate();
            r.view.vertices().iter().map(|v| v.distance(eye)).fold(0.0, f64::max)
        });
        if step.length() > reach { DVec3::ZERO } else { step }
    }

    /// The store.
    pub fn store(&self) -> &Arc<Store> {
        &self.store
    }

    /// The settings.
    pub fn config(&self) -> &StreamConfig {
        &self.config
    }

    /// Bytes resident in the cache.
    pub fn resident_bytes(&self) -> u64 {
        self.cache.resident_bytes()
    }

    /// The cache's budget, bytes.
    pub fn budget_bytes(&self) -> u64 {
        self.cache.budget()
    }

    /// Sets the cache's budget ([`StreamConfig::budget_bytes`] at first), bytes, from the next
    /// [`Streamer::update`] on: an embedder whose other caches of the store share one memory
    /// budget with the blocks (a tree's visited index entries, [`crate::StoreTree::visited_bytes`])
    /// gives the blocks what they leave. Blocks above it are unloaded by that update, within
    /// what its frame needs.
    pub fn set_budget_bytes(&mut self, bytes: u64) {
        self.cache.set_budget(bytes);
    }

    /// The resident levels of a block, if any.
    pub fn block(&self, id: BlockId) -> Option<&BlockLevels> {
        self.cache.get(id).map(|b| &b.levels).filter(|l| l.count() > 0)
    }

    /// The blocks of the last frame: M first, then N - M, each by distance.
    pub fn scheduled(&self) -> &[ScheduledBlock] {
        &self.scheduled
    }

    /// The regions of the last frame.
    pub fn regions(&self) -> Option<&Regions> {
        self.regions.as_ref()
    }

    /// The most worker threads the runtime runs ([`StreamConfig::threads`] resolved).
    pub fn threads(&self) -> usize {
        self.pool.max_threads()
    }

    /// Worker threads started so far: one more whenever the requests in flight outnumber the
    /// workers, up to [`Streamer::threads`] (at most the largest number of requests that were
    /// in flight at once).
    pub fn threads_started(&self) -> usize {
        self.pool.threads_started()
    }

    /// Requests queued or being loaded.
    pub fn in_flight(&self) -> usize {
        self.pool.in_flight()
    }

    fn max_in_flight(&self) -> usize {
        if self.config.max_in_flight == 0 {
            1024 * self.pool.max_threads()
        } else {
            self.config.max_in_flight
        }
    }

    /// Holds the I/O (`true`): the workers start no read (a level already being read, at most
    /// one per worker, finishes and arrives at the next update) until released (`false`).
    /// What a benchmark's real-time flight does while it works outside a real-time frame
    /// (measuring a frame's error, drawing it on a software renderer, seconds a frame), so the
    /// workers get the time of the flight's frames only and the late data counted is the
    /// flight's (`terrain bench`'s real-time mode, `cargo xtask papers --paper ooc`). Requests
    /// are still queued and stale ones cancelled while held; the first frame,
    /// [`Streamer::wait_until_resident`] and [`Streamer::finish_loads`] read held or not.
    pub fn hold_io(&mut self, held: bool) {
        self.pool.set_held(held);
    }

    /// Whether the I/O is held ([`Streamer::hold_io`]).
    pub fn io_held(&self) -> bool {
        self.pool.is_held()
    }

    /// The moving average of the workers' request latency (what the latency-aware look-ahead
    /// uses), if a request has completed.
    pub fn request_latency(&self) -> Option<Duration> {
        self.latency_s.map(Duration::from_secs_f64)
    }

    fn apply(&mut self, r: LoadResult, stats: &mut FrameStats) {
        if let Some(l) = r.latency {
            // An exponential moving average over about the last 16 requests.
            let l = l.as_secs_f64();
            self.latency_s = Some(self.latency_s.map_or(l, |a| a + (l - a) / 16.0));
        }
        let header = self.store.header().clone();
        match r.outcome {
            Outcome::Loaded(l) => {
                stats.disk_bytes += l.disk_bytes;
                stats.io_time += l.io_time;
                if let Some(b) = self.cache.push_level(r.block, &header, r.level, l.samples) {
                    stats.prefetched_bytes += b;
                }
            }
            Outcome::Failed(error) => {
                let entry = self.cache.entry(r.block, &header);
                entry.retry_at_frame = self.frame + self.config.retry_after_frames;
                let resident_levels = entry.levels.count();
                let first = self.faulted.insert((r.block, r.level));
                let area = self.store.block_rect(r.block);
                stats.faults.push(Fault { error, area, resident_levels, first });
            }
            Outcome::Cancelled => {}
        }
        if r.done {
            let b = self.cache.entry(r.block, &header);
            b.requested_to = None;
            b.flags = None;
        }
    }

    /// Applies every result that has arrived (never blocks).
    fn drain(&mut self, stats: &mut FrameStats) {
        while let Some(r) = self.pool.try_recv() {
            self.apply(r, stats);
        }
    }

    /// Waits until every request already in flight has arrived and applies them. Requests
    /// not yet submitted (the in-flight cap, the budget) are not made: this is not "warm";
    /// use [`Streamer::wait_until_resident`] for that. A frame loop never calls this.
    pub fn finish_loads(&mut self) -> FrameStats {
        let mut stats = FrameStats::default();
        // Held or not, the requests in flight are read (see [`Streamer::hold_io`]).
        let held = self.pool.is_held();
        self.pool.set_held(false);
        while let Some(r) = self.pool.recv_until(None) {
            self.apply(r, &mut stats);
        }
        self.pool.set_held(held);
        stats.resident_bytes = self.cache.resident_bytes();
        stats.queue_depth = self.pool.in_flight();
        stats.queued_bytes = self.pool.queued_bytes();
        stats
    }

    /// One real-time frame for `camera` (see the module docs): never reads a block on the
    /// frame thread after the session's first frame, never waits for a worker. The eye's
    /// velocity for Eq. 8 is the change of position since the last frame times the
    /// configured frame rate.
    pub fn update(&mut self, camera: &Camera) -> FrameStats {
        let t0 = Instant::now();
        let mut stats = FrameStats {
            frame: self.frame,
            budget_bytes: self.cache.budget(),
            ..Default::default()
        };
        self.drain(&mut stats);
        let step = self.step_to(camera);
        let velocity = step.truncate() * self.config.schedule.frame_rate_hz;
        self.last_eye = Some(camera.position);
        self.last_camera = Some(*camera);
        // Eq. 8 with the look-ahead grown by the measured request latency (latency-aware).
        let lookahead = self.config.schedule.effective_lookahead(self.latency_s.unwrap_or(0.0));
        let schedule = ScheduleConfig { lookahead_frames: lookahead, ..self.config.schedule };
        let reg = regions(self.store.header(), &schedule, camera, velocity);
        let ahead = step * lookahead;
        stats.lookahead_frames = lookahead;
        stats.request_latency = self.request_latency().unwrap_or_default();
        let scheduled = self.schedule(camera, &reg, ahead);
        stats.blocks_visible = scheduled.iter().filter(|s| s.visible).count();
        stats.blocks_scheduled = scheduled.len();
        for s in scheduled.iter().filter(|s| s.visible) {
            if self.cache.resident_levels(s.block) > s.needed as usize {
                stats.cache_hits += 1;
            } else {
                stats.cache_misses += 1;
            }
        }

        if self.frame == 0 {
            self.first_frame(&scheduled, &mut stats);
        }

        self.cancel_stale(&scheduled, &mut stats);
        self.submit(&scheduled, false, &mut stats);
        stats.evictions = self.evict(&scheduled, camera.position.truncate());
        self.cache.prune();
        self.scheduled = scheduled;
        self.regions = Some(reg);
        self.measure_late(&mut stats);
        self.frame += 1;
        stats.frame_time = t0.elapsed();
        stats
    }

    /// Waits (at most `timeout`) until every level the visible blocks of `camera`'s frame
    /// need is resident: runs [`Streamer::update`] for `camera` unless it was the last
    /// frame's camera, then requests every missing needed level (nearest first, within the
    /// in-flight cap) and applies arrivals until none is missing, nothing more can arrive (a
    /// fault: the block is retried after `retry_after_frames` frames), or the timeout. The
    /// result says which; its statistics are the frame's, the wait included. Deterministic in
    /// what ends resident when it returns `resident: true`.
    pub fn wait_until_resident(&mut self, camera: &Camera, timeout: Duration) -> WaitReport {
        let start = Instant::now();
        let deadline = start + timeout;
        let mut stats = if self.last_camera.as_ref() == Some(camera) {
            let mut s = FrameStats {
                frame: self.frame.saturating_sub(1),
                budget_bytes: self.cache.budget(),
                ..Default::default()
            };
            self.measure_late(&mut s);
            s
        } else {
            self.update(camera)
        };
        let scheduled = self.scheduled.clone();
        // Waiting on purpose reads, held or not (see [`Streamer::hold_io`]).
        let held = self.pool.is_held();
        self.pool.set_held(false);
        loop {
            let mut round = FrameStats::default();
            self.drain(&mut round);
            self.submit(&scheduled, true, &mut round);
            self.measure_late(&mut round);
            let done = round.late_blocks == 0;
            stats.merge(round);
            if done {
                break;
            }
            let mut round = FrameStats::default();
            match self.pool.recv_until(Some(deadline)) {
                Some(r) => self.apply(r, &mut round),
                None => break,
            }
            self.measure_late(&mut round);
            stats.merge(round);
        }
        self.pool.set_held(held);
        stats.wait_time += start.elapsed();
        WaitReport { resident: stats.late_blocks == 0, stats }
    }

    /// The blocks of M and N - M for `camera`, sorted (M first, each by distance, then id),
    /// with the level each needs now and one frame ahead (`ahead`: the eye's motion).
    fn schedule(&self, camera: &Camera, reg: &Regions, ahead: DVec3) -> Vec<ScheduledBlock> {
        self.summaries.new_frame();
        let store = &self.store;
        let header = store.header();
        let refine = self.config.refinement;
        let view = View::floored(camera, self.config.tau, refine.view_angle_floor);
        let next = (ahead != DVec3::ZERO).then(|| View { eye: view.eye + ahead, ..view });
        let eye = camera.position.truncate();
        let predicted = |id: BlockId, e: &BlockSummary, now: u8| {
            next.as_ref().map_or(now, |v| {
                level_ahead((store, &self.summaries), (id, e), v, &reg.extension, now, refine)
            })
        };
        // The level a block's shading needs from the eye one look-ahead ahead.
        let shade_ahead = |e: &BlockSummary| {
            next.as_ref().map_or(0, |v| shading_level_in(header, &e.aabb(), v)).min(header.k)
        };
        let needed = |id: BlockId, e: &BlockSummary, region: &GroundRegion| {
            needed_level_fast((store, &self.summaries), (id, e), &view, region, refine)
        };
        // M is the blocks of the view region whose box meets the view frustum (the paper's
        // projected triangle alone keeps blocks below and beside a pitched view); N - M, the
        // Eq. 8 extension around it, leaves out blocks outside the frustum and wholly behind
        // the eye (behind the vertical plane through it across the plan view direction).
        let frustum = Frustum::from_camera(camera);
        let plan_dir = camera.forward().truncate().normalize_or_zero();
        let behind = |lo: DVec2, hi: DVec2, b: &Aabb| {
            let far_corner = DVec2::new(
                if plan_dir.x >= 0.0 { hi.x } else { lo.x },
                if plan_dir.y >= 0.0 { hi.y } else { lo.y },
            );
            plan_dir != DVec2::ZERO
                && (far_corner - eye).dot(plan_dir) < 0.0
                && frustum.classify(b) == Classification::Outside
        };
        let mut scheduled = Vec::new();
        let mut in_m = BlockSet::empty(header);
        let own_ahead = self.demand.is_some() && self.demand_ahead.is_some();
        if let Some(demand) = &self.demand {
            // The method's own levels one look-ahead ahead, and the levels preloaded last, by
            // block position (0: none).
            let ahead = levels_by_position(header, self.demand_ahead.as_deref());
            let later = levels_by_position(header, self.demand_later.as_deref());
            let at = |levels: &[u8], id: BlockId| {
                header.block_position(id).and_then(|p| levels.get(p)).copied().unwrap_or(0)
            };
            let ahead_of = |id: BlockId| at(&ahead, id);
            let later_of = |id: BlockId| at(&later, id);
            for &(id, level) in demand {
                let Some(e) = self.summaries.get(store, id) else { continue };
                let e = &e;
                if !in_m.insert(header, id) {
                    continue;
                }
                let (lo, hi) = (e.lo, e.hi);
                let needed = level.max(shading_level_in(header, &e.aabb(), &view)).min(header.k);
                let target = match own_ahead {
                    true => needed.max(ahead_of(id)).max(shade_ahead(e)),
                    false => predicted(id, e, needed).max(ahead_of(id)),
                };
                scheduled.push(ScheduledBlock {
                    block: id,
                    needed,
                    target,
                    later: target.max(later_of(id)),
                    visible: true,
                    distance_m: rect_distance(eye, lo, hi),
                });
            }
            // Blocks the method draws only one look-ahead ahead: preloaded (N - M).
            for &(id, _) in self.demand_ahead.iter().flatten() {
                if in_m.contains(header, id) {
                    continue;
                }
                let Some(e) = self.summaries.get(store, id) else { continue };
                in_m.insert(header, id);
                let level = ahead_of(id);
                scheduled.push(ScheduledBlock {
                    block: id,
                    needed: level,
                    target: level,
                    later: level,
                    visible: false,
                    distance_m: rect_distance(eye, e.lo, e.hi),
                });
            }
        }
        let eq7 =
            if self.demand.is_some() { Vec::new() } else { blocks_under_bbox(header, &reg.view) };
        for id in eq7 {
            let Some(e) = self.summaries.get(store, id) else { continue };
            let e = &e;
            if !in_visual_region(&reg.view, &frustum, &e.aabb()) {
                continue;
            }
            let (lo, hi) = (e.lo, e.hi);
            if let Some(needed) = needed(id, e, &reg.view) {
                in_m.insert(header, id);
                let target = predicted(id, e, needed);
                scheduled.push(ScheduledBlock {
                    block: id,
                    needed,
                    target,
                    later: target,
                    visible: true,
                    distance_m: rect_distance(eye, lo, hi),
                });
            }
        }
        for id in blocks_under_bbox(header, &reg.extension) {
            if in_m.contains(header, id) {
                continue;
            }
            let Some(e) = self.summaries.get(store, id) else { continue };
            let e = &e;
            let (lo, hi) = (e.lo, e.hi);
            if !polygon_meets_rect(reg.extension.vertices(), lo, hi) || behind(lo, hi, &e.aabb()) {
                continue;
            }
            let needed = needed(id, e, &reg.extension).unwrap_or(0);
            let target = predicted(id, e, needed);
            scheduled.push(ScheduledBlock {
                block: id,
                needed,
                target,
                later: target,
                visible: false,
                distance_m: rect_distance(eye, lo, hi),
            });
        }
        scheduled.sort_by(|a, b| {
            b.visible
                .cmp(&a.visible)
                .then(a.distance_m.total_cmp(&b.distance_m))
                .then(a.block.cmp(&b.block))
        });
        scheduled
    }

    /// Cancels the requests of blocks no longer in N (each counted once).
    fn cancel_stale(&mut self, scheduled: &[ScheduledBlock], stats: &mut FrameStats) {
        let header = self.store.header().clone();
        let wanted = BlockSet::of(&header, scheduled);
        let stale: Vec<BlockId> = self
            .cache
            .blocks()
            .filter(|(id, b)| b.flags.is_some() && !wanted.contains(&header, **id))
            .map(|(id, _)| *id)
            .collect();
        for id in stale {
            if let Some(c) = self.cache.entry(id, &header).flags.take() {
                c.cancel();
                stats.cancelled += 1;
            }
        }
    }

    /// Submits requests in priority order (see the module docs) until the in-flight cap.
    /// `visible_only`: only the needed levels of M (waiting until warm).
    fn submit(&mut self, scheduled: &[ScheduledBlock], visible_only: bool, stats: &mut FrameStats) {
        let cap = self.max_in_flight();
        let store = self.store.clone();
        let header = store.header();
        let coarse = self.config.coarse_level;
        let frame = self.frame;
        // One pass puts the blocks that may get a request in their tier, in the schedule's
        // order: a block is in one tier at most (by whether it is visible and which of its
        // levels it holds), and one with a request in flight, waiting for a retry, or holding
        // its `later` level already gets none.
        let mut tiers: [Vec<&ScheduledBlock>; 4] = Default::default();
        for s in scheduled {
            let (have, free, flags) = self.cache.get(s.block).map_or((0, true, None), |b| {
                let free = b.requested_to.is_none() && b.retry_at_frame <= frame;
                (b.levels.count(), free, b.flags.as_ref())
            });
            // A visible block lacking its needed level or its level ahead whose request waits
            // at a later tier (a preload, the levels preloaded last): the request moves up
            // to the tier the block would get now.
            if let Some(f) = flags.filter(|_| s.visible && have <= s.target as usize) {
                self.pool.raise(f, u8::from(have > 0));
            }
            let tier = match (s.visible, have) {
                _ if !free || have > s.later as usize => continue,
                (true, 0) => 0,
                (true, _) if have <= s.needed as usize => 1,
                _ if visible_only => continue,
                (true, _) if have <= s.target as usize => 1,
                (false, _) => 2,
                (true, _) => 3,
            };
            tiers[tier].push(s);
        }
        // What is requested and not received yet counts against the budget too (earlier
        // frames' requests, then this frame's): arrivals are applied before the next eviction,
        // so requests beyond it are bytes above the budget (`dss-2` over the 32769^2 store:
        // the blocks' peak 1.01 GB against their 0.94 GB).
        let mut pending: u64 = self.pool.queued_bytes();
        // The levels preloaded last may take what the blocks outside the schedule hold beyond
        // their pinned level: the next eviction drops those first. So their budget counts the
        // scheduled blocks' bytes and the others' pinned levels, not every resident byte (a
        // cache filled by earlier views would keep them out).
        let kept = (!tiers[3].is_empty()).then(|| {
            let pinned =
                self.pinned.checked_sub(1).map_or(0, |l| BlockEntry::resident_bytes(l as u8));
            let others = (header.block_count() as u64).saturating_sub(scheduled.len() as u64);
            let scheduled: u64 = scheduled
                .iter()
                .map(|s| self.cache.get(s.block).map_or(0, |b| b.levels.bytes()))
                .sum();
            scheduled + others * pinned
        });
        for (tier, blocks) in tiers.into_iter().enumerate() {
            // The pre-loading region and the levels preloaded last fill the queue to half the
            // cap at most (see the module docs): the rest is kept for M.
            let cap = if tier >= 2 { cap.div_ceil(2) } else { cap };
            for s in blocks {
                if self.pool.in_flight() >= cap {
                    return;
                }
                let (resident, budget) = (self.cache.resident_bytes(), self.cache.budget());
                let b = self.cache.entry(s.block, header);
                let have = b.levels.count();
                let over = |last: u8| {
                    let add = BlockEntry::resident_bytes(last).saturating_sub(b.levels.bytes());
                    resident + pending + add > budget
                };
                let last = match tier {
                    // Coarse levels of visible blocks with nothing resident.
                    0 => s.needed.min(coarse),
                    // Missing levels of visible blocks: needed now, and one frame ahead
                    // within the budget.
                    1 => {
                        if visible_only || over(s.target) {
                            if have > s.needed as usize {
                                continue;
                            }
                            s.needed
                        } else {
                            s.target
                        }
                    }
                    // The levels preloaded last (`set_demand_later`), within the budget
                    // once the blocks outside the schedule are evicted (`kept`).
                    3 => {
                        let add =
                            BlockEntry::resident_bytes(s.later).saturating_sub(b.levels.bytes());
                        if kept.unwrap_or(u64::MAX).saturating_add(pending + add) > budget {
                            continue;
                        }
                        s.later
                    }
                    // The pre-loading region N - M, within the budget (blocks with nothing
                    // resident get their coarse levels even over it: they are small, and they
                    // are what the block is first drawn from when it enters M).
                    _ => {
                        if !over(s.target) {
                            s.target
                        } else if have == 0 {
                            s.target.min(coarse)
                        } else {
                            continue;
                        }
                    }
                };
                let add = BlockEntry::resident_bytes(last).saturating_sub(b.levels.bytes());
                let flags = RequestFlags::new(tier as u8);
                b.requested_to = Some(last);
                b.flags = Some(flags.clone());
                let req = LoadRequest {
                    block: s.block,
                    first: have as u8,
                    last,
                    coarser: b.levels.levels().to_vec(),
                    flags,
                };
                pending += add;
                self.pool.submit(req);
                stats.requests += 1;
            }
        }
    }

    /// Eviction: blocks outside N first (farthest first), then levels beyond each block's
    /// target, then what N - M holds above its coarse levels, then those, then M's levels
    /// beyond what it needs now; never what M needs, nor a pinned level 0.
    fn evict(&mut self, scheduled: &[ScheduledBlock], eye: DVec2) -> usize {
        // Within the budget nothing is evicted (`Cache::evict` stops there): no order needed.
        if self.cache.resident_bytes() <= self.cache.budget() {
            return 0;
        }
        let store = &self.store;
        let header = store.header();
        let wanted = BlockSet::of(header, scheduled);
        let mut outside: Vec<(BlockId, f64)> = self
            .cache
            .blocks()
            // The cheap test first: with level 0 pinned, most cached blocks hold only it.
            .filter(|(id, b)| b.levels.count() > self.pinned && !wanted.contains(header, **id))
            .map(|(id, _)| {
                let d = self
                    .summaries
                    .get(store, *id)
                    .map_or(f64::MAX, |e| rect_distance(eye, e.lo, e.hi));
                (*id, d)
            })
            .collect();
        outside.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        let pinned = self.pinned;
        let mut order: Vec<(BlockId, usize)> =
            outside.iter().map(|&(id, _)| (id, pinned)).collect();
        let mut by_distance: Vec<&ScheduledBlock> = scheduled.iter().collect();
        by_distance
            .sort_by(|a, b| b.distance_m.total_cmp(&a.distance_m).then(a.block.cmp(&b.block)));
        order.extend(by_distance.iter().map(|s| (s.block, s.target as usize + 1)));
        let coarse = |s: &ScheduledBlock| s.needed.min(self.config.coarse_level) as usize + 1;
        order.extend(by_distance.iter().filter(|s| !s.visible).map(|s| (s.block, coarse(s))));
        order.extend(by_distance.iter().filter(|s| !s.visible).map(|s| (s.block, pinned)));
        order.extend(
            by_distance.iter().filter(|s| s.visible).map(|s| (s.block, s.needed as usize + 1)),
        );
        self.cache.evict(&order)
    }

    /// Needed, resident and late bytes of the last schedule's visible blocks, resident bytes
    /// and queue depth, into `stats`.
    fn measure_late(&self, stats: &mut FrameStats) {
        let (mut needed, mut have_bytes, mut blocks, mut levels) = (0, 0, 0, 0);
        for s in self.scheduled.iter().filter(|s| s.visible) {
            needed += BlockEntry::resident_bytes(s.needed);
            let have = self.cache.resident_levels(s.block);
            if have > 0 {
                have_bytes += BlockEntry::resident_bytes((have - 1).min(s.needed as usize) as u8);
            }
            if have <= s.needed as usize {
                blocks += 1;
                levels += s.needed as usize + 1 - have;
            }
        }
        stats.needed_bytes = needed;
        stats.needed_resident_bytes = have_bytes;
        stats.late_bytes = needed - have_bytes;
        stats.late_blocks = blocks;
        stats.late_levels = levels;
        stats.resident_bytes = self.cache.resident_bytes();
        stats.queue_depth = self.pool.in_flight();
        stats.queued_bytes = self.pool.queued_bytes();
    }

    /// The session's first frame waits for the workers to load the coarse levels of the
    /// visible blocks and the pinned level 0 of every other block (not on a large remote store:
    /// see the module docs).
    fn first_frame(&mut self, scheduled: &[ScheduledBlock], stats: &mut FrameStats) {
        let t = Instant::now();
        let store = self.store.clone();
        let header = store.header();
        let visible = scheduled.iter().filter(|s| s.visible);
        let mut wanted: Vec<(BlockId, u8)> =
            visible.map(|s| (s.block, s.needed.min(self.config.coarse_level))).collect();
        // A remote store's level 0 is a range request per block (16384 on a 32769^2 store:
        // 28 s at 50 ms a request with 32 workers, bench/remote/README.md): above
        // REMOTE_PIN_BLOCKS blocks it is kept as the blocks load, not fetched up front.
        if self.pinned > 0
            && (!store.is_remote() || header.block_count() <= StreamConfig::REMOTE_PIN_BLOCKS)
        {
            wanted.extend(store.block_ids().map(|id| (id, 0)));
        }
        for (id, last) in wanted {
            let b = self.cache.entry(id, header);
            if b.levels.count() > 0 || b.requested_to.is_some() || b.retry_at_frame > self.frame {
                continue;
            }
            let flags = RequestFlags::new(0);
            b.requested_to = Some(last);
            b.flags = Some(flags.clone());
            self.pool.submit(LoadRequest { block: id, first: 0, last, coarser: Vec::new(), flags });
            stats.sync_loads += 1;
        }
        let mut arrived = FrameStats::default();
        // The first frame waits for its loads, held or not (see [`Streamer::hold_io`]).
        let held = self.pool.is_held();
        self.pool.set_held(false);
        while let Some(r) = self.pool.recv_until(None) {
            self.apply(r, &mut arrived);
        }
        self.pool.set_held(held);
        stats.sync_bytes += arrived.prefetched_bytes;
        stats.disk_bytes += arrived.disk_bytes;
        stats.io_time += arrived.io_time;
        stats.faults.extend(arrived.faults);
        stats.sync_io_time += t.elapsed();
    }
}

/// [`needed_level`] without its Eq. 7 walk where the walk cannot change the answer: the walk's
/// level is at most [`geometry_level_bound`], so when that is at most the
/// [`crate::lod::shading_level`] the answer is the shading level (for a block whose rectangle
/// meets `region`, which always has a leaf: the bounding circles of its nodes contain their
/// rectangles). The same answer as [`needed_level`] for such blocks
/// (`needed_level_fast_is_needed_level`).
fn needed_level_fast(
    (store, kept): (&Store, &Summaries),
    (b, e): (BlockId, &BlockSummary),
    view: &View,
    region: &GroundRegion,
    refine: Refinement,
) -> Option<u8> {
    let h = store.header();
    let shade = shading_level_in(h, &e.aabb(), view);
    let bound = geometry_level_bound(h, e, view).max(refine.segment_floor_level(h.k));
    if bound <= shade {
        Some(shade)
    } else {
        needed_level(h, &*kept.entry(store, b)?, b, view, region, refine)
    }
}

/// The finer of `now` and what block `b` needs for `view` (the eye one frame ahead):
/// `max(now, needed_level)` (`now` when that is `None`), without the walk where the bound
/// decides it.
fn level_ahead(
    (store, kept): (&Store, &Summaries),
    (b, e): (BlockId, &BlockSummary),
    view: &View,
    region: &GroundRegion,
    now: u8,
    refine: Refinement,
) -> u8 {
    let h = store.header();
    let shade = shading_level_in(h, &e.aabb(), view);
    let bound = geometry_level_bound(h, e, view).max(refine.segment_floor_level(h.k));
    if shade.max(bound) <= now {
        now
    } else if bound <= shade {
        shade.max(now)
    } else {
        kept.entry(store, b)
            .and_then(|e| needed_level(h, &e, b, view, region, refine))
            .map_or(now, |l| l.max(now))
    }
}

/// An upper bound of the level [`crate::lod::needed_geometry_level`] gives block `e` (of `b`)
/// for `view`, from the block's box and its per-level maxima of `StaticE` alone (no walk).
/// Every node of the block lies in the block's box, so its Eq. 7 `rho` per metre of error is
/// at most `lambda sin(theta) / d` with `d` the eye's distance to the block's box (Eq. 7
/// divides Eq. 6 by `1 + sin(beta) >= 1`); a node of level `l` has `StaticE` at most
/// `level_errors[l]`, so no node of a level whose maximum is within the threshold splits,
/// and no leaf asks for vertices below it. A relative margin of 1e-9 covers rounding.
fn geometry_level_bound(h: &Header, e: &BlockSummary, view: &View) -> u8 {
    let [zmin, zmax] = e.z_nodes;
    let (lo, hi) = (e.lo.extend(zmin.into()), e.hi.extend(zmax.into()));
    let d = (lo - view.eye).max(view.eye - hi).max(DVec3::ZERO).length();
    if !(d.is_finite() && d > 2.0 * MIN_DISTANCE_M) {
        return h.k;
    }
    let per_metre = view.lambda * view_sin_floored(view.dir, view.floor) / d * (1.0 + 1e-9);
    let limit = view.tau / per_metre;
    if !limit.is_finite() {
        return h.k;
    }
    (0..h.k)
        .find(|&l| {
            f64::from(e.level_errors().get(l as usize).copied().unwrap_or(0.0))
                <= limit * (1.0 - 1e-9)
        })
        .unwrap_or(h.k)
}

/// A set of the store's blocks by row-major block position (one bit each): membership without
/// a tree or hash of the thousands of blocks a wide view schedules.
struct BlockSet(Vec<u64>);

impl BlockSet {
    /// No block of the store with header `h`.
    fn empty(h: &Header) -> Self {
        Self(vec![0u64; h.block_count().div_ceil(64)])
    }

    /// The blocks of a schedule.
    fn of(h: &Header, scheduled: &[ScheduledBlock]) -> Self {
        let mut set = Self::empty(h);
        for s in scheduled {
            set.insert(h, s.block);
        }
        set
    }

    /// Adds `id`; whether it was not there (a block outside the grid is never held).
    fn insert(&mut self, h: &Header, id: BlockId) -> bool {
        let Some(p) = h.block_position(id) else { return true };
        let (word, bit) = (&mut self.0[p / 64], 1u64 << (p % 64));
        let new = *word & bit == 0;
        *word |= bit;
        new
    }

    /// Whether `id` is in the set.
    fn contains(&self, h: &Header, id: BlockId) -> bool {
        h.block_position(id).is_some_and(|p| self.0[p / 64] & (1 << (p % 64)) != 0)
    }
}

/// Plan distance from `p` to the rectangle `[lo, hi]` (0 inside).
fn rect_distance(p: DVec2, lo: DVec2, hi: DVec2) -> f64 {
    (lo - p).max(p - hi).max(DVec2::ZERO).length()
}

/// Each block's finest level in `demand` ([`Streamer::set_demand`]'s form), capped at the
/// store's finest, by block position (`Header::block_position`; 0 where none); empty without a
/// demand.
fn levels_by_position(header: &Header, demand: Option<&[(BlockId, u8)]>) -> Vec<u8> {
    let Some(demand) = demand else { return Vec::new() };
    let mut levels = vec![0u8; header.block_count()];
    for &(id, level) in demand {
        if let Some(a) = header.block_position(id).and_then(|p| levels.get_mut(p)) {
            *a = (*a).max(level.min(header.k));
        }
    }
    levels
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::{BakeConfig, bake};
    use crate::lod::SplitRule;
    use crate::schedule::{ScheduleConfig, regions};
    use glam::{dvec2, dvec3};
    use std::ops::ControlFlow;
    use terrain_core::Georef;
    use terrain_core::heightmap::Heightmap;

    /// A rough store (a ridge and a hash) where the geometry decides some blocks' levels.
    /// The store and its folder's guard (removed when dropped, also on a panic).
    fn store(name: &str, spacing: f64) -> (crate::tests::Scratch, Store) {
        let dir = crate::tests::scratch_store(&format!("terrain-stream-streamer-{name}-"));
        let hm = Heightmap::from_fn(257, 193, Georef::local(spacing), |i, j| {
            let (x, y) = (i as f32, j as f32);
            200.0 * (x * 0.03).sin() * (y * 0.02).cos()
                + ((i * 31 + j * 17) % 23) as f32 * if i > 128 { 40.0 } else { 0.1 }
        })
        .unwrap();
        let cfg = BakeConfig { k: 5, node_levels: 3, ..Default::default() };
        bake(&hm, &dir, &cfg, &mut |_: &crate::bake::BakeProgress| ControlFlow::Continue(()))
            .unwrap();
        let store = Store::open(&dir).unwrap();
        (dir, store)
    }

    /// The kept summaries, by value in chunks of blocks, are each block's own: over a store of
    /// 128 x 72 blocks (chunk borders both ways, a last row of chunks partly outside the
    /// grid), asked in a scattered order, each one equals the summary of its entry, asked
    /// again too, and only the chunks holding them are allocated.
    #[test]
    fn kept_summaries_are_each_blocks_own() {
        let dir = crate::tests::scratch_store("terrain-stream-streamer-summaries-");
        let hm = Heightmap::from_fn(1025, 577, Georef::local(5.0), |i, j| {
            ((i * 37 + j * 11) % 101) as f32 + 0.5 * j as f32
        })
        .unwrap();
        let cfg = BakeConfig { k: 3, node_levels: 2, ..Default::default() };
        bake(&hm, &dir, &cfg, &mut |_: &crate::bake::BakeProgress| ControlFlow::Continue(()))
            .unwrap();
        let store = Store::open(&dir).unwrap();
        let h = store.header().clone();
        assert_eq!((h.blocks_x, h.blocks_y), (128, 72));
        let kept = Summaries::default();
        let n = h.block_count();
        for round in 0..2 {
            for k in 0..n {
                let id = h.block_at(k * 7919 % n);
                let want = BlockSummary::of(&h, &store.entry(id).unwrap(), id);
                assert_eq!(kept.get(&store, id), Some(want), "{id:?}, round {round}");
            }
        }
        let chunks = kept.summaries.lock().unwrap();
        assert_eq!((chunks.chunks.len(), chunks.allocated), (12, 12));
        // The size `SUMMARY_CHUNK`'s and `MAX_SUMMARY_CHUNKS`' docs give.
        const { assert!(std::mem::size_of::<Option<BlockSummary>>() == 112) };
        drop(chunks);
        assert_eq!(kept.get(&store, BlockId::new(72, 0)), None, "outside the grid");
    }

    #[test]
    fn needed_level_fast_is_needed_level() {
        let (mut fast, mut walked) = (0usize, 0usize);
        for (name, spacing) in [("fine", 2.0), ("coarse", 30.0)] {
            let (_dir, store) = store(name, spacing);
            let h = store.header().clone();
            let ext = h.georef.spacing_m * dvec2(256.0, 192.0);
            for k in 0..60 {
                let t = k as f64 / 60.0;
                let p = h.georef.world_origin + ext * dvec2(t, (t * 7.0).fract());
                let z = 250.0 + 2000.0 * ((k * 13) % 7) as f64 / 7.0 * spacing / 10.0;
                let cam = Camera::from_yaw_pitch(
                    p.extend(z),
                    (k * 47 % 360) as f64,
                    -5.0 - (k * 11 % 80) as f64,
                )
                .with_viewport(
                    if k % 2 == 0 { 1280.0 } else { 96.0 },
                    if k % 2 == 0 { 720.0 } else { 54.0 },
                )
                .with_clip(1.0, ext.length() * 2.0);
                let reg = regions(&h, &ScheduleConfig::default(), &cam, dvec2(0.0, 300.0));
                for (tau, refine) in [0.5, 2.0, 8.0].into_iter().flat_map(|t| {
                    [
                        Refinement { max_segment_cells: 0, ..Refinement::default() },
                        Refinement {
                            patch_cells: 4,
                            split: SplitRule::Cost,
                            cost_split_px: 0,
                            max_segment_cells: 0,
                            ..Refinement::default()
                        },
                        // The segment floor raises the fast path's answer too (k 5: level 2).
                        Refinement { max_segment_cells: 8, ..Refinement::default() },
                    ]
                    .map(|r| (t, r))
                }) {
                    let view = View::new(&cam, tau);
                    for region in [&reg.view, &reg.extension] {
                        for id in blocks_under_bbox(&h, region) {
                            let Some(e) = store.entry(id) else { continue };
                            let e = &*e;
                            let (lo, hi) = block_rect(&h, e, id);
                            if !polygon_meets_rect(region.vertices(), lo, hi) {
                                continue;
                            }
                            let slow = needed_level(&h, e, id, &view, region, refine);
                            assert!(slow.is_some(), "{id} meets the region but has no leaf");
                            let shade = crate::lod::shading_level(&h, e, id, &view);
                            let sum = BlockSummary::of(&h, e, id);
                            let kept = Summaries::default();
                            assert_eq!(shading_level_in(&h, &sum.aabb(), &view), shade);
                            if geometry_level_bound(&h, &sum, &view) <= shade {
                                fast += 1;
                            } else {
                                walked += 1;
                            }
                            assert_eq!(
                                needed_level_fast(
                                    (&store, &kept),
                                    (id, &sum),
                                    &view,
                                    region,
                                    refine
                                ),
                                slow,
                                "{id}"
                            );
                            for now in 0..=h.k {
                                assert_eq!(
                                    level_ahead(
                                        (&store, &kept),
                                        (id, &sum),
                                        &view,
                                        region,
                                        now,
                                        refine
                                    ),
                                    slow.map_or(now, |l| l.max(now)),
                                    "{id} now {now}"
                                );
                            }
                        }
                    }
                }
            }
        }
        // Both branches are exercised.
        assert!(fast > 100 && walked > 100, "fast {fast}, walked {walked}");
    }

    #[test]
    fn the_bound_is_never_below_the_walk() {
        let (_dir, store) = store("bound", 5.0);
        let h = store.header().clone();
        let mut tight = 0;
        for k in 0..40 {
            let eye = dvec3(30.0 * k as f64, 20.0 * k as f64, 150.0 + 10.0 * k as f64);
            let cam =
                Camera::from_yaw_pitch(eye, (k * 37) as f64, -30.0).with_viewport(640.0, 360.0);
            let view = View::new(&cam, 1.0);
            for id in store.block_ids() {
                let e = store.entry(id).unwrap();
                let (lo, hi) = block_rect(&h, &e, id);
                let all = GroundRegion::Polygon(vec![
                    lo - 1.0,
                    dvec2(hi.x + 1.0, lo.y - 1.0),
                    hi + 1.0,
                    dvec2(lo.x - 1.0, hi.y + 1.0),
                ]);
                let bound = geometry_level_bound(&h, &BlockSummary::of(&h, &e, id), &view);
                for split in [SplitRule::Eq7, SplitRule::Cost] {
                    let refine = Refinement {
                        patch_cells: 4,
                        split,
                        cost_split_px: 0,
                        max_segment_cells: 0,
                        ..Refinement::default()
                    };
                    let walk =
                        crate::lod::needed_geometry_level(&h, &e, id, &view, &all, refine).unwrap();
                    assert!(bound >= walk, "{id}: bound {bound} < walk {walk} ({split:?})");
                    tight += usize::from(bound == walk);
                }
            }
        }
        assert!(tight > 0);
    }
}
