//! Image DEMs: grey PNG/JPEG heightmaps and the Terrain-RGB / Terrarium PNG encodings.
//!
//! * Grey (8- or 16-bit; PNG keeps all 16 bits): `metres = raw x vertical_scale + vertical_offset`.
//!   A colour JPEG is converted to luma (JPEG heightmaps are often saved as YCbCr with equal
//!   channels); a colour PNG is refused unless Terrain-RGB or Terrarium is asked for, because
//!   reading an arbitrary RGB picture as heights is almost always a mistake.
//! * Mapbox Terrain-RGB: `metres = -10000 + (R x 65536 + G x 256 + B) x 0.1`.
//! * Mapzen Terrarium: `metres = R x 256 + G + B / 256 - 32768`.
//!
//! For the RGB encodings, a pixel with alpha 0 is void. Images carry no georeference: the grid
//! is placed in a local metric frame with `LoadOptions::spacing_m`. Rows are top (north) first
//! in the image and flipped to south first here.

use std::io::BufReader;
use std::path::Path;

use image::{DynamicImage, ImageDecoder, ImageError, ImageFormat, ImageReader};

use crate::dem::{Format, LoadOptions, Magic, RawGrid, check_size};
use crate::error::{DemError, DemErrorKind};
use crate::georef::Georef;

fn format_name(magic: Magic) -> &'static str {
    match magic {
        Magic::Jpeg => "JPEG",
        _ => "PNG",
    }
}

fn map_image_error(path: &Path, magic: Magic, e: ImageError) -> DemError {
    let format = format_name(magic);
    let kind = match e {
        ImageError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            DemErrorKind::Malformed {
                format,
                message: format!("unexpected end of file (truncated?): {io}"),
            }
        }
        ImageError::IoError(io) => DemErrorKind::Io(io),
        ImageError::Unsupported(u) => DemErrorKind::Unsupported { format, message: u.to_string() },
        ImageError::Limits(l) => DemErrorKind::Unsupported {
            format,
            message: format!("decoder memory limit exceeded: {l}"),
        },
        other => DemErrorKind::Malformed { format, message: other.to_string() },
    };
    DemError::new(path, kind)
}

/// Refuses a JPEG that ends before its end-of-image marker (`FF D9`): the decoder fills the
/// missing part of a truncated file grey and reports success. Walks the marker segments
/// (ITU-T T.81 annex B: every segment but SOI, EOI, RSTn and TEM carries a 16-bit length;
/// after each SOS the entropy-coded data runs to the next marker, with `FF` stuffed as
/// `FF 00`), so an EOI inside an embedded thumbnail (an APP1 segment) is not taken for the
/// image's own.
fn check_jpeg_complete(path: &Path, bytes: &[u8]) -> Result<(), DemError> {
    let len = bytes.len();
    let truncated = |at: usize, what: &str| {
        DemError::new(
            path,
            DemErrorKind::Malformed {
                format: "JPEG",
                message: format!(
                    "the file ends ({len} bytes) {what} at byte {at}, before the end-of-image \
                     marker (FF D9): it is truncated; read a complete copy"
                ),
            },
        )
    };
    let mut pos = 2; // after SOI
    loop {
        // Fill bytes (FF FF ...) may precede a marker.
        while pos < len && bytes[pos] != 0xFF {
            pos += 1;
        }
        while pos + 1 < len && bytes[pos + 1] == 0xFF {
            pos += 1;
        }
        if pos + 1 >= len {
            return Err(truncated(pos, "looking for a marker"));
        }
        let marker = bytes[pos + 1];
        match marker {
            0xD9 => return Ok(()),
            0x01 | 0xD0..=0xD8 => pos += 2,
            _ => {
                if pos + 4 > len {
                    return Err(truncated(pos, "in a segment header"));
                }
                let seg = usize::from(u16::from_be_bytes([bytes[pos + 2], bytes[pos + 3]]));
                if pos + 2 + seg > len {
                    return Err(truncated(pos, "inside a segment"));
                }
                pos += 2 + seg;
                if marker == 0xDA {
                    // Entropy-coded data up to the next marker that is not a stuffed FF 00 or
                    // a restart marker.
                    loop {
                        if pos + 1 >= len {
                            return Err(truncated(pos, "inside the compressed image data"));
                        }
                        if bytes[pos] == 0xFF
                            && bytes[pos + 1] != 0x00
                            && !(0xD0..=0xD7).contains(&bytes[pos + 1])
                        {
                            break;
                        }
                        pos += 1;
                    }
                }
            }
        }
    }
}

