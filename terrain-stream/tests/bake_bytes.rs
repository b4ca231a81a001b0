//! The bake's output does not depend on how its rows arrive: a grid baked from rows generated
//! band by band (the synthetic source), from the same grid in memory, and from a raw f32 file
//! read by bands of rows (heights and void flags in one read), with one thread or several, gives
//! the same store, every file byte for byte (geomorph's table, computed from the same bands,
//! included). A negative control (one sample changed) shows the comparison sees a difference.
//! Geomorph's table, written into its file band by band as the pass computes it, has the bytes
//! that the table held whole gave before it was streamed (a pinned checksum); so has the index,
//! whose entries are written as the blocks finish.
//!
//! A sharded bake (`bake_shard` K/N, then `merge`) is the same store too, for N = 1..5, on a
//! generated grid and one with voids (a negative control: one shard of a changed grid shows),
//! and its geomorph table, computed by the shards from their rows and stacked by the merge, is
//! the in-memory table of the whole grid, byte for byte;
//! a merge refuses missing, duplicated, foreign and damaged parts by name; a shard that died
//! is baked again alone, the other parts untouched.

mod common;

use std::collections::BTreeMap;
use std::io::Write;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use terrain_core::dem::{Format, LoadOptions, RawSampleType, RawSpec, RowReader};
use terrain_core::heightmap::Heightmap;
use terrain_core::synth::FractalConfig;
use terrain_stream::{
    BakeConfig, BakeError, HeightSource, MergeConfig, Shard, bake, bake_shard, find_parts, merge,
};

/// `name`, not yet made, in a temporary folder of its own, removed when dropped (also when
/// the test panics).
fn scratch(name: &str) -> common::Scratch {
    common::scratch("terrain-stream-bytes-", name)
}

/// Every file of a store folder (relative path -> bytes).
fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(dir).unwrap().to_string_lossy().into_owned();
                out.insert(rel, std::fs::read(&p).unwrap());
            }
        }
    }
    out
}

fn bake_dir(source: &dyn HeightSource, name: &str, threads: usize) -> common::Scratch {
    let out = scratch(name);
    let cfg = BakeConfig { k: 6, threads, geomip_patch_cells: Some(16), ..BakeConfig::default() };
    bake(source, &out, &cfg, &mut |_| ControlFlow::Continue(())).unwrap();
    out
}

/// The first file that differs, or `None`.
fn first_difference(a: &Path, b: &Path) -> Option<String> {
    let (fa, fb) = (files(a), files(b));
    if fa.keys().ne(fb.keys()) {
        return Some(format!("file names differ: {:?} vs {:?}", fa.keys(), fb.keys()));
    }
    fa.iter().find(|(name, bytes)| fb[*name] != **bytes).map(|(name, _)| name.clone())
}

/// The grid's rows into a headerless f32 file, north row first (the raw layout).
fn write_raw(hm: &Heightmap, path: &Path) {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let w = hm.width();
    for j in (0..hm.height()).rev() {
        for z in &hm.data()[j * w..(j + 1) * w] {
            f.write_all(&z.to_le_bytes()).unwrap();
        }
    }
    f.flush().unwrap();
}

#[test]
fn a_bake_is_the_same_bytes_whatever_way_its_rows_arrive() {
    // Not a multiple of the 64-cell blocks either way: padded east and north blocks.
    let synth = FractalConfig::with_size(301, 203, 10.0);
    let hm = synth.to_heightmap().unwrap();
    let generated = bake_dir(&synth, "generated", 2);
    assert!(files(&generated).len() > 10, "a store of several block files");

    let in_memory = bake_dir(&hm, "memory", 1);
    assert_eq!(first_difference(&generated, &in_memory), None, "generated vs in memory");

    let raw = scratch("raw-file");
    std::fs::create_dir_all(&raw).unwrap();
    let raw = raw.join("grid.f32");
    write_raw(&hm, &raw);
    let options = LoadOptions {
        format: Some(Format::Raw),
        raw: Some(RawSpec { width: 301, height: 203, sample: RawSampleType::F32 }),
        spacing_m: 10.0,
        ..LoadOptions::default()
    };
    let rows = RowReader::open(&raw, &options).unwrap();
    let from_file = bake_dir(&rows, "file", 3);
    assert_eq!(first_difference(&generated, &from_file), None, "generated vs raw file");

    // Negative control: one sample 5 m higher changes a block file.
    let mut data = hm.data().to_vec();
    data[150 * 301 + 77] += 5.0;
    let changed = Heightmap::new(301, 203, data, hm.voids().clone(), hm.georef().clone()).unwrap();
    let other = bake_dir(&changed, "changed", 2);
    let diff = first_difference(&generated, &other).expect("a changed sample changes the store");
    assert!(diff.contains("blocks") || diff.contains("index"), "{diff}");
}

