//! The worker pool behind an explicit endpoint (terra's `TileStreamerEndpoint` style): a
//! request queue by priority, a result channel (crossbeam), an in-flight count, and a
//! documented shutdown. The stream's threads are spawned here (the crate's others: a remote
//! side table's background fill, `side_table.rs`, and the [`crate::TreeWarmer`]'s walk ahead,
//! `warm.rs`); the frame thread never reads a block after the first frame (the real-time
//! contract of [`crate::Streamer`]).
//!
//! A request asks for levels `first..=last` of one block; the worker loads them one by one
//! (the paper's sub-thread, "loading ... data level-by-level") and sends each level as soon as
//! it is decoded, so the frame thread can use the coarser levels while finer ones load. A
//! failed level ends the request with an error result; a panic inside a load is caught and
//! reported as [`StoreError::WorkerPanicked`], so the pool never loses a thread.
//!
//! **Stale requests.** Every request carries a cancel flag. The frame thread sets it when the
//! block leaves the scheduling region; a worker checks it before each level and ends the
//! request with [`Outcome::Cancelled`] (levels already sent stay valid), so a queue filled for
//! an earlier view does not delay the blocks the current view needs.
//!
//! **Priorities.** Each request carries its tier (the streamer's priority: the coarse levels of
//! visible blocks with nothing resident, then visible blocks' missing levels, then the
//! pre-loading region, then the levels preloaded last), and a worker takes the waiting request
//! of the lowest tier, the earliest submitted within a tier (a queue per tier); a waiting
//! request whose block the view now needs sooner is moved to that tier
//! ([`WorkerPool::raise`]). So a level the view needs now overtakes the preloads that earlier
//! frames queued, instead of waiting behind them (with one FIFO queue, `pvps-b`'s exact demand
//! preloaded over the 32769^2 store, 300 MiB queued, held back the levels of the blocks
//! entering the view: bench/ooc/README.md, "The workers' queue by priority"). A request a
//! worker has started is not interrupted, except by its cancel flag.
//!
//! **Holding I/O.** [`WorkerPool::set_held`] closes a gate that every worker passes before it
//! starts a request and before each level: while held, the workers start no read (a level
//! already being read finishes). A benchmark holds the I/O while it does work that a real-time
//! frame does not do (measuring a frame's error, drawing it on a software renderer), so that
//! work does not give the workers time the flight would not have ([`crate::Streamer::hold_io`]).
//!
//! **Threads started with the demand.** The pool is given the most workers it may run and
//! starts them as requests arrive: one more whenever the requests in flight outnumber the
//! workers started, up to that limit. A worker blocks on its request (a range request to a
//! remote store takes one round trip), so the workers are the requests in the air; a flight
//! that keeps a few requests in flight starts a few threads, not the limit (256 for a remote
//! store). Workers started stay until the pool is dropped.
//!
//! **Shutdown:** dropping the [`WorkerPool`] closes the request queue and drops the requests
//! waiting in it; each worker finishes the request it is on (results are dropped if nobody
//! receives them) and exits; the pool joins every thread before returning.

use std::collections::{HashMap, VecDeque};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::Instant;

use crossbeam::channel::{Receiver, RecvTimeoutError, Sender, TryRecvError, unbounded};

use crate::error::StoreError;
use crate::format::{BlockEntry, BlockId};
use crate::store::{LoadedLevel, Store};

/// Reads one level of one block on top of its coarser levels: the [`Store`] itself, or a
/// wrapper (a test double that injects latency, a reader that counts or throttles).
/// [`crate::Streamer::with_reader`] takes one; every read of the runtime goes through it.
pub trait LevelReader: Send + Sync + std::fmt::Debug {
    /// Reads, checks and decodes `level` of block `id` (`coarser.len()` must equal `level`),
    /// as [`Store::load_level`] does.
    fn load_level(
        &self,
        id: BlockId,
        level: u8,
        coarser: &[Arc<[i32]>],
    ) -> Result<LoadedLevel, StoreError>;

    /// Called once per load request before its levels are loaded: a remote store fetches
    /// levels `first..=last` of `id` in one range request here ([`Store::prefetch_levels`]).
    /// An error ends the request as a fault of level `first`. Default: nothing.
    fn prefetch(&self, id: BlockId, first: u8, last: u8) -> Result<(), StoreError> {
        let _ = (id, first, last);
        Ok(())
    }
}

impl LevelReader for Store {
    fn prefetch(&self, id: BlockId, first: u8, last: u8) -> Result<(), StoreError> {
        self.prefetch_levels(id, first, last)
    }

    fn load_level(
        &self,
        id: BlockId,
        level: u8,
        coarser: &[Arc<[i32]>],
    ) -> Result<LoadedLevel, StoreError> {
        Store::load_level(self, id, level, coarser)
    }
}

