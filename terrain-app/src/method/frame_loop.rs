//! The one frame loop: a [`Method`]'s frame from a camera, optionally measured (its drawn
//! surface rebuilt on the CPU and compared with the full DEM by terrain-core's [`Measurer`])
//! and optionally drawn by a [`FrameRenderer`], recorded as one [`FrameRecord`]. `render`,
//! `fly` and `bench` all drive their frames through [`FrameLoop::frame`].

use std::time::{Duration, Instant};

use terrain_core::Heightmap;
use terrain_core::geometry::Camera;
use terrain_core::measure::{FrameErrors, MeasureConfig, Measurer};
use terrain_core::quadtree::Quadtree;
use terrain_gpu::RenderOptions;

use super::memory::ms;
use super::renderer::Uploads;
use super::{BlockStats, DrawStats, FrameRenderer, Method, MethodStats};
use crate::bench::{FrameRecord, rss_bytes};

/// Frames of one method instance: measured when given a reference DEM, drawn when given a
/// renderer.
#[derive(Debug)]
pub struct FrameLoop<'a> {
    method: Box<dyn Method + 'a>,
    measurer: Option<Measurer<'a>>,
    renderer: Option<Slot<'a>>,
    options: RenderOptions,
    uploads: Uploads,
    /// Whether a frame's measuring and drawing hold the method's I/O ([`FrameLoop::holding_io`]).
    hold_io: bool,
}

/// The loop's renderer: borrowed (`render`, `fly`, `bench` share renderers between loops) or
/// owned (a loop that lives as long as its method: `terrain view` over a store).
#[derive(Debug)]
enum Slot<'a> {
    Borrowed(&'a mut FrameRenderer),
    Owned(Box<FrameRenderer>),
}

impl Slot<'_> {
    fn get(&mut self) -> &mut FrameRenderer {
        match self {
            Slot::Borrowed(r) => r,
            Slot::Owned(r) => r,
        }
    }
}

/// One frame through the loop.
#[derive(Debug, Clone)]
pub struct LoopFrame {
    /// The frame's record: what was selected and drawn, its stage times, its errors when
    /// measured (default errors otherwise), streaming figures where there are any.
    pub record: FrameRecord,
    /// What the renderer drew and what it cost, when a renderer was given.
    pub drawn: Option<DrawStats>,
    /// Block figures of store-backed methods.
    pub blocks: Option<BlockStats>,
    /// How long the method's I/O was held after the selection (measuring and drawing, with
    /// [`FrameLoop::holding_io`]); zero otherwise.
    pub held: Duration,
}

impl<'a> FrameLoop<'a> {
    /// A loop over `method`'s frames, neither measured nor drawn yet.
    pub fn new(method: Box<dyn Method + 'a>) -> Self {
        Self {
            method,
            measurer: None,
            renderer: None,
            options: RenderOptions::default(),
            uploads: Uploads::default(),
            hold_io: false,
        }
    }

    /// With `hold`, every [`FrameLoop::frame`] holds the method's I/O from the end of its
    /// selection until its measuring and drawing are done ([`Method::hold_io`]): a real-time
    /// flight's measured frames then give a store's workers no more time than a played frame,
    /// so what arrives late is the flight's, not the benchmark's.
    pub fn holding_io(mut self, hold: bool) -> Self {
        self.hold_io = hold;
        self
    }

    /// Measures every frame against `hm` (the full DEM, quadtree `qt`) with `config`.
    pub fn measured(mut self, hm: &'a Heightmap, qt: &'a Quadtree, config: MeasureConfig) -> Self {
        self.measurer = Some(Measurer::new(hm, qt, config));
        self
    }

    /// Draws every frame with `renderer` (of the method's [`Method::renderer_kind`]) when given.
    pub fn rendered(mut self, renderer: Option<&'a mut FrameRenderer>) -> Self {
        self.renderer = renderer.map(Slot::Borrowed);
        self
    }

    /// Draws every frame with `renderer`, which the loop owns from now on.
    pub fn rendered_by(mut self, renderer: FrameRenderer) -> Self {
        self.renderer = Some(Slot::Owned(Box::new(renderer)));
        self
    }

    /// Continues the upload bookkeeping of an earlier loop over the same renderer (see
    /// [`Uploads`]).
    pub fn with_uploads(mut self, uploads: Uploads) -> Self {
        self.uploads = uploads;
        self
    }

    /// The upload bookkeeping so far, for [`FrameLoop::with_uploads`].
    pub fn uploads(&self) -> Uploads {
        self.uploads
    }

    /// Sets the render options (wireframe) of the next frames.
    pub fn set_options(&mut self, options: RenderOptions) {
        self.options = options;
    }

    /// Render options (wireframe) of the drawn frames.
    pub fn with_options(mut self, options: RenderOptions) -> Self {
        self.options = options;
        self
    }

    /// The method.
    pub fn method(&self) -> &dyn Method {
        self.method.as_ref()
    }

