//! One interface over every LOD method: [`Method`]. A method is prepared once per terrain (what
//! it precomputes lives in its [`MethodScene`] or, for the out-of-core method, its store and
//! streaming runtime); then, per frame, a camera goes in and a [`Frame`] comes out: what to
//! draw ([`Draw`]: tessellated patches with optional extra triangles, geo-mipmapped patches to
//! morph, or patches over paged heights with the page changes to apply, tessellated or
//! morphed), the patches that
//! cover it (for the measurement) and the frame's statistics ([`MethodStats`]: selection CPU
//! time, patches, streaming figures where there are any). [`Method::surface`] rebuilds on the
//! CPU exactly what the frame draws (the benchmark's measurement).
//!
//! The renderer-facing half is [`FrameRenderer`] (tessellation, geomorph or paged renderer;
//! the method says which it needs), and [`FrameLoop`] is the one frame loop that `render`,
//! `fly` and `bench` drive: method frame, optional measurement, optional draw, one
//! [`crate::bench::FrameRecord`].
//!
//! Stateful methods keep their state inside their implementation: the out-of-core method its
//! streaming runtime and pages ([`OocMethod`]), `dss-strips` its strips, geomorph the
//! previous camera's surface for popping. Everything a method needs to know about itself (its
//! swept parameter, its plot colour, how it is built) is in [`registry`], so the callers have no
//! per-method cases.

mod entropy;
mod frame_loop;
mod geomorph;
mod memory;
mod ooc;
pub mod registry;
mod renderer;
mod store;
mod tin;
mod tin_store;

use terrain_core::geometry::Camera;
use terrain_core::lod::{GeomipRuns, Selection, SurfaceMesh};
use terrain_gpu::render::{DrawPatch, ExtraTriangles};

pub use entropy::{EntropyMethod, entropy_extra};
pub use frame_loop::{FrameLoop, LoopFrame};
pub use geomorph::{GeomorphMethod, MorphPath};
pub use memory::MemoryMethod;
pub use ooc::{OocMethod, OocWait};
pub use registry::{MethodOptions, build};
pub use renderer::{DrawSource, DrawStats, FrameRenderer, RendererKind, Uploads};
pub use store::{StoreMethod, draws_from_store, store_method};
pub use tin::{
    GridTileBuilder, TinConfig, TinMethod, build_pyramid as build_tin_pyramid, tile_error_full,
    tin_selection,
};
pub use tin_store::{ResolvedTiles, TileCacheStats, TinStoreConfig, TinStoreMethod, TinTiles};

use crate::methods::LodMethod;
use crate::ooc::{OocFrame, StreamRecord};

/// What a frame draws, by the renderer that draws it.
#[derive(Debug, Clone)]
pub enum Draw {
    /// Tessellated patches and extra triangles (the DSS paper's strips, the entropy mesh; empty
    /// for the other methods), for the tessellation renderer over the whole heightmap.
    Tessellated {
        /// The patches with their factors.
        patches: Vec<DrawPatch>,
        /// Triangles between patch domain points, drawn in the same pass.
        extra: ExtraTriangles,
    },
    /// Geo-mipmapped patches with their levels and tween factors, compact (runs of coarsest
    /// patches and single patches, drawn without expanding the runs), for the geomorph
    /// renderer, and where the drawn heights come from (the geomorphing article's Table 1
    /// paths; `Cpu`'s heights are those of the single patches, in their order).
    Morph(GeomipRuns, MorphHeights),
    /// Patches over a store's paged heights, for the paged renderer: the runtime's frame (its
    /// patches and the page changes to apply first; its selection moved to
    /// [`Frame::selection`]).
    Paged(Box<OocFrame>),
    /// Geomorph over a store's paged heights: the runtime's frame (its page changes; its
    /// tessellated patches are not drawn) and the geo-mipmapped patches with their levels and
    /// tween factors, compact, for the geomorph renderer reading the paged renderer's pages.
    PagedMorph(Box<OocFrame>, GeomipRuns),
}

/// Where a [`Draw::Morph`] frame's heights come from (terrain-gpu's `MorphSource`).
#[derive(Debug, Clone, PartialEq)]
pub enum MorphHeights {
    /// Morphed in the vertex shader.
    Shader,
    /// True heights, no morph (tween factors 0).
    Static,
    /// Morphed on the CPU (`MorphGrid::patch_heights`), uploaded by the renderer.
    Cpu(Vec<f32>),
}

