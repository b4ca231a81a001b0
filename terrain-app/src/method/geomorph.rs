//! The geomorphing article's (Wagner 2003) method drawn with its vertex-shader morph: the
//! geo-mipmapped patches with levels and tween factors for terrain-gpu's `GeomorphRenderer`,
//! measured through the morph's CPU reference, and the popping it removes (the per-vertex jump
//! between consecutive cameras, with tweening and without). The article's Table 1 compares
//! three paths over the same patches ([`MorphPath`]): the vertex-shader morph (`geomorph`),
//! no morph (`geomorph-static`) and the morph computed on the CPU and uploaded every frame
//! (`geomorph-cpu`).
//!
//! The frame hands the renderer geomorph's compact selection (`GeomipRuns`: runs of patches at
//! the coarsest level and single patches), drawn without expanding the runs; the measurement
//! expands them (`Method::surface`), as do geomorph-pvs (it culls patch by patch) and
//! geomorph-cpu (it morphs every vertex on the CPU), as the frame's conversion.

use std::time::Instant;

use terrain_core::geometry::Camera;
use terrain_core::lod::{GeomipRuns, GeomipSelection};
use terrain_gpu::geomorph::{GpuMorphPatch, MorphGrid, max_vertex_jump};

use super::memory::ms;
use super::{Draw, DrawSource, DrawnSurface, Frame, Method, MethodStats, MorphHeights};
use crate::methods::{LodMethod, MethodScene};

/// Which of the article's Table 1 paths draws the geo-mipmapped patches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MorphPath {
    /// Morphed in the vertex shader ("hardware morphing"): `geomorph`.
    Shader,
    /// Tweening off, true heights ("static LOD"): `geomorph-static`.
    Static,
    /// Morphed on the CPU every frame and uploaded ("software morphing"): `geomorph-cpu`.
    Cpu,
}

/// A per-patch selection as a compact one without runs (every patch single).
fn singles(lods: GeomipSelection, coarsest: u8) -> GeomipRuns {
    GeomipRuns {
        runs: Vec::new(),
        patches: lods.patches,
        factors: lods.factors,
        coarsest,
        culled: lods.culled,
        cpu_ms: lods.cpu_ms,
    }
}

/// `geomorph` (and its Table 1 variants, and `geomorph-pvs`) with the morph renderer, over a
/// [`MethodScene`] (its current config).
#[derive(Debug)]
pub struct GeomorphMethod<'a> {
    scene: &'a MethodScene,
    path: MorphPath,
    /// `geomorph-pvs`: the patches the conservative PVS proves hidden are not drawn
    /// ([`MethodScene::cull_geomorph_pvs`]).
    pvs: bool,
}

impl<'a> GeomorphMethod<'a> {
    /// The method over `scene`, drawn by `path`.
    pub fn new(scene: &'a MethodScene, path: MorphPath) -> Self {
        Self { scene, path, pvs: false }
    }

    /// `geomorph-pvs`: the vertex-shader morph over the patches the PVS leaves.
    pub fn with_pvs(scene: &'a MethodScene) -> Self {
        Self { scene, path: MorphPath::Shader, pvs: true }
    }

    /// The levels and tween factors this method draws from `camera`.
    fn select(&self, camera: &Camera, morph: bool) -> GeomipSelection {
        let mut lods = self.scene.select_geomorph_with(camera, morph);
        if self.pvs {
            self.scene.cull_geomorph_pvs(&mut lods, camera);
        }
        lods
    }
}

