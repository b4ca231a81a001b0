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

/// `floor(b / a)` along a row-by-row walk, without a division per row: `b` grows by `step`
/// each row, and the quotient and remainder are stepped exactly (`b = q * a + r`, `0 <= r < a`).
#[derive(Clone, Copy)]
struct FloorStep {
    a: i64,
    q: i64,
    r: i64,
    step_q: i64,
    step_r: i64,
}

impl FloorStep {
    /// `floor(b / a)` now, `b + step` next row; `a > 0`.
    #[inline]
    fn new(b: i64, step: i64, a: i64) -> Self {
        Self {
            a,
            q: b.div_euclid(a),
            r: b.rem_euclid(a),
            step_q: step.div_euclid(a),
            step_r: step.rem_euclid(a),
        }
    }

    /// Moves to the next row.
    #[inline]
    fn step(&mut self) {
        self.q += self.step_q;
        self.r += self.step_r;
        if self.r >= self.a {
            self.r -= self.a;
            self.q += 1;
        }
    }
}

/// Calls `f(i, j, z)` for every integer sample of the closed counter-clockwise triangle
/// `v` (grid coordinates) with heights `z`, where `z` is the barycentric interpolation of the
/// vertex heights at `(i, j)`. Samples are visited row by row (south to north, west to east).
///
/// Degenerate or clockwise triangles visit nothing. (The tests' reference: the callers walk
/// [`for_each_row`] over their own rows.)
#[cfg(test)]
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
/// caller that only compares against a threshold can skip most divisions and still decide
/// on the identical value.
pub(crate) fn for_each_numerator_in(
    v: [[i64; 2]; 3],
    z: [f64; 3],
    clip: [i64; 4],
    mut f: impl FnMut(i64, i64, f64),
) {
    for_each_row(v, clip, |y, lo, hi, mut w, dw| {
        for x in lo..=hi {
            f(x, y, numerator(w, z));
            w = step(w, dw);
        }
    });
}

/// The interpolation's numerator at a sample with barycentric weights `w` (times d): the
/// height there is `numerator(w, z) / d`. The one expression every caller evaluates.
#[inline]
pub(crate) fn numerator(w: [f64; 3], z: [f64; 3]) -> f64 {
    w[0] * z[0] + w[1] * z[1] + w[2] * z[2]
}

/// The weights one sample east: `w + dw`, exact (see [`for_each_row`]).
#[inline]
pub(crate) fn step(w: [f64; 3], dw: [f64; 3]) -> [f64; 3] {
    [w[0] + dw[0], w[1] + dw[1], w[2] + dw[2]]
}

/// The change of the barycentric weights (times `d`) of triangle `v` per sample east, the
/// `dw` that [`for_each_row`] passes with every row: exact integers.
#[inline]
pub(crate) fn weights_east(v: [[i64; 2]; 3]) -> [f64; 3] {
    [v[1][1] - v[2][1], v[2][1] - v[0][1], v[0][1] - v[1][1]].map(|k| k as f64)
}

