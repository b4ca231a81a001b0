//! The DSS paper's (Zhang 2019, section 3.3.1) block errors: object-space error per
//! tessellation factor, the view-angle screen error (Eq. 3) and the continuous tessellation
//! factor `F_thr` (Eq. 4).
//!
//! **Which factors.** The paper stores 32 errors per M-block, `delta_i` for
//! `F_tessellation = 2i`, `i = 1..=32` (2, 4, ..., 64), and Eq. 4 interpolates between
//! neighbouring even factors. [`object_errors`] computes exactly those 32 (index `k` is
//! `F = 2(k + 1)`); [`object_error`] measures any single factor `f >= 1` for callers that need
//! odd ones.
//!
//! **What is measured.** The block is tessellated uniformly with `f` segments per side (the
//! GPU's equal-spacing quad tessellation); each tessellated vertex takes the DEM's bilinear
//! height at its position (the displacement-map lookup); the surface between vertices is
//! bilinear over each tessellated cell. The paper does not say how the tessellator's triangles
//! split a cell (hardware-defined), so the bilinear surface is our interpretation; it is exact
//! on planes and at vertices, like any triangulation. The error compares every non-void DEM
//! sample inside the (clipped) block with that surface: the paper's `delta` is the **average**
//! vertical error (section 3.3.1); we also keep the max. A block clipped at the east/north
//! border is tessellated over its clipped extent (`f` segments per side of that rectangle).
//! Heights are the vertical axis (our z, the paper's OpenGL y); nothing else enters.
//!
//! **Monotonicity.** The paper says `delta_i` decreases as the factor grows. It is true for
//! nested factors on convex (or concave) separable terrain, and always `delta = 0` once the
//! factor is a multiple of the block's cells (every sample is a vertex), but it is *not* true
//! in general, not even for factors dividing the block: a single pit that becomes a vertex at
//! the finer factor spreads a tent of error over its neighbours (average up), and an
//! alternating bump (+1, -1) raises the max. The tests pin both counterexamples.
//! [`tessellation_factor`] scans as the paper does and stays well defined either way;
//! [`DssErrors::monotone_envelope`] gives the non-increasing upper envelope for callers who
//! need the paper's assumption.

use glam::DVec3;

use crate::heightmap::Heightmap;
use crate::metrics::{
    ClippedRegion, Coverage, Region, bilerp, bilinear_axis, dem_bilinear, screen,
};

/// Number of object-space errors per block (DSS paper: 32).
pub const FACTORS: usize = 32;

/// The tessellation factor of index `k` in the 32 errors: `2 (k + 1)` (paper: `l_i = 2i`).
pub const fn factor(k: usize) -> usize {
    2 * (k + 1)
}

/// Object-space error of a block at one tessellation factor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObjectError {
    /// Mean vertical error over the measured samples (the paper's `delta`), metres.
    pub avg: f64,
    /// Largest vertical error over the measured samples, metres.
    pub max: f64,
    /// What was measured.
    pub coverage: Coverage,
}

