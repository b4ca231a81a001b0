//! Right-triangulated irregular network (RTIN) with a guaranteed vertical error.
//!
//! Evans, Kirkpatrick & Townsend 2001 ("Right-triangulated irregular networks", Algorithmica
//! 30): a square of `(2^k + 1)^2` samples is cut along a diagonal into two right isosceles
//! triangles, and a triangle splits by joining its right-angle vertex to the midpoint of its
//! hypotenuse. The implicit binary tree and the bottom-up error pass follow mapbox/martini
//! (V. Agafonkin 2019), with one change that makes the bound *hold*:
//!
//! - Martini's error of a triangle is the error at its hypotenuse midpoint alone (then the max
//!   over descendants). A sample deep inside a big triangle is only compared with its own
//!   parent's hypotenuse, not with the big triangle's plane, so its true error there can
//!   exceed the threshold. Here a triangle's error is the **true maximum** over every
//!   non-void sample of the closed triangle, against the triangle's plane.
//! - As in Martini (and the monotone static error of the out-of-core paper, Qiu 2013 Eq. 3),
//!   the stored value at a hypotenuse midpoint is the max of that true error over *both*
//!   triangles sharing the hypotenuse (the diamond) and of the stored values of their
//!   children. So the value is monotone up the tree and equal for both triangles of a diamond:
//!   a triangle splits if and only if its hypotenuse neighbour splits, and whenever a child
//!   would split, so does its parent. This is the RTIN conformity rule: no T-junctions.
//! - A triangle is kept only when its stored value is `<= max_error`; that value bounds its
//!   true error, so every sample is within the bound.
//!
//! **Grids that are not `(2^k + 1)^2`**: the hierarchy is laid over the enclosing square of
//! `2^k + 1` samples, `2^k` the smallest power of two `>= max(width, height) - 1` (no samples
//! are invented: there is nothing to pad). Triangles wholly beyond the grid's east or north
//! border are dropped; triangles *crossing* the border carry the sentinel `INFINITY` (always
//! split), so the border is followed exactly by triangles of the coarsest level whose edges
//! align with it (for a border at sample `n`, squares of the largest power of two dividing
//! `n`: a 1201-sample SRTM tile is followed by 16-cell squares, an odd border at cell level).
//! Because edges of this hierarchy are axis-aligned or diagonal and the border is at an
//! integer sample, a crossing triangle always has children, and leaves never cross.

use crate::heightmap::Heightmap;
use crate::mesh::{TriMesh, raster};

/// Sentinel for a triangle that must split whatever the bound (it crosses the grid border).
const MUST_SPLIT: f64 = f64::INFINITY;

/// Whether a triangle with stored value `e` splits at bound `max_error`.
#[inline]
fn splits(e: f64, max_error: f64) -> bool {
    e > max_error || e == MUST_SPLIT
}

/// The per-midpoint monotone error of every RTIN triangle over a heightmap: built once,
/// then meshed at any bound in time proportional to the output.
#[derive(Debug, Clone)]
pub struct RtinErrors {
    /// Cells of the enclosing square's side (a power of two).
    tile: usize,
    width: usize,
    height: usize,
    /// Stored value at each hypotenuse midpoint, `(tile + 1)^2`, row-major (row 0 south).
    errors: Vec<f64>,
}

/// Where a triangle lies with respect to the grid rectangle `[0, w-1] x [0, h-1]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Place {
    Inside,
    Crossing,
    Outside,
}

fn place(v: [[usize; 2]; 3], width: usize, height: usize) -> Place {
    let min_x = v[0][0].min(v[1][0]).min(v[2][0]);
    let min_y = v[0][1].min(v[1][1]).min(v[2][1]);
    let max_x = v[0][0].max(v[1][0]).max(v[2][0]);
    let max_y = v[0][1].max(v[1][1]).max(v[2][1]);
    // A triangle's interior projects onto the open interval of its bounding box, so the
    // boxes decide: beyond the border, within it, or with interior points on both sides.
    if min_x >= width - 1 || min_y >= height - 1 {
        Place::Outside
    } else if max_x < width && max_y < height {
        Place::Inside
    } else {
        Place::Crossing
    }
}

