//! The one quality knob of `render`, `fly` and `mesh --camera`: `--error-px` (a screen-space
//! error target in pixels) or a `--quality` preset, mapped onto the method's own parameter by
//! the method registry ([`registry::params_for_error_px`]); or the method's own parameter
//! (`--method-param`, and the commands' own `--factor` and `--tau`), never both.

use anyhow::bail;
use clap::Args;
use terrain_app::method::registry::{
    self, ErrorPxParams, ErrorView, Quality, apply_parameter, sweep_values,
};
use terrain_app::methods::{LodMethod, MethodConfig};
use terrain_app::ooc_calibration::TauSource;

/// The quality options every drawing command shares.
#[derive(Debug, Clone, Args)]
pub(crate) struct QualityArgs {
    /// Screen-space error target, pixels (of the image's height and field of view), mapped
    /// onto the method's own parameter (README: "One quality knob"). Not with the method's
    /// own parameter (--method-param, --factor, --tau).
    #[arg(long, conflicts_with = "quality")]
    pub error_px: Option<f64>,
    /// A preset error target: fast (4 px), balanced (2 px), best (1 px). Without any quality
    /// option or own parameter, balanced.
    #[arg(long, value_enum)]
    pub quality: Option<Quality>,
    /// The method's own parameter, the one `terrain bench` sweeps: uniform's factor, pvps-*'s
    /// Eq. 8 C1, dss-*'s rho_thr (px), entropy's E0, geomorph's tau (px), ooc's tau (px).
    #[arg(long)]
    pub method_param: Option<f64>,
}

impl QualityArgs {
    /// The pixel target asked for, and the option that asked (`None`: neither).
    fn knob(&self) -> anyhow::Result<Option<(&'static str, f64)>> {
        if let Some(px) = self.error_px {
            if !(px.is_finite() && px > 0.0) {
                bail!("--error-px must be a positive number of pixels, got {px}");
            }
            return Ok(Some(("--error-px", px)));
        }
        Ok(self.quality.map(|q| ("--quality", q.error_px())))
    }

    /// Sets `method`'s parameter in `config`: the pixel target's mapping (the default preset
    /// when nothing is given; `ooc`: through `config.ooc.calibration`, the store's, when set),
    /// or the own parameter. `own` names the command's own parameter
    /// options and whether each was given (`--factor`, `--tau`); the caller applies those.
    /// Giving a quality option and an own parameter is refused, naming both. Returns the
    /// mapping when one was applied.
    pub(crate) fn apply(
        &self,
        config: &mut MethodConfig,
        method: LodMethod,
        view: ErrorView,
        own: &[(&'static str, bool)],
    ) -> anyhow::Result<Option<ErrorPxParams>> {
        let knob = self.knob()?;
        let mut given: Vec<&str> = own.iter().filter(|(_, g)| *g).map(|(n, _)| *n).collect();
        if self.method_param.is_some() {
            given.push("--method-param");
        }
        if let (Some((name, _)), Some(first)) = (knob, given.first()) {
            let (parameter, _) = sweep_values(method, config.leaf_cells);
            bail!(
                "{first} and {name} both set the quality of {} ({first} its own parameter, \
                 {name} through the error target mapped onto its {parameter}): give one of them",
                method.name()
            );
        }
        if let Some(v) = self.method_param {
            if !(v.is_finite() && v > 0.0) {
                bail!("--method-param must be a positive number, got {v}");
            }
            apply_parameter(config, method, v);
            return Ok(None);
        }
        if !given.is_empty() {
            return Ok(None);
        }
        let px = knob.map_or(Quality::DEFAULT.error_px(), |(_, px)| px);
        let mut params = registry::params_for_error_px(method, px, view);
        params.apply_recorded(config);
        if method == LodMethod::OutOfCore {
            // The store's calibration when it has one for this refinement.
            let (_, source) = config.ooc.tau_for_error_px(px);
            println!(
                "ooc calibration: {}",
                match source {
                    TauSource::Store => "the store's (ooc-calibration.txt)",
                    TauSource::Shared =>
                        "the shared one (the store has none for this refinement: `terrain calibrate STORE` measures it)",
                }
            );
        }
        Ok(Some(params))
    }
}
