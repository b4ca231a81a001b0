//! DEM readers against the real files in `shared/data` (see its README) and against bad input.
//!
//! The data directory is `$TERRAIN_DATA`, or `../shared/data` relative to the workspace root.

mod common;

use common::{TempFile, data};

use std::path::Path;

use terrain_core::dem::{Format, LoadOptions, RawSampleType, RawSpec, load, load_mosaic};
use terrain_core::georef::AngularOrLinear;
use terrain_core::{Crs, DemErrorKind, Heightmap};

/// A temporary directory for one test, removed when dropped (also on a panic).
fn temp_dir() -> tempfile::TempDir {
    common::temp_dir("terrain-core-readers-")
}

/// `bytes` written to `name` in a temporary directory of its own, removed with the returned
/// guard.
fn write_temp(name: &str, bytes: &[u8]) -> TempFile {
    common::write_temp("terrain-core-readers-", name, bytes)
}

fn within_pct(got: f64, want: f64, pct: f64) -> bool {
    ((got - want) / want).abs() * 100.0 <= pct
}

/// Metric spacing expected for a geographic grid: dlon x 111,320 x cos(lat), dlat x 111,320.
fn assert_geographic_spacing(hm: &Heightmap, dlon: f64, dlat: f64) {
    let g = hm.georef();
    assert_eq!(g.units, AngularOrLinear::Degrees);
    assert!(within_pct(g.native_spacing.x, dlon, 0.01), "dlon {} vs {dlon}", g.native_spacing.x);
    assert!(within_pct(g.native_spacing.y, dlat, 0.01), "dlat {} vs {dlat}", g.native_spacing.y);
    let lat = g.native_origin.y + 0.5 * (hm.height() - 1) as f64 * dlat;
    let want_x = dlon * 111_320.0 * lat.to_radians().cos();
    let want_y = dlat * 111_320.0;
    assert!(within_pct(g.spacing_m.x, want_x, 0.5), "x spacing {} m vs {want_x} m", g.spacing_m.x);
    assert!(within_pct(g.spacing_m.y, want_y, 0.5), "y spacing {} m vs {want_y} m", g.spacing_m.y);
}

fn assert_range(hm: &Heightmap, min: f32, max: f32, tol: f32) {
    assert!((hm.min() - min).abs() <= tol, "min {} vs {min}", hm.min());
    assert!((hm.max() - max).abs() <= tol, "max {} vs {max}", hm.max());
}

/// The whole grid as decoded independently with the `tiff` crate must be ours upside down:
/// file row `r` (row 0 = north) is our row `h - 1 - r`; file samples equal to `nodata` must be
/// void, the others equal.
fn assert_tiff_flipped(path: &Path, hm: &Heightmap, nodata: Option<f32>) {
    let mut dec = tiff::decoder::Decoder::new(std::fs::File::open(path).unwrap()).unwrap();
    let file: Vec<f32> = match dec.read_image().unwrap() {
        tiff::decoder::DecodingResult::I16(v) => v.iter().map(|&x| x as f32).collect(),
        tiff::decoder::DecodingResult::F32(v) => v,
        other => panic!("unexpected sample type {:?}", std::mem::discriminant(&other)),
    };
    let (w, h) = (hm.width(), hm.height());
    assert_eq!(file.len(), w * h);
    let mut compared = 0;
    for r in 0..h {
        let j = h - 1 - r;
        for i in 0..w {
            let z = file[r * w + i];
            if Some(z) == nodata {
                assert!(
                    hm.voids().get(i, j),
                    "file nodata at ({i}, row {r}) is not void at ({i}, {j})"
                );
            } else {
                assert!(!hm.voids().get(i, j));
                assert_eq!(hm.get(i, j), z, "file ({i}, row {r}) vs grid ({i}, {j})");
                compared += 1;
            }
        }
    }
    assert!(compared > 0);
    // The file is not north-south symmetric, so an unflipped read would have failed above.
    assert!((0..h).any(|r| file[r * w..(r + 1) * w] != file[(h - 1 - r) * w..(h - r) * w]));
}

#[test]
fn mt_rainier_geotiff() {
    let p = data("srtm/mt_rainier_90m.tif");
    let dem = load(&p, &LoadOptions::default()).unwrap();
    let hm = &dem.heightmap;
    assert_eq!((hm.width(), hm.height()), (1201, 1201));
    assert_eq!(hm.georef().crs, Crs::Epsg(4326));
    assert_geographic_spacing(hm, 3.0 / 3600.0, 3.0 / 3600.0);
    assert_range(hm, 263.0, 4371.0, 0.0);
    assert_eq!(hm.voids().count(), 9_033);
    assert_eq!(dem.source.format, Format::GeoTiff);
    assert_eq!(dem.source.sample_type, "int16");
    assert_eq!(dem.source.nodata, Some(-32768.0));
    // Filled voids stay within the non-void range (the membrane fill is a convex combination).
    assert!(hm.data().iter().all(|&z| z.is_finite() && z >= hm.min() && z <= hm.max()));
    // The SW sample centre is on whole degrees for these SRTM-derived tiles (PixelIsArea shift).
    let o = hm.georef().native_origin;
    assert!((o.x - o.x.round()).abs() < 1e-6 && (o.y - o.y.round()).abs() < 1e-6, "origin {o}");
    assert_tiff_flipped(&p, hm, Some(-32768.0));
}

