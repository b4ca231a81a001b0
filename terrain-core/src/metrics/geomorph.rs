//! The geomorphing article's (Wagner 2003) "maxerror vertex" of each tessellation level of a
//! geo-mipmapped patch.
//!
//! A patch is 17 x 17 heights (16 cells, [`PATCH_CELLS`]) drawn at 5 levels ([`PATCH_LEVELS`]):
//! level 0 uses every vertex, level `L` every `2^L`-th, level 4 a single quad. In
//! preprocessing, "for each level the position of the vertex with the largest error (the one
//! which has the largest distance to the corresponding correct position ...) is determined and
//! saved together with the correct position"; at run time those vertices are projected to pick
//! the level. The article has no equation numbers.
//!
//! **The coarse surface.** A level's mesh is a triangle strip; the article's geomorphing cases
//! say a dropped vertex moves to the middle of its edge's ends (cases A, C) and, at odd/odd
//! positions, to the middle of the "top-left" and "bottom-right" vertices (case B). So each
//! coarse quad is split along that diagonal. The article's top view has "top" = north in our
//! frame (y north; its D3D heightmap is y-up, and the top view looks down that axis), so the
//! diagonal runs north-west to south-east. The renderer's index buffer must use the same one.
//!
//! **Which vertices count.** The article measures each level against the *correct* (full
//! resolution) positions: [`Reference::FullResolution`], every vertex absent at that level.
//! The brief for this module asked for the vertex *dropped at that level* against the coarser
//! level's interpolation: [`Reference::PreviousLevel`], the vertices present at `L - 1` and
//! absent at `L`. Both are provided; the article's is the one to project for level selection,
//! because a level's mesh also misses the vertices dropped at every finer level.
//!
//! Heights are vertical (our z, the article's y); positions are returned relative to the
//! patch's south-west sample, so nothing depends on the projected origin.

use glam::DVec3;

use crate::heightmap::Heightmap;
use crate::metrics::{Coverage, Diagonal, Region, tri_interp};

/// Cells per patch side in the article (17 x 17 heights).
pub const PATCH_CELLS: usize = 16;

/// Tessellation levels of a 16-cell patch in the article (0 = full, 4 = one quad).
pub const PATCH_LEVELS: usize = 5;

/// What a level's error is measured against.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reference {
    /// The article: every vertex absent at level `L`, against the level-`L` mesh.
    FullResolution,
    /// Only the vertices dropped at level `L` (present at `L - 1`), against the level-`L` mesh.
    PreviousLevel,
}

/// The max-error vertex of one level.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MaxErrorVertex {
    /// Grid column of the vertex.
    pub i: usize,
    /// Grid row of the vertex.
    pub j: usize,
    /// Its correct position relative to the patch's south-west sample: metres east, north, and
    /// its true height (z up).
    pub offset: DVec3,
    /// The level mesh's height there (metres).
    pub coarse_height: f64,
    /// `|true height - coarse height|` (metres).
    pub error: f64,
}

/// The result for one level.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LevelError {
    /// Level (0 = full resolution).
    pub level: usize,
    /// The largest vertical error (0 at level 0, and when nothing is measured).
    pub error: f64,
    /// The vertex with that error; `None` at level 0 (nothing dropped) and when no vertex is
    /// measured. Ties go to the first vertex, south row first, west first.
    pub vertex: Option<MaxErrorVertex>,
    /// What was measured.
    pub coverage: Coverage,
}

/// How each coarse quad of a level is split into two triangles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Triangulation {
    /// Every quad along its north-west to south-east diagonal (the article's case B).
    NwSe,
    /// The union-jack (4-8) pattern: quad `(a, b)` of a level (in quads of that level, from
    /// the patch's south-west corner) is split south-west to north-east when `a + b` is even,
    /// north-west to south-east when odd. Levels nest whatever the diagonals, and a border
    /// column's pair of quads is the fan the article's adapting triangles need
    /// (`terrain_core::lod::geomipmap` explains why the renderer uses it).
    UnionJack,
}

/// The max-error vertex of every level of `patch`, each level triangulated NW-SE (the
/// article's case B); see [`max_error_vertices_with`].
pub fn max_error_vertices(hm: &Heightmap, patch: Region, reference: Reference) -> Vec<LevelError> {
    max_error_vertices_with(hm, patch, reference, Triangulation::NwSe)
}