/// Object-space error of `region` tessellated with `f` segments per side (`f = 0` counts as 1).
///
/// Zero-area region: 0 with [`Coverage::Empty`]; void-only: 0 with [`Coverage::VoidOnly`].
pub fn object_error(hm: &Heightmap, region: Region, f: usize) -> ObjectError {
    let Some(clip) = region.clip(hm) else {
        return ObjectError { avg: 0.0, max: 0.0, coverage: Coverage::Empty };
    };
    let f = f.max(1);
    let (x0, y0) = (clip.x0, clip.y0);
    // The tessellated block: the region, or its clipped extent at the east/north border.
    let (cx, cy) = (clip.x1 - x0, clip.y1 - y0);
    // Vertex heights: bilinear DEM at (x0 + cx a / f, y0 + cy b / f).
    let n = f + 1;
    let mut vz = Vec::with_capacity(n * n);
    for b in 0..=f {
        for a in 0..=f {
            let u = x0 as f64 + (cx * a) as f64 / f as f64;
            let v = y0 as f64 + (cy * b) as f64 / f as f64;
            vz.push(dem_bilinear(hm, u, v));
        }
    }
    // Local sample index -> (tessellated cell, fraction), in exact integer arithmetic.
    let locate = |k: usize, c: usize| -> (usize, f64) {
        let num = k * f;
        let cell = (num / c).min(f - 1);
        (cell, (num - cell * c) as f64 / c as f64)
    };
    let (mut sum, mut max, mut count) = (0.0f64, 0.0f64, 0usize);
    for j in clip.y0..=clip.y1 {
        let (b, t) = locate(j - y0, cy);
        for i in clip.x0..=clip.x1 {
            if hm.voids().get(i, j) {
                continue;
            }
            let (a, s) = locate(i - x0, cx);
            let z = |aa: usize, bb: usize| vz[bb * n + aa];
            let surf = bilerp(z(a, b), z(a + 1, b), z(a, b + 1), z(a + 1, b + 1), s, t);
            let e = (f64::from(hm.get(i, j)) - surf).abs();
            sum += e;
            max = max.max(e);
            count += 1;
        }
    }
    let avg = if count == 0 { 0.0 } else { sum / count as f64 };
    ObjectError { avg, max, coverage: Coverage::from_count(count) }
}

/// The 32 object-space errors of a block, index `k` for factor [`factor`]`(k) = 2 (k + 1)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DssErrors {
    /// Mean vertical errors (the paper's `delta_i`, `i = k + 1`).
    pub avg: [f64; FACTORS],
    /// Max vertical errors.
    pub max: [f64; FACTORS],
    /// What was measured (the same for every factor).
    pub coverage: Coverage,
}

impl DssErrors {
    /// The non-increasing upper envelope: each error replaced by the max over itself and every
    /// finer factor, so `delta` never grows with the factor (the paper's stated assumption).
    pub fn monotone_envelope(&self) -> Self {
        let mut out = *self;
        for k in (0..FACTORS - 1).rev() {
            out.avg[k] = out.avg[k].max(out.avg[k + 1]);
            out.max[k] = out.max[k].max(out.max[k + 1]);
        }
        out
    }
}

/// The paper's 32 object-space errors of `region` (section 3.3.1), computed in preprocessing.
///
/// Bit-identical to calling [`object_error`] for each factor (the same operations in the same
/// order, tested in `tests/metrics.rs`), but several times faster:
/// - only the tessellated vertices that some sample's cell uses are interpolated (a factor
///   finer than the node's cells touches at most two vertex columns per sample column), each
///   from per-column and per-row lookups computed once ([`bilinear_axis`]);
/// - the tessellated cell and fraction of every sample column are located once per factor;
/// - the surface's two `x` interpolations (the first half of the bilinear blend) are made once
///   per tessellated cell row instead of once per sample.
///
/// It is [`ObjectErrorsAcc`] fed the whole heightmap at once; a grid read by bands of rows
/// feeds the accumulator band by band and gets the same bits.
pub fn object_errors(hm: &Heightmap, region: Region) -> DssErrors {
    match ObjectErrorsAcc::new(region, hm.width(), hm.height()) {
        None => DssErrors { avg: [0.0; FACTORS], max: [0.0; FACTORS], coverage: Coverage::Empty },
        Some(mut acc) => {
            acc.fill_vertices(hm);
            acc.add_rows(hm);
            acc.finish()
        }
    }
}

/// Full-width rows of a grid's samples, as [`ObjectErrorsAcc`] reads them: the whole
/// [`Heightmap`], or a band of rows read from a file ([`RowBand`]). Rows are absolute grid
/// rows (0 south).
pub trait SampleRows {
    /// The first row present.
    fn first_row(&self) -> usize;
    /// How many rows are present (`first_row()..first_row() + rows()`).
    fn rows(&self) -> usize;
    /// Row `j`'s heights, the grid's full width.
    fn row(&self, j: usize) -> &[f32];
    /// Whether any present sample may be void (`false`: [`SampleRows::void`] is never asked).
    fn any_void(&self) -> bool;
    /// Whether sample `(i, j)` is void.
    fn void(&self, i: usize, j: usize) -> bool;
}

