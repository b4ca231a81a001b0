//! Stores read over HTTP (`Store::open_location`) from a tiny std-only HTTP server started by
//! each test on 127.0.0.1 (range requests; a mode answering 500, a mode that never answers):
//! the same heights as the local store, one range request per block for the levels asked for,
//! a second open reading from the disk cache, the disk cache held to its limit, and the
//! streamer over a failing or hanging server: faults naming block, level and error, coarser
//! levels drawn, no frame stalled.

use std::io::{BufRead, BufReader, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use glam::dvec3;
use terrain_core::geometry::Camera;

use crate::format::block_file_name;
use crate::{BlockId, RemoteOptions, Store, StoreError, StreamConfig, Streamer, is_url};

/// What the server does with one request: the path and the byte range asked for.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Action {
    Serve,
    Fail500,
    Hang,
}

type Rule = Arc<dyn Fn(&str, u64, u64) -> Action + Send + Sync>;

/// Every request's path and byte range (`None`: no `Range` header).
type RequestLog = Mutex<Vec<(String, Option<(u64, u64)>)>>;

/// A std-only HTTP/1.1 server of one folder: GET and HEAD, `Range: bytes=a-b`, one request
/// per connection; what it answers is decided per request by `rule`. Stops on drop.
struct Server {
    port: u16,
    stop: Arc<AtomicBool>,
    /// Requests for block files (paths under `blocks/`).
    block_requests: Arc<AtomicUsize>,
    /// Every request's path and range.
    log: Arc<RequestLog>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Server {
    fn start(root: PathBuf, rule: Rule) -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        listener.set_nonblocking(true).unwrap();
        let port = listener.local_addr().unwrap().port();
        let stop = Arc::new(AtomicBool::new(false));
        let block_requests = Arc::new(AtomicUsize::new(0));
        let log = Arc::new(Mutex::new(Vec::new()));
        let (s, b, l) = (stop.clone(), block_requests.clone(), log.clone());
        let thread = std::thread::spawn(move || {
            while !s.load(Ordering::SeqCst) {
                match listener.accept() {
                    Ok((conn, _)) => {
                        let (root, rule, s, b, l) =
                            (root.clone(), rule.clone(), s.clone(), b.clone(), l.clone());
                        std::thread::spawn(move || {
                            let _ = serve(conn, &root, &*rule, &s, &b, &l);
                        });
                    }
                    Err(_) => std::thread::sleep(Duration::from_millis(2)),
                }
            }
        });
        Self { port, stop, block_requests, log, thread: Some(thread) }
    }

