//! The entropy paper's claim (Chen 2018, section 3.1, Fig. 3 and 18), made measurable: the
//! local curvature entropy map is smoother and less sensitive than the curvature map.
//!
//! Both maps are brought to one domain `[0, 100]` by min-max scaling, as the paper's Fig. 3
//! does, and compared by:
//! * their histograms (`bins` classes over `[0, 100]`) and the share of the fullest bin (a
//!   histogram concentrated in one spike is what the paper calls non-stationary);
//! * smoothness: the mean absolute difference between 4-neighbours, in `[0, 100]` units;
//! * sensitivity: the mean absolute change of each scaled map when every height is perturbed
//!   by a small seeded uniform noise (`± noise_m`), in `[0, 100]` units of the unperturbed map.
//!
//! Min-max scaling lets curvature's few extreme samples squeeze its bulk into a narrow band,
//! which flatters any difference measured in `[0, 100]` units; the `relative_*` figures divide
//! by each map's standard deviation instead and are the fair comparison.

use terrain_core::Heightmap;

use super::curvature::{ScalarMap, profile_curvature};
use super::local::{EntropyConfig, class_range, local_entropy_with_range};

/// Statistics of one map scaled to `[0, 100]`.
#[derive(Debug, Clone, PartialEq)]
pub struct MapStats {
    /// Histogram counts over `[0, 100]`.
    pub histogram: Vec<u64>,
    /// Share of samples in the fullest bin (0..1).
    pub peak_share: f64,
    /// Mean absolute difference between 4-neighbours, `[0, 100]` units.
    pub mean_neighbour_diff: f64,
    /// Standard deviation of the scaled map.
    pub std_dev: f64,
    /// Mean absolute change under the height perturbation, `[0, 100]` units.
    pub sensitivity: f64,
}

impl MapStats {
    /// Smoothness without the scale: mean neighbour difference over the standard deviation
    /// (how much of the map's spread is between neighbours).
    pub fn relative_neighbour_diff(&self) -> f64 {
        if self.std_dev > 0.0 { self.mean_neighbour_diff / self.std_dev } else { 0.0 }
    }

    /// Sensitivity without the scale: mean change under noise over the standard deviation.
    pub fn relative_sensitivity(&self) -> f64 {
        if self.std_dev > 0.0 { self.sensitivity / self.std_dev } else { 0.0 }
    }
}

/// Curvature against entropy on one heightmap.
#[derive(Debug, Clone, PartialEq)]
pub struct ClaimReport {
    /// The profile curvature map's statistics.
    pub curvature: MapStats,
    /// The local curvature entropy map's statistics.
    pub entropy: MapStats,
}

/// Scales `v` from `[lo, hi]` to `[0, 100]` (0 when the range is empty).
fn scale(v: f32, lo: f32, hi: f32) -> f64 {
    if hi > lo {
        (f64::from(v) - f64::from(lo)) / (f64::from(hi) - f64::from(lo)) * 100.0
    } else {
        0.0
    }
}

fn stats(map: &ScalarMap, perturbed: &ScalarMap, bins: usize) -> MapStats {
    let (w, h) = (map.width(), map.height());
    let (lo, hi) = map.range().unwrap_or((0.0, 0.0));
    let bins = bins.max(1);
    let mut histogram = vec![0u64; bins];
    let (mut sum, mut sum2, mut n) = (0.0f64, 0.0f64, 0u64);
    let (mut diff, mut pairs) = (0.0f64, 0u64);
    let (mut change, mut changed) = (0.0f64, 0u64);
    for j in 0..h {
        for i in 0..w {
            let Some(v) = map.get(i, j) else { continue };
            let s = scale(v, lo, hi);
            histogram[((s / 100.0 * bins as f64) as usize).min(bins - 1)] += 1;
            sum += s;
            sum2 += s * s;
            n += 1;
            for (x, y) in [(i + 1, j), (i, j + 1)] {
                if let Some(u) = (x < w && y < h).then(|| map.get(x, y)).flatten() {
                    diff += (scale(u, lo, hi) - s).abs();
                    pairs += 1;
                }
            }
            if let Some(p) = perturbed.get(i, j) {
                change += (scale(p, lo, hi) - s).abs();
                changed += 1;
            }
        }
    }
    let nf = n.max(1) as f64;
    let mean = sum / nf;
    MapStats {
        peak_share: histogram.iter().copied().max().unwrap_or(0) as f64 / nf,
        histogram,
        mean_neighbour_diff: diff / pairs.max(1) as f64,
        std_dev: (sum2 / nf - mean * mean).max(0.0).sqrt(),
        sensitivity: change / changed.max(1) as f64,
    }
}

/// A deterministic uniform value in `[-1, 1)` for sample `k` (SplitMix64 finaliser).
fn noise(k: u64) -> f64 {
    let mut z = k.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

/// Compares the curvature map and its local entropy on `hm` (see the module doc).
pub fn compare_curvature_entropy(
    hm: &Heightmap,
    config: &EntropyConfig,
    bins: usize,
    noise_m: f64,
) -> ClaimReport {
    let curv = profile_curvature(hm);
    let c = class_range(&curv, config);
    let ent = local_entropy_with_range(&curv, config, c);
    let (w, h, mut data, voids, georef) = hm.clone().into_parts();
    for (k, z) in data.iter_mut().enumerate() {
        *z += (noise(k as u64) * noise_m) as f32;
    }
    let noisy = Heightmap::new(w, h, data, voids, georef).expect("a perturbed valid heightmap");
    let curv_n = profile_curvature(&noisy);
    // The same classes as the unperturbed map, so only the heights changed.
    let ent_n = local_entropy_with_range(&curv_n, config, c);
    ClaimReport { curvature: stats(&curv, &curv_n, bins), entropy: stats(&ent, &ent_n, bins) }
}