#[test]
fn mt_everest_geotiff_many_voids() {
    let p = data("srtm/mt_everest_90m.tif");
    let dem = load(&p, &LoadOptions::default()).unwrap();
    let hm = &dem.heightmap;
    assert_eq!((hm.width(), hm.height()), (1201, 1201));
    assert_eq!(hm.georef().crs, Crs::Epsg(4326));
    assert_geographic_spacing(hm, 3.0 / 3600.0, 3.0 / 3600.0);
    assert_range(hm, 192.0, 8642.0, 0.0);
    assert_eq!(hm.voids().count(), 130_953);
    assert!(hm.data().iter().all(|&z| z.is_finite() && z >= hm.min() && z <= hm.max()));
    assert_tiff_flipped(&p, hm, Some(-32768.0));
}

#[test]
fn crater_lake_needs_user_nodata() {
    let p = data("crater_lake/craterlake-elev-16bit-30m.tif");
    // Without --nodata the -32767 cells are heights (the file has no GDAL_NODATA tag).
    let plain = load(&p, &LoadOptions::default()).unwrap();
    assert_eq!(plain.source.nodata, None);
    assert_eq!(plain.heightmap.voids().count(), 0);
    assert_eq!(plain.heightmap.min(), -32767.0);

    let opts = LoadOptions { nodata: Some(-32767.0), ..Default::default() };
    let dem = load(&p, &opts).unwrap();
    let hm = &dem.heightmap;
    assert_eq!((hm.width(), hm.height()), (429, 279));
    assert_eq!(hm.georef().crs, Crs::Epsg(4326));
    let s = hm.georef().native_spacing;
    assert_geographic_spacing(hm, s.x, s.y);
    assert!(within_pct(hm.georef().spacing_m.y, 30.0, 0.5), "~30 m: {}", hm.georef().spacing_m.y);
    assert_range(hm, 1289.0, 1880.0, 1.0);
    assert_eq!(hm.voids().count(), 39_489);
    assert_eq!(dem.source.nodata, Some(-32767.0));
    assert_tiff_flipped(&p, hm, Some(-32767.0));
}

#[test]
fn big_tujunga_gdal_nodata_and_utm() {
    let p = data("big_tujunga/bigtujunga.tif");
    let dem = load(&p, &LoadOptions::default()).unwrap();
    let hm = &dem.heightmap;
    assert_eq!((hm.width(), hm.height()), (1197, 643));
    assert_eq!(hm.georef().crs, Crs::Epsg(32611));
    assert_eq!(hm.georef().units, AngularOrLinear::Metres);
    assert!(within_pct(hm.georef().spacing_m.x, 30.0, 0.5));
    assert!(within_pct(hm.georef().spacing_m.y, 30.0, 0.5));
    assert_range(hm, 315.0, 2295.0, 1.0);
    assert_eq!(dem.source.nodata, Some(32767.0), "from GDAL_NODATA (42113)");
    assert_eq!(dem.source.sample_type, "int16");
    // UTM 11N eastings/northings of the Los Angeles area.
    let o = hm.georef().native_origin;
    assert!(
        (100_000.0..900_000.0).contains(&o.x) && (3_000_000.0..4_500_000.0).contains(&o.y),
        "{o}"
    );
    assert_tiff_flipped(&p, hm, Some(32767.0));
}

#[test]
fn lidar_prairie_float32_projected() {
    let p = data("lidar_prairie/dem.tif");
    let dem = load(&p, &LoadOptions::default()).unwrap();
    let hm = &dem.heightmap;
    assert_eq!((hm.width(), hm.height()), (400, 400));
    assert_eq!(hm.georef().crs, Crs::Epsg(26915));
    assert_eq!(dem.source.sample_type, "float32");
    assert!(within_pct(hm.georef().spacing_m.x, 1.0, 0.5));
    assert!(within_pct(hm.georef().spacing_m.y, 1.0, 0.5));
    assert_range(hm, 379.7, 410.8, 1.0);
    let o = hm.georef().native_origin;
    assert!((100_000.0..1_000_000.0).contains(&o.x), "easting {}", o.x);
    assert_eq!(hm.georef().world_origin, o, "projected: world = CRS coordinates");
    assert_tiff_flipped(&p, hm, dem.source.nodata.map(|v| v as f32));
}

