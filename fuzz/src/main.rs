//! `terrain-fuzz`: the fuzzing harness `cargo xtask fuzz` builds and runs (stable Rust, no
//! cargo-fuzz). Seeded, deterministic mutants of the real DEMs, the conformance corpus and a
//! tiny baked store go through every reader in-process; a case fails on a panic (caught per
//! case), on running past its deadline (each case runs on a worker thread), or on asking for
//! an allocation over `--max-alloc` (a counting global allocator) while the readers' memory
//! limit is `--max-memory`. A failing case is saved as a folder that `--replay` runs again.

mod alloc;
mod case;
mod mutate;
mod rng;
mod seeds;
mod store;

use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::mpsc::{RecvTimeoutError, channel};
use std::time::{Duration, Instant};

use terrain_core::dem::{Format, RawSampleType, RawSpec};

use crate::case::{Case, Opts, Target};
use crate::mutate::Kind;
use crate::rng::Rng;
use crate::seeds::Seed;
use crate::store::Pristine;

const USAGE: &str = "terrain-fuzz [--minutes N] [--iterations N] [--seed S] [--timeout SECONDS]
             [--max-memory BYTES] [--max-alloc BYTES] [--data DIR] [--corpus DIR] [--out DIR]
             [--progress SECONDS] | --replay CASE_DIR";

/// The run's settings.
#[derive(Debug, Clone)]
struct Config {
    minutes: f64,
    iterations: Option<u64>,
    seed: u64,
    timeout: Duration,
    /// The readers' `LoadOptions::max_memory_bytes`.
    max_memory: u64,
    /// A single allocation above this fails the case (and is refused).
    max_alloc: u64,
    data: PathBuf,
    corpus: PathBuf,
    out: PathBuf,
    progress: Duration,
    replay: Option<PathBuf>,
}

fn parse(args: &[String]) -> Result<Config, String> {
    let mut c = Config {
        minutes: 1.0,
        iterations: None,
        seed: 1,
        timeout: Duration::from_secs(10),
        max_memory: 256 << 20,
        max_alloc: 1 << 30,
        data: PathBuf::from("../shared/data"),
        corpus: PathBuf::from("terrain-core/tests/data/geotiff"),
        out: std::env::temp_dir().join("terrain-fuzz"),
        progress: Duration::from_secs(10),
        replay: None,
    };
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = || it.next().ok_or_else(|| format!("{a} needs a value\n{USAGE}"));
        let num = |v: &String| v.parse::<f64>().map_err(|_| format!("{a}: `{v}` is not a number"));
        match a.as_str() {
            "--minutes" => c.minutes = num(value()?)?,
            "--iterations" => c.iterations = Some(num(value()?)? as u64),
            "--seed" => c.seed = value()?.parse().map_err(|_| format!("{a} takes an integer"))?,
            "--timeout" => c.timeout = Duration::from_secs_f64(num(value()?)?),
            "--max-memory" => c.max_memory = num(value()?)? as u64,
            "--max-alloc" => c.max_alloc = num(value()?)? as u64,
            "--data" => c.data = PathBuf::from(value()?),
            "--corpus" => c.corpus = PathBuf::from(value()?),
            "--out" => c.out = PathBuf::from(value()?),
            "--progress" => c.progress = Duration::from_secs_f64(num(value()?)?),
            "--replay" => c.replay = Some(PathBuf::from(value()?)),
            "-h" | "--help" => return Err(USAGE.to_string()),
            other => return Err(format!("unknown option `{other}`\n{USAGE}")),
        }
    }
    Ok(c)
}

/// The last panic's message, location and backtrace (the hook keeps the run's output quiet).
static LAST_PANIC: Mutex<String> = Mutex::new(String::new());

/// How a case ended.
#[derive(Debug)]
enum Outcome {
    /// The reader returned: what it read, or its error (a refusal).
    Returned(Result<String, String>),
    Panicked(String),
    TimedOut,
}

/// What a run needs besides its settings.
struct Harness {
    config: Config,
    seeds: Vec<Seed>,
    stores: Vec<Pristine>,
    work: PathBuf,
}

