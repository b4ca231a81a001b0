//! GPU tests of the terrain renderer, on Vulkan (lavapipe here) and GL (llvmpipe): the
//! shader's surface against the CPU reference, crack-freedom, a golden image, wireframe,
//! colour texture orientation, frame statistics and drawing into a caller's (surface) view. Where no adapter exists the tests print
//! why and pass, unless `TERRAIN_REQUIRE_GPU` is set: then they fail.

use std::path::PathBuf;

use glam::{DVec3, dvec3};
use terrain_core::Heightmap;
use terrain_core::geometry::Camera;
use terrain_core::synth::{HardCase, default_terrain};

use super::crack::{crack_cameras, crack_pixels};

use super::*;
use crate::device::{BackendChoice, GpuContext};
use crate::paged::PagedHeights;
use crate::surface;
use crate::target::read_texture_8bit4;
use crate::tess::{PatchFactors, tessellate};
use crate::test_support::{self, puget_sound};

/// A context on `backend`, or `None` (with the reason printed) where none exists and none is required.
fn context(backend: BackendChoice) -> Option<GpuContext> {
    let ctx = test_support::context(backend)?;
    let want = if backend == BackendChoice::Gl { wgpu::Backend::Gl } else { wgpu::Backend::Vulkan };
    assert_eq!(ctx.adapter_info().backend, want, "{}", ctx.describe());
    Some(ctx)
}

/// Deterministic generator (SplitMix64).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[lo, hi)`.
    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * ((self.next() >> 40) as f32 / (1u64 << 24) as f32)
    }
}

/// Patches of `patch_cells` with random factors in `[lo, hi)`: every patch's inner factors
/// are its own, and every edge factor is drawn once per edge and used by both patches that
/// share it, so neighbours agree on shared edges. With `agree == false` each patch draws its
/// own edge factors (the negative control: cracks expected).
fn random_patches(
    hm: &Heightmap,
    patch_cells: u32,
    lo: f32,
    hi: f32,
    seed: u64,
    agree: bool,
) -> Vec<DrawPatch> {
    let mut rng = Rng(seed);
    let mut patches = uniform_patches(hm, patch_cells, 1.0);
    let xs: Vec<u32> = {
        let mut v: Vec<u32> = patches.iter().map(|p| p.rect[0]).collect();
        v.sort_unstable();
        v.dedup();
        v
    };
    let ys: Vec<u32> = {
        let mut v: Vec<u32> = patches.iter().map(|p| p.rect[1]).collect();
        v.sort_unstable();
        v.dedup();
        v
    };
    let (nx, ny) = (xs.len(), ys.len());
    // Vertical edges: (nx + 1) per patch row; horizontal edges: nx per patch-row boundary.
    let vertical: Vec<f32> = (0..(nx + 1) * ny).map(|_| rng.range(lo, hi)).collect();
    let horizontal: Vec<f32> = (0..nx * (ny + 1)).map(|_| rng.range(lo, hi)).collect();
    for (k, p) in patches.iter_mut().enumerate() {
        let (c, r) = (k % nx, k / nx);
        let outer = if agree {
            [
                vertical[r * (nx + 1) + c],
                horizontal[r * nx + c],
                vertical[r * (nx + 1) + c + 1],
                horizontal[(r + 1) * nx + c],
            ]
        } else {
            [rng.range(lo, hi), rng.range(lo, hi), rng.range(lo, hi), rng.range(lo, hi)]
        };
        p.factors = PatchFactors { inner: [rng.range(lo, hi), rng.range(lo, hi)], outer };
    }
    patches
}

fn config(width: u32, height: u32) -> RenderConfig {
    RenderConfig { width, height, ..Default::default() }
}

// ---------------------------------------------------------------------------------------
// The vertex stage's surface against the CPU reference.

fn surface_matches_reference(backend: BackendChoice) {
    let Some(ctx) = context(backend) else { return };
    // The default fractal (local metres) and the same fractal at UTM 11N coordinates
    // (easting 500 000 m, northing 4 000 000 m), where absolute f32 would lose metres.
    let cases: [(&str, Heightmap); 2] =
        [("default", default_terrain()), ("huge_origin", HardCase::HugeOrigin.build())];
    for (name, hm) in &cases {
        let mut renderer = TerrainRenderer::new(&ctx, hm, &config(64, 64)).unwrap();
        let mut patches = random_patches(hm, 16, 1.0, 17.0, 7, true);
        patches.extend(uniform_patches(hm, 32, 6.5));
        let origin = hm.georef().world_origin;
        // A camera 300 m above a point a third of the way in, not on a whole metre.
        let g = glam::dvec2(hm.width() as f64 / 3.0, hm.height() as f64 / 2.7);
        let eye = (origin + g * hm.georef().spacing_m).extend(f64::from(hm.max()) + 300.0)
            + dvec3(0.37, 0.61, 0.25);
        let anchor = TerrainRenderer::anchor_for(eye);
        let back = renderer.surface_read_back(eye, &patches).unwrap();
        assert!(!back.points.is_empty());
        let (mut worst, mut worst_near, mut worst_normal) = (0.0f64, 0.0f64, 0.0f32);
        for (k, p) in back.points.iter().enumerate() {
            let patch = &patches[p.patch_index as usize];
            let want = surface::vertex_position(hm, patch, p.uv) - anchor;
            let got = back.positions[k];
            let got_v = DVec3::new(got[0].into(), got[1].into(), got[2].into());
            let err = (got_v - want).length();
            // f32 holds the offset from the anchor: allow 1 mm plus two f32 ulps at its distance.
            let tolerance = 1e-3 + 2.5e-7 * want.length();
            assert!(
                err <= tolerance,
                "{name}: point {k} {p:?}: gpu {got_v} cpu {want}, |d| = {err}"
            );
            worst = worst.max(err);
            if want.length() < 2000.0 {
                worst_near = worst_near.max(err);
            }
            let g = surface::grid_coords(patch, p.uv);
            let n = surface::normal_at(hm, g);
            let dn = (glam::Vec3::new(back.normals[k][0], back.normals[k][1], back.normals[k][2])
                - n)
                .length();
            assert!(dn <= 1e-4, "{name}: point {k} normal gpu {:?} cpu {n}", back.normals[k]);
            worst_normal = worst_normal.max(dn);
        }
        println!(
            "{name}: {} points; max |gpu - cpu| = {worst:.2e} m ({worst_near:.2e} m within 2 km of the camera); normals {worst_normal:.1e}",
            back.points.len()
        );
        assert!(worst_near <= 1e-3, "{name}: {worst_near} m within 2 km");
    }
}

