//! The out-of-core method's per-store calibration of `--error-px`
//! (`terrain_app::ooc_calibration`, issue 13): a store's calibration is measured, written
//! beside its index and read back; a file of another store or a garbled one is refused naming
//! the file; with the store's calibration the measured p99 lands near the target on frames it
//! was not fitted on, where the shared calibration is further off; `terrain calibrate`, `terrain
//! info` and `terrain bake --calibrate` on the command line.

mod common;

use std::ops::ControlFlow;
use std::path::Path;
use std::sync::Arc;

use terrain_app::method::registry::ooc_p99_per_tau;
use terrain_app::ooc::OocConfig;
use terrain_app::ooc_calibration::{
    self, CalibrateOptions, Calibration, CalibrationError, FILE_NAME, TauSource, TerrainId,
};
use terrain_core::Heightmap;
use terrain_core::synth::FractalConfig;
use terrain_stream::{BakeConfig, BakeProgress, HeightEncoding, Refinement, Store, bake};

use common::{scratch, terrain};

/// A synthetic fractal grid of `n x n` samples, 10 m apart.
fn synthetic(n: u64) -> Heightmap {
    FractalConfig::with_size(n, n, 10.0).to_heightmap().unwrap()
}

/// `hm` baked into `dir` with exact heights and blocks of `2^k` cells.
fn bake_store(hm: &Heightmap, k: u8, dir: &Path) -> Arc<Store> {
    let config = BakeConfig { k, encoding: HeightEncoding::F32, threads: 1, ..Default::default() };
    bake(hm, dir, &config, &mut |_: &BakeProgress| ControlFlow::Continue(())).unwrap();
    Arc::new(Store::open(dir).unwrap())
}

fn options(frames: usize) -> CalibrateOptions {
    CalibrateOptions { frames, ..CalibrateOptions::default() }
}

/// The median p99 of `ooc` at `tau` over `frames` frames of the calibration's flight.
fn p99_at(hm: &Heightmap, store: &Arc<Store>, tau: f64, frames: usize) -> f64 {
    let config = OocConfig { threads: 1, ..OocConfig::default() };
    let opts = CalibrateOptions { taus: vec![tau], ..options(frames) };
    ooc_calibration::measure(hm.clone(), store.clone(), &config, &opts).unwrap()[0].1
}

/// Calibrates a 513^2 synthetic store, writes and reloads the file, and checks the measured
/// p99 at the calibrated tau on other frames of the flight (5, not the fitted 3) against the
/// target, and the shared calibration's, which on this smooth terrain draws far finer than
/// asked (Eq. 7's p99 per tau here is well under the shared one's, `ooc_p99_per_tau`).
#[test]
fn the_store_calibration_lands_the_target_where_the_shared_one_does_not() {
    let scratch_dir = scratch("ooc-calibration", "synthetic");
    let dir = scratch_dir.join("store");
    let hm = synthetic(513);
    let store = bake_store(&hm, 6, &dir);
    let config = OocConfig { threads: 1, ..OocConfig::default() };
    let c = ooc_calibration::calibrate_store(&dir, &config, &options(3)).unwrap();
    assert_eq!(c.terrain, TerrainId::of(&store));
    assert_eq!(c.refinement, config.refinement());
    println!("points: {:?}", c.points());
    c.write(&dir.join(FILE_NAME)).unwrap();
    let back = ooc_calibration::of_store(&dir).unwrap().expect("the file is read");
    assert_eq!(back, c, "the file round-trips");

    let target = 1.0;
    let with_store = OocConfig { calibration: Some(back), ..config };
    let (tau, source) = with_store.tau_for_error_px(target);
    assert_eq!(source, TauSource::Store);
    let (shared_tau, shared) = config.tau_for_error_px(target);
    assert_eq!(shared, TauSource::Shared);
    let mine = p99_at(&hm, &store, tau, 5);
    let theirs = p99_at(&hm, &store, shared_tau, 5);
    println!(
        "target {target} px: store tau {tau:.3} -> p99 {mine:.3}; shared tau {shared_tau:.3} -> p99 {theirs:.3}"
    );
    let off = |p99: f64| (p99 / target).ln().abs();
    assert!(off(mine) < 0.4f64.ln_1p(), "the store's calibration: p99 {mine} for {target} px");
    assert!(off(theirs) > off(mine), "the shared calibration is further off: {theirs} vs {mine}");
}

