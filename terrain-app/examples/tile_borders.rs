//! Skirts against shared border vertices, measured on a `terrain tiles` tileset: for every pair
//! of neighbouring tiles of one level, the T-junctions (border vertices one tile has and the
//! other lacks) and the vertical gap between the two tiles' border polylines (the cracks the
//! skirts hide), and what sharing the border vertices would cost: stitching inserts each
//! missing border vertex into the tile that lacks it, splitting one triangle (+1 triangle per
//! T-junction), with the neighbour's height there (moving that tile's surface by up to the gap).
//!
//! Usage: `cargo run --release -p terrain-app --example tile_borders -- TILESET [LEVEL]`
//! (LEVEL: default the deepest). Prints one JSON line.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use terrain_core::tin::quantized_mesh::{self, Decoded};

/// One side of a tile: `(position along the side, height)` of its edge vertices, sorted.
fn side(tile: &Decoded, which: usize) -> Vec<(u16, f64)> {
    let mut out: Vec<(u16, f64)> = tile.edges[which]
        .iter()
        .map(|&k| {
            let v = tile.vertices[k as usize];
            // West/east sides run along v, south/north along u.
            let along = if which == 0 || which == 2 { v[1] } else { v[0] };
            (along, tile.position(k as usize).1)
        })
        .collect();
    out.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
    out.dedup_by_key(|p| p.0);
    out
}

/// The polyline's height at `at` (linear between its vertices).
fn height_at(line: &[(u16, f64)], at: u16) -> Option<f64> {
    let k = line.partition_point(|p| p.0 < at);
    let b = line.get(k)?;
    if b.0 == at {
        return Some(b.1);
    }
    let a = line.get(k.checked_sub(1)?)?;
    let t = f64::from(at - a.0) / f64::from(b.0 - a.0);
    Some(a.1 + t * (b.1 - a.1))
}

fn load(path: &Path) -> Option<Decoded> {
    let bytes = std::fs::read(path).ok()?;
    let bytes =
        if quantized_mesh::is_gzip(&bytes) { quantized_mesh::gunzip(&bytes).ok()? } else { bytes };
    quantized_mesh::decode(&bytes).ok()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(dir) = args.first().map(PathBuf::from) else {
        return Err("usage: tile_borders TILESET [LEVEL]".into());
    };
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("tiles.json"))?)?;
    let level = match args.get(1) {
        Some(l) => l.parse::<u32>()?,
        None => summary["max_level"].as_u64().ok_or("tiles.json has no max_level")? as u32,
    };
    let mut tiles: BTreeMap<(u32, u32), Decoded> = BTreeMap::new();
    let ldir = dir.join(level.to_string());
    for x in std::fs::read_dir(&ldir)? {
        let x = x?;
        let Ok(xi) = x.file_name().to_string_lossy().parse::<u32>() else { continue };
        for y in std::fs::read_dir(x.path())? {
            let y = y?;
            let name = y.file_name().to_string_lossy().into_owned();
            let Some(yi) = name.strip_suffix(".terrain").and_then(|s| s.parse::<u32>().ok()) else {
                continue;
            };
            let t =
                load(&y.path()).ok_or_else(|| format!("cannot decode {}", y.path().display()))?;
            tiles.insert((xi, yi), t);
        }
    }
    let triangles: usize = tiles.values().map(|t| t.triangles.len()).sum();
    let (mut pairs, mut tjunctions, mut cracked, mut positions) = (0usize, 0usize, 0usize, 0usize);
    let mut gaps: Vec<f64> = Vec::new();
    for (&(x, y), a) in &tiles {
        // East neighbour: a's east side (2) against b's west (0); north: a's north (3), b's
        // south (1).
        for (nb, sa, sb) in [((x + 1, y), 2, 0), ((x, y + 1), 3, 1)] {
            let Some(b) = tiles.get(&nb) else { continue };
            pairs += 1;
            let (la, lb) = (side(a, sa), side(b, sb));
            let ka: std::collections::BTreeSet<u16> = la.iter().map(|p| p.0).collect();
            let kb: std::collections::BTreeSet<u16> = lb.iter().map(|p| p.0).collect();
            tjunctions += ka.symmetric_difference(&kb).count();
            // Height quanta of both tiles: gaps under them are no crack.
            let q = |t: &Decoded| f64::from(t.max_height - t.min_height) / 32767.0;
            let tol = q(a) + q(b) + 1e-6;
            let mut worst = 0f64;
            for &at in ka.union(&kb) {
                let (Some(ha), Some(hb)) = (height_at(&la, at), height_at(&lb, at)) else {
                    continue;
                };
                positions += 1;
                let g = (ha - hb).abs();
                if g > tol {
                    cracked += 1;
                }
                worst = worst.max(g);
            }
            gaps.push(worst);
        }
    }
    gaps.sort_by(f64::total_cmp);
    let pct = |p: f64| gaps.get(((gaps.len() as f64 - 1.0) * p).round() as usize).copied();
    let bound = summary["levels"]
        .as_array()
        .and_then(|ls| ls.iter().find(|l| l["level"].as_u64() == Some(u64::from(level))))
        .and_then(|l| l["bound_m"].as_f64());
    let out = serde_json::json!({
        "tileset": dir.display().to_string(),
        "level": level,
        "bound_m": bound,
        "tiles": tiles.len(),
        "triangles": triangles,
        "neighbour_pairs": pairs,
        "t_junctions": tjunctions,
        "border_positions": positions,
        "positions_with_a_gap_over_the_quantum": cracked,
        "gap_per_pair_median_m": pct(0.5),
        "gap_per_pair_p99_m": pct(0.99),
        "gap_max_m": gaps.last(),
        "shared_borders_by_stitching_triangles": triangles + tjunctions,
        "shared_borders_extra_triangles_pct": 100.0 * tjunctions as f64 / triangles.max(1) as f64,
    });
    println!("{out}");
    Ok(())
}
