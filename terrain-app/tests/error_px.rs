//! The one quality knob (`--error-px`): the measured p99 pixel error of every method follows the
//! target (the benchmark's own measurement, `run_bench` with an error-px sweep, on Puget Sound
//! 1k and Big Tujunga), and no method draws a degenerate handful of triangles at the default
//! quality.

mod common;

use terrain_app::bench::{BenchConfig, RunRecord, run_bench};
use terrain_app::method::registry::{self, ErrorPxBasis, ErrorView, Quality, params_for_error_px};
use terrain_app::method::{FrameLoop, MethodOptions, build};
use terrain_app::methods::{LodMethod, MethodConfig, MethodScene};
use terrain_core::Heightmap;
use terrain_core::dem::{LoadOptions, load};
use terrain_core::flight::FlightSpec;
use terrain_core::measure::MeasureConfig;
use terrain_visibility::pvs::PvsConfig;

/// The targets of the sweep, pixels.
const TARGETS: [f64; 4] = [0.5, 1.0, 2.0, 4.0];

/// How far above the target the measured median p99 may lie, as a factor, for the methods
/// whose parameter is a pixel threshold or goes through a screen-error model (measured on
/// both DEMs: at most 1.52, dss-strips and pvps-c on Big Tujunga at 4 px; README table).
const MODEL_FACTOR: f64 = 2.0;

/// How far below: geomorph's tau bounds each patch's largest error, so its p99 lies well
/// under the target (measured 0.36-0.50 of it); the others measured 0.57 at least.
const MODEL_FACTOR_BELOW: f64 = 3.0;

/// Tolerance of "non-decreasing": a larger target may measure at most this much less (the
/// medians of a few frames move a little between settings that select almost the same).
const MONOTONE_SLACK: f64 = 0.05;

fn puget() -> Heightmap {
    let options = LoadOptions {
        vertical_scale: 0.1,
        spacing_m: 160.0,
        spacing_given: true,
        ..LoadOptions::default()
    };
    load(common::data("puget_sound/ps_height_1k.png"), &options).unwrap().heightmap
}

fn tujunga() -> Heightmap {
    load(common::data("big_tujunga/bigtujunga.tif"), &LoadOptions::default()).unwrap().heightmap
}

fn flight(name: &str) -> FlightSpec {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../flights");
    FlightSpec::load(root.join(name)).unwrap()
}

/// Every method at every target over a few cameras of a shipped flight, no rendering; `ooc`
/// from a store the benchmark bakes, every frame warm.
/// The methods a user sets with `--error-px`: all but the geomorphing article's two Table 1
/// comparison paths (`geomorph-static`, `geomorph-cpu`), which take geomorph's parameter to
/// time the same patches another way; the static path draws true heights, so its error sits
/// well under the knob's model by design.
fn knob_methods() -> Vec<LodMethod> {
    LodMethod::ALL.into_iter().filter(|&m| registry::benched_by_default(m)).collect()
}

fn sweep(name: &str, hm: Heightmap) -> Vec<RunRecord> {
    let cfg = BenchConfig {
        methods: knob_methods(),
        max_frames: 3,
        render_size: None,
        error_px: Some(TARGETS.to_vec()),
        ooc_wait: true,
        measure: MeasureConfig { max_samples: 200_000, ..MeasureConfig::default() },
        // A small in-memory PVS bake (the culling is not what is measured here).
        method: MethodConfig {
            pvs: PvsConfig { cells: (4, 4), patch_level: 4, ..PvsConfig::default() },
            ..MethodConfig::default()
        },
        ..BenchConfig::default()
    };
    let report = run_bench(name, hm, &[flight("pvps_884.json")], &cfg, None, &mut |_| {}).unwrap();
    report.runs
}

