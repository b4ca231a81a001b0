//! `terrain calibrate STORE`: measures the out-of-core method's p99 pixel error against Eq. 7's
//! `tau` on the store and writes the map `--error-px` then uses for it
//! ([`terrain_app::ooc_calibration`]), `ooc-calibration.txt` in the store's folder by default;
//! `terrain bake` calls the same for large grids.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;
use terrain_app::ooc::OocConfig;
use terrain_app::ooc_calibration::{
    self, CalibrateOptions, Calibration, DEFAULT_TAUS, FILE_NAME, parse_split, split_name,
};

/// Arguments of `terrain calibrate`.
#[derive(Debug, Args)]
pub(crate) struct CalibrateArgs {
    /// The baked store (a folder written by `terrain bake`).
    pub store: PathBuf,
    /// The calibration's file [default: STORE/ooc-calibration.txt, which `render`, `fly`,
    /// `view` and `bench` read].
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    #[command(flatten)]
    pub refine: RefineArgs,
    /// Eq. 7's tau values measured, pixels, comma-separated [default: 0.5,1,2,4,8,16].
    #[arg(long, value_delimiter = ',')]
    pub taus: Vec<f64>,
    /// Frames of the flight (flights/pvps_884.json resolved onto the terrain) per tau.
    #[arg(long, default_value_t = CalibrateOptions::default().frames)]
    pub frames: usize,
    /// A store wider or taller than this many samples is measured on a window of whole blocks
    /// at its centre (the measurement holds the window's grid in memory).
    #[arg(long, default_value_t = CalibrateOptions::default().window)]
    pub window: usize,
}

/// The refinement a calibration is measured under (the ooc method's selection settings).
#[derive(Debug, Clone, Args)]
pub(crate) struct RefineArgs {
    /// The split rule inside the blocks, `eq7` (Eq. 7 alone) or `cost` [default: the ooc
    /// method's default].
    #[arg(long)]
    pub ooc_split: Option<String>,
    /// The smallest patch, cells per side (a power of two) [default: the ooc method's].
    #[arg(long)]
    pub ooc_patch_cells: Option<u32>,
    /// The cost split's screen-size floor, pixels [default: the ooc method's].
    #[arg(long)]
    pub ooc_cost_px: Option<u32>,
    /// The coarsest segment a drawn patch may have, cells (0: none) [default: the ooc
    /// method's].
    #[arg(long)]
    pub ooc_max_segment_cells: Option<u32>,
}

impl RefineArgs {
    /// The default ooc settings with these options applied, checked.
    pub(crate) fn config(&self) -> anyhow::Result<OocConfig> {
        let mut c = OocConfig::default();
        if let Some(s) = &self.ooc_split {
            c.split = parse_split(s)
                .with_context(|| format!("--ooc-split must be eq7 or cost, got {s:?}"))?;
        }
        if let Some(cells) = self.ooc_patch_cells {
            if !cells.is_power_of_two() {
                bail!("--ooc-patch-cells must be a power of two, got {cells}");
            }
            c.patch_cells = cells;
        }
        if let Some(px) = self.ooc_cost_px {
            c.cost_split_px = px;
        }
        if let Some(cells) = self.ooc_max_segment_cells {
            c.max_segment_cells = crate::bench_cli::max_segment_cells(cells)?;
        }
        Ok(c)
    }
}

/// Calibrates the store in `dir` under `config`'s refinement and writes the file to `output`
/// (default [`FILE_NAME`] in `dir`), printing what it measured.
pub(crate) fn calibrate_and_write(
    dir: &Path,
    output: Option<&Path>,
    config: &OocConfig,
    options: &CalibrateOptions,
) -> anyhow::Result<Calibration> {
    let start = std::time::Instant::now();
    let r = config.refinement();
    eprintln!(
        "calibrating ooc on {} ({} split, {}-cell patches, floor {} px, segment floor {} cells): \
         tau {:?}, {} frames each",
        dir.display(),
        split_name(r.split),
        r.patch_cells,
        r.cost_split_px,
        r.max_segment_cells,
        options.taus,
        options.frames
    );
    let c = ooc_calibration::calibrate_store(dir, config, options)?;
    let path = output.map_or_else(|| dir.join(FILE_NAME), Path::to_path_buf);
    c.write(&path)?;
    let points: Vec<String> =
        c.points().iter().map(|[t, p]| format!("tau {t} -> p99 {p:.3} px")).collect();
    println!("{}: {} ({:.1} s)", path.display(), points.join(", "), start.elapsed().as_secs_f64());
    for px in [0.5, 1.0, 2.0, 4.0] {
        let shared = OocConfig { calibration: None, ..*config }.tau_for_error_px(px).0;
        println!(
            "  --error-px {px}: tau {:.3} (the shared calibration's tau {shared:.3} would draw \
             p99 {:.2} px here)",
            c.tau_for(px),
            c.p99_at(shared)
        );
    }
    Ok(c)
}

/// Runs `terrain calibrate`.
pub(crate) fn run(args: &CalibrateArgs) -> anyhow::Result<()> {
    if let Some(url) = terrain_app::ooc::store_url(&args.store) {
        // The calibration is written beside the store's index, and a window of the store may
        // be baked again into a temporary folder: both need the store on this machine.
        bail!(
            "{url} is a store at a URL: `terrain calibrate` measures a store folder on this \
             machine and writes {FILE_NAME} into it; calibrate the local bake before uploading \
             it (or copy the store here), then upload {FILE_NAME} beside its index"
        );
    }
    if !terrain_stream::is_store(&args.store) {
        bail!(
            "{} is not a baked store (bake a DEM with `terrain bake DEM -o STORE` first)",
            args.store.display()
        );
    }
    let config = args.refine.config()?;
    if args.frames == 0 {
        bail!("--frames must be at least 1");
    }
    if let Some(t) = args.taus.iter().find(|t| !(t.is_finite() && **t > 0.0)) {
        bail!("--taus must be positive numbers of pixels, got {t}");
    }
    let options = CalibrateOptions {
        taus: if args.taus.is_empty() { DEFAULT_TAUS.to_vec() } else { args.taus.clone() },
        frames: args.frames,
        window: args.window.max(2),
        ..CalibrateOptions::default()
    };
    calibrate_and_write(&args.store, args.output.as_deref(), &config, &options)?;
    Ok(())
}
