//! The worker pool behind an explicit endpoint (terra's `TileStreamerEndpoint` style): a
//! request channel and a result channel (crossbeam), an in-flight count, and a documented
//! shutdown. Threads are spawned here and nowhere else.
//!
//! A request asks for levels `first..=last` of one block; the worker loads them one by one
//! (the paper's sub-thread, "loading ... data level-by-level") and sends each level as soon as
//! it is decoded, so the frame thread can use the coarser levels while finer ones load. A
//! failed level ends the request with an error result; a panic inside a load is caught and
//! reported as [`StoreError::WorkerPanicked`], so the pool never loses a thread.
//!
//! **Shutdown:** dropping the [`WorkerPool`] (or calling [`WorkerPool::shutdown`]) closes the
//! request channel; each worker finishes the request it is on (results are dropped if nobody
//! receives them) and exits; the pool joins every thread before returning.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Arc;
use std::thread::JoinHandle;

use crossbeam::channel::{Receiver, Sender, TryRecvError, unbounded};

use crate::error::StoreError;
use crate::format::BlockId;
use crate::store::{LoadedLevel, Store};

/// Load levels `first..=last` of `block`, on top of `coarser` (its levels `0..first`).
#[derive(Debug, Clone)]
pub struct LoadRequest {
    /// The block.
    pub block: BlockId,
    /// The first level to load; `coarser.len()` must equal it.
    pub first: u8,
    /// The last level to load.
    pub last: u8,
    /// The block's resident levels `0..first` (shared, not copied).
    pub coarser: Vec<Arc<[i32]>>,
}

/// One level loaded (or the error that ended a request).
#[derive(Debug)]
pub struct LoadResult {
    /// The block.
    pub block: BlockId,
    /// The level.
    pub level: u8,
    /// Whether this is the request's last result (its last level, or an error).
    pub done: bool,
    /// The level, or why it could not be loaded.
    pub result: Result<LoadedLevel, StoreError>,
}

/// Worker threads loading block levels from a [`Store`].
#[derive(Debug)]
pub struct WorkerPool {
    requests: Option<Sender<LoadRequest>>,
    results: Receiver<LoadResult>,
    in_flight: usize,
    threads: Vec<JoinHandle<()>>,
}

impl WorkerPool {
    /// Spawns `threads` workers (0 = one per available core, at least 1).
    pub fn spawn(store: Arc<Store>, threads: usize) -> Self {
        let n = if threads == 0 {
            std::thread::available_parallelism().map_or(1, |n| n.get())
        } else {
            threads
        };
        let (req_tx, req_rx) = unbounded::<LoadRequest>();
        let (res_tx, res_rx) = unbounded::<LoadResult>();
        let threads = (0..n)
            .map(|t| {
                let (rx, tx, store) = (req_rx.clone(), res_tx.clone(), store.clone());
                std::thread::Builder::new()
                    .name(format!("terrain-stream-{t}"))
                    .spawn(move || worker(&store, &rx, &tx))
                    .expect("the OS can spawn a worker thread")
            })
            .collect();
        Self { requests: Some(req_tx), results: res_rx, in_flight: 0, threads }
    }

    /// Number of worker threads.
    pub fn threads(&self) -> usize {
        self.threads.len()
    }

    /// Requests submitted whose last result has not been received yet.
    pub fn in_flight(&self) -> usize {
        self.in_flight
    }

    /// Queues a request.
    pub fn submit(&mut self, request: LoadRequest) {
        if let Some(tx) = &self.requests
            && tx.send(request).is_ok()
        {
            self.in_flight += 1;
        }
    }

    /// A result, if one is ready (never blocks).
    pub fn try_recv(&mut self) -> Option<LoadResult> {
        match self.results.try_recv() {
            Ok(r) => {
                if r.done {
                    self.in_flight -= 1;
                }
                Some(r)
            }
            Err(TryRecvError::Empty | TryRecvError::Disconnected) => None,
        }
    }

    /// Waits for the next result (for tools and tests; the frame loop uses [`Self::try_recv`]).
    pub fn recv(&mut self) -> Option<LoadResult> {
        if self.in_flight == 0 {
            return None;
        }
        let r = self.results.recv().ok()?;
        if r.done {
            self.in_flight -= 1;
        }
        Some(r)
    }

    /// Closes the request channel and joins every worker (see the module docs).
    pub fn shutdown(mut self) {
        self.stop();
    }

    fn stop(&mut self) {
        self.requests = None;
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

fn worker(store: &Store, requests: &Receiver<LoadRequest>, results: &Sender<LoadResult>) {
    while let Ok(req) = requests.recv() {
        let mut coarser = req.coarser;
        let mut level = req.first;
        loop {
            let outcome =
                catch_unwind(AssertUnwindSafe(|| store.load_level(req.block, level, &coarser)))
                    .unwrap_or_else(|p| {
                        let message = p
                            .downcast_ref::<&str>()
                            .map(|s| s.to_string())
                            .or_else(|| p.downcast_ref::<String>().cloned())
                            .unwrap_or_default();
                        Err(StoreError::WorkerPanicked { block: req.block, level, message })
                    });
            let failed = outcome.is_err();
            let done = failed || level >= req.last;
            if let Ok(l) = &outcome {
                coarser.push(l.samples.clone());
            }
            if results.send(LoadResult { block: req.block, level, done, result: outcome }).is_err()
            {
                return;
            }
            if done {
                break;
            }
            level += 1;
        }
    }
}