/// Load levels `first..=last` of `block`, on top of `coarser` (its levels `0..first`).
#[derive(Debug, Clone)]
pub(crate) struct LoadRequest {
    /// The block.
    pub(crate) block: BlockId,
    /// The first level to load; `coarser.len()` must equal it.
    pub(crate) first: u8,
    /// The last level to load.
    pub(crate) last: u8,
    /// The block's resident levels `0..first` (shared, not copied).
    pub(crate) coarser: Vec<Arc<[i32]>>,
    /// Its cancel flag and priority tier, which the frame thread may change while it waits:
    /// a worker takes the lowest tier waiting first, in order of submission within a tier (see
    /// the module docs).
    pub(crate) flags: Arc<RequestFlags>,
}

/// What a worker did with one level of a request.
#[derive(Debug)]
pub(crate) enum Outcome {
    /// The level, read and decoded.
    Loaded(LoadedLevel),
    /// Why it could not be loaded (ends the request).
    Failed(StoreError),
    /// The request was cancelled before this level (ends the request; nothing was read).
    Cancelled,
}

/// What the frame thread may change of a request after submitting it: its cancel flag and its
/// tier.
#[derive(Debug)]
pub(crate) struct RequestFlags {
    cancelled: AtomicBool,
    tier: AtomicU8,
}

impl RequestFlags {
    pub(crate) fn new(tier: u8) -> Arc<Self> {
        Arc::new(Self { cancelled: AtomicBool::new(false), tier: AtomicU8::new(tier) })
    }

    /// Marks the request stale: a worker drops it before its next level.
    pub(crate) fn cancel(&self) {
        self.cancelled.store(true, Ordering::Relaxed);
    }

    fn is_cancelled(&self) -> bool {
        self.cancelled.load(Ordering::Relaxed)
    }

    pub(crate) fn tier(&self) -> u8 {
        self.tier.load(Ordering::Relaxed)
    }
}

/// The streamer's tiers ([`LoadRequest::flags`]): 0 (the first) to `TIERS - 1`.
pub(crate) const TIERS: usize = 4;

/// The requests waiting for a worker: one queue per tier, each in order of submission; a
/// worker takes the first of the lowest tier that has one. A request raised while it waits
/// ([`WorkerPool::raise`]) moves to its new tier's queue at its place in the order of
/// submission.
#[derive(Debug, Default)]
struct Queue {
    state: Mutex<QueueState>,
    ready: Condvar,
}

#[derive(Debug, Default)]
struct QueueState {
    /// Per tier: (order of submission, request), in that order.
    waiting: [VecDeque<(u64, LoadRequest)>; TIERS],
    submitted: u64,
    closed: bool,
}

impl Queue {
    fn lock(&self) -> std::sync::MutexGuard<'_, QueueState> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Queues `request` at its tier; `false` once the queue is closed.
    fn push(&self, request: LoadRequest) -> bool {
        let mut q = self.lock();
        if q.closed {
            return false;
        }
        let seq = q.submitted;
        q.submitted += 1;
        let tier = usize::from(request.flags.tier()).min(TIERS - 1);
        q.waiting[tier].push_back((seq, request));
        drop(q);
        self.ready.notify_one();
        true
    }

    /// Moves the waiting request with `flags` to `tier` if that is lower than its own (a
    /// request a worker took already is not found: nothing changes).
    fn raise(&self, flags: &Arc<RequestFlags>, tier: u8) {
        let mut q = self.lock();
        let from = usize::from(flags.tier()).min(TIERS - 1);
        let to = usize::from(tier).min(TIERS - 1);
        if to >= from {
            return;
        }
        let Some(i) = q.waiting[from].iter().position(|(_, r)| Arc::ptr_eq(&r.flags, flags)) else {
            return;
        };
        let entry = q.waiting[from].remove(i).expect("a position of the queue");
        flags.tier.store(tier, Ordering::Relaxed);
        let at = q.waiting[to].partition_point(|(seq, _)| *seq < entry.0);
        q.waiting[to].insert(at, entry);
    }

    /// The first waiting request by priority, waiting for one; `None` once the queue is
    /// closed (what still waits is dropped).
    fn pop(&self) -> Option<LoadRequest> {
        let q = self.lock();
        let mut q = self
            .ready
            .wait_while(q, |q| q.waiting.iter().all(VecDeque::is_empty) && !q.closed)
            .unwrap_or_else(|e| e.into_inner());
        if q.closed {
            q.waiting.iter_mut().for_each(VecDeque::clear);
            return None;
        }
        let (_, r) = q.waiting.iter_mut().find_map(VecDeque::pop_front)?;
        // Taken: nothing can overtake it any more, and a raise need not look for it.
        r.flags.tier.store(0, Ordering::Relaxed);
        Some(r)
    }

