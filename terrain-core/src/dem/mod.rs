//! DEM readers: real files in their original formats, read in place with no conversion step.
//!
//! [`load`] detects the format from the magic bytes (and the `.hgt` name), reads it into a
//! [`Heightmap`] (south row first, heights in metres), marks no-data samples in the void mask
//! and fills them for geometry ([`voids`]). Every failure is a [`DemError`] naming the file.

use std::io::Read;
use std::path::{Path, PathBuf};

use crate::error::{DemError, DemErrorKind};
use crate::georef::Georef;
use crate::heightmap::Heightmap;

pub mod geotiff;
mod geotiff_chunks;
pub mod hgt;
pub mod image;
pub mod mosaic;
pub mod raw;
pub mod rows;
pub mod voids;

pub use mosaic::load_mosaic;
pub use rows::RowReader;

/// A file format we read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[non_exhaustive]
pub enum Format {
    /// GeoTIFF: 1- to 8-bit, 16-, 32- and 64-bit integer and float samples; strips or tiles
    /// (sparse too); none, Deflate, LZW, PackBits, JPEG, ZSTD; one band of several.
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

impl Format {
    /// A short human-readable name, used in error messages.
    pub fn name(self) -> &'static str {
        match self {
            Format::GeoTiff => "GeoTIFF",
            Format::Hgt => "SRTM .hgt",
            Format::GreyImage => "grey image",
            Format::TerrainRgb => "Terrain-RGB PNG",
            Format::Terrarium => "Terrarium PNG",
            Format::Raw => "raw grid",
        }
    }
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
    /// metres = raw * vertical_scale + vertical_offset. Default 1. Grey images and raw files
    /// have no vertical unit of their own; for GeoTIFF (after GDAL's band scale and offset) and
    /// .hgt it converts the file's vertical unit (feet, decimetres...) and is reported in
    /// [`Dem::warnings`]. A scale that takes a valid sample beyond f32's range is refused
    /// ([`DemErrorKind::VerticalRange`]).
    pub vertical_scale: f64,
    /// See `vertical_scale`. Default 0.
    pub vertical_offset: f64,
    /// Horizontal spacing in metres for files that carry no georeference (images, raw). Default 1.
    pub spacing_m: f64,
    /// Whether the user gave `spacing_m`: a georeferenced file (a GeoTIFF with a georeference,
    /// .hgt) then refuses to be read rather than silently keeping its own spacing. Default false.
    pub spacing_given: bool,
    /// The band read from a multi-band GeoTIFF, from 1 (GDAL's numbering). Default 1; a file
    /// with several bands says which one was read in [`Dem::warnings`].
    pub band: u16,
    /// Dimensions of a raw file.
    pub raw: Option<RawSpec>,
    /// Refuse grids with more samples than this before allocating anything. Default 2^32 (16 GiB of f32).
    pub max_samples: u64,
    /// Refuse, before allocating, a grid whose reading would need more than this many bytes
    /// (the kept heights and void mask plus the reader's decoding buffers, estimated from the
    /// declared size: see [`bytes_to_read`]). Default [`DEFAULT_MAX_MEMORY_BYTES`] (4 GiB).
    /// The CLI's `--max-memory` sets it.
    pub max_memory_bytes: u64,
}

/// Default of [`LoadOptions::max_memory_bytes`]: 4 GiB. A fixed figure rather than a share of
/// the machine's memory, so a run refuses or reads the same file the same way everywhere; it
/// holds a 16k x 16k float32 grid (the largest map of the papers) and refuses the multi-GB
/// allocations a few hundred bytes of hostile header can ask for.
pub const DEFAULT_MAX_MEMORY_BYTES: u64 = 4 << 30;

/// Bytes per sample a read grid keeps: an f32 height and (at most) one byte of void mask.
pub const KEPT_BYTES_PER_SAMPLE: u64 = 5;

