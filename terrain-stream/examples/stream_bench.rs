//! The terrain-stream benchmark: storage (raw, full pyramid, non-redundant, compressed) on the
//! real DEMs and a big synthetic, bake throughput, and long flights (Table-3 rows per speed).
//!
//! `cargo run --release -p terrain-stream --example stream_bench -- [all|storage|codec|flight
//! FRAMES [puget|big]|bake SIZE K [NAME]|raw SIZE PATH|bakeraw PATH SIZE K NAME|upload STORE_DIR URL|
//! realtime STORE FLIGHT [CACHE_MIB [in_flight=N] [threads=N] [lookahead=F]]|repack STORE...|compare STORE_A STORE_B]`
//! (peak RSS: prefix with `/usr/bin/time -v`). Data from `../shared/data`.
//!
//! `repack STORE...` packs the varints of every level payload of baked stores again with
//! miniz_oxide and libdeflate at several levels: bytes, packing and inflating speed (CPU
//! seconds, one thread), for the codec's choice of compressor and level. `compare STORE_A
//! STORE_B` checks that two stores decode to the same heights, block by block, and times each
//! one's decoding (e.g. a store main's build baked against this build's).
//!
//! `raw SIZE PATH` writes the synthetic terrain's rows to a headerless little-endian f32 file
//! (north row first, as `--raw` reads files: the terrain of `terrain bake --synthetic SIZE`),
//! and `bakeraw PATH SIZE K NAME` bakes such a file read by bands of rows, for the bake's
//! throughput from a file.
//!
//! `upload STORE_DIR URL` uploads a baked store folder to `s3://`, `gs://` or `az://` (the
//! bake's own `upload_store`; credentials and endpoint from the environment), for streaming
//! an existing big store from object storage without baking it again.
//!
//! `realtime` plays a flight (e.g. `flights/fast_pass.json`) over a store at the flight's own
//! frame rate, paced in real wall time, every frame through the real-time `Streamer::update`
//! (no rendering: the streamer alone; the first frame waits until warm), and reports the frames that waited for I/O after the
//! first, the share of frames drawn at their needed level, late MB per frame, and peak RSS
//! against the cache budget.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use glam::dvec3;
use rayon::prelude::*;
use terrain_core::dem::{LoadOptions, load};
use terrain_core::geometry::Camera;
use terrain_core::heightmap::Heightmap;
use terrain_core::synth::FractalConfig;
use terrain_stream::{
    BakeConfig, BakeProgress, BlockEntry, Codec, HeightEncoding, HeightSource, ScheduleConfig,
    StatsSummary, Store, StreamConfig, Streamer, bake,
};

fn data() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data")
}

