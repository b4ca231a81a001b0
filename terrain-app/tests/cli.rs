//! End-to-end tests of the `terrain` binary: `terrain info` on every real DEM in
//! ../shared/data and on the embedded default, and clear errors on bad input.

mod common;

use common::{data, terrain};

fn info_json(args: &[&str]) -> serde_json::Value {
    let mut all = vec!["info", "--json"];
    all.extend_from_slice(args);
    let out = terrain(&all);
    assert!(
        out.status.success(),
        "terrain {all:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("info --json prints JSON")
}

#[test]
fn info_on_the_embedded_default() {
    let out = terrain(&["info"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    for field in ["size", "crs", "spacing (m)", "heights", "voids", "embedded synthetic"] {
        assert!(text.contains(field), "missing `{field}` in:\n{text}");
    }
    let j = info_json(&[]);
    assert!(j["width"].as_u64().unwrap() >= 513);
    assert_eq!(j["voids"], 0);
    assert!(j["max_m"].as_f64().unwrap() > j["min_m"].as_f64().unwrap());
}

#[test]
fn info_on_every_shared_dem() {
    /// file, extra args, width, height, epsg, voids (u64::MAX: not asserted).
    type Case<'a> = (&'a str, &'a [&'a str], u64, u64, Option<u64>, u64);
    let cases: &[Case<'_>] = &[
        ("srtm/mt_rainier_90m.tif", &[], 1201, 1201, Some(4326), 9_033),
        ("srtm/mt_everest_90m.tif", &[], 1201, 1201, Some(4326), 130_953),
        ("srtm/N52E008.hgt", &[], 1201, 1201, Some(4326), 3), // three -32768 samples in the file
        ("lidar_prairie/dem.tif", &[], 400, 400, Some(26915), 0),
        (
            "crater_lake/craterlake-elev-16bit-30m.tif",
            &["--nodata", "-32767"],
            429,
            279,
            Some(4326),
            39_489,
        ),
        ("big_tujunga/bigtujunga.tif", &[], 1197, 643, Some(32611), 0),
        (
            "puget_sound/ps_height_1k.png",
            &["--vertical-scale", "0.1", "--spacing", "160"],
            1025,
            1025,
            None,
            0,
        ),
        (
            "puget_sound/ps_height_4k.jpg",
            &["--vertical-scale", "25.6", "--spacing", "40"],
            4096,
            4096,
            None,
            0,
        ),
    ];
    for (file, extra, w, h, epsg, voids) in cases {
        let path = data(file);
        let mut args = vec![path.to_str().unwrap()];
        args.extend_from_slice(extra);
        let j = info_json(&args);
        assert_eq!(j["width"].as_u64(), Some(*w), "{file}");
        assert_eq!(j["height"].as_u64(), Some(*h), "{file}");
        assert_eq!(j["epsg"].as_u64(), *epsg, "{file}");
        if *voids != u64::MAX {
            assert_eq!(j["voids"].as_u64(), Some(*voids), "{file}");
        }
        let (lo, hi) = (j["min_m"].as_f64().unwrap(), j["max_m"].as_f64().unwrap());
        assert!(lo.is_finite() && hi.is_finite() && hi > lo, "{file}: {lo}..{hi}");
    }
    let ps = info_json(&[
        data("puget_sound/ps_height_1k.png").to_str().unwrap(),
        "--vertical-scale",
        "0.1",
    ]);
    assert!((ps["max_m"].as_f64().unwrap() - 4379.8).abs() < 0.05, "{}", ps["max_m"]);
}

#[test]
fn info_on_a_mosaic_of_two_hgt_tiles() {
    let a = data("srtm/N41E001.hgt");
    let b = data("srtm/N42E001.hgt");
    let j = info_json(&[a.to_str().unwrap(), b.to_str().unwrap()]);
    assert_eq!((j["width"].as_u64(), j["height"].as_u64()), (Some(1201), Some(2401)));
    assert!((j["min_m"].as_f64().unwrap() - -20.0).abs() < 1.0);
    assert!((j["max_m"].as_f64().unwrap() - 3100.0).abs() < 1.0);
}

#[test]
fn bad_input_names_the_file_and_the_problem() {
    let dir = common::scratch("cli", "bad");
    let empty = dir.join("empty.tif");
    std::fs::write(&empty, b"").unwrap();
    let text = dir.join("notes.txt");
    std::fs::write(&text, b"this is not a DEM\n").unwrap();
    let missing = dir.join("missing.hgt");
    for (path, problem) in [(&empty, "empty"), (&text, "format"), (&missing, "No such file")] {
        let out = terrain(&["info", path.to_str().unwrap()]);
        assert!(!out.status.success(), "{} should fail", path.display());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains(path.file_name().unwrap().to_str().unwrap()),
            "error does not name the file: {err}"
        );
        assert!(err.contains(problem), "error does not say `{problem}`: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
    let out = terrain(&["info", "--raw", "10x10:f64", text.to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("i16, u16 or f32"));
}

#[test]
fn roughness_pyramids_export_one_png_per_level() {
    let dir = common::scratch("cli", "rough");
    let ps = data("puget_sound/ps_height_1k.png");
    for method in ["a", "b", "c"] {
        let out = terrain(&[
            "roughness",
            ps.to_str().unwrap(),
            "--vertical-scale",
            "0.1",
            "--spacing",
            "160",
            "--method",
            method,
            "-o",
            dir.to_str().unwrap(),
        ]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        for level in 0..7u32 {
            let img =
                image::open(dir.join(format!("{method}_level{level}.png"))).unwrap().to_luma8();
            assert_eq!(img.dimensions(), (1 << level, 1 << level));
        }
        // Puget Sound has flat water and rough mountains: the finest level is not uniform.
        let fine = image::open(dir.join(format!("{method}_level6.png"))).unwrap().to_luma8();
        let (lo, hi) = fine.pixels().fold((255u8, 0u8), |(a, b), p| (a.min(p[0]), b.max(p[0])));
        assert!(hi > lo + 50, "method {method}: {lo}..{hi}");
    }
}

/// A JPEG whose header declares 65535 x 40000 pixels is refused before the decoder allocates,
/// naming the file, the bytes and `--max-memory`; a real file over a lowered limit too.
#[test]
fn max_memory_refuses_huge_declared_sizes() {
    let dir = common::scratch("cli", "mem");
    let mut bytes = std::fs::read(data("puget_sound/ps_height_4k.jpg")).unwrap();
    // Frame header (SOF0..SOF2): FF C0..C2, length, precision, height, width.
    let at = (0..bytes.len() - 1)
        .find(|&i| bytes[i] == 0xFF && (0xC0..=0xC2).contains(&bytes[i + 1]))
        .expect("a frame header");
    bytes[at + 5..at + 7].copy_from_slice(&40000u16.to_be_bytes());
    bytes[at + 7..at + 9].copy_from_slice(&65535u16.to_be_bytes());
    let huge = dir.join("huge.jpg");
    std::fs::write(&huge, &bytes).unwrap();
    let out = terrain(&["info", huge.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("huge.jpg") && err.contains("--max-memory"), "{err}");
    assert!(err.contains("65535 x 40000"), "{err}");
    // Raising the limit does not help a file too small for what it declares.
    let out = terrain(&["info", "--max-memory", "1TiB", huge.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("huge.jpg") && err.contains("corrupt"), "{err}");

    let png = data("puget_sound/ps_height_1k.png");
    let out = terrain(&["info", "--max-memory", "1MiB", png.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("ps_height_1k.png") && err.contains("1048576"), "{err}");
    let out = terrain(&["info", "--max-memory", "4GB", png.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("GiB"));
}

/// A variant of the GeoTIFF corpus (terrain-core/tests/data/geotiff) and GDAL's values of it.
fn corpus(name: &str) -> (String, serde_json::Value) {
    let dir =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../terrain-core/tests/data/geotiff");
    let all: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("gdal_values.json")).unwrap())
            .unwrap();
    let g = all["variants"].as_array().unwrap().iter().find(|v| v["file"] == name).unwrap().clone();
    (dir.join(name).to_str().unwrap().to_string(), g)
}

#[test]
fn band_reads_one_band_of_a_multi_band_geotiff() {
    let (path, g) = corpus("bands3_pixel.tif");
    for band in ["1", "2", "3"] {
        let j = info_json(&[&path, "--band", band]);
        let want = &g["per_band"][band.parse::<usize>().unwrap() - 1];
        assert_eq!(j["max_m"].as_f64(), want["max"].as_f64(), "band {band}");
        assert_eq!(j["min_m"].as_f64(), want["min"].as_f64(), "band {band}");
    }
    // Band 1 by default, and said.
    let out = terrain(&["info", &path]);
    assert!(out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("3 bands, band 1") && err.contains("--band"), "{err}");
    // A band the file lacks: refused before any work, by every command that reads a DEM.
    let store = std::env::temp_dir().join(format!("terrain-cli-band-{}", std::process::id()));
    for cmd in [
        vec!["info", &path, "--band", "4"],
        vec!["bake", &path, "--band", "4", "-o", store.to_str().unwrap()],
        vec!["mesh", &path, "--band", "4", "--max-error", "1", "--stats"],
    ] {
        let out = terrain(&cmd);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{cmd:?}");
        assert!(err.contains("band 4") && err.contains("3 bands"), "{cmd:?}: {err}");
    }
    assert!(!store.exists());
    for cmd in ["bake", "render", "fly", "bench", "mesh", "info"] {
        let out = terrain(&[cmd, "--help"]);
        assert!(String::from_utf8_lossy(&out.stdout).contains("--band"), "{cmd} --help");
    }
}

#[test]
fn vertical_scale_and_spacing_on_georeferenced_files() {
    let (path, g) = corpus("wiz_int16.tif");
    // Beyond f32: refused, not turned into voids and filled.
    let out = terrain(&["info", &path, "--vertical-scale", "1e36"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("wiz_int16.tif") && err.contains("--vertical-scale"), "{err}");
    // A unit conversion: applied, and said.
    let out = terrain(&["info", "--json", &path, "--vertical-scale", "0.3048"]);
    assert!(out.status.success());
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let want = (g["max"].as_f64().unwrap() * 0.3048) as f32;
    // JSON holds the f32 in its shortest form.
    assert_eq!(j["max_m"].as_f64().map(|v| v as f32), Some(want));
    assert!(String::from_utf8_lossy(&out.stderr).contains("x 0.3048"));
    // --spacing: refused for a GeoTIFF with a georeference and for .hgt.
    let hgt = data("srtm/N52E008.hgt");
    for file in [path.as_str(), hgt.to_str().unwrap()] {
        let out = terrain(&["info", file, "--spacing", "30"]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{file}");
        assert!(err.contains("--spacing") && err.contains("georeference"), "{err}");
    }
}
