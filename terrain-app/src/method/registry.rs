//! Everything the callers need to know about each method, in one place: how it is built
//! ([`build`]), its swept parameter and values ([`sweep_values`], [`apply_parameter`]), its
//! plot colour ([`colour`]), what the benchmark report says about how it is timed ([`note`])
//! and whether it draws from a store ([`needs_store`]), and how its own parameter follows from
//! one screen-space error target in pixels ([`params_for_error_px`], the `--error-px` and
//! `--quality` knob). `render`, `fly`, `mesh` and `bench` hold no per-method cases.

use std::sync::Arc;

use super::{
    EntropyMethod, GeomorphMethod, MemoryMethod, Method, MorphPath, OocMethod, OocWait, TinMethod,
};
use crate::methods::{LodMethod, MethodConfig, MethodScene};
use crate::ooc::OocScene;
use terrain_stream::{DEFAULT_MAX_SEGMENT_CELLS, DEFAULT_SPLIT, SplitRule};

/// What [`build`] needs besides the scene.
#[derive(Debug, Clone)]
pub struct MethodOptions {
    /// `geomorph`: draw with the vertex-shader morph (the geomorph renderer, measured through
    /// the morph's CPU reference, with its popping figures); `false` draws its un-morphed
    /// geo-mipmap through the tessellation renderer. Default false.
    pub morph: bool,
    /// `ooc`: the store (baked from the scene's DEM), its runtime settings being the scene's
    /// `config.ooc`. Default `None`: `ooc` cannot be built.
    pub store: Option<Arc<terrain_stream::Store>>,
    /// `ooc`: when frames wait for the workers. Default [`OocWait::FirstFrame`].
    pub ooc_wait: OocWait,
}

impl Default for MethodOptions {
    fn default() -> Self {
        Self { morph: false, store: None, ooc_wait: OocWait::FirstFrame }
    }
}

/// The message for `ooc` without a store.
pub const OOC_NEEDS_STORE: &str = "--method ooc draws a baked store: bake the DEM with `terrain bake <dem> -o <store>`, then `terrain render <store>` (or `terrain bench`, which bakes one)";

/// `kind` prepared over `scene` (its current config; call [`MethodScene::prepare`] first so
/// the first frame's timing is the selection's only).
pub fn build<'a>(
    kind: LodMethod,
    scene: &'a MethodScene,
    options: &MethodOptions,
) -> anyhow::Result<Box<dyn Method + 'a>> {
    Ok(match kind {
        LodMethod::Entropy => Box::new(EntropyMethod::new(scene)),
        LodMethod::Tin => Box::new(TinMethod::new(scene)?),
        LodMethod::Geomorph if options.morph => {
            Box::new(GeomorphMethod::new(scene, MorphPath::Shader))
        }
        LodMethod::GeomorphStatic => Box::new(GeomorphMethod::new(scene, MorphPath::Static)),
        LodMethod::GeomorphCpu => Box::new(GeomorphMethod::new(scene, MorphPath::Cpu)),
        LodMethod::GeomorphPvs if options.morph => Box::new(GeomorphMethod::with_pvs(scene)),
        LodMethod::OutOfCore => {
            let Some(store) = &options.store else { anyhow::bail!("{OOC_NEEDS_STORE}") };
            let runtime = OocScene::new(store.clone(), scene.config.ooc);
            Box::new(OocMethod::measured(runtime, scene, options.ooc_wait)?)
        }
        _ => Box::new(MemoryMethod::new(scene, kind)),
    })
}

/// Whether `kind` draws a triangle mesh of its own (as the renderer's extra triangles over a
/// carrier patch), not tessellated patches: `entropy` and `tin`.
pub fn draws_mesh(kind: LodMethod) -> bool {
    matches!(kind, LodMethod::Entropy | LodMethod::Tin)
}

/// Whether `terrain bench` runs `kind` when no `--methods` are given: every method but the
/// geomorphing article's comparison paths (`geomorph-static`, `geomorph-cpu`: its Table 1;
/// `geomorph-pvs`: its PVS; `cargo xtask papers --paper geomorph`), which draw what
/// `geomorph` draws or a subset of it, and `dss-strips-pow2` (the DSS popping study, `cargo
/// xtask papers --paper dss`).
pub fn benched_by_default(kind: LodMethod) -> bool {
    !matches!(
        kind,
        LodMethod::GeomorphStatic
            | LodMethod::GeomorphCpu
            | LodMethod::GeomorphPvs
            | LodMethod::DssStripsPow2
    )
}

/// Whether `kind` draws from a baked store ([`MethodOptions::store`]).
pub fn needs_store(kind: LodMethod) -> bool {
    kind == LodMethod::OutOfCore
}