/// Checks a .hgt tile against its bytes: north row, void count, georeference.
fn check_hgt(rel: &str, lat: f64, lon: f64, min: f32, max: f32) -> terrain_core::dem::Dem {
    let p = data(rel);
    let bytes = std::fs::read(&p).unwrap();
    let dem = load(&p, &LoadOptions::default()).unwrap();
    let hm = &dem.heightmap;
    assert_eq!((hm.width(), hm.height()), (1201, 1201));
    assert_eq!(hm.georef().crs, Crs::Epsg(4326));
    assert_eq!(dem.source.format, Format::Hgt);
    assert_eq!(dem.source.nodata, Some(-32768.0));
    assert_eq!(hm.georef().native_origin, glam::dvec2(lon, lat));
    assert_geographic_spacing(hm, 1.0 / 1200.0, 1.0 / 1200.0);
    assert_range(hm, min, max, 0.0);
    let raw: Vec<i16> = bytes.chunks_exact(2).map(|b| i16::from_be_bytes([b[0], b[1]])).collect();
    assert_eq!(hm.voids().count(), raw.iter().filter(|&&v| v == -32768).count());
    // The file's first row is the north row.
    for i in 0..1201 {
        if raw[i] == -32768 {
            assert!(hm.voids().get(i, 1200));
        } else {
            assert_eq!(hm.get(i, 1200), raw[i] as f32);
        }
        // and the file's last row is our south row
        let s = raw[1200 * 1201 + i];
        if s != -32768 {
            assert_eq!(hm.get(i, 0), s as f32);
        }
    }
    dem
}

#[test]
fn hgt_tiles() {
    check_hgt("srtm/N41E001.hgt", 41.0, 1.0, -20.0, 1204.0);
    check_hgt("srtm/N42E001.hgt", 42.0, 1.0, 349.0, 3100.0);
    check_hgt("srtm/N52E008.hgt", 52.0, 8.0, -1.0, 357.0);
}

#[test]
fn hgt_mosaic_shares_one_row() {
    let a = load(data("srtm/N41E001.hgt"), &LoadOptions::default()).unwrap().heightmap;
    let b = load(data("srtm/N42E001.hgt"), &LoadOptions::default()).unwrap().heightmap;
    // Order must not matter.
    for paths in [
        [data("srtm/N41E001.hgt"), data("srtm/N42E001.hgt")],
        [data("srtm/N42E001.hgt"), data("srtm/N41E001.hgt")],
    ] {
        let m = load_mosaic(&paths, &LoadOptions::default()).unwrap().heightmap;
        assert_eq!((m.width(), m.height()), (1201, 2401));
        assert_eq!(m.georef().crs, Crs::Epsg(4326));
        assert_eq!(m.georef().native_origin, glam::dvec2(1.0, 41.0));
        assert!((m.min() - a.min().min(b.min())).abs() < 1e-3);
        assert!((m.max() - a.max().max(b.max())).abs() < 1e-3);
        for i in 0..1201 {
            // South part = N41, north part = N42, the shared row from either.
            for (mj, t, tj) in [(0, &a, 0), (1199, &a, 1199), (1200, &b, 0), (2400, &b, 1200)] {
                if !t.voids().get(i, tj) {
                    assert!(!m.voids().get(i, mj));
                    assert_eq!(m.get(i, mj), t.get(i, tj), "mosaic ({i}, {mj})");
                }
            }
            if !a.voids().get(i, 1200) {
                assert_eq!(m.get(i, 1200), a.get(i, 1200));
            }
        }
        let shared_void =
            (0..1201).filter(|&i| a.voids().get(i, 1200) && b.voids().get(i, 0)).count();
        assert_eq!(m.voids().count(), a.voids().count() + b.voids().count() - shared_void);
    }
}

#[test]
fn mosaic_errors() {
    // Same grid, but a gap between them.
    let e =
        load_mosaic(&[data("srtm/N41E001.hgt"), data("srtm/N52E008.hgt")], &LoadOptions::default())
            .unwrap_err();
    assert!(matches!(e.kind, DemErrorKind::Mosaic(_)), "{e}");
    let msg = e.to_string();
    assert!(msg.contains("N41E001") && msg.contains("is not adjacent to any other tile"), "{msg}");
    assert!(!msg.contains("LoadOptions") && !msg.contains("max_samples"), "{msg}");
    // Different spacing (both EPSG:4326).
    let e = load_mosaic(
        &[data("srtm/mt_rainier_90m.tif"), data("crater_lake/craterlake-elev-16bit-30m.tif")],
        &LoadOptions::default(),
    )
    .unwrap_err();
    assert!(matches!(e.kind, DemErrorKind::Mosaic(_)), "{e}");
    assert!(e.to_string().contains("spacing"), "{e}");
    // Different CRS.
    let e = load_mosaic(
        &[data("srtm/N41E001.hgt"), data("big_tujunga/bigtujunga.tif")],
        &LoadOptions::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("EPSG:32611"), "{e}");
    // The same tile twice is not a mosaic.
    let e = load_mosaic(
        &[data("srtm/N41E001.hgt"), data("srtm/N42E001.hgt"), data("srtm/N41E001.hgt")],
        &LoadOptions::default(),
    )
    .unwrap_err();
    assert!(matches!(e.kind, DemErrorKind::Mosaic(_)), "{e}");
    assert!(e.to_string().contains("given twice") && e.to_string().contains("N41E001"), "{e}");
}

