//! The quadtree over a heightmap: a min/max height pyramid per node, clipped to the grid.
//!
//! **Grids that are not `2^L + 1` samples.** The root covers `root_cells` cells per side,
//! the next power of two at or above `max(width - 1, height - 1)` (and at least
//! `leaf_cells`). A node covers samples `x0..=x0 + cells` (its [`NodeId::grid_rect`]); it
//! *exists* when it holds at least one grid cell (`x0 < width - 1` and `y0 < height - 1`,
//! with a one-sample-wide grid counting as one cell), and its [`NodeInfo::rect`] is clipped
//! to the grid's last sample. Nodes entirely outside are skipped by the traversal; partial
//! nodes keep their full [`NodeId`] and report their clipped rectangle and box, so patch
//! builders must use [`NodeInfo::rect`], not the unclipped square.

use glam::{DVec2, DVec3};

use super::node::NodeId;
use crate::geometry::Aabb;
use crate::heightmap::Heightmap;

/// An inclusive rectangle of grid samples: `x0..=x1` by `y0..=y1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct GridRect {
    /// First column.
    pub x0: u32,
    /// First row (south).
    pub y0: u32,
    /// Last column (inclusive).
    pub x1: u32,
    /// Last row (inclusive, north).
    pub y1: u32,
}

impl GridRect {
    /// Number of samples inside.
    pub fn samples(&self) -> u64 {
        (self.x1 - self.x0 + 1) as u64 * (self.y1 - self.y0 + 1) as u64
    }
}

/// What the traversal and the policies know about a node.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeInfo {
    /// The node's samples, clipped to the grid.
    pub rect: GridRect,
    /// Side of the unclipped node in cells: `root_cells >> level`.
    pub cells: u32,
    /// World box over the clipped rectangle: x/y from the georeference, z from the
    /// min/max of *every* sample in it, void samples' filled heights included (they are
    /// drawn, so culling must keep them).
    pub aabb: Aabb,
    /// Min and max over the non-void samples only; `None` when every sample is void.
    pub data_range: Option<(f32, f32)>,
    /// Whether any sample in the rectangle is void.
    pub has_voids: bool,
    /// Whether the node is at the quadtree's finest level (it cannot split).
    pub is_finest: bool,
}

impl NodeInfo {
    /// Side length of the *unclipped* node in metres along x and y.
    pub fn size_m(&self, spacing: DVec2) -> DVec2 {
        spacing * self.cells as f64
    }
}

#[derive(Debug, Clone, Copy)]
struct Range {
    min: f32,
    max: f32,
    dmin: f32,
    dmax: f32,
    voids: bool,
}

impl Range {
    const EMPTY: Range = Range {
        min: f32::INFINITY,
        max: f32::NEG_INFINITY,
        dmin: f32::INFINITY,
        dmax: f32::NEG_INFINITY,
        voids: false,
    };

    fn merge(&mut self, o: &Range) {
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
        self.dmin = self.dmin.min(o.dmin);
        self.dmax = self.dmax.max(o.dmax);
        self.voids |= o.voids;
    }
}

#[derive(Debug, Clone)]
struct Level {
    nx: u32,
    ny: u32,
    ranges: Vec<Range>,
}

/// A quadtree over a heightmap's grid with a void-aware min/max height pyramid.
#[derive(Debug, Clone)]
pub struct Quadtree {
    shape: TreeShape,
    levels: Vec<Level>,
}

/// The geometry of the quadtree over a grid, without heights: grid size, root and leaf cells,
/// levels, georeference. What every node space shares (the in-memory [`Quadtree`], a baked
/// store's tree), so that both address and clip nodes identically (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TreeShape {
    width: u32,
    height: u32,
    root_cells: u32,
    leaf_cells: u32,
    max_level: u8,
    origin: DVec2,
    spacing: DVec2,
}

