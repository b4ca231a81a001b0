//! Measures a mesh against every non-void sample of its heightmap: the export's guarantee.
//!
//! For each sample, the mesh's height at the sample's `(x, y)` is the barycentric
//! interpolation in the triangle that contains it (samples on shared edges are measured in
//! every triangle that holds them, and the worst counts). A sample no triangle covers is an
//! error, as is a vertex that is not a grid sample or a triangle that is degenerate or
//! clockwise seen from above: what is measured is then not a height field over the grid.

use glam::DVec2;

use crate::heightmap::Heightmap;
use crate::mesh::{TriMesh, raster};

/// How far a vertex may sit from a grid sample, in samples (positions are f64 world metres;
/// grid -> world -> grid loses a few ulps).
const ON_GRID_TOLERANCE: f64 = 1e-6;

/// The measured vertical error of a mesh over the non-void samples.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ErrorStats {
    /// Largest `|mesh - sample|`, metres.
    pub max_error: f64,
    /// Root mean square over the non-void samples, metres.
    pub rms_error: f64,
    /// Number of non-void samples measured.
    pub samples: usize,
    /// A sample `(i, j)` where the maximum is reached (`None` on a mesh with no error).
    pub worst: Option<(usize, usize)>,
}

/// Why a mesh failed verification.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum VerifyError {
    /// A sample's error exceeds the bound.
    #[error(
        "the mesh is {max_error} m off at sample ({}, {}), above the bound of {bound} m",
        at.0,
        at.1
    )]
    BoundExceeded {
        /// The measured maximum, metres.
        max_error: f64,
        /// The bound, metres.
        bound: f64,
        /// Where.
        at: (usize, usize),
    },
    /// A non-void sample lies in no triangle.
    #[error("sample ({i}, {j}) is not covered by any triangle")]
    NotCovered {
        /// Column.
        i: usize,
        /// Row.
        j: usize,
    },
    /// A vertex is not at a grid sample.
    #[error("vertex {vertex} is at grid coordinates ({}, {}), not a sample of the grid", at.x, at.y)]
    VertexOffGrid {
        /// Vertex index.
        vertex: usize,
        /// Its fractional grid coordinates.
        at: DVec2,
    },
    /// A triangle is degenerate, clockwise from above, or indexes a missing vertex.
    #[error("triangle {triangle} is degenerate, clockwise or out of range")]
    BadTriangle {
        /// Triangle index.
        triangle: usize,
    },
}

/// The largest vertical error of a mesh over the non-void samples, and where: what
/// [`check_max`] proves (the same figures as [`ErrorStats`]' without the RMS).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct MaxError {
    /// Largest `|mesh - sample|`, metres.
    pub max_error: f64,
    /// Number of non-void samples measured.
    pub samples: usize,
    /// A sample `(i, j)` where the maximum is reached (`None` on a mesh with no error).
    pub worst: Option<(usize, usize)>,
}

/// The vertices' grid samples, or the first that is not one.
fn grid_vertices(hm: &Heightmap, mesh: &TriMesh) -> Result<Vec<[i64; 2]>, VerifyError> {
    let (w, h) = (hm.width(), hm.height());
    let mut grid = Vec::with_capacity(mesh.positions.len());
    for (vertex, p) in mesh.positions.iter().enumerate() {
        let g = hm.world_to_grid(p.truncate());
        let r = g.round();
        let on = (g - r).abs().max_element() <= ON_GRID_TOLERANCE
            && r.x >= 0.0
            && r.y >= 0.0
            && r.x < w as f64
            && r.y < h as f64;
        if !on {
            return Err(VerifyError::VertexOffGrid { vertex, at: g });
        }
        grid.push([r.x as i64, r.y as i64]);
    }
    Ok(grid)
}

/// Triangle `triangle`'s grid vertices and their `d` (twice its area, as `f64`), or why it is
/// not one of a height field's.
fn grid_triangle(
    grid: &[[i64; 2]],
    t: [u32; 3],
    triangle: usize,
) -> Result<([[i64; 2]; 3], f64), VerifyError> {
    if t.iter().any(|&k| k as usize >= grid.len()) {
        return Err(VerifyError::BadTriangle { triangle });
    }
    let g = t.map(|k| grid[k as usize]);
    let d = raster::orient(g[0], g[1], g[2]);
    if d <= 0 {
        return Err(VerifyError::BadTriangle { triangle });
    }
    Ok((g, d as f64))
}

