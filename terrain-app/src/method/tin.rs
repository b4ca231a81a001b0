//! `tin`: our own LOD method, an error-bounded TIN pyramid on the grid's quadtree
//! ([`terrain_core::tin::grid`]): per frame, tiles chosen by Cesium's screen-space error
//! against `tau_px` and frustum-culled, joined by stitches where levels meet, drawn as the
//! tessellation renderer's extra triangles on one carrier patch ([`entropy_extra`], as the
//! entropy mesh) and measured on the CPU as built. The pyramid is built once per terrain
//! ([`build_pyramid`]: every tile on rayon's threads, with a progress line on a terminal).

use std::cell::RefCell;
use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use rayon::prelude::*;
use terrain_core::Heightmap;
use terrain_core::geometry::Camera;
use terrain_core::lod::{Patch, Selection, SelectionStats};
use terrain_core::quadtree::{NodeId, TreeShape};
use terrain_core::tin::decimation::{error_upper_bound, lattice_deviation};
use terrain_core::tin::grid::{
    GridTile, GridTinConfig, GridTinPyramid, TileWindow, TinSelection, build_tile_within,
    tile_error_in, tile_window,
};

use super::memory::ms;
use super::{Draw, DrawSource, DrawnSurface, Frame, Method, MethodStats, entropy_extra};
use crate::decimation::{
    BudgetPolicy, DECIMATION_REGION, Decimation, build_within, planned_stride,
};
use crate::methods::{LodMethod, MethodScene};
use crate::progress::{Progress, on_terminal};
use crate::samples::{HeightmapSamples, Samples, VoidsAsData};

/// The `tin` method's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TinConfig {
    /// Cesium's screen-space error threshold, pixels: a tile is refined while
    /// `e_L lambda / d > tau_px`. Default 1.
    pub tau_px: f64,
    /// The pyramid (bounds per level, finest tiles).
    pub pyramid: GridTinConfig,
    /// Close the gaps where a tile meets finer ones with stitches (default true; false is the
    /// crack test's negative control).
    pub stitch: bool,
    /// How a store is read ([`super::TinStoreMethod`]).
    pub store: super::TinStoreConfig,
}

impl Default for TinConfig {
    fn default() -> Self {
        Self {
            tau_px: 1.0,
            pyramid: GridTinConfig::default(),
            stitch: true,
            store: super::TinStoreConfig::default(),
        }
    }
}

/// Builds the pyramid of `hm` on rayon's threads (tiles weighted by their samples in the
/// progress line, shown on a terminal only), every tile by [`GridTileBuilder::build`] (from
/// all of its samples, or with `max_tile_cells` from decimated samples within a budget, proven
/// or checked, as from a store).
pub fn build_pyramid(hm: &Heightmap, config: &GridTinConfig) -> anyhow::Result<GridTinPyramid> {
    let bar = Progress::new("TIN pyramid", on_terminal());
    let total = (hm.width() * hm.height()) as f64;
    let done = AtomicU64::new(0);
    let pyramid = GridTinPyramid::build_by(hm, config, |shape, errors, nodes| {
        let levels = nodes.iter().map(|n| n.level).max().map_or(1, |l| u64::from(l) + 1);
        let tiles = GridTileBuilder::new(
            VoidsAsData(HeightmapSamples(hm)),
            *shape,
            errors.to_vec(),
            config.max_tile_cells,
        );
        // With decimated tiles, every region's decimation error now (their strides capped).
        let tiles = match config.max_tile_cells {
            Some(_) => tiles.measured_now(config.finer_strides)?,
            None => tiles,
        };
        // Level by level (the nodes come coarse first), each tile seeded by its parent's
        // vertices, as every builder of `tin`'s tiles seeds them.
        let mut built: Vec<GridTile> = Vec::with_capacity(nodes.len());
        let mut parents: HashMap<NodeId, usize> = HashMap::new();
        for level in nodes.chunk_by(|a, b| a.level == b.level) {
            let this: Vec<GridTile> = level
                .par_iter()
                .map(|&n| {
                    let parent = n.parent().and_then(|p| parents.get(&p));
                    let seeds = parent.map_or(&[][..], |&k| &built[k].vertices[..]);
                    let t = tiles.build(n, seeds);
                    if let Ok(t) = &t {
                        let samples = t.measured.samples.max(1) as u64;
                        let now = done.fetch_add(samples, Ordering::Relaxed) + samples;
                        bar.update(now as f64, total * levels as f64);
                    }
                    t
                })
                .collect::<anyhow::Result<_>>()?;
            parents = (0..this.len()).map(|k| (this[k].node, built.len() + k)).collect();
            built.extend(this);
        }
        anyhow::Ok(built)
    })?;
    bar.finish();
    Ok(pyramid)
}

