//! An error-bounded TIN pyramid on Cesium's geographic tiling scheme: the meshes behind
//! `terrain tiles` (quantized-mesh-1.0, [`quantized_mesh`]).
//!
//! **Tiling.** The geographic tiling scheme of EPSG:4326 (Cesium's `GeographicTilingScheme`):
//! two root tiles at level 0 (west and east hemispheres, 180 x 180 degrees), each tile split
//! into four children per level; tile `(x, y)` at level `L` is `180 / 2^L` degrees wide with
//! `x` counted from -180 degrees east and `y` from -90 degrees north (TMS addressing).
//!
//! **Error per level.** A tile at level `L` is meshed with the bound
//! `e_L = scale * E_0 / 2^L` (halving per level), where `E_0` is the geometric error CesiumJS
//! assumes for a level-0 quantized-mesh tile ([`LEVEL_ZERO_ERROR_M`]), so a client refining by
//! screen-space error meets, at every level, a tile no worse than it assumes (`scale <= 1`).
//!
//! **One tile** ([`build_tile`]): the DEM samples that cover the tile's rectangle (the samples
//! inside it and one more on each side, where the DEM has them) are meshed by greedy Delaunay
//! insertion within `e_L` and verified against every non-void sample of that sub-grid by the
//! one tile mesher both pyramids share ([`tile::mesh_window`]; the grid-space pyramid of the
//! `tin` LOD method is [`grid`]), and then clipped to the tile's rectangle (Sutherland & Hodgman 1974, polygon clipping
//! against each border line in turn). Clipping keeps the surface, so every non-void DEM
//! sample inside the tile is within `e_L` of the tile's surface. Where the tile extends beyond
//! the DEM, the rest of its rectangle is filled at height 0 (the ellipsoid, as
//! cesium-terrain-builder fills no-data), so every tile covers its rectangle without holes.
//!
//! **Cracks: skirts.** Each tile is meshed on its own (tiles are independent, so they build in
//! any order and in parallel), so neighbours' borders may differ by up to about twice the bound.
//! Quantized-mesh clients hide that with skirts hung from the edge vertices (CesiumJS always
//! draws them, `5 e_L` deep), which the format's edge indices list; sharing border vertices
//! would cost triangles on both sides and remove nothing CesiumJS draws.
//!
//! **Voids.** Void samples are not measured (the DEM readers fill them for the surface, and the
//! builder and the check skip them); the tile's surface over a void is that fill's.

pub mod decimation;
pub mod grid;
pub mod quantized_mesh;
pub mod tile;
pub mod tile_file;
pub mod warp;

use glam::{DVec2, DVec3, dvec2};

use crate::georef::AngularOrLinear;
use crate::heightmap::{Heightmap, VoidMask};
use crate::mesh::verify::{MaxError, VerifyError};
use crate::mesh::{Algorithm, MeshError, TriMesh};

/// The geometric error CesiumJS assumes for a level-0 quantized-mesh tile, metres:
/// `TerrainProvider.getEstimatedLevelZeroGeometricErrorForAHeightmap` with the WGS84 radius,
/// heightmap quality 0.25, 65-sample tiles and two tiles at level 0:
/// `6378137 * 2 pi * 0.25 / (65 * 2)`.
pub const LEVEL_ZERO_ERROR_M: f64 = 6_378_137.0 * 2.0 * std::f64::consts::PI * 0.25 / 130.0;

/// Deepest level addressed (tiles of 180 / 2^30 degrees, about 2 cm).
pub const MAX_LEVEL: u32 = 30;

/// The bound of a tile at `level`: `scale * LEVEL_ZERO_ERROR_M / 2^level`, metres.
pub fn level_error(level: u32, scale: f64) -> f64 {
    scale * LEVEL_ZERO_ERROR_M / f64::from(1u32 << level.min(MAX_LEVEL))
}

/// A tile of the geographic tiling scheme (TMS: `y` counts from the south).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct TileId {
    /// Level (0: two tiles of 180 x 180 degrees).
    pub level: u32,
    /// Column from -180 degrees, eastwards.
    pub x: u32,
    /// Row from -90 degrees, northwards.
    pub y: u32,
}

impl TileId {
    /// The tile's side in degrees.
    pub fn size_deg(level: u32) -> f64 {
        180.0 / f64::from(1u32 << level.min(MAX_LEVEL))
    }

