//! Right-triangulated irregular network (RTIN) with a guaranteed vertical error.
//!
//! Evans, Kirkpatrick & Townsend 2001 ("Right-triangulated irregular networks", Algorithmica
//! 30): a square of `(2^k + 1)^2` samples is cut along a diagonal into two right isosceles
//! triangles, and a triangle splits by joining its right-angle vertex to the midpoint of its
//! hypotenuse. The error pass follows mapbox/martini (V. Agafonkin 2019); the bound is made to
//! *hold* by checking the mesh it gives:
//!
//! - **The error pass** (Martini's): a triangle's value is the error at its hypotenuse
//!   midpoint alone, against the hypotenuse's mean, made monotone: the stored value at a
//!   midpoint is the max over *both* triangles sharing the hypotenuse (the diamond) of that
//!   error and of their children's stored values (as the monotone static error of the
//!   out-of-core paper, Qiu 2013 Eq. 3). So the value is equal for both triangles of a diamond
//!   and grows up the tree: a triangle splits if and only if its hypotenuse neighbour splits,
//!   and whenever a child would split, so does its parent. This is the RTIN conformity rule:
//!   no T-junctions. One visit per midpoint, level by level (the diamonds of one level are a
//!   regular lattice: square centres and edge midpoints), where a triangle's true maximum
//!   would scan every sample once per level, `2 log2(side)` times.
//! - **The check.** A sample deep inside a big triangle is compared above with its own
//!   parent's hypotenuse only, not with the big triangle's plane, so its true error there can
//!   exceed the bound. Each triangle of the mesh is therefore measured against the true
//!   maximum over every non-void sample of the closed triangle (the interpolation
//!   [`super::verify`] measures with, bit for bit); one that exceeds the bound is forced to
//!   split (its midpoint's value set to must-split, and so the value of every ancestor
//!   diamond, which keeps conformity), and the mesh is extracted again, measuring only the
//!   new triangles, until every triangle is within the bound. Every sample is scanned about
//!   once for the check (the mesh's triangles tile the grid).
//!
//! (The previous version stored each triangle's true maximum in the pass: the same guarantee
//! at `2 log2(side)` scans of every sample, and more triangles, since a child's true error
//! above the bound forced its parent to split even where the parent's own plane was within
//! it.)
//!
//! **Grids that are not `(2^k + 1)^2`**: the hierarchy is laid over the enclosing square of
//! `2^k + 1` samples, `2^k` the smallest power of two `>= max(width, height) - 1` (no samples
//! are invented: there is nothing to pad). Triangles wholly beyond the grid's east or north
//! border are dropped; triangles *crossing* the border carry the sentinel `INFINITY` (always
//! split), so the border is followed exactly by triangles of the coarsest level whose edges
//! align with it (for a border at sample `n`, squares of the largest power of two dividing
//! `n`: a 1201-sample SRTM tile is followed by 16-cell squares, an odd border at cell level).
//! Because edges of this hierarchy are axis-aligned or diagonal and the border is at an
//! integer sample, a crossing triangle always has children, and leaves never cross.

use std::borrow::Cow;

use crate::heightmap::Heightmap;
use crate::mesh::{TriMesh, raster};

/// Sentinel for a triangle that must split whatever the bound (it crosses the grid border).
const MUST_SPLIT: f64 = f64::INFINITY;

/// Whether a triangle with stored value `e` splits at bound `max_error`.
#[inline]
fn splits(e: f64, max_error: f64) -> bool {
    e > max_error || e == MUST_SPLIT
}

/// The per-midpoint monotone error of every RTIN triangle over a heightmap: built once, then
/// meshed at any bound in time proportional to the output plus one check of the samples under
/// it.
#[derive(Debug, Clone)]
pub struct RtinErrors {
    /// Cells of the enclosing square's side (a power of two).
    tile: usize,
    width: usize,
    height: usize,
    /// Stored value at each hypotenuse midpoint, `(tile + 1)^2`, row-major (row 0 south).
    errors: Vec<f64>,
}

