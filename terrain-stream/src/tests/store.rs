//! Bake and read back real and synthetic stores: lossless and bounded encodings, determinism,
//! atomic output, typed errors for corrupt, truncated, changed and missing files.

use std::ops::ControlFlow;
use std::path::Path;

use crate::format::{INDEX_VERSION, block_file_name, vertex_index};
use crate::{
    BakeConfig, BakeError, BlockEntry, BlockId, Codec, HeightEncoding, Store, StoreError, bake,
};
use terrain_core::Georef;
use terrain_core::heightmap::Heightmap;

fn scratch(name: &str) -> super::Scratch {
    super::scratch(&format!("terrain-stream-test-{name}-"))
}

fn go(_: &crate::BakeProgress) -> ControlFlow<()> {
    ControlFlow::Continue(())
}

/// A 200 x 150 float grid (not a multiple of blocks: padding on two sides).
fn float_grid() -> Heightmap {
    Heightmap::from_fn(200, 150, Georef::local(30.0), |i, j| {
        let (x, y) = (i as f32 * 0.07, j as f32 * 0.05);
        400.0 + 120.0 * x.sin() * y.cos() + 3.3 * (i as f32 * 1.7).sin() + j as f32 * 0.731
    })
    .unwrap()
}

/// Opens the store in `dir` and reads every block's index entry (every page of a paged index).
fn open_every_entry(dir: &std::path::Path) -> Result<Store, StoreError> {
    let store = Store::open(dir)?;
    for id in store.block_ids() {
        store.try_entry(id)?;
    }
    Ok(store)
}

fn check_heights(store: &Store, hm: &Heightmap, tol: f32) {
    let h = store.header();
    let cells = h.block_cells() as usize;
    for id in store.block_ids() {
        let b = store.read_block(id, h.k).unwrap();
        let e = store.entry(id).unwrap();
        for j in 0..e.valid_h {
            for i in 0..e.valid_w {
                let z = b.height(i, j).unwrap();
                let src = hm.get(
                    id.col as usize * cells + i as usize,
                    id.row as usize * cells + j as usize,
                );
                assert!((z - src).abs() <= tol, "{id} ({i}, {j}): {z} vs {src}");
                if tol == 0.0 {
                    assert_eq!(z.to_bits(), src.to_bits());
                }
            }
        }
        // Every level's grid holds `height` at each of its vertices, bit for bit (the grid is
        // scattered level by level in stored order, `height` searches each vertex's index).
        for l in 0..=h.k {
            let g = b.grid(l).unwrap();
            let (n, d) = ((1u32 << l) + 1, 1u32 << (h.k - l));
            assert_eq!(g.len(), (n * n) as usize);
            for (v, z) in g.iter().enumerate() {
                let (a, c) = (v as u32 % n, v as u32 / n);
                assert_eq!(z.to_bits(), b.height(a * d, c * d).unwrap().to_bits(), "{id} {l}");
            }
        }
        let g2 = b.grid(2).unwrap();
        let d = 1u32 << (h.k - 2);
        assert_eq!(g2[5 + 1], b.height(d, d).unwrap()); // row 1, column 1 of the 5 x 5 grid
        // A block read to level 1 has no finer grid.
        let coarse = store.read_block(id, 1).unwrap();
        assert_eq!(coarse.grid(1), b.grid(1));
        assert_eq!(coarse.grid(2), None);
    }
}