/// The max-error vertex of every level of `patch`, levels triangulated as `tri` says.
///
/// Levels: `trailing_zeros(cells) + 1` (5 for the article's 16 cells): level `L` needs a
/// vertex step `2^L` that divides `cells`. Zero-area patch: a single level 0 with
/// [`Coverage::Empty`]. Void vertices are never measured (their filled heights still shape the
/// coarse mesh); a level with no measured vertex has error 0 and [`Coverage::VoidOnly`]. A patch
/// clipped at the east/north border keeps its lattice; its last coarse quads shrink to the grid.
pub fn max_error_vertices_with(
    hm: &Heightmap,
    patch: Region,
    reference: Reference,
    tri: Triangulation,
) -> Vec<LevelError> {
    let Some(clip) = patch.clip(hm) else {
        return vec![LevelError { level: 0, error: 0.0, vertex: None, coverage: Coverage::Empty }];
    };
    let c = patch.cells;
    let levels = c.trailing_zeros() as usize + 1;
    let spacing = hm.georef().spacing_m;
    let (x0, y0) = (patch.x0, patch.y0);
    let mut out = Vec::with_capacity(levels);
    let any_valid = (clip.y0..=clip.y1).any(|j| (clip.x0..=clip.x1).any(|i| !hm.voids().get(i, j)));
    out.push(LevelError {
        level: 0,
        error: 0.0,
        vertex: None,
        coverage: if any_valid {
            Coverage::Measured { samples: clip.sample_count() }
        } else {
            Coverage::VoidOnly
        },
    });
    // Powers of two, so the lattice tests and quad indices are masks and shifts (this runs
    // for every sample of every level of every patch of a bake); the arithmetic of the
    // heights is unchanged.
    let (w, data) = (hm.width(), hm.data());
    let voids = hm.voids().any().then(|| hm.voids());
    let frac = |k: usize, k0: usize, k1: usize| {
        if k1 > k0 { (k - k0) as f64 / (k1 - k0) as f64 } else { 0.0 }
    };
    for level in 1..levels {
        let s = 1usize << level;
        let (mask, half_mask, quads) = (s - 1, (s >> 1) - 1, c >> level);
        // The first vertex with the largest error, south row first, west first: (error, i,
        // j, coarse height), `None` until a vertex is measured.
        let mut best: Option<(f64, usize, usize, f64)> = None;
        let mut count = 0;
        for j in clip.y0..=clip.y1 {
            let dj = j - y0;
            let row_kept = dj & mask == 0;
            let row_prev = dj & half_mask == 0;
            // The row of level-L quads holding row j (clipped at the north border).
            let b = (dj >> level).min(quads - 1);
            let cj = y0 + b * s;
            let cj1 = (cj + s).min(clip.y1);
            let v = frac(j, cj, cj1);
            let (r0, r1, rj) = (&data[cj * w..][..w], &data[cj1 * w..][..w], &data[j * w..][..w]);
            // The row's samples quad by quad, west to east (the order of a plain scan): quad
            // `a` holds columns `ci..ci + s`, the last one also its east edge (and at the east
            // border, clipped to the grid).
            for a in 0..quads {
                let ci = x0 + a * s;
                if ci > clip.x1 {
                    break;
                }
                let last = if a + 1 == quads { clip.x1 } else { (ci + s - 1).min(clip.x1) };
                // Split NW-SE (article case B) or by the union-jack parity.
                let diagonal = match tri {
                    Triangulation::UnionJack if (a + b).is_multiple_of(2) => Diagonal::SwNe,
                    _ => Diagonal::SeNw,
                };
                let ci1 = (ci + s).min(clip.x1);
                let (z00, z10) = (f64::from(r0[ci]), f64::from(r0[ci1]));
                let (z01, z11) = (f64::from(r1[ci]), f64::from(r1[ci1]));
                for (i, &z) in rj.iter().enumerate().take(last + 1).skip(ci) {
                    let di = i - x0;
                    let kept = row_kept && di & mask == 0;
                    let candidate = match reference {
                        Reference::FullResolution => !kept,
                        Reference::PreviousLevel => !kept && row_prev && di & half_mask == 0,
                    };
                    if !candidate || voids.is_some_and(|m| m.get(i, j)) {
                        continue;
                    }
                    let coarse = tri_interp(z00, z10, z01, z11, frac(i, ci, ci1), v, diagonal);
                    let z = f64::from(z);
                    let error = (z - coarse).abs();
                    count += 1;
                    if best.is_none_or(|(e, ..)| error > e) {
                        best = Some((error, i, j, coarse));
                    }
                }
            }
        }
        let best = best.map(|(error, i, j, coarse_height)| {
            let (di, dj) = (i - x0, j - y0);
            let z = f64::from(data[j * w + i]);
            MaxErrorVertex {
                i,
                j,
                offset: DVec3::new(di as f64 * spacing.x, dj as f64 * spacing.y, z),
                coarse_height,
                error,
            }
        });
        out.push(LevelError {
            level,
            error: best.map_or(0.0, |b| b.error),
            vertex: best,
            coverage: Coverage::from_count(count),
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::georef::Georef;

    #[test]
    fn case_b_diagonal_is_nw_se() {
        // A 3x3 patch (2 cells): only the SE and NW corners are 1; the centre is 1. Against the
        // NW-SE diagonal the centre interpolates to 1 (no error); against SW-NE it would be 0.
        let hm = Heightmap::from_fn(3, 3, Georef::local(1.0), |i, j| match (i, j) {
            (2, 0) | (0, 2) | (1, 1) => 1.0,
            (1, 0) | (0, 1) | (2, 1) | (1, 2) => 0.5,
            _ => 0.0,
        })
        .unwrap();
        let l = max_error_vertices(&hm, Region::new(0, 0, 2), Reference::FullResolution);
        assert_eq!(l.len(), 2);
        assert_eq!(l[1].error, 0.0);
        // Union jack: quad (0, 0) is split SW-NE, so the centre interpolates to (0 + 0) / 2.
        let u = max_error_vertices_with(
            &hm,
            Region::new(0, 0, 2),
            Reference::FullResolution,
            Triangulation::UnionJack,
        );
        assert_eq!(u[1].error, 1.0);
        assert_eq!((u[1].vertex.unwrap().i, u[1].vertex.unwrap().j), (1, 1));
    }
}
