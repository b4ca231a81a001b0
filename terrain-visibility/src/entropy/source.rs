//! Building the entropy quadtree from a grid DEM or from scattered points (the entropy paper,
//! Chen 2018, Algorithm 1), with its settings.
//!
//! * **Grid DEM.** The entropy map is computed on the DEM itself; heights at the new vertices
//!   are the DEM's samples (the lattice is snapped to sample columns and rows, and the depth is
//!   capped at `floor(log2(min(width, height) - 1))` so no two lattice lines share a sample).
//! * **Scattered points.** Duplicate `(x, y)` positions are merged into one point with their
//!   mean height (a well-defined surface needs one height per position). The points are
//!   interpolated onto a raster of `2^min(D, 10) + 1` samples per side over the bounding
//!   rectangle, on which the curvature and its entropy are computed (Algorithm 1's `Emap`);
//!   heights at the tree's vertices come from the points directly, by IDW as the paper does
//!   or by natural-neighbour (Sibson) interpolation over spade's Delaunay triangulation, the
//!   default: it is exact at the points, smooth, and needs no choice of radius or power.
//!   Outside the points' convex hull (the bounding rectangle's corners) natural neighbour is
//!   undefined and IDW is used there.

use glam::{DVec2, DVec3};
use rayon::prelude::*;
use spade::{DelaunayTriangulation, HasPosition, Point2, Triangulation};
use terrain_core::{Georef, Heightmap, HeightmapError, VoidMask};

use super::curvature::{ScalarMap, profile_curvature};
use super::local::{EntropyConfig, local_entropy};
use super::quadtree::{EntropyGrid, EntropyQuadtree, Lattice, MAX_DEPTH};

/// The units the thresholds `E0` (and `maxE`) are in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EntropyScale {
    /// Bits, Eq. 1-3 as written: `0..=log2(min(M, N))`.
    Bits,
    /// Percent of the largest possible entropy `log2(min(M, N))`: `0..=100`, the common domain
    /// `[0, 100]` of the paper's Fig. 3. With the default window and classes the paper's
    /// thresholds `E0 = 10..18` fall in the range where real terrain's maxima lie.
    Percent,
}

/// How heights at new vertices are interpolated from scattered points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Interpolation {
    /// Inverse distance weighting over the `neighbours` nearest points with weight
    /// `1 / distance^power` (the paper's choice).
    Idw {
        /// Nearest points used. Default 12.
        neighbours: usize,
        /// Distance exponent. Default 2.
        power: f64,
    },
    /// Natural-neighbour (Sibson) interpolation over the Delaunay triangulation (default).
    NaturalNeighbour,
}

impl Interpolation {
    /// IDW with the defaults (12 neighbours, power 2).
    pub const IDW: Interpolation = Interpolation::Idw { neighbours: 12, power: 2.0 };
}

/// Settings of the entropy quadtree.
#[derive(Debug, Clone, PartialEq)]
pub struct TreeConfig {
    /// Threshold `E0` (Algorithm 1, line 9), in [`TreeConfig::scale`] units. Default 10.
    pub e0: f64,
    /// Maximum depth `D` (0..=[`MAX_DEPTH`]). Default 8 (the paper's Table 1).
    pub max_depth: u32,
    /// Window and classes of the local entropy.
    pub entropy: EntropyConfig,
    /// Units of `e0` and `maxE`. Default [`EntropyScale::Percent`].
    pub scale: EntropyScale,
    /// Scattered points only: height interpolation. Default natural neighbour.
    pub interpolation: Interpolation,
}

impl Default for TreeConfig {
    fn default() -> Self {
        Self {
            e0: 10.0,
            max_depth: 8,
            entropy: EntropyConfig::default(),
            scale: EntropyScale::Percent,
            interpolation: Interpolation::NaturalNeighbour,
        }
    }
}

/// Why a tree could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum EntropyError {
    /// `max_depth` above [`MAX_DEPTH`].
    #[error("max depth {0} is above the largest supported, {MAX_DEPTH}")]
    DepthTooLarge(u32),
    /// `e0` is NaN.
    #[error("the entropy threshold E0 is not a number")]
    ThresholdNan,
    /// Fewer than three distinct points.
    #[error("{0} distinct point(s) after merging duplicates; at least 3 are needed")]
    TooFewPoints(usize),
    /// The points' bounding rectangle has no area (all on one vertical or horizontal line).
    #[error("the points span {0} x {1} m: their bounding rectangle has no area")]
    DegenerateBounds(f64, f64),
    /// Every point is on one line: no triangulation for natural-neighbour interpolation.
    #[error(
        "all points are collinear: natural-neighbour interpolation needs a 2-D spread (use IDW)"
    )]
    Collinear,
    /// A point is not finite.
    #[error("point {0} has a non-finite coordinate")]
    NonFinite(usize),
    /// The raster could not be made (the cause in the message, not an error `source`, so an
    /// error chain prints it once).
    #[error("raster: {0}")]
    Raster(HeightmapError),
}