#[test]
fn puget_sound_1k_is_lossless_and_deterministic() {
    // `$TERRAIN_DATA`, else `../shared/data` beside the repository (as every DEM test).
    let data = std::env::var_os("TERRAIN_DATA")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"));
    let path = data.join("puget_sound/ps_height_1k.png");
    let opts = terrain_core::dem::LoadOptions {
        vertical_scale: 0.1,
        spacing_m: 160.0,
        ..Default::default()
    };
    let dem = terrain_core::dem::load(&path, &opts).unwrap();
    let enc = HeightEncoding::for_source(&dem.source, &opts);
    assert_eq!(enc, HeightEncoding::Quantized { step_m: 0.1, offset_m: 0.0 });
    let dir = scratch("puget");
    let cfg = BakeConfig { k: 7, encoding: enc, ..Default::default() };
    let a = bake(&dem.heightmap, &dir.join("a"), &cfg, &mut go).unwrap();
    assert!(a.lossless);
    assert_eq!(a.header.max_error_m, 0.0);
    assert_eq!((a.header.blocks_x, a.header.blocks_y), (8, 8));
    let b = bake(&dem.heightmap, &dir.join("b"), &cfg, &mut go).unwrap();
    assert_eq!(a.store_bytes, b.store_bytes);
    // Same input, same bytes.
    let ids: Vec<BlockId> = Store::open(dir.join("a")).unwrap().block_ids().collect();
    for f in ["index.tsi".to_string()].into_iter().chain(ids.iter().map(|&id| block_file_name(id)))
    {
        assert_eq!(
            std::fs::read(dir.join("a").join(&f)).unwrap(),
            std::fs::read(dir.join("b").join(&f)).unwrap(),
            "{f}"
        );
    }
    let store = Store::open(dir.join("a")).unwrap();
    check_heights(&store, &dem.heightmap, 0.0);
    // The georeference travels with the store.
    assert_eq!(store.header().georef, *dem.heightmap.georef());
    // Non-redundant levels: the store is smaller than the 16-bit raw grid (predictive codec).
    assert!(a.store_bytes < 1025 * 1025 * 2, "{} bytes", a.store_bytes);
}

#[test]
fn float_sources_meet_the_stated_bound_and_padding_is_marked() {
    let hm = float_grid();
    let dir = scratch("float");
    for (name, enc, codec, tol) in [
        ("cm", HeightEncoding::default(), Codec::Predictive, 0.01),
        ("cm-plain", HeightEncoding::default(), Codec::Plain, 0.01),
        ("raw", HeightEncoding::F32, Codec::Predictive, 0.0),
    ] {
        let cfg = BakeConfig { k: 5, encoding: enc, codec, node_levels: 3, ..Default::default() };
        let r = bake(&hm, &dir.join(name), &cfg, &mut go).unwrap();
        assert!(r.header.max_error_m <= tol, "{name}: {}", r.header.max_error_m);
        if name == "cm" {
            assert!(r.header.max_error_m > 0.0 && !r.lossless);
            assert_eq!(r.header.error_bound_m, 0.01);
        }
        let store = Store::open(dir.join(name)).unwrap();
        let h = store.header();
        assert_eq!((h.blocks_x, h.blocks_y), (7, 5));
        // The east column of blocks holds 200 - 6 * 32 = 8 valid columns (padding marked).
        let e = store.entry(BlockId::new(4, 6)).unwrap();
        assert_eq!((e.valid_w, e.valid_h), (8, 150 - 4 * 32));
        // Per-node values: the root's range is the block's and StaticE is monotone (Eq. 3).
        let e = store.entry(BlockId::new(1, 1)).unwrap();
        let root = e.node(0, 0, 0).unwrap();
        assert_eq!((root.min, root.max), (e.min, e.max));
        for l in 1..h.node_levels {
            for j in 0..1u32 << l {
                for i in 0..1u32 << l {
                    let n = e.node(l, i, j).unwrap();
                    let p = e.node(l - 1, i / 2, j / 2).unwrap();
                    assert!(n.static_error <= p.static_error && n.min >= p.min && n.max <= p.max);
                }
            }
        }
        check_heights(&store, &hm, tol as f32);
    }
}