/// The swept parameter of `method`: its name and its full list of values, most detailed
/// first. `uniform`: the factor, `leaf_cells / 8 .. leaf_cells` (factor `leaf_cells` is full
/// resolution); PVPS: Eq. 8's `C1` (larger splits less); DSS: `rho_thr` in pixels.
pub fn sweep_values(method: LodMethod, leaf_cells: u32) -> (&'static str, Vec<f64>) {
    match method {
        LodMethod::Uniform => {
            let l = f64::from(leaf_cells.max(2));
            let mut v: Vec<f64> = [l, l / 2.0, l / 4.0, l / 8.0].map(|f| f.max(2.0)).to_vec();
            v.dedup();
            ("factor", v)
        }
        LodMethod::PvpsA | LodMethod::PvpsB | LodMethod::PvpsC => {
            ("C1", vec![12.5, 25.0, 50.0, 100.0, 200.0])
        }
        LodMethod::Dss1 | LodMethod::Dss2 | LodMethod::DssStrips | LodMethod::DssStripsPow2 => {
            ("rho_thr", vec![0.25, 0.5, 1.0, 2.0, 4.0, 8.0])
        }
        // E0 in percent of the largest entropy (the paper's 10..18 barely simplify at our
        // entropy scale; see `terrain_visibility::entropy::source::EntropyScale`). E0 = 0 is
        // the full-depth mesh, the uniform method's job, and seconds per frame: not swept.
        LodMethod::Entropy => ("E0", vec![18.0, 50.0, 70.0, 85.0, 95.0]),
        LodMethod::Geomorph
        | LodMethod::GeomorphStatic
        | LodMethod::GeomorphCpu
        | LodMethod::GeomorphPvs => ("tau_px", vec![0.5, 1.0, 2.0, 4.0, 8.0]),
        LodMethod::PvpsCPvs | LodMethod::PvpsCConservative => {
            ("C1", vec![12.5, 25.0, 50.0, 100.0, 200.0])
        }
        // Qiu 2013 Eq. 7 threshold, pixels (the paper's figures use 2).
        LodMethod::OutOfCore => ("tau", vec![0.5, 1.0, 2.0, 4.0, 8.0]),
        // Cesium's screen-space error threshold, pixels.
        LodMethod::Tin => ("tau_px", vec![0.5, 1.0, 2.0, 4.0, 8.0]),
    }
}

/// Sets `method`'s swept parameter in `config`.
pub fn apply_parameter(config: &mut MethodConfig, method: LodMethod, value: f64) {
    match method {
        LodMethod::Uniform => config.uniform_factor = value as f32,
        LodMethod::PvpsA | LodMethod::PvpsB | LodMethod::PvpsC => config.pvps.c1 = value,
        LodMethod::Dss1 | LodMethod::Dss2 | LodMethod::DssStrips | LodMethod::DssStripsPow2 => {
            config.dss.rho_thr = value
        }
        LodMethod::Entropy => config.entropy.e0 = value,
        LodMethod::Geomorph
        | LodMethod::GeomorphStatic
        | LodMethod::GeomorphCpu
        | LodMethod::GeomorphPvs => config.geomip.pixel_threshold = value,
        LodMethod::PvpsCPvs | LodMethod::PvpsCConservative => config.pvps.c1 = value,
        LodMethod::OutOfCore => config.ooc.tau = value,
        LodMethod::Tin => config.tin.tau_px = value,
    }
}

/// The current value of `method`'s swept parameter in `config` (what [`apply_parameter`]
/// sets).
pub fn parameter(config: &MethodConfig, method: LodMethod) -> f64 {
    match method {
        LodMethod::Uniform => f64::from(config.uniform_factor),
        LodMethod::PvpsA | LodMethod::PvpsB | LodMethod::PvpsC => config.pvps.c1,
        LodMethod::Dss1 | LodMethod::Dss2 | LodMethod::DssStrips | LodMethod::DssStripsPow2 => {
            config.dss.rho_thr
        }
        LodMethod::Entropy => config.entropy.e0,
        LodMethod::Geomorph
        | LodMethod::GeomorphStatic
        | LodMethod::GeomorphCpu
        | LodMethod::GeomorphPvs => config.geomip.pixel_threshold,
        LodMethod::PvpsCPvs | LodMethod::PvpsCConservative => config.pvps.c1,
        LodMethod::OutOfCore => config.ooc.tau,
        LodMethod::Tin => config.tin.tau_px,
    }
}

/// Whether `method`'s swept parameter is a screen-space error bound in pixels (what the
/// method promises about the drawn error), rather than a factor or a roughness constant.
pub fn parameter_is_pixels(method: LodMethod) -> bool {
    matches!(
        method,
        LodMethod::Dss1
            | LodMethod::Dss2
            | LodMethod::DssStrips
            | LodMethod::DssStripsPow2
            | LodMethod::Geomorph
            | LodMethod::GeomorphStatic
            | LodMethod::GeomorphCpu
            | LodMethod::GeomorphPvs
            | LodMethod::OutOfCore
            | LodMethod::Tin
    )
}

