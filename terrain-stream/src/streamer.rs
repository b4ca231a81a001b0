//! The runtime (Qiu 2013, section 4): per frame, the scheduler's regions M and N, the level
//! each block needs (dynamic LOD, Eq. 7), synchronous loads only for needed blocks with no
//! level at all, prefetch requests to the workers in priority order, and eviction to the
//! budget that never touches what the frame needs.

use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::{DVec2, DVec3};
use terrain_core::geometry::Camera;

use crate::cache::Cache;
use crate::format::{BlockEntry, BlockId};
use crate::lod::{View, needed_level};
use crate::schedule::{
    Regions, ScheduleConfig, block_rect, blocks_under_bbox, polygon_meets_rect, regions,
};
use crate::stats::FrameStats;
use crate::store::{BlockLevels, Store};
use crate::workers::{LoadRequest, LoadResult, WorkerPool};

/// Parameters of the runtime.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StreamConfig {
    /// Cache budget in decoded bytes. Default 256 MiB.
    pub budget_bytes: u64,
    /// Worker threads; 0 (the default) = one per available core.
    pub threads: usize,
    /// The scheduler's `L`, frame rate and look-ahead.
    pub schedule: ScheduleConfig,
    /// Screen-error threshold `tau` of Eq. 7, pixels. Default 2 (the paper's figures).
    pub tau: f64,
    /// A needed block with no level resident is loaded on the frame thread up to this level
    /// (or its needed level if coarser); the workers load the rest. Default 3 (81 samples).
    pub sync_max_level: u8,
    /// Requests in flight at most; 0 (the default) = two per worker thread.
    pub max_in_flight: usize,
    /// Frames before a block whose load failed is tried again. Default 120.
    pub retry_after_frames: u64,
}

impl Default for StreamConfig {
    fn default() -> Self {
        Self {
            budget_bytes: 256 << 20,
            threads: 0,
            schedule: ScheduleConfig::default(),
            tau: 2.0,
            sync_max_level: 3,
            max_in_flight: 0,
            retry_after_frames: 120,
        }
    }
}

/// A block of this frame and the level it needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScheduledBlock {
    /// The block.
    pub block: BlockId,
    /// The finest level it needs (levels `0..=needed` resident).
    pub needed: u8,
    /// Whether it is in the visual region M (else only in the pre-loading region N - M).
    pub visible: bool,
    /// Plan distance from the eye to the block, metres.
    pub distance_m: f64,
}

/// The streaming runtime over one store: cache, scheduler and worker pool.
#[derive(Debug)]
pub struct Streamer {
    store: Arc<Store>,
    config: StreamConfig,
    cache: Cache,
    pool: WorkerPool,
    frame: u64,
    last_eye: Option<DVec3>,
    scheduled: Vec<ScheduledBlock>,
    regions: Option<Regions>,
}

impl Streamer {
    /// Starts the runtime (spawns the workers).
    pub fn new(store: Arc<Store>, config: StreamConfig) -> Self {
        let pool = WorkerPool::spawn(store.clone(), config.threads);
        Self {
            cache: Cache::new(config.budget_bytes),
            store,
            config,
            pool,
            frame: 0,
            last_eye: None,
            scheduled: Vec::new(),
            regions: None,
        }
    }

    /// The store.
    pub fn store(&self) -> &Arc<Store> {
        &self.store
    }

