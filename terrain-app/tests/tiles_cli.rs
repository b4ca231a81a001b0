//! End-to-end tests of `terrain tiles`: tilesets decoded by an independent decoder,
//! `@loaders.gl/terrain`'s quantized-mesh loader under node (tests/quantized_mesh/check.mjs,
//! installed from the npm registry into the git-ignored tests/quantized_mesh/node_modules by
//! tests/quantized_mesh/install.sh, which `.ci/run` calls and this test calls when it is missing),
//! checked against the DEM they were built from, with negative controls: a wrong bound and a
//! corrupted tile must fail the check.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::{data, terrain};
use terrain_core::Heightmap;
use terrain_core::dem::{self, LoadOptions};

/// The checker's folder, with its npm packages installed (once per test process: the tests of
/// this file run in parallel, and two `npm ci` in one folder at once fail).
fn checker() -> PathBuf {
    static INSTALLED: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    INSTALLED.get_or_init(install_checker).clone()
}

fn install_checker() -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/quantized_mesh");
    if !dir.join("node_modules/@loaders.gl/terrain/package.json").exists() {
        let out = Command::new("bash")
            .arg(dir.join("install.sh"))
            .output()
            .expect("bash runs tests/quantized_mesh/install.sh");
        assert!(
            out.status.success(),
            "installing @loaders.gl/terrain with npm failed (node 20 and the npm registry are \
             needed): {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    dir
}

/// Writes the grid the tiles were built from as check.mjs reads it.
fn write_dem(hm: &Heightmap, path: &Path) {
    let g = hm.georef();
    let voids: Vec<usize> = (0..hm.width() * hm.height())
        .filter(|&k| hm.voids().get(k % hm.width(), k / hm.width()))
        .collect();
    let json = serde_json::json!({
        "width": hm.width(),
        "height": hm.height(),
        "origin": [g.native_origin.x, g.native_origin.y],
        "spacing": [g.native_spacing.x, g.native_spacing.y],
        "heights": hm.data(),
        "voids": voids,
    });
    std::fs::write(path, json.to_string()).unwrap();
}

fn check(tiles: &Path, dem: &Path, scale: &str, factor: &str) -> Output {
    Command::new("node")
        .arg(checker().join("check.mjs"))
        .args([tiles.to_str().unwrap(), dem.to_str().unwrap(), scale, factor])
        .output()
        .expect("node runs (node 20 is needed for this test)")
}

fn tile_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = common::files_under(dir);
    out.retain(|p| p.extension().is_some_and(|x| x == "terrain"));
    out
}

/// `terrain tiles SRC EXTRA... --quiet -o OUT`, which must succeed: its `tiles.json`.
fn tileset(src: &Path, extra: &[&str], out: &Path) -> serde_json::Value {
    let mut a = vec!["tiles", src.to_str().unwrap()];
    a.extend_from_slice(extra);
    a.extend_from_slice(&["--quiet", "-o", out.to_str().unwrap()]);
    let run = terrain(&a);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    serde_json::from_slice(&std::fs::read(out.join("tiles.json")).unwrap()).unwrap()
}

