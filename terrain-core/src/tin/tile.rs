//! The one tile mesher of both TIN pyramids: the geographic one of `terrain tiles`
//! ([`super::build_tile`]) and the grid-space one of the `tin` LOD method ([`super::grid`]).
//!
//! A tile is a window of DEM samples ([`window`]: any source fills it through a closure, a
//! heightmap in memory or a store's blocks), meshed by greedy Delaunay insertion
//! ([`crate::mesh::delaunay`], Garland & Heckbert 1995) within the tile's bound and verified
//! against every non-void sample of the window ([`crate::mesh::verify::check_max`]) before it is
//! returned ([`mesh_window`]).
//!
//! **Borders.** With [`Borders::Free`] the greedy insertion picks border samples like any
//! other (the geographic tiles: their cracks are hidden by skirts). With
//! [`Borders::Simplified`] each side's vertices are fixed first by a top-down simplification
//! of the side's height profile alone ([`simplify_profile`]: Douglas & Peucker 1973 with the
//! vertical error, split at the worst sample until every sample is within the bound), and the
//! greedy loop never inserts another border sample: two tiles of the same bound that share a
//! side compute the same profile from the same samples, so they share their border vertices
//! exactly (no crack between them).
//!
//! **Pieces** ([`mesh_in_pieces`]): a window too large to hold at once is meshed as pieces of
//! at most `piece x piece` cells, each read on its own and meshed with [`Borders::Simplified`],
//! so two pieces sharing a side share its vertices (the union is one conforming mesh, no crack
//! and no T-junction), each verified against every non-void sample of its piece (so the union
//! is within the bound of every sample of the window). The memory is one piece's samples and
//! the mesh, whatever the window's size.

use crate::Georef;
use crate::heightmap::{Heightmap, VoidMask};
use crate::mesh::verify::{self, MaxError, VerifyError};
use crate::mesh::{self, Algorithm, MeshError, TriMesh};

/// How a tile's border vertices are chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Borders {
    /// By the greedy insertion, like interior samples.
    Free,
    /// By [`simplify_profile`] of each side alone, then locked.
    Simplified,
}