impl Harness {
    /// The case of iteration `i`: a mutated DEM (80 %) or a mutated store file.
    fn make_case(&self, i: u64) -> Case {
        let seed = self.config.seed;
        let mut rng = Rng::for_case(seed, i);
        if rng.chance(0.2) {
            return store::make_case(&self.stores, &mut rng, seed, i);
        }
        let s = rng.pick(&self.seeds);
        let donor = &rng.pick(&self.seeds).bytes;
        let mut bytes = s.bytes.clone();
        let what = mutate::mutate(&mut bytes, s.kind, &mut rng, donor);
        let mut opts = Opts { format: None, raw: None, nodata: None, vertical_scale: 1.0 };
        if rng.chance(0.1) {
            opts.nodata = Some(*rng.pick(&[-32768.0, -32767.0, 0.0, -9999.0, f64::NAN, 1e300]));
        }
        if rng.chance(0.05) {
            opts.vertical_scale = *rng.pick(&[0.1, 25.6, 1e35, -1.0, 0.0, f64::NAN]);
        }
        if let Some(raw) = s.raw {
            opts.format = Some(Format::Raw);
            opts.raw = Some(if rng.chance(0.8) {
                raw
            } else {
                let dim = [0u64, 1, 2, 63, 64, 65, 1 << 16, 1 << 31, u64::MAX];
                let sample =
                    *rng.pick(&[RawSampleType::I16, RawSampleType::U16, RawSampleType::F32]);
                RawSpec { width: *rng.pick(&dim), height: *rng.pick(&dim), sample }
            });
        } else if s.kind == Kind::Png && rng.chance(0.4) {
            opts.format = Some(*rng.pick(&[Format::TerrainRgb, Format::Terrarium]));
        } else if rng.chance(0.03) {
            opts.format = Some(*rng.pick(&[Format::GeoTiff, Format::Hgt, Format::GreyImage]));
        }
        let mut files = vec![(s.name.clone(), bytes)];
        let hgt = s.name.to_ascii_lowercase().ends_with(".hgt");
        let target = if (s.kind == Kind::Tiff || s.raw.is_some()) && rng.chance(0.3) {
            Target::Rows(opts)
        } else if hgt && rng.chance(0.25) {
            let partners: Vec<&Seed> = self
                .seeds
                .iter()
                .filter(|p| p.name != s.name && p.name.to_ascii_lowercase().ends_with(".hgt"))
                .collect();
            if partners.is_empty() {
                Target::Load(opts)
            } else {
                let p = rng.pick(&partners);
                files.push((p.name.clone(), p.bytes.clone()));
                Target::Mosaic(opts)
            }
        } else {
            Target::Load(opts)
        };
        Case { target, files, seed, iteration: i, what: format!("{}: {what}", s.name) }
    }

    /// Writes the case into `work/current` (left there if the process dies) and runs it on a
    /// worker thread under the deadline.
    fn run_case(&self, case: &Case) -> Outcome {
        let current = self.work.join("current");
        if let Err(e) = case.save(&current) {
            return Outcome::Returned(Err(format!("harness: could not write the case: {e}")));
        }
        let dir = match &case.target {
            Target::Store(n) => {
                let dir = self.work.join("current-store");
                if let Err(e) = materialise(&self.stores[*n], &case.files, &dir) {
                    return Outcome::Returned(Err(format!("harness: {e}")));
                }
                dir
            }
            _ => current,
        };
        let target = case.target.clone();
        let names: Vec<String> = case.files.iter().map(|(n, _)| n.clone()).collect();
        let max_memory = self.config.max_memory;
        let (tx, rx) = channel();
        let (tid_tx, tid_rx) = channel();
        alloc::start_case();
        let worker = std::thread::Builder::new().name("fuzz-case".into()).spawn(move || {
            // `/proc/thread-self` links to `<pid>/task/<tid>`, relative to /proc.
            let _ = tid_tx.send(
                std::fs::read_link("/proc/thread-self").ok().map(|t| Path::new("/proc").join(t)),
            );
            let r = std::panic::catch_unwind(AssertUnwindSafe(|| match &target {
                Target::Store(_) => store::run(&dir),
                t => case::run_dem(t, &dir, &names, max_memory),
            }));
            let _ = tx.send(r);
        });
        let Ok(worker) = worker else {
            return Outcome::Returned(Err("harness: could not start a worker thread".into()));
        };
        // The deadline is on the case's CPU time where the system says it (Linux: /proc), so a
        // busy machine does not turn a slow case into a time-out; a case that waits without
        // computing (blocked, or busy on other threads) still fails at 6x in wall time.
        let cpu_stat = tid_rx.recv().ok().flatten().map(|t| t.join("stat"));
        let start = Instant::now();
        let timeout = self.config.timeout;
        let received = loop {
            match rx.recv_timeout(Duration::from_millis(100).min(timeout)) {
                Err(RecvTimeoutError::Timeout) => {
                    let cpu = cpu_stat.as_deref().and_then(thread_cpu_time);
                    let wall = start.elapsed();
                    if cpu.map_or(wall >= timeout, |c| c >= timeout) || wall >= timeout * 6 {
                        break Err(RecvTimeoutError::Timeout);
                    }
                }
                other => break other,
            }
        };
        match received {
            Ok(Ok(r)) => {
                let _ = worker.join();
                Outcome::Returned(r)
            }
            Ok(Err(_)) | Err(RecvTimeoutError::Disconnected) => {
                let _ = worker.join();
                Outcome::Panicked(std::mem::take(&mut *LAST_PANIC.lock().expect("panic message")))
            }
            // The worker is left running: the run stops after reporting.
            Err(RecvTimeoutError::Timeout) => Outcome::TimedOut,
        }
    }
}

