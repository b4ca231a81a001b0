//! Geomorph's selection from memory and from a baked store, side by side on the same cameras
//! (issue 13, item 2): the in-memory `GeomipScene` (the table and the heightmap's patch
//! quadtree) against the same `GeomipTable` read back from the store's `geomip.bin` over the
//! store's `StoreTree` (node boxes from the block index, no heights in memory). Both must
//! select the same patches (checked every frame); the figures are the median per-frame times.
//!
//! ```sh
//! cargo run --release -p terrain-app --example geomorph_store_select -- \
//!     [--synthetic 4097 | --dem FILE [--vertical-scale 0.1] [--spacing 160]] \
//!     [--flight flights/pvps_884.json] [--frames 30] [--reps 5]
//! ```
//! The store is baked into a temporary folder (exact f32 heights, `terrain bake`'s block size)
//! with the table `terrain bake` writes, and removed at the end. Cameras: the flight resolved
//! onto the grid, `--frames` frames evenly spaced, 1280 x 720; each frame is selected `--reps`
//! times by each path, alternating, and the fastest time of each kept.

mod common;

use std::ops::ControlFlow;
use std::sync::Arc;
use std::time::Instant;

use anyhow::Context;
use terrain_app::bench::median;
use terrain_app::methods::{LodMethod, MethodConfig, MethodScene};
use terrain_core::dem::{LoadOptions, load};
use terrain_core::flight::{FlightConfig, FlightSpec};
use terrain_core::lod::GeomipConfig;
use terrain_core::quadtree::NodeTree;
use terrain_core::synth::FractalConfig;
use terrain_stream::{BakeConfig, BakeProgress, HeightEncoding, Store, StoreTree, bake};

fn main() -> anyhow::Result<()> {
    let mut args = common::Args::from_env();
    let synthetic = args.take("--synthetic");
    let dem = args.take("--dem");
    let vscale: f64 = args.take("--vertical-scale").map_or(Ok(1.0), |v| v.parse())?;
    let spacing: Option<f64> = args.take("--spacing").map(|v| v.parse()).transpose()?;
    let flight = args.take("--flight").unwrap_or_else(|| "flights/pvps_884.json".into());
    let frames: usize = args.take("--frames").map_or(Ok(30), |v| v.parse())?;
    let reps: usize = args.take("--reps").map_or(Ok(5), |v| v.parse::<usize>())?.max(1);

    let (name, hm) = match (dem, synthetic) {
        (Some(path), _) => {
            let options = LoadOptions {
                vertical_scale: vscale,
                spacing_m: spacing.unwrap_or(1.0),
                ..Default::default()
            };
            let hm = load(&path, &options).with_context(|| path.clone())?.heightmap;
            (path, hm)
        }
        (None, n) => {
            let n: u64 = n.map_or(Ok(4097), |v| v.parse())?;
            let hm =
                FractalConfig::with_size(n, n, 10.0).to_heightmap().map_err(anyhow::Error::msg)?;
            (format!("synthetic {n}^2"), hm)
        }
    };
    let scene = MethodScene::new(hm, MethodConfig::default());
    let t = Instant::now();
    scene.prepare(&[LodMethod::Geomorph]);
    let prep_s = t.elapsed().as_secs_f64();

    let dir = std::env::temp_dir().join(format!("geomorph-store-select-{}", std::process::id()));
    let config =
        BakeConfig { encoding: HeightEncoding::F32, overwrite: true, ..Default::default() };
    let t = Instant::now();
    bake(&scene.hm, &dir, &config, &mut |_: &BakeProgress| ControlFlow::Continue(()))?;
    let blocks_s = t.elapsed().as_secs_f64();
    let cells = scene.geomorph_patch_cells();
    let bytes = terrain_app::geomip_scene::bake_into_scene(&scene.hm, cells, &dir)?;
    let store = Arc::new(Store::open(&dir)?);
    let tree = StoreTree::new(store, cells);
    let table = terrain_app::geomip_scene::read_for_store(tree.store(), tree.shape())?;
    // Read by pages: compared below by what it selects, frame by frame.
    let memory = scene.geomip_scene();

    let spec = FlightSpec::load(&flight).with_context(|| format!("flight {flight}"))?;
    let (resolved, _) = spec.resolve(&scene.hm, &FlightConfig::default());
    let all = resolved.frames();
    let step = (all.len() / frames.max(1)).max(1);
    let cameras: Vec<_> = all.iter().step_by(step).take(frames.max(1)).cloned().collect();
    let cfg = GeomipConfig { patch_cells: cells, morph: false, ..scene.config.geomip };

    let (mut mem_ms, mut store_ms, mut patches) = (Vec::new(), Vec::new(), Vec::new());
    for (k, c) in cameras.iter().enumerate() {
        let (mut a_best, mut b_best) = (f64::INFINITY, f64::INFINITY);
        for _ in 0..reps {
            let t = Instant::now();
            let a = memory.select(c, &cfg);
            a_best = a_best.min(t.elapsed().as_secs_f64() * 1e3);
            let t = Instant::now();
            let b = table.select(&tree, c, &cfg);
            b_best = b_best.min(t.elapsed().as_secs_f64() * 1e3);
            anyhow::ensure!(a.patches == b.patches, "frame {k}: the store selects other patches");
            patches.push(a.patches.len() as f64);
        }
        mem_ms.push(a_best);
        store_ms.push(b_best);
    }
    let (m, s) = (median(mem_ms), median(store_ms));
    let (w, h) = (scene.hm.width(), scene.hm.height());
    println!(
        "{name}: {w} x {h} samples; geomip table {:.2} MB in memory ({:.2} MB file, heightmap \
         {:.1} MB), in-memory precomputation {prep_s:.2} s, store blocks {blocks_s:.2} s",
        table.memory_bytes() as f64 / 1e6,
        bytes as f64 / 1e6,
        (w * h * 4) as f64 / 1e6
    );
    println!(
        "flight {flight}: {} cameras, 1280 x 720, {reps} reps; median patches {:.0}",
        cameras.len(),
        median(patches)
    );
    println!(
        "median geomorph selection: memory {m:.3} ms, store {s:.3} ms, store / memory {:.2}x",
        s / m.max(1e-9)
    );
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}