    fn url(&self) -> String {
        format!("http://127.0.0.1:{}/store", self.port)
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn serve(
    conn: TcpStream,
    root: &Path,
    rule: &(dyn Fn(&str, u64, u64) -> Action + Send + Sync),
    stop: &AtomicBool,
    block_requests: &AtomicUsize,
    log: &RequestLog,
) -> std::io::Result<()> {
    conn.set_nonblocking(false)?;
    let mut reader = BufReader::new(conn.try_clone()?);
    let mut line = String::new();
    reader.read_line(&mut line)?;
    let mut parts = line.split_whitespace();
    let (method, target) = (parts.next().unwrap_or(""), parts.next().unwrap_or("/"));
    let mut range = None;
    loop {
        let mut h = String::new();
        if reader.read_line(&mut h)? == 0 || h.trim().is_empty() {
            break;
        }
        if let Some((k, v)) = h.split_once(':')
            && k.trim().eq_ignore_ascii_case("range")
            && let Some(r) = v.trim().strip_prefix("bytes=")
            && let Some((a, b)) = r.split_once('-')
        {
            range = Some((a.parse::<u64>().unwrap_or(0), b.parse::<u64>().unwrap_or(u64::MAX)));
        }
    }
    let path = target.strip_prefix("/store/").unwrap_or("").to_string();
    log.lock().unwrap().push((path.clone(), range));
    if path.starts_with("blocks/") {
        block_requests.fetch_add(1, Ordering::SeqCst);
    }
    let mut out = conn;
    let body = std::fs::read(root.join(&path)).ok();
    let Some(body) = body.filter(|_| !path.is_empty() && !path.contains("..")) else {
        return out.write_all(
            b"HTTP/1.1 404 Not Found\r\nContent-Length: 0\r\nConnection: close\r\n\r\n",
        );
    };
    let size = body.len() as u64;
    let (a, b) = range.map_or((0, size.saturating_sub(1)), |(a, b)| (a, b.min(size - 1)));
    match rule(&path, a, b + 1) {
        Action::Serve => {}
        Action::Fail500 => {
            return out.write_all(
                b"HTTP/1.1 500 Internal Server Error\r\nContent-Length: 0\r\nConnection: close\r\n\r\n",
            );
        }
        Action::Hang => {
            // Never answers (until the server stops).
            while !stop.load(Ordering::SeqCst) {
                std::thread::sleep(Duration::from_millis(20));
            }
            return Ok(());
        }
    }
    let slice = &body[a as usize..=b as usize];
    let status = if range.is_some() { "206 Partial Content" } else { "200 OK" };
    let mut head = format!(
        "HTTP/1.1 {status}\r\nContent-Length: {}\r\nAccept-Ranges: bytes\r\nLast-Modified: Thu, 01 Jan 2026 00:00:00 GMT\r\nETag: \"{size:x}\"\r\nConnection: close\r\n",
        slice.len()
    );
    if range.is_some() {
        head += &format!("Content-Range: bytes {a}-{b}/{size}\r\n");
    }
    head += "\r\n";
    out.write_all(head.as_bytes())?;
    if method != "HEAD" {
        out.write_all(slice)?;
    }
    Ok(())
}

/// A temporary folder for one test, removed when dropped (also when the test panics).
fn temp(name: &str) -> super::Scratch {
    super::scratch(&format!("terrain-stream-remote-{name}-"))
}

/// A 513^2 store with k = 6 (as the runtime tests'), in `dir/store`.
fn local_store(dir: &Path) -> Store {
    super::bake_wave_513(&dir.join("store"));
    Store::open(dir.join("store")).unwrap()
}

fn options(cache: &Path) -> RemoteOptions {
    RemoteOptions {
        cache_dir: Some(cache.to_path_buf()),
        request_timeout: Duration::from_secs(10),
        retries: 1,
        ..Default::default()
    }
}

fn camera(y: f64) -> Camera {
    Camera::from_yaw_pitch(dvec3(2560.0, y, 900.0), 0.0, -20.0)
        .with_viewport(128.0, 72.0)
        .with_clip(1.0, 2500.0)
}

#[test]
fn urls_are_told_from_paths() {
    for u in ["s3://b/x", "gs://b/x", "az://c/x", "http://h/x", "HTTPS://h/x"] {
        assert!(is_url(u), "{u}");
    }
    for p in ["out/store", "/tmp/s3:/x", "s3:/x", "file.tif", "ftp://h/x", "C:\\x"] {
        assert!(!is_url(p), "{p}");
    }
}

#[test]
fn a_store_over_http_reads_as_the_local_one_and_a_second_open_reads_the_disk_cache() {
    let dir = temp("same");
    let local = local_store(&dir);
    let server = Server::start(dir.join("store"), Arc::new(|_: &str, _, _| Action::Serve));
    let cache = dir.join("cache");
    let remote = Store::open_location_with(&server.url(), &options(&cache)).unwrap();
    assert!(remote.is_remote() && remote.location() == server.url());
    assert_eq!(remote.header(), local.header());
    assert!(remote.dir().starts_with(&cache), "the mirror is in the cache folder");
    let k = local.header().k;
    let ids: Vec<BlockId> = local.block_ids().collect();
    // The overview (levels 0-4 of every block) came with the index, in one request; those
    // levels read without a block request.
    assert_eq!(remote.overview_levels(), Some(4));
    let overview_gets =
        |log: &RequestLog| log.lock().unwrap().iter().filter(|(p, _)| p == "overview.bin").count();
    assert_eq!(overview_gets(&server.log), 1);
    // The decimation errors: fetched whole into the mirror on first need (one GET), the
    // local store's values.
    let gets = |log: &RequestLog, name: &str| {
        log.lock().unwrap().iter().filter(|(p, _)| p == name).count()
    };
    assert_eq!(gets(&server.log, crate::DECIMATION_FILE), 0, "not fetched at open");
    let table = remote.decimation_errors().unwrap().expect("a table");
    assert_eq!(Some(&*table), local.decimation_errors().unwrap().as_deref());
    remote.decimation_errors().unwrap();
    assert_eq!(gets(&server.log, crate::DECIMATION_FILE), 1, "fetched once");
    for &id in &ids {
        for level in 0..=4 {
            assert_eq!(
                remote.read_level_bytes(id, level).unwrap(),
                local.read_level_bytes(id, level).unwrap()
            );
        }
    }
    assert_eq!(server.block_requests.load(Ordering::SeqCst), 0);
    // One range request per block covering every finer level asked for.
    for &id in &ids {
        remote.prefetch_levels(id, 0, k).unwrap();
        let (a, b) = (remote.read_block(id, k).unwrap(), local.read_block(id, k).unwrap());
        assert_eq!(a.grid(k), b.grid(k), "{id}");
    }
    assert_eq!(server.block_requests.load(Ordering::SeqCst), ids.len());
    // The first request of a block starts at byte 0 (its header is checked); the next asks
    // for the levels alone.
    let id = ids[0];
    let entry = local.entry(id).unwrap();
    let third = Store::open_location_with(&server.url(), &options(&dir.join("cache2"))).unwrap();
    let before = server.block_requests.load(Ordering::SeqCst);
    third.prefetch_levels(id, 0, 4).unwrap();
    assert_eq!(server.block_requests.load(Ordering::SeqCst), before, "levels 0-4: the overview's");
    third.prefetch_levels(id, 0, 5).unwrap();
    third.prefetch_levels(id, 6, 6).unwrap();
    let log = server.log.lock().unwrap().clone();
    let name = block_file_name(id);
    let ranges: Vec<(u64, u64)> =
        log.iter().filter(|(p, _)| *p == name).filter_map(|(_, r)| *r).rev().take(2).collect();
    let l6 = entry.levels[6];
    assert_eq!(ranges[0], (l6.offset, l6.offset + u64::from(l6.len) - 1), "{log:?}");
    assert_eq!(ranges[1].0, 0);
    // A second open with the same cache: no block request, the same heights.
    drop(remote);
    let before = server.block_requests.load(Ordering::SeqCst);
    let again = Store::open_location_with(&server.url(), &options(&cache)).unwrap();
    for &id in &ids {
        assert_eq!(
            again.read_block(id, k).unwrap().grid(k),
            local.read_block(id, k).unwrap().grid(k)
        );
    }
    assert_eq!(server.block_requests.load(Ordering::SeqCst), before, "read from the disk cache");
    // A cached level that no longer passes its CRC is fetched again (negative control of the
    // cache's check).
    let cached = again.dir().join(format!("{}.L{k}", block_file_name(id)));
    std::fs::write(&cached, b"not the level").unwrap();
    let again2 = Store::open_location_with(&server.url(), &options(&cache)).unwrap();
    assert_eq!(again2.read_block(id, k).unwrap().grid(k), local.read_block(id, k).unwrap().grid(k));
    assert_eq!(server.block_requests.load(Ordering::SeqCst), before + 1);
    // A small disk cache holds to its limit (least recently used evicted).
    let limit = 20_000;
    let small = RemoteOptions { disk_cache_bytes: limit, ..options(&dir.join("small")) };
    let s = Store::open_location_with(&server.url(), &small).unwrap();
    for &id in &ids {
        s.read_block(id, k).unwrap();
    }
    let blocks = s.dir().join("blocks");
    let held: u64 =
        std::fs::read_dir(&blocks).unwrap().map(|e| e.unwrap().metadata().unwrap().len()).sum();
    assert!(held <= limit && held > 0, "{held} bytes cached, limit {limit}");
    // Not a store: the error names the URL and the index.
    let err = Store::open_location_with(&format!("{}/nothing", server.url()), &options(&cache))
        .unwrap_err();
    assert!(matches!(err, StoreError::Remote { .. }), "{err}");
    assert!(err.to_string().contains("/nothing") && err.to_string().contains("index.tsi"), "{err}");
    drop(server);
}

/// An older (version-3) index at a URL is fetched whole once: a later open with the same
/// cache takes the mirror's copy after one range request (the object's length and first
/// bytes), a damaged copy is fetched again, and another bake's index of the same length (its
/// header differs) is fetched and replaces the mirror.
#[test]
fn an_older_index_is_fetched_whole_once_and_checked_against_the_mirror() {
    use crate::format::{INDEX_FILE, read_index, write_index_unpaged};
    let dir = temp("v3");
    local_store(&dir);
    let store = dir.join("store");
    let (h, entries) = read_index(&std::fs::read(store.join(INDEX_FILE)).unwrap()).unwrap();
    let v3 = write_index_unpaged(&h, &entries, 3);
    std::fs::write(store.join(INDEX_FILE), &v3).unwrap();
    let server = Server::start(store.clone(), Arc::new(|_: &str, _, _| Action::Serve));
    let cache = dir.join("cache");
    let index_gets = |log: &RequestLog| {
        let log = log.lock().unwrap();
        log.iter().filter(|(p, _)| p == INDEX_FILE).map(|(_, r)| *r).collect::<Vec<_>>()
    };
    let open = || Store::open_location_with(&server.url(), &options(&cache)).unwrap();
    let first = open();
    assert_eq!(first.header(), &h);
    assert_eq!(index_gets(&server.log).len(), 2, "the first bytes, then the rest");
    let received = first.remote_bytes_received();
    assert!(received >= v3.len() as u64, "{received}");
    server.log.lock().unwrap().clear();
    let second = open();
    assert_eq!(second.header(), &h);
    assert_eq!(
        second.entry(first.block_ids().next().unwrap()),
        first.entry(first.block_ids().next().unwrap())
    );
    assert_eq!(index_gets(&server.log).len(), 1, "the first bytes only");
    assert!(second.remote_bytes_received() < 8192, "{}", second.remote_bytes_received());
    // A damaged copy in the mirror (its CRC-32 fails): fetched again, and the store reads.
    let mirrored = second.dir().join(INDEX_FILE);
    let mut bytes = std::fs::read(&mirrored).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x10;
    std::fs::write(&mirrored, &bytes).unwrap();
    server.log.lock().unwrap().clear();
    let third = open();
    assert_eq!(index_gets(&server.log).len(), 2, "fetched whole again");
    assert_eq!(std::fs::read(&mirrored).unwrap(), v3, "the mirror's copy mended");
    assert_eq!(third.header(), &h);
    // Another bake's index, the same length: its header (bake id) differs, so it is fetched.
    let other = crate::Header { bake_id: h.bake_id ^ 1, ..h.clone() };
    let v3b = write_index_unpaged(&other, &entries, 3);
    assert_eq!(v3b.len(), v3.len());
    std::fs::write(store.join(INDEX_FILE), &v3b).unwrap();
    server.log.lock().unwrap().clear();
    let fourth = open();
    assert_eq!(fourth.header().bake_id, h.bake_id ^ 1);
    assert_eq!(index_gets(&server.log).len(), 2, "another bake's index fetched whole");
    drop(server);
}

/// Byte offset where level `level` of each block ends (exclusive), from the index.
fn level_end(store: &Store, id: BlockId, level: u8) -> u64 {
    let le = store.entry(id).unwrap().levels[level as usize];
    le.offset + u64::from(le.len)
}

/// Streams a flight from a server that fails (or never answers) every range reaching past
/// level 2 of a block: every frame returns at once, faults name the block, the level and the
/// error, and the blocks are drawn from their coarser levels.
fn flight_over_a_bad_server(name: &str, action: Action) {
    let dir = temp(name);
    let local = Arc::new(local_store(&dir));
    // The blocks' own requests are what fails here: served without the overview, which would
    // give levels 0-4 in one request (`the_overview_is_one_request_...`).
    std::fs::remove_file(dir.join("store/overview.bin")).unwrap();
    let ends: std::collections::HashMap<String, u64> =
        local.block_ids().map(|id| (block_file_name(id), level_end(&local, id, 2))).collect();
    let rule: Rule = Arc::new(move |path: &str, _a, b| match ends.get(path) {
        Some(&end) if b > end => action,
        _ => Action::Serve,
    });
    let server = Server::start(dir.join("store"), rule);
    let opts = RemoteOptions {
        request_timeout: Duration::from_millis(800),
        retries: 0,
        disk_cache_bytes: 0,
        ..options(&dir.join("cache"))
    };
    let store = Arc::new(Store::open_location_with(&server.url(), &opts).unwrap());
    let config = StreamConfig { threads: 2, tau: 1.0, coarse_level: 2, ..Default::default() };
    let mut s = Streamer::new(store.clone(), config);
    let mut faults = Vec::new();
    let start = Instant::now();
    let mut frames = 0;
    while start.elapsed() < Duration::from_secs(60) {
        let st = s.update(&camera(-500.0 + (frames % 40) as f64 * 10.0));
        if frames > 0 {
            // Never waits on the server: far below the request timeout.
            assert!(!st.waited_for_io(), "frame {frames}");
            assert!(
                st.frame_time < Duration::from_millis(400),
                "frame {frames}: {:?}",
                st.frame_time
            );
        }
        for b in s.scheduled().iter().filter(|b| b.visible) {
            assert!(s.block(b.block).is_some(), "frame {frames}: {} is a hole", b.block);
        }
        faults.extend(st.faults);
        frames += 1;
        if faults.len() >= 3 {
            break;
        }
        std::thread::sleep(Duration::from_millis(16));
    }
    assert!(faults.len() >= 3, "no fault named in {frames} frames");
    for f in &faults {
        assert!(f.error.level().is_some_and(|l| l >= 3), "{f}");
        assert!(f.error.block().is_some(), "{f}");
        assert!(f.drawn_level().is_some_and(|l| l <= 2), "{f}");
        let text = f.to_string();
        assert!(text.contains(&server.url()) && text.contains("level"), "{text}");
        match action {
            Action::Fail500 => assert!(text.contains("500"), "{text}"),
            _ => assert!(matches!(f.error, StoreError::RemoteBlock { .. }), "{text}"),
        }
    }
    drop(s);
    drop(server);
}

#[test]
fn a_server_answering_500_for_finer_levels_gives_named_faults_and_coarser_levels() {
    flight_over_a_bad_server("fail", Action::Fail500);
}

#[test]
fn a_hanging_server_never_stalls_a_frame() {
    flight_over_a_bad_server("hang", Action::Hang);
}

/// A remote store's streamer may run at least `REMOTE_THREADS` workers by default (each waits
/// out its range request, so the workers are the requests in the air), a local store's one per
/// core (the negative control); an explicit count is kept for both. The workers are started as
/// the requests in flight need them: a streamer that made N requests started at most N threads,
/// and never more than its limit.
#[test]
fn a_remote_store_streams_with_many_workers() {
    let dir = temp("workers");
    let local = Arc::new(local_store(&dir));
    let server = Server::start(dir.join("store"), Arc::new(|_: &str, _, _| Action::Serve));
    let remote =
        Arc::new(Store::open_location_with(&server.url(), &options(&dir.join("cache"))).unwrap());
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let threads = |store: &Arc<Store>, threads: usize| {
        Streamer::new(store.clone(), StreamConfig { threads, ..Default::default() }).threads()
    };
    assert_eq!(threads(&remote, 0), cores.max(StreamConfig::REMOTE_THREADS));
    assert_eq!(threads(&local, 0), cores);
    assert_eq!(threads(&remote, 3), 3);
    assert_eq!(threads(&local, 3), 3);
    // A few frames: the threads started follow the requests, far below the limit.
    let flight = |store: &Arc<Store>, threads: usize| {
        let mut s = Streamer::new(store.clone(), StreamConfig { threads, ..Default::default() });
        assert_eq!(s.threads_started(), 0, "no request, no thread");
        let mut requests = 0;
        for f in 0..4 {
            let st = s.update(&camera(-500.0 + f as f64 * 20.0));
            assert!(st.faults.is_empty(), "{:?}", st.faults);
            requests += st.requests + st.sync_loads;
        }
        (s.threads_started(), requests)
    };
    let (started, requests) = flight(&remote, 0);
    assert!(requests > 0 && requests < StreamConfig::REMOTE_THREADS, "{requests} requests");
    assert!((1..=requests).contains(&started), "{started} threads for {requests} requests");
    // The limit holds: more requests than workers start the limit.
    let (started, requests) = flight(&local, 3);
    assert!(requests > 3, "{requests} requests");
    assert_eq!(started, 3);
    drop(server);
}

/// Part files (`NAME.partPID-K`) of side table `name` anywhere under `cache`.
fn part_files(cache: &Path, name: &str) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut dirs = vec![cache.to_path_buf()];
    while let Some(d) = dirs.pop() {
        for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            let p = e.path();
            if p.is_dir() {
                dirs.push(p);
            } else if e.file_name().to_string_lossy().starts_with(&format!("{name}.part")) {
                out.push(p);
            }
        }
    }
    out
}

