//! Per-store calibration of `--error-px` for the out-of-core method (`ooc`): Eq. 7's `tau`
//! bounds each patch's `StaticE` (out-of-core Eq. 3-7), not the drawn error, and the measured
//! p99 per pixel of `tau` varies by terrain (bench/ooc/README.md: 0.08-0.81 under Eq. 7 alone,
//! 0.08-0.60 with 16-cell segments at most, 0.71-1.16 under the cost split, over four DEMs).
//! The shared calibration
//! ([`crate::method::registry::ooc_p99_per_tau`]) is the largest ratio measured, so smooth
//! terrain is drawn finer than the target asks. A [`Calibration`] is the measured map of one
//! store: a few `tau` values flown over a fixed set of poses ([`measure`]: the first shipped
//! flight, `flights/pvps_884.json`, resolved onto the terrain, `frames` evenly spaced frames,
//! each warm and measured with the benchmark's one measurement, [`FrameLoop::measured`]),
//! the median p99 per `tau`, made monotone, and inverted by interpolation in log space
//! ([`Calibration::tau_for`]).
//!
//! It is written beside the store's index as [`FILE_NAME`], a versioned text file naming the
//! store it was measured on (grid size, block size `k` and the bake's checksum, `bake_id`) and
//! the refinement (split rule, smallest patch, cost-split floor, segment floor) it was measured
//! under: a file of another store is refused ([`CalibrationError::Foreign`]), and one measured
//! under another refinement is not used (the shared calibration is,
//! [`OocConfig::tau_for_error_px`]).
//!
//! A store larger than [`CalibrateOptions::window`] samples per side is measured on a window of
//! whole blocks at its centre, read at full resolution ([`crate::ooc::store_heightmap`]), with
//! the flight resolved onto that window: the measurement needs the grid in memory (the drawn
//! surface is compared with every sample), and the store may not fit. The window has the
//! store's spacing and local relief; it does not have its far field.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use glam::dvec2;
use terrain_core::Heightmap;
use terrain_core::flight::{FlightConfig, FlightSpec};
use terrain_core::measure::MeasureConfig;
use terrain_stream::{Refinement, SplitRule, Store};

use crate::bench::frame_indices;
use crate::method::{FrameLoop, MethodOptions, OocWait, build};
use crate::methods::{LodMethod, MethodConfig, MethodScene};
use crate::ooc::OocConfig;

/// The calibration's file in a store's folder.
pub const FILE_NAME: &str = "ooc-calibration.txt";

/// The first line of the file: its format and version.
pub const MAGIC: &str = "terrain-ooc-calibration 1";

/// Measured points a calibration holds at most.
pub const MAX_POINTS: usize = 12;

/// The `tau` values [`measure`] flies by default (pixels): around the 0.5-4 px targets of
/// `--error-px` at the measured p99 per `tau` (0.08-1.16).
pub const DEFAULT_TAUS: [f64; 6] = [0.5, 1.0, 2.0, 4.0, 8.0, 16.0];

/// The poses: the shipped flight [`measure`] resolves onto the terrain.
const FLIGHT: &str = include_str!("../../flights/pvps_884.json");

/// The flight's name, as the file records it.
const FLIGHT_NAME: &str = "flights/pvps_884.json";

/// What a calibration was measured on: the store's grid, block size and bake checksum.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TerrainId {
    /// Grid columns (samples).
    pub width: u64,
    /// Grid rows (samples).
    pub height: u64,
    /// Blocks are `(2^k + 1)^2` samples.
    pub k: u8,
    /// The bake's checksum (a hash of every level's checksum, [`terrain_stream::Header`]).
    pub bake_id: u64,
}

impl TerrainId {
    /// The identity of `store`.
    pub fn of(store: &Store) -> Self {
        let h = store.header();
        Self { width: h.width, height: h.height, k: h.k, bake_id: h.bake_id }
    }
}

impl std::fmt::Display for TerrainId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} x {} samples, k {}, bake {:016x}",
            self.width, self.height, self.k, self.bake_id
        )
    }
}

