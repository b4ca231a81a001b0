//! The check of a decimated tile against every DEM sample under it ([`check`]): the largest
//! error of its mesh over the non-void samples, or `None` when a non-void sample lies in no
//! triangle, exactly what a scan of every sample finds ([`max_error`], the reference), while
//! visiting few of them.
//!
//! **Which samples a triangle holds** is decided row by row by one function ([`row_span`]: the
//! samples of a row where the three edge functions are at least `-1e-7` cell, so the samples on
//! a shared edge count for both triangles), used by the scan, the coverage sweep and the leaf
//! scans alike, so the three agree sample for sample.
//!
//! **Coverage** from the triangles' rows alone: each triangle holds an interval of every row it
//! meets, and the intervals of a row, swept in order, leave exactly the uncovered samples
//! (work proportional to the triangles' heights, not their areas); only those gaps are read,
//! to see whether they are void.
//!
//! **Error** by branch and bound (Land & Doig 1960) over a min/max pyramid of the samples
//! ([`SampleRange`], measured once per run in the decimation pass's read of every sample:
//! 1/128 of the DEM's f32 bytes up to about a 23,000^2 grid, at most 21 MiB beyond, where its
//! finest boxes grow instead, [`leaf_log2_for`]): over an aligned box of samples, a
//! triangle's plane is off by at most `max(plane_max - z_min, z_max - plane_min)` (a plane's
//! extremes over a box are at its corners), widened by a relative 1e-9 for rounding.
//! (triangle, box) pairs are refined in decreasing order of that bound, the finest boxes
//! (16 x 16 samples, larger on larger grids) are scanned with the reference's arithmetic (a
//! box of up to 64 x 64 whole, in one window, when none of its quarters is proven: the plain
//! scan's cost where little is pruned), and the search stops when the largest bound left is
//! no more than the largest error scanned. So the result is the exact maximum, bit for bit
//! the scan's (the same per-sample expression on the same samples; a maximum does not depend
//! on order), and only pairs whose bound reaches the worst sample are
//! refined: a coarse tile, whose bound is far above the terrain's relief in a box, proves
//! most of its area from the pyramid's upper levels.

use std::sync::atomic::{AtomicU64, Ordering as AtomicOrdering};

use glam::{DVec2, dvec2};
use rayon::prelude::*;
use terrain_core::tin::{GridLayout, TileMesh};

use super::build::{grid_rect, samples_inside};
use terrain_app::samples::{Samples, Window};

/// Tolerance of the edge functions, in cells (scaled by the edge's length).
const EPS: f64 = 1e-7;

/// log2 of the side of the pyramid's finest boxes (16 x 16 samples), the boxes scanned, on a
/// grid of at most [`MAX_LEAF_BOXES`] of them.
const MIN_LEAF_LOG2: u32 = 4;

/// The most finest boxes a pyramid holds (16 MiB of them, 21 MiB with the levels above): on a
/// grid with more 16 x 16 boxes (over about 23,000^2 samples) the finest boxes are 32 x 32 or
/// larger, so the pyramid's memory stays bounded whatever the DEM's size (issue 16: "memory
/// bounded by the store's cache, not the DEM"), at the price of larger leaf scans.
const MAX_LEAF_BOXES: usize = 1 << 21;

/// log2 of the finest boxes' side on a `w x h` grid: the smallest from [`MIN_LEAF_LOG2`] with
/// at most [`MAX_LEAF_BOXES`] boxes.
pub(crate) fn leaf_log2_for(w: usize, h: usize) -> u32 {
    leaf_log2_within(w, h, MAX_LEAF_BOXES)
}

fn leaf_log2_within(w: usize, h: usize, max_boxes: usize) -> u32 {
    let mut k = MIN_LEAF_LOG2;
    while k < usize::BITS - 1 && w.div_ceil(1 << k).saturating_mul(h.div_ceil(1 << k)) > max_boxes {
        k += 1;
    }
    k
}