/// Estimated peak bytes to read a `width` x `height` grid whose reader also holds
/// `transient_bytes_per_sample` bytes per sample while decoding (the decoded file samples and
/// their conversion to f32): `samples x (KEPT_BYTES_PER_SAMPLE + transient)`, saturating.
pub fn bytes_to_read(width: u64, height: u64, transient_bytes_per_sample: u64) -> u64 {
    width
        .saturating_mul(height)
        .saturating_mul(KEPT_BYTES_PER_SAMPLE.saturating_add(transient_bytes_per_sample))
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self {
            format: None,
            nodata: None,
            vertical_scale: 1.0,
            vertical_offset: 0.0,
            spacing_m: 1.0,
            spacing_given: false,
            band: 1,
            raw: None,
            max_samples: 1 << 32,
            max_memory_bytes: DEFAULT_MAX_MEMORY_BYTES,
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
    /// `(scale, offset)`: metres = stored value x scale + offset (a GeoTIFF's own band scale
    /// and offset, then the options' vertical scale and offset); integer samples lie on this
    /// lattice. `(1, 0)` for samples read as stored; NaN when the tiles of a mosaic differ.
    pub vertical: (f64, f64),
}

/// A DEM as read: the heightmap plus where it came from.
#[derive(Debug, Clone)]
pub struct Dem {
    /// Heights, voids and georeference.
    pub heightmap: Heightmap,
    /// The source.
    pub source: SourceInfo,
    /// What looks like a mistake in how the file was read (the data is never changed for it):
    /// callers show these to the user.
    pub warnings: Vec<LoadWarning>,
}

/// Heights below the deepest ocean floor (Challenger Deep, about -10,935 m) or above the
/// highest summit (Everest, 8,849 m), with margins: no terrain has them, so they are void
/// sentinels, a wrong vertical unit or a wrong sample type.
const LOWEST_PLAUSIBLE_M: f64 = -11_000.0;
const HIGHEST_PLAUSIBLE_M: f64 = 9_000.0;
/// Common void sentinels that are plausible heights (ocean depths); flagged only when they
/// stand apart from every other sample by more than [`SENTINEL_GAP_M`].
const IN_RANGE_SENTINELS: [f64; 1] = [-9999.0];
const SENTINEL_GAP_M: f64 = 1000.0;

/// Whether a height in metres is one some terrain has.
pub(crate) fn plausible(z: f64) -> bool {
    (LOWEST_PLAUSIBLE_M..=HIGHEST_PLAUSIBLE_M).contains(&z)
}

/// Something in a DEM that looks like a mistake in how it was read. Reported, never acted on:
/// the heights are read as the file and options say.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum LoadWarning {
    /// Samples at an extreme value (a void sentinel such as -32767, -9999 or -3.4e38) while no
    /// no-data value is in force: they are read as heights.
    Sentinel {
        /// The file.
        path: PathBuf,
        /// The value.
        value: f64,
        /// Samples with it, where known (a file read whole; not when read by rows).
        count: Option<u64>,
    },
    /// A grey image read at 1 m per grey level (no vertical scale given) whose relief is
    /// implausible: higher than any terrain, or steeper than 45 degrees across the whole grid.
    Relief {
        /// The file.
        path: PathBuf,
        /// Highest minus lowest valid height, metres.
        relief_m: f64,
        /// The grid's larger horizontal extent, metres.
        extent_m: f64,
    },
    /// A multi-band file: one band was read (not a mistake, said so the user knows).
    Bands {
        /// The file.
        path: PathBuf,
        /// The band read, from 1.
        band: u16,
        /// Bands in the file.
        bands: u16,
    },
    /// A georeferenced file (GeoTIFF, .hgt) read with a vertical scale or offset: heights are
    /// the file's (with its own scale and offset) times `scale` plus `offset`.
    Rescaled {
        /// The file.
        path: PathBuf,
        /// The vertical scale given.
        scale: f64,
        /// The vertical offset given, metres.
        offset: f64,
    },
}

impl std::fmt::Display for LoadWarning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LoadWarning::Sentinel { path, value, count } => {
                // Short and parseable back: -32767, -9999, -3.4028234663852886e38.
                let v = if value.abs() >= 1e7 { format!("{value:e}") } else { format!("{value}") };
                let n = count.map_or_else(|| "some".to_string(), |c| c.to_string());
                write!(
                    f,
                    "{}: {n} samples are {v} and no nodata value is set, so they are read as \
                     heights of {v} m; if they are voids, give --nodata={v}",
                    path.display()
                )
            }
            LoadWarning::Relief { path, relief_m, extent_m } => write!(
                f,
                "{}: read as 1 m per grey level (no --vertical-scale), the relief is {relief_m:.0} \
                 m over {extent_m:.0} m, which no terrain has; give --vertical-scale (metres per \
                 grey level) and --spacing (metres per sample)",
                path.display()
            ),
            LoadWarning::Bands { path, band, bands } => write!(
                f,
                "{}: the file has {bands} bands, band {band} is read as heights (--band N reads \
                 another)",
                path.display()
            ),
            LoadWarning::Rescaled { path, scale, offset } => write!(
                f,
                "{}: heights are the file's values x {scale} + {offset} m (--vertical-scale, \
                 --vertical-offset), on top of its own vertical unit",
                path.display()
            ),
        }
    }
}