#[test]
fn surface_matches_reference_on_vulkan() {
    surface_matches_reference(BackendChoice::Vulkan);
}

#[test]
fn surface_matches_reference_on_gl() {
    surface_matches_reference(BackendChoice::Gl);
}

// ---------------------------------------------------------------------------------------
// Cracks.
//
// Why the reference is not a full-resolution render: a coarse tessellation has a different
// silhouette from the full-resolution surface (a ridge drawn with fewer vertices is lower),
// so background legitimately appears above coarse ridges where the full-resolution reference
// shows terrain; no erosion by a fixed number of pixels separates that from a crack. The
// reference is instead the *same* tessellation plus skirts hanging below every shared patch
// edge (`RenderOptions::skirt_depth_m`). With every camera above the surface and inside the
// grid's footprint, a ray reaching a point below the surface crosses the (crack-free) surface
// first, so skirts are hidden everywhere except through cracks: a pixel that is background in
// the plain render but terrain in the skirted one is a crack, and the comparison is exact
// (both renders rasterise the identical surface triangles; no erosion). The negative control
// below checks that mismatched edge factors do show up this way. Set TERRAIN_TEST_DUMP to a
// folder to get both images of every camera as PNGs.

fn no_cracks(
    backend: BackendChoice,
    name: &str,
    hm: &Heightmap,
    patch_cells: u32,
    uniform_factor: f32,
) {
    let Some(ctx) = context(backend) else { return };
    let cameras = crack_cameras(hm, patch_cells as usize + 1);
    let sets = [
        ("uniform", uniform_patches(hm, patch_cells, uniform_factor)),
        ("random", random_patches(hm, patch_cells, 1.0, patch_cells as f32 + 1.0, 11, true)),
    ];
    for (kind, patches) in &sets {
        let cracks = crack_pixels(&ctx, hm, patches, &cameras, (256, 144));
        println!(
            "{name} {kind}: {} patches, {} cameras, crack pixels {cracks:?}",
            patches.len(),
            cameras.len()
        );
        assert!(cracks.iter().all(|&c| c == 0), "{name} {kind}: cracks {cracks:?}");
    }
}

#[test]
fn no_cracks_default_fractal_vulkan() {
    no_cracks(BackendChoice::Vulkan, "default", &default_terrain(), 32, 9.5);
}

#[test]
fn no_cracks_default_fractal_gl() {
    no_cracks(BackendChoice::Gl, "default", &default_terrain(), 32, 9.5);
}

#[test]
fn no_cracks_hard_cases_vulkan() {
    no_cracks(BackendChoice::Vulkan, "cliff", &HardCase::Cliff.build(), 8, 3.3);
    no_cracks(BackendChoice::Vulkan, "spike", &HardCase::Spike.build(), 8, 5.0);
}

#[test]
fn no_cracks_hard_cases_gl() {
    no_cracks(BackendChoice::Gl, "cliff", &HardCase::Cliff.build(), 8, 3.3);
    no_cracks(BackendChoice::Gl, "spike", &HardCase::Spike.build(), 8, 5.0);
}

#[test]
fn no_cracks_puget_sound_vulkan() {
    no_cracks(BackendChoice::Vulkan, "puget_sound", &puget_sound(), 32, 12.0);
}

#[test]
fn no_cracks_puget_sound_gl() {
    no_cracks(BackendChoice::Gl, "puget_sound", &puget_sound(), 32, 12.0);
}

/// The negative control: neighbours that disagree on shared edge factors crack, and the
/// comparison above sees it.
#[test]
fn mismatched_edges_are_detected_as_cracks() {
    let Some(ctx) = context(BackendChoice::Vulkan) else { return };
    let hm = default_terrain();
    let patches = random_patches(&hm, 32, 1.0, 33.0, 5, false);
    let cameras = crack_cameras(&hm, 33);
    let cracks = crack_pixels(&ctx, &hm, &patches, &cameras[..7], (256, 144));
    println!("mismatched edges: crack pixels {cracks:?}");
    assert!(cracks.iter().sum::<usize>() > 0, "no crack found: the crack test cannot see cracks");
}

// ---------------------------------------------------------------------------------------
// Golden image.

/// Regenerate with `TERRAIN_UPDATE_GOLDEN=1 cargo test -p terrain-gpu golden` (writes the
/// PNG from the Vulkan path; the GL test only compares).
const UPDATE_GOLDEN_ENV: &str = "TERRAIN_UPDATE_GOLDEN";

fn golden_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/golden/default_160x90.png")
}

fn golden_render(ctx: &GpuContext) -> RgbaImage {
    let hm = default_terrain();
    let camera = default_camera(&hm, 160, 90, 50.0);
    let mut renderer = TerrainRenderer::new(ctx, &hm, &config(160, 90)).unwrap();
    renderer.render(&camera, &uniform_patches(&hm, 32, 16.0), &RenderOptions::default()).unwrap();
    renderer.read_image().unwrap()
}

fn golden(backend: BackendChoice) {
    let Some(ctx) = context(backend) else { return };
    let image = golden_render(&ctx);
    let path = golden_path();
    let update = std::env::var_os(UPDATE_GOLDEN_ENV).is_some();
    if update && backend == BackendChoice::Vulkan {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        let raw: Vec<u8> = image.pixels.iter().flatten().copied().collect();
        image::save_buffer(&path, &raw, image.width, image.height, image::ColorType::Rgba8)
            .unwrap();
        println!("wrote {}", path.display());
    }
    let want = image::open(&path)
        .unwrap_or_else(|e| {
            panic!("{}: {e}; regenerate with {UPDATE_GOLDEN_ENV}=1", path.display())
        })
        .to_rgba8();
    assert_eq!((want.width(), want.height()), (image.width, image.height));
    let diff = crate::target::image_diff(image.pixels.iter().copied(), want.pixels().map(|p| p.0));
    let (mean, far_fraction) = (diff.mean, diff.far_off);
    let far_off = (far_fraction * image.pixels.len() as f64).round();
    println!(
        "golden: mean |diff| per channel {mean:.3?}, {:.3} % of pixels off by > 16",
        far_fraction * 100.0
    );
    assert!(mean.iter().all(|&m| m < 2.0), "mean abs diff {mean:?}");
    assert!(far_fraction < 0.01, "{far_off} pixels off by more than 16 levels");
}

#[test]
fn golden_image_on_vulkan() {
    golden(BackendChoice::Vulkan);
}

#[test]
fn golden_image_on_gl() {
    golden(BackendChoice::Gl);
}

