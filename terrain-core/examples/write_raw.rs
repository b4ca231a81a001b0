//! Writes the synthetic fractal terrain as a headerless little-endian float32 file (rows north
//! first, as `--raw WxH:f32` reads it), one row at a time: the input of the "DEM larger than
//! memory" bake (`terrain bake big.f32 --raw 32769x32769:f32 --spacing 10 --stream`).
//!
//! `cargo run --release -p terrain-core --example write_raw -- SIZE OUT`

use std::io::{BufWriter, Write};

use terrain_core::synth::FractalConfig;

fn main() -> std::io::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let size: u64 = args.first().and_then(|s| s.parse().ok()).unwrap_or(4097);
    let out = args.get(1).map_or("synthetic.f32", String::as_str);
    let cfg = FractalConfig::with_size(size, size, 10.0);
    let mut w = BufWriter::with_capacity(1 << 22, std::fs::File::create(out)?);
    let mut row = Vec::with_capacity(size as usize * 4);
    let t = std::time::Instant::now();
    for r in 0..size {
        let j = size - 1 - r; // north row first
        row.clear();
        for i in 0..size {
            row.extend_from_slice(&cfg.sample(i, j).to_le_bytes());
        }
        w.write_all(&row)?;
        if r % 4096 == 0 {
            eprintln!("row {r}/{size}, {:.0} s", t.elapsed().as_secs_f64());
        }
    }
    w.flush()?;
    println!("{out}: {size} x {size} float32, {:.2} GB", (size * size * 4) as f64 / 1e9);
    Ok(())
}
