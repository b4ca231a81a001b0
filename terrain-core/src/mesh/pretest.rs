//! A conservative f32 pre-test for the greedy mesher's scan: four samples at a time, in the
//! arithmetic hmm scans in, with a proven margin, so that a sample it dismisses is one the
//! exact f64 test dismisses too and the mesh stays bit for bit the same.
//!
//! The scan ([`super::delaunay`]) looks for the sample of a triangle with the largest error
//! `|z_s - n / d|` (`n = w0 z0 + w1 z1 + w2 z2`, the weights `w_k` exact integers in `[0, d]`,
//! `d = orient(v)`), against a running threshold `S = best error x d`. Its f64 dismissal test
//! keeps every sample with `fl64(|z_s d - n|) + fl64((|z_s d| + |n|) 1e-14) > S`. With
//! `E = |z_s d - N|` the exact value (`N = sum w_k z_k` in real arithmetic) and
//! `T = |z_s| d + sum w_k |z_k|`, that test dismisses whenever `E + 1.1e-14 T <= S`: its
//! three products and four sums lose at most `gamma_5 T` (f64, Higham's
//! `gamma_n = n u / (1 - n u)`, `u = 2^-53`), its margin term is at most `1.0001e-14 T`, the
//! last sum multiplies by `1 + u` and `E <= T`.
//!
//! **The pre-test** ([`dismissed`]) evaluates the same expression in f32 (`u = 2^-24`), with
//! heights that are f32 already (grid samples; the caller checks its vertex heights round-trip)
//! and weights rounded once to f32 (exact while `d <= 2^24`), and dismisses a sample when
//!
//! `A + K t + m <= s`, with `A = |fl32(z_s d) - fl32((p0 + p1) + p2)|`, `p_k = fl32(w_k z_k)`,
//! `t = fl32(|z_s d| + |p0| + |p1| + |p2|)`, `K = 2^-20 = 16 u`, `m = 2^-126`,
//!
//! `s` the largest f32 at most `S` ([`threshold`]). Derivation (standard model
//! `fl(a op b) = (a op b)(1 + delta)`, `|delta| <= u`, plus an absolute `2^-150` where a result
//! is subnormal; every term of `T` is non-negative because the weights are):
//!
//! 1. Each `p_k` carries the weight's rounding and the product's; `fl32(z_s d)` the same two;
//!    the sums of `n` two more: `|A - E| <= gamma_4 T + 2^-146` (Higham, Lemma 3.1 and the
//!    inner-product bound 3.4), then `A` is rounded once more: `A >= (1 - u)(E - gamma_4 T) -
//!    2^-146`.
//! 2. `t >= (1 - gamma_5) T - 2^-147` (five roundings on each non-negative term).
//! 3. The left side is three more roundings: computed `L >= (1 - u)^3 (A + K t) + m (1 - u) -
//!    2^-148`, and `m (1 - u)` exceeds every absolute (subnormal) term above together, so
//!    `L <= s <= S` gives `S >= (1 - u)^4 E + (1 - u)^3 ((1 - gamma_5) K - gamma_4) T`.
//! 4. `(1 - u)^4 E >= E - 4 u T` (as `E <= T`), so `S >= E + (12 u - 4 u - O(u^2)) T >= E +
//!    7 u T`, and `7 u = 4.2e-7` is far above the `1.1e-14` the f64 test needs: the f64 test
//!    dismisses the sample too. (`K = 8 u` would still hold with `3 u` to spare; `16 u` leaves
//!    the proof a factor of two.)
//!
//! Overflow and NaN: a height near `f32::MAX` times `d` is infinite in f32, and `inf - inf`
//! or a NaN height (a void) is NaN; `A + K t + m <= s` is then false (NaN) or needs `s` itself
//! infinite, i.e. `S` infinite (an infinite bound), where the f64 test dismisses every finite
//! value as well (f64 never overflows on f32 heights times `d < 2^53`). So the pre-test never
//! dismisses what the exact test keeps; a sample it does not dismiss is decided by the exact
//! test as before. The test `pretest_never_dismisses_a_kept_sample_and_needs_its_margin` tries
//! adversarial cases (huge heights, tiny slopes, heights near the f32 limits, planes nearly
//! through samples) and shows the margin is needed: with `K = m = 0` it dismisses kept samples.