/// Minimum and maximum of the non-void samples of a grid over aligned boxes: level `k` (from
/// the finest boxes' `leaf_log2` up to one box over the grid) holds boxes of `2^k x 2^k`
/// samples, box `(a, b)` the samples `[a 2^k, (a + 1) 2^k)` x `[b 2^k, (b + 1) 2^k)` within
/// the grid. A box without a non-void finite-or-infinite sample (NaN and void samples are
/// never measured) holds `[inf, -inf]`.
#[derive(Debug)]
pub(crate) struct SampleRange {
    /// log2 of the finest boxes' side ([`leaf_log2_for`]).
    leaf_log2: u32,
    /// Per level from `leaf_log2`: boxes per row, and `[min, max]` per box (row-major).
    levels: Vec<(usize, Vec<[f32; 2]>)>,
}

const EMPTY: [f32; 2] = [f32::INFINITY, f32::NEG_INFINITY];

fn merge(a: [f32; 2], b: [f32; 2]) -> [f32; 2] {
    // f32::min and max ignore NaN, as the scan's f64::max ignores a NaN error.
    [a[0].min(b[0]), a[1].max(b[1])]
}

/// The minima and maxima over the finest boxes of the samples of one window (the boxes it
/// meets, partly or wholly: [`merge`] is idempotent, so windows that share samples or boxes
/// merge into the same pyramid).
#[derive(Debug)]
pub(crate) struct LeafBoxes {
    /// log2 of the boxes' side.
    leaf_log2: u32,
    /// The first box's column and row, and boxes per row.
    a0: usize,
    b0: usize,
    nx: usize,
    boxes: Vec<[f32; 2]>,
}

impl LeafBoxes {
    /// The boxes of `2^leaf_log2` samples a side of `win`, whose first sample is `(i0, j0)`
    /// (its non-void samples merged).
    pub(crate) fn of(leaf_log2: u32, i0: usize, j0: usize, win: &Window) -> Self {
        let ww = win.width;
        let wh = win.data.len() / ww.max(1);
        if ww == 0 || wh == 0 {
            return Self { leaf_log2, a0: 0, b0: 0, nx: 0, boxes: Vec::new() };
        }
        let (a0, b0) = (i0 >> leaf_log2, j0 >> leaf_log2);
        let nx = ((i0 + ww - 1) >> leaf_log2) - a0 + 1;
        let ny = ((j0 + wh - 1) >> leaf_log2) - b0 + 1;
        let mut boxes = vec![EMPTY; nx * ny];
        for b in 0..wh {
            let row = &win.data[b * ww..(b + 1) * ww];
            let by = ((j0 + b) >> leaf_log2) - b0;
            for (a, &z) in row.iter().enumerate() {
                if win.voids.as_ref().is_some_and(|v| v.get(a, b)) {
                    continue;
                }
                let m = &mut boxes[by * nx + ((i0 + a) >> leaf_log2) - a0];
                *m = merge(*m, [z, z]);
            }
        }
        Self { leaf_log2, a0, b0, nx, boxes }
    }
}

impl SampleRange {
    /// Reads every sample once, by windows of `region` x `region` samples (rounded up to a
    /// multiple of the finest box) in parallel (`terrain tiles` takes them from the
    /// decimation pass's read instead, [`SampleRange::from_leaves`]).
    #[cfg(test)]
    pub(crate) fn measure(samples: &dyn Samples, region: usize) -> anyhow::Result<Self> {
        let (w, h) = samples.size();
        Self::measure_with(samples, region, leaf_log2_for(w, h))
    }