#[test]
fn the_geomorph_table_written_band_by_band_has_the_pinned_bytes() {
    // The bytes of the table held whole and encoded at the end (main before the table was
    // streamed: `terrain bake --synthetic 301 --no-dss --no-pvs --no-roughness
    // --no-calibration`, 256-cell blocks: 2 bands); here 64-cell blocks: 5 bands.
    let synth = FractalConfig::with_size(301, 301, 10.0);
    let out = bake_dir(&synth, "geomip-pinned", 2);
    let table = std::fs::read(out.join(terrain_stream::GEOMIP_FILE)).unwrap();
    // Re-pinned on branch `geo13c` (was `(14480, 0x8601_6b9b)`, the CRC-32 of a version-1
    // file before its checksum): version 2 adds two header fields and a tail (a CRC-32 per
    // page of entries, the pyramid's summary level, the CRC-32 of header and tail) so that it
    // is read by pages; its entries are the version-1 file's, byte for byte (the version-1
    // header rebuilt around them has the old pinned CRC-32, below). FNV-1a, as the index.
    const PINNED: u64 = 0x13f9_0596_ef9d_9e40;
    let crc =
        |b: &[u8]| terrain_core::checksum::fnv1a_update(terrain_core::checksum::FNV1A_START, b);
    assert_eq!((table.len(), crc(&table)), (14716, PINNED), "geomip.bin's bytes changed");
    let mut v1 = b"TGMP".to_vec();
    v1.extend_from_slice(&1u32.to_le_bytes());
    v1.extend_from_slice(&table[8..36]);
    let entries = &table[44..44 + 19 * 19 * 40];
    let v1_crc = terrain_core::checksum::crc32_update(terrain_core::checksum::crc32(&v1), entries);
    assert_eq!(v1_crc, 0x8601_6b9b, "the entries are version 1's");
    // Negative control: one height changes the table's checksum.
    let hm = synth.to_heightmap().unwrap();
    let mut data = hm.data().to_vec();
    data[150 * 301 + 77] += 5.0;
    let changed = Heightmap::new(301, 301, data, hm.voids().clone(), hm.georef().clone()).unwrap();
    let other = bake_dir(&changed, "geomip-pinned-changed", 2);
    let changed = std::fs::read(other.join(terrain_stream::GEOMIP_FILE)).unwrap();
    assert_ne!(crc(&changed), PINNED);
}