#[test]
fn puget_sound_16bit_png() {
    let p = data("puget_sound/ps_height_1k.png");
    let opts = LoadOptions { vertical_scale: 0.1, spacing_m: 160.0, ..Default::default() };
    let dem = load(&p, &opts).unwrap();
    let hm = &dem.heightmap;
    assert_eq!((hm.width(), hm.height()), (1025, 1025));
    assert_eq!(hm.georef().crs, Crs::Unknown);
    assert_eq!(hm.georef().spacing_m, glam::dvec2(160.0, 160.0));
    assert_range(hm, 0.0, 4379.8, 0.01);
    assert_eq!(hm.voids().count(), 0);
    assert_eq!(dem.source.format, Format::GreyImage);
    // All 16 bits kept: some raw values are not multiples of 256.
    let img = image::open(&p).unwrap().into_luma16();
    assert!(img.pixels().any(|p| p.0[0] % 256 != 0));
    // Image row 0 (top, north) is our last row.
    for x in 0..1025u32 {
        let raw = img.get_pixel(x, 0).0[0] as f32;
        assert!((hm.get(x as usize, 1024) - raw * 0.1).abs() < 1e-3);
        let raw_s = img.get_pixel(x, 1024).0[0] as f32;
        assert!((hm.get(x as usize, 0) - raw_s * 0.1).abs() < 1e-3);
    }
}

#[test]
fn puget_sound_jpeg_and_colour_png() {
    let dem = load(data("puget_sound/ps_height_4k.jpg"), &LoadOptions::default()).unwrap();
    assert_eq!((dem.heightmap.width(), dem.heightmap.height()), (4096, 4096));
    assert_range(&dem.heightmap, 0.0, 171.0, 1.0);
    // The colour texture is not a heightmap unless an RGB encoding is asked for.
    let p = data("puget_sound/ps_texture_1k.png");
    let e = load(&p, &LoadOptions::default()).unwrap_err();
    assert!(matches!(e.kind, DemErrorKind::Unsupported { .. }), "{e}");
    assert!(
        e.to_string().contains("ps_texture_1k.png") && e.to_string().contains("colour PNG"),
        "{e}"
    );
    let opts = LoadOptions { format: Some(Format::Terrarium), ..Default::default() };
    let dem = load(&p, &opts).unwrap();
    assert_eq!((dem.heightmap.width(), dem.heightmap.height()), (1024, 1024));
    let img = image::open(&p).unwrap().into_rgb8();
    let [r, g, b] = img.get_pixel(5, 0).0;
    let want = r as f32 * 256.0 + g as f32 + b as f32 / 256.0 - 32768.0;
    assert_eq!(dem.heightmap.get(5, 1023), want);
}

#[test]
fn terrain_rgb_formula() {
    // A 2 x 1 RGBA PNG: pixel 0 is 0 m in Terrain-RGB (100000 * 0.1 - 10000), pixel 1 transparent.
    let v = 100_000u32;
    let px = [(v >> 16) as u8, (v >> 8) as u8, v as u8, 255, 1, 2, 3, 0];
    let tmp = temp_dir();
    let p = tmp.path().join("trgb.png");
    image::save_buffer(&p, &px, 2, 1, image::ExtendedColorType::Rgba8).unwrap();
    let opts = LoadOptions { format: Some(Format::TerrainRgb), ..Default::default() };
    let dem = load(&p, &opts).unwrap();
    assert_eq!(dem.heightmap.get(0, 0), 0.0);
    assert!(dem.heightmap.voids().get(1, 0));
}

#[test]
fn raw_grid() {
    // 3 x 2 int16, north row first: [1 2 3] / [4 5 -9999].
    let vals: [i16; 6] = [1, 2, 3, 4, 5, -9999];
    let bytes: Vec<u8> = vals.iter().flat_map(|v| v.to_le_bytes()).collect();
    let p = write_temp("grid.raw", &bytes);
    let spec = RawSpec { width: 3, height: 2, sample: RawSampleType::I16 };
    let opts = LoadOptions {
        raw: Some(spec),
        nodata: Some(-9999.0),
        vertical_scale: 2.0,
        vertical_offset: 10.0,
        ..Default::default()
    };
    let dem = load(&p, &opts).unwrap();
    let hm = &dem.heightmap;
    assert_eq!(dem.source.format, Format::Raw);
    assert_eq!((hm.get(0, 1), hm.get(2, 1), hm.get(0, 0)), (12.0, 16.0, 18.0));
    assert!(hm.voids().get(2, 0) && hm.voids().count() == 1);

    // Wrong length names both numbers.
    let spec = RawSpec { width: 4, height: 2, sample: RawSampleType::I16 };
    let e = load(&p, &LoadOptions { raw: Some(spec), ..Default::default() }).unwrap_err();
    let s = e.to_string();
    assert!(s.contains("grid.raw") && s.contains("16 bytes") && s.contains("12 bytes"), "{s}");
    // Nonsense options are refused, naming the option.
    let opts = LoadOptions {
        raw: Some(RawSpec { width: 3, height: 2, sample: RawSampleType::I16 }),
        spacing_m: 0.0,
        ..Default::default()
    };
    let e = load(&p, &opts).unwrap_err();
    assert!(
        matches!(e.kind, DemErrorKind::InvalidOptions(_)) && e.to_string().contains("spacing_m"),
        "{e}"
    );
    // Forced raw without dimensions.
    let e = load(&p, &LoadOptions { format: Some(Format::Raw), ..Default::default() }).unwrap_err();
    assert!(matches!(e.kind, DemErrorKind::InvalidOptions(_)), "{e}");
}

// ---------- bad input ----------