#[test]
fn an_interrupted_bake_leaves_no_valid_store() {
    let hm = float_grid();
    let dir = scratch("cancel");
    let out = dir.join("scene");
    let cfg = BakeConfig { k: 5, ..Default::default() };
    let mut calls = 0;
    let err = bake(&hm, &out, &cfg, &mut |_p: &crate::BakeProgress| {
        calls += 1;
        if calls == 2 { ControlFlow::Break(()) } else { ControlFlow::Continue(()) }
    })
    .unwrap_err();
    assert!(matches!(err, BakeError::Cancelled), "{err}");
    assert!(!out.exists());
    assert!(matches!(Store::open(&out), Err(StoreError::Io { .. })));
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0, "the temporary folder is removed");
    // An existing output is refused unless overwrite is set.
    bake(&hm, &out, &cfg, &mut go).unwrap();
    assert!(matches!(bake(&hm, &out, &cfg, &mut go), Err(BakeError::Exists { .. })));
    bake(&hm, &out, &BakeConfig { overwrite: true, ..cfg }, &mut go).unwrap();
}

#[test]
fn corrupt_truncated_changed_and_missing_files_are_typed_errors() {
    let hm = float_grid();
    let dir = scratch("faults");
    let out = dir.join("scene");
    bake(&hm, &out, &BakeConfig { k: 5, ..Default::default() }, &mut go).unwrap();
    // The block files' own faults: without the overview, which would serve levels 0-4
    // (its faults: `the_overview_serves_the_coarse_levels_and_names_its_faults`).
    std::fs::remove_file(out.join("overview.bin")).unwrap();
    let store = Store::open(&out).unwrap();
    assert_eq!(store.overview_levels(), None);
    let id = BlockId::new(2, 3);
    let path = out.join(block_file_name(id));
    let e = store.entry(id).unwrap().clone();
    let original = std::fs::read(&path).unwrap();

    // A flipped byte inside level 4: that level fails its checksum, coarser ones still read.
    let mut bytes = original.clone();
    bytes[e.levels[4].offset as usize + 3] ^= 0x40;
    std::fs::write(&path, &bytes).unwrap();
    match store.read_level_bytes(id, 4) {
        Err(StoreError::Checksum { block, level, .. }) => assert_eq!((block, level), (id, 4)),
        other => panic!("expected a checksum error, got {other:?}"),
    }
    let msg = store.read_block(id, 5).unwrap_err().to_string();
    assert!(msg.contains("row 2, col 3") && msg.contains("level 4"), "{msg}");
    assert_eq!(store.read_block(id, 3).unwrap().count(), 4);

    // Truncated.
    std::fs::write(&path, &original[..original.len() - 10]).unwrap();
    assert!(matches!(store.read_level_bytes(id, 5), Err(StoreError::Truncated { level: 5, .. })));
    assert!(matches!(store.read_level_bytes(id, 0), Err(StoreError::Truncated { level: 0, .. })));

    // Replaced by another block's file (changed during reading).
    std::fs::copy(out.join(block_file_name(BlockId::new(0, 0))), &path).unwrap();
    let r = store.read_level_bytes(id, 0);
    assert!(
        matches!(
            r,
            Err(StoreError::Foreign { .. }
                | StoreError::Changed { .. }
                | StoreError::Truncated { .. })
        ),
        "{r:?}"
    );

    // Missing.
    std::fs::remove_file(&path).unwrap();
    assert!(
        matches!(store.read_level_bytes(id, 0), Err(StoreError::MissingBlock { block, level: 0, .. }) if block == id)
    );
    std::fs::write(&path, &original).unwrap();
    assert!(store.read_block(id, 5).is_ok());

    // Bad requests.
    assert!(matches!(
        store.read_level_bytes(BlockId::new(99, 0), 0),
        Err(StoreError::BadRequest { .. })
    ));
    assert!(matches!(store.read_level_bytes(id, 9), Err(StoreError::BadRequest { .. })));

    // The index: bad magic, other version, corrupt byte, truncated.
    let ip = out.join("index.tsi");
    let index = std::fs::read(&ip).unwrap();
    let mut b = index.clone();
    b[0] = b'X';
    std::fs::write(&ip, &b).unwrap();
    assert!(matches!(Store::open(&out), Err(StoreError::BadMagic { .. })));
    let mut b = index.clone();
    b[8] = 9;
    std::fs::write(&ip, &b).unwrap();
    assert!(matches!(
        Store::open(&out),
        Err(StoreError::Version { found: 9, expected: INDEX_VERSION, .. })
    ));
    // A store of the previous format (version 1, before the DSS errors): a clear error.
    let mut b = index.clone();
    b[8..12].copy_from_slice(&1u32.to_le_bytes());
    std::fs::write(&ip, &b).unwrap();
    let err = Store::open(&out).unwrap_err();
    assert!(
        matches!(err, StoreError::Version { found: 1, expected: INDEX_VERSION, .. }),
        "{err:?}"
    );
    let msg = err.to_string();
    assert!(
        msg.contains("index.tsi") && msg.contains("version 1") && msg.contains("bake"),
        "{msg}"
    );
    let mut b = index.clone();
    let mid = b.len() / 2;
    b[mid] ^= 1;
    std::fs::write(&ip, &b).unwrap();
    // A paged index opens by its head; the damaged page is refused when read.
    assert!(matches!(open_every_entry(&out), Err(StoreError::IndexPage { .. })));
    std::fs::write(&ip, &index[..index.len() / 3]).unwrap();
    assert!(matches!(Store::open(&out), Err(StoreError::CorruptIndex { .. })));
    // Every truncation and every single-byte corruption of the index is refused (by the
    // opener, or by the page holding the byte), never a panic.
    for cut in (0..index.len()).step_by(97) {
        std::fs::write(&ip, &index[..cut]).unwrap();
        assert!(Store::open(&out).is_err());
    }
    for at in (0..index.len() - 4).step_by(31) {
        let mut b = index.clone();
        b[at] ^= 0x10;
        std::fs::write(&ip, &b).unwrap();
        assert!(open_every_entry(&out).is_err(), "byte {at} flipped");
    }
    std::fs::write(&ip, &index).unwrap();
    assert!(Store::open(&out).is_ok());
}

