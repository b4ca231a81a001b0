//! GeoTIFF: 1- to 8-bit, int16/uint16/int32/uint32/float32/float64 grids, in strips or tiles,
//! uncompressed, Deflate, LZW, PackBits, JPEG (decoded by the `tiff` crate) or ZSTD, one band
//! of one or several, with their georeference. Chunks are decoded one at a time by
//! [`super::geotiff_chunks`] (sparse blocks, bit-packed samples, ZSTD and its predictors, the
//! band, GDAL's internal mask, scale and offset: see there).
//!
//! Georeference tags (GeoTIFF 1.0 spec, OGC 19-008r4):
//! * `ModelPixelScaleTag` (33550): `(ScaleX, ScaleY, ScaleZ)`; y spacing is positive and rows
//!   go *down* (south) in the file.
//! * `ModelTiepointTag` (33922): `(I, J, K, X, Y, Z)`: raster point `(I, J)` is model `(X, Y)`.
//! * `ModelTransformationTag` (34264): a 4x4 affine; read when it has no rotation/shear.
//! * `GeoKeyDirectoryTag` (34735): keys `GTModelTypeGeoKey` (1024: 1 projected, 2 geographic),
//!   `GTRasterTypeGeoKey` (1025: 1 PixelIsArea, 2 PixelIsPoint), `GTCitationGeoKey` (1026),
//!   `GeographicTypeGeoKey` (2048), `GeogAngularUnitsGeoKey` (2054), `ProjectedCSTypeGeoKey`
//!   (3072), `PCSCitationGeoKey` (3073), `ProjLinearUnitsGeoKey` (3076),
//!   `ProjLinearUnitSizeGeoKey` (3077). ASCII key values live in `GeoAsciiParamsTag` (34737),
//!   doubles in `GeoDoubleParamsTag` (34736).
//! * `GDAL_NODATA` (42113): ASCII no-data value.
//!
//! CRS kinds, as GDAL reads them:
//! * Projected (`GTModelTypeGeoKey` 1, or a `ProjectedCSTypeGeoKey`), with an EPSG code or
//!   user-defined (32767: a transverse Mercator, Albers... described by keys): the grid is
//!   placed by its projected coordinates, whatever the projection (the engine never
//!   reprojects). The linear unit comes from `ProjLinearUnitsGeoKey` (EPSG unit codes: metre,
//!   international foot, US survey foot, ...; user-defined: `ProjLinearUnitSizeGeoKey` metres)
//!   or, for an EPSG code without that key, from the CRS name in the citation ("ftUS", "ft",
//!   "feet"); native coordinates stay in that unit and the world frame is in metres. An
//!   unknown unit code is refused, never taken as metres.
//! * Geographic (`GTModelTypeGeoKey` 2, or an EPSG geographic code): degrees; another angular
//!   unit (radians, grads) is refused.
//! * Geocentric (3) is refused. No georeference: a local frame with `LoadOptions::spacing_m`.
//!
//! Samples are read as stored, like GDAL: `PhotometricInterpretation` WhiteIsZero (0) is a
//! display hint, not a change of values, so the decoder is shown BlackIsZero (the tag's value
//! is overlaid while reading, [`Patched`]); the `tiff` crate would otherwise invert unsigned
//! samples (`2^n - 1 - v`), turn floats into `1 - v` and refuse signed ones. Deflate strips and
//! tiles are inflated once more with their zlib Adler-32 and end of stream checked (the decoder
//! stops reading when it has its bytes, so a damaged stream could read as numbers).
//!
//! With PixelIsArea (the default), raster point `(0, 0)` is the *corner* of the first pixel, so
//! sample centres are at `+0.5` pixel; with PixelIsPoint it is the centre. `native_origin` is
//! the centre of the south-west sample (the last file row, first column).

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use glam::{DVec2, dvec2};
use miniz_oxide::inflate::stream::{InflateState, inflate};
use miniz_oxide::{DataFormat, MZError, MZFlush, MZStatus};
use tiff::decoder::{ChunkType, Decoder, DecodingResult, Limits};
use tiff::tags::Tag;
use tiff::{ColorType, TiffError};

use crate::dem::geotiff_chunks::{self, Layout};
use crate::dem::{LoadOptions, RawGrid, check_size};
use crate::error::{DemError, DemErrorKind};
use crate::georef::{Crs, Georef};

const FORMAT: &str = "GeoTIFF";

/// GeoTIFF tag numbers not named by the `tiff` crate.
const MODEL_TRANSFORMATION_TAG: u16 = 34264;
const GEO_DOUBLE_PARAMS_TAG: u16 = 34736;
const GEO_ASCII_PARAMS_TAG: u16 = 34737;
/// `GDAL_METADATA` (42112): XML, with the bands' scale and offset.
const GDAL_METADATA_TAG: u16 = 42112;
/// `PhotometricInterpretation` (262) and its WhiteIsZero / BlackIsZero values.
const PHOTOMETRIC_TAG: u16 = 262;
const WHITE_IS_ZERO: u16 = 0;
const BLACK_IS_ZERO: u16 = 1;

/// GeoKey IDs (GeoTIFF spec section 6.2).
const GT_MODEL_TYPE: u16 = 1024;
const GT_RASTER_TYPE: u16 = 1025;
const GT_CITATION: u16 = 1026;
const GEOGRAPHIC_TYPE: u16 = 2048;
const GEOG_ANGULAR_UNITS: u16 = 2054;
const PROJECTED_CS_TYPE: u16 = 3072;
const PCS_CITATION: u16 = 3073;
const PROJ_LINEAR_UNITS: u16 = 3076;
const PROJ_LINEAR_UNIT_SIZE: u16 = 3077;
/// EPSG angular unit codes read as degrees (9102 degree, 9122 degree supplier to define
/// representation).
const DEGREE_UNITS: [u16; 2] = [9102, 9122];
/// "User-defined" key value: the CRS is described by other keys, not an EPSG code.
const USER_DEFINED: u16 = 32767;

fn malformed(path: &Path, message: impl Into<String>) -> DemError {
    DemError::new(path, DemErrorKind::Malformed { format: FORMAT, message: message.into() })
}

