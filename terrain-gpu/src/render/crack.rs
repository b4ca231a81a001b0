//! The crack check shared by the renderer's tests and the integration tests of every LOD
//! method: render a patch list from many cameras with and without skirts and count the pixels
//! where background shows through the surface.
//!
//! Why the reference is not a full-resolution render: a coarse tessellation has a different
//! silhouette from the full-resolution surface (a ridge drawn with fewer vertices is lower),
//! so background legitimately appears above coarse ridges where the full-resolution reference
//! shows terrain; no erosion by a fixed number of pixels separates that from a crack. The
//! reference is instead the *same* tessellation plus skirts hanging below every shared patch
//! edge (`RenderOptions::skirt_depth_m`). With every camera above the surface and inside the
//! grid's footprint, a ray reaching a point below the surface crosses the (crack-free) surface
//! first, so skirts are hidden everywhere except through cracks: a pixel that is background in
//! the plain render but terrain in the skirted one is a crack, and the comparison is exact
//! (both renders rasterise the identical surface triangles; no erosion). Set
//! `TERRAIN_TEST_DUMP` to a folder to get both images of every camera as PPMs. Test support:
//! these functions panic on GPU errors.

use std::path::PathBuf;

use terrain_core::Heightmap;
use terrain_core::geometry::Camera;

use super::{
    BACKGROUND, DrawPatch, ExtraTriangles, RenderConfig, RenderOptions, TerrainRenderer, clip_range,
};
use crate::device::GpuContext;

/// At least 20 cameras over `hm`: inside the footprint, above every sample within
/// `margin_cells` of their position, pitches from straight down to grazing, all yaws.
pub fn crack_cameras(hm: &Heightmap, margin_cells: usize) -> Vec<Camera> {
    let pitches = [-90.0, -65.0, -40.0, -20.0, -8.0, -3.0, -1.5];
    // Small grids with high relief (the hard cases) would be out of view from high up.
    let extent = hm.extent_m();
    let relief = f64::from(hm.max() - hm.min()).min(0.25 * extent.x.min(extent.y)).max(50.0);
    let centre = hm.grid_to_world((hm.width() - 1) as f64 / 2.0, (hm.height() - 1) as f64 / 2.0);
    let (w, h) = (hm.width(), hm.height());
    (0..21)
        .map(|k| {
            let kf = k as f64;
            let fx = 0.1 + 0.8 * (kf * 0.618_034).fract();
            let fy = 0.1 + 0.8 * (kf * 0.381_966 + 0.3).fract();
            let (i, j) = ((fx * (w - 1) as f64) as usize, (fy * (h - 1) as f64) as usize);
            let mut ground = f32::MIN;
            for jj in j.saturating_sub(margin_cells)..=(j + margin_cells).min(h - 1) {
                for ii in i.saturating_sub(margin_cells)..=(i + margin_cells).min(w - 1) {
                    ground = ground.max(hm.get(ii, jj));
                }
            }
            let pitch = pitches[k % pitches.len()];
            // Grazing views stay low, or they see nothing but sky.
            let scale: f64 = [0.02, 0.1, 0.35, 1.2][k % 4];
            let above = if pitch > -10.0 { scale.min(0.1) } else { scale } * relief + 5.0;
            let xy = hm.grid_to_world(i as f64, j as f64);
            let eye = xy.extend(f64::from(ground) + above);
            let (near, far) = clip_range(hm, eye);
            // Roughly towards the centre (compass heading), give or take 60 degrees.
            let to_centre = centre - xy;
            let yaw = to_centre.x.atan2(to_centre.y).to_degrees() + (kf * 47.0) % 120.0 - 60.0;
            Camera::from_yaw_pitch(eye, yaw, pitch).with_fov_y_deg(60.0).with_clip(near, far)
        })
        .collect()
}

/// Renders `patches` from every camera with and without skirts; returns the number of crack
/// pixels (background without skirts, terrain with them) per camera.
pub fn crack_pixels(
    ctx: &GpuContext,
    hm: &Heightmap,
    patches: &[DrawPatch],
    cameras: &[Camera],
    size: (u32, u32),
) -> Vec<usize> {
    let empty = ExtraTriangles::default();
    let frames: Vec<_> = cameras.iter().map(|c| (*c, patches, &empty)).collect();
    crack_pixels_with_extra(ctx, hm, &frames, size)
}

/// Like [`crack_pixels`], one frame per camera with its own patches and extra triangles
/// (the DSS paper's stitching strips): skirts hang below the patches' edges only, so a gap
/// between a patch and the extra triangles shows as a crack.
pub fn crack_pixels_with_extra(
    ctx: &GpuContext,
    hm: &Heightmap,
    frames: &[(Camera, &[DrawPatch], &ExtraTriangles)],
    (width, height): (u32, u32),
) -> Vec<usize> {
    let config = RenderConfig { width, height, ..RenderConfig::default() };
    let mut renderer =
        TerrainRenderer::new(ctx, hm, &config).expect("a renderer for the crack test");
    crack_frames_on(&mut renderer, frames, hm.max() - hm.min() + 10.0)
}

/// [`crack_pixels`] with a renderer the caller built (a paged one, say) and a skirt depth
/// (metres) larger than the relief it draws.
pub fn crack_pixels_on(
    renderer: &mut TerrainRenderer,
    patches: &[DrawPatch],
    cameras: &[Camera],
    skirt_depth_m: f32,
) -> Vec<usize> {
    let empty = ExtraTriangles::default();
    let frames: Vec<_> = cameras.iter().map(|c| (*c, patches, &empty)).collect();
    crack_frames_on(renderer, &frames, skirt_depth_m)
}

/// The crack count of every frame on `renderer`, with skirts of `skirt_depth_m` metres.
fn crack_frames_on(
    renderer: &mut TerrainRenderer,
    frames: &[(Camera, &[DrawPatch], &ExtraTriangles)],
    skirt_depth_m: f32,
) -> Vec<usize> {
    let skirt = RenderOptions { skirt_depth_m, ..Default::default() };
    frames
        .iter()
        .map(|(camera, patches, extra)| {
            renderer.render_with_extra(camera, patches, extra, &RenderOptions::default()).unwrap();
            let plain = renderer.read_image().unwrap();
            renderer.render_with_extra(camera, patches, extra, &skirt).unwrap();
            let reference = renderer.read_image().unwrap();
            if let Some(dir) = std::env::var_os("TERRAIN_TEST_DUMP") {
                for (tag, im) in [("plain", &plain), ("skirts", &reference)] {
                    let path = PathBuf::from(&dir).join(format!("{}_{tag}.ppm", camera.position));
                    // Binary PPM: no image codec needed in this crate.
                    let mut ppm = format!("P6\n{} {}\n255\n", im.width, im.height).into_bytes();
                    ppm.extend(im.pixels.iter().flat_map(|p| [p[0], p[1], p[2]]));
                    std::fs::write(path, ppm).expect("TERRAIN_TEST_DUMP is writable");
                }
            }
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
