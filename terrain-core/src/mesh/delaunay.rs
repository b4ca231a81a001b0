//! Greedy insertion into a Delaunay triangulation: the fewest-triangle builder.
//!
//! Garland & Heckbert 1995 ("Fast polygonal approximation of terrains and height fields",
//! CMU-CS-95-181), algorithm III as in hmm (M. Fogleman) and Delatin (V. Agafonkin): start
//! with the grid's four corners (two triangles covering the rectangle), then repeatedly insert
//! the sample with the largest vertical error until no sample's error exceeds the bound.
//!
//! - Each triangle keeps its *candidate*: its worst non-void sample (scan-converted exactly,
//!   see `raster`) and that sample's error against the triangle's plane.
//! - Candidates wait in a max-heap. Inserting a point into a Delaunay triangulation (spade:
//!   locate, split, Lawson flips) only creates triangles incident to the new vertex, so only
//!   the new vertex's star is scanned again (G&H §5.2). Heap entries of destroyed triangles
//!   are dropped lazily: an entry is live while its face index still holds the same three
//!   vertices (a destroyed triangle's circumcircle contains the inserted point forever, so it
//!   cannot reappear).
//! - Cost: each insertion rescans the triangles around the new vertex, whose area shrinks as
//!   the mesh refines; the heap adds `O(log n)` per candidate. This is G&H's
//!   `O((m + n) log m)` expected behaviour, not `O(n^2)`.
//!
//! [`build_seeded`] starts from given samples besides the corners and may lock the grid's
//! border (its samples are never inserted by the greedy loop): the TIN pyramids
//! ([`crate::tin::tile`]) fix each tile's border vertices that way, so neighbours agree.
//!
//! Points are inserted in grid coordinates (integers in f64, exact for spade's robust
//! predicates); world positions are applied when the mesh is assembled.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use spade::handles::{FixedFaceHandle, FixedVertexHandle, InnerTag};
use spade::{DelaunayTriangulation, Point2, Triangulation};

use crate::heightmap::Heightmap;
use crate::mesh::{TriMesh, raster};

/// A triangle's worst sample.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    error: f64,
    sample: [u32; 2],
    face: FixedFaceHandle<InnerTag>,
    vertices: [usize; 3],
}

impl PartialEq for Candidate {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Candidate {}
impl PartialOrd for Candidate {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Candidate {
    /// Largest error first; ties broken by position and face so the order is total
    /// (deterministic meshes).
    fn cmp(&self, other: &Self) -> Ordering {
        self.error
            .total_cmp(&other.error)
            .then_with(|| other.sample.cmp(&self.sample))
            .then_with(|| other.face.index().cmp(&self.face.index()))
    }
}

type Tin = DelaunayTriangulation<Point2<f64>>;

/// Grid coordinates of a vertex (inserted as exact integers).
fn grid_of(p: Point2<f64>) -> [i64; 2] {
    [p.x as i64, p.y as i64]
}

/// Scans face `face` and returns its candidate if its worst sample exceeds `max_error`
/// (samples on the grid's border skipped when `lock_border`).
fn candidate(
    hm: &Heightmap,
    tin: &Tin,
    face: FixedFaceHandle<InnerTag>,
    max_error: f64,
    lock_border: bool,
) -> Option<Candidate> {
    let (w, h) = (hm.width() as i64, hm.height() as i64);
    let f = tin.face(face);
    let vs = f.vertices();
    let g = vs.map(|v| grid_of(v.position()));
    let z = g.map(|p| f64::from(hm.get(p[0] as usize, p[1] as usize)));
    let voids = hm.voids().any().then(|| hm.voids());
    let mut best = (max_error, None);
    raster::for_each_sample(g, z, |i, j, zi| {
        if lock_border && (i == 0 || j == 0 || i == w - 1 || j == h - 1) {
            return;
        }
        let (i, j) = (i as usize, j as usize);
        if voids.is_some_and(|m| m.get(i, j)) {
            return;
        }
        let e = (f64::from(hm.get(i, j)) - zi).abs();
        if e > best.0 {
            best = (e, Some([i as u32, j as u32]));
        }
    });
    let (error, sample) = (best.0, best.1?);
    Some(Candidate { error, sample, face, vertices: vs.map(|v| v.fix().index()) })
}

/// Builds the greedy Delaunay mesh of `hm` within `max_error` of every non-void sample.
///
/// # Panics
/// On a grid smaller than 2 x 2 or a negative or NaN bound; [`crate::mesh::build`] checks both.
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
    let mut tin = Tin::new();
    let corners =
        [[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]].map(|[i, j]| [i as u32, j as u32]);
    for [i, j] in corners.iter().chain(seeds) {
        if (*i as usize) < w && (*j as usize) < h {
            tin.insert(Point2::new(f64::from(*i), f64::from(*j)))
                .expect("grid coordinates are finite");
        }
    }
    let mut heap = BinaryHeap::new();
    let faces: Vec<_> = tin.fixed_inner_faces().collect();
    for f in faces {
        heap.extend(candidate(hm, &tin, f, max_error, lock_border));
    }
    while let Some(c) = heap.pop() {
        // Entries only exist above the bound; a stale one belongs to a destroyed triangle.
        if tin.face(c.face).vertices().map(|v| v.fix().index()) != c.vertices {
            continue;
        }
        let p = Point2::new(f64::from(c.sample[0]), f64::from(c.sample[1]));
        let hint = FixedVertexHandle::from_index(c.vertices[0]);
        let v = tin.insert_with_hint(p, hint).expect("grid coordinates are finite");
        let star: Vec<_> = tin
            .vertex(v)
            .out_edges()
            .filter_map(|e| e.face().as_inner())
            .map(|f| f.fix())
            .collect();
        for f in star {
            heap.extend(candidate(hm, &tin, f, max_error, lock_border));
        }
    }
    let vertices: Vec<[u32; 2]> = tin
        .vertices()
        .map(|v| {
            let g = grid_of(v.position());
            [g[0] as u32, g[1] as u32]
        })
        .collect();
    let triangles =
        tin.inner_faces().map(|f| f.vertices().map(|v| v.fix().index() as u32)).collect();
    TriMesh::from_grid(hm, &vertices, triangles)
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
}