// ---------------------------------------------------------------------------------------
// Extra triangles with their own heights.

/// A mesh on every 8th sample of the default terrain as extra triangles over a hidden carrier:
/// drawn at heights equal to the samples at its points (`vs_explicit`) it is the sampled
/// draw (`vs_indexed`), pixel for pixel, so its x and y are the sampled surface's (the CPU
/// reference, `surface_matches_reference`); raised 60 m it is drawn elsewhere (the heights are
/// used, not the samples); heights not one per vertex are refused.
fn extra_triangles_at_their_own_heights(backend: BackendChoice) {
    let Some(ctx) = context(backend) else { return };
    let hm = default_terrain();
    let (w, h) = (hm.width() as u32, hm.height() as u32);
    // 1024 cells a side: every lattice point's uv times the size is its integer exactly.
    assert_eq!((w, h), (1025, 1025));
    let carrier = DrawPatch { rect: [0, 0, w - 1, h - 1], factors: PatchFactors::uniform(0.0) };
    let (step, n) = (8u32, (w - 1) / 8 + 1);
    let mut extra = ExtraTriangles::default();
    for j in 0..n {
        for i in 0..n {
            let uv = [(i * step) as f32 / (w - 1) as f32, (j * step) as f32 / (h - 1) as f32];
            extra.points.push(crate::tess::GpuDomainPoint { uv, patch_index: 0, pad: 0 });
        }
    }
    for j in 0..n - 1 {
        for i in 0..n - 1 {
            let k = j * n + i;
            extra.indices.extend([k, k + 1, k + n + 1, k, k + n + 1, k + n]);
        }
    }
    let camera = default_camera(&hm, 160, 90, 50.0);
    let mut renderer = TerrainRenderer::new(&ctx, &hm, &config(160, 90)).unwrap();
    let mut draw = |extra: &ExtraTriangles| {
        let options = RenderOptions::default();
        renderer.render_with_extra(&camera, &[carrier], extra, &options).map(|stats| {
            assert_eq!(stats.triangles, extra.indices.len() as u64 / 3);
            renderer.read_image().unwrap()
        })
    };
    let sampled = draw(&extra).unwrap();
    let sample_at = |p: &crate::tess::GpuDomainPoint| {
        let g = surface::grid_coords(&carrier, p.uv);
        assert_eq!(g, g.round(), "a lattice point");
        hm.get(g.x as usize, g.y as usize)
    };
    extra.heights = extra.points.iter().map(sample_at).collect();
    let given = draw(&extra).unwrap();
    let background = sampled.pixels.iter().filter(|p| **p == BACKGROUND).count();
    // The whole terrain in view, from afar: about a sixth of the image.
    let covered = sampled.pixels.len() - background;
    assert!(covered > sampled.pixels.len() / 10, "{covered} pixels drawn");
    assert_eq!(given.pixels, sampled.pixels, "heights equal to the samples draw the same image");
    for z in &mut extra.heights {
        *z += 60.0;
    }
    let raised = draw(&extra).unwrap();
    let moved = raised.pixels.iter().zip(&sampled.pixels).filter(|(a, b)| a != b).count();
    println!("{}: raised 60 m, {moved} of {} pixels change", ctx.describe(), raised.pixels.len());
    assert!(moved > covered / 4, "{moved} pixels change: the heights are not used");
    extra.heights.pop();
    assert!(matches!(draw(&extra), Err(RenderError::BadExtra(_))));
}

#[test]
fn extra_triangles_at_their_own_heights_on_vulkan() {
    extra_triangles_at_their_own_heights(BackendChoice::Vulkan);
}

#[test]
fn extra_triangles_at_their_own_heights_on_gl() {
    extra_triangles_at_their_own_heights(BackendChoice::Gl);
}

// ---------------------------------------------------------------------------------------
// Wireframe, texture, statistics.

fn wireframe_covers_the_same_pixels(backend: BackendChoice) {
    let Some(ctx) = context(backend) else { return };
    let hm = HardCase::Cliff.build();
    let mut renderer = TerrainRenderer::new(&ctx, &hm, &config(200, 120)).unwrap();
    let camera = default_camera(&hm, 200, 120, 60.0);
    let patches = uniform_patches(&hm, 16, 2.0);
    renderer.render(&camera, &patches, &RenderOptions::default()).unwrap();
    let plain = renderer.read_image().unwrap();
    renderer
        .render(&camera, &patches, &RenderOptions { wireframe: true, ..Default::default() })
        .unwrap();
    let wire = renderer.read_image().unwrap();
    let mask = |i: &RgbaImage| i.pixels.iter().map(|&p| p == BACKGROUND).collect::<Vec<_>>();
    let differ = mask(&plain).iter().zip(&mask(&wire)).filter(|(a, b)| a != b).count();
    let dark = wire.pixels.iter().filter(|p| p != &&BACKGROUND && p[0] < 40 && p[1] < 40).count();
    println!("wireframe: {differ} pixels change coverage, {dark} dark edge pixels");
    assert_eq!(differ, 0, "the pulled (wireframe) draw covers other pixels than the indexed one");
    assert!(dark > 100, "no wireframe edges drawn");
}

#[test]
fn wireframe_covers_the_same_pixels_on_vulkan() {
    wireframe_covers_the_same_pixels(BackendChoice::Vulkan);
}

#[test]
fn wireframe_covers_the_same_pixels_on_gl() {
    wireframe_covers_the_same_pixels(BackendChoice::Gl);
}

/// A texture with a red north-west quadrant (its first rows are north) seen straight down
/// with north up: the top-left of the image is red, the bottom-right is not.
fn texture_is_north_up(backend: BackendChoice) {
    let Some(ctx) = context(backend) else { return };
    let hm = HardCase::Flat.build();
    let (tw, th) = (8, 8);
    let pixels = (0..th)
        .flat_map(|y| {
            (0..tw).map(
                move |x| if x < tw / 2 && y < th / 2 { [255, 0, 0, 255] } else { [0, 0, 255, 255] },
            )
        })
        .collect();
    let texture = RgbaImage { width: tw, height: th, pixels };
    let config = RenderConfig {
        width: 64,
        height: 64,
        texture: Some(texture),
        sun_direction: [0.0, 0.0, 1.0],
        ..RenderConfig::default()
    };
    let mut renderer = TerrainRenderer::new(&ctx, &hm, &config).unwrap();
    let centre = hm.grid_to_world(32.0, 32.0).extend(f64::from(hm.max()) + 900.0);
    let camera = Camera::from_yaw_pitch(centre, 0.0, -90.0).with_clip(10.0, 2000.0);
    renderer.render(&camera, &uniform_patches(&hm, 16, 4.0), &RenderOptions::default()).unwrap();
    let image = renderer.read_image().unwrap();
    let (nw, se) = (image.get(24, 24), image.get(40, 40));
    println!("north-west {nw:?}, south-east {se:?}");
    assert!(nw[0] > 200 && nw[2] < 50, "north-west should be red: {nw:?}");
    assert!(se[2] > 200 && se[0] < 50, "south-east should be blue: {se:?}");
}

