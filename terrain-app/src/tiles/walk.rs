//! The order `terrain tiles` builds its tiles in: a depth-first walk of the tile quadtree, each
//! tile built, checked against every DEM sample under it, written and dropped before its
//! children are visited, so the meshes held at once are bounded by the threads and the depth,
//! not by the tiles of a level (the walk reports its peak, `peak_pending_tiles`).
//!
//! **Budget per tile.** A tile at stride `2^s > 1` ([`build::stride_log2`]) is meshed within
//! `bound - E` of the strided samples, `E` the decimation error measured once per region and
//! stride ([`Decimation`]; the policy is [`build_within`], shared with the `tin` method): the largest difference between a DEM sample and the strided
//! grid's interpolation. Where `bound - E` is under `min_budget_fraction x bound` the tile is
//! meshed at the next finer stride instead (at `s = 0`, `E = 0`). Every decimated tile is then
//! checked against every DEM sample under it ([`check::check`]); one that fails is built again
//! with its budget cut by the excess measured, at most `max_retries` times, then one stride
//! finer (each rebuild counts as a retry). At `s = 0` the builder's own check covers every
//! sample.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use rayon::prelude::*;
use terrain_core::mesh::Algorithm;
use terrain_core::tin::{GridLayout, TileId, TileMesh, TileRange};

use super::build::{self, ResolutionConfig};
use super::check::{self, SampleRange};
use terrain_app::decimation::{Decimation, build_within};
use terrain_app::samples::Samples;

/// What the walk needs.
pub(crate) struct Walk<'a> {
    pub samples: &'a dyn Samples,
    pub layout: &'a GridLayout,
    pub resolution: ResolutionConfig,
    pub decimation: &'a Decimation,
    /// The samples' minima and maxima a decimated tile is checked with.
    pub range: &'a SampleRange,
    pub max_level: u32,
    /// The tiles of a level.
    pub tiles: &'a (dyn Fn(u32) -> TileRange + Sync),
    /// A tile's bound, metres.
    pub bound: &'a (dyn Fn(TileId) -> f64 + Sync),
    /// Writes a checked tile ([`Done`]: how it was built).
    pub write: &'a (dyn Fn(&TileMesh, &Done) -> anyhow::Result<()> + Sync),
}

/// How a checked tile was built, for its level's statistics.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Done {
    /// Its largest error against every DEM sample under it, metres.
    pub measured: f64,
    /// The decimation error it was meshed under, metres.
    pub decimation: f64,
    /// Seconds its mesh took (built and checked, on its thread).
    pub mesh_s: f64,
    /// Whether it is an RTIN (else greedy Delaunay).
    pub rtin: bool,
    /// The samples it was meshed from and verified against (at its stride).
    pub samples: usize,
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
        roots.par_iter().try_for_each(|&t| self.visit(t, &[], &c))?;
        Ok(WalkStats {
            decimated_tiles: c.decimated.into_inner(),
            retries: c.retries.into_inner(),
            peak_pending_tiles: c.peak.into_inner(),
        })
    }

    /// Visits `tile` (seeded with its parent's vertices, `seeds`) and the tiles below it.
    fn visit(&self, tile: TileId, seeds: &[[u32; 2]], c: &Counters) -> anyhow::Result<()> {
        let now = c.pending.fetch_add(1, Ordering::SeqCst) + 1;
        c.peak.fetch_max(now, Ordering::SeqCst);
        let done = self.one(tile, seeds, c);
        c.pending.fetch_sub(1, Ordering::SeqCst);
        let vertices = done?;
        if tile.level < self.max_level
            && let Some(below) = (self.tiles)(tile.level + 1).below(tile)
        {
            // South row first, west to east: neighbours in the walk read neighbouring blocks.
            let children: Vec<TileId> = below.tiles(tile.level + 1).collect();
            children.par_iter().try_for_each(|&t| self.visit(t, &vertices, c))?;
        }
        Ok(())
    }

    /// Builds, checks and writes one tile; its mesh is dropped on return, its vertices (DEM
    /// samples, its children's seeds) are returned.
    fn one(&self, tile: TileId, seeds: &[[u32; 2]], c: &Counters) -> anyhow::Result<Vec<[u32; 2]>> {
        let started = Instant::now();
        let bound = (self.bound)(tile);
        let error =
            |s: u32| build::decimation_error(self.decimation, self.samples, self.layout, tile, s);
        let density = build::seed_density(self.layout, tile, seeds);
        let cells = build::cells_across(self.layout, tile);
        let r = &self.resolution;
        let built = build_within(
            bound,
            build::stride_log2(self.layout, tile, &self.resolution),
            0,
            &self.resolution.policy,
            error,
            |s, budget| {
                build::build(
                    self.samples,
                    self.layout,
                    tile,
                    s,
                    budget,
                    bound,
                    seeds,
                    r.mesher.algorithm(r, s, cells >> s, density),
                    r,
                )
            },
            |b: &build::Built| b.mesh.measured.map_or(0.0, |m| m.max_error),
            |b| check::check(self.samples, self.layout, &b.mesh, self.range),
        )?;
        if built.decimated {
            c.decimated.fetch_add(1, Ordering::Relaxed);
        }
        c.retries.fetch_add(built.retries, Ordering::Relaxed);
        let build::Built { mesh, mut vertices, algorithm } = built.mesh;
        let seconds = started.elapsed().as_secs_f64();
        let done = Done {
            measured: built.measured,
            decimation: built.decimation,
            mesh_s: seconds,
            rtin: algorithm == Algorithm::Rtin,
            samples: mesh.measured.as_ref().map_or(0, |m| m.samples),
        };
        (self.write)(&mesh, &done)?;
        if built.stride_log2 > 0 {
            // Chosen against strided samples within a budget under the bound: too many, and
            // not where the full-resolution child needs them (seeding with them cost level 10
            // and 11 of the rough synthetic 4097^2 store 17-19 % more triangles).
            vertices = Vec::new();
        }
        Ok(vertices)
    }
}