    /// [`SampleRange::measure`] with finest boxes of `2^leaf_log2` samples a side.
    #[cfg(test)]
    pub(crate) fn measure_with(
        samples: &dyn Samples,
        region: usize,
        leaf_log2: u32,
    ) -> anyhow::Result<Self> {
        let (w, h) = samples.size();
        let leaf = 1usize << leaf_log2;
        let region = region.max(1).next_multiple_of(leaf);
        let (rx, ry) = (w.div_ceil(region), h.div_ceil(region));
        let parts = (0..rx * ry)
            .into_par_iter()
            .map(|r| -> anyhow::Result<LeafBoxes> {
                let (i0, j0) = ((r % rx) * region, (r / rx) * region);
                let (ww, wh) = (region.min(w - i0), region.min(h - j0));
                Ok(LeafBoxes::of(leaf_log2, i0, j0, &samples.window(i0, j0, ww, wh, 0)?))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        Ok(Self::from_leaves(w, h, leaf_log2, &parts))
    }

    /// The pyramid of a `w x h` grid from the finest boxes of windows that together hold
    /// every sample (the caller's to ensure: a sample in no window is never measured, and a
    /// box without one reads as holding none, which the search prunes).
    pub(crate) fn from_leaves(w: usize, h: usize, leaf_log2: u32, parts: &[LeafBoxes]) -> Self {
        assert!(parts.iter().all(|p| p.leaf_log2 == leaf_log2), "boxes of another size");
        let leaf = 1usize << leaf_log2;
        let (nx, ny) = (w.div_ceil(leaf), h.div_ceil(leaf));
        let mut boxes = vec![EMPTY; nx * ny];
        for p in parts {
            for (k, m) in p.boxes.iter().enumerate() {
                let (a, b) = (p.a0 + k % p.nx, p.b0 + k / p.nx);
                if a >= nx || b >= ny {
                    continue;
                }
                let at = &mut boxes[b * nx + a];
                *at = merge(*at, *m);
            }
        }
        let mut levels = vec![(nx, boxes)];
        while let Some((nx, below)) = levels.last().filter(|(_, v)| v.len() > 1) {
            let (nx, ny) = (*nx, below.len() / nx);
            let (ux, uy) = (nx.div_ceil(2), ny.div_ceil(2));
            let mut up = vec![EMPTY; ux * uy];
            for (k, m) in below.iter().enumerate() {
                let u = &mut up[(k / nx / 2) * ux + (k % nx) / 2];
                *u = merge(*u, *m);
            }
            levels.push((ux, up));
        }
        Self { leaf_log2, levels }
    }

    /// The coarsest level (one box over the grid).
    fn top(&self) -> u32 {
        self.leaf_log2 + self.levels.len() as u32 - 1
    }

    /// `[min, max]` of box `(a, b)` at level `k`.
    fn get(&self, k: u32, a: usize, b: usize) -> [f32; 2] {
        let (nx, v) = &self.levels[(k - self.leaf_log2) as usize];
        v[b * nx + a]
    }

    /// Bytes held.
    pub(crate) fn bytes(&self) -> usize {
        self.levels.iter().map(|(_, v)| v.len() * size_of::<[f32; 2]>()).sum()
    }
}

/// A triangle in grid coordinates with its plane: made when needed from the tile's mesh
/// ([`Tris::get`]), never held for every triangle at once.
pub(super) struct Tri {
    p: [DVec2; 3],
    z0: f64,
    /// Height gradient per grid unit.
    g: DVec2,
    lo: DVec2,
    hi: DVec2,
    /// Edge `k` (from corner `k` to `k + 1`) and its length.
    edges: [(DVec2, f64); 3],
}

impl Tri {
    /// The triangle of corners `p` (grid coordinates) and heights `z`; `None` unless it is
    /// counter-clockwise with a positive area.
    fn new([(p0, z0), (p1, z1), (p2, z2)]: [(DVec2, f64); 3]) -> Option<Self> {
        let (e1, e2) = (p1 - p0, p2 - p0);
        let d = e1.perp_dot(e2);
        if d <= 0.0 {
            return None;
        }
        // z = z0 + g . (q - p0), solved from the two edges.
        let g = dvec2(
            ((z1 - z0) * e2.y - (z2 - z0) * e1.y) / d,
            ((z2 - z0) * e1.x - (z1 - z0) * e2.x) / d,
        );
        let edges = [p1 - p0, p2 - p1, p0 - p2].map(|e| (e, e.length()));
        Some(Tri { p: [p0, p1, p2], z0, g, lo: p0.min(p1).min(p2), hi: p0.max(p1).max(p2), edges })
    }

    /// The mesh's height at sample `(i, j)`, off `z` by this (the one expression the scan and
    /// the leaf scans use).
    fn error(&self, i: usize, j: usize, z: f32) -> f64 {
        let q = dvec2(i as f64, j as f64) - self.p[0];
        let m = self.z0 + self.g.dot(q);
        (m - f64::from(z)).abs()
    }

    /// The rows `ja..=jb` of samples in `[i0, j0, i1, j1]` the triangle may hold (`None`: its
    /// box misses them; `ja > jb` possible).
    fn rows(&self, [i0, j0, i1, j1]: [usize; 4]) -> Option<(usize, usize)> {
        if self.hi.x < i0 as f64 - EPS
            || self.lo.x > i1 as f64 + EPS
            || self.hi.y < j0 as f64 - EPS
            || self.lo.y > j1 as f64 + EPS
        {
            return None;
        }
        let ja = ((self.lo.y - EPS).ceil().max(j0 as f64)) as usize;
        let jb = ((self.hi.y + EPS).floor().min(j1 as f64)) as usize;
        Some((ja, jb))
    }

    /// The samples of `rect` in the triangle's box (with the tolerance), `[ia, ja, ib, jb]`;
    /// `None` if there are none.
    fn samples_box(&self, rect: [usize; 4]) -> Option<[usize; 4]> {
        let (ja, jb) = self.rows(rect)?;
        let ia = ((self.lo.x - EPS).ceil().max(rect[0] as f64)) as usize;
        let ib = ((self.hi.x + EPS).floor().min(rect[2] as f64)) as usize;
        (ia <= ib && ja <= jb).then_some([ia, ja, ib, jb])
    }

    /// The samples `i0..=i1` of row `j` inside the triangle: where all three edge functions
    /// are `>= -EPS |e|` (counter-clockwise).
    fn row_span(&self, j: usize, i0: usize, i1: usize) -> Option<(usize, usize)> {
        let y = j as f64;
        let (mut xa, mut xb) = (self.lo.x - EPS, self.hi.x + EPS);
        for (p, (e, len)) in self.p.iter().zip(self.edges) {
            // e x (x - p) = e.x (y - p.y) - e.y (x - p.x) >= -EPS |e|
            let c = e.x * (y - p.y) + e.y * p.x + EPS * len;
            // -e.y x + c >= 0
            if e.y > 0.0 {
                xb = xb.min(c / e.y);
            } else if e.y < 0.0 {
                xa = xa.max(c / e.y);
            } else if c < 0.0 {
                xa = f64::INFINITY;
            }
        }
        let xa = xa.ceil().max(i0 as f64);
        let xb = xb.floor().min(i1 as f64);
        if xa > xb { None } else { Some((xa as usize, xb as usize)) }
    }

    /// Whether the triangle holds no sample of the box `[x0, y0, x1, y1]` for certain: every
    /// corner is outside one edge by more than the tolerance and a margin of 1e-5 cell, far
    /// over the rounding of either computation.
    fn misses(&self, [x0, y0, x1, y1]: [f64; 4]) -> bool {
        self.p.iter().zip(self.edges).any(|(p, (e, len))| {
            let f = |x: f64, y: f64| e.x * (y - p.y) - e.y * (x - p.x);
            let most = f(x0, y0).max(f(x1, y0)).max(f(x0, y1)).max(f(x1, y1));
            most < -(EPS + 1e-5) * len
        })
    }
}

/// A tile's triangles in grid coordinates, each made from the mesh when it is needed
/// ([`Tris::get`]) rather than held: a table of [`Tri`]s (176 bytes a triangle) was the
/// largest thing `terrain tiles` held besides its cache (92 MB at the peak over a 16385^2
/// store, about 260 k triangles a decimated tile, one tile a thread; bench/mesh/README.md).
/// Every use makes the triangle with the same f64 expressions from the same mesh vertices, so
/// its corners, plane, box and edges are bit for bit those of the table, and the check
/// measures exactly what it did with the table.
pub(super) struct Tris<'a> {
    mesh: &'a TileMesh,
    /// The tile's south-west corner in grid coordinates, and its extent.
    a: DVec2,
    size: DVec2,
}

impl<'a> Tris<'a> {
    pub(super) fn new(layout: &GridLayout, mesh: &'a TileMesh) -> Self {
        let (a, b) = grid_rect(layout, mesh.tile);
        Self { mesh, a, size: b - a }
    }

