//! Local Shannon entropy of a classified map over a square window (the entropy paper,
//! Chen 2018, Eq. 1-3): `E = -Σ p_i log2 p_i` with `p_i = K_i / N`, `K_i` the number of
//! window samples in class `i` of `M`, `N` the number of samples in the window.
//!
//! * **Classes.** The paper says "M denotes the number of different types of curvature
//!   values" without saying how real-valued curvature becomes types (a gap). We use the
//!   standard equal-width binning: `M` classes over `[-c, c]`, where `c` is a percentile of
//!   `|curvature|` over the map (default the 98th), and values beyond `±c` fall into the end
//!   classes, so a few extreme cells do not squeeze everything else into one class. When the
//!   percentile is 0 but some value is not (a lone spike), `c` is the largest `|value|`.
//!   When `c = 0` (flat terrain) every sample is in one class and the entropy is 0.
//! * **Window, borders and voids.** The window is `(2r + 1)²` samples centred on the sample,
//!   clipped at the grid's border; samples without a value (voids) are left out of the
//!   histogram, so `N` is the number of valued samples actually in the window. A void sample
//!   has no entropy.
//! * **Units.** Entropy is in bits (log base 2, Eq. 1), between 0 and `log2(min(M, N))`.
//!   `0 log 0` is 0 by the usual convention: the sums run over non-empty classes only.
//!
//! The window slides along each row, adding one column of the window and removing another,
//! and keeps `S = Σ K_i log2 K_i` up to date, so `E = log2 N - S / N` costs O(1) per sample
//! after O(r) per sample for the histogram update. Rows run in parallel with rayon.

use rayon::prelude::*;

use super::curvature::ScalarMap;

/// Settings of the local entropy (window and binning).
#[derive(Debug, Clone, PartialEq)]
pub struct EntropyConfig {
    /// Window radius `r`: the window is `(2r + 1)²` samples, `N` in Eq. 2. Default 3 (7x7,
    /// N = 49), a neighbourhood larger than the 3x3 of the curvature itself.
    pub radius: usize,
    /// Number of classes `M` (Eq. 3). Default 32.
    pub classes: usize,
    /// Percentile of `|value|` that sets the class range `[-c, c]` (0..=1). Default 0.98.
    pub clip_percentile: f64,
}

impl Default for EntropyConfig {
    fn default() -> Self {
        Self { radius: 3, classes: 32, clip_percentile: 0.98 }
    }
}

impl EntropyConfig {
    /// The largest entropy this configuration can produce, bits: `log2(min(M, N))`.
    pub fn max_entropy_bits(&self) -> f64 {
        let n = (2 * self.radius + 1).pow(2);
        (self.classes.max(1).min(n) as f64).log2()
    }
}

/// The class range `c` for `map`: the configured percentile of `|value|` over valued samples.
pub fn class_range(map: &ScalarMap, config: &EntropyConfig) -> f32 {
    let mut abs: Vec<f32> = map.valid().map(f32::abs).collect();
    if abs.is_empty() {
        return 0.0;
    }
    let p = config.clip_percentile.clamp(0.0, 1.0);
    let k = ((abs.len() - 1) as f64 * p).round() as usize;
    let (_, v, _) = abs.select_nth_unstable_by(k, f32::total_cmp);
    let v = *v;
    // A feature on fewer samples than the percentile leaves out (a lone spike) would make the
    // range 0 and every sample one class: take the largest value instead.
    if v > 0.0 { v } else { abs.into_iter().fold(0.0, f32::max) }
}

/// The class of `v` among `m` equal-width classes over `[-c, c]` (ends open).
#[inline]
pub fn class_of(v: f32, c: f32, m: usize) -> usize {
    if c <= 0.0 || m <= 1 {
        return 0;
    }
    let t = (f64::from(v) + f64::from(c)) / (2.0 * f64::from(c)) * m as f64;
    (t.floor().max(0.0) as usize).min(m - 1)
}

/// Local entropy (bits, Eq. 1-3) of `map` classified as in the module doc.
pub fn local_entropy(map: &ScalarMap, config: &EntropyConfig) -> ScalarMap {
    let c = class_range(map, config);
    local_entropy_with_range(map, config, c)
}

/// Local entropy with a given class range `c` (to compare maps on one binning).
pub fn local_entropy_with_range(map: &ScalarMap, config: &EntropyConfig, c: f32) -> ScalarMap {
    let (w, h) = (map.width(), map.height());
    let m = config.classes.max(1);
    let r = config.radius;
    // Class per sample, u16::MAX where the sample has no value.
    let classes: Vec<u16> = map
        .values()
        .iter()
        .map(|&v| if v.is_nan() { u16::MAX } else { class_of(v, c, m).min(65534) as u16 })
        .collect();
    let nmax = (2 * r + 1) * (2 * r + 1);
    // k log2 k for every possible count (0 log 0 = 0).
    let klogk: Vec<f64> =
        (0..=nmax).map(|k| if k == 0 { 0.0 } else { k as f64 * (k as f64).log2() }).collect();
    let mut out = vec![f32::NAN; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(j, row)| {
        let y0 = j.saturating_sub(r);
        let y1 = (j + r).min(h - 1);
        let mut hist = vec![0u32; m];
        let (mut n, mut s) = (0usize, 0.0f64);
        let column = |x: usize, add: bool, hist: &mut [u32], n: &mut usize, s: &mut f64| {
            for y in y0..=y1 {
                let k = classes[y * w + x];
                if k == u16::MAX {
                    continue;
                }
                let slot = &mut hist[k as usize];
                let before = *slot as usize;
                if add {
                    *slot += 1;
                    *n += 1;
                } else {
                    *slot -= 1;
                    *n -= 1;
                }
                *s += klogk[*slot as usize] - klogk[before];
            }
        };
        for x in 0..=r.min(w - 1) {
            column(x, true, &mut hist, &mut n, &mut s);
        }
        for i in 0..w {
            if i > 0 {
                // Remove first: the histogram never holds more than (2r + 1)² samples.
                if i > r {
                    column(i - r - 1, false, &mut hist, &mut n, &mut s);
                }
                if i + r < w {
                    column(i + r, true, &mut hist, &mut n, &mut s);
                }
            }
            if classes[j * w + i] == u16::MAX || n == 0 {
                continue;
            }
            let nf = n as f64;
            // Eq. 3 rearranged: -Σ (K/N) log2 (K/N) = log2 N - Σ K log2 K / N. Clamp the
            // rounding residue of a single-class window to exactly 0.
            let e = (nf.log2() - s / nf).max(0.0);
            row[i] = if e < 1e-9 { 0.0 } else { e as f32 };
        }
    });
    ScalarMap::new(w, h, out)
}

/// Eq. 1-3 directly for one window's list of classes (the reference the sliding version is
/// tested against).
pub fn entropy_of_classes(classes: &[usize]) -> f64 {
    if classes.is_empty() {
        return 0.0;
    }
    let m = classes.iter().copied().max().unwrap_or(0) + 1;
    let mut k = vec![0usize; m];
    for &c in classes {
        k[c] += 1;
    }
    let n = classes.len() as f64;
    -k.iter()
        .filter(|&&ki| ki > 0)
        .map(|&ki| {
            let p = ki as f64 / n; // Eq. 2
            p * p.log2()
        })
        .sum::<f64>()
}
