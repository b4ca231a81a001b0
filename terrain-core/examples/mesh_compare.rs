//! Our error-bounded meshers against fogleman/hmm, Delatin and Martini, side by side in one
//! run: triangles, the maximum error each mesh really has (every mesh measured by
//! `mesh::verify` against the same samples) and the build time (median of the runs).
//! Run by bench/mesh/compare.sh, which builds the peers into bench/mesh/peers (git-ignored):
//!
//! ```text
//! cargo run --release -p terrain-core --example mesh_compare -- DEM VERTICAL_SCALE SPACING_M PEERS_DIR RUNS [BOUNDS...]
//! ```
//!
//! Every tool sees the same heights: hmm (its triangulator, timed by bench/mesh/hmm_time.cpp,
//! `PEERS_DIR/hmm_time`) reads the DEM's own 16-bit PNG (its heights are `raw / 65535`, so
//! its threshold is `bound / (65535 x VERTICAL_SCALE)`); the npm meshers
//! read `PEERS_DIR/heights.f32`, the loaded heightmap in metres written here. A peer whose
//! binary or package is missing is skipped with a message. Peers' vertices are grid samples;
//! each is given our sample's height before measuring, so only the triangulation counts.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use terrain_core::Heightmap;
use terrain_core::dem::{LoadOptions, load};
use terrain_core::mesh::rtin::RtinErrors;
use terrain_core::mesh::{TriMesh, delaunay, verify};

/// One tool's result at one bound.
struct Row {
    tool: &'static str,
    triangles: usize,
    max_error: Result<f64, String>,
    /// Wall and CPU milliseconds of each run.
    wall: Vec<f64>,
    cpu: Vec<f64>,
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[s.len() / 2]
}

/// This thread's CPU time in milliseconds (Linux: /proc/thread-self/schedstat, nanoseconds
/// on a CPU), which a loaded machine does not inflate as it does wall time.
fn thread_cpu_ms() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<f64>().ok())
        .map_or(f64::NAN, |ns| ns / 1e6)
}

/// A mesh over grid samples `[x, y]` with our heights; triangles turned counter-clockwise.
fn grid_mesh(hm: &Heightmap, xy: &[[u32; 2]], tris: &[[u32; 3]]) -> Result<TriMesh, String> {
    let mut positions = Vec::with_capacity(xy.len());
    for &[x, y] in xy {
        if x as usize >= hm.width() || y as usize >= hm.height() {
            return Err(format!("vertex ({x}, {y}) outside the grid"));
        }
        let w = hm.grid_to_world(f64::from(x), f64::from(y));
        positions.push(w.extend(f64::from(hm.get(x as usize, y as usize))));
    }
    let mut triangles = Vec::with_capacity(tris.len());
    for &t in tris {
        if t.iter().any(|&k| k as usize >= xy.len()) {
            return Err(format!("triangle {t:?} indexes a missing vertex"));
        }
        let [a, b, c] = t.map(|k| xy[k as usize].map(i64::from));
        let o = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
        triangles.push(if o < 0 { [t[0], t[2], t[1]] } else { t });
    }
    Ok(TriMesh { positions, normals: Vec::new(), triangles })
}

fn measured(hm: &Heightmap, mesh: &TriMesh) -> Result<f64, String> {
    verify::measure(hm, mesh).map(|s| s.max_error).map_err(|e| e.to_string())
}

/// Reads a peer's mesh file: u32 vertex and triangle counts, `(x, y)` per vertex, 3 indices
/// per triangle.
fn read_mesh(hm: &Heightmap, path: &Path) -> Result<(usize, TriMesh), String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let w: Vec<u32> =
        bytes.chunks_exact(4).map(|c| u32::from_le_bytes(c.try_into().unwrap())).collect();
    let (nv, nt) = (*w.first().unwrap_or(&0) as usize, *w.get(1).unwrap_or(&0) as usize);
    if w.len() != 2 + 2 * nv + 3 * nt {
        return Err(format!("{}: truncated mesh", path.display()));
    }
    let xy: Vec<[u32; 2]> = w[2..2 + 2 * nv].chunks_exact(2).map(|c| [c[0], c[1]]).collect();
    let tris: Vec<[u32; 3]> = w[2 + 2 * nv..].chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    Ok((nt, grid_mesh(hm, &xy, &tris)?))
}

