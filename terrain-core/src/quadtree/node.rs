//! Quadtree node addressing: `NodeId { level, i, j }`, parents, children, neighbours.

/// One of the four compass directions in the plan (x east, y north).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Direction {
    /// +y.
    North,
    /// +x.
    East,
    /// -y.
    South,
    /// -x.
    West,
}

impl Direction {
    /// All four, in the order N, E, S, W.
    pub const ALL: [Direction; 4] =
        [Direction::North, Direction::East, Direction::South, Direction::West];

    /// The opposite direction.
    pub fn opposite(self) -> Direction {
        match self {
            Direction::North => Direction::South,
            Direction::East => Direction::West,
            Direction::South => Direction::North,
            Direction::West => Direction::East,
        }
    }

    /// Unit step `(di, dj)` in node indices.
    pub fn step(self) -> (i64, i64) {
        match self {
            Direction::North => (0, 1),
            Direction::East => (1, 0),
            Direction::South => (0, -1),
            Direction::West => (-1, 0),
        }
    }
}

/// A child's position inside its parent. The discriminants are the DSS paper's child
/// numbers `c` (children of M-block `k` are `4(k + 1) + c`, "starting from the lower left
/// corner anti-clockwise", its section 3.1.1 / Fig. 5; "lower" is south in our plan view).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[repr(u8)]
pub enum Quadrant {
    /// Lower left: `(2i, 2j)`.
    SouthWest = 0,
    /// Lower right: `(2i + 1, 2j)`.
    SouthEast = 1,
    /// Upper right: `(2i + 1, 2j + 1)`.
    NorthEast = 2,
    /// Upper left: `(2i, 2j + 1)`.
    NorthWest = 3,
}

impl Quadrant {
    /// All four in child order (anti-clockwise from the south-west).
    pub const ALL: [Quadrant; 4] =
        [Quadrant::SouthWest, Quadrant::SouthEast, Quadrant::NorthEast, Quadrant::NorthWest];

    /// Offset `(di, dj)` of this child from `(2i, 2j)`.
    pub fn offset(self) -> (u32, u32) {
        match self {
            Quadrant::SouthWest => (0, 0),
            Quadrant::SouthEast => (1, 0),
            Quadrant::NorthEast => (1, 1),
            Quadrant::NorthWest => (0, 1),
        }
    }

    /// The quadrant whose offset is `(di, dj)` (each 0 or 1).
    pub fn from_offset(di: u32, dj: u32) -> Quadrant {
        match (di & 1, dj & 1) {
            (0, 0) => Quadrant::SouthWest,
            (1, 0) => Quadrant::SouthEast,
            (1, 1) => Quadrant::NorthEast,
            _ => Quadrant::NorthWest,
        }
    }
}

/// A quadtree node: `level` 0 is the root covering the whole (power-of-two) grid; at level
/// `l` there are `2^l x 2^l` nodes, `i` counting east and `j` counting north from the
/// south-west corner (grid row 0 is south). This is the PVPS paper's `N^l_{i,j}` with its
/// Z axis mapped to our y (north).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct NodeId {
    /// Depth, 0 = root. At most [`NodeId::MAX_LEVEL`].
    pub level: u8,
    /// Column of nodes at this level (east).
    pub i: u32,
    /// Row of nodes at this level (north).
    pub j: u32,
}

/// Bit `k` of `v` moved to bit `2k` (the standard "magic numbers" bit interleave).
fn spread_bits(v: u32) -> u64 {
    let mut x = u64::from(v);
    x = (x | (x << 16)) & 0x0000_ffff_0000_ffff;
    x = (x | (x << 8)) & 0x00ff_00ff_00ff_00ff;
    x = (x | (x << 4)) & 0x0f0f_0f0f_0f0f_0f0f;
    x = (x | (x << 2)) & 0x3333_3333_3333_3333;
    (x | (x << 1)) & 0x5555_5555_5555_5555
}

/// The even bits of `x` packed into the low 32 (the inverse of [`spread_bits`]).
fn compact_bits(x: u64) -> u32 {
    let mut x = x & 0x5555_5555_5555_5555;
    x = (x | (x >> 1)) & 0x3333_3333_3333_3333;
    x = (x | (x >> 2)) & 0x0f0f_0f0f_0f0f_0f0f;
    x = (x | (x >> 4)) & 0x00ff_00ff_00ff_00ff;
    x = (x | (x >> 8)) & 0x0000_ffff_0000_ffff;
    ((x | (x >> 16)) & 0x0000_0000_ffff_ffff) as u32
}

impl NodeId {
    /// Deepest level addressable (indices are u32; DSS ids and traversal keys need 2 bits
    /// per level in 64 bits).
    pub const MAX_LEVEL: u8 = 30;

    /// The root.
    pub const ROOT: NodeId = NodeId { level: 0, i: 0, j: 0 };