/// The note that a georeferenced format's heights were rescaled by the options.
pub(crate) fn rescaled(path: &Path, format: Format, options: &LoadOptions) -> Option<LoadWarning> {
    let (scale, offset) = (options.vertical_scale, options.vertical_offset);
    (matches!(format, Format::GeoTiff | Format::Hgt) && (scale != 1.0 || offset != 0.0))
        .then(|| LoadWarning::Rescaled { path: path.to_path_buf(), scale, offset })
}

/// Looks for what [`LoadWarning`] describes in a heightmap just read from `path`.
fn inspect(
    path: &Path,
    format: Format,
    options: &LoadOptions,
    hm: &Heightmap,
    nodata: Option<f64>,
) -> Vec<LoadWarning> {
    let (w, h) = (hm.width(), hm.height());
    let valid = || {
        (0..h)
            .flat_map(move |j| (0..w).map(move |i| (i, j)))
            .filter(|&(i, j)| !hm.voids().get(i, j))
            .map(|(i, j)| f64::from(hm.get(i, j)))
    };
    let (lo, hi) =
        valid().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), z| (a.min(z), b.max(z)));
    if !(lo.is_finite() && hi.is_finite()) {
        return Vec::new();
    }
    let mut out = Vec::new();
    let image = matches!(format, Format::GreyImage);
    if image {
        let default_scale = options.vertical_scale == 1.0 && options.vertical_offset == 0.0;
        let g = hm.georef();
        let extent_m = ((w - 1) as f64 * g.spacing_m.x).max((h - 1) as f64 * g.spacing_m.y);
        let relief_m = hi - lo;
        if default_scale && (relief_m > HIGHEST_PLAUSIBLE_M || relief_m > extent_m.max(1.0)) {
            out.push(LoadWarning::Relief { path: path.to_path_buf(), relief_m, extent_m });
        }
    } else if nodata.is_none() {
        for v in [lo, hi] {
            let extreme = !plausible(v);
            let apart = IN_RANGE_SENTINELS.contains(&v) && {
                let next = if v == lo {
                    valid().filter(|&z| z != v).fold(f64::INFINITY, f64::min) - v
                } else {
                    v - valid().filter(|&z| z != v).fold(f64::NEG_INFINITY, f64::max)
                };
                next > SENTINEL_GAP_M
            };
            if (extreme || apart)
                && !out
                    .iter()
                    .any(|o| matches!(o, LoadWarning::Sentinel { value, .. } if *value == v))
            {
                let count = Some(valid().filter(|&z| z == v).count() as u64);
                out.push(LoadWarning::Sentinel { path: path.to_path_buf(), value: v, count });
            }
        }
    }
    out
}

/// Magic bytes of the formats we detect (and of a few we recognise only to name them).
const TIFF_LE: &[u8] = b"II*\0";
const TIFF_BE: &[u8] = b"MM\0*";
const BIGTIFF_LE: &[u8] = b"II+\0";
const BIGTIFF_BE: &[u8] = b"MM\0+";
const PNG_MAGIC: &[u8] = b"\x89PNG\r\n\x1a\n";
const JPEG_MAGIC: &[u8] = b"\xFF\xD8\xFF";

/// Which container the first bytes belong to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Magic {
    Tiff,
    Png,
    Jpeg,
    Other,
}

pub(crate) fn sniff(head: &[u8]) -> Magic {
    if [TIFF_LE, TIFF_BE, BIGTIFF_LE, BIGTIFF_BE].iter().any(|m| head.starts_with(m)) {
        Magic::Tiff
    } else if head.starts_with(PNG_MAGIC) {
        Magic::Png
    } else if head.starts_with(JPEG_MAGIC) {
        Magic::Jpeg
    } else {
        Magic::Other
    }
}