#[test]
fn crater_lake_tiles_decode_with_loaders_gl_within_their_bounds() {
    let src = data("crater_lake/craterlake-elev-16bit-30m.tif");
    let dir = common::scratch("tiles-cli", "crater");
    let tiles = dir.join("tiles");
    let summary = tileset(&src, &["--nodata", "-32767", "--error-scale", "0.5"], &tiles);
    let files = tile_files(&tiles);
    assert_eq!(summary["tiles"].as_u64().unwrap() as usize, files.len());
    assert!(files.len() > 20, "{} tiles", files.len());
    // The same grid, read as the command read it.
    let options = LoadOptions { nodata: Some(-32767.0), ..LoadOptions::default() };
    let hm = dem::load(&src, &options).unwrap().heightmap;
    assert!(hm.voids().any(), "crater lake has voids: they must be skipped, not measured");
    let dem_json = dir.join("dem.json");
    write_dem(&hm, &dem_json);

    let ok = check(&tiles, &dem_json, "0.5", "1");
    let said = String::from_utf8_lossy(&ok.stdout);
    assert!(ok.status.success(), "{said}\n{}", String::from_utf8_lossy(&ok.stderr));
    let report: serde_json::Value = serde_json::from_str(said.trim()).unwrap();
    assert_eq!(report["tiles"].as_u64().unwrap() as usize, files.len());
    let samples = report["samples"].as_u64().unwrap() as usize;
    let non_void = hm.width() * hm.height() - hm.voids().count();
    assert!(samples >= non_void, "every non-void sample is checked at least once: {samples}");
    let worst = report["worstErrorOverBound"].as_f64().unwrap();
    // Above 1 only by the quantization slack the checker allows per sample.
    assert!(worst > 0.5 && worst < 1.1, "the bound is used, not exceeded: {worst}");

    // Negative control 1: a quarter of the bound must be exceeded somewhere.
    let tight = check(&tiles, &dem_json, "0.5", "0.25");
    assert!(!tight.status.success(), "a quarter of the bound passed");
    assert!(String::from_utf8_lossy(&tight.stderr).contains("m off"));

    // Negative control 2: the finest tile with the most triangles (real relief, not void fill)
    // gets its first height delta changed: every height of the tile moves, which the check
    // must see.
    let finest = summary["max_level"].as_u64().unwrap().to_string();
    let victim = files
        .iter()
        .filter(|p| {
            p.strip_prefix(&tiles).unwrap().components().next().unwrap().as_os_str()
                == finest.as_str()
        })
        .max_by_key(|p| {
            let b = std::fs::read(p).unwrap();
            terrain_core::tin::quantized_mesh::decode(&b).unwrap().triangles.len()
        })
        .expect("a finest tile");
    let mut bytes = std::fs::read(victim).unwrap();
    let n = u32::from_le_bytes(bytes[88..92].try_into().unwrap()) as usize;
    let first_height = 92 + 4 * n;
    bytes[first_height..first_height + 2].copy_from_slice(&10_000u16.to_le_bytes());
    std::fs::write(victim, &bytes).unwrap();
    let bad = check(&tiles, &dem_json, "0.5", "1");
    assert!(!bad.status.success(), "a corrupted tile passed: {}", victim.display());
}

/// `--mesher auto` (the default) meshes a full-resolution tile as an RTIN where its parent kept
/// at least `--rtin-density` (0.5) of its samples: on Crater Lake at a tenth of Cesium's bounds
/// that is some of the finest level's tiles and none of the coarse levels' (whose tiles are
/// decimated or whose parents kept few samples), and every tile, of either mesher, is within
/// its bound of every DEM sample by the independent decoder, its edge indices on its borders
/// (where skirts hang: neighbours of different meshers are closed as any two neighbours are).
/// Negative controls: a threshold above 1 gives no RTIN tile (and the fewest triangles), and a
/// quarter of the bound fails.
#[test]
fn auto_meshes_the_dense_fine_tiles_as_rtins_within_their_bounds() {
    let src = data("crater_lake/craterlake-elev-16bit-30m.tif");
    let dir = common::scratch("tiles-cli", "auto");
    let run = |name: &str, extra: &[&str]| {
        let tiles = dir.join(name);
        let mut a = vec!["--nodata", "-32767", "--error-scale", "0.1"];
        a.extend_from_slice(extra);
        let summary = tileset(&src, &a, &tiles);
        (tiles, summary)
    };
    let rtin_per_level = |s: &serde_json::Value| -> Vec<(u64, u64)> {
        let levels = s["levels"].as_array().unwrap();
        levels
            .iter()
            .map(|l| (l["rtin_tiles"].as_u64().unwrap(), l["tiles"].as_u64().unwrap()))
            .collect()
    };
    let (tiles, auto) = run("auto", &[]);
    assert_eq!(auto["mesher"], "auto");
    assert_eq!(auto["rtin_density"], 0.5);
    let per_level = rtin_per_level(&auto);
    let &(finest_rtin, finest_tiles) = per_level.last().unwrap();
    assert!(finest_rtin > 0 && finest_rtin < finest_tiles, "{per_level:?}");
    assert!(per_level[..10].iter().all(|&(r, _)| r == 0), "{per_level:?}");
    // The rule's figure: where a level has RTIN tiles, its parent level kept many samples.
    let levels = auto["levels"].as_array().unwrap();
    for w in levels.windows(2) {
        let density = w[0]["vertices"].as_f64().unwrap() / w[0]["samples"].as_f64().unwrap();
        if w[1]["rtin_tiles"].as_u64().unwrap() > 0 {
            assert!(density > 0.3, "level {} kept {density} of its samples", w[0]["level"]);
        }
    }

    let options = LoadOptions { nodata: Some(-32767.0), ..LoadOptions::default() };
    let hm = dem::load(&src, &options).unwrap().heightmap;
    let dem_json = dir.join("dem.json");
    write_dem(&hm, &dem_json);
    let ok = check(&tiles, &dem_json, "0.1", "1");
    assert!(ok.status.success(), "{}", String::from_utf8_lossy(&ok.stderr));
    let tight = check(&tiles, &dem_json, "0.1", "0.25");
    assert!(!tight.status.success(), "a quarter of the bound passed");

    let (_, greedy) = run("never", &["--rtin-density", "2"]);
    assert!(rtin_per_level(&greedy).iter().all(|&(r, _)| r == 0), "{greedy}");
    let tris = |s: &serde_json::Value| s["triangles"].as_u64().unwrap();
    assert!(tris(&greedy) < tris(&auto), "{} >= {}", tris(&greedy), tris(&auto));
    assert_eq!(greedy["tiles"], auto["tiles"]);
}

