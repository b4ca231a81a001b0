//! The bake streams its source: a synthetic grid delivered by rows is baked with a peak heap
//! far below the size of the whole grid (a counting global allocator measures it), and no
//! read asks for more than one band of block rows. The index is streamed too: its entries go
//! to disk band by band, so the peak stays below the index's own size.
#![allow(unsafe_code)] // The counting allocator below is the only unsafe code, and test-only.

use std::alloc::{GlobalAlloc, Layout, System};
use std::ops::ControlFlow;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use terrain_core::Georef;
use terrain_stream::{BakeConfig, HeightSource, Store, bake};

struct Counting;
static CURRENT: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator and only counts bytes.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(l) };
        if !p.is_null() {
            let now = CURRENT.fetch_add(l.size(), Ordering::Relaxed) + l.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) };
        CURRENT.fetch_sub(l.size(), Ordering::Relaxed);
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// A cheap analytic grid that records the largest read.
struct Rows {
    n: u64,
    largest: Mutex<usize>,
}

impl HeightSource for Rows {
    fn width(&self) -> u64 {
        self.n
    }
    fn height(&self) -> u64 {
        self.n
    }
    fn georef(&self) -> Georef {
        Georef::local(5.0)
    }
    fn read_rows(&self, j0: u64, rows: usize, out: &mut [f32]) -> std::io::Result<()> {
        let mut l = self.largest.lock().unwrap();
        *l = (*l).max(rows);
        for (r, row) in out.chunks_exact_mut(self.n as usize).enumerate() {
            let j = (j0 + r as u64) as f32;
            for (i, z) in row.iter_mut().enumerate() {
                *z = 100.0 + (i as f32 * 0.013).sin() * 50.0 + (j * 0.021).cos() * 40.0;
            }
        }
        Ok(())
    }
}

#[test]
fn a_grid_bakes_in_a_fraction_of_its_size() {
    let n = 2049u64;
    let grid_bytes = (n * n * 4) as usize; // 16.8 MB of f32
    let src = Rows { n, largest: Mutex::new(0) };
    // Removed when dropped, also when the test panics.
    let tmp = tempfile::Builder::new().prefix("terrain-stream-mem-").tempdir().unwrap();
    let dir = tmp.path();
    // Each worker computes a block's 32 DSS object errors with per-factor scratch of the
    // block's size (terrain_core::metrics::dss::ObjectErrorsAcc): measured here on one block of
    // the bake's size, a cost per worker and block, not per grid.
    let scratch = {
        let block = terrain_core::Heightmap::from_fn(65, 65, Georef::local(5.0), |i, j| {
            ((i * j) % 7) as f32
        })
        .unwrap();
        let base = CURRENT.load(Ordering::Relaxed);
        PEAK.store(base, Ordering::Relaxed);
        let region = terrain_core::metrics::Region::new(0, 0, 64);
        std::hint::black_box(terrain_core::metrics::dss::object_errors(&block, region));
        PEAK.load(Ordering::Relaxed) - base
    };
    let base = CURRENT.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    // The default node levels: an index of 5.6 MB (1024 blocks of 5.5 KB), a third of the grid.
    let cfg = BakeConfig { k: 6, threads: 2, ..Default::default() };
    let r = bake(&src, &dir.join("s"), &cfg, &mut |_: &terrain_stream::BakeProgress| {
        ControlFlow::Continue(())
    })
    .unwrap();
    let peak = PEAK.load(Ordering::Relaxed) - base;
    assert_eq!(r.source_samples, n * n);
    // One band is 65 rows: 65 * 2049 * 5 bytes = 0.67 MB. The index's entries are written as
    // each band's blocks finish: memory holds one band's entries (32 of 5.5 KB), never the
    // index. So the peak is the band, a band's entries twice (baked, then written), each
    // worker's block scratch, and 1 MiB for the rest (buffers, rayon), below the index itself.
    let band = 65 * n as usize * 5;
    let entries = 2 * r.index_bytes as usize / 32;
    let bound = band + entries + cfg.threads * scratch + (1 << 20);
    assert!(
        peak < bound,
        "peak heap {peak} bytes, band + {entries} of entries + {} x {scratch} bytes of block \
         scratch + 1 MiB = {bound}",
        cfg.threads
    );
    assert!(peak < r.index_bytes as usize, "peak heap {peak} bytes, index {}", r.index_bytes);
    assert!(peak < grid_bytes / 5, "peak heap {peak} bytes for a {grid_bytes}-byte grid");
    assert!(*src.largest.lock().unwrap() <= 65);
    assert_eq!(Store::open(dir.join("s")).unwrap().header().blocks_x, 32);
}
