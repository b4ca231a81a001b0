//! The entropy paper's scattered-point experiment (Chen 2018, section 4, Table 1: 2,509,683
//! points, D = 8, 19.7 s to build and 86 ms to remove cracks), at the same point count: points
//! drawn with a seeded generator from a real DEM (Puget Sound 1k, 164 km square, about the
//! paper's 132 x 88 km), written as an `x y z` text file, read back with the engine's reader,
//! and built with IDW (the paper's interpolation) and natural neighbour.
//!
//! ```text
//! cargo run --release -p terrain-app --example entropy_scattered -- [POINTS] [E0] [DATA_DIR]
//! ```

use std::io::{BufWriter, Write};
use std::path::PathBuf;
use std::time::Instant;

use terrain_app::bench::{process_cpu_s, thread_cpu_s};
use terrain_core::dem::{LoadOptions, load};
use terrain_core::points::read_points;
use terrain_visibility::entropy::{Interpolation, ScatteredPoints, TreeConfig, build_from_points};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).map(|s| s.parse()).transpose()?.unwrap_or(2_509_683);
    let e0: f64 = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(10.0);
    let dir = args
        .get(3)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"));
    let opts = LoadOptions { vertical_scale: 0.1, spacing_m: 160.0, ..LoadOptions::default() };
    let hm = load(dir.join("puget_sound/ps_height_1k.png"), &opts)?.heightmap;
    // Seeded points (SplitMix64), heights bilinear from the DEM.
    let mut s = 0x5EED_u64;
    let mut next = || {
        s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = s;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    };
    let path = std::env::temp_dir().join(format!("entropy_scattered_{}.xyz", std::process::id()));
    {
        let mut f = BufWriter::new(std::fs::File::create(&path)?);
        let (w, h) = ((hm.width() - 1) as f64, (hm.height() - 1) as f64);
        for _ in 0..n {
            let (u, v) = (next() * w, next() * h);
            let p = hm.grid_to_world(u, v);
            writeln!(f, "{:.3} {:.3} {:.2}", p.x, p.y, hm.sample_grid(u, v))?;
        }
    }
    let bytes = std::fs::metadata(&path)?.len();
    let t = Instant::now();
    let pts = read_points(&path)?;
    let read_s = t.elapsed().as_secs_f64();
    std::fs::remove_file(&path)?;
    println!(
        "{} points ({:.1} MB text) read in {:.3} s; D = 8, E0 = {e0} (percent scale); {} threads",
        pts.len(),
        bytes as f64 / 1e6,
        read_s,
        std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
    );
    println!(
        "| interpolation | prepare (s) | raster + entropy (s) | Algorithm 1 (s) | heights (s) | construction total (s) | construction CPU, all threads (s) | crack elimination (ms) | crack elimination CPU (ms) | tiles | triangles |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for (name, interp) in [
        ("IDW (12 nearest, power 2)", Interpolation::IDW),
        ("natural neighbour", Interpolation::NaturalNeighbour),
    ] {
        let input = pts.clone();
        let (t, c) = (Instant::now(), process_cpu_s());
        let src = ScatteredPoints::new(input, interp)?;
        let prep_s = t.elapsed().as_secs_f64();
        let cfg = TreeConfig { e0, max_depth: 8, interpolation: interp, ..TreeConfig::default() };
        let t = Instant::now();
        let mut built = build_from_points(&src, &cfg)?;
        let total = prep_s + t.elapsed().as_secs_f64();
        let total_cpu = process_cpu_s() - c;
        let c = thread_cpu_s();
        let crack_s = built.tree.eliminate_cracks();
        let crack_cpu = thread_cpu_s() - c;
        let mesh = built.tree.mesh();
        mesh.check_watertight(8).map_err(|e| anyhow::anyhow!("{e}"))?;
        println!(
            "| {name} | {prep_s:.3} | {:.3} | {:.3} | {:.3} | {total:.3} | {total_cpu:.2} | {:.2} | {:.2} | {} | {} |",
            built.entropy_s,
            built.tree.stats.segmentation_s,
            built.tree.stats.heights_s,
            crack_s * 1e3,
            crack_cpu * 1e3,
            built.tree.tiles(),
            mesh.triangles.len()
        );
    }
    Ok(())
}