#[test]
fn a_utm_dem_is_reprojected_and_a_dem_without_georeference_needs_lonlat() {
    let src = data("lidar_prairie/dem.tif");
    let dir = common::scratch("tiles-cli", "prairie");
    let tiles = dir.join("tiles");
    let out = terrain(&[
        "tiles",
        src.to_str().unwrap(),
        "--gzip",
        "--quiet",
        "-o",
        tiles.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stderr).contains("reprojected EPSG:26915 to EPSG:4326"));
    let any = &tile_files(&tiles)[0];
    assert!(terrain_core::tin::quantized_mesh::is_gzip(&std::fs::read(any).unwrap()));
    let hm = dem::load(&src, &LoadOptions::default()).unwrap().heightmap;
    let geo = terrain_core::tin::warp::to_geographic(&hm).unwrap();
    let dem_json = dir.join("dem.json");
    write_dem(&geo, &dem_json);
    let ok = check(&tiles, &dem_json, "1", "1");
    assert!(ok.status.success(), "{}", String::from_utf8_lossy(&ok.stderr));

    let png = data("puget_sound/ps_height_1k.png");
    let png = png.to_str().unwrap();
    let refused = terrain(&["tiles", png, "-o", dir.join("ps").to_str().unwrap()]);
    assert!(!refused.status.success());
    let why = String::from_utf8_lossy(&refused.stderr);
    assert!(why.contains("no georeference") && why.contains("--lonlat"), "{why}");
    let placed = terrain(&[
        "tiles",
        png,
        "--spacing",
        "160",
        "--vertical-scale",
        "0.1",
        "--lonlat=-122.9,46.1",
        "--max-level",
        "8",
        "--quiet",
        "-o",
        dir.join("ps").to_str().unwrap(),
    ]);
    assert!(placed.status.success(), "{}", String::from_utf8_lossy(&placed.stderr));
    let layer: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("ps/layer.json")).unwrap()).unwrap();
    let b: Vec<f64> =
        layer["bounds"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    assert!((b[0] + 122.9).abs() < 1e-9 && (b[1] - 46.1).abs() < 1e-9, "{b:?}");
    // 1024 samples of 160 m: about 2.2 degrees of longitude and 1.5 of latitude there.
    assert!((b[2] - b[0] - 2.2).abs() < 0.2 && (b[3] - b[1] - 1.47).abs() < 0.1, "{b:?}");
}

