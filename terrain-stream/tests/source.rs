//! A store as every LOD method's terrain (`StoreSource`): its nodes are the heightmap
//! quadtree's nodes (same rectangles, boxes and finest level), its heights at grid samples are
//! the heightmap's once the levels are resident, and so the PVPS and DSS selections over the
//! store equal those over the heightmap it was baked from, patch for patch; before the levels
//! arrive the heights are the coarse lattice's, never a panic or a hole. Tried on a square
//! grid, a non-square grid with voids, and a grid smaller than a block.

mod common;

use std::ops::ControlFlow;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use glam::{DVec2, dvec3};
use terrain_core::geometry::Camera;
use terrain_core::heightmap::{Heightmap, VoidMask, bilinear_clamped};
use terrain_core::lod::{
    ConstantField, DssConfig, DssErrorTable, GridSource, PvpsConfig, Selection, TerrainSource,
    select_dss_power_of_two, select_dss_uniform, select_pvps,
};
use terrain_core::quadtree::{NodeId, NodeSource, NodeTree, Quadtree};
use terrain_core::{Georef, dem::voids::fill_voids};

use terrain_stream::{
    BakeConfig, HeightEncoding, Store, StoreSource, StoreTree, StreamConfig, Streamer, bake,
    demand_of,
};

/// `name`, not yet made, in a temporary folder of its own, removed when dropped (also when
/// the test panics).
fn scratch(name: &str) -> common::Scratch {
    common::scratch("terrain-stream-source-", name)
}

/// Integer heights (lossless with 1 m steps), optionally with a void hole filled like a DEM's.
fn terrain(w: usize, h: usize, voids: bool) -> Heightmap {
    let hm = Heightmap::from_fn(w, h, Georef::local(10.0), |i, j| {
        let (x, y) = (i as f32, j as f32);
        (300.0 + 150.0 * (x * 0.05).sin() * (y * 0.04).cos() + ((i * 7 + j * 13) % 11) as f32)
            .round()
    })
    .unwrap();
    if !voids {
        return hm;
    }
    let mut mask = VoidMask::new(w, h);
    for j in h / 3..h / 2 {
        for i in w / 4..w / 2 {
            mask.set(i, j, true);
        }
    }
    let mut data = hm.data().to_vec();
    fill_voids(w, h, &mut data, &mask).unwrap();
    // Filled heights kept on the 1 m lattice, so the store stays lossless.
    let data = data.iter().map(|z| z.round()).collect();
    Heightmap::new(w, h, data, mask, hm.georef().clone()).unwrap()
}

fn bake_store(hm: &Heightmap, name: &str, k: u8) -> (common::Scratch, Arc<Store>) {
    let dir = scratch(name);
    let cfg = BakeConfig {
        k,
        encoding: HeightEncoding::Quantized { step_m: 1.0, offset_m: 0.0 },
        ..Default::default()
    };
    let r = bake(hm, &dir, &cfg, &mut |_: &terrain_stream::BakeProgress| ControlFlow::Continue(()))
        .unwrap();
    assert!(r.lossless);
    let store = Arc::new(Store::open(&dir).unwrap());
    (dir, store)
}

fn cameras(hm: &Heightmap) -> Vec<Camera> {
    let (w, h) = (hm.width() as f64 * 10.0, hm.height() as f64 * 10.0);
    [
        (0.1, 0.1, 500.0, 45.0, -20.0),
        (0.5, -0.2, 900.0, 0.0, -35.0),
        (0.9, 0.8, 300.0, 225.0, -15.0),
        (0.5, 0.5, 4000.0, 10.0, -80.0),
    ]
    .iter()
    .map(|&(x, y, z, yaw, pitch)| {
        Camera::from_yaw_pitch(dvec3(x * w, y * h, z), yaw, pitch)
            .with_viewport(640.0, 360.0)
            .with_clip(1.0, 4.0 * (w + h))
    })
    .collect()
}

/// Loads every level of every block (the whole store is the demand).
fn warm_all(streamer: &mut Streamer, store: &Store, camera: &Camera) {
    let k = store.header().k;
    streamer.set_demand(Some(store.block_ids().map(|b| (b, k)).collect()));
    let w = streamer.wait_until_resident(camera, Duration::from_secs(60));
    assert!(w.resident, "every level loads");
}

