//! `terrain view` in a real window: the test starts its own X server (Xvfb on a display it picks,
//! killed at the end even when an assertion fails), drives the viewer with a script (moves, a
//! method switch, a quality change, screenshots read back from the window's surface), and
//! compares the screenshot with `terrain render` of the same camera and method within the
//! golden-image tolerance (terrain-gpu `render::tests::golden`: per-channel mean < 2, fewer
//! than 1 % of pixels off by more than 16). A second run over a small baked store quits
//! mid-stream and must exit 0 within a bounded time with its workers joined, its per-frame log
//! (`--stats-json`) showing no frame that waited for I/O. With
//! `TERRAIN_REQUIRE_GPU=1` a missing Xvfb or adapter fails instead of skipping.

mod common;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::{scratch, terrain};

fn require() -> bool {
    std::env::var_os("TERRAIN_REQUIRE_GPU").is_some_and(|v| v != "0")
}

/// An Xvfb server on a display of its own; killed on drop.
struct Xvfb {
    child: Child,
    display: String,
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts Xvfb on a display it picks itself (`-displayfd 1`: the server takes the first
/// display whose lock file it can create, and writes the number to its stdout once it accepts
/// connections), so that tests running at once, in this process or another, never share one;
/// `None` when there is no Xvfb binary (a failure under `TERRAIN_REQUIRE_GPU`). Choosing the
/// display here by its lock file, as before, raced: two servers started for one display, the
/// loser's exit came later than the check under load, and the winner's test then killed the
/// server under the other test's window (CI, 2026-12-07: winit's "Connection(IoError(..))" in
/// `a_store_is_exaggerated_and_a_paced_flight_keeps_its_clock`).
fn start_xvfb() -> Option<Xvfb> {
    let found =
        Command::new("Xvfb").arg("-help").stderr(Stdio::null()).stdout(Stdio::null()).status();
    if found.is_err() {
        assert!(!require(), "Xvfb is not installed (apt-get install xvfb; .ci/run does)");
        eprintln!("skipping: no Xvfb");
        return None;
    }
    let mut child = Command::new("Xvfb")
        .args(["-displayfd", "1", "-screen", "0", "1280x800x24", "-nolisten", "tcp"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("Xvfb starts");
    let stdout = child.stdout.take().expect("Xvfb's stdout is piped");
    // Killed on drop from here on, whatever happens.
    let mut x = Xvfb { child, display: String::new() };
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut lines = BufReader::new(stdout).lines();
        let _ = tx.send(lines.next());
        // Read to the end: the pipe stays open for as long as the server runs.
        lines.for_each(drop);
    });
    let line = match rx.recv_timeout(Duration::from_secs(60)) {
        Ok(Some(Ok(line))) => line,
        other => panic!("Xvfb reported no display within 60 s: {other:?}"),
    };
    let n: u32 = line.trim().parse().unwrap_or_else(|_| panic!("Xvfb's display: {line:?}"));
    x.display = format!(":{n}");
    Some(x)
}

/// Runs `terrain view ARGS` on `display` (Vulkan: lavapipe here), waiting at most `limit`;
/// returns (exit ok, stdout, stderr). A hang is a failure, and the process is killed.
fn view(display: &str, cwd: &Path, args: &[&str], limit: Duration) -> (bool, String, String) {
    // The output files live in the calling test's own folder: tests run in parallel threads of
    // one process, so a name from the process id alone would be shared.
    let (out_path, err_path) = (cwd.join("view.out"), cwd.join("view.err"));
    let mut child = Command::new(env!("CARGO_BIN_EXE_terrain"))
        .arg("view")
        .args(args)
        .current_dir(cwd)
        .env("DISPLAY", display)
        .env("TERRAIN_GPU_BACKEND", "vulkan")
        .env_remove("WAYLAND_DISPLAY")
        .stdout(std::fs::File::create(&out_path).unwrap())
        .stderr(std::fs::File::create(&err_path).unwrap())
        .spawn()
        .expect("terrain view starts");
    let t = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break Some(s);
        }
        if t.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let out = std::fs::read_to_string(&out_path).unwrap_or_default();
    let err = std::fs::read_to_string(&err_path).unwrap_or_default();
    let _ = std::fs::remove_file(&out_path);
    let _ = std::fs::remove_file(&err_path);
    let Some(status) = status else {
        panic!("terrain view {args:?} did not exit within {limit:?}\n{out}\n{err}");
    };
    (status.success(), out, err)
}

/// Whether the viewer failed for want of an adapter (a skip unless required).
fn no_adapter(err: &str) -> bool {
    err.contains("no GPU adapter")
}

fn load(path: &Path) -> image::RgbaImage {
    image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).to_rgba8()
}

