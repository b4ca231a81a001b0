//! End-to-end tests of `terrain render`: the embedded default terrain (Vulkan or whatever
//! `TERRAIN_GPU_BACKEND` picks, and GL explicitly) and the lidar prairie GeoTIFF at UTM
//! coordinates with the default camera. Where no adapter exists the tests print why and pass,
//! unless `TERRAIN_REQUIRE_GPU` is set: then they fail.

mod common;

use std::process::Command;

use common::data;

/// The background colour the tests ask for (`--background`): `terrain_gpu::BACKGROUND`, which
/// the shader never produces.
const BACKGROUND: [u8; 4] = [255, 0, 255, 255];

/// Runs `terrain render ARGS -o <tmp>/NAME.png` (with `TERRAIN_GPU_BACKEND=backend` when
/// given) and returns the image and stdout, or `None` when no adapter exists and none is required.
fn render(name: &str, backend: Option<&str>, args: &[&str]) -> Option<(image::RgbaImage, String)> {
    let dir = common::scratch("render-cli", name);
    let out = dir.join(format!("{name}.png"));
    let _ = std::fs::remove_file(&out);
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_terrain"));
    cmd.arg("render").args(args).args(["--background", "255,0,255"]).arg("-o").arg(&out);
    if let Some(b) = backend {
        cmd.env("TERRAIN_GPU_BACKEND", b);
    }
    let output = cmd.output().expect("the terrain binary runs");
    let stdout = String::from_utf8_lossy(&output.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&output.stderr);
    if !output.status.success()
        && stderr.contains("no GPU adapter")
        && std::env::var_os("TERRAIN_REQUIRE_GPU").is_none()
    {
        println!("SKIPPED: {stderr}; set TERRAIN_REQUIRE_GPU=1 to make this a failure");
        return None;
    }
    assert!(output.status.success(), "terrain render {args:?} failed:\n{stdout}\n{stderr}");
    println!("{stdout}");
    for field in ["adapter:", "patches", "triangles", "vertices", "CPU", "GPU", "wrote"] {
        assert!(stdout.contains(field), "missing `{field}` in:\n{stdout}");
    }
    let image = image::open(&out).unwrap_or_else(|e| panic!("{}: {e}", out.display())).to_rgba8();
    let _ = std::fs::remove_file(&out);
    Some((image, stdout))
}

fn assert_terrain_drawn(image: &image::RgbaImage, size: (u32, u32)) {
    assert_eq!(image.dimensions(), size);
    let terrain = image.pixels().filter(|p| p.0 != BACKGROUND).count();
    let total = (size.0 * size.1) as usize;
    println!("{terrain} of {total} pixels show terrain");
    assert!(terrain * 10 > total, "the terrain covers only {terrain} of {total} pixels");
}

#[test]
fn render_the_default_terrain() {
    let args = ["--size", "96x54", "--method", "uniform", "--leaf-cells", "64", "--factor", "8"];
    let Some((image, stdout)) = render("default", None, &args) else { return };
    assert_terrain_drawn(&image, (96, 54));
    // The view direction as plain numbers, not a library type's debug form.
    let camera = stdout.lines().find(|l| l.starts_with("camera:")).expect("a camera line");
    assert!(camera.contains("looking along") && !camera.contains("DVec3"), "{camera}");
}

#[test]
fn render_the_default_terrain_on_gl_with_wireframe() {
    let args = [
        "--size",
        "80x60",
        "--method",
        "uniform",
        "--leaf-cells",
        "64",
        "--factor",
        "6",
        "--wireframe",
    ];
    let Some((image, stdout)) = render("default_gl", Some("gl"), &args) else { return };
    assert!(stdout.contains("adapter:") && stdout.contains("Gl"), "not on GL:\n{stdout}");
    assert_terrain_drawn(&image, (80, 60));
}

#[test]
fn render_the_lidar_prairie_at_utm_coordinates() {
    let dem = data("lidar_prairie/dem.tif");
    let args = [dem.to_str().unwrap(), "--size", "120x80", "--leaf-cells", "16"];
    let Some((image, stdout)) = render("lidar", None, &args) else { return };
    // The default camera stands south of the tile's centre, at UTM 15N coordinates.
    let camera = stdout.lines().find(|l| l.starts_with("camera:")).expect("a camera line");
    let easting: f64 = camera["camera:".len()..].trim().split(',').next().unwrap().parse().unwrap();
    assert!((420_000.0..440_000.0).contains(&easting), "{camera}");
    assert_terrain_drawn(&image, (120, 80));
}

