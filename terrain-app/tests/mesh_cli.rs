//! End-to-end tests of `terrain mesh`: .glb and .obj of the lidar prairie (UTM 15N) at 0.5 m,
//! read back with the gltf crate, and clear errors for bad bounds.

mod common;

use common::{data, terrain};

fn out_dir(name: &str) -> common::Scratch {
    common::scratch("mesh-cli", name)
}

#[test]
fn prairie_exports_glb_and_obj_within_half_a_metre() {
    let dem = data("lidar_prairie/dem.tif");
    let dem = dem.to_str().unwrap();
    let dir = out_dir("prairie");
    let glb = dir.join("prairie.glb");
    let out = terrain(&["mesh", dem, "--max-error", "0.5", "-o", glb.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(said.contains("max error") && said.contains("RMS"), "{said}");

    let bytes = std::fs::read(&glb).unwrap();
    let gltf = gltf::Gltf::from_slice(&bytes).expect("a valid .glb");
    let blob = gltf.blob.as_deref().expect("a BIN chunk");
    let extras = gltf.document.as_json().asset.extras.as_ref().expect("asset extras").get();
    let meta: serde_json::Value = serde_json::from_str(extras).unwrap();
    assert_eq!(meta["epsg"], 26915, "{extras}");
    assert!(meta["measured_max_error_m"].as_f64().unwrap() <= 0.5);
    let origin: Vec<f64> =
        meta["origin"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    // UTM 15N: an easting in the hundreds of kilometres, a northing in the thousands.
    assert!(origin[0] > 100_000.0 && origin[1] > 1_000_000.0, "{origin:?}");
    let node = gltf.nodes().next().expect("a node");
    let t = node.transform().decomposed().0;
    // glTF is y-up: (east, up, -north); the origin is a multiple of 64 m, exact in f32.
    assert_eq!(
        [f64::from(t[0]), f64::from(t[1]), -f64::from(t[2])],
        [origin[0], origin[2], origin[1]]
    );
    let prim = node.mesh().unwrap().primitives().next().unwrap();
    let reader = prim.reader(|_| Some(blob));
    let positions: Vec<[f32; 3]> = reader.read_positions().expect("positions").collect();
    assert!(!positions.is_empty());
    // f32 offsets from a local origin: small numbers, however large the UTM coordinates.
    assert!(positions.iter().flatten().all(|c| c.abs() < 1000.0));
    let normals: Vec<[f32; 3]> = reader.read_normals().expect("normals").collect();
    assert_eq!(normals.len(), positions.len());
    assert!(normals.iter().all(|n| n[1] > 0.0), "normals point up (+y in glTF)");
    let indices: Vec<u32> = reader.read_indices().expect("indices").into_u32().collect();
    assert!(indices.len() >= 6 && indices.len().is_multiple_of(3));
    assert!(indices.iter().all(|&k| (k as usize) < positions.len()));

    let obj = dir.join("prairie.obj");
    let out = terrain(&[
        "mesh",
        dem,
        "--max-error",
        "0.5",
        "--algorithm",
        "rtin",
        "-o",
        obj.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(&obj).unwrap();
    let v = text.lines().filter(|l| l.starts_with("v ")).count();
    let f = text.lines().filter(|l| l.starts_with("f ")).count();
    assert!(v >= 4 && f >= 2, "{v} v, {f} f");
    assert!(text.lines().any(|l| l.starts_with("# origin ")), "origin comment");
    assert!(text.contains("EPSG:26915"));
}

#[test]
fn bad_max_errors_and_outputs_are_clear_errors() {
    let dir = out_dir("bad");
    let glb = dir.join("x.glb");
    let glb = glb.to_str().unwrap();
    for bad in ["-1", "NaN", "-0.5"] {
        let out = terrain(&["mesh", "--max-error", bad, "-o", glb]);
        assert!(!out.status.success(), "--max-error {bad} was accepted");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("--max-error must be a non-negative number"), "{bad}: {err}");
    }
    let out = terrain(&["mesh", "--max-error", "abc", "-o", glb]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--max-error"));
    let out = terrain(&["mesh", "--max-error", "1", "-o", dir.join("x.ply").to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&out.stderr).contains(".glb, .gltf or .obj"));
    assert!(!std::path::Path::new(glb).exists(), "nothing written on error");
}

#[test]
fn a_views_lod_surface_exports_with_its_measured_error() {
    let dem = data("lidar_prairie/dem.tif");
    let dir = out_dir("view");
    let obj = dir.join("view.obj");
    let camera = "429300,5150500,450,45,-30";
    let out = terrain(&[
        "mesh",
        dem.to_str().unwrap(),
        "--camera",
        camera,
        "--method",
        "dss-1",
        "-o",
        obj.to_str().unwrap(),
        "--stats",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let stats: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(stats["algorithm"], "dss-1");
    assert!(stats["max_error_bound_m"].is_null(), "a view's surface has no bound: {stats}");
    let max = stats["measured_max_error_m"].as_f64().unwrap();
    assert!(max.is_finite() && max > 0.0, "the LOD surface is not the full DEM: {max}");
    let text = std::fs::read_to_string(&obj).unwrap();
    let v = text.lines().filter(|l| l.starts_with("v ")).count();
    let f = text.lines().filter(|l| l.starts_with("f ")).count();
    assert_eq!(
        (v as u64, f as u64),
        (stats["vertices"].as_u64().unwrap(), stats["triangles"].as_u64().unwrap())
    );
    assert!(text.contains("bound none"));
    // Without --camera the bound is required.
    let out = terrain(&["mesh", dem.to_str().unwrap(), "-o", obj.to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--max-error"));
}