/// Why a calibration could not be made, read or used.
#[derive(Debug)]
pub enum CalibrationError {
    /// The file could not be read or written.
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        cause: std::io::Error,
    },
    /// The file is not a calibration this reader reads.
    Garbled {
        /// The file (or `<text>`).
        path: PathBuf,
        /// Its line (1-based).
        line: usize,
        /// What is wrong.
        what: String,
    },
    /// The file was measured on another store.
    Foreign {
        /// The file.
        path: PathBuf,
        /// The store it names.
        found: TerrainId,
        /// The store it lies in.
        expected: TerrainId,
    },
    /// Too few usable measured points to fit.
    TooFewPoints {
        /// Usable points (positive, finite `tau` and p99).
        usable: usize,
    },
    /// The store or the measurement failed.
    Measure(anyhow::Error),
}

impl std::fmt::Display for CalibrationError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Io { path, cause } => write!(f, "{}: {cause}", path.display()),
            Self::Garbled { path, line, what } => write!(
                f,
                "{}:{line}: not an ooc calibration this reader reads ({what}); write it again with \
                 `terrain calibrate STORE`",
                path.display()
            ),
            Self::Foreign { path, found, expected } => write!(
                f,
                "{}: an ooc calibration of another store ({found}), not of the store it lies in \
                 ({expected}); write this store's with `terrain calibrate STORE`, or delete the file",
                path.display()
            ),
            Self::TooFewPoints { usable } => write!(
                f,
                "an ooc calibration needs at least 2 measured points with a positive p99, got \
                 {usable} (a terrain this flat or this small is drawn exactly at every tau: use \
                 the shared calibration)"
            ),
            Self::Measure(e) => write!(f, "the calibration's measurement failed: {e:#}"),
        }
    }
}

impl std::error::Error for CalibrationError {}

/// One store's measured map from Eq. 7's `tau` to the drawn p99 pixel error, and its inverse.
/// `Copy` (a fixed array of points), so [`OocConfig`] stays `Copy`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Calibration {
    /// The store it was measured on.
    pub terrain: TerrainId,
    /// The refinement it was measured under; it applies to that one only.
    pub refinement: Refinement,
    /// Frames measured per `tau`.
    pub frames: usize,
    /// `(tau, p99 px)` by increasing `tau`, p99 non-decreasing (see [`Calibration::fit`]).
    points: [[f64; 2]; MAX_POINTS],
    len: usize,
}

impl Calibration {
    /// The calibration of `measured` `(tau, p99 px)` points: points without a positive, finite
    /// `tau` and p99 are dropped (a p99 of 0 says nothing about the slope), repeated `tau`s
    /// keep their largest p99, and the p99 is made non-decreasing in `tau` by a running
    /// maximum (a coarser `tau` never draws finer; where a measurement dips, the larger p99
    /// stands, which maps a target to the finer `tau`). At most [`MAX_POINTS`] points.
    pub fn fit(
        terrain: TerrainId,
        refinement: Refinement,
        frames: usize,
        measured: &[(f64, f64)],
    ) -> Result<Self, CalibrationError> {
        let ok = |v: f64| v.is_finite() && v > 0.0;
        let mut pts: Vec<[f64; 2]> =
            measured.iter().filter(|(t, p)| ok(*t) && ok(*p)).map(|&(t, p)| [t, p]).collect();
        pts.sort_by(|a, b| a[0].total_cmp(&b[0]).then(b[1].total_cmp(&a[1])));
        pts.dedup_by(|later, kept| later[0] == kept[0]);
        if pts.len() < 2 || pts.len() > MAX_POINTS {
            return Err(CalibrationError::TooFewPoints { usable: pts.len().min(MAX_POINTS) });
        }
        let mut high = 0.0f64;
        for p in &mut pts {
            high = high.max(p[1]);
            p[1] = high;
        }
        if pts[0][1] == pts[pts.len() - 1][1] {
            // Flat: no slope to invert.
            return Err(CalibrationError::TooFewPoints { usable: 1 });
        }
        let mut points = [[0.0; 2]; MAX_POINTS];
        points[..pts.len()].copy_from_slice(&pts);
        Ok(Self { terrain, refinement, frames, points, len: pts.len() })
    }

