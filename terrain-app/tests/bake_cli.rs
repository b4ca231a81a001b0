//! End-to-end tests of `terrain bake`: an SRTM .hgt baked losslessly and read back with
//! `terrain_stream::Store` bit-exactly, `--synthetic`, refusal of an existing output, and a
//! bad input file named in the error with no store left behind.

mod common;

use std::path::Path;
use std::process::Output;

use terrain_core::dem::{LoadOptions, load};
use terrain_stream::{BlockId, Store};

use common::{data, terrain};

fn scratch(name: &str) -> common::Scratch {
    common::scratch("bake-cli", name)
}

fn ok(out: &Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "terrain bake failed: {err}");
    assert!(!err.contains("panicked"), "{err}");
    // Not a terminal (a pipe): progress as plain lines, never carriage returns in a log.
    assert!(!err.contains('\r'), "carriage returns in a non-terminal log: {err:?}");
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn an_hgt_bakes_losslessly_and_reads_back_bit_exact() {
    let hgt = data("srtm/N42E001.hgt");
    let dir = scratch("hgt");
    let out = dir.join("n42");
    let stdout = ok(&terrain(&[
        "bake",
        s(&hgt),
        "-o",
        s(&out),
        "--block-k",
        "8",
        "--threads",
        "2",
        "--no-dss",
        "--no-pvs",
    ]));
    assert!(stdout.contains("lossless") && stdout.contains("1201 x 1201"), "{stdout}");
    // `terrain info` describes the store (a folder), in text and JSON.
    let info = ok(&terrain(&["info", s(&out)]));
    assert!(
        info.contains("a baked block store")
            && info.contains("1201 x 1201")
            && info.contains("lossless"),
        "{info}"
    );
    let json: serde_json::Value =
        serde_json::from_str(&ok(&terrain(&["info", s(&out), "--json"]))).unwrap();
    assert_eq!(json["blocks"], serde_json::json!([5, 5]), "{json}");
    // Storage per level (the out-of-core paper's Table 1): Eq. 1-2's new vertices per level
    // times the 25 blocks, every block vertex once over levels 0..=8, and the levels' stored
    // bytes within the store's.
    let levels = json["levels"].as_array().expect("levels");
    assert_eq!(levels.len(), 9, "{json}");
    let mut vertices = 0;
    let mut disk = 0;
    for (n, l) in levels.iter().enumerate() {
        let side = |n: u32| (1u64 << n) + 1;
        let new = side(n as u32).pow(2) - if n == 0 { 0 } else { side(n as u32 - 1).pow(2) };
        assert_eq!(l["vertices"].as_u64(), Some(25 * new), "level {n}: {l}");
        assert_eq!(l["decoded_bytes"].as_u64(), Some(25 * new * 4), "level {n}: {l}");
        vertices += l["vertices"].as_u64().unwrap();
        disk += l["disk_bytes"].as_u64().unwrap();
    }
    assert_eq!(vertices, 25 * 257 * 257);
    assert!(disk > 0 && disk < json["bytes"].as_u64().unwrap(), "{disk} {json}");
    assert!(info.contains("levels       level: new vertices"), "{info}");

    let dem = load(&hgt, &LoadOptions::default()).unwrap();
    let hm = &dem.heightmap;
    let store = Store::open(&out).unwrap();
    let h = store.header().clone();
    assert_eq!((h.width, h.height, h.k), (1201, 1201, 8));
    assert_eq!((h.max_error_m, h.error_bound_m), (0.0, 0.0), "integer heights are lossless");
    assert_eq!(h.georef, *hm.georef());
    // 1200 cells in blocks of 256: 5 x 5 blocks, the east column and north row partly padding.
    assert_eq!((h.blocks_x, h.blocks_y), (5, 5));
    let cells = h.block_cells() as usize;
    let mut compared = 0usize;
    for id in store.block_ids() {
        let e = store.entry(id).unwrap();
        let edge = |n: u32| if n == 4 { 1201 - 4 * 256 } else { 257 };
        assert_eq!((e.valid_w, e.valid_h), (edge(id.col), edge(id.row)), "{id}: padding");
        let b = store.read_block(id, h.k).unwrap();
        for j in 0..h.block_side() {
            for i in 0..h.block_side() {
                let z = b.height(i, j).unwrap();
                // Padding repeats the last valid column and row.
                let si = id.col as usize * cells + (i.min(e.valid_w - 1)) as usize;
                let sj = id.row as usize * cells + (j.min(e.valid_h - 1)) as usize;
                let src = hm.get(si, sj);
                if hm.voids().get(si, sj) {
                    assert!((z - src).abs() as f64 <= h.max_void_error_m + 1e-6, "{id}");
                } else {
                    assert_eq!(z.to_bits(), src.to_bits(), "{id} ({i}, {j}): {z} vs {src}");
                }
                compared += 1;
            }
        }
    }
    assert_eq!(compared, 25 * 257 * 257);
    // A block's coarse level is the finest grid subsampled.
    let b = store.read_block(BlockId::new(2, 3), 2).unwrap();
    assert_eq!(b.grid(2).unwrap()[6], hm.get(3 * 256 + 64, 2 * 256 + 64));
}

