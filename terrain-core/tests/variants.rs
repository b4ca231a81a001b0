//! GeoTIFF and JPEG variants written by GDAL (`tests/data/geotiff/make.py`, from the shared
//! SRTM heights) read against GDAL's own values stored beside them (`gdal_values.json`):
//! WhiteIsZero files read as stored, projected CRSs in feet and user-defined projected CRSs
//! placed in metres, damaged Deflate streams and truncated JPEGs refused; implausible heights
//! (void sentinels without a nodata value, grey images read at 1 m per level) warned about.

mod common;

use std::path::{Path, PathBuf};

use common::data;
use serde_json::Value;
use terrain_core::dem::{LoadOptions, LoadWarning, RowReader, load};
use terrain_core::georef::AngularOrLinear;
use terrain_core::{Crs, Heightmap};

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/geotiff")
}

/// GDAL's values of variant `name`.
fn gdal(name: &str) -> Value {
    let text = std::fs::read_to_string(dir().join("gdal_values.json")).expect("gdal_values.json");
    let all: Value = serde_json::from_str(&text).expect("JSON");
    all["variants"]
        .as_array()
        .expect("variants")
        .iter()
        .find(|v| v["file"] == name)
        .unwrap_or_else(|| panic!("{name} not in gdal_values.json"))
        .clone()
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("{v} is not a number"))
}

/// A temporary folder for one test, removed when dropped (also when the test panics).
fn temp_dir() -> tempfile::TempDir {
    common::temp_dir("terrain-core-variants-")
}

/// Void count, min, max and sum of the valid samples.
fn stats(hm: &Heightmap) -> (usize, f64, f64, f64) {
    let (mut lo, mut hi, mut sum) = (f64::INFINITY, f64::NEG_INFINITY, 0.0);
    for j in 0..hm.height() {
        for i in 0..hm.width() {
            if !hm.voids().get(i, j) {
                let z = f64::from(hm.get(i, j));
                lo = lo.min(z);
                hi = hi.max(z);
                sum += z;
            }
        }
    }
    (hm.voids().count(), lo, hi, sum)
}

/// Size, voids, min, max and sum equal GDAL's.
fn assert_samples_like_gdal(name: &str, hm: &Heightmap) {
    let g = gdal(name);
    assert_eq!(hm.width() as u64, g["size"][0].as_u64().unwrap(), "{name}: width");
    assert_eq!(hm.height() as u64, g["size"][1].as_u64().unwrap(), "{name}: height");
    let (voids, lo, hi, sum) = stats(hm);
    assert_eq!(voids as u64, g["voids"].as_u64().unwrap(), "{name}: voids");
    assert_eq!(lo, f(&g["min"]), "{name}: min");
    assert_eq!(hi, f(&g["max"]), "{name}: max");
    assert_eq!(sum, f(&g["sum"]), "{name}: sum of the valid samples");
}

#[test]
fn white_is_zero_reads_the_stored_values_like_gdal() {
    for name in ["wiz_int16.tif", "wiz_float32.tif"] {
        let dem = load(dir().join(name), &LoadOptions::default())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(dem.source.nodata, gdal(name)["nodata"].as_f64(), "{name}: nodata");
        assert_samples_like_gdal(name, &dem.heightmap);
    }
}

#[test]
fn white_is_zero_streams_the_stored_values_too() {
    for name in ["wiz_int16.tif", "wiz_float32.tif"] {
        let path = dir().join(name);
        let whole = load(&path, &LoadOptions::default()).unwrap();
        let r = RowReader::open(&path, &LoadOptions::default()).unwrap();
        let (w, h) = (r.width() as usize, r.height() as usize);
        let mut rows = vec![0f32; w * h];
        let mut voids = vec![false; w * h];
        r.read_rows(0, h, &mut rows, &mut voids).unwrap();
        for j in 0..h {
            for i in 0..w {
                assert_eq!(
                    voids[j * w + i],
                    whole.heightmap.voids().get(i, j),
                    "{name} ({i}, {j})"
                );
                if !voids[j * w + i] {
                    assert_eq!(rows[j * w + i], whole.heightmap.get(i, j), "{name} ({i}, {j})");
                }
            }
        }
    }
}

