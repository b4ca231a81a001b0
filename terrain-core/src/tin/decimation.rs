//! The decimation error of a region of a grid and the exact bound it gives a tile meshed from
//! decimated samples: **one implementation** for every reader (a DEM in memory, a store's
//! blocks read at run time, the bake that writes a store's table of them).
//!
//! **Decimation error** ([`region_errors`]): for a region of a grid and a stride `2^s`, the
//! largest `|z - B_s|` over the region's non-void samples, `B_s` the bilinear interpolation of
//! the strided samples (every `2^s`-th row and column from 0; an index past the grid's last
//! row or column reads the last one).
//!
//! **The bound of a decimated tile** ([`lattice_deviation`]): a tile meshed from a window at
//! stride `2^s` (its vertices on that lattice) differs from every sample `z` under it by
//!
//! `|z - M| <= |z - B_s| + |B_s - M| <= E_s + max |B_s - M|`,
//!
//! and `max |B_s - M|` over the tile's rectangle is found exactly from the lattice alone:
//! in each piece where one lattice cell meets one triangle, `B_s - M` is a bilinear function
//! less a linear one, `a + b x + c y + d x y`, whose Hessian `[[0, d], [d, 0]]` is indefinite
//! (or zero), so it has no extremum inside the piece; its extremes lie on the piece's border.
//! Along a cell's side (axis-parallel) it is linear, so they lie at the piece's corners: lattice
//! points (where the mesher measured `|z - M|` itself) or where a mesh edge crosses a lattice
//! line. Along a mesh edge it is quadratic in the edge's parameter, so they lie at those
//! crossings or at the parabola's apex within a piece. [`lattice_deviation`] evaluates exactly
//! those points. So a decimated tile is proven within its bound from its own window and the
//! decimation errors under it, without reading the samples under it (which, for a coarse tile
//! of a large DEM, are most of the DEM).

use super::grid::{GridTile, TileWindow};
use crate::heightmap::VoidMask;

/// The decimation errors of the region whose samples at stride 1 are `fine` (`width`
/// columns, row-major, south row first; its first sample is the grid's `(i0, j0)`; `voids`:
/// which of them are not measured), at the strides `2^1..=2^max_s`: element `s - 1` for stride
/// `2^s`. `lattice(s, a0, b0, na, nb)` returns the `na x nb` strided samples from the grid's
/// `(a0, b0)` at stride `2^s` (row-major; an index past the grid's last row or column reads the
/// last one). Non-finite heights count as 0.
pub fn region_errors<E>(
    fine: &[f32],
    width: usize,
    (i0, j0): (usize, usize),
    voids: Option<&VoidMask>,
    max_s: u32,
    mut lattice: impl FnMut(u32, usize, usize, usize, usize) -> Result<Vec<f32>, E>,
) -> Result<Vec<f32>, E> {
    let nw = width.max(1);
    let (i1, j1) = (i0 + nw - 1, j0 + fine.len() / nw - 1);
    let finite = |z: f32| if z.is_finite() { f64::from(z) } else { 0.0 };
    (1..=max_s)
        .map(|s| -> Result<f32, E> {
            let t = 1usize << s;
            // The strided samples around the region: from the one at or before its first
            // sample to the one at or after its last.
            let (a0, b0) = ((i0 / t) * t, (j0 / t) * t);
            let (na, nb) = ((i1.div_ceil(t) * t - a0) / t + 1, (j1.div_ceil(t) * t - b0) / t + 1);
            let (na, nb) = (na.max(2), nb.max(2));
            let lattice = lattice(s, a0, b0, na, nb)?;
            let lz = |a: usize, b: usize| finite(lattice[b * na + a]);
            // The fractions `k / t` of a cell, each computed once (the same f64 values as
            // dividing per sample).
            let frac: Vec<f64> = (0..t).map(|k| k as f64 / t as f64).collect();
            let mut worst = 0f64;
            for j in j0..=j1 {
                let (b, fy) = ((j - b0) >> s, frac[(j - b0) & (t - 1)]);
                let b1 = (b + 1).min(nb - 1);
                let row = &fine[(j - j0) * nw..][..nw];
                // Cell by cell along the row: its four lattice heights read once.
                let mut i = i0;
                while i <= i1 {
                    let a = (i - a0) >> s;
                    let a1 = (a + 1).min(na - 1);
                    let end = (a0 + (a + 1) * t - 1).min(i1);
                    let (sw, se, nw_, ne) = (lz(a, b), lz(a1, b), lz(a, b1), lz(a1, b1));
                    for i in i..=end {
                        if voids.is_some_and(|v| v.get(i - i0, j - j0)) {
                            continue;
                        }
                        let fx = frac[(i - a0) & (t - 1)];
                        let south = sw + fx * (se - sw);
                        let north = nw_ + fx * (ne - nw_);
                        let z = south + fy * (north - south);
                        let d = (finite(row[i - i0]) - z).abs();
                        worst = worst.max(d);
                    }
                    i = end + 1;
                }
            }
            Ok(worst as f32)
        })
        .collect()
}