/// What the benchmark report says about how `method` is timed and measured, if anything
/// beyond the common notes.
pub fn note(method: LodMethod) -> Option<&'static str> {
    match method {
        LodMethod::Entropy => Some(
            "entropy: a triangle mesh, measured on the CPU and drawn as the renderer's extra \
             triangles (uploaded every frame); its selection time is the Eq. 5 cut, its \
             tessellation time the crack elimination and tile triangulation.",
        ),
        LodMethod::DssStripsPow2 => Some(
            "dss-strips-pow2: dss-strips with every block's factor rounded up to a power of two \
             (not the paper's: the test of whether the paper's sliding continuous factors make \
             the strips pop); the same blocks and strips.",
        ),
        LodMethod::GeomorphStatic => Some(
            "geomorph-static: the geomorphing article's Table 1 'static LOD': geomorph's patches \
             with tweening off (integer levels), drawn by the geomorph renderer at their true \
             heights (no morph in the vertex stage).",
        ),
        LodMethod::GeomorphCpu => Some(
            "geomorph-cpu: the geomorphing article's Table 1 'software morphing': geomorph's \
             levels and tweens, every vertex of every drawn patch morphed on the CPU each frame \
             (the morph's CPU reference, timed as the frame's build stage) and uploaded, drawn \
             by a pipeline that reads the heights and does not morph.",
        ),
        LodMethod::GeomorphPvs => Some(
            "geomorph-pvs: geomorph (morphed in the vertex shader) without the patches that the \
             conservative PVS proves hidden from the camera's view cell (the geomorphing \
             article's PVS step; the scene's PVS, or one baked in memory).",
        ),
        LodMethod::OutOfCore => Some(
            "ooc: blocks come from a store through the streamer. By default the flight is played \
             in real time at its own frame rate, every frame, paced in wall time (no rendering \
             between measured frames): no frame after the first waits for I/O, blocks are drawn \
             at their finest resident level and late data (needed, not resident when drawn) is \
             counted. Measured frames are measured and rendered while the flight's clock stops, \
             which gives the workers extra time before the next frames; the streaming summary \
             covers every played frame. With --wait every sampled frame waits until the levels \
             it needs are resident (warm), so its error is the selection's; sampled frames are \
             then further apart than the flight's frame rate, so Eq. 8's speed is overestimated.",
        ),
        LodMethod::Tin => Some(
            "tin: tiles of an error-bounded TIN pyramid (greedy Delaunay per tile, verified), \
             chosen by Cesium's screen-space error; a triangle mesh (tiles and the stitches \
             where levels meet, the stitches without plan area) measured on the CPU and drawn \
             as the renderer's extra triangles (uploaded every frame); its selection time is \
             the traversal, its tessellation time the joining of the tiles and stitches.",
        ),
        _ => None,
    }
}

/// A method's colour in the plots: one per method (with [`marker`], no two methods share
/// the pair; tested).
pub fn colour(m: LodMethod) -> &'static str {
    match m {
        LodMethod::Uniform => "#222222",
        LodMethod::PvpsA => "#1f77b4",
        LodMethod::PvpsB => "#2ca02c",
        LodMethod::PvpsC => "#d62728",
        LodMethod::Dss1 => "#9467bd",
        LodMethod::Dss2 => "#ff7f0e",
        LodMethod::Entropy => "#8c564b",
        LodMethod::Geomorph => "#e377c2",
        LodMethod::PvpsCPvs => "#bcbd22",
        LodMethod::PvpsCConservative => "#17becf",
        LodMethod::DssStrips => "#393b79",
        LodMethod::DssStripsPow2 => "#637939",
        LodMethod::OutOfCore => "#6b8e23",
        LodMethod::Tin => "#b8860b",
        LodMethod::GeomorphStatic => "#f7b6d2",
        LodMethod::GeomorphCpu => "#c49c94",
        LodMethod::GeomorphPvs => "#7b4173",
    }
}

/// A plot marker's shape.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Marker {
    /// A filled circle.
    Circle,
    /// A filled square.
    Square,
    /// A filled triangle, point up.
    Triangle,
    /// A filled diamond.
    Diamond,
    /// A filled triangle, point down.
    TriangleDown,
    /// An open circle (a ring).
    Ring,
}