    /// The mesh's triangles, counter-clockwise or not (ids `0..len`).
    fn len(&self) -> u32 {
        self.mesh.triangles.len() as u32
    }

    /// Triangle `k` of the mesh in grid coordinates; `None` for one that is not
    /// counter-clockwise with a positive area (it holds no sample).
    fn get(&self, k: u32) -> Option<Tri> {
        let corner = |v: u32| {
            let v = self.mesh.vertices[v as usize];
            (dvec2(self.a.x + v.x * self.size.x, self.a.y + v.y * self.size.y), v.z)
        };
        Tri::new(self.mesh.triangles[k as usize].map(corner))
    }

    /// The ids of the triangles `get` makes, in order.
    fn ids(&self) -> impl Iterator<Item = (u32, Tri)> + '_ {
        (0..self.len()).filter_map(|k| Some((k, self.get(k)?)))
    }
}

/// The largest error of `mesh` against every non-void DEM sample under it, exactly as
/// [`max_error`] over all of them would measure it (see the module docs); `None` if the mesh
/// leaves a non-void sample uncovered (which the caller treats as a failure).
pub(crate) fn check(
    samples: &dyn Samples,
    layout: &GridLayout,
    mesh: &TileMesh,
    range: &SampleRange,
) -> anyhow::Result<Option<f64>> {
    let Some(rect) = samples_inside(layout, mesh.tile) else {
        return Ok(Some(0.0));
    };
    let tris = Tris::new(layout, mesh);
    if !covers(samples, &tris, rect)? {
        return Ok(None);
    }
    Ok(Some(worst(samples, range, &tris, rect)?))
}

