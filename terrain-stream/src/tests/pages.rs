//! The paged index (version 4): the baked file is the whole-index writer's bytes, every entry
//! read page by page equals the entry read whole, older indexes (version 3, 2) still open
//! read whole, a damaged page is named, and a cache smaller than the index serves the same
//! selections as a cache that holds it all.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use glam::dvec3;
use terrain_core::Georef;
use terrain_core::geometry::Camera;
use terrain_core::heightmap::Heightmap;

use crate::format::{INDEX_FILE, read_index, write_index, write_index_unpaged};
use crate::pages::{IndexHead, decode_page, paged_prefix_len};
use crate::{
    BakeConfig, BakeProgress, BlockId, Store, StoreError, StoreTree, bake, select_patches,
};

/// A 513^2 store (k = 6, 8 x 8 blocks) with 5 node levels, so that an entry is about 5.6 KB
/// and the index has several pages.
/// The store's folder is removed (with the copies made beside it) when the guard is dropped.
fn paged_store(name: &str) -> super::Scratch {
    let dir = super::scratch_store(&format!("terrain-pages-{name}-"));
    let hm = Heightmap::from_fn(513, 513, Georef::local(10.0), |i, j| {
        300.0
            + 250.0 * ((i as f32) * 0.013).sin() * ((j as f32) * 0.021).cos()
            + ((i * 7 + j * 13) % 23) as f32
    })
    .unwrap();
    let cfg = BakeConfig { k: 6, node_levels: 5, ..Default::default() };
    bake(&hm, &dir, &cfg, &mut |_: &BakeProgress| std::ops::ControlFlow::Continue(())).unwrap();
    dir
}

/// A 4097 x 17 store in blocks of 8 cells: 512 x 2 blocks, 9 levels above the blocks, one
/// more than the head's pyramid holds (`HEAD_LEVELS`).
fn deep_store(name: &str) -> super::Scratch {
    let dir = super::scratch_store(&format!("terrain-pages-{name}-"));
    let hm = Heightmap::from_fn(4097, 17, Georef::local(10.0), |i, j| {
        300.0 + 250.0 * ((i as f32) * 0.0031).sin() + ((i * 7 + j * 13) % 23) as f32
    })
    .unwrap();
    let cfg = BakeConfig { k: 3, node_levels: 2, ..Default::default() };
    bake(&hm, &dir, &cfg, &mut |_: &BakeProgress| std::ops::ControlFlow::Continue(())).unwrap();
    dir
}

/// The folder `to` with `from`'s blocks and `index` as its index.
fn with_index(from: &Path, to: &Path, index: &[u8]) {
    let _ = std::fs::remove_dir_all(to);
    std::fs::create_dir_all(to.join("blocks")).unwrap();
    for f in std::fs::read_dir(from.join("blocks")).unwrap() {
        let p = f.unwrap().path();
        std::fs::copy(&p, to.join("blocks").join(p.file_name().unwrap())).unwrap();
    }
    std::fs::write(to.join(INDEX_FILE), index).unwrap();
}

fn head_of(dir: &Path) -> (crate::Header, IndexHead, Vec<u8>) {
    let bytes = std::fs::read(dir.join(INDEX_FILE)).unwrap();
    let mut r = crate::format::Reader::new(&bytes[12..]);
    let header = crate::format::read_header(&mut r).unwrap();
    let prefix = &bytes[..paged_prefix_len(&header)];
    let mut r = crate::format::Reader::new(&prefix[12..]);
    crate::format::read_header(&mut r).unwrap();
    let head = crate::pages::read_head(&mut r, prefix, &header).unwrap();
    (header, head, bytes)
}