    /// The `(tau, p99 px)` points, by increasing `tau`.
    pub fn points(&self) -> &[[f64; 2]] {
        &self.points[..self.len]
    }

    /// Eq. 7's `tau` for a p99 target of `error_px` pixels: linear interpolation of `ln tau`
    /// against `ln p99` between the measured points (where the p99 is flat over a span, its
    /// smallest `tau`); outside the measured range the end point's p99 per `tau` is held
    /// (`tau` proportional to the target, the shared calibration's form), so extrapolation
    /// follows no fitted slope beyond the data. A non-positive target is taken as 1 px.
    pub fn tau_for(&self, error_px: f64) -> f64 {
        let px = if error_px.is_finite() && error_px > 0.0 { error_px } else { 1.0 };
        let pts = self.points();
        let (first, last) = (pts[0], pts[pts.len() - 1]);
        if px <= first[1] {
            return first[0] * px / first[1];
        }
        if px >= last[1] {
            return last[0] * px / last[1];
        }
        for w in pts.windows(2) {
            let ([t0, p0], [t1, p1]) = (w[0], w[1]);
            if px <= p1 {
                if p1 <= p0 {
                    return t0;
                }
                let f = (px.ln() - p0.ln()) / (p1.ln() - p0.ln());
                return (t0.ln() + f * (t1.ln() - t0.ln())).exp();
            }
        }
        last[0] * px / last[1]
    }

    /// The p99 (pixels) the store is expected to draw at `tau`: the inverse of
    /// [`Calibration::tau_for`] (the same interpolation and end ratios).
    pub fn p99_at(&self, tau: f64) -> f64 {
        let pts = self.points();
        let (first, last) = (pts[0], pts[pts.len() - 1]);
        if tau <= first[0] {
            return first[1] * tau / first[0];
        }
        if tau >= last[0] {
            return last[1] * tau / last[0];
        }
        for w in pts.windows(2) {
            let ([t0, p0], [t1, p1]) = (w[0], w[1]);
            if tau <= t1 {
                let f = (tau.ln() - t0.ln()) / (t1.ln() - t0.ln());
                return (p0.ln() + f * (p1.ln() - p0.ln())).exp();
            }
        }
        last[1] * tau / last[0]
    }

    /// The file's text (see [`Calibration::parse`]).
    pub fn to_text(&self) -> String {
        let t = &self.terrain;
        let r = &self.refinement;
        let mut s = format!(
            "{MAGIC}\n\
             # Eq. 7's tau -> measured p99 pixel error of `ooc` on this store (`terrain calibrate`);\n\
             # median over {} frames of {FLIGHT_NAME}, 1280 x 720, 60 degrees, every frame warm.\n\
             terrain {} {} {} {:016x}\n\
             refinement {} {} {}{}\n\
             frames {}\n",
            self.frames,
            t.width,
            t.height,
            t.k,
            t.bake_id,
            split_name(r.split),
            r.patch_cells,
            r.cost_split_px,
            // The segment floor only when set: files without it are measured without one.
            match r.max_segment_cells {
                0 => String::new(),
                cells => format!(" {cells}"),
            },
            self.frames
        );
        for [tau, p99] in self.points() {
            s.push_str(&format!("point {tau} {p99}\n"));
        }
        s
    }

