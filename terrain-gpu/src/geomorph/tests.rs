//! Tests of the geomorph: continuity under small camera steps (and its failure without
//! morphing), crack-freedom on the CPU (`open_edges`) and on the GPU (magenta background
//! against a skirted reference, naming the adapter), the GPU's morph against the CPU reference,
//! the material passes, Puget Sound 1k, and the paged mode (heights from a paged renderer's
//! pages of mixed strides, as a store's blocks at their resident levels: GPU = CPU reference
//! over the pages' mirror, no cracks), and runs of coarsest patches drawn without expansion
//! (the image of the expanded list). GPU tests print why and pass where no adapter exists,
//! unless `TERRAIN_REQUIRE_GPU` is set.

use std::path::PathBuf;

use glam::DVec3;
use terrain_core::Heightmap;
use terrain_core::geometry::Camera;
use terrain_core::lod::{GeomipConfig, GeomipScene, PatchLod};
use terrain_core::synth::FractalConfig;

use super::*;
use crate::device::BackendChoice;
use crate::paged::{Page, PageClass, PagedHeights};
use crate::render::BACKGROUND;
use crate::render::TerrainRenderer;
use crate::render::crack::crack_cameras;
use crate::test_support::{context, puget_sound};

fn fractal() -> Heightmap {
    FractalConfig::with_size(257, 257, 10.0).to_heightmap().unwrap()
}

fn gpu_patches(lods: &[PatchLod], n: u32) -> Vec<GpuMorphPatch> {
    lods.iter().map(|p| GpuMorphPatch::from_lod(p, n)).collect()
}

/// A camera flying over `hm` north-east at `height` above the start, `step` metres a frame.
fn flight(hm: &Heightmap, frames: usize, step: f64, height: f64) -> Vec<Camera> {
    let start = hm.grid_to_world(10.0, 10.0);
    let z0 = f64::from(hm.max()) + height;
    (0..frames)
        .map(|k| {
            let d = step * k as f64 / 2f64.sqrt();
            let eye = DVec3::new(start.x + d, start.y + d, z0 - 0.3 * step * k as f64);
            Camera::from_yaw_pitch(eye, 45.0, -25.0)
                .with_fov_y_deg(60.0)
                .with_viewport(1280.0, 720.0)
        })
        .collect()
}

/// The largest per-vertex jump between consecutive frames of `cameras`.
fn jumps(hm: &Heightmap, cameras: &[Camera], cfg: &GeomipConfig) -> Vec<f64> {
    let scene = GeomipScene::new(hm, cfg.patch_cells);
    let grid = MorphGrid::new(hm, cfg.patch_cells);
    let lib = MeshLibrary::new(cfg.patch_cells);
    let mut prev = None;
    let mut out = Vec::new();
    for c in cameras {
        let sel = scene.select(c, cfg);
        let (mesh, _) = build_surface(&grid, &lib, &gpu_patches(&sel.patches, cfg.patch_cells));
        if let Some(p) = &prev {
            out.push(max_vertex_jump(p, &mesh));
        }
        prev = Some(mesh);
    }
    out
}

/// With geomorphing the tween factors are Lipschitz in the eye position: a level's weight
/// changes by at most `2 |step| / d` per frame while its projected error is between `tau / 2`
/// and `tau` (module docs of `terrain_core::lod::geomipmap`), and the vertices it moves are at
/// most its error `delta < tau d / lambda` away, so a vertex moves at most `2 tau |step| /
/// lambda` per frame. The neighbour envelope (a patch pulled finer by a nearer neighbour) and
/// border vertices following a neighbour's factor loosen this by the ratio of neighbouring
/// patches' distances; we allow a factor 4. Without morphing, a level switch moves vertices by
/// the level's whole error: metres.
#[test]
fn small_camera_steps_move_no_vertex_far_and_without_morphing_they_pop() {
    let hm = fractal();
    let step = 10.0;
    let cameras = flight(&hm, 50, step, 400.0);
    let on = GeomipConfig { frustum_cull: false, ..Default::default() };
    let off = GeomipConfig { morph: false, ..on };
    let bound = 4.0 * 2.0 * on.pixel_threshold * step / cameras[0].lambda();
    let max = |v: Vec<f64>| v.into_iter().fold(0.0, f64::max);
    let morph = max(jumps(&hm, &cameras, &on));
    let popping = max(jumps(&hm, &cameras, &off));
    println!(
        "largest per-vertex jump per frame: morph {morph:.4} m, no morph {popping:.4} m, bound {bound:.4} m"
    );
    assert!(morph > 0.0, "the flight should change tween factors");
    assert!(morph <= bound, "morphing moved a vertex {morph} m in one frame (bound {bound})");
    assert!(popping > 10.0 * bound, "without morphing levels should pop: {popping} m");
}

/// Every patch drawn (no culling): the surface's open edges all lie on the grid's border, for
/// views that mix levels (adapting borders) and tween factors.
fn assert_watertight(hm: &Heightmap, cameras: &[Camera], tau: f64) {
    let cfg = GeomipConfig { frustum_cull: false, pixel_threshold: tau, ..Default::default() };
    let scene = GeomipScene::new(hm, 16);
    let grid = MorphGrid::new(hm, 16);
    let lib = MeshLibrary::new(16);
    let (wm, hmx) = ((hm.width() - 1) as f64, (hm.height() - 1) as f64);
    let mut adapting = 0;
    for c in cameras {
        let sel = scene.select(c, &cfg);
        let patches = gpu_patches(&sel.patches, 16);
        adapting += patches.iter().filter(|p| p.adapt_mask() != 0).count();
        let (mesh, _) = build_surface(&grid, &lib, &patches);
        for [a, b] in mesh.open_edges() {
            let (a, b) = (mesh.grid[a as usize], mesh.grid[b as usize]);
            let on_border = (a.x == b.x && (a.x == 0.0 || a.x == wm))
                || (a.y == b.y && (a.y == 0.0 || a.y == hmx));
            assert!(on_border, "open edge {a} - {b} inside the grid");
        }
    }
    assert!(adapting > 0, "no adapting border was exercised");
}

