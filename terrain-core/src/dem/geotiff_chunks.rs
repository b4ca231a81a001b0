//! GeoTIFF strips and tiles as one band's samples: what the `tiff` crate decodes (every
//! compression it knows), plus what GDAL writes and it does not read on its own:
//!
//! * **sparse blocks** (`SPARSE_OK=TRUE`: offset and byte count 0): read as GDAL reads them,
//!   no-data where the band has a no-data value (here NaN, a void), 0 otherwise;
//! * **1- to 7-bit samples** (`NBITS`): rows bit-packed, most significant bit first (TIFF 6.0
//!   section 8, `FillOrder` 1), each row starting on a byte;
//! * **ZSTD** (compression 50000, the usual COG compression), decoded with `ruzstd`, with
//!   predictor 1, 2 (horizontal differencing, TIFF 6.0 section 14) or 3 (floating point,
//!   Adobe Photoshop TIFF Technical Note 3: bytes split into planes, most significant first,
//!   then byte-wise differencing);
//! * **several bands**, pixel- (`PlanarConfiguration` 1) or band-interleaved (2): one is read;
//! * **an internal mask** (GDAL's per-dataset mask: an IFD with `NewSubfileType` bit 4 and a
//!   1-bit `PhotometricInterpretation` 4 "transparency mask", shown to the decoder as 1-bit
//!   BlackIsZero): masked samples are voids;
//! * **band scale and offset** (`GDAL_METADATA`, tag 42112: `<Item name="SCALE" sample="0"
//!   role="scale">`): metres = value x scale + offset, as GDAL's unscaled values are scaled.
//!
//! Compressions nobody here decodes (LERC, LZMA, WebP, JPEG-XL, JPEG 2000...) are refused by
//! name before anything is read.

use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

use tiff::decoder::{ChunkType, Decoder, DecodingResult};

use super::geotiff::{self, Source};
use crate::error::{DemError, DemErrorKind};

const FORMAT: &str = "GeoTIFF";

/// TIFF compression codes read (1 none, 2-4 CCITT, 5 LZW, 7 JPEG, 8 and 32946 Deflate, 32773
/// PackBits by the `tiff` crate; 50000 ZSTD here).
pub(crate) const ZSTD: u16 = 50000;
const READ_COMPRESSIONS: [u16; 10] = [1, 2, 3, 4, 5, 7, 8, 32773, 32946, ZSTD];

/// The name of a TIFF compression code (libtiff's `tiff.h` and GDAL's registrations).
pub(crate) fn compression_name(code: u16) -> String {
    let name = match code {
        1 => "none",
        2 => "CCITT RLE",
        3 => "CCITT Group 3 fax",
        4 => "CCITT Group 4 fax",
        5 => "LZW",
        6 => "old-style JPEG",
        7 => "JPEG",
        8 | 32946 => "Deflate",
        9 | 10 => "JBIG (T.85/T.43)",
        32771 => "NeXT 2-bit RLE",
        32773 => "PackBits",
        32809 => "ThunderScan",
        32908 | 32909 => "Pixar",
        34661 => "JBIG",
        34676 | 34677 => "SGI LogLuv",
        34712 => "JPEG 2000",
        34887 => "LERC",
        34925 => "LZMA",
        ZSTD => "ZSTD",
        50001 => "WebP",
        50002 | 52546 => "JPEG-XL",
        _ => return format!("code {code}"),
    };
    format!("{name} ({code})")
}

/// Refuses a compression that is not read, naming it.
pub(crate) fn check_compression(path: &Path, code: u16) -> Result<(), DemError> {
    if READ_COMPRESSIONS.contains(&code) {
        return Ok(());
    }
    Err(DemError::new(
        path,
        DemErrorKind::Unsupported {
            format: FORMAT,
            message: format!(
                "compression {} is not supported (read: none, LZW, Deflate, PackBits, JPEG, \
                 ZSTD); convert the file, e.g. gdal_translate -co COMPRESS=DEFLATE",
                compression_name(code)
            ),
        },
    ))
}

