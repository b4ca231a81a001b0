//! Greedy insertion into a Delaunay triangulation: the fewest-triangle builder.
//!
//! Garland & Heckbert 1995 ("Fast polygonal approximation of terrains and height fields",
//! CMU-CS-95-181), algorithm III as in hmm (M. Fogleman) and Delatin (V. Agafonkin): start
//! with the grid's four corners (two triangles covering the rectangle), then repeatedly insert
//! the sample with the largest vertical error until no sample's error exceeds the bound.
//!
//! - The triangulation is purpose-built for grid samples (the layout of Delatin and hmm): a
//!   flat array of triangles, three half-edges each (`3t`, `3t + 1`, `3t + 2`) with their
//!   twins, and slots reused in place when triangles are split or flipped. A candidate is
//!   always inside the triangle it was found in, so an insertion needs no point location:
//!   it splits that triangle in three (or the two triangles of an edge the sample lies on)
//!   and restores the Delaunay property by Lawson flips (G&H §4.2). Predicates are exact on
//!   the integer grid coordinates (`i64` orientation, `i128` in-circle).
//! - Each triangle keeps its *candidate*: its worst non-void sample (scan-converted exactly,
//!   see `raster`, the same interpolation [`super::verify`] measures with) and that sample's
//!   error against the triangle's plane. Triangles with a candidate above the bound wait in
//!   an indexed max-heap; a split or flipped triangle leaves it at once, and only the
//!   triangles an insertion (re)wrote are scanned again, once each (G&H §5.2).
//! - Cost: each insertion rescans the triangles around the new vertex, whose area shrinks as
//!   the mesh refines; the heap adds `O(log n)` per candidate. This is G&H's
//!   `O((m + n) log m)` expected behaviour, not `O(n^2)`.
//!
//! spade (a general Delaunay triangulation with point location) was used here before and
//! stays where input points are scattered (terrain-visibility's entropy quadtree); this path
//! only ever inserts grid samples into a known triangle, and the purpose-built structure
//! is several times faster at the same triangles (bench/mesh/README.md).
//!
//! [`build_seeded`] starts from given samples besides the corners and may lock the grid's
//! border (its samples are never inserted by the greedy loop): the TIN pyramids
//! ([`crate::tin::tile`]) fix each tile's border vertices that way, so neighbours agree.
//! Seeds are located by a visibility walk, started from a triangle an earlier seed nearby made
//! (the same triangle as a walk from anywhere, except on an edge between two triangles, where
//! the walk from the newest triangle decides, as it always did).

use crate::heightmap::Heightmap;
use crate::mesh::TriMesh;
use crate::mesh::raster::{self, Line, line_margin};

/// No half-edge / not in the heap.
const NONE: u32 = u32::MAX;

/// `true` when `d` is strictly inside the circumcircle of the counter-clockwise triangle
/// `(a, b, c)` (Guibas & Stolfi's in-circle determinant, exact in `i128`). A coordinate range
/// too large for exact `i128` arithmetic (sides over about 2^30 samples) counts as "not
/// inside": the triangulation is then not strictly Delaunay there, but it stays valid and
/// the error bound, which never depends on the flips, still holds.
fn in_circle(a: [i64; 2], b: [i64; 2], c: [i64; 2], d: [i64; 2]) -> bool {
    // Sides up to 2^14 samples (every tile and the 16385^2 grids): the determinant is at
    // most 12 x (2^14)^4 < 2^63 in magnitude, so plain i64 arithmetic is exact, and far
    // cheaper than checked i128 products.
    const SMALL: i64 = 1 << 14;
    let diffs = [a[0] - d[0], a[1] - d[1], b[0] - d[0], b[1] - d[1], c[0] - d[0], c[1] - d[1]];
    if diffs.iter().all(|k| k.abs() <= SMALL) {
        let [adx, ady, bdx, bdy, cdx, cdy] = diffs;
        let (al, bl, cl) = (adx * adx + ady * ady, bdx * bdx + bdy * bdy, cdx * cdx + cdy * cdy);
        let det = al * (bdx * cdy - cdx * bdy)
            + bl * (cdx * ady - adx * cdy)
            + cl * (adx * bdy - bdx * ady);
        return det > 0;
    }
    in_circle_wide(a, b, c, d)
}

/// [`in_circle`] in checked `i128` arithmetic, for any coordinates.
fn in_circle_wide(a: [i64; 2], b: [i64; 2], c: [i64; 2], d: [i64; 2]) -> bool {
    let f = || -> Option<i128> {
        let (adx, ady) = (i128::from(a[0] - d[0]), i128::from(a[1] - d[1]));
        let (bdx, bdy) = (i128::from(b[0] - d[0]), i128::from(b[1] - d[1]));
        let (cdx, cdy) = (i128::from(c[0] - d[0]), i128::from(c[1] - d[1]));
        let al = adx.checked_mul(adx)?.checked_add(ady.checked_mul(ady)?)?;
        let bl = bdx.checked_mul(bdx)?.checked_add(bdy.checked_mul(bdy)?)?;
        let cl = cdx.checked_mul(cdx)?.checked_add(cdy.checked_mul(cdy)?)?;
        let t0 = al.checked_mul(bdx.checked_mul(cdy)?.checked_sub(cdx.checked_mul(bdy)?)?)?;
        let t1 = bl.checked_mul(cdx.checked_mul(ady)?.checked_sub(adx.checked_mul(cdy)?)?)?;
        let t2 = cl.checked_mul(adx.checked_mul(bdy)?.checked_sub(bdx.checked_mul(ady)?)?)?;
        t0.checked_add(t1)?.checked_add(t2)
    };
    f().is_some_and(|det| det > 0)
}