/// hmm's triangulator through bench/mesh/hmm_time.cpp on the 16-bit PNG.
fn run_hmm(
    hm: &Heightmap,
    hmm: &Path,
    dem: &str,
    scale: f64,
    bound: f64,
    runs: usize,
    dir: &Path,
) -> Result<Row, String> {
    let out_path = dir.join("hmm_out.bin");
    let threshold = bound / (65535.0 * scale);
    let out = Command::new(hmm)
        .args([dem, &format!("{threshold:e}"), &runs.to_string()])
        .arg(&out_path)
        .output()
        .map_err(|e| format!("{}: {e}", hmm.display()))?;
    let text = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        return Err(format!("hmm failed: {}", String::from_utf8_lossy(&out.stderr).trim()));
    }
    let (mut wall, mut cpu) = (Vec::new(), Vec::new());
    for l in text.lines() {
        let v: Vec<f64> = l.split_whitespace().filter_map(|x| x.parse().ok()).collect();
        if let [w, c] = v[..] {
            wall.push(w);
            cpu.push(c);
        }
    }
    if wall.is_empty() {
        return Err(format!("no times in hmm_time's output: {text}"));
    }
    let (triangles, mesh) = read_mesh(hm, &out_path)?;
    Ok(Row { tool: "hmm (C++)", triangles, max_error: measured(hm, &mesh), wall, cpu })
}