#[test]
fn texture_is_north_up_on_vulkan() {
    texture_is_north_up(BackendChoice::Vulkan);
}

#[test]
fn texture_is_north_up_on_gl() {
    texture_is_north_up(BackendChoice::Gl);
}

/// LOD colours: over flat ground lit from straight above (Lambert 1), every patch's pixels
/// carry exactly the CPU reference's colour of its step (`lod_colour(lod_step(patch))`): fine
/// patches (factor 16: 1 cell per edge) in the west, coarse ones (factor 2: 8 cells) in the
/// east; without the option the ramp is drawn instead.
fn lod_colours_are_the_cpu_references(backend: BackendChoice) {
    let Some(ctx) = context(backend) else { return };
    let hm = HardCase::Flat.build();
    let config = RenderConfig {
        width: 64,
        height: 64,
        sun_direction: [0.0, 0.0, 1.0],
        ..RenderConfig::default()
    };
    let mut renderer = TerrainRenderer::new(&ctx, &hm, &config).unwrap();
    let centre = hm.grid_to_world(32.0, 32.0).extend(f64::from(hm.max()) + 900.0);
    let camera = Camera::from_yaw_pitch(centre, 0.0, -90.0).with_clip(10.0, 2000.0);
    let mut patches = uniform_patches(&hm, 16, 16.0);
    for p in &mut patches {
        if p.rect[0] >= 32 {
            p.factors = PatchFactors::uniform(2.0);
        }
    }
    let (west, east) = (patches[0], *patches.iter().find(|p| p.rect[0] >= 32).unwrap());
    assert_eq!((lod_step(&west), lod_step(&east)), (1.0, 8.0));
    let lod = RenderOptions { lod_colours: true, ..Default::default() };
    renderer.render(&camera, &patches, &lod).unwrap();
    let image = renderer.read_image().unwrap();
    for (x, patch) in [(20, west), (44, east)] {
        let want = lod_colour(lod_step(&patch)).map(|c| (c * 255.0).round() as i32);
        let got = image.get(x, 32);
        println!("x {x}: {got:?}, reference {want:?}");
        for c in 0..3 {
            assert!((i32::from(got[c]) - want[c]).abs() <= 2, "x {x}: {got:?} vs {want:?}");
        }
    }
    renderer.render(&camera, &patches, &RenderOptions::default()).unwrap();
    let plain = renderer.read_image().unwrap();
    assert_eq!(plain.get(20, 32), plain.get(44, 32), "the ramp does not depend on the factors");
    assert_ne!(plain.get(20, 32), image.get(20, 32));
}

#[test]
fn lod_colours_are_the_cpu_references_on_vulkan() {
    lod_colours_are_the_cpu_references(BackendChoice::Vulkan);
}

#[test]
fn lod_colours_are_the_cpu_references_on_gl() {
    lod_colours_are_the_cpu_references(BackendChoice::Gl);
}

/// The palette's bands: powers of two land in their own band, the entropy carrier (factor
/// 0) in none, and every band's colour differs from the others.
#[test]
fn lod_bands_follow_the_step() {
    for k in 0..LOD_PALETTE.len() {
        assert_eq!(lod_band((1u32 << k) as f32), Some(k));
    }
    assert_eq!(lod_band(1024.0), Some(LOD_PALETTE.len() - 1));
    assert_eq!(lod_band(0.5), Some(0));
    assert_eq!(lod_band(f32::INFINITY), None);
    let carrier = DrawPatch { rect: [0, 0, 64, 64], factors: PatchFactors::uniform(0.0) };
    assert_eq!(lod_colour(lod_step(&carrier)), LOD_NO_PATCH);
    for (a, (ca, _)) in LOD_PALETTE.iter().enumerate() {
        for (cb, _) in &LOD_PALETTE[a + 1..] {
            assert_ne!(ca, cb);
        }
        assert_ne!(*ca, LOD_NO_PATCH);
    }
}

fn frame_stats(backend: BackendChoice) {
    let Some(ctx) = context(backend) else { return };
    let hm = default_terrain();
    let mut renderer = TerrainRenderer::new(&ctx, &hm, &config(128, 72)).unwrap();
    let patches = random_patches(&hm, 64, 1.0, 20.0, 3, true);
    let camera = default_camera(&hm, 128, 72, 60.0);
    let first = renderer.render(&camera, &patches, &RenderOptions::default()).unwrap();
    let second = renderer.render(&camera, &patches, &RenderOptions::default()).unwrap();
    println!("first:  {first}\nsecond: {second}");
    let (mut triangles, mut vertices) = (0, 0);
    for p in &patches {
        let mesh = tessellate(&p.factors);
        triangles += mesh.non_degenerate_triangle_count() as u64;
        vertices += mesh.points.len() as u64;
    }
    assert_eq!(
        (first.patches, first.triangles, first.vertices),
        (patches.len(), triangles, vertices)
    );
    assert!(first.tessellated && !second.tessellated);
    assert_eq!(first.adapter, ctx.describe());
    if ctx.features.timestamp_query {
        assert!(first.gpu_draw_ms.is_some() && second.gpu_ms.is_some());
        assert_eq!(first.gpu_ms.is_some(), ctx.features.compute_timestamps_trustworthy);
    } else {
        assert!(first.gpu_ms.is_none() && first.gpu_note.is_some());
    }
}

