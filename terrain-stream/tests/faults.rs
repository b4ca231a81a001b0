//! Store faults in the user's words: a small baked store is damaged in each way a store can be
//! (a flipped byte, a truncated file, a missing file, a file that is no store block, another
//! store's block), and the runtime reports each fault once, naming the block file, the block,
//! its level and area, the cause, and what is drawn instead (a coarser level, or nothing).

mod common;

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use terrain_core::{Georef, Heightmap};
use terrain_stream::glam::dvec3;
use terrain_stream::{
    BakeConfig, BakeProgress, BlockId, Camera, Fault, Store, StoreError, StreamConfig, Streamer,
    bake,
};

fn go(_: &BakeProgress) -> ControlFlow<()> {
    ControlFlow::Continue(())
}

/// A 97 x 97 grid at 10 m (3 x 3 blocks of 32 cells); `seed` changes the heights.
fn grid(seed: f32) -> Heightmap {
    Heightmap::from_fn(97, 97, Georef::local(10.0), |i, j| {
        100.0 + seed + (i as f32 * 0.21).sin() * 30.0 + (j as f32 * 0.17).cos() * 25.0
    })
    .unwrap()
}

/// `name` in a temporary folder of its own, removed when dropped (also when the test panics).
fn scratch(name: &str) -> common::Scratch {
    let d = common::scratch("terrain-stream-faults-", name);
    std::fs::create_dir_all(&*d).unwrap();
    d
}

/// A store of [`grid`] without its overview (`overview.bin`, which would serve every block's
/// levels 0-4): these tests damage the block files (the overview's own faults are tested in
/// the crate's `tests::store`).
fn baked(dir: &Path, seed: f32) -> PathBuf {
    let out = dir.join(format!("s{seed}"));
    bake(&grid(seed), &out, &BakeConfig { k: 5, ..Default::default() }, &mut go).unwrap();
    std::fs::remove_file(out.join("overview.bin")).unwrap();
    out
}

fn block_file(store: &Path, id: BlockId) -> PathBuf {
    store.join(format!("blocks/r{:05}_c{:05}.tsb", id.row, id.col))
}

/// Looks at the whole grid from the south, close enough that every block needs fine levels.
fn camera() -> Camera {
    Camera::from_yaw_pitch(dvec3(480.0, -250.0, 400.0), 0.0, -35.0).with_clip(1.0, 3000.0)
}

fn config() -> StreamConfig {
    StreamConfig { threads: 1, retry_after_frames: 2, ..Default::default() }
}

/// Every fault of a warm frame (and the loads still in flight).
fn faults_of(s: &mut Streamer) -> Vec<Fault> {
    let mut faults = s.wait_until_resident(&camera(), Duration::from_secs(30)).stats.faults;
    faults.extend(s.finish_loads().faults);
    faults
}

const CENTRE: BlockId = BlockId { row: 1, col: 1 };

/// Damages block (1, 1) of a fresh store with `damage` (given the store folder and the block
/// file) and returns the one fault the runtime reports with its message.
fn one_fault(name: &str, damage: impl FnOnce(&Path, &Path, &Store)) -> (Fault, String, PathBuf) {
    let dir = scratch(name);
    let out = baked(&dir, 0.0);
    let store = Arc::new(Store::open(&out).unwrap());
    let file = block_file(&out, CENTRE);
    damage(&out, &file, &store);
    let mut s = Streamer::new(store, config());
    let mut faults = faults_of(&mut s);
    assert_eq!(faults.len(), 1, "{name}: {faults:?}");
    let f = faults.remove(0);
    let msg = f.to_string();
    assert!(f.first, "{name}: {msg}");
    assert_eq!(f.error.block(), Some(CENTRE), "{name}: {msg}");
    // The file, the block, its level and its area are named.
    assert!(msg.contains(&file.display().to_string()), "{name}: {msg}");
    assert!(msg.contains("block (row 1, col 1)"), "{name}: {msg}");
    assert!(msg.contains(&format!("level {}", f.error.level().unwrap())), "{name}: {msg}");
    assert!(msg.contains("x 320.0..640.0 m, y 320.0..640.0 m"), "{name}: {msg}");
    // Each fault is reported once: the block is retried (every 2 frames here) and fails the
    // same way, and that fault is not new.
    let mut again = Vec::new();
    for _ in 0..6 {
        again.extend(s.update(&camera()).faults);
        again.extend(s.finish_loads().faults);
    }
    assert!(!again.is_empty(), "{name}: the block was not retried");
    assert!(again.iter().all(|f| !f.first && f.error.block() == Some(CENTRE)), "{name}: {again:?}");
    (f, msg, file)
}

