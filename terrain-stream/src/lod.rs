//! The CPU side of the paper's rendering method (Qiu 2013, sections 3.1-3.3) on one block,
//! from the index alone: bounding-circle culling of quadtree nodes against the projected
//! view region, and dynamic LOD construction with the sight-line screen error (Eq. 7) and
//! threshold `tau` (split while `rho > tau`, the paper's algorithm step 4).
//!
//! Node `(l, i, j)` of a block covers `2^(k-l)` cells and is drawn with its corners, which
//! are level-`l` vertices, so a block whose deepest selected node is at level `l` needs its
//! levels `0..=l` resident. Node errors and heights come from the index ([`BlockEntry`]):
//! stored per node down to `node_levels`; below, the error is the smaller of the deepest
//! stored ancestor's `StaticE` and the block's per-level maximum (both bound it, Eq. 3), and
//! the height range is the ancestor's.

use glam::{DVec2, DVec3};
use terrain_core::geometry::{Camera, Classification, GroundRegion, circle_vs_region};
use terrain_core::metrics::screen::{sight_line_eq6, sight_line_eq7};
use terrain_core::quadtree::NodeId;

use crate::format::{BlockEntry, BlockId, Header};

/// The view quantities of the screen error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    /// Eye position, world metres.
    pub eye: DVec3,
    /// Unit sight-line direction.
    pub dir: DVec3,
    /// Pixels per radian (`H / (2 tan(alpha/2))` of Eq. 6-7).
    pub lambda: f64,
    /// Screen-error threshold `tau`, pixels.
    pub tau: f64,
}

impl View {
    /// The view of `camera` with threshold `tau` pixels.
    pub fn new(camera: &Camera, tau: f64) -> Self {
        Self { eye: camera.position, dir: camera.forward(), lambda: camera.lambda(), tau }
    }
}

struct Node {
    level: u8,
    i: u32,
    j: u32,
    err: f64,
    zmin: f64,
    zmax: f64,
}

/// Plan rectangle of a node clipped to the block's valid vertices; `None` if it holds none.
fn node_rect(
    h: &Header,
    e: &BlockEntry,
    b: BlockId,
    level: u8,
    i: u32,
    j: u32,
) -> Option<(DVec2, DVec2)> {
    let c = h.block_cells() >> level;
    let (x0, y0) = (i * c, j * c);
    let (vw, vh) = (e.valid_w - 1, e.valid_h - 1);
    if (x0 > 0 && x0 >= vw) || (y0 > 0 && y0 >= vh) {
        return None;
    }
    let lo = h.vertex_world(b, x0 as f64, y0 as f64);
    let hi = h.vertex_world(b, (x0 + c).min(vw) as f64, (y0 + c).min(vh) as f64);
    Some((lo, hi))
}

fn node_values(
    e: &BlockEntry,
    h: &Header,
    level: u8,
    i: u32,
    j: u32,
    parent: &Node,
) -> (f64, f64, f64) {
    if let Some(v) = e.node(level, i, j).filter(|_| level < h.node_levels) {
        return (v.static_error as f64, v.min as f64, v.max as f64);
    }
    let bound = e.level_errors.get(level as usize).map_or(0.0, |&x| x as f64);
    (bound.min(parent.err), parent.zmin, parent.zmax)
}

/// Distance from `eye` to a box and the vector from `eye` to its centre.
fn box_distance(eye: DVec3, lo: DVec3, hi: DVec3) -> (f64, DVec3) {
    let d = (lo - eye).max(eye - hi).max(DVec3::ZERO);
    (d.length(), (lo - eye) + (hi - lo) * 0.5)
}

/// Walks the block's quadtree (the paper's section 3.3): nodes whose bounding circle misses
/// `region` are dropped, the others split while Eq. 7 gives `rho > tau`. `leaf` gets every
/// selected node. With `fast`, a node below the stored node levels is not expanded: the
/// deepest level its descendants could need is bounded instead (Eq. 6, without the `beta`
/// relief, at the node's own distance, both of which can only overestimate), and reported as
/// one leaf at that level.
fn walk(
    h: &Header,
    e: &BlockEntry,
    b: BlockId,
    view: &View,
    region: &GroundRegion,
    fast: bool,
    leaf: &mut dyn FnMut(NodeId),
) {
    let root =
        Node { level: 0, i: 0, j: 0, err: f64::INFINITY, zmin: e.min as f64, zmax: e.max as f64 };
    let mut stack = vec![root];
    while let Some(parent_like) = stack.pop() {
        let Node { level, i, j, .. } = parent_like;
        let Some((lo, hi)) = node_rect(h, e, b, level, i, j) else { continue };
        let centre = (lo + hi) * 0.5;
        let radius = (hi - lo).length() * 0.5;
        if circle_vs_region(region, centre, radius) == Classification::Outside {
            continue;
        }
        let (err, zmin, zmax) = node_values(e, h, level, i, j, &parent_like);
        let (d, to_centre) = box_distance(view.eye, lo.extend(zmin), hi.extend(zmax));
        if level >= h.k || err <= 0.0 {
            leaf(NodeId { level, i, j });
            continue;
        }
        if fast && level >= h.node_levels {
            // Deepest level any descendant could need.
            let mut l = level;
            while l < h.k {
                let bound = e.level_errors.get(l as usize).map_or(0.0, |&x| x as f64).min(err);
                if bound <= 0.0 || sight_line_eq6(view.lambda, bound, d, view.dir) <= view.tau {
                    break;
                }
                l += 1;
            }
            let s = l - level;
            leaf(NodeId { level: l, i: i << s, j: j << s });
            continue;
        }
        let rho = sight_line_eq7(view.lambda, err, d, view.dir, to_centre);
        if rho > view.tau {
            for (di, dj) in [(0, 1), (1, 1), (1, 0), (0, 0)] {
                stack.push(Node {
                    level: level + 1,
                    i: 2 * i + di,
                    j: 2 * j + dj,
                    err,
                    zmin,
                    zmax,
                });
            }
        } else {
            leaf(NodeId { level, i, j });
        }
    }
}

/// The nodes of block `b` the paper's dynamic LOD construction selects (block-local
/// [`NodeId`]s: level 0 is the whole block), in depth-first order (SW, SE, NE, NW).
pub fn select_nodes(
    h: &Header,
    e: &BlockEntry,
    b: BlockId,
    view: &View,
    region: &GroundRegion,
) -> Vec<NodeId> {
    let mut out = Vec::new();
    walk(h, e, b, view, region, false, &mut |n| out.push(n));
    out
}

/// The finest level block `b` needs for `view` (the deepest selected node's level, bounded
/// from above below the stored node levels), or `None` when no node of it meets `region`.
pub fn needed_level(
    h: &Header,
    e: &BlockEntry,
    b: BlockId,
    view: &View,
    region: &GroundRegion,
) -> Option<u8> {
    let mut deepest: Option<u8> = None;
    walk(h, e, b, view, region, true, &mut |n| {
        deepest = Some(deepest.map_or(n.level, |d| d.max(n.level)))
    });
    deepest
}