/// A frame whose points exceed the batch limit is drawn in several compute + draw batches,
/// pixel for pixel as one batch draws it (plain, wireframe and with skirts), and the surface
/// read-back names the same patches.
fn batches_draw_like_one(backend: BackendChoice) {
    let Some(ctx) = context(backend) else { return };
    let hm = default_terrain();
    let mut renderer = TerrainRenderer::new(&ctx, &hm, &config(160, 90)).unwrap();
    let patches = random_patches(&hm, 32, 2.0, 24.0, 11, true);
    let camera = default_camera(&hm, 160, 90, 60.0);
    let mut images = Vec::new();
    let mut read_backs = Vec::new();
    for limit in [None, Some(16 * 1024)] {
        renderer.force_batch_limit(limit);
        let mut frame_images = Vec::new();
        for options in [
            RenderOptions::default(),
            RenderOptions { wireframe: true, ..Default::default() },
            RenderOptions { skirt_depth_m: 50.0, ..Default::default() },
        ] {
            let stats = renderer.render(&camera, &patches, &options).unwrap();
            println!("limit {limit:?}: {stats}, {} batches", stats.batches);
            assert_eq!(stats.batches > 1, limit.is_some(), "{limit:?}: {} batches", stats.batches);
            frame_images.push(renderer.read_image().unwrap());
        }
        images.push(frame_images);
        read_backs.push(renderer.surface_read_back(camera.position, &patches).unwrap());
    }
    for (a, b) in images[0].iter().zip(&images[1]) {
        let differ = a.pixels.iter().zip(&b.pixels).filter(|(x, y)| x != y).count();
        assert_eq!(differ, 0, "batched frame differs in {differ} pixels");
        assert!(a.pixels.iter().filter(|&&p| p != BACKGROUND).count() > 1000);
    }
    assert_eq!(read_backs[0], read_backs[1]);
}

#[test]
fn batches_draw_like_one_on_vulkan() {
    batches_draw_like_one(BackendChoice::Vulkan);
}

#[test]
fn batches_draw_like_one_on_gl() {
    batches_draw_like_one(BackendChoice::Gl);
}

#[test]
fn frame_stats_on_vulkan() {
    frame_stats(BackendChoice::Vulkan);
}

#[test]
fn frame_stats_on_gl() {
    frame_stats(BackendChoice::Gl);
}

// ---------------------------------------------------------------------------------------
// The surface path: `render_to_view` into a caller's texture.

/// A `format` texture that can be drawn into and copied from: what a windowed viewer's
/// `surface.get_current_texture()` gives, plus the `COPY_SRC` the read-back needs.
fn surface_stand_in(
    ctx: &GpuContext,
    format: wgpu::TextureFormat,
    w: u32,
    h: u32,
) -> wgpu::Texture {
    ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("surface stand-in"),
        size: wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
    })
}

/// The default terrain drawn by `render_to_view` into BGRA textures, read back and swizzled
/// to RGBA, equals the offscreen `render` + `read_image` of the same camera and patches:
/// exactly for `Bgra8Unorm` (both targets quantise the same fragment colours the same way),
/// within one level per channel for `Bgra8UnormSrgb` (the shader decodes, the store encodes
/// again: the round trip can land on the neighbouring level). The sRGB case runs where the
/// adapter can render to that format, and says so where it cannot.
fn render_to_view_matches_offscreen(backend: BackendChoice) {
    let Some(ctx) = context(backend) else { return };
    let hm = default_terrain();
    let (w, h) = (96, 54);
    let camera = default_camera(&hm, w, h, 50.0);
    let patches = uniform_patches(&hm, 32, 16.0);
    let options = RenderOptions::default();
    let mut renderer = TerrainRenderer::new(&ctx, &hm, &config(w, h)).unwrap();
    renderer.render(&camera, &patches, &options).unwrap();
    let offscreen = renderer.read_image().unwrap();
    let terrain = offscreen.pixels.iter().filter(|&&p| p != BACKGROUND).count();
    println!("offscreen: {terrain} of {} pixels are terrain", offscreen.pixels.len());
    assert!(terrain > offscreen.pixels.len() / 10, "too little terrain in view to compare");

    let mut formats = vec![wgpu::TextureFormat::Rgba8Unorm];
    for (format, tolerance) in
        [(wgpu::TextureFormat::Bgra8Unorm, 0u8), (wgpu::TextureFormat::Bgra8UnormSrgb, 1)]
    {
        let usages = ctx.adapter.get_texture_format_features(format).allowed_usages;
        if !usages.contains(wgpu::TextureUsages::RENDER_ATTACHMENT) {
            assert!(format.is_srgb(), "{format:?} must be renderable: {usages:?}");
            println!("{format:?}: not renderable on this adapter; not compared");
            continue;
        }
        let texture = surface_stand_in(&ctx, format, w, h);
        let view = texture.create_view(&Default::default());
        // Twice: the second frame reuses the format's pipelines (and the tessellation).
        for _ in 0..2 {
            let stats =
                renderer.render_to_view(&camera, &patches, &options, &view, format).unwrap();
            assert_eq!(stats.patches, patches.len());
        }
        formats.push(format);
        let bgra = read_texture_8bit4(&ctx.device, &ctx.queue, &texture).unwrap();
        assert_eq!((bgra.width, bgra.height), (w, h));
        let (mut differing, mut worst) = (0usize, 0u8);
        for (got, want) in bgra.pixels.iter().zip(&offscreen.pixels) {
            let [b, g, r, a] = *got;
            let d = [r, g, b, a].iter().zip(want).map(|(x, y)| x.abs_diff(*y)).max().unwrap();
            differing += usize::from(d > 0);
            worst = worst.max(d);
        }
        println!(
            "{format:?} via render_to_view: {differing} of {} pixels differ from the offscreen \
             render, by at most {worst} levels (allowed {tolerance})",
            bgra.pixels.len()
        );
        assert!(worst <= tolerance, "{format:?}: {differing} pixels differ, up to {worst} levels");
    }
    formats.sort_by_key(|f| format!("{f:?}"));
    assert_eq!(renderer.pipeline_formats(), formats, "one pipeline set per format, kept");

    // The offscreen target is untouched by frames drawn elsewhere.
    assert_eq!(renderer.read_image().unwrap(), offscreen);

    // A view of another size, or a format the view's texture cannot have, is an error.
    let small = surface_stand_in(&ctx, wgpu::TextureFormat::Bgra8Unorm, w - 1, h);
    let view = small.create_view(&Default::default());
    let err = renderer
        .render_to_view(&camera, &patches, &options, &view, wgpu::TextureFormat::Bgra8Unorm)
        .unwrap_err();
    assert!(matches!(err, RenderError::InvalidConfig(_)), "{err}");
    let texture = surface_stand_in(&ctx, wgpu::TextureFormat::Bgra8Unorm, w, h);
    let view = texture.create_view(&Default::default());
    let err = renderer
        .render_to_view(&camera, &patches, &options, &view, wgpu::TextureFormat::Rgba8Unorm)
        .unwrap_err();
    assert!(matches!(err, RenderError::InvalidConfig(_)), "{err}");
}

