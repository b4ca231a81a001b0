//! A store's terrain as every LOD method reads it: [`StoreSource`], terrain-core's
//! `TerrainSource` over a [`StoreTree`] (node bounds from the store's index, no heights in
//! memory) and a [`Streamer`]'s resident levels (heights).
//!
//! With this, the in-memory methods (the PVPS paper's A/B/C, the DSS paper's Methods I and II,
//! uniform) select their patches over a store exactly as over a heightmap: the tree's nodes
//! are the heightmap quadtree's nodes (same root, same clipping, the same min/max when the
//! store keeps per-node values down to the methods' leaves: the default bake's node levels
//! reach 16-cell nodes), and a height at a grid sample is the stored sample whenever its level
//! is resident (a patch corner of a node at block-local level `l` is a vertex of level `l` or
//! coarser). Where it is not, the height is the bilinear value of the block's finest resident
//! lattice, as the paged renderer draws it. The method's per-node error tables come from the
//! scene files beside the store; what its patches need is handed to the streamer as its
//! demand ([`Streamer::set_demand`], [`demand_of`]).

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use glam::{DVec2, DVec3};
use terrain_core::bilinear_clamped;
use terrain_core::lod::{Selection, TerrainSource};
use terrain_core::quadtree::{NodeId, NodeInfo, NodeSource, NodeTree, TreeShape};

use crate::format::{BlockEntry, BlockId};
use crate::lod::{KnownSamples, StoreTree};
use crate::store::BlockLevels;
use crate::streamer::Streamer;

/// A store's terrain for the LOD methods: its tree's nodes, heights from what `streamer` holds.
#[derive(Debug, Clone, Copy)]
pub struct StoreSource<'a> {
    tree: &'a StoreTree,
    streamer: &'a Streamer,
}

impl<'a> StoreSource<'a> {
    /// The terrain of `tree`'s store with heights from `streamer` (over the same store).
    pub fn new(tree: &'a StoreTree, streamer: &'a Streamer) -> Self {
        Self { tree, streamer }
    }

    /// Height of grid sample `(x, y)`: the stored sample when a block holding it has its level
    /// resident or it was read so before through the same tree (the tree keeps the samples
    /// read exact: a stored sample never changes), else the finest resident lattice's
    /// bilinear value of the block it lies in (the south-west-most holder), else a height at
    /// or below that block's lowest (the least of its parent node, or of an ancestor, in the
    /// tree's pyramid above the blocks).
    pub fn sample(&self, x: u32, y: u32) -> f32 {
        // One lock a sample, held while it is read (the stand-in height, `block_floor`, reads
        // the tree's pyramid above the blocks, with no lock).
        self.sample_in(&mut self.tree.known_samples(), x, y)
    }

    /// [`StoreSource::sample`] with the known samples' lock held.
    fn sample_in(&self, known: &mut KnownSamples, x: u32, y: u32) -> f32 {
        let key = KnownSamples::key(x, y);
        if let Some(z) = known.get(key) {
            return z;
        }
        let h = self.tree.store().header();
        let b = h.block_cells();
        let (bx, by) = (x / b, y / b);
        let holders = |v: u32, bv: u32, n: u32| {
            let mut out = [Some(bv.min(n - 1)), None];
            if v.is_multiple_of(b) && v > 0 && bv >= 1 && bv - 1 < n {
                out[1] = Some(bv - 1);
            }
            out
        };
        let cols = holders(x, bx, h.blocks_x);
        let rows = holders(y, by, h.blocks_y);
        let mut coarse: Option<(usize, f32)> = None;
        for col in cols.into_iter().flatten() {
            for row in rows.into_iter().flatten() {
                let id = BlockId::new(row, col);
                let Some(levels) = self.streamer.block(id) else { continue };
                let (i, j) = (x - col * b, y - row * b);
                if let Some(z) = levels.height(i, j) {
                    known.keep(key, z);
                    return z;
                }
                let count = levels.count();
                if count > 0 && coarse.is_none_or(|(c, _)| count > c) {
                    coarse = Some((count, lattice_height(levels, h.k, i, j)));
                }
            }
        }
        if let Some((_, z)) = coarse {
            return z;
        }
        let id = BlockId::new(by.min(h.blocks_y - 1), bx.min(h.blocks_x - 1));
        self.tree.block_floor(id).unwrap_or(0.0)
    }
}