#[test]
fn bad_arguments_are_reported() {
    for (args, needle) in [
        (&["--size", "10"][..], "--size"),
        (&["--camera", "1,2,3"][..], "--camera"),
        (&["--factor", "0"][..], "--factor"),
        (&["--method", "nope"][..], "--method"),
        (&["--background", "1,2"][..], "--background"),
    ] {
        let output = Command::new(env!("CARGO_BIN_EXE_terrain"))
            .arg("render")
            .args(args)
            .args(["-o", "/nonexistent/never-written.png"])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success() && stderr.contains(needle), "{args:?}: {stderr}");
    }
}

/// Options a mode would ignore are refused, each named with where it applies: the store
/// options with a DEM (here the embedded terrain), `--scene` with a store, `--frames` with
/// `--flight`, `--max-frames` without it, `--factor` without `--method uniform`.
#[test]
fn options_a_mode_ignores_are_refused() {
    let dir = common::scratch("render", "ignored");
    let store = dir.join("s");
    let baked = Command::new(env!("CARGO_BIN_EXE_terrain"))
        .args(["bake", "--synthetic", "65", "--block-k", "5", "--no-pvs", "--no-dss", "-o"])
        .arg(&store)
        .output()
        .unwrap();
    assert!(baked.status.success(), "{}", String::from_utf8_lossy(&baked.stderr));
    let flight = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../flights/pvps_884.json");
    let (store, flight) = (store.to_str().unwrap(), flight.to_str().unwrap());
    let image = dir.join("never.png");
    for (args, needles) in [
        (&["--tau", "3"][..], &["--tau", "store"][..]),
        (&["--cache-mib", "64"], &["--cache-mib", "store"]),
        (&["--page-capacity", "8"], &["--page-capacity", "store"]),
        (&["--page-mib", "8"], &["--page-mib", "store"]),
        (&["--flight", flight], &["--flight", "store"]),
        (&["--wait"], &["--wait", "store"]),
        (&["--max-frames", "3"], &["--max-frames", "store"]),
        (&["--tau", "3", "--wait"], &["--tau, --wait apply", "store"]),
        (&[store, "--scene", store], &["--scene applies to a DEM"]),
        (&[store, "--flight", flight, "--frames", "2"], &["--frames", "--flight"]),
        (&[store, "--max-frames", "2"], &["--max-frames", "--flight"]),
        (&["--factor", "8"], &["--factor", "--method uniform"]),
        (
            &["--method", "uniform", "--scene", store],
            &["--scene is read by", "uniform reads nothing"],
        ),
        (&[store, "--method", "ooc", "--factor", "8"], &["--factor", "--method uniform"]),
    ] {
        let output = Command::new(env!("CARGO_BIN_EXE_terrain"))
            .arg("render")
            .args(args)
            .arg("-o")
            .arg(&image)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success(), "{args:?} was accepted: {stderr}");
        assert!(needles.iter().all(|n| stderr.contains(n)), "{args:?}: {stderr}");
        assert!(!image.exists());
    }
}

#[test]
fn every_lod_method_renders_and_reports_json_stats() {
    let dir = common::scratch("render", "methods");
    let mut triangles = Vec::new();
    for method in
        ["uniform", "pvps-a", "pvps-b", "pvps-c", "dss-1", "dss-2", "dss-strips", "entropy"]
    {
        let json = dir.join(format!("{method}.json"));
        let args = [
            "--size",
            "96x54",
            "--method",
            method,
            "--frames",
            "2",
            "--stats-json",
            json.to_str().unwrap(),
        ];
        let Some((image, stdout)) = render(method, None, &args) else { return };
        assert!(stdout.contains(&format!("method {method}")), "{stdout}");
        assert_terrain_drawn(&image, (96, 54));
        let stats: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
        let frames = stats["frames"].as_array().unwrap();
        assert_eq!(frames.len(), 2);
        for f in frames {
            assert_eq!(f["method"], method);
            assert!(f["patches"].as_u64().unwrap() > 0 && f["triangles"].as_u64().unwrap() > 0);
            assert!(
                f["selection_ms"].as_f64().unwrap() >= 0.0 && f["wall_ms"].as_f64().unwrap() > 0.0
            );
        }
        assert!(
            stats["adapter"].as_str().unwrap().contains("llvmpipe") || !stats["adapter"].is_null()
        );
        triangles.push((method, frames[0]["triangles"].as_u64().unwrap()));
    }
    // The view-dependent methods do not all draw what the fixed-factor baseline draws.
    let uniform = triangles[0].1;
    assert!(triangles[1..].iter().any(|&(_, t)| t != uniform), "{triangles:?}");
}