#[test]
fn a_remote_table_leaves_no_part_until_read_and_stores_opened_apart_share_its_chunks() {
    use terrain_core::lod::TableReader;
    let dir = temp("parts");
    let _local = local_store(&dir);
    // A side table of 40 chunks of 4 KiB, its bytes a function of the offset.
    let bytes: Vec<u8> =
        (0..40 * 4096u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 24) as u8).collect();
    std::fs::write(dir.join("store/side.bin"), &bytes).unwrap();
    let server = Server::start(dir.join("store"), Arc::new(|_: &str, _, _| Action::Serve));
    let cache = dir.join("cache");
    let chunked =
        RemoteOptions { side_tables_in_chunks: true, side_chunk_bytes: 4096, ..options(&cache) };
    let gets = |log: &RequestLog| {
        log.lock().unwrap().iter().filter(|(p, r)| p == "side.bin" && r.is_some()).count()
    };
    let a = Store::open_location_with(&server.url(), &chunked).unwrap();
    let table = a.side_table("side.bin").unwrap().unwrap();
    assert_eq!(table.len(), bytes.len() as u64);
    // Opened to learn its length: no part file, no range request.
    assert!(part_files(&cache, "side.bin").is_empty(), "{:?}", part_files(&cache, "side.bin"));
    assert_eq!(gets(&server.log), 0);
    let mut buf = vec![0u8; 100];
    table.read_at(5 * 4096 + 10, &mut buf).unwrap();
    assert_eq!(buf, bytes[5 * 4096 + 10..5 * 4096 + 110]);
    assert_eq!(part_files(&cache, "side.bin").len(), 1, "the first fetch makes the part");
    assert_eq!(gets(&server.log), 1);
    // A store opened apart on the same location and cache reads the same part: the chunk
    // already fetched is not fetched again; another one is, once.
    let b = Store::open_location_with(&server.url(), &chunked).unwrap();
    let other = b.side_table("side.bin").unwrap().unwrap();
    other.read_at(5 * 4096, &mut buf).unwrap();
    assert_eq!(buf, bytes[5 * 4096..5 * 4096 + 100]);
    assert_eq!(gets(&server.log), 1, "the chunk store a fetched");
    other.read_at(9 * 4096, &mut buf).unwrap();
    table.read_at(9 * 4096 + 50, &mut buf).unwrap();
    assert_eq!(buf, bytes[9 * 4096 + 50..9 * 4096 + 150]);
    assert_eq!(gets(&server.log), 2);
    assert_eq!(part_files(&cache, "side.bin").len(), 1);
    // With both stores and their tables gone the part goes; a store opened after them reads
    // anew (the control: the requests above would count here if parts were never shared).
    drop((table, other, a, b));
    assert!(part_files(&cache, "side.bin").is_empty());
    let c = Store::open_location_with(&server.url(), &chunked).unwrap();
    c.side_table("side.bin").unwrap().unwrap().read_at(5 * 4096, &mut buf).unwrap();
    assert_eq!(gets(&server.log), 3);
    // Another cache is another mirror: its own part.
    let d = Store::open_location_with(
        &server.url(),
        &RemoteOptions { cache_dir: Some(dir.join("cache2")), ..chunked.clone() },
    )
    .unwrap();
    d.side_table("side.bin").unwrap().unwrap().read_at(5 * 4096, &mut buf).unwrap();
    assert_eq!(gets(&server.log), 4);
    drop((c, d));
}