/// The true maximum vertical error of the closed triangle's non-void samples against its plane
/// (the interpolation [`super::verify`] measures with, bit for bit). Row by row over the
/// heights, and without a division for most samples: a sample is dismissed on `|z d - n|`
/// (`n / d` the interpolated height) with the greedy mesher's margin (1e-14 of the
/// magnitudes, far above the products' rounding), which never dismisses a sample whose exact
/// error exceeds the running maximum; the survivors are measured exactly. So the maximum is
/// the plain scan's, exactly.
fn true_error(hm: &Heightmap, v: [[usize; 2]; 3]) -> f64 {
    let mut g = v.map(|p| [p[0] as i64, p[1] as i64]);
    if raster::orient(g[0], g[1], g[2]) < 0 {
        g.swap(1, 2);
    }
    let z = g.map(|p| f64::from(hm.get(p[0] as usize, p[1] as usize)));
    let voids = hm.voids().any().then(|| hm.voids());
    let df = raster::orient(g[0], g[1], g[2]) as f64;
    let (data, width) = (hm.data(), hm.width());
    let (mut e, mut e_d) = (0.0f64, 0.0f64);
    let all = [i64::MIN, i64::MIN, i64::MAX, i64::MAX];
    raster::for_each_row(g, all, |j, lo, hi, mut wt, dw| {
        let row = j as usize * width;
        for (i, &zs) in (lo..).zip(&data[row + lo as usize..=row + hi as usize]) {
            let n = raster::numerator(wt, z);
            wt = raster::step(wt, dw);
            let zs = f64::from(zs);
            let zd = zs * df;
            if (zd - n).abs() + (zd.abs() + n.abs()) * 1e-14 <= e_d {
                continue;
            }
            if voids.is_some_and(|m| m.get(i as usize, j as usize)) {
                continue;
            }
            let ei = (zs - n / df).abs();
            if ei > e {
                e = ei;
                e_d = e * df;
            }
        }
    });
    e
}

impl RtinErrors {
    /// Computes the monotone error of every triangle (the expensive part: every sample is
    /// visited once per level, `2 log2(tile)` levels).
    ///
    /// # Panics
    /// If the grid is smaller than 2 x 2 (see [`crate::mesh::validate`]).
    pub fn new(hm: &Heightmap) -> Self {
        let (width, height) = (hm.width(), hm.height());
        assert!(width >= 2 && height >= 2, "an RTIN needs at least 2 x 2 samples");
        let tile = (width - 1).max(height - 1).next_power_of_two();
        let size = tile + 1;
        let mut errors = vec![0.0f64; size * size];
        // Martini's implicit tree: ids 2 and 3 are the two halves of the square, children of
        // id n are 2n and 2n + 1. Level l has 2^(l+1) triangles; the finest stored level is
        // the tile^2 triangles whose hypotenuse midpoint is a sample (their children, with
        // legs of one cell, hold only their three vertices and never split).
        // (A 2 x 2 grid has tile = 1: two triangles with one-cell legs, nothing stored.)
        let num_smallest = tile * tile;
        let num_triangles = num_smallest * 2 - 2;
        let last_level = num_triangles.saturating_sub(num_smallest);
        let at = |x: usize, y: usize| y * size + x;
        // Largest first index to smallest: every child is processed before its parent.
        for idx in (0..num_triangles).rev() {
            let mut id = idx + 2;
            // (a, b) is the hypotenuse, c the right-angle vertex.
            let (mut a, mut b, mut c) = if id & 1 == 1 {
                ([0, 0], [tile, tile], [tile, 0])
            } else {
                ([tile, tile], [0, 0], [0, tile])
            };
            loop {
                id >>= 1;
                if id <= 1 {
                    break;
                }
                let m = [(a[0] + b[0]) / 2, (a[1] + b[1]) / 2];
                if id & 1 == 1 {
                    // left half
                    (a, b) = (c, a);
                } else {
                    // right half
                    (a, b) = (b, c);
                }
                c = m;
            }
            let mid = at((a[0] + b[0]) / 2, (a[1] + b[1]) / 2);
            match place([a, b, c], width, height) {
                Place::Outside => {}
                Place::Crossing => errors[mid] = MUST_SPLIT,
                Place::Inside => {
                    let mut e = true_error(hm, [a, b, c]);
                    if idx < last_level {
                        // Monotone: at least the stored values of both children.
                        let left = errors[at((a[0] + c[0]) / 2, (a[1] + c[1]) / 2)];
                        let right = errors[at((b[0] + c[0]) / 2, (b[1] + c[1]) / 2)];
                        e = e.max(left).max(right);
                    }
                    // Shared with the diamond partner: the max over both triangles.
                    errors[mid] = errors[mid].max(e);
                }
            }
        }
        Self { tile, width, height, errors }
    }

