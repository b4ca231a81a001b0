//! The renderer's crack test for every LOD method: each method's selection, converted to draw
//! patches exactly as `terrain render` does, is drawn from 21 cameras (straight down to 1.5°
//! grazing) over a fractal, the cliff and spike hard cases and Puget Sound 1k; no pixel may
//! show background where the skirted reference shows terrain (see `terrain_gpu::render::crack`
//! for why that reference, not a full-resolution render). Skips with a printed reason only when
//! no adapter exists and `TERRAIN_REQUIRE_GPU` is unset.

use terrain_app::method::registry::draws_mesh;
use terrain_app::methods::{LodMethod, MethodConfig, MethodScene};
use terrain_core::Heightmap;
use terrain_core::dem::{self, LoadOptions};
use terrain_core::lod::check_shared_edges;
use terrain_core::synth::{FractalConfig, HardCase};
use terrain_gpu::render::crack::{crack_cameras, crack_pixels_with_extra};
use terrain_gpu::render::{DrawPatch, ExtraTriangles};
use terrain_gpu::{BackendChoice, DeviceConfig, GpuContext};
use terrain_tests::data_file;

#[test]
fn no_crack_on_a_fractal() {
    no_method_draws_a_crack(
        "fractal 257",
        FractalConfig::with_size(257, 257, 10.0).to_heightmap().unwrap(),
    );
}

#[test]
fn no_crack_on_the_cliff() {
    no_method_draws_a_crack("cliff", HardCase::Cliff.build());
}

#[test]
fn no_crack_on_the_spike() {
    no_method_draws_a_crack("spike", HardCase::Spike.build());
}

#[test]
fn no_crack_on_puget_sound() {
    let puget = dem::load(
        data_file("puget_sound/ps_height_1k.png"),
        &LoadOptions { vertical_scale: 0.1, spacing_m: 160.0, ..LoadOptions::default() },
    )
    .expect("Puget Sound 1k loads")
    .heightmap;
    no_method_draws_a_crack("puget sound 1k", puget);
}

fn no_method_draws_a_crack(name: &str, hm: Heightmap) {
    let config = DeviceConfig::from_env(BackendChoice::Auto);
    let Some(ctx) = GpuContext::try_new(&config).expect("GPU set-up") else {
        println!("SKIPPED: no GPU adapter; set TERRAIN_REQUIRE_GPU=1 to make this a failure");
        return;
    };
    println!("adapter: {}", ctx.describe());
    {
        // Small grids get small leaves, so every method has levels to choose from.
        let leaf_cells = if hm.width() < 200 { 4 } else { 16 };
        let mut config = MethodConfig { leaf_cells, ..MethodConfig::default() };
        // The PVS methods bake their PVS in memory: a small one keeps this test fast (the
        // culling still removes patches next to drawn ones, which is what can crack).
        config.pvs.cells = (4, 4);
        config.pvs.patch_level = 4;
        let scene = MethodScene::new(hm, config);
        let cameras = crack_cameras(&scene.hm, leaf_cells as usize + 1);
        assert!(cameras.len() >= 20);
        // dss-strips draws extra triangles and shares no patch edges: tests/tests/dss_strips.rs.
        // entropy and tin draw a triangle mesh, not patches: tin in terrain-app/tests/tin_method.rs;
        // entropy's watertightness is tested in
        // terrain-visibility/tests/entropy.rs and terrain-app/tests/entropy_method.rs.
        // `ooc` draws from a store through its own runtime (terrain_app::ooc); its cracks are
        // tested in terrain-app/tests/ooc_render.rs.
        let patch_methods = LodMethod::ALL
            .into_iter()
            .filter(|&m| !m.has_strips() && !draws_mesh(m) && m != LodMethod::OutOfCore);
        // Every method's selection from every camera first, then all frames through one
        // renderer: building a renderer (pipelines, the height texture) per camera was most of
        // this test's time on lavapipe.
        let mut runs = Vec::new();
        for method in patch_methods {
            let mut levels = std::collections::BTreeSet::new();
            let mut frames = Vec::new();
            for camera in &cameras {
                let selection = scene.select(method, camera);
                assert!(
                    check_shared_edges(&selection).is_empty(),
                    "{name} {}: factors disagree",
                    method.name()
                );
                levels.extend(selection.patches.iter().map(|p| p.node.level));
                frames.push(scene.draw_patches(&selection));
            }
            runs.push((method, levels, frames));
        }
        // Methods that select the same patches from a camera (geomorph and its variants, say)
        // draw the same image: each distinct (camera, patches) frame is rendered once.
        let empty = ExtraTriangles::default();
        let mut distinct: Vec<(usize, &[DrawPatch])> = Vec::new();
        let mut frame_of = Vec::new();
        for (_, _, frames) in &runs {
            for (i, patches) in frames.iter().enumerate() {
                let key = (i, patches.as_slice());
                let at = distinct.iter().position(|d| *d == key).unwrap_or_else(|| {
                    distinct.push(key);
                    distinct.len() - 1
                });
                frame_of.push(at);
            }
        }
        let to_draw: Vec<_> = distinct.iter().map(|&(i, p)| (cameras[i], p, &empty)).collect();
        let drawn = crack_pixels_with_extra(&ctx, &scene.hm, &to_draw, (128, 72));
        assert_eq!(drawn.len(), to_draw.len());
        let mut all_cracks = frame_of.into_iter().map(|at| drawn[at]);
        for (method, levels, frames) in &runs {
            let method = *method;
            let patches_per_camera: Vec<usize> = frames.iter().map(Vec::len).collect();
            let cracks: Vec<usize> = all_cracks.by_ref().take(frames.len()).collect();
            println!(
                "{name} {}: levels {levels:?}, patches {patches_per_camera:?}, crack pixels {cracks:?}",
                method.name()
            );
            assert!(
                cracks.iter().all(|&c| c == 0),
                "{name} {}: crack pixels {cracks:?}",
                method.name()
            );
            // The LOD methods must actually mix levels on the larger terrains, or the test proves
            // little. (On the 65-sample hard cases one DSS patch at factor 64 is already full
            // resolution, so a single level is the right answer there.)
            if matches!(method, LodMethod::PvpsC | LodMethod::Dss1) && scene.hm.width() > 200 {
                assert!(levels.len() > 1, "{name} {}: a single level {levels:?}", method.name());
            }
        }
    }
}
