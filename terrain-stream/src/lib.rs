//! Out-of-core terrain: the block store of the out-of-core paper (Qiu 2013, sections 2 and 4).
//!
//! **API boundary:** other programs embed this crate. It depends on `terrain-core` only (never
//! on wgpu) and owns its threads: blocks of (2^k+1)^2 vertices baked once with non-redundant
//! per-level storage (Eq. 1-2), a byte-budgeted cache, the frustum-extension preloading
//! scheduler (Eq. 8) and a worker pool behind request/result channels.
//!
//! This crate is filled by the terrain-stream issue; it holds no code before it.

#![deny(missing_docs)]