/// A method's marker in the plots (with [`colour`], no two methods share the pair).
pub fn marker(m: LodMethod) -> Marker {
    match m {
        LodMethod::Uniform => Marker::Square,
        LodMethod::PvpsA
        | LodMethod::Geomorph
        | LodMethod::GeomorphStatic
        | LodMethod::GeomorphCpu
        | LodMethod::GeomorphPvs => Marker::Triangle,
        LodMethod::PvpsB | LodMethod::DssStrips | LodMethod::DssStripsPow2 => Marker::Diamond,
        LodMethod::PvpsC | LodMethod::Tin => Marker::Circle,
        LodMethod::Dss1 | LodMethod::OutOfCore => Marker::TriangleDown,
        LodMethod::Dss2 | LodMethod::Entropy => Marker::Ring,
        LodMethod::PvpsCPvs | LodMethod::PvpsCConservative => Marker::Square,
    }
}

/// The `--quality` presets: each is a screen-space error target in pixels
/// ([`Quality::error_px`]), mapped onto every method's own parameter by
/// [`params_for_error_px`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Quality {
    /// 4 px.
    Fast,
    /// 2 px: the default of `render`, `fly` and `mesh --camera` when no quality option and no
    /// own parameter of the method is given.
    Balanced,
    /// 1 px.
    Best,
}

impl Quality {
    /// The preset of a command given no quality option and no own parameter of the method.
    pub const DEFAULT: Quality = Quality::Balanced;

    /// The preset's screen-space error target, pixels.
    pub fn error_px(self) -> f64 {
        match self {
            Quality::Fast => 4.0,
            Quality::Balanced => 2.0,
            Quality::Best => 1.0,
        }
    }
}

/// The view a pixel target refers to: the viewport's height and vertical field of view (the
/// `lambda = H / (2 tan(fov / 2))` of every screen-error formula here).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ErrorView {
    /// Viewport height, pixels.
    pub height_px: f64,
    /// Vertical field of view, degrees.
    pub fov_y_deg: f64,
}

impl ErrorView {
    /// The view the calibrations were measured in: 1280 x 720, 60 degrees (the benchmark's).
    pub const REFERENCE: ErrorView = ErrorView { height_px: 720.0, fov_y_deg: 60.0 };

    /// `lambda`: pixels per radian-ish unit of `delta / d` (DSS Eq. 3, out-of-core Eq. 6).
    pub fn lambda(&self) -> f64 {
        terrain_core::metrics::screen::lambda(self.height_px, self.fov_y_deg.to_radians())
    }

    /// `lambda` relative to the reference view's: a pixel target in this view is the target
    /// divided by this in the reference view (errors in pixels scale with `lambda`).
    fn scale(&self) -> f64 {
        let s = self.lambda() / Self::REFERENCE.lambda();
        if s.is_finite() && s > 0.0 { s } else { 1.0 }
    }
}

/// How a method's parameter follows from the pixel target.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ErrorPxBasis {
    /// The parameter is a screen-space error in pixels already (geomorph's and ooc's tau).
    Direct,
    /// Through the method's own model linking its parameter to a screen error (DSS Eq. 3,
    /// PVPS Eq. 12), with a measured correction where the model's error is not the measured
    /// p99 (see [`params_for_error_px`]).
    Model,
    /// No model: a fit measured on the shared flights (see [`params_for_error_px`]).
    Calibrated,
}

/// A method's own parameter for a pixel target ([`params_for_error_px`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ErrorPxParams {
    /// The method.
    pub method: LodMethod,
    /// The target, pixels.
    pub error_px: f64,
    /// The parameter's name (as [`sweep_values`] names it; PVPS: `C3`).
    pub parameter: &'static str,
    /// Its value.
    pub value: f64,
    /// How it was derived.
    pub basis: ErrorPxBasis,
}

impl ErrorPxParams {
    /// Sets the parameter in `config` (PVPS: Eq. 12's `C3`, and Algorithm 1's `Constant =
    /// C3 C4` with it, so a flat patch keeps equal inner and outer factors).
    pub fn apply(&self, config: &mut MethodConfig) {
        match self.method {
            LodMethod::PvpsA
            | LodMethod::PvpsB
            | LodMethod::PvpsC
            | LodMethod::PvpsCPvs
            | LodMethod::PvpsCConservative => {
                config.pvps.c3 = self.value;
                config.pvps.outer_constant = self.value * config.pvps.c4;
            }
            // The store's calibration when it has one for the configured refinement, else the
            // shared one of the configured split rule and segment floor (`ooc_p99_per_tau`).
            LodMethod::OutOfCore => config.ooc.tau = config.ooc.tau_for_error_px(self.error_px).0,
            m => apply_parameter(config, m, self.value),
        }
    }
}

