//! Every LOD method that draws from a baked store selects, for the same camera, the same
//! patches and draws the same heights as from the DEM in memory (issue 13, item 2): `uniform`,
//! `pvps-a/b/c`, `dss-1`, `dss-2`, `dss-strips` and `geomorph` (with its vertex-shader morph:
//! the same morphed heights, vertex for vertex) over Puget Sound 1k and over a non-square
//! GeoTIFF with voids (Crater Lake, 429 x 279, 39,489 void cells), warm frames; real-time
//! frames before the levels arrive still draw every patch, and geomorph's morph over coarse
//! pages draws no crack on the GPU (with its negative control); methods that cannot draw from
//! a store yet say so.

mod common;

use std::ops::ControlFlow;
use std::path::Path;
use std::sync::Arc;

use terrain_app::method::{self, Draw, MethodOptions, OocWait};
use terrain_app::methods::{LodMethod, MethodConfig, MethodScene};
use terrain_app::ooc::{OocConfig, OocScene};
use terrain_core::Heightmap;
use terrain_core::dem::{LoadOptions, load};
use terrain_core::geometry::Camera;
use terrain_core::lod::check_shared_edges;
use terrain_gpu::render::{clip_range, default_camera};
use terrain_stream::{BakeConfig, BakeProgress, HeightEncoding, Store, bake};

use common::{data, scratch};

fn puget() -> Heightmap {
    let options = LoadOptions { vertical_scale: 0.1, spacing_m: 160.0, ..Default::default() };
    load(data("puget_sound/ps_height_1k.png"), &options).unwrap().heightmap
}

fn crater_lake() -> Heightmap {
    let options = LoadOptions { nodata: Some(-32767.0), ..Default::default() };
    let hm = load(data("crater_lake/craterlake-elev-16bit-30m.tif"), &options).unwrap().heightmap;
    assert!(hm.voids().count() > 30_000, "the voids are read");
    hm
}

/// `scene`'s DEM baked with exact f32 heights, with the DSS errors written beside the blocks
/// as `terrain bake` writes them.
fn bake_scene(scene: &MethodScene, dir: &Path) -> Arc<Store> {
    let config = BakeConfig { encoding: HeightEncoding::F32, threads: 1, ..Default::default() };
    bake(&scene.hm, dir, &config, &mut |_: &BakeProgress| ControlFlow::Continue(())).unwrap();
    terrain_app::dss_scene::bake_into_scene(&scene.hm, &scene.qt, dir).unwrap();
    terrain_app::roughness_scene::bake_from_heightmap(&scene.hm, 16, dir, true).unwrap();
    terrain_app::geomip_scene::bake_into_scene(&scene.hm, scene.config.leaf_cells, dir).unwrap();
    Arc::new(Store::open(dir).unwrap())
}

fn cameras(hm: &Heightmap) -> Vec<Camera> {
    let overview = default_camera(hm, 640, 360, 60.0);
    let (w, h) = (hm.width() as f64, hm.height() as f64);
    let low = {
        let xy = hm.grid_to_world(0.3 * w, 0.2 * h);
        let eye = xy.extend(f64::from(hm.max()) + 300.0);
        let (near, far) = clip_range(hm, eye);
        Camera::from_yaw_pitch(eye, 40.0, -20.0)
            .with_fov_y_deg(60.0)
            .with_viewport(640.0, 360.0)
            .with_clip(near, far)
    };
    vec![overview, low]
}

fn check(name: &str, hm: Heightmap) {
    let scene = MethodScene::new(hm, MethodConfig::default());
    let scratch_dir = scratch("store-methods", name);
    let dir = scratch_dir.join("store");
    let store = bake_scene(&scene, &dir);
    let ooc = OocConfig { threads: 1, ..OocConfig::default() };
    for kind in [
        LodMethod::Uniform,
        LodMethod::PvpsA,
        LodMethod::PvpsB,
        LodMethod::PvpsC,
        LodMethod::Dss1,
        LodMethod::Dss2,
        LodMethod::DssStrips,
        LodMethod::Geomorph,
    ] {
        scene.prepare(&[kind]);
        // Geomorph with its morph from memory, as from the store.
        let options = MethodOptions { morph: kind == LodMethod::Geomorph, ..Default::default() };
        let mut memory = method::build(kind, &scene, &options).unwrap();
        let runtime = OocScene::new(store.clone(), ooc);
        let mut stored =
            method::store_method(kind, runtime, &scene.config, OocWait::EveryFrame, Some(&scene))
                .unwrap();
        assert_eq!(stored.kind(), kind);
        for (c, camera) in cameras(&scene.hm).iter().enumerate() {
            let mut a = memory.frame(camera);
            let mut b = stored.frame(camera);
            // The drawn surfaces, rebuilt with the renderers' CPU references (the tessellator
            // over the whole heightmap; over the store's pages): the measurement, which also
            // builds the coverage of a store's geomorph frame (its frame works on the runs).
            let sa = memory.surface(&mut a).unwrap();
            let sb = stored.surface(&mut b).unwrap();
            assert_eq!(a.stats.patches, b.stats.patches, "{name} {kind:?} camera {c}");
            assert!(!a.selection.patches.is_empty(), "{name} {kind:?} camera {c}: draws");
            assert_eq!(
                a.selection.patches, b.selection.patches,
                "{name} {kind:?} camera {c}: the same patches from the store"
            );
            if !kind.has_strips() {
                assert!(check_shared_edges(&b.selection).is_empty());
            }
            let blocks = b.stats.blocks.unwrap();
            assert_eq!(blocks.blocks_dropped, 0, "{name} {kind:?}: every block drawn");
            let stream = b.stats.stream.clone().unwrap();
            assert!(stream.at_needed_level, "{name} {kind:?}: a warm frame");
            if let (Draw::Morph(la, _), Draw::PagedMorph(_, lb)) = (&a.draw, &b.draw) {
                // Both compact (runs of coarsest patches and single patches): the same runs, and
                // the same patches expanded.
                assert_eq!(la.runs, lb.runs, "{name} camera {c}: the same runs");
                let (la, lb) = (la.expand(), lb.expand());
                assert_eq!(la.patches, lb.patches, "{name} camera {c}: the same levels and tweens");
                assert!(lb.patches.iter().any(|p| p.tween > 0.0), "{name} camera {c}: morphing");
            } else {
                assert!(kind != LodMethod::Geomorph, "{name} camera {c}: geomorph morphs");
            }
            // The same heights.
            assert_eq!(sa.triangles, sb.triangles, "{name} {kind:?} camera {c}");
            assert_eq!(sa.mesh.positions.len(), sb.mesh.positions.len());
            let worst = largest_height_difference(&sa.mesh.positions, &sb.mesh.positions);
            println!(
                "{name} {}: camera {c}: {} patches, {} triangles, {} blocks, largest height \
                 difference {worst} m",
                kind.name(),
                b.selection.patches.len(),
                sb.triangles,
                blocks.blocks_drawn
            );
            assert_eq!(worst, 0.0, "{name} {kind:?} camera {c}: the same heights");
            // Geomorph's popping figures from the store, as from memory.
            let previous = cameras(&scene.hm)[0];
            let ja = memory.vertex_jumps(&previous, camera, &sa);
            let jb = stored.vertex_jumps(&previous, camera, &sb);
            assert_eq!(ja.is_some(), kind == LodMethod::Geomorph, "{name} {kind:?}");
            if let (Some(ja), Some(jb)) = (ja, jb) {
                println!("{name} geomorph camera {c}: vertex jumps memory {ja:?}, store {jb:?}");
                assert_eq!(ja, jb, "{name} camera {c}: the same vertex jumps");
            } else {
                assert!(jb.is_none(), "{name} {kind:?}");
            }
        }
    }
}

