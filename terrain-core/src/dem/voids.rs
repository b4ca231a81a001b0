//! Void (no-data) samples: the mask, and the fill that keeps geometry finite.
//!
//! A sample is void when it equals the no-data value in force (compared as `f32`, the type the
//! heights are stored in, so `-32768` and a GDAL float nodata such as `-3.4028235e38` both
//! match exactly) or when it is NaN or infinite (float files often use NaN for no-data).
//!
//! # Fill method
//!
//! Voids are filled for geometry only; the [`VoidMask`] keeps them marked so analysis and error
//! measurement can exclude them. The method, per connected void region (4-connected):
//!
//! 1. The region's *rim* is every non-void sample 8-adjacent to a sample of the region.
//! 2. If the rim has more than [`MAX_RIM_SAMPLES`] samples, an evenly strided subsample of
//!    [`MAX_RIM_SAMPLES`] of them is used (every `ceil(n / MAX)`-th in discovery order, which
//!    walks the rim in breadth-first order so the subsample is spread along it). This bounds
//!    the cost at `voids x MAX_RIM_SAMPLES` (Everest's 130,953 voids: ~34 M weight terms).
//! 3. Each void sample gets the inverse-distance-weighted mean (power 2, distance in samples)
//!    of those rim samples **plus** its own non-void 8-neighbours, which are always included so
//!    that the fill meets the surrounding terrain without a step even where the subsample
//!    skipped the adjacent rim samples (a neighbour that is also in the subsample simply counts
//!    twice, which only strengthens its already dominant weight).
//!
//! The fill is deterministic and depends only on the grid and the mask.

use std::collections::VecDeque;
use std::path::Path;

use crate::dem::RawGrid;
use crate::error::{DemError, DemErrorKind};
use crate::heightmap::{Heightmap, HeightmapError, VoidMask};

/// Rim samples used per void region at most (see the module docs).
pub const MAX_RIM_SAMPLES: usize = 256;

/// Marks the void samples of a `width x height` grid: equal to `nodata` (as f32) or not finite.
pub fn void_mask(width: usize, height: usize, data: &[f32], nodata: Option<f64>) -> VoidMask {
    let mut mask = VoidMask::new(width, height);
    let nd = nodata.map(|v| v as f32);
    for (k, &z) in data.iter().enumerate().take(width * height) {
        let void = !z.is_finite() || nd.is_some_and(|nd| z == nd);
        if void {
            mask.set(k % width, k / width, true);
        }
    }
    mask
}

/// Fills the void samples of `data` in place by the method in the module docs.
///
/// Returns [`HeightmapError::AllVoid`] if there is nothing to fill from, and
/// [`HeightmapError::SizeMismatch`] if `data` or `mask` do not match `width x height`.
pub fn fill_voids(
    width: usize,
    height: usize,
    data: &mut [f32],
    mask: &VoidMask,
) -> Result<(), HeightmapError> {
    let n = width * height;
    if data.len() != n {
        return Err(HeightmapError::SizeMismatch { what: "data", width, height, got: data.len() });
    }
    if mask.width() != width || mask.height() != height {
        return Err(HeightmapError::SizeMismatch {
            what: "void mask",
            width,
            height,
            got: mask.width() * mask.height(),
        });
    }
    if !mask.any() {
        return Ok(());
    }
    if mask.count() == n {
        return Err(HeightmapError::AllVoid);
    }

    // visited[k]: void sample already assigned to a region. rim_stamp[k]: region id + 1 that last
    // added non-void sample k to its rim (avoids duplicates without clearing between regions).
    let mut visited = vec![false; n];
    let mut rim_stamp = vec![0u32; n];
    let mut region_id = 0u32;
    let mut queue = VecDeque::new();
    let mut region: Vec<usize> = Vec::new();
    let mut rim: Vec<usize> = Vec::new();

    let neighbours8 = |i: usize, j: usize| {
        const D: [(i64, i64); 8] =
            [(-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)];
        D.iter().filter_map(move |&(di, dj)| {
            let (ni, nj) = (i as i64 + di, j as i64 + dj);
            (ni >= 0 && nj >= 0 && (ni as usize) < width && (nj as usize) < height)
                .then_some((ni as usize, nj as usize))
        })
    };

    for start in 0..n {
        if visited[start] || !mask.get(start % width, start / width) {
            continue;
        }
        region_id = region_id.wrapping_add(1).max(1);
        region.clear();
        rim.clear();
        visited[start] = true;
        queue.push_back(start);
        while let Some(k) = queue.pop_front() {
            region.push(k);
            let (i, j) = (k % width, k / width);
            for (ni, nj) in neighbours8(i, j) {
                let nk = nj * width + ni;
                if mask.get(ni, nj) {
                    // Regions are 4-connected: only edge neighbours join the region.
                    let edge = ni == i || nj == j;
                    if edge && !visited[nk] {
                        visited[nk] = true;
                        queue.push_back(nk);
                    }
                } else if rim_stamp[nk] != region_id {
                    rim_stamp[nk] = region_id;
                    rim.push(nk);
                }
            }
        }

        // A region with no rim can only happen if every sample is void (handled above), but
        // stay total: leave such samples at 0.
        let stride = rim.len().div_ceil(MAX_RIM_SAMPLES).max(1);
        let used: Vec<(f64, f64, f64)> = rim
            .iter()
            .step_by(stride)
            .map(|&r| ((r % width) as f64, (r / width) as f64, data[r] as f64))
            .collect();

        for &k in &region {
            let (i, j) = (k % width, k / width);
            let (x, y) = (i as f64, j as f64);
            let mut wsum = 0.0f64;
            let mut zsum = 0.0f64;
            for &(rx, ry, rz) in &used {
                let d2 = (rx - x) * (rx - x) + (ry - y) * (ry - y);
                let w = 1.0 / d2; // d2 >= 1: rim samples are never the void sample itself
                wsum += w;
                zsum += w * rz;
            }
            for (ni, nj) in neighbours8(i, j) {
                if !mask.get(ni, nj) {
                    let d2 = ((ni as f64 - x).powi(2) + (nj as f64 - y).powi(2)).max(1.0);
                    let w = 1.0 / d2;
                    wsum += w;
                    zsum += w * data[nj * width + ni] as f64;
                }
            }
            data[k] = if wsum > 0.0 { (zsum / wsum) as f32 } else { 0.0 };
        }
    }
    Ok(())
}

