//! The benchmark's set-up: [`BenchConfig`], which sweep values and which flight frames are
//! measured (each method's swept parameter is in [`crate::method::registry`]).

use terrain_core::measure::MeasureConfig;

use crate::methods::{LodMethod, MethodConfig};
use crate::ooc::OocConfig;

/// How a benchmark runs.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchConfig {
    /// Methods, in report order. Default [`LodMethod::ALL`] but the geomorphing article's
    /// comparison paths and `dss-strips-pow2` (`crate::method::registry::benched_by_default`).
    pub methods: Vec<LodMethod>,
    /// Frames per flight: at most this many, evenly spaced over the flight (first and last
    /// included); 0 = every frame. Popping is then measured between consecutive *sampled*
    /// frames. Default 60.
    pub max_frames: usize,
    /// Sweep points per method, taken evenly from [`crate::method::registry::sweep_values`]' full list (which has 4-6).
    /// Default 5.
    pub sweep_points: usize,
    /// Rendered image size when a GPU is given; `None` measures without rendering. Default
    /// `Some((640, 360))`.
    pub render_size: Option<(u32, u32)>,
    /// The viewport of the flights' cameras, for selection (DSS's pixel threshold) and pixel
    /// errors. Default 1280 x 720.
    pub measure_viewport: (u32, u32),
    /// The methods' settings (leaf cells, defaults of the parameters not swept). Default
    /// [`MethodConfig::default`].
    pub method: MethodConfig,
    /// A scene folder (`terrain bake`'s output) whose PVS files `pvps-c-pvs` and `pvps-c-cons`
    /// use; an unreadable or mismatched file is a warning and that method runs without
    /// occlusion culling. `None`: the PVS is baked in memory with `method.pvs`. Default `None`.
    pub scene: Option<std::path::PathBuf>,
    /// How frames are measured. Default [`MeasureConfig::default`] (2,000,000 samples: stride 1
    /// up to about 1400 x 1400). A stride above 1 can land every measured sample on tessellation
    /// vertices (stride 2 and a uniform factor of half the leaf cells measure zero error), so
    /// strided figures are biased low; the stride used is in every frame's record.
    pub measure: MeasureConfig,
    /// The out-of-core method (`ooc`): a store baked from the same DEM; `None` (the default)
    /// bakes one into a temporary folder (blocks of `2^ooc_k + 1` vertices, lossless for
    /// integer and scaled-grey sources, else 1 cm) and removes it afterwards.
    pub ooc_store: Option<std::path::PathBuf>,
    /// `k` of the temporary store. Default 8 (the store's default, 257^2 blocks).
    pub ooc_k: u8,
    /// The out-of-core runtime's settings (tau is swept; budget, threads, page capacity).
    pub ooc: OocConfig,
    /// Which calibration maps `--error-px` onto `ooc`'s tau (`--ooc-calibration`). Default
    /// [`OocCalibration::Auto`].
    pub ooc_calibration: OocCalibration,
    /// The out-of-core method: `true` = every sampled frame waits until its needed levels are
    /// resident (warm: the error is the selection's own; `--wait`); `false` (the default) =
    /// real time: the flight is played at its own frame rate, every frame, paced in wall
    /// time, and the sampled frames are measured (the flight's clock stops while one is, and
    /// the store's I/O is held then: `Streamer::hold_io`, so the workers get the flight's
    /// time only).
    pub ooc_wait: bool,
    /// Also run every in-memory method that draws from a store from the benchmark's store
    /// (`--from-store`), after the same method from memory. Default false.
    pub from_store: bool,
    /// Sweep screen-space error targets in pixels instead of each method's own parameter
    /// (`--error-px`): every method at each target, through
    /// [`crate::method::registry::params_for_error_px`]; `sweep_points` is then unused.
    /// Default `None`.
    pub error_px: Option<Vec<f64>>,
    /// Run every method from the store only (`terrain demo`): no run from memory, and no
    /// in-memory tables prepared; the store (`ooc_store`) must hold the tables the methods read.
    /// Default false.
    pub store_only: bool,
    /// Sweep values given per method, replacing [`crate::method::registry::sweep_values`]'
    /// (taken as they are, not thinned by `sweep_points`). Default none.
    pub sweep_override: Vec<(LodMethod, Vec<f64>)>,
    /// Measure geomorph's popping (the per-vertex jump from the previous flight frame's
    /// surface, with and without the morph: two more surfaces a frame). Default true; the
    /// demo skips it.
    pub popping: bool,
    /// Rendered frames colour every patch by its level (`RenderOptions::lod_colours`): the
    /// geomorph renderer then draws its base pass only, lit by the lightmap (the geomorphing
    /// article's "minimum scene": one pass; without it, its material passes, our "full
    /// scene"). Default false.
    pub lod_colours: bool,
}