#[test]
fn render_to_view_matches_offscreen_on_vulkan() {
    render_to_view_matches_offscreen(BackendChoice::Vulkan);
}

#[test]
fn render_to_view_matches_offscreen_on_gl() {
    render_to_view_matches_offscreen(BackendChoice::Gl);
}

#[test]
fn uniform_patches_tile_the_grid() {
    let hm = HardCase::OddSize.build();
    let patches = uniform_patches(&hm, 64, 8.0);
    let cells: u64 =
        patches.iter().map(|p| u64::from((p.rect[2] - p.rect[0]) * (p.rect[3] - p.rect[1]))).sum();
    assert_eq!(cells, (hm.width() as u64 - 1) * (hm.height() as u64 - 1));
    assert_eq!(patches[0].rect, [0, 0, 64, 64]);
    assert_eq!(patches.last().unwrap().rect[2..], [hm.width() as u32 - 1, hm.height() as u32 - 1]);
    let full = full_resolution_patches(&default_terrain(), 32);
    assert_eq!(full[0].factors, PatchFactors::uniform(32.0));
    // The vertices of a full-resolution patch are exactly the samples.
    let mesh = tessellate(&full[0].factors);
    for p in &mesh.points {
        let g = surface::grid_coords(&full[0], *p);
        assert_eq!(g, g.round(), "{g}");
    }
}

// ---------------------------------------------------------------------------------------
// Paged heights (crate::paged): all pages resident is the whole heightmap; pages filled
// from coarse levels match the CPU reference and draw no cracks.

/// A paged renderer holding every page of `paged`: one slot class per stride used (a single
/// class of stride 1 when all pages are full resolution, as before classes existed).
fn paged_renderer(ctx: &GpuContext, paged: &PagedHeights, size: (u32, u32)) -> TerrainRenderer {
    let mut classes: Vec<crate::paged::PageClass> = Vec::new();
    let (mut lo, mut hi) = (f32::MAX, f32::MIN);
    for (_, p) in paged.pages() {
        for &h in &p.samples {
            lo = lo.min(h);
            hi = hi.max(h);
        }
        match classes.iter_mut().find(|c| c.stride == p.stride) {
            Some(c) => c.capacity += 1,
            None => classes.push(crate::paged::PageClass { stride: p.stride, capacity: 1 }),
        }
    }
    let mut r = TerrainRenderer::new_paged_classes(
        ctx,
        *paged.layout(),
        &classes,
        [lo, hi],
        &config(size.0, size.1),
    )
    .unwrap();
    for (&page, p) in paged.pages() {
        r.set_page_lattice(page, &p.samples, p.stride).unwrap();
    }
    r
}

/// `paged` with every page expanded to full resolution (stride 1).
fn expanded_pages(paged: &PagedHeights) -> PagedHeights {
    let mut out = PagedHeights::new(*paged.layout());
    for (&page, p) in paged.pages() {
        let samples = p.expanded(paged.layout());
        out.insert(page, crate::paged::Page { samples, stride: 1 }).unwrap();
    }
    out
}

/// `hm`'s pages of 32 cells, each stored as a coarse level of its own (levels 1 to 5 of a
/// 32-cell page, 5 being every sample): coarse-slot pages, the lattice at stride `32 / 2^L`
/// (checked against `paged::fill_from_level`).
fn mixed_level_pages(hm: &Heightmap) -> PagedHeights {
    let full = PagedHeights::from_heightmap(hm, 32);
    let layout = *full.layout();
    let mut out = PagedHeights::new(layout);
    let w = layout.page_samples()[0] as usize;
    for (&page, p) in full.pages() {
        let level = 1 + (page[0] + 2 * page[1]) % 5;
        let n = 1usize << level;
        let d = 32 / n;
        let mut grid = Vec::new();
        for b in 0..=n {
            for a in 0..=n {
                grid.push(p.samples[b * d * w + a * d]);
            }
        }
        let filled = crate::paged::fill_from_level(&grid, 32).unwrap();
        let coarse = crate::paged::Page { samples: grid, stride: d as u32 };
        assert_eq!(coarse.expanded(&layout), filled);
        out.insert(page, coarse).unwrap();
    }
    out
}

#[test]
fn paged_coarse_slots_draw_like_pages_filled_at_full_resolution() {
    let Some(ctx) = context(BackendChoice::Vulkan) else { return };
    let hm = default_terrain();
    let coarse = mixed_level_pages(&hm);
    assert!(coarse.pages().any(|(_, p)| p.stride > 1), "coarse slots are used");
    let filled = expanded_pages(&coarse);
    let mut a = paged_renderer(&ctx, &coarse, (64, 64));
    let mut b = paged_renderer(&ctx, &filled, (64, 64));
    assert!(a.page_classes().len() > 1);
    assert!(a.page_atlas_bytes() < b.page_atlas_bytes() / 2, "coarse slots are smaller");
    let patches = random_patches(&hm, 16, 1.0, 17.0, 9, true);
    let eye = dvec3(800.0, 600.0, f64::from(hm.max()) + 250.0);
    let ra = a.surface_read_back(eye, &patches).unwrap();
    let rb = b.surface_read_back(eye, &patches).unwrap();
    let anchor = TerrainRenderer::anchor_for(eye);
    let mut inside = 0;
    for (k, p) in ra.points.iter().enumerate() {
        let patch = &patches[p.patch_index as usize];
        let want = surface::vertex_position(&coarse, patch, p.uv) - anchor;
        // The shader's lattice interpolation is fill_from_level's, operation for operation,
        // away from page borders (a shared border sample comes from the finest page holding
        // it; the filled pages all claim stride 1).
        let g = surface::grid_coords(patch, p.uv);
        let off_border = |x: f32| (2.0..30.0).contains(&x.rem_euclid(32.0));
        if off_border(g.x) && off_border(g.y) {
            assert_eq!(ra.positions[k], rb.positions[k], "point {k}");
            assert_eq!(ra.normals[k], rb.normals[k], "point {k}");
            assert_eq!(want, surface::vertex_position(&filled, patch, p.uv) - anchor);
            inside += 1;
        }
        let got = ra.positions[k];
        let err = (DVec3::new(got[0].into(), got[1].into(), got[2].into()) - want).length();
        assert!(err <= 1e-3, "point {k}: gpu {got:?} cpu {want}");
    }
    assert!(inside * 2 > ra.points.len(), "{inside} of {} points compared", ra.points.len());
}

