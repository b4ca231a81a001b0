//! Helpers shared by terrain-gpu's unit tests: a GPU context that skips (with the reason
//! printed) where no adapter exists unless `TERRAIN_REQUIRE_GPU` is set, and the real DEM the
//! tests draw (`../shared/data`, or `$TERRAIN_DATA`).

use std::path::PathBuf;

use terrain_core::Heightmap;

use crate::device::{BackendChoice, GpuContext, GpuError, REQUIRE_ENV};

/// A context on `backend`, or `None` (with the reason printed) where none exists and none is
/// required; any other failure panics.
pub(crate) fn context(backend: BackendChoice) -> Option<GpuContext> {
    match GpuContext::on_backend(backend) {
        Ok(ctx) => {
            println!("adapter: {}", ctx.describe());
            Some(ctx)
        }
        Err(e @ GpuError::NoAdapter { .. }) if std::env::var_os(REQUIRE_ENV).is_none() => {
            println!("SKIPPED: {e}; set {REQUIRE_ENV}=1 to make this a failure");
            None
        }
        Err(e) => panic!("{backend:?}: {e}"),
    }
}

/// The real DEMs' folder.
pub(crate) fn data_dir() -> PathBuf {
    std::env::var_os("TERRAIN_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"))
}

/// Puget Sound 1k as the app loads it (0.1 m per grey level, 160 m spacing).
pub(crate) fn puget_sound() -> Heightmap {
    let path = data_dir().join("puget_sound/ps_height_1k.png");
    let options = terrain_core::dem::LoadOptions {
        vertical_scale: 0.1,
        spacing_m: 160.0,
        ..Default::default()
    };
    terrain_core::dem::load(&path, &options)
        .unwrap_or_else(|e| panic!("{e} (set TERRAIN_DATA to the shared data folder)"))
        .heightmap
}
