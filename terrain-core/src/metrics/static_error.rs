//! The out-of-core paper's (Qiu 2013) static error: the six-point node error `H` (Eq. 4-5) and
//! the monotone `StaticE` (Eq. 3), computed bottom-up as a pyramid over a whole quadtree.
//!
//! The brief cites "section 3.2"; in the paper the static error is section 2.3 (3.2 is the
//! screen error, see [`crate::metrics::screen`]). Equation numbers below are the paper's.
//!
//! The paper's block is `(2^k + 1)^2` vertices; level 0 is its four corners, and each finer
//! level adds the vertices that split every node into four (non-redundant storage, Eq. 1-2).
//! A node at level `l` is drawn as its four corners until it splits; splitting adds exactly
//! five vertices: the four edge midpoints and the centre. Eq. 4 measures `H` over "four
//! midpoints of node's edges and two midpoints of diagonal lines": the two diagonal midpoints
//! are the same vertex (the centre), but its coarse height `f'` differs with the diagonal it is
//! interpolated along, so both are measured. `f'` is "calculated by linear operation": the
//! mean of the two endpoints of the edge or diagonal. Heights are vertical (our z, the paper's
//! OpenGL y), so no frame conversion enters the errors.

use crate::heightmap::Heightmap;
use crate::metrics::{Coverage, Diagonal, Region, tri_interp};

/// `H` of one node (Eq. 4) and what it measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeError {
    /// The error in metres (`>= 0`, finite).
    pub error: f64,
    /// How many of the six points were measured; see [`Coverage`].
    pub coverage: Coverage,
}

/// The static error `H(delta_i^l)` of a node (out-of-core paper Eq. 4 with Eq. 5):
///
/// `H = max_{n=1..6} delta_n`, `delta_n = |f(v_n) - f'(v_n)|` (Eq. 5), over the four edge
/// midpoints (`f'` = mean of the edge's two corners) and the centre twice (`f'` = mean of the
/// SW-NE diagonal's corners, and of the SE-NW diagonal's).
///
/// - A node clipped at the east/north border is drawn as its clipped extent: `f'` is linear
///   over the quad of the clipped corners (so planes stay exact); midpoints off the grid are
///   not measured.
/// - Void midpoints are not measured; if none is measured the result is 0 with
///   [`Coverage::VoidOnly`].
/// - `cells < 2` (no vertex to add) or a region off the grid: 0 with [`Coverage::Empty`].
/// - Odd `cells` (not a quadtree node of a `2^k + 1` block) use `m = cells / 2` as the
///   midpoint; `f'` is then the linear interpolation along the edge, and the two diagonal
///   triangulations at the centre, which reduce to the means above for even `cells`.
pub fn node_error(hm: &Heightmap, region: Region) -> NodeError {
    let Some(clip) = region.clip(hm) else {
        return NodeError { error: 0.0, coverage: Coverage::Empty };
    };
    let c = region.cells;
    if c < 2 {
        return NodeError { error: 0.0, coverage: Coverage::Empty };
    }
    let (x0, y0, m) = (region.x0, region.y0, c / 2);
    // The coarse quad: the node's corners, or its clipped extent's at the east/north border.
    let (x1, y1) = (clip.x1, clip.y1);
    let (w, ht) = ((x1 - x0) as f64, (y1 - y0) as f64);
    let z = |i: usize, j: usize| f64::from(hm.get(i, j));
    let (z00, z10, z01, z11) = (z(x0, y0), z(x1, y0), z(x0, y1), z(x1, y1));
    // f'(v_n): linear on the coarse quad's edges (the mean of the two corners at an edge
    // midpoint), and on each of its two triangulations at the centre (the mean of the
    // diagonal's two corners).
    let coarse = |i: usize, j: usize, diag: Diagonal| {
        tri_interp(z00, z10, z01, z11, (i - x0) as f64 / w, (j - y0) as f64 / ht, diag)
    };
    // The six points of Eq. 4, with the diagonal their f' is interpolated along.
    let points = [
        (x0 + m, y0, Diagonal::SwNe),     // south edge
        (x0 + m, y0 + c, Diagonal::SwNe), // north edge
        (x0, y0 + m, Diagonal::SwNe),     // west edge
        (x0 + c, y0 + m, Diagonal::SwNe), // east edge
        (x0 + m, y0 + m, Diagonal::SwNe), // centre, SW-NE diagonal
        (x0 + m, y0 + m, Diagonal::SeNw), // centre, SE-NW diagonal
    ];
    let mut h = 0.0f64;
    let mut n = 0;
    for (i, j, diag) in points {
        if !clip.contains(i, j) || hm.voids().get(i, j) {
            continue;
        }
        // Eq. 5: delta_n = |f(v_n) - f'(v_n)|.
        h = h.max((z(i, j) - coarse(i, j, diag)).abs());
        n += 1;
    }
    NodeError { error: h, coverage: Coverage::from_count(n) }
}