/// Per-channel mean |difference| and the fraction of pixels off by more than 16 levels.
fn golden_diff(a: &image::RgbaImage, b: &image::RgbaImage) -> ([f64; 3], f64) {
    assert_eq!(a.dimensions(), b.dimensions());
    let d = terrain_gpu::target::image_diff(a.pixels().map(|p| p.0), b.pixels().map(|p| p.0));
    (d.mean, d.far_off)
}

/// The field after `key ` in a `view: screenshot ...` line.
fn field<'a>(line: &'a str, key: &str) -> &'a str {
    let rest = &line[line.find(&format!(" {key} ")).unwrap_or_else(|| panic!("{key}: {line}"))..];
    rest.split_whitespace().nth(1).unwrap()
}

/// Where the scripted camera starts: over the embedded terrain, looking north-east and down.
const START: &str = "1500,1500,2600,45,-25";

/// The window's surface, read back after scripted moves, a method switch and a quality
/// change, equals `terrain render` of the same camera, method and parameter within the golden
/// tolerance; the panel draws over the terrain when shown.
#[test]
fn the_window_shows_what_render_draws_for_the_same_camera() {
    let Some(x) = start_xvfb() else { return };
    let dir = scratch("view", "window");
    let (panel, shot, lod) = (dir.join("panel.png"), dir.join("view.png"), dir.join("lod.png"));
    let script = dir.join("script.txt");
    std::fs::write(
        &script,
        format!(
            "camera {START}\nrecord\nwait 2\nkey down W\nwait 30\nkey up W\nmouse 40 12\nkey down D\nwait 4\nkey up D\n\
             wheel 1\nkey down E\nwait 3\nkey up E\nrecord\n\
             method uniform\nquality 3\nwait 2\nscreenshot {}\npanel off\nwait 1\n\
             screenshot {}\ncolour-levels on\nwait 1\nscreenshot {}\nquit\n",
            panel.display(),
            shot.display(),
            lod.display()
        ),
    )
    .unwrap();
    let flight = dir.join("recorded.json");
    let view_json = dir.join("view.json");
    let args = [
        "--size",
        "320x180",
        "--script",
        script.to_str().unwrap(),
        "--record-to",
        flight.to_str().unwrap(),
        "--stats-json",
        view_json.to_str().unwrap(),
    ];
    let (ok, out, err) = view(&x.display, &dir, &args, Duration::from_secs(300));
    if !ok && no_adapter(&err) && !require() {
        eprintln!("skipping: {err}");
        return;
    }
    assert!(ok, "terrain view failed:\n{out}\n{err}");
    let adapter = out.lines().find(|l| l.starts_with("adapter:")).expect("adapter line");
    println!("{adapter}");
    let line = out
        .lines()
        .filter(|l| l.starts_with("view: screenshot"))
        .nth(1)
        .unwrap_or_else(|| panic!("no second screenshot line:\n{out}"));
    assert_eq!(field(line, "method"), "uniform");
    // The slider's `quality 3` is a pixel target, mapped onto uniform's own factor.
    assert_eq!(field(line, "error-px"), "3");
    let param = field(line, "param");
    let factor = param.strip_prefix("factor=").unwrap_or_else(|| panic!("{param}"));
    let mapped: f64 = factor.parse().unwrap();
    assert!(mapped > 1.0 && mapped != 8.0, "uniform factor {mapped} for 3 px");
    let camera = field(line, "camera");
    // The scripted moves moved the camera away from the default one.
    let start = out.lines().find(|l| l.starts_with("view: screenshot")).unwrap();
    assert_eq!(field(start, "camera"), camera, "the camera moved between the two screenshots");
    let rendered = dir.join("render.png");
    let render_json = dir.join("render.json");
    let r = terrain(&[
        "render",
        "--size",
        "320x180",
        "--method",
        "uniform",
        "--error-px",
        "3",
        "--camera",
        camera,
        "--stats-json",
        render_json.to_str().unwrap(),
        "-o",
        rendered.to_str().unwrap(),
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    // `render --error-px 3` maps onto the same factor as the viewer's slider at 3 px.
    let said = String::from_utf8_lossy(&r.stdout);
    assert!(said.contains(&format!("factor = {mapped:.4} for 3 px")), "{mapped}:\n{said}");
    // Both stats files describe the same frame (the viewer-overhead comparison rests on
    // it): the screenshot's frame drew render's triangles, and both give the process's CPU
    // time of each frame.
    let json = |p: &Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
    };
    let (vj, rj) = (json(&view_json), json(&render_json));
    let shot_frame: usize = field(line, "frame").parse().unwrap();
    let vf = vj["frames"]
        .as_array()
        .and_then(|f| f.iter().find(|f| f["frame"].as_u64() == Some(shot_frame as u64)))
        .unwrap_or_else(|| panic!("no frame {shot_frame} in {vj}"));
    let rf = &rj["frames"][0];
    assert!(rf["triangles"].as_u64().is_some_and(|t| t > 0), "{rf}");
    assert_eq!(vf["triangles"], rf["triangles"], "viewer {vf}\nrender {rf}");
    for f in [vf, rf] {
        let cpu = f["process_cpu_ms"].as_f64().unwrap_or_else(|| panic!("{f}"));
        assert!(cpu.is_finite() && cpu >= 0.0, "{f}");
    }
    let (window, offscreen) = (load(&shot), load(&rendered));
    // Not a trivial match: most of the image is terrain, not sky.
    let sky = offscreen.pixels().filter(|p| p.0[..3] == [150, 185, 225]).count();
    assert!(sky * 2 < offscreen.pixels().len(), "{sky} sky pixels of {}", offscreen.len() / 4);
    let (mean, far) = golden_diff(&window, &offscreen);
    println!("window vs render: mean {mean:?}, {:.3} % off by > 16", far * 100.0);
    assert!(mean.iter().all(|&m| m < 2.0) && far < 0.01, "mean {mean:?}, far {far}");
    // The recorded flight (R) reads back in the `flights/` format: 39 script frames of 1/60 s
    // while recording, a keyframe every 0.5 s of the viewer's clock: at 0 and 0.5 s.
    let spec = terrain_core::flight::FlightSpec::load(&flight).expect("a readable flight");
    assert_eq!(spec.keyframes.len(), 2, "{spec:?}");
    // The panel covers part of the image when shown.
    let (_, panel_far) = golden_diff(&load(&panel), &window);
    assert!(panel_far > 0.02, "the panel changed only {:.3} % of pixels", panel_far * 100.0);
    // The moves happened: the picture is not the one from the start camera.
    let start_png = dir.join("start.png");
    let d = terrain(&[
        "render",
        "--size",
        "320x180",
        "--method",
        "uniform",
        "--method-param",
        factor,
        "--camera",
        START,
        "-o",
        start_png.to_str().unwrap(),
    ]);
    assert!(d.status.success(), "{}", String::from_utf8_lossy(&d.stderr));
    assert_ne!(camera, START);
    let (_, moved) = golden_diff(&load(&start_png), &offscreen);
    assert!(moved > 0.05, "the scripted moves changed only {:.3} % of pixels", moved * 100.0);
    // LOD colours (`colour-levels on`): the window shows what `render --lod-colours` draws,
    // and the colours are not the height ramp's.
    let lod_png = dir.join("render-lod.png");
    let l = terrain(&[
        "render",
        "--size",
        "320x180",
        "--method",
        "uniform",
        "--error-px",
        "3",
        "--camera",
        camera,
        "--lod-colours",
        "-o",
        lod_png.to_str().unwrap(),
    ]);
    assert!(l.status.success(), "{}", String::from_utf8_lossy(&l.stderr));
    let (window_lod, offscreen_lod) = (load(&lod), load(&lod_png));
    let (mean, far) = golden_diff(&window_lod, &offscreen_lod);
    println!("LOD colours, window vs render: mean {mean:?}, {:.3} % off", far * 100.0);
    assert!(mean.iter().all(|&m| m < 2.0) && far < 0.01, "mean {mean:?}, far {far}");
    let (_, recoloured) = golden_diff(&window_lod, &window);
    assert!(recoloured > 0.3, "LOD colours changed only {:.3} % of pixels", recoloured * 100.0);
    drop(x);
}

/// `dir/s.scene`: the synthetic terrain of `size`^2 samples baked with its blocks only (no
/// PVS, DSS, roughness or geomorph tables), plus `extra` bake arguments.
fn baked_blocks(dir: &Path, size: &str, extra: &[&str]) -> PathBuf {
    let store = dir.join("s.scene");
    let mut args = vec!["bake", "--synthetic", size];
    args.extend(extra);
    let out = store.to_str().unwrap();
    args.extend(["-o", out, "--no-pvs", "--no-dss", "--no-roughness", "--no-geomip"]);
    let b = terrain(&args);
    assert!(b.status.success(), "{}", String::from_utf8_lossy(&b.stderr));
    store
}

/// Over a small baked store the viewer streams in real time (the per-frame log shows no frame
/// that waited for I/O); a `quit` mid-stream closes the window, exits 0 within a bounded
/// time, and the store's worker threads are joined.
#[test]
fn the_window_closes_cleanly_mid_stream() {
    let Some(x) = start_xvfb() else { return };
    let dir = scratch("view", "store");
    let store = baked_blocks(&dir, "1025", &[]);
    let script = dir.join("script.txt");
    std::fs::write(
        &script,
        "wait 2\nrecord\nkey down W\nkey down shift\nwait 36\nmouse 90 0\nquality 3\nwait 2\nrecord\nquit\n",
    )
    .unwrap();
    let log = dir.join("frames.json");
    let args = [
        store.to_str().unwrap(),
        "--size",
        "320x180",
        "--script",
        script.to_str().unwrap(),
        "--stats-json",
        log.to_str().unwrap(),
    ];
    let (ok, out, err) = view(&x.display, &dir, &args, Duration::from_secs(180));
    if !ok && no_adapter(&err) && !require() {
        eprintln!("skipping: {err}");
        return;
    }
    assert!(ok, "terrain view of a store failed:\n{out}\n{err}");
    let closed = err
        .lines()
        .find(|l| l.starts_with("view: closed"))
        .unwrap_or_else(|| panic!("no closing line:\n{err}"));
    assert!(closed.contains("worker threads joined"), "{closed}");
    // "(B threads before, A after)": the workers are gone.
    let nums: Vec<usize> =
        closed.split(|c: char| !c.is_ascii_digit()).filter_map(|s| s.parse().ok()).collect();
    let (before, after) = (nums[nums.len() - 2], nums[nums.len() - 1]);
    assert!(after < before, "threads {before} before closing the store, {after} after");
    // The per-frame log: every frame streamed (a store record each), and no frame the event
    // loop drew read from disk or waited for the workers: the first, waiting frame is played
    // on a worker at start (the window shows the sky meanwhile) and again for the quality
    // change's rebuild.
    let log: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&log).unwrap()).unwrap();
    let frames = log["frames"].as_array().unwrap_or_else(|| panic!("no frames: {log}"));
    assert!(frames.len() >= 40, "{} frames logged", frames.len());
    for f in frames {
        assert!(f["stream"].is_object(), "a store frame without its stream figures: {f}");
        assert_eq!(f["waited_for_io"], f["stream"]["waited_for_io"], "{f}");
    }
    let waited: Vec<&serde_json::Value> =
        frames.iter().filter(|f| f["waited_for_io"] != false).map(|f| &f["frame"]).collect();
    assert!(waited.is_empty(), "frames that waited for I/O: {waited:?}");
    // Both methods (the first at start, the quality change's) were built on a worker.
    assert_eq!(out.matches("view: store method ooc ready;").count(), 2, "{out}");
    // The logged frames streamed: data kept arriving from the workers after the first.
    let arrived = frames[1..].iter().filter(|f| f["stream"]["prefetched_mib"].as_f64() > Some(0.0));
    assert!(arrived.count() > 0, "no data arrived after the first frame: {log}");
    println!("last frame: {}", frames[frames.len() - 1]);
    assert!(log["over_twice_the_median"].is_array(), "{log}");
    // Without --record-to the recorded flight goes under the git-ignored out/ of the working
    // folder.
    let recorded = dir.join("out/recorded_flight.json");
    terrain_core::flight::FlightSpec::load(&recorded)
        .unwrap_or_else(|e| panic!("{}: {e}\n{out}", recorded.display()));
    drop(x);
}

