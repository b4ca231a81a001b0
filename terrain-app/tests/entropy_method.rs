//! The `entropy` benchmark method: each frame's Eq. 5 cut of the full tree is crack-free
//! (open edges only on the terrain's border), refines near the view and coarsens with E0, and
//! runs through the one frame loop (`method::FrameLoop`) with a measured (CPU) error.

mod common;

use glam::dvec3;
use terrain_app::entropy_method::{EntropyMethodConfig, EntropyScene};
use terrain_app::method::{FrameLoop, MethodOptions, build};
use terrain_app::methods::{LodMethod, MethodConfig, MethodScene};
use terrain_core::dem::{LoadOptions, load};
use terrain_core::geometry::Camera;
use terrain_core::measure::MeasureConfig;

fn puget() -> terrain_core::Heightmap {
    let opts = LoadOptions { vertical_scale: 0.1, spacing_m: 160.0, ..LoadOptions::default() };
    load(common::data("puget_sound/ps_height_1k.png"), &opts).unwrap().heightmap
}

#[test]
fn cuts_are_crack_free_refine_near_the_view_and_coarsen_with_e0() {
    let hm = puget();
    let cfg = EntropyMethodConfig { max_depth: 7, ..EntropyMethodConfig::default() };
    let scene = EntropyScene::new(&hm, &cfg);
    let o = hm.grid_to_world(0.0, 0.0);
    let eye = dvec3(o.x + 20_000.0, o.y + 20_000.0, 6000.0);
    let camera = Camera::look_at(eye, dvec3(o.x + 60_000.0, o.y + 60_000.0, 0.0))
        .with_viewport(640.0, 360.0)
        .with_clip(10.0, 400_000.0);
    let mut last = usize::MAX;
    for e0 in [0.0, 50.0, 80.0, 95.0] {
        let f = scene.frame(&camera, &EntropyMethodConfig { e0, ..cfg.clone() });
        let s = &f.surface;
        let (w, h) = ((hm.width() - 1) as f64, (hm.height() - 1) as f64);
        for e in s.open_edges() {
            let [a, b] = e.map(|k| s.grid[k as usize]);
            let border = (a.x == b.x && (a.x == 0.0 || a.x == w))
                || (a.y == b.y && (a.y == 0.0 || a.y == h));
            assert!(border, "E0 = {e0}: open edge {a} - {b} inside the terrain (a crack)");
        }
        assert!(s.triangles.len() <= last, "E0 = {e0}: more triangles than a lower E0");
        last = s.triangles.len();
    }
    // The tiles near the eye are finer than those in the far corner: more triangles there.
    let f = scene.frame(&camera, &EntropyMethodConfig { e0: 30.0, ..cfg.clone() });
    let count_near = |x: f64, y: f64| {
        f.surface
            .triangles
            .iter()
            .filter(|t| {
                let [a, b, c] = t.map(|k| f.surface.grid[k as usize]);
                let g = (a + b + c) / 3.0;
                (g.x - x).abs() < 100.0 && (g.y - y).abs() < 100.0
            })
            .count()
    };
    let (near, far) = (count_near(150.0, 150.0), count_near(950.0, 950.0));
    assert!(near > 2 * far, "triangles near the eye {near}, far {far}");
}

#[test]
fn the_benchmark_runner_measures_the_entropy_mesh() {
    let mut config = MethodConfig::default();
    config.entropy.max_depth = 7;
    config.entropy.e0 = 70.0;
    let scene = MethodScene::new(puget(), config);
    scene.prepare(&[LodMethod::Entropy]);
    let o = scene.hm.grid_to_world(512.0, 100.0);
    let camera = Camera::look_at(dvec3(o.x, o.y, 5000.0), dvec3(o.x, o.y + 50_000.0, 1000.0))
        .with_viewport(640.0, 360.0)
        .with_clip(10.0, 400_000.0);
    let method = build(LodMethod::Entropy, &scene, &MethodOptions::default()).unwrap();
    let mut runner =
        FrameLoop::new(method).measured(&scene.hm, &scene.qt, MeasureConfig::default());
    let r = runner.frame(0, &camera, None).unwrap().record;
    assert!(r.triangles > 0 && r.patches > 0);
    assert!(r.errors.samples > 0, "{r:?}");
    assert_eq!(r.errors.unlocated, 0, "every sample in view lies on the mesh");
    assert!(r.errors.rmse_m > 0.0 && r.errors.rmse_m <= r.errors.max_abs_m);
    assert!(r.render_ms.is_none(), "not drawn on the GPU");
    assert!(LodMethod::ALL.contains(&LodMethod::Entropy));
    assert_eq!(LodMethod::Entropy.name(), "entropy");
}

/// The entropy mesh drawn on the GPU as extra triangles (`bench::entropy_extra`): seen from
/// above, the terrain fills the view with no background pixel (no hole, no crack), and the
/// same mesh with a block of triangles removed shows background there (the test can fail).
#[test]
fn the_entropy_mesh_draws_without_holes_on_the_gpu() {
    use terrain_app::bench::entropy_extra;
    use terrain_gpu::render::BACKGROUND;
    use terrain_gpu::{BackendChoice, DeviceConfig, GpuContext, RenderConfig, RenderOptions};
    use terrain_gpu::{TerrainRenderer, render::ExtraTriangles};

    let Some(ctx) =
        GpuContext::try_new(&DeviceConfig::from_env(BackendChoice::Auto)).expect("GPU set-up")
    else {
        println!("SKIPPED: no GPU adapter; set TERRAIN_REQUIRE_GPU=1 to make this a failure");
        return;
    };
    println!("adapter: {}", ctx.describe());
    let hm = puget();
    let cfg = EntropyMethodConfig { max_depth: 7, e0: 70.0, ..EntropyMethodConfig::default() };
    let scene = EntropyScene::new(&hm, &cfg);
    // Straight down over the centre, the view well inside the terrain.
    let c = hm.grid_to_world(512.0, 512.0);
    let top = hm.data().iter().fold(f32::MIN, |a, &b| a.max(b)) as f64;
    let camera = Camera::look_at(dvec3(c.x, c.y - 1.0, top + 40_000.0), dvec3(c.x, c.y, 0.0))
        .with_viewport(160.0, 90.0)
        .with_clip(100.0, 400_000.0);
    let f = scene.frame(&camera, &cfg);
    let (carrier, extra) = entropy_extra(&hm, &f.surface);
    assert_eq!(extra.indices.len(), 3 * f.surface.triangles.len());
    let config = RenderConfig { width: 160, height: 90, ..RenderConfig::default() };
    let mut r = TerrainRenderer::new(&ctx, &hm, &config).unwrap();
    let background = |r: &mut TerrainRenderer, extra: &ExtraTriangles| {
        r.render_with_extra(&camera, &[carrier], extra, &RenderOptions::default()).unwrap();
        r.read_image().unwrap().pixels.iter().filter(|p| **p == BACKGROUND).count()
    };
    assert_eq!(background(&mut r, &extra), 0, "holes in the drawn entropy mesh");
    // Negative control: drop every triangle with a vertex near the centre.
    let mut holed = extra.clone();
    holed.indices = extra
        .indices
        .chunks_exact(3)
        .filter(|t| {
            !t.iter().any(|&k| {
                let uv = extra.points[k as usize].uv;
                (uv[0] - 0.5).abs() < 0.05 && (uv[1] - 0.5).abs() < 0.05
            })
        })
        .flatten()
        .copied()
        .collect();
    assert!(holed.indices.len() < extra.indices.len());
    assert!(background(&mut r, &holed) > 0, "a hole must show the background");
}
