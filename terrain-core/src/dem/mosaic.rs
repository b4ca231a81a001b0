//! Mosaics: adjacent tiles on one grid (same CRS, same spacing, aligned origins) read as one
//! heightmap.
//!
//! Tiles are placed by their native (CRS) origins, in samples of the common spacing. Samples
//! that several tiles cover (SRTM tiles share their edge rows and columns) are merged: where
//! both are non-void they must agree within [`SEAM_TOLERANCE_M`], where one is void the other is
//! taken. Every sample of the union's bounding rectangle must be covered by some tile: gaps,
//! misaligned origins, different spacings or CRSs are [`DemErrorKind::Mosaic`] errors. Voids
//! are filled again over the whole mosaic, so fills are continuous across seams.

use std::path::Path;

use glam::dvec2;

use crate::dem::{Dem, LoadOptions, RawGrid, SourceInfo, check_size, load, voids};
use crate::error::{DemError, DemErrorKind};
use crate::georef::{AngularOrLinear, Crs, Georef};

/// Largest difference (metres) allowed between two tiles' non-void values of a shared sample.
pub const SEAM_TOLERANCE_M: f32 = 1.0;

/// Largest misalignment of a tile origin, in samples, still treated as on-grid.
const ALIGN_TOLERANCE: f64 = 1e-3;