/// How a GeoTIFF's samples are laid out in its chunks, and which band is read.
#[derive(Debug, Clone)]
pub(crate) struct Layout {
    pub width: u32,
    pub height: u32,
    pub chunk: ChunkType,
    pub chunk_w: u32,
    pub chunk_h: u32,
    /// `(offset, byte count)` of every chunk of every plane, as stored.
    pub chunks: Vec<(u64, u64)>,
    pub compression: u16,
    pub bits: u16,
    /// `SampleFormat`: 1 unsigned, 2 signed, 3 IEEE float.
    pub sample_format: u16,
    /// Samples per pixel (bands).
    pub samples: u16,
    /// `PlanarConfiguration`: 1 pixel-interleaved, 2 band-interleaved.
    pub planar: u16,
    pub predictor: u16,
    pub big_endian: bool,
    /// The band read, from 0.
    pub band: u16,
    /// The value of a sparse block's samples: NaN (void) when the band has a no-data value, 0
    /// otherwise (as GDAL).
    pub sparse_fill: f32,
    /// GDAL's band scale and offset (1 and 0 without them).
    pub scale: f64,
    pub offset: f64,
    /// The IFD index of the internal mask, if any.
    pub mask_ifd: Option<usize>,
    /// Whether the file's first row is its southernmost (a positive y pixel size, as numpy
    /// grids with latitude ascending are often written); north-up files store the north row
    /// first.
    pub south_up: bool,
    /// The most bytes one inflated ZSTD chunk may take (`LoadOptions::max_memory_bytes`): a
    /// tile may be declared far larger than its image.
    pub max_chunk_bytes: u64,
}

impl Layout {
    /// Chunks across one plane (strips: 1).
    pub(crate) fn across(&self) -> u32 {
        match self.chunk {
            ChunkType::Strip => 1,
            ChunkType::Tile => self.width.div_ceil(self.chunk_w),
        }
    }

    /// Chunks in one plane.
    pub(crate) fn per_plane(&self) -> u32 {
        self.across() * self.height.div_ceil(self.chunk_h)
    }

    /// Samples of one band in plane chunk `index`: columns and rows inside the image.
    pub(crate) fn data_dims(&self, index: u32) -> (usize, usize) {
        let (across, cw, ch) = (self.across(), self.chunk_w, self.chunk_h);
        let (tx, ty) = (index % across, index / across);
        let w = match self.chunk {
            ChunkType::Strip => self.width,
            ChunkType::Tile => cw.min(self.width.saturating_sub(tx * cw)),
        };
        (w as usize, ch.min(self.height.saturating_sub(ty * ch)) as usize)
    }

    /// The stored chunk index of the read band's plane chunk `index`.
    fn file_index(&self, index: u32) -> u32 {
        if self.planar == 2 { u32::from(self.band) * self.per_plane() + index } else { index }
    }

    /// Samples per pixel inside one chunk.
    fn chunk_samples(&self) -> usize {
        if self.planar == 2 { 1 } else { usize::from(self.samples) }
    }

    /// Sample index of the read band inside a pixel of a chunk.
    fn band_in_chunk(&self) -> usize {
        if self.planar == 2 { 0 } else { usize::from(self.band) }
    }
}

fn malformed(path: &Path, message: String) -> DemError {
    DemError::new(path, DemErrorKind::Malformed { format: FORMAT, message })
}

fn what(layout: &Layout) -> &'static str {
    match layout.chunk {
        ChunkType::Strip => "strip",
        ChunkType::Tile => "tile",
    }
}