/// The `.terrain` files under `dir`, relative, with their bytes.
/// A decimated tile is meshed within at least three quarters of its bound (the budget floor),
/// so a coarse level never costs a client more triangles than the level below it. With a
/// floor of a quarter (the default before) Everest's level 6 had 4,146 triangles in one tile
/// and level 7 2,864 in one.
#[test]
fn a_coarser_level_never_has_more_triangles_than_the_next_finer_one() {
    let src = data("srtm/mt_everest_90m.tif");
    let dir = common::scratch("tiles-cli", "monotone");
    let summary = tileset(&src, &["--max-level", "10"], &dir.join("everest"));
    assert_eq!(summary["min_budget_fraction"], 0.75);
    assert!(summary["decimated_tiles"].as_u64().unwrap() > 0, "{summary}");
    let levels = summary["levels"].as_array().unwrap();
    let per_level: Vec<u64> = levels.iter().map(|l| l["triangles"].as_u64().unwrap()).collect();
    assert_eq!(per_level.len(), 11);
    // From level 1: level 0 has the globe's two root tiles, the one without the DEM two
    // triangles of its own.
    for (l, w) in per_level.windows(2).enumerate().skip(1) {
        assert!(w[0] <= w[1], "level {l} has more triangles than level {}: {per_level:?}", l + 1);
    }
}

fn tileset_bytes(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out: Vec<(PathBuf, Vec<u8>)> = tile_files(dir)
        .into_iter()
        .map(|p| (p.strip_prefix(dir).unwrap().to_path_buf(), std::fs::read(&p).unwrap()))
        .collect();
    out.sort();
    out
}

#[test]
fn a_store_gives_the_tileset_of_its_dem_in_memory_within_its_cache() {
    // SRTM N52E008: 1201^2 int16 samples in degrees, baked losslessly. It has a few voids: the
    // store holds the reader's fill there, the DEM in memory the same fill under a void mask
    // (which only keeps them out of the meshes' checks); the tiles come out the same here.
    let src = data("srtm/N52E008.hgt");
    let hm = dem::load(&src, &LoadOptions::default()).unwrap().heightmap;
    let dir = common::scratch("tiles-cli", "store");
    let store = dir.join("store");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let baked = terrain(&[
        "bake",
        &s(&src),
        "--no-dss",
        "--no-pvs",
        "--no-roughness",
        "--no-geomip",
        "--overwrite",
        "-o",
        &s(&store),
    ]);
    assert!(baked.status.success(), "{}", String::from_utf8_lossy(&baked.stderr));
    // Level 10's tiles span about 211 samples: levels 0..=9 are meshed from every 2nd..256th
    // sample and checked against every sample, level 10 from every sample.
    let run = |input: &Path, out: &Path, extra: &[&str]| {
        let mut a = vec!["tiles", input.to_str().unwrap(), "--max-level", "10", "--quiet"];
        a.extend_from_slice(extra);
        a.extend_from_slice(&["-o", out.to_str().unwrap()]);
        let o = terrain(&a);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice::<serde_json::Value>(&std::fs::read(out.join("tiles.json")).unwrap())
            .unwrap()
    };
    let (mem_dir, store_dir) = (dir.join("mem"), dir.join("from-store"));
    let mem = run(&src, &mem_dir, &[]);
    // A cache of 2 MiB: about 8 decoded blocks of 257^2 (the DEM decoded is 5.5 MiB).
    let st = run(&store, &store_dir, &["--cache", "2MiB"]);
    assert!(st["decimated_tiles"].as_u64().unwrap() > 10, "{st}");
    assert_eq!(st["min_budget_fraction"], mem["min_budget_fraction"]);
    let peak = st["cache_peak_bytes"].as_u64().unwrap();
    let block = 257 * 257 * 4;
    assert!(peak <= (2 << 20) + 2 * block, "the cache held {peak} bytes, over its 2 MiB");
    assert!(st["block_levels_decoded"].as_u64().unwrap() > 0);
    // The same tiles, byte for byte: both go through one per-tile path and the store is
    // lossless (int16 samples on their integer lattice).
    let (a, b) = (tileset_bytes(&mem_dir), tileset_bytes(&store_dir));
    assert_eq!(a.len(), mem["tiles"].as_u64().unwrap() as usize);
    assert_eq!(a.len(), b.len());
    let differ: Vec<_> = a.iter().zip(&b).filter(|(x, y)| x != y).map(|(x, _)| &x.0).collect();
    assert!(differ.is_empty(), "{} tiles differ, e.g. {:?}", differ.len(), differ.first());
    // And the independent decoder finds every tile within its bound of every DEM sample.
    let dem_json = dir.join("dem.json");
    write_dem(&hm, &dem_json);
    let ok = check(&store_dir, &dem_json, "1", "1");
    assert!(ok.status.success(), "{}", String::from_utf8_lossy(&ok.stderr));
    let report: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&ok.stdout).trim()).unwrap();
    let worst = report["worstErrorOverBound"].as_f64().unwrap();
    assert!(worst > 0.3 && worst < 1.1, "the bound is used, not exceeded: {worst}");

    // A store without a georeference needs --lonlat, as a bare heightmap does; one with a
    // georeference refuses it.
    let refused = terrain(&["tiles", &s(&store), "--lonlat=8,52", "-o", &s(&dir.join("x"))]);
    assert!(!refused.status.success());
    assert!(String::from_utf8_lossy(&refused.stderr).contains("georeferenced"));
}