#[test]
fn the_drawn_surface_is_watertight() {
    let hm = fractal();
    let cameras: Vec<Camera> =
        crack_cameras(&hm, 17).into_iter().map(|c| c.with_viewport(1280.0, 720.0)).collect();
    assert_watertight(&hm, &cameras[..8], 2.0);
}

/// The GPU's morph (the compute entry point calling the vertex stage's functions) against the
/// CPU reference, for every drawn vertex of views with mixed levels, tween factors and
/// adapting borders. Plan positions come from the same f32 column/row offsets: bit-identical.
/// Heights: the morph is at most two nested `a + t (m - a)` with `m` a half sum, about eight
/// f32 roundings of values below `2 max |h|`; a GPU may fuse a multiply-add (one rounding
/// fewer), so the two may differ by a few ulps: we allow 16 ulps of `max |h| + |anchor z|`.
fn gpu_morph_matches_cpu(backend: BackendChoice, hm: &Heightmap) {
    let Some(ctx) = context(backend) else { return };
    let config = GeomorphConfig { width: 64, height: 64, ..Default::default() };
    let mut renderer = GeomorphRenderer::new(&ctx, hm, &config).unwrap();
    let scene = GeomipScene::new(hm, 16);
    let grid = MorphGrid::new(hm, 16);
    let cfg = GeomipConfig { frustum_cull: false, pixel_threshold: 2.0, ..Default::default() };
    let mut worst: f32 = 0.0;
    for c in crack_cameras(hm, 17).into_iter().step_by(5) {
        let c = c.with_viewport(1280.0, 720.0);
        let sel = scene.select(&c, &cfg);
        let patches = gpu_patches(&sel.patches, 16);
        assert!(
            patches.iter().any(|p| p.tween > 0.0) && patches.iter().any(|p| p.adapt_mask() != 0)
        );
        let mut items = Vec::new();
        for (k, p) in patches.iter().enumerate() {
            let mut ids: Vec<u32> = renderer.library().triangles(p).to_vec();
            ids.sort_unstable();
            ids.dedup();
            items.extend(ids.into_iter().map(|id| [k as u32, id]));
        }
        let gpu = renderer.morph_read_back(c.position, &patches, &items).unwrap();
        let anchor = crate::render::TerrainRenderer::anchor_for(c.position);
        let tol = 16.0
            * f32::EPSILON
            * (hm.max().abs().max(hm.min().abs()) + anchor.z.abs() as f32 + 1.0);
        for (&[k, id], g) in items.iter().zip(&gpu) {
            let (x, y) = (id % 17, id / 17);
            let cpu = grid.relative_position(&patches[k as usize], x, y, anchor);
            assert_eq!((g[0], g[1]), (cpu[0], cpu[1]), "plan position of {k}/{id}");
            for c in [2, 3] {
                let d = (g[c] - cpu[c]).abs();
                worst = worst.max(d);
                assert!(d <= tol, "patch {k} vertex ({x}, {y}): GPU {g:?} CPU {cpu:?}");
            }
        }
    }
    println!("{} largest height difference GPU - CPU: {worst} m", renderer.adapter());
}

#[test]
fn gpu_morph_matches_the_cpu_reference_vulkan() {
    gpu_morph_matches_cpu(BackendChoice::Vulkan, &fractal());
}

/// Renders the selection of every crack camera with and without skirts; returns the crack
/// pixels per camera (background without skirts, terrain with them: see `render::crack`).
fn geomorph_cracks(
    renderer: &mut GeomorphRenderer,
    hm: &Heightmap,
    tau: f64,
    cameras: &[Camera],
) -> Vec<usize> {
    let scene = GeomipScene::new(hm, 16);
    let cfg = GeomipConfig { pixel_threshold: tau, ..Default::default() };
    let skirt = GeomorphOptions { skirt_depth_m: hm.max() - hm.min() + 10.0, ..Default::default() };
    cameras
        .iter()
        .map(|camera| {
            let sel = scene.select(&camera.with_viewport(1280.0, 720.0), &cfg);
            renderer.render(camera, &sel.patches, &GeomorphOptions::default()).unwrap();
            let plain = renderer.read_image().unwrap();
            renderer.render(camera, &sel.patches, &skirt).unwrap();
            let reference = renderer.read_image().unwrap();
            let terrain = plain.pixels.iter().filter(|&&p| p != BACKGROUND).count();
            assert!(terrain > 0, "camera {camera:?} sees no terrain");
            plain
                .pixels
                .iter()
                .zip(&reference.pixels)
                .filter(|&(&a, &b)| a == BACKGROUND && b != BACKGROUND)
                .count()
        })
        .collect()
}

