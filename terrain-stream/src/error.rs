//! Typed errors of the store: baking ([`BakeError`]) and reading ([`StoreError`]); every
//! error about stored data names the file, and the block and level where it applies.

use std::path::PathBuf;

use crate::format::BlockId;

/// Why a store (or one block level of it) could not be read.
///
/// Grouped as bad input (bad magic, corrupt or truncated data, checksum mismatch), unsupported
/// (another version), I/O (a missing block file, the OS refusing) and a file changed since the
/// store was opened.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StoreError {
    /// A vertical exaggeration that is not a positive number ([`crate::Store::exaggerated`]).
    #[error(
        "{}: a vertical exaggeration must be a finite positive number, got {scale}",
        path.display()
    )]
    Exaggeration {
        /// The store folder.
        path: PathBuf,
        /// The exaggeration asked for.
        scale: f64,
    },
    /// The operating system refused.
    #[error("{}: I/O error: {cause}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause (in the message; not an error `source`, so an error chain prints it once).
        cause: std::io::Error,
    },
    /// The file does not start with the store's magic bytes.
    #[error("{}: not a terrain store ({what} has the wrong magic bytes)", path.display())]
    BadMagic {
        /// The file.
        path: PathBuf,
        /// "index" or "block file".
        what: &'static str,
    },
    /// A store of another format version.
    #[error(
        "{}: store format version {found}, which this reader does not read (it writes version {expected}); bake the store again (`terrain bake`)",
        path.display()
    )]
    Version {
        /// The file.
        path: PathBuf,
        /// Version in the file.
        found: u32,
        /// Version this crate reads and writes.
        expected: u32,
    },
    /// The index is inconsistent or its checksum fails.
    #[error("{}: corrupt index: {message}", path.display())]
    CorruptIndex {
        /// The index file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A page of a paged index (version 4) is truncated or fails its checksum or checks.
    #[error(
        "{}: corrupt index page {page} (blocks {}..{} in row-major order): {message}",
        path.display(), blocks.0, blocks.1
    )]
    IndexPage {
        /// The index file (a remote store's: its local mirror).
        path: PathBuf,
        /// The page.
        page: usize,
        /// The row-major positions of its blocks.
        blocks: (usize, usize),
        /// What is wrong.
        message: String,
    },
    /// A file is shorter than the index says.
    #[error(
        "{}: block {block} level {level}: truncated at byte {got} (the index says the file has {expected} bytes)",
        path.display()
    )]
    Truncated {
        /// The block file.
        path: PathBuf,
        /// The block.
        block: BlockId,
        /// The level being read.
        level: u8,
        /// The file's length in the index.
        expected: u64,
        /// File length.
        got: u64,
    },
    /// A block level's bytes do not match their stored checksum.
    #[error(
        "{}: block {block} level {level}: checksum mismatch (index says {stored:08x}, data has {computed:08x})",
        path.display()
    )]
    Checksum {
        /// The block file.
        path: PathBuf,
        /// The block.
        block: BlockId,
        /// The level.
        level: u8,
        /// CRC-32 in the index.
        stored: u32,
        /// CRC-32 of the bytes read.
        computed: u32,
    },
    /// The store's overview file (`overview.bin`) is damaged or from another bake.
    #[error("{}: {message}", path.display())]
    Overview {
        /// The overview file.
        path: PathBuf,
        /// What is wrong, and what to do.
        message: String,
    },
    /// The store's table of decimation errors (`decimation.bin`) is damaged, from another
    /// bake, or of another grid ([`crate::Store::decimation_errors`]).
    #[error("{}: {message}", path.display())]
    Decimation {
        /// The table's file (a remote store's: its copy in the local mirror).
        path: PathBuf,
        /// What is wrong, and what to do.
        message: String,
    },
    /// A block's file is missing.
    #[error("{}: block {block} level {level}: missing file (the block file is not there)", path.display())]
    MissingBlock {
        /// The expected path.
        path: PathBuf,
        /// The block.
        block: BlockId,
        /// The level being read.
        level: u8,
    },
    /// A block file is longer than the index says (it changed since the store was baked or
    /// opened).
    #[error("{}: block {block} level {level}: the file changed since the store was baked ({message})", path.display())]
    Changed {
        /// The block file.
        path: PathBuf,
        /// The block.
        block: BlockId,
        /// The level being read.
        level: u8,
        /// What differs.
        message: String,
    },
    /// A block file that is not a store block: it does not start with the block file's magic
    /// bytes.
    #[error("{}: block {block} level {level}: not a store block (the file does not start with a block header)", path.display())]
    NotABlock {
        /// The block file.
        path: PathBuf,
        /// The block.
        block: BlockId,
        /// The level being read.
        level: u8,
    },
    /// A store block, but of another store or bake, or of another block position.
    #[error("{}: block {block} level {level}: a block of another store ({message})", path.display())]
    Foreign {
        /// The block file.
        path: PathBuf,
        /// The block.
        block: BlockId,
        /// The level being read.
        level: u8,
        /// What differs.
        message: String,
    },
    /// A level's bytes pass their checksum but do not decode (a writer bug or a forged CRC).
    #[error("block {block} level {level}: corrupt level data: {message}")]
    CorruptLevel {
        /// The block.
        block: BlockId,
        /// The level.
        level: u8,
        /// What is wrong.
        message: String,
    },
    /// Caller misuse: a block outside the grid, a level past the finest, or levels out of order.
    #[error("block {block} level {level}: {message}")]
    BadRequest {
        /// The block.
        block: BlockId,
        /// The level.
        level: u8,
        /// What is wrong.
        message: String,
    },
    /// A store on object storage or HTTP could not be opened or reached (the message says
    /// what the server or client said).
    #[error("{location}: {message}")]
    Remote {
        /// The store's URL.
        location: String,
        /// What went wrong.
        message: String,
    },
    /// A block's range request to a remote store failed (after the retries): a server error,
    /// a timeout, a refused connection.
    #[error("{location}: block {block} level {level}: request failed: {message}")]
    RemoteBlock {
        /// The block file's URL.
        location: String,
        /// The block.
        block: BlockId,
        /// The first level the request asked for.
        level: u8,
        /// What the server or client said.
        message: String,
    },
    /// A worker thread panicked while loading (reported, the pool keeps running).
    #[error("block {block} level {level}: the loading worker panicked: {message}")]
    WorkerPanicked {
        /// The block.
        block: BlockId,
        /// The level.
        level: u8,
        /// The panic message.
        message: String,
    },
}