#[test]
fn a_paged_index_reads_every_entry_as_the_whole_index_does() {
    let dir = paged_store("round");
    let (header, head, bytes) = head_of(&dir);
    let n = header.block_count();
    assert!(head.page_count(n) >= 4, "{} pages: the test needs several", head.page_count(n));
    // The bake's streamed writer wrote the whole-index writer's bytes.
    let (h, whole) = read_index(&bytes).unwrap();
    assert!(write_index(&h, &whole) == bytes, "the streamed index differs from the whole one");

    // Opening reads no page; each entry then equals the whole read's, and the version-3 index
    // of the same entries (read whole, the old path) gives the same entries and totals.
    let store = Store::open(&dir).unwrap();
    assert_eq!(store.index_pages_decoded(), Some(0));
    let v3 = dir.with_extension("v3");
    with_index(&dir, &v3, &write_index_unpaged(&h, &whole, 3));
    let old = Store::open(&v3).unwrap();
    assert_eq!(old.index_pages_decoded(), None);
    assert_eq!(old.header(), store.header());
    for (pos, id) in store.block_ids().enumerate() {
        assert_eq!(*store.entry(id).unwrap(), whole[pos], "{id}");
        assert_eq!(*old.entry(id).unwrap(), whole[pos], "{id}");
    }
    assert_eq!(store.index_pages_decoded(), Some(head.page_count(n) as u64));
    assert_eq!(store.blocks_bytes(), old.blocks_bytes());
    assert_eq!(store.has_dss_errors(), old.has_dss_errors());
    assert_eq!(store.has_fine_errors(), old.has_fine_errors());
    assert!(store.has_fine_errors());
    let id = BlockId::new(3, 5);
    assert_eq!(old.read_block(id, 6).unwrap().grid(6), store.read_block(id, 6).unwrap().grid(6));
    // An exaggerated paged store scales what it decodes as the whole one does.
    let (a, b) = (store.exaggerated(2.5).unwrap(), old.exaggerated(2.5).unwrap());
    for id in store.block_ids() {
        assert_eq!(a.entry(id), b.entry(id), "{id}");
    }
    // Version 2 (no fine maxima) still opens, read whole.
    let v2 = dir.with_extension("v2");
    with_index(&dir, &v2, &write_index_unpaged(&h, &whole, 2));
    let older = Store::open(&v2).unwrap();
    assert!(!older.has_fine_errors());
    assert_eq!(older.entry(id).unwrap().nodes, whole[header.block_position(id).unwrap()].nodes);
}