/// Native origin (centre of the south-west sample) and spacing from GDAL's geotransform, and
/// the metric spacing from GDAL's linear unit.
fn assert_placed_like_gdal(name: &str, hm: &Heightmap) {
    let g = gdal(name);
    let gt: Vec<f64> = g["geotransform"].as_array().unwrap().iter().map(f).collect();
    let h = g["size"][1].as_f64().unwrap();
    let unit = f(&g["linear_unit_m"]);
    assert!(g["projected"].as_bool().unwrap(), "{name}: GDAL reads a projected CRS");
    let geo = hm.georef();
    assert_eq!(geo.units, AngularOrLinear::Metres, "{name}: linear units, not degrees");
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs().max(1.0);
    assert!(close(geo.native_spacing.x, gt[1]), "{name}: native dx {}", geo.native_spacing.x);
    assert!(close(geo.native_spacing.y, -gt[5]), "{name}: native dy {}", geo.native_spacing.y);
    assert!(close(geo.native_origin.x, gt[0] + 0.5 * gt[1]), "{name}: x0");
    assert!(close(geo.native_origin.y, gt[3] + (h - 0.5) * gt[5]), "{name}: y0");
    assert!(
        close(geo.spacing_m.x, gt[1] * unit) && close(geo.spacing_m.y, -gt[5] * unit),
        "{name}: spacing {:?} m, GDAL: {} units of {unit} m",
        geo.spacing_m,
        gt[1]
    );
    assert!(close(geo.world_origin.x, geo.native_origin.x * unit), "{name}: world x0");
    assert!(close(geo.world_origin.y, geo.native_origin.y * unit), "{name}: world y0");
}

#[test]
fn projected_crs_in_us_survey_feet_is_converted_to_metres() {
    let name = "ftus_epsg2272.tif";
    let dem = load(dir().join(name), &LoadOptions::default()).unwrap();
    assert_eq!(dem.heightmap.georef().crs, Crs::Epsg(2272));
    assert_placed_like_gdal(name, &dem.heightmap);
    assert_samples_like_gdal(name, &dem.heightmap);
    // The row reader places it the same way.
    let r = RowReader::open(dir().join(name), &LoadOptions::default()).unwrap();
    assert_eq!(r.georef(), dem.heightmap.georef());
}

#[test]
fn user_defined_projected_crs_is_not_taken_for_degrees() {
    for name in ["ftintl_user_tmerc.tif", "m_user_tmerc.tif", "m_user_albers.tif"] {
        let dem = load(dir().join(name), &LoadOptions::default())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(
            !matches!(dem.heightmap.georef().crs, Crs::Epsg(_)),
            "{name}: no EPSG code, got {}",
            dem.heightmap.georef().crs
        );
        assert_placed_like_gdal(name, &dem.heightmap);
    }
}

