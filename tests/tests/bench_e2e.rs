//! The benchmark end to end on a small synthetic DEM: 30 frames of a flight, two methods, two
//! sweep points each, measured (and rendered at 64 x 36 where a GPU exists); checks the report's
//! fields and sanity, and that the uniform method at full resolution has no error. Rendering
//! is skipped with a printed reason only when no adapter exists and `TERRAIN_REQUIRE_GPU` is unset.

use terrain_app::bench::{BenchConfig, run_bench};
use terrain_app::methods::{LodMethod, MethodConfig};
use terrain_core::flight::FlightSpec;
use terrain_core::synth::FractalConfig;
use terrain_gpu::{BackendChoice, DeviceConfig, GpuContext};

/// One second at 30 fps: exactly 30 frames, a low pass looking across the terrain.
const FLIGHT: &str = r#"{ "name": "e2e", "fps": 30, "height_above": "mean",
  "keyframes": [
    { "t": 0, "relative": [0.1, 0.1, 0.6], "yaw": 45, "pitch": -25 },
    { "t": 1, "relative": [0.5, 0.3, 0.5], "look_at": "center" } ] }"#;

#[test]
fn bench_reports_sane_speed_and_error_for_two_methods() {
    let hm = FractalConfig::with_size(129, 129, 10.0).to_heightmap().unwrap();
    let flight = FlightSpec::parse(FLIGHT).unwrap();
    let ctx =
        GpuContext::try_new(&DeviceConfig::from_env(BackendChoice::Auto)).expect("GPU set-up");
    match &ctx {
        Some(c) => println!("adapter: {}", c.describe()),
        None => println!(
            "SKIPPED rendering: no GPU adapter; set TERRAIN_REQUIRE_GPU=1 to make this a failure"
        ),
    }
    let cfg = BenchConfig {
        methods: vec![LodMethod::Uniform, LodMethod::PvpsC],
        max_frames: 0,
        sweep_points: 2,
        render_size: Some((64, 36)),
        method: MethodConfig { leaf_cells: 16, ..MethodConfig::default() },
        ..BenchConfig::default()
    };
    let mut calls = 0;
    let report = run_bench("fractal 129", hm, &[flight], &cfg, ctx.as_ref(), &mut |p| {
        calls += 1;
        assert!(p.done <= p.total);
    })
    .unwrap();
    assert_eq!(report.grid, [129, 129]);
    assert_eq!(report.flights.len(), 1);
    assert_eq!(report.flights[0].total_frames, 30);
    assert_eq!(report.flights[0].frames.len(), 30);
    // Two methods, two sweep points each: uniform at 16 (= leaf cells: full resolution) and 2.
    let params: Vec<(LodMethod, f64)> = report.runs.iter().map(|r| (r.method, r.value)).collect();
    assert_eq!(
        params,
        [
            (LodMethod::Uniform, 16.0),
            (LodMethod::Uniform, 2.0),
            (LodMethod::PvpsC, 12.5),
            (LodMethod::PvpsC, 200.0)
        ]
    );
    assert_eq!(calls, 4 * 30);
    assert_eq!(report.adapter.is_some(), ctx.is_some());
    assert!(report.timing_notes.len() >= 2, "{:?}", report.timing_notes);

    for run in &report.runs {
        let name = format!("{} {}={}", run.method.name(), run.parameter, run.value);
        assert_eq!(run.frames.len(), 30, "{name}");
        for f in &run.frames {
            let e = &f.errors;
            assert!(f.triangles > 0 && f.patches > 0, "{name} frame {}: nothing drawn", f.frame);
            for x in [
                e.max_px,
                e.p99_px,
                e.rmse_m,
                e.max_abs_m,
                e.popping_rms_m,
                f.selection_ms,
                f.cpu_ms,
            ] {
                assert!(x.is_finite() && x >= 0.0, "{name} frame {}: {x}", f.frame);
            }
            assert!(
                e.p99_px <= e.max_px,
                "{name} frame {}: p99 {} > max {}",
                f.frame,
                e.p99_px,
                e.max_px
            );
            assert!(e.samples > 0, "{name} frame {}: nothing measured", f.frame);
            assert_eq!(e.unlocated, 0, "{name} frame {}: holes in the drawn surface", f.frame);
            assert_eq!(f.encode_ms.is_some(), ctx.is_some(), "{name}: render timing");
            assert_eq!(f.upload_bytes.is_some(), ctx.is_some(), "{name}: upload bytes");
        }
        let s = &run.summary;
        assert!(s.median_triangles > 0.0 && s.max_p99_px <= s.max_px, "{name}: {s:?}");
    }
    let full = &report.runs[0];
    let worst = full.frames.iter().map(|f| f.errors.max_abs_m).fold(0.0, f64::max);
    assert!(worst < 1e-3, "uniform at full resolution is off by {worst} m");
    assert_eq!(full.summary.false_culls, 0);
    // Coarser means fewer triangles and more error.
    let coarse = &report.runs[1].summary;
    assert!(coarse.median_triangles < full.summary.median_triangles);
    assert!(coarse.median_rmse_m > 0.1, "uniform factor 2 rmse {}", coarse.median_rmse_m);

    let json = serde_json::to_value(&report).unwrap();
    let frame = &json["runs"][0]["frames"][0];
    for key in [
        "selection_ms",
        "cpu_tess_ms",
        "triangles",
        "p99_px",
        "max_px",
        "rmse_m",
        "popping_rms_m",
        "false_culls",
        "rss_bytes",
    ] {
        assert!(frame.get(key).is_some(), "JSON frame lacks {key}: {frame}");
    }
    let md = report.to_markdown();
    assert!(
        md.contains("| uniform | factor = 16 |") && md.contains("| pvps-c | C1 = 12.5 |"),
        "{md}"
    );
    let svg = report.to_svg();
    assert!(svg.starts_with("<svg") && svg.matches("<polyline").count() == 4, "{svg}");
}
