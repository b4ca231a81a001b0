//! `cargo xtask`: developer workflows that are code rather than shell (matklad's cargo-xtask).
//!
//! Tasks: `papers` (the source papers' result tables regenerated beside the papers' numbers,
//! with verdicts: [`papers`]), `lint` (the formatting and clippy gates of `.ci/run`), `bench` (every LOD method
//! over the shipped flights, through `terrain bench` built in release; results in
//! `out/bench/`) and `fuzz` (builds the `terrain-fuzz` harness with the `fuzz` profile and
//! runs it on the shared DEMs and the corpus; failing cases in `target/fuzz-run/failures/`).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, bail};

mod papers;

const USAGE: &str = "cargo xtask <task>

tasks:
  lint    cargo fmt --check and clippy with warnings denied
  bench   [--quick] [--dem default|puget1k|PATH]... [--methods a,b,..] [--flight FILE]...
          [--frames N] [--out DIR]
          every method over every flight, each threshold swept; writes
          DIR/<dem>-<backend>.{json,md,svg} (DIR default out/bench).
          --quick: the default backend only, 5 frames per flight, 3 sweep points, 320x180,
          ooc's frames warm, the embedded terrain and Puget Sound 1k, flight pvps_884
          (under 5 minutes on two cores).
          Full: Vulkan then GL, 60 frames per flight, 5 sweep points, 640x360, every flight.
  fuzz    [--minutes N] [--seed S] [--iterations N] [--timeout SECONDS] | --replay CASE_DIR
          mutants of the shared DEMs (TERRAIN_DATA or ../shared/data), the GeoTIFF corpus and a
          tiny store through every reader, in-process; fails on a panic, a case over its
          deadline (10 s of CPU) or an allocation over 1 GiB (readers' limit 256 MiB). Failing cases
          are saved in target/fuzz-run/failures/ for --replay.
  papers  [--paper pvps|ooc|geomorph|entropy|dss]... [--quick] [--out DIR] [--store NAME=DIR]...
          [--terrain BINARY]
          each paper's result tables in its own layout, run on the shared data through
          `terrain bench`, `bake` and `info` built in release, beside the paper's numbers with a
          computed verdict per claim; Markdown + JSON (+ SVG) in DIR/<paper>/ (default
          bench/papers, --quick: out/papers-quick). --store adds a baked store to the
          out-of-core paper's Table 1; --terrain runs a given binary instead of building one.
          Fails when a table or verdict could not be computed.
          --quick: few frames, small images (under 10 minutes on two cores).";

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.first().map(String::as_str) {
        Some("lint") => lint(),
        Some("bench") => bench(&args[1..]),
        Some("fuzz") => fuzz(&args[1..]),
        Some("papers") => papers::papers(&args[1..]),
        Some(other) => bail!("unknown task `{other}`; tasks: lint, bench, fuzz, papers"),
        None => {
            println!("{USAGE}");
            Ok(())
        }
    }
}

fn lint() -> anyhow::Result<()> {
    run("cargo", &["fmt", "--all", "--", "--check"])?;
    run("cargo", &["clippy", "--workspace", "--all-targets", "--", "-D", "warnings"])
}

fn run(program: &str, args: &[&str]) -> anyhow::Result<()> {
    let status = Command::new(program)
        .args(args)
        .status()
        .with_context(|| format!("could not start {program}"))?;
    if !status.success() {
        bail!("{program} {} failed with {status}", args.join(" "));
    }
    Ok(())
}

/// The workspace root: xtask's manifest folder's parent.
fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("xtask has a parent").to_path_buf()
}