#[test]
fn no_cracks_fractal_vulkan() {
    let Some(ctx) = context(BackendChoice::Vulkan) else { return };
    let hm = fractal();
    let config = GeomorphConfig { width: 256, height: 144, ..Default::default() };
    let mut renderer = GeomorphRenderer::new(&ctx, &hm, &config).unwrap();
    let cracks = geomorph_cracks(&mut renderer, &hm, 2.0, &crack_cameras(&hm, 17));
    println!("{}: crack pixels {cracks:?}", ctx.describe());
    assert!(cracks.iter().all(|&c| c == 0), "cracks {cracks:?}");
}

/// Puget Sound 1k (real DEM, 4096 patches): watertight on the CPU for views mixing levels,
/// crack-free on the GPU, and the snow pass is skipped over the lowlands.
#[test]
fn puget_sound_watertight_crack_free_and_skips_materials() {
    let hm = puget_sound();
    let cameras: Vec<Camera> = crack_cameras(&hm, 17);
    let wide: Vec<Camera> = cameras.iter().map(|c| c.with_viewport(1280.0, 720.0)).collect();
    assert_watertight(&hm, &wide[1..2], 4.0);
    let Some(ctx) = context(BackendChoice::Vulkan) else { return };
    let config = GeomorphConfig { width: 256, height: 144, ..Default::default() };
    let mut renderer = GeomorphRenderer::new(&ctx, &hm, &config).unwrap();
    let maps = renderer.materials().expect("a whole heightmap has material maps");
    let (nx, ny) = maps.patches;
    let no_snow = (0..ny)
        .flat_map(|j| (0..nx).map(move |i| (i, j)))
        .filter(|&(i, j)| !maps.draws(i, j, materials::SNOW))
        .count();
    println!("patches without snow: {no_snow} of {}", nx * ny);
    assert!(no_snow > (nx * ny / 2) as usize, "most of Puget Sound is below the snow line");
    let cracks = geomorph_cracks(&mut renderer, &hm, 2.0, &cameras[..4]);
    println!("{}: crack pixels {cracks:?}", ctx.describe());
    assert!(cracks.iter().all(|&c| c == 0), "cracks {cracks:?}");
    // The frame statistics count the skipped passes.
    let scene = GeomipScene::new(&hm, 16);
    let camera = crate::render::default_camera(&hm, 256, 144, 60.0);
    let sel = scene.select(&camera.with_viewport(1280.0, 720.0), &GeomipConfig::default());
    let stats = renderer.render(&camera, &sel.patches, &GeomorphOptions::default()).unwrap();
    println!("{stats:?}");
    assert_eq!(stats.passes_drawn + stats.passes_skipped, sel.patches.len() * materials::MATERIALS);
    assert!(stats.passes_skipped > sel.patches.len(), "snow and more skipped: {stats:?}");
}

/// The negative control: a finer patch that ignores its coarser neighbour (draws its odd
/// border vertices at their own heights, no adapting triangles) cracks, and the comparison
/// above sees it.
#[test]
fn ignored_coarser_neighbours_are_detected_as_cracks() {
    let Some(ctx) = context(BackendChoice::Vulkan) else { return };
    let hm = fractal();
    let config = GeomorphConfig { width: 256, height: 144, ..Default::default() };
    let mut renderer = GeomorphRenderer::new(&ctx, &hm, &config).unwrap();
    let scene = GeomipScene::new(&hm, 16);
    let skirt = GeomorphOptions { skirt_depth_m: hm.max() - hm.min() + 10.0, ..Default::default() };
    let mut total = 0;
    for camera in crack_cameras(&hm, 17).iter().take(7) {
        let sel = scene.select(
            &camera.with_viewport(1280.0, 720.0),
            &GeomipConfig { pixel_threshold: 2.0, ..Default::default() },
        );
        let broken: Vec<PatchLod> = sel
            .patches
            .iter()
            .map(|p| PatchLod { edge_level: [p.level; 4], edge_tween: [0.0; 4], ..*p })
            .collect();
        renderer.render(camera, &broken, &GeomorphOptions::default()).unwrap();
        let plain = renderer.read_image().unwrap();
        renderer.render(camera, &broken, &skirt).unwrap();
        let reference = renderer.read_image().unwrap();
        total += plain
            .pixels
            .iter()
            .zip(&reference.pixels)
            .filter(|&(&a, &b)| a == BACKGROUND && b != BACKGROUND)
            .count();
    }
    println!("ignored neighbours: {total} crack pixels");
    assert!(total > 0, "the crack test cannot see cracks");
}

/// At full resolution (every patch at level 0) with the same sun and no shadows, the
/// geomorph renderer's lightmap and material passes give the tessellation renderer's image:
/// its ramp and lambert per fragment, ours per sample and filtered, so they differ a little.
#[test]
fn looks_like_the_tessellation_renderer_vulkan() {
    looks_like_the_tessellation_renderer(BackendChoice::Vulkan);
}

#[test]
fn looks_like_the_tessellation_renderer_gl() {
    looks_like_the_tessellation_renderer(BackendChoice::Gl);
}