    /// A calibration from its file's text; `path` names it in errors. Refuses another format
    /// or version, missing or repeated fields, and points [`Calibration::fit`] would not keep
    /// as they are (a hand-edited file is read only if it is what a fit writes).
    pub fn parse(text: &str, path: &Path) -> Result<Self, CalibrationError> {
        let bad = |line: usize, what: String| CalibrationError::Garbled {
            path: path.to_path_buf(),
            line,
            what,
        };
        let mut lines = text.lines().enumerate().map(|(k, l)| (k + 1, l.trim()));
        match lines.next() {
            Some((_, l)) if l == MAGIC => {}
            Some((n, l)) => {
                return Err(bad(n, format!("the first line is {l:?}, expected {MAGIC:?}")));
            }
            None => return Err(bad(1, "the file is empty".into())),
        }
        let (mut terrain, mut refinement, mut frames) = (None, None, None);
        let mut points = Vec::new();
        let mut last = 1;
        for (n, line) in lines {
            last = n;
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let mut f = line.split_whitespace();
            let key = f.next().unwrap_or_default();
            let rest: Vec<&str> = f.collect();
            let want = |count: usize| -> Result<(), CalibrationError> {
                if rest.len() == count {
                    Ok(())
                } else {
                    Err(bad(n, format!("{key} takes {count} values, got {}", rest.len())))
                }
            };
            let num = |s: &str| -> Result<f64, CalibrationError> {
                s.parse::<f64>().map_err(|_| bad(n, format!("{s:?} is not a number")))
            };
            let int = |s: &str| -> Result<u64, CalibrationError> {
                s.parse::<u64>().map_err(|_| bad(n, format!("{s:?} is not a whole number")))
            };
            let once =
                |set: bool| if set { Err(bad(n, format!("{key} given twice"))) } else { Ok(()) };
            match key {
                "terrain" => {
                    want(4)?;
                    once(terrain.is_some())?;
                    let k = u8::try_from(int(rest[2])?)
                        .map_err(|_| bad(n, format!("k {} is too large", rest[2])))?;
                    let bake_id = u64::from_str_radix(rest[3], 16).map_err(|_| {
                        bad(n, format!("{:?} is not a hexadecimal bake id", rest[3]))
                    })?;
                    terrain =
                        Some(TerrainId { width: int(rest[0])?, height: int(rest[1])?, k, bake_id });
                }
                "refinement" => {
                    // split, patch cells, cost split px [, segment floor cells (absent: 0)]
                    if rest.len() != 4 {
                        want(3)?;
                    }
                    once(refinement.is_some())?;
                    let split = parse_split(rest[0])
                        .ok_or_else(|| bad(n, format!("split {:?} is not eq7 or cost", rest[0])))?;
                    let cells = |s: &str| {
                        u32::try_from(int(s)?).map_err(|_| bad(n, format!("{s} is too large")))
                    };
                    refinement = Some(Refinement {
                        split,
                        patch_cells: cells(rest[1])?,
                        cost_split_px: cells(rest[2])?,
                        max_segment_cells: rest.get(3).map_or(Ok(0), |s| cells(s))?,
                        // `terrain calibrate` measures at the default view-angle floor.
                        ..Refinement::default()
                    });
                }
                "frames" => {
                    want(1)?;
                    once(frames.is_some())?;
                    frames = Some(int(rest[0])? as usize);
                }
                "point" => {
                    want(2)?;
                    points.push((num(rest[0])?, num(rest[1])?));
                }
                other => return Err(bad(n, format!("unknown field {other:?}"))),
            }
        }
        let missing = |what: &str| bad(last, format!("no {what} line"));
        let terrain = terrain.ok_or_else(|| missing("terrain"))?;
        let refinement = refinement.ok_or_else(|| missing("refinement"))?;
        let frames = frames.ok_or_else(|| missing("frames"))?;
        let fitted = Self::fit(terrain, refinement, frames, &points)
            .map_err(|e| bad(last, format!("its points: {e}")))?;
        let as_read: Vec<[f64; 2]> = points.iter().map(|&(t, p)| [t, p]).collect();
        if fitted.points() != as_read.as_slice() {
            return Err(bad(
                last,
                "its points are not by increasing tau with a non-decreasing positive p99".into(),
            ));
        }
        Ok(fitted)
    }

    /// The calibration of the opened `store` ([`FILE_NAME`] beside its index; a remote
    /// store's fetched into its mirror on first use), if there is one.
    pub fn of_opened(store: &terrain_stream::Store) -> Result<Option<Self>, CalibrationError> {
        store.side_file(FILE_NAME).map_err(|e| {
            CalibrationError::Measure(
                anyhow::Error::new(e).context(format!("could not read {FILE_NAME} of the store")),
            )
        })?;
        Self::load(store.dir(), TerrainId::of(store))
    }