/// A store wider than the window is measured on a centred window of whole blocks (baked into a
/// temporary store), and the calibration names the store itself, not the window's bake; a
/// window of the whole grid measures what the whole store measures (negative control: the
/// same points), and a smaller one differs.
#[test]
fn a_large_store_is_measured_on_a_window() {
    let scratch_dir = scratch("ooc-calibration", "window");
    let dir = scratch_dir.join("store");
    let hm = synthetic(513);
    let store = bake_store(&hm, 6, &dir);
    let config = OocConfig { threads: 1, ..OocConfig::default() };
    let taus = vec![2.0, 4.0, 8.0, 16.0];
    let whole = CalibrateOptions { taus: taus.clone(), window: 513, ..options(2) };
    let window = CalibrateOptions { taus, window: 257, ..options(2) };
    let a = ooc_calibration::calibrate_store(&dir, &config, &whole).unwrap();
    let b = ooc_calibration::calibrate_store(&dir, &config, &window).unwrap();
    assert_eq!(b.terrain, TerrainId::of(&store), "the store's identity, not the window's");
    let direct = ooc_calibration::measure(hm, store, &config, &whole).unwrap();
    let direct = Calibration::fit(a.terrain, a.refinement, 2, &direct).unwrap();
    assert_eq!(a.points(), direct.points(), "the whole grid is the store itself");
    assert_ne!(a.points(), b.points(), "a window is another terrain for the flight");
}