/// Next half-edge of the same triangle.
#[inline]
fn next(e: u32) -> u32 {
    if e % 3 == 2 { e - 2 } else { e + 1 }
}

/// Previous half-edge of the same triangle.
#[inline]
fn prev(e: u32) -> u32 {
    if e.is_multiple_of(3) { e + 2 } else { e - 1 }
}

/// A heap entry (16 bytes): a triangle slot and its candidate's error and sample index
/// `j * width + i` (below 2^32: [`crate::mesh::validate`] bounds the grid).
#[derive(Debug, Clone, Copy)]
struct Entry {
    error: f64,
    key: u32,
    slot: u32,
}

impl Entry {
    /// Heap order: larger error first, then the smaller sample (a total order, so ties
    /// never depend on the heap's layout).
    #[inline]
    fn above(&self, other: &Self) -> bool {
        self.error > other.error || (self.error == other.error && self.key < other.key)
    }
}

/// Samples a scan dismisses together (see [`Mesher::scan`]).
const LANES: usize = 4;

/// A scan's worst sample so far: its error, where, and the error times the scanned
/// triangle's `d` (the dismissal threshold).
struct Best {
    error: f64,
    at: Option<[u32; 2]>,
    scaled: f64,
}

/// `Slot::cand` of a triangle waiting to be scanned.
const PENDING: u32 = u32::MAX;

/// A triangle (32 bytes: what an insertion touches of one triangle is one cache line).
#[derive(Debug, Clone, Copy)]
#[repr(C, align(32))]
struct Slot {
    /// Its half-edges `3t + k`, counter-clockwise, as `[vertex, twin]`: half-edge `e` runs
    /// from its vertex to the next one's, its twin `NONE` on the grid's border.
    he: [[u32; 2]; 3],
    /// Its candidate's sample index `j * width + i` while in the heap; `PENDING` while
    /// waiting for a scan.
    cand: u32,
}

/// A vertex (16 bytes: its grid sample and height share a cache line).
#[derive(Debug, Clone, Copy)]
struct Vertex {
    /// Grid sample `[i, j]`.
    at: [u32; 2],
    /// The sample's height.
    z: f64,
}

impl Vertex {
    #[inline]
    fn grid(&self) -> [i64; 2] {
        self.at.map(i64::from)
    }
}

/// Where seed walks start: per square of `HINT_CELL` x `HINT_CELL` samples, and of 4 and 16
/// times that, a triangle slot made by the last seed inserted there (`NONE`: none yet); a
/// seed starts from its finest square's that has one. Slots are reused in place, never
/// freed, so any recorded slot is some triangle of the mesh, usually one near the square:
/// a good start, and only a start (the walk decides where a seed goes).
#[derive(Default)]
struct Hints {
    /// Per level (squares of `HINT_CELL << 2k` samples): its columns and its squares.
    levels: Vec<(usize, Vec<u32>)>,
}

/// Samples on a side of a finest [`Hints`] square.
const HINT_CELL: usize = 8;

impl Hints {
    /// Hints over a `width x height` grid.
    fn new(width: usize, height: usize) -> Self {
        let levels = (0..3)
            .map(|k| {
                let cell = HINT_CELL << (2 * k);
                let columns = width.div_ceil(cell);
                (columns, vec![NONE; columns * height.div_ceil(cell)])
            })
            .collect();
        Self { levels }
    }

    /// `p`'s square at level `k`.
    #[inline]
    fn index(columns: usize, k: usize, p: [i64; 2]) -> usize {
        let cell = HINT_CELL << (2 * k);
        p[1] as usize / cell * columns + p[0] as usize / cell
    }

    /// The slot recorded for `p`'s finest square that has one (`NONE`: none, or no hints).
    fn get(&self, p: [i64; 2]) -> u32 {
        for (k, (columns, cells)) in self.levels.iter().enumerate() {
            let t = cells.get(Self::index(*columns, k, p)).copied().unwrap_or(NONE);
            if t != NONE {
                return t;
            }
        }
        NONE
    }

    fn set(&mut self, p: [i64; 2], t: u32) {
        for (k, (columns, cells)) in self.levels.iter_mut().enumerate() {
            if let Some(c) = cells.get_mut(Self::index(*columns, k, p)) {
                *c = t;
            }
        }
    }
}

/// The greedy mesher's state.
struct Mesher<'a> {
    hm: &'a Heightmap,
    max_error: f64,
    lock_border: bool,
    /// The vertices, in insertion order.
    verts: Vec<Vertex>,
    /// The triangles.
    slots: Vec<Slot>,
    /// Each slot's position in the heap (`NONE`: not there). Apart from the slots: heap
    /// sifts write it for slots far apart, and 4 bytes a slot keep more of it in cache.
    heap_pos: Vec<u32>,
    /// Indexed binary max-heap of the slots with a candidate above the bound; the keys live
    /// in the entries, so sifting reads one contiguous array.
    heap: Vec<Entry>,
    /// Slots (re)written by the current insertion, each once, scanned after it.
    pending: Vec<u32>,
    /// Half-edges waiting for the Delaunay test (a stack: depth first, as recursion).
    legalize: Vec<u32>,
    /// Where seed walks start (empty without seeds).
    hints: Hints,
    /// Steps the seeds' walks took (the tests read it).
    walk_steps: u64,
    /// The scan's line test margin per unit of `d` ([`raster::line_margin`]).
    line_margin: f64,
}

