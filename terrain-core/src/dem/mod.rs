//! DEM readers: real files in their original formats, read in place with no conversion step.
//!
//! [`load`] detects the format from the magic bytes (and the `.hgt` name), reads it into a
//! [`Heightmap`] (south row first, heights in metres), marks no-data samples in the void mask
//! and fills them for geometry ([`voids`]). Every failure is a [`DemError`] naming the file.

use std::path::{Path, PathBuf};

use crate::error::DemError;
use crate::heightmap::Heightmap;

/// A file format we read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[non_exhaustive]
pub enum Format {
    /// GeoTIFF: int16, uint16, int32, float32, float64; strips or tiles; none, Deflate, LZW.
    GeoTiff,
    /// SRTM `.hgt`: big-endian int16, square, size from the file length, origin from the name.
    Hgt,
    /// 8- or 16-bit grey PNG or JPEG; metres = raw * vertical_scale + vertical_offset.
    GreyImage,
    /// Mapbox Terrain-RGB PNG: metres = -10000 + (R*65536 + G*256 + B) * 0.1.
    TerrainRgb,
    /// Terrarium PNG: metres = R*256 + G + B/256 - 32768.
    Terrarium,
    /// Headerless little-endian samples with explicit dimensions ([`RawSpec`]).
    Raw,
}

/// Sample type of a raw file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum RawSampleType {
    /// Signed 16-bit, little-endian.
    I16,
    /// Unsigned 16-bit, little-endian.
    U16,
    /// IEEE float32, little-endian.
    F32,
}

/// Dimensions and sample type of a headerless raw file (rows north first, as written by GDAL's ENVI/raw drivers).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RawSpec {
    /// Columns.
    pub width: u64,
    /// Rows.
    pub height: u64,
    /// Sample type.
    pub sample: RawSampleType,
}

/// How to read a DEM. The defaults read any supported georeferenced file as it is.
#[derive(Debug, Clone, PartialEq)]
pub struct LoadOptions {
    /// Force a format instead of detecting it (needed for Terrain-RGB/Terrarium, which look
    /// like any RGB PNG, and for raw files, which have no magic).
    pub format: Option<Format>,
    /// No-data value that overrides (or supplies) the file's own (GDAL_NODATA, -32768 in .hgt).
    pub nodata: Option<f64>,
    /// For grey images and raw files: metres = raw * vertical_scale + vertical_offset. Default 1.
    pub vertical_scale: f64,
    /// See `vertical_scale`. Default 0.
    pub vertical_offset: f64,
    /// Horizontal spacing in metres for files that carry no georeference (images, raw). Default 1.
    pub spacing_m: f64,
    /// Dimensions of a raw file.
    pub raw: Option<RawSpec>,
    /// Refuse grids with more samples than this before allocating anything. Default 2^32 (16 GiB of f32).
    pub max_samples: u64,
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self {
            format: None,
            nodata: None,
            vertical_scale: 1.0,
            vertical_offset: 0.0,
            spacing_m: 1.0,
            raw: None,
            max_samples: 1 << 32,
        }
    }
}

/// What the source file was, beyond the heights: for `terrain info` and provenance.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SourceInfo {
    /// The file (the first one of a mosaic).
    pub path: PathBuf,
    /// The format it was read as.
    pub format: Format,
    /// Sample type in the file, e.g. "int16", "float32", "uint16 (grey PNG)".
    pub sample_type: String,
    /// The no-data value in force, if any.
    pub nodata: Option<f64>,
}

/// A DEM as read: the heightmap plus where it came from.
#[derive(Debug, Clone)]
pub struct Dem {
    /// Heights, voids and georeference.
    pub heightmap: Heightmap,
    /// The source.
    pub source: SourceInfo,
}

/// Reads the DEM at `path`.
pub fn load(path: impl AsRef<Path>, options: &LoadOptions) -> Result<Dem, DemError> {
    let _ = (path, options);
    unimplemented!("filled by the DEM-reader work")
}