#[test]
fn the_index_written_entry_by_entry_has_the_pinned_bytes() {
    const PINNED: u64 = 0xfbdf_a49b_fb6c_631e;
    // The bytes of the index built whole in memory and written at the end (main before the
    // entries were streamed, `terrain bake --synthetic 301 --block-k 6 --no-pvs --no-roughness
    // --no-calibration`: this config, its geomip.bin the pinned one above). The entries now go
    // to disk as each band's blocks finish, the header last. Re-pinned on branch `deflate18`
    // (was `0x98b5_745c`, same length): level payloads are packed by the codec's own
    // literal-only Deflate block (and libdeflate where matches pay) instead of miniz_oxide,
    // so the index's per-level payload lengths and CRC-32s changed; the decoded
    // heights of every block are those of the stores main's miniz build writes (checked
    // store against store, bench/ooc/README.md, "Block payloads by libdeflate"). Re-pinned on
    // branch `paged18` (was `(138458, 0xf594_95cc)`, a CRC-32): index version 4 pages the same entries
    // (a head with the block pyramid, a CRC-32 per page), so the file changed by format only;
    // its entries decode to the version-3 entries (`src/tests/pages.rs`). Its bytes are
    // pinned by FNV-1a, not CRC-32: every piece of a version-4 index (the head, each page)
    // ends with its own CRC-32, so a CRC-32 over the whole file is the same for every index
    // of one length (CRC-32's residue) and would not see a changed byte.
    let synth = FractalConfig::with_size(301, 301, 10.0);
    let out = bake_dir(&synth, "index-pinned", 2);
    let index = std::fs::read(out.join(terrain_stream::INDEX_FILE)).unwrap();
    let crc =
        |b: &[u8]| terrain_core::checksum::fnv1a_update(terrain_core::checksum::FNV1A_START, b);
    assert_eq!((index.len(), crc(&index)), (139248, PINNED), "index.tsi's bytes changed");
    // Negative control: one height changes the index (a block's levels' checksums and range).
    let hm = synth.to_heightmap().unwrap();
    let mut data = hm.data().to_vec();
    data[150 * 301 + 77] += 5.0;
    let changed = Heightmap::new(301, 301, data, hm.voids().clone(), hm.georef().clone()).unwrap();
    let other = bake_dir(&changed, "index-pinned-changed", 2);
    let changed = std::fs::read(other.join(terrain_stream::INDEX_FILE)).unwrap();
    assert_ne!(crc(&changed), PINNED);
}

// --- Sharded bakes: parts merged into the same bytes ------------------------------------------

const SHARD_SOURCE: &str = "test grid";

fn cfg() -> BakeConfig {
    BakeConfig { k: 6, threads: 2, geomip_patch_cells: Some(16), ..BakeConfig::default() }
}

/// Bakes shards `which` of `n` into `dir/pK`, returning their folders.
fn bake_parts(source: &dyn HeightSource, dir: &Path, n: u32, which: &[u32]) -> Vec<PathBuf> {
    which
        .iter()
        .map(|&k| {
            let part = dir.join(format!("p{k}"));
            let shard = Shard::new(k, n).unwrap();
            bake_shard(source, &part, &cfg(), shard, SHARD_SOURCE, &mut |_| {
                ControlFlow::Continue(())
            })
            .unwrap();
            part
        })
        .collect()
}

fn merge_into(parts: &[PathBuf], out: &Path) -> Result<terrain_stream::BakeReport, BakeError> {
    let config = MergeConfig {
        source_id: Some(SHARD_SOURCE.into()),
        bake: Some(cfg()),
        ..MergeConfig::default()
    };
    merge(parts, out, &config, &mut |_| ControlFlow::Continue(()))
}

/// A 301 x 203 grid (padded east and north blocks) with a void rectangle across a block edge.
fn grid_with_voids() -> Heightmap {
    let hm = FractalConfig::with_size(301, 203, 10.0).to_heightmap().unwrap();
    let mut voids = terrain_core::heightmap::VoidMask::new(301, 203);
    for j in 50..90 {
        for i in 40..150 {
            voids.set(i, j, true);
        }
    }
    Heightmap::new(301, 203, hm.data().to_vec(), voids, hm.georef().clone()).unwrap()
}