/// The read band's samples of plane chunk `index` (`data_dims` of them, row-major, rows north
/// first), as stored (no scale, offset or no-data applied; a sparse block's are
/// [`Layout::sparse_fill`]).
pub(crate) fn band_chunk(
    path: &Path,
    len: u64,
    dec: &mut Decoder<Source>,
    layout: &Layout,
    index: u32,
) -> Result<Vec<f32>, DemError> {
    let (dw, dh) = layout.data_dims(index);
    let file_index = layout.file_index(index);
    let Some(&(offset, count)) = layout.chunks.get(file_index as usize) else {
        return Err(malformed(
            path,
            format!(
                "{} {file_index} is not in the file's {} offsets",
                what(layout),
                layout.chunks.len()
            ),
        ));
    };
    if count == 0 {
        return Ok(vec![layout.sparse_fill; dw * dh]);
    }
    if layout.compression == ZSTD {
        let (full_w, rows) = match layout.chunk {
            ChunkType::Strip => (dw, dh),
            ChunkType::Tile => (layout.chunk_w as usize, layout.chunk_h as usize),
        };
        let bytes = zstd_chunk(path, layout, file_index, (offset, count), full_w, rows)?;
        return band_from_bytes(path, layout, &bytes, full_w, (dw, dh));
    }
    if matches!(layout.compression, 8 | 32946) {
        geotiff::check_deflate_chunks(
            path,
            &format!("TIFF {}", what(layout)),
            &layout.chunks,
            [file_index as usize].into_iter(),
        )?;
    }
    let result = dec.read_chunk(file_index).map_err(|e| geotiff::decode_error(path, len, e))?;
    if layout.bits < 8 {
        let DecodingResult::U8(packed) = result else {
            return Err(malformed(path, format!("{}-bit samples decoded as words", layout.bits)));
        };
        // The decoder returns the data columns only, each row from a byte boundary.
        return unpack_bits(path, layout, &packed, dw, (dw, dh));
    }
    let (_, values) = geotiff::samples_to_f32(path, result)?;
    pick_band(path, layout, &values, dw, (dw, dh))
}

/// The read band out of row-major pixels `full_w` wide (`chunk_samples` per pixel), cropped
/// to `dw x dh`.
fn pick_band(
    path: &Path,
    layout: &Layout,
    values: &[f32],
    full_w: usize,
    (dw, dh): (usize, usize),
) -> Result<Vec<f32>, DemError> {
    let (cs, b) = (layout.chunk_samples(), layout.band_in_chunk());
    if values.len() < full_w * cs * dh.saturating_sub(1) + dw * cs {
        return Err(malformed(
            path,
            format!(
                "a {} decoded to {} samples, it holds {dw} x {dh} pixels of {cs} samples",
                what(layout),
                values.len()
            ),
        ));
    }
    let mut out = Vec::with_capacity(dw * dh);
    for r in 0..dh {
        let row = &values[r * full_w * cs..];
        out.extend((0..dw).map(|x| row[x * cs + b]));
    }
    Ok(out)
}

/// Bytes per row of `full_w` pixels.
fn row_bytes(layout: &Layout, full_w: usize) -> usize {
    (full_w * layout.chunk_samples() * usize::from(layout.bits)).div_ceil(8)
}

/// The read band of bit-packed rows (`full_w` pixels a row, each row from a byte boundary),
/// cropped to `dw x dh`.
fn unpack_bits(
    path: &Path,
    layout: &Layout,
    packed: &[u8],
    full_w: usize,
    (dw, dh): (usize, usize),
) -> Result<Vec<f32>, DemError> {
    let stride = row_bytes(layout, full_w);
    if packed.len() < stride * dh {
        return Err(malformed(
            path,
            format!(
                "a {} of {}-bit samples decoded to {} bytes, its {dw} x {dh} pixels need {}",
                what(layout),
                layout.bits,
                packed.len(),
                stride * dh
            ),
        ));
    }
    let (bits, cs, b) = (usize::from(layout.bits), layout.chunk_samples(), layout.band_in_chunk());
    let mut out = Vec::with_capacity(dw * dh);
    for r in 0..dh {
        let row = &packed[r * stride..(r + 1) * stride];
        for x in 0..dw {
            let first = (x * cs + b) * bits;
            let mut v = 0u32;
            for k in first..first + bits {
                v = (v << 1) | u32::from((row[k / 8] >> (7 - k % 8)) & 1);
            }
            out.push(v as f32);
        }
    }
    Ok(out)
}