/// [`node_error`]'s `H` of the nodes `(0, y0)`, `(cells, y0)`, ... of `cells` cells (even),
/// one per entry of `out`, every one inside the grid (`x0 + cells <= width - 1`,
/// `y0 + cells <= height - 1`): the bake's hot loop (every node of every block), so without
/// clipping, closures or per-point bounds checks. The same f64 arithmetic as `node_error`'s
/// `tri_interp` at its coordinates `u, v` in `{0, 1/2, 1}`: its terms times 1 are the terms
/// themselves and its terms times 0 are zeros, whose sign the absolute difference ignores, so
/// the values are `node_error`'s bit for bit (`interior_errors_are_node_errors` checks it).
fn interior_errors(hm: &Heightmap, y0: usize, cells: usize, out: &mut [f64]) {
    if out.is_empty() {
        return;
    }
    let (w, m) = (hm.width(), cells / 2);
    let data = hm.data();
    let len = out.len() * cells + 1;
    let row = |j: usize| &data[j * w..j * w + len];
    let (south, middle, north) = (row(y0), row(y0 + m), row(y0 + cells));
    let voids = hm.voids().any().then(|| hm.voids());
    for (n, e) in out.iter_mut().enumerate() {
        let x0 = n * cells;
        let z = |r: &[f32], i: usize| f64::from(r[i]);
        let (z00, z10, z01, z11) =
            (z(south, x0), z(south, x0 + cells), z(north, x0), z(north, x0 + cells));
        let s_mid = z00 + 0.5 * (z10 - z00);
        // The six points of Eq. 4 and their coarse heights f' (as in `node_error`).
        let points = [
            (x0 + m, y0, z(south, x0 + m), s_mid),
            (x0 + m, y0 + cells, z(north, x0 + m), z00 + (z01 - z00) + 0.5 * (z11 - z01)),
            (x0, y0 + m, z(middle, x0), z00 + 0.5 * (z01 - z00)),
            (x0 + cells, y0 + m, z(middle, x0 + cells), z00 + (z10 - z00) + 0.5 * (z11 - z10)),
            (x0 + m, y0 + m, z(middle, x0 + m), s_mid + 0.5 * (z11 - z10)),
            (x0 + m, y0 + m, z(middle, x0 + m), s_mid + 0.5 * (z01 - z00)),
        ];
        let mut h = 0.0f64;
        for (i, j, fine, coarse) in points {
            if voids.is_some_and(|v| v.get(i, j)) {
                continue;
            }
            // Eq. 5: delta_n = |f(v_n) - f'(v_n)|.
            h = h.max((fine - coarse).abs());
        }
        *e = h;
    }
}