/// Where a triangle lies with respect to the grid rectangle `[0, w-1] x [0, h-1]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Place {
    Inside,
    Crossing,
    Outside,
}

fn place(v: [[usize; 2]; 3], width: usize, height: usize) -> Place {
    let min_x = v[0][0].min(v[1][0]).min(v[2][0]);
    let min_y = v[0][1].min(v[1][1]).min(v[2][1]);
    let max_x = v[0][0].max(v[1][0]).max(v[2][0]);
    let max_y = v[0][1].max(v[1][1]).max(v[2][1]);
    // A triangle's interior projects onto the open interval of its bounding box, so the
    // boxes decide: beyond the border, within it, or with interior points on both sides.
    if min_x >= width - 1 || min_y >= height - 1 {
        Place::Outside
    } else if max_x < width && max_y < height {
        Place::Inside
    } else {
        Place::Crossing
    }
}

/// The true maximum vertical error of the closed triangle's non-void samples against its plane
/// (the interpolation [`super::verify`] measures with, bit for bit). Row by row over the
/// heights, and without a division for most samples: a sample is dismissed on `|z d - n|`
/// (`n / d` the interpolated height) with the greedy mesher's margin (1e-14 of the
/// magnitudes, far above the products' rounding), which never dismisses a sample whose exact
/// error exceeds the running maximum; the survivors are measured exactly. So the maximum is
/// the plain scan's, exactly.
fn true_error(hm: &Heightmap, v: [[usize; 2]; 3]) -> f64 {
    let mut g = v.map(|p| [p[0] as i64, p[1] as i64]);
    if raster::orient(g[0], g[1], g[2]) < 0 {
        g.swap(1, 2);
    }
    let z = g.map(|p| f64::from(hm.get(p[0] as usize, p[1] as usize)));
    let voids = hm.voids().any().then(|| hm.voids());
    let df = raster::orient(g[0], g[1], g[2]) as f64;
    let (data, width) = (hm.data(), hm.width());
    let (mut e, mut e_d) = (0.0f64, 0.0f64);
    let all = [i64::MIN, i64::MIN, i64::MAX, i64::MAX];
    raster::for_each_row(g, all, |j, lo, hi, mut wt, dw| {
        let row = j as usize * width;
        for (i, &zs) in (lo..).zip(&data[row + lo as usize..=row + hi as usize]) {
            let n = raster::numerator(wt, z);
            wt = raster::step(wt, dw);
            let zs = f64::from(zs);
            let zd = zs * df;
            if (zd - n).abs() + (zd.abs() + n.abs()) * 1e-14 <= e_d {
                continue;
            }
            if voids.is_some_and(|m| m.get(i as usize, j as usize)) {
                continue;
            }
            let ei = (zs - n / df).abs();
            if ei > e {
                e = ei;
                e_d = e * df;
            }
        }
    });
    e
}

/// What a midpoint `[x, y]` of the hierarchy is, from the lowest set bits of its coordinates
/// (`tile` the enclosing square's side): the centre of a square (both bits equal: the diamond
/// is the square, cut along its diagonal) or the midpoint of a horizontal or vertical edge
/// (the diamond is the two triangles on both sides of the edge); `half` is half the side.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Diamond {
    Centre { half: usize },
    Horizontal { half: usize },
    Vertical { half: usize },
}

fn diamond(p: [usize; 2], tile: usize) -> Diamond {
    // 0 is a multiple of every power of two: its lowest bit counts as above the tile's.
    let low = |v: usize| if v == 0 { 2 * tile } else { 1 << v.trailing_zeros() };
    let (lx, ly) = (low(p[0]), low(p[1]));
    match lx.cmp(&ly) {
        std::cmp::Ordering::Equal => Diamond::Centre { half: lx },
        std::cmp::Ordering::Less => Diamond::Horizontal { half: lx },
        std::cmp::Ordering::Greater => Diamond::Vertical { half: ly },
    }
}

