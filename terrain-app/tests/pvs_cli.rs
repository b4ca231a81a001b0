//! End-to-end tests of the PVS in the CLI: `terrain bake` writes both PVS files into the scene,
//! `terrain pvs` exports a cell's image from a scene or straight from a DEM, a corrupt PVS file
//! is an error naming it for `terrain pvs` and a warning for `terrain bench` (which then runs
//! without occlusion culling).

mod common;

use std::path::Path;
use std::process::Output;

use common::{data, terrain};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn ok(out: &Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "terrain failed: {err}");
    assert!(!err.contains("panicked"), "{err}");
    String::from_utf8_lossy(&out.stdout).into_owned()
}

const SMALL: [&str; 6] = ["--pvs-cells", "4", "--pvs-floors", "2", "--pvs-patch-level", "3"];

#[test]
fn bake_writes_the_pvs_and_pvs_exports_a_cell() {
    let dir = common::scratch("pvs-cli", "scene");
    let scene = dir.join("fractal");
    let mut args =
        vec!["bake", "--synthetic", "257", "-o", s(&scene), "--block-k", "6", "--no-dss"];
    args.extend(SMALL);
    let output = terrain(&args);
    let out = ok(&output);
    assert!(out.contains("pvs.bin") && out.contains("pvs_conservative.bin"), "{out}");
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(err.contains("PVS: 100 %"), "no progress shown: {err}");
    assert!(scene.join("pvs.bin").is_file() && scene.join("pvs_conservative.bin").is_file());

    let png = dir.join("cell.png");
    let out = ok(&terrain(&["pvs", s(&scene), "--cell", "1,2,0", "-o", s(&png)]));
    assert!(out.contains("of 64 patches visible"), "{out}");
    let img = image::open(&png).unwrap().to_luma8();
    assert_eq!(img.dimensions(), (32, 32));
    assert!(img.pixels().all(|p| p.0[0] == 0 || p.0[0] == 255));
    assert!(img.pixels().any(|p| p.0[0] == 255), "nothing visible from the cell");

    // A cell outside the PVS.
    let r = terrain(&["pvs", s(&scene), "--cell", "9,0,0", "-o", s(&png)]);
    assert!(!r.status.success());
    assert!(String::from_utf8_lossy(&r.stderr).contains("out of range"));

    // Corrupt the file: a clear error naming it.
    let file = scene.join("pvs.bin");
    let mut bytes = std::fs::read(&file).unwrap();
    let n = bytes.len();
    bytes.truncate(n - 10);
    std::fs::write(&file, &bytes).unwrap();
    let r = terrain(&["pvs", s(&scene), "--cell", "1,2,0", "-o", s(&png)]);
    assert!(!r.status.success());
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("pvs.bin") && err.contains("truncated"), "{err}");
    assert!(!err.contains("panicked"), "{err}");

    // The benchmark warns and runs pvps-c-pvs without occlusion culling.
    let hgt = data("srtm/N42E001.hgt");
    let out = terrain(&[
        "bench",
        s(&hgt),
        "--flight",
        s(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../flights/pvps_884.json")),
        "--methods",
        "pvps-c-pvs",
        "--frames",
        "1",
        "--sweep",
        "1",
        "--no-render",
        "--pvs-scene",
        s(&scene),
        "-o",
        s(&dir.join("bench")),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("warning") && err.contains("pvs.bin"), "{err}");
}

#[test]
fn pvs_bakes_a_dem_on_the_fly() {
    let dir = common::scratch("pvs-cli", "dem");
    let hgt = data("srtm/N42E001.hgt");
    let png = dir.join("c.png");
    let mut args = vec!["pvs", s(&hgt), "--cell", "2,1,0", "--conservative", "-o", s(&png)];
    args.extend(SMALL);
    args.extend(["--scale", "1"]);
    let out = ok(&terrain(&args));
    assert!(out.contains("conservative") && out.contains("of 64 patches visible"), "{out}");
    assert_eq!(image::open(&png).unwrap().to_luma8().dimensions(), (8, 8));
}

/// A PVS baked from one DEM is refused for another DEM of the same grid size (issue 15 item 7:
/// the check compared only the grid size), with a warning naming the file and saying to bake
/// again; the benchmark then runs without occlusion culling.
#[test]
fn a_stale_pvs_is_refused_naming_the_file() {
    let dir = common::scratch("pvs-cli", "stale");
    let scene = dir.join("n41");
    let n41 = data("srtm/N41E001.hgt");
    let mut args = vec!["bake", s(&n41), "-o", s(&scene), "--block-k", "8", "--no-dss"];
    args.extend(SMALL);
    ok(&terrain(&args));
    let bench = |dem: &Path, out: &str| {
        terrain(&[
            "bench",
            s(dem),
            "--flight",
            s(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../flights/pvps_884.json")),
            "--methods",
            "pvps-c-pvs",
            "--frames",
            "1",
            "--sweep",
            "1",
            "--no-render",
            "--scene",
            s(&scene),
            "-o",
            s(&dir.join(out)),
        ])
    };
    // The DEM it was baked from: no warning about the PVS.
    let same = bench(&data("srtm/N41E001.hgt"), "same");
    let err = String::from_utf8_lossy(&same.stderr);
    assert!(same.status.success(), "{err}");
    assert!(!err.contains("pvs.bin"), "the PVS of this very DEM was refused: {err}");
    // Another tile of the same size: stale.
    let other = bench(&data("srtm/N42E001.hgt"), "other");
    let err = String::from_utf8_lossy(&other.stderr);
    assert!(other.status.success(), "{err}");
    let line = err.lines().find(|l| l.contains("pvs.bin")).unwrap_or_else(|| panic!("{err}"));
    assert!(
        line.contains("stale") && line.contains("terrain bake") && line.contains("warning"),
        "{line}"
    );
}

/// Issue 13: a DEM baked by bands of rows (`--stream`, a small `--max-memory`) gets both PVS
/// files, baked against a coarse conservative grid and tied to the full-resolution heights,
/// and `terrain render <store> --method pvps-c-pvs` draws with them (no warning); without the
/// file it warns (the negative control).
#[test]
fn a_bake_by_rows_writes_a_pvs_that_render_uses() {
    use terrain_core::dem::{LoadOptions, RowReader};
    use terrain_core::lod::dss_file::HeightsChecksum;
    use terrain_visibility::pvs::read_pvs;

    let dir = common::scratch("pvs-cli", "rows");
    let store = dir.join("bt.scene");
    let tif = data("big_tujunga/bigtujunga.tif");
    let mut args = vec!["bake", s(&tif), "--stream", "--max-memory", "4MiB", "--no-dss"];
    args.extend(["--no-geomip", "-o", s(&store)]);
    args.extend(["--pvs-cells", "8", "--pvs-patch-level", "4"]);
    let out = terrain(&args);
    let stdout = ok(&out);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("no PVS files"), "{stderr}");
    assert!(stdout.contains("by bands of rows: against a 151 x 82 conservative grid"), "{stdout}");
    // Tied to the grid's full-resolution heights, as the row reader gives them.
    let reader = RowReader::open(&tif, &LoadOptions::default()).unwrap();
    let (w, h) = (reader.width() as usize, reader.height() as usize);
    let (mut heights, mut voids) = (vec![0f32; w], vec![false; w]);
    let mut crc = HeightsChecksum::new();
    for j in 0..h {
        reader.read_rows(j as u64, 1, &mut heights, &mut voids).unwrap();
        crc.add_heights(&heights);
        crc.add_voids(&voids);
    }
    for name in ["pvs.bin", "pvs_conservative.bin"] {
        let pvs = read_pvs(&store.join(name)).unwrap();
        assert_eq!((pvs.layout.width, pvs.layout.height), (w as u32, h as u32), "{name}");
        assert_eq!(pvs.layout.heights, crc.finish(), "{name}: not the full-resolution CRC");
    }
    // Drawn from the store with its PVS; then without it (negative control).
    let render = |tag: &str| {
        let png = dir.join(format!("{tag}.png"));
        let args = ["render", s(&store), "--method", "pvps-c-pvs", "--size", "160x120"];
        terrain(&[&args[..], &["-o", s(&png)]].concat())
    };
    let drawn = render("with");
    let err = String::from_utf8_lossy(&drawn.stderr).into_owned();
    if !drawn.status.success()
        && err.contains("no GPU adapter")
        && std::env::var_os("TERRAIN_REQUIRE_GPU").is_none()
    {
        println!("SKIPPED the render: {err}; set TERRAIN_REQUIRE_GPU=1 to make this a failure");
        return;
    }
    let stdout = ok(&drawn);
    assert!(stdout.contains("method: pvps-c-pvs"), "{stdout}");
    assert!(!err.contains("occlusion culling"), "the PVS was not used: {err}");
    std::fs::remove_file(store.join("pvs.bin")).unwrap();
    let without = render("without");
    ok(&without);
    let err = String::from_utf8_lossy(&without.stderr);
    assert!(err.contains("drawing without occlusion culling"), "{err}");
}

/// Issue 18: by default the bake takes a spread sample of the PVS's view cells and bakes the
/// PVS only where it pays; on a nearly flat lowland it does not, so no PVS files are written,
/// and the store still draws `pvps-c-pvs` and `pvps-c-cons` (without occlusion culling, with a
/// warning saying how to have it). `--pvs` bakes it whatever it culls (the negative control),
/// and `--pvs` with `--no-pvs` is refused.
#[test]
fn the_default_bake_skips_a_pvs_that_does_not_pay_and_pvs_forces_it() {
    let dir = common::scratch("pvs-cli", "pays");
    let flat = data("srtm/N52E008.hgt");
    let bake = |name: &str, extra: &[&str]| {
        let out = dir.join(name);
        let mut args = vec!["bake", s(&flat), "-o", s(&out), "--block-k", "8", "--no-dss"];
        args.extend(["--no-geomip"]);
        args.extend(extra);
        (terrain(&args), out)
    };
    let (skipped, store) = bake("default", &[]);
    let stdout = ok(&skipped);
    assert!(stdout.contains("PVS sample: 16 of 256 view cell columns"), "{stdout}");
    assert!(stdout.contains("no PVS is baked") && stdout.contains("--pvs"), "{stdout}");
    assert!(!store.join("pvs.bin").exists() && !store.join("pvs_conservative.bin").exists());
    for method in ["pvps-c-pvs", "pvps-c-cons"] {
        let png = dir.join(format!("{method}.png"));
        let args = ["render", s(&store), "--method", method, "--size", "160x120", "-o", s(&png)];
        let drawn = terrain(&args);
        let err = String::from_utf8_lossy(&drawn.stderr).into_owned();
        if !drawn.status.success()
            && err.contains("no GPU adapter")
            && std::env::var_os("TERRAIN_REQUIRE_GPU").is_none()
        {
            println!("SKIPPED the render: {err}; set TERRAIN_REQUIRE_GPU=1 to make this a failure");
            continue;
        }
        ok(&drawn);
        assert!(
            err.contains("drawing without occlusion culling") && err.contains("--pvs"),
            "{err}"
        );
        assert!(png.is_file(), "{method}: no image");
    }
    let (forced, store) = bake("forced", &["--pvs"]);
    let stdout = ok(&forced);
    assert!(!stdout.contains("PVS sample") && stdout.contains("PVS bake"), "{stdout}");
    assert!(stdout.contains("cells x 32^2 patches"), "not scaled to the grid: {stdout}");
    assert!(store.join("pvs.bin").is_file() && store.join("pvs_conservative.bin").is_file());
    let both = bake("both", &["--pvs", "--no-pvs"]).0;
    assert!(!both.status.success());
}