impl SampleRows for Heightmap {
    fn first_row(&self) -> usize {
        0
    }
    fn rows(&self) -> usize {
        self.height()
    }
    fn row(&self, j: usize) -> &[f32] {
        &self.data()[j * self.width()..(j + 1) * self.width()]
    }
    fn any_void(&self) -> bool {
        self.voids().any()
    }
    fn void(&self, i: usize, j: usize) -> bool {
        self.voids().get(i, j)
    }
}

/// Rows `j0..j0 + heights.len() / width` of a grid `width` samples wide: heights and void
/// flags row-major, south row first (what a reader by bands of rows fills).
#[derive(Debug, Clone, Copy)]
pub struct RowBand<'a> {
    j0: usize,
    width: usize,
    heights: &'a [f32],
    voids: &'a [bool],
    /// Whether any flag is set (scanned once, not per node).
    any_void: bool,
}

impl<'a> RowBand<'a> {
    /// Rows from `j0` of a grid `width` samples wide (`voids` as long as `heights`).
    ///
    /// # Panics
    /// If the lengths differ or are not whole rows.
    pub fn new(j0: usize, width: usize, heights: &'a [f32], voids: &'a [bool]) -> Self {
        assert_eq!(heights.len(), voids.len(), "one void flag per height");
        assert_eq!(heights.len() % width.max(1), 0, "whole rows");
        Self { j0, width, heights, voids, any_void: voids.iter().any(|&v| v) }
    }

    /// Row `j`'s void flags.
    pub fn void_row(&self, j: usize) -> &'a [bool] {
        let o = (j - self.j0) * self.width;
        &self.voids[o..o + self.width]
    }
}

impl SampleRows for RowBand<'_> {
    fn first_row(&self) -> usize {
        self.j0
    }
    fn rows(&self) -> usize {
        self.heights.len() / self.width.max(1)
    }
    fn row(&self, j: usize) -> &[f32] {
        let o = (j - self.j0) * self.width;
        &self.heights[o..o + self.width]
    }
    fn any_void(&self) -> bool {
        self.any_void
    }
    fn void(&self, i: usize, j: usize) -> bool {
        self.voids[(j - self.j0) * self.width + i]
    }
}

/// [`object_errors`] of one region, accumulated from rows given in any number of bands: first
/// [`ObjectErrorsAcc::fill_vertices`] with bands holding the rows the tessellated vertices
/// read ([`ObjectErrorsAcc::vertex_rows`]: each vertex needs two adjacent rows, so bands that
/// overlap by one row cover them), then [`ObjectErrorsAcc::add_rows`] with the region's rows
/// in order (bands overlapping or not), then [`ObjectErrorsAcc::finish`]. Every value is the
/// same f64 operation on the same inputs as [`object_error`]'s, and each factor's sum runs
/// over the samples in the same row-major order, so the result does not depend on the bands.
/// Memory: per factor, one entry per sample column and row of the region and the used
/// vertices (at most `(f + 1)^2`).
#[derive(Debug, Clone)]
pub struct ObjectErrorsAcc {
    clip: ClippedRegion,
    factors: Vec<FactorAcc>,
    /// The next sample row [`ObjectErrorsAcc::add_rows`] expects.
    next_row: usize,
    count: usize,
}

/// Factors whose sums [`ObjectErrorsAcc::add_rows`] accumulates side by side.
const LANES: usize = 4;
const _: () = assert!(FACTORS.is_multiple_of(LANES));

/// One factor's state in [`ObjectErrorsAcc`].
#[derive(Debug, Clone)]
struct FactorAcc {
    /// Per sample column: tessellated cell and fraction.
    cols: Vec<(usize, f64)>,
    /// Per sample row: tessellated cell and fraction.
    rows: Vec<(usize, f64)>,
    /// Vertex row -> compact index (`usize::MAX`: unused).
    row_map: Vec<usize>,
    /// Per sample column: compact indices of its cell's two vertex columns.
    col_pair: Vec<(usize, usize)>,
    /// Per used vertex column: its [`bilinear_axis`] lookup.
    col_at: Vec<(usize, usize, f64)>,
    /// Per used vertex row: its lookup.
    row_at: Vec<(usize, usize, f64)>,
    /// Per used vertex row: whether its heights are in `vz`.
    row_filled: Vec<bool>,
    /// Used vertex heights, row-major over the used rows and columns.
    vz: Vec<f64>,
    /// The tessellated cell row `lo` and `hi` are for.
    row_cell: usize,
    /// Per sample column, the surface along the current cell row's south edge.
    lo: Vec<f64>,
    /// ... and north edge.
    hi: Vec<f64>,
    sum: f64,
    max: f64,
}

