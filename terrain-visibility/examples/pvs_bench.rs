//! PVS bake time, size and accuracy on a DEM (the occlusion-culling issue's figures):
//! `cargo run --release -p terrain-visibility --example pvs_bench -- <dem> [--scale S]
//! [--spacing M] [--cells N] [--patch-level L] [--floors F] [--article] [--truth CELLS]
//! [--threads T] [--synthetic SIZE]`.
//!
//! Prints the bake time, the file size, the culled fraction of both modes over all cells, and,
//! with `--truth`, the false-cull rate and culled fraction of both modes against the dense
//! ground truth on that many sampled cells.

use std::path::PathBuf;
use std::time::Instant;

use terrain_core::dem::{LoadOptions, load};
use terrain_core::synth::FractalConfig;
use terrain_visibility::pvs::file::encode;
use terrain_visibility::pvs::truth::{TruthConfig, check, sample_cells};
use terrain_visibility::pvs::{PvsConfig, bake_both};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
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
    if let Some(n) = get("--time-cells") {
        // Time a spread sample of cells only (an estimate of the full bake).
        let n: usize = n.parse().expect("cells");
        let lay = terrain_visibility::pvs::PvsLayout::new(&hm, &cfg);
        let total = lay.cell_count();
        let cells: Vec<usize> = (0..n).map(|k| (k * total / n + total / (2 * n)) % total).collect();
        let t = Instant::now();
        let bits = terrain_visibility::pvs::bake::bake_cells(&hm, &cfg, &cells);
        let s = t.elapsed().as_secs_f64();
        // FNV-1a of the sample's bits: a bake change shows as a different hash.
        let fnv = |h: u64, b: &u8| (h ^ u64::from(*b)).wrapping_mul(0x0100_0000_01b3);
        let (hs, hk) = bits
            .iter()
            .fold((0xcbf2_9ce4_8422_2325u64, 0xcbf2_9ce4_8422_2325u64), |(a, c), (bs, bk)| {
                (bs.iter().fold(a, fnv), bk.iter().fold(c, fnv))
            });
        println!("bits hash: sampled {hs:016x}, conservative {hk:016x}");
        let ones = |v: &Vec<u8>| v.iter().map(|b| b.count_ones()).sum::<u32>();
        println!(
            "visible bits (all levels): sampled {}, conservative {}",
            bits.iter().map(|c| ones(&c.0)).sum::<u32>(),
            bits.iter().map(|c| ones(&c.1)).sum::<u32>()
        );
        println!(
            "{n} of {total} cells in {s:.2} s: {:.1} s estimated for all",
            s * total as f64 / n as f64
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