/// Maps a `tiff` crate error (its messages name the tag where it knows it).
fn map_tiff_error(path: &Path, file_len: u64, e: TiffError) -> DemError {
    let kind = match e {
        TiffError::FormatError(f) => {
            DemErrorKind::Malformed { format: FORMAT, message: f.to_string() }
        }
        TiffError::UnsupportedError(u) => {
            DemErrorKind::Unsupported { format: FORMAT, message: u.to_string() }
        }
        TiffError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            DemErrorKind::Malformed {
                format: FORMAT,
                message: format!(
                    "unexpected end of file ({file_len} bytes): the file is truncated or an offset is wrong"
                ),
            }
        }
        TiffError::IoError(io) => DemErrorKind::Io(io),
        TiffError::LimitsExceeded => DemErrorKind::Unsupported {
            format: FORMAT,
            message: "a tag value or a decoding buffer exceeds the decoder's limits".to_string(),
        },
        other => DemErrorKind::Malformed { format: FORMAT, message: other.to_string() },
    };
    DemError::new(path, kind)
}

/// The file's bytes as the decoder sees them: a few bytes overlaid while reading (the
/// `PhotometricInterpretation` value of a WhiteIsZero file, shown as BlackIsZero so samples
/// come out as stored). Everything else reads through unchanged.
#[derive(Debug)]
pub(crate) struct Patched {
    file: File,
    pos: u64,
    /// `(file offset, bytes)` to show instead of the file's own.
    patches: Vec<(u64, Vec<u8>)>,
}

impl Read for Patched {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.file.read(buf)?;
        let (start, end) = (self.pos, self.pos + n as u64);
        for (at, bytes) in &self.patches {
            for (k, &b) in bytes.iter().enumerate() {
                let o = at + k as u64;
                if (start..end).contains(&o) {
                    buf[(o - start) as usize] = b;
                }
            }
        }
        self.pos = end;
        Ok(n)
    }
}

impl Seek for Patched {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        self.pos = self.file.seek(to)?;
        Ok(self.pos)
    }
}

/// What the decoder reads: the file through [`Patched`], buffered.
pub(crate) type Source = BufReader<Patched>;

/// `NewSubfileType` (254): bit 0 reduced resolution, bit 2 transparency mask.
const NEW_SUBFILE_TYPE_TAG: u16 = 254;
/// `PhotometricInterpretation` 4: transparency mask (TIFF 6.0 section 8).
const TRANSPARENCY_MASK: u16 = 4;
/// IFDs looked through for an internal mask (GDAL writes it right after its image).
const MAX_IFDS_WALKED: usize = 64;

/// What [`precheck_header`] found: the overlay for the decoder and the internal mask's IFD.
struct Precheck {
    patches: Vec<(u64, Vec<u8>)>,
    mask_ifd: Option<usize>,
}

/// Checks the TIFF header and the first IFD lie inside the file, so a truncated file gets a
/// precise [`DemErrorKind::Truncated`] rather than a generic end-of-file error. Returns the
/// overlay that shows a WhiteIsZero first image as BlackIsZero (and GDAL's 1-bit internal
/// mask, `PhotometricInterpretation` 4, as 1-bit BlackIsZero, which the decoder reads), and
/// the IFD index of that full-resolution mask, found by walking the IFD chain (at most
/// [`MAX_IFDS_WALKED`] IFDs inside the file; a broken chain after the first IFD only ends the
/// search).
fn precheck_header(path: &Path, file: &mut File, len: u64) -> Result<Precheck, DemError> {
    let trunc = |what, offset: u64, expected: u64| {
        DemError::new(
            path,
            DemErrorKind::Truncated { what, offset, expected, got: len.saturating_sub(offset) },
        )
    };
    let io = |e| DemError::new(path, DemErrorKind::Io(e));
    let mut head = [0u8; 16];
    let n = file.read(&mut head).map_err(io)?;
    let le = head[0] == b'I';
    let u16_at = |b: &[u8]| {
        if le { u16::from_le_bytes([b[0], b[1]]) } else { u16::from_be_bytes([b[0], b[1]]) }
    };
    let u32_at = |b: &[u8]| {
        let b: [u8; 4] = b[..4].try_into().unwrap_or([0; 4]);
        if le { u32::from_le_bytes(b) } else { u32::from_be_bytes(b) }
    };
    let u64_at = |b: &[u8]| {
        let b: [u8; 8] = b[..8].try_into().unwrap_or([0; 8]);
        if le { u64::from_le_bytes(b) } else { u64::from_be_bytes(b) }
    };
    let big = n >= 4 && u16_at(&head[2..4]) == 43;
    let header_len = if big { 16 } else { 8 };
    if (n as u64) < header_len {
        return Err(trunc("TIFF header", 0, header_len));
    }
    let mut ifd = if big { u64_at(&head[8..16]) } else { u64::from(u32_at(&head[4..8])) };
    let count_len = if big { 8 } else { 2 };
    let entry_len: u64 = if big { 20 } else { 12 };
    let value_at = if big { 12 } else { 8 };
    let mut patches = Vec::new();
    let mut mask_ifd = None;
    for index in 0..MAX_IFDS_WALKED {
        let first = index == 0;
        if first && ifd == 0 {
            return Err(malformed(path, "the header's first IFD offset is 0 (no image)"));
        }
        if ifd == 0 || ifd.saturating_add(count_len) > len {
            if first {
                return Err(trunc("TIFF first IFD (entry count)", ifd, count_len));
            }
            break;
        }
        file.seek(SeekFrom::Start(ifd)).map_err(io)?;
        let mut c = [0u8; 8];
        file.read_exact(&mut c[..count_len as usize]).map_err(io)?;
        let entries = if big { u64_at(&c) } else { u64::from(u16_at(&c[..2])) };
        // Classic TIFF counts entries in a u16; a BigTIFF IFD with more than that is not a
        // DEM's (and reading it whole below must stay small).
        if entries > u64::from(u16::MAX) {
            if first {
                return Err(malformed(path, format!("the first IFD declares {entries} entries")));
            }
            break;
        }
        let next_len = if big { 8 } else { 4 };
        let ifd_len = count_len + entries.saturating_mul(entry_len);
        if ifd.saturating_add(ifd_len) > len {
            if first {
                return Err(trunc("TIFF first IFD (entries)", ifd, ifd_len));
            }
            break;
        }
        // The IFD lies inside the file (checked above): reading it whole is bounded by the file.
        let mut table = vec![0u8; (ifd_len - count_len) as usize];
        file.read_exact(&mut table).map_err(io)?;
        let (mut subfile, mut photometric) = (0u32, None);
        for (k, e) in table.chunks_exact(entry_len as usize).enumerate() {
            // Entry: tag u16, type u16 (3 SHORT, 4 LONG), count, then the value inline.
            let (tag, typ) = (u16_at(&e[0..2]), u16_at(&e[2..4]));
            let at = ifd + count_len + k as u64 * entry_len + value_at as u64;
            // Values that do not fit in the entry lie elsewhere in the file, so a tag declaring
            // more bytes of values than the whole file holds is damaged: refused here, before
            // the decoder sizes a buffer from the count (1.45 GB for an ASCII tag of a 700-byte
            // file, found by `cargo xtask fuzz`).
            let count = if big { u64_at(&e[4..12]) } else { u64::from(u32_at(&e[4..8])) };
            let value_bytes = count.saturating_mul(tiff_type_bytes(typ));
            if value_bytes > (entry_len - value_at as u64) && value_bytes > len {
                return Err(malformed(
                    path,
                    format!(
                        "TIFF tag {tag} declares {count} values ({value_bytes} bytes), more than \
                         the file's {len} bytes; the file is damaged"
                    ),
                ));
            }
            match (tag, typ) {
                (PHOTOMETRIC_TAG, 3) => {
                    photometric = Some((at, u16_at(&e[value_at..value_at + 2])));
                }
                (NEW_SUBFILE_TYPE_TAG, 3) => subfile = u32::from(u16_at(&e[value_at..])),
                (NEW_SUBFILE_TYPE_TAG, 4) => subfile = u32_at(&e[value_at..]),
                _ => {}
            }
        }
        let short = |v: u16| if le { v.to_le_bytes() } else { v.to_be_bytes() }.to_vec();
        match photometric {
            Some((at, WHITE_IS_ZERO)) if first => patches.push((at, short(BLACK_IS_ZERO))),
            Some((at, TRANSPARENCY_MASK))
                if !first && mask_ifd.is_none() && subfile & 4 != 0 && subfile & 1 == 0 =>
            {
                patches.push((at, short(BLACK_IS_ZERO)));
                mask_ifd = Some(index);
            }
            _ => {}
        }
        if mask_ifd.is_some() {
            break;
        }
        let mut next = [0u8; 8];
        if ifd.saturating_add(ifd_len + next_len) > len {
            break;
        }
        file.read_exact(&mut next[..next_len as usize]).map_err(io)?;
        ifd = if big { u64_at(&next) } else { u64::from(u32_at(&next)) };
    }
    file.seek(SeekFrom::Start(0)).map_err(io)?;
    Ok(Precheck { patches, mask_ifd })
}