    /// The calibration in `dir` ([`FILE_NAME`]) if there is one, checked to be of the store
    /// `expected` (else [`CalibrationError::Foreign`]).
    pub fn load(dir: &Path, expected: TerrainId) -> Result<Option<Self>, CalibrationError> {
        let path = dir.join(FILE_NAME);
        let text = match std::fs::read_to_string(&path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(cause) => return Err(CalibrationError::Io { path, cause }),
        };
        Self::read_checked(&text, &path, expected).map(Some)
    }

    /// The calibration in file `path`, checked to be of the store `expected`.
    pub fn load_file(path: &Path, expected: TerrainId) -> Result<Self, CalibrationError> {
        let text = std::fs::read_to_string(path)
            .map_err(|cause| CalibrationError::Io { path: path.to_path_buf(), cause })?;
        Self::read_checked(&text, path, expected)
    }

    fn read_checked(
        text: &str,
        path: &Path,
        expected: TerrainId,
    ) -> Result<Self, CalibrationError> {
        let c = Self::parse(text, path)?;
        if c.terrain != expected {
            return Err(CalibrationError::Foreign {
                path: path.to_path_buf(),
                found: c.terrain,
                expected,
            });
        }
        Ok(c)
    }

    /// Writes the file to `path`.
    pub fn write(&self, path: &Path) -> Result<(), CalibrationError> {
        std::fs::write(path, self.to_text())
            .map_err(|cause| CalibrationError::Io { path: path.to_path_buf(), cause })
    }
}

/// The calibration of the store at `dir` ([`FILE_NAME`] beside its index), if it has one;
/// refused when it is another store's or garbled. Opens the store's index for its identity;
/// `dir` may be a URL (`crate::ooc::open_store`), whose file was mirrored with its tables.
pub fn of_store(dir: &Path) -> Result<Option<Calibration>, CalibrationError> {
    let store = crate::ooc::open_store(dir).map_err(|e| {
        CalibrationError::Measure(
            anyhow::Error::new(e).context(format!("could not open the store {}", dir.display())),
        )
    })?;
    Calibration::of_opened(&store)
}

/// The split rule's name in the file and on the command line (`--ooc-split`).
pub fn split_name(split: SplitRule) -> &'static str {
    match split {
        SplitRule::Eq7 => "eq7",
        SplitRule::Cost => "cost",
    }
}

/// The split rule of a name of [`split_name`].
pub fn parse_split(name: &str) -> Option<SplitRule> {
    match name {
        "eq7" => Some(SplitRule::Eq7),
        "cost" => Some(SplitRule::Cost),
        _ => None,
    }
}

/// Where a `tau` for a pixel target came from ([`OocConfig::tau_for_error_px`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TauSource {
    /// The store's own calibration.
    Store,
    /// The shared calibration ([`crate::method::registry::ooc_p99_per_tau`]): no calibration
    /// given, or one measured under another refinement.
    Shared,
}

impl OocConfig {
    /// Eq. 7's `tau` for a p99 target of `error_px` pixels: the store's calibration
    /// ([`OocConfig::calibration`]) when it was measured under this refinement, else the
    /// shared one (`error_px / ooc_p99_per_tau(split, max_segment_cells)`).
    pub fn tau_for_error_px(&self, error_px: f64) -> (f64, TauSource) {
        match &self.calibration {
            Some(c) if c.refinement == self.refinement() => (c.tau_for(error_px), TauSource::Store),
            _ => {
                let r =
                    crate::method::registry::ooc_p99_per_tau(self.split, self.max_segment_cells);
                (error_px / r, TauSource::Shared)
            }
        }
    }
}

/// What [`measure`] flies.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrateOptions {
    /// Eq. 7's `tau` values measured. Default [`DEFAULT_TAUS`].
    pub taus: Vec<f64>,
    /// Frames of the flight, evenly spaced. Default 6.
    pub frames: usize,
    /// A store wider or taller than this many samples is measured on a window of whole
    /// blocks at its centre at most this wide (at least one block). Default 2049.
    pub window: usize,
    /// The measurement's sample budget per frame ([`MeasureConfig::max_samples`]). Default
    /// 200,000 (the `error_px_calibration` example's).
    pub max_samples: usize,
}

