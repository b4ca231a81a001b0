//! Helpers shared by the `terrain` binary's end-to-end tests: where the real DEMs are, running
//! the binary, and scratch folders. Each test file uses a subset, hence `dead_code` allowed.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The remote store tests' helpers (servers on 127.0.0.1, a small baked store).
pub(crate) mod remote;

/// A file of `../shared/data` (or `$TERRAIN_DATA`); panics with a clear message if missing,
/// because the tests are defined over these files.
pub(crate) fn data(rel: &str) -> PathBuf {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let dir =
        std::env::var_os("TERRAIN_DATA").map(PathBuf::from).unwrap_or(root.join("../shared/data"));
    let p = dir.join(rel);
    assert!(p.exists(), "test data {} is missing (set TERRAIN_DATA)", p.display());
    p
}

/// Runs `terrain ARGS` and returns its output.
pub(crate) fn terrain(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_terrain"))
        .args(args)
        .output()
        .expect("the terrain binary runs")
}

/// An empty scratch folder `terrain-{test}-{name}-…` in the temporary directory, removed with
/// everything in it when the returned guard is dropped, also when the test panics.
pub(crate) fn scratch(test: &str, name: &str) -> Scratch {
    let dir = tempfile::Builder::new()
        .prefix(&format!("terrain-{test}-{name}-"))
        .tempdir()
        .expect("create scratch folder");
    Scratch(dir)
}

/// A scratch folder ([`scratch`]): derefs to its path; removed on drop. Keep it alive as
/// long as the test uses the folder (bind it to a variable, not `scratch(..).join(..)`), and
/// drop servers that write there first (declare them after it).
pub(crate) struct Scratch(tempfile::TempDir);

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        self.0.path()
    }
}

impl AsRef<Path> for Scratch {
    fn as_ref(&self) -> &Path {
        self.0.path()
    }
}

impl AsRef<std::ffi::OsStr> for Scratch {
    fn as_ref(&self) -> &std::ffi::OsStr {
        self.0.path().as_os_str()
    }
}

/// Every file below `dir`, at any depth, sorted by path.
pub(crate) fn files_under(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap_or_else(|e| panic!("{}: {e}", d.display())) {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

/// Per-channel mean |difference| and the fraction of pixels off by more than 16 levels of two
/// renders (`terrain_gpu::target::image_diff`): the golden-image test's measure (terrain-gpu
/// `render::tests::golden`: mean < 2, < 1 %).
pub(crate) fn golden_diff(
    a: &terrain_gpu::target::RgbaImage,
    b: &terrain_gpu::target::RgbaImage,
) -> ([f64; 3], f64) {
    let d = terrain_gpu::target::image_diff(a.pixels.iter().copied(), b.pixels.iter().copied());
    (d.mean, d.far_off)
}

/// The GPU context for a test: `None` (the test says SKIPPED) when there is no adapter, a
/// failure instead when `TERRAIN_REQUIRE_GPU` is set (as `.ci/run` does).
pub(crate) fn gpu() -> Option<terrain_gpu::GpuContext> {
    use terrain_gpu::{BackendChoice, DeviceConfig, GpuContext};
    match GpuContext::new(&DeviceConfig::from_env(BackendChoice::Auto)) {
        Ok(ctx) => Some(ctx),
        Err(e) if std::env::var_os("TERRAIN_REQUIRE_GPU").is_none() => {
            println!("SKIPPED: {e}; set TERRAIN_REQUIRE_GPU=1 to make this a failure");
            None
        }
        Err(e) => panic!("{e}"),
    }
}
