//! `tin` against the seed methods, every one drawn from a baked synthetic store (issue 16's
//! 16385^2 store flight): the benchmark's runs (`run_bench` with `store_only`), measured
//! against the synthetic DEM regenerated in memory (`FractalConfig`, bit for bit the one
//! `terrain bake --synthetic N` baked), no rendering. Prints per method and target the median
//! triangles, median and largest p99 pixel error, median selection ms, tiles late and the share
//! of frames drawn at their needed level.
//!
//! ```sh
//! cargo run --release -p terrain-app --example tin_store_bench -- \
//!     --store /work/stores/sf16k --synthetic 16385 [--flight flights/fast_pass.json] \
//!     [--frames 8] [--methods tin,geomorph,ooc] [--error-px 1,2] [--real-time] \
//!     [--finer-strides N]   # the tiles' stride cap (GridTinConfig::finer_strides; default 2)
//! ```
//! Warm by default (every measured frame waits until its tiles and levels are resident, as
//! `terrain bench --wait`); `--real-time` plays every frame of the flight at its frame rate
//! and only the first waits.

mod common;

use std::path::PathBuf;

use anyhow::Context;
use terrain_app::bench::{BenchConfig, run_bench};
use terrain_app::methods::LodMethod;
use terrain_core::flight::FlightSpec;
use terrain_core::synth::FractalConfig;

fn main() -> anyhow::Result<()> {
    let mut args = common::Args::from_env();
    let store = args.take("--store").context("--store DIR: a store baked with --synthetic N")?;
    let n: u64 = args.take("--synthetic").map_or(Ok(16385), |v| v.parse())?;
    let flight = args.take("--flight").unwrap_or_else(|| "flights/fast_pass.json".into());
    let frames: usize = args.take("--frames").map_or(Ok(8), |v| v.parse())?;
    let methods: Vec<LodMethod> = args
        .take("--methods")
        .unwrap_or_else(|| "tin,geomorph".into())
        .split(',')
        .map(|m| {
            LodMethod::ALL
                .iter()
                .copied()
                .find(|k| k.name() == m)
                .with_context(|| format!("--methods: no method {m}"))
        })
        .collect::<anyhow::Result<_>>()?;
    let error_px: Vec<f64> = args
        .take("--error-px")
        .unwrap_or_else(|| "1,2".into())
        .split(',')
        .map(|v| v.parse().with_context(|| format!("--error-px: {v}")))
        .collect::<anyhow::Result<_>>()?;
    let finer: Option<u32> = args.take("--finer-strides").map(|v| v.parse()).transpose()?;
    let real_time = args.rest().iter().any(|a| a == "--real-time");

    let hm = FractalConfig::with_size(n, n, 10.0).to_heightmap().map_err(anyhow::Error::msg)?;
    let spec = FlightSpec::load(&flight).with_context(|| format!("flight {flight}"))?;
    let mut method = terrain_app::methods::MethodConfig::default();
    if let Some(f) = finer {
        method.tin.pyramid.finer_strides = f;
    }
    let cfg = BenchConfig {
        method,
        methods,
        max_frames: frames,
        render_size: None,
        ooc_store: Some(PathBuf::from(&store)),
        ooc_wait: !real_time,
        from_store: true,
        store_only: true,
        error_px: Some(error_px),
        ..BenchConfig::default()
    };
    let report = run_bench(&format!("synthetic {n}^2"), hm, &[spec], &cfg, None, &mut |_| {})?;
    println!(
        "| method | error px | triangles | p99 px (median / max) | selection ms | late tiles | \
         frames at needed level |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|");
    for r in &report.runs {
        let s = &r.summary;
        let late: usize =
            r.frames.iter().filter_map(|f| f.stream.as_ref()).map(|s| s.late_tiles).sum();
        let share = r.stream.as_ref().map_or(f64::NAN, |s| s.at_needed_level_share);
        println!(
            "| {} | {} | {:.0} | {:.3} / {:.3} | {:.3} | {late} | {:.0} % |",
            r.method.name(),
            r.value,
            s.median_triangles,
            s.median_p99_px,
            s.max_p99_px,
            s.median_selection_ms,
            share * 100.0
        );
    }
    Ok(())
}
