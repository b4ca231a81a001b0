//! The greedy Delaunay build alone (`mesh::delaunay::build`), for profiles and instruction
//! counts (bench/mesh/README.md): loads a DEM, builds the mesh `RUNS` times at each bound and
//! prints, per bound, the triangles, an FNV-1a fingerprint of the mesh (vertices and
//! triangles: two binaries that print the same one built the same mesh) and each run's
//! thread CPU milliseconds. Nothing else runs, so `valgrind --tool=callgrind` with
//! `--toggle-collect='*delaunay*build*'` counts the build and nothing but it.
//!
//! ```text
//! cargo run --release -p terrain-core --example mesh_build -- DEM VERTICAL_SCALE SPACING_M RUNS BOUNDS...
//! ```

use terrain_core::checksum::{FNV1A_START, fnv1a_update};
use terrain_core::dem::{LoadOptions, load};
use terrain_core::mesh::{TriMesh, delaunay};

/// This thread's CPU time in milliseconds (Linux: /proc/thread-self/schedstat).
fn thread_cpu_ms() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<f64>().ok())
        .map_or(f64::NAN, |ns| ns / 1e6)
}

/// FNV-1a over the vertices' positions and normals and the triangles' indices.
fn fingerprint(m: &TriMesh) -> u64 {
    let mut h = FNV1A_START;
    let mut eat = |bytes: &[u8]| h = fnv1a_update(h, bytes);
    for p in &m.positions {
        [p.x, p.y, p.z].iter().for_each(|c| eat(&c.to_le_bytes()));
    }
    for n in &m.normals {
        [n.x, n.y, n.z].iter().for_each(|c| eat(&c.to_le_bytes()));
    }
    for t in &m.triangles {
        t.iter().for_each(|k| eat(&k.to_le_bytes()));
    }
    h
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = || -> ! {
        eprintln!("usage: mesh_build DEM VERTICAL_SCALE SPACING_M RUNS BOUNDS...");
        std::process::exit(2)
    };
    if args.len() < 5 {
        usage();
    }
    let num = |k: usize| -> f64 { args[k].parse().unwrap_or_else(|_| usage()) };
    let options =
        LoadOptions { vertical_scale: num(1), spacing_m: num(2), ..LoadOptions::default() };
    let hm = match load(&args[0], &options) {
        Ok(dem) => dem.heightmap,
        Err(e) => {
            eprintln!("mesh_build: {}: {e}", args[0]);
            std::process::exit(1)
        }
    };
    let runs = num(3) as usize;
    for k in 4..args.len() {
        let bound = num(k);
        let mut cpu = Vec::new();
        let mut mesh = None;
        for _ in 0..runs.max(1) {
            let c = thread_cpu_ms();
            mesh = Some(delaunay::build(&hm, bound));
            cpu.push(thread_cpu_ms() - c);
        }
        let mesh = mesh.expect("at least one run");
        let ms: Vec<String> = cpu.iter().map(|c| format!("{c:.0}")).collect();
        println!(
            "bound {bound} m: {} triangles, fingerprint {:016x}, CPU ms {}",
            mesh.triangles.len(),
            fingerprint(&mesh),
            ms.join(" ")
        );
    }
}
