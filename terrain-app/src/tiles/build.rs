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

/// Which mesher a tile gets (`terrain tiles --mesher`). **The rule: greedy Delaunay at
/// every level.** Measured per level on the rough synthetic 4097^2 store (README, branch
/// tiles16c), the RTIN never cost less CPU than the greedy mesher at any level, even at
/// level 15 where the greedy mesh keeps about a third of the samples (RTIN: about the same
/// meshing time, 35 % more triangles and bytes, so more writing), and at the coarse
/// full-resolution levels (10-12: windows of 257^2 to 1025^2 samples in a power-of-two
/// square) it cost several times the greedy mesher: its error pass scans every sample
/// `2 log2(side)` times whatever the bound, and its vertices follow a fixed hierarchy.
/// `rtin` stays for that measurement.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub(crate) enum MesherChoice {
    /// The greedy Delaunay mesher for every tile (the fewest triangles; the default).
    #[default]
    Greedy,
    /// The RTIN for every tile (for measurements).
    Rtin,
}

impl MesherChoice {
    /// The core's builder.
    pub(crate) fn algorithm(self) -> Algorithm {
        match self {
            MesherChoice::Greedy => Algorithm::Delaunay,
            MesherChoice::Rtin => Algorithm::Rtin,
        }
    }
}

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

/// The stride (log2) a tile is meshed at: the smallest `s` with at most `max_cells` cells
/// across at stride `2^s`.
pub(crate) fn stride_log2(layout: &GridLayout, tile: TileId, config: &ResolutionConfig) -> u32 {
    let (a, b) = grid_rect(layout, tile);
    let (w, h) = (layout.width as f64 - 1.0, layout.height as f64 - 1.0);
    let span = (b.x.min(w) - a.x.max(0.0)).max(b.y.min(h) - a.y.max(0.0)).max(0.0);
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
/// outside the window are skipped; an RTIN takes none), by `config.mesher`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn build(
    samples: &dyn Samples,
    layout: &GridLayout,
    tile: TileId,
    s: u32,
    budget: f64,
    bound: f64,
    seeds: &[[u32; 2]],
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
    let algorithm = config.mesher.algorithm();
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
