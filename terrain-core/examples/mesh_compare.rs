//! Our error-bounded meshers against fogleman/hmm, Delatin and Martini, side by side in one
//! run: triangles, the maximum error each mesh really has (every mesh measured by
//! `mesh::verify` against the same samples) and the build time (median of the runs).
//! Run by bench/mesh/compare.sh, which builds the peers into bench/mesh/peers (git-ignored):
//!
//! ```text
//! cargo run --release -p terrain-core --example mesh_compare -- DEM VERTICAL_SCALE SPACING_M PEERS_DIR RUNS [BOUNDS...]
//! ```
//!
//! Every tool sees the same heights: hmm reads the DEM's own 16-bit PNG (its heights are
//! `raw / 65535`, so its threshold is `bound / (65535 x VERTICAL_SCALE)`); the npm meshers
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
    ms: Vec<f64>,
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[s.len() / 2]
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

/// hmm on the 16-bit PNG: its own "triangulating... Xs" time, the mesh from its binary STL.
fn run_hmm(
    hm: &Heightmap,
    hmm: &Path,
    dem: &str,
    scale: f64,
    bound: f64,
    runs: usize,
    dir: &Path,
) -> Result<Row, String> {
    let stl = dir.join("hmm_out.stl");
    let threshold = bound / (65535.0 * scale);
    let mut ms = Vec::new();
    for _ in 0..runs {
        let out = Command::new(hmm)
            .args(["-z", "1", "-e", &format!("{threshold:e}"), dem])
            .arg(&stl)
            .output()
            .map_err(|e| format!("{}: {e}", hmm.display()))?;
        let text = String::from_utf8_lossy(&out.stdout);
        if !out.status.success() {
            return Err(format!("hmm failed: {text} {}", String::from_utf8_lossy(&out.stderr)));
        }
        let secs = text
            .lines()
            .find_map(|l| l.strip_prefix("triangulating... "))
            .and_then(|s| s.trim().trim_end_matches('s').parse::<f64>().ok())
            .ok_or_else(|| format!("no triangulation time in hmm's output: {text}"))?;
        ms.push(secs * 1e3);
    }
    let bytes = std::fs::read(&stl).map_err(|e| format!("{}: {e}", stl.display()))?;
    let n = u32::from_le_bytes(bytes[80..84].try_into().unwrap()) as usize;
    let mut index = std::collections::HashMap::new();
    let (mut xy, mut tris) = (Vec::new(), Vec::with_capacity(n));
    for f in 0..n {
        let base = 84 + 50 * f + 12;
        let mut t = [0u32; 3];
        for (k, slot) in t.iter_mut().enumerate() {
            let p = base + 12 * k;
            let c = |o: usize| f32::from_le_bytes(bytes[p + o..p + o + 4].try_into().unwrap());
            let v = [c(0).round() as u32, c(4).round() as u32];
            *slot = *index.entry(v).or_insert_with(|| {
                xy.push(v);
                (xy.len() - 1) as u32
            });
        }
        tris.push(t);
    }
    let mesh = grid_mesh(hm, &xy, &tris)?;
    Ok(Row { tool: "hmm (C++)", triangles: n, max_error: measured(hm, &mesh), ms })
}