/// The rows of the scan conversion: calls `f(j, lo, hi, w, dw)` for every row `j` of the
/// closed counter-clockwise triangle `v` (inside `clip`) that holds samples `lo..=hi`,
/// south to north, with `w` the barycentric weights (times `d = orient(v)`) at `(lo, j)`
/// and `dw` their change per sample east. Walking a row with [`step`] and evaluating
/// [`numerator`] gives exactly [`for_each_numerator_in`]'s values; a caller with its own
/// per-sample loop (the greedy mesher's scan, which reads its heights row by row) uses this.
///
/// Degenerate or clockwise triangles visit nothing.
pub(crate) fn for_each_row(
    v: [[i64; 2]; 3],
    clip: [i64; 4],
    mut f: impl FnMut(i64, i64, i64, [f64; 3], [f64; 3]),
) {
    let d = orient(v[0], v[1], v[2]);
    if d <= 0 {
        return;
    }
    let y0 = v[0][1].min(v[1][1]).min(v[2][1]).max(clip[1]);
    let y1 = v[0][1].max(v[1][1]).max(v[2][1]).min(clip[3]);
    let x0 = v[0][0].min(v[1][0]).min(v[2][0]).max(clip[0]);
    let x1 = v[0][0].max(v[1][0]).max(v[2][0]).min(clip[2]);
    if y0 > y1 || x0 > x1 {
        return;
    }
    // Edge k runs from v[k] to v[k + 1]; a sample s is inside (or on) it when
    // orient(p, q, s) = (qx - px)(sy - py) - (qy - py)(sx - px) >= 0. For a fixed row this is
    // `a * sx <= b` with a = qy - py and b = (qx - px)(sy - py) + a * px: an edge with a > 0
    // bounds the row's samples above by floor(b / a), one with a < 0 below by
    // ceil(b / a) = -floor(b / -a). A horizontal edge (a = 0) never empties a row of the
    // triangle's span: with r the third vertex, orient(p, q, r) = (qx - px)(ry - py) > 0,
    // so b = (qx - px)(sy - py) >= 0 for every sy between py and ry. The non-horizontal
    // edges' signs sum to zero, so each side has one or two edges; a side with one lists
    // it twice (the min or max of a value with itself), so each row costs the same four
    // exact steps and no division.
    let (mut ups, mut lows) = ([None; 2], [None; 2]);
    for k in 0..3 {
        let (p, q) = (v[k], v[(k + 1) % 3]);
        let a = q[1] - p[1];
        let (step, b) = (q[0] - p[0], (q[0] - p[0]) * (y0 - p[1]) + a * p[0]);
        if a > 0 {
            ups[usize::from(ups[0].is_some())] = Some(FloorStep::new(b, step, a));
        } else if a < 0 {
            lows[usize::from(lows[0].is_some())] = Some(FloorStep::new(b, step, -a));
        }
    }
    let (Some(u0), Some(l0)) = (ups[0], lows[0]) else {
        return; // unreachable for a counter-clockwise triangle (d > 0)
    };
    let mut up = [u0, ups[1].unwrap_or(u0)];
    let mut low = [l0, lows[1].unwrap_or(l0)];
    // Barycentric weights times d, exact: w0 for v[0] is the area opposite it. Along a row
    // they change by their exact integer x-derivatives (orient(p, q, s) changes by
    // p.y - q.y per unit of s.x). They are stepped as f64: every value is an integer in
    // [0, d], d at most twice the grid's area, far below 2^53 for any grid that fits in
    // memory, so each f64 sum is exact and equals `w as f64` of the determinant evaluated
    // at the sample, bit for bit (no int-to-float conversion per sample).
    let dw = weights_east(v);
    for y in y0..=y1 {
        let hi = x1.min(up[0].q).min(up[1].q);
        let lo = x0.max(-low[0].q).max(-low[1].q);
        up.iter_mut().chain(low.iter_mut()).for_each(FloorStep::step);
        if lo <= hi {
            let s = [lo, y];
            let w = [orient(v[1], v[2], s), orient(v[2], v[0], s), orient(v[0], v[1], s)];
            f(y, lo, hi, w.map(|k| k as f64), dw);
        }
    }
}

/// The margin, per unit of a triangle's `d`, by which a [`Line`] test must leave a sample
/// below the threshold for the exact test to dismiss it too, where the finite heights (the
/// samples' and the vertices') are at most `h` in magnitude. The greedy mesher's scan and
/// [`super::verify::check_max`] both dismiss on it.
///
/// Inside a triangle every weight lies in `[0, d]`, so the exact numerator's three products
/// and two sums round by at most about `3u d h` (`u = 2^-53`); the line `n(lo) + k dn`
/// carries that at `lo`, `dn`'s rounding times `k` (each `|k dw_c| <= d`, as the weights at
/// `lo` and `lo + k` both lie in `[0, d]`: at most `6u d h`) and two more roundings; the
/// product `zs d`, the division `n / d` and the comparison with `error d` of the exact test
/// add a few `u d h` more. Together under `30u d h < 4e-15 d h`: 1e-12 leaves a factor of
/// 250, and still dismisses every sample more than a micrometre per kilometre of relief
/// below the bound (bounds are centimetres and up).
pub(crate) fn line_margin(h: f64) -> f64 {
    1e-12 * (h + 1.0)
}

/// The largest `|z|` of `data`, void samples included (a corner vertex may be one), NaN
/// ignored (infinite when some height is: then the line test dismisses nothing; 0 when there
/// is none), from the grid's extremes by lanes.
pub(crate) fn largest_magnitude(data: &[f32]) -> f64 {
    let (min, max, _) = crate::heightmap::extremes_by_lanes(data);
    if min > max { 0.0 } else { f64::from(min.abs().max(max.abs())) }
}