impl ErrorPxParams {
    /// Sets the parameter in `config` ([`ErrorPxParams::apply`]) and records the value set:
    /// `ooc`'s tau follows the configured calibration and split rule
    /// ([`crate::ooc::OocConfig::tau_for_error_px`]), not [`params_for_error_px`]'s shared map.
    pub fn apply_recorded(&mut self, config: &mut MethodConfig) {
        self.apply(config);
        if self.method == LodMethod::OutOfCore {
            self.value = config.ooc.tau;
        }
    }
}

impl std::fmt::Display for ErrorPxParams {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let how = match self.basis {
            ErrorPxBasis::Direct => "its own pixel threshold",
            ErrorPxBasis::Model => "through its screen-error model",
            ErrorPxBasis::Calibrated => "by a measured calibration",
        };
        write!(
            f,
            "{}: {} = {:.4} for {} px ({how})",
            self.method.name(),
            self.parameter,
            self.value,
            self.error_px
        )
    }
}

/// `method`'s own parameter for a screen-space error target of `error_px` pixels in `view`:
/// the one mapping behind `--error-px` and `--quality` (README "One quality knob" has the
/// table with the measured figures; `cargo run --release -p terrain-app --example
/// error_px_calibration` measures the fits below).
///
/// - `geomorph` (`tau_px`): the parameter is a pixel threshold already (the projected
///   max-error vertex of the drawn level, Wagner 2003): the target itself. It bounds the
///   *largest* error of a patch, so the measured p99 lies below the target (about 0.45 of it).
/// - `ooc` (`tau`): out-of-core Eq. 6-7 is a pixel threshold on each patch's `StaticE`
///   (Eq. 3-5, the largest midpoint deviation below it), not on the drawn error; `tau` is the
///   target over the largest measured p99 per pixel of `tau` ([`ooc_p99_per_tau`], by split
///   rule and segment floor: [`ErrorPxParams::apply`] uses the configured ones).
/// - `dss-1`, `dss-2`, `dss-strips` (`rho_thr`): DSS Eq. 3 projects a block's *mean*
///   object-space error (section 3.3.1), so `rho_thr` bounds the mean, not the p99 that is
///   measured. Measured on Puget Sound 1k (two shipped flights, `rho_thr` 0.25-8): p99 =
///   [`DSS_P99_AT_RHO_1`] `rho_thr ^` [`DSS_P99_EXPONENT`] for all three; inverted here.
/// - `pvps-*` (`C3`): Eq. 12 sets a patch's inner factor to `C3 x ScreenSpaceLength x
///   (RoughnessValue + C4)`, the screen length in NDC (2 = the viewport's height): a flat
///   patch's tessellated segments are `s = H / (2 C3 C4)` pixels long. A segment's error grows
///   with its length; measured (Puget Sound 1k, methods A and C, `C3` 5-160): p99 =
///   [`PVPS_P99_AT_SEGMENT_1PX`] `s ^` [`PVPS_P99_EXPONENT`]; inverted for `s`, then
///   `C3 = H / (2 C4 s)` (Algorithm 1's `Constant = C3 C4` with it).
/// - `tin` (`tau_px`): Cesium's screen-space error `e_L lambda / d` of each drawn tile is at
///   most `tau_px`, and it bounds the projected error of every sample of the tile (its
///   error is at most `e_L`, its distance at least `d`), so `tau_px` bounds the largest
///   pixel error and the measured p99 lies below it: `tau_px` is the target over the
///   largest measured p99 per pixel of `tau_px` ([`TIN_P99_PER_TAU`]).
/// - `uniform` (factor) and `entropy` (`E0`): no model links the parameter to a screen error
///   (a uniform factor's error depends on how near the terrain is; Eq. 5's `E0` is an entropy
///   threshold): measured calibrations, [`UNIFORM_P99_PER_CELL_PX`] pixels of p99 per cell of
///   tessellated segment, and `E0` interpolated in [`ENTROPY_E0_BY_P99`] (entropy cannot go
///   below about 1 px at its finest `E0`, 10; smaller targets get `E0 = 10`).
///
/// The fits were measured at 1280 x 720 and 60 degrees ([`ErrorView::REFERENCE`]); another
/// view's target is first scaled by `lambda` (screen errors are `lambda delta / d`, and so are
/// `rho_thr` and the uniform and entropy errors), and `C3` (NDC) needs no scaling.
pub fn params_for_error_px(method: LodMethod, error_px: f64, view: ErrorView) -> ErrorPxParams {
    let px = if error_px.is_finite() && error_px > 0.0 { error_px } else { 1.0 };
    let scale = view.scale();
    let reference_px = px / scale;
    let leaf = f64::from(MethodConfig::default().leaf_cells);
    let (parameter, value, basis) = match method {
        LodMethod::Geomorph
        | LodMethod::GeomorphStatic
        | LodMethod::GeomorphCpu
        | LodMethod::GeomorphPvs => ("tau_px", px, ErrorPxBasis::Direct),
        LodMethod::OutOfCore => (
            "tau",
            px / ooc_p99_per_tau(DEFAULT_SPLIT, DEFAULT_MAX_SEGMENT_CELLS),
            ErrorPxBasis::Calibrated,
        ),
        LodMethod::Dss1 | LodMethod::Dss2 | LodMethod::DssStrips | LodMethod::DssStripsPow2 => {
            let rho = (reference_px / DSS_P99_AT_RHO_1).powf(1.0 / DSS_P99_EXPONENT);
            ("rho_thr", rho * scale, ErrorPxBasis::Model)
        }
        LodMethod::PvpsA
        | LodMethod::PvpsB
        | LodMethod::PvpsC
        | LodMethod::PvpsCPvs
        | LodMethod::PvpsCConservative => {
            let c4 = terrain_core::lod::PvpsConfig::default().c4;
            let segment_px = (reference_px / PVPS_P99_AT_SEGMENT_1PX).powf(1.0 / PVPS_P99_EXPONENT);
            ("C3", ErrorView::REFERENCE.height_px / (2.0 * c4 * segment_px), ErrorPxBasis::Model)
        }
        LodMethod::Uniform => {
            // Segment length in cells for the target, as a factor of a leaf.
            let cells = reference_px / UNIFORM_P99_PER_CELL_PX;
            ("factor", (leaf / cells).clamp(2.0, leaf), ErrorPxBasis::Calibrated)
        }
        LodMethod::Entropy => ("E0", entropy_e0(reference_px), ErrorPxBasis::Calibrated),
        // Cesium's SSE is in the camera's own pixels (lambda of the view): no scaling.
        LodMethod::Tin => ("tau_px", px / TIN_P99_PER_TAU, ErrorPxBasis::Calibrated),
    };
    ErrorPxParams { method, error_px: px, parameter, value, basis }
}