/// Rows a band of the coverage sweep holds the triangles' intervals of at once.
const BAND_ROWS: usize = 64;

/// Whether every non-void sample of `rect` lies in a triangle ([`Tri::row_span`]), swept by
/// bands of [`BAND_ROWS`] rows: each band holds its triangles' intervals on its own rows only
/// (the intervals of every row at once were 8 bytes a triangle and row, 31 MB at the peak over
/// a 16385^2 store), and the triangles meeting a band are listed by a counting sort (4 bytes a
/// triangle and band it meets).
fn covers(samples: &dyn Samples, tris: &Tris<'_>, rect: [usize; 4]) -> anyhow::Result<bool> {
    let [i0, j0, i1, j1] = rect;
    let rows = j1 - j0 + 1;
    let bands = rows.div_ceil(BAND_ROWS);
    // The bands of rows (relative to j0) each triangle meets.
    let meets = |t: &Tri| {
        let (ja, jb) = t.rows(rect).filter(|(ja, jb)| ja <= jb)?;
        Some((ja - j0) / BAND_ROWS..=(jb - j0) / BAND_ROWS)
    };
    let mut start = vec![0usize; bands + 1];
    for (_, t) in tris.ids() {
        for band in meets(&t).into_iter().flatten() {
            start[band + 1] += 1;
        }
    }
    for band in 0..bands {
        start[band + 1] += start[band];
    }
    let mut in_band = vec![0u32; start[bands]];
    let mut next = start.clone();
    for (k, t) in tris.ids() {
        for band in meets(&t).into_iter().flatten() {
            in_band[next[band]] = k;
            next[band] += 1;
        }
    }
    drop(next);
    // Per band: (row, first, last) of every triangle's interval on its rows, sorted, swept.
    let mut spans: Vec<(u32, u32, u32)> = Vec::new();
    for band in 0..bands {
        let (ra, rb) = (j0 + band * BAND_ROWS, (j0 + (band + 1) * BAND_ROWS - 1).min(j1));
        spans.clear();
        for &k in &in_band[start[band]..start[band + 1]] {
            let Some(t) = tris.get(k) else { continue };
            let Some((ja, jb)) = t.rows(rect) else { continue };
            for j in ja.max(ra)..=jb.min(rb) {
                if let Some((a, b)) = t.row_span(j, i0, i1) {
                    spans.push(((j - ra) as u32, a as u32, b as u32));
                }
            }
        }
        spans.sort_unstable();
        let mut at = 0;
        for j in ra..=rb {
            let r = (j - ra) as u32;
            // The first sample of the row not covered yet.
            let mut from = i0;
            while let Some(&(_, a, b)) = spans.get(at).filter(|s| s.0 == r) {
                let (a, b) = (a as usize, b as usize);
                if a > from && !void_between(samples, from, a - 1, j)? {
                    return Ok(false);
                }
                from = from.max(b + 1);
                at += 1;
            }
            if from <= i1 && !void_between(samples, from, i1, j)? {
                return Ok(false);
            }
        }
    }
    Ok(true)
}