/// `H` and the monotone `StaticE` (Eq. 3) for every node of a quadtree over a heightmap.
///
/// Level 0 is the root, a square of `root_cells` cells (the smallest power of two covering the
/// grid, at least 2) with its south-west sample at (0, 0); level `l` has `2^l x 2^l` nodes of
/// `root_cells / 2^l` cells, node `(i, j)` at column `i` (east) and row `j` (north). Nodes
/// beyond the grid are clipped as [`node_error`] says. The finest level `l_max = levels - 1`
/// has nodes of at least 2 cells.
///
/// Eq. 3: `StaticE = H` at `l_max`, else `max(H, max StaticE of descendants)`. The paper's
/// max ranges over all descendants at levels `l + 1..=l_max`; as each child's `StaticE` already
/// bounds its own descendants, the bottom-up max over the four children is the same value.
#[derive(Debug, Clone)]
pub struct StaticErrorPyramid {
    root_cells: usize,
    levels: usize,
    h: Vec<Vec<f64>>,
    static_e: Vec<Vec<f64>>,
}

impl StaticErrorPyramid {
    /// Builds the pyramid with `levels` levels, clamped to `1..=log2(root_cells)` (nodes of
    /// fewer than 2 cells have no midpoints); [`StaticErrorPyramid::levels`] says how many.
    pub fn build(hm: &Heightmap, levels: usize) -> Self {
        let span = (hm.width() - 1).max(hm.height() - 1).max(2);
        let root_cells = span.next_power_of_two();
        let max_levels = root_cells.trailing_zeros() as usize;
        let levels = levels.clamp(1, max_levels);
        let mut h = Vec::with_capacity(levels);
        for l in 0..levels {
            let n = 1usize << l;
            let cells = root_cells >> l;
            let mut row = vec![0.0; n * n];
            // Nodes inside the grid (every node of a `2^k + 1` block): `interior_errors`.
            let (inside_x, inside_y) = ((hm.width() - 1) / cells, (hm.height() - 1) / cells);
            for (j, row) in row.chunks_exact_mut(n).enumerate() {
                let inside = if j < inside_y { inside_x.min(n) } else { 0 };
                interior_errors(hm, j * cells, cells, &mut row[..inside]);
                for (i, e) in row.iter_mut().enumerate().skip(inside) {
                    *e = node_error(hm, Region::new(i * cells, j * cells, cells)).error;
                }
            }
            h.push(row);
        }
        // Eq. 3, bottom-up.
        let mut static_e = h.clone();
        for l in (0..levels - 1).rev() {
            let n = 1usize << l;
            for j in 0..n {
                for i in 0..n {
                    let child = |ci: usize, cj: usize| static_e[l + 1][cj * 2 * n + ci];
                    let m = child(2 * i, 2 * j)
                        .max(child(2 * i + 1, 2 * j))
                        .max(child(2 * i, 2 * j + 1))
                        .max(child(2 * i + 1, 2 * j + 1));
                    let e = &mut static_e[l][j * n + i];
                    *e = e.max(m);
                }
            }
        }
        Self { root_cells, levels, h, static_e }
    }

    /// Number of levels actually built.
    pub fn levels(&self) -> usize {
        self.levels
    }

    /// Side of the root node in cells (a power of two).
    pub fn root_cells(&self) -> usize {
        self.root_cells
    }

    /// Nodes per side at `level` (`2^level`).
    #[inline]
    pub fn nodes_per_side(&self, level: usize) -> usize {
        1 << level
    }

    /// The region of node `(i, j)` at `level`.
    pub fn region(&self, level: usize, i: usize, j: usize) -> Region {
        let cells = self.root_cells >> level;
        Region::new(i * cells, j * cells, cells)
    }

    /// `StaticE` (Eq. 3) of node `(i, j)` at `level`. Panics out of range.
    #[inline]
    pub fn get(&self, level: usize, i: usize, j: usize) -> f64 {
        let n = self.nodes_per_side(level);
        assert!(level < self.levels && i < n && j < n, "StaticE index out of range");
        self.static_e[level][j * n + i]
    }