#[test]
fn a_damaged_page_is_named_and_the_others_still_read() {
    let dir = paged_store("damaged");
    let (header, head, bytes) = head_of(&dir);
    let n = header.block_count();
    let prefix = paged_prefix_len(&header) as u64;
    let (first, count, at, len) = head.page_span(2, prefix, n);
    let mut b = bytes.clone();
    b[(at + len / 2) as usize] ^= 0x04;
    std::fs::write(dir.join(INDEX_FILE), &b).unwrap();
    let store = Store::open(&dir).unwrap();
    let hit = header.block_at(first + count / 2);
    match store.try_entry(hit) {
        Err(StoreError::IndexPage { page: 2, blocks, ref message, .. }) => {
            assert_eq!(blocks, (first, first + count));
            assert!(message.contains("checksum"), "{message}");
        }
        other => panic!("expected page 2 refused, got {other:?}"),
    }
    let msg = store.try_entry(hit).unwrap_err().to_string();
    assert!(msg.contains("index.tsi") && msg.contains("page 2"), "{msg}");
    // `entry` says `None` and the store remembers why; reading the block's levels says why.
    assert!(store.index_fault().is_none());
    assert!(store.entry(hit).is_none());
    assert!(store.index_fault().unwrap().contains("page 2"));
    let k = header.k;
    assert!(matches!(store.read_level_bytes(hit, k), Err(StoreError::IndexPage { page: 2, .. })));
    // Its coarse levels come from the overview, which needs no index entry.
    assert!(k > 4 && store.read_level_bytes(hit, 0).is_ok());
    // Other pages read.
    assert!(store.entry(header.block_at(0)).is_some());
    assert!(store.entry(header.block_at(n - 1)).is_some());

    // A page read from another page's place fails its checksum (each page's CRC-32 starts
    // from its number): two pages of the same length swapped.
    let (_, _, at1, len1) = head.page_span(1, prefix, n);
    let (_, _, at3, len3) = head.page_span(3, prefix, n);
    assert_eq!(len1, len3);
    let mut b = bytes.clone();
    let p1 = bytes[at1 as usize..(at1 + len1) as usize].to_vec();
    b.copy_within(at3 as usize..(at3 + len3) as usize, at1 as usize);
    b[at3 as usize..(at3 + len3) as usize].copy_from_slice(&p1);
    std::fs::write(dir.join(INDEX_FILE), &b).unwrap();
    let store = Store::open(&dir).unwrap();
    assert!(matches!(store.try_entry(header.block_at(first)), Ok(Some(_))));
    let (f1, ..) = head.page_span(1, prefix, n);
    assert!(matches!(
        store.try_entry(header.block_at(f1)),
        Err(StoreError::IndexPage { page: 1, .. })
    ));
    // Negative control of the framing: page 1's bytes checked as page 1 pass, as page 3 fail,
    // and read one entry off their place fail.
    let page1 = &bytes[at1 as usize..(at1 + len1) as usize];
    assert!(decode_page(page1, &header, &head, 1).is_ok());
    assert!(decode_page(page1, &header, &head, 3).is_err());
    let shifted = &bytes[(at1 + u64::from(head.entry_len)) as usize..][..len1 as usize];
    assert!(decode_page(shifted, &header, &head, 1).is_err());

    // Truncated or grown by a byte: refused at open, naming the file.
    std::fs::write(dir.join(INDEX_FILE), &bytes[..bytes.len() - 1]).unwrap();
    let err = Store::open(&dir).unwrap_err();
    assert!(
        matches!(err, StoreError::CorruptIndex { .. }) && err.to_string().contains("index.tsi")
    );
    let mut b = bytes.clone();
    b.push(0);
    std::fs::write(dir.join(INDEX_FILE), &b).unwrap();
    assert!(matches!(Store::open(&dir), Err(StoreError::CorruptIndex { .. })));
}

#[test]
fn a_cache_smaller_than_the_index_serves_the_same_selections() {
    let dir = paged_store("small-cache");
    let (header, head, _) = head_of(&dir);
    let pages = head.page_count(header.block_count()) as u64;
    let big = Arc::new(Store::open(&dir).unwrap().with_page_cache_bytes(1 << 30).unwrap());
    // One page's worth: every other page evicts it.
    let small = Arc::new(Store::open(&dir).unwrap().with_page_cache_bytes(1).unwrap());
    let all: HashMap<BlockId, u8> = big.block_ids().map(|b| (b, header.k)).collect();
    let cam = |x, y, z, yaw, pitch, far| {
        Camera::from_yaw_pitch(dvec3(x, y, z), yaw, pitch).with_clip(1.0, far)
    };
    let cameras = [
        cam(100.0, 150.0, 420.0, 45.0, -12.0, 6000.0),
        cam(2500.0, 2500.0, 6000.0, 10.0, -89.0, 9000.0),
        cam(2600.0, 4800.0, 600.0, 180.0, -20.0, 4000.0),
    ];
    let (tb, ts) = (StoreTree::new(big.clone(), 8), StoreTree::new(small.clone(), 8));
    let mut patches = 0;
    for c in &cameras {
        for tau in [0.5, 2.0] {
            let a = select_patches(&tb, c, tau, |b| all.get(&b).copied());
            let b = select_patches(&ts, c, tau, |b| all.get(&b).copied());
            assert_eq!(format!("{:?}", a.patches), format!("{:?}", b.patches), "tau {tau}");
            patches += a.patches.len();
        }
    }
    assert!(patches > 100, "{patches} patches: the views must see the terrain");
    // The big cache decoded each page at most once; the small one evicted and read again.
    let (db, ds) = (big.index_pages_decoded().unwrap(), small.index_pages_decoded().unwrap());
    assert!(db <= pages, "{db} of {pages}");
    assert!(ds > pages, "{ds} decodes of {pages} pages: the small cache must evict");
    // The tree above the blocks came from the head's pyramid: it equals the pyramid computed
    // from every entry (the version-3 path).
    let (h, whole) = read_index(&std::fs::read(dir.join(INDEX_FILE)).unwrap()).unwrap();
    let v3 = dir.with_extension("v3");
    with_index(&dir, &v3, &write_index_unpaged(&h, &whole, 3));
    let old = Arc::new(Store::open(&v3).unwrap());
    let to = StoreTree::new(old, 8);
    for c in &cameras {
        let a = select_patches(&to, c, 2.0, |b| all.get(&b).copied());
        let b = select_patches(&ts, c, 2.0, |b| all.get(&b).copied());
        assert_eq!(format!("{:?}", a.patches), format!("{:?}", b.patches));
    }
}