/// Marks voids in a decoded grid, fills them, and builds the [`Heightmap`].
pub(crate) fn build_heightmap(path: &Path, grid: RawGrid) -> Result<Heightmap, DemError> {
    let RawGrid { width, height, mut data, georef, nodata, .. } = grid;
    let mask = void_mask(width, height, &data, nodata);
    if mask.count() == width * height {
        return Err(DemError::new(
            path,
            DemErrorKind::AllVoid { count: (width * height) as u64, nodata },
        ));
    }
    fill_voids(width, height, &mut data, &mask).map_err(|e| heightmap_error(path, e))?;
    Heightmap::new(width, height, data, mask, georef).map_err(|e| heightmap_error(path, e))
}

/// Maps a heightmap-construction failure to a reader error (these indicate a reader bug or an
/// all-void grid; the message keeps the detail).
pub(crate) fn heightmap_error(path: &Path, e: HeightmapError) -> DemError {
    let kind = match e {
        HeightmapError::AllVoid => DemErrorKind::AllVoid { count: 0, nodata: None },
        HeightmapError::Empty { width, height } => {
            DemErrorKind::ZeroSize { width: width as u64, height: height as u64 }
        }
        other => DemErrorKind::Malformed { format: "heightmap", message: other.to_string() },
    };
    DemError::new(path, kind)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mask_where(w: usize, h: usize, f: impl Fn(usize, usize) -> bool) -> VoidMask {
        let mut m = VoidMask::new(w, h);
        for j in 0..h {
            for i in 0..w {
                if f(i, j) {
                    m.set(i, j, true);
                }
            }
        }
        m
    }

    #[test]
    fn constant_field_fills_exactly_even_for_large_regions() {
        // A 60 x 60 hole (rim of 244 + border) and a region touching the grid edge.
        let (w, h) = (100, 80);
        let mask = mask_where(w, h, |i, j| (20..80).contains(&i) && (10..70).contains(&j) || i < 3);
        let mut data: Vec<f32> =
            (0..w * h).map(|k| if mask.get(k % w, k / w) { f32::NAN } else { 7.5 }).collect();
        fill_voids(w, h, &mut data, &mask).unwrap();
        assert!(data.iter().all(|&z| (z - 7.5).abs() < 1e-5));
    }

    #[test]
    fn fill_is_bounded_by_the_rim_and_meets_it() {
        // A ramp z = i with a big hole: the fill stays within the rim's range and next to the
        // rim it is close to the neighbouring samples (no step at the border).
        let (w, h) = (200, 200);
        let mask = mask_where(w, h, |i, j| (50..150).contains(&i) && (50..150).contains(&j));
        let mut data: Vec<f32> = (0..w * h)
            .map(|k| if mask.get(k % w, k / w) { f32::NAN } else { (k % w) as f32 })
            .collect();
        fill_voids(w, h, &mut data, &mask).unwrap();
        for j in 50..150 {
            for i in 50..150 {
                let z = data[j * w + i];
                assert!((49.0..=150.0).contains(&z), "({i}, {j}) = {z}");
            }
            // West edge of the hole: neighbours are 49; the fill next to them is close.
            assert!((data[j * w + 50] - 49.0).abs() < 15.0, "row {j}: {}", data[j * w + 50]);
        }
    }

    #[test]
    fn all_void_and_size_errors() {
        let mask = mask_where(2, 2, |_, _| true);
        let mut d = vec![0.0; 4];
        assert_eq!(fill_voids(2, 2, &mut d, &mask), Err(HeightmapError::AllVoid));
        let mut short = vec![0.0; 3];
        assert!(matches!(
            fill_voids(2, 2, &mut short, &mask),
            Err(HeightmapError::SizeMismatch { .. })
        ));
    }

    #[test]
    fn mask_marks_nodata_and_nan() {
        let d = [1.0, -32768.0, f32::NAN, f32::INFINITY, 3.0, 4.0];
        let m = void_mask(3, 2, &d, Some(-32768.0));
        assert_eq!(m.count(), 3);
        assert!(m.get(1, 0) && m.get(2, 0) && m.get(0, 1) && !m.get(1, 1));
    }
}
