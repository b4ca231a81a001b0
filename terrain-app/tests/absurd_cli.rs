//! Grids and values no surface can be made of are refused up front, the same way by `bake`,
//! `render`, `fly`, `bench` and `mesh`: a grid narrower than 2 samples, a 1 x 1 grid, a
//! spacing that puts the terrain at infinity (`--spacing 1e300`, or a sane spacing times
//! many samples), heights no terrain has (`--vertical-scale 1e30`). Each error says what,
//! why and which option; nothing is written.

mod common;

use std::path::{Path, PathBuf};

use common::{scratch, terrain};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A `w` x `h` raw f32 grid of gentle heights.
fn raw(dir: &Path, w: usize, h: usize) -> PathBuf {
    let p = dir.join(format!("g{w}x{h}.raw"));
    let bytes: Vec<u8> = (0..w * h).flat_map(|k| (100.0 + (k % 7) as f32).to_le_bytes()).collect();
    std::fs::write(&p, bytes).unwrap();
    p
}

/// Every command that makes a surface, on `dem` read with `opts`, writing into `out`.
fn commands(dem: &Path, opts: &[String], out: &Path) -> Vec<(&'static str, Vec<String>)> {
    let flight = Path::new(env!("CARGO_MANIFEST_DIR")).join("../flights/pvps_884.json");
    let o = |n: &str| out.join(n).to_str().unwrap().to_string();
    let mut v = vec![
        ("bake", vec!["-o".into(), o("b.scene"), "--no-pvs".into()]),
        ("render", vec!["-o".into(), o("r.png")]),
        ("fly", vec!["--flight".into(), s(&flight).into(), "-o".into(), o("fly")]),
        ("bench", vec!["--flight".into(), s(&flight).into(), "-o".into(), o("bench")]),
        ("mesh", vec!["--max-error".into(), "1".into(), "-o".into(), o("m.obj")]),
    ];
    for (_, args) in &mut v {
        args.insert(0, s(dem).into());
        args.extend(opts.iter().cloned());
    }
    v
}

/// Runs every command and checks each refuses with all of `words` in its error and wrote no
/// image, mesh, store or report.
fn refused_everywhere(dem: &Path, opts: &[&str], words: &[&str], out: &Path) {
    let opts: Vec<String> = opts.iter().map(|x| x.to_string()).collect();
    for (cmd, args) in commands(dem, &opts, out) {
        let mut all = vec![cmd];
        all.extend(args.iter().map(String::as_str));
        let r = terrain(&all);
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success(), "terrain {all:?} succeeded: {err}");
        for w in words {
            assert!(err.contains(w), "terrain {cmd}: `{w}` not in: {err}");
        }
        for made in ["b.scene", "r.png", "m.obj", "bench/g"] {
            assert!(!out.join(made).exists(), "terrain {cmd} wrote {made}");
        }
        assert!(!err.contains("panicked"), "{err}");
    }
}

#[test]
fn grids_without_a_cell_are_refused_by_every_command() {
    let dir = scratch("absurd", "small");
    let out = dir.join("out");
    std::fs::create_dir_all(&out).unwrap();
    let one_wide = raw(&dir, 1, 5);
    refused_everywhere(
        &one_wide,
        &["--raw", "1x5:f32"],
        &["1 x 5 samples", "at least 2 x 2"],
        &out,
    );
    let single = raw(&dir, 1, 1);
    refused_everywhere(&single, &["--raw", "1x1:f32"], &["1 x 1 samples", "at least 2 x 2"], &out);
}

#[test]
fn absurd_spacing_and_heights_are_refused_by_every_command() {
    let dir = scratch("absurd", "values");
    let out = dir.join("out");
    std::fs::create_dir_all(&out).unwrap();
    let g = raw(&dir, 3, 3);
    let opts = ["--raw", "3x3:f32", "--spacing", "1e300"];
    refused_everywhere(&g, &opts, &["--spacing", "got 1e300"], &out);
    // A spacing within range, but 200 samples of it span 2e8 m: at infinity too.
    let wide = raw(&dir, 200, 2);
    let opts = ["--raw", "200x2:f32", "--spacing", "1000000"];
    refused_everywhere(&wide, &opts, &["span", "check the spacing (--spacing)"], &out);
    let opts = ["--raw", "3x3:f32", "--vertical-scale", "1e30"];
    refused_everywhere(&g, &opts, &["no terrain reaches", "--vertical-scale"], &out);
}