/// Single-bit flips of a Deflate strip longer than 32 KiB (every bit of its last 64 bytes,
/// every 97th before them): every flip the reference zlib refuses (its verdicts are recorded
/// by `make.py`) is refused by the whole-file and the row readers, and the message names the
/// file.
#[test]
fn damaged_deflate_streams_are_refused_like_zlib_refuses_them() {
    let name = "deflate_strip.tif";
    let path = dir().join(name);
    let good = load(&path, &LoadOptions::default()).unwrap();
    assert_samples_like_gdal(name, &good.heightmap);
    let all: Value =
        serde_json::from_str(&std::fs::read_to_string(dir().join("gdal_values.json")).unwrap())
            .unwrap();
    let flips = &all["deflate_flips"];
    assert_eq!(flips["file"], name);
    let (offset, count) = (flips["offset"].as_u64().unwrap(), flips["bytes"].as_u64().unwrap());
    let (every, tail) =
        (flips["every_nth_bit"].as_u64().unwrap(), flips["tail_bytes"].as_u64().unwrap());
    let bits: Vec<u64> = (0..(count - tail) * 8)
        .step_by(every as usize)
        .chain((count - tail) * 8..count * 8)
        .collect();
    assert_eq!(bits.len() as u64, flips["flips"].as_u64().unwrap());
    let zlib_ok: std::collections::HashSet<u64> = flips["zlib_accepted_bits"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b.as_u64().unwrap())
        .collect();
    let bytes = std::fs::read(&path).unwrap();
    let tmp = temp_dir();
    let p = tmp.path().join("flipped.tif");
    let (mut refused, mut checked) = (0, 0);
    for &bit in bits.iter().filter(|b| !zlib_ok.contains(b)) {
        let mut b = bytes.clone();
        b[(offset + bit / 8) as usize] ^= 1 << (bit % 8);
        std::fs::write(&p, &b).unwrap();
        checked += 1;
        match load(&p, &LoadOptions::default()) {
            Err(e) => {
                refused += 1;
                let msg = e.to_string();
                assert!(msg.contains("flipped.tif"), "the message names the file: {msg}");
            }
            Ok(_) => panic!("bit {bit} of the strip flipped: zlib refuses it, we read it"),
        }
        // The row reader (bakes) refuses it too.
        if let Ok(r) = RowReader::open(&p, &LoadOptions::default()) {
            let (w, h) = (r.width() as usize, r.height() as usize);
            let mut rows = vec![0f32; w * h];
            let mut voids = vec![false; w * h];
            assert!(
                r.read_rows(0, h, &mut rows, &mut voids).is_err(),
                "rows: bit {bit} flipped read as numbers"
            );
        }
    }
    assert_eq!(refused, checked);
    assert!(checked > 4_000, "{checked} flips checked");
}

#[test]
fn truncated_jpeg_heightmaps_are_refused() {
    let path = dir().join("grey.jpg");
    let whole = load(&path, &LoadOptions::default()).unwrap();
    let g = gdal("grey.jpg");
    assert_eq!(whole.heightmap.width() as u64, g["size"][0].as_u64().unwrap());
    assert_eq!(whole.heightmap.height() as u64, g["size"][1].as_u64().unwrap());
    let bytes = std::fs::read(&path).unwrap();
    let tmp = temp_dir();
    for keep in [bytes.len() / 10, bytes.len() / 2, bytes.len() * 9 / 10, bytes.len() - 2] {
        let p = tmp.path().join(format!("cut_{keep}.jpg"));
        std::fs::write(&p, &bytes[..keep]).unwrap();
        let e = load(&p, &LoadOptions::default())
            .map(|_| ())
            .expect_err(&format!("{keep} of {} bytes read as a heightmap", bytes.len()));
        let msg = e.to_string();
        assert!(msg.contains("cut_") && msg.contains("truncated"), "{msg}");
    }
}

/// The sentinel warnings of `dem`: (value, count).
fn sentinels(warnings: &[LoadWarning]) -> Vec<(f64, Option<u64>)> {
    warnings
        .iter()
        .filter_map(|w| match w {
            LoadWarning::Sentinel { value, count, .. } => Some((*value, *count)),
            _ => None,
        })
        .collect()
}