impl Default for CalibrateOptions {
    fn default() -> Self {
        Self { taus: DEFAULT_TAUS.to_vec(), frames: 6, window: 2049, max_samples: 200_000 }
    }
}

/// The measured `(tau, median p99 px)` of `ooc` over `store` (the same terrain as `hm`, whose
/// blocks tile `hm`'s quadtree), under `ooc`'s refinement (its `tau` is replaced by each of
/// `options.taus`): `frames` frames of the shipped flight resolved onto `hm`, every frame
/// warm, each measured against `hm` by the benchmark's measurement.
pub fn measure(
    hm: Heightmap,
    store: Arc<Store>,
    ooc: &OocConfig,
    options: &CalibrateOptions,
) -> anyhow::Result<Vec<(f64, f64)>> {
    let spec = FlightSpec::parse(FLIGHT).map_err(|e| anyhow::anyhow!("{FLIGHT_NAME}: {e}"))?;
    let flight_cfg = FlightConfig { viewport_px: dvec2(1280.0, 720.0), ..FlightConfig::default() };
    let (flight, _) = spec.resolve(&hm, &flight_cfg);
    let all = flight.frames();
    let cameras: Vec<_> =
        frame_indices(all.len(), options.frames.max(1)).into_iter().map(|k| all[k]).collect();
    let mut scene = MethodScene::new(hm, MethodConfig::default());
    let measure = MeasureConfig { max_samples: options.max_samples, ..MeasureConfig::default() };
    let method_options =
        MethodOptions { morph: false, store: Some(store), ooc_wait: OocWait::EveryFrame };
    let mut out = Vec::new();
    for &tau in &options.taus {
        scene.config.ooc = OocConfig { tau, calibration: None, ..*ooc };
        let method = build(LodMethod::OutOfCore, &scene, &method_options)?;
        let mut run = FrameLoop::new(method).measured(&scene.hm, &scene.qt, measure);
        let mut p99 = Vec::with_capacity(cameras.len());
        for (k, c) in cameras.iter().enumerate() {
            p99.push(run.frame(k, c, None)?.record.errors.p99_px);
        }
        p99.sort_by(f64::total_cmp);
        out.push((tau, p99[p99.len() / 2]));
    }
    Ok(out)
}

/// Calibrates the store in `dir` under `ooc`'s refinement: reads it (a centred window of at
/// most `options.window` samples per side, see the module docs), bakes that window into a
/// temporary store when it is not the whole grid, [`measure`]s, and fits.
pub fn calibrate_store(
    dir: &Path,
    ooc: &OocConfig,
    options: &CalibrateOptions,
) -> Result<Calibration, CalibrationError> {
    let m = |e: anyhow::Error| CalibrationError::Measure(e);
    let store = Arc::new(Store::open(dir).map_err(|e| {
        m(anyhow::Error::new(e).context(format!("could not open {}", dir.display())))
    })?);
    let id = TerrainId::of(&store);
    let h = store.header().clone();
    let cells = h.block_cells() as usize;
    // Blocks per side of the window: as many as fit in `window` samples, at least one.
    let fit =
        |blocks: u32| (options.window.saturating_sub(1) / cells).clamp(1, blocks as usize) as u32;
    let (nx, ny) = (fit(h.blocks_x), fit(h.blocks_y));
    let (c0, r0) = ((h.blocks_x - nx) / 2, (h.blocks_y - ny) / 2);
    let whole = nx == h.blocks_x && ny == h.blocks_y;
    let hm = crate::ooc::store_heightmap(&store, h.k, [c0..c0 + nx, r0..r0 + ny], 0.0)
        .map_err(|e| m(e.into()))?;
    let (measured_store, temp) = if whole {
        (store, None)
    } else {
        let temp = temp_dir("window");
        crate::ooc::bake_temporary(&hm, h.k, &temp).map_err(m)?;
        let s = Store::open(&temp).map_err(|e| m(e.into()))?;
        (Arc::new(s), Some(temp))
    };
    let measured = measure(hm, measured_store, ooc, options);
    if let Some(t) = temp {
        let _ = std::fs::remove_dir_all(t);
    }
    Calibration::fit(id, ooc.refinement(), options.frames, &measured.map_err(m)?)
}