/// Deflate's largest expansion: a 258-byte match coded in 2 bits (1 bit length code, 1 bit
/// distance code) is 1032 output bytes per input byte (RFC 1951; zlib's "technical details").
const DEFLATE_MAX_RATIO: u64 = 1032;
/// Fewest pixels one byte of baseline or progressive JPEG can describe: every 8x8 block of a
/// full-resolution component codes at least its DC difference, one Huffman code of at least
/// one bit (ITU-T T.81 F.1.2.1, G.1.2.1), so 64 pixels per bit.
const JPEG_MAX_PIXELS_PER_BYTE: u64 = 64 * 8;

/// Refuses an image whose declared size its file is far too small to hold, before a decoder
/// allocates for it: a PNG's zlib stream inflates at most [`DEFLATE_MAX_RATIO`] times, a JPEG
/// codes at most [`JPEG_MAX_PIXELS_PER_BYTE`] pixels a byte. Both bounds are generous (real
/// files are far from them), so only a corrupt or crafted header is refused.
fn check_declared_size(
    path: &Path,
    magic: Magic,
    len: u64,
    w: u64,
    h: u64,
) -> Result<(), DemError> {
    let pixels = w.saturating_mul(h);
    let min_bytes = if magic == Magic::Jpeg {
        pixels.div_ceil(JPEG_MAX_PIXELS_PER_BYTE)
    } else {
        // Filtered rows: one filter byte each plus the row's packed samples (fewer than an
        // interlaced image has, so a lower bound).
        let bits = png_bits_per_pixel(path).unwrap_or(1);
        let raw = h.saturating_mul(1 + w.saturating_mul(bits).div_ceil(8));
        raw.div_ceil(DEFLATE_MAX_RATIO)
    };
    if len < min_bytes {
        let format = format_name(magic);
        return Err(DemError::new(
            path,
            DemErrorKind::Malformed {
                format,
                message: format!(
                    "the header declares {w} x {h} pixels, which no {format} file under \
                     {min_bytes} bytes can hold, and the file has {len} bytes: the header is \
                     corrupt"
                ),
            },
        ));
    }
    Ok(())
}

/// Bits per pixel a PNG declares in its IHDR chunk, which the PNG specification places
/// first (bytes 8..33: length, "IHDR", width, height, bit depth, colour type, ...); `None`
/// when the file cannot say (the decoder then reports the fault).
fn png_bits_per_pixel(path: &Path) -> Option<u64> {
    let mut head = [0u8; 26];
    std::io::Read::read_exact(&mut std::fs::File::open(path).ok()?, &mut head).ok()?;
    if &head[12..16] != b"IHDR" {
        return None;
    }
    let channels = match head[25] {
        0 | 3 => 1, // grey, palette index
        4 => 2,     // grey + alpha
        2 => 3,     // RGB
        6 => 4,     // RGBA
        _ => return None,
    };
    Some(u64::from(head[24]) * channels)
}

fn open(path: &Path, magic: Magic) -> Result<ImageReader<BufReader<std::fs::File>>, DemError> {
    let file = std::fs::File::open(path).map_err(|e| DemError::new(path, DemErrorKind::Io(e)))?;
    let fmt = if magic == Magic::Jpeg { ImageFormat::Jpeg } else { ImageFormat::Png };
    Ok(ImageReader::with_format(BufReader::new(file), fmt))
}