#[test]
fn void_sentinels_without_a_nodata_value_are_warned_about() {
    // The shared Crater Lake file: -32767 voids and no nodata tag (see data/README.md).
    let crater = data("crater_lake/craterlake-elev-16bit-30m.tif");
    let dem = load(&crater, &LoadOptions::default()).unwrap();
    let found = sentinels(&dem.warnings);
    assert_eq!(found.len(), 1, "{:?}", dem.warnings);
    assert_eq!(found[0].0, -32767.0);
    let stored = dem.heightmap.data().iter().filter(|&&z| z == -32767.0).count() as u64;
    assert_eq!(found[0].1, Some(stored), "the count is the samples read as -32767 m");
    let msg = dem.warnings[0].to_string();
    assert!(msg.contains("craterlake") && msg.contains("--nodata=-32767"), "{msg}");
    // The heights are unchanged: the warning changes nothing.
    assert!(stored > 0);
    // With --nodata the samples are voids and nothing is said.
    let fixed =
        load(&crater, &LoadOptions { nodata: Some(-32767.0), ..Default::default() }).unwrap();
    assert!(fixed.warnings.is_empty(), "{:?}", fixed.warnings);
    assert_eq!(Some(fixed.heightmap.voids().count() as u64), found[0].1);
    // Read by rows (bakes of DEMs larger than memory): the same warning, without a count.
    let rows_of = |options: &LoadOptions| {
        let r = RowReader::open(&crater, options).unwrap();
        let (w, h) = (r.width() as usize, r.height() as usize);
        let (mut z, mut v) = (vec![0f32; w * h], vec![false; w * h]);
        r.read_rows(0, h, &mut z, &mut v).unwrap();
        r.warnings()
    };
    assert_eq!(sentinels(&rows_of(&LoadOptions::default())), vec![(-32767.0, None)]);
    assert!(rows_of(&LoadOptions { nodata: Some(-32767.0), ..Default::default() }).is_empty());

    // GDAL-written variants: the Rainier crop's voids as -9999 and as float32's lowest value,
    // with no nodata tag; as many as the crop's voids (GDAL's count of the original).
    let voids = gdal("wiz_int16.tif")["voids"].as_u64().unwrap();
    for (name, value) in
        [("sentinel_9999.tif", -9999.0), ("sentinel_f32min.tif", f64::from(f32::MIN))]
    {
        let dem = load(dir().join(name), &LoadOptions::default()).unwrap();
        // As f32, the file's sample type (serde_json's float parsing is not exact to the last
        // bit of an f64).
        assert_eq!(f(&gdal(name)["min"]) as f32, value as f32, "{name}: GDAL's lowest value");
        assert_eq!(
            sentinels(&dem.warnings),
            vec![(value, Some(voids))],
            "{name}: {:?}",
            dem.warnings
        );
        let msg = dem.warnings[0].to_string();
        let option = format!(
            "--nodata={}",
            if value == -9999.0 { "-9999".to_string() } else { format!("{value:e}") }
        );
        assert!(msg.contains(name) && msg.contains(&option), "{msg}");
    }

    // Real files with their voids declared, or none: nothing to say.
    for rel in ["big_tujunga/bigtujunga.tif", "lidar_prairie/dem.tif", "srtm/N52E008.hgt"] {
        let dem = load(data(rel), &LoadOptions::default()).unwrap();
        assert!(dem.warnings.is_empty(), "{rel}: {:?}", dem.warnings);
    }
}

#[test]
fn a_grey_png_read_without_a_vertical_scale_is_warned_about() {
    // Puget Sound: 16-bit grey, 0..43798 raw, metres = raw x 0.1, 160 m spacing (README).
    let png = data("puget_sound/ps_height_1k.png");
    let dem = load(&png, &LoadOptions::default()).unwrap();
    let relief: Vec<f64> = dem
        .warnings
        .iter()
        .filter_map(|w| match w {
            LoadWarning::Relief { relief_m, .. } => Some(*relief_m),
            _ => None,
        })
        .collect();
    assert_eq!(relief, vec![f64::from(dem.heightmap.max() - dem.heightmap.min())]);
    let msg = dem.warnings[0].to_string();
    assert!(msg.contains("ps_height_1k.png") && msg.contains("--vertical-scale"), "{msg}");
    // Read as the README says: nothing to say.
    let options = LoadOptions { vertical_scale: 0.1, spacing_m: 160.0, ..LoadOptions::default() };
    let dem = load(&png, &options).unwrap();
    assert!(dem.warnings.is_empty(), "{:?}", dem.warnings);
}

