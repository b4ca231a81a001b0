//! The `tin` method (issue 16): its pyramid's tiles meet their bounds and share their borders,
//! its selection follows Cesium's screen-space error rule and covers the view without
//! overlap, its drawn surface has no crack (the renderer's skirt test, with stitches off as
//! the negative control), and its render matches the full grid's within the golden tolerance
//! on Puget Sound 1k and on Crater Lake (non-square, voids).

mod common;

use terrain_app::method::{self, Draw, MethodOptions, registry};
use terrain_app::methods::{LodMethod, MethodConfig, MethodScene, select_uniform};
use terrain_core::Heightmap;
use terrain_core::dem::{self, LoadOptions};
use terrain_core::geometry::Camera;
use terrain_core::quadtree::{
    Cull, CullPolicy, Direction, FrustumCull, NodeId, SplitToLevel, select,
};
use terrain_core::synth::FractalConfig;
use terrain_core::tin::grid::GridTinPyramid;
use terrain_gpu::render::crack::{crack_cameras, crack_pixels_with_extra};
use terrain_gpu::render::{DrawPatch, ExtraTriangles, default_camera};
use terrain_gpu::tess::GpuDomainPoint;
use terrain_gpu::{RenderConfig, RenderOptions};

fn fractal() -> Heightmap {
    FractalConfig::with_size(257, 193, 10.0).to_heightmap().unwrap()
}

fn puget() -> Heightmap {
    let options = LoadOptions { vertical_scale: 0.1, spacing_m: 160.0, ..LoadOptions::default() };
    dem::load(common::data("puget_sound/ps_height_1k.png"), &options).unwrap().heightmap
}

/// Crater Lake: 429 x 279 geographic samples, 39,489 voids (-32767 without a nodata tag).
fn crater_lake() -> Heightmap {
    let options = LoadOptions { nodata: Some(-32767.0), ..LoadOptions::default() };
    let hm = dem::load(common::data("crater_lake/craterlake-elev-16bit-30m.tif"), &options)
        .unwrap()
        .heightmap;
    assert!(hm.voids().count() > 30_000 && hm.width() != hm.height());
    hm
}

/// Every tile is within its level's bound (measured against its samples), the bounds halve per
/// level, and two tiles sharing a side at the same level have the same vertices on it.
#[test]
fn tiles_meet_their_bounds_and_share_their_sides() {
    let scene = MethodScene::new(fractal(), MethodConfig::default());
    let p = scene.tin_pyramid().unwrap();
    let tree = p.tree();
    for l in 1..=tree.max_level() {
        let ratio = p.level_error(l - 1) / p.level_error(l);
        assert!((ratio - 2.0).abs() < 1e-12, "level {l}: {ratio}");
    }
    let (mut tiles, mut shared) = (0, 0);
    for t in p.tiles() {
        tiles += 1;
        assert!(t.measured.max_error <= t.bound, "{:?}: {:?}", t.node, t.measured);
        assert_eq!(t.bound, p.level_error(t.node.level));
        for d in [Direction::East, Direction::North] {
            let Some(n) = t.node.neighbour(d).and_then(|n| p.tile(n)) else { continue };
            let mine: Vec<[u32; 2]> = t.side(d).collect();
            let theirs: Vec<[u32; 2]> = n.side(d.opposite()).collect();
            assert_eq!(mine, theirs, "{:?} {d:?}", t.node);
            shared += 1;
        }
    }
    assert!(tiles > 100 && shared > 100, "{tiles} tiles, {shared} shared sides");
    // The coarse levels simplify: fewer triangles than the finest level's.
    let per_level = |l: u8| -> usize {
        p.tiles().filter(|t| t.node.level == l).map(|t| t.triangles.len()).sum()
    };
    assert!(per_level(1) * 4 < per_level(tree.max_level()), "{} {}", per_level(1), per_level(2));
}