/// Samples under a tile up to which a decimated tile whose exact bound
/// ([`lattice_deviation`]) misses its bound is measured against every one of them before it
/// is rebuilt; above it the proof's value is the check's (a rebuild with a smaller budget, or
/// one stride finer).
const EXACT_CHECK_SAMPLES: u64 = 1 << 22;

/// A decimation error as [`Decimation`] gives it (an `f32`'s value) made an upper bound of
/// the exact one ([`error_upper_bound`]).
fn upper(e: f64) -> f64 {
    error_upper_bound(e as f32)
}

/// The one builder of `tin`'s tiles from any sample source (a DEM in memory, a store): a
/// tile is meshed from its [`tile_window`] (at the stride `max_cells` allows) within the
/// budget [`build_within`] gives it against the decimation error under it
/// ([`Decimation`], measured per region on first need, all at once, or taken from a store's
/// table), and a decimated tile is proven within its bound from its window
/// ([`lattice_deviation`] plus the decimation error) or checked against every sample under it
/// ([`tile_error_in`], window by window), so every tile is within its bound
/// ([`GridTileBuilder::tile_bound`]: its level's, or more where
/// [`GridTinConfig::finer_strides`] caps its stride) of every non-void sample, at any level.
#[derive(Debug)]
pub struct GridTileBuilder<S> {
    samples: S,
    shape: TreeShape,
    errors: Vec<f64>,
    max_cells: Option<u32>,
    decimation: Decimation,
    policy: BudgetPolicy,
    /// Per level (none from the first level whose tiles' own stride is at most `finer`, and
    /// none when the decimation errors are not known): each node's bound, row-major.
    bounds: Vec<Vec<f64>>,
    /// How many strides finer than its own a tile is meshed at most
    /// ([`GridTinConfig::finer_strides`]; used only with `bounds`).
    finer: u32,
}

impl<S: Samples> GridTileBuilder<S> {
    /// Tiles of a tree of `shape` over `samples`, level bounds `errors`, each meshed down to
    /// every sample where its level's bound needs it (the decimation errors measured on first
    /// need); see [`GridTileBuilder::measured_now`] and [`GridTileBuilder::with_table`].
    pub fn new(samples: S, shape: TreeShape, errors: Vec<f64>, max_cells: Option<u32>) -> Self {
        let (w, h) = samples.size();
        // The strides the tiles may use: up to the root's, and up to a region's side (so a
        // store's per-block table covers them all).
        let region_s = DECIMATION_REGION.trailing_zeros();
        let max_s = tile_window(&shape, NodeId::new(0, 0, 0), max_cells)
            .map_or(0, |w| w.stride_log2)
            .min(region_s);
        let decimation = Decimation::new(w, h, DECIMATION_REGION, max_s);
        let policy = BudgetPolicy::default();
        let finer = 0;
        Self { samples, shape, errors, max_cells, decimation, policy, bounds: Vec::new(), finer }
    }

    /// The builder with every region's decimation error measured now, on every core (a DEM in
    /// memory), and its tiles' strides capped ([`GridTinConfig::finer_strides`]).
    pub fn measured_now(mut self, finer: u32) -> anyhow::Result<Self> {
        self.finer = finer;
        if self.decimation.max_s() > 0 {
            self.decimation.measure_all(&self.samples, |_, _, _| ())?;
        }
        self.bounds = self.node_bounds()?;
        Ok(self)
    }