#[test]
fn the_index_cache_budget_set_on_a_clone_holds_for_the_store_it_shares() {
    let dir = paged_store("shared-budget");
    let (header, head, _) = head_of(&dir);
    let pages = head.page_count(header.block_count()) as u64;
    assert!(pages >= 4, "{pages} pages: the test needs several");
    let store = Store::open(&dir).unwrap();
    let (budget, whole) = store.index_cache_bytes().unwrap();
    assert_eq!(budget, 32 << 20, "the default");
    assert!(whole > 0 && whole < budget, "{whole} bytes decoded: this index fits the default");
    // Every entry twice, in row-major order: a cache of one page decodes each page twice, a
    // cache of the whole index once.
    let read_all = |s: &Store| {
        for _ in 0..2 {
            for b in s.block_ids() {
                s.entry(b).unwrap();
            }
        }
    };
    let clone = store.clone();
    clone.set_index_cache_bytes(1);
    assert_eq!(store.index_cache_bytes(), Some((1, whole)), "the clone shares the cache");
    read_all(&store);
    assert_eq!(store.index_pages_decoded(), Some(2 * pages));
    // Raised on the clone to the whole index: each page but the last one read (still held) is
    // decoded once more, then kept.
    clone.set_index_cache_bytes(whole);
    read_all(&store);
    assert_eq!(clone.index_pages_decoded(), Some(3 * pages - 1));
    // Lowered: the pages beyond it leave at once but one, the most recently used (the last
    // page), which the next page read evicts in turn: the next pass decodes every page again.
    store.set_index_cache_bytes(0);
    let last = store.block_ids().last().unwrap();
    store.entry(last).unwrap();
    assert_eq!(store.index_pages_decoded(), Some(3 * pages - 1), "the last page was kept");
    for b in store.block_ids() {
        store.entry(b).unwrap();
    }
    assert_eq!(store.index_pages_decoded(), Some(4 * pages - 1));
}

#[test]
fn the_blocks_box_and_nearest_block_equal_the_brute_force_over_every_entry() {
    let dir = paged_store("nearest");
    let (header, head, _) = head_of(&dir);
    let pages = head.page_count(header.block_count()) as u64;
    let store = Arc::new(Store::open(&dir).unwrap());
    let tree = StoreTree::new(store.clone(), 8);
    let (lo, hi) = tree.blocks_box().unwrap();
    // Read from the corner blocks and the pyramid: not every page.
    let read = store.index_pages_decoded().unwrap();
    assert!(read < pages, "{read} of {pages} pages read for the box");
    let boxes: Vec<_> = store
        .block_ids()
        .map(|b| {
            let e = store.entry(b).unwrap();
            let (a, c) = store.block_rect(b).unwrap();
            (a.extend(e.min.into()), c.extend(e.max.into()))
        })
        .collect();
    let (blo, bhi) = boxes.iter().fold(
        (glam::DVec3::splat(f64::INFINITY), glam::DVec3::splat(f64::NEG_INFINITY)),
        |(l, h), (a, c)| (l.min(*a), h.max(*c)),
    );
    assert_eq!((lo, hi), (blo, bhi));
    let mut far = 0;
    for p in [
        dvec3(100.0, 150.0, 420.0),
        dvec3(2500.0, 2500.0, 6000.0),
        dvec3(2600.0, 4800.0, 300.0),
        dvec3(-3000.0, 9000.0, 50.0),
        dvec3(5119.0, 3.0, 0.0),
        dvec3(641.0, 1919.0, 320.0),
    ] {
        let brute =
            boxes.iter().map(|(a, c)| (p.clamp(*a, *c) - p).length()).fold(f64::INFINITY, f64::min);
        assert_eq!(tree.nearest_block_distance(p), brute, "at {p}");
        far += usize::from(brute > 100.0);
    }
    assert!(far >= 2, "the points must include some away from the blocks");
}