#[test]
fn methods_draw_puget_sound_from_a_store_as_from_memory() {
    check("puget", puget());
}

#[test]
fn methods_draw_a_non_square_dem_with_voids_from_a_store_as_from_memory() {
    check("crater", crater_lake());
}

/// Real time: the first frame waits, later ones never do; a camera jump draws every patch the
/// method selects (coarser heights until the levels arrive), crack-free.
#[test]
fn real_time_frames_draw_every_patch_while_levels_load() {
    let hm = crater_lake();
    let scene = MethodScene::new(hm, MethodConfig::default());
    let scratch_dir = scratch("store-methods", "realtime");
    let dir = scratch_dir.join("store");
    let store = bake_scene(&scene, &dir);
    let ooc = OocConfig { threads: 1, budget_bytes: 4 << 20, ..OocConfig::default() };
    let runtime = OocScene::new(store, ooc);
    let mut m = method::store_method(
        LodMethod::Dss2,
        runtime,
        &scene.config,
        OocWait::FirstFrame,
        Some(&scene),
    )
    .unwrap();
    let cams = cameras(&scene.hm);
    for (k, camera) in [cams[0], cams[1], cams[0], cams[1]].iter().enumerate() {
        let mut f = m.frame(camera);
        let stream = f.stats.stream.clone().unwrap();
        assert_eq!(stream.waited_for_io, k == 0, "frame {k}: only the first frame waits");
        assert!(!f.selection.patches.is_empty(), "frame {k}");
        assert!(check_shared_edges(&f.selection).is_empty(), "frame {k}");
        let s = m.surface(&mut f).unwrap();
        assert!(s.triangles > 0 && s.mesh.positions.iter().all(|p| p.z.is_finite()));
    }
}

/// A view whose exact demand is larger than the cache budget: real-time frames hold it to the
/// budget (PVPS's continuous factors, and the DSS strips' blocks, ask the power-of-two lattice
/// above their factors, not full resolution), so they need fewer bytes than exactly, and draw
/// every patch within the drawn levels' static error; a warm measurement (every frame waits,
/// heights taken to be the DEM's) keeps the exact demand, above the budget, and draws
/// memory's heights. Without `OocScene::with_exact_demand` the
/// warm frame would be held too and this fails. A real-time run's first frame, which waits,
/// holds its demand to the real-time share as its later frames do (`OocScene::with_real_time`),
/// where a waiting run's frame asks an exact demand that fits the whole budget.
#[test]
fn a_demand_above_the_budget_is_held_to_lattices_but_not_when_measured_warm() {
    // A grid seen whole, small on screen: the normals (the streamer's shading level) need less
    // than full resolution, so the patches' demand decides.
    let hm =
        terrain_core::synth::FractalConfig::with_size(1025, 1025, 10.0).to_heightmap().unwrap();
    let scene = MethodScene::new(hm, MethodConfig::default());
    let scratch_dir = scratch("store-methods", "held");
    let dir = scratch_dir.join("store");
    let store = bake_scene(&scene, &dir);
    let ooc = OocConfig { threads: 1, budget_bytes: 64 << 10, ..OocConfig::default() };
    let budget_mib = (64 << 10) as f64 / (1 << 20) as f64;
    let camera = default_camera(&scene.hm, 256, 144, 60.0);
    // PVPS's continuous factors on the patches' squares; the DSS paper's shrunk M-blocks and
    // strips, whose exact demand is every carrier's full resolution.
    for kind in [LodMethod::PvpsC, LodMethod::DssStrips] {
        scene.prepare(&[kind]);
        let open = |wait| {
            let runtime = OocScene::new(store.clone(), ooc);
            method::store_method(kind, runtime, &scene.config, wait, Some(&scene)).unwrap()
        };
        let mut memory = method::build(kind, &scene, &MethodOptions::default()).unwrap();
        let (mut held, mut warm) = (open(OocWait::FirstFrame), open(OocWait::EveryFrame));
        let mut a = memory.frame(&camera);
        let sa = memory.surface(&mut a).unwrap();
        let mut w = warm.frame(&camera);
        let ws = w.stats.stream.clone().unwrap();
        assert!(!ws.demand_on_lattice, "{kind:?}: a warm measurement's demand is exact");
        assert!(ws.needed_mib > budget_mib, "{kind:?}: {} MiB fit the budget", ws.needed_mib);
        let sw = warm.surface(&mut w).unwrap();
        assert_eq!(largest_height_difference(&sa.mesh.positions, &sw.mesh.positions), 0.0);
        let mut h = held.frame(&camera);
        let hs = h.stats.stream.clone().unwrap();
        assert!(hs.demand_on_lattice, "{kind:?}: real time holds the demand");
        // A real-time run's first frame waits, but holds its demand to the real-time share
        // of the budget (a quarter), below what a waiting run's frame asks of the whole budget
        // (here twice the exact demand: the waiting frame's is exact, the real-time one's
        // held).
        let twice = OocConfig { budget_bytes: (ws.needed_mib * f64::from(1 << 21)) as u64, ..ooc };
        let first = |wait| {
            let runtime = OocScene::new(store.clone(), twice);
            let mut m = method::store_method(kind, runtime, &scene.config, wait, None).unwrap();
            m.frame(&camera).stats.stream.unwrap()
        };
        let (rt, wt) = (first(OocWait::FirstFrame), first(OocWait::EveryFrame));
        println!(
            "{kind:?}: first frame needs {:.4} MiB real time, {:.4} MiB waiting, budget {:.4}",
            rt.needed_mib,
            wt.needed_mib,
            twice.budget_bytes as f64 / f64::from(1 << 20)
        );
        assert!(rt.demand_on_lattice && !wt.demand_on_lattice, "{kind:?}");
        assert!(rt.needed_mib < wt.needed_mib, "{kind:?}");
        assert!(
            hs.needed_mib < ws.needed_mib,
            "{kind:?}: held {} MiB, exact {} MiB",
            hs.needed_mib,
            ws.needed_mib
        );
        assert_eq!(a.selection.patches, h.selection.patches, "{kind:?}");
        // Each drawn height within the static error of its block's drawn level (the largest
        // of the blocks drawn: the drawn surface is bilinear over that level's lattice,
        // memory's over the samples, and their difference is largest at a sample).
        let Draw::Paged(pf) = &h.draw else { panic!("a paged frame") };
        let k = store.header().k;
        let bound = pf
            .drawn
            .iter()
            .map(|&(b, level)| {
                let e = store.entry(b).unwrap();
                if level >= k { 0.0 } else { f64::from(e.level_errors[level as usize]) }
            })
            .fold(0.0, f64::max);
        let sh = held.surface(&mut h).unwrap();
        let worst = largest_height_difference(&sa.mesh.positions, &sh.mesh.positions);
        println!(
            "{kind:?}: needed {:.3} MiB held, {:.3} MiB exact; largest height difference \
             {worst:.2} m, bound {bound:.2} m",
            hs.needed_mib, ws.needed_mib
        );
        assert_eq!(sh.triangles, sa.triangles, "{kind:?}");
        assert!(worst > 0.0 && worst <= bound * (1.0 + 1e-6), "{kind:?}: {worst} m, {bound} m");
    }
}

