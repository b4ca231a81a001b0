//! End-to-end tests of the DSS errors stored with the scene: `terrain bake` writes
//! `dss_errors.bin`, `terrain bench --scene` reads it and selects exactly what it selects when
//! it computes the errors itself, and a damaged or foreign table is a warning naming the file
//! (the errors are then computed in memory, with the same results). `terrain fly --scene` reads
//! the table too, and a scene is also the `ooc` method's store.

mod common;

use std::path::Path;
use std::process::Output;

use common::{data, scratch, terrain};
use serde_json::Value;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn ok(out: &Output) -> (String, String) {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "terrain failed: {err}");
    assert!(!err.contains("panicked"), "{err}");
    (String::from_utf8_lossy(&out.stdout).into_owned(), err)
}

const PUGET: [&str; 4] = ["--vertical-scale", "0.1", "--spacing", "160"];

/// Runs the DSS methods over two frames of a flight; returns (triangles per run and frame,
/// stderr).
fn bench(dir: &Path, name: &str, scene: Option<&Path>) -> (Vec<Vec<u64>>, String) {
    let dem = data("puget_sound/ps_height_1k.png");
    let flight = Path::new(env!("CARGO_MANIFEST_DIR")).join("../flights/pvps_884.json");
    let mut args = vec!["bench", s(&dem)];
    args.extend(PUGET);
    args.extend(["--flight", s(&flight), "--methods", "dss-1,dss-2,dss-strips"]);
    args.extend(["--frames", "2", "--sweep", "1", "--no-render", "-o", s(dir), "--name", name]);
    if let Some(scene) = scene {
        args.extend(["--scene", s(scene)]);
    }
    let (_, err) = ok(&terrain(&args));
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join(format!("{name}.json"))).unwrap())
            .unwrap();
    let runs = report["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 3);
    let tris = runs
        .iter()
        .map(|r| {
            r["frames"]
                .as_array()
                .unwrap()
                .iter()
                .map(|f| f["triangles"].as_u64().unwrap())
                .collect()
        })
        .collect();
    (tris, err)
}