    /// The cache.
    pub fn cache(&self) -> &Cache {
        &self.cache
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

    /// Number of worker threads.
    pub fn threads(&self) -> usize {
        self.pool.threads()
    }

    fn apply(&mut self, r: LoadResult, stats: &mut FrameStats) {
        let header = self.store.header().clone();
        let frame = self.frame;
        let retry = self.config.retry_after_frames;
        match r.result {
            Ok(l) => {
                stats.disk_bytes += l.disk_bytes;
                stats.io_time += l.io_time;
                if let Some(b) = self.cache.push_level(r.block, &header, r.level, l.samples) {
                    stats.prefetched_bytes += b;
                }
            }
            Err(e) => {
                self.cache.entry(r.block, &header).retry_at_frame = frame + retry;
                stats.faults.push(e);
            }
        }
        if r.done {
            self.cache.entry(r.block, &header).requested_to = None;
        }
    }

    /// Waits until every request in flight has arrived and applies them (tools and tests; a
    /// frame loop never calls this).
    pub fn finish_loads(&mut self) -> FrameStats {
        let mut stats = FrameStats::default();
        while let Some(r) = self.pool.recv() {
            self.apply(r, &mut stats);
        }
        stats.resident_bytes = self.cache.resident_bytes();
        stats
    }

    /// One frame for `camera`: see the module docs. The eye's velocity for Eq. 8 is the
    /// change of position since the last frame times the configured frame rate.
    pub fn update(&mut self, camera: &Camera) -> FrameStats {
        let t0 = Instant::now();
        let mut stats = FrameStats {
            frame: self.frame,
            budget_bytes: self.cache.budget(),
            ..Default::default()
        };
        while let Some(r) = self.pool.try_recv() {
            self.apply(r, &mut stats);
        }
        let store = self.store.clone();
        let header = store.header();
        let f = self.config.schedule.frame_rate_hz;
        let velocity = self.last_eye.map_or(DVec2::ZERO, |p| (camera.position - p).truncate() * f);
        self.last_eye = Some(camera.position);
        let reg = regions(header, &self.config.schedule, camera, velocity);
        let view = View::new(camera, self.config.tau);
        let eye = camera.position.truncate();

        // M and N with the level each block needs.
        let mut scheduled = Vec::new();
        let mut in_m = std::collections::BTreeSet::new();
        for id in blocks_under_bbox(header, &reg.view) {
            let Some(e) = store.entry(id) else { continue };
            let (lo, hi) = block_rect(header, e, id);
            if !polygon_meets_rect(reg.view.vertices(), lo, hi) {
                continue;
            }
            if let Some(needed) = needed_level(header, e, id, &view, &reg.view) {
                in_m.insert(id);
                scheduled.push(ScheduledBlock {
                    block: id,
                    needed,
                    visible: true,
                    distance_m: rect_distance(eye, lo, hi),
                });
            }
        }
        for id in blocks_under_bbox(header, &reg.extension) {
            if in_m.contains(&id) {
                continue;
            }
            let Some(e) = store.entry(id) else { continue };
            let (lo, hi) = block_rect(header, e, id);
            if !polygon_meets_rect(reg.extension.vertices(), lo, hi) {
                continue;
            }
            let needed = needed_level(header, e, id, &view, &reg.extension).unwrap_or(0);
            scheduled.push(ScheduledBlock {
                block: id,
                needed,
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
        stats.blocks_visible = in_m.len();
        stats.blocks_scheduled = scheduled.len();

        // Hits, then synchronous loads for needed blocks with nothing resident.
        for s in scheduled.iter().filter(|s| s.visible) {
            let have = self.cache.resident_levels(s.block);
            if have > s.needed as usize {
                stats.cache_hits += 1;
            } else {
                stats.cache_misses += 1;
            }
            let retry_at = self.cache.get(s.block).map_or(0, |b| b.retry_at_frame);
            if have == 0 && retry_at <= self.frame {
                self.load_sync(s.block, s.needed.min(self.config.sync_max_level), &mut stats);
            }
        }

        // Prefetch requests in priority order (M by distance, then N - M by distance).
        let max_in_flight = if self.config.max_in_flight == 0 {
            2 * self.pool.threads()
        } else {
            self.config.max_in_flight
        };
        let mut pending: u64 = 0;
        for s in &scheduled {
            if self.pool.in_flight() >= max_in_flight {
                break;
            }
            let b = self.cache.entry(s.block, header);
            let have = b.levels.count();
            if have > s.needed as usize
                || b.requested_to.is_some()
                || b.retry_at_frame > self.frame
                || have == 0
            {
                continue;
            }
            let add = BlockEntry::resident_bytes(s.needed) - b.levels.bytes();
            if !s.visible && self.cache.resident_bytes() + pending + add > self.cache.budget() {
                continue;
            }
            let b = self.cache.entry(s.block, header);
            b.requested_to = Some(s.needed);
            let req = LoadRequest {
                block: s.block,
                first: have as u8,
                last: s.needed,
                coarser: b.levels.levels().to_vec(),
            };
            pending += add;
            self.pool.submit(req);
            stats.requests += 1;
        }
        // Blocks of N - M with nothing resident get their first request too (level 0 upward).
        for s in scheduled.iter().filter(|s| !s.visible) {
            if self.pool.in_flight() >= max_in_flight {
                break;
            }
            let (resident, budget) = (self.cache.resident_bytes(), self.cache.budget());
            let b = self.cache.entry(s.block, header);
            if b.levels.count() > 0 || b.requested_to.is_some() || b.retry_at_frame > self.frame {
                continue;
            }
            // Over budget, at least the coarse levels a synchronous load would fetch: they are
            // small, and they are what spares the frame thread a disk read later.
            let mut last = s.needed;
            if resident + pending + BlockEntry::resident_bytes(last) > budget {
                last = last.min(self.config.sync_max_level);
            }
            let add = BlockEntry::resident_bytes(last);
            b.requested_to = Some(last);
            pending += add;
            self.pool.submit(LoadRequest { block: s.block, first: 0, last, coarser: Vec::new() });
            stats.requests += 1;
        }

        // Eviction: blocks outside N first (farthest first), then levels beyond what N needs,
        // then what N - M needs above its coarse levels, then those; never what M needs.
        let needed: std::collections::BTreeMap<BlockId, (u8, bool, f64)> =
            scheduled.iter().map(|s| (s.block, (s.needed, s.visible, s.distance_m))).collect();
        let mut outside: Vec<(BlockId, f64)> = self
            .cache
            .blocks()
            .filter(|(id, _)| !needed.contains_key(id))
            .map(|(id, _)| {
                let e = store.entry(*id);
                let d = e.map_or(f64::MAX, |e| {
                    let (lo, hi) = block_rect(header, e, *id);
                    rect_distance(eye, lo, hi)
                });
                (*id, d)
            })
            .collect();
        outside.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        let mut order: Vec<(BlockId, usize)> = outside.iter().map(|&(id, _)| (id, 0)).collect();
        let mut by_distance: Vec<&ScheduledBlock> = scheduled.iter().collect();
        by_distance
            .sort_by(|a, b| b.distance_m.total_cmp(&a.distance_m).then(a.block.cmp(&b.block)));
        order.extend(by_distance.iter().map(|s| (s.block, s.needed as usize + 1)));
        let coarse = |s: &ScheduledBlock| s.needed.min(self.config.sync_max_level) as usize + 1;
        order.extend(by_distance.iter().filter(|s| !s.visible).map(|s| (s.block, coarse(s))));
        order.extend(by_distance.iter().filter(|s| !s.visible).map(|s| (s.block, 0)));
        stats.evictions = self.cache.evict(&order);
        self.cache.prune();

        for s in scheduled.iter().filter(|s| s.visible) {
            stats.needed_bytes += BlockEntry::resident_bytes(s.needed);
            let have = self.cache.resident_levels(s.block);
            if have > 0 {
                stats.needed_resident_bytes +=
                    BlockEntry::resident_bytes((have - 1).min(s.needed as usize) as u8);
            }
        }
        stats.resident_bytes = self.cache.resident_bytes();
        stats.queue_depth = self.pool.in_flight();
        self.scheduled = scheduled;
        self.regions = Some(reg);
        self.frame += 1;
        stats.frame_time = t0.elapsed();
        stats
    }

    /// Loads levels `0..=last` of a block on the frame thread (a synchronous load).
    fn load_sync(&mut self, id: BlockId, last: u8, stats: &mut FrameStats) {
        let header = self.store.header().clone();
        stats.sync_loads += 1;
        let t = Instant::now();
        let mut io = Duration::ZERO;
        for level in 0..=last {
            let coarser = self.cache.entry(id, &header).levels.levels().to_vec();
            match self.store.load_level(id, level, &coarser) {
                Ok(l) => {
                    io += l.io_time;
                    stats.disk_bytes += l.disk_bytes;
                    if let Some(b) = self.cache.push_level(id, &header, level, l.samples) {
                        stats.sync_bytes += b;
                    }
                }
                Err(e) => {
                    self.cache.entry(id, &header).retry_at_frame =
                        self.frame + self.config.retry_after_frames;
                    stats.faults.push(e);
                    break;
                }
            }
        }
        let _ = t;
        stats.sync_io_time += io;
        stats.io_time += io;
    }
}

/// Plan distance from `p` to the rectangle `[lo, hi]` (0 inside).
fn rect_distance(p: DVec2, lo: DVec2, hi: DVec2) -> f64 {
    (lo - p).max(p - hi).max(DVec2::ZERO).length()
}