#[test]
fn the_papers_vertex_order_holds_in_a_store() {
    // Vertex (3, 3) of a 5 x 5 block (k = 2) is level 2, order 12, offset 21 (Qiu 2013 Fig. 4),
    // and a store with k = 2 returns the source height there from level 2's 13th sample.
    let v = vertex_index(2, 3, 3).unwrap();
    assert_eq!((v.level, v.order, v.offset), (2, 12, 21));
    let hm = Heightmap::from_fn(5, 5, Georef::local(1.0), |i, j| (j * 5 + i) as f32).unwrap();
    let dir = scratch("five");
    let cfg = BakeConfig {
        k: 2,
        encoding: HeightEncoding::Quantized { step_m: 1.0, offset_m: 0.0 },
        ..Default::default()
    };
    bake(&hm, &dir.join("s"), &cfg, &mut go).unwrap();
    let store = Store::open(dir.join("s")).unwrap();
    let b = store.read_block(BlockId::new(0, 0), 2).unwrap();
    assert_eq!(b.levels()[2][12], 18); // q = height = 3 * 5 + 3
    assert_eq!(b.height(3, 3), Some(18.0));
    // The linear sequence: levels 0..=2 concatenated, 25 samples.
    let seq: Vec<i32> = b.levels().iter().flat_map(|l| l.iter().copied()).collect();
    assert_eq!(seq.len(), 25);
    assert_eq!(seq[21], 18);
    assert_eq!(&seq[..4], &[0, 4, 20, 24]);
}