/// Per method: the targets' median p99 figures are non-decreasing, and between
/// 1 / [`MODEL_FACTOR_BELOW`] and [`MODEL_FACTOR`] times the target where the method's parameter is a pixel threshold or goes
/// through a screen-error model. Prints the table.
fn check(name: &str, runs: &[RunRecord]) {
    println!("{name}: method | target px | p99 px | triangles");
    let mut failures = Vec::new();
    for kind in knob_methods() {
        let mine: Vec<&RunRecord> = runs.iter().filter(|r| r.method == kind).collect();
        assert_eq!(mine.len(), TARGETS.len(), "{kind:?}: one run per target");
        for r in &mine {
            assert_eq!(r.parameter, "error_px");
            assert!(r.summary.frames > 0 && r.summary.median_triangles > 0.0, "{kind:?}");
            println!(
                "{name}: {} | {} | {:.3} | {:.0}",
                kind.name(),
                r.value,
                r.summary.median_p99_px,
                r.summary.median_triangles
            );
        }
        let p99: Vec<f64> = mine.iter().map(|r| r.summary.median_p99_px).collect();
        for w in p99.windows(2) {
            if w[1] < w[0] * (1.0 - MONOTONE_SLACK) {
                failures.push(format!("{}: p99 decreases with the target: {p99:?}", kind.name()));
            }
        }
        let basis = params_for_error_px(kind, 1.0, ErrorView::REFERENCE).basis;
        if basis != ErrorPxBasis::Calibrated {
            for (r, px) in mine.iter().zip(TARGETS) {
                let ratio = r.summary.median_p99_px / px;
                if !(1.0 / MODEL_FACTOR_BELOW..=MODEL_FACTOR).contains(&ratio) {
                    failures.push(format!(
                        "{}: target {px} px measured {:.3} px (ratio {ratio:.2})",
                        kind.name(),
                        r.summary.median_p99_px
                    ));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{name}:\n{}", failures.join("\n"));
}

#[test]
fn measured_p99_follows_error_px_on_puget_sound() {
    check("puget1k", &sweep("puget1k", puget()));
}

#[test]
fn measured_p99_follows_error_px_on_big_tujunga() {
    check("bigtujunga", &sweep("bigtujunga", tujunga()));
}

/// At the default quality, from the default camera (the whole terrain from the south-west,
/// 1280 x 720), every in-memory method draws more than a handful of triangles (the old `dss-1`
/// default, `rho_thr = 1` on the DSS *mean* error, drew Puget Sound as one patch at factor 2,
/// 8 triangles) and, for the methods with a model, a measured p99 within [`MODEL_FACTOR`] of
/// the default target.
#[test]
fn no_method_draws_a_handful_of_triangles_at_the_default() {
    // The old dss-1 default drew 8; the fewest now are dss-1's and dss-strips' 128 (the root
    // at factor 8, p99 2.06 px: Puget Sound's flat sea dilutes the DSS mean error).
    const MIN_TRIANGLES: u64 = 100;
    let (w, h) = (1280, 720);
    let hm = puget();
    let camera = terrain_gpu::render::default_camera(&hm, w, h, 60.0);
    let view = ErrorView { height_px: f64::from(h), fov_y_deg: 60.0 };
    let mut scene = MethodScene::new(hm, MethodConfig::default());
    let mut failures = Vec::new();
    for kind in LodMethod::ALL.into_iter().filter(|&m| !registry::needs_store(m)) {
        scene.config = registry::default_config(kind, view);
        scene.config.pvs = PvsConfig { cells: (4, 4), patch_level: 4, ..PvsConfig::default() };
        scene.prepare(&[kind]);
        let method =
            build(kind, &scene, &MethodOptions { morph: true, ..Default::default() }).unwrap();
        let measure = MeasureConfig { max_samples: 200_000, ..MeasureConfig::default() };
        let mut frames = FrameLoop::new(method).measured(&scene.hm, &scene.qt, measure);
        let r = frames.frame(0, &camera, None).unwrap().record;
        let target = Quality::DEFAULT.error_px();
        println!(
            "{}: {} triangles, p99 {:.3} px, max {:.3} px",
            kind.name(),
            r.triangles,
            r.errors.p99_px,
            r.errors.max_px
        );
        if r.triangles < MIN_TRIANGLES {
            failures.push(format!("{}: {} triangles", kind.name(), r.triangles));
        }
        let basis = params_for_error_px(kind, target, view).basis;
        if basis != ErrorPxBasis::Calibrated && r.errors.p99_px > MODEL_FACTOR * target {
            failures.push(format!("{}: p99 {:.3} px", kind.name(), r.errors.p99_px));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// A quality option and the method's own parameter together are refused, naming both; a bad
/// target is refused; `mesh` takes them only with `--camera`.
#[test]
fn own_parameter_and_error_px_are_refused_together() {
    let out = std::env::temp_dir().join(format!("terrain-error-px-{}.png", std::process::id()));
    let out = out.to_str().unwrap();
    for (args, names) in [
        (
            &["--method", "uniform", "--factor", "4", "--error-px", "1"][..],
            ["--factor", "--error-px"],
        ),
        (
            &["--method", "dss-1", "--method-param", "0.5", "--quality", "fast"][..],
            ["--method-param", "--quality"],
        ),
    ] {
        let mut all = vec!["render"];
        all.extend_from_slice(args);
        all.extend_from_slice(&["-o", out]);
        let o = common::terrain(&all);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?}");
        for n in names {
            assert!(err.contains(n), "{args:?}: {err}");
        }
    }
    let o = common::terrain(&["render", "--error-px", "-1", "-o", out]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("--error-px must be a positive"));
    let o = common::terrain(&["mesh", "--max-error", "4", "--error-px", "1", "--stats"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("apply with --camera"));
}
