//! `cargo xtask papers`: each source paper's result tables regenerated in the paper's layout
//! by the `terrain` commands (bench, bake, info) on the shared data, the paper's numbers for
//! the same rows beside ours, and a computed verdict per claim; written as Markdown + JSON (+
//! SVG figures) under `bench/papers/<paper>/` (`--out` elsewhere; `--quick` defaults to
//! `out/papers-quick`, git-ignored).

mod doc;
mod dss;
mod entropy;
mod geomorph;
mod ooc;
mod pvps;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, bail};
use serde_json::Value;

pub(crate) use doc::PaperDoc;

/// The papers, in the order `--paper` names them.
pub(crate) const PAPERS: [&str; 5] = ["pvps", "ooc", "geomorph", "entropy", "dss"];

/// A run of `cargo xtask papers`: where the binary, the data and the outputs are, and what it
/// ran.
pub(crate) struct Ctx {
    /// The release `terrain` binary.
    pub(crate) terrain: PathBuf,
    /// The shared DEMs.
    pub(crate) data: PathBuf,
    /// The flights folder.
    pub(crate) flights: PathBuf,
    /// Scratch: the raw `terrain bench` reports and baked stores (under `out/`, git-ignored).
    pub(crate) work: PathBuf,
    /// Few frames and small settings.
    pub(crate) quick: bool,
    /// Baked stores given with `--store NAME=DIR` (read only).
    pub(crate) stores: Vec<(String, PathBuf)>,
    /// The commands run for the current paper, as text.
    pub(crate) commands: Vec<String>,
}

impl Ctx {
    /// The shared Puget Sound 1k DEM and its reading options (the README's).
    pub(crate) fn puget1k(&self) -> anyhow::Result<Vec<String>> {
        let p = self.data.join("puget_sound/ps_height_1k.png");
        if !p.exists() {
            bail!("{} is missing (set TERRAIN_DATA)", p.display());
        }
        Ok(vec![
            p.display().to_string(),
            "--vertical-scale".into(),
            "0.1".into(),
            "--spacing".into(),
            "160".into(),
        ])
    }

    /// The shared Puget Sound 4k DEM (8-bit JPEG, terraced) and its reading options (the
    /// data README's: about 25.6 m per grey level, about 40 m spacing).
    pub(crate) fn puget4k(&self) -> anyhow::Result<Vec<String>> {
        let p = self.data.join("puget_sound/ps_height_4k.jpg");
        if !p.exists() {
            bail!("{} is missing (set TERRAIN_DATA)", p.display());
        }
        Ok([p.display().to_string().as_str(), "--vertical-scale", "25.6", "--spacing", "40"]
            .map(String::from)
            .to_vec())
    }

    /// A shipped flight file.
    pub(crate) fn flight(&self, name: &str) -> String {
        self.flights.join(name).display().to_string()
    }

    /// `terrain bench`'s arguments for one flight: the terrain's `dem` arguments, then the
    /// shipped `flight`, `methods` at one parameter `values`, `frames` evenly spaced, the
    /// rendered `size`.
    pub(crate) fn flight_args(
        &self,
        dem: &[String],
        flight: &str,
        methods: &str,
        values: &str,
        frames: &str,
        size: &str,
    ) -> Vec<String> {
        let mut args = dem.to_vec();
        let flight = self.flight(flight);
        args.extend(
            [
                "--flight",
                &flight,
                "--methods",
                methods,
                "--values",
                values,
                "--frames",
                frames,
                "--size",
                size,
            ]
            .map(String::from),
        );
        args
    }

    /// Runs `terrain <args>`, recording the command; returns its stdout.
    pub(crate) fn terrain(&mut self, args: &[String]) -> anyhow::Result<String> {
        let shown: Vec<String> = args.iter().map(|a| self.relative(a)).collect();
        self.commands.push(format!("terrain {}", shown.join(" ")));
        println!("== terrain {}", shown.join(" "));
        let start = Instant::now();
        let out = Command::new(&self.terrain)
            .args(args)
            .stderr(std::process::Stdio::inherit())
            .output()
            .with_context(|| format!("could not start {}", self.terrain.display()))?;
        if !out.status.success() {
            bail!("terrain {} failed with {}", args.join(" "), out.status);
        }
        println!("   ({:.1} s)", start.elapsed().as_secs_f64());
        Ok(String::from_utf8_lossy(&out.stdout).into_owned())
    }

