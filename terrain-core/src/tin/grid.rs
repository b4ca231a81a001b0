//! The grid-space TIN pyramid of the `tin` LOD method: tiles on a quadtree over the DEM's
//! grid (any DEM, georeferenced or not), each an error-bounded greedy Delaunay mesh, chosen
//! per frame by Cesium's screen-space error and joined without cracks.
//!
//! **Tiles.** The nodes of a [`Quadtree`] over the grid with leaves of
//! [`GridTinConfig::finest_cells`] cells (the crate's node addressing: the root covers the
//! next power of two of cells, nodes clipped at the east and north border). Tile `(L, i, j)`
//! is its node's samples meshed by the one tile mesher ([`super::tile::mesh_window`], greedy
//! Delaunay, verified against every non-void sample before use) within the level's bound
//!
//! `e_L = error_scale x 0.25 x (tile side in metres) / 65`,
//!
//! Cesium's estimate of a heightmap tile's geometric error
//! (`TerrainProvider.getEstimatedLevelZeroGeometricErrorForAHeightmap`: heightmap quality
//! 0.25, 65 samples per tile), halving per level as the tiles do. [`GridTinPyramid::build_with`]
//! takes the caller's map over the tiles (the app builds them on every core).
//!
//! **Selection** ([`GridTinPyramid::select`]): Cesium's screen-space error of a tile,
//! `sse = e_L x H / (d x 2 tan(fov_y / 2)) = e_L lambda / d` with `d` the distance from the
//! eye to the tile's box (the min/max pyramid's; the mesh lies within it, its vertices being
//! samples), refined while `sse > tau` (pixels), frustum-culled: the one [`traverse`].
//! `sse <= tau` bounds the projected error of every sample of a drawn tile (`delta <= e_L`
//! at a distance `>= d`), so `tau` bounds the largest pixel error; the p99 lies below it.
//!
//! **Cracks: shared borders and stitches.** Each side of a tile is simplified on its own
//! (Douglas-Peucker on the side's profile, [`super::tile::Borders::Simplified`]), so
//! neighbours at the same level share their border vertices exactly. Where a tile meets finer
//! neighbours, their border vertices differ from its own (T-junctions); the gap between the
//! two border polylines lies in the vertical plane of the side and is closed by a fan of
//! triangles over the polygon made of the fine side's polyline and the coarse side's
//! (*stitches*: every vertex a grid sample at its own height, so the tessellation renderer
//! draws them as extra triangles like any other, and every edge of the drawn surface is used
//! by exactly two triangles). A stitch has no area in plan, so the measurement (which locates
//! samples in plan) sees the tiles only. Skirts (Cesium's way) would need vertices below the
//! samples and cost two triangles per border segment of every drawn tile; stitches cost one
//! per border vertex of a level change only (see [`TinSurface`]).
//!
//! **Voids.** Void samples are never inserted as vertices by the greedy loop and never
//! measured; the surface over them interpolates the vertices around (tile corners and border
//! profile ends may be void samples: the readers' fill heights).

use std::time::{Duration, Instant};

use glam::DVec2;

use super::TinError;
use super::tile::{self, Borders};
use crate::geometry::Camera;
use crate::heightmap::Heightmap;
use crate::lod::SurfaceMesh;
use crate::mesh::verify::ErrorStats;
use crate::quadtree::{
    Direction, FrustumCull, LeafSet, NodeId, NodeInfo, Quadtree, Visit, traverse,
};

/// Cesium's heightmap quality of its geometric-error estimate.
pub const HEIGHTMAP_QUALITY: f64 = 0.25;

/// Samples across the nominal heightmap tile of Cesium's estimate.
pub const NOMINAL_TILE_SAMPLES: f64 = 65.0;

/// How the pyramid is built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridTinConfig {
    /// Factor on every level's bound (`> 0`; smaller: finer tiles). Default 1.
    pub error_scale: f64,
    /// Cells per side of the finest tiles (a power of two, at least 2). Default 8: bound
    /// `0.031` sample spacings.
    pub finest_cells: u32,
}

impl Default for GridTinConfig {
    fn default() -> Self {
        Self { error_scale: 1.0, finest_cells: 8 }
    }
}

