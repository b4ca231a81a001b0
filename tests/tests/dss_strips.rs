//! The DSS paper's stitching-strip method (`dss-strips`) end to end through the app's method
//! scene, as `terrain render` and the benchmark draw it: watertight on the CPU on Puget Sound
//! 1k (only the grid's border open, plan areas adding up to the grid), and no crack pixel on the
//! renderer on a small fractal (the small variant of `lod_cracks.rs`: 7 cameras, 128 x 72).
//! The GPU part skips with a printed reason only when no adapter exists and
//! `TERRAIN_REQUIRE_GPU` is unset.

use terrain_app::methods::{LodMethod, MethodConfig, MethodScene};
use terrain_core::dem::{self, LoadOptions};
use terrain_core::synth::FractalConfig;
use terrain_gpu::render::crack::{crack_cameras, crack_pixels_with_extra};
use terrain_gpu::{BackendChoice, DeviceConfig, GpuContext};
use terrain_tests::data_file;

#[test]
fn dss_strips_surface_is_watertight_on_puget_sound() {
    let puget = dem::load(
        data_file("puget_sound/ps_height_1k.png"),
        &LoadOptions { vertical_scale: 0.1, spacing_m: 160.0, ..LoadOptions::default() },
    )
    .expect("Puget Sound 1k loads")
    .heightmap;
    let (w, h) = ((puget.width() - 1) as f64, (puget.height() - 1) as f64);
    let mut config = MethodConfig::default();
    config.dss.frustum_cull = false; // the whole grid, so its border is the only open edge
    config.dss.rho_thr = 2.0;
    let scene = MethodScene::new(puget, config);
    let cameras = crack_cameras(&scene.hm, 17);
    let mut levels = std::collections::BTreeSet::new();
    for camera in cameras.iter().step_by(5) {
        let camera = camera.with_viewport(1280.0, 720.0);
        let frame = scene.frame(LodMethod::DssStrips, &camera);
        let strips = frame.strips.as_ref().expect("dss-strips builds strips");
        assert!(strips.mesh.strips > 0 && strips.mesh.pblocks > 0);
        levels.extend(frame.selection.patches.iter().map(|p| p.node.level));
        let (mesh, triangles) = scene.frame_surface(&frame);
        assert!(triangles > 0);
        let inner: Vec<_> = mesh
            .open_edges()
            .into_iter()
            .filter(|e| {
                let (a, b) = (mesh.grid[e[0] as usize], mesh.grid[e[1] as usize]);
                !((a.x == 0.0 && b.x == 0.0)
                    || (a.y == 0.0 && b.y == 0.0)
                    || (a.x == w && b.x == w)
                    || (a.y == h && b.y == h))
            })
            .collect();
        assert!(inner.is_empty(), "open edges inside the grid: {:?}", &inner[..inner.len().min(5)]);
        let area: f64 = mesh
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|k| mesh.grid[k as usize]);
                0.5 * (b - a).perp_dot(c - a)
            })
            .sum();
        assert!((area - w * h).abs() < 1e-6 * w * h, "plan area {area} vs {}", w * h);
    }
    assert!(levels.len() > 1, "a single level {levels:?}");
}

#[test]
fn dss_strips_draws_no_crack() {
    let config = DeviceConfig::from_env(BackendChoice::Auto);
    let Some(ctx) = GpuContext::try_new(&config).expect("GPU set-up") else {
        println!("SKIPPED: no GPU adapter; set TERRAIN_REQUIRE_GPU=1 to make this a failure");
        return;
    };
    println!("adapter: {}", ctx.describe());
    let hm = FractalConfig::with_size(257, 257, 10.0).to_heightmap().unwrap();
    let scene = MethodScene::new(hm, MethodConfig { leaf_cells: 8, ..MethodConfig::default() });
    let cameras: Vec<_> = crack_cameras(&scene.hm, 9).into_iter().step_by(3).collect();
    let frames: Vec<_> =
        cameras.iter().map(|c| scene.frame_draw(&scene.frame(LodMethod::DssStrips, c))).collect();
    assert!(frames.iter().all(|(_, extra)| !extra.indices.is_empty()));
    let with: Vec<_> =
        cameras.iter().zip(&frames).map(|(c, (p, extra))| (*c, &p[..], extra)).collect();
    let cracks = crack_pixels_with_extra(&ctx, &scene.hm, &with, (128, 72));
    println!("dss-strips crack pixels per camera: {cracks:?}");
    assert!(cracks.iter().all(|&c| c == 0), "crack pixels {cracks:?}");
}