    /// Runs `terrain bench <args> --name NAME --out WORK` and reads its JSON report.
    pub(crate) fn bench(&mut self, name: &str, args: &[String]) -> anyhow::Result<Value> {
        let mut all = vec!["bench".to_string()];
        all.extend(args.iter().cloned());
        let work = self.work.display().to_string();
        all.extend(["--name".to_string(), name.to_string(), "--out".to_string(), work]);
        self.terrain(&all)?;
        let path = self.work.join(format!("{name}.json"));
        read_json(&path)
    }

    /// `terrain info --json` of a store folder.
    pub(crate) fn store_info(&mut self, dir: &Path) -> anyhow::Result<Value> {
        let s =
            self.terrain(&["info".to_string(), "--json".to_string(), dir.display().to_string()])?;
        serde_json::from_str(&s).context("terrain info --json printed no JSON")
    }

    /// Paths under the workspace root or the data folder, shortened for the documents.
    fn relative(&self, a: &str) -> String {
        let root = super::root().display().to_string();
        let data = self.data.display().to_string();
        a.replace(&format!("{root}/"), "").replace(&data, "$TERRAIN_DATA")
    }
}

fn read_json(path: &Path) -> anyhow::Result<Value> {
    let s = std::fs::read_to_string(path)
        .with_context(|| format!("could not read {}", path.display()))?;
    serde_json::from_str(&s).with_context(|| format!("{} is not JSON", path.display()))
}

/// A number of a JSON value by path (`a.b.c`); `NaN` when absent or not a number.
pub(crate) fn f(v: &Value, path: &str) -> f64 {
    let mut cur = v;
    for key in path.split('.') {
        match cur.get(key) {
            Some(next) => cur = next,
            None => return f64::NAN,
        }
    }
    cur.as_f64().unwrap_or(f64::NAN)
}

/// The runs of a bench report for `method` on `flight` (any flight when `None`), in order.
pub(crate) fn runs<'a>(report: &'a Value, method: &str, flight: Option<&str>) -> Vec<&'a Value> {
    report["runs"]
        .as_array()
        .map(|r| {
            r.iter()
                .filter(|run| run["method"] == method)
                .filter(|run| flight.is_none_or(|fl| run["flight"] == fl))
                .collect()
        })
        .unwrap_or_default()
}

/// The mean of `key` over a run's frames (the papers report averages; the bench's summary has
/// medians); `NaN` for none.
pub(crate) fn frame_mean(run: &Value, key: &str) -> f64 {
    let v: Vec<f64> = run["frames"]
        .as_array()
        .map(|fr| fr.iter().map(|x| f(x, key)).filter(|x| x.is_finite()).collect())
        .unwrap_or_default();
    if v.is_empty() { f64::NAN } else { v.iter().sum::<f64>() / v.len() as f64 }
}

/// Average frames per second of a run: 1000 / the mean frame time (selection + render wall,
/// or selection + CPU tessellation when not rendered).
pub(crate) fn fps(run: &Value) -> f64 {
    1000.0 / frame_mean(run, "frame_ms")
}

fn loadavg() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "unknown".to_string())
}

fn date() -> String {
    Command::new("date")
        .arg("-u")
        .arg("+%Y-%m-%d %H:%M UTC")
        .output()
        .ok()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_default()
}

const USAGE: &str = "cargo xtask papers [--paper pvps|ooc|geomorph|entropy|dss]... [--quick] \
[--out DIR] [--store NAME=DIR]... [--terrain BINARY]";