fn looks_like_the_tessellation_renderer(backend: BackendChoice) {
    let Some(ctx) = context(backend) else { return };
    let hm = fractal();
    let (w, h) = (240, 135);
    let camera = crate::render::default_camera(&hm, w, h, 60.0);
    let lightmap = terrain_core::lightmap::LightmapConfig { shadows: false, ..Default::default() };
    let config = GeomorphConfig { width: w, height: h, lightmap, ..Default::default() };
    let mut ours = GeomorphRenderer::new(&ctx, &hm, &config).unwrap();
    let sel = GeomipScene::new(&hm, 16)
        .select(&camera, &GeomipConfig { pixel_threshold: 1e-9, ..Default::default() });
    assert!(sel.patches.iter().all(|p| p.level == 0));
    ours.render(&camera, &sel.patches, &GeomorphOptions::default()).unwrap();
    let a = ours.read_image().unwrap();
    let rc = crate::render::RenderConfig { width: w, height: h, ..Default::default() };
    let mut theirs = crate::render::TerrainRenderer::new(&ctx, &hm, &rc).unwrap();
    let patches = crate::render::full_resolution_patches(&hm, 16);
    theirs.render(&camera, &patches, &crate::render::RenderOptions::default()).unwrap();
    let b = theirs.read_image().unwrap();
    let (mut sum, mut n) = (0.0, 0usize);
    for (p, q) in a.pixels.iter().zip(&b.pixels) {
        if *p != BACKGROUND && *q != BACKGROUND {
            sum += (0..3).map(|c| f64::from(p[c].abs_diff(q[c]))).sum::<f64>() / 3.0;
            n += 1;
        }
    }
    let both = a
        .pixels
        .iter()
        .zip(&b.pixels)
        .filter(|(p, q)| (**p == BACKGROUND) == (**q == BACKGROUND))
        .count();
    let mean = sum / n.max(1) as f64;
    println!(
        "{}: mean |difference| {mean:.2} levels over {n} pixels; coverage agrees on {both} of {}",
        ours.adapter(),
        a.pixels.len()
    );
    if let Some(dir) = std::env::var_os("TERRAIN_TEST_DUMP") {
        for (tag, im) in [("geomorph", &a), ("tess", &b)] {
            let bytes: Vec<u8> = im.pixels.iter().flatten().copied().collect();
            let png = image::RgbaImage::from_raw(im.width, im.height, bytes).unwrap();
            png.save(PathBuf::from(&dir).join(format!("{tag}.png"))).unwrap();
        }
    }
    assert!(n > 1000, "{n} terrain pixels");
    assert!(both as f64 > 0.99 * a.pixels.len() as f64);
    assert!(mean < 6.0, "mean difference {mean} levels");
}

#[test]
fn gpu_morph_matches_the_cpu_reference_gl() {
    gpu_morph_matches_cpu(BackendChoice::Gl, &fractal());
}

#[test]
fn no_cracks_fractal_gl() {
    let Some(ctx) = context(BackendChoice::Gl) else { return };
    let hm = fractal();
    let config = GeomorphConfig { width: 256, height: 144, ..Default::default() };
    let mut renderer = GeomorphRenderer::new(&ctx, &hm, &config).unwrap();
    let cracks = geomorph_cracks(&mut renderer, &hm, 2.0, &crack_cameras(&hm, 17)[..7]);
    println!("{}: crack pixels {cracks:?}", ctx.describe());
    assert!(cracks.iter().all(|&c| c == 0), "cracks {cracks:?}");
}

/// `hm` in pages of 64 cells, page `k` stored at stride `2^(k mod 4)` (1 to 8: a store's blocks
/// at different resident levels) and the page at `(1, 1)` left out when `hole`; the CPU mirror
/// and a paged tessellation renderer holding the same pages.
fn mixed_pages(
    ctx: &crate::GpuContext,
    hm: &Heightmap,
    hole: bool,
) -> (PagedHeights, TerrainRenderer) {
    let full = PagedHeights::from_heightmap(hm, 64);
    let layout = *full.layout();
    let w = layout.page_samples()[0] as usize;
    let mut mirror = PagedHeights::new(layout);
    for (k, (&page, p)) in full.pages().enumerate() {
        if hole && page == [1, 1] {
            continue;
        }
        let d = 1usize << (k % 4);
        let n = 64 / d;
        let lattice: Vec<f32> = (0..=n)
            .flat_map(|b| (0..=n).map(move |a| (a, b)))
            .map(|(a, b)| p.samples[b * d * w + a * d])
            .collect();
        mirror.insert(page, Page { samples: lattice, stride: d as u32 }).unwrap();
    }
    let classes: Vec<PageClass> =
        [1, 2, 4, 8].map(|stride| PageClass { stride, capacity: 16 }).to_vec();
    let rc = crate::render::RenderConfig { width: 1, height: 1, ..Default::default() };
    let mut pages =
        TerrainRenderer::new_paged_classes(ctx, layout, &classes, [hm.min(), hm.max()], &rc)
            .unwrap();
    for (&page, p) in mirror.pages() {
        pages.set_page_lattice(page, &p.samples, p.stride).unwrap();
    }
    (mirror, pages)
}

