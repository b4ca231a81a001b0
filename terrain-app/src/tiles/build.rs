//! One tile of `terrain tiles` from a [`Samples`] source, at the resolution its level needs,
//! and the decimation error under a tile ([`decimation_error`]); the check of a coarse tile
//! against every DEM sample under it is [`super::check`]'s. The decimation error and the
//! budget policy are the library's ([`terrain_app::decimation`], shared with the `tin` method).
//!
//! **Resolution per level.** A tile spanning `N` DEM samples is meshed from every `2^s`-th
//! sample, `s` the smallest with `N / 2^s <= max_cells` (cesium-terrain-builder resamples
//! every tile to a fixed grid the same way; we keep the DEM's own samples, which a store holds
//! as its levels). At `s = 0` the tile is [`tin::build_tile`] on the DEM's own samples, which
//! verifies it against every one of them. At `s > 0` it is meshed within a budget under its
//! bound against the decimated samples and then checked against every DEM sample under it
//! ([`super::check::check`]); the budgets and retries are [`super::walk`]'s. So every written tile is within
//! its bound of every non-void DEM sample, at any level, while the coarse levels read and mesh
//! a bounded number of samples.

use glam::{DVec2, dvec2};
use terrain_core::heightmap::VoidMask;
use terrain_core::mesh::Algorithm;
use terrain_core::tin::{self, GridLayout, TileId, TileMesh};
use terrain_core::{Crs, Georef};

use terrain_app::decimation::{BudgetPolicy, Decimation};
use terrain_app::samples::Samples;

/// Which mesher a tile gets (`terrain tiles --mesher`). **The rule (`auto`, the default): the
/// RTIN for a tile meshed from every sample (stride 1) of at most `max_cells` (256) cells across whose
/// parent kept at least `--rtin-density` of the DEM samples inside it as vertices; the greedy
/// Delaunay insertion for every other tile.** The parent's density predicts the tile's: the
/// tile's bound is half its parent's, so it keeps at least about as many. Where the greedy
/// mesh keeps most samples the RTIN (nearly the full grid there) draws nearly as many
/// triangles and costs about two passes over the samples (its error pass and its check),
/// while the greedy insertion pays a scan of each new vertex's neighbourhood; where it keeps
/// few, the RTIN draws 1.3-1.8x the triangles, whose clipping, encoding and writing cost more
/// than its build saves (measured per level: bench/mesh/README.md, branches tiles16c,
/// tiles16e and rtin16). `greedy` and `rtin` force one mesher everywhere, for
/// measurements.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub(crate) enum MesherChoice {
    /// Per tile: RTIN where the parent's density says the greedy mesh would keep most
    /// samples, else greedy (the default).
    #[default]
    Auto,
    /// The greedy Delaunay mesher for every tile (the fewest triangles).
    Greedy,
    /// The RTIN for every tile (for measurements).
    Rtin,
}

/// The fraction of a tile's DEM samples its parent kept as vertices, the figure
/// [`MesherChoice::Auto`] decides by: the `seeds` (the parent's vertices, DEM samples) inside
/// the tile's samples over those samples (0 for a tile without samples or seeds).
pub(crate) fn seed_density(layout: &GridLayout, tile: TileId, seeds: &[[u32; 2]]) -> f64 {
    let Some([i0, j0, i1, j1]) = samples_inside(layout, tile) else { return 0.0 };
    let inside = |v: u32, a: usize, b: usize| (a..=b).contains(&(v as usize));
    let kept = seeds.iter().filter(|&&[i, j]| inside(i, i0, i1) && inside(j, j0, j1)).count();
    kept as f64 / ((i1 - i0 + 1) * (j1 - j0 + 1)) as f64
}