#[test]
fn bake_stores_the_dss_errors_and_bench_reads_them() {
    let dir = scratch("dss-scene", "puget");
    let scene = dir.join("ps1k.scene");
    let dem = data("puget_sound/ps_height_1k.png");
    let mut args = vec!["bake", s(&dem)];
    args.extend(PUGET);
    args.extend(["-o", s(&scene), "--block-k", "8", "--threads", "2", "--no-pvs"]);
    let (out, err) = ok(&terrain(&args));
    assert!(out.contains("dss_errors.bin") && out.contains("7 quadtree levels"), "{out}");
    assert!(err.contains("DSS errors: 100 %"), "no progress shown: {err}");
    let file = scene.join("dss_errors.bin");
    let flight = Path::new(env!("CARGO_MANIFEST_DIR")).join("../flights/pvps_884.json");
    // 1 + 4 + ... + 4^6 nodes of 32 f64, a 32-byte header, 8 bytes per level, a CRC per page
    // of 256 nodes and the header's CRC (version 2).
    let nodes: u64 = (0..7).map(|l| 4u64.pow(l)).sum();
    let pages = nodes.div_ceil(256);
    assert_eq!(std::fs::metadata(&file).unwrap().len(), 32 + 7 * 8 + nodes * 256 + 4 * pages + 4);

    let (computed, err) = bench(&dir, "computed", None);
    assert!(!err.contains("warning") && !err.contains("read from"), "{err}");
    assert!(computed.iter().flatten().all(|&t| t > 0));
    let (read, err) = bench(&dir, "read", Some(&scene));
    assert!(!err.contains("warning"), "{err}");
    assert!(err.contains("DSS errors read from") && err.contains("dss_errors.bin"), "{err}");
    assert_eq!(read, computed, "the stored errors select differently");

    // `terrain fly --scene` reads it too (where a GPU adapter exists or one is required).
    let mut args = vec!["fly", s(&dem)];
    args.extend(PUGET);
    args.extend(["--method", "dss-strips", "--scene", s(&scene), "--flight", s(&flight)]);
    let fly_out = dir.join("fly");
    args.extend(["--frames", "2", "--size", "64x36", "-o", s(&fly_out)]);
    let out = terrain(&args);
    let err = String::from_utf8_lossy(&out.stderr);
    if !out.status.success()
        && err.contains("no GPU adapter")
        && std::env::var_os("TERRAIN_REQUIRE_GPU").is_none()
    {
        println!("SKIPPED terrain fly: {err}; set TERRAIN_REQUIRE_GPU=1 to make this a failure");
    } else {
        let (_, err) = ok(&out);
        assert!(err.contains("DSS errors read from") && !err.contains("warning"), "{err}");
    }

    // A damaged table: a warning naming the file, and the same selections from computed errors.
    let mut bytes = std::fs::read(&file).unwrap();
    let n = bytes.len();
    bytes[n / 2] ^= 0x40;
    std::fs::write(&file, &bytes).unwrap();
    let (damaged, err) = bench(&dir, "damaged", Some(&scene));
    assert!(err.contains("warning") && err.contains("dss_errors.bin"), "{err}");
    assert!(err.contains("checksum"), "{err}");
    assert_eq!(damaged, computed);

    // A table of another terrain (the same DEM at another vertical scale): refused.
    let other = dir.join("scaled.scene");
    let mut args = vec!["bake", s(&dem), "--vertical-scale", "0.2", "--spacing", "160"];
    args.extend(["-o", s(&other), "--block-k", "8", "--threads", "2", "--no-pvs"]);
    ok(&terrain(&args));
    let (foreign, err) = bench(&dir, "foreign", Some(&other));
    assert!(err.contains("dss_errors.bin") && err.contains("heights differ"), "{err}");
    assert_eq!(foreign, computed);

    // The scene is also the `ooc` method's store: one of another terrain is refused by name.
    let synthetic = dir.join("synthetic.scene");
    ok(&terrain(&[
        "bake",
        "--synthetic",
        "257",
        "-o",
        s(&synthetic),
        "--block-k",
        "6",
        "--no-dss",
        "--no-pvs",
    ]));
    let flight = Path::new(env!("CARGO_MANIFEST_DIR")).join("../flights/pvps_884.json");
    let mut args = vec!["bench", s(&dem)];
    args.extend(PUGET);
    args.extend(["--flight", s(&flight), "--methods", "ooc", "--frames", "1", "--sweep", "1"]);
    args.extend(["--no-render", "-o", s(&dir), "--scene", s(&synthetic)]);
    let r = terrain(&args);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success() && err.contains("synthetic.scene is 257 x 257"), "{err}");

    // --no-dss writes no table.
    let none = dir.join("none.scene");
    let mut args = vec!["bake", s(&dem)];
    args.extend(PUGET);
    args.extend(["-o", s(&none), "--block-k", "8", "--no-dss", "--no-pvs", "--no-geomip"]);
    ok(&terrain(&args));
    assert!(!none.join("dss_errors.bin").exists());
    // ... nor the per-block errors in the index: `terrain info` says so, and the DSS methods
    // refuse the store by name and say how to bake it.
    let (info, _) = ok(&terrain(&["info", s(&none)]));
    assert!(info.contains("dss errors   none (baked without them"), "{info}");
    let json: Value = serde_json::from_str(&ok(&terrain(&["info", "--json", s(&none)])).0).unwrap();
    assert_eq!(json["dss_block_errors"], Value::Bool(false), "{json}");
    // Both bakes write the fine maxima `ooc`'s factor walk reads (index version 3).
    assert_eq!(json["fine_maxima"], Value::Bool(true), "{json}");
    let (info, _) = ok(&terrain(&["info", s(&scene)]));
    assert!(info.contains("dss errors   per block in the index"), "{info}");
    assert!(info.contains("fine maxima  yes"), "{info}");
    for method in ["dss-1", "dss-2", "dss-strips"] {
        let image = dir.join("refused.png");
        let r =
            terrain(&["render", s(&none), "--size", "64x36", "--method", method, "-o", s(&image)]);
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success() && !image.exists(), "{method}: {err}");
        let named = format!("the store {} was baked without them", none.display());
        assert!(err.contains(&named), "{err}");
        assert!(err.contains("bake it again without --no-dss"), "{err}");
    }
    // --no-geomip writes no geomorph table; the default bake does.
    assert!(!none.join("geomip.bin").exists());
    assert!(synthetic.join("geomip.bin").exists());
}

/// Bakes `args` (blocks and DSS errors only) into `dir/name`; returns the table's bytes and
/// the bake's stdout and stderr.
fn bake_dss(dir: &Path, name: &str, args: &[&str]) -> (Vec<u8>, String, String) {
    let out = dir.join(name);
    let mut a = vec!["bake"];
    a.extend(args);
    a.extend(["--no-pvs", "--no-roughness", "--no-geomip", "--threads", "2", "-o", s(&out)]);
    let (stdout, stderr) = ok(&terrain(&a));
    let bytes = std::fs::read(out.join("dss_errors.bin")).expect("dss_errors.bin written");
    (bytes, stdout, stderr)
}

