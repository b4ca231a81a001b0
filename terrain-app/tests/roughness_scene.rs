//! End-to-end tests of the PVPS roughness pyramids stored with a baked scene/store:
//! `terrain bake` writes `roughness.bin` holding exactly the in-memory pyramids (Puget Sound
//! 1k), a bake by bands of rows writes the same file as the in-memory bake of the same grid
//! (synthetic, and a GeoTIFF read with `--stream`; with voids, the pyramids of the rows the
//! stream reads), the PVPS methods select the same patches with the file as without, and a
//! damaged or foreign file is refused with a message naming it.

mod common;

use std::path::{Path, PathBuf};
use std::process::Output;

use common::{data, scratch, terrain};
use glam::dvec3;
use terrain_app::methods::{LodMethod, MethodConfig, MethodScene};
use terrain_app::roughness_scene::{load_from_store, load_into, roughness_path};
use terrain_core::dem::{LoadOptions, RowReader, load};
use terrain_core::geometry::Camera;
use terrain_core::lod::dss_file::heights_checksum;
use terrain_core::{Heightmap, VoidMask};
use terrain_visibility::roughness::file::{Expected, TerrainTie, decode, decode_for};
use terrain_visibility::roughness::{RoughnessConfig, RoughnessTables};

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

fn puget() -> Heightmap {
    let opts = LoadOptions { vertical_scale: 0.1, spacing_m: 160.0, ..LoadOptions::default() };
    load(data("puget_sound/ps_height_1k.png"), &opts).unwrap().heightmap
}

/// Bakes `args` (blocks and roughness only) into `dir/name`; returns the folder and stdout.
fn bake(dir: &Path, name: &str, args: &[&str]) -> (PathBuf, String) {
    let out = dir.join(name);
    let mut a = vec!["bake"];
    a.extend(args);
    a.extend(["--no-pvs", "-o", s(&out)]);
    let (stdout, _) = ok(&terrain(&a));
    (out, stdout)
}

fn expected(hm: &Heightmap, levels: usize) -> Expected {
    Expected {
        width: hm.width(),
        height: hm.height(),
        levels,
        config: RoughnessConfig::default(),
        tie: TerrainTie::Heights(heights_checksum(hm)),
    }
}

#[test]
fn a_baked_puget_store_holds_the_in_memory_pyramids_bit_for_bit() {
    let dir = scratch("roughness", "puget");
    let dem = data("puget_sound/ps_height_1k.png");
    let mut args = vec![s(&dem)];
    args.extend(PUGET);
    args.push("--no-dss");
    let (store, stdout) = bake(&dir, "ps.scene", &args);
    assert!(stdout.contains("roughness.bin") && stdout.contains("(in memory)"), "{stdout}");

    let hm = puget();
    let scene = MethodScene::new(hm, MethodConfig::default());
    let levels = scene.qt.max_level() as usize + 1;
    assert_eq!(levels, 7, "1024 cells in leaves of 16");
    let want = RoughnessTables::compute(&scene.hm, levels, &RoughnessConfig::default());
    let bytes = std::fs::read(roughness_path(&store)).unwrap();
    let got = decode_for(&bytes, &expected(&scene.hm, levels)).unwrap();
    assert!(got.bits_eq(&want), "roughness.bin differs from the in-memory pyramids");
    assert!(want.c.level(6).iter().any(|&v| v > 0.0) && want.a.level(3).iter().any(|&v| v > 0.0));
    // Without the heightmap: tied to the store's bake id.
    let from_store = load_from_store(&store, 16).unwrap();
    assert!(from_store.bits_eq(&want));
    let e = format!("{:#}", load_from_store(&store, 8).unwrap_err());
    assert!(e.contains("roughness.bin") && e.contains("quadtree levels 7"), "{e}");

    // The PVPS methods select the same patches from the file as from their own pyramids.
    let from_file = MethodScene::new(puget(), MethodConfig::default());
    let methods = [LodMethod::PvpsA, LodMethod::PvpsB, LodMethod::PvpsC];
    let warnings = terrain_app::scene_files::load(&from_file, &store, &methods);
    assert!(warnings.is_empty(), "{warnings:?}");
    // Already set from the file: a second set is refused.
    assert!(!from_file.set_roughness(want.clone()));
    let o = scene.hm.grid_to_world(0.0, 0.0);
    let camera = Camera::look_at(
        dvec3(o.x + 30_000.0, o.y + 20_000.0, 6000.0),
        dvec3(o.x + 90_000.0, o.y + 100_000.0, 500.0),
    )
    .with_viewport(1280.0, 720.0)
    .with_clip(10.0, 400_000.0);
    for m in methods {
        let (a, b) = (scene.select(m, &camera), from_file.select(m, &camera));
        assert!(a.patches.len() > 10, "{m:?}: {} patches", a.patches.len());
        assert_eq!(a.patches, b.patches, "{m:?}");
    }
}