impl From<HeightmapError> for EntropyError {
    fn from(e: HeightmapError) -> Self {
        Self::Raster(e)
    }
}

impl TreeConfig {
    fn validate(&self) -> Result<(), EntropyError> {
        if self.max_depth > MAX_DEPTH {
            return Err(EntropyError::DepthTooLarge(self.max_depth));
        }
        if self.e0.is_nan() {
            return Err(EntropyError::ThresholdNan);
        }
        Ok(())
    }

    /// Multiplier from bits to the configured units.
    pub fn bits_to_units(&self) -> f64 {
        match self.scale {
            EntropyScale::Bits => 1.0,
            EntropyScale::Percent => {
                let m = self.entropy.max_entropy_bits();
                if m > 0.0 { 100.0 / m } else { 0.0 }
            }
        }
    }
}

/// The entropy map of a heightmap in the configured units (voids NaN).
pub fn entropy_map(hm: &Heightmap, config: &TreeConfig) -> ScalarMap {
    let e = local_entropy(&profile_curvature(hm), &config.entropy);
    let k = config.bits_to_units() as f32;
    let values = e.values().iter().map(|&v| v * k).collect();
    ScalarMap::new(e.width(), e.height(), values)
}

/// The depth a grid can hold: `floor(log2(min(width, height) - 1))`.
pub fn grid_depth_cap(hm: &Heightmap) -> u32 {
    let cells = hm.width().min(hm.height()).saturating_sub(1).max(1);
    cells.ilog2()
}

/// Builds the tree for a grid DEM (see the module doc). The depth used is
/// `min(config.max_depth, grid_depth_cap(hm))`.
pub fn build_from_grid(
    hm: &Heightmap,
    config: &TreeConfig,
) -> Result<EntropyQuadtree, EntropyError> {
    config.validate()?;
    let emap = entropy_map(hm, config);
    Ok(build_from_grid_with_map(hm, &emap, config))
}

/// [`build_from_grid`] with a precomputed [`entropy_map`] (to sweep `E0` on one map).
pub fn build_from_grid_with_map(
    hm: &Heightmap,
    emap: &ScalarMap,
    config: &TreeConfig,
) -> EntropyQuadtree {
    let depth = config.max_depth.min(MAX_DEPTH).min(grid_depth_cap(hm));
    let n = 1u64 << depth;
    let snap = |k: u64, samples: usize| ((k * (samples as u64 - 1) + n / 2) / n) as f64;
    let g = hm.georef();
    let lattice = Lattice {
        depth,
        x: (0..=n).map(|a| snap(a, hm.width())).collect(),
        y: (0..=n).map(|b| snap(b, hm.height())).collect(),
        world_origin: g.world_origin,
        world_scale: g.spacing_m,
    };
    let grid = EntropyGrid {
        values: emap.values(),
        width: emap.width(),
        height: emap.height(),
        origin: DVec2::ZERO,
        spacing: DVec2::ONE,
    };
    EntropyQuadtree::build(lattice, &grid, config.e0, |p| {
        f64::from(hm.get(p.x as usize, p.y as usize))
    })
}

/// A Delaunay vertex carrying its height.
#[derive(Debug, Clone, Copy)]
struct ZPoint {
    x: f64,
    y: f64,
    z: f64,
}

impl HasPosition for ZPoint {
    type Scalar = f64;
    fn position(&self) -> Point2<f64> {
        Point2::new(self.x, self.y)
    }
}

/// Scattered points ready for interpolation: merged duplicates, a bucket grid for IDW, and
/// (for natural neighbour) their Delaunay triangulation.
#[derive(Debug)]
pub struct ScatteredPoints {
    points: Vec<DVec3>,
    min: DVec2,
    max: DVec2,
    /// Bucket grid: `nx x ny` cells of size `cell`, CSR offsets into `order`.
    nx: usize,
    ny: usize,
    cell: DVec2,
    start: Vec<u32>,
    order: Vec<u32>,
    delaunay: Option<DelaunayTriangulation<ZPoint>>,
    interpolation: Interpolation,
    /// Number of input points merged away as duplicates.
    pub duplicates: usize,
}

