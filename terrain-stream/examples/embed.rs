//! Embedding terrain-stream: bake a small synthetic store, open it, drive the scheduler along
//! a camera path, select the crack-free patches to draw each frame (quadtree nodes with
//! tessellation factors that agree on every shared edge), and read a block's heights at a
//! level. Run with
//! `cargo run -p terrain-stream --example embed`.

use std::ops::ControlFlow;
use std::sync::Arc;

use terrain_core::lod::check_shared_edges;
use terrain_core::synth::FractalConfig;
use terrain_stream::glam::dvec3;
use terrain_stream::lod::DEFAULT_PATCH_CELLS;
use terrain_stream::{
    BakeConfig, BakeProgress, Camera, Store, StoreTree, StreamConfig, Streamer, bake,
    select_streamed,
};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::env::temp_dir().join(format!("terrain-stream-embed-{}", std::process::id()));
    // A 257 x 257 synthetic terrain at 10 m, streamed by rows into blocks of 65 x 65 vertices.
    let source = FractalConfig::with_size(257, 257, 10.0);
    let config = BakeConfig { k: 6, overwrite: true, ..Default::default() };
    bake(&source, &dir, &config, &mut |_: &BakeProgress| ControlFlow::Continue(()))?;

    let store = Arc::new(Store::open(&dir)?);
    let tree = StoreTree::new(store.clone(), DEFAULT_PATCH_CELLS);
    let mut streamer =
        Streamer::new(store.clone(), StreamConfig { threads: 1, ..Default::default() });
    for frame in 0..20 {
        let eye = dvec3(1280.0, 100.0 * frame as f64, 1800.0);
        let camera = Camera::from_yaw_pitch(eye, 0.0, -30.0).with_clip(1.0, 3000.0);
        let stats = streamer.update(&camera);
        // What to draw: global quadtree nodes (`node.grid_rect(tree.root_cells())` is a
        // patch's square of grid samples) with outer and inner tessellation factors.
        let sel = select_streamed(&tree, &camera, 2.0, &streamer);
        let mismatches = check_shared_edges(&sel);
        assert!(mismatches.is_empty(), "shared edges disagree: {mismatches:?}");
        let triangles: f32 = sel.patches.iter().map(|p| 2.0 * p.inner[0] * p.inner[1]).sum();
        println!(
            "frame {frame}: {} visible blocks, {} synchronous loads, {} bytes resident, \
             {} patches (about {triangles} triangles), crack-free",
            stats.blocks_visible,
            stats.sync_loads,
            stats.resident_bytes,
            sel.patches.len()
        );
    }
    streamer.finish_loads();
    // The nearest visible block's heights at level 2: a 5 x 5 grid, south row first.
    let nearest = streamer.scheduled()[0].block;
    let levels = streamer.block(nearest).expect("a visible block is resident");
    let grid = levels.grid(2).expect("levels 0..=2 are resident");
    println!("block {nearest}, level 2: {grid:?}");
    drop(streamer);
    std::fs::remove_dir_all(&dir)?;
    Ok(())
}