    fn close(&self) {
        self.lock().closed = true;
        self.ready.notify_all();
    }
}

/// One level loaded (or what ended a request).
#[derive(Debug)]
pub(crate) struct LoadResult {
    /// The block.
    pub(crate) block: BlockId,
    /// The level.
    pub(crate) level: u8,
    /// Whether this is the request's last result (its last level, an error, a cancel).
    pub(crate) done: bool,
    /// What happened.
    pub(crate) outcome: Outcome,
    /// On a request's first result: the time from the start of the request to this result
    /// (the request's latency: one range request for a remote store, a disk read for a local
    /// one). What the latency-aware look-ahead measures.
    pub(crate) latency: Option<std::time::Duration>,
}

/// Worker threads loading block levels through a [`LevelReader`].
#[derive(Debug)]
pub(crate) struct WorkerPool {
    requests: Arc<Queue>,
    results: Receiver<LoadResult>,
    /// What a worker started later is given besides the request queue: the results' sender
    /// and the reader.
    spawn: Spawn,
    /// The most workers the pool starts.
    max_threads: usize,
    in_flight: usize,
    /// Per block with a request in flight (the streamer keeps at most one per block), the
    /// decoded bytes of its levels not received yet.
    pending: HashMap<BlockId, u64>,
    /// The sum of `pending`.
    queued_bytes: u64,
    threads: Vec<JoinHandle<()>>,
    /// The hold gate the workers pass before each read.
    gate: Arc<Gate>,
}

/// What each worker thread is started with.
#[derive(Debug)]
struct Spawn {
    results: Sender<LoadResult>,
    reader: Arc<dyn LevelReader>,
}

/// The workers' hold gate: closed (held) or open.
#[derive(Debug, Default)]
struct Gate {
    held: Mutex<bool>,
    opened: Condvar,
}

impl Gate {
    fn set(&self, held: bool) {
        *self.held.lock().unwrap_or_else(|e| e.into_inner()) = held;
        self.opened.notify_all();
    }

    fn is_held(&self) -> bool {
        *self.held.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Returns once the gate is open.
    fn pass(&self) {
        let held = self.held.lock().unwrap_or_else(|e| e.into_inner());
        drop(self.opened.wait_while(held, |h| *h).unwrap_or_else(|e| e.into_inner()));
    }
}

/// Decoded bytes of level `level` alone (levels `0..=level` less levels `0..level`).
fn level_bytes(level: u8) -> u64 {
    let below = level.checked_sub(1).map_or(0, BlockEntry::resident_bytes);
    BlockEntry::resident_bytes(level) - below
}

impl WorkerPool {
    /// A pool of at most `threads` workers (0 = one per available core, at least 1), started
    /// as the requests in flight need them (none before the first request).
    pub(crate) fn spawn(reader: Arc<dyn LevelReader>, threads: usize) -> Self {
        let max_threads = if threads == 0 {
            std::thread::available_parallelism().map_or(1, |n| n.get())
        } else {
            threads
        };
        let (res_tx, res_rx) = unbounded::<LoadResult>();
        Self {
            requests: Arc::new(Queue::default()),
            results: res_rx,
            spawn: Spawn { results: res_tx, reader },
            max_threads,
            in_flight: 0,
            pending: HashMap::new(),
            queued_bytes: 0,
            threads: Vec::new(),
            gate: Arc::new(Gate::default()),
        }
    }

    /// Starts one more worker.
    fn start_worker(&mut self) {
        let t = self.threads.len();
        let (rx, tx) = (self.requests.clone(), self.spawn.results.clone());
        let (reader, gate) = (self.spawn.reader.clone(), self.gate.clone());
        let handle = std::thread::Builder::new()
            .name(format!("terrain-stream-{t}"))
            .spawn(move || worker(&*reader, &gate, &rx, &tx))
            .expect("the OS can spawn a worker thread");
        self.threads.push(handle);
    }

    /// Holds the workers (`true`: no read starts until released) or releases them.
    pub(crate) fn set_held(&self, held: bool) {
        self.gate.set(held);
    }

    /// Whether the workers are held.
    pub(crate) fn is_held(&self) -> bool {
        self.gate.is_held()
    }

    /// The most worker threads the pool starts.
    pub(crate) fn max_threads(&self) -> usize {
        self.max_threads
    }

    /// Worker threads started so far (at most the largest number of requests that were in
    /// flight at once, and at most [`WorkerPool::max_threads`]).
    pub(crate) fn threads_started(&self) -> usize {
        self.threads.len()
    }

    /// Requests submitted whose last result has not been received yet.
    pub(crate) fn in_flight(&self) -> usize {
        self.in_flight
    }

    /// Decoded bytes of the levels requested and not received yet (waiting or being loaded).
    pub(crate) fn queued_bytes(&self) -> u64 {
        self.queued_bytes
    }