#[test]
fn synthetic_bakes_and_an_existing_output_is_refused() {
    let dir = scratch("synth");
    let out = dir.join("synth");
    let args = [
        "bake",
        "--synthetic",
        "257",
        "-o",
        s(&out),
        "--block-k",
        "6",
        "--threads",
        "2",
        "--no-pvs",
    ];
    let stdout = ok(&terrain(&args));
    assert!(stdout.contains("257 x 257") && stdout.contains("4 x 4 blocks"), "{stdout}");
    let store = Store::open(&out).unwrap();
    assert_eq!((store.header().width, store.header().blocks_x), (257, 4));
    // The float fractal is stored within the default 1 cm bound.
    assert!(store.header().max_error_m <= 0.01 && store.header().max_error_m > 0.0);
    assert_eq!(store.read_block(BlockId::new(3, 3), 6).unwrap().count(), 7);
    let index = std::fs::read(out.join("index.tsi")).unwrap();

    // Again without --overwrite: refused, the error names the output, the store is untouched.
    let again = terrain(&args);
    assert!(!again.status.success());
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(err.contains(s(&out)) && err.contains("already exists"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(std::fs::read(out.join("index.tsi")).unwrap(), index);
    // With --overwrite: replaced (the same bytes: the bake is deterministic).
    let mut over = args.to_vec();
    over.push("--overwrite");
    ok(&terrain(&over));
    assert_eq!(std::fs::read(out.join("index.tsi")).unwrap(), index);
}

#[test]
fn a_bad_input_is_named_and_leaves_no_store() {
    let dir = scratch("bad");
    let text = dir.join("notes.txt");
    std::fs::write(&text, b"this is not a DEM\n").unwrap();
    let out = dir.join("store");
    let r = terrain(&["bake", s(&text), "-o", s(&out)]);
    assert!(!r.status.success());
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("notes.txt"), "the error does not name the input: {err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(!out.exists(), "a store was left behind");
    let left: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left, vec![std::ffi::OsString::from("notes.txt")], "debris: {left:?}");
}

/// `--stream` reads a real GeoTIFF (tiled, with voids) by bands of rows: the store holds the
/// file's samples bit-exactly wherever they are valid, the same as the whole-file bake, and
/// the void flags agree; a PNG cannot be streamed and says so.
#[test]
fn a_streamed_bake_equals_the_whole_file_bake_at_valid_samples() {
    let tif = data("srtm/mt_rainier_90m.tif");
    let dir = scratch("stream");
    let (whole, rows) = (dir.join("whole"), dir.join("rows"));
    ok(&terrain(&["bake", s(&tif), "-o", s(&whole), "--threads", "2", "--no-dss", "--no-pvs"]));
    let stderr = {
        let out =
            terrain(&["bake", s(&tif), "-o", s(&rows), "--threads", "2", "--stream", "--no-pvs"]);
        ok(&out);
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    assert!(stderr.contains("read by bands of rows"), "{stderr}");
    let dem = load(&tif, &LoadOptions::default()).unwrap();
    let hm = &dem.heightmap;
    assert!(hm.voids().count() > 0);
    let (a, b) = (Store::open(&whole).unwrap(), Store::open(&rows).unwrap());
    let h = a.header().clone();
    let same = terrain_stream::Header { bake_id: h.bake_id, ..b.header().clone() };
    assert_eq!(h, same, "same header but for the bake id");
    let cells = h.block_cells() as usize;
    let (mut valid, mut void) = (0usize, 0usize);
    for id in a.block_ids() {
        let e = a.entry(id).unwrap();
        let (ba, bb) = (a.read_block(id, h.k).unwrap(), b.read_block(id, h.k).unwrap());
        for j in 0..e.valid_h {
            for i in 0..e.valid_w {
                let (si, sj) =
                    (id.col as usize * cells + i as usize, id.row as usize * cells + j as usize);
                let (za, zb) = (ba.height(i, j).unwrap(), bb.height(i, j).unwrap());
                if hm.voids().get(si, sj) {
                    assert!(zb.is_finite());
                    void += 1;
                } else {
                    assert_eq!(za.to_bits(), zb.to_bits(), "{id} ({i}, {j})");
                    assert_eq!(zb, hm.get(si, sj));
                    valid += 1;
                }
            }
        }
    }
    assert!(valid > 1_000_000 && void > 0, "{valid} valid, {void} void samples compared");
    // The grid was never in memory: geomorph's table comes from the store's blocks; it is
    // tied to the grid and to its 16-cell patches.
    let table = std::fs::read(rows.join("geomip.bin")).expect("geomip.bin from the blocks");
    let want = terrain_core::lod::GeomipFor {
        width: h.width as u32,
        height: h.height as u32,
        patch_cells: 16,
        heights_crc: None,
    };
    let t = terrain_core::lod::GeomipTable::decode(&table, &want).unwrap();
    assert!(t.level_error(10, 10, 4) > 0.0);
    let out = terrain(&[
        "bake",
        s(&data("puget_sound/ps_height_1k.png")),
        "-o",
        s(&dir.join("png")),
        "--stream",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("ps_height_1k.png") && err.contains("streamed"),
        "{err}"
    );
    assert!(!dir.join("png").exists());
}

/// Runs a small synthetic bake into `out` with `extra` arguments.
fn bake_synthetic(out: &Path, extra: &[&str]) -> Output {
    let mut args =
        vec!["bake", "--synthetic", "129", "-o", s(out), "--block-k", "5", "--no-pvs", "--no-dss"];
    args.extend(extra);
    terrain(&args)
}

/// `--overwrite` replaces only a store: a folder of the user's files and a regular file are
/// refused before any work (no progress shown), named, left as they were, and no `.NAME.part`
/// folder is left behind (issue 15: both were lost or damaged).
#[test]
fn overwrite_replaces_only_a_store_and_refuses_before_working() {
    let dir = scratch("guard");
    let mine = dir.join("photos");
    std::fs::create_dir_all(&mine).unwrap();
    std::fs::write(mine.join("holiday.txt"), b"mine").unwrap();
    let notes = dir.join("notes.txt");
    std::fs::write(&notes, b"also mine").unwrap();
    for (out, what) in [(&mine, "not a store"), (&notes, "is a file")] {
        for extra in [&["--overwrite"][..], &[][..]] {
            let r = bake_synthetic(out, extra);
            let err = String::from_utf8_lossy(&r.stderr);
            assert!(!r.status.success(), "{} {extra:?} was baked over", out.display());
            assert!(err.contains(s(out)) && err.contains(what), "{extra:?}: {err}");
            assert!(!err.contains("blocks,"), "the bake ran before refusing: {err}");
            assert!(!err.contains("panicked"), "{err}");
        }
    }
    assert_eq!(std::fs::read(mine.join("holiday.txt")).unwrap(), b"mine");
    assert_eq!(std::fs::read(&notes).unwrap(), b"also mine");
    let mut left: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    assert_eq!(left, ["notes.txt", "photos"], "something was left behind");

    // A store is replaced; an empty folder is baked into.
    let store = dir.join("store");
    ok(&bake_synthetic(&store, &[]));
    ok(&bake_synthetic(&store, &["--overwrite"]));
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    ok(&bake_synthetic(&empty, &[]));
    assert!(Store::open(&empty).is_ok());
}

/// The `.NAME.part` folder a killed bake leaves is removed by the next bake of that output.
#[test]
fn a_killed_bakes_part_folder_is_removed_by_the_next_bake() {
    let dir = scratch("part");
    let out = dir.join("scene");
    let part = dir.join(".scene.part");
    std::fs::create_dir_all(part.join("blocks")).unwrap();
    std::fs::write(part.join("blocks/r0_c0.tsb"), b"half a block").unwrap();
    ok(&bake_synthetic(&out, &[]));
    assert!(!part.exists(), "the stale .part folder is still there");
    assert!(Store::open(&out).is_ok());
}

/// A DEM whose voids are -32767 with no nodata tag is baked as it is, with a warning naming
/// the option that fixes it, whether read whole or by rows (issue 15 item 8).
#[test]
fn a_void_sentinel_without_nodata_is_warned_about_when_baking() {
    let dir = scratch("sentinel");
    let crater = data("crater_lake/craterlake-elev-16bit-30m.tif");
    for (name, extra) in [("whole", &[][..]), ("rows", &["--stream"][..])] {
        let out = dir.join(name);
        let mut args = vec!["bake", s(&crater), "-o", s(&out), "--no-pvs", "--no-dss"];
        args.extend(extra);
        let r = terrain(&args);
        ok(&r);
        let err = String::from_utf8_lossy(&r.stderr);
        let line = err.lines().find(|l| l.contains("warning") && l.contains("-32767"));
        let line = line.unwrap_or_else(|| panic!("{name}: no warning: {err}"));
        assert!(line.contains("craterlake") && line.contains("--nodata=-32767"), "{line}");
        // With --nodata: nothing to say.
        let fixed = dir.join(format!("{name}-fixed"));
        let mut args = vec!["bake", s(&crater), "-o", s(&fixed), "--no-pvs", "--no-dss"];
        args.extend(extra);
        args.push("--nodata=-32767");
        let r = terrain(&args);
        ok(&r);
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(!err.contains("-32767 and no nodata"), "{name}: {err}");
    }
    // A whole read over --max-memory: baked by rows instead of refused.
    let low = dir.join("low");
    let r = terrain(&[
        "bake",
        s(&crater),
        "-o",
        s(&low),
        "--no-pvs",
        "--no-dss",
        "--max-memory",
        "1MiB",
    ]);
    let err = ok(&r);
    let err = format!("{err}{}", String::from_utf8_lossy(&r.stderr));
    assert!(err.contains("read by bands of rows"), "{err}");
}