/// The diagonal of the square of centre `m` and half side `half`: from its corner whose
/// coordinates are multiples of twice its side (the corner it shares with its parent square;
/// `[0, 0]` for the whole square) through `m` to the opposite corner.
fn diagonal(m: [usize; 2], half: usize) -> ([usize; 2], [usize; 2]) {
    let corner = |v: usize| if (v - half).is_multiple_of(4 * half) { v - half } else { v + half };
    let k = [corner(m[0]), corner(m[1])];
    (k, [2 * m[0] - k[0], 2 * m[1] - k[1]])
}

fn mid(a: [usize; 2], b: [usize; 2]) -> [usize; 2] {
    [(a[0] + b[0]) / 2, (a[1] + b[1]) / 2]
}

/// Forces the diamond at `m` to split, and every diamond above it (a split needs its parents
/// split: the conformity the monotone pass keeps).
fn force(errors: &mut [f64], tile: usize, m: [usize; 2]) {
    let mut stack = vec![m];
    while let Some(p) = stack.pop() {
        let k = p[1] * (tile + 1) + p[0];
        if errors[k] == MUST_SPLIT {
            continue;
        }
        errors[k] = MUST_SPLIT;
        match diamond(p, tile) {
            // The square's triangles are children of the triangles on the parent square's
            // two edges at the shared corner.
            Diamond::Centre { half } if 2 * half < tile => {
                let (k, _) = diagonal(p, half);
                stack.push([2 * p[0] - k[0], k[1]]);
                stack.push([k[0], 2 * p[1] - k[1]]);
            }
            Diamond::Centre { .. } => {}
            // An edge's triangles are children of the squares' on both sides: across the
            // edge, `y` for a horizontal one, `x` for a vertical one.
            kind @ (Diamond::Horizontal { half } | Diamond::Vertical { half }) => {
                let k = usize::from(matches!(kind, Diamond::Horizontal { .. }));
                for c in [p[k].checked_sub(half), Some(p[k] + half)].into_iter().flatten() {
                    if c <= tile {
                        let mut q = p;
                        q[k] = c;
                        stack.push(q);
                    }
                }
            }
        }
    }
}

