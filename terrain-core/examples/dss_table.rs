//! Times the DSS paper's preprocessing (section 3.3.1: 32 object-space errors per quadtree
//! node) on one thread: the whole table with the fast `object_errors`, and one quadtree level
//! both ways (the fast path and 32 calls of the single-factor reference `object_error`), which
//! must agree bit for bit. Run in release:
//!
//! ```text
//! cargo run --release -p terrain-core --example dss_table -- DEM [VERTICAL_SCALE SPACING_M] [LEVEL]
//! cargo run --release -p terrain-core --example dss_table -- ../shared/data/puget_sound/ps_height_4k.jpg 25.6 40 4
//! ```

use std::time::Instant;

use terrain_core::dem::{LoadOptions, load};
use terrain_core::lod::DssErrorTable;
use terrain_core::metrics::Region;
use terrain_core::metrics::dss::{FACTORS, factor, object_error, object_errors};
use terrain_core::quadtree::Quadtree;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(path) = args.first() else {
        eprintln!("usage: dss_table DEM [VERTICAL_SCALE SPACING_M] [LEVEL]");
        std::process::exit(2);
    };
    let mut options = LoadOptions::default();
    if args.len() >= 3 {
        options.vertical_scale = args[1].parse().expect("VERTICAL_SCALE");
        options.spacing_m = args[2].parse().expect("SPACING_M");
    }
    let level: u8 = args.get(3).map_or(4, |s| s.parse().expect("LEVEL"));
    let dem = load(path, &options).unwrap_or_else(|e| {
        eprintln!("{e}");
        std::process::exit(1)
    });
    let hm = dem.heightmap;
    let qt = Quadtree::new(&hm, 16);
    println!("{path}: {} x {}, {} quadtree levels", hm.width(), hm.height(), qt.max_level() + 1);
    let t = Instant::now();
    let table = DssErrorTable::new(&hm, &qt);
    let whole = t.elapsed().as_secs_f64();
    println!("whole table, fast, 1 thread: {whole:.2} s");
    let level = level.min(qt.max_level());
    let c = (qt.root_cells() >> level) as usize;
    let n = hm.width().max(hm.height()).div_ceil(c);
    let regions: Vec<Region> =
        (0..n).flat_map(|j| (0..n).map(move |i| Region::new(i * c, j * c, c))).collect();
    let t = Instant::now();
    let fast: Vec<_> = regions.iter().map(|&r| object_errors(&hm, r)).collect();
    let t_fast = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let reference: Vec<[f64; FACTORS]> = regions
        .iter()
        .map(|&r| std::array::from_fn(|k| object_error(&hm, r, factor(k)).avg))
        .collect();
    let t_ref = t.elapsed().as_secs_f64();
    let same = fast
        .iter()
        .zip(&reference)
        .all(|(a, b)| a.avg.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()));
    println!(
        "level {level} ({} nodes of {c} cells): fast {t_fast:.2} s, reference {t_ref:.2} s, \
         {:.1}x; bit-identical: {same}",
        regions.len(),
        t_ref / t_fast
    );
    assert!(same, "the fast path differs from the reference");
    let _ = table;
}
