//! Everything the callers need to know about each method, in one place: how it is built
//! ([`build`]), its swept parameter and values ([`sweep_values`], [`apply_parameter`]), its
//! plot colour ([`colour`]), what the benchmark report says about how it is timed ([`note`])
//! and whether it draws from a store ([`needs_store`]). `render`, `fly` and `bench` hold no
//! per-method cases.

use std::sync::Arc;

use super::{EntropyMethod, GeomorphMethod, MemoryMethod, Method, OocMethod, OocWait};
use crate::methods::{LodMethod, MethodConfig, MethodScene};
use crate::ooc::OocScene;

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
        LodMethod::Geomorph if options.morph => Box::new(GeomorphMethod::new(scene)),
        LodMethod::OutOfCore => {
            let Some(store) = &options.store else { anyhow::bail!("{OOC_NEEDS_STORE}") };
            let runtime = OocScene::new(store.clone(), scene.config.ooc);
            Box::new(OocMethod::measured(runtime, scene, options.ooc_wait)?)
        }
        _ => Box::new(MemoryMethod::new(scene, kind)),
    })
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
        LodMethod::Dss1 | LodMethod::Dss2 | LodMethod::DssStrips => {
            ("rho_thr", vec![0.25, 0.5, 1.0, 2.0, 4.0, 8.0])
        }
        // E0 in percent of the largest entropy (the paper's 10..18 barely simplify at our
        // entropy scale; see `terrain_visibility::entropy::source::EntropyScale`). E0 = 0 is
        // the full-depth mesh, the uniform method's job, and seconds per frame: not swept.
        LodMethod::Entropy => ("E0", vec![18.0, 50.0, 70.0, 85.0, 95.0]),
        LodMethod::Geomorph => ("tau_px", vec![0.5, 1.0, 2.0, 4.0, 8.0]),
        LodMethod::PvpsCPvs | LodMethod::PvpsCConservative => {
            ("C1", vec![12.5, 25.0, 50.0, 100.0, 200.0])
        }
        // Qiu 2013 Eq. 7 threshold, pixels (the paper's figures use 2).
        LodMethod::OutOfCore => ("tau", vec![0.5, 1.0, 2.0, 4.0, 8.0]),
    }
}

/// Sets `method`'s swept parameter in `config`.
pub fn apply_parameter(config: &mut MethodConfig, method: LodMethod, value: f64) {
    match method {
        LodMethod::Uniform => config.uniform_factor = value as f32,
        LodMethod::PvpsA | LodMethod::PvpsB | LodMethod::PvpsC => config.pvps.c1 = value,
        LodMethod::Dss1 | LodMethod::Dss2 | LodMethod::DssStrips => config.dss.rho_thr = value,
        LodMethod::Entropy => config.entropy.e0 = value,
        LodMethod::Geomorph => config.geomip.pixel_threshold = value,
        LodMethod::PvpsCPvs | LodMethod::PvpsCConservative => config.pvps.c1 = value,
        LodMethod::OutOfCore => config.ooc.tau = value,
    }
}

/// The current value of `method`'s swept parameter in `config` (what [`apply_parameter`]
/// sets).
pub fn parameter(config: &MethodConfig, method: LodMethod) -> f64 {
    match method {
        LodMethod::Uniform => f64::from(config.uniform_factor),
        LodMethod::PvpsA | LodMethod::PvpsB | LodMethod::PvpsC => config.pvps.c1,
        LodMethod::Dss1 | LodMethod::Dss2 | LodMethod::DssStrips => config.dss.rho_thr,
        LodMethod::Entropy => config.entropy.e0,
        LodMethod::Geomorph => config.geomip.pixel_threshold,
        LodMethod::PvpsCPvs | LodMethod::PvpsCConservative => config.pvps.c1,
        LodMethod::OutOfCore => config.ooc.tau,
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
            | LodMethod::Geomorph
            | LodMethod::OutOfCore
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
        _ => None,
    }
}

/// A method's colour in the plots.
pub fn colour(m: LodMethod) -> &'static str {
    match m {
        LodMethod::Uniform => "#555555",
        LodMethod::PvpsA => "#1f77b4",
        LodMethod::PvpsB => "#2ca02c",
        LodMethod::PvpsC => "#d62728",
        LodMethod::Dss1 => "#9467bd",
        LodMethod::Dss2 => "#ff7f0e",
        LodMethod::Entropy => "#8c564b",
        LodMethod::Geomorph => "#e377c2",
        LodMethod::PvpsCPvs => "#bcbd22",
        LodMethod::PvpsCConservative => "#17becf",
        LodMethod::DssStrips => "#7f7f7f",
        LodMethod::OutOfCore => "#aec7e8",
    }
}
