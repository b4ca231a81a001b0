//! The entropy paper's (Chen 2018) method: a per-frame Eq. 5 cut of the full entropy quadtree,
//! cracks removed and tiles triangulated ([`crate::entropy_method`]): a triangle mesh, not
//! patches. It is measured on the CPU as built and drawn as the tessellation renderer's extra
//! triangles on one carrier patch ([`entropy_extra`]).

use std::time::Instant;

use terrain_core::Heightmap;
use terrain_core::geometry::Camera;
use terrain_core::lod::SurfaceMesh;
use terrain_gpu::render::{DrawPatch, ExtraTriangles};
use terrain_gpu::tess::GpuDomainPoint;

use super::memory::ms;
use super::{Draw, DrawSource, DrawnSurface, Frame, Method, MethodStats};
use crate::entropy_method::whole_terrain_selection;
use crate::methods::{LodMethod, MethodScene};

/// `entropy` over a [`MethodScene`] (its current config).
#[derive(Debug)]
pub struct EntropyMethod<'a> {
    scene: &'a MethodScene,
}

impl<'a> EntropyMethod<'a> {
    /// The method over `scene`.
    pub fn new(scene: &'a MethodScene) -> Self {
        Self { scene }
    }
}

impl Method for EntropyMethod<'_> {
    fn kind(&self) -> LodMethod {
        LodMethod::Entropy
    }

    /// The cut (Eq. 4-5) is the selection time; crack elimination and tile triangulation are
    /// the build time (the benchmark's tessellation time).
    fn frame(&mut self, camera: &Camera) -> Frame {
        let scene = self.scene;
        let f = scene.entropy_scene().frame(camera, &scene.config.entropy);
        let t = Instant::now();
        let (carrier, extra) = entropy_extra(&scene.hm, &f.surface);
        let convert_ms = ms(t);
        let triangles = f.surface.triangles.len() as u64;
        Frame {
            selection: whole_terrain_selection(f.tiles, f.cut_ms),
            draw: Draw::Tessellated { patches: vec![carrier], extra },
            stats: MethodStats {
                selection_ms: f.cut_ms,
                build_ms: f.crack_ms + f.triangulate_ms,
                convert_ms,
                patches: f.tiles,
                ..MethodStats::default()
            },
            built: Some((f.surface, triangles)),
        }
    }

    fn surface(&self, frame: &mut Frame) -> anyhow::Result<DrawnSurface> {
        frame.take_built("entropy")
    }

    fn draws_on(&self) -> DrawSource<'_> {
        DrawSource::Tessellation(&self.scene.hm)
    }
}

/// A triangle mesh in grid coordinates (the entropy and tin methods') as the renderer's extra
/// triangles: every vertex is a domain point of one carrier patch spanning the whole grid,
/// whose factors are 0 so that the tessellator emits nothing for it (a patch with an outer
/// factor `<= 0` is culled). The vertex stage maps `(u, v)` to `x0 + u (x1 - x0)`, so a vertex
/// at grid sample `i` lands within an f32 rounding of it, and samples the same heightmap.
pub fn entropy_extra(hm: &Heightmap, mesh: &SurfaceMesh) -> (DrawPatch, ExtraTriangles) {
    let (w, h) = ((hm.width() - 1).max(1) as f64, (hm.height() - 1).max(1) as f64);
    let carrier = DrawPatch {
        rect: [0, 0, w as u32, h as u32],
        factors: terrain_gpu::tess::PatchFactors::uniform(0.0),
    };
    let points = mesh
        .grid
        .iter()
        .map(|g| GpuDomainPoint {
            uv: [(g.x / w) as f32, (g.y / h) as f32],
            patch_index: 0,
            pad: 0,
        })
        .collect();
    let indices = mesh.triangles.iter().flatten().copied().collect();
    (carrier, ExtraTriangles { points, indices, heights: Vec::new() })
}