    /// The tile's rectangle, degrees.
    pub fn rect(&self) -> LonLatRect {
        let s = Self::size_deg(self.level);
        let west = -180.0 + f64::from(self.x) * s;
        let south = -90.0 + f64::from(self.y) * s;
        LonLatRect { west, south, east: west + s, north: south + s }
    }
}

/// A longitude/latitude rectangle, degrees.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct LonLatRect {
    /// Western longitude.
    pub west: f64,
    /// Southern latitude.
    pub south: f64,
    /// Eastern longitude.
    pub east: f64,
    /// Northern latitude.
    pub north: f64,
}

/// An inclusive rectangle of tiles at one level.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct TileRange {
    /// First column.
    #[serde(rename = "startX")]
    pub start_x: u32,
    /// First row.
    #[serde(rename = "startY")]
    pub start_y: u32,
    /// Last column (inclusive).
    #[serde(rename = "endX")]
    pub end_x: u32,
    /// Last row (inclusive).
    #[serde(rename = "endY")]
    pub end_y: u32,
}

impl TileRange {
    /// Whether the range holds tile `(x, y)`.
    pub fn contains(&self, x: u32, y: u32) -> bool {
        (self.start_x..=self.end_x).contains(&x) && (self.start_y..=self.end_y).contains(&y)
    }

    /// The tiles of the range, row by row.
    pub fn tiles(&self, level: u32) -> impl Iterator<Item = TileId> + '_ {
        (self.start_y..=self.end_y)
            .flat_map(move |y| (self.start_x..=self.end_x).map(move |x| TileId { level, x, y }))
    }

    /// Number of tiles.
    pub fn len(&self) -> u64 {
        u64::from(self.end_x - self.start_x + 1) * u64::from(self.end_y - self.start_y + 1)
    }

    /// Never empty (a range holds at least one tile); for clippy's `len` convention.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// The part of this range (at level `L + 1`) below tile `parent` (at level `L`).
    pub fn below(&self, parent: TileId) -> Option<TileRange> {
        let r = TileRange {
            start_x: self.start_x.max(2 * parent.x),
            start_y: self.start_y.max(2 * parent.y),
            end_x: self.end_x.min(2 * parent.x + 1),
            end_y: self.end_y.min(2 * parent.y + 1),
        };
        (r.start_x <= r.end_x && r.start_y <= r.end_y).then_some(r)
    }
}

/// Why a tile could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum TinError {
    /// The grid is not in degrees (reproject it first: [`warp::to_geographic`]).
    #[error("the TIN pyramid needs a grid in longitude/latitude degrees; this one is {crs}")]
    NotGeographic {
        /// The grid's CRS.
        crs: String,
    },
    /// The grid's extent is not within longitude -180..180, latitude -90..90.
    #[error(
        "the grid spans longitude {west}..{east}, latitude {south}..{north}: outside -180..180, -90..90 \
         (a grid wholly within longitudes 180..360 is shifted by -360; one crossing 180 must be split there)"
    )]
    OutOfRange {
        /// Western longitude.
        west: f64,
        /// Southern latitude.
        south: f64,
        /// Eastern longitude.
        east: f64,
        /// Northern latitude.
        north: f64,
    },
    /// The mesher refused the tile's sub-grid or bound.
    #[error("tile {level}/{x}/{y}: {source}")]
    Mesh {
        /// Level.
        level: u32,
        /// Column.
        x: u32,
        /// Row.
        y: u32,
        /// Why.
        source: MeshError,
    },
    /// The tile is not in the grid's quadtree (grid-space pyramid).
    #[error("tile {level}/{x}/{y} holds no cell of the grid")]
    OutsideGrid {
        /// Level.
        level: u32,
        /// Column.
        x: u32,
        /// Row.
        y: u32,
    },
    /// An RTIN was asked for a tile with locked borders (a caller's bug).
    #[error("tile {level}/{x}/{y}: an RTIN tile cannot lock its borders")]
    RtinLockedBorders {
        /// Level.
        level: u32,
        /// Column.
        x: u32,
        /// Row.
        y: u32,
    },
    /// A piece of the tile's samples, as read, does not make a grid (a reader's bug).
    #[error("tile {level}/{x}/{y}: a piece of its samples: {source}")]
    Piece {
        /// Level.
        level: u32,
        /// Column.
        x: u32,
        /// Row.
        y: u32,
        /// Why.
        source: crate::heightmap::HeightmapError,
    },
    /// The tile's mesh failed its check against the DEM (a bug: the mesher guarantees it).
    #[error("tile {level}/{x}/{y} failed its check against the DEM: {source}")]
    Verify {
        /// Level.
        level: u32,
        /// Column.
        x: u32,
        /// Row.
        y: u32,
        /// Why.
        source: VerifyError,
    },
}