/// Reads and inflates ZSTD chunk `file_index` (`rows` rows of `full_w` pixels), and undoes its
/// predictor: the bytes of the samples in file order (predictor 3: big-endian).
fn zstd_chunk(
    path: &Path,
    layout: &Layout,
    file_index: u32,
    (offset, count): (u64, u64),
    full_w: usize,
    rows: usize,
) -> Result<Vec<u8>, DemError> {
    let io = |e| DemError::new(path, DemErrorKind::Io(e));
    let stride = row_bytes(layout, full_w);
    let expected = stride.saturating_mul(rows);
    if expected as u64 > layout.max_chunk_bytes {
        return Err(DemError::new(
            path,
            DemErrorKind::ChunkMemoryLimit {
                chunk_w: full_w as u32,
                chunk_h: rows as u32,
                chunks: 1,
                bytes: expected as u64,
                limit: layout.max_chunk_bytes,
            },
        ));
    }
    let mut file = File::open(path).map_err(io)?;
    file.seek(SeekFrom::Start(offset)).map_err(io)?;
    // The chunk lies inside the file (checked when opened), so this is bounded by its size.
    let mut compressed = vec![0u8; count as usize];
    file.read_exact(&mut compressed).map_err(io)?;
    let damaged = |why: String| {
        malformed(
            path,
            format!(
                "TIFF {} {file_index} (bytes {offset}..{}): corrupt ZSTD stream ({why}); the \
                 file is damaged, read a good copy",
                what(layout),
                offset + count
            ),
        )
    };
    let mut out = Vec::with_capacity(expected);
    let decoder = ruzstd::decoding::StreamingDecoder::new(compressed.as_slice())
        .map_err(|e| damaged(e.to_string()))?;
    // At most one byte more than needed: a longer stream is refused, not buffered.
    decoder.take(expected as u64 + 1).read_to_end(&mut out).map_err(|e| damaged(e.to_string()))?;
    if out.len() != expected {
        return Err(damaged(format!(
            "{} bytes inflated, {rows} rows of {full_w} pixels are {expected}",
            out.len()
        )));
    }
    let bps = usize::from(layout.bits).div_ceil(8);
    let n = full_w * layout.chunk_samples();
    match layout.predictor {
        1 => {}
        2 => {
            if layout.bits < 8 || layout.sample_format == 3 {
                return Err(unsupported(
                    path,
                    format!(
                        "predictor 2 on {}-bit {} samples",
                        layout.bits,
                        if layout.sample_format == 3 { "float" } else { "packed" }
                    ),
                ));
            }
            let cs = layout.chunk_samples();
            for row in out.chunks_exact_mut(stride) {
                undo_horizontal(row, bps, cs, layout.big_endian);
            }
        }
        3 => {
            if layout.sample_format != 3 {
                return Err(unsupported(path, "predictor 3 on integer samples".into()));
            }
            let cs = layout.chunk_samples();
            let mut tmp = vec![0u8; stride];
            for row in out.chunks_exact_mut(stride) {
                // Byte-wise differencing, `cs` bytes apart (one byte plane of each sample).
                for i in cs..row.len() {
                    row[i] = row[i].wrapping_add(row[i - cs]);
                }
                // Plane `k` holds byte `k` (most significant first) of every sample.
                tmp.copy_from_slice(row);
                for s in 0..n {
                    for k in 0..bps {
                        row[s * bps + k] = tmp[k * n + s];
                    }
                }
            }
        }
        p => return Err(unsupported(path, format!("predictor {p}"))),
    }
    Ok(out)
}

fn unsupported(path: &Path, message: String) -> DemError {
    DemError::new(path, DemErrorKind::Unsupported { format: FORMAT, message })
}

/// Undoes horizontal differencing (predictor 2) on one row of `bps`-byte integer samples,
/// `cs` samples a pixel, in the file's byte order: each sample adds the one a pixel before,
/// modulo 2^bits.
fn undo_horizontal(row: &mut [u8], bps: usize, cs: usize, big_endian: bool) {
    let get = |b: &[u8]| -> u64 {
        let mut v = 0u64;
        for k in 0..bps {
            let byte = if big_endian { b[k] } else { b[bps - 1 - k] };
            v = (v << 8) | u64::from(byte);
        }
        v
    };
    let mask = if bps >= 8 { u64::MAX } else { (1u64 << (8 * bps)) - 1 };
    let n = row.len() / bps;
    for s in cs..n {
        let prev = get(&row[(s - cs) * bps..(s - cs + 1) * bps]);
        let cur = get(&row[s * bps..(s + 1) * bps]);
        let v = cur.wrapping_add(prev) & mask;
        for k in 0..bps {
            let byte = (v >> (8 * k)) as u8;
            let at = if big_endian { s * bps + bps - 1 - k } else { s * bps + k };
            row[at] = byte;
        }
    }
}

