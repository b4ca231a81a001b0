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
    // 1 + 4 + ... + 4^6 nodes of 32 f64, a 28-byte header, 8 bytes per level and the CRC.
    let nodes: u64 = (0..7).map(|l| 4u64.pow(l)).sum();
    assert_eq!(std::fs::metadata(&file).unwrap().len(), 28 + 7 * 8 + nodes * 256 + 4);

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
    // --no-geomip writes no geomorph table; the default bake does.
    assert!(!none.join("geomip.bin").exists());
    assert!(synthetic.join("geomip.bin").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}
