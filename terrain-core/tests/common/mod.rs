//! Helpers shared by this crate's integration tests: where the workspace and the real DEMs
//! (`../shared/data`, or `$TERRAIN_DATA`) are. Each test file uses a subset, hence
//! `dead_code` allowed.

#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// The workspace root.
pub(crate) fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("workspace root").to_owned()
}

/// The real DEMs' folder: `$TERRAIN_DATA`, else `../shared/data` beside the workspace.
pub(crate) fn data_dir() -> PathBuf {
    std::env::var_os("TERRAIN_DATA")
        .map_or_else(|| workspace().join("../shared/data"), PathBuf::from)
}

/// A file of the data folder; panics with a clear message if it is missing, because the
/// tests are defined over these files.
pub(crate) fn data(rel: &str) -> PathBuf {
    let p = data_dir().join(rel);
    assert!(p.is_file(), "test data missing: {} (set TERRAIN_DATA)", p.display());
    p
}