/// A store viewed with `--vertical-scale 2` is read exaggerated, the script's `exaggeration 3`
/// rebuilds its runtime at 3x, and `--paced` plays the flight at its own clock: every drawn
/// frame shows the flight's frame `floor(t fps)` of the flight time `t` when it started (never
/// the next pose in line: the clock, not the frame count, advances the flight), to its end.
#[test]
fn a_store_is_exaggerated_and_a_paced_flight_keeps_its_clock() {
    let Some(x) = start_xvfb() else { return };
    let dir = scratch("view", "paced");
    let store = baked_blocks(&dir, "257", &["--block-k", "5"]);
    let script = dir.join("script.txt");
    std::fs::write(&script, "exaggeration 3\nwait-flight\nquit\n").unwrap();
    let flight = Path::new(env!("CARGO_MANIFEST_DIR")).join("../flights/fast_pass.json");
    let log = dir.join("frames.json");
    let args = [
        store.to_str().unwrap(),
        "--vertical-scale",
        "2",
        "--size",
        "160x90",
        "--flight",
        flight.to_str().unwrap(),
        "--paced",
        "--script",
        script.to_str().unwrap(),
        "--stats-json",
        log.to_str().unwrap(),
    ];
    let (ok, out, err) = view(&x.display, &dir, &args, Duration::from_secs(240));
    if !ok && no_adapter(&err) && !require() {
        eprintln!("skipping: {err}");
        return;
    }
    assert!(ok, "terrain view failed:\n{out}\n{err}");
    assert!(out.contains("store: heights exaggerated x2"), "{out}");
    assert!(out.contains("view: exaggeration x3"), "{out}");
    assert!(out.contains("(paced: the others skipped)"), "{out}");
    let log: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&log).unwrap()).unwrap();
    let frames = log["frames"].as_array().unwrap();
    let shown: Vec<(usize, f64)> = frames
        .iter()
        .filter_map(|f| Some((f["flight_frame"].as_u64()? as usize, f["flight_s"].as_f64()?)))
        .collect();
    assert!(shown.len() >= 3, "{} flight frames drawn", shown.len());
    for (k, t) in &shown {
        assert_eq!(*k, (t * 30.0).floor() as usize, "frame {k} shown at flight time {t} s");
    }
    assert!(shown.windows(2).all(|w| w[1].1 > w[0].1 && w[1].0 >= w[0].0), "{shown:?}");
    let last = shown[shown.len() - 1].0;
    println!("{} frames drawn showed flight frames 0..{last}", shown.len());
    assert!(last >= 240, "the flight played to near its end (frame {last} of 300)");
}

