//! The drawn surface rebuilt on the CPU: a selection's patches, tessellated by a caller's
//! tessellator (terrain-gpu's CPU reference in practice), displaced by the heightmap.
//!
//! **Domain mapping (the contract the GPU side mirrors).** Domain point `(u, v)` of node `n`'s
//! patch lies at grid position `(x0 + u c, y0 + v c)`, with `(x0, y0, c)` the node's
//! *unclipped* square ([`NodeId::grid_rect`]), then clamped to the grid
//! `[0, width - 1] x [0, height - 1]` ([`patch_grid_point`]); its height is the heightmap's
//! bilinear height there. Mapping onto the clipped rectangle instead would stretch a clipped
//! patch's edge differently from its finer neighbours' edges and open cracks at the east and
//! north borders of grids that are not `2^L + 1` samples; clamping after the mapping is a
//! function of the position, so vertices that coincide in the full quadtree still coincide.
//! The price: the part of a border patch past the grid collapses onto the border line
//! (zero-area triangles).

use std::collections::HashMap;

use glam::{DVec2, DVec3};

use super::patch::{Edge, Patch, Selection};
use super::source::TerrainSource;
use crate::heightmap::Heightmap;
use crate::quadtree::{NodeId, Quadtree, TreeShape};

/// Grid position (fractional samples, x east, y north) of domain point `uv` of `node`'s patch:
/// the unclipped node square, clamped to the grid (see the module docs).
pub fn patch_grid_point(shape: &TreeShape, node: NodeId, uv: [f32; 2]) -> DVec2 {
    let (x0, y0, c) = node.grid_rect(shape.root_cells());
    let x = x0 as f64 + f64::from(uv[0]) * c as f64;
    let y = y0 as f64 + f64::from(uv[1]) * c as f64;
    DVec2::new(x.clamp(0.0, (shape.width() - 1) as f64), y.clamp(0.0, (shape.height() - 1) as f64))
}

/// World position of domain point `uv` of `node`'s patch: [`patch_grid_point`], the source's
/// bilinear height there.
pub fn patch_world_point(src: &dyn TerrainSource, node: NodeId, uv: [f32; 2]) -> DVec3 {
    let shape = src.shape();
    let g = patch_grid_point(shape, node, uv);
    shape.grid_to_world(g).extend(f64::from(src.height(g)))
}

/// A patch's corners in its domain: south-west, south-east, north-west, north-east.
pub(crate) const CORNERS_UV: [[f32; 2]; 4] = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]];

/// The corners ([`CORNERS_UV`] indices) that end `edge`, its south or west end first.
pub(crate) fn edge_corners(edge: Edge) -> (usize, usize) {
    match edge {
        Edge::South => (0, 1),
        Edge::East => (1, 3),
        Edge::North => (2, 3),
        Edge::West => (0, 2),
    }
}

/// The world segment of a patch edge (clamped like every domain point), from its south or
/// west end: two same-level patches sharing an edge get the identical segment.
pub fn edge_segment(src: &dyn TerrainSource, node: NodeId, edge: Edge) -> (DVec3, DVec3) {
    let (a, b) = edge_corners(edge);
    (patch_world_point(src, node, CORNERS_UV[a]), patch_world_point(src, node, CORNERS_UV[b]))
}

/// A triangle mesh in world coordinates, vertices welded where they coincide exactly.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SurfaceMesh {
    /// Vertex positions, world frame, metres.
    pub positions: Vec<DVec3>,
    /// Grid position of each vertex (fractional samples).
    pub grid: Vec<DVec2>,
    /// Triangles, anti-clockwise seen from above when the tessellator's are in `(u, v)`.
    pub triangles: Vec<[u32; 3]>,
}

impl SurfaceMesh {
    /// Edges used by exactly one triangle of non-zero plan area, as sorted vertex pairs, in
    /// ascending order. On a crack-free surface these lie on the terrain's border (or on the
    /// border of what was culled).
    pub fn open_edges(&self) -> Vec<[u32; 2]> {
        let mut count: HashMap<[u32; 2], u32> = HashMap::new();
        for t in &self.triangles {
            let [a, b, c] = t.map(|k| self.grid[k as usize]);
            if (b - a).perp_dot(c - a) == 0.0 {
                continue;
            }
            for (p, q) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                *count.entry([p.min(q), p.max(q)]).or_default() += 1;
            }
        }
        let mut v: Vec<[u32; 2]> =
            count.into_iter().filter(|&(_, n)| n == 1).map(|(e, _)| e).collect();
        v.sort_unstable();
        v
    }
}

