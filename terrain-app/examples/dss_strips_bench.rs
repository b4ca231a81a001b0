//! The DSS paper's per-frame CPU costs on a large DEM along a flight: the multilevel update
//! (section 3.3.1, "about 2 ms" in the paper) and the strip construction (section 3.2, "2-10
//! ms"), with blocks, strips, P-blocks and triangles, for `dss-strips`; Method I's and II's
//! selection times beside them. No rendering and no error measurement (the benchmark does
//! those: `terrain bench`).
//!
//! ```sh
//! cargo run --release -p terrain-app --example dss_strips_bench -- \
//!     [DEM [vertical_scale spacing_m]] [--flight flights/dss_approach.json] [--rho 0.25,1,4] [--frames 60]
//! ```
//! Default DEM: `../shared/data/puget_sound/ps_height_4k.jpg` (4096 x 4096, scale 25.6,
//! spacing 40 m, as terrain-stream's `stream_bench`). Threads: rayon's default (`RAYON_NUM_THREADS`).

mod common;

use std::time::Instant;

use anyhow::Context;
use glam::dvec2;
use terrain_app::bench::median;
use terrain_app::methods::{LodMethod, MethodConfig, MethodScene};
use terrain_core::dem::{LoadOptions, load};
use terrain_core::flight::{FlightConfig, FlightSpec};
use terrain_core::lod::{DssStripsConfig, StripFactors, select_dss_strips};
use terrain_gpu::strips::build_strips_with;

fn main() -> anyhow::Result<()> {
    let mut args = common::Args::from_env();
    let flight = args.take_or("--flight", "flights/dss_approach.json");
    let rhos: Vec<f64> = args
        .take_or("--rho", "0.25,1,4")
        .split(',')
        .map(|r| r.parse().context("--rho: comma-separated numbers"))
        .collect::<anyhow::Result<_>>()?;
    let frames: usize = args.take_or("--frames", "60").parse().context("--frames")?;
    let (path, opts) = match args.rest() {
        [] => (
            "../shared/data/puget_sound/ps_height_4k.jpg".to_string(),
            LoadOptions { vertical_scale: 25.6, spacing_m: 40.0, ..Default::default() },
        ),
        [p] | [p, _] => (p.clone(), LoadOptions::default()),
        [p, scale, spacing, ..] => (
            p.clone(),
            LoadOptions {
                vertical_scale: scale.parse().context("vertical scale")?,
                spacing_m: spacing.parse().context("spacing")?,
                ..Default::default()
            },
        ),
    };
    let t = Instant::now();
    let hm = load(&path, &opts).with_context(|| format!("loading {path}"))?.heightmap;
    println!(
        "{path}: {} x {} samples, loaded in {:.1} s",
        hm.width(),
        hm.height(),
        t.elapsed().as_secs_f64()
    );
    let spec = FlightSpec::load(&flight).with_context(|| format!("loading {flight}"))?;
    let flight_cfg = FlightConfig { viewport_px: dvec2(1280.0, 720.0), ..FlightConfig::default() };
    let (resolved, _) = spec.resolve(&hm, &flight_cfg);
    let all = resolved.frames();
    let picks = terrain_app::bench::frame_indices(all.len(), frames);

    let mut scene = MethodScene::new(hm, MethodConfig::default());
    let t = Instant::now();
    scene.prepare(&[LodMethod::DssStrips]);
    println!(
        "precomputation (32 object-space errors per node, {} levels): {:.1} s",
        scene.qt.max_level() + 1,
        t.elapsed().as_secs_f64()
    );
    println!(
        "cores: {} (RAYON_NUM_THREADS={})",
        std::thread::available_parallelism().map_or(1, |n| n.get()),
        std::env::var("RAYON_NUM_THREADS").unwrap_or_else(|_| "unset".into())
    );

    for &rho in &rhos {
        scene.config.dss.rho_thr = rho;
        // One frame first, not counted: rayon's pool starts on first use.
        let _ = scene.frame(LodMethod::DssStrips, &all[picks[0]]);
        let (mut serial, mut parallel) = (vec![], vec![]);
        let (mut update, mut strips, mut blocks, mut nstrips, mut pblocks, mut tris) =
            (vec![], vec![], vec![], vec![], vec![], vec![]);
        for &k in &picks {
            let frame = scene.frame(LodMethod::DssStrips, &all[k]);
            let s = frame.strips.as_ref().expect("dss-strips has strips");
            update.push(s.update.as_secs_f64() * 1e3);
            strips.push(s.mesh.cpu_time.as_secs_f64() * 1e3);
            blocks.push(frame.selection.patches.len() as f64);
            nstrips.push(s.mesh.strips as f64);
            pblocks.push(s.mesh.pblocks as f64);
            let block_tris: usize = s
                .patches
                .iter()
                .map(|p| terrain_gpu::tess::tessellate(&p.factors).non_degenerate_triangle_count())
                .sum();
            tris.push((block_tris + s.mesh.triangles.indices.len() / 3) as f64);
            // The same frame's strips on the calling thread and on rayon's pool.
            let cfg = DssStripsConfig {
                dss: scene.config.dss.clone(),
                half_width_cells: scene.config.strip_half_width_cells,
                factors: StripFactors::Sliding,
            };
            let f = select_dss_strips(&scene.qt, &all[k], scene.dss_errors(), &cfg);
            serial.push(build_strips_with(&f, false).cpu_time.as_secs_f64() * 1e3);
            parallel.push(build_strips_with(&f, true).cpu_time.as_secs_f64() * 1e3);
        }
        println!(
            "dss-strips, rho_thr {rho}, {} frames of {}: median update {:.3} ms (max {:.3}), strip \
             construction {:.3} ms (max {:.3}); blocks {:.0}, strips {:.0}, P-blocks {:.0}, triangles {:.0}",
            picks.len(),
            spec.name,
            median(update.clone()),
            update.iter().copied().fold(0.0, f64::max),
            median(strips.clone()),
            strips.iter().copied().fold(0.0, f64::max),
            median(blocks),
            median(nstrips),
            median(pblocks),
            median(tris)
        );
        println!(
            "  strip construction, serial {:.3} ms, rayon {:.3} ms (medians)",
            median(serial),
            median(parallel)
        );
        for method in [LodMethod::Dss1, LodMethod::Dss2] {
            let ms: Vec<f64> = picks
                .iter()
                .map(|&k| scene.select(method, &all[k]).stats.cpu_time.as_secs_f64() * 1e3)
                .collect();
            println!("{}: median selection {:.3} ms", method.name(), median(ms));
        }
    }
    Ok(())
}