/// `bytes` with the first occurrence of the GeoKey entry `from` (four u16, little-endian)
/// replaced by `to`.
fn patch_geokey(bytes: &[u8], from: [u16; 4], to: [u16; 4]) -> Vec<u8> {
    let le = |k: [u16; 4]| k.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>();
    let (from, to) = (le(from), le(to));
    let at = bytes.windows(8).position(|w| w == from.as_slice()).expect("the key is in the file");
    let mut out = bytes.to_vec();
    out[at..at + 8].copy_from_slice(&to);
    out
}

#[test]
fn the_unit_of_an_epsg_crs_without_a_units_key_comes_from_its_name() {
    // The EPSG:2272 variant with its ProjLinearUnitsGeoKey (3076 = 9003, US survey foot)
    // renamed to an unknown key: the unit must come from the CRS name GDAL wrote in the
    // citation ("NAD83 / Pennsylvania South (ftUS)").
    let name = "ftus_epsg2272.tif";
    let bytes = std::fs::read(dir().join(name)).unwrap();
    let tmp = temp_dir();
    let p = tmp.path().join("no_units_key.tif");
    std::fs::write(&p, patch_geokey(&bytes, [3076, 0, 1, 9003], [3999, 0, 1, 9003])).unwrap();
    let dem = load(&p, &LoadOptions::default()).unwrap();
    let g = gdal(name);
    let want = f(&g["geotransform"][1]) * f(&g["linear_unit_m"]);
    assert!(
        (dem.heightmap.georef().spacing_m.x - want).abs() < 1e-9,
        "{:?}",
        dem.heightmap.georef()
    );
}

#[test]
fn unsupported_crs_kinds_are_refused_saying_what_is_not_read() {
    let bytes = std::fs::read(dir().join("wiz_int16.tif")).unwrap();
    let tmp = temp_dir();
    for (from, to, said) in [
        // GeogAngularUnitsGeoKey: degree (9102) -> radian (9101).
        ([2054, 0, 1, 9102], [2054, 0, 1, 9101], "angular unit EPSG:9101"),
        // GTModelTypeGeoKey: geographic (2) -> geocentric (3).
        ([1024, 0, 1, 2], [1024, 0, 1, 3], "geocentric"),
    ] {
        let p = tmp.path().join("patched.tif");
        std::fs::write(&p, patch_geokey(&bytes, from, to)).unwrap();
        let e = load(&p, &LoadOptions::default()).map(|_| ()).unwrap_err().to_string();
        assert!(e.contains("patched.tif") && e.contains(said), "{e}");
    }
    // A projected CRS in an unknown linear unit is refused, never taken as metres.
    let bytes = std::fs::read(dir().join("ftus_epsg2272.tif")).unwrap();
    let p = tmp.path().join("odd_unit.tif");
    std::fs::write(&p, patch_geokey(&bytes, [3076, 0, 1, 9003], [3076, 0, 1, 9999])).unwrap();
    let e = load(&p, &LoadOptions::default()).map(|_| ()).unwrap_err().to_string();
    assert!(e.contains("EPSG:9999") && e.contains("linear unit"), "{e}");
}

/// The row reader (bakes) reads `name` as the whole-file reader does: same voids, same heights.
fn assert_rows_like_load(name: &str, options: &LoadOptions) {
    let path = dir().join(name);
    let whole = load(&path, options).unwrap_or_else(|e| panic!("{name}: {e}"));
    let r = RowReader::open(&path, options).unwrap_or_else(|e| panic!("{name} by rows: {e}"));
    let (w, h) = (r.width() as usize, r.height() as usize);
    assert_eq!((w, h), (whole.heightmap.width(), whole.heightmap.height()), "{name}");
    assert_eq!(r.source().sample_type, whole.source.sample_type, "{name}");
    let mut rows = vec![0f32; w * h];
    let mut voids = vec![false; w * h];
    r.read_rows(0, h, &mut rows, &mut voids).unwrap();
    for j in 0..h {
        for i in 0..w {
            let void = whole.heightmap.voids().get(i, j);
            assert_eq!(voids[j * w + i], void, "{name} ({i}, {j}): void");
            if !void {
                assert_eq!(rows[j * w + i], whole.heightmap.get(i, j), "{name} ({i}, {j})");
            }
        }
    }
}