/// Builds the world-space mesh of `sel`: each patch tessellated by `tess` (domain points in
/// `[0, 1]^2`, `u` east, `v` north, and triangles indexing them), mapped by
/// [`patch_world_point`], with coincident vertices welded (by exact grid position).
/// `qt` must be the quadtree of `hm` the selection was made on.
pub fn build_surface<T>(hm: &Heightmap, qt: &Quadtree, sel: &Selection, tess: T) -> SurfaceMesh
where
    T: Fn(&Patch) -> (Vec<[f32; 2]>, Vec<[u32; 3]>),
{
    assert_eq!((hm.width() as u32, hm.height() as u32), (qt.width(), qt.height()));
    let mut mesh = SurfaceMesh::default();
    let mut weld: HashMap<(u64, u64), u32> = HashMap::new();
    for p in &sel.patches {
        let (points, tris) = tess(p);
        let ids: Vec<u32> = points
            .iter()
            .map(|&uv| {
                let g = patch_grid_point(qt.shape(), p.node, uv);
                *weld.entry((g.x.to_bits(), g.y.to_bits())).or_insert_with(|| {
                    mesh.positions.push(
                        hm.grid_to_world(g.x, g.y).extend(f64::from(hm.sample_grid(g.x, g.y))),
                    );
                    mesh.grid.push(g);
                    (mesh.positions.len() - 1) as u32
                })
            })
            .collect();
        mesh.triangles.extend(tris.iter().map(|t| t.map(|k| ids[k as usize])));
    }
    mesh
}

