//! The files mutated: the shared real DEMs (GeoTIFF, `.hgt`, PNG, JPEG), the repository's
//! conformance corpus, and small files made here (grey and RGB PNGs, a grey JPEG, TIFFs of
//! other sample types and compressions, BigTIFF, raw grids), read once into memory.

use std::io::Cursor;
use std::path::Path;

use terrain_core::dem::{RawSampleType, RawSpec};

use crate::mutate::Kind;

/// A file to mutate.
#[derive(Debug, Clone)]
pub(crate) struct Seed {
    /// File name the mutant is written under (the `.hgt` name carries the georeference).
    pub name: String,
    pub bytes: Vec<u8>,
    pub kind: Kind,
    /// A raw grid's dimensions.
    pub raw: Option<RawSpec>,
}

fn kind_of(name: &str) -> Option<Kind> {
    let ext = Path::new(name).extension()?.to_str()?.to_ascii_lowercase();
    Some(match ext.as_str() {
        "tif" | "tiff" => Kind::Tiff,
        "png" => Kind::Png,
        "jpg" | "jpeg" => Kind::Jpeg,
        "hgt" => Kind::Samples,
        _ => return None,
    })
}

/// Every DEM-like file under `dir` (recursively), sorted by path so runs are deterministic.
fn files_under(dir: &Path, out: &mut Vec<Seed>) -> std::io::Result<()> {
    let mut entries: Vec<_> = std::fs::read_dir(dir)?.filter_map(|e| e.ok()).collect();
    entries.sort_by_key(|e| e.path());
    for e in entries {
        let p = e.path();
        if p.is_dir() {
            files_under(&p, out)?;
        } else if let Some(name) = p.file_name().and_then(|n| n.to_str())
            && let Some(kind) = kind_of(name)
        {
            out.push(Seed { name: name.to_string(), bytes: std::fs::read(&p)?, kind, raw: None });
        }
    }
    Ok(())
}

/// The seeds: the real files in `data`, the corpus in `corpus`, and the made ones.
pub(crate) fn collect(data: &Path, corpus: &Path) -> Result<Vec<Seed>, String> {
    let mut seeds = Vec::new();
    for dir in [data, corpus] {
        files_under(dir, &mut seeds).map_err(|e| format!("reading {}: {e}", dir.display()))?;
    }
    if !seeds.iter().any(|s| s.kind == Kind::Tiff) {
        return Err(format!(
            "no GeoTIFF under {} or {} (set TERRAIN_DATA to the shared data folder)",
            data.display(),
            corpus.display()
        ));
    }
    seeds.extend(made());
    Ok(seeds)
}

fn image_bytes(img: image::DynamicImage, format: image::ImageFormat) -> Vec<u8> {
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, format).expect("encoding a small image in memory");
    out.into_inner()
}