/// A DEM read by bands of rows (`--stream`, or forced by a small `--max-memory`) gets the
/// same `dss_errors.bin`, byte for byte, as the same DEM baked from memory; with voids, the
/// table of the rows the stream read.
#[test]
fn a_bake_by_rows_writes_the_dss_errors_of_the_in_memory_bake_byte_for_byte() {
    use terrain_core::Heightmap;
    use terrain_core::dem::{LoadOptions, RowReader};
    use terrain_core::heightmap::VoidMask;
    use terrain_core::lod::DssErrorTable;
    use terrain_core::quadtree::Quadtree;

    let dir = scratch("dss-scene", "rows");
    // A GeoTIFF without voids (float32, 400 x 400): whole, --stream, and --max-memory.
    let tif = data("lidar_prairie/dem.tif");
    let (whole, out, _) = bake_dss(&dir, "whole", &[s(&tif)]);
    assert!(out.contains("dss_errors.bin") && out.contains("(in memory)"), "{out}");
    let (rows, out, err) = bake_dss(&dir, "rows", &[s(&tif), "--stream"]);
    assert!(out.contains("(by bands of rows, the grid read 1.00 times)"), "{out}");
    assert!(err.contains("DSS errors: 100 %"), "progress shown: {err}");
    assert_eq!(rows.len(), whole.len());
    assert!(rows == whole, "the streamed table differs from the in-memory one");
    // The PVS too, against a coarse conservative grid (issue 13): no warning.
    let pvs = dir.join("pvs");
    let a = ["bake", s(&tif), "--stream", "--no-roughness", "--no-geomip", "-o", s(&pvs)];
    let a = [&a[..], &["--pvs-cells", "4", "--pvs-floors", "2", "--pvs-patch-level", "3"]].concat();
    let (out, err) = ok(&terrain(&a));
    assert!(!err.contains("no PVS files"), "{err}");
    assert!(out.contains("by bands of rows: against a"), "{out}");
    assert!(pvs.join("dss_errors.bin").exists() && pvs.join("pvs.bin").exists());
    assert!(pvs.join("pvs_conservative.bin").exists());
    let (small, out, _) = bake_dss(&dir, "small", &[s(&tif), "--max-memory", "2MiB"]);
    assert!(out.contains("(by bands of rows, the grid read "), "{out}");
    assert!(small == whole, "the table under --max-memory differs");
    // Not a constant table: the comparison compares something.
    let qt = Quadtree::new(&load_whole(&tif, LoadOptions::default()), 16);
    let table = DssErrorTable::decode_for(&whole, qt.shape(), None).unwrap();
    let root = table.get(terrain_core::quadtree::NodeId::new(0, 0, 0)).unwrap();
    assert!(root[0] > root[31] && root[31] >= 0.0, "{root:?}");

    // Voids (Crater Lake): streamed voids are filled along rows and columns, so the reference
    // is the in-memory table of the grid the row reader gives.
    let crater = data("crater_lake/craterlake-elev-16bit-30m.tif");
    let (got, out, _) = bake_dss(&dir, "crater", &[s(&crater), "--nodata", "-32767", "--stream"]);
    assert!(out.contains("(by bands of rows, the grid read "), "{out}");
    let opts = LoadOptions { nodata: Some(-32767.0), ..LoadOptions::default() };
    let reader = RowReader::open(&crater, &opts).unwrap();
    let (w, h) = (reader.width() as usize, reader.height() as usize);
    let mut heights = vec![0f32; w * h];
    let mut flags = vec![false; w * h];
    reader.read_rows(0, h, &mut heights, &mut flags).unwrap();
    let mut mask = VoidMask::new(w, h);
    for (k, &v) in flags.iter().enumerate() {
        mask.set(k % w, k / w, v);
    }
    assert!(mask.count() > 30_000, "{} voids", mask.count());
    let hm = Heightmap::new(w, h, heights, mask, reader.georef().clone()).unwrap();
    assert!(got == DssErrorTable::new(&hm, &Quadtree::new(&hm, 16)).encode(&hm));
}

fn load_whole(path: &Path, opts: terrain_core::dem::LoadOptions) -> terrain_core::Heightmap {
    terrain_core::dem::load(path, &opts).unwrap().heightmap
}
