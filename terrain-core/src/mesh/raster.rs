//! Exact scan conversion of a grid triangle: every sample `(i, j)` in the *closed* triangle,
//! with the mesh's height there by barycentric interpolation.
//!
//! Vertices are grid samples (integers), so the inside test and the barycentric weights are
//! exact `i64` orientation determinants (no epsilon, no missed sample on a shared edge); only
//! the final weighted mean is floating point. The mesh builders and [`super::verify`] share
//! this one interpolation, so the error a builder measured is bit for bit the error the
//! verification measures. (The tests check it independently, with a different search.)

/// Twice the signed area of `(a, b, c)`: positive when counter-clockwise (x east, y north).
#[inline]
pub(crate) fn orient(a: [i64; 2], b: [i64; 2], c: [i64; 2]) -> i64 {
    (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
}

/// `floor(n / d)` for `d > 0`.
#[inline]
fn div_floor(n: i64, d: i64) -> i64 {
    n.div_euclid(d)
}

/// `ceil(n / d)` for `d > 0`.
#[inline]
fn div_ceil(n: i64, d: i64) -> i64 {
    -(-n).div_euclid(d)
}

/// Calls `f(i, j, z)` for every integer sample of the closed counter-clockwise triangle
/// `v` (grid coordinates) with heights `z`, where `z` is the barycentric interpolation of the
/// vertex heights at `(i, j)`. Samples are visited row by row (south to north, west to east).
///
/// Degenerate or clockwise triangles visit nothing.
pub(crate) fn for_each_sample(v: [[i64; 2]; 3], z: [f64; 3], f: impl FnMut(i64, i64, f64)) {
    for_each_sample_in(v, z, [i64::MIN, i64::MIN, i64::MAX, i64::MAX], f);
}

/// [`for_each_sample`] over the samples inside `clip` only (`[x0, y0, x1, y1]`, inclusive):
/// a large triangle checked window by window visits each window's rows and columns only.
pub(crate) fn for_each_sample_in(
    v: [[i64; 2]; 3],
    z: [f64; 3],
    clip: [i64; 4],
    mut f: impl FnMut(i64, i64, f64),
) {
    let df = orient(v[0], v[1], v[2]) as f64;
    for_each_numerator_in(v, z, clip, |x, y, num| f(x, y, num / df));
}

/// [`for_each_sample_in`] without the final division: calls `f(i, j, n)` where the height
/// there is `n / d` exactly as [`for_each_sample`] computes it, `d = orient(v) as f64`. A
/// caller that only compares against a threshold can skip most divisions (the greedy
/// mesher's scan) and still decide on the identical value.
pub(crate) fn for_each_numerator_in(
    v: [[i64; 2]; 3],
    z: [f64; 3],
    clip: [i64; 4],
    mut f: impl FnMut(i64, i64, f64),
) {
    let d = orient(v[0], v[1], v[2]);
    if d <= 0 {
        return;
    }
    let y0 = v[0][1].min(v[1][1]).min(v[2][1]).max(clip[1]);
    let y1 = v[0][1].max(v[1][1]).max(v[2][1]).min(clip[3]);
    let x0 = v[0][0].min(v[1][0]).min(v[2][0]).max(clip[0]);
    let x1 = v[0][0].max(v[1][0]).max(v[2][0]).min(clip[2]);
    // Edge k runs from v[k] to v[k + 1]; a sample s is inside (or on) it when
    // orient(p, q, s) = (qx - px)(sy - py) - (qy - py)(sx - px) >= 0. For a fixed row this is
    // `a * sx <= b` with a = qy - py and b = (qx - px)(sy - py) + a * px.
    let edges = [(v[0], v[1]), (v[1], v[2]), (v[2], v[0])];
    for y in y0..=y1 {
        let (mut lo, mut hi) = (x0, x1);
        for &(p, q) in &edges {
            let a = q[1] - p[1];
            let b = (q[0] - p[0]) * (y - p[1]) + a * p[0];
            if a > 0 {
                hi = hi.min(div_floor(b, a));
            } else if a < 0 {
                lo = lo.max(div_ceil(-b, -a));
            } else if b < 0 {
                hi = lo - 1; // a horizontal edge with the row on its outer side
            }
        }
        if lo > hi {
            continue;
        }
        // Barycentric weights times d, exact: w0 for v[0] is the area opposite it. They are
        // evaluated at the row's first sample and then stepped along the row by their exact
        // integer x-derivatives (orient(p, q, s) changes by p.y - q.y per unit of s.x), so
        // every weight equals the determinant evaluated at the sample, bit for bit.
        let s = [lo, y];
        let (mut w0, mut w1, mut w2) =
            (orient(v[1], v[2], s), orient(v[2], v[0], s), orient(v[0], v[1], s));
        let (d0, d1, d2) = (v[1][1] - v[2][1], v[2][1] - v[0][1], v[0][1] - v[1][1]);
        for x in lo..=hi {
            f(x, y, w0 as f64 * z[0] + w1 as f64 * z[1] + w2 as f64 * z[2]);
            w0 += d0;
            w1 += d1;
            w2 += d2;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Samples of the closed triangle by brute force over its bounding box.
    fn brute(v: [[i64; 2]; 3]) -> Vec<(i64, i64)> {
        let mut out = Vec::new();
        for y in -2..12 {
            for x in -2..12 {
                let s = [x, y];
                if orient(v[0], v[1], s) >= 0
                    && orient(v[1], v[2], s) >= 0
                    && orient(v[2], v[0], s) >= 0
                {
                    out.push((x, y));
                }
            }
        }
        out
    }

    #[test]
    fn scan_conversion_matches_brute_force_and_interpolates_planes_exactly() {
        let tris = [
            [[0, 0], [8, 0], [0, 8]],
            [[0, 0], [9, 3], [2, 7]],
            [[1, 1], [2, 9], [0, 5]],
            [[5, 0], [5, 10], [0, 5]],
            [[0, 0], [10, 1], [10, 2]],
        ];
        for mut v in tris {
            if orient(v[0], v[1], v[2]) < 0 {
                v.swap(1, 2);
            }
            let plane = |x: i64, y: i64| 3.0 + 0.5 * x as f64 - 0.25 * y as f64;
            let z = v.map(|p| plane(p[0], p[1]));
            let mut got = Vec::new();
            for_each_sample(v, z, |x, y, h| {
                assert!((h - plane(x, y)).abs() < 1e-12, "{v:?} at ({x}, {y})");
                got.push((x, y));
            });
            assert_eq!(got, brute(v), "{v:?}");
        }
        let mut n = 0;
        for_each_sample([[0, 0], [0, 4], [4, 0]], [0.0; 3], |_, _, _| n += 1);
        assert_eq!(n, 0, "clockwise triangles visit nothing");
    }
}