/// Small files of the kinds the real data lacks.
fn made() -> Vec<Seed> {
    use image::{DynamicImage, GrayImage, ImageBuffer, ImageFormat, Luma, RgbImage};
    let (w, h) = (64u32, 48u32);
    let z = |x: u32, y: u32| (x * 37 + y * 11 + (x * y) % 13) as u16;
    let mut seeds = Vec::new();
    let mut add = |name: &str, bytes: Vec<u8>, kind: Kind, raw: Option<RawSpec>| {
        seeds.push(Seed { name: name.to_string(), bytes, kind, raw });
    };
    let grey8 = GrayImage::from_fn(w, h, |x, y| Luma([z(x, y) as u8]));
    let grey16: ImageBuffer<Luma<u16>, Vec<u16>> =
        ImageBuffer::from_fn(w, h, |x, y| Luma([z(x, y) * 7]));
    let rgb = RgbImage::from_fn(32, 32, |x, y| image::Rgb([1, (x * 3) as u8, (y * 5) as u8]));
    add(
        "grey8.png",
        image_bytes(DynamicImage::ImageLuma8(grey8.clone()), ImageFormat::Png),
        Kind::Png,
        None,
    );
    add(
        "grey16.png",
        image_bytes(DynamicImage::ImageLuma16(grey16), ImageFormat::Png),
        Kind::Png,
        None,
    );
    add("rgb.png", image_bytes(DynamicImage::ImageRgb8(rgb), ImageFormat::Png), Kind::Png, None);
    add(
        "grey.jpg",
        image_bytes(DynamicImage::ImageLuma8(grey8), ImageFormat::Jpeg),
        Kind::Jpeg,
        None,
    );

    // TIFFs: int16 LZW, uint16 PackBits, float32 Deflate, float64 plain, a BigTIFF.
    use tiff::encoder::{Compression, colortype};
    let n = (w * h) as usize;
    let i16s: Vec<i16> = (0..n).map(|k| (k as i16).wrapping_mul(7) - 300).collect();
    let u16s: Vec<u16> = (0..n).map(|k| (k % 500) as u16).collect();
    let f32s: Vec<f32> = (0..n).map(|k| k as f32 * 0.25 - 10.0).collect();
    let f64s: Vec<f64> = (0..n).map(|k| k as f64 * 0.5).collect();
    let deflate = Compression::Deflate(tiff::encoder::compression::DeflateLevel::Fast);
    add(
        "lzw_i16.tif",
        tiff_bytes::<colortype::GrayI16>(false, Compression::Lzw, w, h, &i16s),
        Kind::Tiff,
        None,
    );
    add(
        "packbits_u16.tif",
        tiff_bytes::<colortype::Gray16>(false, Compression::Packbits, w, h, &u16s),
        Kind::Tiff,
        None,
    );
    add(
        "deflate_f32.tif",
        tiff_bytes::<colortype::Gray32Float>(false, deflate, w, h, &f32s),
        Kind::Tiff,
        None,
    );
    add(
        "plain_f64.tif",
        tiff_bytes::<colortype::Gray64Float>(false, Compression::Uncompressed, w, h, &f64s),
        Kind::Tiff,
        None,
    );
    add(
        "big_i16.tif",
        tiff_bytes::<colortype::GrayI16>(true, Compression::Uncompressed, w, h, &i16s),
        Kind::Tiff,
        None,
    );

    // Raw grids, little-endian, rows north first.
    let spec = |sample| Some(RawSpec { width: u64::from(w), height: u64::from(h), sample });
    add(
        "grid.i16",
        i16s.iter().flat_map(|v| v.to_le_bytes()).collect(),
        Kind::Samples,
        spec(RawSampleType::I16),
    );
    add(
        "grid.u16",
        u16s.iter().flat_map(|v| v.to_le_bytes()).collect(),
        Kind::Samples,
        spec(RawSampleType::U16),
    );
    add(
        "grid.f32",
        f32s.iter().flat_map(|v| v.to_le_bytes()).collect(),
        Kind::Samples,
        spec(RawSampleType::F32),
    );
    seeds
}

/// A single-image TIFF (BigTIFF when `big`) of samples `data` in memory.
fn tiff_bytes<C: tiff::encoder::colortype::ColorType>(
    big: bool,
    compression: tiff::encoder::Compression,
    w: u32,
    h: u32,
    data: &[C::Inner],
) -> Vec<u8>
where
    [C::Inner]: tiff::encoder::TiffValue,
{
    use tiff::encoder::TiffEncoder;
    let mut out = Cursor::new(Vec::new());
    let written = if big {
        TiffEncoder::new_big(&mut out)
            .and_then(|e| e.with_compression(compression).write_image::<C>(w, h, data))
    } else {
        TiffEncoder::new(&mut out)
            .and_then(|e| e.with_compression(compression).write_image::<C>(w, h, data))
    };
    written.expect("encoding a small TIFF in memory");
    out.into_inner()
}