fn same_nodes(qt: &Quadtree, tree: &StoreTree) {
    assert_eq!(qt.shape(), tree.shape(), "the same quadtree geometry");
    for level in 0..=qt.max_level() {
        let side = 1u32 << level;
        for j in 0..side {
            for i in 0..side {
                let n = NodeId::new(level, i, j);
                let (a, b) = (qt.node_info(n), tree.node_info(n));
                assert_eq!(a.is_some(), b.is_some(), "{n:?} exists in both or neither");
                if let (Some(a), Some(b)) = (a, b) {
                    assert_eq!(a.rect, b.rect, "{n:?}");
                    assert_eq!(a.aabb, b.aabb, "{n:?}");
                    assert_eq!(a.cells, b.cells, "{n:?}");
                    assert_eq!(a.is_finest, b.is_finest, "{n:?}");
                }
            }
        }
    }
}

fn selections(src: &dyn TerrainSource, table: &DssErrorTable, camera: &Camera) -> Vec<Selection> {
    let pvps = PvpsConfig { leaf_cells: 16, max_level: 30, ..PvpsConfig::default() };
    let dss = DssConfig { leaf_cells: 16, uniform_block_cells: 64, ..DssConfig::default() };
    vec![
        select_pvps(src, camera, &ConstantField(120.0), &pvps),
        select_pvps(src, camera, &|n: NodeId| (n.i * 37 + n.j * 11) as f32 % 255.0, &pvps),
        select_dss_power_of_two(src, camera, table, &dss),
        select_dss_uniform(src, camera, table, &dss),
    ]
}

/// Grid points every few samples, the last row and column included, on samples, halfway
/// and at a quarter between them, and off the grid.
fn heights_probe(w: usize, h: usize) -> Vec<DVec2> {
    let mut points = Vec::new();
    for y in (0..h).step_by(5).chain([h - 1]) {
        for x in (0..w).step_by(3).chain([w - 1]) {
            for (dx, dy) in [(0.0, 0.0), (0.5, 0.0), (0.0, 0.25), (0.25, 0.75)] {
                points.push(DVec2::new(x as f64 + dx, y as f64 + dy));
            }
        }
    }
    points.extend([
        DVec2::new(-1.0, 2.0),
        DVec2::new(w as f64 + 3.0, h as f64),
        DVec2::new(1e12, 5.0),
        DVec2::new(3.0, f64::from(u32::MAX)),
    ]);
    points
}

fn check_grid(w: usize, h: usize, voids: bool, k: u8, name: &str) {
    let hm = terrain(w, h, voids);
    let qt = Quadtree::new(&hm, 16);
    let (_dir, store) = bake_store(&hm, name, k);
    let tree = StoreTree::new(store.clone(), 16);
    same_nodes(&qt, &tree);

    let table = DssErrorTable::new(&hm, &qt);
    let memory = GridSource::new(&qt, &hm);
    let mut streamer =
        Streamer::new(store.clone(), StreamConfig { threads: 1, ..Default::default() });
    let cams = cameras(&hm);

    // Before anything is resident: heights come from what there is, selections still work.
    streamer.update(&cams[0]);
    let cold = StoreSource::new(&tree, &streamer);
    let sel = selections(&cold, &table, &cams[0]);
    assert!(sel.iter().all(|s| !s.patches.is_empty()), "{name}: cold selections draw");
    assert!(!demand_of(&tree, &sel[0], true).is_empty());
    // Heights on and between grid samples are the bilinear mean of `sample` (a sample off
    // the last row and column is read alone: the same value), bit for bit, also while the
    // blocks are coarse.
    let points = heights_probe(w, h);
    for &g in &points {
        let want = bilinear_clamped(w, h, g.x, g.y, |i, j| cold.sample(i as u32, j as u32));
        assert_eq!(cold.height(g).to_bits(), want.to_bits(), "{name}: cold height at {g}");
    }

    warm_all(&mut streamer, &store, &cams[0]);
    let warm = StoreSource::new(&tree, &streamer);
    // Every sample equals the heightmap's (the store is lossless).
    for y in (0..h as u32).step_by(3) {
        for x in 0..w as u32 {
            assert_eq!(warm.sample(x, y), hm.get(x as usize, y as usize), "{name}: ({x}, {y})");
        }
    }
    let g = DVec2::new(w as f64 * 0.37, h as f64 * 0.61);
    assert_eq!(warm.height(g), memory.height(g), "{name}: bilinear heights agree");
    for &g in &points {
        assert_eq!(warm.height(g).to_bits(), memory.height(g).to_bits(), "{name}: height at {g}");
    }
    for camera in &cams {
        let a = selections(&memory, &table, camera);
        let b = selections(&warm, &table, camera);
        for (m, (x, y)) in a.iter().zip(&b).enumerate() {
            assert!(!x.patches.is_empty(), "{name}: method {m} draws");
            assert_eq!(x.patches, y.patches, "{name}: method {m} selects the same patches");
        }
        // The demand covers every block a patch lies in.
        let demand = demand_of(&tree, &b[0], true);
        for p in &b[0].patches {
            if let Some((blk, _)) = tree.block_of(p.node) {
                assert!(demand.iter().any(|&(d, _)| d == blk), "{name}: {blk:?} demanded");
            }
        }
        assert!(demand.iter().all(|&(_, l)| l <= store.header().k));
    }
    drop(streamer);
}