/// Paged mode: the morph the vertex stage computes from a paged renderer's pages (mixed
/// strides) equals the CPU reference over the pages' mirror (`MorphGrid` over
/// `PagedHeights`), with the tolerance of `gpu_morph_matches_cpu`; the coarse pages change
/// the heights (the control: the whole heightmap's morph differs there).
fn paged_morph_matches_cpu(backend: BackendChoice) {
    let Some(ctx) = context(backend) else { return };
    let hm = fractal();
    let (mirror, mut pages) = mixed_pages(&ctx, &hm, false);
    let config = GeomorphConfig { width: 64, height: 64, ..Default::default() };
    let mut renderer = GeomorphRenderer::new_paged(&ctx, &pages, &config).unwrap();
    assert!(renderer.is_paged() && renderer.materials().is_none());
    let scene = GeomipScene::new(&hm, 16);
    let paged = MorphGrid::new(&mirror, 16);
    let whole = MorphGrid::new(&hm, 16);
    let cfg = GeomipConfig { frustum_cull: false, pixel_threshold: 2.0, ..Default::default() };
    let (mut worst, mut differs, mut compared) = (0.0f32, 0usize, 0usize);
    for c in crack_cameras(&hm, 17).into_iter().step_by(5) {
        let c = c.with_viewport(1280.0, 720.0);
        let sel = scene.select(&c, &cfg);
        let patches = gpu_patches(&sel.patches, 16);
        assert!(patches.iter().any(|p| p.tween > 0.0));
        let mut items = Vec::new();
        for (k, p) in patches.iter().enumerate() {
            let mut ids: Vec<u32> = renderer.library().triangles(p).to_vec();
            ids.sort_unstable();
            ids.dedup();
            items.extend(ids.into_iter().map(|id| [k as u32, id]));
        }
        let gpu = renderer.morph_read_back_paged(&mut pages, c.position, &patches, &items).unwrap();
        let anchor = TerrainRenderer::anchor_for(c.position);
        let tol = 16.0
            * f32::EPSILON
            * (hm.max().abs().max(hm.min().abs()) + anchor.z.abs() as f32 + 1.0);
        for (&[k, id], g) in items.iter().zip(&gpu) {
            let (x, y) = (id % 17, id / 17);
            let p = &patches[k as usize];
            let cpu = paged.relative_position(p, x, y, anchor);
            assert_eq!((g[0], g[1]), (cpu[0], cpu[1]), "plan position of {k}/{id}");
            for c in [2, 3] {
                let d = (g[c] - cpu[c]).abs();
                worst = worst.max(d);
                assert!(d <= tol, "patch {k} vertex ({x}, {y}): GPU {g:?} CPU {cpu:?}");
            }
            differs += usize::from(whole.height(p, x, y) != cpu[3]);
            compared += 1;
        }
    }
    println!(
        "{} paged: largest height difference GPU - CPU {worst} m over {compared} vertices; \
         {differs} differ from the whole heightmap's morph",
        renderer.adapter()
    );
    assert!(differs > compared / 10, "coarse pages change the morph: {differs} of {compared}");
}

#[test]
fn paged_morph_matches_the_cpu_reference_vulkan() {
    paged_morph_matches_cpu(BackendChoice::Vulkan);
}

#[test]
fn paged_morph_matches_the_cpu_reference_gl() {
    paged_morph_matches_cpu(BackendChoice::Gl);
}

/// Paged mode draws no crack over pages of mixed strides (the crack cameras, skirts as the
/// reference), and the negative control (patches ignoring their coarser neighbours) cracks on
/// the same pages. With all pages at stride 1 it draws the whole-heightmap renderer's
/// geometry: the same depth-tested coverage.
#[test]
fn paged_mode_draws_no_cracks_and_the_control_does() {
    let Some(ctx) = context(BackendChoice::Vulkan) else { return };
    let hm = fractal();
    let (_, mut pages) = mixed_pages(&ctx, &hm, false);
    let config = GeomorphConfig { width: 256, height: 144, ..Default::default() };
    let mut renderer = GeomorphRenderer::new_paged(&ctx, &pages, &config).unwrap();
    let scene = GeomipScene::new(&hm, 16);
    let skirt = GeomorphOptions { skirt_depth_m: hm.max() - hm.min() + 10.0, ..Default::default() };
    let mut crack_pixels = |renderer: &mut GeomorphRenderer, lods: &[PatchLod], camera: &Camera| {
        renderer.render_paged(&mut pages, camera, lods, &GeomorphOptions::default()).unwrap();
        let plain = renderer.read_image().unwrap();
        renderer.render_paged(&mut pages, camera, lods, &skirt).unwrap();
        let reference = renderer.read_image().unwrap();
        assert!(plain.pixels.iter().any(|&p| p != BACKGROUND), "terrain in view");
        plain
            .pixels
            .iter()
            .zip(&reference.pixels)
            .filter(|&(&a, &b)| a == BACKGROUND && b != BACKGROUND)
            .count()
    };
    let (mut cracks, mut control) = (Vec::new(), 0);
    for camera in crack_cameras(&hm, 17).iter().take(7) {
        let cfg = GeomipConfig { pixel_threshold: 2.0, ..Default::default() };
        let sel = scene.select(&camera.with_viewport(1280.0, 720.0), &cfg);
        cracks.push(crack_pixels(&mut renderer, &sel.patches, camera));
        let broken: Vec<PatchLod> = sel
            .patches
            .iter()
            .map(|p| PatchLod { edge_level: [p.level; 4], edge_tween: [0.0; 4], ..*p })
            .collect();
        control += crack_pixels(&mut renderer, &broken, camera);
    }
    println!("{} paged: crack pixels {cracks:?}, negative control {control}", ctx.describe());
    assert!(cracks.iter().all(|&c| c == 0), "cracks {cracks:?}");
    assert!(control > 0, "the crack test cannot see cracks");
    // A paged renderer refuses to draw without its pages, and a whole one with pages.
    let sel = scene.select(&crack_cameras(&hm, 17)[0], &GeomipConfig::default());
    let camera = crack_cameras(&hm, 17)[0];
    assert!(renderer.render(&camera, &sel.patches, &GeomorphOptions::default()).is_err());
    let mut whole = GeomorphRenderer::new(&ctx, &hm, &config).unwrap();
    let e = whole.render_paged(&mut pages, &camera, &sel.patches, &GeomorphOptions::default());
    assert!(e.is_err());
}