impl RtinErrors {
    /// Computes the monotone midpoint error of every triangle: one visit per midpoint, level
    /// by level, finest first (module docs).
    ///
    /// # Panics
    /// If the grid is smaller than 2 x 2 (see [`crate::mesh::validate`]).
    pub fn new(hm: &Heightmap) -> Self {
        let (width, height) = (hm.width(), hm.height());
        assert!(width >= 2 && height >= 2, "an RTIN needs at least 2 x 2 samples");
        let tile = (width - 1).max(height - 1).next_power_of_two();
        let size = tile + 1;
        let mut errors = vec![0.0f64; size * size];
        let at = |p: [usize; 2]| p[1] * size + p[0];
        let (data, voids) = (hm.data(), hm.voids().any().then(|| hm.voids()));
        let z = |p: [usize; 2]| f64::from(data[p[1] * width + p[0]]);
        // A triangle's value (`None` beyond the border): must-split across it; else its
        // midpoint's error against the hypotenuse's mean (0 at a void; `e` keeps it for the
        // diamond's other triangle) and, if it has children (legs over one cell), their
        // stored values.
        // `inside`: the whole diamond is known to be inside the grid (the common case; its
        // triangles' boxes lie within `m` +- `half`), so no triangle needs placing.
        let value = |errors: &[f64],
                     [a, b, c]: [[usize; 2]; 3],
                     e: &mut Option<f64>,
                     children: bool,
                     inside: bool| {
            match if inside { Place::Inside } else { place([a, b, c], width, height) } {
                Place::Outside => None,
                Place::Crossing => Some(MUST_SPLIT),
                Place::Inside => {
                    let m = mid(a, b);
                    let mut v = *e.get_or_insert_with(|| {
                        if voids.is_some_and(|v| v.get(m[0], m[1])) {
                            0.0
                        } else {
                            (z(m) - 0.5 * (z(a) + z(b))).abs()
                        }
                    });
                    if children {
                        v = v.max(errors[at(mid(a, c))]).max(errors[at(mid(b, c))]);
                    }
                    Some(v)
                }
            }
        };
        let mut s = 2;
        while s <= tile {
            let half = s / 2;
            // The edges of side s (children, where half >= 2: the centres of the squares of
            // side s / 2, done in the previous round).
            for u in (0..=tile).step_by(s) {
                for v in (half..tile).step_by(s) {
                    for (a, b) in [([v - half, u], [v + half, u]), ([u, v - half], [u, v + half])] {
                        let m = mid(a, b);
                        // Beyond the grid by `half` or more: every triangle outside, nothing
                        // stored (the enclosing square can be four times the grid).
                        if m[0] >= width - 1 + half || m[1] >= height - 1 + half {
                            continue;
                        }
                        let d = [(b[0] - a[0]) / 2, (b[1] - a[1]) / 2];
                        let sides = [
                            Some([m[0] + d[1], m[1] + d[0]]),
                            m[0].checked_sub(d[1]).zip(m[1].checked_sub(d[0])).map(|(x, y)| [x, y]),
                        ];
                        let inside = m[0] + half < width && m[1] + half < height;
                        let mut e = None;
                        let mut stored = 0.0f64;
                        for c in
                            sides.into_iter().flatten().filter(|c| c[0] <= tile && c[1] <= tile)
                        {
                            if let Some(v) = value(&errors, [a, b, c], &mut e, half >= 2, inside) {
                                stored = stored.max(v);
                            }
                        }
                        errors[at(m)] = stored;
                    }
                }
            }
            // The centres of the squares of side s (children: their edges' midpoints).
            for y in (half..tile.min(height - 1 + half)).step_by(s) {
                for x in (half..tile.min(width - 1 + half)).step_by(s) {
                    let (a, b) = diagonal([x, y], half);
                    let inside = x + half < width && y + half < height;
                    let mut e = None;
                    let mut stored = 0.0f64;
                    for c in [[a[0], b[1]], [b[0], a[1]]] {
                        if let Some(v) = value(&errors, [a, b, c], &mut e, true, inside) {
                            stored = stored.max(v);
                        }
                    }
                    errors[at([x, y])] = stored;
                }
            }
            s *= 2;
        }
        Self { tile, width, height, errors }
    }

    /// The mesh for a bound: the coarsest conforming RTIN whose every kept triangle has a
    /// stored value `<= max_error` (`max_error >= 0`, not NaN; infinite is allowed), with the
    /// triangles whose true error exceeds the bound forced to split (module docs): every
    /// non-void sample is within `max_error` of the mesh.
    pub fn mesh(&self, hm: &Heightmap, max_error: f64) -> TriMesh {
        self.mesh_checked(hm, max_error, true, Cow::Borrowed(&self.errors)).0
    }

    /// [`Self::mesh`] with these stored values (this table's; owned where they may be
    /// changed in place, borrowed and copied on the first forced split otherwise), or without
    /// the check (the tests' negative control), and how many extractions it took.
    fn mesh_checked(
        &self,
        hm: &Heightmap,
        max_error: f64,
        check: bool,
        mut errors: Cow<'_, [f64]>,
    ) -> (TriMesh, usize) {
        assert_eq!((hm.width(), hm.height()), (self.width, self.height), "another grid");
        let t = self.tile;
        let mut leaves = Vec::new();
        let first = Extract { rtin: self, errors: &errors, max_error };
        first.process([[0, 0], [t, t], [t, 0]], &mut leaves);
        first.process([[t, t], [0, 0], [0, t]], &mut leaves);
        // Every leaf is measured once: `checked` leaves are within the bound (a leaf over it
        // is forced to split, so it never stays).
        let mut checked = 0;
        for round in 1.. {
            let over: Vec<[usize; 2]> = if check {
                leaves[checked..]
                    .iter()
                    .map(|&leaf| widen(leaf))
                    .filter(|&[a, b, c]| {
                        a[0].abs_diff(c[0]) + a[1].abs_diff(c[1]) > 1
                            && true_error(hm, [a, b, c]) > max_error
                    })
                    .map(|[a, b, _]| mid(a, b))
                    .collect()
            } else {
                Vec::new()
            };
            if over.is_empty() {
                return (self.assemble(hm, &leaves), round);
            }
            let forced = errors.to_mut();
            for m in over {
                force(forced, t, m);
            }
            // The values only grew, so the new mesh refines the old one: each leaf either
            // stays or is extracted again from itself. The kept ones are checked already.
            let extract = Extract { rtin: self, errors: &errors, max_error };
            let mut split = Vec::new();
            leaves.retain(|&leaf| {
                let leaf = widen(leaf);
                let splits = extract.splits(leaf);
                if splits {
                    extract.process(leaf, &mut split);
                }
                !splits
            });
            checked = leaves.len();
            leaves.append(&mut split);
        }
        unreachable!("every round forces a split, and one-cell triangles never split")
    }