    /// The mesh for a bound: the coarsest conforming RTIN whose every kept triangle has a
    /// stored value `<= max_error` (`max_error >= 0`, not NaN; infinite is allowed).
    pub fn mesh(&self, hm: &Heightmap, max_error: f64) -> TriMesh {
        assert_eq!((hm.width(), hm.height()), (self.width, self.height), "another grid");
        let mut builder = Builder {
            rtin: self,
            max_error,
            index: vec![u32::MAX; self.width * self.height],
            vertices: Vec::new(),
            triangles: Vec::new(),
        };
        let t = self.tile;
        builder.process([0, 0], [t, t], [t, 0]);
        builder.process([t, t], [0, 0], [0, t]);
        TriMesh::from_grid(hm, &builder.vertices, builder.triangles)
    }
}

/// Mesh extraction state: the vertex index of each used sample and the output.
struct Builder<'a> {
    rtin: &'a RtinErrors,
    max_error: f64,
    index: Vec<u32>,
    vertices: Vec<[u32; 2]>,
    triangles: Vec<[u32; 3]>,
}

impl Builder<'_> {
    fn vertex(&mut self, p: [usize; 2]) -> u32 {
        let k = p[1] * self.rtin.width + p[0];
        if self.index[k] == u32::MAX {
            self.index[k] = self.vertices.len() as u32;
            self.vertices.push([p[0] as u32, p[1] as u32]);
        }
        self.index[k]
    }

    fn process(&mut self, a: [usize; 2], b: [usize; 2], c: [usize; 2]) {
        let r = self.rtin;
        if place([a, b, c], r.width, r.height) == Place::Outside {
            return;
        }
        let m = [(a[0] + b[0]) / 2, (a[1] + b[1]) / 2];
        let leg = a[0].abs_diff(c[0]) + a[1].abs_diff(c[1]);
        if leg > 1 && splits(r.errors[m[1] * (r.tile + 1) + m[0]], self.max_error) {
            self.process(c, a, m);
            self.process(b, c, m);
            return;
        }
        debug_assert_eq!(place([a, b, c], r.width, r.height), Place::Inside);
        let g = [a, b, c].map(|p| [p[0] as i64, p[1] as i64]);
        let mut t = [self.vertex(a), self.vertex(b), self.vertex(c)];
        if raster::orient(g[0], g[1], g[2]) < 0 {
            t.swap(1, 2);
        }
        self.triangles.push(t);
    }
}

/// Builds the RTIN mesh of `hm` within `max_error` of every non-void sample.
///
/// # Panics
/// On a grid smaller than 2 x 2 or a negative or NaN bound; [`crate::mesh::build`] checks both.
pub fn build(hm: &Heightmap, max_error: f64) -> TriMesh {
    assert!(max_error >= 0.0, "max_error must be >= 0, got {max_error}");
    RtinErrors::new(hm).mesh(hm, max_error)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::HardCase;

    #[test]
    fn flat_is_two_triangles_and_tiny3_splits_for_its_peak() {
        let flat = build(&HardCase::Flat.build(), 0.0);
        assert_eq!(flat.triangles.len(), 2);
        let tiny3 = HardCase::Tiny3.build();
        assert_eq!(build(&tiny3, 1000.0).triangles.len(), 2);
        // The centre (100 m) is the first split; the four border edges are then exact
        // (their midpoints are the means of their ends), so four triangles are exact.
        let fine = build(&tiny3, 0.0);
        assert_eq!(fine.triangles.len(), 4);
    }

    #[test]
    fn a_crossing_triangle_splits_even_at_an_infinite_bound() {
        // 3 x 2 samples in a 5 x 5 square: the border at x = 2, y = 1 is followed exactly.
        let hm = crate::Heightmap::from_fn(3, 2, crate::Georef::local(1.0), |_, _| 0.0).unwrap();
        let m = build(&hm, f64::INFINITY);
        let area: i64 = m
            .triangles
            .iter()
            .map(|t| {
                let g =
                    t.map(|k| [m.positions[k as usize].x as i64, m.positions[k as usize].y as i64]);
                raster::orient(g[0], g[1], g[2])
            })
            .sum();
        assert_eq!(area, 2 * 2, "twice the 2 x 1 cell area, all counter-clockwise");
    }
}
