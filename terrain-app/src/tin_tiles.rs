//! `terrain tin-tiles STORE`: builds the `tin` method's coarse tiles into a store baked without
//! them (before they existed, or with `terrain bake --no-tin`), as the bake does
//! ([`terrain_app::tin_scene::bake_from_store`]): `tin_tiles.bin`, which `--method tin` from the
//! store reads instead of meshing millions of samples while flying.

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::Args;
use terrain_app::tin_scene::{TIN_TILES_FILE, bake_from_store};

/// Arguments of `terrain tin-tiles`.
#[derive(Debug, Args)]
pub(crate) struct TinTilesArgs {
    /// The baked store (a local folder written by `terrain bake`).
    pub store: PathBuf,
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
    let store = terrain_stream::Store::open(dir)
        .with_context(|| format!("could not open the store {}", dir.display()))?;
    let h = store.header();
    if store.decimation_errors().with_context(|| format!("reading {}", dir.display()))?.is_none() {
        bail!(
            "{} has no table of decimation errors ({}: baked before it existed), which the tiles \
             need: bake the store again (that writes the tiles too)",
            dir.display(),
            terrain_stream::DECIMATION_FILE
        );
    }
    if h.block_cells() != 256 {
        bail!(
            "{} has blocks of {} cells; the tin method's baked tiles need 256 (bake it with the \
             default --block-k 8)",
            dir.display(),
            h.block_cells()
        );
    }
    match bake_from_store(&store, !args.quiet)? {
        Some(r) => println!(
            "{}: {} of the tin method's coarse tiles ({} triangles), {:.2} MiB, {:.1} s",
            dir.join(TIN_TILES_FILE).display(),
            r.tiles,
            r.triangles,
            r.bytes as f64 / terrain_app::MIB,
            r.secs
        ),
        None => println!(
            "{}: no tile of 1024 cells or more across: `--method tin` builds every tile of this \
             {} x {} store while flying",
            dir.display(),
            h.width,
            h.height
        ),
    }
    Ok(())
}