#[test]
fn the_index_holds_the_dss_object_errors_of_every_block() {
    use terrain_core::metrics::Region;
    use terrain_core::metrics::dss::{FACTORS, object_errors};
    // Integer heights (lossless), 200 x 150: padded east and north blocks are measured over
    // their valid extent only.
    let hm = Heightmap::from_fn(200, 150, Georef::local(30.0), |i, j| {
        (400.0
            + 120.0 * (i as f32 * 0.07).sin() * (j as f32 * 0.05).cos()
            + ((i * 5 + j * 3) % 7) as f32)
            .round()
    })
    .unwrap();
    let dir = scratch("dss");
    let cfg = BakeConfig {
        k: 5,
        encoding: HeightEncoding::Quantized { step_m: 1.0, offset_m: 0.0 },
        ..Default::default()
    };
    assert!(bake(&hm, &dir.join("s"), &cfg, &mut go).unwrap().lossless);
    let store = Store::open(dir.join("s")).unwrap();
    let cells = store.header().block_cells() as usize;
    let mut nonzero = 0;
    for id in store.block_ids() {
        let e = store.entry(id).unwrap();
        let (x0, y0) = (id.col as usize * cells, id.row as usize * cells);
        let (w, h) = (e.valid_w as usize, e.valid_h as usize);
        let block =
            Heightmap::from_fn(w, h, Georef::local(1.0), |i, j| hm.get(x0 + i, y0 + j)).unwrap();
        let exact = object_errors(&block, Region::new(0, 0, cells));
        let d = e.dss.expect("a default bake writes the DSS errors");
        for f in 0..FACTORS {
            assert_eq!(d.avg[f], exact.avg[f] as f32, "{id} factor {f}");
            assert_eq!(d.max[f], exact.max[f] as f32, "{id} factor {f}");
        }
        // Factor 32 = the block's cells: every sample of a full block is a vertex, no error.
        if (w, h) == (cells + 1, cells + 1) {
            assert_eq!(d.max[15], 0.0, "{id}");
        }
        nonzero += (d.avg[0] > 0.0) as usize;
    }
    assert_eq!(nonzero, store.header().block_count());
    assert!(store.has_dss_errors());
}

#[test]
fn a_bake_without_dss_errors_says_so_and_keeps_everything_else() {
    let hm = Heightmap::from_fn(200, 150, Georef::local(30.0), |i, j| {
        (400.0 + 120.0 * (i as f32 * 0.07).sin() * (j as f32 * 0.05).cos()).round()
    })
    .unwrap();
    let dir = scratch("no_dss");
    let with = BakeConfig {
        k: 5,
        encoding: HeightEncoding::Quantized { step_m: 1.0, offset_m: 0.0 },
        ..Default::default()
    };
    let without = BakeConfig { dss_errors: false, ..with.clone() };
    bake(&hm, &dir.join("with"), &with, &mut go).unwrap();
    bake(&hm, &dir.join("without"), &without, &mut go).unwrap();
    let (a, b) =
        (Store::open(dir.join("with")).unwrap(), Store::open(dir.join("without")).unwrap());
    assert!(a.has_dss_errors());
    assert!(!b.has_dss_errors());
    assert_eq!(a.header().block_count(), b.header().block_count());
    for id in a.block_ids() {
        let (ea, eb) = (a.entry(id).unwrap(), b.entry(id).unwrap());
        assert!(ea.dss.is_some() && eb.dss.is_none(), "{id}");
        // Everything but the DSS errors is the same bake.
        assert_eq!(&BlockEntry { dss: None, ..BlockEntry::clone(&ea) }, &*eb, "{id}");
        for level in 0..a.header().levels() {
            assert_eq!(
                a.read_level_bytes(id, level).unwrap(),
                b.read_level_bytes(id, level).unwrap()
            );
        }
    }
}