/// A method that cannot draw from a store yet fails with what to do instead; a store-backed
/// method whose table was not baked names the file and the bake option.
#[test]
fn what_a_store_cannot_do_is_said() {
    let hm = Heightmap::from_fn(129, 97, terrain_core::Georef::local(10.0), |i, j| {
        ((i * 3 + j * 5) % 17) as f32
    })
    .unwrap();
    let scene = MethodScene::new(hm, MethodConfig::default());
    let scratch_dir = scratch("store-methods", "cannot");
    let dir = scratch_dir.join("store");
    let config = BakeConfig { k: 5, threads: 1, ..Default::default() };
    bake(&scene.hm, &dir, &config, &mut |_: &BakeProgress| ControlFlow::Continue(())).unwrap();
    let store = Arc::new(Store::open(&dir).unwrap());
    let run = |kind| {
        let runtime =
            OocScene::new(store.clone(), OocConfig { threads: 1, ..OocConfig::default() });
        method::store_method(kind, runtime, &scene.config, OocWait::FirstFrame, None)
            .err()
            .map(|e| format!("{e:#}"))
    };
    let e = run(LodMethod::Entropy).expect("refused");
    assert!(e.contains("from a DEM in memory only") && e.contains("entropy"), "{e}");
    let e = run(LodMethod::Geomorph).expect("no geomorph table");
    assert!(e.contains("geomip.bin") && e.contains("--no-geomip"), "{e}");
    let e = run(LodMethod::Dss1).expect("no DSS table");
    assert!(e.contains("dss_errors.bin") && e.contains("--no-dss"), "{e}");
    let e = run(LodMethod::PvpsC).expect("no roughness table");
    assert!(e.contains("roughness") && e.contains("--no-roughness"), "{e}");
    // A store baked without the DSS errors (`BakeConfig::dss_errors` false, as the demo's) is
    // refused by name for every DSS method.
    let bare = dir.with_file_name("no-dss");
    let config = BakeConfig { dss_errors: false, ..config };
    bake(&scene.hm, &bare, &config, &mut |_: &BakeProgress| ControlFlow::Continue(())).unwrap();
    let bare_store = Arc::new(Store::open(&bare).unwrap());
    assert!(store.has_dss_errors() && !bare_store.has_dss_errors());
    for kind in [LodMethod::Dss1, LodMethod::Dss2, LodMethod::DssStrips, LodMethod::DssStripsPow2] {
        let runtime =
            OocScene::new(bare_store.clone(), OocConfig { threads: 1, ..OocConfig::default() });
        let e = method::store_method(kind, runtime, &scene.config, OocWait::FirstFrame, None)
            .err()
            .map(|e| format!("{e:#}"))
            .expect("refused");
        let named = format!("the store {} was baked without them", bare.display());
        assert!(e.contains(&named) && e.contains("bake it again without --no-dss"), "{e}");
    }
    // A table of another patch size is refused with what it was made for.
    terrain_app::geomip_scene::bake_into_scene(&scene.hm, 8, &dir).unwrap();
    let e = run(LodMethod::Geomorph).expect("another patch size");
    assert!(e.contains("patch cells 8 in the file, 16 here"), "{e}");
    assert!(run(LodMethod::Uniform).is_none(), "uniform needs no table");
    assert!(run(LodMethod::OutOfCore).is_none());
}