impl TreeShape {
    /// The shape of a `width x height` sample grid (sample (0, 0) at world `origin`, `spacing`
    /// metres apart) with finest nodes of `leaf_cells` cells (a power of two): the root is the
    /// next power of two of cells at or above the larger side, and at least `leaf_cells`.
    ///
    /// # Panics
    /// If `leaf_cells` is not a power of two, the grid is empty, or the tree would be deeper
    /// than [`NodeId::MAX_LEVEL`].
    pub fn new(width: u32, height: u32, leaf_cells: u32, origin: DVec2, spacing: DVec2) -> Self {
        assert!(width >= 1 && height >= 1, "an empty grid has no quadtree");
        let cells = (width - 1).max(height - 1).max(1);
        let root_cells = cells.next_power_of_two().max(leaf_cells);
        Self::with_root(width, height, root_cells, leaf_cells, origin, spacing)
    }

    /// [`TreeShape::new`] with a larger root than the grid needs (a store's root covers whole
    /// blocks: a grid smaller than one block lies in the south-west corner of its root).
    ///
    /// # Panics
    /// If `root_cells` or `leaf_cells` is not a power of two, the root does not cover the grid
    /// or is smaller than a leaf, or the tree would be deeper than [`NodeId::MAX_LEVEL`].
    pub fn with_root(
        width: u32,
        height: u32,
        root_cells: u32,
        leaf_cells: u32,
        origin: DVec2,
        spacing: DVec2,
    ) -> Self {
        assert!(leaf_cells.is_power_of_two(), "leaf_cells must be a power of two");
        assert!(root_cells.is_power_of_two() && root_cells >= leaf_cells, "root of {root_cells}");
        assert!(width >= 1 && height >= 1, "an empty grid has no quadtree");
        assert!((width - 1).max(height - 1) <= root_cells, "the root does not cover the grid");
        let max_level = (root_cells / leaf_cells).trailing_zeros() as u8;
        assert!(max_level <= NodeId::MAX_LEVEL);
        Self { width, height, root_cells, leaf_cells, max_level, origin, spacing }
    }

    /// Nodes per side at `level` that hold at least one grid cell.
    pub fn level_dims(&self, level: u8) -> (u32, u32) {
        let c = self.root_cells >> level;
        let cx = (self.width - 1).max(1);
        let cy = (self.height - 1).max(1);
        (cx.div_ceil(c), cy.div_ceil(c))
    }

    fn clip(&self, n: NodeId) -> GridRect {
        let (x0, y0, c) = n.grid_rect(self.root_cells);
        GridRect { x0, y0, x1: (x0 + c).min(self.width - 1), y1: (y0 + c).min(self.height - 1) }
    }

    /// Grid width in samples.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Grid height in samples.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Cells per side of the root (a power of two).
    pub fn root_cells(&self) -> u32 {
        self.root_cells
    }

    /// Cells per side of a finest-level node.
    pub fn leaf_cells(&self) -> u32 {
        self.leaf_cells
    }

    /// The finest level: `log2(root_cells / leaf_cells)`.
    pub fn max_level(&self) -> u8 {
        self.max_level
    }

    /// Grid spacing in metres (x east, y north).
    pub fn spacing(&self) -> DVec2 {
        self.spacing
    }

    /// World position of sample (0, 0).
    pub fn world_origin(&self) -> DVec2 {
        self.origin
    }

    /// World plan position of fractional grid position `g`.
    pub fn grid_to_world(&self, g: DVec2) -> DVec2 {
        self.origin + g * self.spacing
    }

    /// Side of the root patch in metres along x and y (the PVPS paper's `Length`).
    pub fn root_length_m(&self) -> DVec2 {
        self.spacing * self.root_cells as f64
    }

    /// Whether `n` is within `max_level` and holds at least one grid cell.
    pub fn contains_node(&self, n: NodeId) -> bool {
        if n.level > self.max_level {
            return false;
        }
        let (nx, ny) = self.level_dims(n.level);
        n.i < nx && n.j < ny
    }