/// Whether the samples `i0..=i1` of row `j` are all void.
fn void_between(samples: &dyn Samples, i0: usize, i1: usize, j: usize) -> anyhow::Result<bool> {
    let n = i1 - i0 + 1;
    let win = samples.window(i0, j, n, 1, 0)?;
    Ok(win.voids.is_some_and(|v| (0..n).all(|a| v.get(a, 0))))
}

/// log2 of the side of the largest boxes scanned whole when every quarter is left to search
/// (64 x 64 samples).
const SCAN_LOG2: u32 = 6;

/// Boxes of `2^REGION_LOG2` samples a side are searched in parallel, the largest bound first.
const REGION_LOG2: u32 = 8;

/// The search of one tile: its triangles and the largest error found so far (shared by the
/// regions searched in parallel; an `f64 >= 0` as its bits, which order as the numbers do).
struct Search<'a> {
    samples: &'a dyn Samples,
    range: &'a SampleRange,
    tris: &'a Tris<'a>,
    /// The tile's samples.
    rect: [usize; 4],
    best: AtomicU64,
}

/// Triangles meeting a box, with their bounds there.
type Meeting = Vec<(u32, f64)>;

impl Search<'_> {
    fn best(&self) -> f64 {
        f64::from_bits(self.best.load(AtomicOrdering::Relaxed))
    }

    /// The bound of triangle `t`'s error over the samples of box `(k, a, b)` it may hold
    /// (`None`: it holds none there, or none is measured).
    fn bound(&self, t: &Tri, k: u32, a: usize, b: usize) -> Option<f64> {
        // Each triangle's samples lie in its box (with the tolerance) clipped to the tile's.
        let [ia, ja, ib, jb] = t.samples_box(self.rect)?;
        let x0 = (a << k).max(ia);
        let y0 = (b << k).max(ja);
        let x1 = (((a + 1) << k) - 1).min(ib);
        let y1 = (((b + 1) << k) - 1).min(jb);
        if x0 > x1 || y0 > y1 {
            return None;
        }
        let corners = [x0 as f64, y0 as f64, x1 as f64, y1 as f64];
        if t.misses(corners) {
            return None;
        }
        let [zmin, zmax] = self.range.get(k, a, b);
        if zmin > zmax || zmin.is_nan() {
            return None;
        }
        let (zmin, zmax) = (f64::from(zmin), f64::from(zmax));
        let [cx0, cy0, cx1, cy1] = corners;
        let m = |x: f64, y: f64| t.z0 + t.g.dot(dvec2(x, y) - t.p[0]);
        let ms = [m(cx0, cy0), m(cx1, cy0), m(cx0, cy1), m(cx1, cy1)];
        let lo = ms.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = ms.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let reach = (cx0 - t.p[0].x).abs().max((cx1 - t.p[0].x).abs()) * t.g.x.abs()
            + (cy0 - t.p[0].y).abs().max((cy1 - t.p[0].y).abs()) * t.g.y.abs();
        let slack = 1e-9 * (t.z0.abs() + reach + zmin.abs().max(zmax.abs()) + 1.0);
        let bound = (hi - zmin).max(zmax - lo) + slack;
        Some(if bound.is_nan() { f64::INFINITY } else { bound })
    }

    /// The triangles of `of` that may raise the largest error in each of the boxes `at` (at
    /// level `k`), with their bounds there, and the largest of those per box: each triangle
    /// made once for all the boxes.
    fn meeting<const N: usize>(
        &self,
        of: impl Iterator<Item = u32>,
        k: u32,
        at: [(usize, usize); N],
    ) -> [(f64, Meeting); N] {
        let best = self.best();
        let mut out: [(f64, Meeting); N] = std::array::from_fn(|_| (f64::NEG_INFINITY, Vec::new()));
        for id in of {
            let Some(t) = self.tris.get(id) else { continue };
            for ((most, list), &(a, b)) in out.iter_mut().zip(&at) {
                if let Some(e) = self.bound(&t, k, a, b).filter(|&e| e > best) {
                    list.push((id, e));
                    *most = most.max(e);
                }
            }
        }
        out
    }

    /// Searches box `(k, a, b)` with the triangles `list` meeting it: children in decreasing
    /// order of their bounds (so the worst samples are found early and prune the rest), the
    /// finest boxes scanned.
    fn search(&self, k: u32, a: usize, b: usize, list: Meeting) -> anyhow::Result<()> {
        let best = self.best();
        if list.iter().all(|&(_, e)| e <= best) {
            return Ok(());
        }
        if k > self.range.leaf_log2 {
            let quarters =
                [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(da, db)| (2 * a + da, 2 * b + db));
            let found = self.meeting(list.iter().map(|&(t, _)| t), k - 1, quarters);
            let mut children: Vec<(f64, usize, usize, Meeting)> = found
                .into_iter()
                .zip(quarters)
                .map(|((e, l), (ca, cb))| (e, ca, cb, l))
                .filter(|(_, _, _, l)| !l.is_empty())
                .collect();
            // Every quarter of a small box left to search: its samples are as good as all
            // visited, so one scan of the box does it at the plain scan's cost (one window,
            // one row interval per triangle and row) instead of a search per leaf box (a
            // window, bounds and row intervals per 16 x 16 box), which cost the middle levels
            // up to 3x the plain scan (measured on a 16385^2 store). A box with a quarter
            // proven within the bound goes on with the search, so the coarse tiles, which
            // prove most quarters, still visit few samples.
            if k <= SCAN_LOG2 && children.len() == 4 {
                return self.scan(k, a, b, &list);
            }
            children.sort_by(|p, q| q.0.total_cmp(&p.0));
            for (_, ca, cb, l) in children {
                self.search(k - 1, ca, cb, l)?;
            }
            return Ok(());
        }
        self.scan(k, a, b, &list)
    }

    /// Measures the samples of box `(k, a, b)` in the tile with every triangle of `list` that
    /// may raise the largest error, as the reference does ([`Tri::rows`], [`Tri::row_span`],
    /// [`Tri::error`] over the tile's samples).
    fn scan(&self, k: u32, a: usize, b: usize, list: &Meeting) -> anyhow::Result<()> {
        let best = self.best();
        let [i0, j0, i1, j1] = self.rect;
        let (x0, y0) = ((a << k).max(i0), (b << k).max(j0));
        let (x1, y1) = ((((a + 1) << k) - 1).min(i1), (((b + 1) << k) - 1).min(j1));
        if x0 > x1 || y0 > y1 {
            return Ok(());
        }
        let win = self.samples.window(x0, y0, x1 - x0 + 1, y1 - y0 + 1, 0)?;
        let mut worst = 0f64;
        for &(tri, e) in list {
            if e <= best {
                continue;
            }
            let Some(t) = self.tris.get(tri) else { continue };
            let Some((ja, jb)) = t.rows([x0, y0, x1, y1]) else { continue };
            for j in ja..=jb {
                let Some((xa, xb)) = t.row_span(j, x0, x1) else { continue };
                let row = (j - y0) * win.width;
                for i in xa..=xb {
                    if !win.voids.as_ref().is_some_and(|v| v.get(i - x0, j - y0)) {
                        worst = worst.max(t.error(i, j, win.data[row + i - x0]));
                    }
                }
            }
        }
        self.best.fetch_max(worst.to_bits(), AtomicOrdering::Relaxed);
        Ok(())
    }
}

