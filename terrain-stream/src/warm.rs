//! The tree warmer: a thread that walks a [`StoreTree`] ahead (at the out-of-core paper's
//! Eq. 8 eye, [`crate::Streamer::camera_ahead`], and at the next frame's camera,
//! [`crate::Streamer::camera_next`]), so that what the next frame's
//! selection computes the first time it visits a block (the block's index entry, its part of
//! the tree's `sub_max` and its entry's fine maxima pyramid) is computed beside the frame
//! thread, not on it.
//!
//! The walks are [`crate::select_patches`] itself, their patches dropped: one at Eq. 8's eye
//! ahead over the levels drawn now (a block not drawn yet at its finest level: the next frame
//! may draw it), and one at the next frame's camera over the blocks drawn now that it will
//! still draw ([`next_frame_levels`]: those meeting its view region and frustum, the
//! streamer's M). The second finds what the first cannot: a node above the blocks that the
//! next frame splits because one of its blocks left the drawn set (behind the eye, beside the
//! view triangle) sends that frame into every block under it that still has a page, hundreds
//! of blocks visited for the first time in one frame. Over the 32769^2 store's `fast_pass`
//! (`ooc`), the frame thread read 44 blocks a frame for the first time (in 93 of 300 frames,
//! 300-400 at once) with the first walk alone, 2 (in 22 frames) with both.
//!
//! The walks only fill the tree's caches, whose values are functions of the store: a
//! selection gives the same patches with or without them, bit for bit, whatever their timing
//! (tested). They never start a visit of the tree's blocks (the frame's selection does:
//! `VisitedBlocks`), so the blocks they add are kept with the current frame's. One request
//! is pending at most: a newer one replaces an older one not yet walked, so a frame thread
//! faster than the walks never queues work.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;

use terrain_core::geometry::{Camera, Frustum, project_view_to_ground};

use crate::format::BlockId;
use crate::lod::{BlockLevelGrid, StoreTree, Walk, select_patches_in};
use crate::schedule::in_visual_region;

/// A walk asked for: the eye ahead, the next frame's camera, Eq. 7's `tau` and the levels
/// drawn now.
struct Ahead {
    camera: Camera,
    next: Camera,
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

    /// Asks for the walks (see the module docs) at `camera` (Eq. 8's eye ahead,
    /// [`crate::Streamer::camera_ahead`]) and at `next` (the next frame's camera,
    /// [`crate::Streamer::camera_next`]) with Eq. 7's `tau`, over the blocks' levels in
    /// `resident` (block, finest level drawn now), as the next frames'
    /// [`crate::select_patches`] will be asked. Replaces walks asked for and not started yet;
    /// never waits.
    pub fn ahead(&self, camera: &Camera, next: &Camera, tau: f64, resident: Vec<(BlockId, u8)>) {
        let mut slot = self.shared.lock();
        slot.next = Some(Ahead { camera: *camera, next: *next, tau, resident });
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
        let levels = BlockLevelGrid::new(&ahead.resident);
        // A block with nothing resident now is walked as if its finest level were: the blocks
        // the next frame enters have no pages yet, and a block without is not visited.
        let finest = tree.store().header().k;
        let resident = |b: BlockId| Some(levels.get(b).unwrap_or(finest));
        let next = next_frame_levels(tree, &ahead.next, &levels);
        // The walks only fill caches: a panic in one (a defect) loses the walks, not the thread.
        let _ = catch_unwind(AssertUnwindSafe(|| {
            select_patches_in(tree, &ahead.camera, ahead.tau, resident, Walk::Ahead);
            select_patches_in(tree, &ahead.next, ahead.tau, next, Walk::Ahead);
        }));
        let mut slot = shared.lock();
        slot.busy = false;
        slot.walks += 1;
        shared.changed.notify_all();
    }
}

/// The levels the frame at `camera` will draw, as far as a walk can tell before it: each block
/// of `drawn` (the levels drawn now) in `camera`'s visual region M as the streamer chooses it
/// (`schedule::in_visual_region`: its box meets the projected view triangle and is not
/// outside the frustum), with the box's heights bounded by the block's parent node's (no
/// index entry read). A block that leaves M has no page the next frame; one that enters it
/// has none yet.
pub(crate) fn next_frame_levels<'a>(
    tree: &'a StoreTree,
    camera: &Camera,
    drawn: &'a BlockLevelGrid,
) -> impl Fn(BlockId) -> Option<u8> + 'a {
    let view = project_view_to_ground(camera);
    let frustum = Frustum::from_camera(camera);
    move |b: BlockId| {
        let level = drawn.get(b)?;
        in_visual_region(&view, &frustum, &tree.block_box_bound(b)?).then_some(level)
    }
}