/// CPU time (user + system) of the thread whose `/proc/.../stat` is `stat`, at the kernel's
/// usual 100 ticks a second (`USER_HZ`), or `None` where it cannot be read.
fn thread_cpu_time(stat: &Path) -> Option<Duration> {
    let text = std::fs::read_to_string(stat).ok()?;
    // Fields after the command name (which is in parentheses and may hold spaces): state is
    // field 3, utime and stime are fields 14 and 15.
    let rest = &text[text.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?;
    Some(Duration::from_millis(ticks * 10))
}

/// A copy of the pristine store with `files` replacing its own, in `dir`.
fn materialise(store: &Pristine, files: &[(String, Vec<u8>)], dir: &Path) -> std::io::Result<()> {
    if dir.exists() {
        std::fs::remove_dir_all(dir)?;
    }
    for (name, bytes) in &store.files {
        let bytes = files.iter().find(|(n, _)| n == name).map_or(bytes, |(_, b)| b);
        let p = dir.join(name);
        std::fs::create_dir_all(p.parent().expect("a file in the store"))?;
        std::fs::write(p, bytes)?;
    }
    Ok(())
}

fn mib(bytes: usize) -> String {
    format!("{:.1} MiB", bytes as f64 / (1 << 20) as f64)
}

/// Counts of a run.
#[derive(Debug, Default)]
struct Tally {
    iterations: u64,
    panics: u64,
    timeouts: u64,
    over_limit: u64,
    largest: usize,
    /// Per target: (read, refused).
    per_target: std::collections::BTreeMap<&'static str, (u64, u64)>,
    saved: Vec<PathBuf>,
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let config = match parse(&args) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(2);
        }
    };
    std::process::exit(match run(config) {
        Ok(true) => 0,
        Ok(false) => 1,
        Err(e) => {
            eprintln!("terrain-fuzz: {e}");
            2
        }
    });
}