/// Why a tile could not be meshed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum TileError {
    /// The mesher refused the window or the bound.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// The mesh failed its check against the window's samples.
    #[error(transparent)]
    Verify(#[from] VerifyError),
    /// An RTIN's border vertices are its hierarchy's, so it cannot take locked sides.
    #[error("an RTIN tile cannot lock its borders (Borders::Simplified needs the greedy mesher)")]
    RtinLockedBorders,
    /// A piece's samples as read do not make a grid (a reader's bug: wrong size).
    #[error("a piece of the window: {0}")]
    Piece(#[from] crate::heightmap::HeightmapError),
}

/// A window of `width x height` samples, sample `(i, j)` being `sample(i, j)` = `(height,
/// void)`, with a local georeference of one metre per sample (so its world coordinates are
/// its grid coordinates). A void sample may hold anything (a non-finite height is replaced by
/// 0: the mesh's vertices need finite heights); a window of only void samples is taken as it
/// is, unmasked (the fill is what the surface shows, and nothing can be measured).
pub fn window(
    width: usize,
    height: usize,
    mut sample: impl FnMut(usize, usize) -> (f32, bool),
) -> Heightmap {
    let mut data = Vec::with_capacity(width * height);
    let mut voids = VoidMask::new(width, height);
    for j in 0..height {
        for i in 0..width {
            let (mut z, void) = sample(i, j);
            if void {
                voids.set(i, j, true);
                if !z.is_finite() {
                    z = 0.0;
                }
            }
            data.push(if z.is_finite() { z } else { 0.0 });
        }
    }
    if voids.count() == width * height {
        voids = VoidMask::new(width, height);
    }
    // Same sizes, finite heights.
    Heightmap::new(width, height, data, voids, Georef::local(1.0))
        .unwrap_or_else(|e| unreachable!("a window of finite samples: {e}"))
}

/// [`window`] of samples read as a block (`data` row-major, `voids` `None`: none): the same
/// grid without a copy (non-finite heights made 0; a window of only void samples unmasked).
pub fn window_of(
    width: usize,
    height: usize,
    mut data: Vec<f32>,
    voids: Option<VoidMask>,
) -> Result<Heightmap, TileError> {
    for z in data.iter_mut() {
        if !z.is_finite() {
            *z = 0.0;
        }
    }
    let voids = match voids {
        Some(v) if v.count() < width * height => v,
        _ => VoidMask::new(width, height),
    };
    Ok(Heightmap::new(width, height, data, voids, Georef::local(1.0))?)
}

/// The samples of a height profile to keep so that linear interpolation between consecutive
/// kept samples is within `bound` of every non-void sample: indices in increasing order, the
/// first and last always kept. Top-down: split a span at its worst sample while that sample
/// is more than `bound` off (Douglas & Peucker 1973, vertical error). The result depends on
/// the profile and the bound only. A small margin (`bound x 1e-6`) keeps the bound through
/// the meshes' own interpolation, which rounds differently; a bound under `1e-6` m keeps every
/// sample.
pub fn simplify_profile(heights: &[f32], voids: &[bool], bound: f64) -> Vec<usize> {
    let n = heights.len();
    if n <= 2 || bound < 1e-6 {
        return (0..n).collect();
    }
    let limit = bound * (1.0 - 1e-6);
    let mut keep = vec![false; n];
    keep[0] = true;
    keep[n - 1] = true;
    let mut spans = vec![(0usize, n - 1)];
    while let Some((a, b)) = spans.pop() {
        let (za, zb) = (f64::from(heights[a]), f64::from(heights[b]));
        let mut worst = (limit, None);
        for (k, &z) in heights.iter().enumerate().take(b).skip(a + 1) {
            if voids.get(k).copied().unwrap_or(false) {
                continue;
            }
            let t = (k - a) as f64 / (b - a) as f64;
            let e = (f64::from(z) - (za + t * (zb - za))).abs();
            if e > worst.0 {
                worst = (e, Some(k));
            }
        }
        if let Some(k) = worst.1 {
            keep[k] = true;
            spans.push((a, k));
            spans.push((k, b));
        }
    }
    (0..n).filter(|&k| keep[k]).collect()
}

/// The border seeds of `sub` under [`Borders::Simplified`]: each side's kept samples.
fn border_seeds(sub: &Heightmap, bound: f64) -> Vec<[u32; 2]> {
    let (w, h) = (sub.width(), sub.height());
    let voids = sub.voids();
    let mut seeds = Vec::new();
    for j in [0, h - 1] {
        let z: Vec<f32> = (0..w).map(|i| sub.get(i, j)).collect();
        let v: Vec<bool> = (0..w).map(|i| voids.get(i, j)).collect();
        seeds.extend(simplify_profile(&z, &v, bound).into_iter().map(|i| [i as u32, j as u32]));
    }
    for i in [0, w - 1] {
        let z: Vec<f32> = (0..h).map(|j| sub.get(i, j)).collect();
        let v: Vec<bool> = (0..h).map(|j| voids.get(i, j)).collect();
        seeds.extend(simplify_profile(&z, &v, bound).into_iter().map(|j| [i as u32, j as u32]));
    }
    seeds
}

/// Meshes `sub` (a [`window`]) within `bound` metres of every non-void sample and verifies
/// it: the mesh in the window's grid coordinates (x, y) with the samples' heights, and the
/// measured error.
pub fn mesh_window(
    sub: &Heightmap,
    bound: f64,
    borders: Borders,
) -> Result<(TriMesh, MaxError), TileError> {
    mesh_window_seeded(sub, bound, borders, &[])
}

/// [`mesh_window`] starting from `seeds` (samples `[i, j]` of `sub` that become vertices
/// before the greedy insertion; outside the window they are skipped). The TIN pyramid of
/// `terrain tiles` seeds a tile with its parent's vertices: they are where the parent's
/// greedy insertion found the worst errors at twice the bound, so the child's insertion starts
/// from them instead of from the window's corners, and each sample is scanned for the few
/// refinements from twice the bound to the bound only (the scans dominate the mesher's time).
/// The bound and its verification are the same; only the order of insertion changes.
pub fn mesh_window_seeded(
    sub: &Heightmap,
    bound: f64,
    borders: Borders,
    seeds: &[[u32; 2]],
) -> Result<(TriMesh, MaxError), TileError> {
    mesh_window_with(sub, bound, borders, seeds, Algorithm::Delaunay)
}

/// [`mesh_window_seeded`] by the builder `algorithm`: [`Algorithm::Delaunay`] (greedy
/// insertion, the fewest triangles) or [`Algorithm::Rtin`] ([`crate::mesh::rtin`]: one visit
/// per sample for its error pass and about one scan of every sample for its check, whatever
/// the bound, where the greedy insertion rescans a vertex's neighbourhood per vertex, so on a
/// window whose bound keeps most samples the RTIN is cheaper for somewhat more triangles).
/// An RTIN takes no seeds (its vertices are its hierarchy's) and only [`Borders::Free`].
/// Either mesh is verified against every non-void sample the same way.
pub fn mesh_window_with(
    sub: &Heightmap,
    bound: f64,
    borders: Borders,
    seeds: &[[u32; 2]],
    algorithm: Algorithm,
) -> Result<(TriMesh, MaxError), TileError> {
    mesh::validate(sub, bound)?;
    if algorithm == Algorithm::Rtin {
        if borders != Borders::Free {
            return Err(TileError::RtinLockedBorders);
        }
        let m = mesh::rtin::build(sub, bound);
        let stats = verify::check_max(sub, &m, bound)?;
        return Ok((m, stats));
    }
    let m = match borders {
        Borders::Free if seeds.is_empty() => mesh::delaunay::build(sub, bound),
        Borders::Free => mesh::delaunay::build_seeded(sub, bound, seeds, false),
        Borders::Simplified => {
            // Seeds on the border would break the side's lock: only interior ones.
            let (w, h) = (sub.width() as u32, sub.height() as u32);
            let mut all = border_seeds(sub, bound);
            all.extend(seeds.iter().filter(|&&[i, j]| i > 0 && j > 0 && i + 1 < w && j + 1 < h));
            mesh::delaunay::build_seeded(sub, bound, &all, true)
        }
    };
    let stats = verify::check_max(sub, &m, bound)?;
    Ok((m, stats))
}

/// The `n + 1` boundaries (from 0 to `cells`) of `n` nearly equal spans of at most `piece`
/// cells each, `n` the fewest that fit.
fn cuts(cells: usize, piece: usize) -> Vec<usize> {
    let n = cells.div_ceil(piece.max(1)).max(1);
    (0..=n).map(|k| k * cells / n).collect()
}

/// The samples of a piece as read, made a mesher's input: a void's non-finite height becomes
/// 0 (a vertex needs a finite height); the voids stay masked even where every sample is void
/// (then nothing is measured and the piece is its corners at their fill), so the two pieces
/// sharing a side see the same voids on it and keep the same side vertices.
fn piece_window(
    width: usize,
    height: usize,
    mut data: Vec<f32>,
    voids: Option<VoidMask>,
) -> Result<Heightmap, TileError> {
    let voids = voids.unwrap_or_else(|| VoidMask::new(width, height));
    for (k, z) in data.iter_mut().enumerate() {
        if !z.is_finite() && voids.get(k % width, k / width) {
            *z = 0.0;
        }
    }
    Ok(Heightmap::new(width, height, data, voids, Georef::local(1.0))?)
}

/// Meshes a `width x height` window (grid coordinates, one metre per sample, as a
/// [`window`]) within `bound` of every non-void sample in pieces of at most `piece x piece`
/// cells (see the module docs): `read([i0, j0, i1, j1])` returns the samples of that inclusive
/// rectangle of the window, row-major from its south-west sample, and their voids (`None`:
/// none). Pieces that share a side share its vertices ([`Borders::Simplified`]); `seeds`
/// (window samples `[i, j]`) go to the pieces they are inside of (not on a piece's side).
/// Returns the union in the window's grid coordinates (vertices shared by pieces merged) and
/// the error measured over every piece: its maximum and where (window coordinates), and the
/// samples over the pieces, a sample on a shared side counted in each of its pieces.
pub fn mesh_in_pieces<E: From<TileError>>(
    width: usize,
    height: usize,
    piece: usize,
    bound: f64,
    seeds: &[[u32; 2]],
    mut read: impl FnMut([usize; 4]) -> Result<(Vec<f32>, Option<VoidMask>), E>,
) -> Result<(TriMesh, MaxError), E> {
    if width < 2 || height < 2 {
        return Err(TileError::Mesh(MeshError::GridTooSmall { width, height }).into());
    }
    let (xs, ys) = (cuts(width - 1, piece), cuts(height - 1, piece));
    let mut index: rustc_hash::FxHashMap<[u32; 2], u32> = Default::default();
    let mut positions: Vec<glam::DVec3> = Vec::new();
    let mut triangles: Vec<[u32; 3]> = Vec::new();
    let mut stats = MaxError { max_error: 0.0, samples: 0, worst: None };
    for y in ys.windows(2) {
        for x in xs.windows(2) {
            let ([x0, x1], [y0, y1]) = ([x[0], x[1]], [y[0], y[1]]);
            let (pw, ph) = (x1 - x0 + 1, y1 - y0 + 1);
            let (data, voids) = read([x0, y0, x1, y1])?;
            let sub = piece_window(pw, ph, data, voids)?;
            let local: Vec<[u32; 2]> = seeds
                .iter()
                .filter(|&&[i, j]| {
                    (x0..=x1).contains(&(i as usize)) && (y0..=y1).contains(&(j as usize))
                })
                .map(|&[i, j]| [i - x0 as u32, j - y0 as u32])
                .collect();
            let (m, s) =
                mesh_window_with(&sub, bound, Borders::Simplified, &local, Algorithm::Delaunay)?;
            drop(sub);
            if s.max_error > stats.max_error || stats.worst.is_none() && s.worst.is_some() {
                stats.max_error = s.max_error;
                stats.worst = s.worst.map(|(i, j)| (i + x0, j + y0));
            }
            stats.samples += s.samples;
            // Vertices are samples of the piece: integer grid coordinates.
            let ids: Vec<u32> = m
                .positions
                .iter()
                .map(|q| {
                    let g = [q.x.round() as u32 + x0 as u32, q.y.round() as u32 + y0 as u32];
                    *index.entry(g).or_insert_with(|| {
                        positions.push(glam::DVec3::new(f64::from(g[0]), f64::from(g[1]), q.z));
                        (positions.len() - 1) as u32
                    })
                })
                .collect();
            triangles.extend(m.triangles.iter().map(|t| t.map(|k| ids[k as usize])));
        }
    }
    let normals = crate::mesh::vertex_normals(&positions, &triangles);
    Ok((TriMesh { positions, normals, triangles }, stats))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The profile keeps what the bound needs, and only that on a polyline of known corners.
    #[test]
    fn a_profile_keeps_its_corners_only() {
        // A tent: 0 at both ends, 10 in the middle, straight in between.
        let z: Vec<f32> = (0..21).map(|k| 10.0 - (k as f32 - 10.0).abs()).collect();
        let none = vec![false; z.len()];
        assert_eq!(simplify_profile(&z, &none, 0.5), vec![0, 10, 20]);
        // A bound above the tent's height keeps only the ends.
        assert_eq!(simplify_profile(&z, &none, 10.5), vec![0, 20]);
        // A void apex is not measured.
        let mut v = none.clone();
        v[10] = true;
        let kept = simplify_profile(&z, &v, 0.5);
        assert!(!kept.contains(&10) && kept.len() == 4, "{kept:?}");
    }

    /// The pieces' boundaries: the fewest spans of at most `piece` cells, nearly equal,
    /// covering every cell once (neighbours share their boundary sample).
    #[test]
    fn cuts_split_into_the_fewest_spans() {
        assert_eq!(cuts(4096, 1024), vec![0, 1024, 2048, 3072, 4096]);
        assert_eq!(cuts(1024, 1024), vec![0, 1024]);
        assert_eq!(cuts(1025, 1024), vec![0, 512, 1025]);
        assert_eq!(cuts(7, 3), vec![0, 2, 4, 7]);
        for (cells, piece) in [(1, 1), (100, 7), (4097, 256), (5, 100)] {
            let c = cuts(cells, piece);
            assert_eq!((c[0], *c.last().unwrap()), (0, cells));
            assert!(c.windows(2).all(|w| w[1] > w[0] && w[1] - w[0] <= piece), "{c:?}");
            assert_eq!(c.len() - 1, cells.div_ceil(piece));
        }
    }

    /// Two windows sharing a side get the same vertices on it, and the bound holds.
    #[test]
    fn neighbours_share_their_side() {
        let f = |i: usize, j: usize| {
            let (x, y) = (i as f64, j as f64);
            ((x * 0.37).sin() * 20.0 + (y * 0.23).cos() * 15.0 + (x * y * 0.01).sin() * 5.0) as f32
        };
        let left = window(33, 33, |i, j| (f(i, j), false));
        let right = window(33, 33, |i, j| (f(i + 32, j), false));
        // No negative control with free borders: on a rectangle a border sample lies on a hull
        // edge, so its error depends on the side's vertices alone and greedy insertion picks
        // the same side vertices in both windows (checked: they agreed at every bound here).
        // The lock matters where neighbours' sides differ in length (levels apart) or where
        // the inserted vertices would be tried in another order; `Borders::Simplified` makes
        // the side a function of its profile alone by construction.
        for bound in [0.5, 2.0, 8.0] {
            let (a, sa) = mesh_window(&left, bound, Borders::Simplified).unwrap();
            let (b, sb) = mesh_window(&right, bound, Borders::Simplified).unwrap();
            assert!(sa.max_error <= bound && sb.max_error <= bound);
            let mut east: Vec<i64> =
                a.positions.iter().filter(|p| p.x == 32.0).map(|p| p.y as i64).collect();
            let mut west: Vec<i64> =
                b.positions.iter().filter(|p| p.x == 0.0).map(|p| p.y as i64).collect();
            east.sort_unstable();
            west.sort_unstable();
            assert_eq!(east, west, "bound {bound}");
            assert!(east.len() > 2, "the side needs vertices besides its corners at {bound}");
        }
    }
}