impl FactorAcc {
    /// Enters tessellated cell row `cell_b`: bilerp's first half (`a` and `b` there) for every
    /// sample column, the surface along the cell row's south (`lo`) and north (`hi`) edges.
    fn start_cell_row(&mut self, cell_b: usize) {
        self.row_cell = cell_b;
        let nc = self.col_at.len();
        let (rb0, rb1) = (self.row_map[cell_b], self.row_map[cell_b + 1]);
        assert!(self.row_filled[rb0] && self.row_filled[rb1], "vertex rows not filled");
        let (r0, r1) = (rb0 * nc, rb1 * nc);
        for (i, (&(_, s), &(c0, c1))) in self.cols.iter().zip(&self.col_pair).enumerate() {
            let (z00, z10) = (self.vz[r0 + c0], self.vz[r0 + c1]);
            let (z01, z11) = (self.vz[r1 + c0], self.vz[r1 + c1]);
            self.lo[i] = z00 + (z10 - z00) * s;
            self.hi[i] = z01 + (z11 - z01) * s;
        }
    }
}

impl ObjectErrorsAcc {
    /// The accumulator of `region` in a `width x height` grid; `None` for a region with no
    /// area there ([`object_errors`] gives 0, [`Coverage::Empty`]).
    pub fn new(region: Region, width: usize, height: usize) -> Option<Self> {
        let clip = region.clip_to(width, height)?;
        let (x0, y0) = (clip.x0, clip.y0);
        let (cx, cy) = (clip.x1 - x0, clip.y1 - y0);
        let factors = (0..FACTORS)
            .map(|k| {
                let f = factor(k);
                // As object_error's `locate`: local sample index -> (tessellated cell, fraction).
                let locate = |k: usize, c: usize| -> (usize, f64) {
                    let num = k * f;
                    let cell = (num / c).min(f - 1);
                    (cell, (num - cell * c) as f64 / c as f64)
                };
                let cols: Vec<(usize, f64)> = (0..=cx).map(|i| locate(i, cx)).collect();
                let rows: Vec<(usize, f64)> = (0..=cy).map(|j| locate(j, cy)).collect();
                // The vertices used: columns a, a + 1 of every sample column's cell (rows
                // alike), each with its compact index and its dem_bilinear axis lookup at
                // x0 + cx a / f.
                let used = |cells: &mut dyn Iterator<Item = usize>,
                            map: &mut Vec<usize>,
                            at: &mut Vec<(usize, usize, f64)>,
                            origin: usize,
                            c: usize,
                            n: usize| {
                    map.clear();
                    map.resize(f + 1, usize::MAX);
                    for cell in cells {
                        for a in [cell, cell + 1] {
                            if map[a] == usize::MAX {
                                map[a] = at.len();
                                at.push(bilinear_axis(
                                    origin as f64 + (c * a) as f64 / f as f64,
                                    n,
                                ));
                            }
                        }
                    }
                };
                let (mut col_map, mut col_at) = (Vec::new(), Vec::new());
                used(&mut cols.iter().map(|c| c.0), &mut col_map, &mut col_at, x0, cx, width);
                let (mut row_map, mut row_at) = (Vec::new(), Vec::new());
                used(&mut rows.iter().map(|r| r.0), &mut row_map, &mut row_at, y0, cy, height);
                let col_pair = cols.iter().map(|&(a, _)| (col_map[a], col_map[a + 1])).collect();
                FactorAcc {
                    cols,
                    rows,
                    row_map,
                    col_pair,
                    vz: vec![0.0; row_at.len() * col_at.len()],
                    row_filled: vec![false; row_at.len()],
                    col_at,
                    row_at,
                    row_cell: usize::MAX,
                    lo: vec![0.0; cx + 1],
                    hi: vec![0.0; cx + 1],
                    sum: 0.0,
                    max: 0.0,
                }
            })
            .collect();
        Some(Self { clip, factors, next_row: y0, count: 0 })
    }