/// Measures `mesh` against every non-void sample of `hm`.
pub fn measure(hm: &Heightmap, mesh: &TriMesh) -> Result<ErrorStats, VerifyError> {
    let (w, h) = (hm.width(), hm.height());
    let grid = grid_vertices(hm, mesh)?;
    // Per-sample worst error (NaN: not yet covered). f32 suffices for the RMS; the maximum
    // and its sample are tracked exactly in f64.
    let mut err = vec![f32::NAN; w * h];
    let (mut max_error, mut worst) = (0.0f64, None);
    for (triangle, t) in mesh.triangles.iter().enumerate() {
        let (g, df) = grid_triangle(&grid, *t, triangle)?;
        let z = t.map(|k| mesh.positions[k as usize].z);
        // Row by row over the heights and errors (the interpolation `for_each_sample` gives,
        // `n / d`, bit for bit).
        let data = hm.data();
        let all = [i64::MIN, i64::MIN, i64::MAX, i64::MAX];
        raster::for_each_row(g, all, |j, lo, hi, mut wt, dw| {
            let (row, j) = (j as usize * w, j as usize);
            let (lo, hi) = (lo as usize, hi as usize);
            let slots = err[row + lo..=row + hi].iter_mut();
            for ((i, &zs), slot) in (lo..).zip(&data[row + lo..=row + hi]).zip(slots) {
                let zi = raster::numerator(wt, z) / df;
                wt = raster::step(wt, dw);
                let e = (f64::from(zs) - zi).abs();
                // f32::max ignores the NaN of an uncovered slot.
                *slot = slot.max(e as f32);
                if e > max_error && !hm.voids().get(i, j) {
                    max_error = e;
                    worst = Some((i, j));
                }
            }
        });
    }
    let mut sum = 0.0f64;
    let mut samples = 0usize;
    for j in 0..h {
        for i in 0..w {
            if hm.voids().get(i, j) {
                continue;
            }
            let e = err[j * w + i];
            if e.is_nan() {
                return Err(VerifyError::NotCovered { i, j });
            }
            sum += f64::from(e) * f64::from(e);
            samples += 1;
        }
    }
    let rms_error = if samples > 0 { (sum / samples as f64).sqrt() } else { 0.0 };
    Ok(ErrorStats { max_error, rms_error, samples, worst })
}

/// Measures `mesh` and refuses it when any non-void sample is more than `bound` metres off.
pub fn check(hm: &Heightmap, mesh: &TriMesh, bound: f64) -> Result<ErrorStats, VerifyError> {
    let stats = measure(hm, mesh)?;
    refuse_above(bound, stats.max_error, stats.worst)?;
    Ok(stats)
}

/// The bound check both [`check`] and [`check_max`] make (a NaN bound is refused too).
fn refuse_above(
    bound: f64,
    max_error: f64,
    worst: Option<(usize, usize)>,
) -> Result<(), VerifyError> {
    if bound.is_nan() || max_error > bound {
        let at = worst.unwrap_or((0, 0));
        return Err(VerifyError::BoundExceeded { max_error, bound, at });
    }
    Ok(())
}