/// Loads `name` and compares it with GDAL's values, whole and by rows.
fn assert_reads_like_gdal(name: &str) {
    let dem =
        load(dir().join(name), &LoadOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
    assert_samples_like_gdal(name, &dem.heightmap);
    assert_rows_like_load(name, &LoadOptions::default());
}

#[test]
fn sparse_blocks_read_as_no_data_or_zero_like_gdal() {
    // Tiles of a Deflate file with a nodata value (voids), strips of a file without one (0 m).
    for name in ["sparse_tiled_deflate.tif", "sparse_strips_nonodata.tif"] {
        assert_reads_like_gdal(name);
    }
    let dem = load(dir().join("sparse_strips_nonodata.tif"), &LoadOptions::default()).unwrap();
    let south_row_zeros = (0..dem.heightmap.width()).all(|i| dem.heightmap.get(i, 0) == 0.0);
    assert!(south_row_zeros, "the unwritten southern strips read as 0 m");
}

#[test]
fn one_to_seven_bit_samples_read_like_gdal() {
    for name in ["nbits1.tif", "nbits3_tiled_deflate.tif", "nbits7_lzw.tif"] {
        assert_reads_like_gdal(name);
        let g = gdal(name);
        let dem = load(dir().join(name), &LoadOptions::default()).unwrap();
        assert_eq!(
            dem.source.sample_type,
            format!("uint{}", g["nbits"].as_str().unwrap()),
            "{name}: sample type"
        );
    }
}

#[test]
fn zstd_with_predictors_1_2_3_reads_like_gdal() {
    for name in
        ["zstd_p1.tif", "zstd_p2_tiled.tif", "zstd_p2_be.tif", "zstd_p3_f32.tif", "zstd_p3_f64.tif"]
    {
        assert_eq!(gdal(name)["compression"], "ZSTD", "{name}");
        assert_reads_like_gdal(name);
    }
}

#[test]
fn damaged_zstd_chunks_are_refused_naming_the_file() {
    let name = "zstd_p2_tiled.tif";
    let bytes = std::fs::read(dir().join(name)).unwrap();
    let good = load(dir().join(name), &LoadOptions::default()).unwrap();
    let tmp = temp_dir();
    let p = tmp.path().join("zstd_cut.tif");
    // Zero the last 200 bytes (tile data; the IFD comes first in GDAL's files).
    let mut b = bytes.clone();
    let n = b.len();
    b[n - 200..].fill(0);
    std::fs::write(&p, &b).unwrap();
    match load(&p, &LoadOptions::default()) {
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.contains("zstd_cut.tif") && msg.contains("ZSTD"), "{msg}");
        }
        Ok(d) => assert_ne!(d.heightmap.data(), good.heightmap.data(), "damage unnoticed"),
    }
}

#[test]
fn unsupported_compressions_are_refused_by_name() {
    for (name, said) in [
        ("lerc.tif", "LERC (34887)"),
        ("lzma.tif", "LZMA (34925)"),
        ("webp_rgb.tif", "WebP (50001)"),
    ] {
        let gdal_name = gdal(name)["compression"].as_str().unwrap().to_string();
        assert!(said.to_ascii_uppercase().starts_with(&gdal_name), "{name}: GDAL says {gdal_name}");
        for e in [
            load(dir().join(name), &LoadOptions::default()).map(|_| ()).unwrap_err(),
            RowReader::open(dir().join(name), &LoadOptions::default()).map(|_| ()).unwrap_err(),
        ] {
            let msg = e.to_string();
            assert!(
                msg.contains(name) && msg.contains(said) && msg.contains("not supported"),
                "{msg}"
            );
            assert!(!msg.contains("Unknown("), "{msg}");
        }
    }
}