    /// The mesh of the leaves `[a, b, c]` (hypotenuse `a`-`b`), turned counter-clockwise.
    fn assemble(&self, hm: &Heightmap, leaves: &[Leaf]) -> TriMesh {
        let mut index = vec![u32::MAX; self.width * self.height];
        let mut vertices: Vec<[u32; 2]> = Vec::new();
        let mut vertex = |p: [usize; 2]| {
            let k = p[1] * self.width + p[0];
            if index[k] == u32::MAX {
                index[k] = vertices.len() as u32;
                vertices.push([p[0] as u32, p[1] as u32]);
            }
            index[k]
        };
        let triangles = leaves
            .iter()
            .map(|&leaf| {
                let [a, b, c] = widen(leaf);
                let g = [a, b, c].map(|p| [p[0] as i64, p[1] as i64]);
                let mut t = [vertex(a), vertex(b), vertex(c)];
                if raster::orient(g[0], g[1], g[2]) < 0 {
                    t.swap(1, 2);
                }
                t
            })
            .collect();
        TriMesh::from_grid(hm, &vertices, triangles)
    }
}

/// Mesh extraction: the coarsest conforming triangles under a triangle whose stored values
/// are within the bound.
struct Extract<'a> {
    rtin: &'a RtinErrors,
    errors: &'a [f64],
    max_error: f64,
}

impl Extract<'_> {
    /// Whether the triangle `[a, b, c]` (hypotenuse `a`-`b`) splits: its legs are longer
    /// than one cell and its stored value is over the bound.
    #[inline]
    fn splits(&self, [a, b, c]: [[usize; 2]; 3]) -> bool {
        let m = mid(a, b);
        a[0].abs_diff(c[0]) + a[1].abs_diff(c[1]) > 1
            && splits(self.errors[m[1] * (self.rtin.tile + 1) + m[0]], self.max_error)
    }

    fn process(&self, [a, b, c]: [[usize; 2]; 3], out: &mut Vec<Leaf>) {
        if place([a, b, c], self.rtin.width, self.rtin.height) == Place::Outside {
            return;
        }
        if self.splits([a, b, c]) {
            let m = mid(a, b);
            self.process([c, a, m], out);
            self.process([b, c, m], out);
            return;
        }
        debug_assert_eq!(place([a, b, c], self.rtin.width, self.rtin.height), Place::Inside);
        out.push([a, b, c].map(|p| p.map(|v| v as u32)));
    }
}

/// A triangle of the mesh, `[a, b, c]` with the hypotenuse `a`-`b` (grid samples; `u32` to
/// halve the list a round goes over).
type Leaf = [[u32; 2]; 3];

fn widen(leaf: Leaf) -> [[usize; 2]; 3] {
    leaf.map(|p| p.map(|v| v as usize))
}

