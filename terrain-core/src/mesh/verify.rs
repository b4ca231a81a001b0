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

/// Measures `mesh` against every non-void sample of `hm`.
pub fn measure(hm: &Heightmap, mesh: &TriMesh) -> Result<ErrorStats, VerifyError> {
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
    // Per-sample worst error (NaN: not yet covered). f32 suffices for the RMS; the maximum
    // and its sample are tracked exactly in f64.
    let mut err = vec![f32::NAN; w * h];
    let (mut max_error, mut worst) = (0.0f64, None);
    for (triangle, t) in mesh.triangles.iter().enumerate() {
        if t.iter().any(|&k| k as usize >= grid.len()) {
            return Err(VerifyError::BadTriangle { triangle });
        }
        let g = t.map(|k| grid[k as usize]);
        if raster::orient(g[0], g[1], g[2]) <= 0 {
            return Err(VerifyError::BadTriangle { triangle });
        }
        let z = t.map(|k| mesh.positions[k as usize].z);
        // Row by row over the heights and errors (the interpolation `for_each_sample` gives,
        // `n / d`, bit for bit).
        let df = raster::orient(g[0], g[1], g[2]) as f64;
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
    // A NaN bound is refused too.
    if bound.is_nan() || stats.max_error > bound {
        let at = stats.worst.unwrap_or((0, 0));
        return Err(VerifyError::BoundExceeded { max_error: stats.max_error, bound, at });
    }
    Ok(stats)
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