/// A decimation error as stored (`f32`, rounded to nearest) made an upper bound of the `f64`
/// value it was rounded from: one part in 2^22 more.
pub fn error_upper_bound(e: f32) -> f64 {
    let e = f64::from(e);
    e + e * (1.0 / f64::from(1u32 << 22))
}

/// `max |B_s - M|` over `tile`'s rectangle (see the module docs): `B_s` the bilinear
/// interpolation of `heights`, the samples of `win` (row-major, south row first, no void)
/// that the tile was meshed from, `M` the tile's surface. Exact but for `f64` rounding, for
/// which a margin of `1e-9` of the largest height magnitude (plus a nanometre) is added. The
/// tile's vertices must lie on the window's lattice (those of a tile built from `win`).
pub fn lattice_deviation(tile: &GridTile, win: &TileWindow, heights: &[f32]) -> f64 {
    let (w, h) = (win.width, win.height);
    debug_assert_eq!(heights.len(), w * h);
    let s = win.stride_log2;
    let lat = |v: [u32; 2]| -> [f64; 2] {
        [f64::from((v[0] - win.x0) >> s), f64::from((v[1] - win.y0) >> s)]
    };
    let z = |a: usize, b: usize| f64::from(heights[b.min(h - 1) * w + a.min(w - 1)]);
    let largest = heights.iter().fold(0f64, |m, &v| m.max(f64::from(v).abs()));
    // The lattice points: the mesher measured `|z - M|` at every window sample.
    let mut worst = tile.measured.max_error;
    let mut ts: Vec<f64> = Vec::new();
    for t in &tile.triangles {
        for k in 0..3 {
            let (p, q) = (t[k] as usize, t[(k + 1) % 3] as usize);
            let (pa, pb) = (lat(tile.vertices[p]), lat(tile.vertices[q]));
            let (ma, mb) = (f64::from(tile.heights[p]), f64::from(tile.heights[q]));
            let d = [pb[0] - pa[0], pb[1] - pa[1]];
            // The edge's parameters where it crosses a lattice line, its ends included.
            ts.clear();
            ts.extend([0.0, 1.0]);
            for axis in 0..2 {
                if d[axis] == 0.0 {
                    continue;
                }
                let (lo, hi) = (pa[axis].min(pb[axis]), pa[axis].max(pb[axis]));
                let mut c = lo + 1.0;
                while c < hi {
                    ts.push((c - pa[axis]) / d[axis]);
                    c += 1.0;
                }
            }
            ts.sort_by(f64::total_cmp);
            for pair in ts.windows(2) {
                let (t0, t1) = (pair[0], pair[1]);
                if t1 <= t0 {
                    continue;
                }
                let tm = 0.5 * (t0 + t1);
                // The lattice cell holding this piece.
                let cx = (pa[0] + d[0] * tm).floor().clamp(0.0, (w.max(2) - 2) as f64);
                let cy = (pa[1] + d[1] * tm).floor().clamp(0.0, (h.max(2) - 2) as f64);
                let (ci, cj) = (cx as usize, cy as usize);
                let (z00, z10, z01, z11) =
                    (z(ci, cj), z(ci + 1, cj), z(ci, cj + 1), z(ci + 1, cj + 1));
                let (ex, ey, dd) = (z10 - z00, z01 - z00, z11 - z10 - z01 + z00);
                // u = pu + qu t, v = pv + qv t in the cell; M = ma + (mb - ma) t.
                let (pu, qu, pv, qv) = (pa[0] - cx, d[0], pa[1] - cy, d[1]);
                let c0 = z00 + ex * pu + ey * pv + dd * pu * pv - ma;
                let c1 = ex * qu + ey * qv + dd * (pu * qv + qu * pv) - (mb - ma);
                let c2 = dd * qu * qv;
                let g = |t: f64| c0 + t * (c1 + t * c2);
                worst = worst.max(g(t0).abs()).max(g(t1).abs());
                if c2 != 0.0 {
                    let apex = -c1 / (2.0 * c2);
                    if apex > t0 && apex < t1 {
                        worst = worst.max(g(apex).abs());
                    }
                }
            }
        }
    }
    worst + 1e-9 * largest + 1e-9
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quadtree::NodeId;
    use crate::tin::grid::build_tile_within;

    /// A rough window: sines and a hash's noise.
    fn heights(w: usize, h: usize, seed: u64) -> Vec<f32> {
        (0..w * h)
            .map(|p| {
                let (i, j) = ((p % w) as f32, (p / w) as f32);
                let n = (p as u64 ^ seed).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 40;
                300.0 * (i * 0.31).sin() * (j * 0.23).cos() + (n % 97) as f32 - 48.0
            })
            .collect()
    }

    /// `|B_s - M|` sampled densely inside every triangle (on a fine grid of the plane) never
    /// exceeds [`lattice_deviation`], and comes within a small part of it: the bound is the
    /// maximum, not a loose estimate.
    #[test]
    fn the_lattice_deviation_is_the_maximum_over_the_tile() {
        for (w, h, budget, seed) in
            [(17, 17, 5.0, 1), (33, 17, 20.0, 2), (9, 33, 0.0, 3), (33, 33, 60.0, 4)]
        {
            let z = heights(w, h, seed);
            let win = TileWindow { x0: 64, y0: 128, width: w, height: h, stride_log2: 2 };
            let tile = build_tile_within(NodeId::new(0, 0, 0), &win, &z, None, budget, budget, &[])
                .expect("a tile");
            let bound = lattice_deviation(&tile, &win, &z);
            // Dense samples of B_s - M: every triangle at 1/64 of a lattice cell.
            let bil = |x: f64, y: f64| {
                let (ci, cj) = ((x.floor() as usize).min(w - 2), (y.floor() as usize).min(h - 2));
                let (u, v) = (x - ci as f64, y - cj as f64);
                let g = |a: usize, b: usize| f64::from(z[b * w + a]);
                let s = g(ci, cj) + u * (g(ci + 1, cj) - g(ci, cj));
                let n = g(ci, cj + 1) + u * (g(ci + 1, cj + 1) - g(ci, cj + 1));
                s + v * (n - s)
            };
            let mut dense = 0f64;
            for t in &tile.triangles {
                let p = t.map(|k| {
                    let v = tile.vertices[k as usize];
                    [
                        f64::from((v[0] - 64) >> 2),
                        f64::from((v[1] - 128) >> 2),
                        f64::from(tile.heights[k as usize]),
                    ]
                });
                let n = 64;
                for a in 0..=n {
                    for b in 0..=n - a {
                        let (l1, l2) = (a as f64 / n as f64, b as f64 / n as f64);
                        let l0 = 1.0 - l1 - l2;
                        let x = l0 * p[0][0] + l1 * p[1][0] + l2 * p[2][0];
                        let y = l0 * p[0][1] + l1 * p[1][1] + l2 * p[2][1];
                        let m = l0 * p[0][2] + l1 * p[1][2] + l2 * p[2][2];
                        dense = dense.max((bil(x, y) - m).abs());
                    }
                }
            }
            assert!(dense <= bound, "{w} x {h}: dense {dense} above the bound {bound}");
            assert!(
                dense >= 0.97 * bound - 1e-6,
                "{w} x {h}: dense {dense}, bound {bound}: not the maximum"
            );
            assert!(bound >= tile.measured.max_error);
        }
    }

    /// Each stride's error is the largest `|z - B_s|` computed sample by sample.
    #[test]
    fn region_errors_are_the_bilinear_reference() {
        let (w, h) = (37, 29);
        let z = heights(w, h, 7);
        let at = |i: usize, j: usize| z[j.min(h - 1) * w + i.min(w - 1)];
        let got = region_errors(&z, w, (0, 0), None, 3, |s, a0, b0, na, nb| {
            let t = 1usize << s;
            Ok::<_, ()>((0..na * nb).map(|p| at(a0 + (p % na) * t, b0 + (p / na) * t)).collect())
        })
        .unwrap();
        for s in 1..=3u32 {
            let t = 1usize << s;
            let mut want = 0f64;
            for j in 0..h {
                for i in 0..w {
                    let (a, b) = ((i / t) * t, (j / t) * t);
                    let (fx, fy) = ((i - a) as f64 / t as f64, (j - b) as f64 / t as f64);
                    let g = |i: usize, j: usize| f64::from(at(i, j));
                    let south = g(a, b) + fx * (g(a + t, b) - g(a, b));
                    let north = g(a, b + t) + fx * (g(a + t, b + t) - g(a, b + t));
                    want =
                        want.max((f64::from(z[j * w + i]) - (south + fy * (north - south))).abs());
                }
            }
            assert_eq!(got[s as usize - 1].to_bits(), (want as f32).to_bits(), "stride 2^{s}");
            assert!(error_upper_bound(got[s as usize - 1]) >= want);
        }
    }
}