impl TinError {
    /// The error of tile `level/x/y` from the tile mesher's.
    pub fn from_tile(e: tile::TileError, level: u32, x: u32, y: u32) -> Self {
        match e {
            tile::TileError::Mesh(source) => TinError::Mesh { level, x, y, source },
            tile::TileError::Verify(source) => TinError::Verify { level, x, y, source },
            tile::TileError::RtinLockedBorders => TinError::RtinLockedBorders { level, x, y },
            tile::TileError::Piece(source) => TinError::Piece { level, x, y, source },
        }
    }
}

/// Where a grid in longitude/latitude degrees lies, without its samples: its size, origin and
/// spacing. What the pyramid's tiling needs (extent, tile ranges, native level), shared by a
/// grid in memory ([`GeoGrid`]) and one read tile by tile from elsewhere (a baked store).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridLayout {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Longitude/latitude of sample (0, 0).
    pub origin: DVec2,
    /// Degrees per sample.
    pub spacing: DVec2,
}

impl GridLayout {
    /// The layout of a `width` x `height` grid whose georeference is geographic (degrees;
    /// taken as WGS84), checked to lie within longitude -180..180, latitude -90..90. A grid in
    /// the 0..360 convention (common for ocean and climate grids) that lies wholly east of 180
    /// is the same place 360 degrees west, and is shifted there.
    pub fn new(width: usize, height: usize, georef: &crate::Georef) -> Result<Self, TinError> {
        if georef.units != AngularOrLinear::Degrees {
            return Err(TinError::NotGeographic { crs: georef.crs.to_string() });
        }
        let mut layout =
            Self { width, height, origin: georef.native_origin, spacing: georef.native_spacing };
        let e = layout.extent();
        if e.west >= 180.0 && e.east <= 360.0 {
            layout.origin.x -= 360.0;
        }
        let e = layout.extent();
        let ok = e.west >= -180.0 && e.east <= 180.0 && e.south >= -90.0 && e.north <= 90.0;
        if !ok
            || layout.spacing.min_element().partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater)
        {
            return Err(TinError::OutOfRange {
                west: e.west,
                south: e.south,
                east: e.east,
                north: e.north,
            });
        }
        Ok(layout)
    }

    /// Fractional grid coordinates of a longitude/latitude.
    pub fn to_grid(&self, lonlat: DVec2) -> DVec2 {
        (lonlat - self.origin) / self.spacing
    }

    /// Longitude/latitude of fractional grid coordinates.
    pub fn to_lonlat(&self, g: DVec2) -> DVec2 {
        self.origin + g * self.spacing
    }

    /// The rectangle of the sample centres.
    pub fn extent(&self) -> LonLatRect {
        let (w, h) = (self.width as f64 - 1.0, self.height as f64 - 1.0);
        let ne = self.to_lonlat(dvec2(w, h));
        LonLatRect { west: self.origin.x, south: self.origin.y, east: ne.x, north: ne.y }
    }

    /// The tiles at `level` whose rectangle overlaps the grid's extent (with positive area).
    pub fn tile_range(&self, level: u32) -> TileRange {
        let e = self.extent();
        let s = TileId::size_deg(level);
        let (nx, ny) = (2u64 << level, 1u64 << level);
        let lo = |v: f64, n: u64| ((v / s).floor().max(0.0) as u64).min(n - 1) as u32;
        let hi = |v: f64, n: u64| (((v / s).ceil() - 1.0).max(0.0) as u64).min(n - 1) as u32;
        let (x0, x1) = (lo(e.west + 180.0, nx), hi(e.east + 180.0, nx));
        let (y0, y1) = (lo(e.south + 90.0, ny), hi(e.north + 90.0, ny));
        TileRange { start_x: x0, start_y: y0, end_x: x1.max(x0), end_y: y1.max(y0) }
    }

    /// The deepest level worth building: the first whose tiles span at most `cells` DEM
    /// samples across (cesium-terrain-builder's choice with `cells = 64`: a 65-sample tile at
    /// the DEM's resolution).
    pub fn native_level(&self, cells: f64) -> u32 {
        let per_sample = self.spacing.max_element();
        (0..MAX_LEVEL).find(|&l| TileId::size_deg(l) / per_sample <= cells).unwrap_or(MAX_LEVEL)
    }
}