/// The largest error of the triangles over the non-void samples of `rect` they hold, by
/// branch and bound (see the module docs).
fn worst(
    samples: &dyn Samples,
    range: &SampleRange,
    tris: &Tris<'_>,
    rect: [usize; 4],
) -> anyhow::Result<f64> {
    let s = Search { samples, range, tris, rect, best: AtomicU64::new(0f64.to_bits()) };
    // The regions, each with the triangles whose boxes meet it.
    let k = REGION_LOG2.clamp(range.leaf_log2, range.top());
    let [ra, rb] = [rect[0] >> k, rect[1] >> k];
    let (nx, ny) = ((rect[2] >> k) - ra + 1, (rect[3] >> k) - rb + 1);
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); nx * ny];
    for (id, t) in tris.ids() {
        let Some([ia, ja, ib, jb]) = t.samples_box(rect) else { continue };
        for b in (ja >> k)..=(jb >> k) {
            for a in (ia >> k)..=(ib >> k) {
                bins[(b - rb) * nx + (a - ra)].push(id);
            }
        }
    }
    let mut regions: Vec<(f64, usize, usize, Meeting)> = bins
        .into_iter()
        .enumerate()
        .map(|(r, bin)| {
            let (a, b) = (ra + r % nx, rb + r / nx);
            let [(e, l)] = s.meeting(bin.into_iter(), k, [(a, b)]);
            (e, a, b, l)
        })
        .filter(|(_, _, _, l)| !l.is_empty())
        .collect();
    regions.sort_by(|p, q| q.0.total_cmp(&p.0));
    // The worst region first, alone (its samples set the bar the others are pruned by), then
    // the rest on every core, dealt alternately into the two halves rayon splits first, so
    // each thread starts from the largest bounds.
    let mut rest = regions.into_iter();
    if let Some((_, a, b, l)) = rest.next() {
        s.search(k, a, b, l)?;
    }
    let (even, odd): (Vec<_>, Vec<_>) = rest.enumerate().partition(|(n, _)| n % 2 == 0);
    let dealt: Vec<_> = even.into_iter().chain(odd).map(|(_, r)| r).collect();
    dealt.into_par_iter().try_for_each(|(_, a, b, l)| s.search(k, a, b, l))?;
    Ok(s.best())
}