/// The heights of a store at full resolution, placed as `terrain tiles --lonlat` places it.
fn store_heightmap(store: &Path, lonlat: glam::DVec2) -> Heightmap {
    let store = terrain_stream::Store::open(store).unwrap();
    let h = store.header().clone();
    let (w, ht, cells) = (h.width as usize, h.height as usize, h.block_cells() as usize);
    let blocks: Vec<terrain_stream::BlockLevels> = (0..h.blocks_y)
        .flat_map(|r| (0..h.blocks_x).map(move |c| (r, c)))
        .map(|(r, c)| store.read_block(terrain_stream::BlockId::new(r, c), h.k).unwrap())
        .collect();
    let mut data = Vec::with_capacity(w * ht);
    for j in 0..ht {
        for i in 0..w {
            let (bc, br) = (
                (i / cells).min(h.blocks_x as usize - 1),
                (j / cells).min(h.blocks_y as usize - 1),
            );
            let b = &blocks[br * h.blocks_x as usize + bc];
            data.push(b.height((i - bc * cells) as u32, (j - br * cells) as u32).unwrap());
        }
    }
    let georef = terrain_core::tin::warp::place_georef(&h.georef, (w, ht), lonlat).unwrap();
    Heightmap::new(w, ht, data, terrain_core::heightmap::VoidMask::new(w, ht), georef).unwrap()
}

