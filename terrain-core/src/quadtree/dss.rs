//! The DSS paper's (Zhang 2019) M-block ids and the neighbour-strip ids `Idsneighbour`.
//!
//! Section 3.1.1: "With an M-block, the Id of which is k, the Ids of its children can be
//! expressed as 4(k + 1), 4(k + 1) + 1, 4(k + 1) + 2, 4(k + 1) + 3, respectively, starting
//! from the lower left corner anti-clockwise" (its Fig. 5). Its worked example (Fig. 7) has
//! level-1 blocks B0..B3 (B1 has children B8..B11, B11 has B48..B51), which fixes the root's
//! id at **-1** (`4(-1 + 1) + c = c`). So level `l >= 1` holds ids
//! `(4^l - 4) / 3 .. (4^(l+1) - 4) / 3`. "Lower" is south in our plan view (x east, y
//! north), so child `c` is [`Quadrant`] `c`: SW, SE, NE, NW.
//!
//! Section 3.2.1 / Table 1: `Idsneighbour[0..4]` hold the ids of the stitching strips (DSS)
//! on the block's edges "A ~ d". Table 1's entries fix the edge order: the lower-left and
//! lower-right children share edge 0 with the parent, lower-right and upper-right edge 1,
//! and so on, so the edges are **0 = south, 1 = east, 2 = north, 3 = west** (anti-clockwise
//! from the bottom). Each block owns the strip on its anti-clockwise side; a strip has the id
//! of its owning block; `None` is the paper's `null` (no strip: the terrain border).

use super::node::{NodeId, Quadrant};

/// The DSS paper's id of the root M-block (see the module docs).
pub const DSS_ROOT_ID: i64 = -1;

/// The M-block id of a node: `-1` for the root, then `4(k + 1) + c` down the tree.
/// Levels up to [`NodeId::MAX_LEVEL`] fit in an i64.
pub fn dss_block_id(node: NodeId) -> i64 {
    let mut k = DSS_ROOT_ID;
    for l in 1..=node.level {
        k = 4 * (k + 1) + node.ancestor(l).quadrant() as i64;
    }
    k
}

/// The node of an M-block id (inverse of [`dss_block_id`]); `None` for ids below -1 or
/// deeper than [`NodeId::MAX_LEVEL`].
pub fn dss_node(id: i64) -> Option<NodeId> {
    if id < DSS_ROOT_ID {
        return None;
    }
    // Walk up: the parent of k >= 0 is k / 4 - 1, the child number k % 4.
    let mut quads = Vec::new();
    let mut k = id;
    while k != DSS_ROOT_ID {
        quads.push(Quadrant::ALL[(k % 4) as usize]);
        k = k / 4 - 1;
        if quads.len() > NodeId::MAX_LEVEL as usize {
            return None;
        }
    }
    Some(quads.iter().rev().fold(NodeId::ROOT, |n, &q| n.child(q)))
}

/// Table 1: the `Idsneighbour` of the child in quadrant `child` of block `n`, whose own
/// `Idsneighbour` is `parent = [DssId_a, DssId_b, DssId_c, DssId_d]`.
pub fn dss_child_neighbours(n: i64, parent: [Option<i64>; 4], child: Quadrant) -> [Option<i64>; 4] {
    let base = 4 * (n + 1);
    let [a, b, c, d] = parent;
    match child {
        // lower left:  DssId_a, 4(n+1), 4(n+1)+3, DssId_d
        Quadrant::SouthWest => [a, Some(base), Some(base + 3), d],
        // lower right: DssId_a, DssId_b, 4(n+1)+1, 4(n+1)
        Quadrant::SouthEast => [a, b, Some(base + 1), Some(base)],
        // upper right: 4(n+1)+1, DssId_b, DssId_c, 4(n+1)+2
        Quadrant::NorthEast => [Some(base + 1), b, c, Some(base + 2)],
        // upper left:  4(n+1)+3, 4(n+1)+2, DssId_c, DssId_d
        Quadrant::NorthWest => [Some(base + 3), Some(base + 2), c, d],
    }
}

