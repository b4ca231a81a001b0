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

/// A file in a temporary folder of its own: folder and file are removed when this is dropped,
/// also when the test panics. Derefs to the file's path.
pub(crate) struct TempFile {
    _dir: tempfile::TempDir,
    path: PathBuf,
}

impl std::ops::Deref for TempFile {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.path
    }
}

impl AsRef<Path> for TempFile {
    fn as_ref(&self) -> &Path {
        &self.path
    }
}

/// A temporary folder named `{prefix}…` (removed when dropped, also on a panic).
pub(crate) fn temp_dir(prefix: &str) -> tempfile::TempDir {
    tempfile::Builder::new().prefix(prefix).tempdir().expect("create temp dir")
}

/// `bytes` written to `name` in a new temporary folder named `{prefix}…`.
pub(crate) fn write_temp(prefix: &str, name: &str, bytes: &[u8]) -> TempFile {
    let dir = temp_dir(prefix);
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).expect("write temp file");
    TempFile { _dir: dir, path }
}