fn assert_err(path: &Path, opts: &LoadOptions, needle: &str) -> DemErrorKind {
    let e = load(path, opts).expect_err("bad input must be an error");
    let s = e.to_string();
    let name = path.file_name().unwrap().to_str().unwrap();
    assert!(s.contains(name), "error does not name the file: {s}");
    assert!(s.to_lowercase().contains(&needle.to_lowercase()), "error {s:?} lacks {needle:?}");
    e.kind
}

#[test]
fn truncated_tiff() {
    let bytes = std::fs::read(data("crater_lake/craterlake-elev-16bit-30m.tif")).unwrap();
    // End of the image data: a cut just before it must be caught.
    let mut dec = tiff::decoder::Decoder::new(std::io::Cursor::new(&bytes)).unwrap();
    let offs = dec.get_tag_u64_vec(tiff::tags::Tag::StripOffsets).unwrap();
    let counts = dec.get_tag_u64_vec(tiff::tags::Tag::StripByteCounts).unwrap();
    let end = offs.iter().zip(&counts).map(|(o, c)| o + c).max().unwrap() as usize;
    for cut in [4, 7, bytes.len() / 2, end - 1] {
        let p = write_temp("cut.tif", &bytes[..cut]);
        let kind = assert_err(&p, &LoadOptions::default(), "truncated");
        assert!(matches!(kind, DemErrorKind::Truncated { .. }), "cut at {cut}: {kind}");
    }
}

#[test]
fn truncated_and_misnamed_hgt() {
    let bytes = std::fs::read(data("srtm/N41E001.hgt")).unwrap();
    let p = write_temp("N41E001.hgt", &bytes[..bytes.len() - 2]);
    let kind = assert_err(&p, &LoadOptions::default(), "truncated");
    assert!(matches!(kind, DemErrorKind::Truncated { expected: 2_884_802, .. }), "{kind}");
    // Between the two valid sizes: names both.
    let p = write_temp("N41E001.hgt", &vec![0u8; 3_000_000]);
    assert_err(&p, &LoadOptions::default(), "2,884,802");
    // Right size, no tile name.
    let p = write_temp("tile.hgt", &bytes);
    assert_err(&p, &LoadOptions::default(), "N41E001");
}

#[test]
fn empty_file() {
    let p = write_temp("empty.tif", &[]);
    let kind = assert_err(&p, &LoadOptions::default(), "empty");
    assert!(matches!(kind, DemErrorKind::Empty));
}

#[test]
fn wrong_magic_and_unsupported_formats() {
    let p = write_temp("notatiff.tif", b"XXXX this is not a TIFF at all");
    assert!(matches!(
        assert_err(&p, &LoadOptions::default(), "not a recognised"),
        DemErrorKind::UnknownFormat(_)
    ));
    let p = write_temp("anim.gif", b"GIF89a\x01\x00\x01\x00\x00\x00\x00;");
    assert_err(&p, &LoadOptions::default(), "GIF");
    let p = write_temp("notes.txt", b"ncols 10\nnrows 10\n");
    assert_err(&p, &LoadOptions::default(), "text");
    // A forced format whose magic the file lacks.
    let opts = LoadOptions { format: Some(Format::GeoTiff), ..Default::default() };
    assert_err(&data("puget_sound/ps_height_1k.png"), &opts, "GeoTIFF was asked for");
    // Missing file: I/O error naming it.
    let tmp = temp_dir();
    let missing = tmp.path().join("missing.tif");
    assert!(matches!(assert_err(&missing, &LoadOptions::default(), "I/O"), DemErrorKind::Io(_)));
}

/// A TIFF field for [`build_tiff`]: tag, field type (2 ASCII, 3 SHORT, 4 LONG, 12 DOUBLE),
/// count, and the value bytes (little-endian).
type Field = (u16, u16, u32, Vec<u8>);

