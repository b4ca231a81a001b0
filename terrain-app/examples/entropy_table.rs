//! The entropy paper's Table 1 (Chen 2018) on real DEMs: for each threshold E0 the tiles,
//! triangles, construction time, crack-elimination time, simplification and the mesh's max
//! and RMS vertical error against every DEM sample; then the curvature-against-entropy
//! comparison (Fig. 3, 18).
//!
//! ```text
//! cargo run --release -p terrain-app --example entropy_table -- [DEPTH] [DATA_DIR]
//! ```
//! DEPTH defaults to 8 (the paper's D); DATA_DIR to `../shared/data`.

use std::path::PathBuf;
use std::time::Instant;

use terrain_app::bench::{process_cpu_s, thread_cpu_s};
use terrain_core::Heightmap;
use terrain_core::dem::{LoadOptions, load};
use terrain_core::mesh::verify;
use terrain_visibility::entropy::compare::compare_curvature_entropy;
use terrain_visibility::entropy::source::{build_from_grid_with_map, entropy_map};
use terrain_visibility::entropy::{EntropyConfig, TreeConfig};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let depth: u32 = args.get(1).map(|s| s.parse()).transpose()?.unwrap_or(8);
    let dir = args
        .get(2)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"));
    let dems: [(&str, &str, LoadOptions); 3] = [
        (
            "Puget Sound 1k",
            "puget_sound/ps_height_1k.png",
            LoadOptions { vertical_scale: 0.1, spacing_m: 160.0, ..LoadOptions::default() },
        ),
        (
            "Puget Sound 4k",
            "puget_sound/ps_height_4k.jpg",
            LoadOptions { vertical_scale: 25.6, spacing_m: 40.0, ..LoadOptions::default() },
        ),
        ("SRTM N42E001", "srtm/N42E001.hgt", LoadOptions::default()),
    ];
    println!(
        "threads: {} (rayon), D = {depth}, entropy in percent of log2(min(M, N))",
        rayon_threads()
    );
    for (name, rel, opts) in dems {
        let hm = load(dir.join(rel), &opts)?.heightmap;
        table(name, &hm, depth)?;
    }
    Ok(())
}

fn rayon_threads() -> usize {
    std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
}

fn table(name: &str, hm: &Heightmap, depth: u32) -> anyhow::Result<()> {
    let base = TreeConfig { max_depth: depth, ..TreeConfig::default() };
    let t = Instant::now();
    let emap = entropy_map(hm, &base);
    let map_s = t.elapsed().as_secs_f64();
    let (lo, hi) = emap.range().unwrap_or((0.0, 0.0));
    let mut sorted: Vec<f32> = emap.valid().collect();
    sorted.sort_by(f32::total_cmp);
    let pct = |p: f64| sorted[((sorted.len() - 1) as f64 * p) as usize];
    println!(
        "\n## {name}: {} x {}, entropy map {:.3} s, entropy {lo:.1}..{hi:.1} % (median {:.1}, p10 {:.1}, p90 {:.1})",
        hm.width(),
        hm.height(),
        map_s,
        pct(0.5),
        pct(0.1),
        pct(0.9)
    );
    println!(
        "| E0 | tiles | triangles | construction (s) | construction CPU (s) | crack elimination (ms) | crack elimination CPU (ms) | triangulation (ms) | simplification (%) | max error (m) | RMS error (m) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    let mut full_triangles = None;
    for e0 in [0.0, 10.0, 12.0, 14.0, 16.0, 18.0, 30.0, 50.0, 70.0, 80.0, 90.0] {
        let cfg = TreeConfig { e0, ..base.clone() };
        let (t, c) = (Instant::now(), process_cpu_s());
        let mut tree = build_from_grid_with_map(hm, &emap, &cfg);
        let build_s = t.elapsed().as_secs_f64();
        let build_cpu = process_cpu_s() - c;
        let c = thread_cpu_s();
        let crack_s = tree.eliminate_cracks();
        let crack_cpu = thread_cpu_s() - c;
        let t = Instant::now();
        let mesh = tree.mesh();
        let tri_s = t.elapsed().as_secs_f64();
        mesh.check_watertight(tree.lattice.depth).map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
        let stats = verify::measure(hm, &mesh.to_trimesh())?;
        let full = *full_triangles.get_or_insert(mesh.triangles.len());
        let simpl = 100.0 * (1.0 - mesh.triangles.len() as f64 / full as f64);
        println!(
            "| {e0} | {} | {} | {:.3} | {:.2} | {:.2} | {:.2} | {:.1} | {:.2} | {:.1} | {:.2} |",
            tree.tiles(),
            mesh.triangles.len(),
            build_s,
            build_cpu,
            crack_s * 1e3,
            crack_cpu * 1e3,
            tri_s * 1e3,
            simpl,
            stats.max_error,
            stats.rms_error
        );
    }
    let r = compare_curvature_entropy(hm, &EntropyConfig::default(), 20, 0.5);
    println!(
        "\nCurvature vs entropy (both min-max scaled to [0, 100], 20-bin histograms, 0.5 m noise):"
    );
    for (what, s) in [("curvature", &r.curvature), ("entropy", &r.entropy)] {
        println!(
            "- {what}: fullest bin {:.1} % of samples, std {:.2}, mean |neighbour diff| {:.3} ({:.3} of std), noise change {:.3} ({:.3} of std); histogram {:?}",
            100.0 * s.peak_share,
            s.std_dev,
            s.mean_neighbour_diff,
            s.relative_neighbour_diff(),
            s.sensitivity,
            s.relative_sensitivity(),
            s.histogram
        );
    }
    Ok(())
}