impl MesherChoice {
    /// The builder of a tile meshed at stride `2^s` over `cells` cells across, its parent
    /// having kept `density` of its samples ([`seed_density`]).
    pub(crate) fn algorithm(
        self,
        config: &ResolutionConfig,
        s: u32,
        cells: usize,
        density: f64,
    ) -> Algorithm {
        match self {
            MesherChoice::Greedy => Algorithm::Delaunay,
            MesherChoice::Rtin => Algorithm::Rtin,
            MesherChoice::Auto
                if s == 0 && cells <= config.max_cells && density >= config.rtin_density =>
            {
                Algorithm::Rtin
            }
            MesherChoice::Auto => Algorithm::Delaunay,
        }
    }
}

/// [`ResolutionConfig::rtin_density`]'s default (`--rtin-density`). Measured on the rough
/// synthetic 4097^2 store, levels 12-15 (README, branch tiles16e): at a twentieth of the
/// bounds 0.5 took 0.65x the greedy mesher's CPU for 1.037x its triangles, 0.7 took 0.75x for
/// 1.017x; at a quarter of the bounds both were within the noise of greedy's CPU (1.03x and
/// 1.008x the triangles); at the default bounds 0.5 switches 35 of 9,132 tiles (0.2 switched
/// 3,148 for 1.09x the triangles and no CPU saved).
pub(crate) const RTIN_DENSITY: f64 = 0.5;

/// How tiles are sampled and meshed.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ResolutionConfig {
    /// Most cells across a tile's mesh input before it is decimated.
    pub max_cells: usize,
    /// The budget a decimated tile gets, its retries and strides (the one policy both
    /// pyramids use).
    pub policy: BudgetPolicy,
    /// The mesher.
    pub mesher: MesherChoice,
    /// [`MesherChoice::Auto`]'s threshold: the RTIN where the parent kept at least this
    /// fraction of a full-resolution tile's samples.
    pub rtin_density: f64,
    /// Most cells across a greedy tile's samples meshed at once: a larger tile (one meshed
    /// from every sample where the decimation error leaves too little of its bound) is meshed
    /// in pieces of at most this many cells a side with locked shared sides
    /// ([`tin::tile::mesh_in_pieces`]), so its samples held at once do not grow with the DEM.
    pub piece_cells: usize,
}

impl Default for ResolutionConfig {
    fn default() -> Self {
        Self {
            max_cells: 256,
            policy: BudgetPolicy::default(),
            mesher: MesherChoice::default(),
            rtin_density: RTIN_DENSITY,
            piece_cells: 2048,
        }
    }
}

/// The tile's rectangle in fractional grid coordinates (south-west, north-east).
pub(super) fn grid_rect(layout: &GridLayout, tile: TileId) -> (DVec2, DVec2) {
    let r = tile.rect();
    (layout.to_grid(dvec2(r.west, r.south)), layout.to_grid(dvec2(r.east, r.north)))
}

/// The DEM samples inside the tile (inclusive index ranges), or `None` if none is.
pub(super) fn samples_inside(layout: &GridLayout, tile: TileId) -> Option<[usize; 4]> {
    let (a, b) = grid_rect(layout, tile);
    let (w, h) = (layout.width as f64 - 1.0, layout.height as f64 - 1.0);
    let i0 = (a.x - 1e-9).ceil().max(0.0);
    let j0 = (a.y - 1e-9).ceil().max(0.0);
    let i1 = (b.x + 1e-9).floor().min(w);
    let j1 = (b.y + 1e-9).floor().min(h);
    (i0 <= i1 && j0 <= j1).then_some([i0 as usize, j0 as usize, i1 as usize, j1 as usize])
}

/// The most DEM cells across the tile's part of the DEM (fractional).
fn span(layout: &GridLayout, tile: TileId) -> f64 {
    let (a, b) = grid_rect(layout, tile);
    let (w, h) = (layout.width as f64 - 1.0, layout.height as f64 - 1.0);
    (b.x.min(w) - a.x.max(0.0)).max(b.y.min(h) - a.y.max(0.0)).max(0.0)
}

/// The most whole DEM cells across the tile's part of the DEM, at stride 1 (rounded up).
pub(crate) fn cells_across(layout: &GridLayout, tile: TileId) -> usize {
    span(layout, tile).ceil() as usize
}