/// The bound of tiles of `cells` cells per side on a grid of `spacing_m` metres per cell:
/// `error_scale x 0.25 x cells x spacing / 65` (see the module docs).
pub fn level_error(cells: u32, spacing_m: f64, error_scale: f64) -> f64 {
    error_scale * HEIGHTMAP_QUALITY * f64::from(cells) * spacing_m / NOMINAL_TILE_SAMPLES
}

/// One tile: its mesh over global grid samples and its border.
#[derive(Debug, Clone, PartialEq)]
pub struct GridTile {
    /// The tile's node.
    pub node: NodeId,
    /// Vertices: grid samples `[i, j]` of the whole grid.
    pub vertices: Vec<[u32; 2]>,
    /// Counter-clockwise (from above) triangles over `vertices`.
    pub triangles: Vec<[u32; 3]>,
    /// The border vertices of each side (indices into `vertices`), in [`Direction::ALL`]
    /// order (N, E, S, W), each ordered west to east or south to north.
    pub sides: [Vec<u32>; 4],
    /// The tile's bound, metres.
    pub bound: f64,
    /// The error measured against the tile's samples.
    pub measured: ErrorStats,
}

impl GridTile {
    /// The border vertices of side `d`, as grid samples, ordered along it.
    pub fn side(&self, d: Direction) -> impl Iterator<Item = [u32; 2]> + '_ {
        self.sides[side_index(d)].iter().map(|&k| self.vertices[k as usize])
    }
}

/// Index of `d` in [`Direction::ALL`].
fn side_index(d: Direction) -> usize {
    match d {
        Direction::North => 0,
        Direction::East => 1,
        Direction::South => 2,
        Direction::West => 3,
    }
}

/// The position of a sample along side `d` (x on north and south sides, y on east and west).
fn along(d: Direction, g: [u32; 2]) -> u32 {
    match d {
        Direction::North | Direction::South => g[0],
        Direction::East | Direction::West => g[1],
    }
}

/// Builds tile `node` of `tree` (a quadtree over `hm`) within `bound` metres, verified.
pub fn build_tile(
    hm: &Heightmap,
    tree: &Quadtree,
    node: NodeId,
    bound: f64,
) -> Result<GridTile, TinError> {
    let (level, x, y) = (u32::from(node.level), node.i, node.j);
    let rect = tree.clipped_rect(node).ok_or(TinError::OutsideGrid { level, x, y })?;
    let (x0, y0) = (rect.x0 as usize, rect.y0 as usize);
    let (w, h) = ((rect.x1 - rect.x0) as usize + 1, (rect.y1 - rect.y0) as usize + 1);
    let sub = tile::window(w, h, |i, j| (hm.get(x0 + i, y0 + j), hm.voids().get(x0 + i, y0 + j)));
    let (mesh, measured) = tile::mesh_window(&sub, bound, Borders::Simplified)
        .map_err(|e| TinError::from_tile(e, level, x, y))?;
    // Local positions are exact integers (one metre per sample from the origin).
    let local: Vec<[u32; 2]> = mesh.positions.iter().map(|p| [p.x as u32, p.y as u32]).collect();
    let (wl, hl) = ((w - 1) as u32, (h - 1) as u32);
    let mut sides: [Vec<u32>; 4] = Default::default();
    for d in Direction::ALL {
        let on = |g: &[u32; 2]| match d {
            Direction::North => g[1] == hl,
            Direction::East => g[0] == wl,
            Direction::South => g[1] == 0,
            Direction::West => g[0] == 0,
        };
        let mut k: Vec<u32> = (0..local.len() as u32).filter(|&k| on(&local[k as usize])).collect();
        k.sort_by_key(|&k| along(d, local[k as usize]));
        sides[side_index(d)] = k;
    }
    let vertices = local.iter().map(|g| [g[0] + rect.x0, g[1] + rect.y0]).collect();
    Ok(GridTile { node, vertices, triangles: mesh.triangles, sides, bound, measured })
}