/// Samples the pre-test takes together (four f32 lanes: one SSE register; eight were slower).
pub(crate) const LANES: usize = 4;

/// The relative margin `K = 2^-20` (16 f32 units of rounding; see the module's derivation).
pub(crate) const MARGIN: f32 = 1.0 / 1_048_576.0;

/// The absolute margin `m = 2^-126`, above the subnormal results' absolute errors.
pub(crate) const FLOOR: f32 = f32::MIN_POSITIVE;

/// Largest `d` whose weights (integers in `[0, d]`) are exact in f32, stepped or not.
pub(crate) const EXACT_WEIGHTS: f64 = 16_777_216.0;

/// The largest f32 at most `scaled` (the threshold `S`; `+inf` stays infinite).
#[inline]
pub(crate) fn threshold(scaled: f64) -> f32 {
    let s = scaled as f32;
    if f64::from(s) > scaled { s.next_down() } else { s }
}

/// Which of `LANES` samples (heights `zs`, weights `w[k][lane]`, triangle heights `z`, `d`)
/// the pre-test dismisses against `s` ([`threshold`]), with the margins `margin` ([`MARGIN`])
/// and `floor` ([`FLOOR`]) (parameters only so that the tests can show they are needed).
#[inline(always)]
pub(crate) fn dismissed(
    w: &[[f32; LANES]; 3],
    z: [f32; 3],
    zs: &[f32; LANES],
    d: f32,
    s: f32,
    margin: f32,
    floor: f32,
) -> [bool; LANES] {
    let mut out = [false; LANES];
    for k in 0..LANES {
        let p = [w[0][k] * z[0], w[1][k] * z[1], w[2][k] * z[2]];
        let zd = zs[k] * d;
        let a = (zd - ((p[0] + p[1]) + p[2])).abs();
        let t = ((zd.abs() + p[0].abs()) + p[1].abs()) + p[2].abs();
        out[k] = (a + t * margin) + floor <= s;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The exact test's verdict as the scan decides a sample (`delaunay`'s `exact`): kept when
    /// not dismissed by the f64 test and its error `|z_s - n / d|` is above `best`.
    fn kept(w: [f64; 3], z: [f64; 3], zs: f64, d: f64, best: f64) -> bool {
        let n = w[0] * z[0] + w[1] * z[1] + w[2] * z[2];
        let zd = zs * d;
        let scaled = best * d;
        if (zd - n).abs() + (zd.abs() + n.abs()) * 1e-14 <= scaled {
            return false;
        }
        (zs - n / d).abs() > best
    }

    /// Deterministic generator.
    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self) -> u64 {
            self.0 = self
                .0
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            self.0 >> 11
        }
        fn unit(&mut self) -> f64 {
            self.next() as f64 / (1u64 << 53) as f64
        }
    }

    /// Counts, over adversarial cases, the samples the pre-test dismisses that the exact test
    /// keeps (`wrong`) and all the samples it dismisses (`dismissed`), with the given margins.
    fn trial(margin: f32, floor: f32) -> (usize, usize) {
        let mut rng = Lcg(42);
        let (mut wrong, mut total) = (0, 0);
        // Height scales: tiny (subnormal), ordinary, huge, near f32::MAX.
        let scales = [1e-40, 1e-3, 1.0, 3000.0, 1e7, 1e30, 1e37, 3e38];
        let pick = |rng: &mut Lcg, n: usize| (rng.next() % n as u64) as usize;
        for _ in 0..200_000 {
            let scale = scales[pick(&mut rng, scales.len())];
            // Triangle sizes: small tiles up to d = 2^24 (the exact-weight range).
            let d = (1 + rng.next() % (1 << (4 + pick(&mut rng, 21)))) as f64;
            let d = d.min(EXACT_WEIGHTS);
            let w0 = (rng.unit() * d).floor();
            let w1 = (rng.unit() * (d - w0)).floor();
            let w = [w0, w1, d - w0 - w1];
            // Nearly coplanar heights: a plane plus a tiny slope, and a sample a tiny offset
            // off it, so the sample's error is close to the threshold (the margin's business).
            let base = (rng.unit() * 2.0 - 1.0) * scale;
            let slope = scale * [0.0, 1e-9, 1e-6, 1e-3][pick(&mut rng, 4)];
            let z = [0, 1, 2].map(|_| f64::from((base + slope * rng.unit()) as f32));
            let plane = (w[0] * z[0] + w[1] * z[1] + w[2] * z[2]) / d;
            let off = plane.abs() * [0.0, 1e-8, 1e-7, 1e-6, 1e-5][pick(&mut rng, 5)];
            let zs = f64::from((plane + off * (rng.unit() - 0.5)) as f32);
            if !zs.is_finite() || z.iter().any(|z| !z.is_finite()) {
                continue;
            }
            // The running best: at, just below or just above the sample's f64 error, or above
            // it by a fraction of the heights (where the pre-test dismisses).
            let e = (zs - (w[0] * z[0] + w[1] * z[1] + w[2] * z[2]) / d).abs();
            let best = match pick(&mut rng, 4) {
                0 => e,
                1 => e * (1.0 - 1e-7 * rng.unit()),
                2 => e * (1.0 + 1e-6 * rng.unit()),
                _ => e + scale * [1e-7, 1e-6, 1e-5, 1e-3][pick(&mut rng, 4)] * rng.unit(),
            };
            let lanes = [w[0], w[1], w[2]].map(|wk| [wk as f32; LANES]);
            let got = dismissed(
                &lanes,
                z.map(|z| z as f32),
                &[zs as f32; LANES],
                d as f32,
                threshold(best * d),
                margin,
                floor,
            )[0];
            if got {
                total += 1;
                if kept(w, z, zs, d, best) {
                    wrong += 1;
                }
            }
        }
        (wrong, total)
    }

    #[test]
    fn pretest_never_dismisses_a_kept_sample_and_needs_its_margin() {
        let (wrong, total) = trial(MARGIN, FLOOR);
        assert_eq!(wrong, 0, "the pre-test dismissed {wrong} kept samples");
        // It is no empty test: it dismisses most of the samples well below the best.
        assert!(total > 10_000, "only {total} dismissed");
        // Negative control: without its margin the f32 test dismisses kept samples.
        let (wrong, _) = trial(0.0, 0.0);
        eprintln!("without the margin: {wrong} kept samples dismissed");
        assert!(wrong > 0, "no kept sample dismissed without the margin");
    }

    #[test]
    fn pretest_edge_cases_are_never_dismissed() {
        let w = [[1.0f32; LANES], [1.0; LANES], [2.0; LANES]];
        // A void (NaN) sample and an infinite product are never dismissed; an exact plane
        // far below the best is.
        let mut zs = [1.0f32; LANES];
        zs[0] = f32::NAN;
        zs[1] = f32::MAX;
        let got = dismissed(&w, [1.0, 1.0, 1.0], &zs, 4.0, threshold(1e30), MARGIN, FLOOR);
        assert_eq!(got, std::array::from_fn(|k| k >= 2));
        // A zero threshold (bound 0, nothing found yet) dismisses nothing, not even exact
        // planes.
        let got = dismissed(&w, [1.0, 1.0, 1.0], &[1.0; LANES], 4.0, threshold(0.0), MARGIN, FLOOR);
        assert_eq!(got, [false; LANES]);
        // The threshold never rounds up.
        for s in [0.1, 1.0 / 3.0, 1e-45, 3.5e38, 1e300, f64::INFINITY] {
            assert!(f64::from(threshold(s)) <= s, "{s}");
        }
        assert_eq!(threshold(0.1), 0.1f32.next_down(), "0.1f32 is above 0.1");
        assert_eq!(threshold(0.5), 0.5f32, "exact");
    }
}
