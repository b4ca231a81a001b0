//! Typed errors for reading DEMs: every error names the file and the problem.
//!
//! Grouped as image-tiff does: bad input (the file is wrong), unsupported (valid but not
//! handled), I/O, limits exceeded, and caller misuse (options that contradict the file).

use std::path::{Path, PathBuf};

/// An error while reading a DEM, always with the file's path.
#[derive(Debug, thiserror::Error)]
#[error("{}: {kind}", path.display())]
pub struct DemError {
    /// The file that could not be read (or the first file of a mosaic).
    pub path: PathBuf,
    /// What went wrong.
    pub kind: DemErrorKind,
}

impl DemError {
    /// Builds an error for `path`.
    pub fn new(path: impl AsRef<Path>, kind: DemErrorKind) -> Self {
        Self { path: path.as_ref().to_path_buf(), kind }
    }
}

/// What went wrong while reading a DEM.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DemErrorKind {
    /// The operating system refused (missing file, permissions...).
    #[error("I/O error: {0}")]
    Io(#[from] std::io::Error),
    /// The file is empty.
    #[error("the file is empty")]
    Empty,
    /// The file ended before the data it declares.
    #[error("truncated: {what} needs {expected} bytes at offset {offset}, the file has {got}")]
    Truncated {
        /// What was being read.
        what: &'static str,
        /// Offset where it starts.
        offset: u64,
        /// Bytes needed.
        expected: u64,
        /// Bytes available.
        got: u64,
    },
    /// The file does not start with the magic bytes of any format we read, or of the one asked for.
    #[error("not a recognised DEM format ({0})")]
    UnknownFormat(String),
    /// The file's structure is wrong: a bad tag, an inconsistent header.
    #[error("malformed {format}: {message}")]
    Malformed {
        /// Format being read (e.g. "GeoTIFF").
        format: &'static str,
        /// What is wrong, with tag names and offsets where known.
        message: String,
    },
    /// A valid file that uses something we do not read (a sample type, a compression).
    #[error("unsupported {format}: {message}")]
    Unsupported {
        /// Format being read.
        format: &'static str,
        /// What is not supported.
        message: String,
    },
    /// The vertical scale and offset take a valid sample out of f32's range.
    #[error(
        "the vertical scale {scale:e} and offset {offset} take the sample {raw} to {metres:e} m, \
         beyond the range of heights (f32, about ±3.4e38 m): give a smaller --vertical-scale"
    )]
    VerticalRange {
        /// The sample as stored.
        raw: f64,
        /// The scale in force (the file's times the options').
        scale: f64,
        /// The offset in force.
        offset: f64,
        /// What it became.
        metres: f64,
    },
    /// The declared size is beyond the limit; nothing of that size was allocated.
    #[error(
        "declared size {width} x {height} samples exceeds the limit of {limit} samples (the largest grid read)"
    )]
    TooLarge {
        /// Declared columns.
        width: u64,
        /// Declared rows.
        height: u64,
        /// The limit in samples.
        limit: u64,
    },
    /// Reading the declared size would need more memory than allowed
    /// (`LoadOptions::max_memory_bytes`, the CLI's `--max-memory`); nothing of that size was
    /// allocated.
    #[error(
        "declared size {width} x {height} samples would need {} to read, over the memory limit \
         of {}; raise it with --max-memory if the file is meant to be that large",
        crate::error::mib(*bytes),
        crate::error::mib(*limit)
    )]
    MemoryLimit {
        /// Declared columns.
        width: u64,
        /// Declared rows.
        height: u64,
        /// Estimated bytes needed ([`crate::dem::bytes_to_read`]).
        bytes: u64,
        /// The limit in bytes.
        limit: u64,
    },
    /// Reading by rows would hold more strip or tile memory than allowed
    /// (`LoadOptions::max_memory_bytes`, the CLI's `--max-memory`).
    #[error(
        "reading by rows holds {chunks} strips or tiles of {chunk_w} x {chunk_h} samples at \
         once, which would need {}, over the memory limit of {}; raise it with --max-memory \
         if the file is meant to be read so",
        crate::error::mib(*bytes),
        crate::error::mib(*limit)
    )]
    ChunkMemoryLimit {
        /// Columns of a strip or tile.
        chunk_w: u32,
        /// Rows of a strip or tile.
        chunk_h: u32,
        /// Strips or tiles held at once.
        chunks: usize,
        /// Estimated bytes needed.
        bytes: u64,
        /// The limit in bytes.
        limit: u64,
    },
    /// Width or height is zero.
    #[error("the grid is empty ({width} x {height} samples)")]
    ZeroSize {
        /// Declared columns.
        width: u64,
        /// Declared rows.
        height: u64,
    },
    /// Every sample is no-data: there is no terrain to build.
    #[error("every sample is no-data ({count} samples{})", match .nodata { Some(v) => format!(", nodata = {v}"), None => String::new() })]
    AllVoid {
        /// Samples in the grid.
        count: u64,
        /// The no-data value in force.
        nodata: Option<f64>,
    },
    /// The options contradict the file (e.g. raw dimensions that do not match its length).
    #[error("invalid options: {0}")]
    InvalidOptions(String),
    /// Tiles of a mosaic do not fit together.
    #[error("mosaic: {0}")]
    Mosaic(String),
}

/// `bytes` as "N bytes (X MiB)" for messages.
pub(crate) fn mib(bytes: u64) -> String {
    format!("{bytes} bytes ({:.1} MiB)", bytes as f64 / (1u64 << 20) as f64)
}