    /// The builder with the decimation errors of region `(x, y)` taken from `table(x, y)` (a
    /// store's, baked from the same heights by the same function), and its tiles meshed at
    /// most `finer` strides finer than their own ([`GridTinConfig::finer_strides`]); unchanged
    /// (errors measured on first need, no cap) when the table lacks a region or has too few
    /// strides.
    pub fn with_table<'t>(
        mut self,
        finer: u32,
        table: impl Fn(usize, usize) -> Option<&'t [f32]>,
    ) -> Self {
        self.finer = finer;
        let (rx, ry) = self.decimation.regions();
        let mut complete = true;
        'all: for y in 0..ry {
            for x in 0..rx {
                match table(x, y) {
                    Some(e) if self.decimation.set_region(x, y, e) => {}
                    _ => {
                        complete = false;
                        break 'all;
                    }
                }
            }
        }
        if complete && let Ok(bounds) = self.node_bounds() {
            self.bounds = bounds;
        }
        self
    }

    /// Each capped level's node bounds (see [`GridTinConfig::finer_strides`]).
    fn node_bounds(&self) -> anyhow::Result<Vec<Vec<f64>>> {
        let floor = self.policy.min_budget_fraction;
        let samples = &self.samples as &dyn Samples;
        let mut bounds = Vec::new();
        for level in 0..=self.shape.max_level() {
            let (nx, ny) = self.shape.level_dims(level);
            let own = |i: u32, j: u32| self.own_stride(NodeId::new(level, i, j)).unwrap_or(0);
            if (0..ny).all(|j| (0..nx).all(|i| own(i, j) <= self.finer)) {
                break;
            }
            let bound = self.errors.get(level as usize).copied().unwrap_or(0.0);
            let mut row = Vec::with_capacity((nx * ny) as usize);
            for j in 0..ny {
                for i in 0..nx {
                    // (`bounds` is being made: the cap itself, not `finest_stride`.)
                    let s = own(i, j).saturating_sub(self.finer);
                    let Some(r) = self.shape.clipped_rect(NodeId::new(level, i, j)) else {
                        row.push(bound);
                        continue;
                    };
                    let rect = [r.x0, r.y0, r.x1, r.y1].map(|v| v as usize);
                    let e = upper(self.decimation.error_in(samples, rect, s)?);
                    row.push(bound.max(e + floor * bound));
                }
            }
            bounds.push(row);
        }
        Ok(bounds)
    }

    /// The bound tile `node` is built within (and selected by), metres: its level's `e_L`, or,
    /// for a builder whose decimation errors are known, `E + floor x e_L` where even `finer`
    /// strides finer than its own the decimation error `E` leaves less than the budget floor
    /// (`floor x e_L`, [`BudgetPolicy::min_budget_fraction`]) of it.
    pub fn tile_bound(&self, node: NodeId) -> f64 {
        let level = self.errors.get(node.level as usize).copied().unwrap_or(0.0);
        let Some(row) = self.bounds.get(node.level as usize) else {
            return level;
        };
        let (nx, _) = self.shape.level_dims(node.level);
        row.get((node.j * nx + node.i) as usize).copied().unwrap_or(level)
    }

    /// The stride (log2) tile `node` will first be meshed at ([`planned_stride`]), known
    /// without reading a sample where the builder's decimation errors are
    /// ([`GridTileBuilder::measured_now`], [`GridTileBuilder::with_table`]); `None` otherwise.
    pub fn planned_stride(&self, node: NodeId) -> Option<u32> {
        if self.bounds.is_empty() {
            return None;
        }
        let own = tile_window(&self.shape, node, self.max_cells)?;
        let r = self.shape.clipped_rect(node)?;
        let rect = [r.x0, r.y0, r.x1, r.y1].map(|v| v as usize);
        let samples = &self.samples as &dyn Samples;
        let error = |s: u32| self.decimation.error_in(samples, rect, s);
        let min_s = self.finest_stride(own.stride_log2);
        planned_stride(self.tile_bound(node), own.stride_log2, min_s, &self.policy, error).ok()
    }

    /// Tile `node`'s own stride (log2): that of its window of at most `max_cells` cells
    /// across ([`tile_window`]); `None` outside the grid.
    pub fn own_stride(&self, node: NodeId) -> Option<u32> {
        tile_window(&self.shape, node, self.max_cells).map(|w| w.stride_log2)
    }

    /// The finest stride (log2) a tile of own stride `2^own` is meshed at before a failed
    /// check sends it finer: `finer` strides finer with the decimation errors known
    /// (`bounds`), else any (0).
    pub(crate) fn finest_stride(&self, own: u32) -> u32 {
        if self.bounds.is_empty() { 0 } else { own.saturating_sub(self.finer) }
    }

    /// The sample source.
    pub fn samples(&self) -> &S {
        &self.samples
    }

    /// Every level's bound, metres.
    pub fn errors(&self) -> &[f64] {
        &self.errors
    }

    /// The tree's shape.
    pub fn shape(&self) -> &TreeShape {
        &self.shape
    }

    /// Tile `node`: see the type's docs. Meshed from every sample, its greedy insertion
    /// starts from `seeds`, its parent tile's vertices ([`build_tile_within`]; empty for the
    /// root): every caller passes them (the pyramid in memory level by level, the bake, the
    /// run-time builders), so a tile is the same tile whoever builds it.
    pub fn build(&self, node: NodeId, seeds: &[[u32; 2]]) -> anyhow::Result<GridTile> {
        let own = tile_window(&self.shape, node, self.max_cells)
            .ok_or_else(|| anyhow::anyhow!("tile {node:?} lies outside the grid"))?;
        let rect = self
            .shape
            .clipped_rect(node)
            .map(|r| [r.x0, r.y0, r.x1, r.y1])
            .ok_or_else(|| anyhow::anyhow!("tile {node:?} lies outside the grid"))?;
        let bound = self.tile_bound(node);
        let min_s = self.finest_stride(own.stride_log2);
        let samples = &self.samples as &dyn Samples;
        let error = |s: u32| self.decimation.error_in(samples, rect.map(|v| v as usize), s);
        // The last decimated window meshed, for its tile's exact bound.
        let last: RefCell<Option<(TileWindow, Vec<f32>)>> = RefCell::new(None);
        let build = |s: u32, budget: f64| -> anyhow::Result<GridTile> {
            let (wc, hc) = (rect[2] - rect[0], rect[3] - rect[1]);
            let win = TileWindow {
                width: (wc >> s) as usize + 1,
                height: (hc >> s) as usize + 1,
                stride_log2: s,
                ..own
            };
            let w = samples.window(win.x0 as usize, win.y0 as usize, win.width, win.height, s)?;
            // Seeded from every sample only: a decimated mesh is proven by its lattice
            // deviation, which seeds move (a tile planned at one stride then fails its check
            // there now and then and goes finer than the streamer was told).
            let seeds = if s == 0 { seeds } else { &[] };
            let tile =
                build_tile_within(node, &win, &w.data, w.voids.as_ref(), budget, bound, seeds)?;
            // A window with voids is checked against every sample (the lattice's bound
            // interpolates the voids' heights, which the mesher does not measure).
            *last.borrow_mut() = (s > 0 && w.voids.is_none()).then_some((win, w.data));
            Ok(tile)
        };
        let check = |tile: &GridTile| -> anyhow::Result<Option<f64>> {
            let proven = match last.borrow().as_ref() {
                Some((win, data)) => {
                    let e = upper(error(win.stride_log2)?);
                    Some(e + lattice_deviation(tile, win, data))
                }
                None => None,
            };
            let n = u64::from(rect[2] - rect[0] + 1) * u64::from(rect[3] - rect[1] + 1);
            match proven {
                Some(p) if p <= bound || n > EXACT_CHECK_SAMPLES => Ok(Some(p)),
                _ => Ok(Some(tile_error_full(samples, tile, rect)?)),
            }
        };
        let built = build_within(
            bound,
            own.stride_log2,
            min_s,
            &self.policy,
            error,
            build,
            |t: &GridTile| t.measured.max_error,
            check,
        )?;
        Ok(built.mesh)
    }
}