#[test]
fn paged_all_resident_matches_the_whole_heightmap() {
    let Some(ctx) = context(BackendChoice::Vulkan) else { return };
    let hm = default_terrain();
    let paged = PagedHeights::from_heightmap(&hm, 32);
    assert!(paged.pages().count() >= 16, "several pages");
    let mut whole = TerrainRenderer::new(&ctx, &hm, &config(160, 90)).unwrap();
    let mut pages = paged_renderer(&ctx, &paged, (160, 90));
    assert_eq!(pages.resident_pages().len(), paged.pages().count());
    // The golden view: byte-identical images.
    let camera = default_camera(&hm, 160, 90, 50.0);
    let patches = uniform_patches(&hm, 32, 16.0);
    whole.render(&camera, &patches, &RenderOptions::default()).unwrap();
    pages.render(&camera, &patches, &RenderOptions::default()).unwrap();
    let (a, b) = (whole.read_image().unwrap(), pages.read_image().unwrap());
    let differ = a.pixels.iter().zip(&b.pixels).filter(|(x, y)| x != y).count();
    println!("adapter {}: paged vs whole image, {differ} pixels differ", ctx.describe());
    assert!(a.pixels.iter().any(|&p| p != BACKGROUND));
    assert_eq!(differ, 0);
    // The shader's surface: bit-identical read-backs, equal to the CPU reference of the pages.
    let patches = random_patches(&hm, 16, 1.0, 17.0, 5, true);
    let eye = dvec3(900.0, 700.0, f64::from(hm.max()) + 250.0);
    let ra = whole.surface_read_back(eye, &patches).unwrap();
    let rb = pages.surface_read_back(eye, &patches).unwrap();
    assert_eq!(ra, rb);
    let anchor = TerrainRenderer::anchor_for(eye);
    for (k, p) in rb.points.iter().enumerate() {
        let patch = &patches[p.patch_index as usize];
        let want = surface::vertex_position(&paged, patch, p.uv);
        assert_eq!(want, surface::vertex_position(&hm, patch, p.uv));
        let got = rb.positions[k];
        let err =
            (DVec3::new(got[0].into(), got[1].into(), got[2].into()) - (want - anchor)).length();
        assert!(err <= 1e-3, "point {k}: {err} m");
    }
}

#[test]
fn paged_coarse_levels_match_the_reference_and_draw_no_cracks() {
    let Some(ctx) = context(BackendChoice::Vulkan) else { return };
    let hm = default_terrain();
    let mut paged = mixed_level_pages(&hm);
    let drawn = paged.to_heightmap(&hm);
    // Coarse levels change the surface (the test is not vacuous).
    let changed = (0..hm.height())
        .flat_map(|j| (0..hm.width()).map(move |i| (i, j)))
        .filter(|&(i, j)| drawn.get(i, j) != hm.get(i, j))
        .count();
    assert!(changed > hm.width() * hm.height() / 4, "{changed} samples changed");
    // Crack-free: patches that agree on shared edges, over pages of five different levels.
    let mut renderer = paged_renderer(&ctx, &paged, (256, 144));
    // Every other camera of the crack set: from straight down to grazing, all yaws.
    let cameras: Vec<_> = crack_cameras(&drawn, 33).into_iter().step_by(2).collect();
    let patches = random_patches(&hm, 16, 1.0, 17.0, 13, true);
    let relief = drawn.max() - drawn.min() + 10.0;
    let cracks = crack::crack_pixels_on(&mut renderer, &patches, &cameras, relief);
    println!("paged mixed levels: crack pixels {cracks:?} on {}", ctx.describe());
    assert!(cracks.iter().all(|&c| c == 0), "{cracks:?}");
    // One page gone: the shader's surface and normals still follow the CPU reference (border
    // samples from the neighbours, one-sided differences next to the hole).
    let hole = [2u32, 3u32];
    assert!(paged.remove(hole));
    assert!(renderer.remove_page(hole));
    let c = paged.layout().cells();
    let inside_hole = |p: &DrawPatch| {
        let [x0, y0, x1, y1] = p.rect;
        x1 > hole[0] * c[0]
            && x0 < (hole[0] + 1) * c[0]
            && y1 > hole[1] * c[1]
            && y0 < (hole[1] + 1) * c[1]
    };
    let patches: Vec<DrawPatch> = random_patches(&hm, 16, 1.0, 17.0, 21, true)
        .into_iter()
        .filter(|p| !inside_hole(p))
        .collect();
    let eye = dvec3(1100.0, 1300.0, f64::from(hm.max()) + 300.0);
    let anchor = TerrainRenderer::anchor_for(eye);
    let back = renderer.surface_read_back(eye, &patches).unwrap();
    let mut next_to_hole = 0;
    for (k, p) in back.points.iter().enumerate() {
        let patch = &patches[p.patch_index as usize];
        let want = surface::vertex_position(&paged, patch, p.uv) - anchor;
        let got = back.positions[k];
        let err = (DVec3::new(got[0].into(), got[1].into(), got[2].into()) - want).length();
        assert!(err <= 1e-3, "point {k} {p:?}: gpu {got:?} cpu {want}");
        let g = surface::grid_coords(patch, p.uv);
        let n = surface::normal_at(&paged, g);
        let dn = (glam::Vec3::new(back.normals[k][0], back.normals[k][1], back.normals[k][2]) - n)
            .length();
        assert!(dn <= 1e-4, "point {k} normal gpu {:?} cpu {n}", back.normals[k]);
        let (gi, gj) = (g.x.round() as u32, g.y.round() as u32);
        if paged.locate(gi.saturating_sub(1), gj).is_none()
            || paged.locate(gi + 1, gj).is_none()
            || paged.locate(gi, gj + 1).is_none()
            || paged.locate(gi, gj.saturating_sub(1)).is_none()
        {
            next_to_hole += 1;
        }
    }
    assert!(next_to_hole > 0, "some points lie next to the missing page");
}

