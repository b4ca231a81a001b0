//! Out-of-core terrain: the block store of the out-of-core paper (Qiu 2013, sections 2 and 4).
//!
//! **API boundary:** other programs embed this crate. It depends on `terrain-core` only (never
//! on wgpu) and owns its threads: blocks of (2^k+1)^2 vertices baked once with non-redundant
//! per-level storage (Eq. 1-2), a byte-budgeted cache, the frustum-extension preloading
//! scheduler (Eq. 8) and a worker pool behind request/result channels.

#![deny(missing_docs)]

pub mod bake;
pub mod cache;
mod codec;
pub mod error;
pub mod format;
pub mod lod;
pub mod schedule;
pub mod source;
pub mod stats;
pub mod store;
pub mod streamer;
pub mod workers;

pub use bake::{BakeConfig, BakeProgress, BakeReport, HeightEncoding, bake};
pub use error::{BakeError, StoreError};
pub use format::{BlockId, Codec, Header};
pub use source::HeightSource;
pub use stats::{FrameStats, StatsSummary};
pub use store::{BlockLevels, LoadedLevel, Store};
pub use streamer::{ScheduledBlock, StreamConfig, Streamer};
pub use workers::{LoadRequest, LoadResult, WorkerPool};
