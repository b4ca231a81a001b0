//! `terrain bake`: a DEM (or a synthetic terrain streamed by rows) into an out-of-core block
//! store, with a plain-text progress bar on stderr, then the PVS files of the scene
//! (`pvs.bin`, `pvs_conservative.bin`, see `terrain pvs`) unless `--no-pvs`.

use std::io::Write;
use std::ops::ControlFlow;
use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use terrain_core::synth::FractalConfig;
use terrain_stream::{BakeConfig, BakeProgress, HeightEncoding, HeightSource, bake};

use crate::source::SourceArgs;

/// Largest synthetic side whose PVS `terrain bake` computes (the grid is held in memory).
const MAX_PVS_SYNTHETIC: u64 = 8193;

/// Arguments of `terrain bake`.
#[derive(Debug, Args)]
pub struct BakeArgs {
    #[command(flatten)]
    pub source: SourceArgs,
    /// Output store folder.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Blocks of (2^K + 1)^2 vertices.
    #[arg(long, default_value_t = BakeConfig::default().k)]
    pub block_k: u8,
    /// Bake the synthetic fractal terrain of SIZE x SIZE samples (10 m) instead of a DEM,
    /// streamed by rows (e.g. 32769).
    #[arg(long)]
    pub synthetic: Option<u64>,
    /// Vertical error bound in metres for float sources (integer sources are lossless).
    #[arg(long, default_value_t = 0.01)]
    pub max_error: f64,
    /// Store float heights as raw f32 instead.
    #[arg(long)]
    pub raw_f32: bool,
    /// Store levels uncompressed (fixed width) instead of the predictive codec with Deflate.
    #[arg(long)]
    pub no_compression: bool,
    /// Replace an existing store.
    #[arg(long)]
    pub overwrite: bool,
    /// Worker threads (0 = one per core).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Skip the PVS bake (by default both PVS files, sampled and conservative, are written
    /// into the store folder after the blocks; see `terrain pvs`).
    #[arg(long)]
    pub no_pvs: bool,
    #[command(flatten)]
    pub pvs: crate::pvs::PvsArgs,
}

/// Runs `terrain bake`.
pub fn run(args: &BakeArgs) -> anyhow::Result<()> {
    let bounded = HeightEncoding::Bounded { max_error_m: args.max_error };
    let mut config = BakeConfig {
        k: args.block_k,
        encoding: bounded,
        overwrite: args.overwrite,
        threads: args.threads,
        ..BakeConfig::default()
    };
    if args.no_compression {
        config.codec = terrain_stream::Codec::Plain;
    }
    let synthetic;
    let dem;
    let mut source_hm: Option<&terrain_core::Heightmap> = None;
    let source: &dyn HeightSource = if let Some(n) = args.synthetic {
        synthetic = FractalConfig::with_size(n, n, 10.0);
        synthetic.validate().map_err(anyhow::Error::msg)?;
        &synthetic
    } else {
        let options = args.source.load_options()?;
        dem = args.source.load()?.context("give a DEM file or --synthetic SIZE")?;
        config.encoding = HeightEncoding::for_source(&dem.source, &options);
        if matches!(config.encoding, HeightEncoding::Bounded { .. }) {
            config.encoding = bounded;
        }
        source_hm = Some(&dem.heightmap);
        &dem.heightmap
    };
    if args.raw_f32 {
        config.encoding = HeightEncoding::F32;
    }
    let start = std::time::Instant::now();
    let mut err = std::io::stderr();
    let mut bar = |p: &BakeProgress| {
        let frac = p.blocks_done as f64 / p.blocks_total.max(1) as f64;
        let filled = (frac * 40.0).round() as usize;
        let _ = write!(
            err,
            "\r[{}{}] {:5.1}% {}/{} blocks, {:.1} MB written, {:.0} s",
            "#".repeat(filled),
            " ".repeat(40 - filled),
            frac * 100.0,
            p.blocks_done,
            p.blocks_total,
            p.bytes_written as f64 / 1e6,
            start.elapsed().as_secs_f64()
        );
        let _ = err.flush();
        ControlFlow::Continue(())
    };
    let report = bake(source, &args.output, &config, &mut bar)
        .with_context(|| format!("baking {}", args.output.display()))?;
    eprintln!();
    let h = &report.header;
    let secs = report.elapsed.as_secs_f64();
    println!(
        "{}: {} x {} samples in {} x {} blocks of {}^2, {:.1} MB ({:.2} bytes/sample), {}, {:.1} s, {:.1} MB/s of f32 input",
        args.output.display(),
        h.width,
        h.height,
        h.blocks_x,
        h.blocks_y,
        h.block_side(),
        report.store_bytes as f64 / 1e6,
        report.store_bytes as f64 / report.source_samples as f64,
        if report.lossless {
            "lossless".to_string()
        } else {
            format!("max vertical error {:.4} m", h.max_error_m)
        },
        secs,
        report.source_samples as f64 * 4.0 / 1e6 / secs.max(1e-9)
    );
    if args.no_pvs {
        return Ok(());
    }
    let synthetic_hm;
    let hm = match (source_hm, args.synthetic) {
        (Some(hm), _) => hm,
        (None, Some(n)) if n <= MAX_PVS_SYNTHETIC => {
            // A streamed synthetic terrain: the PVS needs the whole grid in memory.
            synthetic_hm =
                FractalConfig::with_size(n, n, 10.0).to_heightmap().map_err(anyhow::Error::msg)?;
            &synthetic_hm
        }
        (None, _) => {
            eprintln!(
                "warning: no PVS for a synthetic terrain above {MAX_PVS_SYNTHETIC}^2 samples \
                 (it would not fit in memory); the scene draws without occlusion culling"
            );
            return Ok(());
        }
    };
    crate::pvs::bake_into_scene(hm, &args.pvs.config()?, &args.output)
}