    /// Queues a request (taken by its tier, then in order: see the module docs).
    pub(crate) fn submit(&mut self, request: LoadRequest) {
        let (block, bytes) =
            (request.block, (request.first..=request.last).map(level_bytes).sum::<u64>());
        if self.requests.push(request) {
            self.in_flight += 1;
            *self.pending.entry(block).or_default() += bytes;
            self.queued_bytes += bytes;
            if self.in_flight > self.threads.len() && self.threads.len() < self.max_threads {
                self.start_worker();
            }
        }
    }

    /// Moves a waiting request up to `tier` (never down): its block is needed sooner than when
    /// it was asked (a preloaded level the view now needs). Only a lower tier than its own
    /// takes the queue's lock.
    pub(crate) fn raise(&self, flags: &Arc<RequestFlags>, tier: u8) {
        if tier < flags.tier() {
            self.requests.raise(flags, tier);
        }
    }

    fn received(&mut self, r: LoadResult) -> LoadResult {
        // A level received leaves the queue; a request's end (its last level, an error, a
        // cancel) takes whatever of it is left.
        let gone = match self.pending.get_mut(&r.block) {
            Some(left) if r.done => std::mem::take(left),
            Some(left) => {
                let b =
                    if matches!(r.outcome, Outcome::Loaded(_)) { level_bytes(r.level) } else { 0 };
                let b = b.min(*left);
                *left -= b;
                b
            }
            None => 0,
        };
        self.queued_bytes -= gone;
        if r.done {
            self.pending.remove(&r.block);
            self.in_flight -= 1;
        }
        r
    }

    /// A result, if one is ready (never blocks).
    pub(crate) fn try_recv(&mut self) -> Option<LoadResult> {
        match self.results.try_recv() {
            Ok(r) => Some(self.received(r)),
            Err(TryRecvError::Empty | TryRecvError::Disconnected) => None,
        }
    }

    /// Waits for the next result until `deadline` (`None`: without limit); `None` when
    /// nothing is in flight or the deadline passed. Never called by a real-time frame.
    pub(crate) fn recv_until(&mut self, deadline: Option<Instant>) -> Option<LoadResult> {
        if self.in_flight == 0 {
            return None;
        }
        let r = match deadline {
            None => self.results.recv().ok()?,
            Some(d) => match self.results.recv_deadline(d) {
                Ok(r) => r,
                Err(RecvTimeoutError::Timeout | RecvTimeoutError::Disconnected) => return None,
            },
        };
        Some(self.received(r))
    }

    fn stop(&mut self) {
        self.requests.close();
        // A held worker must get past the gate to see the closed queue.
        self.gate.set(false);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

impl Drop for WorkerPool {
    fn drop(&mut self) {
        self.stop();
    }
}

fn worker(reader: &dyn LevelReader, gate: &Gate, requests: &Queue, results: &Sender<LoadResult>) {
    while let Some(req) = requests.pop() {
        gate.pass();
        let mut coarser = req.coarser;
        let mut level = req.first;
        let start = Instant::now();
        if !req.flags.is_cancelled() {
            // One range request for the levels; if it fails, each level is then read alone
            // (its own request), so a fault names the level that cannot be read and the
            // coarser levels the range held still load.
            let _ =
                catch_unwind(AssertUnwindSafe(|| reader.prefetch(req.block, req.first, req.last)));
        }
        let mut first_result = true;
        loop {
            gate.pass();
            let outcome = if req.flags.is_cancelled() {
                Outcome::Cancelled
            } else {
                match catch_unwind(AssertUnwindSafe(|| {
                    reader.load_level(req.block, level, &coarser)
                })) {
                    Ok(Ok(l)) => Outcome::Loaded(l),
                    Ok(Err(e)) => Outcome::Failed(e),
                    Err(p) => {
                        let message = p
                            .downcast_ref::<&str>()
                            .map(|s| s.to_string())
                            .or_else(|| p.downcast_ref::<String>().cloned())
                            .unwrap_or_default();
                        Outcome::Failed(StoreError::WorkerPanicked {
                            block: req.block,
                            level,
                            message,
                        })
                    }
                }
            };
            let done = !matches!(outcome, Outcome::Loaded(_)) || level >= req.last;
            if let Outcome::Loaded(l) = &outcome {
                coarser.push(l.samples.clone());
            }
            // A request cancelled before it read anything measured no request.
            let latency =
                (first_result && !matches!(outcome, Outcome::Cancelled)).then(|| start.elapsed());
            first_result = false;
            let r = LoadResult { block: req.block, level, done, outcome, latency };
            if results.send(r).is_err() {
                return;
            }
            if done {
                break;
            }
            level += 1;
        }
    }
}