/// The tile builder handed to [`GridTinPyramid::build_with`]'s map.
pub type TileBuilder<'a> = dyn Fn(NodeId) -> Result<GridTile, TinError> + Sync + 'a;

/// Every tile of the pyramid, level by level, and the tree the selection walks.
#[derive(Debug, Clone)]
pub struct GridTinPyramid {
    tree: Quadtree,
    /// Per level: tiles in row-major order of the level's nodes.
    levels: Vec<Vec<GridTile>>,
    /// Per level: its bound, metres.
    errors: Vec<f64>,
}

/// What one frame selects.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TinSelection {
    /// The drawn tiles, in traversal order.
    pub tiles: Vec<NodeId>,
    /// Nodes rejected by the frustum.
    pub culled: usize,
    /// CPU time of the selection.
    pub cpu_time: Duration,
}

/// A frame's surface: the tiles' meshes and the stitches between them.
#[derive(Debug, Clone, Default)]
pub struct TinSurface {
    /// The surface (vertices repeated per tile and per stitch; grid coordinates in `grid`).
    pub mesh: SurfaceMesh,
    /// Triangles of the tiles.
    pub tile_triangles: u64,
    /// Triangles of the stitches (no plan area).
    pub stitch_triangles: u64,
    /// Border segments of the drawn tiles (what skirts would hang from: two triangles each).
    pub border_segments: u64,
}

impl GridTinPyramid {
    /// The nodes to mesh for `hm` under `config` (coarse levels first) and the tree.
    fn plan(hm: &Heightmap, config: &GridTinConfig) -> (Quadtree, Vec<NodeId>) {
        let cells = config.finest_cells.clamp(2, 1 << 15).next_power_of_two();
        let tree = Quadtree::new(hm, cells);
        let mut nodes = Vec::new();
        for level in 0..=tree.max_level() {
            let (nx, ny) = tree.shape().level_dims(level);
            for j in 0..ny {
                for i in 0..nx {
                    nodes.push(NodeId::new(level, i, j));
                }
            }
        }
        (tree, nodes)
    }