/// Builds the RTIN mesh of `hm` within `max_error` of every non-void sample.
///
/// # Panics
/// On a grid smaller than 2 x 2 or a negative or NaN bound; [`crate::mesh::build`] checks both.
pub fn build(hm: &Heightmap, max_error: f64) -> TriMesh {
    assert!(max_error >= 0.0, "max_error must be >= 0, got {max_error}");
    let mut rtin = RtinErrors::new(hm);
    // One bound: the forced splits change the stored values in place.
    let errors = std::mem::take(&mut rtin.errors);
    rtin.mesh_checked(hm, max_error, true, Cow::Owned(errors)).0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::HardCase;

    #[test]
    fn flat_is_two_triangles_and_tiny3_splits_for_its_peak() {
        let flat = build(&HardCase::Flat.build(), 0.0);
        assert_eq!(flat.triangles.len(), 2);
        let tiny3 = HardCase::Tiny3.build();
        assert_eq!(build(&tiny3, 1000.0).triangles.len(), 2);
        // The centre (100 m) is the first split; the four border edges are then exact
        // (their midpoints are the means of their ends), so four triangles are exact.
        let fine = build(&tiny3, 0.0);
        assert_eq!(fine.triangles.len(), 4);
    }

    /// Martini's pass as written there (one triangle at a time by its implicit id, its
    /// vertices found by walking the id's bits), with the midpoint error and this module's
    /// border rule: the reference for the level-by-level pass.
    fn martini_errors(hm: &Heightmap) -> Vec<f64> {
        let (width, height) = (hm.width(), hm.height());
        let tile = (width - 1).max(height - 1).next_power_of_two();
        let size = tile + 1;
        let mut errors = vec![0.0f64; size * size];
        let num_smallest = tile * tile;
        let num_triangles = num_smallest * 2 - 2;
        let last_level = num_triangles.saturating_sub(num_smallest);
        let at = |x: usize, y: usize| y * size + x;
        let z = |p: [usize; 2]| f64::from(hm.get(p[0], p[1]));
        for idx in (0..num_triangles).rev() {
            let mut id = idx + 2;
            let (mut a, mut b, mut c) = if id & 1 == 1 {
                ([0, 0], [tile, tile], [tile, 0])
            } else {
                ([tile, tile], [0, 0], [0, tile])
            };
            loop {
                id >>= 1;
                if id <= 1 {
                    break;
                }
                let m = [(a[0] + b[0]) / 2, (a[1] + b[1]) / 2];
                if id & 1 == 1 {
                    (a, b) = (c, a);
                } else {
                    (a, b) = (b, c);
                }
                c = m;
            }
            let m = [(a[0] + b[0]) / 2, (a[1] + b[1]) / 2];
            match place([a, b, c], width, height) {
                Place::Outside => {}
                Place::Crossing => errors[at(m[0], m[1])] = MUST_SPLIT,
                Place::Inside => {
                    let mut e = if hm.voids().get(m[0], m[1]) {
                        0.0
                    } else {
                        (z(m) - 0.5 * (z(a) + z(b))).abs()
                    };
                    if idx < last_level {
                        let left = errors[at((a[0] + c[0]) / 2, (a[1] + c[1]) / 2)];
                        let right = errors[at((b[0] + c[0]) / 2, (b[1] + c[1]) / 2)];
                        e = e.max(left).max(right);
                    }
                    errors[at(m[0], m[1])] = errors[at(m[0], m[1])].max(e);
                }
            }
        }
        errors
    }

    fn grids() -> Vec<(String, Heightmap)> {
        let fractal = |w, h| crate::synth::FractalConfig::with_size(w, h, 10.0).to_heightmap();
        let mut out: Vec<(String, Heightmap)> = [(17, 17), (65, 65), (33, 20), (2, 9), (100, 37)]
            .into_iter()
            .map(|(w, h)| (format!("fractal {w} x {h}"), fractal(w, h).unwrap()))
            .collect();
        out.push(("plateau with voids".into(), HardCase::PlateauWithVoids.build()));
        out.push(("spike".into(), HardCase::Spike.build()));
        out
    }

    #[test]
    fn the_level_pass_equals_martinis_pass_bit_for_bit() {
        for (name, hm) in grids() {
            let ours = RtinErrors::new(&hm).errors;
            let reference = martini_errors(&hm);
            assert_eq!(ours.len(), reference.len(), "{name}");
            for (k, (a, b)) in ours.iter().zip(&reference).enumerate() {
                assert_eq!(a.to_bits(), b.to_bits(), "{name}: midpoint {k}: {a} against {b}");
            }
        }
    }

    /// No T-junction: no vertex lies strictly inside a triangle's edge (the edges are
    /// axis-aligned or diagonal, so the samples along one are its integer steps).
    fn assert_conforming(hm: &Heightmap, mesh: &TriMesh, label: &str) {
        let grid = crate::mesh::grid_vertices(hm, mesh);
        let mut is_vertex = vec![false; hm.width() * hm.height()];
        for g in &grid {
            is_vertex[g[1] as usize * hm.width() + g[0] as usize] = true;
        }
        for t in &mesh.triangles {
            for k in 0..3 {
                let (a, b) = (grid[t[k] as usize], grid[t[(k + 1) % 3] as usize]);
                let n = (b[0] - a[0]).abs().max((b[1] - a[1]).abs());
                let step = [(b[0] - a[0]) / n, (b[1] - a[1]) / n];
                for i in 1..n {
                    let q = [a[0] + i * step[0], a[1] + i * step[1]];
                    assert!(
                        !is_vertex[q[1] as usize * hm.width() + q[0] as usize],
                        "{label}: vertex {q:?} inside the edge {a:?}-{b:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn every_sample_is_within_the_bound_and_the_check_is_what_keeps_it() {
        let (mut forced, mut over_unchecked) = (0, 0);
        for (name, hm) in grids() {
            let rtin = RtinErrors::new(&hm);
            for bound in [0.0, 0.5, 2.0, 8.0, 30.0, 200.0] {
                let (mesh, rounds) =
                    rtin.mesh_checked(&hm, bound, true, Cow::Borrowed(&rtin.errors));
                let stats = crate::mesh::verify::check(&hm, &mesh, bound)
                    .unwrap_or_else(|e| panic!("{name} at {bound} m: {e}"));
                assert!(stats.max_error <= bound, "{name} at {bound} m");
                assert_conforming(&hm, &mesh, &format!("{name} at {bound} m"));
                forced += rounds - 1;
                let (unchecked, _) =
                    rtin.mesh_checked(&hm, bound, false, Cow::Borrowed(&rtin.errors));
                assert_eq!(build(&hm, bound).triangles, mesh.triangles, "{name} at {bound} m");
                let e = crate::mesh::verify::measure(&hm, &unchecked).unwrap().max_error;
                over_unchecked += usize::from(e > bound);
                assert!(unchecked.triangles.len() <= mesh.triangles.len(), "{name} at {bound} m");
            }
        }
        // The negative control: Martini's midpoint error alone leaves samples over the bound,
        // and the check's forced splits are what bring them within it.
        assert!(over_unchecked >= 5, "only {over_unchecked} unchecked meshes over their bound");
        assert!(forced >= 5, "only {forced} extra rounds");
    }

    #[test]
    fn a_crossing_triangle_splits_even_at_an_infinite_bound() {
        // 3 x 2 samples in a 5 x 5 square: the border at x = 2, y = 1 is followed exactly.
        let hm = crate::Heightmap::from_fn(3, 2, crate::Georef::local(1.0), |_, _| 0.0).unwrap();
        let m = build(&hm, f64::INFINITY);
        let area: i64 = m
            .triangles
            .iter()
            .map(|t| {
                let g =
                    t.map(|k| [m.positions[k as usize].x as i64, m.positions[k as usize].y as i64]);
                raster::orient(g[0], g[1], g[2])
            })
            .sum();
        assert_eq!(area, 2 * 2, "twice the 2 x 1 cell area, all counter-clockwise");
    }
}
