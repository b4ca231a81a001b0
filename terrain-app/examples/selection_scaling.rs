//! Selection cost against grid size: the median per-frame selection time of every in-memory
//! LOD method on seeded synthetic grids of growing size, flown with the same relative camera
//! poses, and the growth from the smallest to the largest grid (issue 13: "selection cost
//! follows the view, not the grid"). No rendering, no error measurement (`terrain bench` does
//! those); each method at its default parameter.
//!
//! ```sh
//! cargo run --release -p terrain-app --example selection_scaling -- \
//!     [--sizes 1025,4097,16385] [--flight flights/pvps_884.json] [--frames 30] \
//!     [--methods uniform,pvps-a,pvps-b,pvps-c,dss-1,dss-2,geomorph] [--reps 3]
//! ```
//! Grids: `FractalConfig::with_size(n, n, 10.0)` (seed 1, 10 m spacing, 1500 m relief), built
//! once per size with every method's precomputation (`MethodScene::prepare`, timed apart).
//! Cameras: the flight resolved onto each grid (relative coordinates: the same fractions of the
//! extent and of the relief), `--frames` frames evenly spaced, 1280 x 720. Each frame is
//! selected `--reps` times and its fastest time kept (less noise from other processes); the
//! table gives the median over frames, milliseconds, and the patches drawn (median).

use std::time::Instant;

use anyhow::Context;
use terrain_app::methods::{LodMethod, MethodConfig, MethodScene};
use terrain_core::flight::{FlightConfig, FlightSpec};
use terrain_core::synth::FractalConfig;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() { 0.0 } else { v[v.len() / 2] }
}

fn main() -> anyhow::Result<()> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let mut take = |flag: &str, default: &str| -> String {
        match args.iter().position(|a| a == flag) {
            Some(k) if k + 1 < args.len() => {
                let v = args.remove(k + 1);
                args.remove(k);
                v
            }
            _ => default.to_string(),
        }
    };
    let sizes: Vec<u64> = take("--sizes", "1025,4097,16385")
        .split(',')
        .map(|s| s.parse().context("--sizes: comma-separated sample counts"))
        .collect::<anyhow::Result<_>>()?;
    let flight = take("--flight", "flights/pvps_884.json");
    let frames: usize = take("--frames", "30").parse().context("--frames")?;
    let reps: usize = take("--reps", "3").parse::<usize>().context("--reps")?.max(1);
    let methods: Vec<LodMethod> =
        take("--methods", "uniform,pvps-a,pvps-b,pvps-c,dss-1,dss-2,geomorph")
            .split(',')
            .map(|m| {
                LodMethod::ALL
                    .iter()
                    .copied()
                    .find(|x| x.name() == m)
                    .with_context(|| format!("unknown method {m}"))
            })
            .collect::<anyhow::Result<_>>()?;
    let spec = FlightSpec::load(&flight).with_context(|| format!("flight {flight}"))?;

    // Per method: per size, (median ms, median patches).
    let mut table: Vec<Vec<(f64, f64)>> = vec![Vec::new(); methods.len()];
    for &n in &sizes {
        let t = Instant::now();
        let hm = FractalConfig::with_size(n, n, 10.0).to_heightmap().map_err(anyhow::Error::msg)?;
        let gen_s = t.elapsed().as_secs_f64();
        let (resolved, _) = spec.resolve(&hm, &FlightConfig::default());
        let all = resolved.frames();
        let step = (all.len() / frames.max(1)).max(1);
        let cameras: Vec<_> = all.iter().step_by(step).take(frames.max(1)).cloned().collect();
        let scene = MethodScene::new(hm, MethodConfig::default());
        let t = Instant::now();
        scene.prepare(&methods);
        eprintln!(
            "{n}^2: grid {gen_s:.1} s, precomputation {:.1} s, {} cameras",
            t.elapsed().as_secs_f64(),
            cameras.len()
        );
        for (k, &m) in methods.iter().enumerate() {
            let mut times = Vec::new();
            let mut patches = Vec::new();
            for c in &cameras {
                let mut best = f64::INFINITY;
                let mut count = 0;
                for _ in 0..reps {
                    let t = Instant::now();
                    let sel = scene.select(m, c);
                    best = best.min(t.elapsed().as_secs_f64() * 1e3);
                    count = sel.patches.len();
                }
                times.push(best);
                patches.push(count as f64);
            }
            let row = (median(times), median(patches));
            eprintln!("  {:<9} {:>9.3} ms {:>8.0} patches", m.name(), row.0, row.1);
            table[k].push(row);
        }
    }
    println!("\nmedian selection ms per frame (patches), flight {flight}, {frames} frames");
    print!("| method |");
    for n in &sizes {
        print!(" {n}^2 |");
    }
    println!(" growth {}^2 / {}^2 |", sizes[sizes.len() - 1], sizes[0]);
    println!("|---|{}---|", "---|".repeat(sizes.len()));
    for (k, m) in methods.iter().enumerate() {
        print!("| {} |", m.name());
        for (ms, p) in &table[k] {
            print!(" {ms:.3} ({p:.0}) |");
        }
        let (first, last) = (table[k][0].0, table[k][table[k].len() - 1].0);
        println!(" {:.1}x |", last / first.max(1e-9));
    }
    Ok(())
}
