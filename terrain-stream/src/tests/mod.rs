//! The crate's tests that read its internals (the vertex order, block files, the scheduler's
//! regions, the selection's metrics): unit tests of the whole crate, kept in one folder.

mod decimation;
mod lod;
mod pages;
mod remote;
mod runtime;
mod store;

/// A test's folder in the temporary directory, removed with everything in it when dropped,
/// also when the test panics; derefs to its path (the temporary folder itself, or a
/// not-yet-made `store` folder in it for a bake that makes its output).
pub(crate) struct Scratch {
    _dir: tempfile::TempDir,
    path: std::path::PathBuf,
}

impl std::ops::Deref for Scratch {
    type Target = std::path::Path;
    fn deref(&self) -> &std::path::Path {
        &self.path
    }
}

impl AsRef<std::path::Path> for Scratch {
    fn as_ref(&self) -> &std::path::Path {
        &self.path
    }
}

fn temp(prefix: &str) -> tempfile::TempDir {
    tempfile::Builder::new().prefix(prefix).tempdir().expect("create a temporary folder")
}

/// An empty temporary folder named `{prefix}…`.
pub(crate) fn scratch(prefix: &str) -> Scratch {
    let dir = temp(prefix);
    let path = dir.path().to_path_buf();
    Scratch { _dir: dir, path }
}

/// `store`, not yet made, in a new temporary folder named `{prefix}…` (a bake's output).
pub(crate) fn scratch_store(prefix: &str) -> Scratch {
    let dir = temp(prefix);
    let path = dir.path().join("store");
    Scratch { _dir: dir, path }
}

/// Raw 64-bit numbers from Vigna's xorshift64* (12, 25, 27, multiplier 0x2545F4914F6CDD1D)
/// for the crate's randomized tests: deterministic, platform-independent; a zero seed is
/// taken as 1.
pub(crate) fn xorshift64_star(seed: u64) -> impl FnMut() -> u64 {
    let mut x = seed.max(1);
    move || {
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
}

/// The runtime and remote tests' 513^2 store (k = 6, 4 node levels): a smooth wave with a
/// small integer ripple, baked into `dir`.
fn bake_wave_513(dir: &std::path::Path) {
    use crate::{BakeConfig, BakeProgress, bake};
    use terrain_core::Georef;
    use terrain_core::heightmap::Heightmap;
    let hm = Heightmap::from_fn(513, 513, Georef::local(10.0), |i, j| {
        300.0
            + 200.0 * ((i as f32) * 0.02).sin() * ((j as f32) * 0.015).cos()
            + ((i * 7 + j * 13) % 17) as f32
    })
    .unwrap();
    let cfg = BakeConfig { k: 6, node_levels: 4, ..Default::default() };
    bake(&hm, dir, &cfg, &mut |_: &BakeProgress| std::ops::ControlFlow::Continue(())).unwrap();
}