impl ScatteredPoints {
    /// Prepares `points` for `interpolation` (see the module doc for duplicates).
    pub fn new(points: Vec<DVec3>, interpolation: Interpolation) -> Result<Self, EntropyError> {
        if let Some(k) = points.iter().position(|p| !p.is_finite()) {
            return Err(EntropyError::NonFinite(k));
        }
        let input = points.len();
        let points = merge_duplicates(points);
        let duplicates = input - points.len();
        if points.len() < 3 {
            return Err(EntropyError::TooFewPoints(points.len()));
        }
        let (mut min, mut max) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
        for p in &points {
            min = min.min(p.truncate());
            max = max.max(p.truncate());
        }
        let ext = max - min;
        if ext.x <= 0.0 || ext.y <= 0.0 {
            return Err(EntropyError::DegenerateBounds(ext.x, ext.y));
        }
        // About two points per bucket.
        let per_side = ((points.len() as f64 / 2.0).sqrt()).max(1.0);
        let aspect = (ext.x / ext.y).sqrt();
        let nx = ((per_side * aspect).round() as usize).clamp(1, 1 << 14);
        let ny = ((per_side / aspect).round() as usize).clamp(1, 1 << 14);
        let cell = DVec2::new(ext.x / nx as f64, ext.y / ny as f64);
        let bucket = |p: DVec3| {
            let c = ((p.truncate() - min) / cell).floor();
            (c.y.max(0.0) as usize).min(ny - 1) * nx + (c.x.max(0.0) as usize).min(nx - 1)
        };
        let mut start = vec![0u32; nx * ny + 1];
        for &p in &points {
            start[bucket(p) + 1] += 1;
        }
        for k in 0..nx * ny {
            start[k + 1] += start[k];
        }
        let mut fill = start.clone();
        let mut order = vec![0u32; points.len()];
        for (k, &p) in points.iter().enumerate() {
            let b = bucket(p);
            order[fill[b] as usize] = k as u32;
            fill[b] += 1;
        }
        let delaunay = match interpolation {
            Interpolation::NaturalNeighbour => {
                let v: Vec<ZPoint> =
                    points.iter().map(|p| ZPoint { x: p.x, y: p.y, z: p.z }).collect();
                let t = DelaunayTriangulation::<ZPoint>::bulk_load(v)
                    .map_err(|_| EntropyError::Collinear)?;
                if t.num_inner_faces() == 0 {
                    return Err(EntropyError::Collinear);
                }
                Some(t)
            }
            Interpolation::Idw { .. } => None,
        };
        Ok(Self {
            points,
            min,
            max,
            nx,
            ny,
            cell,
            start,
            order,
            delaunay,
            interpolation,
            duplicates,
        })
    }

    /// The distinct points.
    pub fn points(&self) -> &[DVec3] {
        &self.points
    }

    /// The bounding rectangle `(min, max)`.
    pub fn bounds(&self) -> (DVec2, DVec2) {
        (self.min, self.max)
    }

    /// Height at `p` by the configured interpolation.
    pub fn height(&self, p: DVec2) -> f64 {
        match self.interpolation {
            Interpolation::NaturalNeighbour => self.natural_neighbour(p).unwrap_or_else(|| {
                let Interpolation::Idw { neighbours, power } = Interpolation::IDW else {
                    unreachable!()
                };
                self.idw(p, neighbours, power)
            }),
            Interpolation::Idw { neighbours, power } => self.idw(p, neighbours, power),
        }
    }

    fn natural_neighbour(&self, p: DVec2) -> Option<f64> {
        let t = self.delaunay.as_ref()?;
        t.natural_neighbor().interpolate(|v| v.data().z, Point2::new(p.x, p.y))
    }

    /// Inverse distance weighting over the `k` nearest points (a point at distance 0 gives its
    /// own height).
    pub fn idw(&self, p: DVec2, k: usize, power: f64) -> f64 {
        let k = k.max(1).min(self.points.len());
        // (distance², index), the k best so far, sorted.
        let mut best: Vec<(f64, u32)> = Vec::with_capacity(k + 1);
        let c = ((p - self.min) / self.cell).floor();
        let (ci, cj) = (c.x as i64, c.y as i64);
        let mut ring = 0i64;
        loop {
            for j in cj - ring..=cj + ring {
                for i in ci - ring..=ci + ring {
                    if (i - ci).abs() != ring && (j - cj).abs() != ring {
                        continue;
                    }
                    if i < 0 || j < 0 || i >= self.nx as i64 || j >= self.ny as i64 {
                        continue;
                    }
                    let b = j as usize * self.nx + i as usize;
                    for &q in &self.order[self.start[b] as usize..self.start[b + 1] as usize] {
                        let d2 = (self.points[q as usize].truncate() - p).length_squared();
                        if best.len() < k || d2 < best[best.len() - 1].0 {
                            let at = best.partition_point(|e| (e.0, e.1) < (d2, q));
                            best.insert(at, (d2, q));
                            best.truncate(k);
                        }
                    }
                }
            }
            // Every point not yet seen lies outside the searched square of buckets, so at
            // least `margin` from `p`.
            let lo = self.min + DVec2::new((ci - ring) as f64, (cj - ring) as f64) * self.cell;
            let hi =
                self.min + DVec2::new((ci + ring + 1) as f64, (cj + ring + 1) as f64) * self.cell;
            let margin = (p.x - lo.x).min(hi.x - p.x).min(p.y - lo.y).min(hi.y - p.y);
            let covers_all = ci - ring <= 0
                && cj - ring <= 0
                && ci + ring >= self.nx as i64 - 1
                && cj + ring >= self.ny as i64 - 1;
            if covers_all || (best.len() == k && margin > 0.0 && best[k - 1].0 <= margin * margin) {
                break;
            }
            ring += 1;
        }
        if best[0].0 == 0.0 {
            return self.points[best[0].1 as usize].z;
        }
        let (mut sw, mut swz) = (0.0, 0.0);
        for &(d2, q) in &best {
            let w = 1.0 / d2.powf(power / 2.0);
            sw += w;
            swz += w * self.points[q as usize].z;
        }
        swz / sw
    }