/// A grid in longitude/latitude degrees: the input of the pyramid.
#[derive(Debug, Clone, Copy)]
pub struct GeoGrid<'a> {
    hm: &'a Heightmap,
    layout: GridLayout,
}

impl<'a> GeoGrid<'a> {
    /// Wraps a heightmap whose georeference is geographic (degrees; taken as WGS84).
    pub fn new(hm: &'a Heightmap) -> Result<Self, TinError> {
        let layout = GridLayout::new(hm.width(), hm.height(), hm.georef())?;
        Ok(Self { hm, layout })
    }

    /// The heightmap.
    pub fn heightmap(&self) -> &'a Heightmap {
        self.hm
    }

    /// Where the grid lies ([`GridLayout`]).
    pub fn layout(&self) -> &GridLayout {
        &self.layout
    }

    /// Fractional grid coordinates of a longitude/latitude.
    pub fn to_grid(&self, lonlat: DVec2) -> DVec2 {
        self.layout.to_grid(lonlat)
    }

    /// Longitude/latitude of fractional grid coordinates.
    pub fn to_lonlat(&self, g: DVec2) -> DVec2 {
        self.layout.to_lonlat(g)
    }

    /// The rectangle of the sample centres.
    pub fn extent(&self) -> LonLatRect {
        self.layout.extent()
    }

    /// The tiles at `level` whose rectangle overlaps the grid's extent (with positive area).
    pub fn tile_range(&self, level: u32) -> TileRange {
        self.layout.tile_range(level)
    }

    /// The deepest level worth building ([`GridLayout::native_level`]).
    pub fn native_level(&self, cells: f64) -> u32 {
        self.layout.native_level(cells)
    }
}

/// One tile's mesh: vertices in the tile's unit square and metres, triangles
/// counter-clockwise seen from above, its bound and the measured error.
#[derive(Debug, Clone, PartialEq)]
pub struct TileMesh {
    /// The tile.
    pub tile: TileId,
    /// `(u, v, height)`: `u`, `v` in `[0, 1]` across the tile west to east and south to north
    /// (exactly 0 or 1 on its borders), height in metres.
    pub vertices: Vec<DVec3>,
    /// Counter-clockwise (seen from above) vertex indices.
    pub triangles: Vec<[u32; 3]>,
    /// The tile's bound, metres.
    pub bound: f64,
    /// The error measured against the DEM samples the tile was meshed from; `None` for a tile
    /// without DEM samples (flat at height 0).
    pub measured: Option<MaxError>,
}

impl TileMesh {
    /// Longitude/latitude of vertex `k`.
    pub fn lonlat(&self, k: usize) -> DVec2 {
        let r = self.tile.rect();
        let v = self.vertices[k];
        dvec2(r.west + v.x * (r.east - r.west), r.south + v.y * (r.north - r.south))
    }
}

/// An axis-aligned box in grid coordinates.
#[derive(Debug, Clone, Copy)]
struct Rect {
    x0: f64,
    y0: f64,
    x1: f64,
    y1: f64,
}

/// The part of `hm` from sample `(i0, j0)` to `(i1, j1)` (inclusive) as a [`tile::window`].
fn crop(hm: &Heightmap, i0: usize, j0: usize, i1: usize, j1: usize) -> Heightmap {
    tile::window(i1 - i0 + 1, j1 - j0 + 1, |i, j| {
        (hm.get(i0 + i, j0 + j), hm.voids().get(i0 + i, j0 + j))
    })
}

/// Vertices of the output, deduplicated by exact position (FxHash: the map is only looked up,
/// never iterated, so the hasher changes nothing but the time, 5 % of `terrain tiles` with
/// SipHash).
#[derive(Default)]
struct VertexSet {
    index: rustc_hash::FxHashMap<(u64, u64), u32>,
    points: Vec<DVec3>,
}

impl VertexSet {
    /// Room for `n` vertices without growing.
    fn with_capacity(n: usize) -> Self {
        Self {
            index: rustc_hash::FxHashMap::with_capacity_and_hasher(n, Default::default()),
            points: Vec::with_capacity(n),
        }
    }