/// On the GPU: the store-backed methods' real-time frames (a tiny cache, so blocks draw from
/// coarse levels while finer ones load) draw no crack through the paged renderer, over the
/// crack test's cameras; the negative control (the same patches and pages with each patch's
/// edge factors drawn at random, so neighbours disagree) cracks, so the test can see cracks.
#[test]
fn store_backed_frames_draw_no_cracks_over_coarse_pages() {
    use terrain_gpu::render::RenderConfig;
    use terrain_gpu::render::crack::{crack_cameras, crack_pixels_on};
    use terrain_gpu::{BackendChoice, DeviceConfig, GpuContext};
    let ctx = match GpuContext::new(&DeviceConfig::from_env(BackendChoice::Auto)) {
        Ok(ctx) => ctx,
        Err(e) if std::env::var_os("TERRAIN_REQUIRE_GPU").is_none() => {
            println!("SKIPPED: {e}; set TERRAIN_REQUIRE_GPU=1 to make this a failure");
            return;
        }
        Err(e) => panic!("{e}"),
    };
    println!("adapter: {}", ctx.describe());
    let scene = MethodScene::new(crater_lake(), MethodConfig::default());
    let scratch_dir = scratch("store-methods", "cracks");
    let dir = scratch_dir.join("store");
    let config =
        BakeConfig { k: 6, encoding: HeightEncoding::F32, threads: 1, ..Default::default() };
    bake(&scene.hm, &dir, &config, &mut |_: &BakeProgress| ControlFlow::Continue(())).unwrap();
    terrain_app::dss_scene::bake_into_scene(&scene.hm, &scene.qt, &dir).unwrap();
    let store = Arc::new(Store::open(&dir).unwrap());
    let cameras: Vec<Camera> = crack_cameras(&scene.hm, 17)
        .into_iter()
        .step_by(3)
        .map(|c| c.with_viewport(256.0, 144.0))
        .collect();
    let depth = scene.hm.max() - scene.hm.min() + 100.0;
    let (mut coarse, mut control) = (0usize, 0usize);
    for kind in [LodMethod::Uniform, LodMethod::Dss1, LodMethod::Dss2] {
        let ooc = OocConfig { threads: 1, budget_bytes: 64 << 10, ..OocConfig::default() };
        let runtime = OocScene::new(store.clone(), ooc).with_mirror();
        let mut m =
            method::store_method(kind, runtime, &scene.config, OocWait::FirstFrame, Some(&scene))
                .unwrap();
        let rc = RenderConfig { width: 256, height: 144, ..Default::default() };
        let mut renderer = m.renderer(&ctx, &rc).unwrap();
        for (n, camera) in cameras.iter().enumerate() {
            let frame = m.frame(camera);
            renderer.apply(&frame).unwrap();
            let terrain_app::method::Draw::Paged(f) = &frame.draw else { panic!("paged") };
            if f.patches.is_empty() {
                continue;
            }
            let stream = frame.stats.stream.as_ref().unwrap();
            coarse += usize::from(!stream.at_needed_level);
            let r = renderer.terrain_renderer_mut().expect("a paged renderer");
            let cracks = crack_pixels_on(r, &f.patches, std::slice::from_ref(camera), depth);
            assert_eq!(cracks, vec![0], "{kind:?} frame {n}: crack pixels");
            // The negative control on the same pages.
            let mut seed = 0x9e37_79b9_7f4a_7c15u64 ^ n as u64;
            let mut next = || {
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                1.0 + (seed % 31) as f32
            };
            let broken: Vec<_> = f
                .patches
                .iter()
                .map(|p| {
                    let mut p = *p;
                    p.factors.outer = [next(), next(), next(), next()];
                    p
                })
                .collect();
            control += crack_pixels_on(r, &broken, std::slice::from_ref(camera), depth)[0];
        }
    }
    println!("{coarse} frames drawn below their needed level; negative control: {control} px");
    assert!(coarse > 0, "the tiny cache forced coarse levels");
    assert!(control >= 20, "the negative control cracks visibly: {control} px");
}

/// On the GPU: geomorph drawn from a store with its vertex-shader morph (the geomorph renderer
/// reading the paged renderer's pages) in real time with a tiny cache (blocks at coarse levels
/// while finer ones load) draws no crack over the crack test's cameras (skirts as the
/// reference: magenta background without them, terrain with them); the negative control (the
/// same pages, each patch ignoring its coarser neighbours: no adapting triangles, border
/// vertices at their own heights) cracks. And every drawn vertex the vertex stage morphs from
/// the store's pages (read back) equals the CPU reference (`MorphGrid`) over a CPU mirror of
/// the same pages (`PagedHeights`, kept here from the frames' page changes).
#[test]
fn geomorph_from_a_store_morphs_on_the_gpu_without_cracks() {
    use terrain_core::lod::PatchLod;
    use terrain_gpu::geomorph::{GeomorphOptions, GpuMorphPatch, MeshLibrary, MorphGrid};
    use terrain_gpu::render::crack::crack_cameras;
    use terrain_gpu::render::{BACKGROUND, RenderConfig, TerrainRenderer};
    use terrain_gpu::{BackendChoice, DeviceConfig, GpuContext};
    let ctx = match GpuContext::new(&DeviceConfig::from_env(BackendChoice::Auto)) {
        Ok(ctx) => ctx,
        Err(e) if std::env::var_os("TERRAIN_REQUIRE_GPU").is_none() => {
            println!("SKIPPED: {e}; set TERRAIN_REQUIRE_GPU=1 to make this a failure");
            return;
        }
        Err(e) => panic!("{e}"),
    };
    println!("adapter: {}", ctx.describe());
    for (name, hm, k) in [("puget", puget(), 7), ("crater", crater_lake(), 6)] {
        let scene = MethodScene::new(hm, MethodConfig::default());
        let scratch_dir = scratch("store-methods", &format!("geomorph-{name}"));
        let dir = scratch_dir.join("store");
        let config =
            BakeConfig { k, encoding: HeightEncoding::F32, threads: 1, ..Default::default() };
        bake(&scene.hm, &dir, &config, &mut |_: &BakeProgress| ControlFlow::Continue(())).unwrap();
        terrain_app::geomip_scene::bake_into_scene(&scene.hm, 16, &dir).unwrap();
        let store = Arc::new(Store::open(&dir).unwrap());
        let cameras: Vec<Camera> = crack_cameras(&scene.hm, 17)
            .into_iter()
            .step_by(3)
            .map(|c| c.with_viewport(256.0, 144.0))
            .collect();
        let skirt = GeomorphOptions {
            skirt_depth_m: scene.hm.max() - scene.hm.min() + 100.0,
            ..Default::default()
        };
        let lib = MeshLibrary::new(16);
        let (mut coarse, mut control, mut checked) = (0usize, 0usize, 0usize);
        // 64 KiB for the blocks (the budget's other half holds the view's index entries).
        let ooc = OocConfig { threads: 1, budget_bytes: 128 << 10, ..OocConfig::default() };
        let runtime = OocScene::new(store.clone(), ooc).with_mirror();
        let mut m = method::store_method(
            LodMethod::Geomorph,
            runtime,
            &scene.config,
            OocWait::FirstFrame,
            Some(&scene),
        )
        .unwrap();
        let rc = RenderConfig { width: 256, height: 144, ..Default::default() };
        let mut renderer = m.renderer(&ctx, &rc).unwrap();
        let layout = *renderer.terrain_renderer().expect("the pages' renderer").page_layout();
        let mut mirror = terrain_gpu::PagedHeights::new(layout);
        for (n, camera) in cameras.iter().enumerate() {
            let frame = m.frame(camera);
            renderer.apply(&frame).unwrap();
            let Draw::PagedMorph(f, lods) = &frame.draw else { panic!("a morphed frame") };
            for u in &f.updates {
                match &u.fill {
                    Some(p) => mirror.insert(u.page, p.clone()).unwrap(),
                    None => assert!(mirror.remove(u.page)),
                }
            }
            // The frame's runs expanded: every patch it draws.
            let lods = lods.expand();
            if lods.patches.is_empty() {
                continue;
            }
            coarse += usize::from(!frame.stats.stream.as_ref().unwrap().at_needed_level);
            let (morph, pages) = renderer.paged_morph_mut().expect("a paged geomorph renderer");
            let mut cracks = |lods: &[PatchLod]| {
                morph.render_paged(pages, camera, lods, &GeomorphOptions::default()).unwrap();
                let plain = morph.read_image().unwrap();
                morph.render_paged(pages, camera, lods, &skirt).unwrap();
                let reference = morph.read_image().unwrap();
                assert!(plain.pixels.iter().any(|&p| p != BACKGROUND), "frame {n}: terrain");
                plain
                    .pixels
                    .iter()
                    .zip(&reference.pixels)
                    .filter(|&(&a, &b)| a == BACKGROUND && b != BACKGROUND)
                    .count()
            };
            assert_eq!(cracks(&lods.patches), 0, "{name} frame {n}: crack pixels");
            let broken: Vec<PatchLod> = lods
                .patches
                .iter()
                .map(|p| PatchLod { edge_level: [p.level; 4], edge_tween: [0.0; 4], ..*p })
                .collect();
            control += cracks(&broken);
            // The vertex stage's morph over these pages = the CPU reference over the mirror.
            let gpu: Vec<GpuMorphPatch> =
                lods.patches.iter().map(|p| GpuMorphPatch::from_lod(p, 16)).collect();
            let items: Vec<[u32; 2]> = (0..gpu.len() as u32)
                .flat_map(|k| {
                    let mut ids = lib.triangles(&gpu[k as usize]).to_vec();
                    ids.sort_unstable();
                    ids.dedup();
                    ids.into_iter().map(move |id| [k, id])
                })
                .collect();
            let read = morph.morph_read_back_paged(pages, camera.position, &gpu, &items).unwrap();
            let grid = MorphGrid::new(&mirror, 16);
            let anchor = TerrainRenderer::anchor_for(camera.position);
            let tol = 16.0 * f32::EPSILON * (scene.hm.max().abs() + anchor.z.abs() as f32 + 1.0);
            for (&[k, id], g) in items.iter().zip(&read) {
                let cpu = grid.relative_position(&gpu[k as usize], id % 17, id / 17, anchor);
                assert_eq!((g[0], g[1]), (cpu[0], cpu[1]), "{name} frame {n}");
                assert!((g[3] - cpu[3]).abs() <= tol, "{name} frame {n}: {g:?} vs {cpu:?}");
                checked += 1;
            }
        }
        println!(
            "{name}: {coarse} frames below their needed level; {checked} vertices GPU = CPU; \
             negative control {control} crack px"
        );
        assert!(coarse > 0, "{name}: the tiny cache forced coarse levels");
        assert!(control >= 20, "{name}: the negative control cracks visibly: {control} px");
    }
}