/// Paged mode's shading (per-vertex normals from the pages, the materials blended per
/// fragment) looks like the whole heightmap's (lightmap and alpha maps, no shadows) over the
/// same heights (every page at stride 1): the same coverage, colours within a few levels
/// (per sample and filtered there, per vertex and interpolated here).
#[test]
fn paged_mode_looks_like_the_whole_heightmaps() {
    let Some(ctx) = context(BackendChoice::Vulkan) else { return };
    let hm = fractal();
    let (w, h) = (240, 135);
    let camera = crate::render::default_camera(&hm, w, h, 60.0);
    let lightmap = terrain_core::lightmap::LightmapConfig { shadows: false, ..Default::default() };
    let config = GeomorphConfig { width: w, height: h, lightmap, ..Default::default() };
    let sel = GeomipScene::new(&hm, 16).select(&camera, &GeomipConfig::default());
    let mut whole = GeomorphRenderer::new(&ctx, &hm, &config).unwrap();
    whole.render(&camera, &sel.patches, &GeomorphOptions::default()).unwrap();
    let a = whole.read_image().unwrap();
    let full = PagedHeights::from_heightmap(&hm, 64);
    let classes = [PageClass { stride: 1, capacity: 16 }];
    let rc = crate::render::RenderConfig { width: 1, height: 1, ..Default::default() };
    let mut pages = TerrainRenderer::new_paged_classes(
        &ctx,
        *full.layout(),
        &classes,
        [hm.min(), hm.max()],
        &rc,
    )
    .unwrap();
    for (&page, p) in full.pages() {
        pages.set_page_lattice(page, &p.samples, 1).unwrap();
    }
    let mut paged = GeomorphRenderer::new_paged(&ctx, &pages, &config).unwrap();
    paged.render_paged(&mut pages, &camera, &sel.patches, &GeomorphOptions::default()).unwrap();
    let b = paged.read_image().unwrap();
    let (mut sum, mut n) = (0.0, 0usize);
    for (p, q) in a.pixels.iter().zip(&b.pixels) {
        if *p != BACKGROUND && *q != BACKGROUND {
            sum += (0..3).map(|c| f64::from(p[c].abs_diff(q[c]))).sum::<f64>() / 3.0;
            n += 1;
        }
    }
    let both = a
        .pixels
        .iter()
        .zip(&b.pixels)
        .filter(|(p, q)| (**p == BACKGROUND) == (**q == BACKGROUND))
        .count();
    let mean = sum / n.max(1) as f64;
    println!("paged vs whole: mean |difference| {mean:.2} levels over {n} pixels, coverage {both}");
    assert!(n > 1000, "{n} terrain pixels");
    assert!(both as f64 > 0.99 * a.pixels.len() as f64);
    assert!(mean < 6.0, "mean difference {mean} levels");
}

/// LOD colours: over flat ground lit from straight above (light 1), every patch's pixels carry
/// exactly the CPU reference's colour of its level (`lod_colour(lod_step(patch))`, `2^level`
/// cells per triangle edge): level 0 in the west, level 3 in the east, from a whole heightmap
/// (lightmap) and from pages (per-fragment sun); without the option the materials are drawn.
fn lod_colours_are_the_cpu_references(backend: BackendChoice) {
    let Some(ctx) = context(backend) else { return };
    let hm = terrain_core::synth::HardCase::Flat.build();
    let lightmap = terrain_core::lightmap::LightmapConfig {
        sun_direction: [0.0, 0.0, 1.0],
        shadows: false,
        ..Default::default()
    };
    let config = GeomorphConfig { width: 64, height: 64, lightmap, ..Default::default() };
    let centre = hm.grid_to_world(32.0, 32.0).extend(f64::from(hm.max()) + 900.0);
    let camera = Camera::from_yaw_pitch(centre, 0.0, -90.0).with_clip(10.0, 2000.0);
    let lods: Vec<PatchLod> = (0..4)
        .flat_map(|j| (0..4).map(move |i| (i, j)))
        .map(|(i, j)| {
            let level = if i < 2 { 0 } else { 3 };
            PatchLod { i, j, level, tween: 0.0, edge_level: [level; 4], edge_tween: [0.0; 4] }
        })
        .collect();
    assert_eq!((lod_step(&lods[0]), lod_step(&lods[3])), (1.0, 8.0));
    let on = GeomorphOptions { lod_colours: true, ..Default::default() };
    let mut whole = GeomorphRenderer::new(&ctx, &hm, &config).unwrap();
    let pages_hm = PagedHeights::from_heightmap(&hm, 64);
    let rc = crate::render::RenderConfig { width: 1, height: 1, ..Default::default() };
    let range = [hm.min(), hm.max()];
    let mut pages = TerrainRenderer::new_paged(&ctx, *pages_hm.layout(), 4, range, &rc).unwrap();
    for (&page, p) in pages_hm.pages() {
        pages.set_page_lattice(page, &p.samples, p.stride).unwrap();
    }
    let mut paged = GeomorphRenderer::new_paged(&ctx, &pages, &config).unwrap();
    let mut draw = |options: &GeomorphOptions| {
        whole.render(&camera, &lods, options).unwrap();
        paged.render_paged(&mut pages, &camera, &lods, options).unwrap();
        [whole.read_image().unwrap(), paged.read_image().unwrap()]
    };
    let coloured = draw(&on);
    let plain = draw(&GeomorphOptions::default());
    for (mode, image, plain) in
        [("whole", &coloured[0], &plain[0]), ("paged", &coloured[1], &plain[1])]
    {
        for (x, lod) in [(20, &lods[0]), (44, &lods[3])] {
            let want = crate::render::lod_colour(lod_step(lod)).map(|c| (c * 255.0).round() as i32);
            let got = image.get(x, 32);
            println!("{mode} x {x}: {got:?}, reference {want:?}");
            for c in 0..3 {
                assert!(
                    (i32::from(got[c]) - want[c]).abs() <= 2,
                    "{mode} x {x}: {got:?} vs {want:?}"
                );
            }
        }
        assert_eq!(plain.get(20, 32), plain.get(44, 32), "{mode}: materials ignore the level");
        assert_ne!(plain.get(20, 32), image.get(20, 32), "{mode}");
    }
}