/// The largest error of `tile` against every non-void sample of `rect` (`[x0, y0, x1, y1]`,
/// inclusive), read window by window ([`DECIMATION_REGION`] cells a side).
pub fn tile_error_full(
    samples: &dyn Samples,
    tile: &GridTile,
    rect: [u32; 4],
) -> anyhow::Result<f64> {
    let r = DECIMATION_REGION as u32;
    let mut worst = 0f64;
    let mut y = rect[1];
    while y <= rect[3] {
        let y1 = (y + r - 1).min(rect[3]);
        let mut x = rect[0];
        while x <= rect[2] {
            let x1 = (x + r - 1).min(rect[2]);
            let (ww, wh) = ((x1 - x + 1) as usize, (y1 - y + 1) as usize);
            let win = samples.window(x as usize, y as usize, ww, wh, 0)?;
            let (x0, y0) = (x as usize, y as usize);
            let e = tile_error_in(tile, [x, y, x1, y1], |i, j| {
                let (a, b) = (i - x0, j - y0);
                let void = win.voids.as_ref().is_some_and(|v| v.get(a, b));
                (!void).then(|| win.data[b * ww + a])
            });
            worst = worst.max(e);
            x = x1 + 1;
        }
        y = y1 + 1;
    }
    Ok(worst)
}