    /// `H` (Eq. 4) of node `(i, j)` at `level`, before the monotone max. Panics out of range.
    pub fn h(&self, level: usize, i: usize, j: usize) -> f64 {
        let n = self.nodes_per_side(level);
        assert!(level < self.levels && i < n && j < n, "H index out of range");
        self.h[level][j * n + i]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::georef::Georef;
    use crate::heightmap::VoidMask;

    #[test]
    fn odd_cells_reduce_to_means_for_even() {
        // A saddle z = (i - 2)(j - 2) on a 5x5 node: corners 4, -4, -4, 4; centre 0.
        let hm = Heightmap::from_fn(5, 5, Georef::local(1.0), |i, j| {
            (i as f32 - 2.0) * (j as f32 - 2.0)
        })
        .unwrap();
        let e = node_error(&hm, Region::new(0, 0, 4));
        // Edges: midpoints 0 vs mean of (4, -4) = 0; centre 0 vs mean of SW-NE (4 + 4) / 2 = 4.
        assert_eq!(e.error, 4.0);
        assert_eq!(e.coverage, Coverage::Measured { samples: 6 });
    }

    #[test]
    fn interior_errors_are_node_errors() {
        // Grids whose nodes are inside (the fast path) and clipped at the east/north border
        // (`node_error`), with and without voids, heights of mixed signs, magnitudes and
        // repeats (zeros of either sign): every `H` is `node_error`'s, bit for bit.
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        let mut interior = 0;
        for (w, h, void_every) in [(33, 33, 0), (33, 33, 7), (40, 27, 0), (29, 65, 5), (9, 9, 3)] {
            let data: Vec<f32> = (0..w * h)
                .map(|_| match next() % 8 {
                    0 => 0.0,
                    1 => -0.0,
                    2 => 1.0,
                    r => (next() % 100_000) as f32 * 0.37 - 18_000.0 * (r as f32 - 3.0),
                })
                .collect();
            let mut voids = VoidMask::new(w, h);
            if void_every > 0 {
                for p in (0..w * h).filter(|p| p % void_every == 0) {
                    voids.set(p % w, p / w, true);
                }
            }
            let hm = Heightmap::new(w, h, data, voids, Georef::local(1.0)).unwrap();
            let pyr = StaticErrorPyramid::build(&hm, 10);
            for l in 0..pyr.levels() {
                let n = pyr.nodes_per_side(l);
                for j in 0..n {
                    for i in 0..n {
                        let r = pyr.region(l, i, j);
                        if r.x0 + r.cells < w && r.y0 + r.cells < h {
                            interior += 1;
                        }
                        let want = node_error(&hm, r).error;
                        assert_eq!(pyr.h(l, i, j).to_bits(), want.to_bits(), "{w}x{h} {l} {i} {j}");
                    }
                }
            }
        }
        // Negative control: the fast path ran (nodes inside the grid), and the check sees a
        // difference where there is one.
        assert!(interior > 500, "{interior} interior nodes");
        let hm = Heightmap::from_fn(9, 9, Georef::local(1.0), |i, j| (i * j) as f32).unwrap();
        let mut other = hm.data().to_vec();
        other[4 * 9 + 4] += 1.0;
        let other = Heightmap::new(9, 9, other, VoidMask::new(9, 9), Georef::local(1.0)).unwrap();
        let h = |hm: &Heightmap| StaticErrorPyramid::build(hm, 3).h(0, 0, 0);
        assert_ne!(h(&hm).to_bits(), h(&other).to_bits());
    }

    #[test]
    fn levels_are_clamped() {
        let hm = Heightmap::from_fn(9, 9, Georef::local(1.0), |_, _| 0.0).unwrap();
        let p = StaticErrorPyramid::build(&hm, 10);
        assert_eq!(p.root_cells(), 8);
        assert_eq!(p.levels(), 3);
        assert_eq!(StaticErrorPyramid::build(&hm, 0).levels(), 1);
    }
}