impl<'a> Mesher<'a> {
    fn new(hm: &'a Heightmap, max_error: f64, lock_border: bool) -> Self {
        let (w, h) = (hm.width() as i64, hm.height() as i64);
        let mut m = Self {
            hm,
            max_error,
            lock_border,
            verts: Vec::new(),
            slots: Vec::new(),
            heap_pos: Vec::new(),
            heap: Vec::new(),
            pending: Vec::new(),
            legalize: Vec::new(),
            hints: Hints::default(),
            walk_steps: 0,
            line_margin: line_margin(raster::largest_magnitude_of(hm)),
        };
        for p in [[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]] {
            m.add_vertex(p);
        }
        // Two counter-clockwise triangles sharing the diagonal 0-2 (as hmm and Delatin).
        let t0 = m.new_slot();
        let t1 = m.new_slot();
        m.set_triangle(t0, [0, 1, 2], [NONE, NONE, NONE]);
        m.set_triangle(t1, [0, 2, 3], [3 * t0 + 2, NONE, NONE]);
        m
    }

    fn add_vertex(&mut self, p: [i64; 2]) -> u32 {
        let k = self.verts.len() as u32;
        let z = f64::from(self.hm.get(p[0] as usize, p[1] as usize));
        self.verts.push(Vertex { at: [p[0] as u32, p[1] as u32], z });
        k
    }

    fn new_slot(&mut self) -> u32 {
        let t = self.slots.len() as u32;
        self.slots.push(Slot { he: [[0, NONE]; 3], cand: 0 });
        self.heap_pos.push(NONE);
        t
    }

    /// Writes triangle `t` (counter-clockwise vertices `v`, half-edge twins `tw`; the twins'
    /// own links are set too), takes it out of the heap and marks it for scanning.
    fn set_triangle(&mut self, t: u32, v: [u32; 3], tw: [u32; 3]) {
        let e = 3 * t as usize;
        for (k, (&vk, &twin)) in v.iter().zip(&tw).enumerate() {
            self.slots[t as usize].he[k] = [vk, twin];
            if twin != NONE {
                let (s, j) = (twin as usize / 3, twin as usize % 3);
                self.slots[s].he[j][1] = (e + k) as u32;
            }
        }
        self.heap_remove(t);
        if self.slots[t as usize].cand != PENDING {
            self.slots[t as usize].cand = PENDING;
            self.pending.push(t);
        }
    }

    /// Half-edge `e`: `[vertex, twin]`.
    #[inline]
    fn he(&self, e: usize) -> [u32; 2] {
        self.slots[e / 3].he[e % 3]
    }

    #[inline]
    fn at(&self, e: u32) -> [i64; 2] {
        self.verts[self.he(e as usize)[0] as usize].grid()
    }

    /// Inserts grid sample `p` inside (or on an edge of) triangle `t`, not at a vertex, and
    /// legalizes; the triangles it wrote wait in `pending` for [`Self::flush`].
    fn insert(&mut self, t: u32, p: [i64; 2]) {
        let e = 3 * t;
        let [a, b, c] = [self.at(e), self.at(e + 1), self.at(e + 2)];
        let pn = self.add_vertex(p);
        if raster::orient(a, b, p) == 0 {
            self.split_edge(pn, e);
        } else if raster::orient(b, c, p) == 0 {
            self.split_edge(pn, e + 1);
        } else if raster::orient(c, a, p) == 0 {
            self.split_edge(pn, e + 2);
        } else {
            let [va, vb, vc] = [e, e + 1, e + 2].map(|k| self.he(k as usize)[0]);
            let [ha, hb, hc] = [e, e + 1, e + 2].map(|k| self.he(k as usize)[1]);
            let t1 = self.new_slot();
            let t2 = self.new_slot();
            // (a, b, p), (b, c, p), (c, a, p): edge 0 of each is an old edge, opposite p.
            self.set_triangle(t, [va, vb, pn], [ha, NONE, NONE]);
            self.set_triangle(t1, [vb, vc, pn], [hb, NONE, 3 * t + 1]);
            self.set_triangle(t2, [vc, va, pn], [hc, 3 * t + 2, 3 * t1 + 1]);
            self.legalize.extend([3 * t2, 3 * t1, 3 * t]);
        }
        self.run_legalize();
    }

    /// Splits half-edge `e` (from u to v in triangle (u, v, x)) at the new vertex `pn` on
    /// it, and its twin's triangle (v, u, y) when there is one.
    fn split_edge(&mut self, pn: u32, e: u32) {
        let t = e / 3;
        let (en, ep) = (next(e), prev(e));
        let [u, v, x] = [e, en, ep].map(|k| self.he(k as usize)[0]);
        let (h_vx, h_xu) = (self.he(en as usize)[1], self.he(ep as usize)[1]);
        let b = self.he(e as usize)[1];
        let t1 = self.new_slot();
        if b == NONE {
            // (x, u, p) and (v, x, p); u-p and p-v lie on the grid's border.
            self.set_triangle(t, [x, u, pn], [h_xu, NONE, NONE]);
            self.set_triangle(t1, [v, x, pn], [h_vx, 3 * t + 2, NONE]);
            self.legalize.extend([3 * t1, 3 * t]);
            return;
        }
        let s = b / 3;
        let (bn, bp) = (next(b), prev(b));
        let y = self.he(bp as usize)[0];
        let (h_uy, h_yv) = (self.he(bn as usize)[1], self.he(bp as usize)[1]);
        let t3 = self.new_slot();
        // (x, u, p), (v, x, p), (u, y, p), (y, v, p).
        self.set_triangle(t, [x, u, pn], [h_xu, NONE, NONE]);
        self.set_triangle(t1, [v, x, pn], [h_vx, 3 * t + 2, NONE]);
        self.set_triangle(s, [u, y, pn], [h_uy, NONE, 3 * t + 1]);
        self.set_triangle(t3, [y, v, pn], [h_yv, 3 * t1 + 2, 3 * s + 1]);
        self.legalize.extend([3 * t3, 3 * s, 3 * t1, 3 * t]);
    }