/// Bytes of one value of TIFF field type `typ` (TIFF 6.0 section 2, BigTIFF's 16..18); 1 for
/// an unknown type, so a count alone still bounds it.
fn tiff_type_bytes(typ: u16) -> u64 {
    match typ {
        3 | 8 => 2,
        4 | 9 | 11 | 13 => 4,
        5 | 10 | 12 | 16 | 17 | 18 => 8,
        _ => 1,
    }
}

/// Inflates the zlib stream of one Deflate strip or tile to its end, discarding the output,
/// and checks its Adler-32 (RFC 1950 section 2.2): the decoder of the `tiff` crate stops
/// reading once it has the chunk's bytes, so without this a damaged stream can read as
/// (wrong) numbers. GDAL's zlib refuses such a chunk.
fn check_deflate_chunk(
    path: &Path,
    file: &mut File,
    (what, index): (&str, usize),
    (offset, count): (u64, u64),
) -> Result<(), DemError> {
    if count == 0 {
        // A sparse chunk (GDAL's SPARSE_OK): nothing to check here.
        return Ok(());
    }
    let io = |e| DemError::new(path, DemErrorKind::Io(e));
    let damaged = |why: String| {
        malformed(
            path,
            format!(
                "{what} {index} (bytes {offset}..{}): corrupt Deflate stream ({why}); the file is damaged, read a good copy",
                offset + count
            ),
        )
    };
    file.seek(SeekFrom::Start(offset)).map_err(io)?;
    let mut state = InflateState::new_boxed(DataFormat::Zlib);
    let mut input = vec![0u8; count.min(1 << 20) as usize];
    let mut out = vec![0u8; 1 << 16];
    let mut left = count;
    while left > 0 {
        let n = input.len().min(left as usize);
        file.read_exact(&mut input[..n]).map_err(io)?;
        left -= n as u64;
        let mut chunk = &input[..n];
        loop {
            // MZFlush::None throughout: Finish on a first call would ask for the whole output
            // in one buffer.
            let r = inflate(&mut state, chunk, &mut out, MZFlush::None);
            chunk = &chunk[r.bytes_consumed..];
            let progress = r.bytes_consumed > 0 || r.bytes_written > 0;
            match r.status {
                Ok(MZStatus::StreamEnd) => return Ok(()),
                Ok(_) | Err(MZError::Buf) if progress => {}
                Ok(_) | Err(MZError::Buf) => break,
                Err(MZError::Data) => {
                    return Err(damaged("invalid data or Adler-32 checksum mismatch".into()));
                }
                Err(e) => return Err(damaged(format!("{e:?}"))),
            }
        }
    }
    Err(damaged("the stream ends before its end marker and checksum".into()))
}

/// Checks every Deflate chunk of `chunks` (offset, byte count) with [`check_deflate_chunk`].
pub(crate) fn check_deflate_chunks(
    path: &Path,
    what: &str,
    chunks: &[(u64, u64)],
    indices: impl Iterator<Item = usize>,
) -> Result<(), DemError> {
    let mut file = File::open(path).map_err(|e| DemError::new(path, DemErrorKind::Io(e)))?;
    for k in indices {
        if let Some(&c) = chunks.get(k) {
            check_deflate_chunk(path, &mut file, (what, k), c)?;
        }
    }
    Ok(())
}

