//! Per-frame statistics, the columns of the paper's Table 3 (needed data, data loaded in real
//! time, prefetched data, I/O time) plus the cache's own: hits, evictions, resident bytes,
//! queue depth, faults.

use std::time::Duration;

use crate::error::StoreError;

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
    /// Blocks of M that had no level at all and were loaded on the frame thread (synchronous).
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
    /// Requests submitted this frame.
    pub requests: usize,
    /// Faults reported this frame (the runtime keeps serving coarser levels).
    pub faults: Vec<StoreError>,
    /// Time `update` took on the frame thread.
    pub frame_time: Duration,
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
        }
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
