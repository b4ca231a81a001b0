//! The out-of-core paper's (Qiu 2013) method over a baked store, as a [`Method`]: its state
//! (the streaming runtime and the pages, [`OocScene`], used through its public methods) lives
//! here; each frame hands the paged renderer the runtime's patches and page changes, and the
//! surface is rebuilt from the pages' heights (the CPU mirror of the paged renderer).

use terrain_core::geometry::Camera;

use super::{BlockStats, Draw, DrawSource, DrawnSurface, Frame, Method, MethodStats};
use crate::methods::{LodMethod, MethodScene, drawn_surface_of};
use crate::ooc::OocScene;

/// When an out-of-core frame waits for the workers until the levels it needs are resident.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OocWait {
    /// The first frame only (an image is not empty); later frames draw what is resident.
    FirstFrame,
    /// Every frame (measurements: the error is the selection's, not the stream's).
    EveryFrame,
}

impl OocWait {
    /// Whether the next frame, after `frames` frames, waits until warm; counts it.
    pub(super) fn next_is_warm(self, frames: &mut usize) -> bool {
        let warm = self == OocWait::EveryFrame || *frames == 0;
        *frames += 1;
        warm
    }
}

/// `ooc` over one store's runtime.
#[derive(Debug)]
pub struct OocMethod<'a> {
    scene: OocScene,
    /// The in-memory DEM the drawn surface is measured against (the benchmark's).
    reference: Option<&'a MethodScene>,
    wait: OocWait,
    frames: usize,
}

impl<'a> OocMethod<'a> {
    /// The method over `scene`, not measured.
    pub fn new(scene: OocScene, wait: OocWait) -> Self {
        Self { scene, reference: None, wait, frames: 0 }
    }

    /// The method over `scene` with its drawn surface measurable against `reference` (the same
    /// DEM in memory): keeps a CPU mirror of the pages unless every frame waits (see
    /// [`paged_surface`]). Fails when the store's blocks do not tile the reference's quadtree.
    pub fn measured(
        scene: OocScene,
        reference: &'a MethodScene,
        wait: OocWait,
    ) -> anyhow::Result<Self> {
        let scene = mirrored(scene, wait);
        if scene.root_cells() != reference.qt.root_cells() {
            anyhow::bail!(
                "the store's blocks ({} cells) do not tile the DEM's quadtree (root {} cells): bake with a smaller k",
                scene.store().header().block_cells(),
                reference.qt.root_cells()
            );
        }
        super::store::check_same_heights(scene.store(), &reference.hm)?;
        Ok(Self { scene, reference: Some(reference), wait, frames: 0 })
    }

    /// The runtime.
    pub fn scene(&self) -> &OocScene {
        &self.scene
    }
}

impl Method for OocMethod<'_> {
    fn kind(&self) -> LodMethod {
        LodMethod::OutOfCore
    }

    fn frame(&mut self, camera: &Camera) -> Frame {
        let warm = self.wait.next_is_warm(&mut self.frames);
        paged_frame(self.scene.frame(camera, warm))
    }

    /// The surface drawn from the pages' heights (the paged renderer's CPU reference).
    fn surface(&self, frame: &mut Frame) -> anyhow::Result<DrawnSurface> {
        paged_surface(&self.scene, self.reference, frame)
    }

    fn draws_on(&self) -> DrawSource<'_> {
        DrawSource::Paged(&self.scene)
    }

    fn hold_io(&mut self, held: bool) {
        self.scene.hold_io(held);
    }
}

/// A store's frame ([`OocScene::frame`] or [`OocScene::frame_for`]) as a [`Frame`] for the
/// paged renderer, with its selection, stream and block figures: one conversion for every
/// store-backed method.
pub(super) fn paged_frame(mut f: crate::ooc::OocFrame) -> Frame {
    let selection = std::mem::take(&mut f.selection);
    let stats = MethodStats {
        selection_ms: selection.stats.cpu_time.as_secs_f64() * 1e3,
        patches: selection.patches.len(),
        stream: Some(f.stream.clone()),
        blocks: Some(BlockStats {
            blocks_drawn: f.blocks_drawn,
            blocks_dropped: f.blocks_dropped,
            pages_uploaded: f.updates.iter().filter(|u| u.fill.is_some()).count(),
        }),
        ..MethodStats::default()
    };
    Frame { selection, draw: Draw::Paged(Box::new(f)), stats, built: None }
}

/// `scene` with a CPU mirror of its pages when frames may draw what is resident
/// ([`OocWait::FirstFrame`]); without one when every frame waits: a warm frame draws every
/// patch from pages of its level or finer, whose lattice samples are the DEM's up to the
/// store's quantization (its encoding's bound, 5 cm for the demo's 10 cm steps), so the
/// drawn surface is rebuilt from the DEM in memory instead of copying the pages into a
/// whole grid each frame (268 MB a frame on 8193^2). That holds only if the demand is exact,
/// so it is made so ([`OocScene::with_exact_demand`]; the demand held to the cache budget
/// draws continuous factors from coarser lattices).
pub(super) fn mirrored(scene: OocScene, wait: OocWait) -> OocScene {
    match wait {
        OocWait::FirstFrame => scene.with_mirror(),
        OocWait::EveryFrame => scene.with_exact_demand(),
    }
}

/// The heights a store's frame is drawn from: the pages' (the CPU mirror, holes filled from
/// `reference`'s DEM) when `scene` keeps a mirror, else the DEM itself (every frame warm;
/// see [`mirrored`]).
pub(super) fn drawn_heights<'h>(
    scene: &OocScene,
    reference: &'h MethodScene,
) -> std::borrow::Cow<'h, terrain_core::Heightmap> {
    match scene.mirror() {
        Some(mirror) => std::borrow::Cow::Owned(mirror.to_heightmap(&reference.hm)),
        None => std::borrow::Cow::Borrowed(&reference.hm),
    }
}

/// The surface a store's frame draws, rebuilt from the pages' heights ([`drawn_heights`]):
/// the tessellated patches, and the strips' triangles when the frame has them.
pub(super) fn paged_surface(
    scene: &OocScene,
    reference: Option<&MethodScene>,
    frame: &Frame,
) -> anyhow::Result<DrawnSurface> {
    let Some(reference) = reference else {
        anyhow::bail!("a method drawn from a store is measured only against a DEM in memory");
    };
    let drawn = drawn_heights(scene, reference);
    let drawn = drawn.as_ref();
    let (mesh, triangles) = match &frame.draw {
        // Blocks plus strips: the strips join blocks that share no edge.
        Draw::Paged(f) if !f.extra.indices.is_empty() => {
            terrain_gpu::strips::build_strip_surface(drawn, &f.patches, &f.extra)
        }
        _ => drawn_surface_of(drawn, &reference.qt, &frame.selection),
    };
    Ok(DrawnSurface { mesh, triangles })
}
