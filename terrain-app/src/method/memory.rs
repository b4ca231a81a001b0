//! The in-memory patch methods through [`MethodScene`]: `uniform`, `pvps-a/b/c`, `pvps-c-pvs`,
//! `pvps-c-cons`, `dss-1`, `dss-2`, `dss-strips` (its blocks and the strips built this frame,
//! drawn as extra triangles) and `geomorph` un-morphed (its leaves at their levels' factors):
//! tessellated patches for the tessellation renderer, measured through the tessellator's CPU
//! reference.

use std::time::Instant;

use terrain_core::geometry::Camera;
use terrain_gpu::render::ExtraTriangles;
use terrain_gpu::strips;

use super::{Draw, DrawSource, DrawnSurface, Frame, Method, MethodStats};
use crate::methods::{LodMethod, MethodScene};

/// A patch method over a [`MethodScene`] (its current config).
#[derive(Debug)]
pub struct MemoryMethod<'a> {
    scene: &'a MethodScene,
    kind: LodMethod,
}

impl<'a> MemoryMethod<'a> {
    /// `kind` over `scene`.
    pub fn new(scene: &'a MethodScene, kind: LodMethod) -> Self {
        Self { scene, kind }
    }
}

impl Method for MemoryMethod<'_> {
    fn kind(&self) -> LodMethod {
        self.kind
    }

    fn frame(&mut self, camera: &Camera) -> Frame {
        let scene = self.scene;
        let t = Instant::now();
        let drawn = scene.frame(self.kind, camera);
        let selection_ms = ms(t);
        let strip_stages_ms = drawn
            .strips
            .as_ref()
            .map(|s| [s.update.as_secs_f64() * 1e3, s.mesh.cpu_time.as_secs_f64() * 1e3]);
        let t = Instant::now();
        let (patches, extra) = match drawn.strips {
            None => (scene.draw_patches(&drawn.selection), ExtraTriangles::default()),
            Some(s) => (s.patches, s.mesh.triangles),
        };
        let convert_ms = ms(t);
        Frame {
            stats: MethodStats {
                selection_ms,
                convert_ms,
                patches: drawn.selection.patches.len(),
                strip_stages_ms,
                ..MethodStats::default()
            },
            selection: drawn.selection,
            draw: Draw::Tessellated { patches, extra },
            built: None,
        }
    }

    fn surface(&self, frame: &mut Frame) -> anyhow::Result<DrawnSurface> {
        let (mesh, triangles) = match &frame.draw {
            // Blocks plus strips: the strips join blocks that share no edge.
            Draw::Tessellated { patches, extra } if self.kind.has_strips() => {
                strips::build_strip_surface(&self.scene.hm, patches, extra)
            }
            _ => self.scene.drawn_surface(&frame.selection),
        };
        Ok(DrawnSurface { mesh, triangles })
    }

    fn draws_on(&self) -> DrawSource<'_> {
        DrawSource::Tessellation(&self.scene.hm)
    }
}

pub(super) fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
