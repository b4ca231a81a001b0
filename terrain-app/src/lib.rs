//! The composition layer of the terrain engine, shared by the `terrain` binary, `cargo xtask`
//! and the integration tests: LOD methods assembled from terrain-core (quadtree, metrics,
//! selection), terrain-visibility (roughness) and handed to terrain-gpu as draw patches.

/// Bytes in a MiB (2^20). Every size the `terrain` command takes or prints is in binary
/// units: options in MiB (`--cache-mib`, `--page-mib`), `--max-memory` in KiB/MiB/GiB/TiB,
/// messages and reports in MiB.
pub const MIB: f64 = (1u64 << 20) as f64;

pub mod bench;
pub mod camera;
pub mod clock;
pub mod decimation;
pub mod dss_scene;
pub mod entropy_method;
pub mod geomip_scene;
pub mod method;
pub mod methods;
pub mod ooc;
pub mod ooc_calibration;
pub mod progress;
pub mod pvs_scene;
pub mod roughness_scene;
pub mod samples;
pub mod scene_files;
pub mod tin_scene;