/// The stride (log2) a tile is meshed at: the smallest `s` with at most `max_cells` cells
/// across at stride `2^s`.
pub(crate) fn stride_log2(layout: &GridLayout, tile: TileId, config: &ResolutionConfig) -> u32 {
    let span = span(layout, tile);
    let mut s = 0;
    while span / f64::from(1u32 << s) > config.max_cells as f64 && s < 30 {
        s += 1;
    }
    s
}

/// A tile built by [`build`].
pub(crate) struct Built {
    /// The mesh, its `bound` the tile's own.
    pub mesh: TileMesh,
    /// The DEM samples it took as vertices (its children's seeds).
    pub vertices: Vec<[u32; 2]>,
    /// The mesher.
    pub algorithm: Algorithm,
}

/// Builds `tile` from every `2^s`-th sample within `budget` metres of them (see the module
/// docs), seeded with the DEM samples `seeds` (`[i, j]`; those off the stride's lattice or
/// outside the window are skipped; an RTIN takes none), by `algorithm`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn build(
    samples: &dyn Samples,
    layout: &GridLayout,
    tile: TileId,
    s: u32,
    budget: f64,
    bound: f64,
    seeds: &[[u32; 2]],
    algorithm: Algorithm,
    config: &ResolutionConfig,
) -> anyhow::Result<Built> {
    let (a, b) = grid_rect(layout, tile);
    let (w, h) = (layout.width, layout.height);
    let t = 1usize << s;
    // The window: every 2^s-th sample from the one at or before the tile's west (south)
    // border to the one at or after its east (north) border, clipped to the DEM (the last
    // may lie past it and reads the last column or row).
    let lo = |v: f64| ((v.floor().max(0.0) as usize) >> s) << s;
    let hi = |v: f64, n: usize| (v.ceil().min(n as f64 - 1.0).max(0.0) as usize).div_ceil(t) * t;
    let (i0, j0) = (lo(a.x).min(w - 1), lo(a.y).min(h - 1));
    let (i1, j1) = (hi(b.x, w).max(i0 + t), hi(b.y, h).max(j0 + t));
    let (ww, wh) = ((i1 - i0) / t + 1, (j1 - j0) / t + 1);
    let origin = layout.to_lonlat(dvec2(i0 as f64, j0 as f64));
    let spacing = layout.spacing * t as f64;
    let centre_lat = origin.y + 0.5 * (wh as f64 - 1.0) * spacing.y;
    let georef = Georef::geographic(Crs::Epsg(4326), origin, spacing, centre_lat);
    let window = GridLayout::new(ww, wh, &georef)?;
    // The seeds on this window's lattice, in its coordinates.
    let on_lattice = |v: u32, v0: usize, n: usize| {
        let v = v as usize;
        (v >= v0 && (v - v0).is_multiple_of(t) && (v - v0) / t < n).then(|| ((v - v0) / t) as u32)
    };
    let local: Vec<[u32; 2]> = seeds
        .iter()
        .filter_map(|&[i, j]| Some([on_lattice(i, i0, ww)?, on_lattice(j, j0, wh)?]))
        .collect();
    // The tile's samples are read by rectangles of the window: at once, or piece by piece
    // where the tile spans more than `piece_cells` (then only a piece is held at a time).
    let read = |[a, b, c, d]: [usize; 4]| -> anyhow::Result<(Vec<f32>, Option<VoidMask>)> {
        let win = samples.window(i0 + a * t, j0 + b * t, c - a + 1, d - b + 1, s)?;
        Ok((win.data, win.voids))
    };
    let (mut mesh, used) =
        tin::build_tile_read(&window, tile, budget, &local, algorithm, config.piece_cells, read)?;
    mesh.bound = bound;
    let used =
        used.into_iter().map(|[i, j]| [(i0 + i as usize * t) as u32, (j0 + j as usize * t) as u32]);
    // The last row or column may stand past the DEM (read at its edge): not a DEM sample.
    let vertices = used.filter(|&[i, j]| (i as usize) < w && (j as usize) < h).collect();
    Ok(Built { mesh, vertices, algorithm })
}