#[test]
fn pages_are_checked() {
    let Some(ctx) = context(BackendChoice::Vulkan) else { return };
    let hm = default_terrain();
    let paged = PagedHeights::from_heightmap(&hm, 64);
    let layout = *paged.layout();
    let mut r = TerrainRenderer::new_paged(&ctx, layout, 2, [0.0, 1.0], &config(32, 32)).unwrap();
    let page = paged.get([0, 0]).unwrap().samples.clone();
    r.set_page([0, 0], &page).unwrap();
    r.set_page([1, 0], &page).unwrap();
    // Replacing a resident page takes no new slot; a third page does not fit.
    r.set_page([0, 0], &page).unwrap();
    let e = r.set_page([0, 1], &page).unwrap_err();
    assert!(matches!(e, crate::paged::PageError::Full { capacity: 2, .. }), "{e}");
    let e = r.set_page([99, 0], &page).unwrap_err();
    assert!(e.to_string().contains("outside"), "{e}");
    let e = r.set_page([0, 1], &page[1..]).unwrap_err();
    assert!(e.to_string().contains("samples"), "{e}");
    let mut bad = page.clone();
    bad[7] = f32::NAN;
    assert!(matches!(
        r.set_page([0, 0], &bad),
        Err(crate::paged::PageError::NotFinite { index: 7, .. })
    ));
    assert!(r.remove_page([1, 0]));
    assert!(!r.remove_page([1, 0]));
    r.set_page([0, 1], &page).unwrap();
    assert_eq!(r.resident_pages(), vec![[0, 0], [0, 1]]);

    // Slot classes: a page at stride 16 (a 5 x 5 lattice of a 64-cell page) takes a coarse
    // slot; moving it to full resolution frees that slot.
    use crate::paged::{PageClass, PageError};
    let classes = [PageClass { stride: 1, capacity: 1 }, PageClass { stride: 16, capacity: 1 }];
    let mut r =
        TerrainRenderer::new_paged_classes(&ctx, layout, &classes, [0.0, 1.0], &config(32, 32))
            .unwrap();
    assert_eq!(r.page_capacity(), 2);
    let lattice = vec![1.0f32; 25];
    r.set_page_lattice([1, 1], &lattice, 16).unwrap();
    let e = r.set_page_lattice([0, 1], &lattice, 16).unwrap_err();
    assert!(matches!(e, PageError::Full { capacity: 1, stride: 16, .. }), "{e}");
    let e = r.set_page_lattice([0, 1], &[1.0f32; 9], 32).unwrap_err();
    assert!(matches!(e, PageError::BadStride { stride: 32, .. }), "{e}");
    let e = r.set_page_lattice([0, 1], &lattice[1..], 16).unwrap_err();
    assert!(e.to_string().contains("samples"), "{e}");
    r.set_page([1, 1], &page).unwrap();
    r.set_page_lattice([0, 1], &lattice, 16).unwrap();
    assert_eq!(r.resident_pages(), vec![[0, 1], [1, 1]]);
    let bad = [PageClass { stride: 3, capacity: 1 }];
    assert!(
        TerrainRenderer::new_paged_classes(&ctx, layout, &bad, [0.0, 1.0], &config(8, 8)).is_err()
    );
}

/// The normal from 12 shared lookups (`surface::normal_at`, the shader's `normal_at`) is the
/// bilinear blend of four separate central-difference gradients of 5 lookups each (the
/// formulation it replaces, written out here as the reference), bit for bit: inside the grid,
/// on its last column and row, and next to a page that is not resident (one-sided
/// differences). The GPU side is checked against `surface::normal_at` by the surface tests.
#[test]
fn the_shared_stencil_normal_is_the_four_gradient_normal() {
    use crate::paged::HeightGrid;
    use glam::{Vec2, Vec3};
    fn gradient<G: HeightGrid + ?Sized>(hm: &G, i: u32, j: u32) -> Vec2 {
        let [w, h] = hm.size();
        let s = hm.frame().1.as_vec2();
        let at = |a: u32, b: u32| hm.sample(a, b).unwrap_or(0.0);
        let here = |a: u32, b: u32| hm.sample(a, b).is_some();
        let il = if i > 0 && here(i - 1, j) { i - 1 } else { i };
        let ir = if i + 1 < w && here(i + 1, j) { i + 1 } else { i };
        let jd = if j > 0 && here(i, j - 1) { j - 1 } else { j };
        let ju = if j + 1 < h && here(i, j + 1) { j + 1 } else { j };
        Vec2::new(
            (at(ir, j) - at(il, j)) / ((ir - il).max(1) as f32 * s.x),
            (at(i, ju) - at(i, jd)) / ((ju - jd).max(1) as f32 * s.y),
        )
    }
    fn four_gradients<G: HeightGrid + ?Sized>(hm: &G, g: Vec2) -> Vec3 {
        let [w, h] = hm.size();
        let g = g.clamp(Vec2::ZERO, Vec2::new((w - 1) as f32, (h - 1) as f32));
        let cell = g.floor();
        let f = g - cell;
        let (i0, j0) = (cell.x as u32, cell.y as u32);
        let (i1, j1) = ((i0 + 1).min(w - 1), (j0 + 1).min(h - 1));
        let a = gradient(hm, i0, j0) + (gradient(hm, i1, j0) - gradient(hm, i0, j0)) * f.x;
        let b = gradient(hm, i0, j1) + (gradient(hm, i1, j1) - gradient(hm, i0, j1)) * f.x;
        let grad = a + (b - a) * f.y;
        Vec3::new(-grad.x, -grad.y, 1.0).normalize()
    }
    let hm = default_terrain();
    let mut paged = mixed_level_pages(&hm);
    assert!(paged.remove([2, 3]));
    let (w, h) = (hm.width() as f32, hm.height() as f32);
    let mut points = vec![Vec2::new(w - 1.0, h - 1.0), Vec2::new(0.0, 0.0)];
    for k in 0..4000u32 {
        // A scattered walk over the grid, with whole and fractional coordinates.
        let x = ((k * 37) % hm.width() as u32) as f32 + [0.0, 0.25, 0.5, 0.999][(k % 4) as usize];
        let y = ((k * 53) % hm.height() as u32) as f32 + [0.0, 0.7, 0.1, 0.5][(k % 3) as usize];
        points.push(Vec2::new(x.min(w - 1.0), y.min(h - 1.0)));
        points.push(Vec2::new(w - 1.0, y.min(h - 1.0)));
        points.push(Vec2::new(x.min(w - 1.0), h - 1.0));
    }
    // Around the page taken out (cells 64-96 x 96-128).
    for y in (90..134).step_by(3) {
        for x in (58..102).step_by(3) {
            points.push(Vec2::new(x as f32 + 0.3, y as f32 + 0.6));
        }
    }
    let mut one_sided = 0;
    for g in &points {
        assert_eq!(surface::normal_at(&hm, *g), four_gradients(&hm, *g), "whole grid at {g}");
        assert_eq!(surface::normal_at(&paged, *g), four_gradients(&paged, *g), "pages at {g}");
        let east = g.x as u32 + 1;
        one_sided += usize::from(east + 1 < w as u32 && paged.sample(east, g.y as u32).is_none());
    }
    assert!(one_sided > 10, "{one_sided} points next to the hole: the test reaches it");
}