    /// The node's samples clipped to the grid, or `None` when it holds no cell.
    pub fn clipped_rect(&self, n: NodeId) -> Option<GridRect> {
        self.contains_node(n).then(|| self.clip(n))
    }

    /// The world plan box of clipped rectangle `rect`: `(south-west, north-east)`.
    pub fn plan_box(&self, rect: &GridRect) -> (DVec2, DVec2) {
        let lo = self.origin + DVec2::new(rect.x0 as f64, rect.y0 as f64) * self.spacing;
        let hi = self.origin + DVec2::new(rect.x1 as f64, rect.y1 as f64) * self.spacing;
        (lo, hi)
    }
}

impl Quadtree {
    /// Builds the quadtree for `hm` with finest nodes of `leaf_cells x leaf_cells` cells
    /// (a power of two; e.g. 1 for per-cell nodes, 16..64 for GPU patches).
    ///
    /// Memory is about 20 bytes per node: `(cells / leaf_cells)^2 * 4/3` nodes.
    pub fn new(hm: &Heightmap, leaf_cells: u32) -> Self {
        let (w, h) = (hm.width() as u32, hm.height() as u32);
        let g = hm.georef();
        let shape = TreeShape::new(w, h, leaf_cells, g.world_origin, g.spacing_m);
        let max_level = shape.max_level;
        let mut qt = Self { shape, levels: Vec::new() };
        // Finest level from the samples, coarser levels by merging children.
        let mut levels: Vec<Level> = Vec::with_capacity(max_level as usize + 1);
        let (nx, ny) = qt.level_dims(max_level);
        let mut ranges = vec![Range::EMPTY; (nx * ny) as usize];
        let voids = hm.voids();
        for j in 0..ny {
            for i in 0..nx {
                let r = qt.clip(NodeId { level: max_level, i, j });
                let mut acc = Range::EMPTY;
                for y in r.y0..=r.y1 {
                    let row = &hm.data()[y as usize * w as usize..][..w as usize];
                    for x in r.x0..=r.x1 {
                        let z = row[x as usize];
                        acc.min = acc.min.min(z);
                        acc.max = acc.max.max(z);
                        if voids.any() && voids.get(x as usize, y as usize) {
                            acc.voids = true;
                        } else {
                            acc.dmin = acc.dmin.min(z);
                            acc.dmax = acc.dmax.max(z);
                        }
                    }
                }
                ranges[(j * nx + i) as usize] = acc;
            }
        }
        levels.push(Level { nx, ny, ranges });
        for level in (0..max_level).rev() {
            let (nx, ny) = qt.level_dims(level);
            let fine = levels.last().expect("finer level");
            let mut ranges = vec![Range::EMPTY; (nx * ny) as usize];
            for j in 0..ny {
                for i in 0..nx {
                    let acc = &mut ranges[(j * nx + i) as usize];
                    for (ci, cj) in [
                        (2 * i, 2 * j),
                        (2 * i + 1, 2 * j),
                        (2 * i, 2 * j + 1),
                        (2 * i + 1, 2 * j + 1),
                    ] {
                        if ci < fine.nx && cj < fine.ny {
                            acc.merge(&fine.ranges[(cj * fine.nx + ci) as usize]);
                        }
                    }
                }
            }
            levels.push(Level { nx, ny, ranges });
        }
        levels.reverse();
        qt.levels = levels;
        qt
    }

    fn level_dims(&self, level: u8) -> (u32, u32) {
        self.shape.level_dims(level)
    }

    fn clip(&self, n: NodeId) -> GridRect {
        self.shape.clip(n)
    }

    /// The tree's geometry (what a store's tree of the same grid shares).
    pub fn shape(&self) -> &TreeShape {
        &self.shape
    }

    /// Grid width in samples.
    pub fn width(&self) -> u32 {
        self.shape.width
    }