    fn add(&mut self, p: DVec3) -> u32 {
        let key = (p.x.to_bits(), p.y.to_bits());
        *self.index.entry(key).or_insert_with(|| {
            self.points.push(p);
            (self.points.len() - 1) as u32
        })
    }
}

/// Twice the signed area of a triangle of points (positive: counter-clockwise).
fn area2(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x)
}

/// Clips a convex polygon to the half-plane `axis >= at` (`keep_above`) or `axis <= at`.
/// The crossing of an edge is computed from its endpoints in a canonical order, so the two
/// triangles sharing an edge get the same point, bit for bit, and the point is put on the line
/// exactly.
fn clip(poly: &[DVec3], axis: usize, at: f64, keep_above: bool) -> Vec<DVec3> {
    let inside = |p: &DVec3| if keep_above { p[axis] >= at } else { p[axis] <= at };
    let mut out = Vec::with_capacity(poly.len() + 2);
    for k in 0..poly.len() {
        let (p, q) = (poly[k], poly[(k + 1) % poly.len()]);
        let (pin, qin) = (inside(&p), inside(&q));
        if pin {
            out.push(p);
        }
        if pin != qin {
            let (a, b) = if (p.x, p.y) < (q.x, q.y) { (p, q) } else { (q, p) };
            let t = (at - a[axis]) / (b[axis] - a[axis]);
            let mut m = a + (b - a) * t;
            m[axis] = at;
            out.push(m);
        }
    }
    out.dedup();
    while out.len() > 1 && out.first() == out.last() {
        out.pop();
    }
    out
}

/// Builds the mesh of `tile` within `bound` metres of every non-void sample of `grid` inside it
/// (see the module docs), verified before it is returned.
pub fn build_tile(grid: &GeoGrid<'_>, tile: TileId, bound: f64) -> Result<TileMesh, TinError> {
    build_tile_seeded(grid, tile, bound, &[]).map(|(mesh, _)| mesh)
}

/// [`build_tile`] seeded with samples `[i, j]` of `grid` ([`tile::mesh_window_seeded`]; those
/// outside the tile's sub-grid are skipped), and the samples the mesh took as vertices before
/// clipping (in `grid`'s coordinates: the seeds of the tile's children).
pub fn build_tile_seeded(
    grid: &GeoGrid<'_>,
    tile: TileId,
    bound: f64,
    seeds: &[[u32; 2]],
) -> Result<(TileMesh, Vec<[u32; 2]>), TinError> {
    let placed = Placed::new(&grid.layout, tile);
    let sub = placed.crop.map(|[i0, j0, i1, j1]| crop(grid.hm, i0, j0, i1, j1));
    placed.mesh(sub.as_ref(), tile, bound, seeds, Algorithm::Delaunay)
}

/// [`build_tile_seeded`] of a grid it owns (geographic, as [`GeoGrid::new`] takes): where the
/// tile's sub-grid is the whole grid (a window read for the tile) it is meshed in place instead
/// of copied, the same samples, so the same mesh, with one copy of them less in memory. The
/// sub-grid is meshed by `algorithm` ([`tile::mesh_window_with`]: an RTIN takes no seeds).
pub fn build_tile_owned(
    hm: Heightmap,
    tile: TileId,
    bound: f64,
    seeds: &[[u32; 2]],
    algorithm: Algorithm,
) -> Result<(TileMesh, Vec<[u32; 2]>), TinError> {
    let layout = GridLayout::new(hm.width(), hm.height(), hm.georef())?;
    let placed = Placed::new(&layout, tile);
    let (w, h) = (hm.width(), hm.height());
    // What `crop` would change: void samples' non-finite heights (made 0) and the georeference.
    let voids_finite = !hm.voids().any()
        || hm
            .data()
            .iter()
            .enumerate()
            .all(|(k, z)| z.is_finite() || !hm.voids().get(k % w, k / w));
    let sub = match placed.crop {
        Some(c) if c == [0, 0, w - 1, h - 1] && voids_finite => {
            Some(hm.with_georef(crate::Georef::local(1.0)))
        }
        Some([i0, j0, i1, j1]) => Some(crop(&hm, i0, j0, i1, j1)),
        None => None,
    };
    placed.mesh(sub.as_ref(), tile, bound, seeds, algorithm)
}