    /// About how many bytes the accumulator of a region of `cx x cy` cells holds (its column
    /// and row tables, the surface along a cell row and the used vertices, for the 32
    /// factors), for callers that bound how many they keep at once.
    pub fn bytes_estimate(cx: usize, cy: usize) -> usize {
        (0..FACTORS)
            .map(|k| {
                let used = factor(k) + 1;
                let per_col =
                    size_of::<(usize, f64)>() + size_of::<(usize, usize)>() + 2 * size_of::<f64>();
                let per_row = size_of::<(usize, f64)>();
                let vertices = used.min(cx + 1) * used.min(cy + 1) * size_of::<f64>();
                (cx + 1) * per_col + (cy + 1) * per_row + vertices + 2 * used * 40
            })
            .sum::<usize>()
            + size_of::<Self>()
    }

    /// The region clipped to the grid.
    pub fn clip(&self) -> ClippedRegion {
        self.clip
    }

    /// The first of the two adjacent rows of every tessellated vertex row still missing,
    /// ascending, without repeats (a vertex reads rows `j` and `j + 1`).
    pub fn vertex_rows(&self) -> Vec<usize> {
        let mut out: Vec<usize> = self
            .factors
            .iter()
            .flat_map(|fa| {
                fa.row_at.iter().zip(&fa.row_filled).filter(|(_, f)| !**f).map(|(r, _)| r.0)
            })
            .collect();
        out.sort_unstable();
        out.dedup();
        out
    }

    /// As [`ObjectErrorsAcc::vertex_rows`], only those that adding the region's rows up to
    /// `last_row` (inclusive) needs: the vertex rows of the tessellated cell rows those sample
    /// rows fall in (for each factor, at most one vertex row beyond `last_row`). A reader by
    /// bands asks this before each band and reads ahead only these.
    pub fn vertex_rows_until(&self, last_row: usize) -> Vec<usize> {
        let clip = self.clip;
        let last = last_row.min(clip.y1);
        if last < self.next_row {
            return Vec::new();
        }
        let (a, z) = (self.next_row - clip.y0, last - clip.y0);
        let mut out: Vec<usize> = self
            .factors
            .iter()
            .flat_map(|fa| {
                (fa.rows[a].0..=fa.rows[z].0 + 1)
                    .map(|b| fa.row_map[b])
                    // Cell rows holding no sample row (a factor finer than the rows) use none.
                    .filter(|&r| r != usize::MAX && !fa.row_filled[r])
                    .map(|r| fa.row_at[r].0)
            })
            .collect();
        out.sort_unstable();
        out.dedup();
        out
    }

    /// Interpolates the tessellated vertices whose two rows are both in `rows` (vertices
    /// already filled are left alone: any band gives them the same bits).
    pub fn fill_vertices(&mut self, rows: &impl SampleRows) {
        let (first, end) = (rows.first_row(), rows.first_row() + rows.rows());
        for fa in &mut self.factors {
            let nc = fa.col_at.len();
            for (r, &(j0, j1, fv)) in fa.row_at.iter().enumerate() {
                if fa.row_filled[r] || j0 < first || j1 >= end {
                    continue;
                }
                let (row0, row1) = (rows.row(j0), rows.row(j1));
                // dem_bilinear's bilerp, with its lookups shared.
                for (c, &(i0, i1, fu)) in fa.col_at.iter().enumerate() {
                    let z = |row: &[f32], i: usize| f64::from(row[i]);
                    fa.vz[r * nc + c] =
                        bilerp(z(row0, i0), z(row0, i1), z(row1, i0), z(row1, i1), fu, fv);
                }
                fa.row_filled[r] = true;
            }
        }
    }