fn scratch() -> PathBuf {
    let d = std::env::temp_dir().join("terrain-stream-bench");
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn go(_: &BakeProgress) -> ControlFlow<()> {
    ControlFlow::Continue(())
}

fn datasets() -> Vec<(&'static str, Heightmap, HeightEncoding, u64)> {
    let mut v = Vec::new();
    let grey = LoadOptions { vertical_scale: 0.1, spacing_m: 160.0, ..Default::default() };
    for (name, file, opts) in [
        ("puget 1k", "puget_sound/ps_height_1k.png", grey.clone()),
        (
            "puget 4k",
            "puget_sound/ps_height_4k.jpg",
            LoadOptions { vertical_scale: 25.6, spacing_m: 40.0, ..Default::default() },
        ),
        ("mt_rainier srtm", "srtm/mt_rainier_90m.tif", LoadOptions::default()),
        ("N42E001 hgt", "srtm/N42E001.hgt", LoadOptions::default()),
        ("everest srtm", "srtm/mt_everest_90m.tif", LoadOptions::default()),
        ("lidar f32", "lidar_prairie/dem.tif", LoadOptions::default()),
    ] {
        let dem = load(data().join(file), &opts).unwrap();
        let enc = HeightEncoding::for_source(&dem.source, &opts);
        let bytes = if dem.source.sample_type.contains("float") {
            4
        } else if dem.source.sample_type.contains("8") {
            1
        } else {
            2
        };
        v.push((name, dem.heightmap, enc, bytes));
    }
    v
}

/// Bytes of the traditional pyramid (every level's full grid, same sample width as plain).
fn pyramid_bytes(store: &Store, sample_bytes: u64) -> u64 {
    let h = store.header();
    let per_block: u64 = (0..=h.k).map(|l| ((1u64 << l) + 1).pow(2)).sum();
    per_block * h.block_count() as u64 * sample_bytes
}

fn storage() {
    println!("\n## Storage (k = 8 unless said; sizes in MB)\n");
    println!(
        "| dataset | samples | raw | full pyramid | non-redundant plain | predictive | predictive + deflate | vs raw | vs pyramid | lossless | bake MB/s |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    let dir = scratch();
    for (name, hm, enc, sb) in datasets() {
        let n = (hm.width() * hm.height()) as u64;
        let mut sizes = Vec::new();
        let mut lossless = false;
        let mut mbs = 0.0;
        let mut pyr = 0;
        for codec in [Codec::Plain, Codec::Predictive, Codec::PredictiveDeflate] {
            let cfg =
                BakeConfig { k: 8, encoding: enc, codec, overwrite: true, ..Default::default() };
            let t = Instant::now();
            let r = bake(&hm, &dir.join("s"), &cfg, &mut go).unwrap();
            mbs = n as f64 * 4.0 / 1e6 / t.elapsed().as_secs_f64();
            let store = Store::open(dir.join("s")).unwrap();
            // Plain payloads hold i16 where values fit, so their width is the pyramid's.
            let w = store.blocks_bytes() as f64
                / (store.header().block_count() as f64
                    * (BlockEntry::resident_bytes(8) / 4) as f64);
            if codec == Codec::Plain {
                pyr = pyramid_bytes(&store, w.round().max(1.0) as u64);
            }
            sizes.push(r.store_bytes);
            lossless = r.lossless;
        }
        let mb = |b: u64| b as f64 / 1e6;
        println!(
            "| {name} | {}x{} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {} | {:.0} |",
            hm.width(),
            hm.height(),
            mb(n * sb),
            mb(pyr),
            mb(sizes[0]),
            mb(sizes[1]),
            mb(sizes[2]),
            sizes[2] as f64 / (n * sb) as f64,
            sizes[2] as f64 / pyr as f64,
            lossless,
            mbs
        );
    }
    println!("\n### Block size on puget 4k\n");
    println!("| k | block | store MB | index KB | bake s |");
    println!("|---|---|---|---|---|");
    let ds = datasets();
    let (_, hm, enc, _) = &ds[1];
    for k in [6u8, 7, 8, 9, 10] {
        let cfg = BakeConfig { k, encoding: *enc, overwrite: true, ..Default::default() };
        let t = Instant::now();
        let r = bake(hm, &dir.join(format!("k{k}")), &cfg, &mut go).unwrap();
        println!(
            "| {k} | {0}^2 | {1:.2} | {2:.0} | {3:.2} |",
            (1 << k) + 1,
            r.store_bytes as f64 / 1e6,
            r.index_bytes as f64 / 1e3,
            t.elapsed().as_secs_f64()
        );
    }
}

/// The payload codecs on real stores (k = 8): sizes of every level payload, and decode speed
/// in MB/s of decoded samples (best of 3; payloads in the page cache, so the time of reading
/// and checking them, measured alone, is subtracted). Deflate over the plain i16 payloads is
/// the off-the-shelf alternative (inflate, then the fixed-width decode).
fn codecs() {
    println!("\n## Codecs (k = 8, every level payload; MB, decode MB/s of decoded samples)\n");
    println!(
        "| dataset | plain | predictive | deflate(plain) | predictive + deflate | predictive MB/s | deflate(plain) MB/s | predictive + deflate MB/s |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    let dir = scratch();
    for (name, hm, enc, _) in
        datasets().into_iter().filter(|d| ["puget 1k", "puget 4k", "N42E001 hgt"].contains(&d.0))
    {
        let mut runs = Vec::new();
        for codec in [Codec::Plain, Codec::Predictive, Codec::PredictiveDeflate] {
            let out = dir.join(format!("codec-{codec:?}"));
            let cfg =
                BakeConfig { k: 8, encoding: enc, codec, overwrite: true, ..Default::default() };
            bake(&hm, &out, &cfg, &mut go).unwrap();
            let store = Store::open(&out).unwrap();
            let k = store.header().k;
            let ids: Vec<_> = store.block_ids().collect();
            let (mut payloads, mut read, mut load) = (Vec::new(), f64::MAX, f64::MAX);
            for _ in 0..3 {
                payloads.clear();
                let t = Instant::now();
                for &id in &ids {
                    for l in 0..=k {
                        payloads.push(store.read_level_bytes(id, l).unwrap());
                    }
                }
                read = read.min(t.elapsed().as_secs_f64());
                let t = Instant::now();
                for &id in &ids {
                    std::hint::black_box(store.read_block(id, k).unwrap());
                }
                load = load.min(t.elapsed().as_secs_f64());
            }
            let decoded = ids.len() as f64 * ((1u64 << k) + 1).pow(2) as f64 * 4.0;
            runs.push((payloads, (load - read).max(1e-9), decoded));
        }
        let mb = |p: &[Vec<u8>]| p.iter().map(Vec::len).sum::<usize>() as f64 / 1e6;
        // Deflate over the plain payloads, level by level.
        let deflated: Vec<Vec<u8>> =
            runs[0].0.iter().map(|p| miniz_oxide::deflate::compress_to_vec(p, 6)).collect();
        let mut inflate = f64::MAX;
        for _ in 0..3 {
            let t = Instant::now();
            for d in &deflated {
                std::hint::black_box(miniz_oxide::inflate::decompress_to_vec(d).unwrap());
            }
            inflate = inflate.min(t.elapsed().as_secs_f64());
        }
        let speed = |secs: f64| runs[0].2 / 1e6 / secs;
        println!(
            "| {name} | {:.2} | {:.2} | {:.2} | {:.2} | {:.0} | {:.0} | {:.0} |",
            mb(&runs[0].0),
            mb(&runs[1].0),
            mb(&deflated),
            mb(&runs[2].0),
            speed(runs[1].1),
            speed(inflate + runs[0].1),
            speed(runs[2].1),
        );
    }
}

/// A circular flight of `frames` frames at `speed` m/s, 60 frames/s, over a store.
fn flight(
    store: &Arc<Store>,
    speed: f64,
    frames: usize,
    budget: u64,
    lookahead: f64,
    alt: f64,
) -> StatsSummary {
    let h = store.header();
    let ext = h.georef.spacing_m * glam::dvec2((h.width - 1) as f64, (h.height - 1) as f64);
    let centre = h.georef.world_origin + ext * 0.5;
    let radius = ext.min_element() * 0.35;
    let schedule = ScheduleConfig { lookahead_frames: lookahead, ..Default::default() };
    let config = StreamConfig { budget_bytes: budget, threads: 0, schedule, ..Default::default() };
    let mut s = Streamer::new(store.clone(), config);
    let mut sum = StatsSummary::default();
    let omega = speed / radius / 60.0; // radians per frame
    let next = Instant::now();
    for f in 0..frames {
        let a = f as f64 * omega;
        let p = centre + glam::dvec2(a.cos(), a.sin()) * radius;
        // Heading along the tangent (counter-clockwise): compass yaw from north.
        let (tx, ty) = (-a.sin(), a.cos());
        let yaw = tx.atan2(ty).to_degrees();
        let cam = Camera::from_yaw_pitch(dvec3(p.x, p.y, alt), yaw, -15.0).with_clip(1.0, 20_000.0);
        let st = s.update(&cam);
        sum.add(&st);
        // Pace the frames at 60 Hz so the workers get real time between them.
        let due = next + std::time::Duration::from_secs_f64((f + 1) as f64 / 60.0);
        if let Some(w) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(w);
        }
    }
    sum
}

fn print_flight(name: &str, speed: f64, lookahead: f64, budget: u64, s: &StatsSummary) {
    let f = s.frames as f64;
    println!(
        "| {name} | {speed} | {lookahead} | {:.2} | {:.3} | {:.3} | {} | {} | {:.1} / {:.0} | {:.3} | {:.2} | {:.2} | {} | {} |",
        s.needed_bytes as f64 / f / 1e6,
        s.sync_bytes as f64 / f / 1e6,
        s.prefetched_bytes as f64 / f / 1e6,
        s.sync_loads,
        s.sync_loads_after_first,
        s.peak_resident_bytes as f64 / 1048576.0,
        budget as f64 / 1048576.0,
        s.io_time.as_secs_f64() * 1e3 / f,
        s.max_io_time.as_secs_f64() * 1e3,
        s.frame_time.as_secs_f64() * 1e3 / f,
        s.evictions,
        s.frames_incomplete
    );
}

fn flights(frames: usize, which: &str) {
    println!(
        "\n## Flights ({frames} frames at 60 Hz, circular path, 15 deg down; per-frame means, MB of decoded samples)\n"
    );
    println!(
        "| terrain | speed m/s | look-ahead frames | needed MB | sync MB | prefetched MB | sync loads | after frame 1 | peak resident / budget MiB | I/O ms/frame | max I/O ms | frame ms | evictions | frames short |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let dir = scratch();
    let budget = 64 << 20;
    if which != "big" {
        let ds = datasets();
        let (_, hm, enc, _) = &ds[1];
        let cfg = BakeConfig { k: 8, encoding: *enc, overwrite: true, ..Default::default() };
        bake(hm, &dir.join("p4k"), &cfg, &mut go).unwrap();
        let store = Arc::new(Store::open(dir.join("p4k")).unwrap());
        for (speed, la) in
            [(100.0, 1.0), (300.0, 1.0), (1000.0, 1.0), (1000.0, 30.0), (3000.0, 30.0)]
        {
            let s = flight(&store, speed, frames, budget, la, 3000.0);
            print_flight("puget 4k", speed, la, budget, &s);
        }
    }
    let big = dir.join("big");
    if which != "puget" && big.join("index.tsi").exists() {
        let store = Arc::new(Store::open(&big).unwrap());
        for (speed, la) in [(300.0, 1.0), (1000.0, 30.0), (3000.0, 30.0)] {
            let s = flight(&store, speed, frames, budget, la, 2500.0);
            print_flight(&format!("synthetic {}", store.header().width), speed, la, budget, &s);
        }
    }
}

/// Peak resident set of this process (Linux `VmHWM`), bytes.
fn peak_rss() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse::<u64>().ok().map(|kb| kb * 1024)
}

/// An overview heightmap of the store at `level` (every block's level-`level` lattice).
fn overview(store: &Store, level: u8) -> Heightmap {
    let h = store.header();
    let level = level.min(h.k);
    let d = 1u64 << (h.k - level);
    let per_block = 1usize << level;
    let (w, hh) = (((h.width - 1) / d + 1) as usize, ((h.height - 1) / d + 1) as usize);
    let mut data = vec![0f32; w * hh];
    for id in store.block_ids() {
        let grid = store.read_block(id, level).unwrap().grid(level).unwrap();
        for bj in 0..=per_block {
            let j = id.row as usize * per_block + bj;
            for bi in 0..=per_block {
                let i = id.col as usize * per_block + bi;
                if i < w && j < hh {
                    data[j * w + i] = grid[bj * (per_block + 1) + bi];
                }
            }
        }
    }
    let g = terrain_core::Georef::projected(
        terrain_core::Crs::Unknown,
        h.georef.world_origin,
        h.georef.spacing_m * d as f64,
    );
    Heightmap::from_fn(w, hh, g, |i, j| data[j * w + i]).unwrap()
}

/// Plays `flight` over the store at its frame rate in real time (see the module docs).
/// `realtime`'s optional `key=value` settings: `in_flight=N` (default 128: on a
/// 16385^2 store far blocks need many small levels at once, and 32 in flight left 55-62 % of
/// frames short of their needed level against 33-35 % with 128; bench/ooc/README.md), `threads=N`
/// (default 0: one per core), `lookahead=F` frames (default 1: the paper's Eq. 8),
/// `latency_aware=0` (the look-ahead not grown by the measured request latency), `ground=DIR`
/// (the flight's ground heights from the local store DIR, the same store: see `realtime`), `trace=1`
/// (one line per late frame on stderr). STORE may be a URL (`s3://`, `http://`...: read
/// through the disk cache, `$TERRAIN_CACHE_DIR`).
fn realtime_config(budget: u64, fps: f64, opts: &[String]) -> (StreamConfig, bool) {
    let mut trace = false;
    let mut config =
        StreamConfig { budget_bytes: budget, max_in_flight: 128, ..Default::default() };
    // Eq. 8's `f` is the flight's frame rate: the latency-aware look-ahead converts the
    // measured request latency into frames with it.
    config.schedule.frame_rate_hz = fps;
    for o in opts {
        let (k, v) = o.split_once('=').expect("key=value");
        match k {
            "in_flight" => config.max_in_flight = v.parse().expect("in_flight=N"),
            "threads" => config.threads = v.parse().expect("threads=N"),
            "lookahead" => config.schedule.lookahead_frames = v.parse().expect("lookahead=F"),
            "latency_aware" => config.schedule.latency_aware = v == "1",
            "trace" => trace = v == "1",
            _ => {
                panic!("unknown setting {k} (in_flight, threads, lookahead, latency_aware, trace)")
            }
        }
    }
    (config, trace)
}

fn realtime(dir: &Path, flight: &Path, cache_mib: u64, opts: &[String]) {
    use terrain_core::flight::{FlightConfig, FlightSpec};
    let store = Arc::new(Store::open_location(dir.to_str().expect("a UTF-8 location")).unwrap());
    let h = store.header().clone();
    let spec = FlightSpec::load(flight).unwrap();
    let cfg = FlightConfig { viewport_px: glam::dvec2(1280.0, 720.0), ..Default::default() };
    // `ground=DIR`: the flight's heights above ground from a local copy of the store, so a
    // remote store is not read (nor its disk cache filled) before the streamer starts.
    let (ground, opts): (Vec<String>, Vec<String>) =
        opts.iter().cloned().partition(|o| o.starts_with("ground="));
    let local;
    let ground: &Store = match ground.last() {
        Some(g) => {
            local = Store::open(&g["ground=".len()..]).unwrap();
            &local
        }
        None => &store,
    };
    let (flight, _) = spec.resolve(&overview(ground, 4), &cfg);
    let ext = h.georef.spacing_m * glam::dvec2((h.width - 1) as f64, (h.height - 1) as f64);
    let budget = cache_mib << 20;
    let (config, trace) = realtime_config(budget, flight.fps, &opts);
    let mut s = Streamer::new(store.clone(), config);
    let mut sum = StatsSummary::default();
    let (mut late, mut needed, mut update_ms) = (Vec::new(), Vec::new(), Vec::new());
    let (mut latency_ms, mut lookahead) = (Vec::new(), Vec::new());
    let fps = flight.fps;
    // Frame k > 0 is due (k - 1) / fps after the first frame returned: the first frame's wait
    // (warm-up, every pinned level 0 fetched) does not eat the flight's time.
    let mut start = Instant::now();
    let mut behind = 0;
    let mut requests = 0;
    let mut first_s = 0.0;
    for (k, cam) in flight.frames().iter().enumerate() {
        // The far plane reaches the far corner of the store (as `terrain render` sets it).
        let far = (cam.position.truncate() - h.georef.world_origin)
            .abs()
            .max((h.georef.world_origin + ext - cam.position.truncate()).abs());
        let cam = cam.with_clip(1.0, far.length() * 1.05 + 1.0);
        if k > 0 {
            let due = start + std::time::Duration::from_secs_f64((k - 1) as f64 / fps);
            match due.checked_duration_since(Instant::now()) {
                Some(w) => std::thread::sleep(w),
                None => behind += 1,
            }
        }
        // The first frame waits until warm (a session's first image); the others never wait.
        let st = if k == 0 {
            let st = s.wait_until_resident(&cam, std::time::Duration::from_secs(120)).stats;
            first_s = start.elapsed().as_secs_f64();
            start = Instant::now();
            st
        } else {
            s.update(&cam)
        };
        if trace && st.late_blocks > 0 {
            eprintln!(
                "frame {k}: late {} blocks / {} levels / {:.3} MB of {:.3} MB needed, queue {}, requests {}, arrived {:.3} MB, update {:.2} ms",
                st.late_blocks,
                st.late_levels,
                st.late_bytes as f64 / 1e6,
                st.needed_bytes as f64 / 1e6,
                st.queue_depth,
                st.requests,
                st.prefetched_bytes as f64 / 1e6,
                st.frame_time.as_secs_f64() * 1e3
            );
        }
        requests += st.requests + st.sync_loads;
        update_ms.push(st.frame_time.as_secs_f64() * 1e3);
        latency_ms.push(st.request_latency.as_secs_f64() * 1e3);
        lookahead.push(st.lookahead_frames);
        late.push(st.late_bytes as f64 / 1e6);
        needed.push(st.needed_bytes as f64 / 1e6);
        sum.add(&st);
    }
    let wall = start.elapsed().as_secs_f64();
    let med = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        (v[v.len() / 2], v[(v.len() * 95 / 100).min(v.len() - 1)], v[v.len() - 1])
    };
    let (l50, l95, lmax) = med(late);
    let (n50, _, _) = med(needed);
    let (u50, u95, umax) = med(update_ms);
    let (r50, _, _) = med(latency_ms);
    let (a50, _, _) = med(lookahead);
    let f = sum.frames as f64;
    println!(
        "\n## Real-time flight `{}` over {} ({} x {} samples, k = {}): {} frames at {} fps, paced\n",
        flight.name,
        dir.display(),
        h.width,
        h.height,
        h.k,
        sum.frames,
        fps
    );
    println!(
        "| frames | waited for I/O after frame 1 | at needed level | late MB/frame median / p95 / max | needed MB median | prefetched MB/frame | sync MB (frame 1) | update ms median / p95 / max | frames behind schedule | peak resident MiB / budget | peak RSS MiB | frame 1 s | wall s after frame 1 | worker request ms median | look-ahead frames median | load requests | cache hits / misses | faults | threads |"
    );
    println!(
        "|---:|---:|---:|---|---:|---:|---:|---|---:|---|---:|---:|---:|---:|---:|---:|---|---:|---:|"
    );
    println!(
        "| {} | {} | {:.1} % | {:.3} / {:.3} / {:.3} | {:.3} | {:.3} | {:.3} | {:.2} / {:.2} / {:.2} | {} | {:.1} / {} | {:.0} | {:.1} | {:.1} | {:.2} | {:.2} | {} | {} / {} | {} | {} |",
        sum.frames,
        sum.frames_waited_after_first,
        100.0 * sum.frames_at_needed_level as f64 / f,
        l50,
        l95,
        lmax,
        n50,
        sum.prefetched_bytes as f64 / f / 1e6,
        sum.sync_bytes as f64 / 1e6,
        u50,
        u95,
        umax,
        behind,
        sum.peak_resident_bytes as f64 / 1048576.0,
        cache_mib,
        peak_rss().map_or(f64::NAN, |b| b as f64 / 1048576.0),
        first_s,
        wall,
        r50,
        a50,
        requests,
        sum.cache_hits,
        sum.cache_misses,
        sum.faults,
        s.threads()
    );
}

fn bake_big(size: u64, k: u8, name: &str) {
    let src = FractalConfig::with_size(size, size, 10.0);
    let cfg = BakeConfig { k, overwrite: true, ..Default::default() };
    let t = Instant::now();
    let mut last = Instant::now();
    let r = bake(&src, &scratch().join(name), &cfg, &mut |p: &BakeProgress| {
        if last.elapsed().as_secs_f64() > 10.0 {
            eprintln!(
                "{}/{} blocks, {:.0} s",
                p.blocks_done,
                p.blocks_total,
                t.elapsed().as_secs_f64()
            );
            last = Instant::now();
        }
        ControlFlow::Continue(())
    })
    .unwrap();
    let s = t.elapsed().as_secs_f64();
    let n = src.width() * src.height();
    println!(
        "synthetic {size}^2 k={k}: {:.1} MB store ({:.3} of f32 raw), {:.1} s, {:.1} MB/s of f32 input, max error {:.4} m",
        r.store_bytes as f64 / 1e6,
        r.store_bytes as f64 / (n * 4) as f64,
        s,
        n as f64 * 4.0 / 1e6 / s,
        r.header.max_error_m
    );
}

/// The synthetic terrain's rows into a raw f32 file, generated a band at a time on every core.
fn write_raw(size: u64, path: &Path) {
    use std::io::Write;
    let src = FractalConfig::with_size(size, size, 10.0);
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let band = 256usize;
    let w = size as usize;
    let mut buf = vec![0f32; w * band];
    // `--raw` files are read north row first; the generator's row 0 is the south row (the
    // one `terrain bake --synthetic` puts at j = 0), so bands are written from the north, each
    // band's rows north first. Written south first, the file was the store's terrain mirrored
    // north-south, and `terrain bench FILE --raw ... --ooc-store STORE` measured the store
    // against that mirror (19 px p99 on fast_pass over big32k; bench/ooc/README.md).
    let mut top = size;
    while top > 0 {
        let n = band.min(top as usize);
        let j0 = top - n as u64;
        let rows = &mut buf[..w * n];
        rows.par_chunks_mut(w).enumerate().for_each(|(r, row)| {
            src.read_rows(j0 + (n - 1 - r) as u64, 1, row).unwrap();
        });
        for z in rows.iter() {
            f.write_all(&z.to_le_bytes()).unwrap();
        }
        top = j0;
    }
    f.flush().unwrap();
}

/// A raw f32 file of `size^2` samples baked by bands of rows (as `terrain bake` streams one).
fn bake_raw(path: &Path, size: u64, k: u8, name: &str) {
    let options = LoadOptions {
        format: Some(terrain_core::dem::Format::Raw),
        raw: Some(terrain_core::dem::RawSpec {
            width: size,
            height: size,
            sample: terrain_core::dem::RawSampleType::F32,
        }),
        ..Default::default()
    };
    let rows = terrain_core::dem::RowReader::open(path, &options).unwrap();
    let cfg = BakeConfig { k, overwrite: true, ..Default::default() };
    let t = Instant::now();
    let r = bake(&rows, &scratch().join(name), &cfg, &mut go).unwrap();
    let s = t.elapsed().as_secs_f64();
    let n = size * size;
    println!(
        "raw f32 {size}^2 k={k}: {:.1} MB store, {:.1} s, {:.1} MB/s of f32 input",
        r.store_bytes as f64 / 1e6,
        s,
        n as f64 * 4.0 / 1e6 / s
    );
}

/// One way to pack a payload's varints: `("miniz", 1, 3)` is miniz level 1, packed again at
/// level 3 where level 1 left under half (the codec's rule); a second level of 0: none.
type Packer = (&'static str, u8, u8);

fn pack_with(p: Packer, varints: &[u8], ld: &mut [Option<libdeflater::Compressor>; 13]) -> Vec<u8> {
    let one = |level: u8, ld: &mut [Option<libdeflater::Compressor>; 13]| -> Vec<u8> {
        if p.0 == "miniz" {
            return miniz_oxide::deflate::compress_to_vec(varints, level);
        }
        if let Some(strategy) = match p.0 {
            "miniz-huffman-only" => {
                Some(miniz_oxide::deflate::core::CompressionStrategy::HuffmanOnly)
            }
            "miniz-rle" => Some(miniz_oxide::deflate::core::CompressionStrategy::RLE),
            _ => None,
        } {
            use miniz_oxide::deflate::core::*;
            let flags = create_comp_flags_from_zip_params(i32::from(level), -15, strategy as i32);
            let mut c = CompressorOxide::new(flags);
            let mut out = vec![0u8; varints.len() * 2 + 64];
            let (status, _, n) = compress(&mut c, varints, &mut out, TDEFLFlush::Finish);
            assert_eq!(status, TDEFLStatus::Done);
            out.truncate(n);
            return out;
        }
        let c = ld[level as usize].get_or_insert_with(|| {
            libdeflater::Compressor::new(
                libdeflater::CompressionLvl::new(i32::from(level)).unwrap(),
            )
        });
        let mut out = vec![0u8; c.deflate_compress_bound(varints.len())];
        let n = c.deflate_compress(varints, &mut out).unwrap();
        out.truncate(n);
        out
    };
    let mut packed = one(p.1, ld);
    if p.2 > 0 && (packed.len() as f64) < 0.5 * varints.len() as f64 {
        let smooth = one(p.2, ld);
        if smooth.len() < packed.len() {
            packed = smooth;
        }
    }
    packed
}

/// `repack STORE...`: every level payload of each store (a predictive store, deflated or not),
/// its varints packed again by each packer: payload bytes against the store's, CPU seconds of
/// packing (one thread, best of 3), and inflating the packed streams with miniz_oxide and with
/// libdeflate.
fn repack(stores: &[String]) {
    let packers: [Packer; 12] = [
        ("miniz-huffman-only", 1, 0),
        ("miniz-rle", 1, 0),
        ("miniz", 1, 3),
        ("miniz", 1, 0),
        ("libdeflate", 1, 0),
        ("libdeflate", 1, 3),
        ("libdeflate", 1, 6),
        ("libdeflate", 2, 0),
        ("libdeflate", 3, 0),
        ("libdeflate", 4, 0),
        ("libdeflate", 6, 0),
        ("libdeflate", 9, 0),
    ];
    for dir in stores {
        let store = Store::open(dir).unwrap();
        let k = store.header().k;
        let mut varints = Vec::new();
        let mut stored = 0usize;
        for id in store.block_ids().collect::<Vec<_>>() {
            for l in 0..=k {
                let p = store.read_level_bytes(id, l).unwrap();
                stored += p.len();
                match p[0] {
                    2 => varints.push(p[1..].to_vec()),
                    3 => varints.push(miniz_oxide::inflate::decompress_to_vec(&p[1..]).unwrap()),
                    _ => {}
                }
            }
        }
        let vb: usize = varints.iter().map(Vec::len).sum();
        println!(
            "\n{dir}: {} payloads, {:.2} MB stored, {:.2} MB of varints in {} payloads\n",
            store.block_ids().count() * (k as usize + 1),
            stored as f64 / 1e6,
            vb as f64 / 1e6,
            varints.len()
        );
        println!(
            "| packer | packed bytes | / miniz 1+3 | pack MB/s of varints | inflate miniz MB/s | inflate libdeflate MB/s |"
        );
        println!("|---|---|---|---|---|---|");
        // Each timing repeats its loop over at least 50 MB of varints (the CPU clock ticks
        // every 10 ms).
        let reps = 50_000_000usize.div_ceil(vb.max(1));
        let mut base = 0usize;
        for p in packers {
            let mut ld: [Option<libdeflater::Compressor>; 13] = Default::default();
            let (mut best, mut packed) = (f64::MAX, Vec::new());
            for _ in 0..3 {
                let t = cpu_s();
                for _ in 0..reps {
                    packed = varints.iter().map(|v| pack_with(p, v, &mut ld)).collect::<Vec<_>>();
                }
                best = best.min((cpu_s() - t) / reps as f64);
            }
            // Each payload keeps the smaller of packed and plain varints (as the codec does).
            let bytes: usize = packed.iter().zip(&varints).map(|(a, b)| a.len().min(b.len())).sum();
            if base == 0 {
                base = bytes;
            }
            let (mut inf_m, mut inf_l) = (f64::MAX, f64::MAX);
            let mut d = libdeflater::Decompressor::new();
            let mut out = vec![0u8; varints.iter().map(Vec::len).max().unwrap_or(0)];
            for _ in 0..3 {
                let t = cpu_s();
                for _ in 0..reps {
                    for (c, v) in packed.iter().zip(&varints) {
                        let r = miniz_oxide::inflate::decompress_to_vec(c).unwrap();
                        assert_eq!(r.len(), v.len());
                    }
                }
                inf_m = inf_m.min((cpu_s() - t) / reps as f64);
                let t = cpu_s();
                for _ in 0..reps {
                    for (c, v) in packed.iter().zip(&varints) {
                        let n = d.deflate_decompress(c, &mut out).unwrap();
                        assert_eq!(&out[..n], &v[..]);
                    }
                }
                inf_l = inf_l.min((cpu_s() - t) / reps as f64);
            }
            println!(
                "| {} {}{} | {bytes} | {:.4} | {:.1} | {:.0} | {:.0} |",
                p.0,
                p.1,
                if p.2 > 0 { format!(" (+{} below half)", p.2) } else { String::new() },
                bytes as f64 / base as f64,
                vb as f64 / 1e6 / best,
                vb as f64 / 1e6 / inf_m,
                vb as f64 / 1e6 / inf_l,
            );
        }
    }
}

/// This process's CPU seconds (user + system), from `/proc/self/stat`.
fn cpu_s() -> f64 {
    let s = std::fs::read_to_string("/proc/self/stat").unwrap();
    let f: Vec<&str> = s.rsplit(')').next().unwrap().split_whitespace().collect();
    (f[11].parse::<f64>().unwrap() + f[12].parse::<f64>().unwrap()) / 100.0
}

/// `compare STORE_A STORE_B`: both stores decode to the same heights (every level of every
/// block, and the same blocks), and the CPU seconds each takes to decode (every block to its
/// finest level, this build's reader, best of 3 rounds).
fn compare(a: &Path, b: &Path) {
    let (sa, sb) = (Store::open(a).unwrap(), Store::open(b).unwrap());
    let ids: Vec<_> = sa.block_ids().collect();
    assert_eq!(ids, sb.block_ids().collect::<Vec<_>>(), "other blocks");
    let k = sa.header().k;
    assert_eq!(k, sb.header().k, "other k");
    for &id in &ids {
        let (la, lb) = (sa.read_block(id, k).unwrap(), sb.read_block(id, k).unwrap());
        assert!(la.levels() == lb.levels(), "block {id:?} decodes to other heights");
    }
    let decode = |s: &Store| {
        let t = cpu_s();
        for &id in &ids {
            std::hint::black_box(s.read_block(id, k).unwrap());
        }
        cpu_s() - t
    };
    let (mut ta, mut tb) = (f64::MAX, f64::MAX);
    for _ in 0..3 {
        ta = ta.min(decode(&sa));
        tb = tb.min(decode(&sb));
    }
    println!(
        "{} blocks (k = {k}) decode to the same heights; blocks {:.2} MB / {:.2} MB; decode {:.3} / {:.3} CPU s ({:.1} / {:.1} ms a block)",
        ids.len(),
        sa.blocks_bytes() as f64 / 1e6,
        sb.blocks_bytes() as f64 / 1e6,
        ta,
        tb,
        ta * 1e3 / ids.len() as f64,
        tb * 1e3 / ids.len() as f64
    );
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.first().map(String::as_str) {
        Some("storage") => storage(),
        Some("codec") => codecs(),
        Some("repack") => repack(&args[1..]),
        Some("compare") => compare(
            Path::new(args.get(1).expect("compare STORE_A STORE_B")),
            Path::new(args.get(2).expect("compare STORE_A STORE_B")),
        ),
        Some("flight") => flights(
            args.get(1).and_then(|s| s.parse().ok()).unwrap_or(10_000),
            args.get(2).map_or("all", String::as_str),
        ),
        Some("bake") => bake_big(
            args.get(1).and_then(|s| s.parse().ok()).unwrap_or(16385),
            args.get(2).and_then(|s| s.parse().ok()).unwrap_or(8),
            args.get(3).map_or("big", String::as_str),
        ),
        Some("raw") => write_raw(
            args.get(1).and_then(|s| s.parse().ok()).expect("raw SIZE PATH"),
            Path::new(args.get(2).expect("raw SIZE PATH")),
        ),
        Some("bakeraw") => bake_raw(
            Path::new(args.get(1).expect("bakeraw PATH SIZE K NAME")),
            args.get(2).and_then(|s| s.parse().ok()).expect("bakeraw PATH SIZE K NAME"),
            args.get(3).and_then(|s| s.parse().ok()).unwrap_or(8),
            args.get(4).map_or("raw", String::as_str),
        ),
        Some("upload") => {
            let (dir, url) = (
                Path::new(args.get(1).expect("upload STORE_DIR URL")),
                args.get(2).expect("upload STORE_DIR URL"),
            );
            let t = Instant::now();
            let r =
                terrain_stream::upload_store(dir, url, &terrain_stream::RemoteOptions::default())
                    .unwrap();
            println!(
                "{url}: uploaded {} files, {:.1} MB ({} multipart), {:.1} s",
                r.files,
                r.bytes as f64 / 1e6,
                r.multipart,
                t.elapsed().as_secs_f64()
            );
        }
        Some("realtime") => realtime(
            Path::new(args.get(1).expect("realtime STORE FLIGHT [CACHE_MIB]")),
            Path::new(args.get(2).expect("realtime STORE FLIGHT [CACHE_MIB]")),
            args.get(3).and_then(|s| s.parse().ok()).unwrap_or(256),
            args.get(4..).unwrap_or(&[]),
        ),
        _ => {
            storage();
            codecs();
            flights(10_000, "all");
        }
    }
}