/// Per-band GDAL values of a multi-band variant: (voids, min, max, sum).
fn band_stats(name: &str, band: usize) -> (u64, f64, f64, f64) {
    let b = &gdal(name)["per_band"][band - 1];
    (b["voids"].as_u64().unwrap(), f(&b["min"]), f(&b["max"]), f(&b["sum"]))
}

#[test]
fn multi_band_files_read_band_1_or_the_band_asked_for() {
    for name in ["bands3_pixel.tif", "bands2_band.tif"] {
        let bands = gdal(name)["bands"].as_u64().unwrap() as u16;
        assert!(bands > 1, "{name}");
        for band in 1..=bands {
            let options = LoadOptions { band, ..LoadOptions::default() };
            let dem = load(dir().join(name), &options).unwrap_or_else(|e| panic!("{name}: {e}"));
            let (voids, lo, hi, sum) = stats(&dem.heightmap);
            assert_eq!(
                (voids as u64, lo, hi, sum),
                band_stats(name, band as usize),
                "{name} band {band}"
            );
            let said: Vec<_> = dem
                .warnings
                .iter()
                .filter(|w| matches!(w, LoadWarning::Bands { .. }))
                .map(|w| w.to_string())
                .collect();
            assert_eq!(said.len(), 1, "{name}: {:?}", dem.warnings);
            assert!(said[0].contains(&format!("{bands} bands, band {band}")), "{}", said[0]);
            assert_rows_like_load(name, &options);
        }
        // Band 1 is the default.
        let dem = load(dir().join(name), &LoadOptions::default()).unwrap();
        assert_samples_like_gdal(name, &dem.heightmap);
        // A band the file does not have is refused, saying how many it has.
        let options = LoadOptions { band: bands + 1, ..LoadOptions::default() };
        for e in [
            load(dir().join(name), &options).map(|_| ()).unwrap_err(),
            RowReader::open(dir().join(name), &options).map(|_| ()).unwrap_err(),
        ] {
            let msg = e.to_string();
            assert!(
                msg.contains(&format!("band {}", bands + 1))
                    && msg.contains(&format!("{bands} bands")),
                "{msg}"
            );
        }
    }
    // A single-band file has no band 2, and says nothing about bands.
    let options = LoadOptions { band: 2, ..LoadOptions::default() };
    let e = load(dir().join("wiz_int16.tif"), &options).map(|_| ()).unwrap_err().to_string();
    assert!(e.contains("band 2") && e.contains("1 band"), "{e}");
}

#[test]
fn gdal_band_scale_and_offset_are_applied() {
    let name = "scaled.tif";
    let g = gdal(name);
    let (scale, offset) = (f(&g["scale"]), f(&g["offset"]));
    assert_ne!((scale, offset), (1.0, 0.0), "the variant has a scale and an offset");
    let dem = load(dir().join(name), &LoadOptions::default()).unwrap();
    let (voids, lo, hi, sum) = stats(&dem.heightmap);
    let valid = (g["size"][0].as_u64().unwrap() * g["size"][1].as_u64().unwrap()
        - g["voids"].as_u64().unwrap()) as f64;
    assert_eq!(voids as u64, g["voids"].as_u64().unwrap(), "voids: nodata is a raw value");
    assert_eq!(lo, f(&g["min"]) * scale + offset);
    assert_eq!(hi, f(&g["max"]) * scale + offset);
    assert_eq!(sum, f(&g["sum"]) * scale + offset * valid);
    assert_rows_like_load(name, &LoadOptions::default());
    // The options' vertical scale converts on top: feet to metres.
    let feet = LoadOptions { vertical_scale: 0.3048, ..LoadOptions::default() };
    let dem = load(dir().join(name), &feet).unwrap();
    assert_eq!(
        f64::from(dem.heightmap.max()),
        f64::from(((f(&g["max"]) * scale + offset) * 0.3048) as f32)
    );
}