    /// Adds the region's rows present in `rows` that were not added yet, in order.
    ///
    /// # Panics
    /// If `rows` starts after the next row expected (a row would be skipped), or a vertex the
    /// rows need was not filled.
    pub fn add_rows(&mut self, rows: &impl SampleRows) {
        let clip = self.clip;
        let first = self.next_row.max(rows.first_row());
        let last = clip.y1.min((rows.first_row() + rows.rows()).saturating_sub(1));
        if first > last {
            return;
        }
        assert_eq!(first, self.next_row, "rows {}..{first} were never added", self.next_row);
        let any_void = rows.any_void();
        let x0 = clip.x0;
        let mut count = 0usize;
        // Factors in groups of LANES, each row's samples visited once per group: the groups'
        // sums are independent chains the CPU runs side by side (one chain per factor was
        // bound by the latency of its f64 additions). Each factor's sum still adds its
        // samples in row-major order, so every bit is as before.
        for group in self.factors.chunks_exact_mut(LANES) {
            // The rows' non-void samples (the same for every group).
            let mut group_count = 0usize;
            let mut sum = [0.0f64; LANES];
            let mut max = [0.0f64; LANES];
            for (g, fa) in group.iter().enumerate() {
                (sum[g], max[g]) = (fa.sum, fa.max);
            }
            let mut t = [0.0f64; LANES];
            for j in first..=last {
                for (g, fa) in group.iter_mut().enumerate() {
                    let (cell_b, tt) = fa.rows[j - clip.y0];
                    t[g] = tt;
                    if cell_b != fa.row_cell {
                        fa.start_cell_row(cell_b);
                    }
                }
                let row = &rows.row(j)[x0..=clip.x1];
                let lo: [&[f64]; LANES] = std::array::from_fn(|g| &group[g].lo[..row.len()]);
                let hi: [&[f64]; LANES] = std::array::from_fn(|g| &group[g].hi[..row.len()]);
                for (i, &h) in row.iter().enumerate() {
                    if any_void && rows.void(x0 + i, j) {
                        continue;
                    }
                    let h = f64::from(h);
                    for g in 0..LANES {
                        let (l, u) = (lo[g][i], hi[g][i]);
                        let e = (h - (l + (u - l) * t[g])).abs();
                        sum[g] += e;
                        max[g] = max[g].max(e);
                    }
                    group_count += 1;
                }
            }
            for (g, fa) in group.iter_mut().enumerate() {
                (fa.sum, fa.max) = (sum[g], max[g]);
            }
            count = group_count;
        }
        self.count += count;
        self.next_row = last + 1;
    }

    /// Whether every row of the region was added.
    pub fn is_complete(&self) -> bool {
        self.next_row > self.clip.y1
    }

    /// The 32 errors.
    ///
    /// # Panics
    /// If rows of the region were not added.
    pub fn finish(&self) -> DssErrors {
        assert!(self.is_complete(), "rows {}..={} were not added", self.next_row, self.clip.y1);
        let count = self.count;
        let mut out = DssErrors {
            avg: [0.0; FACTORS],
            max: [0.0; FACTORS],
            coverage: Coverage::from_count(count),
        };
        for (k, fa) in self.factors.iter().enumerate() {
            out.avg[k] = if count == 0 { 0.0 } else { fa.sum / count as f64 };
            out.max[k] = fa.max;
        }
        out
    }
}

/// Eq. 3 for every factor: `rho_i = lambda * delta_i / d * sin(theta)` (see
/// [`screen::dss`] for the clamps and the must-split case).
pub fn screen_errors(
    delta: &[f64; FACTORS],
    lambda: f64,
    d: f64,
    view_dir: DVec3,
) -> [f64; FACTORS] {
    screen_errors_floored(delta, lambda, d, view_dir, screen::MIN_VIEW_SIN)
}

/// [`screen_errors`] with the view-angle floor `floor` ([`screen::dss_floored`]).
pub fn screen_errors_floored(
    delta: &[f64; FACTORS],
    lambda: f64,
    d: f64,
    view_dir: DVec3,
    floor: f64,
) -> [f64; FACTORS] {
    let sin = screen::view_sin_floored(view_dir, floor);
    delta.map(|e| screen::dss_at_sin(lambda, e, d, sin))
}

