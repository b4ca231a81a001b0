//! `terrain tin-tiles STORE`: builds the `tin` method's coarse tiles into a store baked without
//! them (before they existed, or with `terrain bake --no-tin`), as the bake does
//! ([`terrain_app::tin_scene::bake_tiles`]), or again with another `--tin-min-cells`:
//! `tin_tiles.bin`, which `--method tin` from the store reads instead of meshing millions of
//! samples while flying.

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::Args;
use terrain_app::tin_scene::{bake_tiles, min_stride_for_cells, not_bakeable};

/// Arguments of `terrain tin-tiles`.
#[derive(Debug, Args)]
pub(crate) struct TinTilesArgs {
    /// The baked store (a local folder written by `terrain bake`).
    pub store: PathBuf,
    /// Bake the tiles spanning at least this many cells (a power of two of at least 64; 64
    /// bakes every tile, so `--method tin` never meshes while flying, in a larger file and a
    /// longer bake).
    #[arg(long, value_name = "CELLS", default_value_t = terrain_app::tin_scene::BAKED_MIN_CELLS)]
    pub tin_min_cells: u32,
    /// No progress line.
    #[arg(long)]
    pub quiet: bool,
}

pub(crate) fn run(args: &TinTilesArgs) -> anyhow::Result<()> {
    let dir = &args.store;
    if !terrain_stream::is_store(dir) {
        bail!(
            "{} is not a store folder (`terrain tin-tiles` takes a local folder written by \
             `terrain bake`)",
            dir.display()
        );
    }
    let min_stride_log2 = min_stride_for_cells(args.tin_min_cells)?;
    let store = terrain_stream::Store::open(dir)
        .with_context(|| format!("could not open the store {}", dir.display()))?;
    let why = not_bakeable(&store).with_context(|| format!("reading {}", dir.display()))?;
    if let Some(why) = why {
        bail!("{}: no tin tiles can be baked: {why}", dir.display());
    }
    match bake_tiles(&store, min_stride_log2, !args.quiet)? {
        Some(r) => println!("{}", r.line(dir)),
        None => println!(
            "{}: no tile of {} cells or more across: `--method tin` builds every tile of this \
             {} x {} store while flying",
            dir.display(),
            args.tin_min_cells,
            store.header().width,
            store.header().height
        ),
    }
    Ok(())
}
