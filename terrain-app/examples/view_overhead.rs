//! The viewer's overhead: `terrain view`'s frame time against `terrain render`'s per-frame
//! time for the same camera, method and size (issue 14's target: within 1.1x), per method,
//! measured side by side in one run.
//!
//! ```sh
//! cargo build --release -p terrain-app
//! xvfb-run -a -s "-screen 0 1280x800x24 -noreset" \
//!     cargo run --release -p terrain-app --example view_overhead -- \
//!     [--methods uniform,pvps-c,...] [--frames 10] [--rounds 2] [--size 1280x720] \
//!     [--camera X,Y,Z,YAW,PITCH] [--panel off] [DEM options, e.g. a DEM path ...]
//! ```
//! For each method and round, in turn (odd rounds the viewer first): `terrain render --frames
//! N --stats-json` (the frame loop's `frame_ms` per frame: selection, conversion, the
//! renderer's wall time) and `terrain view --script` (`camera C`, `wait N`, `quit`) with
//! `--stats-json` (each frame's period: start of one redraw to the next, event handling, panel
//! and present included). The first frame of each (pipelines, first tessellation) is left
//! out; printed per method: the median over the rounds' frames of the viewer's period, its
//! engine part, panel and present, the render's frame, and the ratio viewer period / render
//! frame; then the process's CPU time (every thread, the driver's rasterizer threads
//! included, 10 ms ticks) per viewer period and per render frame and their ratio: the work
//! each frame costs, which other processes on the machine do not inflate as wall times. Both
//! runs must draw the same triangles (checked). The binary is `target/release/terrain` (or
//! `TERRAIN_BIN`); the window needs a display (`DISPLAY`, e.g.
//! under `xvfb-run`; `-noreset` keeps the server up between the runs, or a viewer started as
//! the previous one closes may find it resetting) and runs on Vulkan (lavapipe without a GPU).

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, bail};
use terrain_app::bench::median;

/// `key` of every frame after the first in a `--stats-json` file.
fn column(json: &serde_json::Value, key: &str) -> anyhow::Result<Vec<f64>> {
    let frames = json["frames"].as_array().context("no frames in the stats")?;
    frames
        .iter()
        .skip(1)
        .map(|f| f[key].as_f64().with_context(|| format!("no {key} in {f}")))
        .collect()
}

/// [`column`] where every frame has `key`, `None` where none has (a binary from before the key
/// was written).
fn column_if_any(json: &serde_json::Value, key: &str) -> anyhow::Result<Option<Vec<f64>>> {
    let first = json["frames"].as_array().and_then(|f| f.first());
    if first.is_some_and(|f| f.get(key).is_none()) { Ok(None) } else { column(json, key).map(Some) }
}

fn run(bin: &Path, args: &[String]) -> anyhow::Result<()> {
    let out = Command::new(bin)
        .args(args)
        .env("TERRAIN_GPU_BACKEND", std::env::var("TERRAIN_GPU_BACKEND").unwrap_or("vulkan".into()))
        .output()
        .with_context(|| format!("could not run {}", bin.display()))?;
    if !out.status.success() {
        bail!(
            "{} {} failed:\n{}\n{}",
            bin.display(),
            args.join(" "),
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    Ok(())
}

fn read(path: &Path) -> anyhow::Result<serde_json::Value> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("could not read {}", path.display()))?;
    Ok(serde_json::from_str(&text)?)
}

