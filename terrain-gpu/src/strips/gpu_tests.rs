//! Stitching strips on the GPU (lavapipe here): the vertex stage puts every strip vertex
//! exactly (bit for bit) where it puts the block's own tessellated vertex, within 1 mm of the
//! CPU reference; and blocks plus strips draw no crack, while blocks alone do. Skips with a
//! printed reason where no adapter exists, unless `TERRAIN_REQUIRE_GPU` is set.

use std::collections::HashMap;

use glam::DVec3;
use terrain_core::geometry::Camera;
use terrain_core::lod::{DssConfig, DssErrorTable, DssStripsConfig, select_dss_strips};
use terrain_core::quadtree::Quadtree;
use terrain_core::synth::FractalConfig;

use super::*;
use crate::device::BackendChoice;
use crate::render::crack::{crack_cameras, crack_pixels_with_extra};
use crate::render::{RenderConfig, TerrainRenderer};
use crate::surface;
use crate::test_support::context;

fn scene() -> (terrain_core::Heightmap, Quadtree, DssErrorTable) {
    let hm = FractalConfig::with_size(129, 129, 10.0).to_heightmap().unwrap();
    let qt = Quadtree::new(&hm, 4);
    let table = DssErrorTable::new(&hm, &qt);
    (hm, qt, table)
}

fn config(rho_thr: f64) -> DssStripsConfig {
    DssStripsConfig {
        dss: DssConfig { leaf_cells: 4, rho_thr, ..DssConfig::default() },
        ..DssStripsConfig::default()
    }
}

#[test]
fn strip_vertices_land_on_the_block_vertices_on_the_gpu() {
    let Some(ctx) = context(BackendChoice::Vulkan) else { return };
    let (hm, qt, table) = scene();
    let eye = hm.grid_to_world(20.3, 30.7).extend(f64::from(hm.max()) + 40.0);
    let camera = Camera::from_yaw_pitch(eye, 40.0, -30.0).with_viewport(1280.0, 720.0);
    let frame = select_dss_strips(&qt, &camera, &table, &config(0.5));
    assert!(!frame.strips.is_empty() && !frame.pblocks.is_empty());
    let patches = draw_patches(&frame);
    let strips = build_strips(&frame);
    let config = RenderConfig { width: 64, height: 64, ..RenderConfig::default() };
    let mut renderer = TerrainRenderer::new(&ctx, &hm, &config).unwrap();
    let tess = renderer.surface_read_back(eye, &patches).unwrap();
    let by_point: HashMap<(u32, u32, u32), [f32; 4]> = tess
        .points
        .iter()
        .zip(&tess.positions)
        .map(|(p, &x)| ((p.patch_index, p.uv[0].to_bits(), p.uv[1].to_bits()), x))
        .collect();
    let extra = &strips.triangles.points;
    let got = renderer.points_read_back(eye, &patches, extra).unwrap();
    let anchor = TerrainRenderer::anchor_for(eye);
    let mut matched = 0;
    for (p, g) in extra.iter().zip(&got) {
        let want = surface::vertex_position(&hm, &patches[p.patch_index as usize], p.uv) - anchor;
        let gv = DVec3::new(g[0].into(), g[1].into(), g[2].into());
        assert!((gv - want).length() <= 1e-3, "{p:?}: gpu {gv} cpu {want}");
        // Visible blocks' edge points are tessellated too: the same bits.
        if let Some(t) = by_point.get(&(p.patch_index, p.uv[0].to_bits(), p.uv[1].to_bits())) {
            assert_eq!(t.map(f32::to_bits), g.map(f32::to_bits), "{p:?}");
            matched += 1;
        }
    }
    assert!(matched > extra.len() / 2, "{matched} of {}", extra.len());
}

#[test]
fn blocks_and_strips_draw_no_crack_and_blocks_alone_do() {
    let Some(ctx) = context(BackendChoice::Vulkan) else { return };
    let (hm, qt, table) = scene();
    let cameras: Vec<Camera> = crack_cameras(&hm, 5)
        .into_iter()
        .step_by(3)
        .map(|c| c.with_viewport(1280.0, 720.0))
        .collect();
    let frames: Vec<_> = cameras
        .iter()
        .map(|c| {
            let f = select_dss_strips(&qt, c, &table, &config(1.0));
            (draw_patches(&f), build_strips(&f).triangles)
        })
        .collect();
    let with: Vec<_> = cameras.iter().zip(&frames).map(|(c, (p, s))| (*c, &p[..], s)).collect();
    let cracks = crack_pixels_with_extra(&ctx, &hm, &with, (128, 72));
    assert!(cracks.iter().all(|&c| c == 0), "cracks per camera: {cracks:?}");
    let empty = ExtraTriangles::default();
    let without: Vec<_> =
        cameras.iter().zip(&frames).map(|(c, (p, _))| (*c, &p[..], &empty)).collect();
    let gaps: usize = crack_pixels_with_extra(&ctx, &hm, &without, (128, 72)).iter().sum();
    assert!(gaps > 0, "the gaps between shrunk blocks must show without strips");
}