    /// Grid height in samples.
    pub fn height(&self) -> u32 {
        self.shape.height
    }

    /// Cells per side of the root (a power of two).
    pub fn root_cells(&self) -> u32 {
        self.shape.root_cells
    }

    /// Cells per side of a finest-level node.
    pub fn leaf_cells(&self) -> u32 {
        self.shape.leaf_cells
    }

    /// The finest level: `log2(root_cells / leaf_cells)`.
    pub fn max_level(&self) -> u8 {
        self.shape.max_level
    }

    /// Grid spacing in metres (x east, y north).
    pub fn spacing(&self) -> DVec2 {
        self.shape.spacing
    }

    /// World position of sample (0, 0).
    pub fn world_origin(&self) -> DVec2 {
        self.shape.origin
    }

    /// Side of the root patch in metres along x and y (the PVPS paper's `Length`).
    pub fn root_length_m(&self) -> DVec2 {
        self.shape.root_length_m()
    }

    /// Whether `n` is within `max_level` and holds at least one grid cell.
    pub fn contains_node(&self, n: NodeId) -> bool {
        self.shape.contains_node(n)
    }

    /// The node's samples clipped to the grid, or `None` when it holds no cell.
    pub fn clipped_rect(&self, n: NodeId) -> Option<GridRect> {
        self.shape.clipped_rect(n)
    }

    /// Everything the policies need about `n`, or `None` when it holds no grid cell.
    pub fn node_info(&self, n: NodeId) -> Option<NodeInfo> {
        if !self.contains_node(n) {
            return None;
        }
        let lv = &self.levels[n.level as usize];
        let r = lv.ranges[(n.j * lv.nx + n.i) as usize];
        let rect = self.clip(n);
        let (lo, hi) = self.shape.plan_box(&rect);
        Some(NodeInfo {
            rect,
            cells: self.shape.root_cells >> n.level,
            aabb: Aabb {
                min: DVec3::new(lo.x, lo.y, r.min as f64),
                max: DVec3::new(hi.x, hi.y, r.max as f64),
            },
            data_range: (r.dmin <= r.dmax).then_some((r.dmin, r.dmax)),
            has_voids: r.voids,
            is_finest: n.level == self.shape.max_level,
        })
    }