/// Bilinear height of block vertex `(i, j)` on the finest resident level's lattice.
fn lattice_height(levels: &BlockLevels, k: u8, i: u32, j: u32) -> f32 {
    let level = (levels.count() - 1) as u8;
    let d = 1u32 << (k - level);
    let n = (1usize << level) + 1;
    bilinear_clamped(n, n, f64::from(i) / f64::from(d), f64::from(j) / f64::from(d), |a, b| {
        levels.height(a as u32 * d, b as u32 * d).unwrap_or(0.0)
    })
}

impl NodeSource for StoreSource<'_> {
    fn node_info(&self, node: NodeId) -> Option<NodeInfo> {
        self.tree.node_info(node)
    }
}

impl NodeTree for StoreSource<'_> {
    fn shape(&self) -> &TreeShape {
        self.tree.shape()
    }

    fn with_traversal_source(&self, f: &mut dyn FnMut(&dyn NodeSource)) {
        self.tree.with_traversal_source(f)
    }
}

impl TerrainSource for StoreSource<'_> {
    fn height(&self, g: DVec2) -> f32 {
        let s = self.tree.shape();
        let (w, h) = (s.width(), s.height());
        // A sample of the grid off its last row and column (patch corners, edge ends: most of
        // what the selections ask) is its own height: the bilinear mean takes it as its first
        // corner with both fractions 0, `z + (z' - z) 0` is `z` exactly for finite heights,
        // and a store's are finite. One sample instead of four. (On the last row or column
        // the mean takes it as the far corner, `z + (z' - z) 1`, which may round: left to it.)
        if on_sample(g, w, h) {
            return self.sample(g.x as u32, g.y as u32);
        }
        bilinear_clamped(w as usize, h as usize, g.x, g.y, |i, j| self.sample(i as u32, j as u32))
    }

    /// [`TerrainSource::height`] of each point under one lock of the known samples: first
    /// every grid sample among them looked up there in one loop (lookups that miss the CPU's
    /// caches overlap instead of waiting in turn), then the samples not known yet; then, the
    /// lock let go, the points between samples (bilinear, [`TerrainSource::height`]).
    fn heights(&self, points: &[DVec2], out: &mut Vec<f32>) {
        let s = self.tree.shape();
        let (w, h) = (s.width(), s.height());
        let mut known = self.tree.known_samples();
        out.clear();
        out.extend(points.iter().map(|&g| {
            let hit = on_sample(g, w, h)
                .then(|| known.get(KnownSamples::key(g.x as u32, g.y as u32)))
                .flatten();
            hit.unwrap_or(f32::NAN)
        }));
        // Known heights are a store's samples, finite: NaN is a point not looked up yet.
        for (z, &g) in out.iter_mut().zip(points) {
            if z.is_nan() && on_sample(g, w, h) {
                *z = self.sample_in(&mut known, g.x as u32, g.y as u32);
            }
        }
        drop(known);
        for (z, &g) in out.iter_mut().zip(points) {
            if z.is_nan() && !on_sample(g, w, h) {
                *z = self.height(g);
            }
        }
    }
}

/// Whether grid position `g` is a sample of a `w` x `h` grid off its last row and column
/// ([`StoreSource`]'s `height` reads it alone).
fn on_sample(g: DVec2, w: u32, h: u32) -> bool {
    let inside = |v: f64, n: u32| v >= 0.0 && v + 1.0 < f64::from(n) && v == v.floor();
    inside(g.x, w) && inside(g.y, h)
}

