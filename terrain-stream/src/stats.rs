//! Per-frame statistics, the columns of the paper's Table 3 (needed data, data loaded in real
//! time, prefetched data, I/O time) plus the cache's own: hits, evictions, resident bytes,
//! queue depth, faults, and what the real-time runtime adds: late data (needed by the frame,
//! not resident when it was drawn) and whether the frame was drawn at its needed level.

use std::fmt;
use std::time::Duration;

use glam::DVec2;

use crate::error::StoreError;

/// A block level that could not be read, as the runtime met it: the error (which names the
/// file, the block, the level and the cause), where the block lies, and what the runtime
/// draws instead.
#[derive(Debug)]
pub struct Fault {
    /// What went wrong (file, block, level, cause).
    pub error: StoreError,
    /// The block's plan rectangle (world metres, south-west and north-east corners), when
    /// the block is in the store's grid.
    pub area: Option<(DVec2, DVec2)>,
    /// The block's levels still resident when the fault arrived (`0..resident_levels`): the
    /// block is drawn from level `resident_levels - 1`, or not at all when 0.
    pub resident_levels: usize,
    /// Whether this is the first time this block and level failed in this session (a block
    /// is retried after [`crate::StreamConfig::retry_after_frames`] frames; a fault that
    /// repeats is not new). Report the new ones only.
    pub first: bool,
}

impl Fault {
    /// The level the block is drawn from instead of the one that failed, or `None` when the
    /// block has nothing resident (it cannot be drawn: a hole where it is in view).
    pub fn drawn_level(&self) -> Option<u8> {
        self.resident_levels.checked_sub(1).map(|l| l as u8)
    }
}

impl fmt::Display for Fault {
    /// One line for the user: the error, the block's area and what is drawn instead.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.error)?;
        if let Some((a, b)) = self.area {
            write!(f, "; the block covers x {:.1}..{:.1} m, y {:.1}..{:.1} m", a.x, b.x, a.y, b.y)?;
        }
        match (self.drawn_level(), self.error.level()) {
            (Some(l), Some(failed)) if l < failed => {
                write!(f, "; drawn from its coarser level {l} instead")
            }
            (Some(l), _) => write!(f, "; drawn from its resident level {l}"),
            (None, _) => write!(f, "; no level of this block can be read: it is not drawn"),
        }
    }
}

/// What one frame of [`crate::Streamer::update`] did. Byte counts are decoded bytes in memory
/// (4 per sample) unless named `disk`.
#[derive(Debug, Default)]
pub struct FrameStats {
    /// Frame number, from 0.
    pub frame: u64,
    /// Blocks in the visual region M.
    pub blocks_visible: usize,
    /// Blocks in the scheduling region N (M included).
    pub blocks_scheduled: usize,
    /// Bytes of the levels the blocks of M need this frame.
    pub needed_bytes: u64,
    /// Of those, bytes resident when the frame ended.
    pub needed_resident_bytes: u64,
    /// Late data: bytes of needed levels not resident when the frame ended (the frame is
    /// drawn from coarser resident levels instead): `needed_bytes - needed_resident_bytes`.
    pub late_bytes: u64,
    /// Blocks of M lacking some needed level when the frame ended.
    pub late_blocks: usize,
    /// Levels short, summed over the blocks of M (a block with nothing resident counts all
    /// its needed levels).
    pub late_levels: usize,
    /// Blocks loaded on the frame thread (synchronous): only on a session's first frame in
    /// real-time use (see [`crate::Streamer::update`]).
    pub sync_loads: usize,
    /// Bytes loaded synchronously (the paper's "real-time loaded data").
    pub sync_bytes: u64,
    /// Bytes that arrived from the workers this frame (prefetched data).
    pub prefetched_bytes: u64,
    /// Disk bytes read this frame (synchronous and workers).
    pub disk_bytes: u64,
    /// Read time this frame: synchronous reads plus the workers' reads that arrived.
    pub io_time: Duration,
    /// Of that, time the frame thread itself waited on disk.
    pub sync_io_time: Duration,
    /// Blocks of M whose needed levels were all resident before this frame's loads.
    pub cache_hits: usize,
    /// Blocks of M that lacked some needed level.
    pub cache_misses: usize,
    /// Levels unloaded to stay within the budget.
    pub evictions: usize,
    /// Bytes resident after the frame.
    pub resident_bytes: u64,
    /// The budget.
    pub budget_bytes: u64,
    /// Requests waiting or being loaded by the workers.
    pub queue_depth: usize,
    /// Decoded bytes of the levels those requests ask for and have not delivered yet (what
    /// [`FrameStats::queue_depth`] counts in requests, in bytes).
    pub queued_bytes: u64,
    /// Requests submitted this frame.
    pub requests: usize,
    /// Stale requests cancelled this frame (their blocks left the scheduling region).
    pub cancelled: usize,
    /// Time the frame thread waited for the workers ([`crate::Streamer::wait_until_resident`];
    /// zero for a real-time frame).
    pub wait_time: Duration,
    /// Faults met this frame: each with what is drawn instead (a coarser resident level, or
    /// nothing) and whether it is new this session ([`Fault::first`]).
    pub faults: Vec<Fault>,
    /// Time `update` took on the frame thread.
    pub frame_time: Duration,
    /// The look-ahead used, frames (Eq. 8's `S` multiplier: the configured look-ahead plus,
    /// latency-aware, the measured request latency over the frame interval).
    pub lookahead_frames: f64,
    /// The moving average of the workers' request latency when the frame was scheduled.
    pub request_latency: Duration,
}

