//! The measured p99 pixel error of each in-memory method against its own parameter: the
//! calibration behind `--error-px` for the methods whose parameter has no screen-error model
//! (`terrain_app::method::registry::params_for_error_px` states the fits), and the check of
//! the others' models.
//!
//! ```sh
//! cargo run --release -p terrain-app --example error_px_calibration -- \
//!     DEM [--vertical-scale S --spacing M] [--frames 6] [--methods uniform,pvps-c,...] \
//!     [--values 2,4,8,16] [--parameter c3]
//! ```
//! Cameras: `flights/pvps_884.json` and `flights/dss_approach.json` resolved onto the DEM,
//! `--frames` frames of each evenly spaced, 1280 x 720, 60 degrees; each frame measured with
//! the benchmark's measurement (`FrameLoop::measured`, 200,000 samples at most). Printed per
//! method and value: the median over the frames of the p99 pixel error and of the triangles.
//! Without `--values`, each method's own sweep ([`sweep_values`]); `--parameter c3` sweeps the
//! PVPS methods' Eq. 12 `C3` instead of Eq. 8's `C1`, with `outer_constant = C3 C4`.

mod common;

use anyhow::Context;
use glam::dvec2;
use terrain_app::bench::median;
use terrain_app::bench::{apply_parameter, frame_indices, sweep_values};
use terrain_app::method::{FrameLoop, MethodOptions, build};
use terrain_app::methods::{LodMethod, MethodConfig, MethodScene};
use terrain_core::dem::{LoadOptions, load};
use terrain_core::flight::{FlightConfig, FlightSpec};
use terrain_core::measure::MeasureConfig;

fn main() -> anyhow::Result<()> {
    let mut args = common::Args::from_env();
    let scale: Option<f64> = args.take("--vertical-scale").map(|s| s.parse()).transpose()?;
    let spacing: Option<f64> = args.take("--spacing").map(|s| s.parse()).transpose()?;
    let frames: usize = args.take("--frames").unwrap_or("6".into()).parse().context("--frames")?;
    let parameter = args.take("--parameter");
    let values: Option<Vec<f64>> = args
        .take("--values")
        .map(|v| v.split(',').map(|x| x.parse().context("--values")).collect())
        .transpose()?;
    let methods: Vec<LodMethod> = args
        .take("--methods")
        .unwrap_or("uniform,pvps-a,pvps-b,pvps-c,dss-1,dss-2,dss-strips,entropy,geomorph".into())
        .split(',')
        .map(|m| LodMethod::ALL.into_iter().find(|x| x.name() == m).context("unknown method"))
        .collect::<anyhow::Result<_>>()?;
    let dem = args.rest().first().context("give a DEM")?;
    let options = LoadOptions {
        vertical_scale: scale.unwrap_or(1.0),
        spacing_m: spacing.unwrap_or(1.0),
        spacing_given: spacing.is_some(),
        ..LoadOptions::default()
    };
    let hm = load(std::path::Path::new(dem), &options)?.heightmap;
    let flight_cfg = FlightConfig { viewport_px: dvec2(1280.0, 720.0), ..FlightConfig::default() };
    let mut cameras = Vec::new();
    for f in ["flights/pvps_884.json", "flights/dss_approach.json"] {
        let (flight, _) = FlightSpec::load(std::path::Path::new(f))?.resolve(&hm, &flight_cfg);
        let all = flight.frames();
        cameras.extend(frame_indices(all.len(), frames).into_iter().map(|k| all[k]));
    }
    let mut scene = MethodScene::new(hm, MethodConfig::default());
    scene.prepare(&methods);
    let measure = MeasureConfig { max_samples: 200_000, ..MeasureConfig::default() };
    println!("| method | parameter | p99 px (median) | triangles (median) |");
    println!("|---|---|---:|---:|");
    for kind in methods {
        let (mut name, mut list) = sweep_values(kind, scene.config.leaf_cells);
        let c3 = parameter.as_deref() == Some("c3");
        if c3 {
            name = "C3";
        }
        if let Some(v) = &values {
            list = v.clone();
        }
        for value in list {
            let mut config = MethodConfig::default();
            if c3 {
                config.pvps.c3 = value;
                config.pvps.outer_constant = value * config.pvps.c4;
            } else {
                apply_parameter(&mut config, kind, value);
            }
            scene.config = config;
            let method =
                build(kind, &scene, &MethodOptions { morph: true, ..MethodOptions::default() })?;
            let mut run = FrameLoop::new(method).measured(&scene.hm, &scene.qt, measure);
            let (mut p99, mut tris) = (Vec::new(), Vec::new());
            for (k, c) in cameras.iter().enumerate() {
                let r = run.frame(k, c, None)?.record;
                p99.push(r.errors.p99_px);
                tris.push(r.triangles as f64);
            }
            println!(
                "| {} | {name} = {value} | {:.3} | {:.0} |",
                kind.name(),
                median(p99),
                median(tris)
            );
        }
    }
    Ok(())
}