/// A reader's error, or the tile mesher's ([`build_tile_read`]).
enum ReadOr<E> {
    Read(E),
    Tile(tile::TileError),
}

impl<E> From<tile::TileError> for ReadOr<E> {
    fn from(e: tile::TileError) -> Self {
        ReadOr::Tile(e)
    }
}

/// [`build_tile_owned`] of a grid read by rectangles: `layout` is the grid's (geographic, as
/// [`GridLayout::new`] takes), `read([i0, j0, i1, j1])` returns the samples of that inclusive
/// rectangle of it, row-major from its south-west sample, and their voids (`None`: none).
/// Where the tile's sub-grid spans at most `piece` cells each way, or `algorithm` is the RTIN,
/// it is read at once and meshed as [`build_tile_owned`] meshes it (the same samples, so the
/// same mesh); a larger one under the greedy mesher is meshed by [`tile::mesh_in_pieces`]
/// (each piece read, meshed with locked sides and verified on its own, then the next), so the
/// samples held at once are one piece's whatever the tile's size.
#[allow(clippy::too_many_arguments)]
pub fn build_tile_read<E: From<TinError>>(
    layout: &GridLayout,
    tile: TileId,
    bound: f64,
    seeds: &[[u32; 2]],
    algorithm: Algorithm,
    piece: usize,
    mut read: impl FnMut([usize; 4]) -> Result<(Vec<f32>, Option<VoidMask>), E>,
) -> Result<(TileMesh, Vec<[u32; 2]>), E> {
    let placed = Placed::new(layout, tile);
    let tile_err = |e| E::from(TinError::from_tile(e, tile.level, tile.x, tile.y));
    let Some([i0, j0, i1, j1]) = placed.crop else {
        return Ok(placed.place(None, tile, bound));
    };
    let (w, h) = (i1 - i0 + 1, j1 - j0 + 1);
    let local = placed.local_seeds(seeds);
    let meshed = if algorithm == Algorithm::Delaunay && (w - 1 > piece || h - 1 > piece) {
        let at = |[a, b, c, d]: [usize; 4]| [i0 + a, j0 + b, i0 + c, j0 + d];
        tile::mesh_in_pieces(w, h, piece, bound, &local, |r| read(at(r)).map_err(ReadOr::Read))
            .map_err(|e| match e {
                ReadOr::Read(e) => e,
                ReadOr::Tile(e) => tile_err(e),
            })?
    } else {
        let (data, voids) = read([i0, j0, i1, j1])?;
        let sub = tile::window_of(w, h, data, voids).map_err(tile_err)?;
        tile::mesh_window_with(&sub, bound, tile::Borders::Free, &local, algorithm)
            .map_err(tile_err)?
    };
    Ok(placed.place(Some(meshed), tile, bound))
}

/// Where a tile lies on a grid: its rectangle, the grid's part of it and the samples that
/// cover that part.
struct Placed {
    /// The tile's rectangle in grid coordinates.
    tr: Rect,
    /// Its part within the grid's extent.
    p: Rect,
    /// The samples covering `p` (`[i0, j0, i1, j1]`, inclusive), if `p` has an area.
    crop: Option<[usize; 4]>,
}

impl Placed {
    fn new(layout: &GridLayout, tile: TileId) -> Self {
        let r = tile.rect();
        let a = layout.to_grid(dvec2(r.west, r.south));
        let b = layout.to_grid(dvec2(r.east, r.north));
        let tr = Rect { x0: a.x, y0: a.y, x1: b.x, y1: b.y };
        let (w, h) = (layout.width as f64 - 1.0, layout.height as f64 - 1.0);
        let p = Rect { x0: tr.x0.max(0.0), y0: tr.y0.max(0.0), x1: tr.x1.min(w), y1: tr.y1.min(h) };
        let crop = (p.x0 < p.x1 && p.y0 < p.y1).then(|| {
            let (i0, j0) = (p.x0.floor() as usize, p.y0.floor() as usize);
            let (i1, j1) = (p.x1.ceil() as usize, p.y1.ceil() as usize);
            [i0, j0, i1, j1]
        });
        Self { tr, p, crop }
    }