impl Method for GeomorphMethod<'_> {
    fn kind(&self) -> LodMethod {
        match self.path {
            MorphPath::Shader if self.pvs => LodMethod::GeomorphPvs,
            MorphPath::Shader => LodMethod::Geomorph,
            MorphPath::Static => LodMethod::GeomorphStatic,
            MorphPath::Cpu => LodMethod::GeomorphCpu,
        }
    }

    fn frame(&mut self, camera: &Camera) -> Frame {
        let t = Instant::now();
        let morph = self.path != MorphPath::Static && self.scene.config.geomip.morph;
        // The selection is compact (runs of coarsest patches, the others one by one) and the
        // renderer draws it so (`GeomorphRenderer::render_runs`): nothing is expanded for
        // `geomorph` and `geomorph-static`. geomorph-pvs culls patch by patch within its
        // selection, as before, and geomorph-cpu morphs every vertex of every patch on the
        // CPU: both expand the runs, as the frame's conversion (`convert_ms`).
        let mut runs = self.scene.select_geomorph_runs(camera, morph);
        let mut selection_ms = ms(t);
        let mut convert_ms = 0.0;
        if self.pvs {
            let t = Instant::now();
            let mut lods = runs.expand();
            convert_ms = ms(t);
            let t = Instant::now();
            self.scene.cull_geomorph_pvs(&mut lods, camera);
            runs = singles(lods, runs.coarsest);
            selection_ms += ms(t);
        }
        // Software morphing: every vertex of every patch morphed on the CPU (the shader's
        // tested reference), the frame's build stage; the renderer uploads the result.
        let (heights, build_ms) = match self.path {
            MorphPath::Shader => (MorphHeights::Shader, 0.0),
            MorphPath::Static => (MorphHeights::Static, 0.0),
            MorphPath::Cpu => {
                let t = Instant::now();
                runs = singles(runs.expand(), runs.coarsest);
                convert_ms += ms(t);
                let t = Instant::now();
                let n = self.scene.geomorph_patch_cells();
                let grid = MorphGrid::new(&self.scene.hm, n);
                let patches: Vec<GpuMorphPatch> =
                    runs.patches.iter().map(|p| GpuMorphPatch::from_lod(p, n)).collect();
                let mut h = Vec::new();
                grid.patch_heights(&patches, &mut h);
                (MorphHeights::Cpu(h), ms(t))
            }
        };
        // The leaves as a quadtree selection: the measurement's coverage (per patch, untimed
        // as before).
        let selection = self.scene.geomorph_selection_runs(&runs);
        Frame {
            stats: MethodStats {
                selection_ms,
                build_ms,
                convert_ms,
                patches: runs.drawn_patches() as usize,
                ..MethodStats::default()
            },
            selection,
            draw: Draw::Morph(runs, heights),
            built: None,
        }
    }

    /// The morph's CPU reference over the frame's patches: the true heights where the tween
    /// factors are 0 (`geomorph-static`), the CPU-morphed heights `geomorph-cpu` uploads.
    fn surface(&self, frame: &mut Frame) -> anyhow::Result<DrawnSurface> {
        let Draw::Morph(runs, _) = &frame.draw else {
            anyhow::bail!("a geomorph frame draws morphed patches");
        };
        // The measurement takes the patches one by one: the runs expanded here (row-major, as
        // the selection's own expansion), outside the frame's selection.
        let (mesh, triangles) = self.scene.geomorph_surface(&runs.expand());
        Ok(DrawnSurface { mesh, triangles })
    }

    /// The jump from `previous`'s surface (morphing), and the same with tweening off (integer
    /// levels): the popping geomorphing removes. `None` for `geomorph-static`, which does not
    /// morph.
    fn vertex_jumps(
        &self,
        previous: &Camera,
        camera: &Camera,
        drawn: &DrawnSurface,
    ) -> Option<[f64; 2]> {
        if self.path == MorphPath::Static {
            return None;
        }
        let scene = self.scene;
        let (before, _) = scene.geomorph_surface(&self.select(previous, scene.config.geomip.morph));
        let morph = max_vertex_jump(&before, &drawn.mesh);
        drop(before);
        let mut off = scene.config.geomip;
        off.morph = false;
        off.patch_cells = scene.geomorph_patch_cells();
        let still = |c: &Camera| {
            let mut lods = scene.geomip_scene().select(c, &off);
            if self.pvs {
                scene.cull_geomorph_pvs(&mut lods, c);
            }
            scene.geomorph_surface(&lods).0
        };
        Some([morph, max_vertex_jump(&still(previous), &still(camera))])
    }

    fn draws_on(&self) -> DrawSource<'_> {
        DrawSource::Geomorph(&self.scene.hm, self.scene.geomorph_patch_cells())
    }
}