/// `-o` is checked before any rendering (an extension we cannot write, a folder that does not
/// exist: no adapter is even opened), and `-o x.jpg` writes a JPEG in RGB (issue 15: RGBA into
/// JPEG failed after the rendering).
#[test]
fn render_checks_its_output_first_and_writes_jpeg() {
    let dir = common::scratch("render", "out");
    let run = |out: &std::path::Path| {
        Command::new(env!("CARGO_BIN_EXE_terrain"))
            .args(["render", "--size", "48x27", "--method", "uniform", "--leaf-cells", "64"])
            .arg("-o")
            .arg(out)
            .output()
            .expect("the terrain binary runs")
    };
    for (out, said) in [
        (dir.join("frame.bmp"), ".png or .jpg"),
        (dir.join("no-such-folder/frame.png"), "cannot write"),
        (dir.to_path_buf(), "is a folder"),
    ] {
        let r = run(&out);
        let (stdout, stderr) =
            (String::from_utf8_lossy(&r.stdout), String::from_utf8_lossy(&r.stderr));
        assert!(!r.status.success(), "{} was accepted", out.display());
        assert!(stderr.contains(out.to_str().unwrap()) && stderr.contains(said), "{stderr}");
        assert!(!stdout.contains("adapter:"), "checked only after opening the GPU: {stdout}");
    }
    let jpg = dir.join("frame.jpg");
    let r = run(&jpg);
    let stderr = String::from_utf8_lossy(&r.stderr);
    if !r.status.success()
        && stderr.contains("no GPU adapter")
        && std::env::var_os("TERRAIN_REQUIRE_GPU").is_none()
    {
        println!("SKIPPED: {stderr}; set TERRAIN_REQUIRE_GPU=1 to make this a failure");
        return;
    }
    assert!(r.status.success(), "{stderr}");
    let bytes = std::fs::read(&jpg).unwrap();
    assert_eq!(image::guess_format(&bytes).unwrap(), image::ImageFormat::Jpeg);
    let img = image::load_from_memory(&bytes).unwrap();
    assert_eq!(img.color(), image::ColorType::Rgb8);
    assert_eq!((img.width(), img.height()), (48, 27));
}

/// The band of `pixel` in the LOD palette: the entry whose colour, scaled by the light, it is
/// (channels over their largest, within 0.06), or `None`.
fn lod_band_of(pixel: &image::Rgba<u8>) -> Option<usize> {
    use terrain_gpu::render::LOD_PALETTE;
    let [r, g, b, _] = pixel.0.map(f32::from);
    let top = r.max(g).max(b);
    if top < 60.0 {
        return None;
    }
    LOD_PALETTE.iter().position(|(c, _)| {
        let m = c[0].max(c[1]).max(c[2]);
        [r, g, b].iter().zip(c).all(|(p, q)| (p / top - q / m).abs() < 0.06)
    })
}

/// `render --method geomorph --lod-colours`: geomorph's patches are drawn in the LOD palette
/// (their level's colour, lit), more than one level shows, and without the option (the
/// materials) almost no pixel is a palette colour.
#[test]
fn geomorph_draws_lod_colours() {
    let args = ["--size", "160x90", "--method", "geomorph"];
    let Some((plain, _)) = render("geomorph-plain", None, &args) else { return };
    let Some((lod, _)) = render("geomorph-lod", None, &[&args[..], &["--lod-colours"]].concat())
    else {
        return;
    };
    assert_terrain_drawn(&lod, (160, 90));
    let terrain: Vec<_> = lod.pixels().filter(|p| p.0 != BACKGROUND).collect();
    let bands: Vec<Option<usize>> = terrain.iter().map(|p| lod_band_of(p)).collect();
    let in_palette = bands.iter().filter(|b| b.is_some()).count();
    let mut seen: Vec<usize> = bands.iter().flatten().copied().collect();
    seen.sort_unstable();
    seen.dedup();
    let plain_in = plain.pixels().filter(|p| p.0 != BACKGROUND && lod_band_of(p).is_some()).count();
    println!(
        "LOD colours: {in_palette} of {} terrain pixels in the palette, bands {seen:?}; \
         plain: {plain_in}",
        terrain.len()
    );
    // Pixels in the lightmap's shadows (too dark to classify) and on edges between patches of
    // two bands are not counted: about a fifth of them at this size.
    assert!(in_palette as f64 > 0.7 * terrain.len() as f64, "{in_palette} of {}", terrain.len());
    assert!(seen.len() >= 2, "one level only: {seen:?}");
    assert!((plain_in as f64) < 0.1 * terrain.len() as f64, "plain: {plain_in}");
}