/// The read band of a decoded (and un-predicted) chunk's bytes: `full_w` pixels a row, cropped
/// to `dw x dh`.
fn band_from_bytes(
    path: &Path,
    layout: &Layout,
    bytes: &[u8],
    full_w: usize,
    dims: (usize, usize),
) -> Result<Vec<f32>, DemError> {
    if layout.bits < 8 {
        return unpack_bits(path, layout, bytes, full_w, dims);
    }
    let bps = usize::from(layout.bits) / 8;
    // Predictor 3 leaves the samples big-endian whatever the file's byte order.
    let be = layout.big_endian || layout.predictor == 3;
    let word = |b: &[u8]| -> u64 {
        let mut v = 0u64;
        for k in 0..bps {
            v = (v << 8) | u64::from(if be { b[k] } else { b[bps - 1 - k] });
        }
        v
    };
    let convert = |w: u64| -> Option<f32> {
        Some(match (layout.sample_format, layout.bits) {
            (1, 8 | 16 | 32) => w as f32,
            (2, 8) => f32::from(w as u8 as i8),
            (2, 16) => f32::from(w as u16 as i16),
            (2, 32) => w as u32 as i32 as f32,
            (3, 32) => f32::from_bits(w as u32),
            (3, 64) => f64::from_bits(w) as f32,
            _ => return None,
        })
    };
    let mut values = Vec::with_capacity(bytes.len() / bps);
    for b in bytes.chunks_exact(bps) {
        values.push(convert(word(b)).ok_or_else(|| {
            unsupported(
                path,
                format!(
                    "{}-bit samples of SampleFormat {} (read: int8/16/32, uint8/16/32, float32/64)",
                    layout.bits, layout.sample_format
                ),
            )
        })?);
    }
    pick_band(path, layout, &values, full_w, dims)
}

/// Whether plane chunk `index`'s samples are valid by the internal mask (`None`: no mask).
/// The decoder is left on the image's IFD.
pub(crate) fn mask_chunk(
    path: &Path,
    len: u64,
    dec: &mut Decoder<Source>,
    layout: &Layout,
    index: u32,
) -> Result<Option<Vec<bool>>, DemError> {
    let Some(ifd) = layout.mask_ifd else { return Ok(None) };
    let (dw, dh) = layout.data_dims(index);
    let e = |e| geotiff::decode_error(path, len, e);
    dec.seek_to_image(ifd).map_err(e)?;
    let counts = dec
        .get_tag_u64_vec(match layout.chunk {
            ChunkType::Strip => tiff::tags::Tag::StripByteCounts,
            ChunkType::Tile => tiff::tags::Tag::TileByteCounts,
        })
        .map_err(e);
    let result = match counts {
        // A sparse mask block reads as 0 (masked), as GDAL reads sparse blocks without no-data.
        Ok(c) if c.get(index as usize) == Some(&0) => Ok(None),
        Ok(_) => dec.read_chunk(index).map(Some).map_err(e),
        Err(err) => Err(err),
    };
    dec.seek_to_image(0).map_err(e)?;
    let valid = match result? {
        None => vec![false; dw * dh],
        Some(DecodingResult::U8(packed)) => {
            let stride = dw.div_ceil(8);
            if packed.len() < stride * dh {
                return Err(malformed(
                    path,
                    format!(
                        "internal mask {} {index}: {} bytes decoded",
                        what(layout),
                        packed.len()
                    ),
                ));
            }
            (0..dh)
                .flat_map(|r| {
                    let row = &packed[r * stride..];
                    (0..dw).map(move |x| (row[x / 8] >> (7 - x % 8)) & 1 == 1)
                })
                .collect()
        }
        Some(_) => {
            return Err(unsupported(path, "an internal mask that is not 1-bit".into()));
        }
    };
    Ok(Some(valid))
}