/// Delatin or Martini through node (bench/mesh/js_meshers.mjs).
#[allow(clippy::too_many_arguments)]
fn run_js(
    hm: &Heightmap,
    script: &Path,
    dir: &Path,
    tool: &'static str,
    label: &'static str,
    bound: f64,
    runs: usize,
) -> Result<Row, String> {
    let out_path = dir.join(format!("{tool}_out.bin"));
    let heights = dir.join("heights.f32");
    let out = Command::new("node")
        .arg(script)
        .arg(dir)
        .arg(&heights)
        .args([
            hm.width().to_string(),
            hm.height().to_string(),
            tool.into(),
            bound.to_string(),
            runs.to_string(),
        ])
        .arg(&out_path)
        .output()
        .map_err(|e| format!("node: {e}"))?;
    if !out.status.success() {
        return Err(format!("{tool}: {}", String::from_utf8_lossy(&out.stderr).trim()));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let ms: Vec<f64> = text
        .trim()
        .strip_prefix("{\"ms\":[")
        .and_then(|s| s.strip_suffix("]}"))
        .map(|s| s.split(',').filter_map(|x| x.parse().ok()).collect())
        .ok_or_else(|| format!("{tool}: unexpected output {text}"))?;
    let bytes = std::fs::read(&out_path).map_err(|e| format!("{}: {e}", out_path.display()))?;
    let w: Vec<u32> =
        bytes.chunks_exact(4).map(|c| u32::from_le_bytes(c.try_into().unwrap())).collect();
    let (nv, nt) = (w[0] as usize, w[1] as usize);
    let xy: Vec<[u32; 2]> = w[2..2 + 2 * nv].chunks_exact(2).map(|c| [c[0], c[1]]).collect();
    let tris: Vec<[u32; 3]> =
        w[2 + 2 * nv..2 + 2 * nv + 3 * nt].chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let mesh = grid_mesh(hm, &xy, &tris)?;
    Ok(Row { tool: label, triangles: nt, max_error: measured(hm, &mesh), ms })
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
    let hmm = dir.join("hmm/hmm");
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
        "{dem}: {} x {} samples, spacing {spacing} m, vertical scale {scale}; build time: median of {runs}\n",
        hm.width(),
        hm.height()
    );
    println!(
        "| bound (m) | mesher | triangles | measured max error (m) | build (ms) | triangles / fewest | time / fastest |"
    );
    println!("|---:|---|---:|---:|---:|---:|---:|");
    for &bound in &bounds {
        let mut rows = Vec::new();
        let mut ms = Vec::new();
        let mut mesh = TriMesh::default();
        for _ in 0..runs {
            let t = Instant::now();
            mesh = delaunay::build(&hm, bound);
            ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
        rows.push(Ok(Row {
            tool: "ours: greedy Delaunay",
            triangles: mesh.triangles.len(),
            max_error: measured(&hm, &mesh),
            ms,
        }));
        let mut ms = Vec::new();
        for _ in 0..runs {
            let t = Instant::now();
            mesh = RtinErrors::new(&hm).mesh(&hm, bound);
            ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
        rows.push(Ok(Row {
            tool: "ours: RTIN (true error)",
            triangles: mesh.triangles.len(),
            max_error: measured(&hm, &mesh),
            ms,
        }));
        if have_hmm {
            rows.push(run_hmm(&hm, &hmm, dem, scale, bound, runs, &dir));
        }
        if have_npm {
            rows.push(run_js(&hm, &script, &dir, "delatin", "delatin (JS)", bound, runs));
            rows.push(run_js(&hm, &script, &dir, "martini", "martini (JS)", bound, runs));
        }
        // "Equal maximum error": the meshes that keep the bound (hmm thresholds in f32, so a
        // millimetre of slack) set the fewest triangles and the fastest time.
        let keeps = |r: &Row| r.max_error.as_ref().is_ok_and(|&e| e <= bound + 1e-3);
        let ok: Vec<&Row> =
            rows.iter().filter_map(|r| r.as_ref().ok()).filter(|r| keeps(r)).collect();
        let fewest = ok.iter().map(|r| r.triangles).min().unwrap_or(1) as f64;
        let fastest = ok.iter().map(|r| median(&r.ms)).fold(f64::INFINITY, f64::min);
        for r in &rows {
            match r {
                Ok(r) => {
                    let err = match &r.max_error {
                        Ok(e) if keeps(r) => format!("{e:.3}"),
                        Ok(e) => format!("{e:.3} (over the bound)"),
                        Err(e) => format!("not measurable: {e}"),
                    };
                    println!(
                        "| {bound} | {} | {} | {err} | {:.1} | {:.3} | {:.2} |",
                        r.tool,
                        r.triangles,
                        median(&r.ms),
                        r.triangles as f64 / fewest,
                        median(&r.ms) / fastest
                    );
                }
                Err(e) => println!("| {bound} | skipped | | {e} | | | |"),
            }
        }
    }
}
