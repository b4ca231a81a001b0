//! Shared helpers for the integration tests: where the real DEMs live.

use std::path::PathBuf;

/// The workspace root (the folder holding the top-level Cargo.toml).
pub fn workspace_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).parent().expect("tests/ has a parent").to_path_buf()
}

/// `../shared/data` beside the checkout, or `$TERRAIN_DATA` when set.
pub fn data_dir() -> PathBuf {
    match std::env::var_os("TERRAIN_DATA") {
        Some(p) => PathBuf::from(p),
        None => workspace_root().join("../shared/data"),
    }
}

/// Path of a file in the shared data folder; panics with a clear message if it is missing,
/// because the tests are defined over these files.
pub fn data_file(rel: &str) -> PathBuf {
    let p = data_dir().join(rel);
    assert!(
        p.exists(),
        "test data {} is missing (set TERRAIN_DATA to the shared data folder)",
        p.display()
    );
    p
}
