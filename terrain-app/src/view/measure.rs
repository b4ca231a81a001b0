//! `terrain view`'s on-demand measurement over a store (the M key, the panel's "measure p99",
//! the script's `measure`): a store has no DEM in memory to measure against, so a worker
//! thread reads the store's own full-resolution heights ([`ooc::store_heightmap_exact`]) into
//! the reference and runs the benchmark's measurement of a store, the one `render` and `bench`
//! run: the method over a second runtime of the same store, measured against that reference
//! ([`method::store_method`] with the reference, [`FrameLoop::measured`]), one warm frame
//! (every level it selects resident, [`OocWait::EveryFrame`]) from the frame's camera. The
//! event loop only polls the worker. The reference is the store's level-0 heights, quantized
//! as baked, so the figure is the method's LOD error, not the bake's quantization error.
//!
//! Memory is bounded: the reference is the whole grid (the measured selection is the method's
//! over the whole store, and the measurement's quadtree is the store's), 4 bytes a sample; over
//! `--measure-mib` the measurement is refused with the figures, instead of measuring
//! something else.

use std::path::PathBuf;
use std::thread::JoinHandle;

use anyhow::Context;
use terrain_app::method::{self, FrameLoop, OocWait};
use terrain_app::methods::{LodMethod, MethodConfig, MethodScene};
use terrain_app::ooc;
use terrain_core::geometry::Camera;
use terrain_core::measure::{FrameErrors, MeasureConfig};

/// The reference's bytes per sample (its `f32` heights; the void mask and the quadtree add
/// under 1 %).
pub(crate) const BYTES_PER_SAMPLE: u64 = 4;

/// `--measure-mib`'s default: 1 GiB, a store of up to about 16000^2 samples.
pub(crate) const MEASURE_MIB: u64 = 1024;

/// What a store measurement gave.
#[derive(Debug, Clone)]
pub(crate) enum Outcome {
    /// The frame's errors against the store's full-resolution heights.
    Measured(FrameErrors),
    /// The reference would exceed the budget: nothing was read.
    OverBudget {
        /// Samples of the store's grid.
        samples: u64,
        /// MiB the reference needs.
        needed_mib: u64,
        /// `--measure-mib`.
        budget_mib: u64,
    },
}

impl Outcome {
    /// The panel's line and stdout's `view: measured ...` (the in-memory measurement's form).
    pub(crate) fn text(&self) -> String {
        match self {
            Outcome::Measured(e) => format!(
                "p99 {:.3} px, max {:.3} px ({} samples; reference: the store's full-resolution \
                 heights, quantized, so this is the LOD error)",
                e.p99_px, e.max_px, e.samples
            ),
            Outcome::OverBudget { samples, needed_mib, budget_mib } => format!(
                "n/a: the store's full-resolution reference is {samples} samples ({needed_mib} \
                 MiB), over --measure-mib {budget_mib}: raise --measure-mib to measure"
            ),
        }
    }
}

/// A store measurement in flight on its worker.
#[derive(Debug)]
pub(crate) struct StoreMeasure {
    handle: JoinHandle<anyhow::Result<Outcome>>,
}

impl StoreMeasure {
    /// Starts measuring `kind` (with `config`, the store opened as `config.ooc` says) over the
    /// store in `dir` from `camera`, within `budget_mib` MiB of reference.
    pub(crate) fn start(
        dir: PathBuf,
        kind: LodMethod,
        config: MethodConfig,
        camera: Camera,
        budget_mib: u64,
    ) -> anyhow::Result<Self> {
        let handle = std::thread::Builder::new()
            .name("view-measure".into())
            .spawn(move || measure(&dir, kind, &config, &camera, budget_mib))
            .context("could not start the measurement's thread")?;
        Ok(Self { handle })
    }

    /// The outcome of the measurement in `slot` once its worker is done (the slot emptied);
    /// `None` while it runs or when there is none.
    pub(crate) fn poll(slot: &mut Option<Self>) -> Option<anyhow::Result<Outcome>> {
        if !slot.as_ref()?.handle.is_finished() {
            return None;
        }
        slot.take().map(Self::join)
    }

    /// Waits for the worker (closing the window).
    pub(crate) fn join(self) -> anyhow::Result<Outcome> {
        self.handle.join().map_err(|_| anyhow::anyhow!("the store measurement panicked"))?
    }
}

/// The measurement itself (see the module docs); runs on the worker.
pub(crate) fn measure(
    dir: &std::path::Path,
    kind: LodMethod,
    config: &MethodConfig,
    camera: &Camera,
    budget_mib: u64,
) -> anyhow::Result<Outcome> {
    let scene = crate::render::open_store(dir, config.ooc)?;
    let h = scene.store().header();
    let samples = h.width * h.height;
    let needed_mib = (samples * BYTES_PER_SAMPLE).div_ceil(1 << 20);
    if needed_mib > budget_mib {
        return Ok(Outcome::OverBudget { samples, needed_mib, budget_mib });
    }
    let hm = ooc::store_heightmap_exact(scene.store())?;
    let reference = MethodScene::new(hm, config.clone());
    let method = method::store_method(kind, scene, config, OocWait::EveryFrame, Some(&reference))?;
    let mut run =
        FrameLoop::new(method).measured(&reference.hm, &reference.qt, MeasureConfig::default());
    let frame = run.frame(0, camera, None)?;
    Ok(Outcome::Measured(frame.record.errors))
}