/// Reads an image DEM as `format` (grey, Terrain-RGB or Terrarium).
pub(crate) fn read(
    path: &Path,
    len: u64,
    format: Format,
    magic: Magic,
    options: &LoadOptions,
) -> Result<RawGrid, DemError> {
    let err = |kind| DemError::new(path, kind);
    if magic == Magic::Jpeg {
        // Whole: the decoder reads the whole file too.
        let bytes = std::fs::read(path).map_err(|e| err(DemErrorKind::Io(e)))?;
        check_jpeg_complete(path, &bytes)?;
    }
    // Read the header first and refuse oversized images before the decoder allocates.
    let decoder = open(path, magic)?.into_decoder().map_err(|e| map_image_error(path, magic, e))?;
    let (w, h) = decoder.dimensions();
    let pixel_bytes = u64::from(decoder.color_type().bytes_per_pixel());
    drop(decoder);
    // While decoding: the decoded pixels, then at most one converted copy (RGBA8 for the RGB
    // encodings, luma for a colour JPEG: at most 4 bytes a pixel).
    check_size(path, w as u64, h as u64, pixel_bytes + 4, options)?;
    check_declared_size(path, magic, len, w as u64, h as u64)?;
    let mut reader = open(path, magic)?;
    let mut limits = image::Limits::default();
    // Decoded image plus decoder slack (a progressive JPEG keeps 16-bit coefficients of every
    // component), never over the memory limit.
    limits.max_alloc =
        Some((w as u64 * h as u64).saturating_mul(16).max(64 << 20).min(options.max_memory_bytes));
    reader.limits(limits);
    let img = reader.decode().map_err(|e| map_image_error(path, magic, e))?;
    let (w, h) = (w as usize, h as usize);
    if img.width() as usize != w || img.height() as usize != h {
        return Err(err(DemErrorKind::Malformed {
            format: format_name(magic),
            message: "decoded size differs from the header's".to_string(),
        }));
    }

    let mut data = vec![0f32; w * h];
    // Writes value `v` of image pixel (x, y) (y = 0 at the top) into the south-first grid.
    let mut put = |x: usize, y: usize, v: f32| data[(h - 1 - y) * w + x] = v;
    let (scale, offset) = (options.vertical_scale, options.vertical_offset);
    let nodata = options.nodata;
    // No-data applies to the raw value; voids become NaN so the void mask finds them.
    // A sample the scale takes beyond f32's range: refused below, not read as a void.
    let overflow = std::cell::Cell::new(None::<f64>);
    let grey = |raw: f64| -> f32 {
        if nodata.is_some_and(|nd| raw == nd) {
            return f32::NAN;
        }
        let z = (raw * scale + offset) as f32;
        if !z.is_finite() && overflow.get().is_none() {
            overflow.set(Some(raw));
        }
        z
    };

    let sample_type = match format {
        Format::GreyImage => match img {
            DynamicImage::ImageLuma16(g) => {
                for (x, y, p) in g.enumerate_pixels() {
                    put(x as usize, y as usize, grey(p.0[0] as f64));
                }
                "uint16 (grey PNG)".to_string()
            }
            DynamicImage::ImageLumaA16(g) => {
                for (x, y, p) in g.enumerate_pixels() {
                    put(x as usize, y as usize, grey(p.0[0] as f64));
                }
                "uint16 (grey+alpha PNG)".to_string()
            }
            DynamicImage::ImageLuma8(g) => {
                for (x, y, p) in g.enumerate_pixels() {
                    put(x as usize, y as usize, grey(p.0[0] as f64));
                }
                format!("uint8 (grey {})", format_name(magic))
            }
            DynamicImage::ImageLumaA8(g) => {
                for (x, y, p) in g.enumerate_pixels() {
                    put(x as usize, y as usize, grey(p.0[0] as f64));
                }
                format!("uint8 (grey+alpha {})", format_name(magic))
            }
            other if magic == Magic::Jpeg => {
                let g = other.to_luma8();
                for (x, y, p) in g.enumerate_pixels() {
                    put(x as usize, y as usize, grey(p.0[0] as f64));
                }
                "uint8 (colour JPEG read as luma)".to_string()
            }
            other => {
                return Err(err(DemErrorKind::Unsupported {
                    format: "PNG",
                    message: format!(
                        "a colour PNG ({:?}) is not a grey heightmap; give --format terrain-rgb \
                         or --format terrarium if it encodes heights in RGB",
                        other.color()
                    ),
                }));
            }
        },
        Format::TerrainRgb | Format::Terrarium => {
            let bits8 = matches!(img, DynamicImage::ImageRgb8(_) | DynamicImage::ImageRgba8(_));
            if !bits8 {
                return Err(err(DemErrorKind::Unsupported {
                    format: "PNG",
                    message: format!(
                        "{} needs an 8-bit RGB or RGBA PNG, this one is {:?}",
                        format.name(),
                        img.color()
                    ),
                }));
            }
            let rgba = img.to_rgba8();
            for (x, y, p) in rgba.enumerate_pixels() {
                let [r, g, b, a] = p.0;
                let (r, g, b) = (r as f64, g as f64, b as f64);
                let z = if format == Format::TerrainRgb {
                    -10000.0 + (r * 65536.0 + g * 256.0 + b) * 0.1
                } else {
                    r * 256.0 + g + b / 256.0 - 32768.0
                };
                put(x as usize, y as usize, if a == 0 { f32::NAN } else { z as f32 });
            }
            format!("uint8 RGB ({})", format.name())
        }
        _ => {
            return Err(err(DemErrorKind::InvalidOptions(format!(
                "{} is not an image format",
                format.name()
            ))));
        }
    };

    if let Some(raw) = overflow.get() {
        super::metres(path, raw, scale, offset)?;
    }
    Ok(RawGrid {
        width: w,
        height: h,
        data,
        georef: Georef::local(options.spacing_m),
        nodata,
        sample_type,
        notes: Vec::new(),
        vertical: if format == Format::GreyImage { (scale, offset) } else { (1.0, 0.0) },
    })
}