    /// Builds every tile of `hm`: `map` receives the nodes and the tile builder and returns
    /// the builder's results in the nodes' order (serially, or on the caller's threads).
    pub fn build_with(
        hm: &Heightmap,
        config: &GridTinConfig,
        map: impl FnOnce(&[NodeId], &TileBuilder<'_>) -> Vec<Result<GridTile, TinError>>,
    ) -> Result<Self, TinError> {
        let (tree, nodes) = Self::plan(hm, config);
        let spacing = tree.spacing().max_element();
        let scale = if config.error_scale > 0.0 { config.error_scale } else { 1.0 };
        let errors: Vec<f64> = (0..=tree.max_level())
            .map(|l| level_error(tree.root_cells() >> l, spacing, scale))
            .collect();
        let build = |node: NodeId| build_tile(hm, &tree, node, errors[node.level as usize]);
        let built = map(&nodes, &build);
        let mut levels: Vec<Vec<GridTile>> = vec![Vec::new(); errors.len()];
        for r in built {
            let t = r?;
            levels[t.node.level as usize].push(t);
        }
        Ok(Self { tree, levels, errors })
    }

    /// The tree of tiles.
    pub fn tree(&self) -> &Quadtree {
        &self.tree
    }

    /// The bound of `level`, metres.
    pub fn level_error(&self, level: u8) -> f64 {
        self.errors.get(level as usize).copied().unwrap_or(0.0)
    }

    /// Tile `node`, if the pyramid has it.
    pub fn tile(&self, node: NodeId) -> Option<&GridTile> {
        if !self.tree.contains_node(node) {
            return None;
        }
        let (nx, _) = self.tree.shape().level_dims(node.level);
        self.levels.get(node.level as usize)?.get((node.j * nx + node.i) as usize)
    }

    /// Every tile, coarse levels first.
    pub fn tiles(&self) -> impl Iterator<Item = &GridTile> {
        self.levels.iter().flatten()
    }

    /// Cesium's screen-space error of tile `node` (box `info`) seen from `camera`, pixels:
    /// `e_L lambda / d` (infinite with the eye in the box).
    pub fn screen_error(&self, camera: &Camera, node: NodeId, info: &NodeInfo) -> f64 {
        let d = info.aabb.distance(camera.position);
        let e = self.level_error(node.level) * camera.lambda();
        if d > 0.0 { e / d } else { f64::INFINITY }
    }

    /// The tiles drawn from `camera` at a screen-space error of at most `tau_px` pixels
    /// (finest tiles excepted), frustum-culled.
    pub fn select(&self, camera: &Camera, tau_px: f64) -> TinSelection {
        let start = Instant::now();
        let lambda = camera.lambda();
        let eye = camera.position;
        let tau = if tau_px > 0.0 { tau_px } else { f64::MIN_POSITIVE };
        let mut split = |node: NodeId, info: &NodeInfo| {
            // sse > tau, without dividing: e lambda > tau d (always with the eye in the box).
            self.level_error(node.level) * lambda > tau * info.aabb.distance(eye)
        };
        let mut cull = FrustumCull::new(camera.frustum());
        let mut culled = 0;
        let tiles = traverse(&self.tree, &mut split, &mut cull, &mut |_, v| {
            culled += usize::from(v == Visit::Culled);
        });
        TinSelection { tiles, culled, cpu_time: start.elapsed() }
    }

    /// The surface of `tiles` over `hm` (the heights every vertex takes): the tiles' meshes
    /// and, with `stitch`, the stitches where a tile meets finer ones.
    pub fn surface(&self, hm: &Heightmap, tiles: &[NodeId], stitch: bool) -> TinSurface {
        let mut out = TinSurface::default();
        let m = &mut out.mesh;
        let push = |m: &mut SurfaceMesh, g: [u32; 2]| {
            let (x, y) = (f64::from(g[0]), f64::from(g[1]));
            m.grid.push(DVec2::new(x, y));
            m.positions.push(
                hm.grid_to_world(x, y).extend(f64::from(hm.get(g[0] as usize, g[1] as usize))),
            );
            (m.grid.len() - 1) as u32
        };
        for &node in tiles {
            let Some(t) = self.tile(node) else { continue };
            let base = m.grid.len() as u32;
            for &g in &t.vertices {
                push(m, g);
            }
            m.triangles.extend(t.triangles.iter().map(|tr| tr.map(|k| k + base)));
            out.tile_triangles += t.triangles.len() as u64;
            out.border_segments +=
                t.sides.iter().map(|s| s.len().saturating_sub(1) as u64).sum::<u64>();
        }
        if !stitch {
            return out;
        }
        let set = LeafSet::new(tiles.iter().copied());
        let mut polygon: Vec<[u32; 2]> = Vec::new();
        for &node in tiles {
            let Some(t) = self.tile(node) else { continue };
            for d in Direction::ALL {
                let across = set.neighbours(node, d);
                if across.is_empty() || across.iter().any(|n| n.level <= node.level) {
                    continue;
                }
                let coarse: Vec<[u32; 2]> = t.side(d).collect();
                let (Some(&s), Some(&e)) = (coarse.first(), coarse.last()) else { continue };
                let (a0, a1) = (along(d, s), along(d, e));
                let mut fine: Vec<[u32; 2]> = across
                    .iter()
                    .filter_map(|&n| self.tile(n))
                    .flat_map(|f| f.side(d.opposite()))
                    .filter(|g| (a0 + 1..a1).contains(&along(d, *g)))
                    .collect();
                fine.sort_by_key(|g| along(d, *g));
                fine.dedup();
                let inner = &coarse[1..coarse.len() - 1];
                if fine == inner {
                    continue;
                }
                // The polygon: s, the fine polyline, e, the coarse polyline back; a fan from s.
                polygon.clear();
                polygon.push(s);
                polygon.extend_from_slice(&fine);
                polygon.push(e);
                polygon.extend(inner.iter().rev());
                let base = m.grid.len() as u32;
                for &g in &polygon {
                    push(m, g);
                }
                for k in 1..polygon.len() as u32 - 1 {
                    m.triangles.push([base, base + k, base + k + 1]);
                }
                out.stitch_triangles += polygon.len() as u64 - 2;
            }
        }
        out
    }
}