#[test]
fn scaled_integer_geotiffs_are_stored_on_their_own_lattice() {
    // GDAL's band scale 0.5 and offset 100 (terrain-core's corpus): heights are half metres
    // from 100 m, which a 1 m lattice would round.
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../terrain-core/tests/data/geotiff/scaled.tif");
    let opts = terrain_core::dem::LoadOptions::default();
    let dem = terrain_core::dem::load(&path, &opts).unwrap();
    let enc = HeightEncoding::for_source(&dem.source, &opts);
    assert_eq!(enc, HeightEncoding::Quantized { step_m: 0.5, offset_m: 100.0 });
    let dir = scratch("scaled");
    let cfg = BakeConfig { k: 4, encoding: enc, ..Default::default() };
    let a = bake(&dem.heightmap, &dir.join("a"), &cfg, &mut go).unwrap();
    assert!(a.lossless, "the valid samples are stored without loss");
    // (The filled voids are off the lattice: rounded to it, within half a step.)
    check_heights(&Store::open(dir.join("a")).unwrap(), &dem.heightmap, 0.25);
    // With a vertical scale on top (feet): its lattice too.
    let feet = terrain_core::dem::LoadOptions { vertical_scale: 0.3048, ..opts };
    let dem = terrain_core::dem::load(&path, &feet).unwrap();
    let enc = HeightEncoding::for_source(&dem.source, &feet);
    assert_eq!(enc, HeightEncoding::Quantized { step_m: 0.5 * 0.3048, offset_m: 100.0 * 0.3048 });
}

/// A store read exaggerated 3 times is the store baked from the heights times 3: the same
/// decoded heights bit for bit (f32 heights scaled in f64, rounded once, as `h * 3.0f32`), and
/// the same index values (minima, maxima, `StaticE`, per-level maxima, the DSS errors) up to
/// f32 rounding of errors computed from scaled heights; a scale that is not positive is
/// refused with a typed error. Negative control: the store read unscaled fails the comparison.
#[test]
fn an_exaggerated_store_reads_as_the_store_of_scaled_heights() {
    let hm = float_grid();
    let tripled =
        Heightmap::from_fn(hm.width(), hm.height(), hm.georef().clone(), |i, j| hm.get(i, j) * 3.0)
            .unwrap();
    let dir = scratch("exaggerated");
    let cfg = BakeConfig { k: 5, encoding: HeightEncoding::F32, ..Default::default() };
    bake(&hm, &dir.join("a"), &cfg, &mut go).unwrap();
    bake(&tripled, &dir.join("b"), &cfg, &mut go).unwrap();
    let plain = Store::open(dir.join("a")).unwrap();
    let scaled = plain.exaggerated(3.0).unwrap();
    let want = Store::open(dir.join("b")).unwrap();
    assert_eq!(scaled.header().vertical_scale, 3.0);
    check_heights(&scaled, &tripled, 0.0);
    // Errors are differences of heights computed in f32: a few units in the last place of the
    // largest height apart.
    let top = want.block_ids().map(|id| want.entry(id).unwrap().max).fold(0.0f32, f32::max);
    let close = |a: f32, b: f32| (a - b).abs() <= 4.0 * f32::EPSILON * top;
    let same_index = |s: &Store| {
        s.block_ids().all(|id| {
            let (a, b) = (s.entry(id).unwrap(), want.entry(id).unwrap());
            let dss = match (&a.dss, &b.dss) {
                (Some(x), Some(y)) => x.avg.iter().zip(&y.avg).all(|(p, q)| close(*p, *q)),
                (x, y) => x.is_none() && y.is_none(),
            };
            a.min == b.min
                && a.max == b.max
                && a.nodes.iter().zip(&b.nodes).all(|(p, q)| {
                    p.min == q.min && p.max == q.max && close(p.static_error, q.static_error)
                })
                && a.level_errors.iter().zip(&b.level_errors).all(|(p, q)| close(*p, *q))
                && dss
        })
    };
    assert!(same_index(&scaled), "the exaggerated index is the scaled store's");
    assert!(!same_index(&plain), "negative control: the unscaled index differs");
    for bad in [0.0, -2.0, f64::NAN, f64::INFINITY] {
        let e = plain.exaggerated(bad).unwrap_err();
        assert!(matches!(e, StoreError::Exaggeration { .. }), "{bad}: {e}");
    }
}

