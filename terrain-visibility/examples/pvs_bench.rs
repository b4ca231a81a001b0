//! PVS bake time, size and accuracy on a DEM (the occlusion-culling issue's figures):
//! `cargo run --release -p terrain-visibility --example pvs_bench -- <dem> [--scale S | --vertical-scale S]
//! [--spacing M] [--cells N] [--patch-level L] [--floors F] [--article] [--truth CELLS]
//! [--threads T] [--synthetic SIZE] [--time-cells N] [--conservative-only]`.
//!
//! Prints the bake time, the file size, the culled fraction of both modes over all cells, and,
//! with `--truth`, the false-cull rate and culled fraction of both modes against the dense
//! ground truth on that many sampled cells. With `--time-cells N` it bakes only a spread
//! sample of about `N` cells (whole plan cells, all floors, as the full bake chains them) and
//! prints their wall and CPU time, the full bake's estimate, and a hash of their bits (baked
//! again cell by cell, which must give the same bits).

use std::path::PathBuf;
use std::time::Instant;

use terrain_core::checksum::{FNV1A_START, fnv1a_update};
use terrain_core::dem::{LoadOptions, load};
use terrain_core::synth::FractalConfig;
use terrain_visibility::pvs::file::encode;
use terrain_visibility::pvs::truth::{TruthConfig, check, sample_cells};
use terrain_visibility::pvs::{PvsConfig, bake_both};