/// GDAL's scale and offset of band `band` (from 0) in the `GDAL_METADATA` XML (tag 42112):
/// `<Item name="SCALE" sample="0" role="scale">0.5</Item>`. `(1, 0)` where absent.
pub(crate) fn gdal_scale_offset(xml: &str, band: u16) -> (f64, f64) {
    let (mut scale, mut offset) = (1.0, 0.0);
    for item in xml.split("<Item").skip(1) {
        let Some((attrs, rest)) = item.split_once('>') else { continue };
        let Some((value, _)) = rest.split_once("</Item>") else { continue };
        let attr = |name: &str| {
            let key = format!("{name}=\"");
            attrs.find(&key).and_then(|at| {
                let v = &attrs[at + key.len()..];
                v.split_once('"').map(|(v, _)| v.to_string())
            })
        };
        let sample = attr("sample").and_then(|s| s.parse::<u16>().ok());
        if sample != Some(band) {
            continue;
        }
        let role = attr("role").or_else(|| attr("name")).unwrap_or_default().to_ascii_lowercase();
        let Ok(v) = value.trim().parse::<f64>() else { continue };
        match role.as_str() {
            "scale" if v.is_finite() && v != 0.0 => scale = v,
            "offset" if v.is_finite() => offset = v,
            _ => {}
        }
    }
    (scale, offset)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gdal_metadata_scale_and_offset_per_band() {
        let xml = r#"<GDALMetadata>
  <Item name="OFFSET" sample="0" role="offset">100</Item>
  <Item name="SCALE" sample="0" role="scale">0.5</Item>
  <Item name="SCALE" sample="1" role="scale">2</Item>
</GDALMetadata>"#;
        assert_eq!(gdal_scale_offset(xml, 0), (0.5, 100.0));
        assert_eq!(gdal_scale_offset(xml, 1), (2.0, 0.0));
        assert_eq!(gdal_scale_offset(xml, 2), (1.0, 0.0));
        assert_eq!(gdal_scale_offset("<GDALMetadata></GDALMetadata>", 0), (1.0, 0.0));
    }

    #[test]
    fn horizontal_differencing_is_undone_in_both_byte_orders() {
        // Samples 1000, 1001, 999 as differences 1000, +1, -2 (int16).
        let diffs: [i16; 3] = [1000, 1, -2];
        for be in [false, true] {
            let mut row: Vec<u8> = diffs
                .iter()
                .flat_map(|d| if be { d.to_be_bytes() } else { d.to_le_bytes() })
                .collect();
            undo_horizontal(&mut row, 2, 1, be);
            let got: Vec<i16> = row
                .chunks_exact(2)
                .map(|b| {
                    if be {
                        i16::from_be_bytes([b[0], b[1]])
                    } else {
                        i16::from_le_bytes([b[0], b[1]])
                    }
                })
                .collect();
            assert_eq!(got, vec![1000, 1001, 999], "big-endian: {be}");
        }
    }

    #[test]
    fn a_zstd_tile_beyond_the_memory_limit_is_refused_before_reading() {
        // One 65535 x 65535 int16 tile declared for a 10 x 10 image: 8 GiB inflated.
        let layout = Layout {
            width: 10,
            height: 10,
            chunk: ChunkType::Tile,
            chunk_w: 65535,
            chunk_h: 65535,
            chunks: vec![(8, 100)],
            compression: ZSTD,
            bits: 16,
            sample_format: 2,
            samples: 1,
            planar: 1,
            predictor: 1,
            big_endian: false,
            band: 0,
            sparse_fill: 0.0,
            scale: 1.0,
            offset: 0.0,
            mask_ifd: None,
            south_up: false,
            max_chunk_bytes: 1 << 30,
        };
        // The file is never opened: the size is refused first.
        let e = zstd_chunk(Path::new("no/such/file.tif"), &layout, 0, (8, 100), 65535, 65535)
            .unwrap_err();
        assert!(matches!(e.kind, DemErrorKind::ChunkMemoryLimit { .. }), "{e}");
    }

    #[test]
    fn compressions_are_named() {
        assert_eq!(compression_name(34887), "LERC (34887)");
        assert_eq!(compression_name(4242), "code 4242");
        let e = check_compression(Path::new("x.tif"), 50001).unwrap_err().to_string();
        assert!(e.contains("WebP (50001)") && e.contains("not supported"), "{e}");
        assert!(check_compression(Path::new("x.tif"), ZSTD).is_ok());
    }
}