#[test]
fn a_grid_beyond_the_head_pyramid_selects_as_the_whole_read_tree_without_reading_every_entry() {
    let dir = deep_store("deep");
    let (header, head, _) = head_of(&dir);
    assert_eq!((header.blocks_x, header.blocks_y), (512, 2));
    assert_eq!(head.levels, crate::pages::HEAD_LEVELS);
    let pages = head.page_count(header.block_count()) as u64;
    assert!(pages > 4, "{pages} pages");
    let store = Arc::new(Store::open(&dir).unwrap());
    let tree = StoreTree::new(store.clone(), 8);
    assert_eq!(tree.block_level(), 9);
    assert_eq!(store.index_pages_decoded(), Some(0), "building the tree read no page");
    // The whole-read tree: the same entries in a version-3 index (every level computed from
    // every entry at build).
    let (h, whole) = read_index(&std::fs::read(dir.join(INDEX_FILE)).unwrap()).unwrap();
    let v3 = dir.with_extension("v3");
    with_index(&dir, &v3, &write_index_unpaged(&h, &whole, 3));
    let old = StoreTree::new(Arc::new(Store::open(&v3).unwrap()), 8);
    let all: HashMap<BlockId, u8> = store.block_ids().map(|b| (b, header.k)).collect();
    let cam = |x, y, z, yaw, pitch, far| {
        Camera::from_yaw_pitch(dvec3(x, y, z), yaw, pitch).with_clip(1.0, far)
    };
    let mut patches = 0;
    // Along the strip from its west end, and down on its east end.
    for c in [
        cam(50.0, 80.0, 600.0, 90.0, -8.0, 50000.0),
        cam(39000.0, 80.0, 900.0, 270.0, -30.0, 50000.0),
    ] {
        for tau in [0.5, 3.0] {
            let a = select_patches(&old, &c, tau, |b| all.get(&b).copied());
            let b = select_patches(&tree, &c, tau, |b| all.get(&b).copied());
            assert_eq!(format!("{:?}", a.patches), format!("{:?}", b.patches), "tau {tau}");
            patches += a.patches.len();
        }
    }
    assert!(patches > 20, "{patches} patches: the views must see the terrain");
    // Every node's values equal the whole-read tree's, down to the level above the blocks.
    for level in 0..9u8 {
        for i in (0..1u32 << level).step_by(((1usize << level) / 8).max(1)) {
            let n = terrain_core::quadtree::NodeId { level, i, j: 0 };
            use terrain_core::quadtree::NodeSource;
            let (a, b) = (old.node_info(n).map(|x| x.aabb), tree.node_info(n).map(|x| x.aabb));
            assert_eq!(format!("{a:?}"), format!("{b:?}"), "node {n:?}");
        }
    }
}

