//! The crate's tests that read its internals (the vertex order, block files, the scheduler's
//! regions, the selection's metrics): unit tests of the whole crate, kept in one folder.

mod lod;
mod remote;
mod runtime;
mod store;
