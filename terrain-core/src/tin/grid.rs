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
//! takes the caller's map over the tiles (the app builds them on every core). A caller that
//! meshes coarse tiles from decimated samples may give a tile a larger bound than its level's
//! ([`GridTile::bound`]: where the samples at the finest stride it allows a coarse tile stray
//! from the surface by more than the level's bound leaves room for; see the app's
//! `GridTileBuilder`); the selection then refines that tile by its own bound.
//!
//! **Selection** ([`GridTinPyramid::select`]): Cesium's screen-space error of a tile,
//! `sse = e x H / (d x 2 tan(fov_y / 2)) = e lambda / d` with `e` the tile's bound (`e_L` but
//! where raised as above) and `d` the distance from the eye to the tile's box (the min/max
//! pyramid's; the mesh lies within it, its vertices being samples), refined while
//! `sse > tau` (pixels), frustum-culled: the one [`traverse`].
//! `sse <= tau` bounds the projected error of every sample of a drawn tile (`delta <= e`
//! at a distance `>= d`), so `tau` bounds the largest pixel error; the p99 lies below it.
//!
//! **Cracks: shared borders and stitches.** Each side of a tile is simplified on its own
//! (Douglas-Peucker on the side's profile, [`super::tile::Borders::Simplified`]), so
//! neighbours at the same level share their border vertices exactly (when meshed within the
//! same budget at the same stride; tiles built from decimated samples within different budgets
//! get the stitches below between them too). Where a tile meets finer
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
use crate::heightmap::{Heightmap, VoidMask};
use crate::lod::SurfaceMesh;
use crate::mesh::verify::MaxError;
use crate::quadtree::{
    Direction, FrustumCull, LeafSet, NodeId, NodeInfo, NodeSource, Quadtree, TreeShape, Visit,
    traverse,
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
    /// Most cells across a tile's mesh input: a tile spanning more is meshed from every
    /// `2^s`-th sample, `s` the smallest with at most this many cells across ([`tile_window`]).
    /// `None` (the default in memory): every tile from all of its samples, so its bound holds
    /// against every sample; a store's tiles read a bounded number of samples
    /// (`Some(64)`), their bound holding against the samples they were built from.
    pub max_tile_cells: Option<u32>,
    /// With `max_tile_cells`, where the decimation errors are known before the tiles are built
    /// (a store's table, or measured at once in memory): how many strides finer than its own
    /// a tile is meshed at most, so its window spans at most `max_tile_cells x
    /// 2^finer_strides` cells; a tile that its level's bound would need finer gets a larger
    /// bound, by which the selection refines it (the app's `GridTileBuilder`). Default 5
    /// (windows of at most 2048 cells, 4.2 M samples, at the store's 64; `terrain tiles`'
    /// piece size): on the mirrored Everest (16385^2) 1.17x the triangles of tiles all within
    /// their level's bound at 1 px, where 2 (256 cells) draws 5x as many (a raised coarse
    /// tile hands more of the view to finer tiles), for faster builds (its first `fast_pass`
    /// frame over the 32769^2 synthetic store waits 1.2 s instead of 25.5 s; 116 s with no
    /// cap; bench/ooc/README.md, "The tin method's coarse tiles"). 31: every tile within its
    /// level's bound, from every sample if it must.
    pub finer_strides: u32,
}

impl Default for GridTinConfig {
    fn default() -> Self {
        Self { error_scale: 1.0, finest_cells: 8, max_tile_cells: None, finer_strides: 5 }
    }
}

/// Every level's bound for a tree of `shape` (level 0 first), metres.
pub fn level_errors(shape: &TreeShape, error_scale: f64) -> Vec<f64> {
    let spacing = shape.spacing().max_element();
    let scale = if error_scale > 0.0 { error_scale } else { 1.0 };
    (0..=shape.max_level()).map(|l| level_error(shape.root_cells() >> l, spacing, scale)).collect()
}

/// The samples a tile is built from: columns `x0 + a 2^s` for `a < width` and rows
/// `y0 + b 2^s` for `b < height`, `s = stride_log2`, the last ones on the tile's clipped
/// east and north borders.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TileWindow {
    /// First column.
    pub x0: u32,
    /// First row.
    pub y0: u32,
    /// Columns read.
    pub width: usize,
    /// Rows read.
    pub height: usize,
    /// log2 of the stride between the samples read.
    pub stride_log2: u32,
}