    /// Lawson flips: half-edge `a` (u to v) of a triangle (u, v, p) whose apex p is the new
    /// vertex is flipped when the apex y across it lies inside the circumcircle.
    fn run_legalize(&mut self) {
        while let Some(a) = self.legalize.pop() {
            let b = self.he(a as usize)[1];
            if b == NONE {
                continue;
            }
            let (an, ap, bn, bp) = (next(a), prev(a), next(b), prev(b));
            let [u, v, x, y] = [a, an, ap, bp].map(|k| self.he(k as usize)[0]);
            let c = |k: u32| self.verts[k as usize].grid();
            if !in_circle(c(u), c(v), c(x), c(y)) {
                continue;
            }
            let [h_vx, h_xu, h_uy, h_yv] = [an, ap, bn, bp].map(|k| self.he(k as usize)[1]);
            let (s, s2) = (a / 3, b / 3);
            // (x, u, y) and (y, v, x): the new diagonal x-y.
            self.set_triangle(s, [x, u, y], [h_xu, h_uy, NONE]);
            self.set_triangle(s2, [y, v, x], [h_yv, h_vx, 3 * s + 2]);
            self.legalize.extend([3 * s2, 3 * s + 1]);
        }
    }

    /// Scans every pending triangle and queues those with a sample above the bound.
    fn flush(&mut self) {
        let mut pending = std::mem::take(&mut self.pending);
        for &t in &pending {
            self.slots[t as usize].cand = 0;
            self.scan(t);
        }
        pending.clear();
        self.pending = pending;
    }

    /// Finds triangle `t`'s worst sample and queues it when above the bound.
    fn scan(&mut self, t: u32) {
        let e = 3 * t as usize;
        let vi = [self.he(e)[0], self.he(e + 1)[0], self.he(e + 2)[0]];
        let v = vi.map(|k| self.verts[k as usize]);
        let (g, z) = (v.map(|v| v.grid()), v.map(|v| v.z));
        // A triangle of doubled area 1 holds no sample but its vertices (Pick's theorem:
        // area = interior + boundary / 2 - 1 with at least its 3 vertices on the boundary, so
        // 1/2 leaves no other), and a vertex is never a candidate: nothing to scan. Nearly a
        // fifth of a finely meshed tile's triangles (a quarter of the samples kept) are such.
        let d = raster::orient(g[0], g[1], g[2]);
        if d == 1 {
            return;
        }
        let hm = self.hm;
        let (w, h) = (hm.width() as i64, hm.height() as i64);
        let voids = hm.voids().any().then(|| hm.voids());
        let lock = self.lock_border;
        let mut best = Best { error: self.max_error, at: None, scaled: 0.0 };
        // The sample's error is |z - n / d| (n the interpolation's numerator, exactly as
        // `verify` computes it). Most samples are far below the running best: they are
        // dismissed on |z d - n| without a division, with a margin (1e-14 of the magnitudes,
        // far above the products' rounding) that never dismisses a sample the exact test
        // would keep; the survivors are decided on the exact value. Void samples are never
        // candidates: they are dropped among the survivors only (a void's height may be
        // NaN, which no dismissal test passes), the same outcome as before the test.
        let df = d as f64;
        best.scaled = best.error * df;
        // A locked border leaves exactly the samples off the border: a clip, not a test.
        let clip =
            if lock { [1, 1, w - 2, h - 2] } else { [i64::MIN, i64::MIN, i64::MAX, i64::MAX] };
        let (data, width) = (hm.data(), hm.width());
        // One sample's full test, in row order: the dismissal, then the void and the exact
        // error (`n` its numerator, `zd` its height times d).
        let exact = |best: &mut Best, i: i64, j: i64, zs: f64, n: f64, zd: f64| {
            if (zd - n).abs() + (zd.abs() + n.abs()) * 1e-14 <= best.scaled {
                return;
            }
            if voids.is_some_and(|m| m.get(i as usize, j as usize)) {
                return;
            }
            let e = (zs - n / df).abs();
            // A vertex's own sample is never a candidate (its error is rounding alone).
            if e > best.error && !g.contains(&[i, j]) {
                *best = Best { error: e, at: Some([i as u32, j as u32]), scaled: e * df };
            }
        };
        // The first test of every sample is cheaper still: along a row the numerator is
        // linear, `n(lo + k) = n(lo) + k dn`, so it is taken as that line (one product and
        // one sum a sample, where the weights' three products and their stepping cost
        // five). The line differs from the exact numerator by rounding only, at most
        // `line_margin(H) x d` with `H` the largest height magnitude of the grid (see
        // [`line_margin`]), so a sample the line leaves that much below the threshold is one
        // the exact test would dismiss too: only those are dismissed on it, and every other
        // sample takes the exact test as before, in order. The outcome is the same.
        let line_margin = self.line_margin * df;
        // The change per sample east is the triangle's: `dw` is the same on every row.
        let slope = raster::numerator(raster::weights_east(g), z);
        raster::for_each_row(g, clip, |j, lo, hi, wt, dw| {
            let row = j as usize * width;
            let heights = &data[row + lo as usize..=row + hi as usize];
            let line = Line { at_lo: raster::numerator(wt, z), slope };
            // The weights `lo + k` samples east: exact integers, so `wt + k dw` equals the
            // weights stepped `k` times bit for bit.
            let weights = |k: f64| [wt[0] + k * dw[0], wt[1] + k * dw[1], wt[2] + k * dw[2]];
            let mut cut = best.scaled - line_margin;
            // Runs of `LANES` samples are dismissed together on the line against the running
            // best at the run's start, which is at most the best at any of its samples: a run
            // that cannot hold a candidate is skipped whole; any other run has every sample
            // tested exactly, in order.
            let mut chunks = heights.chunks_exact(LANES);
            let mut k0 = 0.0;
            for run in &mut chunks {
                let mut dismissed = [false; LANES];
                for k in 0..LANES {
                    // (A NaN height is never dismissed: its run is tested one by one.)
                    dismissed[k] = line.dismisses(run[k], k0 + k as f64, df, cut);
                }
                if !dismissed.iter().all(|&d| d) {
                    for (k, &zs) in run.iter().enumerate() {
                        let at = k0 + k as f64;
                        let n = raster::numerator(weights(at), z);
                        let zs = f64::from(zs);
                        exact(&mut best, lo + at as i64, j, zs, n, zs * df);
                    }
                    cut = best.scaled - line_margin;
                }
                k0 += LANES as f64;
            }
            for &zs in chunks.remainder() {
                if !line.dismisses(zs, k0, df, cut) {
                    let zs = f64::from(zs);
                    let n = raster::numerator(weights(k0), z);
                    exact(&mut best, lo + k0 as i64, j, zs, n, zs * df);
                    cut = best.scaled - line_margin;
                }
                k0 += 1.0;
            }
        });
        if let Best { error, at: Some(sample), .. } = best {
            let key = sample[1] * self.hm.width() as u32 + sample[0];
            self.slots[t as usize].cand = key;
            self.heap_push(Entry { error, key, slot: t });
        }
    }