/// `ooc`: the measured p99 (pixels) per pixel of Eq. 7's `tau` under `split` and the segment
/// floor `max_segment_cells` (`Refinement::max_segment_cells`; 0: none): the largest ratio
/// over `terrain bench --values 0.5,0.7,1,1.4,2,2.8,4 --wait` (`tau` swept) on
/// `flights/pvps_884.json` (6 frames) on Puget Sound 1k, N42E001, the synthetic 1025^2 grid
/// and Big Tujunga (bench/ooc/README.md, "The cost split as an option" and "The segment floor
/// as the default"). Eq. 7 bounds each patch's `StaticE`, not the drawn error; the ratio
/// varies by DEM and `tau` (28 points each: Eq. 7 alone 0.08-0.81, median 0.50, lowest on the
/// synthetic grid at small `tau`; Eq. 7 with 16-cell segments at most 0.08-0.60, median 0.50:
/// the floor draws the far patches that set the largest ratios finer; the cost split
/// 0.71-1.16, median 1.06). The largest, not the median: with the median the p99 of N42E001
/// at 2 px measured 3.27 px (1.6x the target); with the largest, every measured DEM stays at
/// or under the target, and the smoother ones are drawn finer than they need. The cost split
/// with a floor was not measured: it takes the cost split's ratio (a floor only draws
/// patches finer, so the p99 stays at or under the target).
pub fn ooc_p99_per_tau(split: SplitRule, max_segment_cells: u32) -> f64 {
    ooc_p99_per_tau_spread(split, max_segment_cells).1
}

/// `ooc`: the smallest and largest measured p99 per pixel of `tau` under `split` and the
/// segment floor over the four DEMs of [`ooc_p99_per_tau`] (bench/ooc/README.md): what a
/// store without its own calibration ([`crate::ooc_calibration`]) can expect, the target
/// times `low / largest` to the target.
pub fn ooc_p99_per_tau_spread(split: SplitRule, max_segment_cells: u32) -> (f64, f64) {
    match (split, max_segment_cells > 0) {
        (SplitRule::Eq7, false) => (0.08, OOC_P99_PER_TAU_EQ7),
        (SplitRule::Eq7, true) => (0.08, OOC_P99_PER_TAU_EQ7_FLOOR),
        (SplitRule::Cost, _) => (0.71, OOC_P99_PER_TAU_COST),
    }
}

/// `tin`: the measured p99 (pixels) per pixel of Cesium's SSE threshold `tau_px` (see
/// [`params_for_error_px`]): the largest median p99 over `tau_px` of `terrain bench
/// --methods tin --error-px 0.5,1,2,4` (then `tau_px` = target) on `flights/pvps_884.json`
/// (6 frames) over Puget Sound 1k: 0.64, 0.57, 0.43, 0.35 (README, "The `tin` method").
pub const TIN_P99_PER_TAU: f64 = 0.64;