/// Calibrates the in-memory `hm` (baked into a temporary store with blocks of `2^k` cells)
/// under `ooc`'s refinement; the calibration names the temporary store's identity.
pub fn calibrate_heightmap(
    hm: &Heightmap,
    k: u8,
    ooc: &OocConfig,
    options: &CalibrateOptions,
) -> Result<Calibration, CalibrationError> {
    let m = |e: anyhow::Error| CalibrationError::Measure(e);
    let temp = temp_dir("dem");
    let result = (|| {
        crate::ooc::bake_temporary(hm, k, &temp).map_err(m)?;
        let store = Arc::new(Store::open(&temp).map_err(|e| m(e.into()))?);
        let id = TerrainId::of(&store);
        let measured = measure(hm.clone(), store, ooc, options).map_err(m)?;
        Calibration::fit(id, ooc.refinement(), options.frames, &measured)
    })();
    let _ = std::fs::remove_dir_all(&temp);
    result
}

/// A fresh temporary folder name, unique within the process (tests calibrate in parallel).
fn temp_dir(what: &str) -> PathBuf {
    static NEXT: AtomicUsize = AtomicUsize::new(0);
    std::env::temp_dir().join(format!(
        "terrain-ooc-calibration-{what}-{}-{}",
        std::process::id(),
        NEXT.fetch_add(1, Ordering::Relaxed)
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn id() -> TerrainId {
        TerrainId { width: 513, height: 513, k: 6, bake_id: 0xabc }
    }

    fn eq7() -> Refinement {
        Refinement {
            split: SplitRule::Eq7,
            patch_cells: 32,
            cost_split_px: 0,
            ..Refinement::default()
        }
    }

    fn cal(points: &[(f64, f64)]) -> Calibration {
        Calibration::fit(id(), eq7(), 6, points).expect("a fit")
    }

    /// The fit sorts, drops unusable points, keeps a repeated tau's larger p99 and makes the
    /// p99 non-decreasing; too few or flat points are refused.
    #[test]
    fn the_fit_is_monotone() {
        let c = cal(&[(4.0, 2.0), (1.0, 0.6), (2.0, 0.5), (1.0, 0.7), (0.5, 0.0), (8.0, f64::NAN)]);
        assert_eq!(c.points(), &[[1.0, 0.7], [2.0, 0.7], [4.0, 2.0]]);
        assert!(c.points().windows(2).all(|w| w[0][0] < w[1][0] && w[0][1] <= w[1][1]));
        assert!(matches!(
            Calibration::fit(id(), eq7(), 6, &[(1.0, 0.5)]),
            Err(CalibrationError::TooFewPoints { usable: 1 })
        ));
        assert!(Calibration::fit(id(), eq7(), 6, &[(1.0, 0.5), (2.0, 0.5)]).is_err());
        // Negative control: an increasing set is kept as given.
        let c = cal(&[(1.0, 0.5), (2.0, 0.9)]);
        assert_eq!(c.points(), &[[1.0, 0.5], [2.0, 0.9]]);
    }

    /// Between points, log-log interpolation (exact at the points, the geometric mean's tau at
    /// the geometric mean's p99 on a power law); a larger target never gives a smaller tau;
    /// outside, the end ratio is held.
    #[test]
    fn interpolation_and_clamped_extrapolation() {
        let c = cal(&[(1.0, 0.5), (2.0, 0.8), (4.0, 2.0), (8.0, 4.0)]);
        for &[t, p] in c.points() {
            assert!((c.tau_for(p) - t).abs() < 1e-12, "{t} {p}");
            assert!((c.p99_at(t) - p).abs() < 1e-12);
        }
        let mid = (0.8f64 * 2.0).sqrt();
        assert!((c.tau_for(mid) - (2.0f64 * 4.0).sqrt()).abs() < 1e-9);
        let targets: Vec<f64> = (1..200).map(|k| 0.05 * f64::from(k)).collect();
        let taus: Vec<f64> = targets.iter().map(|&px| c.tau_for(px)).collect();
        assert!(taus.windows(2).all(|w| w[0] <= w[1]), "{taus:?}");
        for &px in &targets {
            let back = c.p99_at(c.tau_for(px));
            assert!((back - px).abs() < 1e-9 * px.max(1.0), "{px} -> {back}");
        }
        // Below and above: the end points' p99 per tau.
        assert!((c.tau_for(0.25) - 0.5).abs() < 1e-12);
        assert!((c.tau_for(8.0) - 16.0).abs() < 1e-12);
        // A flat span maps to its smallest tau.
        let flat = cal(&[(1.0, 0.5), (2.0, 1.0), (4.0, 1.0), (8.0, 3.0)]);
        assert_eq!(flat.tau_for(1.0), 2.0);
    }

    /// The text round-trips; another format, a garbled number, a missing field and points a
    /// fit would change are refused with the file and line named.
    #[test]
    fn the_file_round_trips_and_refuses_garbled_text() {
        let c = cal(&[(0.5, 0.21), (1.0, 0.43), (2.0, 0.87), (4.0, 1.9)]);
        let path = Path::new("store/ooc-calibration.txt");
        let text = c.to_text();
        assert_eq!(Calibration::parse(&text, path).expect("round trip"), c);
        for (bad, says) in [
            (text.replacen(MAGIC, "terrain-ooc-calibration 2", 1), ":1:"),
            (text.replacen("point 1 0.43", "point 1 x", 1), "\"x\" is not a number"),
            (text.replacen("frames 6\n", "", 1), "no frames line"),
            (text.replacen("point 1 0.43", "point 1 0.1", 1), "non-decreasing"),
            (text.replacen("refinement eq7", "refinement roam", 1), "not eq7 or cost"),
            (String::new(), "empty"),
        ] {
            let e = Calibration::parse(&bad, path).expect_err(&bad).to_string();
            assert!(e.contains("store/ooc-calibration.txt") && e.contains(says), "{e}");
        }
        // The segment floor: written only when set (a file without it was measured without
        // one), read back either way; a fifth value is refused.
        let unfloored =
            Calibration { refinement: Refinement { max_segment_cells: 0, ..c.refinement }, ..c };
        let text = unfloored.to_text();
        assert!(text.contains("refinement eq7 32 0\n"), "{text}");
        assert_eq!(Calibration::parse(&text, path).expect("round trip"), unfloored);
        let floored =
            Calibration { refinement: Refinement { max_segment_cells: 16, ..c.refinement }, ..c };
        let text = floored.to_text();
        assert!(text.contains("refinement eq7 32 0 16\n"), "{text}");
        assert_eq!(Calibration::parse(&text, path).expect("round trip"), floored);
        let five = text.replacen("refinement eq7 32 0 16", "refinement eq7 32 0 16 1", 1);
        let e = Calibration::parse(&five, path).expect_err("five values").to_string();
        assert!(e.contains("refinement takes 3 values, got 5"), "{e}");
    }

    /// A calibration applies to its refinement only; otherwise the shared one is used.
    #[test]
    fn the_config_uses_a_calibration_of_its_refinement() {
        let c = cal(&[(1.0, 0.2), (2.0, 0.4), (4.0, 0.8)]);
        let config = OocConfig { calibration: Some(c), ..OocConfig::default() };
        let (tau, source) = config.tau_for_error_px(0.4);
        assert_eq!(source, TauSource::Store);
        assert!((tau - 2.0).abs() < 1e-12);
        let other = OocConfig { split: SplitRule::Cost, ..config };
        assert_eq!(other.tau_for_error_px(0.4).1, TauSource::Shared);
        let d = OocConfig::default();
        let none = d.tau_for_error_px(1.0);
        assert_eq!(none.1, TauSource::Shared);
        assert!(
            (none.0 - 1.0 / crate::method::registry::ooc_p99_per_tau(d.split, d.max_segment_cells))
                .abs()
                < 1e-12
        );
    }
}