/// A store's `geomip.bin` is read by pages: its open reads the header and the tail only, and
/// a damaged page fails the frames that need it (naming the file), not the open nor the
/// frames that do not. A table this small is read whole by default
/// ([`terrain_app::geomip_scene::READ_WHOLE_MAX_BYTES`]), and selects the same.
#[test]
fn a_store_geomip_table_opens_by_pages_and_a_damaged_page_fails_only_where_needed() {
    use terrain_core::lod::{GeomipConfig, GeomipScene};
    use terrain_core::quadtree::NodeTree;
    use terrain_stream::StoreTree;
    let hm = terrain_core::synth::FractalConfig::with_size(513, 513, 10.0).to_heightmap().unwrap();
    let scratch_dir = scratch("store-methods", "geomip-pages");
    let dir = scratch_dir.join("store");
    let config =
        BakeConfig { k: 6, encoding: HeightEncoding::F32, threads: 1, ..Default::default() };
    bake(&hm, &dir, &config, &mut |_: &BakeProgress| ControlFlow::Continue(())).unwrap();
    terrain_app::geomip_scene::bake_into_scene(&hm, 16, &dir).unwrap();
    let path = dir.join("geomip.bin");
    let len = std::fs::metadata(&path).unwrap().len();
    // 32 x 32 patches of 40 bytes: 40960 bytes of entries in 8 pages of 128 patches.
    let entries = 32 * 32 * 40;
    let store = Arc::new(Store::open(&dir).unwrap());
    let tree = StoreTree::new(store, 16);
    let cfg = GeomipConfig { patch_cells: 16, ..GeomipConfig::default() };
    let memory = GeomipScene::new(&hm, 16);
    let cam = |x: f64, y: f64, yaw: f64| {
        Camera::from_yaw_pitch(hm.grid_to_world(x, y).extend(60.0), yaw, -25.0)
            .with_viewport(1280.0, 720.0)
    };
    let (south, north) = (cam(256.0, 20.0, 180.0), cam(256.0, 500.0, 0.0));
    let open = || {
        let paging = terrain_core::lod::GeomipPaging::default();
        terrain_app::geomip_scene::read_for_store_with(tree.store(), tree.shape(), &paging, 0)
            .unwrap()
    };
    let same = |a: &terrain_core::lod::GeomipRuns, b: &terrain_core::lod::GeomipRuns| {
        (&a.runs, &a.patches, &a.factors) == (&b.runs, &b.patches, &b.factors)
    };
    // Below the size read whole, the default reads it whole: no pages, the same selection.
    let whole = terrain_app::geomip_scene::read_for_store(tree.store(), tree.shape()).unwrap();
    assert!(whole.paging_stats().is_none(), "a {len}-byte table is read whole by default");
    assert!(same(&whole.select_runs(&tree, &south, &cfg), &memory.select_runs(&south, &cfg)));
    // Undamaged (the negative control below): both views select as from memory.
    let table = open();
    let read = table.paging_stats().unwrap().bytes_read;
    assert_eq!(read, len - entries, "the open reads all but the entries");
    assert!(read * 50 < len, "{read} of {len} bytes");
    for c in [&south, &north] {
        let runs = table.try_select_runs(&tree, c, &cfg).unwrap();
        assert!(same(&runs, &memory.select_runs(c, &cfg)));
        assert!(!runs.patches.is_empty());
    }
    // The last page (the northernmost patches) damaged.
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[44 + entries as usize - 30] ^= 0x10;
    std::fs::write(&path, &bytes).unwrap();
    let table = open();
    let runs = table.try_select_runs(&tree, &south, &cfg).unwrap();
    assert!(same(&runs, &memory.select_runs(&south, &cfg)), "the south view as before");
    let e = table.try_select_runs(&tree, &north, &cfg).unwrap_err().to_string();
    assert!(e.contains("geomip.bin, page 7") && e.contains("checksum mismatch"), "{e}");
}

