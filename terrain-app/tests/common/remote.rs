//! Helpers of the remote store tests (`remote_store.rs`: nginx, SeaweedFS, Azurite;
//! `remote_gcs.rs`: fake-gcs-server): running `terrain` with an environment, servers on ports
//! of 127.0.0.1 stopped on drop, a small baked store, and the `info` and warm `bench` figures
//! that a remote store must share with the local one.

use std::net::TcpStream;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output};
use std::time::{Duration, Instant};

use serde_json::Value;

pub(crate) fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A command's stdout and stderr, one after the other.
pub(crate) fn text(out: &Output) -> String {
    format!("{}\n{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr))
}

/// Runs `terrain ARGS` in `cwd` with `env` and the disk cache in `cache`.
pub(crate) fn terrain_in(cwd: &Path, cache: &Path, env: &[(&str, &str)], args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_terrain"))
        .args(args)
        .current_dir(cwd)
        .env("TERRAIN_CACHE_DIR", cache)
        .envs(env.iter().copied())
        .output()
        .expect("the terrain binary runs")
}

/// Waits until `port` accepts connections, else fails naming `what` and the text of `logs`.
/// The wait is long (120 s) because it ends as soon as the server answers: a server that starts
/// in 4 s on an idle machine took over 30 s once in CI, where the test binaries' other servers
/// and builds share two cores (Azurite, a Node program, with an empty log).
pub(crate) fn wait_for(port: u16, what: &str, child: &mut Child, logs: &[&Path]) {
    const WAIT: Duration = Duration::from_secs(120);
    let said = || {
        logs.iter()
            .map(|l| {
                let t = std::fs::read_to_string(l).unwrap_or_default();
                format!("{}:\n{t}", l.display())
            })
            .collect::<Vec<_>>()
            .join("\n")
    };
    let start = Instant::now();
    while start.elapsed() < WAIT {
        if TcpStream::connect(("127.0.0.1", port)).is_ok() {
            return;
        }
        if let Ok(Some(status)) = child.try_wait() {
            panic!("{what} exited ({status}) before answering on port {port}:\n{}", said());
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    panic!("{what} did not answer on 127.0.0.1:{port} within {WAIT:?}:\n{}", said());
}

/// A server process stopped on drop: SIGTERM, then waited for (never left running); then the
/// files it made outside the test's scratch folder (`leftovers`) are removed.
pub(crate) struct Server {
    pub(crate) child: Child,
    pub(crate) port: u16,
    /// Files the server writes where it cannot be told otherwise (weed's Unix sockets in
    /// /tmp), removed once it has stopped.
    pub(crate) leftovers: Vec<PathBuf>,
}

impl Server {
    /// A server with nothing to remove but its process.
    pub(crate) fn new(child: Child, port: u16) -> Self {
        Server { child, port, leftovers: Vec::new() }
    }

    /// The server stopped (SIGSTOP) until the guard is dropped (SIGCONT): a request sent
    /// meanwhile is accepted by the kernel and answered only then, so a test can order a
    /// background fetch after a read it checks, whatever the scheduling of its threads. For a
    /// server of one process (nginx with `master_process off`).
    pub(crate) fn pause(&self) -> Paused {
        let pid = self.child.id().to_string();
        let status = Command::new("kill").args(["-STOP", &pid]).status().expect("kill runs");
        assert!(status.success(), "kill -STOP {pid}: {status}");
        Paused { pid }
    }

    fn stop(&mut self) {
        // A stopped process would take the TERM only once continued.
        let _ = Command::new("kill").args(["-CONT", &self.child.id().to_string()]).status();
        let _ = Command::new("kill").args(["-TERM", &self.child.id().to_string()]).status();
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(10) {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A server stopped by [`Server::pause`], continued on drop.
#[must_use = "the server continues when this is dropped"]
pub(crate) struct Paused {
    pid: String,
}

impl Drop for Paused {
    fn drop(&mut self) {
        let _ = Command::new("kill").args(["-CONT", &self.pid]).status();
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop();
        for p in &self.leftovers {
            let _ = std::fs::remove_file(p);
        }
    }
}

/// `n` distinct free ports on 127.0.0.1 in `range`, which a test file keeps below Linux's
/// ephemeral range (32768..): a port released here before the server binds it cannot be
/// handed to another test's `bind(127.0.0.1:0)` (nginx's `free_port`, clients' local ports)
/// in the meantime. Each port is checked free by binding it. The tests of one file share one
/// cursor, so two servers started at once never get the same port; the start is spread by the
/// process id (steps of 25 over the first 5/6 of the range) so concurrent test processes
/// rarely probe the same ports. One range per test file (the cursor is the process's).
pub(crate) fn free_ports_in(range: Range<u16>, n: usize) -> Vec<u16> {
    static NEXT: std::sync::Mutex<u16> = std::sync::Mutex::new(0);
    let mut next = NEXT.lock().unwrap_or_else(|e| e.into_inner());
    if *next == 0 {
        let steps = u32::from(range.end - range.start) / 30;
        *next = range.start + (std::process::id() % steps) as u16 * 25;
    }
    let mut ports: Vec<u16> = Vec::new();
    while ports.len() < n && *next < range.end {
        let p = *next;
        *next += 1;
        if std::net::TcpListener::bind(("127.0.0.1", p)).is_ok() {
            ports.push(p);
        }
    }
    assert_eq!(ports.len(), n, "no {n} free ports in {range:?} on 127.0.0.1");
    ports
}

/// The `--raw` shape of [`baked_at`]'s grid.
pub(crate) const GRID_RAW: &str = "129x129:f32";

/// A 129 x 129 raw f32 grid and a store baked from it (4 x 4 blocks of 33 x 33 vertices, no
/// tables), in `dir`'s `www/` (what the HTTP tests serve); returns the DEM and the store.
pub(crate) fn baked(dir: &Path) -> (PathBuf, PathBuf) {
    std::fs::create_dir_all(dir.join("www")).unwrap();
    baked_at(dir, dir.join("www/g.scene"))
}

/// A 129 x 129 raw f32 grid (little-endian, north row first, 10 m) written to `dir`, and
/// `store` baked from it with [`bake_args`]; returns the DEM and the store.
pub(crate) fn baked_at(dir: &Path, store: PathBuf) -> (PathBuf, PathBuf) {
    let dem = dir.join("grid.raw");
    let mut bytes = Vec::new();
    for j in 0..129 {
        for i in 0..129 {
            let z = 200.0 + (i as f32 * 0.11).sin() * 60.0 + (j as f32 * 0.07).cos() * 45.0;
            bytes.extend(z.to_le_bytes());
        }
    }
    std::fs::write(&dem, bytes).unwrap();
    let out = terrain_in(dir, &dir.join("cache"), &[], &bake_args(&dem, s(&store)));
    assert!(out.status.success(), "bake failed: {}", text(&out));
    (dem, store)
}

/// `terrain bake` of [`baked`]'s grid to `out`.
pub(crate) fn bake_args<'a>(dem: &'a Path, out: &'a str) -> Vec<&'a str> {
    vec![
        "bake",
        s(dem),
        "--raw",
        GRID_RAW,
        "--spacing",
        "10",
        "-o",
        out,
        "--block-k",
        "5",
        "--no-pvs",
        "--no-dss",
        "--no-roughness",
        "--no-geomip",
    ]
}

/// `terrain info --json LOCATION` without the location itself.
pub(crate) fn info(dir: &Path, cache: &Path, env: &[(&str, &str)], location: &str) -> Value {
    let out = terrain_in(dir, cache, env, &["info", "--json", location]);
    assert!(out.status.success(), "info {location}: {}", text(&out));
    let mut v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["store"], location);
    v.as_object_mut().unwrap().remove("store");
    v
}

/// A warm `terrain bench` of the ooc method from `location` (the DEM as reference): the ooc
/// run's per-frame figures without the times, and the stderr.
pub(crate) fn bench(
    dir: &Path,
    cache: &Path,
    env: &[(&str, &str)],
    dem: &Path,
    location: &str,
    name: &str,
) -> (Vec<Value>, String) {
    let flight = Path::new(env!("CARGO_MANIFEST_DIR")).join("../flights/pvps_884.json");
    let out_dir = dir.join("bench");
    let out = terrain_in(
        dir,
        cache,
        env,
        &[
            "bench",
            s(dem),
            "--raw",
            GRID_RAW,
            "--spacing",
            "10",
            "--flight",
            s(&flight),
            "--methods",
            "ooc",
            "--ooc-store",
            location,
            "--wait",
            "--frames",
            "3",
            "--sweep",
            "1",
            "--no-render",
            "-o",
            s(&out_dir),
            "--name",
            name,
        ],
    );
    let all = text(&out);
    assert!(out.status.success(), "bench {location}: {all}");
    let report: Value = serde_json::from_str(
        &std::fs::read_to_string(out_dir.join(format!("{name}.json"))).unwrap(),
    )
    .unwrap();
    let ooc =
        report["runs"].as_array().unwrap().iter().find(|r| r["method"] == "ooc").unwrap().clone();
    let frames = ooc["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            let mut f = f.clone();
            // What is drawn and measured (times, memory and I/O differ from run to run).
            let keep = ["frame", "patches", "triangles", "missing_blocks", "errors"];
            f.as_object_mut().unwrap().retain(|k, _| keep.contains(&k.as_str()));
            f
        })
        .collect();
    (frames, all)
}

/// The store at `url` reads as the local bake `store`: the same `info`, and a warm bench of
/// it draws the same (non-empty) frames without a store fault.
pub(crate) fn assert_reads_as_local(
    dir: &Path,
    cache: &Path,
    env: &[(&str, &str)],
    dem: &Path,
    store: &Path,
    url: &str,
) {
    assert_eq!(info(dir, cache, env, url), info(dir, cache, env, s(store)));
    let (local, _) = bench(dir, cache, env, dem, s(store), "local");
    let (remote, err) = bench(dir, cache, env, dem, url, "remote");
    assert!(!local.is_empty());
    assert_eq!(local, remote);
    assert!(!err.contains("store fault"), "{err}");
}

/// A second bake to `url` (17^2 vertices a block this time) is refused before any work, as a
/// local store folder is (the same message, naming --overwrite), and the store is as it was.
/// Returns that bake's arguments and the store's `info`, for the caller's `--overwrite` run.
pub(crate) fn assert_second_bake_refused<'a>(
    dir: &Path,
    cache: &Path,
    env: &[(&str, &str)],
    dem: &'a Path,
    url: &'a str,
) -> (Vec<&'a str>, Value) {
    let before = info(dir, cache, env, url);
    let mut k4 = bake_args(dem, url);
    let k = k4.iter().position(|a| *a == "--block-k").unwrap() + 1;
    k4[k] = "4";
    let out = terrain_in(dir, cache, env, &k4);
    let all = text(&out);
    assert!(!out.status.success(), "{all}");
    assert!(
        all.contains(&format!("{url}: already exists (give --overwrite to replace it)")),
        "{all}"
    );
    assert!(!all.contains("uploaded") && !all.contains("blocks:"), "{all}");
    assert_eq!(info(dir, cache, env, url), before);
    (k4, before)
}

/// A store with a block file above the 16 MiB multipart threshold (terrain_stream's
/// `MULTIPART_ABOVE`: one 2049^2 block of raw f32 levels, 16.8 MB) baked to `url` and to a
/// local folder: the bake says one file went as a multipart upload, and the store at the URL
/// reads as the local one: the same `info`, and the same tiles from every sample (the finest
/// level spans both parts; every level read is checked against its length and CRC-32, so a
/// part lost or misordered fails the read).
pub(crate) fn assert_multipart_upload(dir: &Path, cache: &Path, env: &[(&str, &str)], url: &str) {
    let local = dir.join("multipart.scene");
    let bake = |out: &str| {
        let args = [
            "bake",
            "--synthetic",
            "1537",
            "--block-k",
            "11",
            "--raw-f32",
            "--no-pvs",
            "--no-dss",
            "--no-roughness",
            "--no-geomip",
            "--no-calibration",
            "-o",
            out,
        ];
        let o = terrain_in(dir, cache, env, &args);
        assert!(o.status.success(), "bake -o {out}: {}", text(&o));
        text(&o)
    };
    bake(s(&local));
    let all = bake(url);
    assert!(all.contains("(1 as multipart uploads)"), "bake -o {url}: {all}");
    assert_eq!(info(dir, cache, env, url), info(dir, cache, env, s(&local)));
    // Every sample, strictly: a tileset's coarse tiles are checked against every sample at
    // full resolution, read with the strict store reader (a short or damaged level is an error).
    let tiles = |location: &str, name: &str| {
        let out = dir.join(name);
        let args = ["tiles", location, "--lonlat=-122.5,46.5", "--max-level", "0", "-o", s(&out)];
        let o = terrain_in(dir, cache, env, &args);
        assert!(o.status.success(), "tiles {location}: {}", text(&o));
        ["0/0/0.terrain", "0/1/0.terrain"].map(|t| std::fs::read(out.join(t)).unwrap())
    };
    assert!(tiles(s(&local), "multipart-local.tiles") == tiles(url, "multipart-remote.tiles"));
}