/// The tiles of a frame as a [`Selection`] of their nodes (what the measurement counts as
/// covered; the factors are not used).
pub fn tin_selection(sel: &TinSelection) -> Selection {
    let patches: Vec<Patch> =
        sel.tiles.iter().map(|&node| Patch { node, outer: [1.0; 4], inner: [1.0; 2] }).collect();
    let stats = SelectionStats {
        traversal_leaves: patches.len(),
        patches: patches.len(),
        culled: sel.culled,
        max_level: patches.iter().map(|p| p.node.level).max().unwrap_or(0),
        cpu_time: sel.cpu_time,
        ..SelectionStats::default()
    };
    Selection { patches, stats }
}

/// `tin` over a [`MethodScene`] (its pyramid and current config).
#[derive(Debug)]
pub struct TinMethod<'a> {
    scene: &'a MethodScene,
    pyramid: &'a GridTinPyramid,
}

impl<'a> TinMethod<'a> {
    /// The method over `scene`, its pyramid built on first use.
    pub fn new(scene: &'a MethodScene) -> anyhow::Result<Self> {
        Ok(Self { scene, pyramid: scene.tin_pyramid()? })
    }
}

impl Method for TinMethod<'_> {
    fn kind(&self) -> LodMethod {
        LodMethod::Tin
    }

    /// The traversal is the selection time; joining the tiles' meshes and the stitches the
    /// build time (the benchmark's tessellation time).
    fn frame(&mut self, camera: &Camera) -> Frame {
        let (scene, config) = (self.scene, &self.scene.config.tin);
        let sel = self.pyramid.select(camera, config.tau_px);
        let t = Instant::now();
        let surface = self.pyramid.surface(&scene.hm, &sel.tiles, config.stitch);
        let build_ms = ms(t);
        let t = Instant::now();
        let (carrier, extra) = entropy_extra(&scene.hm, &surface.mesh);
        let convert_ms = ms(t);
        let triangles = surface.tile_triangles + surface.stitch_triangles;
        Frame {
            selection: tin_selection(&sel),
            draw: Draw::Tessellated { patches: vec![carrier], extra },
            stats: MethodStats {
                selection_ms: sel.cpu_time.as_secs_f64() * 1e3,
                build_ms,
                convert_ms,
                patches: sel.tiles.len(),
                ..MethodStats::default()
            },
            built: Some((surface.mesh, triangles)),
        }
    }

    fn surface(&self, frame: &mut Frame) -> anyhow::Result<DrawnSurface> {
        frame.take_built("tin")
    }

    fn draws_on(&self) -> DrawSource<'_> {
        DrawSource::Tessellation(&self.scene.hm)
    }
}
