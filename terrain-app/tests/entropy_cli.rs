//! End-to-end tests of `terrain entropy` (maps as PNG, the curvature-against-entropy
//! comparison) and `terrain mesh --entropy` (a watertight mesh from a DEM or from scattered
//! points, exported as .obj and .glb), with clear errors for bad input.

mod common;

use common::{data, scratch, terrain};

#[test]
fn entropy_maps_and_comparison_on_srtm() {
    let dir = scratch("entropy-cli", "maps");
    let (map, curv) = (dir.join("entropy.png"), dir.join("curvature.png"));
    let dem = data("srtm/N52E008.hgt");
    let out = terrain(&[
        "entropy",
        dem.to_str().unwrap(),
        "-o",
        map.to_str().unwrap(),
        "--curvature",
        curv.to_str().unwrap(),
        "--radius",
        "2",
        "--compare",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for p in [&map, &curv] {
        let img = image::open(p).unwrap().to_luma8();
        assert_eq!(img.dimensions(), (1201, 1201));
        // Not a constant image: the map carries the terrain's structure.
        let (lo, hi) = img.pixels().fold((255u8, 0u8), |(l, h), p| (l.min(p[0]), h.max(p[0])));
        assert!(hi > lo + 50, "{}: {lo}..{hi}", p.display());
    }
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let share = |k: &str| v[k]["fullest_bin_share"].as_f64().unwrap();
    assert!(share("entropy") < share("curvature"), "{v}");
    assert_eq!(v["entropy"]["histogram_0_100"].as_array().unwrap().len(), 20);
}

#[test]
fn entropy_mesh_from_a_dem_and_from_points() {
    let dir = scratch("entropy-cli", "mesh");
    let dem = data("puget_sound/ps_height_1k.png");
    let obj = dir.join("ps.obj");
    let common = ["--spacing", "160", "--vertical-scale", "0.1", "--depth", "6"];
    let mut args = vec!["mesh", dem.to_str().unwrap(), "--entropy", "80", "--stats"];
    args.extend(common);
    args.extend(["-o", obj.to_str().unwrap()]);
    let out = terrain(&args);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let tiles = v["tiles"].as_u64().unwrap();
    let triangles = v["triangles"].as_u64().unwrap();
    assert!(tiles > 1 && tiles < 4096 && triangles >= 2 * tiles, "{v}");
    assert!(v["simplification_percent"].as_f64().unwrap() > 0.0);
    assert!(v["measured_max_error_m"].as_f64().unwrap() >= v["rms_error_m"].as_f64().unwrap());
    let text = std::fs::read_to_string(&obj).unwrap();
    let faces = text.lines().filter(|l| l.starts_with("f ")).count() as u64;
    assert_eq!(faces, triangles);

    // Scattered points: a CSV with a header, exported as .glb.
    let pts = dir.join("pts.csv");
    let mut csv = String::from("x,y,z\n");
    for k in 0..2000u64 {
        let (x, y) = ((k * 7919 % 1000) as f64, (k * 104729 % 997) as f64);
        csv.push_str(&format!("{x},{y},{}\n", (x * 0.01).sin() * 50.0 + y * 0.02));
    }
    std::fs::write(&pts, csv).unwrap();
    let glb = dir.join("pts.glb");
    let out = terrain(&[
        "mesh",
        "--entropy",
        "30",
        "--depth",
        "5",
        "--points",
        pts.to_str().unwrap(),
        "--interpolation",
        "idw",
        "-o",
        glb.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    gltf::Gltf::from_slice(&std::fs::read(&glb).unwrap()).expect("a valid .glb");

    // A bad line names the file and the line.
    let bad = dir.join("bad.xyz");
    std::fs::write(&bad, "1 2 3\n4 5 6\n7 8\n").unwrap();
    let out = terrain(&["mesh", "--entropy", "10", "--points", bad.to_str().unwrap(), "--stats"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.xyz") && err.contains("line 3"), "{err}");
    // Collinear points with natural neighbour: a clear error.
    let line = dir.join("line.xyz");
    std::fs::write(&line, "0 0 0\n1 1 1\n2 2 2\n3 3 3\n").unwrap();
    let out = terrain(&["mesh", "--entropy", "10", "--points", line.to_str().unwrap(), "--stats"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("collinear"));
    // Depth beyond the maximum.
    let out =
        terrain(&["mesh", dem.to_str().unwrap(), "--entropy", "10", "--depth", "17", "--stats"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("depth"));
}

/// `terrain entropy --table E0s --foci` (the entropy paper's Table 1 and Fig. 13 as JSON): one
/// row per threshold, fewer tiles as E0 rises, and a four-focus cut with fewer tiles than its
/// tree that keeps the tree's leaves at every focus; `--foci` without `--table` is refused.
#[test]
fn entropy_table_with_four_focuses() {
    let dem = data("srtm/N42E001.hgt");
    let dem = dem.to_str().unwrap();
    let out = terrain(&["entropy", dem, "--table", "0,90", "--depth", "6", "--foci"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let rows = v["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 2, "{v}");
    let tiles = |r: &serde_json::Value| r["tiles"].as_u64().unwrap();
    assert!(tiles(&rows[1]) < tiles(&rows[0]), "{v}");
    assert_eq!(tiles(&rows[0]), 4096, "E0 = 0 at depth 6 is the full tree: {v}");
    for r in rows {
        let foci = &r["foci"];
        assert!(tiles(foci) < tiles(r), "{r}");
        assert_eq!(foci["focus_leaves_kept"], serde_json::json!(true), "{r}");
        assert_eq!(foci["focuses"].as_array().unwrap().len(), 4, "{r}");
    }
    let scratch_dir = scratch("entropy-cli", "foci");
    let png = scratch_dir.join("x.png");
    let out = terrain(&["entropy", dem, "-o", png.to_str().unwrap(), "--foci"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--table"), "{out:?}");
}