/// A store's DSS table read by pages (above the size read whole; here forced with a
/// threshold of 0): the open reads the header and the page checksums only, and the DSS
/// selections over the store's tree are memory's; a damaged page (the northernmost nodes)
/// leaves a view that does not ask it as before and is reported, naming the file and page,
/// by a view that does (its nodes split to the finest factor, so that view differs).
#[test]
fn a_store_dss_table_opens_by_pages_and_a_damaged_page_fails_only_where_needed() {
    use terrain_core::lod::{DssConfig, select_dss_power_of_two};
    use terrain_core::quadtree::NodeTree;
    use terrain_stream::StoreTree;
    let hm =
        terrain_core::synth::FractalConfig::with_size(2049, 2049, 10.0).to_heightmap().unwrap();
    let scratch_dir = scratch("store-methods", "dss-pages");
    let dir = scratch_dir.join("store");
    let config =
        BakeConfig { k: 6, encoding: HeightEncoding::F32, threads: 1, ..Default::default() };
    bake(&hm, &dir, &config, &mut |_: &BakeProgress| ControlFlow::Continue(())).unwrap();
    let qt = terrain_core::quadtree::Quadtree::new(&hm, 16);
    terrain_app::dss_scene::bake_into_scene(&hm, &qt, &dir).unwrap();
    let path = dir.join("dss_errors.bin");
    let len = std::fs::metadata(&path).unwrap().len();
    // 1 + 4 + ... + 128^2 = 21845 nodes of 256 bytes, in 86 pages of 256 nodes. The
    // selection stops at 64-cell nodes (factor 64 is their full resolution): level 5, nodes
    // 341..1365, pages 1 (the south rows) to 5 (the north rows).
    let entries = 21845 * 256;
    let memory = terrain_core::lod::DssErrorTable::new(&hm, &qt);
    let store = Arc::new(Store::open(&dir).unwrap());
    let tree = StoreTree::new(store, 16);
    let cfg = DssConfig { leaf_cells: 16, rho_thr: 0.5, ..DssConfig::default() };
    // Low over the ground, looking down: the selection reaches the leaves under the camera.
    let cam = |x: f64, y: f64, yaw: f64| {
        let z = f64::from(hm.get(x as usize, y as usize)) + 30.0;
        Camera::from_yaw_pitch(hm.grid_to_world(x, y).extend(z), yaw, -40.0)
            .with_viewport(1280.0, 720.0)
    };
    let (south, north) = (cam(1024.0, 20.0, 180.0), cam(1024.0, 2040.0, 180.0));
    let read = |max| {
        terrain_app::dss_scene::read_for_store(tree.store(), tree.shape(), "dss-1", max, 32 << 20)
            .unwrap()
    };
    let select = |t: &terrain_core::lod::DssErrorTable, c: &Camera| {
        select_dss_power_of_two(&tree, c, t, &cfg).patches
    };
    let from_memory = |c: &Camera| select_dss_power_of_two(&qt, c, &memory, &cfg).patches;
    // Below the size read whole, the store methods' default reads it whole.
    let whole = read(terrain_app::geomip_scene::READ_WHOLE_MAX_BYTES);
    assert!(!whole.is_paged(), "a {len}-byte table is read whole by default");
    assert_eq!(select(&whole, &south), from_memory(&south));
    // Undamaged (the negative control below): both views select as from memory.
    let table = read(0);
    let opened = table.paging_stats().unwrap().bytes_read;
    assert_eq!(opened, len - entries, "the open reads all but the entries");
    assert!(opened * 50 < len, "{opened} of {len} bytes");
    for c in [&south, &north] {
        let patches = select(&table, c);
        assert!(!patches.is_empty());
        assert_eq!(patches, from_memory(c));
    }
    assert!(table.take_error().is_none());
    // Page 5 (level 5's northernmost rows, under the north camera) damaged.
    let mut bytes = std::fs::read(&path).unwrap();
    let entries_at = 32 + 8 * 8;
    bytes[entries_at + 5 * 256 * 256 + 100] ^= 0x10;
    std::fs::write(&path, &bytes).unwrap();
    let table = read(0);
    assert_eq!(select(&table, &south), from_memory(&south), "the south view as before");
    assert!(table.take_error().is_none(), "the south view does not ask the damaged page");
    assert_ne!(select(&table, &north), from_memory(&north), "split finest where damaged");
    let e = table.take_error().expect("the damaged page is reported").to_string();
    assert!(e.contains("dss_errors.bin, page 5") && e.contains("checksum mismatch"), "{e}");
}

/// A grid not held in memory gets geomorph's table from its store's blocks, a block row at a
/// time: equal to the one computed from the heightmap (exact f32 store, no voids), and so is
/// the heights' checksum; on Puget Sound 1k and on an odd-sized grid whose last blocks and
/// patches are clipped.
#[test]
fn the_geomip_table_from_a_store_equals_the_one_from_memory() {
    let odd = terrain_core::synth::FractalConfig::with_size(301, 203, 30.0).to_heightmap().unwrap();
    for (name, hm, k) in [("puget", puget(), 8), ("odd", odd, 6)] {
        assert!(!hm.voids().any());
        let scratch_dir = scratch("store-methods", &format!("geomip-{name}"));
        let dir = scratch_dir.join("store");
        let config =
            BakeConfig { k, encoding: HeightEncoding::F32, threads: 1, ..Default::default() };
        bake(&hm, &dir, &config, &mut |_: &BakeProgress| ControlFlow::Continue(())).unwrap();
        let store = Store::open(&dir).unwrap();
        let (table, crc) =
            terrain_app::geomip_scene::compute_from_store(&store, 16, false).unwrap();
        assert_eq!(table, terrain_core::lod::GeomipTable::new(&hm, 16), "{name}");
        assert_eq!(crc, terrain_core::lod::dss_file::heights_checksum(&hm), "{name}");
    }
}

/// `hm` with every height times `k` (a vertical exaggeration applied in memory).
fn times(hm: &Heightmap, k: f32) -> Heightmap {
    let data: Vec<f32> = hm.data().iter().map(|h| h * k).collect();
    Heightmap::new(hm.width(), hm.height(), data, hm.voids().clone(), hm.georef().clone()).unwrap()
}

fn within_golden(d: ([f64; 3], f64)) -> bool {
    d.0.iter().all(|&m| m < 2.0) && d.1 < 0.01
}