fn shorts(v: &[u16]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}
fn doubles(v: &[f64]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// A little-endian classic TIFF with one uncompressed int16 strip declaring `w x h`, plus
/// `extra` fields (e.g. GeoTIFF tags). Values over 4 bytes go after the IFD.
fn build_tiff(w: u32, h: u32, strip: &[u8], extra: Vec<Field>) -> Vec<u8> {
    let mut fields: Vec<Field> = vec![
        (256, 4, 1, w.to_le_bytes().to_vec()),
        (257, 4, 1, h.to_le_bytes().to_vec()),
        (258, 3, 1, shorts(&[16])),
        (259, 3, 1, shorts(&[1])),
        (262, 3, 1, shorts(&[1])),
        (273, 4, 1, vec![]), // StripOffsets: filled in below
        (278, 4, 1, h.to_le_bytes().to_vec()),
        (279, 4, 1, (strip.len() as u32).to_le_bytes().to_vec()),
        (339, 3, 1, shorts(&[2])), // SampleFormat: signed integer
    ];
    fields.extend(extra);
    fields.sort_by_key(|f| f.0);
    let ifd_len = 2 + fields.len() * 12 + 4;
    let mut blob_off = 8 + ifd_len;
    let mut blobs = Vec::new();
    let mut ifd = (fields.len() as u16).to_le_bytes().to_vec();
    let strip_off_pos = {
        let big: usize = fields.iter().filter(|f| f.3.len() > 4).map(|f| f.3.len()).sum();
        (8 + ifd_len + big) as u32
    };
    for (tag, ty, count, mut val) in fields {
        if tag == 273 {
            val = strip_off_pos.to_le_bytes().to_vec();
        }
        ifd.extend(tag.to_le_bytes());
        ifd.extend(ty.to_le_bytes());
        ifd.extend(count.to_le_bytes());
        if val.len() <= 4 {
            val.resize(4, 0);
            ifd.extend(val);
        } else {
            ifd.extend((blob_off as u32).to_le_bytes());
            blob_off += val.len();
            blobs.extend(val);
        }
    }
    ifd.extend(0u32.to_le_bytes());
    let mut b = b"II*\0".to_vec();
    b.extend(8u32.to_le_bytes());
    b.extend(ifd);
    b.extend(blobs);
    b.extend(strip);
    b
}

fn tiny_tiff(w: u32, h: u32, strip: &[u8]) -> Vec<u8> {
    build_tiff(w, h, strip, vec![])
}

/// GeoTIFF georeference: PixelIsArea shifts the tiepoint by half a pixel, PixelIsPoint not;
/// geographic vs projected from the GeoKeys; GDAL_NODATA parsed from ASCII.
#[test]
fn geotiff_georeference_keys() {
    let strip: Vec<u8> = [1i16, 2, 3, 4, 5, 6].iter().flat_map(|v| v.to_le_bytes()).collect();
    let geo = |model: u16, raster: u16, key: u16, code: u16| -> Vec<Field> {
        vec![
            (33550, 12, 3, doubles(&[0.5, 0.25, 0.0])),
            (33922, 12, 6, doubles(&[0.0, 0.0, 0.0, 10.0, 50.0, 0.0])),
            (
                34735,
                3,
                16,
                shorts(&[1, 1, 0, 3, 1024, 0, 1, model, 1025, 0, 1, raster, key, 0, 1, code]),
            ),
            (42113, 2, 3, b"5\0\0".to_vec()),
        ]
    };
    // PixelIsPoint, geographic: the tiepoint is the centre of the NW sample.
    let p = write_temp("point.tif", &build_tiff(3, 2, &strip, geo(2, 2, 2048, 4326)));
    let dem = load(&p, &LoadOptions::default()).unwrap();
    let g = dem.heightmap.georef();
    assert_eq!(g.crs, Crs::Epsg(4326));
    assert_eq!(g.units, AngularOrLinear::Degrees);
    assert_eq!(g.native_origin, glam::dvec2(10.0, 49.75));
    assert_eq!(g.native_spacing, glam::dvec2(0.5, 0.25));
    assert_eq!(dem.source.nodata, Some(5.0));
    // file row 1 = [4 5 6] is our row 0; the 5 is void.
    assert!(dem.heightmap.voids().get(1, 0) && dem.heightmap.voids().count() == 1);
    // PixelIsArea, projected: the tiepoint is the NW corner; centres are half a pixel in.
    let p = write_temp("area.tif", &build_tiff(3, 2, &strip, geo(1, 1, 3072, 32611)));
    let dem = load(&p, &LoadOptions::default()).unwrap();
    let g = dem.heightmap.georef();
    assert_eq!(g.crs, Crs::Epsg(32611));
    assert_eq!(g.units, AngularOrLinear::Metres);
    assert_eq!(g.native_origin, glam::dvec2(10.25, 49.625));
    // A GeoKeyDirectory that declares more keys than it holds is malformed, naming the tag.
    let mut bad = geo(2, 1, 2048, 4326);
    bad[2] = (34735, 3, 8, shorts(&[1, 1, 0, 3, 1024, 0, 1, 2]));
    let p = write_temp("badkeys.tif", &build_tiff(3, 2, &strip, bad));
    assert_err(&p, &LoadOptions::default(), "GeoKeyDirectoryTag (34735)");
    // A zero pixel scale is malformed.
    let mut bad = geo(2, 1, 2048, 4326);
    bad[0] = (33550, 12, 3, doubles(&[0.0, 0.25, 0.0]));
    let p = write_temp("badscale.tif", &build_tiff(3, 2, &strip, bad));
    assert_err(&p, &LoadOptions::default(), "pixel scale");
}

/// A south-up GeoTIFF (negative y pixel scale: the first row is the southernmost, as numpy
/// grids with latitude ascending are often written) reads as the north-up file with its rows
/// reversed, whole and by rows; the tie point is then the south-west corner. A negative x
/// scale (east to the left) stays refused.
#[test]
fn south_up_geotiff_reads_as_its_north_up_twin() {
    use terrain_core::dem::RowReader;
    let (w, h) = (3u32, 4u32);
    let rows: Vec<[i16; 3]> = vec![[1, 2, 3], [4, 5, 6], [7, 8, 9], [10, 11, 12]];
    let bytes = |rows: &[[i16; 3]]| -> Vec<u8> {
        rows.iter().flatten().flat_map(|v| v.to_le_bytes()).collect()
    };
    let geo = |sy: f64, y0: f64| -> Vec<Field> {
        vec![
            (33550, 12, 3, doubles(&[0.5, sy, 0.0])),
            (33922, 12, 6, doubles(&[0.0, 0.0, 0.0, 10.0, y0, 0.0])),
            (34735, 3, 12, shorts(&[1, 1, 0, 2, 1024, 0, 1, 2, 2048, 0, 1, 4326])),
        ]
    };
    // The same terrain: north-up stores row [10 11 12] (north, y 50..49.75) first; south-up
    // stores [1 2 3] (south, y 49..49.25) first, its tie point at the south edge.
    let mut reversed = rows.clone();
    reversed.reverse();
    let north = write_temp("north_up.tif", &build_tiff(w, h, &bytes(&reversed), geo(0.25, 50.0)));
    let south = write_temp("south_up.tif", &build_tiff(w, h, &bytes(&rows), geo(-0.25, 49.0)));
    let a = load(&north, &LoadOptions::default()).unwrap();
    let b = load(&south, &LoadOptions::default()).unwrap();
    assert_eq!(b.heightmap.georef().native_origin, glam::dvec2(10.25, 49.125));
    assert_eq!(a.heightmap.georef().native_origin, b.heightmap.georef().native_origin);
    assert_eq!(a.heightmap.georef().native_spacing, b.heightmap.georef().native_spacing);
    assert_eq!((a.heightmap.width(), a.heightmap.height()), (w as usize, h as usize));
    for (j, row) in rows.iter().enumerate() {
        for (i, &v) in row.iter().enumerate() {
            // Our row 0 is the south row [1 2 3] in both.
            let want = f32::from(v);
            assert_eq!(a.heightmap.get(i, j), want, "north-up ({i}, {j})");
            assert_eq!(b.heightmap.get(i, j), want, "south-up ({i}, {j})");
        }
    }
    // By rows: rows 1..3 of the south-up file, south first.
    let reader = RowReader::open(&south, &LoadOptions::default()).unwrap();
    let mut heights = vec![0f32; 6];
    let mut voids = vec![false; 6];
    reader.read_rows(1, 2, &mut heights, &mut voids).unwrap();
    assert_eq!(heights, vec![4.0, 5.0, 6.0, 7.0, 8.0, 9.0]);
    // East to the left is not a raster we read.
    let flipped_x = write_temp(
        "east_left.tif",
        &build_tiff(w, h, &bytes(&rows), {
            let mut g = geo(0.25, 50.0);
            g[0] = (33550, 12, 3, doubles(&[-0.5, 0.25, 0.0]));
            g
        }),
    );
    assert_err(&flipped_x, &LoadOptions::default(), "pixel scale");
}

/// Writes a 5 x 4 GeoTIFF of colour type `C` with `compression`, in strips of 2 rows, with
/// geographic georeference tags and GDAL_NODATA 7, and checks every sample reads back flipped.
fn roundtrip<C>(compression: tiff::encoder::Compression, name: &str, want_type: &str)
where
    C: tiff::encoder::colortype::ColorType,
    C::Inner: Copy + Into<f64> + TryFrom<u8>,
    <C::Inner as TryFrom<u8>>::Error: std::fmt::Debug,
    [C::Inner]: tiff::encoder::TiffValue,
{
    use tiff::tags::Tag;
    let (w, h) = (5u32, 4u32);
    let vals: Vec<C::Inner> =
        (0..w * h).map(|k| C::Inner::try_from((k * 3 + 1) as u8).unwrap()).collect();
    let mut buf = std::io::Cursor::new(Vec::new());
    {
        let mut enc =
            tiff::encoder::TiffEncoder::new(&mut buf).unwrap().with_compression(compression);
        let mut img = enc.new_image::<C>(w, h).unwrap();
        img.rows_per_strip(2).unwrap();
        let e = img.encoder();
        e.write_tag(Tag::ModelPixelScaleTag, &[0.5f64, 0.5, 0.0][..]).unwrap();
        e.write_tag(Tag::ModelTiepointTag, &[0.0f64, 0.0, 0.0, 100.0, 60.0, 0.0][..]).unwrap();
        e.write_tag(Tag::GeoKeyDirectoryTag, &[1u16, 1, 0, 2, 1024, 0, 1, 2, 2048, 0, 1, 4326][..])
            .unwrap();
        e.write_tag(Tag::GdalNodata, "7").unwrap();
        img.write_data(&vals).unwrap();
    }
    let p = write_temp(name, buf.get_ref());
    let dem = load(&p, &LoadOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
    let hm = &dem.heightmap;
    assert_eq!(dem.source.sample_type, want_type, "{name}");
    assert_eq!(dem.source.nodata, Some(7.0));
    assert_eq!(hm.georef().crs, Crs::Epsg(4326));
    assert_eq!(hm.georef().native_origin, glam::dvec2(100.25, 58.25), "{name}");
    let (w, h) = (w as usize, h as usize);
    for r in 0..h {
        for i in 0..w {
            let v: f64 = vals[r * w + i].into();
            let j = h - 1 - r;
            if v == 7.0 {
                assert!(hm.voids().get(i, j), "{name}");
            } else {
                assert_eq!(hm.get(i, j) as f64, v, "{name} ({i}, {j})");
            }
        }
    }
    assert_eq!(hm.voids().count(), 1, "{name}");
}

/// Every sample type the brief lists, uncompressed, LZW and Deflate, multi-strip.
#[test]
fn geotiff_sample_types_and_compressions() {
    use tiff::encoder::{Compression, colortype::*, compression::DeflateLevel};
    for (c, cn) in [
        (Compression::Uncompressed, "none"),
        (Compression::Lzw, "lzw"),
        (Compression::Deflate(DeflateLevel::default()), "deflate"),
    ] {
        roundtrip::<GrayI16>(c, &format!("i16_{cn}.tif"), "int16");
        roundtrip::<Gray16>(c, &format!("u16_{cn}.tif"), "uint16");
        roundtrip::<GrayI32>(c, &format!("i32_{cn}.tif"), "int32");
        roundtrip::<Gray32Float>(c, &format!("f32_{cn}.tif"), "float32");
        roundtrip::<Gray64Float>(c, &format!("f64_{cn}.tif"), "float64");
    }
}

#[test]
fn hgt_southern_western_name() {
    let bytes = std::fs::read(data("srtm/N52E008.hgt")).unwrap();
    let p = write_temp("S01W002.hgt", &bytes);
    let dem = load(&p, &LoadOptions::default()).unwrap();
    assert_eq!(dem.heightmap.georef().native_origin, glam::dvec2(-2.0, -1.0));
}

#[test]
fn tiny_tiff_reads_and_huge_tiff_is_refused() {
    // Sanity-check the hand-made TIFF first, so the TooLarge case tests the size check only.
    let strip: Vec<u8> = [1i16, 2, 3, 4, 5, 6].iter().flat_map(|v| v.to_le_bytes()).collect();
    let p = write_temp("tiny.tif", &tiny_tiff(3, 2, &strip));
    let dem = load(&p, &LoadOptions::default()).unwrap();
    assert_eq!(dem.heightmap.data(), &[4.0, 5.0, 6.0, 1.0, 2.0, 3.0]);
    assert_eq!(dem.heightmap.georef().crs, Crs::Unknown);

    let p = write_temp("huge.tif", &tiny_tiff(1_000_000, 1_000_000, &strip));
    // Refused by the size check (its kind), before any sample is read: a reader that touched
    // the 10^12 samples would not return (no clock asserted here: CI's machines are shared).
    let kind = assert_err(&p, &LoadOptions::default(), "exceeds the limit");
    assert!(
        matches!(kind, DemErrorKind::TooLarge { width: 1_000_000, height: 1_000_000, .. }),
        "{kind}"
    );
    // Under a raised limit the size check passes but the data cannot hold the grid: refused too,
    // before the decoder allocates 2 TB.
    let opts = LoadOptions { max_samples: u64::MAX, ..Default::default() };
    assert!(load(&p, &opts).is_err());
}

#[test]
fn all_void_hgt() {
    let bytes: Vec<u8> = std::iter::repeat_n([0x80u8, 0x00], 1201 * 1201).flatten().collect();
    let p = write_temp("N10E010.hgt", &bytes);
    let kind = assert_err(&p, &LoadOptions::default(), "every sample is no-data");
    assert!(matches!(kind, DemErrorKind::AllVoid { count: 1_442_401, .. }), "{kind}");
}

/// xorshift64*: a deterministic RNG for the mutation loop.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

/// Mutated and truncated real files: `load` returns Ok or Err, never panics.
#[test]
fn mutated_files_never_panic() {
    let tif = std::fs::read(data("crater_lake/craterlake-elev-16bit-30m.tif")).unwrap();
    let png = std::fs::read(data("puget_sound/ps_height_1k.png")).unwrap();
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let tmp = temp_dir();
    let dir = tmp.path();
    // A small limit keeps a mutated width/height from asking for gigabytes.
    let opts = LoadOptions { max_samples: 1 << 22, ..Default::default() };
    let mut errors = 0;
    for case in 0..220 {
        let (src, name) = if case % 10 == 9 { (&png, "m.png") } else { (&tif, "m.tif") };
        let mut b = src.clone();
        match case % 3 {
            0 => b.truncate(rng.below(b.len())),
            // Structure: the header, and the last 3 KB (crater_lake's IFD and GeoTIFF tag
            // values sit at the end of the file; PNG's IEND too).
            1 => {
                for _ in 0..1 + rng.below(4) {
                    let n = b.len();
                    let k = if rng.below(4) == 0 {
                        rng.below(16)
                    } else {
                        n - 1 - rng.below(3000.min(n))
                    };
                    b[k] = rng.next() as u8;
                }
            }
            _ => {
                for _ in 0..1 + rng.below(8) {
                    let k = rng.below(b.len());
                    b[k] = rng.next() as u8;
                }
            }
        }
        let p = dir.join(name);
        std::fs::write(&p, &b).unwrap();
        let r = std::panic::catch_unwind(|| load(&p, &opts));
        match r {
            Ok(Err(e)) => {
                errors += 1;
                assert!(e.to_string().contains(name), "{e}");
            }
            Ok(Ok(_)) => {}
            Err(_) => panic!("load panicked on case {case} (mutated {name})"),
        }
    }
    assert!(errors > 50, "the mutations should break most files ({errors} errors)");
}