    /// The seeds (samples `[i, j]` of the grid) inside `self.crop`, in its coordinates.
    fn local_seeds(&self, seeds: &[[u32; 2]]) -> Vec<[u32; 2]> {
        let Some([i0, j0, i1, j1]) = self.crop else { return Vec::new() };
        seeds
            .iter()
            .filter(|&&[i, j]| {
                (i0..=i1).contains(&(i as usize)) && (j0..=j1).contains(&(j as usize))
            })
            .map(|&[i, j]| [i - i0 as u32, j - j0 as u32])
            .collect()
    }

    /// Meshes `sub` (the samples `self.crop` as a [`tile::window`]), clips it to the tile and
    /// fills the rest of the tile.
    fn mesh(
        &self,
        sub: Option<&Heightmap>,
        tile: TileId,
        bound: f64,
        seeds: &[[u32; 2]],
        algorithm: Algorithm,
    ) -> Result<(TileMesh, Vec<[u32; 2]>), TinError> {
        let meshed = match (self.crop, sub) {
            (Some(_), Some(sub)) => {
                let local = self.local_seeds(seeds);
                Some(
                    tile::mesh_window_with(sub, bound, tile::Borders::Free, &local, algorithm)
                        .map_err(|e| TinError::from_tile(e, tile.level, tile.x, tile.y))?,
                )
            }
            _ => None,
        };
        Ok(self.place(meshed, tile, bound))
    }

    /// Clips the mesh of `self.crop` (in its grid coordinates, vertices at its samples, and
    /// its measured error) to the tile and fills the rest of the tile; and the samples the
    /// mesh took as vertices, in the grid's coordinates.
    fn place(
        &self,
        meshed: Option<(TriMesh, MaxError)>,
        tile: TileId,
        bound: f64,
    ) -> (TileMesh, Vec<[u32; 2]>) {
        let Placed { tr, p, crop } = *self;
        // Sized for the mesh's vertices plus the clipped border's and the fill's: the map grown
        // from empty rehashed its way up (`reserve_rehash`, with the encoder's map below, 1.8 %
        // of `terrain tiles`' CPU samples on the 4097^2 store).
        let expect = meshed.as_ref().map_or(0, |(m, _)| m.positions.len()) + 64;
        let mut set = VertexSet::with_capacity(expect);
        let mut triangles: Vec<[u32; 3]> = Vec::new();
        let mut measured = None;
        let mut used = Vec::new();
        let has_dem = crop.is_some();
        if let (Some([i0, j0, _, _]), Some((m, stats))) = (crop, meshed) {
            measured = Some(stats);
            // Vertices are samples: integer grid coordinates of the sub-grid.
            used = m
                .positions
                .iter()
                .map(|q| [q.x.round() as u32 + i0 as u32, q.y.round() as u32 + j0 as u32])
                .collect();
            let off = DVec3::new(i0 as f64, j0 as f64, 0.0);
            // Each mesh vertex's index in `set`, once it has one: a triangle inside the tile
            // (most of them) takes its corners' indices from here, one hash lookup per vertex
            // instead of per corner (the lookups were 6 % of `terrain tiles`). The same
            // `set.add` calls in the same order, so the same vertices and triangles.
            let mut index = vec![u32::MAX; m.positions.len()];
            triangles.reserve(m.triangles.len());
            for t in &m.triangles {
                let corners = t.map(|k| m.positions[k as usize] + off);
                let inside = corners
                    .iter()
                    .all(|q| q.x >= p.x0 && q.x <= p.x1 && q.y >= p.y0 && q.y <= p.y1);
                if inside {
                    if area2(corners[0], corners[1], corners[2]) > 0.0 {
                        let mut id = |c: usize| {
                            let k = t[c] as usize;
                            if index[k] == u32::MAX {
                                index[k] = set.add(corners[c]);
                            }
                            index[k]
                        };
                        triangles.push([id(0), id(1), id(2)]);
                    }
                    continue;
                }
                let c = clip(&corners, 0, p.x0, true);
                let c = clip(&c, 0, p.x1, false);
                let c = clip(&c, 1, p.y0, true);
                let poly = clip(&c, 1, p.y1, false);
                fan(&poly, &mut set, &mut triangles);
            }
        }
        fill_outside(tr, has_dem.then_some(p), &mut set, &mut triangles);
        let sx = tr.x1 - tr.x0;
        let sy = tr.y1 - tr.y0;
        let vertices = set
            .points
            .iter()
            .map(|q| {
                // Exactly 0 or 1 on the tile's borders.
                let u = if q.x == tr.x0 {
                    0.0
                } else if q.x == tr.x1 {
                    1.0
                } else {
                    (q.x - tr.x0) / sx
                };
                let v = if q.y == tr.y0 {
                    0.0
                } else if q.y == tr.y1 {
                    1.0
                } else {
                    (q.y - tr.y0) / sy
                };
                DVec3::new(u.clamp(0.0, 1.0), v.clamp(0.0, 1.0), q.z)
            })
            .collect();
        (TileMesh { tile, vertices, triangles, bound, measured }, used)
    }
}