    /// Puts `entry` at heap position `i` and records it.
    #[inline]
    fn heap_set(&mut self, i: usize, entry: Entry) {
        self.heap[i] = entry;
        self.heap_pos[entry.slot as usize] = i as u32;
    }

    /// Moves the entry at `i` up to its place. The entries it passes move down one level
    /// each and it is written once, at the end: the layout a swap at each level gives.
    fn sift_up(&mut self, mut i: usize) {
        let entry = self.heap[i];
        while i > 0 {
            let parent = (i - 1) / 2;
            if !entry.above(&self.heap[parent]) {
                break;
            }
            self.heap_set(i, self.heap[parent]);
            i = parent;
        }
        self.heap_set(i, entry);
    }

    /// Moves the entry at `i` down to its place (as [`Self::sift_up`], one write a level).
    fn sift_down(&mut self, mut i: usize) {
        let n = self.heap.len();
        let entry = self.heap[i];
        loop {
            let (l, r) = (2 * i + 1, 2 * i + 2);
            let mut top = i;
            let mut top_entry = entry;
            if l < n && self.heap[l].above(&top_entry) {
                (top, top_entry) = (l, self.heap[l]);
            }
            if r < n && self.heap[r].above(&top_entry) {
                (top, top_entry) = (r, self.heap[r]);
            }
            if top == i {
                break;
            }
            self.heap_set(i, top_entry);
            i = top;
        }
        self.heap_set(i, entry);
    }

    fn heap_push(&mut self, entry: Entry) {
        self.heap_pos[entry.slot as usize] = self.heap.len() as u32;
        self.heap.push(entry);
        self.sift_up(self.heap.len() - 1);
    }

    fn heap_remove(&mut self, t: u32) {
        let i = self.heap_pos[t as usize];
        if i == NONE {
            return;
        }
        self.heap_pos[t as usize] = NONE;
        // The last entry fills the hole (as swapping it there and popping).
        let Some(last) = self.heap.pop() else { return };
        let i = i as usize;
        if i < self.heap.len() {
            self.heap_set(i, last);
            self.sift_down(i);
            self.sift_up(i);
        }
    }

    /// Inserts a seed sample, located by a visibility walk; a sample that is already a
    /// vertex is skipped.
    ///
    /// The walk starts from a triangle made by an earlier seed near `p` ([`Hints`]), a few
    /// steps away, where the first walk (from the newest triangle) crossed the whole mesh.
    /// Where `p` is strictly inside the triangle found, on the grid's border or at a vertex,
    /// that triangle is the only one the walk from any start could end in (the only closed
    /// triangle holding `p`, or an insertion that does nothing), so the mesh is the same;
    /// on an edge between two triangles the walk from the newest triangle decides which, as
    /// it did before.
    fn insert_seed(&mut self, p: [i64; 2]) {
        let triangles = self.slots.len() as u32;
        let hint = self.hints.get(p);
        if hint != NONE
            && let Some(t) = self.walk(hint, p)
            && self.only_holder(t, p)
        {
            self.insert_located(t, p);
            self.hints.set(p, t);
            return;
        }
        if let Some(t) = self.walk(triangles - 1, p) {
            self.insert_located(t, p);
            self.hints.set(p, t);
            return;
        }
        // Outside the hull (cannot happen for a sample of the grid) or a walk that does not
        // end (cannot happen in a Delaunay triangulation): search.
        for t in 0..triangles {
            let e = 3 * t;
            if (e..e + 3).all(|k| raster::orient(self.at(k), self.at(next(k)), p) >= 0) {
                self.insert_located(t, p);
                self.hints.set(p, t);
                return;
            }
        }
    }

