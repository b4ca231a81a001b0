//! Profile curvature of a heightmap (the entropy paper's input map, Chen 2018 section 3.1).
//!
//! The paper derived its curvature map with ArcGIS's Curvature tool; ArcGIS computes
//! profile curvature with the Zevenbergen & Thorne (1987) fourth-order polynomial over the
//! 3x3 window. We use that formula, in the ArcGIS sign and units convention:
//!
//! ```text
//!   z1 z2 z3      D = ((z4 + z6)/2 - z5) / Lx²      G = (z6 - z4) / (2 Lx)
//!   z4 z5 z6      E = ((z2 + z8)/2 - z5) / Ly²      H = (z2 - z8) / (2 Ly)
//!   z7 z8 z9      F = (-z1 + z3 + z7 - z9) / (4 Lx Ly)
//!   (z2 north)    profile = -2 (D G² + E H² + F G H) / (G² + H²) · 100
//! ```
//!
//! in 1/100 of a z-unit per metre (ArcGIS's "1/100 z-units"). On a flat cell (G = H = 0) the
//! direction of steepest slope is undefined and the profile curvature is 0, as ArcGIS reports.
//!
//! Borders and voids (the paper does not say): a void sample has no curvature. A missing
//! neighbour (outside the grid or void) is extrapolated linearly through the centre from the
//! opposite neighbour (`2 z5 - z_opposite`), or takes the centre's height when the opposite
//! one is missing too. Linear extrapolation keeps a plane's curvature exactly 0 up to the
//! border, where ArcGIS's "centre value" rule would invent curvature on every sloping edge.

use terrain_core::Heightmap;

/// A per-sample scalar map with a validity mask (row 0 = south), e.g. curvature or entropy.
#[derive(Debug, Clone, PartialEq)]
pub struct ScalarMap {
    width: usize,
    height: usize,
    /// Values; NaN where [`ScalarMap::get`] returns `None` (void samples).
    values: Vec<f32>,
}

impl ScalarMap {
    /// A map from row-major values; NaN marks a sample without a value.
    pub fn new(width: usize, height: usize, values: Vec<f32>) -> Self {
        assert_eq!(values.len(), width * height, "ScalarMap::new: size mismatch");
        Self { width, height, values }
    }

    /// Columns.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Rows.
    pub fn height(&self) -> usize {
        self.height
    }

    /// The value at `(i, j)`, `None` where the sample has none (void).
    #[inline]
    pub fn get(&self, i: usize, j: usize) -> Option<f32> {
        let v = self.values[j * self.width + i];
        (!v.is_nan()).then_some(v)
    }

    /// Row-major values, NaN where there is none.
    pub fn values(&self) -> &[f32] {
        &self.values
    }

    /// The values that exist, in row-major order.
    pub fn valid(&self) -> impl Iterator<Item = f32> + '_ {
        self.values.iter().copied().filter(|v| !v.is_nan())
    }

    /// Smallest and largest value, `None` when no sample has one.
    pub fn range(&self) -> Option<(f32, f32)> {
        self.valid().fold(None, |acc, v| match acc {
            None => Some((v, v)),
            Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
        })
    }
}

/// Profile curvature at every sample (Zevenbergen & Thorne 1987 as ArcGIS computes it, see
/// the module doc); void samples get none.
pub fn profile_curvature(hm: &Heightmap) -> ScalarMap {
    let (w, h) = (hm.width(), hm.height());
    let s = hm.georef().spacing_m;
    let (lx, ly) = (s.x, s.y);
    let voids = hm.voids();
    let present = |x: i64, y: i64| -> Option<f64> {
        if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 || voids.get(x as usize, y as usize) {
            None
        } else {
            Some(f64::from(hm.get(x as usize, y as usize)))
        }
    };
    let mut values = Vec::with_capacity(w * h);
    for j in 0..h {
        for i in 0..w {
            if voids.get(i, j) {
                values.push(f32::NAN);
                continue;
            }
            let (x, y) = (i as i64, j as i64);
            let z5 = f64::from(hm.get(i, j));
            // A neighbour at offset (di, dj), extrapolated through the centre when missing.
            let z = |di: i64, dj: i64| -> f64 {
                present(x + di, y + dj)
                    .or_else(|| present(x - di, y - dj).map(|o| 2.0 * z5 - o))
                    .unwrap_or(z5)
            };
            let (z1, z2, z3) = (z(-1, 1), z(0, 1), z(1, 1));
            let (z4, z6) = (z(-1, 0), z(1, 0));
            let (z7, z8, z9) = (z(-1, -1), z(0, -1), z(1, -1));
            values.push(zevenbergen_thorne_profile([z1, z2, z3, z4, z5, z6, z7, z8, z9], lx, ly));
        }
    }
    ScalarMap::new(w, h, values)
}

/// Zevenbergen & Thorne (1987) profile curvature of a 3x3 window `z1..z9` (row by row from
/// the north-west, `z5` the centre), ArcGIS convention (×100, see the module doc).
pub fn zevenbergen_thorne_profile(z: [f64; 9], lx: f64, ly: f64) -> f32 {
    let [z1, z2, z3, z4, z5, z6, z7, z8, z9] = z;
    let d = ((z4 + z6) / 2.0 - z5) / (lx * lx);
    let e = ((z2 + z8) / 2.0 - z5) / (ly * ly);
    let f = (-z1 + z3 + z7 - z9) / (4.0 * lx * ly);
    let g = (z6 - z4) / (2.0 * lx);
    let hh = (z2 - z8) / (2.0 * ly);
    let gh2 = g * g + hh * hh;
    // Flat: no slope direction, curvature 0 (ArcGIS). The relative floor keeps f64 rounding
    // on a plane far from the origin from producing a huge ratio of two tiny numbers.
    if gh2 <= 1e-24 {
        return 0.0;
    }
    (-2.0 * (d * g * g + e * hh * hh + f * g * hh) / gh2 * 100.0) as f32
}
