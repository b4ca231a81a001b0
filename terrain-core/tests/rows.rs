//! `dem::RowReader` against `dem::load` on the real GeoTIFFs: the same samples, the same voids,
//! band by band; void filling that does not depend on the band boundaries; raw files; errors.

mod common;

use common::data;

use terrain_core::dem::{LoadOptions, RawSampleType, RawSpec, RowReader, load};

/// Reads `rows` rows from `j0` through the reader.
fn band(r: &RowReader, j0: u64, rows: usize) -> (Vec<f32>, Vec<bool>) {
    let n = r.width() as usize * rows;
    let (mut h, mut v) = (vec![0f32; n], vec![false; n]);
    r.read_rows(j0, rows, &mut h, &mut v).unwrap_or_else(|e| panic!("{e}"));
    (h, v)
}

/// Every real GeoTIFF, read in uneven bands, equals the whole-file reader at every valid sample,
/// with the same void mask and the same georeference; filled voids are finite.
#[test]
fn bands_equal_whole_file_on_real_geotiffs() {
    for (file, nodata) in [
        ("srtm/mt_rainier_90m.tif", None),
        ("srtm/mt_everest_90m.tif", None),
        ("crater_lake/craterlake-elev-16bit-30m.tif", Some(-32767.0)),
        ("big_tujunga/bigtujunga.tif", None),
        ("lidar_prairie/dem.tif", None),
    ] {
        let options = LoadOptions { nodata, ..Default::default() };
        let path = data(file);
        let dem = load(&path, &options).unwrap();
        let hm = &dem.heightmap;
        let r = RowReader::open(&path, &options).unwrap();
        assert_eq!((r.width() as usize, r.height() as usize), (hm.width(), hm.height()), "{file}");
        assert_eq!(r.georef(), hm.georef(), "{file}");
        assert_eq!(r.source().sample_type, dem.source.sample_type, "{file}");
        assert_eq!(r.source().nodata, dem.source.nodata, "{file}");
        let w = hm.width();
        let mut j0 = 0usize;
        let mut step = 1usize;
        let (mut voids, mut checked) = (0usize, 0usize);
        while j0 < hm.height() {
            let rows = step.min(hm.height() - j0);
            let (h, v) = band(&r, j0 as u64, rows);
            let mut only = vec![false; v.len()];
            r.read_void_rows(j0 as u64, rows, &mut only).unwrap();
            assert_eq!(only, v, "{file} void rows {j0}..+{rows}");
            for k in 0..rows {
                for i in 0..w {
                    let (j, idx) = (j0 + k, k * w + i);
                    assert_eq!(v[idx], hm.voids().get(i, j), "{file} void flag at ({i}, {j})");
                    assert!(h[idx].is_finite(), "{file} ({i}, {j})");
                    if v[idx] {
                        voids += 1;
                    } else {
                        assert_eq!(h[idx], hm.get(i, j), "{file} ({i}, {j})");
                        checked += 1;
                    }
                }
            }
            j0 += rows;
            step = step * 3 + 7; // 1, 10, 37, 118, ...: bands of many sizes
        }
        assert_eq!(voids, hm.voids().count(), "{file}");
        assert!(checked > 0, "{file}");
    }
}

/// Two bands that share rows fill their voids identically there (blocks share border rows,
/// so a fill that depended on the band would open cracks between blocks).
#[test]
fn void_fill_does_not_depend_on_the_band() {
    let path = data("srtm/mt_everest_90m.tif");
    let r = RowReader::open(&path, &LoadOptions::default()).unwrap();
    let w = r.width() as usize;
    let (a, va) = band(&r, 300, 257);
    let (b, _) = band(&r, 556, 257);
    let (c, _) = band(&r, 500, 20);
    // Row 556 is the last of `a` and the first of `b`; rows 500..520 are inside `a`.
    assert_eq!(&a[256 * w..257 * w], &b[..w]);
    assert_eq!(&a[200 * w..220 * w], &c[..]);
    assert!(va.iter().any(|&v| v), "the test needs voids in the band");
    assert_eq!(r.zero_filled(), 0, "Everest's voids all have valid samples within reach");
}