/// [`ooc_p99_per_tau`] under Eq. 7 alone.
const OOC_P99_PER_TAU_EQ7: f64 = 0.81;

/// [`ooc_p99_per_tau`] under Eq. 7 with a segment floor (measured with 16 cells).
const OOC_P99_PER_TAU_EQ7_FLOOR: f64 = 0.60;

/// [`ooc_p99_per_tau`] under the cost split.
const OOC_P99_PER_TAU_COST: f64 = 1.16;

/// DSS: the measured median p99 (pixels) at `rho_thr = 1` (see [`params_for_error_px`]).
pub const DSS_P99_AT_RHO_1: f64 = 2.8;

/// DSS: the exponent of the measured p99 against `rho_thr`.
pub const DSS_P99_EXPONENT: f64 = 0.71;

/// PVPS: the measured median p99 (pixels) for Eq. 12 segments of 1 pixel.
pub const PVPS_P99_AT_SEGMENT_1PX: f64 = 0.30;

/// PVPS: the exponent of the measured p99 against the Eq. 12 segment length.
pub const PVPS_P99_EXPONENT: f64 = 0.77;

/// `uniform`: measured p99 pixel error per cell of tessellated segment (reference view).
pub const UNIFORM_P99_PER_CELL_PX: f64 = 0.46;

/// `entropy`: measured median p99 (pixels, reference view) against `E0`, both increasing.
pub const ENTROPY_E0_BY_P99: [(f64, f64); 6] =
    [(1.02, 10.0), (1.31, 18.0), (1.76, 30.0), (2.87, 50.0), (5.67, 70.0), (9.9, 85.0)];

/// `E0` for a p99 target by log-linear interpolation in [`ENTROPY_E0_BY_P99`], clamped to its
/// ends.
fn entropy_e0(px: f64) -> f64 {
    let t = &ENTROPY_E0_BY_P99;
    if px <= t[0].0 {
        return t[0].1;
    }
    for w in t.windows(2) {
        let ((p0, e0), (p1, e1)) = (w[0], w[1]);
        if px <= p1 {
            let f = (px.ln() - p0.ln()) / (p1.ln() - p0.ln());
            return e0 + f * (e1 - e0);
        }
    }
    t[t.len() - 1].1
}