/// Flips a byte in the middle of `level`'s payload.
fn flip(file: &Path, store: &Store, level: usize) {
    let le = store.entry(CENTRE).unwrap().levels[level];
    let mut bytes = std::fs::read(file).unwrap();
    bytes[(le.offset + u64::from(le.len) / 2) as usize] ^= 0x41;
    std::fs::write(file, bytes).unwrap();
}

#[test]
fn a_corrupt_level_zero_is_a_checksum_mismatch_and_the_block_is_not_drawn() {
    let (f, msg, _) = one_fault("crc0", |_, file, store| flip(file, store, 0));
    assert!(matches!(f.error, StoreError::Checksum { level: 0, .. }), "{msg}");
    assert!(msg.contains("checksum mismatch"), "{msg}");
    assert_eq!(f.drawn_level(), None);
    assert!(msg.contains("it is not drawn") && !msg.contains("coarser"), "{msg}");
}

#[test]
fn a_corrupt_fine_level_is_drawn_from_the_coarser_level() {
    let (f, msg, _) = one_fault("crc3", |_, file, store| flip(file, store, 3));
    assert!(matches!(f.error, StoreError::Checksum { level: 3, .. }), "{msg}");
    assert_eq!(f.drawn_level(), Some(2), "{msg}");
    assert!(msg.contains("drawn from its coarser level 2 instead"), "{msg}");
}

#[test]
fn a_truncated_block_says_at_which_byte() {
    let mut cut = 0;
    let (f, msg, _) = one_fault("truncated", |_, file, _| {
        let bytes = std::fs::read(file).unwrap();
        cut = bytes.len() / 2;
        std::fs::write(file, &bytes[..cut]).unwrap();
    });
    assert!(matches!(f.error, StoreError::Truncated { .. }), "{msg}");
    assert!(msg.contains(&format!("truncated at byte {cut}")), "{msg}");
    assert!(msg.contains("it is not drawn"), "{msg}");
}

#[test]
fn a_missing_block_file_is_named() {
    let (f, msg, _) = one_fault("missing", |_, file, _| std::fs::remove_file(file).unwrap());
    assert!(matches!(f.error, StoreError::MissingBlock { level: 0, .. }), "{msg}");
    assert!(msg.contains("missing file") && msg.contains("it is not drawn"), "{msg}");
}

#[test]
fn a_file_that_is_no_block_and_another_stores_block_are_told_apart() {
    // Same length, other bytes: not a store block.
    let (f, msg, _) = one_fault("garbage", |_, file, _| {
        let n = std::fs::metadata(file).unwrap().len() as usize;
        std::fs::write(file, vec![0x55u8; n]).unwrap();
    });
    assert!(matches!(f.error, StoreError::NotABlock { .. }), "{msg}");
    assert!(msg.contains("not a store block"), "{msg}");

    // The same block of another bake (other heights), at this file's length.
    let (f, msg, _) = one_fault("foreign", |out, file, _| {
        let other = baked(out.parent().unwrap(), 7.0);
        let n = std::fs::metadata(file).unwrap().len() as usize;
        let mut bytes = std::fs::read(block_file(&other, CENTRE)).unwrap();
        bytes.resize(n, 0);
        std::fs::write(file, bytes).unwrap();
    });
    assert!(matches!(f.error, StoreError::Foreign { .. }), "{msg}");
    assert!(msg.contains("a block of another store"), "{msg}");
}

#[test]
fn every_block_corrupt_leaves_nothing_resident_and_each_fault_is_reported_once() {
    let dir = scratch("all");
    let out = baked(&dir, 0.0);
    let store = Arc::new(Store::open(&out).unwrap());
    let ids: Vec<BlockId> = store.block_ids().collect();
    for &id in &ids {
        let le = store.entry(id).unwrap().levels[0];
        let file = block_file(&out, id);
        let mut bytes = std::fs::read(&file).unwrap();
        bytes[le.offset as usize] ^= 0xFF;
        std::fs::write(&file, bytes).unwrap();
    }
    let mut s = Streamer::new(store, config());
    let faults = faults_of(&mut s);
    let mut blocks: Vec<BlockId> = faults.iter().filter_map(|f| f.error.block()).collect();
    blocks.sort();
    blocks.dedup();
    assert_eq!(blocks.len(), ids.len(), "{faults:?}");
    assert!(faults.iter().all(|f| f.drawn_level().is_none()), "{faults:?}");
    assert!(ids.iter().all(|&id| s.block(id).is_none()));
    let new = faults.iter().filter(|f| f.first).count();
    assert_eq!(new, ids.len(), "one new fault per block: {faults:?}");
}