/// A calibration of another store is refused, naming the file and both stores; a garbled file
/// names its line; a missing file is no calibration; one measured under another refinement
/// (without the default segment floor) is read but not used; `terrain info` says which is used.
#[test]
fn foreign_and_garbled_files_are_refused() {
    let root = scratch("ooc-calibration", "foreign");
    let a = root.join("a");
    let b = root.join("b");
    let store_a = bake_store(&synthetic(129), 5, &a);
    bake_store(&synthetic(257), 5, &b);
    assert!(ooc_calibration::of_store(&a).unwrap().is_none(), "no file: no calibration");
    let info = terrain(&["info", a.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(info.status.success() && text.contains("the shared calibration"), "{text}");

    let refinement = OocConfig::default().refinement();
    let c = Calibration::fit(TerrainId::of(&store_a), refinement, 3, &[(1.0, 0.3), (4.0, 1.1)])
        .unwrap();
    // Negative control: in its own store it is read.
    c.write(&a.join(FILE_NAME)).unwrap();
    assert_eq!(ooc_calibration::of_store(&a).unwrap(), Some(c));
    let info = terrain(&["info", a.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(text.contains("ooc-calibration.txt, measured under"), "{text}");
    assert!(!text.contains("not the default refinement's"), "{text}");

    // A file measured without the default segment floor (as every store's was before it was
    // the default): read and named, but `--error-px` takes the default's shared calibration,
    // which `terrain info` names with its floor.
    let floor = refinement.max_segment_cells;
    assert!(floor > 0, "the default refinement has a segment floor");
    let unfloored = Refinement { max_segment_cells: 0, ..refinement };
    let old =
        Calibration::fit(TerrainId::of(&store_a), unfloored, 3, &[(1.0, 0.3), (4.0, 1.1)]).unwrap();
    old.write(&a.join(FILE_NAME)).unwrap();
    let read = ooc_calibration::of_store(&a).unwrap();
    assert_eq!(read, Some(old));
    let config = OocConfig { calibration: read, ..OocConfig::default() };
    assert_eq!(config.tau_for_error_px(1.0).1, TauSource::Shared);
    let info = terrain(&["info", a.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&info.stdout);
    let r = ooc_p99_per_tau(refinement.split, floor);
    let shared = format!("segments of at most {floor} cells: tau = PX / {r},");
    assert!(text.contains("not the default refinement's") && text.contains(&shared), "{text}");

    c.write(&b.join(FILE_NAME)).unwrap();
    let e = ooc_calibration::of_store(&b).unwrap_err();
    assert!(matches!(e, CalibrationError::Foreign { .. }), "{e}");
    let msg = e.to_string();
    assert!(msg.contains(&b.join(FILE_NAME).display().to_string()), "{msg}");
    assert!(msg.contains("129 x 129") && msg.contains("257 x 257"), "{msg}");
    let info = terrain(&["info", b.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(text.contains("refused") && text.contains("another store"), "{text}");

    std::fs::write(a.join(FILE_NAME), "terrain-ooc-calibration 1\nterrain 129 129 5\n").unwrap();
    let msg = ooc_calibration::of_store(&a).unwrap_err().to_string();
    assert!(msg.contains("ooc-calibration.txt:2") && msg.contains("takes 4 values"), "{msg}");
}

/// `terrain calibrate` writes the file a later `of_store` reads (and `-o` elsewhere); a folder
/// that is not a store and a bad option are refused by name; `terrain bake --calibrate` writes
/// it with the store, `--no-calibration` does not (and the default skips a small grid).
#[test]
fn the_commands_write_and_refuse() {
    let root = scratch("ooc-calibration", "cli");
    let dir = root.join("store");
    bake_store(&synthetic(257), 6, &dir);
    let d = dir.to_str().unwrap();
    let out = terrain(&["calibrate", d, "--frames", "2"]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}{}", String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains("--error-px 1: tau"), "{stdout}");
    assert!(ooc_calibration::of_store(&dir).unwrap().is_some());
    let other = root.join("elsewhere.txt");
    let out = terrain(&["calibrate", d, "--frames", "2", "-o", other.to_str().unwrap()]);
    assert!(out.status.success() && other.is_file());
    // Too small a terrain (drawn exactly at every tau) is refused, saying why.
    let tiny = root.join("tiny");
    bake_store(&synthetic(129), 5, &tiny);
    let out = terrain(&["calibrate", tiny.to_str().unwrap(), "--taus", "0.5,1", "--frames", "1"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("at least 2 measured points"), "{err}");
    assert!(!tiny.join(FILE_NAME).exists());

    let out = terrain(&["calibrate", root.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("is not a baked store"), "{err}");
    // A store at a URL is named as one (the calibration is written into a local folder); no
    // server is needed to refuse it.
    let out = terrain(&["calibrate", "http://127.0.0.1:9/store"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("is a store at a URL"), "{err}");
    let out = terrain(&["calibrate", d, "--ooc-split", "roam"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--ooc-split must be eq7 or cost"), "{err}");

    // `bench --ooc-calibration` without `--error-px` would be unused: refused.
    let flight = Path::new(env!("CARGO_MANIFEST_DIR")).join("../flights/pvps_884.json");
    let out = terrain(&[
        "bench",
        "--flight",
        flight.to_str().unwrap(),
        "--methods",
        "ooc",
        "--ooc-calibration",
        "shared",
        "--no-render",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("give --error-px too"), "{err}");

    for (flag, written) in [("--calibrate", true), ("--no-calibration", false), ("", false)] {
        let out_dir = root.join(format!("baked{}", flag.replace('-', "_")));
        let o = out_dir.to_str().unwrap();
        let mut args =
            vec!["bake", "--synthetic", "257", "--block-k", "6", "-o", o, "--no-pvs", "--no-dss"];
        args.extend(["--no-roughness", "--no-geomip"]);
        if !flag.is_empty() {
            args.push(flag);
        }
        let out = terrain(&args);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        assert_eq!(out_dir.join(FILE_NAME).is_file(), written, "bake {flag}");
    }
}