/// Runs the fuzzing loop (or a replay); `Ok(false)` when a case failed.
fn run(config: Config) -> Result<bool, String> {
    std::panic::set_hook(Box::new(|info| {
        // The backtrace's frames in our crates (with their file and line) are what a fix needs.
        let bt = std::backtrace::Backtrace::force_capture().to_string();
        let lines: Vec<&str> = bt.lines().collect();
        let mut ours = Vec::new();
        for (k, l) in lines.iter().enumerate() {
            if l.contains("terrain_") && !l.contains("terrain_fuzz") {
                ours.push(l.trim().to_string());
                if let Some(at) = lines.get(k + 1).filter(|n| n.trim().starts_with("at ")) {
                    ours.push(format!("  {}", at.trim()));
                }
            }
        }
        *LAST_PANIC.lock().unwrap_or_else(|p| p.into_inner()) =
            format!("{info}\n{}", ours.join("\n"));
    }));
    let work = config.out.join("work");
    std::fs::create_dir_all(&work).map_err(|e| format!("{}: {e}", work.display()))?;
    let stores = store::fixture(&work)?;
    // The fixture is made; from now on an allocation over the limit is a finding.
    alloc::set_cap(config.max_alloc);

    if let Some(dir) = config.replay.clone() {
        let case = Case::load(&dir)?;
        let h = Harness { config, seeds: Vec::new(), stores, work };
        println!("replay {}: {} ({})", dir.display(), case.target.name(), case.what);
        let outcome = h.run_case(&case);
        let (largest, refused) = alloc::case_largest();
        println!("largest allocation {}", mib(largest));
        return Ok(match outcome {
            Outcome::Returned(r) if refused == 0 => {
                println!("returned: {r:?}");
                true
            }
            Outcome::Returned(_) => {
                println!(
                    "FAIL: an allocation of {refused} bytes (over --max-alloc {})",
                    h.config.max_alloc
                );
                false
            }
            Outcome::Panicked(m) => {
                println!("FAIL: panic: {m}");
                false
            }
            Outcome::TimedOut => {
                println!("FAIL: still running after {:?} of CPU time", h.config.timeout);
                std::process::exit(1);
            }
        });
    }

    let seeds = seeds::collect(&config.data, &config.corpus)?;
    println!(
        "fuzz: seed {}, {:.1} minutes, {} seed files ({:.1} MiB) + {} store files, readers' \
         memory limit {}, allocation limit {}, {:?} per case",
        config.seed,
        config.minutes,
        seeds.len(),
        seeds.iter().map(|s| s.bytes.len()).sum::<usize>() as f64 / (1 << 20) as f64,
        stores.iter().map(|s| s.files.len()).sum::<usize>(),
        mib(config.max_memory as usize),
        mib(config.max_alloc as usize),
        config.timeout
    );
    let failures = config.out.join("failures");
    let h = Harness { config, seeds, stores, work };
    let start = Instant::now();
    let deadline = Duration::from_secs_f64(h.config.minutes.max(0.0) * 60.0);
    let mut t = Tally::default();
    let mut last_progress = Instant::now();
    let mut i = 0u64;
    loop {
        if start.elapsed() >= deadline || h.config.iterations.is_some_and(|n| i >= n) {
            break;
        }
        let case = h.make_case(i);
        let outcome = h.run_case(&case);
        let (largest, refused) = alloc::case_largest();
        t.largest = t.largest.max(largest);
        t.iterations += 1;
        let failure = match &outcome {
            Outcome::Returned(r) => {
                let e = t.per_target.entry(case.target.name()).or_default();
                if r.is_ok() {
                    e.0 += 1
                } else {
                    e.1 += 1
                }
                (refused > 0).then(|| {
                    t.over_limit += 1;
                    format!(
                        "an allocation of {refused} bytes, over --max-alloc {}",
                        h.config.max_alloc
                    )
                })
            }
            Outcome::Panicked(m) => {
                t.panics += 1;
                Some(format!("panic: {m}"))
            }
            Outcome::TimedOut => {
                t.timeouts += 1;
                Some(format!(
                    "still running after {:?} of CPU time (or 6x that in wall time)",
                    h.config.timeout
                ))
            }
        };
        if let Some(f) = failure {
            let dir = failures.join(format!("s{}-i{i}", h.config.seed));
            let saved = if t.saved.len() < 50 { case.save(&dir).map(|_| true) } else { Ok(false) };
            println!(
                "FAIL at iteration {i} (seed {}): {} [{}]",
                h.config.seed,
                case.what,
                case.target.name()
            );
            println!("  {}", f.lines().take(40).collect::<Vec<_>>().join("\n  "));
            match saved {
                Ok(true) => {
                    println!(
                        "  saved: {}; replay: cargo xtask fuzz --replay {}",
                        dir.display(),
                        dir.display()
                    );
                    t.saved.push(dir);
                }
                Ok(false) => println!("  (not saved: 50 cases are)"),
                Err(e) => println!("  could not save the case: {e}"),
            }
        }
        if matches!(outcome, Outcome::TimedOut) {
            break;
        }
        i += 1;
        if last_progress.elapsed() >= h.config.progress {
            last_progress = Instant::now();
            let s = start.elapsed().as_secs_f64();
            println!(
                "fuzz: {s:.0} s, {} iterations, {:.1} cases/s, peak memory {}, largest \
                 allocation {}, panics {}, time-outs {}, over the limit {}",
                t.iterations,
                t.iterations as f64 / s,
                mib(alloc::peak_live()),
                mib(t.largest),
                t.panics,
                t.timeouts,
                t.over_limit
            );
        }
    }
    let s = start.elapsed().as_secs_f64();
    println!("fuzz summary (seed {}, {s:.0} s):", h.config.seed);
    println!("  iterations: {} ({:.1} cases/s)", t.iterations, t.iterations as f64 / s.max(1e-9));
    for (name, (read, refused)) in &t.per_target {
        println!("  {name}: {read} read, {refused} refused");
    }
    println!("  panics: {}", t.panics);
    println!("  time-outs: {}", t.timeouts);
    println!("  allocations over the limit: {}", t.over_limit);
    println!(
        "  peak allocated: {} live; largest single allocation {}",
        mib(alloc::peak_live()),
        mib(t.largest)
    );
    for d in &t.saved {
        println!("  failing case: {}", d.display());
    }
    let ok = t.panics == 0 && t.timeouts == 0 && t.over_limit == 0;
    if !ok {
        // A timed-out worker may still be running: leave without waiting for it.
        use std::io::Write;
        let _ = std::io::stdout().flush();
        std::process::exit(1);
    }
    Ok(ok)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(target_os = "linux")]
    #[test]
    fn a_threads_cpu_time_is_read_from_proc() {
        let stat =
            Path::new("/proc").join(std::fs::read_link("/proc/thread-self").unwrap()).join("stat");
        let before = thread_cpu_time(&stat).unwrap();
        let spin = Instant::now();
        let mut x = 0u64;
        while spin.elapsed() < Duration::from_millis(300) {
            x = std::hint::black_box(x.wrapping_mul(31).wrapping_add(7));
        }
        let spent = thread_cpu_time(&stat).unwrap() - before;
        // Busy for 300 ms of wall time: at least some of it on this thread's CPU clock, and
        // never more than the wall time (plus a tick).
        assert!(spent > Duration::ZERO && spent <= Duration::from_millis(320), "{spent:?}");
    }
}