/// Every triangle of `m` the check measures, made at once (the reference's table).
#[cfg(test)]
fn grid_triangles(layout: &GridLayout, m: &TileMesh) -> Vec<Tri> {
    Tris::new(layout, m).ids().map(|(_, t)| t).collect()
}

/// The largest `|mesh - sample|` over the samples `[i0, j0]..=[i1, j1]` that `at` gives
/// (`None`: void), `None` if a non-void one lies in no triangle: every sample of every
/// triangle visited ([`Tri::row_span`]), the reference [`check`] is tested against.
#[cfg(test)]
fn max_error(
    tris: &[&Tri],
    [i0, j0, i1, j1]: [usize; 4],
    at: impl Fn(usize, usize) -> Option<f32>,
) -> Option<f64> {
    let (nw, nh) = (i1 - i0 + 1, j1 - j0 + 1);
    let mut covered = vec![false; nw * nh];
    let mut worst = 0f64;
    for t in tris {
        let Some((ja, jb)) = t.rows([i0, j0, i1, j1]) else { continue };
        for j in ja..=jb {
            let Some((xa, xb)) = t.row_span(j, i0, i1) else { continue };
            for i in xa..=xb {
                covered[(j - j0) * nw + (i - i0)] = true;
                if let Some(z) = at(i, j) {
                    worst = worst.max(t.error(i, j, z));
                }
            }
        }
    }
    for j in 0..nh {
        for i in 0..nw {
            if !covered[j * nw + i] && at(i0 + i, j0 + j).is_some() {
                return None;
            }
        }
    }
    Some(worst)
}

#[cfg(test)]
mod tests;
