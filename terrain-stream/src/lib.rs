//! Out-of-core terrain: the block store of the out-of-core paper (Qiu 2013, sections 2 and 4).
//!
//! **API boundary:** other programs embed this crate. It depends on `terrain-core` only (never
//! on wgpu) and owns its threads: blocks of (2^k+1)^2 vertices baked once with non-redundant
//! per-level storage (Eq. 1-2), a byte-budgeted cache, the frustum-extension preloading
//! scheduler (Eq. 8) and a worker pool behind request/result channels.
//!
//! # The API (everything an embedder needs is at the crate root; the rest is private)
//! - **Bake** a DEM file into a store in one call ([`bake_file`]: any format terrain-core
//!   reads, large GeoTIFFs by bands of rows), or any [`HeightSource`] ([`bake`]); typed
//!   [`BakeError`]s.
//! - **Shard** a bake across processes or machines ([`bake_shard`]: shard `K/N` writes a part
//!   folder of its block rows) and [`merge`] the parts into the store a single bake writes,
//!   byte for byte; a merge refuses missing, duplicated or foreign parts by name.
//! - **Open** a store ([`Store::open`], [`is_store`]): its [`Header`], per-block
//!   [`BlockEntry`]s, positioned reads of one level ([`Store::read_block`]), the blocks'
//!   decimation errors the bake measured ([`Store::decimation_errors`]); typed
//!   [`StoreError`]s naming the file.
//! - **Stream** ([`Streamer`]): per frame a camera goes in ([`Streamer::update`], real time:
//!   never waits for I/O after the first frame; late data counted in its [`FrameStats`]), the
//!   resident levels come out ([`Streamer::block`]: [`BlockLevels`]); the visual region M and
//!   its levels from the paper's Eq. 7, or another LOD method's [`Streamer::set_demand`];
//!   [`Streamer::wait_until_resident`] waits until warm on purpose. Worker threads are the
//!   crate's own; reads go through the [`LevelReader`] trait.
//! - **Select** crack-free patches with tessellation factors: the out-of-core paper's method
//!   ([`select_streamed`] / [`select_patches`] over the [`StoreTree`]), or any of terrain-core's
//!   LOD selections over the store's terrain ([`StoreSource`], a `TerrainSource`; what they
//!   need loaded: [`demand_of`]; the drawn blocks' levels as a [`BlockLevelGrid`]). A
//!   [`TreeWarmer`] walks the tree ahead on its own thread (at Eq. 8's eye and at the next
//!   frame's camera, [`Streamer::camera_next`]), so the next frame's selection finds the
//!   blocks it enters already read.
//! - [`glam`] and the [`Camera`] are re-exported, so an embedder needs no other crate of ours.
//!
//! # Example
//!
//! Bake, open, drive the scheduler from a camera path in real time, select the crack-free
//! patches to draw from the resident levels, wait until the last frame's needed levels are
//! resident, read a block's heights at a level (the same as
//! `examples/embed.rs`):
//!
//! ```
//! use std::ops::ControlFlow;
//! use std::sync::Arc;
//! use std::time::Duration;
//!
//! use terrain_core::lod::check_shared_edges;
//! use terrain_core::synth::FractalConfig;
//! use terrain_stream::glam::dvec3;
//! use terrain_stream::{
//!     BakeConfig, BakeProgress, Camera, DEFAULT_PATCH_CELLS, Store, StoreTree, StreamConfig,
//!     Streamer, bake, select_streamed,
//! };
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let dir = std::env::temp_dir().join(format!("terrain-stream-doc-{}", std::process::id()));
//! // 129 x 129 samples at 10 m, streamed by rows into blocks of 33 x 33 vertices.
//! let source = FractalConfig::with_size(129, 129, 10.0);
//! let config = BakeConfig { k: 5, overwrite: true, ..Default::default() };
//! bake(&source, &dir, &config, &mut |_: &BakeProgress| ControlFlow::Continue(()))?;
//!
//! let store = Arc::new(Store::open(&dir)?);
//! let tree = StoreTree::new(store.clone(), DEFAULT_PATCH_CELLS);
//! let mut streamer = Streamer::new(store, StreamConfig { threads: 1, ..Default::default() });
//! let mut camera = Camera::from_yaw_pitch(dvec3(640.0, 0.0, 900.0), 0.0, -30.0);
//! for frame in 0..10 {
//!     let eye = dvec3(640.0, 50.0 * frame as f64, 900.0);
//!     camera = Camera::from_yaw_pitch(eye, 0.0, -30.0).with_clip(1.0, 2000.0);
//!     // Real time: never waits after the first frame; late data is counted.
//!     let stats = streamer.update(&camera);
//!     assert!(stats.faults.is_empty());
//!     // Patches (quadtree nodes of the whole grid) with tessellation factors, crack-free.
//!     let patches = select_streamed(&tree, &camera, 2.0, &streamer);
//!     assert!(!patches.patches.is_empty());
//!     assert!(check_shared_edges(&patches).is_empty());
//! }
//! let warm = streamer.wait_until_resident(&camera, Duration::from_secs(30));
//! assert!(warm.resident);
//! let nearest = streamer.scheduled()[0];
//! let levels = streamer.block(nearest.block).unwrap();
//! assert!(levels.count() > nearest.needed as usize);
//! let grid = levels.grid(1).unwrap(); // 3 x 3 heights at level 1
//! assert_eq!(grid.len(), 9);
//! # drop(streamer);
//! # std::fs::remove_dir_all(&dir)?;
//! # Ok(())
//! # }
//! ```