/// [`largest_magnitude`] of `hm`'s samples: from the extremes the heightmap already holds
/// when it has no voids (then every sample is finite and its minimum and maximum are the
/// data's), so a window is not scanned once more per mesher and check; by the scan otherwise
/// (a void's height may be larger than any non-void one, or NaN).
pub(crate) fn largest_magnitude_of(hm: &crate::heightmap::Heightmap) -> f64 {
    if hm.voids().any() {
        largest_magnitude(hm.data())
    } else {
        f64::from(hm.min().abs().max(hm.max().abs()))
    }
}

/// A scan row's interpolation numerator as a line: `n(lo + k) = n(lo) + k dn`.
#[derive(Clone, Copy)]
pub(crate) struct Line {
    /// The numerator at the row's first sample.
    pub at_lo: f64,
    /// Its change per sample east.
    pub slope: f64,
}

impl Line {
    /// The row whose first sample has weights `wt`, stepping by `dw`, vertex heights `z`
    /// (the scan computes the slope once per triangle, the same value).
    #[cfg(test)]
    pub(crate) fn new(wt: [f64; 3], dw: [f64; 3], z: [f64; 3]) -> Self {
        Self { at_lo: numerator(wt, z), slope: numerator(dw, z) }
    }

    /// Whether the sample `k` east of the row's first, height `zs`, is at most `cut` from
    /// the line (times `d`): `cut` is the threshold times `d` less the margin, so the exact
    /// test would dismiss it too ([`line_margin`]). A NaN height is never dismissed.
    #[inline]
    pub(crate) fn dismisses(&self, zs: f32, k: f64, df: f64, cut: f64) -> bool {
        (f64::from(zs) * df - (self.at_lo + k * self.slope)).abs() <= cut
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

    #[test]
    fn stepped_rows_and_weights_equal_the_determinants_at_every_sample_and_clip() {
        // Deterministic triangles over the brute-force window: the samples visited, clipped
        // or not, are the brute-force ones, and each height is bit for bit the weighted mean
        // of the three determinants evaluated at that sample.
        let mut k = 7u64;
        let mut next = || {
            k = k.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            (k >> 35) as i64 % 12
        };
        let (mut triangles, mut samples) = (0, 0);
        for _ in 0..400 {
            let mut v = [[next(), next()], [next(), next()], [next(), next()]];
            if orient(v[0], v[1], v[2]) < 0 {
                v.swap(1, 2);
            }
            let d = orient(v[0], v[1], v[2]);
            if d == 0 {
                continue;
            }
            let z = [1.1 + next() as f64 * 0.7, -3.3 * next() as f64, 0.123_456_789];
            let clip = [next() - 1, next() - 1, next() + 2, next() + 2];
            let mut got = Vec::new();
            for_each_sample_in(v, z, clip, |x, y, h| {
                let s = [x, y];
                let w = [orient(v[1], v[2], s), orient(v[2], v[0], s), orient(v[0], v[1], s)];
                let want =
                    (w[0] as f64 * z[0] + w[1] as f64 * z[1] + w[2] as f64 * z[2]) / d as f64;
                assert_eq!(h.to_bits(), want.to_bits(), "{v:?} at ({x}, {y})");
                got.push((x, y));
            });
            let want: Vec<(i64, i64)> = brute(v)
                .into_iter()
                .filter(|&(x, y)| x >= clip[0] && y >= clip[1] && x <= clip[2] && y <= clip[3])
                .collect();
            assert_eq!(got, want, "{v:?} clipped to {clip:?}");
            triangles += 1;
            samples += got.len();
        }
        assert!(triangles > 300 && samples > 500, "{triangles} triangles, {samples} samples");
    }

    /// The line test never dismisses a sample the exact test keeps: at every sample
    /// of triangles up to 2^14 samples across, with heights of up to Everest's magnitude near
    /// the plane, the threshold just under the sample's exact error (the hardest case) leaves
    /// the sample to the exact test. With no margin the line dismisses such samples (a
    /// negative control, checked in the test), so the margin is what keeps the outcome.
    #[test]
    fn the_line_test_never_dismisses_a_sample_the_exact_test_keeps() {
        let mut rand = crate::test_support::unit_rng(0x2545_f491_4f6c_dd1d);
        let (mut tested, mut unguarded) = (0usize, 0usize);
        for case in 0..400 {
            let side = [8.0, 64.0, 900.0, 16384.0][case % 4];
            let g: [[i64; 2]; 3] =
                std::array::from_fn(|_| [(rand() * side) as i64, (rand() * side) as i64]);
            if orient(g[0], g[1], g[2]) <= 0 {
                continue;
            }
            let base = [0.0, 412.0, -430.5, 8848.0][case % 4 / 2 * 2 + usize::from(case % 3 == 0)];
            let z: [f64; 3] = std::array::from_fn(|_| f64::from((base + rand() * 3000.0) as f32));
            let df = orient(g[0], g[1], g[2]) as f64;
            let mut rows = 0;
            for_each_row(g, [i64::MIN, i64::MIN, i64::MAX, i64::MAX], |_, lo, hi, wt, dw| {
                rows += 1;
                if rows > 40 {
                    return;
                }
                let line = Line::new(wt, dw, z);
                let mut w = wt;
                for i in lo..=hi.min(lo + 300) {
                    let at = (i - lo) as f64;
                    let n = numerator(w, z);
                    w = step(w, dw);
                    // A sample near the plane: errors from micrometres to metres.
                    let off = (rand() - 0.5) * 10f64.powf(rand() * 7.0 - 6.0);
                    let zs = (n / df + off) as f32;
                    let e = (f64::from(zs) - n / df).abs();
                    if e == 0.0 {
                        continue;
                    }
                    // The largest threshold the exact test still keeps the sample at.
                    let error = f64::from_bits(e.to_bits() - 1);
                    let h = z.iter().fold(f64::from(zs.abs()), |a, v| a.max(v.abs()));
                    let cut = error * df - line_margin(h) * df;
                    assert!(
                        !line.dismisses(zs, at, df, cut),
                        "{g:?} {z:?}: sample {at} of a row, error {e}, dismissed"
                    );
                    unguarded += usize::from(line.dismisses(zs, at, df, error * df));
                    tested += 1;
                }
            });
        }
        assert!(tested > 20_000, "{tested} samples");
        assert!(unguarded > 0, "the margin was never needed: the test tests nothing");
    }

    #[test]
    fn the_largest_magnitude_ignores_nan_and_keeps_infinity() {
        // Lengths around the eight lanes, the extreme in every position, negative or not.
        for n in 1..20 {
            for at in 0..n {
                for sign in [1.0f32, -1.0] {
                    let mut v: Vec<f32> = (0..n).map(|k| (k % 5) as f32 - 2.0).collect();
                    v[at] = 9.5 * sign;
                    if at > 0 {
                        v[at - 1] = f32::NAN;
                    }
                    assert_eq!(largest_magnitude(&v), 9.5, "{v:?}");
                }
            }
        }
        assert_eq!(largest_magnitude(&[f32::NAN; 11]), 0.0);
        assert_eq!(largest_magnitude(&[]), 0.0);
        assert_eq!(largest_magnitude(&[1.0, f32::NEG_INFINITY, 3.0]), f64::INFINITY);
        // A heightmap's own extremes give the scan's answer without voids; with voids the scan.
        let mut rand = crate::test_support::unit_rng(0x51_7cc1_b727_220a);
        for case in 0..200 {
            let (w, h) = (1 + case % 9, 1 + case % 5);
            let mut data: Vec<f32> =
                (0..w * h).map(|_| ((rand() - 0.5) * 2.0 * 9000.0) as f32).collect();
            if case % 7 == 0 {
                data.iter_mut().for_each(|z| *z = -z.abs()); // all negative
            }
            if case % 11 == 0 {
                data[0] = -0.0; // a zero extreme of either sign
            }
            let mut voids = crate::heightmap::VoidMask::new(w, h);
            if case % 3 == 0 && w * h > 1 {
                data[w * h - 1] = 1e5;
                voids.set(w - 1, h - 1, true); // a void larger than every other sample
            }
            let hm = crate::heightmap::Heightmap::new(
                w,
                h,
                data.clone(),
                voids,
                crate::Georef::local(1.0),
            )
            .unwrap();
            assert_eq!(
                largest_magnitude_of(&hm).to_bits(),
                largest_magnitude(&data).to_bits(),
                "case {case}"
            );
        }
        // An infinite height: the line test dismisses nothing (the exact test decides all).
        assert_eq!(line_margin(f64::INFINITY), f64::INFINITY);
    }
}
