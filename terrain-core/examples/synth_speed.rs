//! Speed of the seeded fractal generator on one thread: nanoseconds a sample (median of five
//! runs) over a band of rows of the demo's 8193-wide grid, and a checksum of the samples' bits
//! (FNV-1a), so a faster generator can be checked to give the same terrain bit for bit.
//!
//! `cargo run --release -p terrain-core --example synth_speed -- [ROWS] [WIDTH]`

use std::time::Instant;

use terrain_core::synth::FractalConfig;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let rows: usize = args.first().and_then(|s| s.parse().ok()).unwrap_or(64);
    let width: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(8193);
    let cfg = FractalConfig::with_size(width, width, 10.0);
    let mut out = vec![0f32; width as usize * rows];
    let mut times = Vec::new();
    for rep in 0..5u64 {
        // Different bands each run (same cost), from the grid's middle.
        let j0 = width / 2 + rep * rows as u64;
        let t = Instant::now();
        cfg.generate_rows(j0.min(width - rows as u64), rows, &mut out);
        times.push(t.elapsed().as_secs_f64() * 1e9 / out.len() as f64);
    }
    times.sort_by(f64::total_cmp);
    // Checksum of one fixed band (the grid's middle rows).
    cfg.generate_rows(width / 2, rows, &mut out);
    let h = out.iter().fold(terrain_core::checksum::FNV1A_START, |h, z| {
        terrain_core::checksum::fnv1a_update(h, &z.to_bits().to_le_bytes())
    });
    println!(
        "{rows} rows of {width}: median {:.1} ns a sample (runs {:.1}..{:.1}), checksum {h:016x}",
        times[2], times[0], times[4]
    );
}
