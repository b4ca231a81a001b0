//! What a LOD method reads from terrain, wherever the terrain is held: [`TerrainSource`].
//!
//! A method's selection needs, per quadtree node, its bounds (the [`NodeSource`] that the one
//! [`traverse`](crate::quadtree::traverse) walks), the quadtree's geometry ([`TreeShape`]:
//! which nodes exist, how they are clipped and placed in the world) and heights at patch
//! corners (Algorithm 1's screen-space edge lengths). Its per-node error tables (roughness
//! pyramids, the DSS paper's object-space errors) come as [`super::NodeField`]s and
//! [`super::DssErrorTable`]s beside the source, from memory or from a baked scene's files.
//!
//! Two implementations: [`GridSource`] (a heightmap in memory and its [`Quadtree`]) and a
//! baked store's resident pages (terrain-stream's `StoreSource`: node bounds from the store's
//! index, heights from the resident levels, each block's nodes finest where its resident
//! level stops). With every level resident, a store answers exactly what the heightmap it was
//! baked from answers, so a method selects the same patches from either.

use glam::DVec2;

use crate::heightmap::Heightmap;
use crate::quadtree::{NodeId, NodeInfo, NodeSource, NodeTree, Quadtree, TreeShape};

/// Terrain as the LOD methods read it: per-node bounds and the quadtree's geometry
/// ([`NodeTree`]; [`NodeInfo::is_finest`] stops the descent where the source holds nothing
/// finer) and heights. See the module docs.
pub trait TerrainSource: NodeTree {
    /// Bilinear height (metres) at fractional grid position `g` (samples; clamped to the grid),
    /// from the finest data the source holds there.
    fn height(&self, g: DVec2) -> f32;

    /// [`TerrainSource::height`] at each of `points`, into `out` (cleared first): the same
    /// values as one call each, asked together so that a source may look them up together
    /// (a store's under one lock, in a loop of lookups that do not wait for each other).
    fn heights(&self, points: &[DVec2], out: &mut Vec<f32>) {
        out.clear();
        out.extend(points.iter().map(|&g| self.height(g)));
    }
}

/// The in-memory terrain source: a heightmap and its quadtree.
#[derive(Debug, Clone, Copy)]
pub struct GridSource<'a> {
    qt: &'a Quadtree,
    hm: &'a Heightmap,
}

impl<'a> GridSource<'a> {
    /// `qt` over `hm`.
    ///
    /// # Panics
    /// If `qt` was built for a grid of another size.
    pub fn new(qt: &'a Quadtree, hm: &'a Heightmap) -> Self {
        assert_eq!(
            (qt.width(), qt.height()),
            (hm.width() as u32, hm.height() as u32),
            "the quadtree of another grid"
        );
        Self { qt, hm }
    }

    /// The quadtree.
    pub fn quadtree(&self) -> &'a Quadtree {
        self.qt
    }

    /// The heightmap.
    pub fn heightmap(&self) -> &'a Heightmap {
        self.hm
    }
}

impl NodeSource for GridSource<'_> {
    fn node_info(&self, node: NodeId) -> Option<NodeInfo> {
        self.qt.node_info(node)
    }
}

impl NodeTree for GridSource<'_> {
    fn shape(&self) -> &TreeShape {
        self.qt.shape()
    }
}

impl TerrainSource for GridSource<'_> {
    fn height(&self, g: DVec2) -> f32 {
        self.hm.sample_grid(g.x, g.y)
    }
}

impl<T: TerrainSource + ?Sized> TerrainSource for &T {
    fn height(&self, g: DVec2) -> f32 {
        (**self).height(g)
    }

    fn heights(&self, points: &[DVec2], out: &mut Vec<f32>) {
        (**self).heights(points, out)
    }
}