/// Checks every strip/tile lies inside the file (a truncated file fails here, precisely) and
/// that the data can hold the declared grid. Returns `(offset, byte count)` of every chunk.
/// Sparse chunks (byte count 0, GDAL's `SPARSE_OK`) are allowed.
fn check_chunks(
    path: &Path,
    dec: &mut Decoder<Source>,
    len: u64,
    compression: u16,
) -> Result<Vec<(u64, u64)>, DemError> {
    let (off_tag, cnt_tag, what) = match dec.get_chunk_type() {
        ChunkType::Strip => (Tag::StripOffsets, Tag::StripByteCounts, "TIFF strip"),
        ChunkType::Tile => (Tag::TileOffsets, Tag::TileByteCounts, "TIFF tile"),
    };
    let offsets = dec.get_tag_u64_vec(off_tag).map_err(|e| map_tiff_error(path, len, e))?;
    let counts = dec.get_tag_u64_vec(cnt_tag).map_err(|e| map_tiff_error(path, len, e))?;
    if offsets.len() != counts.len() {
        return Err(malformed(
            path,
            format!("{} chunk offsets and {} byte counts", offsets.len(), counts.len()),
        ));
    }
    for (&o, &c) in offsets.iter().zip(&counts) {
        if o.saturating_add(c) > len {
            return Err(DemError::new(
                path,
                DemErrorKind::Truncated {
                    what,
                    offset: o,
                    expected: c,
                    got: len.saturating_sub(o),
                },
            ));
        }
    }
    // Refuse files whose data cannot possibly hold the declared grid: uncompressed data must
    // be at least w x h x bytes; compressed data cannot expand more than 4096:1 (LZW's 12-bit
    // codes emit at most 4096 bytes each; Deflate's limit is about 1032:1). Sparse chunks hold
    // nothing and are left out of both sides.
    let (w, h) = dec.dimensions().map_err(|e| map_tiff_error(path, len, e))?;
    let bits: u64 = dec
        .find_tag_unsigned_vec::<u64>(Tag::BitsPerSample)
        .ok()
        .flatten()
        .and_then(|v| v.first().copied())
        .unwrap_or(1);
    let stored = counts.iter().filter(|&&c| c > 0).count() as u64;
    let all = counts.len().max(1) as u64;
    let needed = (w as u64).saturating_mul(h as u64).saturating_mul(bits) / 8 / all * stored;
    let total: u64 = counts.iter().fold(0u64, |a, &c| a.saturating_add(c));
    let capacity = if compression == 1 { total } else { total.saturating_mul(4096) };
    if needed > capacity {
        return Err(DemError::new(
            path,
            DemErrorKind::Truncated {
                what: "TIFF image data (all strips/tiles)",
                offset: offsets.first().copied().unwrap_or(0),
                expected: needed,
                got: total,
            },
        ));
    }
    Ok(offsets.into_iter().zip(counts).collect())
}

/// Reads an optional tag as f64s, naming the tag on failure.
fn tag_f64s(
    path: &Path,
    dec: &mut Decoder<Source>,
    tag: Tag,
    name: &str,
) -> Result<Option<Vec<f64>>, DemError> {
    match dec.find_tag(tag) {
        Ok(None) => Ok(None),
        Ok(Some(v)) => {
            v.into_f64_vec().map(Some).map_err(|e| malformed(path, format!("{name}: {e}")))
        }
        Err(e) => Err(malformed(path, format!("{name}: {e}"))),
    }
}

/// The parsed GeoKeyDirectory (only the keys we use).
#[derive(Debug, Default)]
struct GeoKeys {
    model_type: Option<u16>,
    raster_type: Option<u16>,
    geographic: Option<u16>,
    angular_units: Option<u16>,
    projected: Option<u16>,
    linear_units: Option<u16>,
    linear_unit_size: Option<f64>,
    citation: Option<String>,
}

fn parse_geokeys(
    path: &Path,
    dir: &[u16],
    ascii: Option<&str>,
    doubles: Option<&[f64]>,
) -> Result<GeoKeys, DemError> {
    if dir.len() < 4 {
        return Err(malformed(
            path,
            format!("GeoKeyDirectoryTag (34735) has {} values, at least 4 needed", dir.len()),
        ));
    }
    let n = dir[3] as usize;
    let mut keys = GeoKeys::default();
    for k in 0..n {
        let Some(e) = dir.get(4 + 4 * k..8 + 4 * k) else {
            return Err(malformed(
                path,
                format!(
                    "GeoKeyDirectoryTag (34735) declares {n} keys but holds {} values",
                    dir.len()
                ),
            ));
        };
        let (id, loc, count, value) = (e[0], e[1], e[2] as usize, e[3] as usize);
        // Location 0: the value is inline. GeoAsciiParamsTag: a '|'-terminated substring.
        let short = (loc == 0).then_some(e[3]);
        let text = || {
            (loc == GEO_ASCII_PARAMS_TAG)
                .then(|| ascii.and_then(|a| a.get(value..value + count)))
                .flatten()
                .map(|s| s.trim_end_matches(['|', '\0']).trim().to_string())
        };
        // GeoDoubleParamsTag: `count` doubles from index `value`.
        let double = || {
            (loc == GEO_DOUBLE_PARAMS_TAG && count >= 1)
                .then(|| doubles.and_then(|d| d.get(value).copied()))
                .flatten()
        };
        match id {
            GT_MODEL_TYPE => keys.model_type = short,
            GT_RASTER_TYPE => keys.raster_type = short,
            GEOGRAPHIC_TYPE => keys.geographic = short,
            GEOG_ANGULAR_UNITS => keys.angular_units = short,
            PROJECTED_CS_TYPE => keys.projected = short,
            PROJ_LINEAR_UNITS => keys.linear_units = short,
            PROJ_LINEAR_UNIT_SIZE => keys.linear_unit_size = double(),
            PCS_CITATION => keys.citation = text().or(keys.citation.take()),
            GT_CITATION if keys.citation.is_none() => keys.citation = text(),
            _ => {}
        }
    }
    Ok(keys)
}

