//! Helpers shared by this crate's integration tests: scratch folders removed when dropped.

#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// `name`, not yet made (a bake makes its output), in a new temporary folder named
/// `{prefix}{name}-…`: both are removed when this is dropped, also when the test panics.
/// Derefs to `name`'s path.
pub(crate) struct Scratch {
    _dir: tempfile::TempDir,
    path: PathBuf,
}

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.path
    }
}

impl AsRef<Path> for Scratch {
    fn as_ref(&self) -> &Path {
        &self.path
    }
}

pub(crate) fn scratch(prefix: &str, name: &str) -> Scratch {
    let dir = tempfile::Builder::new()
        .prefix(&format!("{prefix}{name}-"))
        .tempdir()
        .expect("create a temporary folder");
    let path = dir.path().join(name);
    Scratch { _dir: dir, path }
}
