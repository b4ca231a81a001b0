//! The benchmark's geomorph branch end to end on a small synthetic DEM: its own selection,
//! CPU morph reference, measurement and (where a GPU exists) renderer; every frame after the
//! first reports the largest per-vertex jump from the flight's previous frame with and
//! without tweening, and the Markdown report shows them. Rendering is skipped with a printed
//! reason only when no adapter exists and `TERRAIN_REQUIRE_GPU` is unset.

use terrain_app::bench::{BenchConfig, run_bench};
use terrain_app::methods::{LodMethod, MethodConfig};
use terrain_core::flight::FlightSpec;
use terrain_core::synth::FractalConfig;
use terrain_gpu::{BackendChoice, DeviceConfig, GpuContext};

const FLIGHT: &str = r#"{ "name": "e2e", "fps": 30, "height_above": "mean",
  "keyframes": [
    { "t": 0, "relative": [0.1, 0.1, 0.6], "yaw": 45, "pitch": -25 },
    { "t": 1, "relative": [0.5, 0.3, 0.5], "look_at": "center" } ] }"#;

#[test]
fn geomorph_bench_reports_jumps_with_and_without_tweening() {
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
        methods: vec![LodMethod::Geomorph],
        max_frames: 10,
        sweep_points: 2,
        render_size: Some((64, 36)),
        method: MethodConfig { leaf_cells: 16, ..MethodConfig::default() },
        ..BenchConfig::default()
    };
    let report = run_bench("fractal 129", hm, &[flight], &cfg, ctx.as_ref(), &mut |_| {}).unwrap();
    let params: Vec<f64> = report.runs.iter().map(|r| r.value).collect();
    assert_eq!(params, [0.5, 8.0]);
    for run in &report.runs {
        assert_eq!(run.frames.len(), 10);
        for (k, f) in run.frames.iter().enumerate() {
            assert!(f.triangles > 0 && f.patches > 0);
            assert_eq!(f.errors.unlocated, 0, "the measured surface has holes");
            assert_eq!(f.vertex_jump_m.is_some(), f.frame > 0, "frame {k}");
            if let (Some(a), Some(b)) = (f.vertex_jump_m, f.vertex_jump_no_morph_m) {
                assert!(a.is_finite() && b.is_finite() && a >= 0.0);
            }
            assert_eq!(f.material_passes_skipped.is_some(), ctx.is_some());
        }
        let s = &run.summary;
        let (with, without) = (s.max_vertex_jump_m.unwrap(), s.max_vertex_jump_no_morph_m.unwrap());
        println!(
            "tau {}: largest jump {with:.4} m with tweening, {without:.4} m without",
            run.value
        );
        assert!(with <= without, "tweening should not pop more than integer levels");
    }
    assert!(report.to_markdown().contains("largest per-vertex height jump"));
}
