//! The bake's table of decimation errors (`decimation.bin`): every block's values are
//! terrain-core's `region_errors` of the store's decoded samples with the grid's clamping
//! rule, bit for bit; a store without the table says `None`; a damaged table, another bake's
//! or another grid's is a typed error naming the file; an exaggerated store scales them; a
//! sharded bake's merge writes the single bake's bytes, and refuses a part's damaged table.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use terrain_core::Georef;
use terrain_core::heightmap::{Heightmap, VoidMask};
use terrain_core::tin::decimation::region_errors;

use crate::{
    BakeConfig, BakeError, DECIMATION_FILE, HeightEncoding, MergeConfig, Shard, Store, StoreError,
    bake, bake_shard, merge,
};

fn scratch(name: &str) -> super::Scratch {
    super::scratch(&format!("terrain-stream-decimation-{name}-"))
}

fn go(_: &crate::BakeProgress) -> ControlFlow<()> {
    ControlFlow::Continue(())
}

/// A rough 300 x 200 grid (blocks of 64 cells: 5 x 4 blocks, the last column 44 samples wide
/// and the last row 8 high) with a patch of voids across a block border.
fn grid() -> Heightmap {
    let (w, h) = (300, 200);
    let mut voids = VoidMask::new(w, h);
    for j in 50..90 {
        for i in 100..140 {
            voids.set(i, j, true);
        }
    }
    let data = (0..w * h)
        .map(|p| {
            let (i, j) = (p % w, p / w);
            let n = (p as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 41;
            500.0 + 150.0 * (i as f32 * 0.05).sin() * (j as f32 * 0.04).cos() + (n % 61) as f32
                - 30.0
                + 0.37 * j as f32
        })
        .collect();
    Heightmap::new(w, h, data, voids, Georef::local(10.0)).unwrap()
}

fn config() -> BakeConfig {
    BakeConfig { k: 6, threads: 2, ..BakeConfig::default() }
}

/// The store's decoded samples at full resolution, the whole grid (row-major, south first).
fn decoded(store: &Store) -> Vec<f32> {
    let h = store.header();
    let (w, hh, k) = (h.width as usize, h.height as usize, h.k);
    let (cells, side) = (1usize << k, (1usize << k) + 1);
    let mut out = vec![f32::NAN; w * hh];
    for id in store.block_ids() {
        let g = store.read_block(id, k).unwrap().grid(k).unwrap();
        let e = store.entry(id).unwrap();
        let (x0, y0) = (id.col as usize * cells, id.row as usize * cells);
        for j in 0..e.valid_h as usize {
            for i in 0..e.valid_w as usize {
                out[(y0 + j) * w + x0 + i] = g[j * side + i];
            }
        }
    }
    assert!(out.iter().all(|z| z.is_finite()), "every sample decoded");
    out
}

/// Every block's errors recomputed as the `tin` method measures a region: `region_errors` of
/// the region's samples (its `2^k + 1` columns and rows clipped to the grid), the strided
/// samples of the whole grid read with its rule (past the last column or row: the last one).
fn recomputed(store: &Store) -> Vec<Vec<f32>> {
    let h = store.header();
    let (w, hh, k) = (h.width as usize, h.height as usize, h.k);
    let cells = 1usize << k;
    let z = decoded(store);
    store
        .block_ids()
        .map(|id| {
            let (i0, j0) = (id.col as usize * cells, id.row as usize * cells);
            let (i1, j1) = ((i0 + cells).min(w - 1), (j0 + cells).min(hh - 1));
            let fine: Vec<f32> =
                (j0..=j1).flat_map(|j| z[j * w + i0..=j * w + i1].iter().copied()).collect();
            let lattice = |s: u32, a0: usize, b0: usize, na: usize, nb: usize| {
                let t = 1usize << s;
                Ok::<_, ()>(
                    (0..na * nb)
                        .map(|p| {
                            let (a, b) = (a0 + (p % na) * t, b0 + (p / na) * t);
                            z[b.min(hh - 1) * w + a.min(w - 1)]
                        })
                        .collect(),
                )
            };
            region_errors(&fine, i1 - i0 + 1, (i0, j0), None, u32::from(k), lattice).unwrap()
        })
        .collect()
}

/// (a) Every block's values are the recomputed ones, bit for bit, in a grid that is not a
/// multiple of the block, with voids (measured as their stored heights), for a lossy and a
/// lossless encoding.
#[test]
fn every_blocks_errors_are_the_regions_of_the_decoded_samples() {
    let dir = scratch("values");
    let hm = grid();
    for (name, encoding) in [("bounded", HeightEncoding::default()), ("f32", HeightEncoding::F32)] {
        let out = dir.join(name);
        bake(&hm, &out, &BakeConfig { encoding, ..config() }, &mut go).unwrap();
        let store = Store::open(&out).unwrap();
        assert_eq!((store.header().blocks_x, store.header().blocks_y), (5, 4));
        let table = store.decimation_errors().unwrap().expect("every bake writes the table");
        assert_eq!(table.strides(), 6);
        let want = recomputed(&store);
        for (id, want) in store.block_ids().zip(&want) {
            let got = table.errors(id).unwrap();
            let bits = |v: &[f32]| v.iter().map(|e| e.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(got), bits(want), "{name}: block {id}");
        }
        // Not all zero: the comparison sees values (coarser strides err more here).
        let last = want.iter().map(|e| e[5]).fold(0f32, f32::max);
        assert!(last > 10.0, "{name}: {last}");
        assert_eq!(table.errors(crate::BlockId::new(4, 0)), None, "outside the grid");
        assert_eq!(table.errors(crate::BlockId::new(0, 5)), None, "outside the grid");
        // The same table from a clone (read once) and from a second open.
        assert!(std::sync::Arc::ptr_eq(
            &table,
            &store.clone().decimation_errors().unwrap().unwrap()
        ));
        assert_eq!(*table, *Store::open(&out).unwrap().decimation_errors().unwrap().unwrap());
    }
}

/// (b), (c) Without the file: `None`. A damaged file (a flipped byte anywhere, cut short),
/// another bake's file or another grid's: [`StoreError::Decimation`] naming the file and
/// saying to bake again, never a panic; the good file back reads again.
#[test]
fn a_missing_damaged_or_foreign_table_is_none_or_a_typed_error() {
    let dir = scratch("faults");
    let hm = grid();
    let out = dir.join("scene");
    bake(&hm, &out, &config(), &mut go).unwrap();
    let path = out.join(DECIMATION_FILE);
    let good = std::fs::read(&path).unwrap();
    assert_eq!(good.len(), 40 + 20 * 6 * 4 + 4, "head, 20 blocks of 6 values, CRC-32");
    let want = Store::open(&out).unwrap().decimation_errors().unwrap().unwrap();
    std::fs::remove_file(&path).unwrap();
    assert_eq!(Store::open(&out).unwrap().decimation_errors().unwrap(), None);
    let refused = |bytes: &[u8]| -> String {
        std::fs::write(&path, bytes).unwrap();
        match Store::open(&out).unwrap().decimation_errors() {
            Err(e @ StoreError::Decimation { .. }) => {
                let msg = e.to_string();
                assert!(
                    msg.contains(DECIMATION_FILE) && msg.contains("bake the store again"),
                    "{msg}"
                );
                msg
            }
            other => panic!("expected a decimation error, got {other:?}"),
        }
    };
    // A flipped bit in the head, a value, the checksum.
    for at in [3, 20, 40, 200, good.len() - 1] {
        let mut bad = good.clone();
        bad[at] ^= 0x10;
        let msg = refused(&bad);
        assert!(msg.contains("checksum"), "byte {at}: {msg}");
    }
    for len in [0, 10, 44, good.len() - 5] {
        refused(&good[..len]);
    }
    // Another bake's table (the same grid with another step): its own checksum holds.
    let other = dir.join("other");
    let step = HeightEncoding::Quantized { step_m: 0.5, offset_m: 0.0 };
    bake(&hm, &other, &BakeConfig { encoding: step, ..config() }, &mut go).unwrap();
    let msg = refused(&std::fs::read(other.join(DECIMATION_FILE)).unwrap());
    assert!(msg.contains("another bake"), "{msg}");
    // This bake's id, but a table of fewer blocks (its checksum made good): another grid's.
    let mut short = good[..good.len() - 4 - 6 * 4].to_vec();
    short[32..40].copy_from_slice(&19u64.to_le_bytes());
    let crc = crate::format::crc32(&short);
    short.extend_from_slice(&crc.to_le_bytes());
    let msg = refused(&short);
    assert!(msg.contains("20 blocks"), "{msg}");
    // The good one back: the same table.
    std::fs::write(&path, &good).unwrap();
    assert_eq!(Store::open(&out).unwrap().decimation_errors().unwrap(), Some(want));
}

/// (d) An exaggerated store's values bound the errors of its heights as it reads them (each
/// scaled and rounded on its own), recomputed from its decoded samples, at every stride of
/// every block, and exceed the base values times the exaggeration by at most the rounding
/// margin (`2 |h|max 2^-23`, a few millimetres here, and the rounding up to an f32), where
/// the values scaled alone fall short of the read heights' own; the plain store's stay as
/// they were; scales compose.
#[test]
fn an_exaggerated_store_scales_its_decimation_errors() {
    let dir = scratch("exaggerated");
    let out = dir.join("scene");
    bake(&grid(), &out, &config(), &mut go).unwrap();
    let plain = Store::open(&out).unwrap();
    let base = plain.decimation_errors().unwrap().unwrap();
    for (store, scale) in [
        (plain.exaggerated(3.0).unwrap(), 3.0),
        (plain.exaggerated(2.0).unwrap().exaggerated(0.25).unwrap(), 0.5),
        (plain.exaggerated(7.3).unwrap(), 7.3),
    ] {
        let scaled = store.decimation_errors().unwrap().unwrap();
        let own = recomputed(&store);
        let mut short = 0;
        // The grid's heights reach at most 760 m before the exaggeration.
        let eps = f64::from(f32::EPSILON);
        let margin = 2.0 * 760.0 * scale * eps;
        for (id, own) in plain.block_ids().zip(&own) {
            let got = scaled.errors(id).unwrap();
            for (s, ((&g, &b), &o)) in got.iter().zip(base.errors(id).unwrap()).zip(own).enumerate()
            {
                assert!(
                    g >= o,
                    "{id} x {scale}, stride 2^{}: {g} below the read heights' {o}",
                    s + 1
                );
                let exact = f64::from(b) * scale;
                short += usize::from((exact as f32) < o);
                assert!(
                    f64::from(g) >= exact && f64::from(g) <= exact + margin + f64::from(g) * eps,
                    "{id} x {scale}, stride 2^{}: {g} against {exact}",
                    s + 1
                );
            }
        }
        // The negative control: the values scaled alone (the rule before the margin) fall
        // short of the read heights' own errors in some blocks (60 and 63 values here).
        println!("x {scale}: {short} values scaled alone fall short of the read heights' own");
        assert!(scale == 0.5 || short > 0, "x {scale}: the control finds no shortfall");
    }
    assert_eq!(plain.decimation_errors().unwrap().unwrap(), base, "the plain store's unchanged");
}

/// Bakes `source` as shards `0..n` into `dir/pK`.
fn parts(source: &Heightmap, dir: &Path, n: u32) -> Vec<PathBuf> {
    (0..n)
        .map(|k| {
            let part = dir.join(format!("p{k}"));
            bake_shard(source, &part, &config(), Shard::new(k, n).unwrap(), "grid", &mut go)
                .unwrap();
            part
        })
        .collect()
}

/// (e) A merge of 1 to 5 shards (5: one shard with no rows) writes the single bake's table,
/// byte for byte; each part holds its rows' table. A part without one (baked before the
/// table existed) gives a store without one; a part's damaged table is refused by name.
#[test]
fn a_merged_store_has_the_single_bakes_table() {
    let dir = scratch("shards");
    let hm = grid();
    let single = dir.join("single");
    bake(&hm, &single, &config(), &mut go).unwrap();
    let want = std::fs::read(single.join(DECIMATION_FILE)).unwrap();
    for n in 1..=5 {
        let d = dir.join(format!("n{n}"));
        let ps = parts(&hm, &d, n);
        for p in &ps {
            assert!(p.join(DECIMATION_FILE).is_file(), "{}", p.display());
        }
        let out = d.join("merged");
        merge(&ps, &out, &MergeConfig::default(), &mut go).unwrap();
        let got = std::fs::read(out.join(DECIMATION_FILE)).unwrap();
        assert!(got == want, "{n} shards: the merged table differs");
    }
    // Negative control: one part's table holds another grid's values (shard 1 of 2 baked
    // from a grid 500 m higher at one sample): the merged table differs.
    let d = dir.join("control");
    let mut changed = hm.clone();
    // Row 199 (block row 3, shard 1's), column 71: between lattice samples at every stride.
    let (w, p) = (changed.width(), 199 * 300 + 71);
    let mut data = changed.data().to_vec();
    data[p] += 500.0;
    changed =
        Heightmap::new(w, changed.height(), data, changed.voids().clone(), Georef::local(10.0))
            .unwrap();
    let mut ps = parts(&hm, &d, 2);
    let other = parts(&changed, &d.join("changed"), 2);
    ps[1] = other[1].clone();
    let out = d.join("merged");
    merge(&ps, &out, &MergeConfig::default(), &mut go).unwrap();
    assert!(std::fs::read(out.join(DECIMATION_FILE)).unwrap() != want, "the control shows");
    // A part without a table: the merged store has none.
    let ps = parts(&hm, &dir.join("old"), 3);
    std::fs::remove_file(ps[1].join(DECIMATION_FILE)).unwrap();
    let out = dir.join("old/merged");
    merge(&ps, &out, &MergeConfig::default(), &mut go).unwrap();
    assert!(!out.join(DECIMATION_FILE).exists());
    assert!(!out.join(format!("{DECIMATION_FILE}.tmp")).exists());
    assert_eq!(Store::open(&out).unwrap().decimation_errors().unwrap(), None);
    // A part's damaged table: refused, naming the part.
    let ps = parts(&hm, &dir.join("damaged"), 3);
    let t = ps[2].join(DECIMATION_FILE);
    let mut bytes = std::fs::read(&t).unwrap();
    bytes[50] ^= 0x01;
    std::fs::write(&t, &bytes).unwrap();
    let e = merge(&ps, &dir.join("damaged/merged"), &MergeConfig::default(), &mut go).unwrap_err();
    assert!(matches!(e, BakeError::BadPart { .. }), "{e}");
    let msg = e.to_string();
    assert!(
        msg.contains("p2") && msg.contains(DECIMATION_FILE) && msg.contains("checksum"),
        "{msg}"
    );
}