impl Default for BenchConfig {
    fn default() -> Self {
        Self {
            methods: LodMethod::ALL
                .into_iter()
                .filter(|&m| crate::method::registry::benched_by_default(m))
                .collect(),
            max_frames: 60,
            sweep_points: 5,
            render_size: Some((640, 360)),
            measure_viewport: (1280, 720),
            method: MethodConfig::default(),
            scene: None,
            measure: MeasureConfig::default(),
            ooc_store: None,
            ooc_k: 8,
            ooc: OocConfig::default(),
            ooc_calibration: OocCalibration::Auto,
            ooc_wait: false,
            lod_colours: false,
            from_store: false,
            error_px: None,
            store_only: false,
            sweep_override: Vec::new(),
            popping: true,
        }
    }
}

impl BenchConfig {
    /// The `--quick` settings (`cargo xtask bench --quick` in under 5 minutes on two cores):
    /// 5 frames per flight, 3 sweep points, 320 x 180 images, a 200,000-sample budget per
    /// frame (strided on large grids: errors biased low, see `measure`), and the `ooc` method's
    /// sampled frames warm (`ooc_wait`; played in real time, each of its runs would last the
    /// flight's duration).
    pub fn quick() -> Self {
        Self {
            max_frames: 5,
            sweep_points: 3,
            render_size: Some((320, 180)),
            measure: MeasureConfig { max_samples: 200_000, ..MeasureConfig::default() },
            ooc_wait: true,
            ..Self::default()
        }
    }
}

/// `points` values taken evenly from `all` (both ends included); all of them when `points`
/// is at least their number.
pub fn pick_evenly(all: &[f64], points: usize) -> Vec<f64> {
    let n = all.len();
    if points >= n || n == 0 {
        return all.to_vec();
    }
    if points <= 1 {
        return vec![all[n / 2]];
    }
    let mut v: Vec<f64> = (0..points)
        .map(|k| all[((k * (n - 1)) as f64 / (points - 1) as f64).round() as usize])
        .collect();
    v.dedup();
    v
}

/// The frame indices of a flight of `n` frames: at most `max` evenly spaced (0 = all).
pub fn frame_indices(n: usize, max: usize) -> Vec<usize> {
    if max == 0 || max >= n {
        return (0..n).collect();
    }
    if max == 1 {
        return vec![0];
    }
    let mut v: Vec<usize> =
        (0..max).map(|k| ((k * (n - 1)) as f64 / (max - 1) as f64).round() as usize).collect();
    v.dedup();
    v
}

/// Which calibration maps a pixel target onto the `ooc` method's tau in a benchmark
/// ([`crate::ooc_calibration`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum OocCalibration {
    /// The store's (`ooc-calibration.txt` in its folder) when it has one for the configured
    /// refinement, else the shared one (a temporary store has none).
    Auto,
    /// The shared one, whatever the store has.
    Shared,
    /// This file, which must be a calibration of the benchmark's store.
    File(std::path::PathBuf),
}

impl OocCalibration {
    /// `auto`, `shared` or a file's path.
    pub fn parse(s: &str) -> Self {
        match s {
            "auto" => Self::Auto,
            "shared" => Self::Shared,
            path => Self::File(path.into()),
        }
    }

    /// The calibration chosen for `store`.
    pub fn resolve(
        &self,
        store: &terrain_stream::Store,
    ) -> Result<Option<crate::ooc_calibration::Calibration>, crate::ooc_calibration::CalibrationError>
    {
        use crate::ooc_calibration::{Calibration, TerrainId};
        match self {
            Self::Auto => Calibration::of_opened(store),
            Self::Shared => Ok(None),
            Self::File(path) => Calibration::load_file(path, TerrainId::of(store)).map(Some),
        }
    }
}