/// The window tile `node` of a tree of `shape` is built from (`None` outside the grid): its
/// clipped rectangle at the smallest stride `2^s` with at most `max_cells` cells across, and
/// no larger than what divides both clipped spans (a tile clipped at the grid's east or north
/// border keeps its last column and row on the lattice; such tiles read more samples).
pub fn tile_window(shape: &TreeShape, node: NodeId, max_cells: Option<u32>) -> Option<TileWindow> {
    let rect = shape.clipped_rect(node)?;
    let (wc, hc) = (rect.x1 - rect.x0, rect.y1 - rect.y0);
    let mut s = 0;
    if let Some(max) = max_cells {
        let max = max.max(2);
        while (wc.max(hc) >> s) > max && s < 31 {
            s += 1;
        }
        s = s.min(wc.trailing_zeros()).min(hc.trailing_zeros());
    }
    Some(TileWindow {
        x0: rect.x0,
        y0: rect.y0,
        width: (wc >> s) as usize + 1,
        height: (hc >> s) as usize + 1,
        stride_log2: s,
    })
}

/// The bound of tiles of `cells` cells per side on a grid of `spacing_m` metres per cell:
/// `error_scale x 0.25 x cells x spacing / 65` (see the module docs).
pub fn level_error(cells: u32, spacing_m: f64, error_scale: f64) -> f64 {
    error_scale * HEIGHTMAP_QUALITY * f64::from(cells) * spacing_m / NOMINAL_TILE_SAMPLES
}

/// One tile: its mesh over global grid samples, their heights and its border: everything
/// the renderer and the surface need, so a tile built from a store is drawn without the grid.
#[derive(Debug, Clone, PartialEq)]
pub struct GridTile {
    /// The tile's node.
    pub node: NodeId,
    /// Vertices: grid samples `[i, j]` of the whole grid.
    pub vertices: Vec<[u32; 2]>,
    /// The height of each vertex (its sample's), metres.
    pub heights: Vec<f32>,
    /// log2 of the stride of the samples the tile was built from ([`TileWindow`]).
    pub stride_log2: u32,
    /// Lowest and highest vertex height, metres.
    pub range: [f32; 2],
    /// Counter-clockwise (from above) triangles over `vertices`.
    pub triangles: Vec<[u32; 3]>,
    /// The border vertices of each side (indices into `vertices`), in [`Direction::ALL`]
    /// order (N, E, S, W), each ordered west to east or south to north.
    pub sides: [Vec<u32>; 4],
    /// The tile's bound, metres.
    pub bound: f64,
    /// The error measured against the tile's samples.
    pub measured: MaxError,
}