#[test]
fn lod_colours_are_the_cpu_references_vulkan() {
    lod_colours_are_the_cpu_references(BackendChoice::Vulkan);
}

#[test]
fn lod_colours_are_the_cpu_references_gl() {
    lod_colours_are_the_cpu_references(BackendChoice::Gl);
}

/// The article's three Table 1 paths draw the same frame: heights morphed on the CPU
/// (`MorphGrid::patch_heights`, uploaded: "software morphing") give the vertex stage's morph
/// image ("hardware morphing") but for pixels where the two differ by an FMA's rounding, and
/// the true heights ("static LOD") a visibly different one when patches tween.
fn cpu_morph_draws_the_shaders_morph(backend: BackendChoice) {
    let Some(ctx) = context(backend) else { return };
    let hm = fractal();
    let config = GeomorphConfig { width: 320, height: 180, ..Default::default() };
    let mut renderer = GeomorphRenderer::new(&ctx, &hm, &config).unwrap();
    let scene = GeomipScene::new(&hm, 16);
    let grid = MorphGrid::new(&hm, 16);
    let cfg = GeomipConfig { pixel_threshold: 2.0, ..Default::default() };
    let options = GeomorphOptions::default();
    let mut heights = Vec::new();
    let (mut cpu_off, mut static_off, mut total) = (0usize, 0usize, 0usize);
    for c in crack_cameras(&hm, 17).into_iter().step_by(5) {
        let c = c.with_viewport(1280.0, 720.0);
        let sel = scene.select(&c, &cfg);
        let patches = gpu_patches(&sel.patches, 16);
        assert!(patches.iter().any(|p| p.tween > 0.0));
        grid.patch_heights(&patches, &mut heights);
        assert_eq!(heights.len(), patches.len() * 17 * 17);
        let mut image = |source| {
            renderer.render_with(&c, &sel.patches, source, &options).unwrap();
            renderer.read_image().unwrap()
        };
        let shader = image(MorphSource::Shader);
        let cpu = image(MorphSource::Cpu(&heights));
        let still = image(MorphSource::Static);
        let differ = |a: &crate::RgbaImage, b: &crate::RgbaImage| {
            a.pixels.iter().zip(&b.pixels).filter(|(p, q)| p != q).count()
        };
        cpu_off += differ(&shader, &cpu);
        static_off += differ(&shader, &still);
        total += shader.pixels.len();
    }
    // Wrong lengths are refused, not drawn.
    let sel = scene.select(&crack_cameras(&hm, 17)[0].with_viewport(1280.0, 720.0), &cfg);
    let short = vec![0.0f32; 3];
    assert!(
        renderer
            .render_with(
                &crack_cameras(&hm, 17)[0],
                &sel.patches,
                MorphSource::Cpu(&short),
                &options
            )
            .is_err()
    );
    println!(
        "{}: pixels differing from the shader's morph: CPU morph {cpu_off}, static {static_off} \
         of {total}",
        renderer.adapter()
    );
    assert!(cpu_off * 1000 <= total, "CPU morph: {cpu_off} of {total} pixels differ");
    assert!(static_off > 10 * cpu_off.max(10), "static {static_off}, CPU morph {cpu_off}");
}

#[test]
fn cpu_morph_draws_the_shaders_morph_vulkan() {
    cpu_morph_draws_the_shaders_morph(BackendChoice::Vulkan);
}

/// Views of a 257^2 fractal grid with runs of coarsest patches (`select_runs` at 8 px): the
/// whole grid framed from afar (every patch one run, or a few) and three views from the
/// grid's south-west corner over it (runs beside single patches, partly visible nodes along
/// the frustum's sides); every camera has runs, and some has single patches.
fn run_views(hm: &Heightmap) -> (GeomipScene, GeomipConfig, Vec<Camera>) {
    let scene = GeomipScene::new(hm, 16);
    let cfg = GeomipConfig { pixel_threshold: 8.0, ..Default::default() };
    let framed = crate::render::default_camera(hm, 256, 144, 60.0);
    let corner = hm.grid_to_world(0.0, 0.0);
    let top = f64::from(hm.max());
    let mut cameras = vec![framed];
    for (yaw, pitch, above) in [(45.0, -20.0, 600.0), (60.0, -12.0, 300.0)] {
        let eye = corner.extend(top + above);
        cameras.push(Camera::from_yaw_pitch(eye, yaw, pitch).with_fov_y_deg(60.0));
    }
    (scene, cfg, cameras)
}