    /// The raster of `2^cells_log2 + 1` samples per side over the bounding rectangle, each
    /// sample interpolated (the entropy map's grid).
    pub fn raster(&self, cells_log2: u32) -> Result<Heightmap, EntropyError> {
        let n = 1usize << cells_log2;
        let spacing = (self.max - self.min) / n as f64;
        let mut data = vec![0.0f32; (n + 1) * (n + 1)];
        data.par_chunks_mut(n + 1).enumerate().for_each(|(j, row)| {
            for (i, z) in row.iter_mut().enumerate() {
                *z = self.height(self.min + DVec2::new(i as f64, j as f64) * spacing) as f32;
            }
        });
        let mut georef = Georef::local(1.0);
        georef.spacing_m = spacing;
        georef.native_spacing = spacing;
        georef.world_origin = self.min;
        georef.native_origin = self.min;
        Ok(Heightmap::new(n + 1, n + 1, data, VoidMask::new(n + 1, n + 1), georef)?)
    }
}

/// Sorts by position and merges points at the same `(x, y)` into their mean height.
fn merge_duplicates(mut points: Vec<DVec3>) -> Vec<DVec3> {
    points.par_sort_unstable_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    let mut out: Vec<DVec3> = Vec::with_capacity(points.len());
    let mut run = 0usize;
    for p in points {
        match out.last_mut() {
            Some(q) if q.x == p.x && q.y == p.y => {
                run += 1;
                q.z += (p.z - q.z) / run as f64;
            }
            _ => {
                out.push(p);
                run = 1;
            }
        }
    }
    out
}

/// The resolution of the scattered source's entropy raster: `2^min(D, 10)` cells per side.
pub fn raster_cells_log2(max_depth: u32) -> u32 {
    max_depth.clamp(1, 10)
}

/// A tree built from scattered points, with the raster its entropy map was computed on.
#[derive(Debug)]
pub struct ScatteredTree {
    /// The tree (plan coordinates are world metres).
    pub tree: EntropyQuadtree,
    /// The interpolated raster (`Emap`'s grid), also the reference to measure the mesh against.
    pub raster: Heightmap,
    /// Seconds to interpolate the raster and compute its entropy.
    pub entropy_s: f64,
}

/// Builds the tree from prepared scattered points (see the module doc).
pub fn build_from_points(
    points: &ScatteredPoints,
    config: &TreeConfig,
) -> Result<ScatteredTree, EntropyError> {
    config.validate()?;
    let t0 = std::time::Instant::now();
    let raster = points.raster(raster_cells_log2(config.max_depth))?;
    let emap = entropy_map(&raster, config);
    let entropy_s = t0.elapsed().as_secs_f64();
    let (min, max) = points.bounds();
    let depth = config.max_depth;
    let n = 1u64 << depth;
    let ext = max - min;
    let lattice = Lattice {
        depth,
        x: (0..=n).map(|a| min.x + ext.x * a as f64 / n as f64).collect(),
        y: (0..=n).map(|b| min.y + ext.y * b as f64 / n as f64).collect(),
        world_origin: DVec2::ZERO,
        world_scale: DVec2::ONE,
    };
    let g = raster.georef();
    let grid = EntropyGrid {
        values: emap.values(),
        width: emap.width(),
        height: emap.height(),
        origin: g.world_origin,
        spacing: g.spacing_m,
    };
    // Lattice vertices that are raster samples (all of them when D <= 10) take the raster's
    // height, interpolated once already (to f32, millimetres at terrain heights).
    let (origin, spacing) = (g.world_origin, g.spacing_m);
    let height = |p: DVec2| {
        let q = (p - origin) / spacing;
        let r = q.round();
        if (q - r).abs().max_element() < 1e-6 {
            f64::from(raster.get(r.x as usize, r.y as usize))
        } else {
            points.height(p)
        }
    };
    let tree = EntropyQuadtree::build(lattice, &grid, config.e0, height);
    Ok(ScatteredTree { tree, raster, entropy_s })
}