/// Metres per unit of an EPSG linear unit code: every length unit of the EPSG dataset that is
/// not deprecated, with the factors of PROJ's `proj.db` (through which GDAL reads them).
/// `None` for any other code, which is refused rather than guessed.
fn linear_unit_m(code: u16) -> Option<f64> {
    Some(match code {
        1025 => 0.001,               // millimetre
        1033 => 0.01,                // centimetre
        9001 => 1.0,                 // metre
        9002 => 0.3048,              // foot
        9003 => 1200.0 / 3937.0,     // US survey foot
        9005 => 0.3047972654,        // Clarke's foot
        9014 => 1.8288,              // fathom
        9030 => 1852.0,              // nautical mile
        9031 => 1.0000135965,        // German legal metre
        9033 => 20.11684023368047,   // US survey chain
        9034 => 0.2011684023368047,  // US survey link
        9035 => 1609.3472186944375,  // US survey mile
        9036 => 1000.0,              // kilometre
        9037 => 0.9143917962,        // Clarke's yard
        9038 => 20.1166195164,       // Clarke's chain
        9039 => 0.201166195164,      // Clarke's link
        9040 => 0.9143984146160287,  // British yard (Sears 1922)
        9041 => 0.3047994715386762,  // British foot (Sears 1922)
        9042 => 20.116765121552632,  // British chain (Sears 1922)
        9043 => 0.2011676512155263,  // British link (Sears 1922)
        9050 => 0.9143992,           // British yard (Benoit 1895 A)
        9051 => 0.3047997333333333,  // British foot (Benoit 1895 A)
        9052 => 20.1167824,          // British chain (Benoit 1895 A)
        9053 => 0.201167824,         // British link (Benoit 1895 A)
        9060 => 0.9143992042898124,  // British yard (Benoit 1895 B)
        9061 => 0.30479973476327077, // British foot (Benoit 1895 B)
        9062 => 20.116782494375872,  // British chain (Benoit 1895 B)
        9063 => 0.2011678249437587,  // British link (Benoit 1895 B)
        9070 => 0.30480083333333335, // British foot (1865)
        9080 => 0.30479951024814694, // Indian foot
        9081 => 0.30479841,          // Indian foot (1937)
        9082 => 0.3047996,           // Indian foot (1962)
        9083 => 0.3047995,           // Indian foot (1975)
        9084 => 0.9143985307444408,  // Indian yard
        9085 => 0.91439523,          // Indian yard (1937)
        9086 => 0.9143988,           // Indian yard (1962)
        9087 => 0.9143985,           // Indian yard (1975)
        9093 => 1609.344,            // Statute mile
        9094 => 0.3047997101815088,  // Gold Coast foot
        9095 => 0.3048007491,        // British foot (1936)
        9096 => 0.9144,              // yard
        9097 => 20.1168,             // chain
        9098 => 0.201168,            // link
        9099 => 0.914398,            // British yard (Sears 1922 truncated)
        9300 => 0.30479933333333337, // British foot (Sears 1922 truncated)
        9301 => 20.116756,           // British chain (Sears 1922 truncated)
        9302 => 0.20116756,          // British link (Sears 1922 truncated)
        _ => return None,
    })
}

/// The linear unit of a projected CRS named only by its EPSG code and citation (no
/// `ProjLinearUnitsGeoKey`): EPSG's names carry it ("NAD83 / Pennsylvania South (ftUS)",
/// "... (ft)", "... feet"). Metres otherwise.
fn unit_from_name(name: &str) -> f64 {
    let n = name.to_ascii_lowercase();
    if n.contains("ftus") || n.contains("us survey foot") || n.contains("us survey feet") {
        1200.0 / 3937.0
    } else if n.contains("(ft)") || n.contains("feet") || n.contains("foot") {
        0.3048
    } else {
        1.0
    }
}

/// What the GeoKeys say the CRS is.
enum CrsKind {
    /// Projected, with metres per linear unit.
    Projected { crs: Crs, unit_m: f64 },
    /// Geographic, in degrees.
    Geographic(Crs),
    /// No model type and no CRS code: the coordinates are taken as metres.
    Unknown(Crs),
}

/// The CRS of `keys` (see the module docs for what is and is not supported).
fn crs_kind(path: &Path, keys: &GeoKeys) -> Result<CrsKind, DemError> {
    let unsupported = |message: String| {
        DemError::new(path, DemErrorKind::Unsupported { format: FORMAT, message })
    };
    let code = |c: Option<u16>| c.filter(|&c| c != 0 && c != USER_DEFINED);
    let projected_code = code(keys.projected);
    let geographic_code = code(keys.geographic);
    // GTModelTypeGeoKey decides; without it, a projected code, then a geographic one.
    let model = match keys.model_type {
        Some(m) => m,
        None if keys.projected.is_some_and(|c| c != 0) => 1,
        None if geographic_code.is_some_and(is_geographic_code) => 2,
        None => 0,
    };
    match model {
        1 => {
            let crs = match (projected_code, &keys.citation) {
                (Some(c), _) => Crs::Epsg(u32::from(c)),
                (None, Some(t)) => Crs::Text(t.clone()),
                (None, None) => Crs::Text("user-defined projected CRS".into()),
            };
            let unit_m = match keys.linear_units {
                Some(USER_DEFINED) => keys
                    .linear_unit_size
                    .filter(|u| u.is_finite() && *u > 0.0)
                    .ok_or_else(|| {
                    unsupported(
                        "a user-defined linear unit (ProjLinearUnitsGeoKey 32767) without a valid \
                         ProjLinearUnitSizeGeoKey (3077)"
                            .into(),
                    )
                })?,
                Some(u) => linear_unit_m(u).ok_or_else(|| {
                    unsupported(format!(
                        "linear unit EPSG:{u} (ProjLinearUnitsGeoKey) is not an EPSG length unit; \
                         convert the file to metres (gdalwarp -t_srs) to read it"
                    ))
                })?,
                None => keys.citation.as_deref().map_or(1.0, unit_from_name),
            };
            Ok(CrsKind::Projected { crs, unit_m })
        }
        2 => {
            if let Some(u) = keys.angular_units.filter(|u| !DEGREE_UNITS.contains(u)) {
                return Err(unsupported(format!(
                    "a geographic CRS in angular unit EPSG:{u} (GeogAngularUnitsGeoKey); only \
                     degrees are read: convert the file (gdalwarp -t_srs EPSG:4326)"
                )));
            }
            let crs = match (geographic_code, &keys.citation) {
                (Some(c), _) => Crs::Epsg(u32::from(c)),
                (None, Some(t)) => Crs::Text(t.clone()),
                (None, None) => Crs::Text("user-defined geographic".into()),
            };
            Ok(CrsKind::Geographic(crs))
        }
        3 => Err(unsupported(
            "a geocentric CRS (GTModelTypeGeoKey 3): only projected and geographic grids are read"
                .into(),
        )),
        _ => Ok(CrsKind::Unknown(keys.citation.clone().map_or(Crs::Unknown, Crs::Text))),
    }
}