/// Delatin or Martini through node (bench/mesh/js_meshers.mjs).
fn run_js(
    hm: &Heightmap,
    script: &Path,
    dir: &Path,
    (tool, label): (&str, &'static str),
    bound: f64,
    runs: usize,
) -> Result<Row, String> {
    let out_path = dir.join(format!("{tool}_out.bin"));
    let out = Command::new("node")
        .arg(script)
        .arg(dir)
        .arg(dir.join("heights.f32"))
        .args([hm.width().to_string(), hm.height().to_string(), tool.into()])
        .args([bound.to_string(), runs.to_string()])
        .arg(&out_path)
        .output()
        .map_err(|e| format!("node: {e}"))?;
    if !out.status.success() {
        return Err(format!("{tool}: {}", String::from_utf8_lossy(&out.stderr).trim()));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let list = |key: &str| -> Option<Vec<f64>> {
        let rest = text.split(&format!("\"{key}\":[")).nth(1)?;
        let body = rest.split(']').next()?;
        Some(body.split(',').filter_map(|x| x.parse().ok()).collect())
    };
    let (Some(wall), Some(cpu)) = (list("ms"), list("cpu")) else {
        return Err(format!("{tool}: unexpected output {text}"));
    };
    let (triangles, mesh) = read_mesh(hm, &out_path)?;
    Ok(Row { tool: label, triangles, max_error: measured(hm, &mesh), wall, cpu })
}

/// Runs `f` `runs` times, timing each run (wall and this thread's CPU).
fn timed<T>(runs: usize, mut f: impl FnMut() -> T) -> (T, Vec<f64>, Vec<f64>) {
    let (mut wall, mut cpu) = (Vec::new(), Vec::new());
    let mut out = None;
    for _ in 0..runs {
        let (t, c) = (Instant::now(), thread_cpu_ms());
        out = Some(f());
        cpu.push(thread_cpu_ms() - c);
        wall.push(t.elapsed().as_secs_f64() * 1e3);
    }
    (out.expect("at least one run"), wall, cpu)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 5 {
        eprintln!("usage: mesh_compare DEM VERTICAL_SCALE SPACING_M PEERS_DIR RUNS [BOUNDS...]");
        std::process::exit(2);
    }
    let dem = &args[0];
    let parse = |k: usize, what: &str| -> f64 {
        args[k].parse().unwrap_or_else(|_| {
            eprintln!("mesh_compare: {what} must be a number, got {:?}", args[k]);
            std::process::exit(2)
        })
    };
    let (scale, spacing) = (parse(1, "VERTICAL_SCALE"), parse(2, "SPACING_M"));
    let dir = PathBuf::from(&args[3]);
    let runs = parse(4, "RUNS") as usize;
    let bounds: Vec<f64> = if args.len() > 5 {
        (5..args.len()).map(|k| parse(k, "a bound in metres")).collect()
    } else {
        vec![1.0, 4.0, 16.0]
    };
    let options =
        LoadOptions { vertical_scale: scale, spacing_m: spacing, ..LoadOptions::default() };
    let hm = load(dem, &options)
        .unwrap_or_else(|e| {
            eprintln!("mesh_compare: {dem}: {e}");
            std::process::exit(1)
        })
        .heightmap;
    std::fs::create_dir_all(&dir).expect("the peers folder");
    let raw: Vec<u8> = hm.data().iter().flat_map(|z| z.to_le_bytes()).collect();
    std::fs::write(dir.join("heights.f32"), raw).expect("heights.f32 in the peers folder");
    let hmm = dir.join("hmm_time");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../bench/mesh/js_meshers.mjs");
    let have_hmm = hmm.exists() && dem.ends_with(".png");
    if !have_hmm {
        eprintln!("hmm: skipped ({} missing, or the DEM is not a 16-bit PNG)", hmm.display());
    }
    let have_npm = dir.join("node_modules/delatin").exists();
    if !have_npm {
        eprintln!("delatin, martini: skipped ({} missing)", dir.join("node_modules").display());
    }
    println!(
        "{dem}: {} x {} samples, spacing {spacing} m, vertical scale {scale}; times: median of \
         {runs} runs, CPU (the process's own) and wall\n",
        hm.width(),
        hm.height()
    );
    println!(
        "| bound (m) | mesher | triangles | measured max error (m) | CPU (ms) | wall (ms) \
         | triangles / fewest | CPU / fastest |"
    );
    println!("|---:|---|---:|---:|---:|---:|---:|---:|");
    for &bound in &bounds {
        let mut rows = Vec::new();
        let (mesh, wall, cpu) = timed(runs, || delaunay::build(&hm, bound));
        rows.push(Ok(Row {
            tool: "ours: greedy Delaunay",
            triangles: mesh.triangles.len(),
            max_error: measured(&hm, &mesh),
            wall,
            cpu,
        }));
        let (mesh, wall, cpu) = timed(runs, || RtinErrors::new(&hm).mesh(&hm, bound));
        rows.push(Ok(Row {
            tool: "ours: RTIN (true error)",
            triangles: mesh.triangles.len(),
            max_error: measured(&hm, &mesh),
            wall,
            cpu,
        }));
        if have_hmm {
            rows.push(run_hmm(&hm, &hmm, dem, scale, bound, runs, &dir));
        }
        if have_npm {
            rows.push(run_js(&hm, &script, &dir, ("delatin", "delatin (JS)"), bound, runs));
            rows.push(run_js(&hm, &script, &dir, ("martini", "martini (JS)"), bound, runs));
        }
        // "Equal maximum error": the meshes that keep the bound (hmm thresholds in f32, so a
        // millimetre of slack) set the fewest triangles and the fastest time.
        let keeps = |r: &Row| r.max_error.as_ref().is_ok_and(|&e| e <= bound + 1e-3);
        let ok: Vec<&Row> =
            rows.iter().filter_map(|r| r.as_ref().ok()).filter(|r| keeps(r)).collect();
        let fewest = ok.iter().map(|r| r.triangles).min().unwrap_or(1) as f64;
        let fastest = ok.iter().map(|r| median(&r.cpu)).fold(f64::INFINITY, f64::min);
        for r in &rows {
            match r {
                Ok(r) => {
                    let err = match &r.max_error {
                        Ok(e) if keeps(r) => format!("{e:.3}"),
                        Ok(e) => format!("{e:.3} (over the bound)"),
                        Err(e) => format!("not measurable: {e}"),
                    };
                    println!(
                        "| {bound} | {} | {} | {err} | {:.0} | {:.0} | {:.3} | {:.2} |",
                        r.tool,
                        r.triangles,
                        median(&r.cpu),
                        median(&r.wall),
                        r.triangles as f64 / fewest,
                        median(&r.cpu) / fastest
                    );
                }
                Err(e) => println!("| {bound} | skipped | | {e} | | | | |"),
            }
        }
    }
}
