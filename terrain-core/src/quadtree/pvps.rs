//! The PVPS paper's (Zhang 2021, section 2.3) node centre, span and patch corners.
//!
//! Frame conversion: the paper is y-up (OpenGL): its node `N^l_{i,j}` has `i` counting along
//! X and `j` along Z, the patch lies in the X-Z plane with Y = 0. We map paper X -> our x
//! (east), paper Z -> our y (north), paper Y (up) -> our z, and count `j` northwards from
//! the south edge. (OpenGL's +Z points towards the viewer, i.e. south when X is east and Y
//! up, so this is a mirror of the paper's picture; the formulas below are offsets from the
//! terrain's corner along the axis `j` counts on, so they apply unchanged.) All positions
//! here are relative to the root patch's south-west corner; add the grid's world origin.
//!
//! `Length` is the side of the root patch `N^0_{0,0}` (the paper's Fig. 10 calls it the
//! distance between Vertex0 and Vertex3, which is the diagonal; Eq. 9 with l = 0 makes
//! `Span = Length` the side, which is what the formulas need). We allow different lengths
//! along x and y for grids with `dx != dy`.

use glam::DVec2;

use super::node::NodeId;

/// Eq. (9): `Span = Length / 2^l`, the side of a node's patch at level `l`.
pub fn pvps_span(length: f64, level: u8) -> f64 {
    length / (1u64 << level) as f64
}

/// Eq. (6) and (7), corrected: the centre of node `N^l_{i,j}`,
/// `X = (2i + 1) Length / 2^(l+1)`, `Z = (2j + 1) Length / 2^(l+1)` (Z -> our y).
///
/// **Erratum.** The paper prints `X = (i + 1) Length / 2^(l+1)` (and the same for Z). That
/// is right only for `i = 0`: at level 1 it puts node `i = 1` at `Length / 2`, the root's
/// centre, instead of `3 Length / 4`, and makes centres at one level half a span apart, so
/// patches built by Eq. (10) would overlap. The centre of the `i`-th of `2^l` equal
/// intervals is `(i + 1/2) Length / 2^l`, which is what we implement; the printed form is
/// kept as [`pvps_node_center_as_printed`] for comparison.
pub fn pvps_node_center(length: DVec2, node: NodeId) -> DVec2 {
    let denom = (1u64 << (node.level as u32 + 1)) as f64;
    DVec2::new(
        (2 * node.i as u64 + 1) as f64 * length.x / denom,
        (2 * node.j as u64 + 1) as f64 * length.y / denom,
    )
}

/// Eq. (6) and (7) exactly as printed: `(i + 1) Length / 2^(l+1)`. Wrong for `i, j > 0`
/// (see [`pvps_node_center`]); only for checking the erratum.
pub fn pvps_node_center_as_printed(length: DVec2, node: NodeId) -> DVec2 {
    let denom = (1u64 << (node.level as u32 + 1)) as f64;
    DVec2::new(
        (node.i as u64 + 1) as f64 * length.x / denom,
        (node.j as u64 + 1) as f64 * length.y / denom,
    )
}

