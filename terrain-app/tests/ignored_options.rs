//! Options a command would accept and then ignore in the mode it runs in are refused, each
//! named with where it applies: `terrain bench`'s store options without the ooc method or
//! `--from-store`, `--ooc-k` with a store already baked, `--size` with `--no-render`,
//! `--scene` when no method reads it; `terrain mesh`'s `--method`/`--size` without
//! `--camera`, `--interpolation` without `--points`, `--algorithm` with `--camera` or
//! `--entropy`; `terrain bake`'s `--stream` and `--stream-above` with `--synthetic`,
//! `--max-error` with `--raw-f32`, `--pvs-*` with `--no-pvs`, `--pvs-article` with the cell
//! flags; the DEM reading options with a store (`info`, `render`) or a scene folder (`pvs`,
//! also its `--pvs-*`). (`terrain render`'s own are in `render_cli.rs`.)

mod common;

use std::path::Path;

use common::{scratch, terrain};

fn refused(args: &[&str], needles: &[&str]) {
    let out = terrain(args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{args:?} was accepted: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(needles.iter().all(|n| stderr.contains(n)), "{args:?}: {stderr}");
}

#[test]
fn bench_refuses_options_no_run_uses() {
    let dir = scratch("ignored", "bench");
    let flight = Path::new(env!("CARGO_MANIFEST_DIR")).join("../flights/pvps_884.json");
    let scene = dir.join("scene");
    std::fs::create_dir_all(&scene).unwrap();
    let (flight, scene, out) = (flight.to_str().unwrap(), scene.to_str().unwrap(), dir.join("out"));
    let out = out.to_str().unwrap();
    // Small runs, should a refusal be missing: the test then fails quickly.
    let base = ["bench", "--flight", flight, "--frames", "1", "--sweep", "1", "-o", out];
    let with = |extra: &[&'static str]| -> Vec<&str> {
        base.iter().copied().chain(extra.iter().copied()).collect()
    };
    refused(
        &with(&["--no-render", "--methods", "uniform", "--ooc-k", "6"]),
        &["--ooc-k applies to the ooc method and --from-store", "--methods has no ooc"],
    );
    refused(
        &with(&["--no-render", "--methods", "uniform", "--wait", "--ooc-cache-mib", "8"]),
        &["--ooc-cache-mib, --wait apply to the ooc method"],
    );
    let mut args = with(&["--no-render", "--methods", "ooc", "--ooc-k", "6", "--scene"]);
    args.push(scene);
    refused(&args, &["--ooc-k", "--scene", "already baked"]);
    refused(&with(&["--no-render", "--size", "64x36"]), &["--size", "--no-render"]);
    let mut args = with(&["--no-render", "--methods", "uniform,entropy", "--scene"]);
    args.push(scene);
    refused(&args, &["--scene is read by", "uniform, entropy reads nothing"]);
    assert!(!dir.join("out").exists(), "a refused bench wrote its report");
}

#[test]
fn mesh_refuses_options_of_another_mode() {
    let dir = scratch("ignored", "mesh");
    let obj = dir.join("m.obj");
    let obj = obj.to_str().unwrap();
    let camera = "100,100,500,45,-30";
    refused(&["mesh", "--max-error", "1", "--method", "dss-1", "-o", obj], &["--camera"]);
    refused(&["mesh", "--max-error", "1", "--size", "64x36", "-o", obj], &["--camera"]);
    refused(&["mesh", "--entropy", "30", "--interpolation", "idw", "-o", obj], &["--points"]);
    refused(&["mesh", "--camera", camera, "--algorithm", "rtin", "-o", obj], &["--algorithm"]);
    refused(&["mesh", "--entropy", "30", "--algorithm", "rtin", "-o", obj], &["--algorithm"]);
    assert!(!Path::new(obj).exists());
}

#[test]
fn bake_refuses_options_it_would_ignore() {
    let dir = scratch("ignored", "bake");
    let out = dir.join("s");
    let out = out.to_str().unwrap();
    let bake = ["bake", "--synthetic", "65", "--no-dss", "-o", out];
    let with = |extra: &[&'static str]| -> Vec<&str> {
        bake.iter().copied().chain(extra.iter().copied()).collect()
    };
    refused(&with(&["--stream"]), &["--stream", "--synthetic"]);
    refused(&with(&["--stream-above", "100"]), &["--stream-above", "--synthetic"]);
    refused(&with(&["--raw-f32", "--max-error", "0.5"]), &["--max-error", "--raw-f32"]);
    refused(&with(&["--no-pvs", "--pvs-cells", "8"]), &["--pvs-cells applies", "--no-pvs"]);
    refused(&with(&["--pvs-article", "--pvs-floors", "2"]), &["--pvs-article", "--pvs-floors"]);
    assert!(!Path::new(out).exists(), "a refused bake wrote {out}");
}

#[test]
fn reading_options_are_refused_for_a_store_or_a_scene() {
    let dir = scratch("ignored", "store");
    let store = dir.join("s");
    let store = store.to_str().unwrap();
    let baked = terrain(&["bake", "--synthetic", "65", "--no-pvs", "--no-dss", "-o", store]);
    assert!(baked.status.success(), "{}", String::from_utf8_lossy(&baked.stderr));
    // The same store is accepted without them (the refusals below are about the options).
    assert!(terrain(&["info", store]).status.success());
    refused(&["info", store, "--vertical-scale", "2"], &["--vertical-scale applies", "store"]);
    refused(
        &["info", store, "--spacing", "30", "--nodata", "0"],
        &["--nodata, --spacing apply to reading a DEM file", "store"],
    );
    let png = dir.join("r.png");
    refused(
        &["render", store, "--max-memory", "1MiB", "-o", png.to_str().unwrap()],
        &["--max-memory", "store"],
    );
    refused(
        &["pvs", store, "--cell", "0,0,0", "--vertical-offset", "5", "-o", "p.png"],
        &["--vertical-offset", "scene folder"],
    );
    refused(
        &["pvs", store, "--cell", "0,0,0", "--pvs-cells", "8", "-o", "p.png"],
        &["--pvs-cells applies", "scene folder"],
    );
    assert!(!png.exists() && !Path::new("p.png").exists());
}

/// `render`, `fly` and `view` share one definition of their options (`draw_args`): the same
/// checks in all three (a bad field of view, a zero leaf size), and `view` refuses a store's
/// options with a DEM before it opens a window (the embedded terrain here; no display needed).
#[test]
fn shared_drawing_options_are_checked_alike() {
    let dir = scratch("ignored", "shared");
    let flight = Path::new(env!("CARGO_MANIFEST_DIR")).join("../flights/pvps_884.json");
    let (flight, png, out) =
        (flight.to_str().unwrap(), dir.join("x.png"), dir.join("fly").to_str().unwrap().to_owned());
    let png = png.to_str().unwrap();
    refused(&["render", "--fov", "200", "-o", png], &["--fov must be between 0 and 180"]);
    refused(&["view", "--fov", "200"], &["--fov must be between 0 and 180"]);
    for cmd in [
        vec!["render", "--leaf-cells", "0", "-o", png],
        vec!["view", "--leaf-cells", "0"],
        vec!["fly", "--flight", flight, "--leaf-cells", "0", "-o", &out],
    ] {
        refused(&cmd, &["--leaf-cells must be at least 1"]);
    }
    refused(
        &["view", "--cache-mib", "8", "--page-mib", "4"],
        &["--cache-mib, --page-mib apply to a baked store"],
    );
    // The measurement's reference budget is a store's (a DEM in memory is its own reference).
    refused(&["view", "--measure-mib", "8"], &["--measure-mib apply to a baked store"]);
    refused(&["render", "--page-capacity", "8", "-o", png], &["--page-capacity applies"]);
}
