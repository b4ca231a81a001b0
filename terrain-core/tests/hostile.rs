//! Hostile files (issue 15): small crafted headers that declare huge grids must be refused
//! before anything of that size is allocated, with a message naming the file, the bytes the
//! read would need and the option to raise.
//!
//! A counting global allocator records the largest single allocation of this test binary, so
//! "refused without a multi-GB allocation" is checked, not assumed.

// The counting allocator is the only unsafe code: it forwards to `System` unchanged.
#![allow(unsafe_code)]

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Cursor;
use std::sync::atomic::{AtomicUsize, Ordering};

use terrain_core::dem::{LoadOptions, RawSampleType, RawSpec, bytes_to_read, load};
use terrain_core::{DemError, DemErrorKind};

/// The system allocator, recording the largest single request.
struct Counting;
static LARGEST: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards every call to `System` unchanged; only records sizes.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        LARGEST.fetch_max(layout.size(), Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        LARGEST.fetch_max(layout.size(), Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        LARGEST.fetch_max(new_size, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// No test here legitimately allocates more than this at once.
const MAX_ALLOCATION: usize = 256 << 20;

fn assert_no_huge_allocation() {
    let largest = LARGEST.load(Ordering::Relaxed);
    assert!(largest <= MAX_ALLOCATION, "an allocation of {largest} bytes was made");
}

/// `bytes` written to `name` in a temporary folder of its own, removed with the returned guard
/// (also when the test panics).
fn write_temp(name: &str, bytes: &[u8]) -> common::TempFile {
    common::write_temp("terrain-core-hostile-", name, bytes)
}

/// A small valid grey image of `w` x `h` in `format`.
fn encode(w: u32, h: u32, format: image::ImageFormat) -> Vec<u8> {
    let img = image::GrayImage::from_fn(w, h, |x, y| image::Luma([(x * 7 + y * 3) as u8]));
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, format).unwrap();
    out.into_inner()
}

/// Sets the size in a JPEG's frame header (SOF0..SOF2: FF C0..C2, length, precision, height,
/// width).
fn patch_jpeg_size(bytes: &mut [u8], w: u16, h: u16) {
    let at = (0..bytes.len() - 1)
        .find(|&i| bytes[i] == 0xFF && (0xC0..=0xC2).contains(&bytes[i + 1]))
        .expect("a frame header");
    bytes[at + 5..at + 7].copy_from_slice(&h.to_be_bytes());
    bytes[at + 7..at + 9].copy_from_slice(&w.to_be_bytes());
}

/// Sets the size in a PNG's IHDR and fixes its CRC (the decoder checks it).
fn patch_png_size(bytes: &mut [u8], w: u32, h: u32) {
    assert_eq!(&bytes[12..16], b"IHDR");
    bytes[16..20].copy_from_slice(&w.to_be_bytes());
    bytes[20..24].copy_from_slice(&h.to_be_bytes());
    let crc = terrain_core::checksum::crc32(&bytes[12..29]);
    bytes[29..33].copy_from_slice(&crc.to_be_bytes());
}

fn memory_limit(e: &DemError) -> (u64, u64, u64, u64) {
    match e.kind {
        DemErrorKind::MemoryLimit { width, height, bytes, limit } => (width, height, bytes, limit),
        ref other => panic!("expected MemoryLimit, got {other}"),
    }
}

/// The case: a JPEG of a few KB declaring 65535 x 40000 pixels (the decoder would
/// allocate 2.6 GB to 7.9 GB).
#[test]
fn jpeg_declaring_huge_size_is_refused_without_allocating() {
    let mut bytes = encode(64, 64, image::ImageFormat::Jpeg);
    patch_jpeg_size(&mut bytes, 65535, 40000);
    let p = write_temp("huge.jpg", &bytes);

    // Default limit: refused for memory, with the file, the bytes and the option named.
    let e = load(&p, &LoadOptions::default()).unwrap_err();
    let (w, h, need, limit) = memory_limit(&e);
    assert_eq!((w, h), (65535, 40000));
    assert!(need > limit, "{need} <= {limit}");
    assert_eq!(need, bytes_to_read(65535, 40000, 1 + 4), "grey JPEG: 1 byte a pixel decoded");
    let msg = e.to_string();
    for want in [p.display().to_string(), need.to_string(), "--max-memory".to_string()] {
        assert!(msg.contains(&want), "{msg} lacks {want}");
    }

    // With no memory limit, the file is still far too small for what it declares.
    let opts = LoadOptions { max_memory_bytes: u64::MAX, ..Default::default() };
    let e = load(&p, &opts).unwrap_err();
    assert!(matches!(e.kind, DemErrorKind::Malformed { format: "JPEG", .. }), "{e}");
    assert!(e.to_string().contains("65535 x 40000"), "{e}");
    assert_no_huge_allocation();
}

#[test]
fn png_declaring_huge_size_is_refused_without_allocating() {
    let mut bytes = encode(64, 64, image::ImageFormat::Png);
    // 8-bit grey: 40000 rows of 1 + 65535 bytes inflate from at least 2.5 MB of zlib data.
    patch_png_size(&mut bytes, 65535, 40000);
    let p = write_temp("huge.png", &bytes);
    let e = load(&p, &LoadOptions::default()).unwrap_err();
    let (w, h, need, _) = memory_limit(&e);
    assert_eq!((w, h), (65535, 40000));
    assert!(e.to_string().contains(&need.to_string()), "{e}");

    let opts = LoadOptions { max_memory_bytes: u64::MAX, ..Default::default() };
    let e = load(&p, &opts).unwrap_err();
    assert!(matches!(e.kind, DemErrorKind::Malformed { format: "PNG", .. }), "{e}");
    assert!(e.to_string().contains("65535 x 40000"), "{e}");
    assert_no_huge_allocation();
}

/// The size check against the file length refuses nothing real: the small valid images read,
/// and so does a highly compressible one (a constant 2000 x 2000 PNG of a few KB).
#[test]
fn valid_images_pass_the_declared_size_check() {
    for (name, fmt) in [("ok.png", image::ImageFormat::Png), ("ok.jpg", image::ImageFormat::Jpeg)] {
        let p = write_temp(name, &encode(64, 48, fmt));
        let dem = load(&p, &LoadOptions::default()).unwrap();
        assert_eq!((dem.heightmap.width(), dem.heightmap.height()), (64, 48));
    }
    let flat = image::GrayImage::from_pixel(2000, 2000, image::Luma([9u8]));
    let mut out = Cursor::new(Vec::new());
    flat.write_to(&mut out, image::ImageFormat::Png).unwrap();
    let bytes = out.into_inner();
    assert!(bytes.len() < 64 << 10, "{} bytes", bytes.len());
    let dem = load(write_temp("flat.png", &bytes), &LoadOptions::default()).unwrap();
    assert_eq!(dem.heightmap.get(1999, 1999), 9.0);
    assert_no_huge_allocation();
}

/// A valid, tiny Deflate GeoTIFF whose grid needs far more than its file size: read under
/// the default limit, refused under a lower one with the message.
#[test]
fn deflate_geotiff_over_a_lower_limit_is_refused() {
    use tiff::encoder::{Compression, TiffEncoder, colortype::Gray32Float};
    let (w, h) = (1024u32, 1024u32);
    let data = vec![100f32; (w * h) as usize];
    let mut out = Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new(&mut out)
        .unwrap()
        .with_compression(Compression::Deflate(tiff::encoder::compression::DeflateLevel::Best));
    enc.write_image::<Gray32Float>(w, h, &data).unwrap();
    let bytes = out.into_inner();
    assert!(bytes.len() < 64 << 10, "{} bytes", bytes.len());
    let p = write_temp("deflate.tif", &bytes);

    let dem = load(&p, &LoadOptions::default()).unwrap();
    assert_eq!(dem.heightmap.get(5, 5), 100.0);

    let opts = LoadOptions { max_memory_bytes: 8 << 20, ..Default::default() };
    let e = load(&p, &opts).unwrap_err();
    let (_, _, need, limit) = memory_limit(&e);
    // float32: 4 bytes decoded + 4 converted while decoding, 5 kept.
    assert_eq!((need, limit), (bytes_to_read(1024, 1024, 8), 8 << 20));
    let msg = e.to_string();
    assert!(msg.contains("deflate.tif") && msg.contains("--max-memory"), "{msg}");
    assert!(msg.contains(&need.to_string()) && msg.contains(&limit.to_string()), "{msg}");
}

/// Raw grids and .hgt tiles are under the same limit.
#[test]
fn raw_and_hgt_are_under_the_limit() {
    let p = write_temp("g.f32", &vec![0u8; 100 * 100 * 4]);
    let raw = RawSpec { width: 100, height: 100, sample: RawSampleType::F32 };
    let ok = LoadOptions { raw: Some(raw), ..Default::default() };
    load(&p, &ok).unwrap();
    let low = LoadOptions { max_memory_bytes: 10_000, ..ok };
    let e = load(&p, &low).unwrap_err();
    assert_eq!(memory_limit(&e).2, bytes_to_read(100, 100, 4));

    let p = write_temp("N10E010.hgt", &vec![0u8; 1201 * 1201 * 2]);
    load(&p, &LoadOptions::default()).unwrap();
    let low = LoadOptions { max_memory_bytes: 1 << 20, ..Default::default() };
    let e = load(&p, &low).unwrap_err();
    assert_eq!(memory_limit(&e).2, bytes_to_read(1201, 1201, 2));
}

/// Reading by rows holds a few strips or tiles, not the grid: those are under the limit too.
#[test]
fn rows_hold_strips_under_the_limit() {
    use terrain_core::dem::RowReader;
    use tiff::encoder::{TiffEncoder, colortype::Gray32Float};
    let (w, h) = (512u32, 512u32);
    let mut out = Cursor::new(Vec::new());
    let data = vec![7f32; (w * h) as usize];
    TiffEncoder::new(&mut out).unwrap().write_image::<Gray32Float>(w, h, &data).unwrap();
    let p = write_temp("strips.tif", &out.into_inner());

    let r = RowReader::open(&p, &LoadOptions::default()).unwrap();
    let (mut row, mut voids) = (vec![0f32; w as usize], vec![false; w as usize]);
    r.read_rows(0, 1, &mut row, &mut voids).unwrap();
    assert_eq!(row[3], 7.0);
    // Under the whole-grid estimate of a load, but over what 4 cached strips and one decode take.
    let opts = LoadOptions { max_memory_bytes: 4 << 10, ..Default::default() };
    let Err(e) = RowReader::open(&p, &opts) else { panic!("not refused") };
    let DemErrorKind::ChunkMemoryLimit { chunk_w, chunks, bytes, limit, .. } = e.kind else {
        panic!("expected ChunkMemoryLimit, got {e}");
    };
    assert_eq!((chunk_w, chunks, limit), (512, 4, 4 << 10));
    assert!(bytes > limit);
    let msg = e.to_string();
    assert!(msg.contains("strips.tif") && msg.contains("--max-memory"), "{msg}");
    assert_no_huge_allocation();
}

/// The first IFD entry of a classic little-endian TIFF with tag `tag`: its position.
fn ifd_entry(bytes: &[u8], tag: u16) -> usize {
    let ifd = u32::from_le_bytes(bytes[4..8].try_into().unwrap()) as usize;
    let n = u16::from_le_bytes(bytes[ifd..ifd + 2].try_into().unwrap()) as usize;
    (0..n)
        .map(|k| ifd + 2 + 12 * k)
        .find(|&at| u16::from_le_bytes(bytes[at..at + 2].try_into().unwrap()) == tag)
        .expect("the tag is in the first IFD")
}

/// Found by `cargo xtask fuzz`: an ASCII tag declaring 1.45 billion characters (in a file of
/// 700 bytes) made the `tiff` crate allocate 1.45 GB to read it under the default memory
/// limit. A tag whose values cannot fit in the file is refused
/// before the decoder reads it.
#[test]
fn a_tag_declaring_more_values_than_the_file_holds_is_refused_without_allocating() {
    use tiff::encoder::{TiffEncoder, colortype::Gray16};
    let mut out = Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new(&mut out).unwrap();
    let mut img = enc.new_image::<Gray16>(16, 16).unwrap();
    // GDAL_NODATA (42113), read by every GeoTIFF load: 8 characters, out of line.
    img.encoder().write_tag(tiff::tags::Tag::Unknown(42113), "-32768 ").unwrap();
    img.write_data(&[7u16; 256]).unwrap();
    let mut bytes = out.into_inner();
    let ok = write_temp("ascii.tif", &bytes);
    load(&ok, &LoadOptions::default()).unwrap();

    let at = ifd_entry(&bytes, 42113);
    bytes[at + 4..at + 8].copy_from_slice(&1_450_457_600u32.to_le_bytes());
    let p = write_temp("ascii_huge.tif", &bytes);
    let e = load(&p, &LoadOptions::default()).unwrap_err();
    assert!(matches!(e.kind, DemErrorKind::Malformed { format: "GeoTIFF", .. }), "{e}");
    let msg = e.to_string();
    assert!(msg.contains("42113") && msg.contains("1450457600"), "{msg}");
    assert!(terrain_core::dem::RowReader::open(&p, &LoadOptions::default()).is_err());
    assert_no_huge_allocation();
}