/// The runs drawn without expansion (`render_runs`: one instanced draw per pass over the
/// runs) give the image of the same selection expanded and drawn patch by patch, pixel for
/// pixel, with the material passes: the selection's own expansion (`expand`, row-major)
/// without skirts; with skirts, the patches listed in the order the runs path draws them (the
/// single patches, then each run's row by row), since the coincident skirts of neighbouring
/// patches may tie in depth, where the first drawn wins. A run moved by one patch changes the
/// image (the negative control). The same in paged mode (`render_paged_runs` over pages of
/// mixed strides against `render_paged` of the list).
fn runs_draw_the_expanded_image(backend: BackendChoice) {
    let Some(ctx) = context(backend) else { return };
    let hm = fractal();
    let config = GeomorphConfig { width: 256, height: 144, ..Default::default() };
    let mut renderer = GeomorphRenderer::new(&ctx, &hm, &config).unwrap();
    let (_, mut pages) = mixed_pages(&ctx, &hm, false);
    let mut paged = GeomorphRenderer::new_paged(&ctx, &pages, &config).unwrap();
    let (scene, cfg, cameras) = run_views(&hm);
    let skirt = GeomorphOptions { skirt_depth_m: 50.0, ..Default::default() };
    let (mut in_runs, mut single, mut moved_off) = (0u64, 0usize, 0usize);
    for (k, camera) in cameras.iter().enumerate() {
        let runs = scene.select_runs(&camera.with_viewport(1280.0, 720.0), &cfg);
        let all = runs.expand();
        let mut in_order = runs.patches.clone();
        for r in &runs.runs {
            for j in r.j..r.j + r.height {
                in_order.extend((r.i..r.i + r.width).map(|i| runs.run_patch(i, j)));
            }
        }
        assert_eq!(in_order.len(), all.patches.len());
        assert!(!runs.runs.is_empty(), "camera {k}: no runs");
        in_runs += runs.run_patches();
        single += runs.patches.len();
        for (options, list) in [(GeomorphOptions::default(), &all.patches), (skirt, &in_order)] {
            let s = renderer.render_runs(camera, &runs, MorphSource::Shader, &options).unwrap();
            let compact = renderer.read_image().unwrap();
            let e = renderer.render(camera, list, &options).unwrap();
            let expanded = renderer.read_image().unwrap();
            assert_eq!(
                (s.patches, s.triangles, s.passes_drawn, s.passes_skipped),
                (e.patches, e.triangles, e.passes_drawn, e.passes_skipped),
                "camera {k}: the statistics"
            );
            let terrain = expanded.pixels.iter().filter(|&&p| p != BACKGROUND).count();
            assert!(terrain > 1000, "camera {k} sees little terrain: {terrain} pixels");
            let differ =
                compact.pixels.iter().zip(&expanded.pixels).filter(|(a, b)| a != b).count();
            assert_eq!(differ, 0, "camera {k} ({options:?}): {differ} pixels differ");
            let s = paged.render_paged_runs(&mut pages, camera, &runs, &options).unwrap();
            let compact = paged.read_image().unwrap();
            let e = paged.render_paged(&mut pages, camera, &in_order, &options).unwrap();
            let expanded = paged.read_image().unwrap();
            assert_eq!((s.patches, s.triangles), (e.patches, e.triangles), "camera {k}, paged");
            let differ =
                compact.pixels.iter().zip(&expanded.pixels).filter(|(a, b)| a != b).count();
            assert_eq!(differ, 0, "camera {k} ({options:?}), paged: {differ} pixels differ");
        }
        // The negative control: the largest run one patch east (or west at the border).
        let mut shifted = runs.clone();
        let (nx, _) = scene.patch_counts();
        let r = shifted.runs.iter_mut().max_by_key(|r| r.patches()).expect("runs");
        if r.i + r.width < nx {
            r.i += 1
        } else {
            r.i -= 1
        }
        renderer.render_runs(camera, &shifted, MorphSource::Shader, &skirt).unwrap();
        let wrong = renderer.read_image().unwrap();
        renderer.render_runs(camera, &runs, MorphSource::Shader, &skirt).unwrap();
        let right = renderer.read_image().unwrap();
        moved_off += right.pixels.iter().zip(&wrong.pixels).filter(|(a, b)| a != b).count();
    }
    println!(
        "{}: {in_runs} patches in runs, {single} single patches over {} cameras; a run moved \
         by one patch changed {moved_off} pixels",
        renderer.adapter(),
        cameras.len()
    );
    assert!(single > 0, "no single patches beside the runs");
    assert!(moved_off > 0, "the comparison cannot see a misplaced run");
    // Runs of another coarsest level, or past the grid, are refused.
    let c = &cameras[0];
    let mut runs = scene.select_runs(&c.with_viewport(1280.0, 720.0), &cfg);
    runs.coarsest -= 1;
    assert!(renderer.render_runs(c, &runs, MorphSource::Shader, &skirt).is_err());
    runs.coarsest += 1;
    runs.runs[0].width += 32;
    assert!(renderer.render_runs(c, &runs, MorphSource::Shader, &skirt).is_err());
}

#[test]
fn runs_draw_the_expanded_image_vulkan() {
    runs_draw_the_expanded_image(BackendChoice::Vulkan);
}

#[test]
fn runs_draw_the_expanded_image_gl() {
    runs_draw_the_expanded_image(BackendChoice::Gl);
}