/// Vertical exaggeration of a store (issue 14, `--vertical-scale` over a store): Puget Sound
/// baked once, read exaggerated 3 times (`Store::exaggerated`), selects for the same camera the
/// same patches as the DEM exaggerated 3 times in memory, with the same heights, for `ooc`
/// (against the store baked from the exaggerated heights: `ooc` needs a store), `uniform`,
/// `dss-2` and `geomorph` (whose selection errors are the scaled index, DSS table and
/// max-error vertices); and the store's GPU image equals the in-memory render of the same
/// patches at exaggeration 3 within the golden tolerance, for `ooc` and `uniform`. Negative
/// control: the store read without the exaggeration fails the image comparison.
#[test]
fn an_exaggerated_store_draws_as_the_exaggerated_dem() {
    const K: f32 = 3.0;
    let scene1 = MethodScene::new(puget(), MethodConfig::default());
    let scene = MethodScene::new(times(&scene1.hm, K), MethodConfig::default());
    let dir = scratch("store-methods", "exaggerated");
    let plain = bake_scene(&scene1, &dir.join("store"));
    let store = Arc::new(plain.exaggerated(f64::from(K)).unwrap());
    let ooc = OocConfig { threads: 1, ..OocConfig::default() };
    let camera = cameras(&scene.hm)[1];
    // The patch methods: the same patches and heights as from the exaggerated DEM.
    for kind in [LodMethod::Uniform, LodMethod::Dss2, LodMethod::Geomorph] {
        scene.prepare(&[kind]);
        let options = MethodOptions { morph: kind == LodMethod::Geomorph, ..Default::default() };
        let mut memory = method::build(kind, &scene, &options).unwrap();
        let runtime = OocScene::new(store.clone(), ooc);
        let mut stored =
            method::store_method(kind, runtime, &scene.config, OocWait::EveryFrame, Some(&scene))
                .unwrap();
        let mut a = memory.frame(&camera);
        let mut b = stored.frame(&camera);
        // Measured first: a store's geomorph frame builds its coverage there.
        let (sa, sb) = (memory.surface(&mut a).unwrap(), stored.surface(&mut b).unwrap());
        assert!(!a.selection.patches.is_empty());
        // The same nodes; the factors of DSS (interpolated in its errors) equal up to f32
        // rounding (errors of heights times 3 against errors times 3).
        let (pa, pb) = (&a.selection.patches, &b.selection.patches);
        assert_eq!(pa.len(), pb.len(), "{kind:?}: as many patches");
        let close = |x: f32, y: f32| (x - y).abs() <= 1e-5 * x.abs().max(1.0);
        for (p, q) in pa.iter().zip(pb) {
            assert_eq!(p.node, q.node, "{kind:?}: the same patches");
            let factors = p.outer.iter().chain(&p.inner).zip(q.outer.iter().chain(&q.inner));
            assert!(factors.into_iter().all(|(x, y)| close(*x, *y)), "{kind:?}: {p:?} {q:?}");
        }
        assert_eq!(sa.triangles, sb.triangles, "{kind:?}");
        let worst = largest_height_difference(&sa.mesh.positions, &sb.mesh.positions);
        println!(
            "exaggerated x{K} {}: {} patches, largest height difference {worst} m",
            kind.name(),
            b.selection.patches.len()
        );
        assert!(worst <= 1e-2, "{kind:?}: the same heights ({worst} m apart)");
    }
    // ooc: the store read exaggerated selects as the store of the exaggerated heights.
    let baked3 = bake_scene(&scene, &dir.join("store3"));
    let mut read3 = OocScene::new(store.clone(), ooc);
    let mut want = OocScene::new(baked3, ooc);
    let fa = read3.frame(&camera, true);
    let fb = want.frame(&camera, true);
    assert!(!fa.patches.is_empty());
    let nodes = |f: &terrain_app::ooc::OocFrame| {
        f.selection.patches.iter().map(|p| p.node).collect::<Vec<_>>()
    };
    assert_eq!(nodes(&fa), nodes(&fb), "ooc: the same patches");

    let Some(ctx) = common::gpu() else { return };
    let (w, h) = (320, 180);
    let camera = camera.with_viewport(f64::from(w), f64::from(h));
    let rc = terrain_gpu::RenderConfig { width: w, height: h, ..Default::default() };
    let mut whole = terrain_gpu::TerrainRenderer::new(&ctx, &scene.hm, &rc).unwrap();
    let mut memory_image = |patches: &[terrain_gpu::render::DrawPatch]| {
        whole.render(&camera, patches, &terrain_gpu::RenderOptions::default()).unwrap();
        whole.read_image().unwrap()
    };
    // ooc, and its negative control (the same store read without the exaggeration).
    for (name, s, expect) in [("ooc", store.clone(), true), ("ooc unexaggerated", plain, false)] {
        let mut scene_s = OocScene::new(s, ooc);
        let f = scene_s.frame(&camera, true);
        let mut paged = scene_s.renderer(&ctx, &rc).unwrap();
        OocScene::apply(&mut paged, &f).unwrap();
        paged.render(&camera, &f.patches, &terrain_gpu::RenderOptions::default()).unwrap();
        let d = common::golden_diff(&paged.read_image().unwrap(), &memory_image(&f.patches));
        println!(
            "{name} x{K}: store vs memory image: mean |diff| {:.3?}, {:.3} % off",
            d.0,
            d.1 * 100.0
        );
        assert_eq!(within_golden(d), expect, "{name}: {d:?}");
    }
    // uniform from the store, through its method and paged renderer.
    let runtime = OocScene::new(store, ooc);
    let mut stored =
        method::store_method(LodMethod::Uniform, runtime, &scene.config, OocWait::EveryFrame, None)
            .unwrap();
    let f = stored.frame(&camera);
    let mut r = stored.renderer(&ctx, &rc).unwrap();
    r.apply(&f).unwrap();
    let Draw::Paged(pf) = &f.draw else { panic!("a paged frame") };
    let paged = r.terrain_renderer_mut().unwrap();
    paged.render(&camera, &pf.patches, &terrain_gpu::RenderOptions::default()).unwrap();
    let d = common::golden_diff(&paged.read_image().unwrap(), &memory_image(&pf.patches));
    println!(
        "uniform x{K}: store vs memory image: mean |diff| {:.3?}, {:.3} % off",
        d.0,
        d.1 * 100.0
    );
    assert!(within_golden(d), "uniform: {d:?}");
}

/// The largest height difference between the corresponding vertices of two surfaces, metres.
fn largest_height_difference(a: &[glam::DVec3], b: &[glam::DVec3]) -> f64 {
    a.iter().zip(b).map(|(p, q)| (p.z - q.z).abs()).fold(0.0, f64::max)
}