/// Runs `cargo xtask papers`.
pub(crate) fn papers(args: &[String]) -> anyhow::Result<()> {
    let (mut quick, mut which, mut out, mut stores) = (false, Vec::new(), None, Vec::new());
    let mut binary = None;
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = || it.next().with_context(|| format!("{a} needs a value\n\n{USAGE}"));
        match a.as_str() {
            "--quick" => quick = true,
            "--paper" => {
                let p = value()?;
                if !PAPERS.contains(&p.as_str()) {
                    bail!("unknown paper `{p}`; papers: {}", PAPERS.join(", "));
                }
                which.push(p.clone());
            }
            "--out" => out = Some(PathBuf::from(value()?)),
            "--terrain" => binary = Some(PathBuf::from(value()?)),
            "--store" => {
                let v = value()?;
                let (name, dir) = v
                    .split_once('=')
                    .with_context(|| format!("--store expects NAME=DIR, got `{v}`"))?;
                stores.push((name.to_string(), PathBuf::from(dir)));
            }
            other => bail!("unknown papers option `{other}`\n\n{USAGE}"),
        }
    }
    if which.is_empty() {
        which = PAPERS.iter().map(|s| s.to_string()).collect();
    }
    let root = super::root();
    let out =
        out.unwrap_or_else(|| root.join(if quick { "out/papers-quick" } else { "bench/papers" }));
    let start = Instant::now();
    let terrain = match binary {
        Some(b) => b,
        None => {
            super::run("cargo", &["build", "--release", "-q", "-p", "terrain-app"])?;
            println!("release build: {:.1} s", start.elapsed().as_secs_f64());
            root.join("target/release/terrain")
        }
    };
    let mut ctx = Ctx {
        terrain,
        data: super::data_dir(),
        flights: root.join("flights"),
        work: root.join(if quick { "out/papers-work-quick" } else { "out/papers-work" }),
        quick,
        stores,
        commands: Vec::new(),
    };
    std::fs::create_dir_all(&ctx.work)
        .with_context(|| format!("could not create {}", ctx.work.display()))?;
    let mut problems = Vec::new();
    for key in &which {
        ctx.commands.clear();
        let (load0, t0, date0) = (loadavg(), Instant::now(), date());
        let mut doc = match key.as_str() {
            "ooc" => ooc::run(&mut ctx)?,
            "pvps" => pvps::run(&mut ctx)?,
            "dss" => dss::run(&mut ctx)?,
            "geomorph" => geomorph::run(&mut ctx)?,
            _ => entropy::run(&mut ctx)?,
        };
        doc.quick = quick;
        doc.commands = std::mem::take(&mut ctx.commands);
        doc.load = vec![
            format!("started {date0}, load average (1, 5, 15 min) {load0}"),
            format!(
                "finished after {:.0} s, load average {}; machine: {} cores",
                t0.elapsed().as_secs_f64(),
                loadavg(),
                std::thread::available_parallelism().map_or(0, |n| n.get())
            ),
        ];
        let dir = out.join(key);
        write(&doc, &dir)?;
        for s in &doc.sections {
            problems.extend(s.problems().into_iter().map(|p| format!("{key} {p}")));
        }
    }
    println!(
        "\npapers done in {:.1} s; documents in {}",
        start.elapsed().as_secs_f64(),
        out.display()
    );
    if !problems.is_empty() {
        bail!("some tables or verdicts were not computed:\n  {}", problems.join("\n  "));
    }
    Ok(())
}

/// Writes `README.md`, `results.json` and the figures' SVG files into `dir`.
fn write(doc: &PaperDoc, dir: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("could not create {}", dir.display()))?;
    let mut files = vec![
        (dir.join("README.md"), doc.to_markdown()),
        (dir.join("results.json"), serde_json::to_string_pretty(doc)?),
    ];
    for s in &doc.sections {
        for fig in &s.figures {
            files.push((dir.join(&fig.file), fig.to_svg()));
        }
    }
    for (p, c) in files {
        std::fs::write(&p, c).with_context(|| format!("could not write {}", p.display()))?;
        println!("wrote {}", p.display());
    }
    Ok(())
}
