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

use crate::heightmap::{Heightmap, VoidMask};
use crate::metrics::{ClippedRegion, Coverage, Diagonal, Region, tri_interp};

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
    let (w, data) = (hm.width(), hm.data());
    let voids = hm.voids().any().then(|| hm.voids());
    // A whole patch (not clipped at the grid's border) measured against the full resolution,
    // the bake's case, takes the row scan of all levels at once ([`scan_whole_patch`]); the
    // rest the general scan, level by level.
    // Both give the same vertex and the same error bits (test
    // `the_row_scan_is_the_general_scan_bit_for_bit`).
    let whole = clip.x1 == x0 + c && clip.y1 == y0 + c && c <= ROW_SCAN_MAX_CELLS;
    let rows = (whole && reference == Reference::FullResolution)
        .then(|| scan_whole_patch(data, w, voids, (x0, y0, c), tri));
    for level in 1..levels {
        let (best, count) = match &rows {
            Some(rows) => rows[level],
            None => scan_level(data, w, voids, patch, clip, level, reference, tri),
        };
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

/// `(k - k0) / (k1 - k0)` in f64, 0 for an empty span: a vertex's place in its coarse quad.
fn frac(k: usize, k0: usize, k1: usize) -> f64 {
    if k1 > k0 { (k - k0) as f64 / (k1 - k0) as f64 } else { 0.0 }
}

/// The first vertex with the largest error of one level, south row first, west first:
/// `(error, i, j, coarse height)` (`None` when no vertex is measured), and how many vertices
/// were measured. Any patch, any reference: the definition [`scan_whole_patch`] keeps.
#[allow(clippy::too_many_arguments)]
fn scan_level(
    data: &[f32],
    w: usize,
    voids: Option<&VoidMask>,
    patch: Region,
    clip: ClippedRegion,
    level: usize,
    reference: Reference,
    tri: Triangulation,
) -> (Option<(f64, usize, usize, f64)>, usize) {
    let (x0, y0, c) = (patch.x0, patch.y0, patch.cells);
    // Powers of two, so the lattice tests and quad indices are masks and shifts.
    let s = 1usize << level;
    let (mask, half_mask, quads) = (s - 1, (s >> 1) - 1, c >> level);
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
            let diagonal = quad_diagonal(tri, a, b);
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
    (best, count)
}

/// Quad `(a, b)`'s diagonal: NW-SE (article case B), or by the union-jack parity.
fn quad_diagonal(tri: Triangulation, a: usize, b: usize) -> Diagonal {
    match tri {
        Triangulation::UnionJack if (a + b).is_multiple_of(2) => Diagonal::SwNe,
        _ => Diagonal::SeNw,
    }
}

/// Most cells per patch side the row scan takes (its rows live on the stack).
const ROW_SCAN_MAX_CELLS: usize = 64;

/// Levels of a row-scanned patch at most (64 cells: levels 0 to 6).
const ROW_SCAN_MAX_LEVELS: usize = ROW_SCAN_MAX_CELLS.trailing_zeros() as usize + 1;

/// Where level `L`'s entries start in [`ROW_SCAN_U`]: `L - 1 + 2^L - 2` (levels `1..L` take
/// `2^l + 1` entries each).
const ROW_SCAN_U_FIRST: [usize; ROW_SCAN_MAX_LEVELS] = {
    let mut first = [0; ROW_SCAN_MAX_LEVELS];
    let mut level = 2;
    while level < ROW_SCAN_MAX_LEVELS {
        first[level] = first[level - 1] + (1 << (level - 1)) + 1;
        level += 1;
    }
    first
};

/// Entries of [`ROW_SCAN_U`]: levels `1..ROW_SCAN_MAX_LEVELS`, `2^L + 1` each.
const ROW_SCAN_U_LEN: usize = ROW_SCAN_U_FIRST[ROW_SCAN_MAX_LEVELS - 1] + ROW_SCAN_MAX_CELLS + 1;

/// Per level `L` of the row scan, from [`ROW_SCAN_U_FIRST`]`[L]` on: `u = t / 2^L` and `1 - u`
/// for `t` in `0..=2^L`, as [`frac`] and [`tri_interp`] compute them at run time (IEEE
/// division and subtraction, correctly rounded in constant evaluation as at run time; `t / 2^L`
/// is exact anyway). Test `the_row_scan_tables_are_frac`.
static ROW_SCAN_U: ([f64; ROW_SCAN_U_LEN], [f64; ROW_SCAN_U_LEN]) = {
    let (mut u, mut w) = ([0.0; ROW_SCAN_U_LEN], [0.0; ROW_SCAN_U_LEN]);
    let mut level = 1;
    while level < ROW_SCAN_MAX_LEVELS {
        let s = 1usize << level;
        let mut t = 0;
        while t <= s {
            u[ROW_SCAN_U_FIRST[level] + t] = t as f64 / s as f64;
            w[ROW_SCAN_U_FIRST[level] + t] = 1.0 - u[ROW_SCAN_U_FIRST[level] + t];
            t += 1;
        }
        level += 1;
    }
    (u, w)
};

/// One level's result of a scan: `(error, i, j, coarse height)` of the first vertex with the
/// largest error (`None` when no vertex is measured), and how many vertices were measured.
type LevelScan = (Option<(f64, usize, usize, f64)>, usize);

/// [`scan_level`] of every level `1..` of a whole patch (`(x0, y0, c)`: no side clipped at the
/// grid's border, `c` at most [`ROW_SCAN_MAX_CELLS`]) against the full resolution, in one pass
/// over the patch's rows: the same vertex, error bits and count per level (index = level;
/// index 0 and levels past the patch's are unused), at a fraction of the cost (this runs for
/// every sample of every level of every patch of a bake).
///
/// The patch's heights are converted to f64 once for all levels, and each row's void flags
/// read once. Why the same bits: in a whole patch every coarse quad spans `s = 2^L` samples, so
/// a vertex's place in it, `u = t / s` and `v = r / s` (`t`, `r` in `0..=s`), is exact, and the
/// triangle test of [`tri_interp`] (`u >= v` for a SW-NE split, `u + v <= 1` for NW-SE) is
/// `t >= r` or `t + r <= s` on integers: within a quad's row it splits the columns into two
/// runs, each interpolated by one of [`tri_interp`]'s expressions with the same operations in
/// the same order (the terms that do not depend on `t` computed once per run, which are the
/// same values). The errors of a row go to an array, non-candidates (kept or void vertices)
/// as -1; the row's largest error is taken over four interleaved running maxima (the maximum
/// of a set of non-NaN values, whatever the order: errors are never NaN, heights are finite,
/// and never -0, they are absolute values), and a row whose largest error beats the level's
/// best so far strictly gives its first vertex with that error, which is the first such vertex
/// of a plain scan. Without voids a level measures every vertex but its own
/// `(c / s + 1)^2`, so the count is that difference.
fn scan_whole_patch(
    data: &[f32],
    w: usize,
    voids: Option<&VoidMask>,
    (x0, y0, c): (usize, usize, usize),
    tri: Triangulation,
) -> [LevelScan; ROW_SCAN_MAX_LEVELS] {
    let levels = c.trailing_zeros() as usize + 1;
    let side = c + 1;
    // The patch's heights in f64, converted once for all levels: a 16-cell patch (the
    // bake's) on the stack, written once (no zeroing first), any other on the heap.
    let row = |dj: usize| &data[(y0 + dj) * w + x0..][..side];
    let small: Option<[[f64; 17]; 17]> = (side == 17).then(|| {
        std::array::from_fn(|dj| {
            let row: &[f32; 17] = row(dj).try_into().unwrap_or(&[0.0; 17]);
            row.map(f64::from)
        })
    });
    let large: Vec<f64> = match small {
        Some(_) => Vec::new(),
        None => (0..side).flat_map(|dj| row(dj).iter().map(|&h| f64::from(h))).collect(),
    };
    let z_row = |dj: usize| -> &[f64] {
        match &small {
            Some(rows) => &rows[dj][..side],
            None => &large[dj * side..][..side],
        }
    };
    let (ut, wt) = (&ROW_SCAN_U.0, &ROW_SCAN_U.1);
    let mut err = [0f64; ROW_SCAN_MAX_CELLS + 1];
    let err = &mut err[..side];
    let mut void_row = [false; ROW_SCAN_MAX_CELLS + 1];
    let void_row = &mut void_row[..side];
    // Per level: the largest error so far (-1: none measured yet), its vertex, the count.
    let mut best_e = [-1f64; ROW_SCAN_MAX_LEVELS];
    let mut best_at = [(0usize, 0usize); ROW_SCAN_MAX_LEVELS];
    let mut count = [0usize; ROW_SCAN_MAX_LEVELS];
    for dj in 0..side {
        let j = y0 + dj;
        let zj = z_row(dj);
        if let Some(m) = voids {
            for (di, v) in void_row.iter_mut().enumerate() {
                *v = m.get(x0 + di, j);
            }
        }
        for level in 1..levels {
            let s = 1usize << level;
            let quads = c >> level;
            let first = ROW_SCAN_U_FIRST[level];
            let (ut, wt) = (&ut[first..][..=s], &wt[first..][..=s]);
            let b = (dj >> level).min(quads - 1);
            let r = dj - b * s;
            let (v, one_v) = (ut[r], wt[r]);
            let (r0, r1) = (z_row(b * s), z_row(b * s + s));
            for a in 0..quads {
                let ci = a * s;
                // Columns of this quad: the last quad also holds the patch's east edge.
                let n = if a + 1 == quads { s + 1 } else { s };
                let (zr, e) = (&zj[ci..ci + n], &mut err[ci..ci + n]);
                let (z00, z10, z01, z11) = (r0[ci], r0[ci + s], r1[ci], r1[ci + s]);
                match quad_diagonal(tri, a, b) {
                    Diagonal::SwNe => {
                        // `u < v` (t < r): triangle SW, NW, NE; then SW, SE, NE.
                        let split = r.min(n);
                        let (p, d) = (z00 + v * (z01 - z00), z11 - z01);
                        for t in 0..split {
                            e[t] = (zr[t] - (p + ut[t] * d)).abs();
                        }
                        let (d, k) = (z10 - z00, v * (z11 - z10));
                        for t in split..n {
                            e[t] = (zr[t] - (z00 + ut[t] * d + k)).abs();
                        }
                    }
                    Diagonal::SeNw => {
                        // `u + v <= 1` (t <= s - r): triangle SW, SE, NW; then NE, NW, SE.
                        let split = (s - r + 1).min(n);
                        let (d, k) = (z10 - z00, v * (z01 - z00));
                        for t in 0..split {
                            e[t] = (zr[t] - (z00 + ut[t] * d + k)).abs();
                        }
                        let (d, k) = (z01 - z11, one_v * (z10 - z11));
                        for t in split..n {
                            e[t] = (zr[t] - (z11 + wt[t] * d + k)).abs();
                        }
                    }
                }
            }
            // Not measured: the level's own vertices (a kept row's every s-th column), voids.
            if dj & (s - 1) == 0 {
                for e in err.iter_mut().step_by(s) {
                    *e = -1.0;
                }
            }
            if voids.is_some() {
                for (e, &void) in err.iter_mut().zip(void_row.iter()) {
                    if void {
                        *e = -1.0;
                    }
                }
                count[level] += err.iter().filter(|&&e| e >= 0.0).count();
            }
            let row_max = max_of(err);
            if row_max > best_e[level] {
                best_e[level] = row_max;
                let di = err.iter().position(|&e| e == row_max).unwrap_or(0);
                best_at[level] = (x0 + di, j);
            }
        }
    }
    let mut out = [(None, 0); ROW_SCAN_MAX_LEVELS];
    for level in 1..levels {
        let (s, quads) = (1usize << level, c >> level);
        if voids.is_none() {
            count[level] = side * side - (quads + 1) * (quads + 1);
        }
        if best_e[level] < 0.0 {
            out[level] = (None, count[level]);
            continue;
        }
        // The level mesh's height at the vertex, as the general scan computes it.
        let (i, j) = best_at[level];
        let (di, dj) = (i - x0, j - y0);
        let (a, b) = ((di >> level).min(quads - 1), (dj >> level).min(quads - 1));
        let (ci, cj) = (x0 + a * s, y0 + b * s);
        let at = |i: usize, j: usize| f64::from(data[j * w + i]);
        let coarse = tri_interp(
            at(ci, cj),
            at(ci + s, cj),
            at(ci, cj + s),
            at(ci + s, cj + s),
            frac(i, ci, ci + s),
            frac(j, cj, cj + s),
            quad_diagonal(tri, a, b),
        );
        out[level] = (Some((best_e[level], i, j, coarse)), count[level]);
    }
    out
}

/// The largest of `values` (never NaN, at least -1 where the caller marks none) by four
/// interleaved running maxima, so the comparisons do not wait on each other: the same value
/// as a plain left-to-right maximum.
fn max_of(values: &[f64]) -> f64 {
    let mut m = [-1f64; 4];
    let mut chunks = values.chunks_exact(4);
    for ch in &mut chunks {
        for (m, &e) in m.iter_mut().zip(ch) {
            *m = if e > *m { e } else { *m };
        }
    }
    for &e in chunks.remainder() {
        m[0] = if e > m[0] { e } else { m[0] };
    }
    let (a, b) = (if m[1] > m[0] { m[1] } else { m[0] }, if m[3] > m[2] { m[3] } else { m[2] });
    if b > a { b } else { a }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::georef::Georef;
    use crate::test_support::xorshift64_star as rng;

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

    #[test]
    fn the_row_scan_tables_are_frac() {
        let mut entries = 0;
        for (level, &first) in ROW_SCAN_U_FIRST.iter().enumerate().skip(1) {
            let s = 1usize << level;
            for t in 0..=s {
                let k = first + t;
                let u = frac(t, 0, s);
                assert_eq!(ROW_SCAN_U.0[k].to_bits(), u.to_bits(), "L{level} t{t}");
                assert_eq!(ROW_SCAN_U.1[k].to_bits(), (1.0 - u).to_bits(), "L{level} t{t}");
                entries += 1;
            }
        }
        assert_eq!(entries, ROW_SCAN_U_LEN);
    }

    #[test]
    fn the_row_scan_is_the_general_scan_bit_for_bit() {
        // Grids of few distinct heights (many ties: the first vertex must win), of wide-range
        // values, and with voids; every patch size, both triangulations. Each whole patch's
        // row scan (all levels in one pass) against the general scan on the same patch, level
        // by level.
        let mut next = rng(0x5EED);
        let (mut patches, mut tied) = (0usize, 0usize);
        for case in 0..24 {
            let c = 2usize << (case % 6);
            let (w, h) = (2 * c + 3, c + 5);
            let kind = case / 6;
            let data: Vec<f32> = (0..w * h)
                .map(|_| {
                    let r = next();
                    match kind {
                        0 => (r % 3) as f32,
                        1 => (r % 5) as f32 * 0.25 - 0.5,
                        2 => f32::from_bits((r as u32 & 0x807F_FFFF) | 0x4B00_0000) * 37.0,
                        _ => (r % 1000) as f32 * 0.1 - 50.0,
                    }
                })
                .collect();
            let mut voids = VoidMask::new(w, h);
            if kind == 3 {
                for k in 0..w * h / 5 {
                    voids.set((k * 7919 + case) % w, (k * 104_729) % h, true);
                }
            }
            let hm = Heightmap::new(w, h, data, voids, Georef::local(1.0)).unwrap();
            let (data, voids) = (hm.data(), hm.voids().any().then(|| hm.voids()));
            for tri in [Triangulation::UnionJack, Triangulation::NwSe] {
                for (x0, y0) in [(0, 0), (1, 2), (c + 2, 4), (c, 1)] {
                    let patch = Region::new(x0, y0, c);
                    let clip = patch.clip(&hm).unwrap();
                    assert_eq!((clip.x1, clip.y1), (x0 + c, y0 + c), "a whole patch");
                    let rows = scan_whole_patch(data, w, voids, (x0, y0, c), tri);
                    let levels = c.trailing_zeros() as usize + 1;
                    for (level, &fast) in rows.iter().enumerate().take(levels).skip(1) {
                        let general = scan_level(
                            data,
                            w,
                            voids,
                            patch,
                            clip,
                            level,
                            Reference::FullResolution,
                            tri,
                        );
                        let bits = |r: (Option<(f64, usize, usize, f64)>, usize)| {
                            (r.0.map(|(e, i, j, z)| (e.to_bits(), i, j, z.to_bits())), r.1)
                        };
                        assert_eq!(
                            bits(fast),
                            bits(general),
                            "case {case} {tri:?} {x0},{y0} L{level}"
                        );
                        patches += 1;
                        // Every measured vertex's error, plainly, in scan order: the winner is
                        // the first with the largest error, and ties do occur (else the tie
                        // order would go untested).
                        let s = 1usize << level;
                        let quads = c >> level;
                        let mut errors = Vec::new();
                        for dj in 0..=c {
                            for di in 0..=c {
                                let (i, j) = (x0 + di, y0 + dj);
                                if (di % s == 0 && dj % s == 0)
                                    || voids.is_some_and(|m| m.get(i, j))
                                {
                                    continue;
                                }
                                let (a, b) = ((di / s).min(quads - 1), (dj / s).min(quads - 1));
                                let (ci, cj) = (x0 + a * s, y0 + b * s);
                                let at = |i: usize, j: usize| f64::from(hm.get(i, j));
                                let coarse = tri_interp(
                                    at(ci, cj),
                                    at(ci + s, cj),
                                    at(ci, cj + s),
                                    at(ci + s, cj + s),
                                    (i - ci) as f64 / s as f64,
                                    (j - cj) as f64 / s as f64,
                                    quad_diagonal(tri, a, b),
                                );
                                errors.push(((at(i, j) - coarse).abs(), i, j));
                            }
                        }
                        let max = errors.iter().fold(-1f64, |m, e| m.max(e.0));
                        let first =
                            errors.iter().find(|e| e.0 == max).map(|e| (e.0.to_bits(), e.1, e.2));
                        assert_eq!(first, general.0.map(|(e, i, j, _)| (e.to_bits(), i, j)));
                        assert_eq!(errors.len(), general.1);
                        tied += usize::from(errors.iter().filter(|e| e.0 == max).count() > 1);
                    }
                }
            }
        }
        assert!(patches > 300, "{patches} levels compared");
        assert!(tied > 0, "no tie was exercised");
    }
}