#[test]
fn internal_masks_make_voids_like_gdal() {
    let name = "mask_internal.tif";
    let g = gdal(name);
    assert!(g["nodata"].is_null(), "no nodata value: the voids come from the mask");
    assert_eq!(g["mask_flags"].as_u64(), Some(2), "GDAL's per-dataset mask");
    assert_reads_like_gdal(name);
}

#[test]
fn vertical_scale_beyond_f32_is_refused_and_applied_otherwise() {
    // The crop's heights are 989..1971 m: x 1e35 fits f32 (1.97e38), x 1e36 does not (the
    // issue's 1e35 on the whole Rainier tile, 4,392 m, does not either).
    for name in ["wiz_int16.tif", "zstd_p3_f32.tif"] {
        let path = dir().join(name);
        let huge = LoadOptions { vertical_scale: 1e36, ..LoadOptions::default() };
        for e in [load(&path, &huge).map(|_| ()).unwrap_err(), {
            let r = RowReader::open(&path, &huge);
            r.and_then(|r| {
                let (w, h) = (r.width() as usize, r.height() as usize);
                r.read_rows(0, h, &mut vec![0f32; w * h], &mut vec![false; w * h])
            })
            .unwrap_err()
        }] {
            let msg = e.to_string();
            assert!(msg.contains(name) && msg.contains("vertical scale 1e36"), "{msg}");
        }
        // Feet: applied, and said.
        let feet = LoadOptions { vertical_scale: 0.3048, ..LoadOptions::default() };
        let dem = load(&path, &feet).unwrap();
        assert_eq!(
            f64::from(dem.heightmap.max()),
            f64::from((f(&gdal(name)["max"]) * 0.3048) as f32)
        );
        assert!(
            dem.warnings
                .iter()
                .any(|w| matches!(w, LoadWarning::Rescaled { scale, .. } if *scale == 0.3048)),
            "{:?}",
            dem.warnings
        );
        assert_rows_like_load(name, &feet);
    }
    // Grey images too: 255 x 1e37 is beyond f32.
    let huge = LoadOptions { vertical_scale: 1e37, ..LoadOptions::default() };
    let e = load(dir().join("grey.jpg"), &huge).map(|_| ()).unwrap_err().to_string();
    assert!(e.contains("grey.jpg") && e.contains("vertical scale"), "{e}");
}

#[test]
fn spacing_is_refused_for_georeferenced_files() {
    let given = LoadOptions { spacing_m: 30.0, spacing_given: true, ..LoadOptions::default() };
    for path in [dir().join("wiz_int16.tif"), data("srtm/N52E008.hgt")] {
        let e = load(&path, &given).map(|_| ()).unwrap_err().to_string();
        assert!(e.contains("--spacing") && e.contains("georeference"), "{e}");
        // Not given: read.
        assert!(load(&path, &LoadOptions { spacing_m: 30.0, ..LoadOptions::default() }).is_ok());
    }
    let e = RowReader::open(dir().join("wiz_int16.tif"), &given).map(|_| ()).unwrap_err();
    assert!(e.to_string().contains("--spacing"), "{e}");
    // A grey image has no georeference: the spacing is used.
    let dem = load(dir().join("grey.jpg"), &given).unwrap();
    assert_eq!(dem.heightmap.georef().spacing_m.x, 30.0);
}

#[test]
fn a_first_ifd_offset_of_zero_is_refused_as_such() {
    let mut bytes = std::fs::read(dir().join("wiz_int16.tif")).unwrap();
    bytes[4..8].fill(0);
    let tmp = temp_dir();
    let p = tmp.path().join("no_ifd.tif");
    std::fs::write(&p, &bytes).unwrap();
    let e = load(&p, &LoadOptions::default()).map(|_| ()).unwrap_err().to_string();
    assert!(e.contains("no_ifd.tif") && e.contains("first IFD offset is 0"), "{e}");
}