/// Geomorph's store frame works on its runs (issue 13): the streamer's demand from the runs
/// (`morph_demand`) equals `demand_of` over the patches one by one, and the drawn-block filter
/// on the runs (`morph_on_pages`) keeps exactly the patches the per-patch filter kept (a run
/// wholly over drawn blocks stays one, the kept patches of another become single patches, in
/// the same order), bit for bit, on a non-square DEM with voids and a synthetic grid, with a
/// page budget that leaves blocks undrawn so runs are split. Negative control: a demand one
/// level too coarse for one block fails the comparison.
#[test]
fn geomorph_store_frames_work_on_runs_as_on_patches() {
    use std::collections::HashSet;
    use terrain_app::methods::geomorph_selection_runs;
    use terrain_app::ooc::{MorphDraw, StoreDraw, morph_demand, morph_on_pages};
    use terrain_core::lod::{GeomipConfig, GeomipRuns, Selection, TerrainSource};
    use terrain_core::quadtree::{NodeId, NodeTree};
    use terrain_core::synth::FractalConfig;
    use terrain_stream::{StoreTree, demand_of};

    // The per-patch filter `frame_for` applied before (the reference).
    fn per_patch_filter(
        tree: &StoreTree,
        runs: &GeomipRuns,
        drawn: &terrain_core::hash::IdMap<terrain_stream::BlockId, u8>,
    ) -> GeomipRuns {
        let (n, leaf) = (tree.shape().leaf_cells(), tree.shape().max_level());
        let on_pages = |node: NodeId| tree.blocks_under(node).iter().all(|b| drawn.contains_key(b));
        let mut selection = geomorph_selection_runs(runs, n, leaf);
        selection.patches.retain(|p| on_pages(p.node));
        let kept: HashSet<NodeId> = selection.patches.iter().map(|p| p.node).collect();
        let on = |i: u32, j: u32| kept.contains(&NodeId::new(leaf, i, j));
        let mut lods = runs.clone();
        let keep: Vec<bool> = lods.patches.iter().map(|p| on(p.i, p.j)).collect();
        let mut k = keep.iter();
        lods.patches.retain(|_| *k.next().unwrap());
        let mut k = keep.iter();
        lods.factors.retain(|_| *k.next().unwrap());
        let mut split = Vec::new();
        lods.runs.retain(|r| {
            let cells: Vec<(u32, u32)> = (r.j..r.j + r.height)
                .flat_map(|j| (r.i..r.i + r.width).map(move |i| (i, j)))
                .filter(|&(i, j)| on(i, j))
                .collect();
            let all = cells.len() as u64 == r.patches();
            if !all {
                split.extend(cells);
            }
            all
        });
        for (i, j) in split {
            let p = lods.run_patch(i, j);
            lods.patches.push(p);
            lods.factors.push(f32::from(lods.coarsest));
        }
        lods
    }

    let synthetic = FractalConfig::with_size(769, 513, 10.0).to_heightmap().unwrap();
    // The synthetic grid at a coarser threshold (its fractal detail keeps most patches finer
    // than the coarsest level at the default).
    for (name, hm, px) in [("crater", crater_lake(), None), ("synthetic", synthetic, Some(8.0))] {
        let scene = MethodScene::new(hm, MethodConfig::default());
        let scratch_dir = scratch("store-methods", &format!("morph-runs-{name}"));
        let dir = scratch_dir.join("store");
        let config =
            BakeConfig { k: 5, encoding: HeightEncoding::F32, threads: 1, ..Default::default() };
        bake(&scene.hm, &dir, &config, &mut |_: &BakeProgress| ControlFlow::Continue(())).unwrap();
        terrain_app::geomip_scene::bake_into_scene(&scene.hm, 16, &dir).unwrap();
        let store = Arc::new(Store::open(&dir).unwrap());
        let tree = StoreTree::new(store.clone(), 16);
        let table = terrain_app::geomip_scene::read_for_store(tree.store(), tree.shape()).unwrap();
        let mut cfg = GeomipConfig { patch_cells: 16, ..scene.config.geomip };
        cfg.pixel_threshold = px.unwrap_or(cfg.pixel_threshold);
        // Few full-resolution slots: the nearest blocks take them, farther ones fall to coarser
        // classes until those are full too, and the rest are not drawn.
        let ooc = OocConfig {
            threads: 1,
            page_capacity: 4,
            page_budget_bytes: 4 << 10,
            ..OocConfig::default()
        };
        let mut runtime = OocScene::new(store.clone(), ooc);
        let (mut dropped, mut split_runs, mut whole_runs) = (0, 0, 0);
        let mut cams = cameras(&scene.hm);
        cams.extend(
            terrain_gpu::render::crack::crack_cameras(&scene.hm, 17).into_iter().step_by(4),
        );
        for (c, camera) in cams.iter().enumerate() {
            let mut all: Option<GeomipRuns> = None;
            let mut select = |src: &dyn TerrainSource, camera: &Camera| -> StoreDraw {
                let runs = table.select_runs(&src, camera, &cfg);
                all = Some(runs.clone());
                StoreDraw {
                    selection: Selection::default(),
                    morph: Some(MorphDraw { runs, patch_cells: 16 }),
                    ..Default::default()
                }
            };
            let frame = runtime.frame_for(camera, true, &tree, &mut select);
            let all = all.unwrap();
            // The demand from the runs, against the patches one by one.
            let morph = MorphDraw { runs: all.clone(), patch_cells: 16 };
            let fast = morph_demand(&tree, &morph);
            let patches = geomorph_selection_runs(&all, 16, tree.shape().max_level());
            let reference = demand_of(&tree, &patches, true);
            assert!(!reference.is_empty(), "{name} camera {c}");
            assert_eq!(fast, reference, "{name} camera {c}: the demand");
            // Negative control: one block asked one level coarser fails the comparison.
            let mut coarser = reference.clone();
            let b = coarser.iter_mut().find(|(_, l)| *l > 0).expect("a block above level 0");
            b.1 -= 1;
            assert_ne!(fast, coarser, "{name} camera {c}: the control");
            // The drawn-block filter, against the per-patch one.
            let drawn: terrain_core::hash::IdMap<_, _> = frame.drawn.iter().copied().collect();
            let kept = frame.morph.clone().expect("a morphed frame");
            assert_eq!(kept, per_patch_filter(&tree, &all, &drawn), "{name} camera {c}");
            assert_eq!(kept, morph_on_pages(&tree, all.clone(), &drawn));
            assert!(frame.patches.is_empty(), "no per-patch draw list");
            dropped += frame.blocks_dropped;
            whole_runs += kept.runs.len();
            split_runs += all.runs.len() - kept.runs.len();
        }
        println!("{name}: {dropped} blocks dropped, {whole_runs} runs kept, {split_runs} split");
        assert!(dropped > 0 && split_runs > 0 && whole_runs > 0, "{name}: the split path ran");
    }
}