    /// The visibility walk from triangle `t` to a triangle whose closure holds `p` (it leaves
    /// by the first edge, in order, that has `p` strictly on its outside); `None` where it
    /// would leave the hull or takes more steps than there are triangles.
    fn walk(&mut self, mut t: u32, p: [i64; 2]) -> Option<u32> {
        let triangles = self.slots.len() as u32;
        let mut steps = 0u32;
        'walk: loop {
            let e = 3 * t;
            for k in e..e + 3 {
                if raster::orient(self.at(k), self.at(next(k)), p) < 0 {
                    let twin = self.he(k as usize)[1];
                    if twin == NONE || steps > triangles {
                        return None;
                    }
                    t = twin / 3;
                    steps += 1;
                    self.walk_steps += 1;
                    continue 'walk;
                }
            }
            return Some(t);
        }
    }

    /// Whether `p`, in the closed triangle `t`, is in no other triangle's interior or
    /// interior edge: strictly inside `t`, at one of its vertices, or on a border edge.
    fn only_holder(&self, t: u32, p: [i64; 2]) -> bool {
        let e = 3 * t;
        (e..e + 3).all(|k| {
            self.at(k) == p
                || self.at(next(k)) == p
                || raster::orient(self.at(k), self.at(next(k)), p) > 0
                || self.he(k as usize)[1] == NONE
        })
    }

    fn insert_located(&mut self, t: u32, p: [i64; 2]) {
        let e = 3 * t;
        if (e..e + 3).any(|k| self.at(k) == p) {
            return;
        }
        self.insert(t, p);
    }

    /// Inserts candidates until none is above the bound.
    fn run(&mut self) {
        self.flush();
        let w = self.hm.width() as u32;
        while let Some(&Entry { slot: t, key, .. }) = self.heap.first() {
            let (i, j) = (key % w, key / w);
            self.insert(t, [i64::from(i), i64::from(j)]);
            self.flush();
        }
    }

    fn into_mesh(self) -> TriMesh {
        let vertices: Vec<[u32; 2]> = self.verts.iter().map(|v| v.at).collect();
        let triangles = self.slots.iter().map(|t| t.he.map(|h| h[0])).collect();
        TriMesh::from_grid(self.hm, &vertices, triangles)
    }
}

/// Builds the greedy Delaunay mesh of `hm` within `max_error` of every non-void sample.
///
/// # Panics
/// On a grid smaller than 2 x 2 or too large for `u32` indices, or a negative or NaN bound;
/// [`crate::mesh::build`] checks them.
pub fn build(hm: &Heightmap, max_error: f64) -> TriMesh {
    build_seeded(hm, max_error, &[], false)
}

/// [`build`] starting from the grid's corners and `seeds` (grid samples `[i, j]`, inserted in
/// order; outside the grid they are skipped); with `lock_border`, samples on the grid's
/// border are never candidates, so the border's vertices are the corners and the seeds on
/// it. The bound then holds on the border only if the seeds there keep it (the caller's
/// verification checks it).
///
/// # Panics
/// As [`build`].
pub fn build_seeded(
    hm: &Heightmap,
    max_error: f64,
    seeds: &[[u32; 2]],
    lock_border: bool,
) -> TriMesh {
    assert!(max_error >= 0.0, "max_error must be >= 0, got {max_error}");
    let (w, h) = (hm.width(), hm.height());
    assert!(w >= 2 && h >= 2, "a mesh needs at least 2 x 2 samples");
    assert!(
        (w as u64) * (h as u64) <= u64::from(u32::MAX),
        "the grid is too large for u32 indices"
    );
    seeded_mesher(hm, max_error, seeds, lock_border, true).into_mesh()
}