#[test]
fn a_bake_by_rows_writes_the_same_file_as_the_in_memory_bake() {
    let dir = scratch("roughness", "rows");
    // A synthetic grid: streamed by rows unless the DSS errors need it in memory.
    let (rows, out) = bake(&dir, "rows.scene", &["--synthetic", "300", "--no-dss"]);
    assert!(out.contains("(by bands of rows)"), "{out}");
    let (mem, out) = bake(&dir, "mem.scene", &["--synthetic", "300"]);
    assert!(out.contains("(in memory)"), "{out}");
    let a = std::fs::read(roughness_path(&rows)).unwrap();
    let b = std::fs::read(roughness_path(&mem)).unwrap();
    // `--no-dss` also leaves the DSS errors out of the store's index, so the two indexes (and
    // with them the files' tie to their store, `index_crc`) differ; everything else is equal.
    let ((mut ha, ta), (mut hb, tb)) = (decode(&a).unwrap(), decode(&b).unwrap());
    assert_ne!(ha.index_crc, hb.index_crc, "the two stores' indexes should differ (--no-dss)");
    (ha.index_crc, hb.index_crc) = (0, 0);
    assert_eq!(ha, hb);
    assert!(ta == tb, "the roughness tables by rows differ from the in-memory ones");
    assert!(ta.c.level(0)[0] > 0.0);
    // A GeoTIFF without voids, read with --stream or whole.
    let tif = data("lidar_prairie/dem.tif");
    let (rows, out) = bake(&dir, "lidar-rows", &[s(&tif), "--stream", "--no-dss"]);
    assert!(out.contains("(by bands of rows)"), "{out}");
    let (mem, out) = bake(&dir, "lidar-mem", &[s(&tif), "--no-dss"]);
    assert!(out.contains("(in memory)"), "{out}");
    assert_eq!(
        std::fs::read(roughness_path(&rows)).unwrap(),
        std::fs::read(roughness_path(&mem)).unwrap()
    );
    // --no-roughness writes none.
    let (none, _) = bake(&dir, "none", &["--synthetic", "65", "--no-dss", "--no-roughness"]);
    assert!(!roughness_path(&none).exists());
}

#[test]
fn a_streamed_bake_with_voids_holds_the_pyramids_of_the_rows_it_read() {
    // Streamed voids are filled along rows and columns (not from the whole void's rim), so
    // the reference is the in-memory pyramids of the grid the row reader gives.
    let dir = scratch("roughness", "voids");
    let tif = data("crater_lake/craterlake-elev-16bit-30m.tif");
    let (store, out) =
        bake(&dir, "crater", &[s(&tif), "--nodata", "-32767", "--stream", "--no-dss"]);
    assert!(out.contains("(by bands of rows)"), "{out}");
    let opts = LoadOptions { nodata: Some(-32767.0), ..LoadOptions::default() };
    let reader = RowReader::open(&tif, &opts).unwrap();
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
    let levels = terrain_visibility::roughness::quadtree_levels(w, h, 16);
    let want = RoughnessTables::compute(&hm, levels, &RoughnessConfig::default());
    let got = decode_for(&std::fs::read(roughness_path(&store)).unwrap(), &expected(&hm, levels))
        .unwrap();
    assert!(got.bits_eq(&want));
}

#[test]
fn damaged_or_foreign_files_are_refused_naming_the_file() {
    let dir = scratch("roughness", "bad");
    let dem = data("puget_sound/ps_height_1k.png");
    let mut args = vec![s(&dem)];
    args.extend(PUGET);
    args.push("--no-dss");
    let (store, _) = bake(&dir, "ps.scene", &args);
    let path = roughness_path(&store);
    let good = std::fs::read(&path).unwrap();
    let scene = || MethodScene::new(puget(), MethodConfig::default());
    let warn = |what: &str| {
        let w = load_into(&scene(), &store).unwrap_err();
        assert!(w.contains(s(&path)), "{what}: {w}");
        assert!(w.contains("computing the roughness pyramids in memory"), "{what}: {w}");
        let e = format!("{:#}", load_from_store(&store, 16).unwrap_err());
        assert!(e.contains(s(&path)), "{what}: {e}");
        (w, e)
    };

    // Damaged: one flipped bit.
    let mut bad = good.clone();
    bad[good.len() / 2] ^= 4;
    std::fs::write(&path, &bad).unwrap();
    let (w, e) = warn("damaged");
    assert!(w.contains("checksum mismatch") && e.contains("checksum mismatch"), "{w}\n{e}");

    // Missing.
    std::fs::remove_file(&path).unwrap();
    warn("missing");

    // Another terrain of the same size (another vertical scale): its own store's file.
    let mut args = vec![s(&dem)];
    args.extend(["--vertical-scale", "0.2", "--spacing", "160", "--no-dss"]);
    let (other, _) = bake(&dir, "ps2.scene", &args);
    std::fs::copy(roughness_path(&other), &path).unwrap();
    let (w, e) = warn("foreign");
    assert!(w.contains("heights differ"), "{w}");
    assert!(e.contains("baked for store"), "{e}");
    // The foreign file serves its own store.
    assert!(load_from_store(&other, 16).is_ok());

    // Through the CLI: a warning naming the file, and the method still runs.
    let flight = Path::new(env!("CARGO_MANIFEST_DIR")).join("../flights/pvps_884.json");
    let mut args = vec!["bench", s(&dem)];
    args.extend(PUGET);
    args.extend(["--flight", s(&flight), "--methods", "pvps-c", "--frames", "1", "--sweep", "1"]);
    args.extend(["--no-render", "-o", s(&dir), "--name", "b", "--scene", s(&store)]);
    let (_, err) = ok(&terrain(&args));
    assert!(err.contains(s(&path)) && err.contains("heights differ"), "{err}");

    // Put back, the file is read.
    std::fs::write(&path, &good).unwrap();
    assert_eq!(load_into(&scene(), &store).unwrap(), path);
}
