//! Embedding terrain-stream: bake a small synthetic store, open it, drive the scheduler along
//! a camera path in real time (no frame waits for I/O after the first), select the crack-free
//! patches to draw each frame (quadtree nodes with tessellation factors that agree on every
//! shared edge), wait until the last frame's needed levels are resident, and read a block's
//! heights at a level. Run with
//! `cargo run -p terrain-stream --example embed` (a synthetic terrain), or with a DEM file's
//! path after `--` (baked in one call by `bake_file`).

use std::ops::ControlFlow;
use std::sync::Arc;
use std::time::Duration;

use terrain_core::lod::check_shared_edges;
use terrain_core::synth::FractalConfig;
use terrain_stream::glam::dvec3;
use terrain_stream::{
    BakeConfig, BakeProgress, Camera, DEFAULT_PATCH_CELLS, Store, StoreTree, StreamConfig,
    Streamer, bake, bake_file, select_streamed,
};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::env::temp_dir().join(format!("terrain-stream-embed-{}", std::process::id()));
    let config = BakeConfig { k: 6, overwrite: true, ..Default::default() };
    let mut progress = |_: &BakeProgress| ControlFlow::Continue(());
    match std::env::args_os().nth(1) {
        // A DEM file (GeoTIFF, .hgt, PNG, ...) in one call; large GeoTIFFs stream by rows.
        Some(path) => {
            let options = terrain_core::dem::LoadOptions::default();
            bake_file(path.as_ref(), &options, &dir, &config, &mut progress)?;
        }
        // A 257 x 257 synthetic terrain at 10 m, streamed by rows into blocks of 65 x 65
        // vertices.
        None => {
            let source = FractalConfig::with_size(257, 257, 10.0);
            bake(&source, &dir, &config, &mut progress)?;
        }
    }

    let store = Arc::new(Store::open(&dir)?);
    let tree = StoreTree::new(store.clone(), DEFAULT_PATCH_CELLS);
    let mut streamer =
        Streamer::new(store.clone(), StreamConfig { threads: 1, ..Default::default() });
    // A camera path northwards over the middle of the grid, looking north and down.
    let h = store.header();
    let (w, n) = ((h.width - 1) as f64, (h.height - 1) as f64);
    let lo = h.georef.grid_to_world(dvec3(0.0, 0.0, 0.0).truncate());
    let hi = h.georef.grid_to_world(dvec3(w, n, 0.0).truncate());
    let (size, top) = (
        (hi - lo).abs().max_element(),
        store
            .block_ids()
            .filter_map(|b| store.entry(b))
            .map(|e| f64::from(e.max))
            .fold(0.0, f64::max),
    );
    let at = |t: f64| dvec3(0.5 * (lo.x + hi.x), lo.y + t * (hi.y - lo.y), top + 0.7 * size);
    let mut camera = Camera::from_yaw_pitch(at(0.0), 0.0, -30.0);
    for frame in 0..20 {
        camera =
            Camera::from_yaw_pitch(at(frame as f64 / 40.0), 0.0, -30.0).with_clip(1.0, 3.0 * size);
        let stats = streamer.update(&camera);
        // What to draw: global quadtree nodes (`node.grid_rect(tree.root_cells())` is a
        // patch's square of grid samples) with outer and inner tessellation factors.
        let sel = select_streamed(&tree, &camera, 2.0, &streamer);
        let mismatches = check_shared_edges(&sel);
        assert!(mismatches.is_empty(), "shared edges disagree: {mismatches:?}");
        let triangles: f32 = sel.patches.iter().map(|p| 2.0 * p.inner[0] * p.inner[1]).sum();
        println!(
            "frame {frame}: {} visible blocks, {} synchronous loads, late {} bytes ({} blocks), \
             {} bytes resident, {} patches (about {triangles} triangles), crack-free",
            stats.blocks_visible,
            stats.sync_loads,
            stats.late_bytes,
            stats.late_blocks,
            stats.resident_bytes,
            sel.patches.len()
        );
    }
    // Warm on purpose: every level the last frame's visible blocks need becomes resident.
    let warm = streamer.wait_until_resident(&camera, Duration::from_secs(60));
    println!(
        "waited {:.1} ms: every needed level resident: {}",
        warm.stats.wait_time.as_secs_f64() * 1e3,
        warm.resident
    );
    // The nearest visible block's heights at its needed level, south row first.
    let nearest = streamer.scheduled()[0];
    let levels = streamer.block(nearest.block).expect("a visible block is resident");
    println!(
        "block {}: needs levels 0..={}, {} resident",
        nearest.block,
        nearest.needed,
        levels.count()
    );
    let grid = levels.grid(nearest.needed).expect("the needed levels are resident");
    println!("block {}, level {}: {} heights", nearest.block, nearest.needed, grid.len());
    drop(streamer);
    std::fs::remove_dir_all(&dir)?;
    Ok(())
}