/// The methods' settings with `method`'s parameter from the default preset
/// ([`Quality::DEFAULT`]) in `view`: what `render`, `fly` and `mesh --camera` draw when given
/// no quality option and no own parameter.
pub fn default_config(method: LodMethod, view: ErrorView) -> MethodConfig {
    let mut config = MethodConfig::default();
    params_for_error_px(method, Quality::DEFAULT.error_px(), view).apply(&mut config);
    config
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A larger target never asks for more detail: each method's parameter moves towards
    /// coarser as the target grows (uniform's factor and PVPS's C3 down, the thresholds up).
    #[test]
    fn parameters_coarsen_as_the_target_grows() {
        let targets = [0.25, 0.5, 1.0, 2.0, 4.0, 8.0];
        for m in LodMethod::ALL {
            let v: Vec<f64> = targets
                .iter()
                .map(|&px| params_for_error_px(m, px, ErrorView::REFERENCE).value)
                .collect();
            // Uniform's factor and PVPS's C3 grow with detail; the thresholds shrink.
            let parameter = params_for_error_px(m, 1.0, ErrorView::REFERENCE).parameter;
            let finer_is_larger = parameter == "factor" || parameter == "C3";
            for w in v.windows(2) {
                let ok = if finer_is_larger { w[1] <= w[0] } else { w[1] >= w[0] };
                assert!(ok, "{m:?}: {v:?}");
            }
            assert!(v.iter().all(|x| x.is_finite() && *x > 0.0), "{m:?}: {v:?}");
        }
    }

    /// Geomorph's pixel threshold is the target itself; ooc's `tau` and the DSS and PVPS fits
    /// invert to the measured p99 they were fitted to.
    #[test]
    fn mappings_invert_their_fits() {
        let view = ErrorView::REFERENCE;
        for px in [0.5, 1.0, 3.0] {
            assert_eq!(params_for_error_px(LodMethod::Geomorph, px, view).value, px);
            // ooc: the target over the measured p99 per pixel of tau, by split rule and
            // segment floor (Eq. 7's differs with the floor: the key is not vacuous).
            let tau = params_for_error_px(LodMethod::OutOfCore, px, view).value;
            let shared = ooc_p99_per_tau(DEFAULT_SPLIT, DEFAULT_MAX_SEGMENT_CELLS);
            assert!((tau * shared - px).abs() < 1e-9, "{px} {tau}");
            let mut taus = Vec::new();
            for split in [SplitRule::Eq7, SplitRule::Cost] {
                for floor in [0, 16] {
                    let mut c = MethodConfig::default();
                    c.ooc.split = split;
                    c.ooc.max_segment_cells = floor;
                    params_for_error_px(LodMethod::OutOfCore, px, view).apply(&mut c);
                    let r = ooc_p99_per_tau(split, floor);
                    assert!((c.ooc.tau * r - px).abs() < 1e-9, "{split:?} {floor}");
                    taus.push(c.ooc.tau);
                }
            }
            assert!(taus[1] > taus[0] * 1.2, "Eq. 7's floor: {taus:?}");
            // With a store's calibration of the configured refinement: its map, not the
            // shared one (whose tau differs at these points).
            let mut c = MethodConfig::default();
            let store = crate::ooc_calibration::TerrainId { width: 9, height: 9, k: 3, bake_id: 1 };
            let fit = [(1.0, 0.5), (4.0, 2.0), (16.0, 3.0)];
            let cal = crate::ooc_calibration::Calibration::fit(store, c.ooc.refinement(), 1, &fit)
                .expect("a fit");
            c.ooc.calibration = Some(cal);
            params_for_error_px(LodMethod::OutOfCore, px, view).apply(&mut c);
            assert!((c.ooc.tau - cal.tau_for(px)).abs() < 1e-12, "{px}");
            assert!(
                (c.ooc.tau - px / ooc_p99_per_tau(DEFAULT_SPLIT, DEFAULT_MAX_SEGMENT_CELLS)).abs()
                    > 0.1,
                "{px}"
            );
            let rho = params_for_error_px(LodMethod::Dss1, px, view).value;
            let p99 = DSS_P99_AT_RHO_1 * rho.powf(DSS_P99_EXPONENT);
            assert!((p99 - px).abs() < 1e-9, "{px} {rho} {p99}");
            let c3 = params_for_error_px(LodMethod::PvpsC, px, view).value;
            let segment = view.height_px / (2.0 * c3);
            let p99 = PVPS_P99_AT_SEGMENT_1PX * segment.powf(PVPS_P99_EXPONENT);
            assert!((p99 - px).abs() < 1e-9, "{px} {c3} {p99}");
        }
        // Entropy's table ends clamp; its points are met exactly.
        assert_eq!(params_for_error_px(LodMethod::Entropy, 0.1, view).value, 10.0);
        assert_eq!(params_for_error_px(LodMethod::Entropy, 100.0, view).value, 85.0);
        assert!((params_for_error_px(LodMethod::Entropy, 2.87, view).value - 50.0).abs() < 1e-9);
    }

    /// A view twice as tall in pixels (same fov) selects what the reference view selects at
    /// half the target: `rho_thr` doubles with the view for the same selection, C3 (NDC) stays.
    #[test]
    fn other_views_scale_by_lambda() {
        let big = ErrorView { height_px: 1440.0, fov_y_deg: 60.0 };
        let r = ErrorView::REFERENCE;
        let dss = |v, px| params_for_error_px(LodMethod::Dss2, px, v).value;
        assert!((dss(big, 2.0) - 2.0 * dss(r, 1.0)).abs() < 1e-9);
        let c3 = |v, px| params_for_error_px(LodMethod::PvpsB, px, v).value;
        assert!((c3(big, 2.0) - c3(r, 1.0)).abs() < 1e-9);
        let f = |v, px| params_for_error_px(LodMethod::Uniform, px, v).value;
        assert!((f(big, 2.0) - f(r, 1.0)).abs() < 1e-9);
    }

    /// Applying a mapping sets the named parameter (PVPS: C3 and Algorithm 1's constant).
    #[test]
    fn apply_sets_the_parameter() {
        let mut c = MethodConfig::default();
        let p = params_for_error_px(LodMethod::PvpsC, 1.0, ErrorView::REFERENCE);
        p.apply(&mut c);
        assert_eq!(c.pvps.c3, p.value);
        assert_eq!(c.pvps.outer_constant, p.value * c.pvps.c4);
        let p = params_for_error_px(LodMethod::DssStrips, 1.0, ErrorView::REFERENCE);
        p.apply(&mut c);
        assert_eq!(c.dss.rho_thr, p.value);
        let p = params_for_error_px(LodMethod::Uniform, 1.0, ErrorView::REFERENCE);
        p.apply(&mut c);
        assert_eq!(c.uniform_factor, p.value as f32);
        let tau = default_config(LodMethod::OutOfCore, ErrorView::REFERENCE).ooc.tau;
        assert_eq!(
            tau,
            Quality::DEFAULT.error_px() / ooc_p99_per_tau(DEFAULT_SPLIT, DEFAULT_MAX_SEGMENT_CELLS)
        );
    }
}
