//! Measures both mesh builders on a DEM: triangles and build time at several error bounds,
//! each mesh verified against every sample. Run in release:
//!
//! ```text
//! cargo run --release -p terrain-core --example mesh_table -- DEM [VERTICAL_SCALE SPACING_M] [BOUNDS...]
//! cargo run --release -p terrain-core --example mesh_table -- ../shared/data/puget_sound/ps_height_1k.png 0.1 160
//! cargo run --release -p terrain-core --example mesh_table -- ../shared/data/srtm/N42E001.hgt
//! ```
//!
//! Prints a Markdown table. RTIN time is split into its error pass (independent of the bound,
//! done once per DEM) and the extraction at each bound.

use std::time::Instant;

use terrain_core::dem::{LoadOptions, load};
use terrain_core::mesh::{delaunay, rtin::RtinErrors, verify};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(path) = args.first() else {
        eprintln!("usage: mesh_table DEM [VERTICAL_SCALE SPACING_M] [BOUNDS...]");
        std::process::exit(2);
    };
    let mut options = LoadOptions::default();
    let mut rest = &args[1..];
    if rest.len() >= 2 && !path.ends_with(".hgt") && !path.ends_with(".tif") {
        options.vertical_scale = rest[0].parse().expect("VERTICAL_SCALE");
        options.spacing_m = rest[1].parse().expect("SPACING_M");
        rest = &rest[2..];
    }
    let bounds: Vec<f64> = if rest.is_empty() {
        vec![1.0, 2.0, 4.0, 8.0, 16.0]
    } else {
        rest.iter().map(|s| s.parse().expect("bound in metres")).collect()
    };
    let hm = load(path, &options).expect("a readable DEM").heightmap;
    println!(
        "{path}: {} x {} samples, spacing {:.2} x {:.2} m, heights {:.1}..{:.1} m, {} voids",
        hm.width(),
        hm.height(),
        hm.georef().spacing_m.x,
        hm.georef().spacing_m.y,
        hm.min(),
        hm.max(),
        hm.voids().count()
    );
    let t = Instant::now();
    let rtin = RtinErrors::new(&hm);
    let rtin_errors_ms = t.elapsed().as_secs_f64() * 1e3;
    println!("RTIN error pass (once per DEM): {rtin_errors_ms:.1} ms\n");
    println!(
        "| max error (m) | RTIN triangles | RTIN extract (ms) | RTIN total (ms) | RTIN max / RMS (m) \
         | Delaunay triangles | Delaunay build (ms) | Delaunay max / RMS (m) |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|");
    for &e in &bounds {
        let t = Instant::now();
        let r = rtin.mesh(&hm, e);
        let r_ms = t.elapsed().as_secs_f64() * 1e3;
        let rs = verify::check(&hm, &r, e).expect("RTIN within the bound");
        let t = Instant::now();
        let d = delaunay::build(&hm, e);
        let d_ms = t.elapsed().as_secs_f64() * 1e3;
        let ds = verify::check(&hm, &d, e).expect("Delaunay within the bound");
        println!(
            "| {e} | {} | {r_ms:.1} | {:.1} | {:.3} / {:.3} | {} | {d_ms:.1} | {:.3} / {:.3} |",
            r.triangles.len(),
            rtin_errors_ms + r_ms,
            rs.max_error,
            rs.rms_error,
            d.triangles.len(),
            ds.max_error,
            ds.rms_error
        );
    }
}