/// Cesium's rule: every selected tile has `sse <= tau` or is a finest tile, and its parent
/// had `sse > tau`; the selection covers every finest node in the frustum exactly once.
#[test]
fn the_selection_follows_the_sse_rule_and_covers_the_view_once() {
    let scene = MethodScene::new(fractal(), MethodConfig::default());
    let p = scene.tin_pyramid().unwrap();
    let tree = p.tree();
    let mut levels = std::collections::BTreeSet::new();
    for tau in [0.5, 2.0, 8.0] {
        for camera in crack_cameras(&scene.hm, 9).iter().step_by(3) {
            let camera = camera.with_viewport(1280.0, 720.0);
            let sel = p.select(&camera, tau);
            assert!(!sel.tiles.is_empty());
            for &n in &sel.tiles {
                levels.insert(n.level);
                let info = tree.node_info(n).unwrap();
                let sse = p.screen_error(&camera, n, &info);
                assert!(sse <= tau || info.is_finest, "{n:?}: sse {sse} > {tau}");
                if let Some(parent) = n.parent() {
                    let pi = tree.node_info(parent).unwrap();
                    assert!(p.screen_error(&camera, parent, &pi) > tau, "{n:?}: parent kept");
                }
            }
            // Every visible finest node lies in exactly one selected tile.
            let mut cull = FrustumCull::new(camera.frustum());
            let finest = select(tree, &mut SplitToLevel(tree.max_level()), &mut cull);
            for f in &finest {
                let holders = sel.tiles.iter().filter(|t| t.is_ancestor_or_self_of(*f)).count();
                assert_eq!(holders, 1, "{f:?} in {holders} tiles");
            }
            // And no selected tile is outside the frustum.
            let mut c = FrustumCull::new(camera.frustum());
            for &n in &sel.tiles {
                assert_ne!(c.classify(n, &tree.node_info(n).unwrap()), Cull::Reject);
            }
        }
    }
    assert!(levels.len() >= 3, "the selection mixes levels: {levels:?}");
}

/// The registry builds `tin`; its frame draws its surface's triangles, the tiles as patches.
#[test]
fn the_frame_draws_what_it_measures() {
    let scene = MethodScene::new(fractal(), MethodConfig::default());
    let camera = default_camera(&scene.hm, 320, 180, 60.0);
    let mut m = method::build(LodMethod::Tin, &scene, &MethodOptions::default()).unwrap();
    let mut f = m.frame(&camera);
    let Draw::Tessellated { patches, extra } = f.draw.clone() else { panic!("extra triangles") };
    assert_eq!(patches.len(), 1);
    let s = m.surface(&mut f).unwrap();
    assert_eq!(s.triangles as usize, s.mesh.triangles.len());
    assert_eq!(extra.indices.len(), 3 * s.mesh.triangles.len());
    assert_eq!(f.selection.patches.len(), f.stats.patches);
    assert!(registry::draws_mesh(LodMethod::Tin) && registry::parameter_is_pixels(LodMethod::Tin));
}

/// Skirts below every border segment of the frame's tiles, as extra triangles whose lower
/// vertices the renderer drops by the skirt depth (`pad = 1`).
fn skirts(scene: &MethodScene, p: &GridTinPyramid, tiles: &[NodeId], extra: &mut ExtraTriangles) {
    let (w, h) = ((scene.hm.width() - 1) as f32, (scene.hm.height() - 1) as f32);
    let point = |g: [u32; 2], pad: u32| GpuDomainPoint {
        uv: [g[0] as f32 / w, g[1] as f32 / h],
        patch_index: 0,
        pad,
    };
    for &n in tiles {
        let t = p.tile(n).unwrap();
        for d in Direction::ALL {
            let side: Vec<[u32; 2]> = t.side(d).collect();
            for s in side.windows(2) {
                let k = extra.points.len() as u32;
                extra.points.extend([
                    point(s[0], 0),
                    point(s[1], 0),
                    point(s[1], 1),
                    point(s[0], 1),
                ]);
                extra.indices.extend([k, k + 1, k + 2, k, k + 2, k + 3]);
            }
        }
    }
}

