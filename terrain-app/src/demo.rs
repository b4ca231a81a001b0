//! `terrain demo`: the whole engine end to end on the embedded synthetic terrain: a flight drawn
//! into PNG frames with their statistics, then a small benchmark of every method with its
//! report and plot, all in one folder that it names.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use terrain_app::bench::{BenchConfig, print_progress, run_bench};
use terrain_app::methods::LodMethod;
use terrain_core::flight::FlightSpec;
use terrain_core::synth;
use terrain_gpu::{BackendChoice, DeviceConfig, GpuContext};

use crate::bench_cli::write_report;
use crate::fly::{FlyOptions, fly};

/// The flights the demo flies (the shipped files, embedded).
const FLIGHTS: [&str; 2] =
    [include_str!("../../flights/pvps_884.json"), include_str!("../../flights/dss_approach.json")];

/// Arguments of `terrain demo`.
#[derive(Debug, Args)]
pub(crate) struct DemoArgs {
    /// Output folder (created).
    #[arg(short, long, default_value = "out/demo")]
    pub output: PathBuf,
}

/// Runs `terrain demo`.
pub(crate) fn run(args: &DemoArgs) -> anyhow::Result<()> {
    let start = std::time::Instant::now();
    let flights = FLIGHTS
        .iter()
        .map(|t| FlightSpec::parse(t))
        .collect::<Result<Vec<_>, _>>()
        .context("an embedded flight is invalid")?;
    let ctx = GpuContext::try_new(&DeviceConfig::from_env(BackendChoice::Auto))?;
    let out = &args.output;
    std::fs::create_dir_all(out).with_context(|| format!("could not create {}", out.display()))?;
    println!("terrain demo: the embedded 1025 x 1025 synthetic terrain, into {}", out.display());

    match &ctx {
        Some(ctx) => {
            println!("adapter: {}", ctx.describe());
            println!("1/2 flying `{}` with pvps-c: 48 frames at 640x360", flights[0].name);
            let options = FlyOptions {
                method: LodMethod::PvpsC,
                leaf_cells: 16,
                size: (640, 360),
                max_frames: 48,
                scene: None,
                config: crate::quality::default_config(LodMethod::PvpsC, 360),
            };
            fly(synth::default_terrain(), &flights[0], options, ctx, &out.join("frames"))?;
        }
        None => println!("1/2 skipped the frames: no GPU adapter (Vulkan or GL) is available"),
    }

    println!("2/2 benchmark: every method, 3 thresholds each, 8 frames of each flight");
    let cfg = BenchConfig { max_frames: 8, ..BenchConfig::quick() };
    let report = run_bench(
        "default",
        synth::default_terrain(),
        &flights,
        &cfg,
        ctx.as_ref(),
        &mut print_progress,
    )?;
    let paths = write_report(&report, out, "report")?;
    println!("{}", report.to_markdown());
    println!(
        "demo done in {:.0} s; everything is in {}:",
        start.elapsed().as_secs_f64(),
        out.display()
    );
    if ctx.is_some() {
        println!("  {}/frames/frame_*.png, stats.csv, stats.json: the flight", out.display());
    }
    for p in &paths {
        println!("  {}", p.display());
    }
    println!("open {} to see triangles and CPU ms against pixel error", paths[2].display());
    Ok(())
}