/// Names what the first bytes look like, for the "not a recognised format" message.
fn describe_unknown(head: &[u8]) -> String {
    let hex: Vec<String> = head.iter().take(8).map(|b| format!("{b:02x}")).collect();
    let what = if head.starts_with(b"GIF87a") || head.starts_with(b"GIF89a") {
        "a GIF image, which carries no elevation: convert it to GeoTIFF or a grey PNG"
    } else if head.starts_with(b"BM") {
        "a BMP image: convert it to GeoTIFF or a grey PNG"
    } else if head.starts_with(b"RIFF") {
        "a RIFF (WebP?) file: not read"
    } else if !head.is_empty()
        && head.iter().all(|&b| b == b'\t' || b == b'\n' || b == b'\r' || (0x20..0x7f).contains(&b))
    {
        "text, not a DEM (ASCII grids such as .asc are not read)"
    } else {
        "unknown magic bytes"
    };
    format!(
        "{what}; first bytes {}; expected TIFF (II*\\0 / MM\\0*), PNG, JPEG, a .hgt name, \
         or a raw grid given with --raw WIDTHxHEIGHT:TYPE",
        hex.join(" ")
    )
}

/// Whether `path` has the `.hgt` extension (any case).
fn has_hgt_extension(path: &Path) -> bool {
    path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("hgt"))
}

/// Detects the format of a file from its first bytes and its name.
///
/// TIFF (classic or BigTIFF) -> [`Format::GeoTiff`]; PNG and JPEG -> [`Format::GreyImage`]
/// (Terrain-RGB and Terrarium look like any RGB PNG, so they must be forced); a `.hgt`
/// extension -> [`Format::Hgt`] (that format has no magic). `None` if nothing matches.
pub fn detect_format(path: &Path, head: &[u8]) -> Option<Format> {
    match sniff(head) {
        Magic::Tiff => Some(Format::GeoTiff),
        Magic::Png | Magic::Jpeg => Some(Format::GreyImage),
        Magic::Other if has_hgt_extension(path) => Some(Format::Hgt),
        Magic::Other => None,
    }
}

/// A grid as decoded by a reader, before voids are marked and filled.
///
/// `data` is row-major with row 0 = south (readers flip north-first files); heights in metres.
/// Void samples hold the no-data value (or NaN).
#[derive(Debug)]
pub(crate) struct RawGrid {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
    pub georef: Georef,
    pub nodata: Option<f64>,
    pub sample_type: String,
    /// What the reader has to say (a band chosen among several).
    pub notes: Vec<LoadWarning>,
    /// See [`SourceInfo::vertical`].
    pub vertical: (f64, f64),
}

/// `raw * scale + offset` as an f32 height; refused when a finite sample leaves f32's range
/// (it would otherwise become an infinite height, then a void, then be filled).
pub(crate) fn metres(path: &Path, raw: f64, scale: f64, offset: f64) -> Result<f32, DemError> {
    let m = raw * scale + offset;
    let z = m as f32;
    if z.is_finite() {
        Ok(z)
    } else {
        Err(DemError::new(path, DemErrorKind::VerticalRange { raw, scale, offset, metres: m }))
    }
}

/// Refuses `spacing_m` given for a file placed by its own georeference (`what`, e.g. "this
/// .hgt tile"), rather than keeping its spacing silently.
pub(crate) fn refuse_spacing(
    path: &Path,
    options: &LoadOptions,
    what: &str,
    georef: &Georef,
) -> Result<(), DemError> {
    if !options.spacing_given {
        return Ok(());
    }
    Err(DemError::new(
        path,
        DemErrorKind::InvalidOptions(format!(
            "--spacing is for files without a georeference; {what} is placed by its own ({} x \
             {} m per sample), which is used: leave --spacing out",
            georef.spacing_m.x, georef.spacing_m.y
        )),
    ))
}