impl GridTile {
    /// Bytes the tile takes in memory (its vectors' contents; a cache's budget unit).
    pub fn bytes(&self) -> u64 {
        let sides: usize = self.sides.iter().map(Vec::len).sum();
        (std::mem::size_of::<Self>()
            + self.vertices.len() * 8
            + self.heights.len() * 4
            + self.triangles.len() * 12
            + sides * 4) as u64
    }

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

/// Builds tile `node` of `tree` (a quadtree over `hm`) within `bound` metres from all of its
/// samples, verified against every one of them.
pub fn build_tile(
    hm: &Heightmap,
    tree: &Quadtree,
    node: NodeId,
    bound: f64,
) -> Result<GridTile, TinError> {
    build_tile_at(hm, tree.shape(), node, bound, None)
}

/// Builds tile `node` of a tree of `shape` over `hm` within `bound` metres from the samples
/// of its [`tile_window`] under `max_cells` ([`build_tile_from`]).
pub fn build_tile_at(
    hm: &Heightmap,
    shape: &TreeShape,
    node: NodeId,
    bound: f64,
    max_cells: Option<u32>,
) -> Result<GridTile, TinError> {
    let (level, x, y) = (u32::from(node.level), node.i, node.j);
    let win = tile_window(shape, node, max_cells).ok_or(TinError::OutsideGrid { level, x, y })?;
    let (w, h) = (hm.width() - 1, hm.height() - 1);
    let s = win.stride_log2;
    let col = |a: usize| (win.x0 as usize + (a << s)).min(w);
    let row = |b: usize| (win.y0 as usize + (b << s)).min(h);
    // Voids are meshed as data: the reader's fill (the membrane of `dem::voids`) is what every
    // other method draws over a void, and what a store holds (a store keeps no void mask), so
    // the `tin` method draws the same surface there from memory and from a store, within its
    // bound of the fill.
    let mut heights = Vec::with_capacity(win.width * win.height);
    for b in 0..win.height {
        for a in 0..win.width {
            heights.push(hm.get(col(a), row(b)));
        }
    }
    build_tile_from(node, &win, &heights, None, bound)
}

/// The one tile builder from samples (in memory or read from a store): `heights` (row-major,
/// south row first) and `voids` are the samples of `win`; the tile is meshed by
/// [`tile::mesh_window`] within `bound` metres of them, verified against every non-void one,
/// and its vertices placed back on the whole grid.
pub fn build_tile_from(
    node: NodeId,
    win: &TileWindow,
    heights: &[f32],
    voids: Option<&VoidMask>,
    bound: f64,
) -> Result<GridTile, TinError> {
    build_tile_within(node, win, heights, voids, bound, bound, &[])
}

/// [`build_tile_from`] meshed within `budget` metres of the window's samples (a decimated
/// window's budget: the bound less the decimation error, so that the tile meets `bound`
/// against every sample under it, which the caller checks with [`tile_error_in`]); the tile
/// carries `bound`. The greedy insertion starts from `seeds` (grid samples; those inside the
/// window on its lattice are taken, as [`tile::mesh_window_seeded`] takes them: the
/// parent tile's vertices, where its insertion found the worst errors at twice the bound, so
/// the child's scans are for the refinements from there only: 1.3-1.6x faster on rough
/// terrain for the same bound, within 1 % of the triangles).
pub fn build_tile_within(
    node: NodeId,
    win: &TileWindow,
    heights: &[f32],
    voids: Option<&VoidMask>,
    budget: f64,
    bound: f64,
    seeds: &[[u32; 2]],
) -> Result<GridTile, TinError> {
    let (level, x, y) = (u32::from(node.level), node.i, node.j);
    let (w, h) = (win.width, win.height);
    let sub = tile::window(w, h, |i, j| (heights[j * w + i], voids.is_some_and(|v| v.get(i, j))));
    let s = win.stride_log2;
    let step = 1u32 << s;
    let local_seeds: Vec<[u32; 2]> = seeds
        .iter()
        .filter_map(|g| {
            let (dx, dy) = (g[0].checked_sub(win.x0)?, g[1].checked_sub(win.y0)?);
            let (i, j) = (dx >> s, dy >> s);
            (dx % step == 0 && dy % step == 0 && (i as usize) < w && (j as usize) < h)
                .then_some([i, j])
        })
        .collect();
    let (mesh, measured) =
        tile::mesh_window_seeded(&sub, budget, Borders::Simplified, &local_seeds)
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
    let heights: Vec<f32> = local.iter().map(|g| sub.get(g[0] as usize, g[1] as usize)).collect();
    let range = heights
        .iter()
        .fold([f32::INFINITY, f32::NEG_INFINITY], |[lo, hi], &z| [lo.min(z), hi.max(z)]);
    let vertices = local.iter().map(|g| [(g[0] << s) + win.x0, (g[1] << s) + win.y0]).collect();
    Ok(GridTile {
        node,
        vertices,
        heights,
        stride_log2: s,
        range,
        triangles: mesh.triangles,
        sides,
        bound,
        measured,
    })
}

/// The largest `|tile - sample|` over the grid samples in `rect` (`[x0, y0, x1, y1]`,
/// inclusive) that `sample(i, j)` gives (`None`: void, not measured), by the exact scan
/// conversion the meshers' verification uses; with `rect` the whole tile, the tile's error
/// against every sample under it (read window by window for a large tile: the samples of one
/// window at a time). Samples in no triangle are not measured (a tile covers its rectangle).
pub fn tile_error_in(
    tile: &GridTile,
    rect: [u32; 4],
    mut sample: impl FnMut(usize, usize) -> Option<f32>,
) -> f64 {
    let clip = rect.map(i64::from);
    let mut worst = 0f64;
    for t in &tile.triangles {
        let v = t.map(|k| tile.vertices[k as usize].map(i64::from));
        let lo = [v[0][0].min(v[1][0]).min(v[2][0]), v[0][1].min(v[1][1]).min(v[2][1])];
        let hi = [v[0][0].max(v[1][0]).max(v[2][0]), v[0][1].max(v[1][1]).max(v[2][1])];
        if hi[0] < clip[0] || lo[0] > clip[2] || hi[1] < clip[1] || lo[1] > clip[3] {
            continue;
        }
        let z = t.map(|k| f64::from(tile.heights[k as usize]));
        crate::mesh::raster::for_each_sample_in(v, z, clip, |i, j, m| {
            if let Some(s) = sample(i as usize, j as usize) {
                worst = worst.max((m - f64::from(s)).abs());
            }
        });
    }
    worst
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
    /// Per vertex of `mesh`: the index (in the tiles drawn) of the tile it belongs to; a
    /// stitch's vertices belong to its coarse tile, on whose side they lie.
    pub owner: Vec<u32>,
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
        let errors = level_errors(tree.shape(), config.error_scale);
        let max_cells = config.max_tile_cells;
        let build = |node: NodeId| {
            build_tile_at(hm, tree.shape(), node, errors[node.level as usize], max_cells)
        };
        let built = map(&nodes, &build);
        let mut levels: Vec<Vec<GridTile>> = vec![Vec::new(); errors.len()];
        for r in built {
            let t = r?;
            levels[t.node.level as usize].push(t);
        }
        Ok(Self { tree, levels, errors })
    }