/// The `Idsneighbour` of any node, by applying Table 1 from the root (whose four edges
/// are the terrain border: all `None`). Order: south, east, north, west.
pub fn dss_neighbours(node: NodeId) -> [Option<i64>; 4] {
    let mut ids = [None; 4];
    let mut k = DSS_ROOT_ID;
    for l in 1..=node.level {
        let q = node.ancestor(l).quadrant();
        ids = dss_child_neighbours(k, ids, q);
        k = 4 * (k + 1) + q as i64;
    }
    ids
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quadtree::node::Direction;

    #[test]
    fn ids_follow_4k_plus_4_plus_c() {
        assert_eq!(dss_block_id(NodeId::ROOT), -1);
        let level1: Vec<i64> = NodeId::ROOT.children().iter().map(|&c| dss_block_id(c)).collect();
        assert_eq!(level1, [0, 1, 2, 3]);
        // B1 is the lower-right (south-east) level-1 block; its children are B8..B11.
        let b1 = dss_node(1).unwrap();
        assert_eq!(b1, NodeId::new(1, 1, 0));
        let kids: Vec<i64> = b1.children().iter().map(|&c| dss_block_id(c)).collect();
        assert_eq!(kids, [8, 9, 10, 11]);
        // B11 is B1's upper-left child; B49 is B11's lower-right child.
        assert_eq!(dss_node(11), Some(NodeId::new(2, 2, 1)));
        assert_eq!(dss_node(49), Some(NodeId::new(3, 5, 2)));
        // Level ranges: level 2 holds 4..=19, level 3 starts at 20.
        assert_eq!(dss_block_id(NodeId::new(2, 0, 0)), 4);
        assert_eq!(dss_block_id(NodeId::new(2, 0, 3)), 19);
        assert_eq!(dss_block_id(NodeId::new(3, 0, 0)), 20);
        assert_eq!(dss_node(-2), None);
    }

    #[test]
    fn id_round_trip() {
        for id in -1..2000 {
            let n = dss_node(id).unwrap();
            assert_eq!(dss_block_id(n), id);
        }
        let deep = NodeId::new(NodeId::MAX_LEVEL, 123_456_789, 987_654_321);
        assert_eq!(dss_node(dss_block_id(deep)), Some(deep));
    }

    #[test]
    fn table1_worked_example() {
        // Fig. 7: B1 has Idsneighbour {null, null, 1, 0}; B11 {11, 10, 1, 0}; B49 {11, 10, 49, 48}.
        assert_eq!(dss_neighbours(dss_node(1).unwrap()), [None, None, Some(1), Some(0)]);
        assert_eq!(dss_neighbours(dss_node(11).unwrap()), [Some(11), Some(10), Some(1), Some(0)]);
        assert_eq!(dss_neighbours(dss_node(49).unwrap()), [Some(11), Some(10), Some(49), Some(48)]);
        // Table 1 rows for n = 5 with parent ids a, b, c, d = 100, 101, 102, 103.
        let p = [Some(100), Some(101), Some(102), Some(103)];
        let t = |q| dss_child_neighbours(5, p, q);
        assert_eq!(t(Quadrant::SouthWest), [Some(100), Some(24), Some(27), Some(103)]);
        assert_eq!(t(Quadrant::SouthEast), [Some(100), Some(101), Some(25), Some(24)]);
        assert_eq!(t(Quadrant::NorthEast), [Some(25), Some(101), Some(102), Some(26)]);
        assert_eq!(t(Quadrant::NorthWest), [Some(27), Some(26), Some(102), Some(103)]);
    }

    #[test]
    fn strips_are_shared_by_the_two_blocks_they_join() {
        // For every pair of same-level neighbours, the strip id on the shared edge agrees,
        // and it is the id of one of the two blocks (its anti-clockwise owner).
        let edge = |d: Direction| match d {
            Direction::South => 0,
            Direction::East => 1,
            Direction::North => 2,
            Direction::West => 3,
        };
        for l in 1..=3u8 {
            for i in 0..(1u32 << l) {
                for j in 0..(1u32 << l) {
                    let n = NodeId::new(l, i, j);
                    for d in Direction::ALL {
                        let ours = dss_neighbours(n)[edge(d)];
                        match n.neighbour(d) {
                            None => assert_eq!(ours, None, "{n:?} {d:?}"),
                            Some(m) => {
                                assert_eq!(
                                    ours,
                                    dss_neighbours(m)[edge(d.opposite())],
                                    "{n:?} {d:?}"
                                );
                                let owner = ours.unwrap();
                                if m.parent() == n.parent() {
                                    assert!(owner == dss_block_id(n) || owner == dss_block_id(m));
                                } else {
                                    // Across parents the strip is inherited from ancestors.
                                    assert!(owner < dss_block_id(n).min(dss_block_id(m)));
                                }
                            }
                        }
                    }
                }
            }
        }
    }
}
