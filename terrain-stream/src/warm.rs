//! The tree warmer: a thread that walks a [`StoreTree`] one frame ahead (the out-of-core
//! paper's Eq. 8 eye, [`crate::Streamer::camera_ahead`]), so that what the next frame's
//! selection computes the first time it visits a block (the block's index entry, its part of
//! the tree's `sub_max` and its entry's fine maxima pyramid) is computed beside the frame
//! thread, not on it.
//!
//! The walk is [`crate::select_patches`] itself at the eye ahead, over the levels drawn now
//! (a block not drawn yet at its finest level: the next frame may draw it); its patches are
//! dropped. It only fills the tree's caches, whose values are functions
//! of the store: a selection gives the same patches with or without it, bit for bit, whatever
//! the walk's timing (tested). It never starts a visit of the tree's blocks (the frame's
//! selection does: `VisitedBlocks`), so the blocks it adds are kept with the current
//! frame's. One walk is pending at most: a newer eye replaces an older one not yet walked, so
//! a frame thread faster than the walks never queues work.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;

use terrain_core::geometry::Camera;
use terrain_core::hash::IdMap;

use crate::format::BlockId;
use crate::lod::{StoreTree, Walk, select_patches_in};

/// A walk asked for: the eye ahead, Eq. 7's `tau` and the levels drawn now.
struct Ahead {
    camera: Camera,
    tau: f64,
    resident: Vec<(BlockId, u8)>,
}

#[derive(Default)]
struct Slot {
    next: Option<Ahead>,
    busy: bool,
    closed: bool,
    walks: u64,
}

#[derive(Default)]
struct Shared {
    slot: Mutex<Slot>,
    changed: Condvar,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Slot> {
        self.slot.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// A thread that walks a [`StoreTree`] one frame ahead (see the module docs); stopped and
/// joined when dropped.
pub struct TreeWarmer {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl std::fmt::Debug for TreeWarmer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TreeWarmer").field("walks", &self.walks()).finish_non_exhaustive()
    }
}

impl TreeWarmer {
    /// Starts the thread over `tree` (a clone: the tree's caches are shared by its clones).
    /// An error when the system cannot start a thread.
    pub fn spawn(tree: &StoreTree) -> std::io::Result<Self> {
        let shared = Arc::new(Shared::default());
        let (tree, inner) = (tree.clone(), shared.clone());
        let thread = std::thread::Builder::new()
            .name("terrain-warm".into())
            .spawn(move || run(&tree, &inner))?;
        Ok(Self { shared, thread: Some(thread) })
    }

    /// Asks for a walk at `camera` (the eye one frame ahead) with Eq. 7's `tau`, over the
    /// blocks' levels in `resident` (block, finest level drawn now; a block not there is
    /// walked to its finest level: the next frame may draw it), as the next frame's
    /// [`crate::select_patches`] will be asked. Replaces a walk asked for and not started
    /// yet; never waits.
    pub fn ahead(&self, camera: &Camera, tau: f64, resident: Vec<(BlockId, u8)>) {
        let mut slot = self.shared.lock();
        slot.next = Some(Ahead { camera: *camera, tau, resident });
        self.shared.changed.notify_all();
    }

    /// Waits until no walk is pending or running (tests, measurements).
    pub fn wait_idle(&self) {
        let mut slot = self.shared.lock();
        while (slot.next.is_some() || slot.busy) && !slot.closed {
            slot = self.shared.changed.wait(slot).unwrap_or_else(|e| e.into_inner());
        }
    }

    /// Walks done so far.
    pub fn walks(&self) -> u64 {
        self.shared.lock().walks
    }
}

impl Drop for TreeWarmer {
    fn drop(&mut self) {
        {
            let mut slot = self.shared.lock();
            slot.closed = true;
            slot.next = None;
            self.shared.changed.notify_all();
        }
        if let Some(t) = self.thread.take() {
            // A walk that panicked was caught in `run`; the thread itself ends normally.
            let _ = t.join();
        }
    }
}

/// The thread: one walk per eye asked for, until closed.
fn run(tree: &StoreTree, shared: &Shared) {
    loop {
        let ahead = {
            let mut slot = shared.lock();
            loop {
                if slot.closed {
                    return;
                }
                if let Some(a) = slot.next.take() {
                    slot.busy = true;
                    break a;
                }
                slot = shared.changed.wait(slot).unwrap_or_else(|e| e.into_inner());
            }
        };
        let levels: IdMap<BlockId, u8> = ahead.resident.into_iter().collect();
        // A block with nothing resident now is walked as if its finest level were: the blocks
        // the next frame enters have no pages yet, and a block without is not visited.
        let finest = tree.store().header().k;
        let resident = |b: BlockId| Some(levels.get(&b).copied().unwrap_or(finest));
        // The walk only fills caches: a panic in it (a defect) loses that walk, not the thread.
        let _ = catch_unwind(AssertUnwindSafe(|| {
            select_patches_in(tree, &ahead.camera, ahead.tau, resident, Walk::Ahead)
        }));
        let mut slot = shared.lock();
        slot.busy = false;
        slot.walks += 1;
        shared.changed.notify_all();
    }
}
