//! Options a command would accept and then ignore in the mode it runs in are refused, each
//! named with where it applies: `terrain bench`'s store options without the ooc method or
//! `--from-store`, `--ooc-k` with a store already baked, `--size` with `--no-render`;
//! `terrain mesh`'s `--method`/`--size` without `--camera`, `--interpolation` without
//! `--points`, `--algorithm` with `--camera` or `--entropy`. (`terrain render`'s are in
//! `render_cli.rs`.)

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
    assert!(!dir.join("out").exists(), "a refused bench wrote its report");
    let _ = std::fs::remove_dir_all(&dir);
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
    let _ = std::fs::remove_dir_all(&dir);
}