#[test]
fn a_synthetic_store_is_walked_depth_first_in_bounded_memory_every_tile_within_its_bound() {
    // A synthetic 1025^2 store (10 m, rough fractal relief: the coarse levels' decimation error
    // is large), tiled to its native level 15 with a cache of 1 MiB (about 4 decoded blocks;
    // the store decoded is 4 MiB). Levels 14-15 once failed the checker: border vertices the
    // builder clips onto long mesh edges (14/5237/12426 10.0 m off the DEM where bound + cell
    // relief + quantization allowed 4.70 + 2.65 + 0.24 m). The mesh is bounded at samples only,
    // and between a clipped vertex and its cell's samples it moves by up to the triangle's
    // slope times the cell's diagonal: check.mjs now allows that term for off-sample vertices.
    let dir = common::scratch("tiles-cli", "walk");
    let store = dir.join("store");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let baked = terrain(&[
        "bake",
        "--synthetic",
        "1025",
        "--no-dss",
        "--no-pvs",
        "--no-roughness",
        "--no-geomip",
        "--overwrite",
        "-o",
        &s(&store),
    ]);
    assert!(baked.status.success(), "{}", String::from_utf8_lossy(&baked.stderr));
    let tiles = dir.join("tiles");
    let out = terrain(&[
        "tiles",
        &s(&store),
        "--lonlat=-122.5,46.5",
        "--cache",
        "1MiB",
        "--max-level",
        "15",
        "--quiet",
        "-o",
        &s(&tiles),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let sum: serde_json::Value =
        serde_json::from_slice(&std::fs::read(tiles.join("tiles.json")).unwrap()).unwrap();
    let n = |k: &str| sum[k].as_u64().unwrap_or_else(|| panic!("{k} in {sum}"));
    let files = tile_files(&tiles);
    assert_eq!(n("tiles") as usize, files.len());
    let levels = n("max_level") - n("min_level") + 1;
    // Depth first: the meshes held at once are bounded by the threads and the depth, far under
    // the tiles of the finest level (which a level-by-level build holds at once).
    let (peak, threads) = (n("peak_pending_tiles"), n("threads"));
    let finest = sum["levels"].as_array().unwrap().last().unwrap()["tiles"].as_u64().unwrap();
    assert!(
        peak >= 1 && peak <= threads * levels,
        "{peak} pending, {threads} threads, {levels} levels"
    );
    assert!(peak * 4 < finest, "{peak} pending of {finest} finest tiles");
    // The block cache stays within its budget plus a block in flight per thread.
    let block = 257 * 257 * 4;
    let cache = n("cache_peak_bytes");
    assert!(cache <= (1 << 20) + (threads + 1) * block, "the cache held {cache} bytes");
    // Decimated tiles were meshed within their bound less the measured decimation error: most
    // pass the check at once (the mesh's triangles are not the strided grid's bilinear cells,
    // so a few are rebuilt with a smaller budget), none loops.
    let decimated = n("decimated_tiles");
    assert!(decimated > 5, "{sum}");
    assert!(sum["decimation_error_m"].as_f64().unwrap() > 0.0, "{sum}");
    assert!(n("retries") <= decimated / 2, "{sum}");
    // Every tile within its bound of every sample the store holds, by the independent decoder.
    let hm = store_heightmap(&store, glam::dvec2(-122.5, 46.5));
    let dem_json = dir.join("dem.json");
    write_dem(&hm, &dem_json);
    let ok = check(&tiles, &dem_json, "1", "1");
    assert!(ok.status.success(), "{}", String::from_utf8_lossy(&ok.stderr));
    // Negative control: a quarter of the bound fails somewhere.
    let tight = check(&tiles, &dem_json, "1", "0.25");
    assert!(!tight.status.success(), "a quarter of the bound passed");
}

/// The CesiumJS check's folder, with its npm packages installed.
fn cesium_checker() -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/cesium");
    if !dir.join("node_modules/cesium/package.json").exists() {
        let out = Command::new("bash")
            .arg(dir.join("install.sh"))
            .output()
            .expect("bash runs tests/cesium/install.sh");
        assert!(
            out.status.success(),
            "installing cesium and playwright-core with npm failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    dir
}

#[test]
fn cesium_loads_a_tileset_in_headless_chromium_and_fails_on_a_missing_tile() {
    assert!(
        Path::new("/usr/bin/chromium").exists(),
        "Debian's chromium is needed (`apt-get install chromium`; .ci/run installs it)"
    );
    let dir = common::scratch("tiles-cli", "cesium");
    let tiles = dir.join("tiles");
    let out = terrain(&[
        "tiles",
        data("srtm/N52E008.hgt").to_str().unwrap(),
        "--max-level",
        "9",
        "--gzip",
        "--quiet",
        "-o",
        tiles.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let script = cesium_checker().join("check.mjs");
    let shot = dir.join("cesium.png");
    let run = || {
        Command::new("node")
            .arg(&script)
            .args([tiles.to_str().unwrap(), shot.to_str().unwrap(), "300"])
            .output()
            .expect("node runs")
    };
    let ok = run();
    let said = String::from_utf8_lossy(&ok.stdout);
    assert!(ok.status.success(), "{said}\n{}", String::from_utf8_lossy(&ok.stderr));
    let report: serde_json::Value = serde_json::from_str(said.trim()).unwrap();
    assert!(report["tilesServed"].as_u64().unwrap() >= 4, "{report}");
    assert!(report["deepestLevel"].as_i64().unwrap() >= 5, "{report}");
    // The screenshot shows lit terrain, not one flat colour.
    let img = image::open(&shot).unwrap().to_luma8();
    let (lo, hi) = img.pixels().fold((255u8, 0u8), |(lo, hi), p| (lo.min(p[0]), hi.max(p[0])));
    assert!(hi - lo > 40, "a flat screenshot: grey {lo}..{hi}");

    // Negative control: a missing root tile is a tile request error.
    std::fs::remove_file(tiles.join("0/1/0.terrain")).unwrap();
    let bad = run();
    assert!(!bad.status.success(), "a missing tile passed");
    assert!(String::from_utf8_lossy(&bad.stderr).contains("404"));
}
