//! The composition layer of the terrain engine, shared by the `terrain` binary, `cargo xtask`
//! and the integration tests: LOD methods assembled from terrain-core (quadtree, metrics,
//! selection), terrain-visibility (roughness) and handed to terrain-gpu as draw patches.

pub mod bench;
pub mod dss_scene;
pub mod entropy_method;
pub mod geomip_scene;
pub mod method;
pub mod methods;
pub mod ooc;
pub mod progress;
pub mod pvs_scene;
pub mod roughness_scene;
pub mod scene_files;