/// A store-backed method's block figures of one frame.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct BlockStats {
    /// Blocks drawn.
    pub blocks_drawn: usize,
    /// Blocks of the view not drawn (nothing resident, or no page slot left).
    pub blocks_dropped: usize,
    /// Pages uploaded this frame.
    pub pages_uploaded: usize,
}

/// What a frame cost and selected, as the method reports it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MethodStats {
    /// CPU time of the selection, ms.
    pub selection_ms: f64,
    /// CPU time of work every frame does after the selection to build what it draws (the
    /// entropy method's crack elimination and triangulation), ms; 0 for patch methods, whose
    /// tessellation is the renderer's (or, when measuring, the CPU reference's).
    pub build_ms: f64,
    /// CPU time to convert the frame into the renderer's input, ms (part of a rendered frame's
    /// CPU cost).
    pub convert_ms: f64,
    /// Patches selected (the entropy method: tiles of its cut).
    pub patches: usize,
    /// The stitching-strip methods from memory: the multilevel update's and the strips'
    /// construction's CPU times, ms (both inside `selection_ms`; the DSS paper's Fig. 20
    /// stages).
    pub strip_stages_ms: Option<[f64; 2]>,
    /// Streaming figures (store-backed methods).
    pub stream: Option<StreamRecord>,
    /// Block figures (store-backed methods).
    pub blocks: Option<BlockStats>,
}

/// One frame of a method: what to draw, what covers it, what it cost.
#[derive(Debug, Clone)]
pub struct Frame {
    /// The patches of the frame as quadtree nodes: what the measurement counts as covered
    /// (the entropy method: the root, it covers everything).
    pub selection: Selection,
    /// What the renderer draws.
    pub draw: Draw,
    /// The frame's statistics.
    pub stats: MethodStats,
    /// A surface the method built itself this frame (the entropy mesh) and its triangles;
    /// [`Method::surface`] hands it out instead of rebuilding it.
    pub(crate) built: Option<(SurfaceMesh, u64)>,
}

impl Frame {
    /// The surface the method built itself this frame ([`Frame::built`]), handed out once;
    /// `method` names the method in the error of a second call.
    pub(crate) fn take_built(&mut self, method: &str) -> anyhow::Result<DrawnSurface> {
        let (mesh, triangles) = self
            .built
            .take()
            .ok_or_else(|| anyhow::anyhow!("the {method} frame's mesh was already taken"))?;
        Ok(DrawnSurface { mesh, triangles })
    }
}

/// A frame's drawn surface rebuilt on the CPU (the same numbers as the GPU draws).
#[derive(Debug)]
pub struct DrawnSurface {
    /// The surface.
    pub mesh: SurfaceMesh,
    /// Its non-degenerate triangles, as the renderer counts them.
    pub triangles: u64,
}

/// A LOD method prepared for one terrain. Per frame: camera in, [`Frame`] out.
pub trait Method: std::fmt::Debug {
    /// Which method this is.
    fn kind(&self) -> LodMethod;

    /// The frame seen from `camera`: selection, what to draw, statistics.
    fn frame(&mut self, camera: &Camera) -> Frame;

    /// The surface `frame` draws, rebuilt on the CPU with the renderer's reference (the
    /// tessellator's, the morph's, the paged lookup's): what the benchmark measures.
    fn surface(&self, frame: &mut Frame) -> anyhow::Result<DrawnSurface>;

    /// The largest per-vertex height jump of the drawn surface from `previous` to `drawn`
    /// (seen from `camera`), with the method's smoothing and without it, metres: the popping a
    /// method removes (geomorph). `None` for methods without such smoothing.
    fn vertex_jumps(
        &self,
        _previous: &Camera,
        _camera: &Camera,
        _drawn: &DrawnSurface,
    ) -> Option<[f64; 2]> {
        None
    }

    /// Holds the I/O of a store-backed method's streaming runtime (`true`) or releases it
    /// ([`terrain_stream::Streamer::hold_io`]): what a real-time benchmark does while it
    /// measures and draws a frame off the flight's clock. Nothing for in-memory methods.
    fn hold_io(&mut self, _held: bool) {}