#[test]
fn a_merged_store_is_the_bytes_of_a_single_bake() {
    let synth = FractalConfig::with_size(301, 203, 10.0);
    let voids = grid_with_voids();
    let hm = synth.to_heightmap().unwrap();
    let sources: [(&str, &dyn HeightSource, &Heightmap); 2] =
        [("generated", &synth, &hm), ("voids", &voids, &voids)];
    for (name, source, grid) in sources {
        let single = scratch(&format!("single-{name}"));
        bake(source, &single, &cfg(), &mut |_| ControlFlow::Continue(())).unwrap();
        // Geomorph's table from the bake's bands is the whole grid's, computed in memory.
        let table = std::fs::read(single.join(terrain_stream::GEOMIP_FILE)).unwrap();
        let whole = terrain_core::lod::GeomipTable::new(grid, 16).encode(grid);
        assert!(table == whole, "{name}: geomip.bin is not the in-memory table");
        // 4 block rows: N = 4 is one row a shard, N = 5 leaves a shard empty.
        for n in 1..=5u32 {
            let dir = scratch(&format!("shards-{name}-{n}"));
            let parts = bake_parts(source, &dir, n, &(0..n).collect::<Vec<_>>());
            let out = dir.join("merged");
            // Given in reverse: the merge orders the parts by shard.
            let reversed: Vec<PathBuf> = parts.iter().rev().cloned().collect();
            merge_into(&reversed, &out).unwrap();
            assert_eq!(first_difference(&single, &out), None, "{name}, {n} shards");
            // A folder of parts is found whole.
            assert_eq!(find_parts(&dir).unwrap(), parts, "{name}, {n} shards");
        }
    }

    // Negative control: shard 1 of 2 baked from a grid with one sample 5 m higher (and the
    // same source id, so the merge cannot tell) gives a store that differs from the single bake.
    let hm = synth.to_heightmap().unwrap();
    let mut data = hm.data().to_vec();
    data[150 * 301 + 77] += 5.0;
    let changed = Heightmap::new(301, 203, data, hm.voids().clone(), hm.georef().clone()).unwrap();
    let single = scratch("single-control");
    bake(&synth, &single, &cfg(), &mut |_| ControlFlow::Continue(())).unwrap();
    let dir = scratch("shards-control");
    let mut parts = bake_parts(&synth, &dir, 2, &[0]);
    let other = scratch("shards-control-changed");
    parts.extend(bake_parts(&changed, &other, 2, &[1]));
    merge_into(&parts, &dir.join("merged")).unwrap();
    let diff = first_difference(&single, &dir.join("merged")).expect("a changed sample shows");
    assert!(diff.contains("blocks") || diff.contains("index"), "{diff}");
}

/// Every file of a folder with its modification time, to show a folder was left alone.
fn snapshot(dir: &Path) -> Vec<(String, Vec<u8>, std::time::SystemTime)> {
    files(dir)
        .into_iter()
        .map(|(name, bytes)| {
            let t = std::fs::metadata(dir.join(&name)).unwrap().modified().unwrap();
            (name, bytes, t)
        })
        .collect()
}