/// Whether an EPSG code is a geographic 2D CRS (EPSG's 4001..4999 range: 4326 WGS 84, 4269 NAD83...).
fn is_geographic_code(code: u16) -> bool {
    (4001..=4999).contains(&code)
}

/// A GeoTIFF whose header and georeference have been read, samples not yet decoded.
pub(crate) struct Opened {
    pub dec: Decoder<Source>,
    pub width: u32,
    pub height: u32,
    pub georef: Georef,
    pub file_nodata: Option<f64>,
    /// How the samples lie in the chunks, and the band read.
    pub layout: Layout,
    /// The sample type's name ("int16", "uint3"...).
    pub sample_type: String,
    /// Bands in the file.
    pub bands: u16,
}

/// Opens a decoder on `path` with the decoding limits of `options` (a buffer of at most
/// `max_bytes`), without reading anything but the header.
pub(crate) fn decoder(
    path: &Path,
    len: u64,
    max_bytes: usize,
) -> Result<Decoder<Source>, DemError> {
    Ok(decoder_and_mask(path, len, max_bytes)?.0)
}

/// [`decoder`], with the IFD index of the internal mask (if any).
fn decoder_and_mask(
    path: &Path,
    len: u64,
    max_bytes: usize,
) -> Result<(Decoder<Source>, Option<usize>), DemError> {
    let mut file = File::open(path).map_err(|e| DemError::new(path, DemErrorKind::Io(e)))?;
    let Precheck { patches, mask_ifd } = precheck_header(path, &mut file, len)?;
    let file = Patched { file, pos: 0, patches };
    let limits = {
        let mut l = Limits::default();
        l.decoding_buffer_size = max_bytes;
        l.intermediate_buffer_size = max_bytes.min(1 << 30);
        l.ifd_value_size = 64 << 20;
        l
    };
    let dec = Decoder::new(BufReader::new(file))
        .map_err(|e| map_tiff_error(path, len, e))?
        .with_limits(limits);
    Ok((dec, mask_ifd))
}

/// Maps a `tiff` error while decoding samples (for [`super::rows`]).
pub(crate) fn decode_error(path: &Path, len: u64, e: TiffError) -> DemError {
    map_tiff_error(path, len, e)
}

/// Reads a GeoTIFF of `len` bytes: band [`LoadOptions::band`], chunk by chunk
/// ([`geotiff_chunks::band_chunk`]), no-data, masked and sparse samples as NaN, the others in
/// metres (GDAL's scale and offset, then `vertical_scale` and `vertical_offset`).
pub(crate) fn read(path: &Path, len: u64, options: &LoadOptions) -> Result<RawGrid, DemError> {
    // Decoding buffer: one chunk as f64 at most; the image was checked against max_samples
    // before any decode happens, so this limit is a second line of defence. Also capped by the
    // memory limit: the decoder sizes tag value lists by it too.
    let max_bytes =
        options.max_samples.saturating_mul(8).min(options.max_memory_bytes).min(usize::MAX as u64)
            as usize;
    let Opened { mut dec, width: w, height: h, georef, file_nodata, layout, sample_type, bands } =
        open(path, len, options, max_bytes)?;
    let mut notes = Vec::new();
    if bands > 1 {
        let band = options.band;
        notes.push(super::LoadWarning::Bands { path: path.to_path_buf(), band, bands });
    }
    let (w, h) = (w as usize, h as usize);
    let nodata = options.nodata.or(file_nodata);
    let vertical = Vertical::new(&layout, options);
    let mut data = vec![0f32; w * h];
    for index in 0..layout.per_plane() {
        let values = geotiff_chunks::band_chunk(path, len, &mut dec, &layout, index)?;
        let mask = geotiff_chunks::mask_chunk(path, len, &mut dec, &layout, index)?;
        let (dw, dh) = layout.data_dims(index);
        let (across, cw, ch) = (layout.across(), layout.chunk_w, layout.chunk_h);
        let (x0, r0) = (((index % across) * cw) as usize, ((index / across) * ch) as usize);
        for r in 0..dh {
            // File rows are north first (south first when south-up); ours are south first.
            let j = if layout.south_up { r0 + r } else { h - 1 - (r0 + r) };
            for c in 0..dw {
                let k = r * dw + c;
                let valid = mask.as_ref().is_none_or(|m| m[k]);
                data[j * w + x0 + c] = vertical.metres(path, values[k], nodata, valid)?;
            }
        }
    }
    let vertical = (vertical.scale, vertical.offset);
    Ok(RawGrid { width: w, height: h, data, georef, nodata, sample_type, notes, vertical })
}

/// A GeoTIFF sample's way to metres: GDAL's band scale and offset, then the options'.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Vertical {
    pub scale: f64,
    pub offset: f64,
}

impl Vertical {
    pub(crate) fn new(layout: &Layout, options: &LoadOptions) -> Self {
        let (s, o) = (options.vertical_scale, options.vertical_offset);
        Self { scale: layout.scale * s, offset: layout.offset * s + o }
    }

    /// Sample `raw` in metres, NaN when it is void (no-data, NaN, masked); refused when the
    /// scale takes it out of f32's range.
    pub(crate) fn metres(
        &self,
        path: &Path,
        raw: f32,
        nodata: Option<f64>,
        valid: bool,
    ) -> Result<f32, DemError> {
        let v = f64::from(raw);
        let void = !valid
            || !v.is_finite()
            || nodata.is_some_and(|nd| v == nd || nd.is_nan() && v.is_nan());
        if void {
            return Ok(f32::NAN);
        }
        super::metres(path, v, self.scale, self.offset)
    }
}

