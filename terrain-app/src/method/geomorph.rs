//! The geomorphing article's (Wagner 2003) method drawn with its vertex-shader morph: the
//! geo-mipmapped patches with levels and tween factors for terrain-gpu's `GeomorphRenderer`,
//! measured through the morph's CPU reference, and the popping it removes (the per-vertex jump
//! between consecutive cameras, with tweening and without).

use std::time::Instant;

use terrain_core::geometry::Camera;
use terrain_gpu::geomorph::max_vertex_jump;

use super::memory::ms;
use super::{Draw, DrawSource, DrawnSurface, Frame, Method, MethodStats};
use crate::methods::{LodMethod, MethodScene};

/// `geomorph` with the morph renderer, over a [`MethodScene`] (its current config).
#[derive(Debug)]
pub struct GeomorphMethod<'a> {
    scene: &'a MethodScene,
}

impl<'a> GeomorphMethod<'a> {
    /// The method over `scene`.
    pub fn new(scene: &'a MethodScene) -> Self {
        Self { scene }
    }
}

impl Method for GeomorphMethod<'_> {
    fn kind(&self) -> LodMethod {
        LodMethod::Geomorph
    }

    fn frame(&mut self, camera: &Camera) -> Frame {
        let t = Instant::now();
        let lods = self.scene.select_geomorph(camera);
        let selection_ms = ms(t);
        // The leaves as a quadtree selection: the measurement's coverage.
        let selection = self.scene.geomorph_selection(&lods);
        Frame {
            stats: MethodStats {
                selection_ms,
                patches: lods.patches.len(),
                ..MethodStats::default()
            },
            selection,
            draw: Draw::Morph(lods),
            built: None,
        }
    }

    fn surface(&self, frame: &mut Frame) -> anyhow::Result<DrawnSurface> {
        let Draw::Morph(lods) = &frame.draw else {
            anyhow::bail!("a geomorph frame draws morphed patches");
        };
        let (mesh, triangles) = self.scene.geomorph_surface(lods);
        Ok(DrawnSurface { mesh, triangles })
    }

    /// The jump from `previous`'s surface (morphing), and the same with tweening off (integer
    /// levels): the popping geomorphing removes.
    fn vertex_jumps(
        &self,
        previous: &Camera,
        camera: &Camera,
        drawn: &DrawnSurface,
    ) -> Option<[f64; 2]> {
        let scene = self.scene;
        let (before, _) = scene.geomorph_surface(&scene.select_geomorph(previous));
        let morph = max_vertex_jump(&before, &drawn.mesh);
        drop(before);
        let mut off = scene.config.geomip;
        off.morph = false;
        off.patch_cells = scene.geomorph_patch_cells();
        let still = |c: &Camera| scene.geomorph_surface(&scene.geomip_scene().select(c, &off)).0;
        Some([morph, max_vertex_jump(&still(previous), &still(camera))])
    }

    fn draws_on(&self) -> DrawSource<'_> {
        DrawSource::Geomorph(&self.scene.hm, self.scene.geomorph_patch_cells())
    }
}