#![deny(missing_docs)]

mod bake;
mod cache;
mod codec;
mod decimation;
mod entries;
mod error;
mod format;
mod huffman;
mod lod;
mod overview;
mod pages;
mod remote;
mod schedule;
mod shard;
mod side_table;
mod source;
mod stats;
mod store;
mod streamer;
mod terrain;
mod warm;
mod workers;

pub use bake::{
    BakeConfig, BakeProgress, BakeReport, GEOMIP_FILE, HeightEncoding, STREAM_ABOVE_SAMPLES, bake,
    bake_file, check_output,
};
pub use decimation::{DECIMATION_FILE, DecimationErrors};
pub use error::{BakeError, StoreError};
pub use format::{
    BlockEntry, BlockId, Codec, DssBlockErrors, Header, INDEX_FILE, LevelEntry, MAGIC, NodeValues,
    SampleEncoding, vertex_level,
};
pub use glam;
pub use lod::{
    BlockLevelGrid, DEFAULT_COST_SPLIT_PX, DEFAULT_MAX_SEGMENT_CELLS, DEFAULT_PATCH_CELLS,
    DEFAULT_SPLIT, Refinement, SplitRule, StoreTree, select_patches, select_streamed,
};
pub use remote::{
    MULTIPART_ABOVE, RemoteOptions, UploadReport, check_remote_output, is_url, upload_store,
};
pub use schedule::ScheduleConfig;
pub use shard::{
    MergeConfig, PART_FILE, PartInfo, Shard, ShardReport, bake_options, bake_shard, find_parts,
    is_part, merge, read_part,
};
pub use side_table::SideTable;
pub use source::{HeightSource, read_rows_parallel};
pub use stats::{Fault, FrameStats, StatsSummary};
pub use store::{BlockLevels, LoadedLevel, Store, is_store};
pub use streamer::{ScheduledBlock, StreamConfig, Streamer, WaitReport};
pub use terrain::{
    Demand, StoreSource, coarsen_to_budget, demand_and_held, demand_bytes, demand_of, demand_within,
};
pub use terrain_core::geometry::Camera;
pub use warm::TreeWarmer;
pub use workers::LevelReader;

#[cfg(test)]
mod tests;