/// [`check`] without the RMS: the largest error and where, the samples counted and the same
/// refusals, equal to [`measure`]'s bit for bit (the tests compare them), in a fraction of its
/// time. The tile pyramids verify every tile with it.
///
/// [`measure`] divides at every sample and keeps every sample's error for the RMS; here a
/// sample is first tested on its row's interpolation numerator as a line, without a division
/// ([`raster::Line`], the greedy mesher's own first test), against the largest error so far
/// less the line's rounding margin ([`raster::line_margin`]): a sample it dismisses has an
/// exact error at most that largest, so it could not have raised it, and every other sample
/// takes [`measure`]'s exact test in the same order. Coverage is a byte per sample, set
/// row span by row span.
pub fn check_max(hm: &Heightmap, mesh: &TriMesh, bound: f64) -> Result<MaxError, VerifyError> {
    let (w, h) = (hm.width(), hm.height());
    let grid = grid_vertices(hm, mesh)?;
    let (data, voids) = (hm.data(), hm.voids());
    // The margin covers the vertices' heights too: they need not be the samples'.
    let magnitude =
        mesh.positions.iter().fold(raster::largest_magnitude_of(hm), |m, p| m.max(p.z.abs()));
    let margin = raster::line_margin(magnitude);
    let mut covered = vec![false; w * h];
    let mut best = Worst { error: 0.0, at: None };
    for (triangle, t) in mesh.triangles.iter().enumerate() {
        let (g, df) = grid_triangle(&grid, *t, triangle)?;
        let z = t.map(|k| mesh.positions[k as usize].z);
        if df == 1.0 {
            // Doubled area 1: the vertices are the only samples (Pick's theorem; see the
            // mesher's scan), each weighted 1 and the others 0, taken in row order.
            let mut corners = [0, 1, 2];
            corners.sort_unstable_by_key(|&c| (g[c][1], g[c][0]));
            for c in corners {
                let (i, j) = (g[c][0] as usize, g[c][1] as usize);
                covered[j * w + i] = true;
                let wt = std::array::from_fn(|k| if k == c { 1.0 } else { 0.0 });
                best.take(data[j * w + i], wt, z, df, (i, j), voids);
            }
            continue;
        }
        let (slope, margin) = (raster::numerator(raster::weights_east(g), z), margin * df);
        let all = [i64::MIN, i64::MIN, i64::MAX, i64::MAX];
        raster::for_each_row(g, all, |j, lo, hi, wt, dw| {
            let (row, j) = (j as usize * w, j as usize);
            let (lo, hi) = (lo as usize, hi as usize);
            covered[row + lo..=row + hi].fill(true);
            let line = raster::Line { at_lo: raster::numerator(wt, z), slope };
            let mut cut = best.error * df - margin;
            for (k, &zs) in data[row + lo..=row + hi].iter().enumerate() {
                let at = k as f64;
                if line.dismisses(zs, at, df, cut) {
                    continue;
                }
                // `measure`'s test: the weights `k` samples east are exact integers, so
                // `wt + k dw` is `wt` stepped `k` times bit for bit.
                let wk = [wt[0] + at * dw[0], wt[1] + at * dw[1], wt[2] + at * dw[2]];
                if best.take(zs, wk, z, df, (lo + k, j), voids) {
                    cut = best.error * df - margin;
                }
            }
        });
    }
    // The first non-void sample no triangle covered, in row order (as `measure` reports).
    let uncovered = if voids.any() {
        (0..w * h).find(|&k| !covered[k] && !voids.get(k % w, k / w))
    } else {
        covered.iter().position(|&c| !c)
    };
    if let Some(k) = uncovered {
        return Err(VerifyError::NotCovered { i: k % w, j: k / w });
    }
    let samples = w * h - voids.count();
    refuse_above(bound, best.error, best.at)?;
    Ok(MaxError { max_error: best.error, samples, worst: best.at })
}

/// [`check_max`]'s largest error so far and its sample.
struct Worst {
    error: f64,
    at: Option<(usize, usize)>,
}