#[test]
fn a_square_store_selects_like_its_heightmap() {
    check_grid(513, 513, false, 7, "square");
}

#[test]
fn a_non_square_store_with_voids_selects_like_its_heightmap() {
    check_grid(327, 468, true, 6, "voids");
}

#[test]
fn a_grid_smaller_than_a_block_selects_like_its_heightmap() {
    check_grid(100, 70, false, 8, "small");
}

/// `bake_file` bakes a DEM file in one call (here an SRTM .hgt tile and a GeoTIFF with voids
/// that need `--nodata`), losslessly for integer sources, and the store reads back each
/// file's valid samples exactly (filled voids within the recorded bound).
#[test]
fn a_dem_file_bakes_in_one_call() {
    use terrain_core::dem::{LoadOptions, load};
    let data = std::env::var_os("TERRAIN_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"));
    for (file, nodata) in
        [("srtm/N52E008.hgt", None), ("crater_lake/craterlake-elev-16bit-30m.tif", Some(-32767.0))]
    {
        let path = data.join(file);
        assert!(path.exists(), "test data {} is missing (set TERRAIN_DATA)", path.display());
        let options = LoadOptions { nodata, ..LoadOptions::default() };
        let dir = scratch(&format!("file-{}", file.replace('/', "-")));
        let config = BakeConfig { k: 6, ..Default::default() };
        let report = terrain_stream::bake_file(&path, &options, &dir, &config, &mut |_| {
            ControlFlow::Continue(())
        })
        .unwrap();
        assert!(report.lossless, "{file}: integer heights are stored exactly");
        let hm = load(&path, &options).unwrap().heightmap;
        let store = Arc::new(Store::open(&dir).unwrap());
        let tree = StoreTree::new(store.clone(), 16);
        let mut streamer =
            Streamer::new(store.clone(), StreamConfig { threads: 1, ..Default::default() });
        warm_all(&mut streamer, &store, &cameras(&hm)[0]);
        let src = StoreSource::new(&tree, &streamer);
        // Exact at every valid sample; filled void samples are stored on the integer lattice
        // too, within the bound the header records.
        let void_bound = store.header().max_void_error_m;
        assert!(void_bound <= 0.5, "{file}: {void_bound}");
        let mut valid = 0;
        for y in (0..hm.height() as u32).step_by(7) {
            for x in (0..hm.width() as u32).step_by(5) {
                let (a, b) = (src.sample(x, y), hm.get(x as usize, y as usize));
                if hm.voids().get(x as usize, y as usize) {
                    assert!(f64::from((a - b).abs()) <= void_bound + 1e-6, "{file} ({x}, {y})");
                } else {
                    assert_eq!(a, b, "{file} ({x}, {y})");
                    valid += 1;
                }
            }
        }
        assert!(valid > 1000, "{file}: {valid} samples compared");
        drop(streamer);
        let missing = terrain_stream::bake_file(
            &data.join("no/such.tif"),
            &options,
            &dir,
            &config,
            &mut |_| ControlFlow::Continue(()),
        )
        .unwrap_err();
        assert!(missing.to_string().contains("such.tif"), "{missing}");
    }
}