impl FrameStats {
    /// Whether the frame thread read from disk (synchronous loads) or waited for the workers.
    pub fn waited_for_io(&self) -> bool {
        self.sync_loads > 0 || !self.wait_time.is_zero()
    }

    /// Whether every block of M had its needed levels resident when the frame ended.
    pub fn at_needed_level(&self) -> bool {
        self.late_blocks == 0
    }

    /// Folds in what a later call of the same frame did (arrivals, waits, loads): sums for
    /// the flows, the later value for the states.
    pub fn merge(&mut self, later: FrameStats) {
        self.sync_loads += later.sync_loads;
        self.sync_bytes += later.sync_bytes;
        self.prefetched_bytes += later.prefetched_bytes;
        self.disk_bytes += later.disk_bytes;
        self.io_time += later.io_time;
        self.sync_io_time += later.sync_io_time;
        self.evictions += later.evictions;
        self.requests += later.requests;
        self.cancelled += later.cancelled;
        self.wait_time += later.wait_time;
        self.frame_time += later.frame_time;
        self.faults.extend(later.faults);
        self.needed_bytes = later.needed_bytes;
        self.needed_resident_bytes = later.needed_resident_bytes;
        self.late_bytes = later.late_bytes;
        self.late_blocks = later.late_blocks;
        self.late_levels = later.late_levels;
        self.resident_bytes = later.resident_bytes;
        self.queue_depth = later.queue_depth;
        self.queued_bytes = later.queued_bytes;
        if later.lookahead_frames > 0.0 {
            self.lookahead_frames = later.lookahead_frames;
            self.request_latency = later.request_latency;
        }
    }
}

/// Sums and maxima over many frames, for reports.
#[derive(Debug, Default, Clone)]
pub struct StatsSummary {
    /// Frames seen.
    pub frames: u64,
    /// Sum of needed bytes.
    pub needed_bytes: u64,
    /// Sum of synchronous bytes.
    pub sync_bytes: u64,
    /// Synchronous loads after the first frame.
    pub sync_loads_after_first: usize,
    /// Frames after the first that waited for I/O (synchronous loads or a wait for the
    /// workers): 0 in real-time use.
    pub frames_waited_after_first: u64,
    /// Frames with every needed level resident when drawn.
    pub frames_at_needed_level: u64,
    /// Sum of late bytes.
    pub late_bytes: u64,
    /// All synchronous loads.
    pub sync_loads: usize,
    /// Sum of prefetched bytes.
    pub prefetched_bytes: u64,
    /// Sum of disk bytes.
    pub disk_bytes: u64,
    /// Sum of I/O time.
    pub io_time: Duration,
    /// Largest I/O time of a frame.
    pub max_io_time: Duration,
    /// Sum of synchronous I/O time.
    pub sync_io_time: Duration,
    /// Largest resident bytes after a frame.
    pub peak_resident_bytes: u64,
    /// Sum of cache hits.
    pub cache_hits: usize,
    /// Sum of cache misses.
    pub cache_misses: usize,
    /// Sum of evictions.
    pub evictions: usize,
    /// Faults.
    pub faults: usize,
    /// Frames whose needed data was not all resident at the end of the frame.
    pub frames_incomplete: u64,
    /// Sum of frame times.
    pub frame_time: Duration,
    /// Largest frame time.
    pub max_frame_time: Duration,
}

impl StatsSummary {
    /// Adds a frame.
    pub fn add(&mut self, s: &FrameStats) {
        self.frames += 1;
        self.needed_bytes += s.needed_bytes;
        self.sync_bytes += s.sync_bytes;
        self.sync_loads += s.sync_loads;
        if s.frame > 0 {
            self.sync_loads_after_first += s.sync_loads;
            self.frames_waited_after_first += u64::from(s.waited_for_io());
        }
        self.frames_at_needed_level += u64::from(s.at_needed_level());
        self.late_bytes += s.late_bytes;
        self.prefetched_bytes += s.prefetched_bytes;
        self.disk_bytes += s.disk_bytes;
        self.io_time += s.io_time;
        self.max_io_time = self.max_io_time.max(s.io_time);
        self.sync_io_time += s.sync_io_time;
        self.peak_resident_bytes = self.peak_resident_bytes.max(s.resident_bytes);
        self.cache_hits += s.cache_hits;
        self.cache_misses += s.cache_misses;
        self.evictions += s.evictions;
        self.faults += s.faults.len();
        self.frames_incomplete += u64::from(s.needed_resident_bytes < s.needed_bytes);
        self.frame_time += s.frame_time;
        self.max_frame_time = self.max_frame_time.max(s.frame_time);
    }
}