impl Worst {
    /// [`measure`]'s exact test of sample `(i, j)` (height `zs`, barycentric weights `wt` times
    /// `df`, vertex heights `z`): takes its error when it is larger and the sample is not
    /// void, and says whether it did. The one test of both the row walk and the triangles of
    /// doubled area 1.
    fn take(
        &mut self,
        zs: f32,
        wt: [f64; 3],
        z: [f64; 3],
        df: f64,
        (i, j): (usize, usize),
        voids: &crate::heightmap::VoidMask,
    ) -> bool {
        let e = (f64::from(zs) - raster::numerator(wt, z) / df).abs();
        let raised = e > self.error && !voids.get(i, j);
        if raised {
            self.error = e;
            self.at = Some((i, j));
        }
        raised
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{Algorithm, MeshConfig, build};
    use crate::synth::HardCase;

    #[test]
    fn two_triangles_over_the_spike_are_refused_and_an_exact_mesh_passes() {
        let hm = HardCase::Spike.build();
        let coarse =
            build(&hm, &MeshConfig { max_error: f64::INFINITY, algorithm: Algorithm::Rtin })
                .unwrap();
        assert_eq!(coarse.triangles.len(), 2);
        let s = measure(&hm, &coarse).unwrap();
        assert_eq!(s.max_error, f64::from(HardCase::SPIKE_HEIGHT));
        assert_eq!(s.worst, Some(HardCase::SPIKE_POS));
        assert_eq!(s.samples, 65 * 65);
        let e = check(&hm, &coarse, 999.0).unwrap_err();
        assert!(matches!(e, VerifyError::BoundExceeded { at: (32, 32), .. }), "{e}");
        let exact = build(&hm, &MeshConfig { max_error: 0.0, algorithm: Algorithm::Rtin }).unwrap();
        assert_eq!(check(&hm, &exact, 0.0).unwrap().max_error, 0.0);
    }

    /// The measure equals a sample-by-sample reference over `raster::for_each_sample` (the
    /// exact `n / d` at every sample): the maximum and its sample bit for bit, the samples
    /// counted, the RMS to f32 precision; on rough grids with voids, meshed at several bounds
    /// by both builders, and on a grid lifted by 1e6 m (large heights, small errors).
    #[test]
    fn the_measure_is_the_exact_per_sample_reference() {
        use crate::georef::Georef;
        use crate::heightmap::VoidMask;
        for (w, h, lift) in [(61usize, 47usize, 0.0f32), (33, 90, 1.0e6)] {
            let mut voids = VoidMask::new(w, h);
            for k in (0..w * h).step_by(37) {
                voids.set(k % w, k / w, true);
            }
            let hm = Heightmap::from_fn(w, h, Georef::local(5.0), |i, j| {
                let (x, y) = (i as f32, j as f32);
                lift + 90.0 * (x * 0.31).sin() * (y * 0.17).cos() + 7.0 * (x * y * 0.05).sin()
            })
            .unwrap();
            let hm = Heightmap::new(w, h, hm.data().to_vec(), voids, hm.georef().clone()).unwrap();
            for algorithm in [Algorithm::Rtin, Algorithm::Delaunay] {
                for bound in [0.5, 4.0, 30.0] {
                    let m = build(&hm, &MeshConfig { max_error: bound, algorithm }).unwrap();
                    let got = measure(&hm, &m).unwrap();
                    let grid = crate::mesh::grid_vertices(&hm, &m);
                    let mut per = vec![f64::NAN; w * h];
                    for t in &m.triangles {
                        let v = t.map(|k| grid[k as usize]);
                        let z = t.map(|k| m.positions[k as usize].z);
                        raster::for_each_sample(v, z, |i, j, zi| {
                            let (i, j) = (i as usize, j as usize);
                            let e = (f64::from(hm.get(i, j)) - zi).abs();
                            let slot = &mut per[j * w + i];
                            // NaN: not yet covered.
                            if slot.is_nan() || e > *slot {
                                *slot = e;
                            }
                        });
                    }
                    let (mut max, mut sum, mut n) = (0.0f64, 0.0f64, 0usize);
                    for j in 0..h {
                        for i in 0..w {
                            if !hm.voids().get(i, j) {
                                let e = per[j * w + i];
                                max = max.max(e);
                                sum += f64::from(e as f32) * f64::from(e as f32);
                                n += 1;
                            }
                        }
                    }
                    let what = format!("{w} x {h}, {algorithm:?} at {bound} m");
                    assert_eq!(got.max_error.to_bits(), max.to_bits(), "{what}");
                    let worst = got.worst.unwrap();
                    assert_eq!(per[worst.1 * w + worst.0].to_bits(), max.to_bits(), "{what}");
                    assert_eq!(got.samples, n, "{what}");
                    let rms = (sum / n as f64).sqrt();
                    assert!((got.rms_error - rms).abs() <= 1e-6 * rms, "{what}");
                    assert!(got.max_error > 0.0, "{what}: nothing measured");
                }
            }
        }
    }

    /// [`check_max`] is [`measure`] without the RMS, bit for bit: the maximum, its sample and
    /// the samples counted, on rough grids with scattered and blocky voids (NaN heights in
    /// some), lifted by 0, -430 m and 1e6 m, meshed by both builders at bounds from exact to
    /// loose, and with the vertices' heights moved off their samples by micrometres (errors
    /// at the line test's margin) or metres; the refusals are the same errors.
    #[test]
    fn check_max_is_measure_without_the_rms() {
        use crate::georef::Georef;
        use crate::heightmap::VoidMask;
        let mut compared = 0;
        for (w, h, lift, nan) in
            [(61usize, 47usize, 0.0f32, false), (33, 90, 1.0e6, false), (80, 80, -430.0, true)]
        {
            let mut voids = VoidMask::new(w, h);
            for k in (0..w * h).step_by(37) {
                voids.set(k % w, k / w, true);
            }
            for j in 10..20 {
                for i in 5..25 {
                    voids.set(i, j, true);
                }
            }
            let hm = Heightmap::from_fn(w, h, Georef::local(5.0), |i, j| {
                let (x, y) = (i as f32, j as f32);
                lift + 90.0 * (x * 0.31).sin() * (y * 0.17).cos() + 7.0 * (x * y * 0.05).sin()
            })
            .unwrap();
            let mut data = hm.data().to_vec();
            if nan {
                for j in 12..18 {
                    data[j * w + 10] = f32::NAN;
                }
            }
            let hm = Heightmap::new(w, h, data, voids, hm.georef().clone()).unwrap();
            for algorithm in [Algorithm::Rtin, Algorithm::Delaunay] {
                for bound in [0.0, 0.5, 4.0, 30.0] {
                    let base = build(&hm, &MeshConfig { max_error: bound, algorithm }).unwrap();
                    for offset in [0.0, 3e-6, 2.5] {
                        let mut m = base.clone();
                        for (k, p) in m.positions.iter_mut().enumerate() {
                            p.z += offset * [1.0, -1.0, 0.5][k % 3];
                        }
                        let what =
                            format!("{w} x {h} + {lift}, {algorithm:?} at {bound} m, {offset}");
                        let full = measure(&hm, &m).unwrap();
                        let max = check_max(&hm, &m, f64::INFINITY).unwrap();
                        assert_eq!(max.max_error.to_bits(), full.max_error.to_bits(), "{what}");
                        assert_eq!(max.worst, full.worst, "{what}");
                        assert_eq!(max.samples, full.samples, "{what}");
                        assert_eq!(
                            check(&hm, &m, full.max_error).unwrap().max_error,
                            max.max_error
                        );
                        assert_eq!(check_max(&hm, &m, full.max_error).unwrap(), max, "{what}");
                        if full.max_error > 0.0 {
                            let under = f64::from_bits(full.max_error.to_bits() - 1);
                            assert_eq!(
                                check_max(&hm, &m, under).unwrap_err(),
                                check(&hm, &m, under).unwrap_err(),
                                "{what}"
                            );
                        }
                        compared += 1;
                    }
                }
            }
        }
        assert_eq!(compared, 72);
        let hm = HardCase::Spike.build();
        let coarse =
            build(&hm, &MeshConfig { max_error: f64::INFINITY, algorithm: Algorithm::Rtin })
                .unwrap();
        let e = check_max(&hm, &coarse, f64::NAN).unwrap_err();
        assert!(matches!(e, VerifyError::BoundExceeded { at: (32, 32), .. }), "{e}");
        let mut holed = coarse.clone();
        holed.triangles.pop();
        assert_eq!(check_max(&hm, &holed, 1e9).unwrap_err(), measure(&hm, &holed).unwrap_err());
        let mut flipped = coarse.clone();
        flipped.triangles[1].swap(1, 2);
        assert_eq!(
            check_max(&hm, &flipped, 1e9).unwrap_err(),
            VerifyError::BadTriangle { triangle: 1 }
        );
        let mut off = coarse;
        off.positions[2].y += 0.5 * HardCase::SPACING_M;
        assert!(matches!(
            check_max(&hm, &off, 1e9),
            Err(VerifyError::VertexOffGrid { vertex: 2, .. })
        ));
    }

    #[test]
    fn holes_flipped_and_off_grid_meshes_are_refused() {
        let hm = HardCase::Flat.build();
        let mut m = build(&hm, &MeshConfig { max_error: 0.0, algorithm: Algorithm::Rtin }).unwrap();
        let mut holed = m.clone();
        holed.triangles.pop();
        assert!(matches!(measure(&hm, &holed), Err(VerifyError::NotCovered { .. })));
        let mut flipped = m.clone();
        flipped.triangles[0].swap(1, 2);
        assert!(matches!(measure(&hm, &flipped), Err(VerifyError::BadTriangle { triangle: 0 })));
        m.positions[0].x += 0.5 * HardCase::SPACING_M;
        assert!(matches!(measure(&hm, &m), Err(VerifyError::VertexOffGrid { vertex: 0, .. })));
    }
}