/// Decoded samples as f32, with the file's sample type name.
pub(crate) fn samples_to_f32(
    path: &Path,
    result: DecodingResult,
) -> Result<(&'static str, Vec<f32>), DemError> {
    Ok(match result {
        DecodingResult::I16(v) => ("int16", v.into_iter().map(f32::from).collect()),
        DecodingResult::U16(v) => ("uint16", v.into_iter().map(f32::from).collect()),
        DecodingResult::I32(v) => ("int32", v.into_iter().map(|x| x as f32).collect()),
        DecodingResult::U32(v) => ("uint32", v.into_iter().map(|x| x as f32).collect()),
        DecodingResult::F32(v) => ("float32", v),
        DecodingResult::F64(v) => ("float64", v.into_iter().map(|x| x as f32).collect()),
        DecodingResult::I8(v) => ("int8", v.into_iter().map(f32::from).collect()),
        DecodingResult::U8(v) => ("uint8", v.into_iter().map(f32::from).collect()),
        DecodingResult::F16(_) | DecodingResult::I64(_) | DecodingResult::U64(_) => {
            return Err(DemError::new(
                path,
                DemErrorKind::Unsupported {
                    format: FORMAT,
                    message:
                        "sample type float16/int64/uint64 (read: int8/16/32, uint8/16/32, float32/64)"
                            .to_string(),
                },
            ));
        }
    })
}

