//! The counting global allocator of the harness: live and peak bytes, the largest single
//! request of the case being run, and a hard cap above which a request is refused (the case
//! has asked for far more than its reader's memory limit allows).
//!
//! Refusing returns null: a fallible reservation (`try_reserve`) sees an error and the case is
//! reported as over the limit; an infallible one aborts the process, after the harness has
//! saved the case in progress (`current/` in its work folder), which the driver names.

// The allocator is the only unsafe code of the harness: it forwards to `System` unchanged.
#![allow(unsafe_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};

/// The system allocator, counting.
struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
static CASE_LARGEST: AtomicUsize = AtomicUsize::new(0);
static REFUSED: AtomicUsize = AtomicUsize::new(0);
/// Requests above this are refused; `u64::MAX` until [`set_cap`].
static CAP: AtomicU64 = AtomicU64::new(u64::MAX);

impl Counting {
    /// Records a request of `size` bytes; false when it is over the cap.
    fn admit(size: usize) -> bool {
        if size as u64 > CAP.load(Ordering::Relaxed) {
            REFUSED.fetch_max(size, Ordering::Relaxed);
            return false;
        }
        CASE_LARGEST.fetch_max(size, Ordering::Relaxed);
        true
    }

    fn added(size: usize) {
        let now = LIVE.fetch_add(size, Ordering::Relaxed) + size;
        PEAK.fetch_max(now, Ordering::Relaxed);
    }
}

// SAFETY: every call is forwarded to `System` with the caller's arguments; a refused request
// returns null, which the `GlobalAlloc` contract allows.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if !Self::admit(layout.size()) {
            return std::ptr::null_mut();
        }
        // SAFETY: same contract as the caller's.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            Self::added(layout.size());
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if !Self::admit(layout.size()) {
            return std::ptr::null_mut();
        }
        // SAFETY: same contract as the caller's.
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            Self::added(layout.size());
        }
        p
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if !Self::admit(new_size) {
            return std::ptr::null_mut();
        }
        // SAFETY: same contract as the caller's.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
            Self::added(new_size);
        }
        p
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Refuses every later request over `bytes`.
pub(crate) fn set_cap(bytes: u64) {
    CAP.store(bytes, Ordering::Relaxed);
}

/// Starts a case: its largest request and refusals are counted from zero.
pub(crate) fn start_case() {
    CASE_LARGEST.store(0, Ordering::Relaxed);
    REFUSED.store(0, Ordering::Relaxed);
}

/// The case's largest admitted request, and its largest refused one (0: none).
pub(crate) fn case_largest() -> (usize, usize) {
    (CASE_LARGEST.load(Ordering::Relaxed), REFUSED.load(Ordering::Relaxed))
}

/// Peak live bytes of the process so far.
pub(crate) fn peak_live() -> usize {
    PEAK.load(Ordering::Relaxed)
}