/// Reads the tiles at `paths` and joins them into one DEM (see the module docs).
///
/// Errors name the first tile's path (and the offending tile in the message).
pub fn load_mosaic(paths: &[impl AsRef<Path>], options: &LoadOptions) -> Result<Dem, DemError> {
    let Some(first) = paths.first() else {
        return Err(DemError::new("", DemErrorKind::Mosaic("no tiles given".to_string())));
    };
    let first = first.as_ref();
    let merr = |msg: String| DemError::new(first, DemErrorKind::Mosaic(msg));
    let tiles = paths.iter().map(|p| load(p, options)).collect::<Result<Vec<Dem>, DemError>>()?;
    let g0 = tiles[0].heightmap.georef().clone();
    if g0.crs == Crs::Unknown {
        return Err(merr("the tiles carry no georeference, so they cannot be placed".to_string()));
    }
    let sp = g0.native_spacing;

    // Place each tile: offset of its sample (0, 0) from tile 0's, in samples.
    let mut placed = Vec::with_capacity(tiles.len());
    for (t, p) in tiles.iter().zip(paths) {
        let g = t.heightmap.georef();
        let name = p.as_ref().display();
        if g.crs != g0.crs || g.units != g0.units {
            return Err(merr(format!(
                "{name} is in {} but the first tile is in {}",
                g.crs, g0.crs
            )));
        }
        let rel = ((g.native_spacing - sp) / sp).abs();
        if rel.x > 1e-9 || rel.y > 1e-9 {
            return Err(merr(format!(
                "{name} has spacing ({}, {}) but the first tile has ({}, {})",
                g.native_spacing.x, g.native_spacing.y, sp.x, sp.y
            )));
        }
        let off = (g.native_origin - g0.native_origin) / sp;
        let r = off.round();
        if (off - r).abs().max_element() > ALIGN_TOLERANCE || !r.is_finite() {
            return Err(merr(format!(
                "{name} is not on the first tile's grid (offset ({:.4}, {:.4}) samples)",
                off.x, off.y
            )));
        }
        // Offsets beyond +-2^40 samples cannot fit any allowed grid; refusing them here keeps
        // the index arithmetic below far from overflow.
        const FAR: f64 = (1u64 << 40) as f64;
        if r.x.abs() > FAR || r.y.abs() > FAR {
            return Err(merr(format!(
                "{name} is {} x {} samples away from the first tile",
                r.x, r.y
            )));
        }
        // The same area twice (the same tile given twice, or a copy of it) is a mistake, not
        // a mosaic: refused rather than silently merged.
        let (pi, pj) = (r.x as i64, r.y as i64);
        let size = (t.heightmap.width(), t.heightmap.height());
        if let Some(k) = placed.iter().position(|&(qi, qj, q): &(i64, i64, &Dem)| {
            (qi, qj) == (pi, pj) && (q.heightmap.width(), q.heightmap.height()) == size
        }) {
            return Err(merr(format!(
                "{name} covers exactly the area of {} (the same tile given twice?): give each \
                 tile once",
                paths[k].as_ref().display()
            )));
        }
        placed.push((pi, pj, t));
    }
    let i0 = placed.iter().map(|p| p.0).min().unwrap_or(0);
    let j0 = placed.iter().map(|p| p.1).min().unwrap_or(0);
    let i1 = placed.iter().map(|p| p.0 + p.2.heightmap.width() as i64).max().unwrap_or(0);
    let j1 = placed.iter().map(|p| p.1 + p.2.heightmap.height() as i64).max().unwrap_or(0);
    let (w, h) = ((i1 - i0) as u64, (j1 - j0) as u64);
    // Tiles that are not adjacent leave a gap: say so before sizing their bounding grid
    // (two tiles far apart would otherwise read as one absurdly large grid).
    let rect = |&(pi, pj, t): &(i64, i64, &Dem)| {
        (pi, pj, pi + t.heightmap.width() as i64, pj + t.heightmap.height() as i64)
    };
    // Rectangles of samples that overlap or lie side by side (a one-sample step between them).
    let touch = |a: (i64, i64, i64, i64), b: (i64, i64, i64, i64)| {
        a.0 <= b.2 && b.0 <= a.2 && a.1 <= b.3 && b.1 <= a.3
    };
    if placed.len() > 1 {
        for (k, p) in placed.iter().enumerate() {
            let a = rect(p);
            if !placed.iter().enumerate().any(|(m, q)| m != k && touch(a, rect(q))) {
                let other = if k == 0 { 1 } else { 0 };
                let (di, dj) = (p.0 - placed[other].0, p.1 - placed[other].1);
                return Err(merr(format!(
                    "{} is not adjacent to any other tile (it starts {} samples {} and {} \
                     samples {} of {}): a mosaic joins adjacent tiles only; give them one at a \
                     time",
                    paths[k].as_ref().display(),
                    di.unsigned_abs(),
                    if di < 0 { "west" } else { "east" },
                    dj.unsigned_abs(),
                    if dj < 0 { "south" } else { "north" },
                    paths[other].as_ref().display()
                )));
            }
        }
    }
    let area: u64 =
        placed.iter().map(|p| (p.2.heightmap.width() * p.2.heightmap.height()) as u64).sum();
    if area < w.saturating_mul(h) {
        return Err(merr(format!(
            "the tiles do not cover a rectangle: they leave a gap in their {w} x {h} sample \
             bounding grid; a mosaic joins adjacent tiles that cover one"
        )));
    }
    // The joined grid plus its coverage flags (one byte each).
    check_size(first, w, h, 1, options)?;
    let (w, h) = (w as usize, h as usize);

    let mut data = vec![f32::NAN; w * h];
    let mut covered = vec![false; w * h];
    for ((pi, pj, t), p) in placed.iter().zip(paths) {
        let hm = &t.heightmap;
        let (di, dj) = ((pi - i0) as usize, (pj - j0) as usize);
        for j in 0..hm.height() {
            for i in 0..hm.width() {
                let k = (j + dj) * w + i + di;
                covered[k] = true;
                if hm.voids().get(i, j) {
                    continue;
                }
                let z = hm.get(i, j);
                let old = data[k];
                if old.is_nan() {
                    data[k] = z;
                } else if (old - z).abs() > SEAM_TOLERANCE_M {
                    let at = g0.grid_to_native(dvec2(
                        (i + di) as f64 + i0 as f64,
                        (j + dj) as f64 + j0 as f64,
                    ));
                    return Err(merr(format!(
                        "{} disagrees with an earlier tile at the shared sample ({:.6}, {:.6}): {z} vs {old} \
                         (tolerance {SEAM_TOLERANCE_M} m)",
                        p.as_ref().display(),
                        at.x,
                        at.y
                    )));
                }
            }
        }
    }
    if let Some(k) = covered.iter().position(|c| !c) {
        return Err(merr(format!(
            "gap: sample ({}, {}) of the {w} x {h} mosaic is covered by no tile",
            k % w,
            k / w
        )));
    }

    let origin = g0.native_origin + dvec2(i0 as f64, j0 as f64) * sp;
    let georef = match g0.units {
        AngularOrLinear::Degrees => {
            Georef::geographic(g0.crs.clone(), origin, sp, origin.y + 0.5 * (h as f64 - 1.0) * sp.y)
        }
        AngularOrLinear::Metres => {
            Georef::projected_in(g0.crs.clone(), origin, sp, g0.linear_unit_m().unwrap_or(1.0))
        }
    };
    let s0 = &tiles[0].source;
    let sample_type = if tiles.iter().all(|t| t.source.sample_type == s0.sample_type) {
        s0.sample_type.clone()
    } else {
        tiles.iter().map(|t| t.source.sample_type.as_str()).collect::<Vec<_>>().join(" + ")
    };
    let vertical = if tiles.iter().all(|t| t.source.vertical == s0.vertical) {
        s0.vertical
    } else {
        (f64::NAN, f64::NAN)
    };
    let grid = RawGrid {
        width: w,
        height: h,
        data,
        georef,
        nodata: None,
        sample_type: sample_type.clone(),
        notes: Vec::new(),
        vertical,
    };
    let heightmap = voids::build_heightmap(first, grid)?;
    let warnings = tiles.iter().flat_map(|t| t.warnings.iter().cloned()).collect();
    Ok(Dem {
        warnings,
        heightmap,
        source: SourceInfo {
            path: first.to_path_buf(),
            format: s0.format,
            sample_type,
            nodata: s0.nodata,
            vertical,
        },
    })
}