fn main() -> anyhow::Result<()> {
    let mut methods = "uniform,pvps-c,dss-1,dss-2,dss-strips,geomorph".to_string();
    let (mut frames, mut rounds) = (10u32, 2u32);
    let mut size = "1280x720".to_string();
    let mut camera = "1500,1500,2600,45,-25".to_string();
    let mut panel = true;
    let mut source = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().with_context(|| format!("{a} needs a value"));
        match a.as_str() {
            "--methods" => methods = value()?,
            "--frames" => frames = value()?.parse()?,
            "--rounds" => rounds = value()?.parse()?,
            "--size" => size = value()?,
            "--camera" => camera = value()?,
            "--panel" => panel = value()? != "off",
            _ => source.push(a),
        }
    }
    if frames < 2 {
        bail!("--frames must be at least 2 (the first is left out)");
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let bin = std::env::var_os("TERRAIN_BIN")
        .map_or_else(|| root.join("target/release/terrain"), PathBuf::from);
    let dir = root.join("out/view_overhead");
    std::fs::create_dir_all(&dir)?;
    let script = dir.join("script.txt");
    std::fs::write(
        &script,
        format!("camera {camera}\n{}wait {frames}\nquit\n", if panel { "" } else { "panel off\n" }),
    )?;
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!("load average before: {}", load.trim());
    println!(
        "size {size}, camera {camera}, {frames} frames x {rounds} rounds (first of each left \
         out), panel {}",
        if panel { "on" } else { "off" }
    );
    println!(
        "| method | viewer period ms | engine ms | panel ms | present ms | render frame ms | \
         viewer / render | viewer CPU ms | render CPU ms | CPU viewer / render |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for method in methods.split(',') {
        let (mut period, mut engine, mut panel_ms, mut present, mut render) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let (mut view_cpu, mut render_cpu) = (Vec::new(), Vec::new());
        for round in 0..rounds {
            let r_json = dir.join(format!("render-{method}-{round}.json"));
            let v_json = dir.join(format!("view-{method}-{round}.json"));
            let common = |cmd: &str| -> Vec<String> {
                let mut v: Vec<String> = vec![cmd.into()];
                v.extend(source.iter().cloned());
                v.extend(["--size", &size, "--method", method].map(String::from));
                v
            };
            let mut r = common("render");
            r.extend(
                [
                    "--camera",
                    &camera,
                    "--frames",
                    &frames.to_string(),
                    "--stats-json",
                    r_json.to_str().context("path")?,
                    "-o",
                    dir.join("render.png").to_str().context("path")?,
                ]
                .map(String::from),
            );
            let mut v = common("view");
            v.extend(
                [
                    "--script",
                    script.to_str().context("path")?,
                    "--stats-json",
                    v_json.to_str().context("path")?,
                ]
                .map(String::from),
            );
            // Odd rounds run the viewer first: neither side always runs second (a warmer or
            // busier machine).
            if round % 2 == 0 {
                run(&bin, &r)?;
                run(&bin, &v)?;
            } else {
                run(&bin, &v)?;
                run(&bin, &r)?;
            }
            let (rj, vj) = (read(&r_json)?, read(&v_json)?);
            render.extend(column(&rj, "frame_ms")?);
            period.extend(column(&vj, "period_ms")?);
            engine.extend(column(&vj, "engine_ms")?);
            panel_ms.extend(column(&vj, "panel_ms")?);
            present.extend(column(&vj, "present_ms")?);
            let cpu =
                (column_if_any(&vj, "process_cpu_ms")?, column_if_any(&rj, "process_cpu_ms")?);
            if let (Some(v), Some(r)) = cpu {
                view_cpu.extend(v);
                render_cpu.extend(r);
            }
            let tris = (column_if_any(&vj, "triangles")?, column_if_any(&rj, "triangles")?);
            if let (Some(vt), Some(rt)) = tris
                && vt.iter().chain(&rt).any(|&t| t != rt[0])
            {
                bail!(
                    "{method}: the viewer drew {vt:?} triangles, render {rt:?}: not the same frame"
                );
            }
        }
        let (p, r) = (median(period), median(render));
        let (vc, rc) = (median(view_cpu), median(render_cpu));
        println!(
            "| {method} | {p:.1} | {:.1} | {:.1} | {:.1} | {r:.1} | {:.2}x | {vc:.0} | {rc:.0} | \
             {:.2}x |",
            median(engine),
            median(panel_ms),
            median(present),
            p / r,
            vc / rc
        );
    }
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!("load average after: {}", load.trim());
    Ok(())
}