/// The renderer's crack test (`terrain_gpu::render::crack`): no pixel shows background where
/// skirts below every tile's border show terrain; without the stitches (the negative control)
/// some do.
#[test]
fn no_crack_with_stitches_and_cracks_without() {
    let Some(ctx) = common::gpu() else { return };
    for (name, hm) in [("fractal", fractal()), ("puget sound 1k", puget())] {
        let mut scene = MethodScene::new(hm, MethodConfig::default());
        scene.tin_pyramid().unwrap();
        // A coarse target, so that the negative control's cracks (up to about the drawn
        // error) span pixels at this small size.
        scene.config.tin.tau_px = 4.0;
        let cameras = crack_cameras(&scene.hm, 17);
        let mut counts = Vec::new();
        for stitch in [true, false] {
            scene.config.tin.stitch = stitch;
            let p = scene.tin_pyramid().unwrap();
            let mut frames: Vec<(Camera, Vec<DrawPatch>, ExtraTriangles)> = Vec::new();
            for camera in &cameras {
                let camera = camera.with_viewport(128.0, 72.0);
                let mut m =
                    method::build(LodMethod::Tin, &scene, &MethodOptions::default()).unwrap();
                let f = m.frame(&camera);
                let Draw::Tessellated { patches, mut extra } = f.draw else { panic!() };
                let tiles: Vec<NodeId> = f.selection.patches.iter().map(|q| q.node).collect();
                skirts(&scene, p, &tiles, &mut extra);
                frames.push((camera, patches, extra));
            }
            if stitch {
                // What each way of hiding cracks costs over these views: stitches against
                // skirts (two triangles per border segment of every drawn tile).
                let (mut tiles_t, mut stitches, mut skirts_t) = (0, 0, 0);
                for camera in &cameras {
                    let sel = p.select(&camera.with_viewport(128.0, 72.0), scene.config.tin.tau_px);
                    let s = p.surface(&scene.hm, &sel.tiles, true);
                    tiles_t += s.tile_triangles;
                    stitches += s.stitch_triangles;
                    skirts_t += 2 * s.border_segments;
                }
                println!(
                    "{name}: {tiles_t} tile triangles; stitches {stitches}, skirts would be {skirts_t}"
                );
                assert!(stitches < skirts_t);
            }
            let refs: Vec<_> = frames.iter().map(|(c, p, e)| (*c, p.as_slice(), e)).collect();
            let cracks = crack_pixels_with_extra(&ctx, &scene.hm, &refs, (128, 72));
            println!("{name}: stitches {stitch}: crack pixels {cracks:?}");
            counts.push(cracks.iter().sum::<usize>());
        }
        assert_eq!(counts[0], 0, "{name}: cracks with stitches");
        assert!(counts[1] > 0, "{name}: the negative control shows no crack");
    }
}

/// `tin`'s render of a view equals the full grid's (every leaf at full resolution) within the
/// golden tolerance on Puget Sound 1k and on Crater Lake (non-square, voids); the frame with
/// half its triangles dropped (the negative control) does not.
#[test]
fn renders_as_the_full_grid() {
    let Some(ctx) = common::gpu() else { return };
    let (w, h) = (320, 180);
    for (name, hm) in [("puget sound 1k", puget()), ("crater lake", crater_lake())] {
        let mut scene = MethodScene::new(hm, MethodConfig::default());
        let camera = default_camera(&scene.hm, w, h, 60.0);
        let rc = RenderConfig { width: w, height: h, ..Default::default() };
        let mut r = terrain_gpu::TerrainRenderer::new(&ctx, &scene.hm, &rc).unwrap();
        let leaf = scene.qt.leaf_cells() as f32;
        let full = scene.draw_patches(&select_uniform(&scene.qt, &camera, leaf));
        r.render(&camera, &full, &RenderOptions::default()).unwrap();
        let reference = r.read_image().unwrap();
        // The negative control: the same frame with every other tile's triangles dropped.
        scene.config.tin.tau_px = 0.5;
        let mut m = method::build(LodMethod::Tin, &scene, &MethodOptions::default()).unwrap();
        let f = m.frame(&camera);
        let Draw::Tessellated { patches, extra } = &f.draw else { panic!() };
        let mut holed = extra.clone();
        holed.indices = extra
            .indices
            .chunks_exact(3)
            .enumerate()
            .filter(|(k, _)| k % 2 == 0)
            .flat_map(|(_, t)| t.iter().copied())
            .collect();
        for (what, e, expect) in [("tin", extra, true), ("half the triangles", &holed, false)] {
            r.render_with_extra(&camera, patches, e, &RenderOptions::default()).unwrap();
            let d = common::golden_diff(&r.read_image().unwrap(), &reference);
            println!(
                "{name} {what} (tau 0.5): {} tiles, {} triangles: mean |diff| {:.3?}, {:.3} % off",
                f.stats.patches,
                e.indices.len() / 3,
                d.0,
                d.1 * 100.0
            );
            let within = d.0.iter().all(|&m| m < 2.0) && d.1 < 0.01;
            assert_eq!(within, expect, "{name} {what}: {d:?}");
        }
    }
}