    /// What this method's frames are drawn over: the renderer they need and the terrain it
    /// reads (the one place a method says it; [`Method::renderer_kind`] and
    /// [`Method::renderer`] follow from it).
    fn draws_on(&self) -> DrawSource<'_>;

    /// The renderer kind this method's frames need.
    fn renderer_kind(&self) -> RendererKind {
        self.draws_on().kind()
    }

    /// A renderer for this method's frames (of [`Method::renderer_kind`]).
    fn renderer(
        &self,
        ctx: &terrain_gpu::GpuContext,
        config: &terrain_gpu::RenderConfig,
    ) -> anyhow::Result<FrameRenderer> {
        self.draws_on().renderer(ctx, config)
    }
}

#[cfg(test)]
mod tests {
    use terrain_core::measure::MeasureConfig;
    use terrain_core::synth::FractalConfig;
    use terrain_gpu::render::default_camera;

    use super::*;
    use crate::methods::{MethodConfig, MethodScene};

    fn scene() -> MethodScene {
        let hm = FractalConfig::with_size(129, 97, 10.0).to_heightmap().unwrap();
        MethodScene::new(hm, MethodConfig::default())
    }

    /// The loop records, for every in-memory method, the patches and the triangles of the
    /// method's own path (selection, surface rebuilt with the renderer's reference), measured.
    #[test]
    fn the_loop_records_each_methods_own_frame() {
        let scene = scene();
        let camera = default_camera(&scene.hm, 320, 180, 60.0);
        let kinds = [
            LodMethod::Uniform,
            LodMethod::PvpsA,
            LodMethod::PvpsB,
            LodMethod::PvpsC,
            LodMethod::Dss1,
            LodMethod::Dss2,
            LodMethod::DssStrips,
            LodMethod::Geomorph,
        ];
        scene.prepare(&kinds);
        for morph in [false, true] {
            for kind in kinds {
                let options = MethodOptions { morph, ..MethodOptions::default() };
                let method = build(kind, &scene, &options).unwrap();
                assert_eq!(method.kind(), kind);
                let mut frames = FrameLoop::new(method).measured(
                    &scene.hm,
                    &scene.qt,
                    MeasureConfig { max_samples: 20_000, ..MeasureConfig::default() },
                );
                let r = frames.frame(3, &camera, None).unwrap().record;
                let (patches, triangles) = if kind == LodMethod::Geomorph && morph {
                    let lods = scene.select_geomorph(&camera);
                    (lods.patches.len(), scene.geomorph_surface(&lods).1)
                } else {
                    let drawn = scene.frame(kind, &camera);
                    (drawn.selection.patches.len(), scene.frame_surface(&drawn).1)
                };
                assert_eq!(r.frame, 3);
                assert!(patches > 0 && triangles > 0, "{kind:?}");
                assert_eq!(
                    (r.patches, r.triangles),
                    (patches, triangles),
                    "{kind:?} morph {morph}"
                );
                assert!(r.errors.samples > 0, "{kind:?}: measured");
                assert!(r.selection_ms >= 0.0 && r.encode_ms.is_none());
                assert!(r.stream.is_none(), "{kind:?}: no store");
            }
        }
    }

    /// The entropy method through the loop: its cut's tiles and mesh, measured as built.
    #[test]
    fn the_loop_measures_the_entropy_mesh_as_built() {
        let scene = scene();
        let camera = default_camera(&scene.hm, 320, 180, 60.0);
        let own = scene.entropy_scene().frame(&camera, &scene.config.entropy);
        let method = build(LodMethod::Entropy, &scene, &MethodOptions::default()).unwrap();
        let mut frames = FrameLoop::new(method).measured(
            &scene.hm,
            &scene.qt,
            MeasureConfig { max_samples: 20_000, ..MeasureConfig::default() },
        );
        let r = frames.frame(0, &camera, None).unwrap().record;
        assert_eq!(r.patches, own.tiles);
        assert_eq!(r.triangles, own.surface.triangles.len() as u64);
        assert_eq!(r.errors.unlocated, 0, "every sample in view lies on the mesh");
    }