/// The streamer's demand for a selection over `tree` ([`Streamer::set_demand`]): every block a
/// patch lies in, with the finest level its patches there need to be drawn with the heights
/// the whole heightmap gives them. A patch of `c` cells at block-local level `l` whose factors
/// are all powers of two, the largest `f`, places its vertices on the lattice of level
/// `l + log2(f)`; a factor that is not a power of two (continuous tessellation: the DSS
/// paper's `F_thr`, PVPS's inner levels) places them between lattice samples, where the height
/// is bilinear over the full-resolution samples, so it needs the patch's full resolution,
/// `l + log2(c)`. Levels are capped at the block's finest. A patch larger than a block needs
/// the same of every block under it (its local level is negative). Without `on_squares` (a
/// method that draws its patches over other rectangles than their nodes' squares, e.g. the
/// DSS paper's M-blocks shrunk for their strips) every vertex may fall between lattice samples:
/// every patch needs its full resolution.
pub fn demand_of(tree: &StoreTree, selection: &Selection, on_squares: bool) -> Vec<(BlockId, u8)> {
    demand_with(tree, selection, on_squares, false)
}

/// The bytes a demand holds resident (levels `0..=level` of each block, decoded): what the
/// streamer keeps for it even above its budget.
pub fn demand_bytes(demand: &[(BlockId, u8)]) -> u64 {
    demand.iter().map(|&(_, level)| BlockEntry::resident_bytes(level)).sum()
}

/// [`demand_of`] held to `budget_bytes` where it can be: when the exact demand holds more
/// than the budget ([`demand_bytes`]), a patch whose factors are not all powers of two (or
/// any patch, without `on_squares`) asks the lattice of its largest factor rounded up to a
/// power of two (`l + ceil(log2(f))`, capped at `l + log2(c)`) instead of its full
/// resolution, and the second value says whether that changed the demand. Its vertices then
/// lie between that lattice's samples and are drawn bilinear over it (the paged renderer's
/// lookup, [`StoreSource`]): each height within that level's static error of the
/// full-resolution one, where memory would draw the exact bilinear value (and the renderer's
/// normals, central differences of the drawn heights, come from that lattice too: smoother
/// shading than the samples give). The lattice has at least as many samples per side as the
/// patch has vertices, the standard choice of a height mip for a vertex density (e.g.
/// Strugar's CDLOD samples the level of its morph range, Losasso & Hoppe's geometry clipmaps
/// one level per ring). Power-of-two patches on their squares need what they need either way.
/// Without `on_squares` (vertices anywhere in the patch, e.g. the DSS paper's shrunk M-blocks
/// and their strips, each patch given its block's factor) the exact demand is every patch's
/// full resolution, and the held one the same lattice of every patch's largest factor, power
/// of two or not.
pub fn demand_within(
    tree: &StoreTree,
    selection: &Selection,
    on_squares: bool,
    budget_bytes: u64,
) -> (Vec<(BlockId, u8)>, bool) {
    match demand_and_held(tree, selection, on_squares, budget_bytes) {
        (exact, None) => (exact, false),
        (exact, Some(held)) => {
            let changed = held != exact;
            (held, changed)
        }
    }
}

/// A demand: the level each block is asked for ([`demand_of`]'s form).
pub type Demand = Vec<(BlockId, u8)>;

/// The exact demand ([`demand_of`]) and, where it holds more than `budget_bytes`, the demand
/// [`demand_within`] holds to it: for a caller that preloads the exact demand beside the held
/// one ([`crate::Streamer::set_demand_later`]) without a second pass over the patches.
pub fn demand_and_held(
    tree: &StoreTree,
    selection: &Selection,
    on_squares: bool,
    budget_bytes: u64,
) -> (Demand, Option<Demand>) {
    let exact = demand_with(tree, selection, on_squares, false);
    if demand_bytes(&exact) <= budget_bytes {
        return (exact, None);
    }
    let held = demand_with(tree, selection, on_squares, true);
    (exact, Some(held))
}