    /// A node; panics when `i` or `j` is out of range for `level`.
    pub fn new(level: u8, i: u32, j: u32) -> Self {
        assert!(level <= Self::MAX_LEVEL, "level {level} too deep");
        assert!(
            i < (1u32 << level) && j < (1u32 << level),
            "node ({i}, {j}) outside level {level}"
        );
        Self { level, i, j }
    }

    /// The node packed into one integer, a linear quadtree's locational code: a marker bit
    /// at `2 level` above the Morton interleaving of `i` (even bits) and `j` (odd bits)
    /// (Gargantini 1982, "An effective way to represent quadtrees"). Distinct nodes have
    /// distinct keys at every level (61 bits at the deepest), and hashing one `u64` is
    /// cheaper than three fields.
    pub fn key(self) -> u64 {
        (1u64 << (2 * u32::from(self.level))) | spread_bits(self.i) | (spread_bits(self.j) << 1)
    }

    /// The node of [`NodeId::key`].
    pub fn from_key(k: u64) -> NodeId {
        let level = ((63 - k.leading_zeros()) / 2) as u8;
        let m = k & !(1u64 << (2 * u32::from(level)));
        NodeId { level, i: compact_bits(m), j: compact_bits(m >> 1) }
    }

    /// Nodes per side at this level: `2^level`.
    pub fn nodes_per_side(self) -> u32 {
        1u32 << self.level
    }

    /// The parent, or `None` for the root.
    pub fn parent(self) -> Option<NodeId> {
        (self.level > 0).then(|| NodeId { level: self.level - 1, i: self.i >> 1, j: self.j >> 1 })
    }

    /// The ancestor at `level` (`self` when equal); panics if `level > self.level`.
    pub fn ancestor(self, level: u8) -> NodeId {
        assert!(level <= self.level);
        let s = self.level - level;
        NodeId { level, i: self.i >> s, j: self.j >> s }
    }

    /// Whether `self` is `other` or one of its ancestors.
    pub fn is_ancestor_or_self_of(self, other: NodeId) -> bool {
        self.level <= other.level && other.ancestor(self.level) == self
    }

    /// The child in quadrant `q`.
    pub fn child(self, q: Quadrant) -> NodeId {
        let (di, dj) = q.offset();
        NodeId { level: self.level + 1, i: 2 * self.i + di, j: 2 * self.j + dj }
    }

    /// The four children in [`Quadrant::ALL`] order (SW, SE, NE, NW).
    pub fn children(self) -> [NodeId; 4] {
        Quadrant::ALL.map(|q| self.child(q))
    }

    /// Which quadrant of its parent this node is (root: `SouthWest`).
    pub fn quadrant(self) -> Quadrant {
        Quadrant::from_offset(self.i, self.j)
    }

    /// The same-level neighbour in direction `d`, or `None` past the root's border.
    pub fn neighbour(self, d: Direction) -> Option<NodeId> {
        let (di, dj) = d.step();
        let n = self.nodes_per_side() as i64;
        let (i, j) = (self.i as i64 + di, self.j as i64 + dj);
        (0..n).contains(&i).then_some(())?;
        (0..n).contains(&j).then_some(())?;
        Some(NodeId { level: self.level, i: i as u32, j: j as u32 })
    }

    /// The node's square in grid samples for a root of `root_cells` cells per side (a power
    /// of two): `(x0, y0, cells)`, covering samples `x0..=x0 + cells`, `y0..=y0 + cells`.
    /// Unclipped: see [`crate::quadtree::Quadtree::clipped_rect`] for grids that are not
    /// `2^L + 1` samples.
    pub fn grid_rect(self, root_cells: u32) -> (u32, u32, u32) {
        let cells = root_cells >> self.level;
        (self.i * cells, self.j * cells, cells)
    }

    /// A key ordering nodes depth-first in child order (SW, SE, NE, NW): the traversal's
    /// output order. Disjoint nodes never compare equal; an ancestor sorts before its
    /// descendants.
    ///
    /// O(1): the quadrant of the level-`l` ancestor is `2 j_b + (i_b xor j_b)` with `i_b`, `j_b`
    /// bit `level - l` of `i` and `j` (SW 0, SE 1, NE 2, NW 3), and level `l` takes key bits
    /// `63 - 2(l - 1)` and `62 - 2(l - 1)`; so the key is the bit interleaving (a Morton code)
    /// of `j` and `i xor j`, shifted to the top (sorting calls it `n log n` times).
    pub fn dfs_key(self) -> (u64, u8) {
        if self.level == 0 {
            return (0, 0);
        }
        let mask = if self.level >= 32 { u32::MAX } else { (1u32 << self.level) - 1 };
        let (i, j) = (self.i & mask, self.j & mask);
        let key = (spread_bits(j) << 1) | spread_bits(i ^ j);
        (key << (64 - 2 * u32::from(self.level)), self.level)
    }