/// Triangulates a convex counter-clockwise polygon as a fan, dropping slivers of zero area.
fn fan(poly: &[DVec3], set: &mut VertexSet, triangles: &mut Vec<[u32; 3]>) {
    for k in 1..poly.len().saturating_sub(1) {
        let (a, b, c) = (poly[0], poly[k], poly[k + 1]);
        if area2(a, b, c) > 0.0 {
            triangles.push([set.add(a), set.add(b), set.add(c)]);
        }
    }
}

/// Covers the tile rectangle `tr` minus the DEM's part `p` (if any) at height 0: four
/// trapezoids between `p`'s sides (with every vertex the clipped mesh put there) and the
/// tile's sides, each a fan from one outer corner.
fn fill_outside(tr: Rect, p: Option<Rect>, set: &mut VertexSet, triangles: &mut Vec<[u32; 3]>) {
    let corner = |x: f64, y: f64| DVec3::new(x, y, 0.0);
    let Some(p) = p else {
        let (a, b) = (corner(tr.x0, tr.y0), corner(tr.x1, tr.y0));
        let (c, d) = (corner(tr.x1, tr.y1), corner(tr.x0, tr.y1));
        fan(&[a, b, c, d], set, triangles);
        return;
    };
    // The vertices on each side of p, in order along the side.
    let on = |pred: &dyn Fn(&DVec3) -> bool, key: &dyn Fn(&DVec3) -> f64| {
        let mut v: Vec<DVec3> = set.points.iter().copied().filter(|q| pred(q)).collect();
        v.sort_by(|a, b| key(a).total_cmp(&key(b)));
        v
    };
    // (inner side from its first corner to its second, outer corners next to each, whether
    // the tile extends beyond that side); sides listed counter-clockwise seen from outside p.
    let south = on(&|q| q.y == p.y0, &|q| q.x);
    let east = on(&|q| q.x == p.x1, &|q| q.y);
    let mut north = on(&|q| q.y == p.y1, &|q| q.x);
    north.reverse();
    let mut west = on(&|q| q.x == p.x0, &|q| q.y);
    west.reverse();
    let sides = [
        (south, corner(tr.x0, tr.y0), corner(tr.x1, tr.y0), tr.y0 < p.y0),
        (east, corner(tr.x1, tr.y0), corner(tr.x1, tr.y1), tr.x1 > p.x1),
        (north, corner(tr.x1, tr.y1), corner(tr.x0, tr.y1), tr.y1 > p.y1),
        (west, corner(tr.x0, tr.y1), corner(tr.x0, tr.y0), tr.x0 < p.x0),
    ];
    for (inner, a, b, beyond) in sides {
        if !beyond || inner.is_empty() {
            continue;
        }
        // Trapezoid a -> b (outer, counter-clockwise around the tile) over inner (from the
        // corner next to a to the corner next to b): fan from a over the inner chain, then the
        // triangle (a, last inner, b). Orientation: the outer side runs opposite to the inner
        // one seen from inside the trapezoid.
        for k in 0..inner.len() - 1 {
            push_ccw([a, inner[k + 1], inner[k]], set, triangles);
        }
        push_ccw([a, b, inner[inner.len() - 1]], set, triangles);
    }
}

/// Adds a triangle in counter-clockwise order; drops it if it has no area.
fn push_ccw(t: [DVec3; 3], set: &mut VertexSet, triangles: &mut Vec<[u32; 3]>) {
    let s = area2(t[0], t[1], t[2]);
    if s > 0.0 {
        triangles.push([set.add(t[0]), set.add(t[1]), set.add(t[2])]);
    } else if s < 0.0 {
        triangles.push([set.add(t[0]), set.add(t[2]), set.add(t[1])]);
    }
}

#[cfg(test)]
mod tests;