/// The `view: measured p99 P px, max M px (N samples...` lines of a run: (p99, max, samples).
fn measured(out: &str) -> Vec<(f64, f64, usize)> {
    out.lines()
        .filter_map(|l| l.strip_prefix("view: measured p99 "))
        .map(|l| {
            let w: Vec<&str> = l.split_whitespace().collect();
            let num =
                |s: &str| s.trim_matches(|c: char| !c.is_ascii_digit() && c != '.').to_owned();
            (num(w[0]).parse().unwrap(), num(w[3]).parse().unwrap(), num(w[5]).parse().unwrap())
        })
        .collect()
}

/// The on-demand measurement (the script's `measure`, the M key) over a store reads the
/// store's full-resolution heights on a worker and runs the benchmark's measurement: over a
/// lossless store (`--raw-f32`) of the embedded terrain it equals the measurement of the same
/// camera and method over the terrain in memory: the same sample count, and the same p99 and
/// max as printed (3 decimals; same heights and node bounds, so the same patches and the same
/// drawn surface: no tolerance is needed); `ooc`, a store-only method, measures too. Negative
/// control: with `--measure-mib 1` (the 1025^2 grid needs 5 MiB) the panel and stdout say
/// so and which option to raise, and give no number.
#[test]
fn a_store_frame_is_measured_against_its_own_heights() {
    let Some(x) = start_xvfb() else { return };
    let dir = scratch("view", "measure");
    let store = baked_blocks(&dir, "1025", &["--raw-f32"]);
    let script = dir.join("script.txt");
    let run = |source: Option<&str>, text: &str, extra: &[&str]| {
        std::fs::write(&script, text).unwrap();
        let mut args: Vec<&str> = source.into_iter().collect();
        args.extend(["--size", "320x180", "--method", "uniform", "--script"]);
        args.push(script.to_str().unwrap());
        args.extend(extra);
        view(&x.display, &dir, &args, Duration::from_secs(240))
    };
    let measure = format!("camera {START}\nwait 3\nmeasure\n");
    let (ok, mem, err) = run(None, &format!("{measure}quit\n"), &[]);
    if !ok && no_adapter(&err) && !require() {
        eprintln!("skipping: {err}");
        return;
    }
    assert!(ok, "terrain view of the embedded terrain failed:\n{mem}\n{err}");
    let (ok, out, err) =
        run(Some(store.to_str().unwrap()), &format!("{measure}method ooc\n{measure}quit\n"), &[]);
    assert!(ok, "terrain view of the store failed:\n{out}\n{err}");
    let (m, s) = (measured(&mem), measured(&out));
    assert_eq!(m.len(), 1, "{mem}");
    assert_eq!(s.len(), 2, "{out}");
    println!("in memory {:?}, store (uniform, ooc) {:?}", m[0], s);
    assert!(out.contains("reference: the store's full-resolution heights"), "{out}");
    let (mem, store_uniform, ooc) = (m[0], s[0], s[1]);
    assert!(mem.2 > 10_000 && mem.0 > 0.0, "a vacuous measurement: {mem:?}");
    assert_eq!(store_uniform.2, mem.2, "samples: store {store_uniform:?}, memory {mem:?}");
    assert!((store_uniform.0 - mem.0).abs() < 1e-9, "p99: {store_uniform:?} vs {mem:?}");
    assert!((store_uniform.1 - mem.1).abs() < 1e-9, "max: {store_uniform:?} vs {mem:?}");
    assert!(ooc.2 > 10_000 && ooc.0.is_finite() && ooc.0 > 0.0, "ooc: {ooc:?}");
    // Negative control: a budget too small refuses, with the figures and the option.
    let (ok, out, err) =
        run(Some(store.to_str().unwrap()), &format!("{measure}quit\n"), &["--measure-mib", "1"]);
    assert!(ok, "terrain view of the store failed:\n{out}\n{err}");
    assert!(measured(&out).is_empty(), "{out}");
    assert!(
        out.contains("view: measured n/a: the store's full-resolution reference is 1050625 samples (5 MiB), over --measure-mib 1: raise --measure-mib"),
        "{out}"
    );
    drop(x);
}