/// Opens a GeoTIFF of `len` bytes and reads its header and georeference (no samples).
pub(crate) fn open(
    path: &Path,
    len: u64,
    options: &LoadOptions,
    max_bytes: usize,
) -> Result<Opened, DemError> {
    let err = |kind| DemError::new(path, kind);
    let unsupported = |message: String| {
        DemError::new(path, DemErrorKind::Unsupported { format: FORMAT, message })
    };
    let (mut dec, mask_ifd) = decoder_and_mask(path, len, max_bytes)?;

    let (w, h) = dec.dimensions().map_err(|e| map_tiff_error(path, len, e))?;
    let compression: u16 = dec.find_tag_unsigned(Tag::Compression).ok().flatten().unwrap_or(1);
    geotiff_chunks::check_compression(path, compression)?;
    // Bits per sample and samples per pixel (bands): every band is a grid of heights to GDAL,
    // whatever the photometric interpretation says.
    let (bits, bands) = match dec.colortype().map_err(|e| map_tiff_error(path, len, e))? {
        ColorType::Gray(b) => (b, 1),
        ColorType::GrayA(b) => (b, 2),
        ColorType::RGB(b) => (b, 3),
        ColorType::RGBA(b) | ColorType::CMYK(b) => (b, 4),
        ColorType::Multiband { bit_depth, num_samples } => (bit_depth, num_samples),
        other => {
            return Err(unsupported(format!(
                "samples of colour type {other:?}: elevation rasters are read from grey or \
                 multi-band files"
            )));
        }
    };
    if !(matches!(bits, 1..=8 | 16 | 32 | 64)) {
        return Err(unsupported(format!(
            "{bits}-bit samples (NBITS={bits}) are not supported (read: 1 to 8, 16, 32 or 64 \
             bits); convert the file, e.g. gdal_translate -ot UInt16"
        )));
    }
    let band = options.band;
    if band == 0 || band > bands {
        return Err(err(DemErrorKind::InvalidOptions(format!(
            "band {band} was asked for (--band), the file has {bands} band{} (1..={bands})",
            if bands == 1 { "" } else { "s" }
        ))));
    }
    // While decoding: the file's samples, then their conversion to f32 (the flip into the kept
    // grid is counted by check_size).
    check_size(path, w as u64, h as u64, u64::from(bits).div_ceil(8) + 4, options)?;
    let chunks = check_chunks(path, &mut dec, len, compression)?;
    let (chunk_w, chunk_h) = dec.chunk_dimensions();
    if chunk_w == 0 || chunk_h == 0 {
        return Err(malformed(path, format!("chunk size {chunk_w} x {chunk_h}")));
    }
    let tag_u16 = |dec: &mut Decoder<Source>, tag: Tag, default: u16| {
        dec.find_tag_unsigned_vec::<u16>(tag)
            .ok()
            .flatten()
            .and_then(|v| v.first().copied())
            .unwrap_or(default)
    };
    let sample_format = tag_u16(&mut dec, Tag::SampleFormat, 1);
    let planar = tag_u16(&mut dec, Tag::PlanarConfiguration, 1);
    let predictor = tag_u16(&mut dec, Tag::Predictor, 1);
    let big_endian = matches!(dec.byte_order(), tiff::tags::ByteOrder::BigEndian);
    let metadata = match dec.find_tag(Tag::Unknown(GDAL_METADATA_TAG)) {
        Ok(Some(v)) => v.into_string().ok(),
        _ => None,
    };
    let (band_scale, band_offset) = metadata
        .as_deref()
        .map_or((1.0, 0.0), |xml| geotiff_chunks::gdal_scale_offset(xml, band - 1));
    let sample_type = match (sample_format, bits) {
        (_, 1..=7) => format!("uint{bits}"),
        (2, b) => format!("int{b}"),
        (3, b) => format!("float{b}"),
        (_, b) => format!("uint{b}"),
    };
    let mut layout = Layout {
        width: w,
        height: h,
        chunk: dec.get_chunk_type(),
        chunk_w,
        chunk_h,
        chunks,
        compression,
        bits: u16::from(bits),
        sample_format,
        samples: bands,
        planar,
        predictor,
        big_endian,
        band: band - 1,
        sparse_fill: 0.0,
        scale: band_scale,
        offset: band_offset,
        mask_ifd: None,
        south_up: false,
        max_chunk_bytes: options.max_memory_bytes,
    };
    let needed = u64::from(layout.per_plane()) * if planar == 2 { u64::from(bands) } else { 1 };
    if (layout.chunks.len() as u64) < needed {
        return Err(malformed(
            path,
            format!(
                "{} strip/tile offsets for {needed} chunks ({w} x {h} in {chunk_w} x {chunk_h}, \
                 {bands} band(s))",
                layout.chunks.len()
            ),
        ));
    }
    if let Some(ifd) = mask_ifd {
        // GDAL writes the mask with the image's size and blocks; anything else is refused.
        let e = |e| map_tiff_error(path, len, e);
        dec.seek_to_image(ifd).map_err(e)?;
        let same = dec.dimensions().map_err(e)? == (w, h)
            && dec.chunk_dimensions() == (chunk_w, chunk_h)
            && dec.get_chunk_type() == layout.chunk
            && matches!(dec.colortype(), Ok(ColorType::Gray(1)));
        dec.seek_to_image(0).map_err(e)?;
        if !same {
            return Err(unsupported(format!(
                "an internal mask (IFD {ifd}) unlike GDAL's (not 1-bit, or its size or blocks \
                 differ from the image's)"
            )));
        }
        layout.mask_ifd = Some(ifd);
    }

    // --- Georeference ---
    let scale = tag_f64s(path, &mut dec, Tag::ModelPixelScaleTag, "ModelPixelScaleTag (33550)")?;
    let tie = tag_f64s(path, &mut dec, Tag::ModelTiepointTag, "ModelTiepointTag (33922)")?;
    let transform = tag_f64s(
        path,
        &mut dec,
        Tag::Unknown(MODEL_TRANSFORMATION_TAG),
        "ModelTransformationTag (34264)",
    )?;
    let geo_dir = match dec.find_tag(Tag::GeoKeyDirectoryTag) {
        Ok(None) => None,
        Ok(Some(v)) => Some(
            v.into_u16_vec()
                .map_err(|e| malformed(path, format!("GeoKeyDirectoryTag (34735): {e}")))?,
        ),
        Err(e) => return Err(malformed(path, format!("GeoKeyDirectoryTag (34735): {e}"))),
    };
    let ascii = match dec.find_tag(Tag::Unknown(GEO_ASCII_PARAMS_TAG)) {
        Ok(Some(v)) => v.into_string().ok(),
        _ => None,
    };
    let doubles =
        tag_f64s(path, &mut dec, Tag::Unknown(GEO_DOUBLE_PARAMS_TAG), "GeoDoubleParamsTag (34736)")
            .ok()
            .flatten();
    let keys = match &geo_dir {
        Some(d) => parse_geokeys(path, d, ascii.as_deref(), doubles.as_deref())?,
        None => GeoKeys::default(),
    };
    let file_nodata = match dec.find_tag(Tag::GdalNodata) {
        Ok(None) => None,
        Ok(Some(v)) => {
            let s = v
                .into_string()
                .map_err(|e| malformed(path, format!("GDAL_NODATA (42113): {e}")))?;
            let t = s.trim_matches(|c: char| c == '\0' || c.is_whitespace());
            let parsed =
                if t.eq_ignore_ascii_case("nan") { Some(f64::NAN) } else { t.parse::<f64>().ok() };
            Some(parsed.ok_or_else(|| {
                malformed(path, format!("GDAL_NODATA (42113) {t:?} is not a number"))
            })?)
        }
        Err(e) => return Err(malformed(path, format!("GDAL_NODATA (42113): {e}"))),
    };

    // Raster -> model: x = x0 + col * sx, y = y0 - row * sy, with (col, row) raster coordinates
    // (corner convention, PixelIsArea). None if the file carries no georeference.
    let affine: Option<(DVec2, DVec2)> = if let (Some(s), Some(t)) = (&scale, &tie) {
        if s.len() < 2 || t.len() < 6 {
            return Err(malformed(
                path,
                format!(
                    "ModelPixelScaleTag (33550) has {} values and ModelTiepointTag (33922) {}; need 3 and 6",
                    s.len(),
                    t.len()
                ),
            ));
        }
        let (sx, sy) = (s[0], s[1]);
        Some((dvec2(t[3] - t[0] * sx, t[4] + t[1] * sy), dvec2(sx, sy)))
    } else if let Some(m) = &transform {
        if m.len() < 16 {
            return Err(malformed(
                path,
                format!("ModelTransformationTag (34264) has {} values, need 16", m.len()),
            ));
        }
        if m[1] != 0.0 || m[4] != 0.0 {
            return Err(err(DemErrorKind::Unsupported {
                format: FORMAT,
                message: "ModelTransformationTag (34264) with rotation or shear".to_string(),
            }));
        }
        Some((dvec2(m[3], m[7]), dvec2(m[0], -m[5])))
    } else {
        None
    };

    // A negative y pixel size (GeoTIFF's ModelPixelScale y, or a positive ModelTransformation
    // [5]) puts the file's first row at the south edge: such a raster is read with its rows
    // taken in file order (GDAL reads it the same way, as a "south-up" image). Its tie point is
    // then the south-west corner.
    let south_up = affine.is_some_and(|(_, s)| s.y < 0.0);
    layout.south_up = south_up;
    let georef = match affine {
        None => Georef::local(options.spacing_m),
        Some((corner, spacing)) => {
            let spacing = dvec2(spacing.x, spacing.y.abs());
            let finite = spacing.is_finite() && corner.is_finite();
            if !(finite && spacing.x > 0.0 && spacing.y > 0.0) {
                return Err(malformed(
                    path,
                    format!(
                        "pixel scale ({}, {}) must be finite and non-zero, with x positive \
                         (east to the right), origin ({}, {}) finite",
                        spacing.x, spacing.y, corner.x, corner.y
                    ),
                ));
            }
            // GTRasterTypeGeoKey (1025): 1 = PixelIsArea (default), 2 = PixelIsPoint.
            let half = if keys.raster_type == Some(2) { 0.0 } else { 0.5 };
            let sw = if south_up {
                dvec2(corner.x + half * spacing.x, corner.y + half * spacing.y)
            } else {
                dvec2(corner.x + half * spacing.x, corner.y - (h as f64 - 1.0 + half) * spacing.y)
            };
            match crs_kind(path, &keys)? {
                CrsKind::Projected { crs, unit_m } => {
                    Georef::projected_in(crs, sw, spacing, unit_m)
                }
                CrsKind::Geographic(crs) => {
                    let centre_lat = sw.y + 0.5 * (h as f64 - 1.0) * spacing.y;
                    if !(-90.0..=90.0).contains(&centre_lat) {
                        return Err(malformed(
                            path,
                            format!(
                                "geographic grid (degrees) centred at latitude {centre_lat}: the \
                                 georeference is not in degrees"
                            ),
                        ));
                    }
                    Georef::geographic(crs, sw, spacing, centre_lat)
                }
                CrsKind::Unknown(crs) => Georef::projected(crs, sw, spacing),
            }
        }
    };

    if affine.is_some() && options.spacing_given {
        return Err(err(DemErrorKind::InvalidOptions(format!(
            "--spacing is for files without a georeference; this GeoTIFF is placed by its own \
             ({} x {} m per sample), which is used: leave --spacing out",
            georef.spacing_m.x, georef.spacing_m.y
        ))));
    }
    // A sparse block is no-data where the band has a no-data value (a void), 0 otherwise.
    layout.sparse_fill = if file_nodata.is_some() { f32::NAN } else { 0.0 };
    Ok(Opened { dec, width: w, height: h, georef, file_nodata, layout, sample_type, bands })
}