#[test]
fn a_streamers_frames_read_the_index_once_not_every_frame() {
    use crate::{StreamConfig, Streamer};
    let dir = paged_store("streamer");
    let (header, head, _) = head_of(&dir);
    let pages = head.page_count(header.block_count()) as u64;
    let cam = |x, y| {
        Camera::from_yaw_pitch(dvec3(x, y, 900.0), 30.0, -25.0)
            .with_viewport(320.0, 180.0)
            .with_clip(1.0, 9000.0)
    };
    let cameras = [cam(100.0, 150.0), cam(1500.0, 300.0), cam(2600.0, 900.0)];
    let stats_of = |store: Arc<Store>, demand: bool| {
        // The workers read the blocks (and their entries) through a store of their own, so
        // `store`'s page decodes count the schedule's reads alone.
        let loads: Arc<dyn crate::workers::LevelReader> = Arc::new(Store::open(&dir).unwrap());
        // A fine `tau`: Eq. 7 walks blocks on several pages.
        let config = StreamConfig { threads: 1, tau: 0.25, ..Default::default() };
        let mut s = Streamer::with_reader(store.clone(), config, loads);
        if demand {
            let all: Vec<(BlockId, u8)> = store.block_ids().map(|b| (b, 3)).collect();
            s.set_demand(Some(all));
        }
        let mut out = Vec::new();
        let mut decoded = Vec::new();
        // Each camera waited for until its levels are resident (the workers' loads read
        // entries), then held (nothing left to load).
        for c in &cameras {
            assert!(s.wait_until_resident(c, std::time::Duration::from_secs(60)).resident);
            // The first held frame may schedule blocks the moving one did not (Eq. 8's
            // extension follows the motion): their entries are read once, here.
            let f = s.update(c);
            out.push((f.blocks_visible, f.blocks_scheduled, f.cache_hits + f.cache_misses));
            let before = store.index_pages_decoded().unwrap();
            for _ in 0..3 {
                let f = s.update(c);
                out.push((f.blocks_visible, f.blocks_scheduled, f.cache_hits + f.cache_misses));
            }
            decoded.push((before, store.index_pages_decoded().unwrap()));
        }
        (out, decoded)
    };
    for demand in [true, false] {
        let big = Arc::new(Store::open(&dir).unwrap().with_page_cache_bytes(1 << 30).unwrap());
        let small = Arc::new(Store::open(&dir).unwrap().with_page_cache_bytes(1).unwrap());
        let (a, _) = stats_of(big, demand);
        let (b, decoded) = stats_of(small, demand);
        // The same schedules whatever the page cache holds.
        assert_eq!(a, b, "demand {demand}");
        assert!(a.iter().all(|s| s.1 > 0), "the views must schedule blocks: {a:?}");
        // A block's entry is read once (its summary kept, and the whole entry where Eq. 7
        // walks the block): held frames read no page (with a one-page cache, reading entries
        // again would decode pages every frame).
        assert!(decoded.iter().all(|(a, b)| a == b), "demand {demand}: {decoded:?} of {pages}");
    }
}

/// A sample of a block with no resident level reads no index entry: its stand-in height
/// (`StoreTree::block_floor`, through `StoreSource::sample` over an empty streamer) comes from
/// the index's head, and lies at or below the block's least height, on a grid whose block
/// parents are in the head and on one with more blocks a side than the head has levels for.
#[test]
fn a_sample_without_a_resident_level_reads_no_index_page() {
    let deep = deep_store("floor-deep");
    let shallow = paged_store("floor");
    for dir in [&*shallow, &*deep] {
        let (h, whole) = read_index(&std::fs::read(dir.join(INDEX_FILE)).unwrap()).unwrap();
        let store = Arc::new(Store::open(dir).unwrap());
        let tree = StoreTree::new(store.clone(), 8);
        let config = crate::StreamConfig { threads: 1, ..Default::default() };
        let empty = crate::Streamer::new(store.clone(), config);
        let source = crate::StoreSource::new(&tree, &empty);
        let cells = h.block_cells();
        let mut below = 0;
        for (p, e) in whole.iter().enumerate() {
            let b =
                BlockId::new((p / h.blocks_x as usize) as u32, (p % h.blocks_x as usize) as u32);
            // The block's centre sample (inside the grid on every block here).
            let (x, y) = (b.col * cells + cells / 2, b.row * cells + cells / 2);
            let z = source.sample(x, y);
            assert!(z <= e.min, "{dir:?} block {b}: {z} over its least {}", e.min);
            below += usize::from(z < e.min);
        }
        assert_eq!(store.index_pages_decoded(), Some(0), "{dir:?}: an index page decoded");
        // The stand-in is a bound, not the block's own least everywhere (so the check above
        // can tell the two apart).
        assert!(below > 0, "{dir:?}");
    }
}
