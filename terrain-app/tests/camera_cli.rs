//! End-to-end tests of cameras users place (`terrain render --camera/--look-at`, the default
//! framing) on the real DEMs: the default view fills the image with terrain on DEMs of
//! different aspect and format, lon/lat lands where PROJ and the map say on a geographic and a
//! projected DEM, heights above ground and look-at targets, the warnings for cameras that see
//! no terrain or stand under it, and `--vertical-scale` on every reader. Rendering tests print
//! why and pass where no adapter exists, unless `TERRAIN_REQUIRE_GPU` is set.

mod common;

use std::path::PathBuf;
use std::process::Command;

use common::{data, scratch, terrain};

/// The background the tests ask for: `terrain_gpu::BACKGROUND`, which the shader never draws.
const BACKGROUND: [u8; 4] = [255, 0, 255, 255];

/// What one `terrain render` printed, and its image.
struct Rendered {
    image: image::RgbaImage,
    stdout: String,
    stderr: String,
}

impl Rendered {
    /// Share of the image's pixels that show terrain.
    fn coverage(&self) -> f64 {
        let terrain = self.image.pixels().filter(|p| p.0 != BACKGROUND).count();
        terrain as f64 / (self.image.width() * self.image.height()) as f64
    }

    /// The camera position from the `camera:` line.
    fn eye(&self) -> [f64; 3] {
        let line = self.stdout.lines().find(|l| l.starts_with("camera:")).expect("a camera line");
        let v: Vec<f64> = line["camera:".len()..]
            .split_whitespace()
            .next()
            .unwrap()
            .split(',')
            .map(|x| x.parse().unwrap())
            .collect();
        [v[0], v[1], v[2]]
    }
}