fn main() {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    // `--vertical-scale` as the CLI spells it; an unknown flag is an error, not ignored.
    for a in &mut args {
        if a == "--vertical-scale" {
            *a = "--scale".into();
        }
    }
    const FLAGS: [&str; 11] = [
        "--article",
        "--cells",
        "--conservative-only",
        "--floors",
        "--patch-level",
        "--scale",
        "--spacing",
        "--synthetic",
        "--threads",
        "--time-cells",
        "--truth",
    ];
    if let Some(bad) = args.iter().find(|a| a.starts_with("--") && !FLAGS.contains(&a.as_str())) {
        eprintln!("pvs_bench: unknown flag {bad} (known: {})", FLAGS.join(" "));
        std::process::exit(2);
    }
    let get = |name: &str| args.iter().position(|a| a == name).map(|k| args[k + 1].clone());
    let num =
        |name: &str, d: f64| get(name).map(|v| v.parse::<f64>().expect("a number")).unwrap_or(d);
    let loading = Instant::now();
    let hm = if let Some(n) = get("--synthetic") {
        let n: usize = n.parse().expect("a size");
        let cfg = FractalConfig::with_size(n as u64, n as u64, 10.0);
        cfg.to_heightmap().expect("synthetic terrain")
    } else {
        let path = PathBuf::from(args.first().expect("a DEM path"));
        let opts = LoadOptions {
            vertical_scale: num("--scale", 1.0),
            spacing_m: num("--spacing", LoadOptions::default().spacing_m),
            ..Default::default()
        };
        load(&path, &opts).unwrap_or_else(|e| panic!("{e}")).heightmap
    };
    println!("loaded in {:.2} s", loading.elapsed().as_secs_f64());
    let mut cfg = if args.iter().any(|a| a == "--article") {
        PvsConfig::article(num("--patch-level", 4.0) as u8)
    } else {
        PvsConfig { patch_level: num("--patch-level", 6.0) as u8, ..PvsConfig::default() }
    };
    if let Some(c) = get("--cells") {
        let c: u32 = c.parse().expect("cells");
        cfg.cells = (c, c);
    }
    if let Some(f) = get("--floors") {
        cfg.floors = f.parse().expect("floors");
    }
    cfg.threads = num("--threads", 0.0) as usize;
    println!(
        "grid {} x {}, relief {:.0} m, cells {} x {} x {}, patches {}^2",
        hm.width(),
        hm.height(),
        hm.max() - hm.min(),
        cfg.cells.0,
        cfg.cells.1,
        cfg.floors,
        1u32 << cfg.patch_level
    );
    // Sizes without baking: this configuration and the geomorphing article's variant (view
    // cells on the patch grid, 32 layers) at the same patch level, bit fields of every
    // pyramid level.
    for (name, c) in [
        ("this configuration", cfg.clone()),
        ("article variant", PvsConfig::article(cfg.patch_level)),
    ] {
        let lay = terrain_visibility::pvs::PvsLayout::new(&hm, &c);
        println!(
            "size, {name}: {} cells x {} bytes = {:.1} MB",
            lay.cell_count(),
            lay.bytes_per_cell(),
            (lay.cell_count() * lay.bytes_per_cell()) as f64 / 1e6
        );
    }
    if let Some(n) = get("--time-cells") {
        // Time a spread sample of plan cells, all floors of each (an estimate of the full
        // bake), then the same cells one by one (no floor chaining): the bits must agree.
        let n: usize = n.parse().expect("cells");
        let lay = terrain_visibility::pvs::PvsLayout::new(&hm, &cfg);
        let total = lay.cell_count();
        let plan_total = (lay.cells_x * lay.cells_y) as usize;
        let m = n.div_ceil(lay.floors as usize).max(1);
        let plan: Vec<(u32, u32)> = (0..m)
            .map(|k| {
                let p = ((k * plan_total / m + plan_total / (2 * m)) % plan_total) as u32;
                (p % lay.cells_x, p / lay.cells_x)
            })
            .collect();
        let cells: Vec<usize> = plan
            .iter()
            .flat_map(|&(a, b)| {
                let lay = &lay;
                (0..lay.floors)
                    .map(move |k| lay.cell_index(terrain_visibility::pvs::CellId { a, b, k }))
            })
            .collect();
        let cpu = || {
            let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
            let f: Vec<&str> = s.rsplit(')').next().unwrap_or("").split_whitespace().collect();
            let tick = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
            (tick(11) + tick(12)) / 100.0
        };
        let (t, c0) = (Instant::now(), cpu());
        let _ = terrain_visibility::pvs::mip::HeightMip::new(&hm);
        let _ = terrain_visibility::pvs::mip::LineMins::new(&hm);
        let (setup, setup_cpu) = (t.elapsed().as_secs_f64(), cpu() - c0);
        println!(
            "setup (height mip and line mins, once per bake): {setup:.2} s wall, {setup_cpu:.2} s CPU"
        );
        let (t, c0) = (Instant::now(), cpu());
        let columns = terrain_visibility::pvs::bake::bake_columns(&hm, &cfg, &plan);
        // Per cell, without the setup that a full bake does once.
        let (s, c) = (t.elapsed().as_secs_f64() - setup, cpu() - c0 - setup_cpu);
        let done = cells.len();
        println!(
            "{done} of {total} cells ({m} plan cells x {} floors) in {s:.2} s wall, {c:.2} s CPU: \
             {:.0} s wall, {:.0} CPU-s estimated for all (plus setup)",
            lay.floors,
            s * total as f64 / done as f64,
            c * total as f64 / done as f64
        );
        let chained: Vec<(Vec<u8>, Vec<u8>)> = columns.into_iter().flatten().collect();
        let (t, c0) = (Instant::now(), cpu());
        let bits = terrain_visibility::pvs::bake::bake_cells(&hm, &cfg, &cells);
        println!(
            "unchained: {:.2} s wall, {:.2} s CPU; bits equal: {}",
            t.elapsed().as_secs_f64(),
            cpu() - c0,
            bits == chained
        );
        // FNV-1a of the sample's bits: a bake change shows as a different hash.
        let (hs, hk) = bits.iter().fold((FNV1A_START, FNV1A_START), |(a, c), (bs, bk)| {
            (fnv1a_update(a, bs), fnv1a_update(c, bk))
        });
        println!("bits hash: sampled {hs:016x}, conservative {hk:016x}");
        let ones = |v: &Vec<u8>| v.iter().map(|b| b.count_ones()).sum::<u32>();
        println!(
            "visible bits (all levels): sampled {}, conservative {}",
            bits.iter().map(|c| ones(&c.0)).sum::<u32>(),
            bits.iter().map(|c| ones(&c.1)).sum::<u32>()
        );
        return;
    }
    if args.iter().any(|a| a == "--conservative-only") {
        let cfg = PvsConfig { mode: terrain_visibility::pvs::PvsMode::Conservative, ..cfg };
        let t = Instant::now();
        let pvs = terrain_visibility::pvs::bake(&hm, &cfg);
        println!(
            "conservative bake: {} cells in {:.1} s, file {} bytes, culled {:.4}",
            pvs.layout.cell_count(),
            t.elapsed().as_secs_f64(),
            encode(&pvs).len(),
            pvs.culled_fraction()
        );
        return;
    }
    let t = Instant::now();
    let (sampled, cons, stats) = bake_both(&hm, &cfg);
    println!(
        "bake: {} cells in {:.1} s ({} threads); file {} bytes ({} bytes/cell with all pyramid levels)",
        stats.cells,
        t.elapsed().as_secs_f64(),
        rayon::current_num_threads(),
        encode(&sampled).len(),
        sampled.layout.bytes_per_cell()
    );
    println!(
        "culled fraction over all cells: sampled {:.4}, conservative {:.4}",
        sampled.culled_fraction(),
        cons.culled_fraction()
    );
    if let Some(n) = get("--truth") {
        let cells = sample_cells(&sampled, n.parse().expect("cells"));
        let t = Instant::now();
        let counts = check(&hm, &[&sampled, &cons], &cells, &TruthConfig::default());
        for (name, c) in ["sampled", "conservative"].iter().zip(&counts) {
            println!(
                "truth on {} cells ({} pairs): {name}: culled {:.4}, false culls {} (rate {:.5})",
                cells.len(),
                c.pairs,
                c.culled_fraction(),
                c.false_culls,
                c.false_cull_rate()
            );
        }
        println!("truth took {:.1} s", t.elapsed().as_secs_f64());
    }
}