/// A filled void lies within the range of the valid samples around it (IDW is a convex mean).
#[test]
fn filled_voids_are_convex_means_of_their_neighbours() {
    let w = 9u64;
    let h = 5u64;
    // Row-major, north first, f32 LE; -9999 = no-data.
    let mut vals = vec![100f32; (w * h) as usize];
    vals[2 * 9 + 4] = -9999.0; // a single void in the middle row
    vals[..9].fill(-9999.0); // the whole north row is void
    vals[4 * 9 + 8] = 300.0;
    let bytes: Vec<u8> = vals.iter().flat_map(|v| v.to_le_bytes()).collect();
    let tmp = common::temp_dir("terrain-rows-");
    let p = tmp.path().join("fill.f32");
    std::fs::write(&p, bytes).unwrap();
    let options = LoadOptions {
        raw: Some(RawSpec { width: w, height: h, sample: RawSampleType::F32 }),
        nodata: Some(-9999.0),
        spacing_m: 10.0,
        ..Default::default()
    };
    let r = RowReader::open(&p, &options).unwrap();
    let (hs, vs) = band(&r, 0, h as usize);
    // South-first: file row 2 is row 2; the north row (file row 0) is row 4.
    assert!(vs[2 * 9 + 4]);
    assert_eq!(hs[2 * 9 + 4], 100.0, "every neighbour is 100 m");
    for i in 0..9 {
        assert!(vs[4 * 9 + i]);
        // The column below is valid: 100 m (the 300 m sample is in the south row, column 8,
        // further than the column's first valid sample).
        assert_eq!(hs[4 * 9 + i], 100.0, "column {i}");
    }
    assert_eq!(hs[8], 300.0);
    std::fs::remove_file(&p).ok();
}

/// A raw float32 file equals `load` on it, in bands; a wrong length and a PNG are clear errors
/// naming the file.
#[test]
fn raw_bands_and_errors() {
    let (w, h) = (37u64, 23u64);
    let vals: Vec<f32> = (0..w * h).map(|k| (k as f32 * 0.37).sin() * 50.0 + 200.0).collect();
    let bytes: Vec<u8> = vals.iter().flat_map(|v| v.to_le_bytes()).collect();
    let tmp = common::temp_dir("terrain-rows-");
    let p = tmp.path().join("grid.f32");
    std::fs::write(&p, &bytes).unwrap();
    let options = LoadOptions {
        raw: Some(RawSpec { width: w, height: h, sample: RawSampleType::F32 }),
        ..Default::default()
    };
    let hm = load(&p, &options).unwrap().heightmap;
    let r = RowReader::open(&p, &options).unwrap();
    for (j0, rows) in [(0u64, 23usize), (5, 7), (22, 1)] {
        let (hs, _) = band(&r, j0, rows);
        for k in 0..rows {
            for i in 0..w as usize {
                assert_eq!(hs[k * w as usize + i], hm.get(i, j0 as usize + k));
            }
        }
    }
    // Out of range.
    let mut hs = vec![0f32; w as usize * 2];
    let mut vs = vec![false; w as usize * 2];
    let e = r.read_rows(22, 2, &mut hs, &mut vs).unwrap_err().to_string();
    assert!(e.contains("grid.f32") && e.contains("do not fit"), "{e}");
    // Wrong length.
    std::fs::write(&p, &bytes[..bytes.len() - 4]).unwrap();
    let e = RowReader::open(&p, &options).unwrap_err().to_string();
    assert!(e.contains("grid.f32") && e.contains("exactly"), "{e}");
    std::fs::remove_file(&p).ok();
    // A PNG is read whole, not by rows.
    let e = RowReader::open(data("puget_sound/ps_height_1k.png"), &LoadOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("ps_height_1k.png") && e.contains("streamed"), "{e}");
}