/// The decimation error at stride `2^s` over the regions under `tile` (0 for a tile without
/// samples): [`Decimation::error_in`] over the DEM samples inside it.
pub(crate) fn decimation_error(
    decimation: &Decimation,
    samples: &dyn Samples,
    layout: &GridLayout,
    tile: TileId,
    s: u32,
) -> anyhow::Result<f64> {
    match samples_inside(layout, tile) {
        Some(rect) => decimation.error_in(samples, rect, s),
        None => Ok(0.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 257^2 geographic grid and a tile of it that lies inside, with at least 16^2 samples.
    fn grid_and_tile() -> (GridLayout, TileId, [usize; 4]) {
        let georef =
            Georef::geographic(Crs::Epsg(4326), dvec2(-122.5, 46.5), dvec2(1e-4, 1e-4), 46.5128);
        let layout = GridLayout::new(257, 257, &georef).unwrap();
        let level = layout.native_level(64.0);
        let (tile, rect) = layout
            .tile_range(level)
            .tiles(level)
            .filter_map(|t| Some((t, samples_inside(&layout, t)?)))
            .find(|(_, [i0, j0, i1, j1])| *i0 > 0 && *j0 > 0 && i1 - i0 >= 16 && j1 - j0 >= 16)
            .expect("a tile inside the grid");
        (layout, tile, rect)
    }

    /// The parent's density is counted over the tile's own samples only, and `auto` takes the
    /// RTIN exactly where the rule says: a full-resolution tile no larger than a piece whose
    /// parent kept at least the threshold; the greedy mesher at a coarser stride, in a larger
    /// tile, under the threshold, and always for `greedy` (the negative controls).
    #[test]
    fn auto_takes_the_rtin_where_the_parent_kept_most_samples() {
        let (layout, tile, [i0, j0, i1, j1]) = grid_and_tile();
        let n = (i1 - i0 + 1) * (j1 - j0 + 1);
        let inside: Vec<[u32; 2]> =
            (j0..=j1).flat_map(|j| (i0..=i1).map(move |i| [i as u32, j as u32])).collect();
        // Seeds outside the tile (the parent's other quarters) do not count.
        let outside = [[i0 as u32 - 1, j0 as u32], [i1 as u32 + 1, j1 as u32], [0, 0]];
        let mut all = inside.clone();
        all.extend(outside);
        assert_eq!(seed_density(&layout, tile, &all), 1.0);
        assert_eq!(seed_density(&layout, tile, &outside), 0.0);
        let half: Vec<[u32; 2]> = inside.iter().copied().step_by(2).collect();
        let d = seed_density(&layout, tile, &half);
        assert_eq!(d, half.len() as f64 / n as f64);
        assert!((d - 0.5).abs() < 0.01, "{d}");

        let config = ResolutionConfig { rtin_density: 0.4, ..ResolutionConfig::default() };
        let cells = cells_across(&layout, tile);
        assert!(cells >= 16 && cells <= config.max_cells, "{cells}");
        let auto = |s, cells, density| MesherChoice::Auto.algorithm(&config, s, cells, density);
        assert_eq!(auto(0, cells, d), Algorithm::Rtin);
        assert_eq!(auto(0, cells, 0.4), Algorithm::Rtin, "at the threshold");
        assert_eq!(auto(0, cells, 0.39), Algorithm::Delaunay, "under the threshold");
        assert_eq!(auto(1, cells, 1.0), Algorithm::Delaunay, "a decimated tile");
        // A tile at full resolution only because its decimation error left too little of its
        // bound: its window is larger than a full-resolution level's.
        assert_eq!(auto(0, config.max_cells + 1, 1.0), Algorithm::Delaunay, "a large window");
        let greedy = MesherChoice::Greedy.algorithm(&config, 0, cells, 1.0);
        assert_eq!(greedy, Algorithm::Delaunay);
        assert_eq!(MesherChoice::Rtin.algorithm(&config, 3, cells, 0.0), Algorithm::Rtin);
    }
}