/// Every bake writes `overview.bin`: levels 0-4 of every block in one file, read instead of
/// the block files (the same bytes, checked by the same CRC), so they read with the block
/// files gone; a finer level still needs its block file. A damaged payload is a checksum
/// error naming the overview; a damaged table or an overview of another bake refuses the
/// store at open, saying to remove it; without it the store reads the block files.
#[test]
fn the_overview_serves_the_coarse_levels_and_names_its_faults() {
    let hm = float_grid();
    let dir = scratch("overview");
    let out = dir.join("scene");
    bake(&hm, &out, &BakeConfig { k: 5, ..Default::default() }, &mut go).unwrap();
    let ov = out.join("overview.bin");
    let store = Store::open(&out).unwrap();
    assert_eq!(store.overview_levels(), Some(4));
    let ids = store.block_ids().collect::<Vec<_>>();
    let every = |s: &Store, levels: std::ops::RangeInclusive<u8>| -> Vec<Vec<u8>> {
        ids.iter()
            .flat_map(|&id| levels.clone().map(move |l| s.read_level_bytes(id, l).unwrap()))
            .collect()
    };
    let with = every(&store, 0..=4);
    // Without the block files: levels 0-4 from the overview, level 5 missing.
    let hidden = dir.join("blocks-away");
    std::fs::rename(out.join("blocks"), &hidden).unwrap();
    assert_eq!(every(&Store::open(&out).unwrap(), 0..=4), with);
    assert!(matches!(store.read_level_bytes(ids[0], 5), Err(StoreError::MissingBlock { .. })));
    std::fs::rename(&hidden, out.join("blocks")).unwrap();
    // Without the overview: the block files give the same bytes.
    let bytes = std::fs::read(&ov).unwrap();
    std::fs::remove_file(&ov).unwrap();
    let plain = Store::open(&out).unwrap();
    assert_eq!(plain.overview_levels(), None);
    assert_eq!(every(&plain, 0..=4), with);
    // A flipped payload byte (the last block's level 4 ends the file): a checksum error
    // naming the overview, for that level only.
    let last = *ids.last().unwrap();
    let mut bad = bytes.clone();
    let n = bad.len();
    bad[n - 2] ^= 0x40;
    std::fs::write(&ov, &bad).unwrap();
    let s = Store::open(&out).unwrap();
    match s.read_level_bytes(last, 4) {
        Err(StoreError::Checksum { path, block, level: 4, .. }) => {
            assert_eq!((path, block), (ov.clone(), last));
        }
        other => panic!("expected the overview's checksum error, got {other:?}"),
    }
    assert!(s.read_level_bytes(last, 3).is_ok() && s.read_level_bytes(ids[0], 4).is_ok());
    // A damaged table: the store is refused at open, naming the file and what to do.
    let mut bad = bytes.clone();
    bad[30] ^= 0x01;
    std::fs::write(&ov, &bad).unwrap();
    let err = Store::open(&out).unwrap_err();
    assert!(matches!(err, StoreError::Overview { .. }), "{err}");
    let msg = err.to_string();
    assert!(
        msg.contains("overview.bin") && msg.contains("checksum") && msg.contains("remove it"),
        "{msg}"
    );
    // Another bake's overview (the same grid baked with another step): refused too.
    let other = dir.join("other");
    let cfg = BakeConfig {
        k: 5,
        encoding: HeightEncoding::Quantized { step_m: 0.5, offset_m: 0.0 },
        ..Default::default()
    };
    bake(&hm, &other, &cfg, &mut go).unwrap();
    std::fs::copy(other.join("overview.bin"), &ov).unwrap();
    let msg = Store::open(&out).unwrap_err().to_string();
    assert!(msg.contains("another bake"), "{msg}");
    // The bake's own overview back: the store reads.
    std::fs::write(&ov, &bytes).unwrap();
    assert_eq!(every(&Store::open(&out).unwrap(), 0..=4), with);
}