/// The tessellation decision of Eq. 4.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Tessellation {
    /// `rho_32 > rho_thr`: even the finest factor 64 is too coarse; the node splits (a leaf
    /// that cannot split renders at 64).
    MustSplit,
    /// The continuous factor `F_thr`, in `[2, 64]`.
    Factor(f64),
}

/// Eq. 4: `F_thr = (rho_i - rho_thr) / (rho_i - rho_{i+1}) * 2 + l_i`, `l_i = 2i`.
///
/// As the paper: if `rho_32 > rho_thr` the node must split; otherwise scan `i` from 31 down to
/// 1 for the first `rho_i > rho_thr` (so `rho_{i+1} <= rho_thr < rho_i` and the denominator is
/// positive) and interpolate into `(2i, 2i + 2]`; if none exceeds the threshold, the coarsest
/// factor 2. `rho` index `k` is the paper's `i = k + 1`. A negative or NaN threshold counts as
/// 0; an infinite `rho_i` (camera inside the box) gives `2i + 2`.
pub fn tessellation_factor(rho: &[f64; FACTORS], rho_thr: f64) -> Tessellation {
    tessellation_factor_of(|k| rho[k], rho_thr)
}

/// [`tessellation_factor`] of the screen errors `rho(k)`, each worked out only when the scan
/// reaches it (from the finest down to the first over the threshold, and the one after it).
pub fn tessellation_factor_of(rho: impl Fn(usize) -> f64, rho_thr: f64) -> Tessellation {
    let thr = if rho_thr.is_nan() { 0.0 } else { rho_thr.max(0.0) };
    let mut rn = rho(FACTORS - 1);
    if rn > thr {
        return Tessellation::MustSplit;
    }
    for k in (0..FACTORS - 1).rev() {
        let ri = rho(k);
        if ri > thr {
            let li = factor(k) as f64;
            let frac = if ri.is_infinite() { 1.0 } else { (ri - thr) / (ri - rn) };
            return Tessellation::Factor(frac * 2.0 + li);
        }
        rn = ri;
    }
    Tessellation::Factor(2.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(k: usize) -> f64 {
        // rho_i = 64 - 2i: rho_1 = 62, ..., rho_32 = 0.
        64.0 - factor(k) as f64
    }

    #[test]
    fn eq4_interpolates_between_even_factors() {
        let rho: [f64; FACTORS] = std::array::from_fn(ramp);
        // rho_thr = 33: rho_15 = 34 > 33 >= rho_16 = 32 -> F = (34 - 33) / 2 * 2 + 30 = 31.
        assert_eq!(tessellation_factor(&rho, 33.0), Tessellation::Factor(31.0));
        // Exactly on rho_16 = 32: first rho_i > 32 is i = 15 -> F = 2/2*2 + 30 = 32.
        assert_eq!(tessellation_factor(&rho, 32.0), Tessellation::Factor(32.0));
        assert_eq!(tessellation_factor(&rho, 100.0), Tessellation::Factor(2.0));
        assert_eq!(tessellation_factor(&rho, -5.0), Tessellation::Factor(64.0));
        let mut split = rho;
        split[31] = 1.0;
        assert_eq!(tessellation_factor(&split, 0.5), Tessellation::MustSplit);
        assert_eq!(tessellation_factor(&[f64::INFINITY; FACTORS], 1.0), Tessellation::MustSplit);
        let mut inf = [0.0; FACTORS];
        inf[4] = f64::INFINITY;
        assert_eq!(tessellation_factor(&inf, 1.0), Tessellation::Factor(12.0));
    }

    #[test]
    fn envelope_is_non_increasing() {
        let e = DssErrors {
            avg: std::array::from_fn(|k| if k % 2 == 0 { 1.0 } else { 2.0 }),
            max: [0.0; FACTORS],
            coverage: Coverage::Measured { samples: 1 },
        };
        let m = e.monotone_envelope();
        assert!(m.avg.windows(2).all(|w| w[0] >= w[1]));
        assert_eq!(m.avg[0], 2.0);
    }
}