impl StoreError {
    /// The block this error is about, if any.
    pub fn block(&self) -> Option<BlockId> {
        match self {
            StoreError::Truncated { block, .. }
            | StoreError::Checksum { block, .. }
            | StoreError::MissingBlock { block, .. }
            | StoreError::Changed { block, .. }
            | StoreError::NotABlock { block, .. }
            | StoreError::Foreign { block, .. }
            | StoreError::CorruptLevel { block, .. }
            | StoreError::BadRequest { block, .. }
            | StoreError::WorkerPanicked { block, .. }
            | StoreError::RemoteBlock { block, .. } => Some(*block),
            _ => None,
        }
    }

    /// The level this error is about, if any.
    pub fn level(&self) -> Option<u8> {
        match self {
            StoreError::Truncated { level, .. }
            | StoreError::Checksum { level, .. }
            | StoreError::MissingBlock { level, .. }
            | StoreError::Changed { level, .. }
            | StoreError::NotABlock { level, .. }
            | StoreError::Foreign { level, .. }
            | StoreError::CorruptLevel { level, .. }
            | StoreError::BadRequest { level, .. }
            | StoreError::WorkerPanicked { level, .. }
            | StoreError::RemoteBlock { level, .. } => Some(*level),
            _ => None,
        }
    }
}

/// Why a bake failed. A failed or cancelled bake leaves no store that reads as valid.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BakeError {
    /// The operating system refused.
    #[error("{}: I/O error: {cause}", path.display())]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The cause (in the message; not an error `source`, so an error chain prints it once).
        cause: std::io::Error,
    },
    /// The output exists and `BakeConfig::overwrite` is off.
    #[error("{}: already exists (give --overwrite to replace it)", path.display())]
    Exists {
        /// The output folder.
        path: PathBuf,
    },
    /// The output exists and is not a store: a file, or a folder without the store's index.
    /// Never replaced, even with `BakeConfig::overwrite`: it may hold the user's files.
    #[error(
        "{}: {what}; a bake replaces only a store folder (one holding index.tsi with the store's \
         magic): choose another output, or move it away yourself",
        path.display()
    )]
    NotAStore {
        /// The output path.
        path: PathBuf,
        /// What it is instead.
        what: String,
    },
    /// The output URL could not be checked (the server or client's answer in the message).
    #[error("{location}: {message}")]
    Remote {
        /// The output URL.
        location: String,
        /// What went wrong.
        message: String,
    },
    /// Caller misuse: a config value out of range.
    #[error("invalid bake config: {0}")]
    InvalidConfig(String),
    /// The source could not deliver rows.
    #[error("reading source rows {j0}..{}: {cause}", j0 + *rows as u64)]
    Source {
        /// First row.
        j0: u64,
        /// Rows asked for.
        rows: usize,
        /// The cause (in the message; not an error `source`, so an error chain prints it once).
        cause: std::io::Error,
    },
    /// A height does not fit the chosen quantization, or the error bound was not met.
    #[error("height encoding: {0}")]
    Encoding(String),
    /// The progress callback asked to stop.
    #[error("the bake was cancelled")]
    Cancelled,
    /// A shard's part folder cannot be merged: unreadable, corrupt, or of another bake (another
    /// source, other options, another grid or number of shards). The reason names what differs.
    #[error("{}: {reason}", path.display())]
    BadPart {
        /// The part folder.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// The parts given to a merge are not every shard of one bake once: one is given twice or
    /// some are missing (named).
    #[error("merging parts: {0}")]
    Shards(String),
    /// The DEM file could not be read ([`crate::bake_file`]); the error names the file.
    #[error(transparent)]
    Dem(#[from] terrain_core::DemError),
}