/// A demand still above `budget_bytes` ([`demand_bytes`]) after [`demand_within`] held to it by
/// coarsening blocks a level at a time, the block whose samples are densest on screen first:
/// the largest `2^level x d`, `d` the distance from `eye` to the block's box (at least a
/// metre), so the sample spacing over the distance, about the samples' size on screen, stays
/// as even over the view as the budget allows (the mip bias of texture streaming, e.g.
/// Unreal's and id Tech's virtual texturing, which drop the finest mips of the most
/// oversampled textures first). A patch over a coarsened block is drawn bilinear over that
/// block's level, each height within its static error, as when a level arrives late. Level 0
/// is never asked for less. Returns the levels dropped (0: it fitted, nothing changed).
/// Deterministic: ties go to the block listed first.
pub fn coarsen_to_budget(
    tree: &StoreTree,
    demand: &mut [(BlockId, u8)],
    eye: DVec3,
    budget_bytes: u64,
) -> usize {
    let mut bytes = demand_bytes(demand);
    if bytes <= budget_bytes {
        return 0;
    }
    // Distances to the blocks' boxes (from the index: no block is read).
    let distance: Vec<f64> = demand
        .iter()
        .map(|&(b, _)| {
            let node = tree.global(b, NodeId { level: 0, i: 0, j: 0 });
            tree.node_info(node).map_or(f64::MAX, |info| {
                let (lo, hi) = (info.aabb.min, info.aabb.max);
                (lo - eye).max(eye - hi).max(DVec3::ZERO).length().max(1.0)
            })
        })
        .collect();
    // Positive finite keys order as their bits; the index breaks ties towards the first.
    let key = |i: usize, level: u8| {
        ((distance[i] * f64::from(1u32 << level)).min(f64::MAX).to_bits(), Reverse(i))
    };
    let mut heap: BinaryHeap<(u64, Reverse<usize>)> =
        demand.iter().enumerate().filter(|(_, d)| d.1 > 0).map(|(i, d)| key(i, d.1)).collect();
    let mut dropped = 0;
    while bytes > budget_bytes {
        let Some((_, Reverse(i))) = heap.pop() else { break };
        let level = demand[i].1;
        bytes -= BlockEntry::resident_bytes(level) - BlockEntry::resident_bytes(level - 1);
        demand[i].1 = level - 1;
        dropped += 1;
        if level > 1 {
            heap.push(key(i, level - 1));
        }
    }
    dropped
}

/// [`demand_of`]; with `lattice`, continuous factors ask the power-of-two lattice at or above
/// their largest factor ([`demand_within`]).
fn demand_with(
    tree: &StoreTree,
    selection: &Selection,
    on_squares: bool,
    lattice: bool,
) -> Vec<(BlockId, u8)> {
    let h = tree.store().header();
    let bl = i32::from(tree.block_level());
    let root = tree.root_cells();
    // Per patch its block (or blocks) and level, the same block's patches in a row folded as
    // they come (a selection lists a block's patches together), then sorted by block with
    // each block's largest level: the map this replaced, without a tree insert per patch.
    let mut need: Vec<(BlockId, u8)> = Vec::new();
    let mut add = |b: BlockId, level: u8| match need.last_mut() {
        Some((last, l)) if *last == b => *l = (*l).max(level),
        _ => need.push((b, level)),
    };
    for p in &selection.patches {
        let n = p.node;
        let cells = root >> n.level;
        let factors = p.outer.iter().chain(&p.inner);
        let nested = on_squares
            && factors
                .clone()
                .all(|&f| f >= 1.0 && f.fract() == 0.0 && (f as u32).is_power_of_two());
        let steps = if nested {
            let f = factors.fold(1f32, |m, &f| m.max(f)) as u32;
            f.min(cells).trailing_zeros() as i32
        } else if lattice {
            let f = p.outer.iter().chain(&p.inner).fold(1f32, |m, &f| m.max(f));
            let f = (f.ceil() as u32).max(1).next_power_of_two();
            f.min(cells.max(1)).trailing_zeros() as i32
        } else {
            cells.max(1).trailing_zeros() as i32
        };
        let local = i32::from(n.level) - bl;
        let level = (local + steps).clamp(0, i32::from(h.k)) as u8;
        match tree.block_of(n) {
            Some((b, _)) => add(b, level),
            None => tree.blocks_under(n).into_iter().for_each(|b| add(b, level)),
        }
    }
    need.sort_unstable_by_key(|&(b, _)| b);
    need.dedup_by(|later, kept| {
        let same = later.0 == kept.0;
        if same {
            kept.1 = kept.1.max(later.1);
        }
        same
    });
    need
}