    /// Builds every tile of `hm` by the caller's `build`, which receives the tree's shape,
    /// every level's bound and the nodes to build (coarse levels first) and returns their
    /// tiles in that order (the app's builder from any sample source, with its decimation
    /// budget and check).
    pub fn build_by<E>(
        hm: &Heightmap,
        config: &GridTinConfig,
        build: impl FnOnce(&TreeShape, &[f64], &[NodeId]) -> Result<Vec<GridTile>, E>,
    ) -> Result<Self, E> {
        let (tree, nodes) = Self::plan(hm, config);
        let errors = level_errors(tree.shape(), config.error_scale);
        let built = build(tree.shape(), &errors, &nodes)?;
        let mut levels: Vec<Vec<GridTile>> = vec![Vec::new(); errors.len()];
        for t in built {
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

    /// The bound of tile `node`, metres: the one it was built within ([`GridTile::bound`]),
    /// its level's or more (a tile meshed from decimated samples coarser than its level's
    /// bound allows); its level's for a node the pyramid lacks.
    pub fn tile_error(&self, node: NodeId) -> f64 {
        self.tile(node).map_or_else(|| self.level_error(node.level), |t| t.bound)
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
    /// `e lambda / d` with `e` the tile's bound (infinite with the eye in the box).
    pub fn screen_error(&self, camera: &Camera, node: NodeId, info: &NodeInfo) -> f64 {
        let d = info.aabb.distance(camera.position);
        let e = self.tile_error(node) * camera.lambda();
        if d > 0.0 { e / d } else { f64::INFINITY }
    }

    /// The tiles drawn from `camera` at a screen-space error of at most `tau_px` pixels
    /// (finest tiles excepted), frustum-culled ([`select_tiles`] over the pyramid's tree).
    pub fn select(&self, camera: &Camera, tau_px: f64) -> TinSelection {
        select_tiles(&self.tree, |n| self.tile_error(n), camera, tau_px)
    }

    /// The surface of `tiles` (the heights every vertex takes: its sample's, as `hm` holds
    /// it): the tiles' meshes and, with `stitch`, the stitches where a tile meets finer ones
    /// ([`tin_surface`]).
    pub fn surface(&self, hm: &Heightmap, tiles: &[NodeId], stitch: bool) -> TinSurface {
        let drawn: Vec<&GridTile> = tiles.iter().filter_map(|&n| self.tile(n)).collect();
        tin_surface(&drawn, |g| hm.grid_to_world(g.x, g.y), stitch)
    }
}

/// The tiles of a tree (`tree`: the in-memory quadtree, or a store's index) drawn from
/// `camera` at a screen-space error of at most `tau_px` pixels (finest tiles excepted),
/// frustum-culled: Cesium's `sse = e lambda / d > tau` refines (`error(node)`: the tile's
/// bound, its level's from [`level_errors`] or more for a tile meshed from decimated samples
/// coarser than the level's bound allows), through the one [`traverse`].
pub fn select_tiles<Q: NodeSource + ?Sized>(
    tree: &Q,
    error: impl Fn(NodeId) -> f64,
    camera: &Camera,
    tau_px: f64,
) -> TinSelection {
    let start = Instant::now();
    let lambda = camera.lambda();
    let eye = camera.position;
    let tau = if tau_px > 0.0 { tau_px } else { f64::MIN_POSITIVE };
    let mut split = |node: NodeId, info: &NodeInfo| {
        // sse > tau, without dividing: e lambda > tau d (always with the eye in the box).
        error(node) * lambda > tau * info.aabb.distance(eye)
    };
    let mut cull = FrustumCull::new(camera.frustum());
    let mut culled = 0;
    let tiles = traverse(tree, &mut split, &mut cull, &mut |_, v| {
        culled += usize::from(v == Visit::Culled);
    });
    TinSelection { tiles, culled, cpu_time: start.elapsed() }
}

/// Where [`tin_surface_into`] puts a surface: its vertices in order (the `n`-th call is
/// vertex `n`) and its triangles over them.
pub trait SurfaceSink {
    /// Makes room for `vertices` more vertices and `triangles` more triangles.
    fn reserve(&mut self, vertices: usize, triangles: usize);
    /// The next vertex: grid sample `g` at height `z`, of drawn tile `tile` (its index in the
    /// tiles; a stitch's vertices are its coarse tile's).
    fn vertex(&mut self, g: [u32; 2], z: f32, tile: u32);
    /// A triangle over the vertices so far (counter-clockwise from above).
    fn triangle(&mut self, t: [u32; 3]);
    /// A tile's vertices at once: [`SurfaceSink::vertex`] for each of `g` (heights `z`), of
    /// drawn tile `tile`. A sink that can write them in bulk overrides it.
    fn vertices(&mut self, g: &[[u32; 2]], z: &[f32], tile: u32) {
        for (&g, &z) in g.iter().zip(z) {
            self.vertex(g, z, tile);
        }
    }
    /// A tile's triangles at once, each vertex index offset by `base`:
    /// [`SurfaceSink::triangle`] for each. A sink that can write them in bulk overrides it.
    fn triangles(&mut self, t: &[[u32; 3]], base: u32) {
        for tr in t {
            self.triangle(tr.map(|v| v + base));
        }
    }
}

/// What [`tin_surface_into`] put in its sink, by kind.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SurfaceCounts {
    /// Triangles of the tiles.
    pub tile_triangles: u64,
    /// Triangles of the stitches (no plan area).
    pub stitch_triangles: u64,
    /// Border segments of the drawn tiles (what skirts would hang from: two triangles each).
    pub border_segments: u64,
}

/// The surface of the drawn `tiles` (disjoint nodes covering the view), vertices at their
/// tiles' heights and placed in the plane by `plan` (grid to world): the tiles' meshes and,
/// with `stitch`, the stitches where a tile meets finer ones (see the module docs). One
/// function for the pyramid in memory and the tiles built from a store
/// ([`tin_surface_into`] with a [`SurfaceMesh`] sink).
pub fn tin_surface(tiles: &[&GridTile], plan: impl Fn(DVec2) -> DVec2, stitch: bool) -> TinSurface {
    struct Mesh<P> {
        mesh: SurfaceMesh,
        owner: Vec<u32>,
        plan: P,
    }
    impl<P: Fn(DVec2) -> DVec2> SurfaceSink for Mesh<P> {
        fn reserve(&mut self, vertices: usize, triangles: usize) {
            self.mesh.grid.reserve(vertices);
            self.mesh.positions.reserve(vertices);
            self.owner.reserve(vertices);
            self.mesh.triangles.reserve(triangles);
        }
        fn vertex(&mut self, g: [u32; 2], z: f32, tile: u32) {
            let p = DVec2::new(f64::from(g[0]), f64::from(g[1]));
            self.mesh.grid.push(p);
            self.mesh.positions.push((self.plan)(p).extend(f64::from(z)));
            self.owner.push(tile);
        }
        fn triangle(&mut self, t: [u32; 3]) {
            self.mesh.triangles.push(t);
        }
    }
    let mut sink = Mesh { mesh: SurfaceMesh::default(), owner: Vec::new(), plan };
    let c = tin_surface_into(tiles, stitch, &mut sink);
    TinSurface {
        mesh: sink.mesh,
        tile_triangles: c.tile_triangles,
        stitch_triangles: c.stitch_triangles,
        border_segments: c.border_segments,
        owner: sink.owner,
    }
}

/// [`tin_surface`]'s vertices and triangles, in its order, into `sink` (the renderer's
/// buffers directly: a frame's surface is millions of vertices at 1280 x 720).
pub fn tin_surface_into(
    tiles: &[&GridTile],
    stitch: bool,
    sink: &mut impl SurfaceSink,
) -> SurfaceCounts {
    let mut out = SurfaceCounts::default();
    // The tiles' vertices and triangles and room for the stitches (each side vertex enters at
    // most one stitch as its coarse side's and one as its fine side's), reserved at once.
    let (mut nv, mut nt) = (0, 0);
    for t in tiles {
        let sides = if stitch { 2 * t.sides.iter().map(Vec::len).sum::<usize>() } else { 0 };
        nv += t.vertices.len() + sides;
        nt += t.triangles.len() + sides;
    }
    sink.reserve(nv, nt);
    let mut count = 0u32;
    for (k, t) in tiles.iter().enumerate() {
        let base = count;
        sink.vertices(&t.vertices, &t.heights, k as u32);
        count += t.vertices.len() as u32;
        sink.triangles(&t.triangles, base);
        out.tile_triangles += t.triangles.len() as u64;
        out.border_segments +=
            t.sides.iter().map(|s| s.len().saturating_sub(1) as u64).sum::<u64>();
    }
    if !stitch {
        return out;
    }
    let by_node: std::collections::HashMap<NodeId, &GridTile> =
        tiles.iter().map(|t| (t.node, *t)).collect();
    let set = LeafSet::new(tiles.iter().map(|t| t.node));
    let side = |t: &GridTile, d: Direction| -> Vec<([u32; 2], f32)> {
        t.sides[side_index(d)]
            .iter()
            .map(|&k| (t.vertices[k as usize], t.heights[k as usize]))
            .collect()
    };
    let mut polygon: Vec<([u32; 2], f32)> = Vec::new();
    for (k, t) in tiles.iter().enumerate() {
        let node = t.node;
        for d in Direction::ALL {
            let across = set.neighbours(node, d);
            // A same-level neighbour shares this side's vertices unless the two were meshed
            // within different budgets or strides (decimated tiles: the budget is the bound less
            // the decimation error under each); then the gap between the two polylines is
            // stitched like a level change, once per pair (from the south or west tile).
            let same = across.len() == 1 && across[0].level == node.level;
            if across.is_empty()
                || (same && !matches!(d, Direction::North | Direction::East))
                || (!same && across.iter().any(|n| n.level <= node.level))
            {
                continue;
            }
            let coarse = side(t, d);
            let (Some(&s), Some(&e)) = (coarse.first(), coarse.last()) else { continue };
            let (a0, a1) = (along(d, s.0), along(d, e.0));
            let mut fine: Vec<([u32; 2], f32)> = across
                .iter()
                .filter_map(|n| by_node.get(n))
                .flat_map(|f| side(f, d.opposite()))
                .filter(|g| (a0 + 1..a1).contains(&along(d, g.0)))
                .collect();
            fine.sort_by_key(|g| along(d, g.0));
            fine.dedup_by_key(|g| g.0);
            let inner = &coarse[1..coarse.len() - 1];
            if fine.iter().map(|g| g.0).eq(inner.iter().map(|g| g.0)) {
                continue;
            }
            // The polygon: s, the fine polyline, e, the coarse polyline back; a fan from s.
            polygon.clear();
            polygon.push(s);
            polygon.extend_from_slice(&fine);
            polygon.push(e);
            polygon.extend(inner.iter().rev());
            let base = count;
            for &(g, z) in &polygon {
                sink.vertex(g, z, k as u32);
            }
            count += polygon.len() as u32;
            for k in 1..polygon.len() as u32 - 1 {
                sink.triangle([base, base + k, base + k + 1]);
            }
            out.stitch_triangles += polygon.len() as u64 - 2;
        }
    }
    out
}