    /// Popping figures come from the method that smooths it (geomorph with its morph), given
    /// the flight's previous camera.
    #[test]
    fn vertex_jumps_only_where_the_method_smooths() {
        let scene = scene();
        let camera = default_camera(&scene.hm, 320, 180, 60.0);
        let mut previous = camera;
        previous.position += glam::DVec3::new(-40.0, -40.0, 5.0);
        let measure = MeasureConfig { max_samples: 20_000, ..MeasureConfig::default() };
        for (kind, morph, expect) in [
            (LodMethod::Geomorph, true, true),
            (LodMethod::Geomorph, false, false),
            (LodMethod::PvpsC, true, false),
        ] {
            let options = MethodOptions { morph, ..MethodOptions::default() };
            let method = build(kind, &scene, &options).unwrap();
            let mut frames = FrameLoop::new(method).measured(&scene.hm, &scene.qt, measure);
            let r = frames.frame(1, &camera, Some(&previous)).unwrap().record;
            assert_eq!(r.vertex_jump_m.is_some(), expect, "{kind:?} morph {morph}");
            assert_eq!(r.vertex_jump_no_morph_m.is_some(), expect);
            for jump in [r.vertex_jump_m, r.vertex_jump_no_morph_m].into_iter().flatten() {
                assert!(jump.is_finite() && jump >= 0.0, "{jump}");
            }
        }
    }

    /// A method that records the loop's `hold_io` calls around another.
    #[derive(Debug)]
    struct HoldRecorder<'a> {
        inner: Box<dyn Method + 'a>,
        calls: std::rc::Rc<std::cell::RefCell<Vec<bool>>>,
    }

    impl Method for HoldRecorder<'_> {
        fn kind(&self) -> LodMethod {
            self.inner.kind()
        }
        fn frame(&mut self, camera: &Camera) -> Frame {
            assert!(self.calls.borrow().last() != Some(&true), "selected while held");
            self.inner.frame(camera)
        }
        fn surface(&self, frame: &mut Frame) -> anyhow::Result<DrawnSurface> {
            assert_eq!(self.calls.borrow().last(), Some(&true), "measured while not held");
            self.inner.surface(frame)
        }
        fn draws_on(&self) -> DrawSource<'_> {
            self.inner.draws_on()
        }
        fn hold_io(&mut self, held: bool) {
            self.calls.borrow_mut().push(held);
        }
    }

    /// `holding_io`: the I/O is held after the selection, through the measuring, and released
    /// before the frame returns; played frames and loops without it never hold.
    #[test]
    fn a_holding_loop_holds_the_io_while_it_measures() {
        let scene = scene();
        let camera = default_camera(&scene.hm, 320, 180, 60.0);
        let measure = MeasureConfig { max_samples: 20_000, ..MeasureConfig::default() };
        for hold in [true, false] {
            let calls = std::rc::Rc::new(std::cell::RefCell::new(Vec::new()));
            let inner = build(LodMethod::PvpsC, &scene, &MethodOptions::default()).unwrap();
            let method = Box::new(HoldRecorder { inner, calls: calls.clone() });
            let mut frames = if hold {
                FrameLoop::new(method).measured(&scene.hm, &scene.qt, measure).holding_io(true)
            } else {
                // The negative control: the surface's assertion expects a hold, so measure
                // nothing and only check that no call is made.
                FrameLoop::new(method)
            };
            frames.play(&camera).unwrap();
            assert!(calls.borrow().is_empty(), "a played frame never holds");
            let f = frames.frame(0, &camera, None).unwrap();
            if hold {
                assert_eq!(*calls.borrow(), [true, false]);
                assert!(f.held > std::time::Duration::ZERO && f.record.errors.samples > 0);
            } else {
                assert!(calls.borrow().is_empty());
                assert_eq!(f.held, std::time::Duration::ZERO);
            }
        }
    }

    /// `ooc` needs a store; without one the registry says how to get one.
    #[test]
    fn ooc_without_a_store_says_how_to_bake_one() {
        let scene = scene();
        let e = build(LodMethod::OutOfCore, &scene, &MethodOptions::default()).unwrap_err();
        assert_eq!(e.to_string(), registry::OOC_NEEDS_STORE);
        assert!(registry::needs_store(LodMethod::OutOfCore));
        assert!(
            !LodMethod::ALL.iter().any(|&m| m != LodMethod::OutOfCore && registry::needs_store(m))
        );
    }
}
