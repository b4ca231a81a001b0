//! Selection cost of the out-of-core method over stores of growing size: synthetic fractal
//! stores (k = 8) of 1025^2, 4097^2 and 16385^2 samples (baked once into
//! `$TMPDIR/terrain-select-bench/`), the same relative camera poses on each, every block
//! resident at its finest level (the selection alone, no I/O), `lod::select_patches` timed per
//! pose (median of repeats), at 1280 x 720. Prints, per grid and `tau`: median ms per frame,
//! patches, triangles (2 per cell of each patch's factor), and the growth from the smallest
//! grid. Also prints `--camera` strings for `terrain render <store>` at the same poses (the
//! side-by-side comparison with another build).
//!
//! `cargo run --release -p terrain-stream --example select_bench -- [SIZE ...]`

use std::ops::ControlFlow;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use terrain_core::synth::FractalConfig;
use terrain_stream::glam::dvec3;
use terrain_stream::{
    BakeConfig, BakeProgress, Camera, DEFAULT_PATCH_CELLS, Store, StoreTree, bake, select_patches,
};

fn store(size: u64) -> PathBuf {
    let dir = std::env::temp_dir().join("terrain-select-bench").join(format!("s{size}"));
    if !dir.join("index.tsi").exists() {
        let start = Instant::now();
        let src = FractalConfig::with_size(size, size, 10.0);
        let cfg = BakeConfig { k: 8, overwrite: true, ..Default::default() };
        bake(&src, &dir, &cfg, &mut |_: &BakeProgress| ControlFlow::Continue(())).unwrap();
        eprintln!("baked {size}^2 in {:.1} s", start.elapsed().as_secs_f64());
    }
    dir
}

/// Poses at fixed fractions of the extent: plan position, height above the highest block
/// (fraction of the extent), yaw, pitch.
const POSES: [([f64; 2], f64, f64, f64); 4] = [
    ([0.3, 0.3], 0.01, 45.0, -15.0),
    ([0.5, 0.1], 0.02, 0.0, -25.0),
    ([0.8, 0.6], 0.005, 250.0, -10.0),
    ([0.5, 0.5], 0.2, 30.0, -60.0),
];

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let sizes: Vec<u64> = {
        let v: Vec<u64> = std::env::args().skip(1).filter_map(|a| a.parse().ok()).collect();
        if v.is_empty() { vec![1025, 4097, 16385] } else { v }
    };
    let mut base: Vec<f64> = Vec::new();
    println!(
        "| grid | tau | median selection ms | patches (median) | triangles (median) | growth |"
    );
    println!("|---|---:|---:|---:|---:|---:|");
    for (g, &size) in sizes.iter().enumerate() {
        let dir = store(size);
        let store = Arc::new(Store::open(&dir).unwrap());
        let h = store.header().clone();
        let tree = StoreTree::new(store.clone(), DEFAULT_PATCH_CELLS);
        let extent = (size - 1) as f64 * h.georef.spacing_m.x;
        let top = store
            .block_ids()
            .filter_map(|b| store.entry(b))
            .map(|e| e.max)
            .fold(f32::MIN, f32::max);
        let cameras: Vec<Camera> = POSES
            .iter()
            .map(|&([fx, fy], up, yaw, pitch)| {
                let eye = h.georef.world_origin.extend(0.0)
                    + dvec3(fx * extent, fy * extent, f64::from(top) + up * extent);
                Camera::from_yaw_pitch(eye, yaw, pitch)
                    .with_fov_y_deg(60.0)
                    .with_viewport(1280.0, 720.0)
                    .with_clip(1.0, 2.0 * extent)
            })
            .collect();
        for (c, &(_, _, yaw, pitch)) in cameras.iter().zip(&POSES) {
            let p = c.position;
            eprintln!("{size}: --camera {:.1},{:.1},{:.1},{yaw},{pitch}", p.x, p.y, p.z);
        }
        for (t, tau) in [1.0, 2.0].into_iter().enumerate() {
            let (mut ms, mut patches, mut triangles) = (Vec::new(), Vec::new(), Vec::new());
            for cam in &cameras {
                for _ in 0..15 {
                    let start = Instant::now();
                    let sel = select_patches(&tree, cam, tau, |_| Some(h.k));
                    ms.push(start.elapsed().as_secs_f64() * 1e3);
                    patches.push(sel.patches.len() as f64);
                    triangles.push(
                        sel.patches.iter().map(|p| 2.0 * f64::from(p.inner[0] * p.inner[1])).sum(),
                    );
                }
            }
            let m = median(ms);
            if g == 0 {
                base.push(m);
            }
            println!(
                "| {size}^2 | {tau} | {m:.3} | {:.0} | {:.0} | {:.2}x |",
                median(patches),
                median(triangles),
                m / base[t]
            );
        }
    }
}