    /// The world-space plan rectangle of the clipped node: `(south-west, north-east)`.
    pub fn node_plan_rect(&self, n: NodeId) -> Option<(DVec2, DVec2)> {
        self.node_info(n).map(|i| (i.aabb.min.truncate(), i.aabb.max.truncate()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::georef::Georef;
    use crate::heightmap::VoidMask;

    fn hm(w: usize, h: usize) -> Heightmap {
        Heightmap::from_fn(w, h, Georef::local(2.0), |i, j| (i * 3 + j * 7) as f32).unwrap()
    }

    #[test]
    fn sizes_and_clipping() {
        let q = Quadtree::new(&hm(1000, 777), 1);
        assert_eq!(q.root_cells(), 1024);
        assert_eq!(q.max_level(), 10);
        // Level 10: 999 x 776 nodes hold cells.
        assert!(q.contains_node(NodeId::new(10, 998, 775)));
        assert!(!q.contains_node(NodeId::new(10, 999, 0)));
        assert!(!q.contains_node(NodeId::new(10, 0, 776)));
        // Level 1: the north half starts at row 512 < 776: exists, clipped to row 776.
        let r = q.clipped_rect(NodeId::new(1, 1, 1)).unwrap();
        assert_eq!(r, GridRect { x0: 512, y0: 512, x1: 999, y1: 776 });
        let info = q.node_info(NodeId::ROOT).unwrap();
        assert_eq!(info.rect, GridRect { x0: 0, y0: 0, x1: 999, y1: 776 });
        assert_eq!(info.aabb.min, DVec3::new(0.0, 0.0, 0.0));
        assert_eq!(info.aabb.max, DVec3::new(1998.0, 1552.0, (999 * 3 + 776 * 7) as f64));
        let q = Quadtree::new(&hm(1000, 777), 64);
        assert_eq!(q.max_level(), 4);
        assert!(
            q.contains_node(NodeId::new(4, 15, 12)) && !q.contains_node(NodeId::new(4, 15, 13))
        );
    }

    #[test]
    fn tiny_grids() {
        for (w, h) in [(1, 1), (2, 2), (3, 3), (2, 5)] {
            let q = Quadtree::new(&hm(w, h), 1);
            let info = q.node_info(NodeId::ROOT).unwrap();
            assert_eq!(info.rect.x1 as usize, w - 1);
            assert_eq!(info.rect.y1 as usize, h - 1);
            assert_eq!(info.aabb.max.z, ((w - 1) * 3 + (h - 1) * 7) as f64);
        }
        let q = Quadtree::new(&hm(3, 3), 1);
        assert_eq!((q.root_cells(), q.max_level()), (2, 1));
        let q = Quadtree::new(&hm(2, 2), 16);
        assert_eq!((q.root_cells(), q.max_level()), (16, 0));
    }

    #[test]
    fn pyramid_matches_brute_force_and_is_void_aware() {
        let (w, h) = (37, 23);
        let mut data: Vec<f32> = (0..w * h).map(|k| ((k * 7919) % 101) as f32).collect();
        let mut voids = VoidMask::new(w, h);
        // A void with a wild filled value: it stays in the box but not in the data range.
        voids.set(5, 5, true);
        data[5 * w + 5] = 1000.0;
        // A whole void block in the north-east corner.
        for j in 16..23 {
            for i in 32..37 {
                voids.set(i, j, true);
            }
        }
        let hm = Heightmap::new(w, h, data.clone(), voids.clone(), Georef::local(1.0)).unwrap();
        let q = Quadtree::new(&hm, 4);
        for level in 0..=q.max_level() {
            let n = 1u32 << level;
            for j in 0..n {
                for i in 0..n {
                    let id = NodeId::new(level, i, j);
                    let Some(info) = q.node_info(id) else { continue };
                    let r = info.rect;
                    let (mut lo, mut hi, mut dlo, mut dhi) =
                        (f32::MAX, f32::MIN, f32::MAX, f32::MIN);
                    let mut any_void = false;
                    for y in r.y0..=r.y1 {
                        for x in r.x0..=r.x1 {
                            let z = data[y as usize * w + x as usize];
                            lo = lo.min(z);
                            hi = hi.max(z);
                            any_void |= voids.get(x as usize, y as usize);
                            if !voids.get(x as usize, y as usize) {
                                dlo = dlo.min(z);
                                dhi = dhi.max(z);
                            }
                        }
                    }
                    assert_eq!(
                        (info.aabb.min.z, info.aabb.max.z),
                        (lo as f64, hi as f64),
                        "{id:?}"
                    );
                    assert_eq!(info.data_range, (dlo <= dhi).then_some((dlo, dhi)), "{id:?}");
                    assert_eq!(info.has_voids, any_void, "{id:?}");
                }
            }
        }
        // The node holding (5, 5) has 1000 in its box only.
        let info = q.node_info(NodeId::new(q.max_level(), 1, 1)).unwrap();
        assert_eq!(info.aabb.max.z, 1000.0);
        assert!(info.data_range.unwrap().1 < 1000.0);
        assert!(info.has_voids);
        assert!(!q.node_info(NodeId::new(q.max_level(), 3, 1)).unwrap().has_voids);
        // A node entirely void has no data range.
        let info = q.node_info(NodeId::new(q.max_level(), 8, 4)).unwrap();
        assert_eq!(info.rect, GridRect { x0: 32, y0: 16, x1: 36, y1: 20 });
        assert_eq!(info.data_range, None);
    }
}