/// Refuses empty grids, grids over `LoadOptions::max_samples` and grids whose reading would
/// need more than `LoadOptions::max_memory_bytes` ([`bytes_to_read`] with the reader's
/// `transient_bytes_per_sample`), before anything of that size is allocated.
pub(crate) fn check_size(
    path: &Path,
    width: u64,
    height: u64,
    transient_bytes_per_sample: u64,
    options: &LoadOptions,
) -> Result<(), DemError> {
    if width == 0 || height == 0 {
        return Err(DemError::new(path, DemErrorKind::ZeroSize { width, height }));
    }
    let samples = width.saturating_mul(height);
    let limit = options.max_samples;
    // The grid also has to be addressable in memory as f32 on this platform.
    if samples > limit || usize::try_from(samples).map_or(true, |s| s > isize::MAX as usize / 8) {
        return Err(DemError::new(path, DemErrorKind::TooLarge { width, height, limit }));
    }
    let bytes = bytes_to_read(width, height, transient_bytes_per_sample);
    if bytes > options.max_memory_bytes {
        let limit = options.max_memory_bytes;
        return Err(DemError::new(path, DemErrorKind::MemoryLimit { width, height, bytes, limit }));
    }
    Ok(())
}

/// The length of the file at `path` and its first 16 bytes (for format detection); an
/// empty file is [`DemErrorKind::Empty`]. Shared by [`load`] and [`rows::RowReader::open`].
pub(crate) fn read_head(path: &Path) -> Result<(u64, Vec<u8>), DemError> {
    let err = |kind| DemError::new(path, kind);
    let file = std::fs::File::open(path).map_err(|e| err(DemErrorKind::Io(e)))?;
    let len = file.metadata().map_err(|e| err(DemErrorKind::Io(e)))?.len();
    if len == 0 {
        return Err(err(DemErrorKind::Empty));
    }
    let mut head = Vec::with_capacity(16);
    file.take(16).read_to_end(&mut head).map_err(|e| err(DemErrorKind::Io(e)))?;
    Ok((len, head))
}

/// Reads the DEM at `path`.
///
/// The format is `options.format` if given; otherwise it is detected from the magic bytes
/// (TIFF, PNG, JPEG) and the `.hgt` extension; a file with no magic is read as raw when
/// `options.raw` is given. The heights are in metres, row 0 south, voids marked and filled.
pub fn load(path: impl AsRef<Path>, options: &LoadOptions) -> Result<Dem, DemError> {
    let path = path.as_ref();
    let err = |kind| DemError::new(path, kind);
    let sane = options.spacing_m.is_finite()
        && options.spacing_m > 0.0
        && options.vertical_scale.is_finite()
        && options.vertical_offset.is_finite();
    if !sane {
        return Err(err(DemErrorKind::InvalidOptions(format!(
            "spacing_m ({}) must be finite and positive, vertical_scale ({}) and vertical_offset ({}) finite",
            options.spacing_m, options.vertical_scale, options.vertical_offset
        ))));
    }
    let (len, head) = read_head(path)?;

    let format = match options.format {
        Some(f) => f,
        None => match detect_format(path, &head) {
            Some(f) => f,
            None if options.raw.is_some() => Format::Raw,
            None => return Err(err(DemErrorKind::UnknownFormat(describe_unknown(&head)))),
        },
    };
    // A forced format must still match the container's magic where the format has one.
    let magic = sniff(&head);
    let magic_ok = match format {
        Format::GeoTiff => magic == Magic::Tiff,
        Format::GreyImage => matches!(magic, Magic::Png | Magic::Jpeg),
        Format::TerrainRgb | Format::Terrarium => magic == Magic::Png,
        Format::Hgt | Format::Raw => true,
    };
    if !magic_ok {
        return Err(err(DemErrorKind::UnknownFormat(format!(
            "{} was asked for, but the file does not start with its magic bytes; {}",
            format.name(),
            describe_unknown(&head)
        ))));
    }

    let grid = match format {
        Format::GeoTiff => geotiff::read(path, len, options)?,
        Format::Hgt => hgt::read(path, len, options)?,
        Format::GreyImage | Format::TerrainRgb | Format::Terrarium => {
            image::read(path, len, format, magic, options)?
        }
        Format::Raw => raw::read(path, len, options)?,
    };
    let nodata = grid.nodata;
    let sample_type = grid.sample_type.clone();
    let mut warnings = grid.notes.clone();
    let vertical = grid.vertical;
    let heightmap = voids::build_heightmap(path, grid)?;
    warnings.extend(rescaled(path, format, options));
    warnings.extend(inspect(path, format, options, &heightmap, nodata));
    Ok(Dem {
        heightmap,
        source: SourceInfo { path: path.to_path_buf(), format, sample_type, nodata, vertical },
        warnings,
    })
}