/// [`build_seeded`]'s mesher after its run; `hinted: false` starts every seed's walk from the
/// newest triangle (the tests compare the two).
fn seeded_mesher<'a>(
    hm: &'a Heightmap,
    max_error: f64,
    seeds: &[[u32; 2]],
    lock_border: bool,
    hinted: bool,
) -> Mesher<'a> {
    let (w, h) = (hm.width(), hm.height());
    let mut m = Mesher::new(hm, max_error, lock_border);
    if hinted && !seeds.is_empty() {
        m.hints = Hints::new(w, h);
    }
    // Seeds first, without scanning: the scan after the last seed covers every triangle.
    for &[i, j] in seeds {
        if (i as usize) < w && (j as usize) < h {
            m.insert_seed([i64::from(i), i64::from(j)]);
        }
    }
    m.run();
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::HardCase;

    #[test]
    fn flat_is_two_triangles_and_the_spike_is_isolated_exactly() {
        assert_eq!(build(&HardCase::Flat.build(), 0.0).triangles.len(), 2);
        // Exact: the spike and a small ring of zero samples around it isolate the peak.
        let spike = build(&HardCase::Spike.build(), 0.0);
        assert!(spike.triangles.len() <= 24, "{} triangles", spike.triangles.len());
        assert!(spike.positions.iter().any(|p| p.z == f64::from(HardCase::SPIKE_HEIGHT)));
    }

    use crate::georef::Georef;
    use crate::heightmap::VoidMask;
    use crate::mesh::verify;

    /// A rough deterministic surface (no library code in common with the mesher).
    fn rough(i: usize, j: usize) -> f32 {
        let (x, y) = (i as f64, j as f64);
        ((x * 0.37).sin() * 20.0 + (y * 0.23).cos() * 15.0 + (x * y * 0.011).sin() * 9.0) as f32
    }

    /// Every interior edge is locally Delaunay: the apex across it is not strictly inside the
    /// circumcircle (the exact determinant, evaluated here on the output mesh).
    fn assert_delaunay(hm: &Heightmap, m: &TriMesh) {
        let g = crate::mesh::grid_vertices(hm, m);
        let mut apex = std::collections::HashMap::new();
        for t in &m.triangles {
            for k in 0..3 {
                apex.insert((t[k], t[(k + 1) % 3]), t[(k + 2) % 3]);
            }
        }
        for (&(u, v), &x) in &apex {
            if let Some(&y) = apex.get(&(v, u)) {
                let [a, b, c, d] = [u, v, x, y].map(|k| g[k as usize]);
                assert!(!in_circle(a, b, c, d), "edge {a:?}-{b:?}: {d:?} inside");
            }
        }
    }

    #[test]
    fn tiny_flat_and_constant_grids_need_two_triangles_exactly() {
        let georef = Georef::local(10.0);
        let tiny =
            Heightmap::from_fn(2, 2, georef.clone(), |i, j| [3.0, -7.5, 12.25, 0.5][2 * j + i])
                .unwrap();
        let constant = Heightmap::from_fn(50, 37, georef, |_, _| 1000.5).unwrap();
        for hm in [&tiny, &constant] {
            for bound in [0.0, 1.0, f64::INFINITY] {
                let m = build(hm, bound);
                assert_eq!(m.triangles.len(), 2);
                assert_eq!(verify::check(hm, &m, bound).unwrap().max_error, 0.0);
            }
        }
    }

    #[test]
    fn voids_holding_nan_are_never_vertices_and_the_bound_holds_around_them() {
        let (w, h) = (61, 47);
        let mut voids = VoidMask::new(w, h);
        let mut data = Vec::new();
        for j in 0..h {
            for i in 0..w {
                // A void disc and a void stripe touching the south border, holding NaN.
                let void =
                    (i as i64 - 30).pow(2) + (j as i64 - 20).pow(2) < 64 || (i == 7 && j < 12);
                voids.set(i, j, void);
                data.push(if void { f32::NAN } else { rough(i, j) });
            }
        }
        let hm = Heightmap::new(w, h, data, voids, Georef::local(5.0)).unwrap();
        for bound in [0.0, 0.5, 4.0] {
            let m = build(&hm, bound);
            let stats = verify::check(&hm, &m, bound).unwrap();
            assert!(stats.max_error <= bound, "{bound}: {}", stats.max_error);
            assert!(m.positions.iter().all(|p| p.z.is_finite()), "a void sample became a vertex");
            assert_delaunay(&hm, &m);
        }
        // Negative control: the same grid without the voids needs the disc's samples.
        let filled = Heightmap::from_fn(w, h, Georef::local(5.0), rough).unwrap();
        assert!(build(&filled, 0.5).triangles.len() > build(&hm, 0.5).triangles.len());
    }

    #[test]
    fn meshes_are_deterministic_delaunay_and_seeds_lock_the_border() {
        let hm = Heightmap::from_fn(97, 65, Georef::local(2.0), rough).unwrap();
        let seeds = [[40, 0], [96, 30], [0, 20], [10, 64], [96, 30], [33, 33], [500, 3]];
        for bound in [0.25, 2.0] {
            let a = build_seeded(&hm, bound, &seeds, true);
            assert_eq!(a, build_seeded(&hm, bound, &seeds, true), "not deterministic at {bound}");
            assert_eq!(build(&hm, bound), build(&hm, bound));
            assert_delaunay(&hm, &a);
            assert_delaunay(&hm, &build(&hm, bound));
            // The border's vertices are the corners and the in-grid border seeds, nothing else.
            let mut border: Vec<[i64; 2]> = a
                .positions
                .iter()
                .map(|p| [(p.x / 2.0).round() as i64, (p.y / 2.0).round() as i64])
                .filter(|&[i, j]| i == 0 || j == 0 || i == 96 || j == 64)
                .collect();
            border.sort_unstable();
            let want = [[0, 0], [0, 20], [0, 64], [10, 64], [40, 0], [96, 0], [96, 30], [96, 64]];
            assert_eq!(border, want, "at {bound}");
            assert!(a.positions.iter().any(|p| p.x == 66.0 && p.y == 66.0), "interior seed");
            // The interior keeps the bound (the border is the seeds' business).
            let stats = verify::measure(&hm, &a).unwrap();
            let unlocked = verify::check(&hm, &build(&hm, bound), bound).unwrap();
            assert!(unlocked.max_error <= bound);
            assert!(stats.samples == unlocked.samples);
        }
    }

    #[test]
    fn seed_walks_from_hints_build_the_same_meshes_in_fewer_steps() {
        // Seeds as the tiles give them (a coarser mesh's vertices, in its insertion order),
        // plus samples on the first diagonal and on a grid line, which fall on interior edges
        // (where the walk from the newest triangle decides): the same mesh with and without
        // hints, and the hints must shorten the walks (or they were not used).
        let hm = Heightmap::from_fn(129, 97, Georef::local(1.0), rough).unwrap();
        let coarse = build(&hm, 6.0);
        let mut seeds: Vec<[u32; 2]> =
            coarse.positions.iter().map(|p| [p.x.round() as u32, p.y.round() as u32]).collect();
        seeds.extend((0..33).map(|k| [4 * k, 3 * k]));
        seeds.extend((0..129).step_by(5).map(|i| [i, 40]));
        assert!(seeds.len() > 200, "{} seeds", seeds.len());
        for (bound, lock) in [(0.5, false), (2.0, true), (f64::INFINITY, false)] {
            let hinted = seeded_mesher(&hm, bound, &seeds, lock, true);
            let plain = seeded_mesher(&hm, bound, &seeds, lock, false);
            assert!(
                2 * hinted.walk_steps < plain.walk_steps,
                "{} steps with hints, {} without",
                hinted.walk_steps,
                plain.walk_steps
            );
            assert_eq!(hinted.into_mesh(), plain.into_mesh(), "at {bound}, locked {lock}");
        }
    }

    /// A rough surface from integer hashing and exact f64 operations only (no `sin`, whose
    /// last bits may differ between platforms' libm), so its meshes can be pinned.
    fn hashed(i: usize, j: usize) -> f32 {
        let lattice = |x: u64, y: u64| {
            let mut k =
                x.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ y.wrapping_mul(0xc2b2_ae3d_27d4_eb4f);
            k ^= k >> 29;
            k = k.wrapping_mul(0xbf58_476d_1ce4_e5b9);
            (k >> 40) as f64 / (1u64 << 24) as f64
        };
        let mut z = 0.0;
        for (cell, amp) in [(32usize, 40.0), (8, 8.0), (2, 1.5)] {
            let (x0, y0) = ((i / cell) as u64, (j / cell) as u64);
            let (fx, fy) = ((i % cell) as f64 / cell as f64, (j % cell) as f64 / cell as f64);
            let top = lattice(x0, y0) * (1.0 - fx) + lattice(x0 + 1, y0) * fx;
            let bottom = lattice(x0, y0 + 1) * (1.0 - fx) + lattice(x0 + 1, y0 + 1) * fx;
            z += amp * (top * (1.0 - fy) + bottom * fy);
        }
        z as f32
    }

    /// FNV-1a over the vertices' positions and the triangles' indices.
    fn fingerprint(m: &TriMesh) -> u64 {
        let mut h = crate::checksum::FNV1A_START;
        let mut eat = |bytes: &[u8]| h = crate::checksum::fnv1a_update(h, bytes);
        for p in &m.positions {
            eat(&p.x.to_le_bytes());
            eat(&p.y.to_le_bytes());
            eat(&p.z.to_le_bytes());
        }
        for t in &m.triangles {
            t.iter().for_each(|k| eat(&k.to_le_bytes()));
        }
        h
    }

    #[test]
    fn output_is_pinned_triangle_for_triangle() {
        // The mesher's speed work must not change a single vertex or triangle: these are
        // the triangle counts and fingerprints of main before it (2026-12-03, a23565a).
        let hm = Heightmap::from_fn(301, 217, Georef::local(3.0), hashed).unwrap();
        let seeds = [[150, 0], [300, 100], [0, 77], [42, 216], [120, 130]];
        // The same heights with a void disc (NaN) reaching the west border.
        let (w, h) = (hm.width(), hm.height());
        let mut voids = VoidMask::new(w, h);
        let mut data = hm.data().to_vec();
        for j in 0..h {
            for i in 0..w {
                if (i as i64 - 20).pow(2) + (j as i64 - 90).pow(2) < 900 {
                    voids.set(i, j, true);
                    data[j * w + i] = f32::NAN;
                }
            }
        }
        let holed = Heightmap::new(w, h, data, voids, Georef::local(3.0)).unwrap();
        let got: Vec<(usize, u64)> = [0.05, 0.5, 4.0]
            .into_iter()
            .flat_map(|bound| {
                [build(&hm, bound), build_seeded(&hm, bound, &seeds, true), build(&holed, bound)]
            })
            .map(|m| (m.triangles.len(), fingerprint(&m)))
            .collect();
        let want: [(usize, u64); 9] = [
            (64791, 8858538936999255093),
            (64426, 13063378151317722863),
            (62394, 817308423241619984),
            (19794, 16522847300232377025),
            (19620, 397457956571778275),
            (19121, 4432548633386860313),
            (861, 545046945738958998),
            (842, 17929625846236250871),
            (854, 13269574065649745266),
        ];
        assert_eq!(got, want);
        // Negative control: the fingerprint sees a single moved vertex.
        let mut m = build(&hm, 4.0);
        let before = fingerprint(&m);
        m.positions[5].z += 1e-9;
        assert_ne!(fingerprint(&m), before);
    }

    #[test]
    fn in_circle_is_exact_on_cocircular_grid_points() {
        // The unit square's corners are cocircular: neither inside.
        assert!(!in_circle([0, 0], [1, 0], [1, 1], [0, 1]));
        assert!(in_circle([0, 0], [2, 0], [2, 2], [1, 1]));
        assert!(!in_circle([0, 0], [2, 0], [2, 2], [5, 5]));
    }

    #[test]
    fn in_circles_i64_path_agrees_with_i128_up_to_its_largest_sides() {
        // Points at up to 2^14 from d (the i64 path's limit), corners and a deterministic
        // spread; both answers, and both signs, must occur (or the comparison is vacuous).
        let n = 1i64 << 14;
        let mut pts = vec![[0, 0], [n, 0], [0, n], [n, n], [n / 2, n / 2], [1, n - 1]];
        let mut k = 12_345u64;
        for _ in 0..60 {
            k = k.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            pts.push([(k >> 33) as i64 % (n + 1), (k >> 13) as i64 % (n + 1)]);
        }
        let (mut inside, mut outside) = (0, 0);
        for (x, &a) in pts.iter().enumerate() {
            for &b in &pts[x + 1..] {
                for &c in pts.iter().step_by(7) {
                    if raster::orient(a, b, c) <= 0 {
                        continue;
                    }
                    for &d in pts.iter().step_by(5) {
                        let got = in_circle(a, b, c, d);
                        assert_eq!(got, in_circle_wide(a, b, c, d), "{a:?} {b:?} {c:?} {d:?}");
                        if got { inside += 1 } else { outside += 1 }
                    }
                }
            }
        }
        assert!(inside > 100 && outside > 100, "{inside} inside, {outside} outside");
    }
}
