//! The order `terrain tiles` builds its tiles in: a depth-first walk of the tile quadtree, each
//! tile built, checked against every DEM sample under it, written and dropped before its
//! children are visited, so the meshes held at once are bounded by the threads and the depth,
//! not by the tiles of a level (the walk reports its peak, `peak_pending_tiles`).
//!
//! **Budget per tile.** A tile at stride `2^s > 1` ([`build::stride_log2`]) is meshed within
//! `bound - E` of the strided samples, `E` the decimation error measured once per region and
//! stride ([`build::Decimation`]): the largest difference between a DEM sample and the strided
//! grid's interpolation. Where `bound - E` is under `min_budget_fraction x bound` the tile is
//! meshed at the next finer stride instead (at `s = 0`, `E = 0`). Every decimated tile is then
//! checked against every DEM sample under it ([`build::check`]); one that fails is built again
//! with its budget cut by the excess measured, at most [`MAX_RETRIES`] times, then one stride
//! finer (each rebuild counts as a retry). At `s = 0` the builder's own check covers every
//! sample.

use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;
use terrain_core::tin::{GridLayout, TileId, TileMesh, TileRange};

use super::build::{self, Decimation, ResolutionConfig};
use terrain_app::samples::Samples;

/// Rebuilds of a tile at one stride with a smaller budget before it goes one stride finer.
pub(crate) const MAX_RETRIES: u32 = 2;

/// What the walk needs.
pub(crate) struct Walk<'a> {
    pub samples: &'a dyn Samples,
    pub layout: &'a GridLayout,
    pub resolution: ResolutionConfig,
    pub decimation: &'a Decimation,
    /// Cells per side of the windows a decimated tile is checked by.
    pub check_region: usize,
    pub max_level: u32,
    /// The tiles of a level.
    pub range: &'a (dyn Fn(u32) -> TileRange + Sync),
    /// A tile's bound, metres.
    pub bound: &'a (dyn Fn(TileId) -> f64 + Sync),
    /// Writes a checked tile with its measured error and decimation error.
    pub write: &'a (dyn Fn(&TileMesh, f64, f64) -> anyhow::Result<()> + Sync),
}

/// What the walk did.
#[derive(Debug, Default)]
pub(crate) struct WalkStats {
    /// Tiles meshed from decimated samples (and so checked against every sample).
    pub decimated_tiles: usize,
    /// Rebuilds after a failed check.
    pub retries: usize,
    /// Most tiles whose mesh was being built, checked or written at once.
    pub peak_pending_tiles: usize,
}

#[derive(Default)]
struct Counters {
    decimated: AtomicUsize,
    retries: AtomicUsize,
    pending: AtomicUsize,
    peak: AtomicUsize,
}

impl Walk<'_> {
    /// Visits every tile from the `roots` down to `max_level`, on every core.
    pub(crate) fn run(&self, roots: &[TileId]) -> anyhow::Result<WalkStats> {
        let c = Counters::default();
        roots.par_iter().try_for_each(|&t| self.visit(t, &c))?;
        Ok(WalkStats {
            decimated_tiles: c.decimated.into_inner(),
            retries: c.retries.into_inner(),
            peak_pending_tiles: c.peak.into_inner(),
        })
    }

    fn visit(&self, tile: TileId, c: &Counters) -> anyhow::Result<()> {
        let now = c.pending.fetch_add(1, Ordering::SeqCst) + 1;
        c.peak.fetch_max(now, Ordering::SeqCst);
        let done = self.one(tile, c);
        c.pending.fetch_sub(1, Ordering::SeqCst);
        done?;
        if tile.level < self.max_level
            && let Some(below) = (self.range)(tile.level + 1).below(tile)
        {
            // South row first, west to east: neighbours in the walk read neighbouring blocks.
            let children: Vec<TileId> = below.tiles(tile.level + 1).collect();
            children.par_iter().try_for_each(|&t| self.visit(t, c))?;
        }
        Ok(())
    }

    /// Builds, checks and writes one tile; its mesh is dropped on return.
    fn one(&self, tile: TileId, c: &Counters) -> anyhow::Result<()> {
        let bound = (self.bound)(tile);
        let floor = self.resolution.min_budget_fraction * bound;
        let error = |s: u32| self.decimation.error(self.layout, tile, s);
        // The coarsest stride, up to the tile's own, whose decimation error leaves the floor.
        let coarsest = |mut s: u32| {
            while s > 0 && bound - error(s) < floor {
                s -= 1;
            }
            s
        };
        let mut s = coarsest(build::stride_log2(self.layout, tile, &self.resolution));
        if s == 0 {
            let mesh = build::build(self.samples, self.layout, tile, 0, bound, bound)?;
            let measured = mesh.measured.map_or(0.0, |m| m.max_error);
            return (self.write)(&mesh, measured, 0.0);
        }
        c.decimated.fetch_add(1, Ordering::Relaxed);
        let mut budget = bound - error(s);
        let mut tries = 0;
        loop {
            let mesh = build::build(self.samples, self.layout, tile, s, budget, bound)?;
            let measured = build::check(self.samples, self.layout, &mesh, self.check_region)?;
            match measured {
                Some(e) if e <= bound => return (self.write)(&mesh, e, error(s)),
                _ => {}
            }
            c.retries.fetch_add(1, Ordering::Relaxed);
            tries += 1;
            // Cut the budget by the excess (and a hundredth of the bound more), or go finer.
            let cut = measured.map(|e| budget - (e - bound) - 0.01 * bound);
            match cut {
                Some(b) if tries <= MAX_RETRIES && b >= floor => budget = b,
                _ => {
                    s = coarsest(s - 1);
                    tries = 0;
                    budget = bound - error(s);
                    if s == 0 {
                        let mesh = build::build(self.samples, self.layout, tile, 0, bound, bound)?;
                        let measured = mesh.measured.map_or(0.0, |m| m.max_error);
                        return (self.write)(&mesh, measured, 0.0);
                    }
                }
            }
        }
    }
}