    /// The renderer, for reading the last frame back.
    pub fn renderer(&mut self) -> Option<&mut FrameRenderer> {
        self.renderer.as_mut().map(Slot::get)
    }

    /// Plays a frame that is neither measured nor drawn (a real-time flight's frames between
    /// measured ones): the method's state advances (a store's streaming runtime), and a paged
    /// renderer takes the frame's page changes so it stays in step with the runtime. Returns
    /// the frame's statistics.
    pub fn play(&mut self, camera: &Camera) -> anyhow::Result<MethodStats> {
        let frame = self.method.frame(camera);
        if let Some(renderer) = self.renderer.as_mut().map(Slot::get) {
            renderer.apply(&frame)?;
        }
        Ok(frame.stats)
    }

    /// Frame `index` seen from `camera`: select; when measuring, rebuild the drawn surface on
    /// the CPU (timed: the tessellation stage) and measure it (and, given the flight's
    /// `previous` camera, the method's per-vertex jumps from it); when rendering, draw it.
    pub fn frame(
        &mut self,
        index: usize,
        camera: &Camera,
        previous: Option<&Camera>,
    ) -> anyhow::Result<LoopFrame> {
        self.frame_drawn_from(index, camera, camera, previous)
    }

    /// [`FrameLoop::frame`] selected (and measured) from `camera` but drawn from `eye`: a
    /// frozen selection looked at from elsewhere (`terrain view`'s freeze).
    pub fn frame_drawn_from(
        &mut self,
        index: usize,
        camera: &Camera,
        eye: &Camera,
        previous: Option<&Camera>,
    ) -> anyhow::Result<LoopFrame> {
        let mut frame = self.method.frame(camera);
        let held_from = self.hold_io.then(|| {
            self.method.hold_io(true);
            Instant::now()
        });
        let result = self.measure_and_draw(index, camera, eye, previous, &mut frame);
        let held = held_from.map_or(Duration::ZERO, |t| {
            self.method.hold_io(false);
            t.elapsed()
        });
        let (record, drawn) = result?;
        Ok(LoopFrame { record, drawn, blocks: frame.stats.blocks, held })
    }

    /// The measuring and drawing of [`FrameLoop::frame_drawn_from`]'s selected `frame`.
    fn measure_and_draw(
        &mut self,
        index: usize,
        camera: &Camera,
        eye: &Camera,
        previous: Option<&Camera>,
        frame: &mut super::Frame,
    ) -> anyhow::Result<(FrameRecord, Option<DrawStats>)> {
        let stats = frame.stats.clone();
        let mut triangles = 0;
        let (mut cpu_tess_ms, mut measure_ms) = (stats.build_ms, 0.0);
        let mut errors = FrameErrors::default();
        let mut jumps = None;
        if let Some(measurer) = self.measurer.as_mut() {
            let t = Instant::now();
            let drawn = self.method.surface(frame)?;
            cpu_tess_ms += ms(t);
            triangles = drawn.triangles;
            let t = Instant::now();
            errors = measurer.measure(camera, &frame.selection, &drawn.mesh);
            measure_ms = ms(t);
            // Popping analysis (untimed).
            jumps = previous.and_then(|p| self.method.vertex_jumps(p, camera, &drawn));
        }
        let mut record = FrameRecord {
            vertex_jump_m: jumps.map(|j| j[0]),
            vertex_jump_no_morph_m: jumps.map(|j| j[1]),
            stream: stats.stream.clone(),
            missing_blocks: stats.blocks.map_or(0, |b| b.blocks_dropped),
            update_ms: stats.strip_stages_ms.map(|s| s[0]),
            strips_ms: stats.strip_stages_ms.map(|s| s[1]),
            ..FrameRecord::measured(
                index,
                stats.patches,
                triangles,
                [stats.selection_ms, cpu_tess_ms, measure_ms],
                errors,
            )
        };
        let mut drawn = None;
        if let Some(renderer) = self.renderer.as_mut().map(Slot::get) {
            let s = renderer.draw(eye, frame, &self.options, &mut self.uploads)?;
            // The frame's CPU work before the renderer: selection, building what is drawn
            // (the entropy mesh) and converting it to the renderer's input.
            let before = stats.selection_ms + stats.build_ms + stats.convert_ms;
            record.encode_ms = Some(s.cpu_ms);
            record.render_ms = Some(s.wall_ms);
            record.gpu_ms = s.gpu_ms;
            record.gpu_draw_ms = s.gpu_draw_ms;
            record.gpu_tessellated = s.tessellated;
            record.upload_bytes = Some(s.upload_bytes);
            record.material_passes_skipped = s.passes_skipped;
            record.cpu_ms = before + s.cpu_ms;
            record.frame_ms = before + s.wall_ms;
            if self.measurer.is_none() {
                record.triangles = s.triangles;
            }
            drawn = Some(s);
        }
        record.rss_bytes = rss_bytes();
        Ok((record, drawn))
    }
}
