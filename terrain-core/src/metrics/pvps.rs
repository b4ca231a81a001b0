//! The PVPS paper's (Zhang 2021) roughness-weighted quadtree split (section 2.3.4, Eq. 8-9)
//! and the roughness it reads (section 2.2.3, Eq. 5).
//!
//! Eq. 8: `ratio = C1 * D / (Span * (R + C2))`; Eq. 9: `Span = Length / 2^l`. `D` is the node's
//! distance to the camera, `Span` the node's edge length in the terrain (the whole terrain's
//! edge `Length` halved per level `l`), `R` the node's precomputed roughness, `C1` the degree of
//! subdivision, `C2` how much roughness matters. A node splits when `ratio < 1`. So the ratio
//! divides a scaled distance by the node's roughness-weighted size: near, large, rough nodes
//! split. This is a split criterion, not an error: a plane has roughness `1 / cos(slope)`, not 0.
//!
//! Eq. 5: `C_roughness = 1 / cos(C_slope)` per DEM cell, slope from the centre cell and its
//! eight neighbours (the paper used ArcGIS's Slope tool, i.e. Horn's method), which equals
//! `sqrt(1 + |grad z|^2)`, the surface-to-projected area ratio. The paper then normalises the
//! map to 0..255 (a grey image, [`normalize_roughness`]) and builds a pyramid whose pixels are
//! the mean of their four children; a node's roughness is its pixel. [`region_roughness`] is
//! the mean over the node's samples, which is what the mean pyramid computes for aligned
//! nodes (up to shared border samples). The paper gives no values for `C1`, `C2` (only
//! `C3 = 10`, `C4 = 1` for its Eq. 12), so they are parameters, with `R` on whatever scale the
//! caller normalised to.
//!
//! Frames: the paper's ground is OpenGL's xz plane; ours is xy. The slope uses the metric
//! spacing only, the distance comes from differences, so no absolute coordinate enters.

use crate::heightmap::Heightmap;
use crate::metrics::{Coverage, Region};

/// Eq. 9: `Span = Length / 2^l`, the edge length (metres) of a level-`l` node of a terrain
/// whose edge is `length` metres. Levels past 1023 give 0 (f64 cannot halve further).
pub fn span(length: f64, level: u32) -> f64 {
    length * 0.5f64.powi(level.min(1023) as i32)
}

/// Eq. 8: `ratio = C1 * D / (Span * (R + C2))`; the node splits when it is below 1.
///
/// Degenerate: `d <= 0` (camera inside or on the node) gives 0 (split); a non-positive or
/// NaN denominator (`Span = 0`, a zero-area node, or `R + C2 <= 0`) gives `f64::INFINITY`
/// (never split: there is nothing to refine, or the constants are out of their domain,
/// `R >= 0`, `C2 > 0`); a NaN numerator gives `f64::INFINITY` as well (never split).
pub fn split_ratio(d: f64, span: f64, roughness: f64, c1: f64, c2: f64) -> f64 {
    let den = span * (roughness + c2);
    if den.is_nan() || den <= 0.0 {
        return f64::INFINITY;
    }
    let num = c1 * d.max(0.0);
    if num.is_nan() {
        return f64::INFINITY;
    }
    num / den
}

/// Eq. 8's decision: split when `ratio < 1`.
pub fn should_split(ratio: f64) -> bool {
    ratio < 1.0
}

/// Eq. 5 at sample `(i, j)`: `1 / cos(slope) = sqrt(1 + (dz/dx)^2 + (dz/dy)^2)`, with Horn's
/// 3 x 3 gradient (edge-extended at the grid border, filled heights for void neighbours), x
/// east and y north in metres. Always finite and `>= 1`.
pub fn cell_roughness(hm: &Heightmap, i: usize, j: usize) -> f64 {
    let (i, j) = (i as i64, j as i64);
    let z = |di: i64, dj: i64| f64::from(hm.get_clamped(i + di, j + dj));
    let s = hm.georef().spacing_m;
    // Horn (1981): weighted differences over the 3 x 3 window (row j + 1 is north).
    let dzdx = ((z(1, 1) + 2.0 * z(1, 0) + z(1, -1)) - (z(-1, 1) + 2.0 * z(-1, 0) + z(-1, -1)))
        / (8.0 * s.x);
    let dzdy = ((z(-1, 1) + 2.0 * z(0, 1) + z(1, 1)) - (z(-1, -1) + 2.0 * z(0, -1) + z(1, -1)))
        / (8.0 * s.y);
    (1.0 + dzdx * dzdx + dzdy * dzdy).sqrt()
}

/// Mean [`cell_roughness`] over the non-void samples of `region` (0 with [`Coverage::Empty`]
/// or [`Coverage::VoidOnly`] when there are none).
pub fn region_roughness(hm: &Heightmap, region: Region) -> (f64, Coverage) {
    let Some(c) = region.clip(hm) else {
        return (0.0, Coverage::Empty);
    };
    let (mut sum, mut n) = (0.0, 0usize);
    for j in c.y0..=c.y1 {
        for i in c.x0..=c.x1 {
            if !hm.voids().get(i, j) {
                sum += cell_roughness(hm, i, j);
                n += 1;
            }
        }
    }
    (if n == 0 { 0.0 } else { sum / n as f64 }, Coverage::from_count(n))
}

/// The paper's normalisation of the roughness map to a 0..255 grey value, over the map's
/// range `[r_min, r_max]` (clamped; a flat range gives 0).
pub fn normalize_roughness(r: f64, r_min: f64, r_max: f64) -> f64 {
    let range = r_max - r_min;
    if range.is_nan() || range <= 0.0 || r.is_nan() {
        return 0.0;
    }
    (255.0 * (r - r_min) / range).clamp(0.0, 255.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::georef::Georef;

    #[test]
    fn ratio_and_span() {
        assert_eq!(span(4096.0, 3), 512.0);
        // C1 = 2, D = 100, Span = 50, R = 3, C2 = 1: 200 / 200 = 1 -> no split.
        let r = split_ratio(100.0, 50.0, 3.0, 2.0, 1.0);
        assert_eq!(r, 1.0);
        assert!(!should_split(r));
        assert!(should_split(split_ratio(99.0, 50.0, 3.0, 2.0, 1.0)));
        assert_eq!(split_ratio(0.0, 50.0, 3.0, 2.0, 1.0), 0.0);
        assert_eq!(split_ratio(-1.0, 50.0, 3.0, 2.0, 1.0), 0.0);
        assert_eq!(split_ratio(10.0, 0.0, 3.0, 2.0, 1.0), f64::INFINITY);
        assert_eq!(split_ratio(10.0, 5.0, 0.0, 2.0, -1.0), f64::INFINITY);
        assert_eq!(normalize_roughness(1.5, 1.0, 2.0), 127.5);
        assert_eq!(normalize_roughness(1.5, 1.0, 1.0), 0.0);
    }

    #[test]
    fn plane_roughness_is_secant_of_slope() {
        // z = 0.75 x (spacing 2 m, so 1.5 m per sample): slope tan = 0.75, 1 / cos = 1.25.
        let hm = Heightmap::from_fn(5, 5, Georef::local(2.0), |i, _| 1.5 * i as f32).unwrap();
        assert!((cell_roughness(&hm, 2, 2) - 1.25).abs() < 1e-12);
        // An interior region (every 3 x 3 window on the grid) averages the same value.
        let (r, cov) = region_roughness(&hm, Region::new(1, 1, 2));
        assert!((r - 1.25).abs() < 1e-12);
        assert_eq!(cov, Coverage::Measured { samples: 9 });
    }
}