/// The shared DEM folder: `$TERRAIN_DATA`, else `../shared/data` beside the checkout.
fn data_dir() -> PathBuf {
    std::env::var_os("TERRAIN_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| root().join("../shared/data"))
}

/// Builds the harness (release speed, our crates' overflow checks on: the `fuzz` profile) and
/// runs it; its own options pass through.
fn fuzz(args: &[String]) -> anyhow::Result<()> {
    run("cargo", &["build", "--profile", "fuzz", "-q", "-p", "terrain-fuzz"])?;
    let bin = root().join("target/fuzz/terrain-fuzz");
    let out = root().join("target/fuzz-run");
    let mut cmd = Command::new(&bin);
    cmd.arg("--data").arg(data_dir());
    cmd.arg("--corpus").arg(root().join("terrain-core/tests/data/geotiff"));
    cmd.arg("--out").arg(&out).args(args);
    let status = cmd.status().with_context(|| format!("could not start {}", bin.display()))?;
    if status.code().is_none() {
        // Killed by a signal: an abort on an allocation refused over the limit (the harness
        // saved the case before running it), or the machine's OOM killer.
        let current = out.join("work/current");
        bail!(
            "the fuzz harness died ({status}) while running the case saved in {}; replay it \
             with `cargo xtask fuzz --replay {}` after copying it elsewhere",
            current.display(),
            current.display()
        );
    }
    if !status.success() {
        bail!("fuzzing found failures ({status}): see the FAIL lines above");
    }
    Ok(())
}

/// A DEM of the benchmark: a report name and the `terrain bench` arguments that load it.
fn dem_args(spec: &str) -> anyhow::Result<(String, Vec<String>)> {
    let data = data_dir();
    Ok(match spec {
        "default" => ("default".to_string(), vec![]),
        "puget1k" => {
            let p = data.join("puget_sound/ps_height_1k.png");
            if !p.exists() {
                bail!("{} is missing (set TERRAIN_DATA)", p.display());
            }
            let args = ["--vertical-scale", "0.1", "--spacing", "160"];
            (
                "puget1k".to_string(),
                std::iter::once(p.display().to_string())
                    .chain(args.iter().map(|s| s.to_string()))
                    .collect(),
            )
        }
        path => {
            let p = Path::new(path);
            let name = p.file_stem().map(|s| s.to_string_lossy().into_owned());
            (name.unwrap_or_else(|| "dem".to_string()), vec![path.to_string()])
        }
    })
}

fn bench(args: &[String]) -> anyhow::Result<()> {
    let (mut quick, mut dems, mut flights, mut extra) = (false, vec![], vec![], vec![]);
    let mut out = root().join("out/bench");
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = || it.next().with_context(|| format!("{a} needs a value"));
        match a.as_str() {
            "--quick" => quick = true,
            "--dem" => dems.push(value()?.clone()),
            "--flight" => flights.push(PathBuf::from(value()?)),
            "--methods" | "--frames" | "--sweep" | "--size" => {
                extra.extend([a.clone(), value()?.clone()]);
            }
            "--out" => out = PathBuf::from(value()?),
            other => bail!("unknown bench option `{other}`\n\n{USAGE}"),
        }
    }
    if dems.is_empty() {
        dems = vec!["default".to_string(), "puget1k".to_string()];
    }
    if flights.is_empty() {
        let dir = root().join("flights");
        flights = if quick {
            vec![dir.join("pvps_884.json")]
        } else {
            let mut v: Vec<PathBuf> = std::fs::read_dir(&dir)
                .with_context(|| format!("could not list {}", dir.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e == "json"))
                .collect();
            v.sort();
            v
        };
    }
    // Quick: whichever backend `terrain` picks (Vulkan first); full: each backend in turn.
    let backends: &[Option<&str>] = if quick { &[None] } else { &[Some("vulkan"), Some("gl")] };
    let start = Instant::now();
    run("cargo", &["build", "--release", "-q", "-p", "terrain-app"])?;
    let terrain = root().join("target/release/terrain");
    let mut written = Vec::new();
    for dem in &dems {
        let (name, load) = dem_args(dem)?;
        for backend in backends {
            let report = format!("{name}-{}", backend.unwrap_or("quick"));
            let mut cmd = Command::new(&terrain);
            cmd.arg("bench").args(&load).arg("--name").arg(&report).arg("--out").arg(&out);
            for f in &flights {
                cmd.arg("--flight").arg(f);
            }
            if quick {
                cmd.arg("--quick");
            }
            cmd.args(&extra);
            if let Some(b) = backend {
                cmd.env("TERRAIN_GPU_BACKEND", b);
            }
            println!("== {report}: {cmd:?}");
            let status =
                cmd.status().with_context(|| format!("could not start {}", terrain.display()))?;
            if !status.success() {
                bail!("terrain bench for {report} failed with {status}");
            }
            written.push(out.join(format!("{report}.md")));
        }
    }
    println!("\nbench done in {:.1} s; reports:", start.elapsed().as_secs_f64());
    for w in &written {
        println!("  {}", w.display());
    }
    Ok(())
}