    /// Whether two nodes share part of an edge (positive length), at any levels.
    pub fn shares_edge_with(self, other: NodeId) -> bool {
        let l = self.level.max(other.level);
        let r = |n: NodeId| {
            let s = 1u64 << (l - n.level);
            (n.i as u64 * s, n.j as u64 * s, (n.i as u64 + 1) * s, (n.j as u64 + 1) * s)
        };
        let (a, b) = (r(self), r(other));
        let x_overlap = a.0.max(b.0) < a.2.min(b.2);
        let y_overlap = a.1.max(b.1) < a.3.min(b.3);
        let x_touch = a.2 == b.0 || b.2 == a.0;
        let y_touch = a.3 == b.1 || b.3 == a.1;
        (x_touch && y_overlap) || (y_touch && x_overlap)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parent_children_round_trip() {
        let n = NodeId::new(3, 5, 2);
        for (k, c) in n.children().into_iter().enumerate() {
            assert_eq!(c.parent(), Some(n));
            assert_eq!(c.quadrant() as usize, k);
            assert_eq!(n.child(c.quadrant()), c);
        }
        assert_eq!(n.children()[2], NodeId::new(4, 11, 5));
        assert_eq!(NodeId::ROOT.parent(), None);
        assert_eq!(NodeId::new(5, 23, 17).ancestor(2), NodeId::new(2, 2, 2));
        assert!(NodeId::new(2, 2, 2).is_ancestor_or_self_of(NodeId::new(5, 23, 17)));
        assert!(!NodeId::new(2, 2, 1).is_ancestor_or_self_of(NodeId::new(5, 23, 17)));
    }

    #[test]
    fn neighbours_and_rects() {
        let n = NodeId::new(2, 0, 3);
        assert_eq!(n.neighbour(Direction::North), None);
        assert_eq!(n.neighbour(Direction::West), None);
        assert_eq!(n.neighbour(Direction::East), Some(NodeId::new(2, 1, 3)));
        assert_eq!(n.neighbour(Direction::South), Some(NodeId::new(2, 0, 2)));
        for d in Direction::ALL {
            if let Some(m) = n.neighbour(d) {
                assert_eq!(m.neighbour(d.opposite()), Some(n));
                assert!(m.shares_edge_with(n));
            }
        }
        assert_eq!(NodeId::new(2, 1, 3).grid_rect(64), (16, 48, 16));
        assert_eq!(NodeId::ROOT.grid_rect(64), (0, 0, 64));
        assert!(NodeId::new(1, 0, 0).shares_edge_with(NodeId::new(3, 4, 1)));
        assert!(!NodeId::new(1, 0, 0).shares_edge_with(NodeId::new(3, 4, 4))); // corner only
        assert!(!NodeId::new(1, 0, 0).shares_edge_with(NodeId::new(3, 5, 1)));
    }

    #[test]
    fn dfs_order() {
        let mut v = vec![
            NodeId::new(1, 1, 1),
            NodeId::new(2, 1, 0),
            NodeId::new(1, 0, 1),
            NodeId::new(2, 0, 0),
        ];
        v.sort_by_key(|n| n.dfs_key());
        // SW subtree (level-2 (0,0) then (1,0)), then NE (1,1,1), then NW (1,0,1).
        assert_eq!(
            v,
            [
                NodeId::new(2, 0, 0),
                NodeId::new(2, 1, 0),
                NodeId::new(1, 1, 1),
                NodeId::new(1, 0, 1)
            ]
        );
        assert!(NodeId::ROOT.dfs_key() < NodeId::new(1, 0, 0).dfs_key());
    }

    /// The former per-level loop, kept as the reference of the O(1) key.
    fn dfs_key_reference(n: NodeId) -> (u64, u8) {
        let mut key = 0u64;
        for l in 1..=n.level {
            let q = n.ancestor(l).quadrant() as u64;
            key |= q << (62 - 2 * (l as u32 - 1));
        }
        (key, n.level)
    }

    #[test]
    fn dfs_key_matches_the_per_level_definition() {
        // Every node down to level 5, and pseudo-random ones at every level to the deepest.
        let mut seen = std::collections::HashSet::new();
        for level in 0..=5u8 {
            for j in 0..1u32 << level {
                for i in 0..1u32 << level {
                    let n = NodeId::new(level, i, j);
                    assert_eq!(n.dfs_key(), dfs_key_reference(n), "{n:?}");
                    assert!(seen.insert(n.dfs_key()), "keys of distinct nodes differ");
                }
            }
        }
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        for level in 0..=NodeId::MAX_LEVEL {
            for _ in 0..200 {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                let m = (1u64 << level) - 1;
                let n = NodeId::new(level, (x & m) as u32, ((x >> 32) & m) as u32);
                assert_eq!(n.dfs_key(), dfs_key_reference(n), "{n:?}");
            }
        }
    }
}