#[test]
fn a_merge_refuses_missing_duplicated_and_foreign_parts_by_name() {
    let synth = FractalConfig::with_size(301, 203, 10.0);
    let dir = scratch("refusals");
    let parts = bake_parts(&synth, &dir, 3, &[0, 1, 2]);
    let out = dir.join("merged");
    let err = |parts: &[PathBuf]| merge_into(parts, &out).unwrap_err().to_string();

    let e = err(&[parts[0].clone(), parts[2].clone()]);
    assert!(e.contains("shard 1/3 missing"), "{e}");
    let e = err(&[parts[0].clone(), parts[1].clone(), parts[1].clone(), parts[2].clone()]);
    assert!(e.contains("shard 1/3 is given twice") && e.contains("p1"), "{e}");

    // Another source (its id), other options, another shard count: named by their folder.
    let foreign = scratch("refusals-foreign");
    let shard = Shard::new(1, 3).unwrap();
    let go = &mut |_: &_| ControlFlow::Continue(());
    let other_dem = foreign.join("other-dem");
    bake_shard(&synth, &other_dem, &cfg(), shard, "another DEM", go).unwrap();
    let e = err(&[parts[0].clone(), other_dem.clone(), parts[2].clone()]);
    assert!(e.contains("other-dem") && e.contains("another source"), "{e}");
    let other_opts = foreign.join("other-options");
    let no_dss = BakeConfig { dss_errors: false, ..cfg() };
    bake_shard(&synth, &other_opts, &no_dss, shard, SHARD_SOURCE, go).unwrap();
    let e = err(&[parts[0].clone(), other_opts.clone(), parts[2].clone()]);
    assert!(e.contains("other-options") && e.contains("other options"), "{e}");
    let other_n = foreign.join("other-n");
    bake_shard(&synth, &other_n, &cfg(), Shard::new(1, 2).unwrap(), SHARD_SOURCE, go).unwrap();
    let e = err(&[parts[0].clone(), other_n, parts[2].clone()]);
    assert!(e.contains("other-n") && e.contains("2-shard"), "{e}");
    // A part whose block file was damaged after it was published.
    let damaged = foreign.join("damaged");
    bake_shard(&synth, &damaged, &cfg(), shard, SHARD_SOURCE, go).unwrap();
    let block = std::fs::read_dir(damaged.join("blocks")).unwrap().next().unwrap().unwrap().path();
    let mut bytes = std::fs::read(&block).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0x55;
    std::fs::write(&block, bytes).unwrap();
    let e = err(&[parts[0].clone(), damaged, parts[2].clone()]);
    assert!(e.contains("damaged") && e.contains("checksum"), "{e}");
    // A part whose part file was damaged in one of its block entries: its checksum says so
    // before the entry is read.
    let damaged_index = foreign.join("damaged-index");
    bake_shard(&synth, &damaged_index, &cfg(), shard, SHARD_SOURCE, go).unwrap();
    let file = damaged_index.join(terrain_stream::PART_FILE);
    let mut bytes = std::fs::read(&file).unwrap();
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0x55;
    std::fs::write(&file, bytes).unwrap();
    let e = err(&[parts[0].clone(), damaged_index, parts[2].clone()]);
    assert!(e.contains("damaged-index") && e.contains("checksum mismatch"), "{e}");
    // Nothing was published by the refused merges, and a bad `K/N` is refused.
    assert!(!out.exists());
    assert!("3/3".parse::<Shard>().is_err() && "1-3".parse::<Shard>().is_err());
    assert_eq!("2/3".parse::<Shard>().unwrap(), Shard::new(2, 3).unwrap());
}

#[test]
fn a_dead_shard_is_baked_again_alone() {
    let synth = FractalConfig::with_size(301, 203, 10.0);
    let single = scratch("dead-single");
    bake(&synth, &single, &cfg(), &mut |_| ControlFlow::Continue(())).unwrap();
    let dir = scratch("dead");
    let parts = bake_parts(&synth, &dir, 3, &[0, 2]);
    // Shard 1 dies: cancelled after its first row, it publishes nothing; a killed process
    // leaves its half-written `.p1.part` folder, which the merge skips.
    let p1 = dir.join("p1");
    let died =
        bake_shard(&synth, &p1, &cfg(), Shard::new(1, 3).unwrap(), SHARD_SOURCE, &mut |_| {
            ControlFlow::Break(())
        });
    assert!(matches!(died, Err(BakeError::Cancelled)), "{died:?}");
    assert!(!p1.exists());
    std::fs::create_dir_all(dir.join(".p1.part/blocks")).unwrap();
    std::fs::write(dir.join(".p1.part/blocks/r00001_c00000.tsb"), b"half").unwrap();
    let found = find_parts(&dir).unwrap();
    assert_eq!(found, parts);
    let e = merge_into(&found, &dir.join("merged")).unwrap_err().to_string();
    assert!(e.contains("shard 1/3 missing"), "{e}");

    let before: Vec<_> = parts.iter().map(|p| snapshot(p)).collect();
    std::thread::sleep(std::time::Duration::from_millis(20));
    bake_parts(&synth, &dir, 3, &[1]);
    assert!(!dir.join(".p1.part").exists(), "the re-run replaced the dead shard's folder");
    let after: Vec<_> = parts.iter().map(|p| snapshot(p)).collect();
    assert!(before == after, "shards 0 and 2 were not touched");
    merge_into(&find_parts(&dir).unwrap(), &dir.join("merged")).unwrap();
    assert_eq!(first_difference(&single, &dir.join("merged")), None);
    // The parts are only read by a merge: merging again into another folder works.
    merge_into(&find_parts(&dir).unwrap(), &dir.join("merged-again")).unwrap();
    assert_eq!(first_difference(&single, &dir.join("merged-again")), None);
}