/// Eq. (10): the patch corners `[Vertex0, Vertex1, Vertex2, Vertex3]` of node `N^l_{i,j}`
/// in the plan (the paper's Y = 0 plane is our z = 0):
/// Vertex0 = (X - Span/2, Z - Span/2) = south-west, Vertex1 = (X - Span/2, Z + Span/2) =
/// north-west, Vertex2 = (X + Span/2, Z - Span/2) = south-east, Vertex3 = (X + Span/2,
/// Z + Span/2) = north-east (with paper Z -> our y).
pub fn pvps_patch_corners(length: DVec2, node: NodeId) -> [DVec2; 4] {
    let c = pvps_node_center(length, node);
    let h = DVec2::new(pvps_span(length.x, node.level), pvps_span(length.y, node.level)) * 0.5;
    [
        DVec2::new(c.x - h.x, c.y - h.y),
        DVec2::new(c.x - h.x, c.y + h.y),
        DVec2::new(c.x + h.x, c.y - h.y),
        DVec2::new(c.x + h.x, c.y + h.y),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::dvec2;

    #[test]
    fn span_eq9() {
        assert_eq!(pvps_span(1024.0, 0), 1024.0);
        assert_eq!(pvps_span(1024.0, 1), 512.0);
        assert_eq!(pvps_span(1024.0, 6), 16.0); // the paper's 64 x 64 patches at level 6
        assert_eq!(pvps_span(3.0, 2), 0.75);
    }

    #[test]
    fn centres_eq6_eq7_hand_computed() {
        let len = dvec2(1024.0, 1024.0);
        // Root: the centre of the terrain (paper section 2.3.1).
        assert_eq!(pvps_node_center(len, NodeId::ROOT), dvec2(512.0, 512.0));
        // Level 1: quarters.
        assert_eq!(pvps_node_center(len, NodeId::new(1, 0, 0)), dvec2(256.0, 256.0));
        assert_eq!(pvps_node_center(len, NodeId::new(1, 1, 0)), dvec2(768.0, 256.0));
        assert_eq!(pvps_node_center(len, NodeId::new(1, 0, 1)), dvec2(256.0, 768.0));
        // Level 2, node (3, 1): x = 7 * 1024 / 8 = 896, y = 3 * 1024 / 8 = 384.
        assert_eq!(pvps_node_center(len, NodeId::new(2, 3, 1)), dvec2(896.0, 384.0));
        // Level 6 (64 x 64 patches of 16), node (63, 0): x = 127 * 1024 / 128 = 1016, y = 8.
        assert_eq!(pvps_node_center(len, NodeId::new(6, 63, 0)), dvec2(1016.0, 8.0));
        // Rectangular cells: lengths differ per axis.
        assert_eq!(pvps_node_center(dvec2(100.0, 60.0), NodeId::new(1, 1, 1)), dvec2(75.0, 45.0));
        // The printed formula agrees at i = j = 0 only.
        for n in [NodeId::ROOT, NodeId::new(1, 0, 0), NodeId::new(4, 0, 0)] {
            assert_eq!(pvps_node_center_as_printed(len, n), pvps_node_center(len, n));
        }
        assert_eq!(pvps_node_center_as_printed(len, NodeId::new(1, 1, 0)), dvec2(512.0, 256.0));
        // Our centres are the centres of the node's grid rectangle.
        let (x0, y0, cells) = NodeId::new(3, 5, 2).grid_rect(1024);
        let c = pvps_node_center(len, NodeId::new(3, 5, 2));
        assert_eq!(c, dvec2(x0 as f64 + cells as f64 / 2.0, y0 as f64 + cells as f64 / 2.0));
    }

    #[test]
    fn corners_eq10() {
        let len = dvec2(1024.0, 1024.0);
        // Node (1, 1, 0): centre (768, 256), span 512.
        let v = pvps_patch_corners(len, NodeId::new(1, 1, 0));
        assert_eq!(
            v,
            [dvec2(512.0, 0.0), dvec2(512.0, 512.0), dvec2(1024.0, 0.0), dvec2(1024.0, 512.0)]
        );
        // The four children's patches tile the parent's exactly.
        let p = pvps_patch_corners(len, NodeId::new(2, 1, 2));
        let kids: Vec<_> =
            NodeId::new(2, 1, 2).children().iter().map(|&c| pvps_patch_corners(len, c)).collect();
        assert_eq!(kids[0][0], p[0]); // SW child's Vertex0 = parent's Vertex0
        assert_eq!(kids[2][3], p[3]); // NE child's Vertex3 = parent's Vertex3
        assert_eq!(kids[0][3], kids[2][0]); // they meet at the parent's centre
        assert_eq!(kids[0][3], pvps_node_center(len, NodeId::new(2, 1, 2)));
    }
}