/// A simple tessellation for tests: each outer edge gets `max(1, round(factor))` equal
/// segments (so its points depend only on its factor), fanned to the patch centre. Inner
/// factors are ignored.
pub fn fan_tessellation(p: &Patch) -> (Vec<[f32; 2]>, Vec<[u32; 3]>) {
    let n = p.outer.map(|f| (f.round() as u32).max(1));
    let mut ring: Vec<[f32; 2]> = Vec::new();
    let t = |k: u32, n: u32| k as f32 / n as f32;
    // Anti-clockwise: south west->east, east south->north, north east->west, west north->south.
    ring.extend((0..n[0]).map(|k| [t(k, n[0]), 0.0]));
    ring.extend((0..n[1]).map(|k| [1.0, t(k, n[1])]));
    ring.extend((0..n[2]).map(|k| [t(n[2] - k, n[2]), 1.0]));
    ring.extend((0..n[3]).map(|k| [0.0, t(n[3] - k, n[3])]));
    let m = ring.len() as u32;
    ring.push([0.5, 0.5]);
    let tris = (0..m).map(|k| [m, k, (k + 1) % m]).collect();
    (ring, tris)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::georef::Georef;
    use crate::lod::GridSource;
    use crate::lod::edges::{EdgeRule, outer_factors};
    use crate::quadtree::{LeafSet, balance};

    /// Same-level edges 3, coarse edges 4, unshared 1: a valid rule.
    struct Simple;
    impl EdgeRule for Simple {
        fn same_level(&self, _: NodeId, _: Edge, _: NodeId) -> f32 {
            3.0
        }
        fn coarse_edge(&self, _: NodeId, _: Edge, _: &[NodeId]) -> f32 {
            4.0
        }
        fn unshared(&self, _: NodeId, _: Edge) -> f32 {
            1.0
        }
    }

    /// Same-level edges 3, coarse edges 3 (not halvable): cracks.
    struct Broken;
    impl EdgeRule for Broken {
        fn same_level(&self, _: NodeId, _: Edge, _: NodeId) -> f32 {
            3.0
        }
        fn coarse_edge(&self, _: NodeId, _: Edge, _: &[NodeId]) -> f32 {
            3.0
        }
        fn unshared(&self, _: NodeId, _: Edge) -> f32 {
            1.0
        }
    }

    fn on_border(m: &SurfaceMesh, e: [u32; 2], w: f64, h: f64) -> bool {
        let (a, b) = (m.grid[e[0] as usize], m.grid[e[1] as usize]);
        (a.x == 0.0 && b.x == 0.0)
            || (a.y == 0.0 && b.y == 0.0)
            || (a.x == w && b.x == w)
            || (a.y == h && b.y == h)
    }

    fn mixed_selection(qt: &Quadtree, rule: &dyn EdgeRule) -> Selection {
        // Refine towards the south-west corner, then balance: levels 1..=max meet.
        let deep = NodeId::new(qt.max_level(), 0, 0);
        let mut leaves = Vec::new();
        for l in 1..=qt.max_level() {
            for c in deep.ancestor(l - 1).children() {
                if qt.contains_node(c) && !c.is_ancestor_or_self_of(deep) || c == deep {
                    leaves.push(c);
                }
            }
        }
        let leaves = balance(qt, &leaves);
        let set = LeafSet::new(leaves.iter().copied());
        let patches = leaves
            .iter()
            .map(|&n| Patch { node: n, outer: outer_factors(&set, n, rule), inner: [1.0; 2] })
            .collect();
        Selection { patches, ..Default::default() }
    }

    #[test]
    fn matched_factors_are_watertight_and_broken_ones_are_not() {
        for (w, h) in [(65, 65), (50, 37)] {
            let hm =
                Heightmap::from_fn(w, h, Georef::local(2.0), |i, j| ((i * 7 + j * 3) % 11) as f32)
                    .unwrap();
            let qt = Quadtree::new(&hm, 4);
            let (wm, hmax) = ((w - 1) as f64, (h - 1) as f64);
            let sel = mixed_selection(&qt, &Simple);
            assert!(sel.patches.iter().any(|p| p.node.level == qt.max_level()));
            assert!(sel.patches.iter().any(|p| p.node.level == 1));
            assert!(crate::lod::check_shared_edges(&sel).is_empty());
            let mesh = build_surface(&hm, &qt, &sel, fan_tessellation);
            let open = mesh.open_edges();
            assert!(!open.is_empty());
            let inner: Vec<_> = open.iter().filter(|&&e| !on_border(&mesh, e, wm, hmax)).collect();
            assert!(inner.is_empty(), "{w}x{h}: cracks along {inner:?}");
            // Heights come from the heightmap at sample positions.
            for (p, g) in mesh.positions.iter().zip(&mesh.grid) {
                assert_eq!(p.z, f64::from(hm.sample_grid(g.x, g.y)));
            }
            let bad = mixed_selection(&qt, &Broken);
            assert!(!crate::lod::check_shared_edges(&bad).is_empty());
            let mesh = build_surface(&hm, &qt, &bad, fan_tessellation);
            assert!(mesh.open_edges().iter().any(|&e| !on_border(&mesh, e, wm, hmax)));
        }
    }

    #[test]
    fn domain_maps_onto_the_unclipped_square_then_clamps() {
        let hm = Heightmap::from_fn(50, 37, Georef::local(1.0), |_, _| 0.0).unwrap();
        let qt = Quadtree::new(&hm, 4);
        assert_eq!(qt.root_cells(), 64);
        let n = NodeId::new(1, 1, 1); // samples 32..=64 by 32..=64, clipped to 49 x 36
        assert_eq!(patch_grid_point(qt.shape(), n, [0.0, 0.0]), DVec2::new(32.0, 32.0));
        assert_eq!(patch_grid_point(qt.shape(), n, [0.25, 0.125]), DVec2::new(40.0, 36.0));
        assert_eq!(patch_grid_point(qt.shape(), n, [1.0, 1.0]), DVec2::new(49.0, 36.0));
        let (a, b) = edge_segment(&GridSource::new(&qt, &hm), NodeId::new(1, 0, 0), Edge::East);
        let (c, d) = edge_segment(&GridSource::new(&qt, &hm), NodeId::new(1, 1, 0), Edge::West);
        assert_eq!((a, b), (c, d));
    }
}