/// Runs `terrain render ARGS` at 160 x 90 into a scratch PNG; `None` where no adapter exists
/// and none is required.
fn render(name: &str, args: &[&str]) -> Option<Rendered> {
    let dir = scratch("camera-cli", name);
    let out = dir.join("view.png");
    let output = Command::new(env!("CARGO_BIN_EXE_terrain"))
        .arg("render")
        .args(args)
        .args(["--size", "160x90", "--background", "255,0,255", "-o"])
        .arg(&out)
        .output()
        .expect("the terrain binary runs");
    let stdout = String::from_utf8_lossy(&output.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    if !output.status.success()
        && stderr.contains("no GPU adapter")
        && std::env::var_os("TERRAIN_REQUIRE_GPU").is_none()
    {
        println!("SKIPPED: {stderr}; set TERRAIN_REQUIRE_GPU=1 to make this a failure");
        return None;
    }
    assert!(output.status.success(), "terrain render {args:?} failed:\n{stdout}\n{stderr}");
    let image = image::open(&out).unwrap_or_else(|e| panic!("{}: {e}", out.display())).to_rgba8();
    Some(Rendered { image, stdout, stderr })
}

/// Least share of the image the default framing covers with terrain. Measured at 160 x 90 and
/// 320 x 180 on the DEMs below: 0.89 to 0.91 (the framing aims at 0.9, `FILL_TARGET`); the
/// framing before covered 0.15 to 0.16.
const DEFAULT_COVERAGE: f64 = 0.85;

#[test]
fn the_default_view_fills_the_image_with_terrain() {
    let dems: [(&str, &[&str]); 5] = [
        ("puget_sound/ps_height_1k.png", &["--vertical-scale", "0.1", "--spacing", "160"]),
        ("srtm/mt_rainier_90m.tif", &[]),
        ("srtm/N42E001.hgt", &[]),
        ("big_tujunga/bigtujunga.tif", &[]),
        ("crater_lake/craterlake-elev-16bit-30m.tif", &["--nodata", "-32767"]),
    ];
    for (rel, options) in dems {
        let dem = data(rel);
        let mut args = vec![dem.to_str().unwrap()];
        args.extend_from_slice(options);
        let Some(r) = render("default", &args) else { return };
        let c = r.coverage();
        println!("{rel}: terrain covers {:.1} % of the default view", 100.0 * c);
        assert!(c >= DEFAULT_COVERAGE, "{rel}: the default view shows {:.1} % terrain", 100.0 * c);
        assert!(!r.stderr.contains("sees no terrain"), "{}", r.stderr);
    }
}

/// Mount Rainier's summit is at 46.8529 N, 121.7604 W, 4392 m (USGS); the SRTM 90 m grid
/// holds about 4370 m there. `lonlat:` with `agl` puts the eye over it, on the geographic DEM.
#[test]
fn lonlat_and_agl_place_the_eye_over_a_known_summit() {
    let dem = data("srtm/mt_rainier_90m.tif");
    let args = [dem.to_str().unwrap(), "--camera", "lonlat:-121.7604,46.8529,100agl,0,-30"];
    let Some(r) = render("summit", &args) else { return };
    let z = r.eye()[2];
    assert!((4392.0 + 100.0 - z).abs() < 120.0, "eye at {z} m, not 100 m over the summit");
    // The same place as a world position (the equirectangular frame `terrain info` reports):
    // a look-at target at the summit from 5 km south looks north and down.
    let south = "lonlat:-121.7604,46.8079,3000";
    let Some(r2) = render(
        "look",
        &[dem.to_str().unwrap(), "--camera", south, "--look-at", "lonlat:-121.7604,46.8529"],
    ) else {
        return;
    };
    let line = r2.stdout.lines().find(|l| l.starts_with("camera:")).unwrap();
    let along: Vec<f64> = line
        .split("looking along ")
        .nth(1)
        .unwrap()
        .split_whitespace()
        .next()
        .unwrap()
        .split(',')
        .map(|x| x.parse().unwrap())
        .collect();
    assert!(along[0].abs() < 0.01 && along[1] > 0.9 && along[2] > 0.0, "{line}");
    assert!(r2.coverage() > 0.2, "{:.3}", r2.coverage());
}

/// Big Tujunga is on UTM 11N: its centre (394268.655, 3798272.828) is 118 8'57.22" W,
/// 34 19'13.20" N (GDAL's gdalinfo, from PROJ).
#[test]
fn lonlat_lands_on_a_projected_dem_where_proj_says() {
    let dem = data("big_tujunga/bigtujunga.tif");
    let lon = -(118.0 + 8.0 / 60.0 + 57.22 / 3600.0);
    let lat = 34.0 + 19.0 / 60.0 + 13.20 / 3600.0;
    let camera = format!("lonlat:{lon},{lat},3000,0,-45");
    let Some(r) = render("utm", &[dem.to_str().unwrap(), "--camera", &camera]) else { return };
    let [x, y, z] = r.eye();
    assert!((x - 394_268.655).abs() < 0.5 && (y - 3_798_272.828).abs() < 0.5, "{x}, {y}");
    assert_eq!(z, 3000.0);
}

/// A store keeps its CRS: `lonlat:` and `agl` (on its level-4 overview) work on it, and its
/// default view fills the image too. The lidar tile's centre (429452.313, 5150685.425) on UTM
/// 15N is 93 55'10.23" W, 46 30'21.75" N (gdalinfo).
#[test]
fn cameras_are_placed_on_a_store() {
    let dir = scratch("camera-cli", "store");
    let store = dir.join("lidar.store");
    let dem = data("lidar_prairie/dem.tif");
    let r = terrain(&[
        "bake",
        dem.to_str().unwrap(),
        "--no-pvs",
        "--no-dss",
        "-o",
        store.to_str().unwrap(),
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let s = store.to_str().unwrap();
    let Some(r) = render("store-default", &[s]) else { return };
    assert!(r.coverage() >= DEFAULT_COVERAGE, "{:.3}", r.coverage());
    let lon = -(93.0 + 55.0 / 60.0 + 10.23 / 3600.0);
    let lat = 46.0 + 30.0 / 60.0 + 21.75 / 3600.0;
    let camera = format!("lonlat:{lon},{lat},50agl,0,-60");
    let Some(r) = render("store-lonlat", &[s, "--camera", &camera]) else { return };
    let [x, y, z] = r.eye();
    assert!((x - 429_452.313).abs() < 0.5 && (y - 5_150_685.425).abs() < 0.5, "{x}, {y}");
    // The tile's heights are 379.7 to 410.8 m.
    assert!((379.7 + 50.0..=410.8 + 50.0).contains(&z), "{z}");
    assert!(r.coverage() > 0.5, "{:.3}", r.coverage());
}

#[test]
fn lonlat_without_a_crs_is_refused_by_name() {
    let dem = data("puget_sound/ps_height_1k.png");
    let scratch_dir = scratch("camera-cli", "nocrs");
    let out = scratch_dir.join("never.png");
    let r = terrain(&[
        "render",
        dem.to_str().unwrap(),
        "--spacing",
        "160",
        "--camera",
        "lonlat:-122,47,3000,0,-30",
        "-o",
        out.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success(), "{stderr}");
    assert!(
        stderr.contains("lonlat") && stderr.contains("no coordinate reference system"),
        "{stderr}"
    );
    assert!(!out.exists());
}

/// Cameras that see no terrain write their image, exit 0, and say why on stderr naming
/// `--camera`; an eye under the ground is lifted above it, with a warning.
#[test]
fn cameras_that_see_no_terrain_are_warned_about() {
    let dem = data("lidar_prairie/dem.tif");
    let dem = dem.to_str().unwrap();
    // The tile spans 429252-429652 E, 5150485-5150885 N, 380-411 m.
    for (name, camera, said) in [
        ("far", "429452,-5000000,400,0,0", "km away"),
        ("behind", "429452,5150000,500,180,-20", "behind"),
        ("sky", "429452,5150000,500,0,30", "misses the terrain"),
    ] {
        let Some(r) = render(name, &[dem, "--camera", camera]) else { return };
        assert!(
            r.stderr.contains("sees no terrain") && r.stderr.contains(said),
            "{name}: {}",
            r.stderr
        );
        assert!(r.stderr.contains("--camera"), "{}", r.stderr);
        assert_eq!(r.coverage(), 0.0, "{name}");
    }
    let Some(r) = render("under", &[dem, "--camera", "429452,5150685,0,0,-10"]) else { return };
    assert!(r.stderr.contains("under the ground") && r.stderr.contains("--camera"), "{}", r.stderr);
    assert!(r.eye()[2] > 379.0, "{:?}", r.eye());
    assert!(!r.stderr.contains("sees no terrain"), "{}", r.stderr);
}

/// A flight whose frames look at the sky draws them and says so once, naming the frames.
#[test]
fn a_flight_that_sees_no_terrain_is_warned_about() {
    let dir = scratch("camera-cli", "fly");
    let flight = dir.join("up.json");
    std::fs::write(
        &flight,
        r#"{"name": "up", "fps": 2, "height_above": "ground", "keyframes": [
            {"t": 0, "relative": [0.2, 0.5, 0.3], "yaw": 90, "pitch": 60},
            {"t": 1, "relative": [0.8, 0.5, 0.3], "yaw": 90, "pitch": 60}]}"#,
    )
    .unwrap();
    let dem = data("lidar_prairie/dem.tif");
    let out = dir.join("frames");
    let r = terrain(&[
        "fly",
        dem.to_str().unwrap(),
        "--flight",
        flight.to_str().unwrap(),
        "--size",
        "64x36",
        "-o",
        out.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&r.stderr);
    if !r.status.success()
        && stderr.contains("no GPU adapter")
        && std::env::var_os("TERRAIN_REQUIRE_GPU").is_none()
    {
        println!("SKIPPED: {stderr}; set TERRAIN_REQUIRE_GPU=1 to make this a failure");
        return;
    }
    assert!(r.status.success(), "{stderr}");
    assert!(stderr.contains("flight up: 2 of 2 drawn frames see no terrain"), "{stderr}");
    assert!(stderr.contains("misses the terrain") && stderr.contains("keyframes"), "{stderr}");
}

/// `info --json`'s height range with and without `--vertical-scale 3`.
fn heights(file: &str, extra: &[&str], scale: &str) -> (f64, f64) {
    let mut args = vec!["info", "--json", file, "--vertical-scale", scale];
    args.extend_from_slice(extra);
    let r = terrain(&args);
    assert!(r.status.success(), "{args:?}: {}", String::from_utf8_lossy(&r.stderr));
    let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    (v["min_m"].as_f64().unwrap(), v["max_m"].as_f64().unwrap())
}

/// `--vertical-scale` multiplies the heights of every reader: GeoTIFF, .hgt, grey PNG, raw
/// (and scattered points, in `mesh --points`) and a baked store (exaggerated as read).
#[test]
fn vertical_scale_applies_to_every_reader() {
    let dir = scratch("camera-cli", "vscale");
    let raw = dir.join("g.raw");
    let samples: Vec<u8> = (0..16i16).flat_map(|v| (v * 10).to_le_bytes()).collect();
    std::fs::write(&raw, samples).unwrap();
    let cases: Vec<(PathBuf, Vec<&str>)> = vec![
        (data("lidar_prairie/dem.tif"), vec![]),
        (data("srtm/N52E008.hgt"), vec![]),
        (data("puget_sound/ps_height_1k.png"), vec!["--spacing", "160"]),
        (raw.clone(), vec!["--raw", "4x4:i16"]),
    ];
    for (file, extra) in &cases {
        let f = file.to_str().unwrap();
        let (lo1, hi1) = heights(f, extra, "1");
        let (lo3, hi3) = heights(f, extra, "3");
        assert!(hi1 > lo1, "{f}");
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-3 * b.abs().max(1.0);
        assert!(
            close(lo3, 3.0 * lo1) && close(hi3, 3.0 * hi1),
            "{f}: {lo1}..{hi1} -> {lo3}..{hi3}"
        );
    }
    // Scattered points: the mesh's vertices carry the scaled heights.
    let pts = dir.join("p.xyz");
    let text: String = (0..25).map(|k| format!("{} {} {}\n", k % 5 * 10, k / 5 * 10, k)).collect();
    std::fs::write(&pts, text).unwrap();
    let mesh_z = |scale: &str| {
        let obj = dir.join(format!("m{scale}.obj"));
        let r = terrain(&[
            "mesh",
            "--entropy",
            "1",
            "--depth",
            "2",
            "--points",
            pts.to_str().unwrap(),
            "--vertical-scale",
            scale,
            "-o",
            obj.to_str().unwrap(),
        ]);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        let text = std::fs::read_to_string(&obj).unwrap();
        // Vertices are written relative to the `# origin` line's point.
        let origin_z: f64 = text
            .lines()
            .find_map(|l| l.strip_prefix("# origin "))
            .map(|l| l.split_whitespace().nth(2).unwrap().parse().unwrap())
            .expect("an origin line");
        text.lines()
            .filter_map(|l| l.strip_prefix("v "))
            .map(|l| l.split_whitespace().nth(2).unwrap().parse::<f64>().unwrap() + origin_z)
            .fold(f64::NEG_INFINITY, f64::max)
    };
    let (z1, z3) = (mesh_z("1"), mesh_z("3"));
    assert!(z1 > 0.0 && (z3 - 3.0 * z1).abs() < 1e-3 * z3.abs(), "{z1} -> {z3}");
    // A store's heights are baked: --vertical-scale is refused with how to bake again.
    let store = dir.join("s");
    let baked = terrain(&[
        "bake",
        "--synthetic",
        "65",
        "--block-k",
        "5",
        "--no-pvs",
        "--no-dss",
        "-o",
        store.to_str().unwrap(),
    ]);
    assert!(baked.status.success(), "{}", String::from_utf8_lossy(&baked.stderr));
    // A store's --vertical-scale exaggerates it as it is read; not a positive number, and a
    // --vertical-offset (a unit conversion), are refused, the latter saying to bake again.
    let png = dir.join("s.png");
    let render_store = |opts: &[&str]| {
        let mut args = vec!["render", store.to_str().unwrap(), "--size", "64x36"];
        args.extend_from_slice(opts);
        args.extend_from_slice(&["-o", png.to_str().unwrap()]);
        terrain(&args)
    };
    let r = render_store(&["--vertical-scale", "3"]);
    let stdout = String::from_utf8_lossy(&r.stdout);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(stdout.contains("heights exaggerated x3"), "{stdout}");
    let r = render_store(&["--vertical-scale", "-3"]);
    let stderr = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success() && stderr.contains("positive number"), "{stderr}");
    let r = render_store(&["--vertical-offset", "5"]);
    let stderr = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success() && stderr.contains("--vertical-offset"), "{stderr}");
    assert!(stderr.contains("bake it again") && stderr.contains("terrain bake"), "{stderr}");
}
