//! The PVS bake: both modes in one pass over every view cell (rayon over plan cells, each
//! plan cell's floors in the order of `Ctx::column`), top-down over the patch pyramid.
//!
//! # Per cell
//! Only the cell's *top plane* (height `Z`, its plan rectangle `R`) is tested: a point visible
//! from some viewpoint is visible from every viewpoint above it (the PVPS paper's Fig. 5, first
//! property; for a straight sight line to a fixed target, raising the eye raises every interior
//! point of the line), so the top plane sees all that the cell's volume sees.
//!
//! Patches are visited top-down from pyramid level 0. At each node `Q`:
//! 1. **Proof of occlusion** (both modes): if the node is proven hidden (below), its whole
//!    subtree is 0 in both modes.
//! 2. Otherwise, above level `L`, recurse into the four children; the node's bit is the OR of
//!    theirs (section 2.3.1).
//! 3. At level `L`: the sampled mode runs the paper's test ([`sampled_patch_visible`]); the
//!    conservative mode marks the patch visible (nothing proved it hidden). At level `L` the
//!    sampled test runs *first* and the proof only when it finds nothing, since a visible patch
//!    can never be proven hidden.
//!
//! # Speed (results unchanged)
//! Proofs are the costly part, so they are skipped whenever a *witness* shows them hopeless:
//! any unblocked Eq. 4 sight line from the top plane to a sample of the node (the paper's own
//! test at level `L`; then, at every level, a 3 x 3 grid of the node's samples raised as high
//! as every part of the proof still covers, seen from the plane's centre and corners). Sight
//! lines try *occluder hints* first ([`los::Hints`]: the samples that blocked recent lines of
//! the same cell; passing one that blocks is an exact early exit), then the steps nearest the
//! test point, then max-height halving (see [`los`]).
//!
//! **Floors share work** (`Ctx::column`): the lowest floor is baked first, then the highest,
//! then the others upwards, each chained to the nearest baked floor below and the highest
//! above, all by the monotonicity of Fig. 5 over the same plan rectangle:
//! - from below (`Below`): a node visible in a lower floor's conservative bits skips its proof
//!   (a proof that fails from a plane fails from every plane above it); a patch the paper's test
//!   saw through a pair whose plane was above its test point is seen again without a test;
//! - from above (`Above`): a node hidden in a higher floor's conservative bits is hidden
//!   (its proofs hold from every lower plane); a patch the paper's test found hidden there only
//!   tests the test points whose Fig. 6 case differs between the two planes.
//!
//! The eye-height arguments are exact in floating point: a guard (`chain_margin`) checks that
//! the floors are far enough apart for the rise of every Bresenham step's sight line to exceed
//! its rounding. Rejects inside the proofs read the min of the largest mip block (or line
//! pyramid entry) inside the queried rectangle, an upper bound of its min from a small,
//! cache-resident level, before the block query. Rounding uses exact integer forms of
//! `floor`/`ceil`/`round` (the build's baseline CPU has no rounding instruction). The bits equal
//! the unaccelerated bake's (pinned in `tests/pvs_pinned.rs`; chained floors equal cells baked
//! alone in `chaining_the_floors_changes_no_bit`).
//!
//! # The proof (conservative mode)
//! Claim: every sight line from a point `v` of `R x {Z}` to a point of `Q` at a height at most
//! `Hp` (the max of `Q`'s samples, from the [`HeightMip`]) is blocked. Raising the target to
//! `Hp` raises the line (as raising the eye does), so it suffices for targets at `Hp`. A line
//! from `q in Q` at `Hp` to `v in R` at `Z`, at the fraction `s` from the target, is at height
//! `(1 - s) Hp + s Z`, *the same for every such pair*, and its plan point lies in the rectangle
//! `(1 - s) Q + s R`. Take an interval `[sa, sb]` of `s` whose plan length is at least 2.5
//! samples for every pair (`(sb - sa) dmin`, `dmin` the plan distance between `R` and `Q`):
//! every such line crosses a grid line (and passes an integer major coordinate, where the
//! Bresenham traversal samples) inside the interval, where the terrain is at least the min of
//! the samples around the swept rectangle. If that min exceeds the line's highest height over
//! the interval plus `epsilon_m`, every line is blocked: by exact line of sight
//! (terrain-core's `LineOfSight`, interpolation along grid lines, any tolerance up to
//! `epsilon_m`) and by Eq. 4 over the Bresenham section line alike. When no interval proves it,
//! the larger of `R` and `Q` is split in four and every part must be proven (a bounded number
//! of parts). The proof never culls a visible patch; what it cannot prove stays visible.
//!
//! Because a proven-hidden patch is hidden for the paper's test too, proving first does not
//! change the sampled mode's result: it equals the paper's test on every patch (tested against
//! a bake without proofs in `tests/pvs.rs`), and the sampled set is always a subset of the
//! conservative one.

use std::time::{Duration, Instant};

use glam::{DVec2, DVec3};
use rayon::prelude::*;
use terrain_core::Heightmap;

use super::los;
use super::los::{ceil_i64, floor_i64};
use super::mip::{HeightMip, LineMins};
use super::{CellId, Pvs, PvsConfig, PvsLayout, PvsMode};

/// What a bake did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BakeStats {
    /// Cells baked.
    pub cells: usize,
    /// Wall time.
    pub elapsed: Duration,
}

/// Bakes the PVS of `cfg.mode` for `hm`.
pub fn bake(hm: &Heightmap, cfg: &PvsConfig) -> Pvs {
    match cfg.mode {
        PvsMode::Sampled => bake_impl(hm, cfg, true, true, &|_, _| ()).0,
        // Without the paper's test: one witness sight line and the proofs per node.
        PvsMode::Conservative => bake_impl(hm, cfg, true, false, &|_, _| ()).1,
    }
}

/// Bakes both modes at once (they share the proofs): `(sampled, conservative, stats)`.
pub fn bake_both(hm: &Heightmap, cfg: &PvsConfig) -> (Pvs, Pvs, BakeStats) {
    bake_impl(hm, cfg, true, true, &|_, _| ())
}

/// [`bake_both`], calling `progress(done, total)` (in plan cells, each with all its floors)
/// from the bake's threads as plan cells finish, for a progress display.
pub fn bake_both_with_progress(
    hm: &Heightmap,
    cfg: &PvsConfig,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> (Pvs, Pvs, BakeStats) {
    bake_impl(hm, cfg, true, true, progress)
}

/// The paper's sampled test alone, without occlusion proofs (slow; for checking that the
/// proofs do not change the sampled mode's result).
pub fn bake_sampled_without_proofs(hm: &Heightmap, cfg: &PvsConfig) -> Pvs {
    bake_impl(hm, cfg, false, true, &|_, _| ()).0
}

/// The bits of some cells only (by [`PvsLayout::cell_index`]): `(sampled, conservative)` per
/// cell, as [`bake_both`] computes them. For timing a sample of cells and for tests.
pub fn bake_cells(hm: &Heightmap, cfg: &PvsConfig, cells: &[usize]) -> Vec<(Vec<u8>, Vec<u8>)> {
    with_grid_ctx(hm, cfg, |ctx| cells.par_iter().map(|&n| ctx.cell(n)).collect())
}

/// The bits of every floor of some plan cells `(a, b)`, lowest floor first, as [`bake_both`]
/// computes them (floors chained as in the full bake). For timing a sample of cells.
pub fn bake_columns(
    hm: &Heightmap,
    cfg: &PvsConfig,
    plan: &[(u32, u32)],
) -> Vec<Vec<(Vec<u8>, Vec<u8>)>> {
    with_grid_ctx(hm, cfg, |ctx| plan.par_iter().map(|&(a, b)| ctx.column(a, b)).collect())
}

/// What a spread sample of a bake's view cells culls ([`estimate_cull`]): a bake's cost and
/// benefit known before it is run whole.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CullEstimate {
    /// Plan cells baked (each with all its floors).
    pub plan_cells: usize,
    /// Plan cells of the whole layout.
    pub plan_total: usize,
    /// Fraction of the sample's (cell inside the grid, finest patch holding samples) pairs
    /// hidden in the paper's sampled PVS ([`Pvs::culled_fraction`] of the sample).
    pub sampled: f64,
    /// The same in the conservative PVS.
    pub conservative: f64,
    /// Wall time of the sample.
    pub elapsed: Duration,
}

/// The plan cells of a spread sample of a `cells_x x cells_y` layout: the middle cell of every
/// `stride x stride` block (clipped to the layout: at least one cell whatever the stride).
pub fn spread_sample(cells_x: u32, cells_y: u32, stride: u32) -> Vec<(u32, u32)> {
    let s = stride.max(1);
    let axis =
        |n: u32| -> Vec<u32> { (0..n.div_ceil(s)).map(|k| (k * s + s / 2).min(n - 1)).collect() };
    let (xs, ys) = (axis(cells_x.max(1)), axis(cells_y.max(1)));
    ys.iter().flat_map(|&b| xs.iter().map(move |&a| (a, b))).collect()
}

/// Bakes the plan cells of [`spread_sample`]`(stride)` of `cfg`'s layout on `hm` (every floor,
/// bits as [`bake_both`] computes them) and returns what they cull: about `1 / stride^2` of
/// the whole bake's time.
pub fn estimate_cull(hm: &Heightmap, cfg: &PvsConfig, stride: u32) -> CullEstimate {
    let start = Instant::now();
    let layout = PvsLayout::new(hm, cfg);
    let mip = HeightMip::new(hm);
    estimate_grids(&mip, &mip, &layout, cfg, stride, start)
}

/// [`estimate_cull`] with occluders `mip` and targets `targets` (see [`bake_grids`]).
pub(super) fn estimate_grids(
    mip: &HeightMip<'_>,
    targets: &HeightMip<'_>,
    layout: &PvsLayout,
    cfg: &PvsConfig,
    stride: u32,
    start: Instant,
) -> CullEstimate {
    let hm = mip.heightmap();
    let lines = LineMins::new(hm);
    let ctx = Ctx { targets, ..Ctx::of_grid(hm, mip, &lines, layout, cfg) };
    let plan = spread_sample(layout.cells_x, layout.cells_y, stride);
    let columns: Vec<Vec<(Vec<u8>, Vec<u8>)>> =
        plan.par_iter().map(|&(a, b)| ctx.column(a, b)).collect();
    let (mut s, mut c) = ((0u64, 0u64), (0u64, 0u64));
    for (&(a, b), floors) in plan.iter().zip(&columns) {
        for (k, (sampled, conservative)) in floors.iter().enumerate() {
            let cell = CellId { a, b, k: k as u32 };
            let add = |acc: &mut (u64, u64), bits: &[u8]| {
                if let Some((hidden, total)) = layout.hidden_patches(cell, bits) {
                    *acc = (acc.0 + hidden, acc.1 + total);
                }
            };
            add(&mut s, sampled);
            add(&mut c, conservative);
        }
    }
    let frac = |(hidden, total): (u64, u64)| hidden as f64 / total.max(1) as f64;
    CullEstimate {
        plan_cells: plan.len(),
        plan_total: (layout.cells_x * layout.cells_y) as usize,
        sampled: frac(s),
        conservative: frac(c),
        elapsed: start.elapsed(),
    }
}

/// Runs `f` with the context of a bake of `hm` itself (its layout, mip and grid-line minima;
/// occlusion proofs and the sampled test on): what [`bake_cells`] and [`bake_columns`] share.
fn with_grid_ctx<R>(hm: &Heightmap, cfg: &PvsConfig, f: impl FnOnce(&Ctx<'_>) -> R) -> R {
    let layout = PvsLayout::new(hm, cfg);
    let mip = HeightMip::new(hm);
    let lines = LineMins::new(hm);
    f(&Ctx::of_grid(hm, &mip, &lines, &layout, cfg))
}

fn bake_impl(
    hm: &Heightmap,
    cfg: &PvsConfig,
    proofs: bool,
    sampled: bool,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> (Pvs, Pvs, BakeStats) {
    let start = Instant::now();
    let layout = PvsLayout::new(hm, cfg);
    let mip = HeightMip::new(hm);
    bake_grids(&mip, &mip, layout, cfg, proofs, sampled, progress, start)
}

/// The bake of `layout`'s cells with occluders `mip` (sight lines, proofs) and target
/// heights `targets` (the same mip for a bake of the grid itself; see [`super::coarse`]).
#[allow(clippy::too_many_arguments)]
pub(super) fn bake_grids(
    mip: &HeightMip<'_>,
    targets: &HeightMip<'_>,
    layout: PvsLayout,
    cfg: &PvsConfig,
    proofs: bool,
    sampled: bool,
    progress: &(dyn Fn(usize, usize) + Sync),
    start: Instant,
) -> (Pvs, Pvs, BakeStats) {
    let hm = mip.heightmap();
    let lines = LineMins::new(hm);
    let ctx = Ctx { proofs, sampled, targets, ..Ctx::of_grid(hm, mip, &lines, &layout, cfg) };
    // Rayon over plan cells; each bakes its floors lowest first (see [`Below`]).
    let run = || -> Vec<(Vec<u8>, Vec<u8>)> {
        let total = (layout.cells_x * layout.cells_y) as usize;
        let done = std::sync::atomic::AtomicUsize::new(0);
        let columns: Vec<Vec<(Vec<u8>, Vec<u8>)>> = (0..layout.cells_x * layout.cells_y)
            .into_par_iter()
            .map(|n| {
                let bits = ctx.column(n % layout.cells_x, n / layout.cells_x);
                progress(done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1, total);
                bits
            })
            .collect();
        // Back to the bake's cell order (floor, then row, then column).
        let mut cells = vec![(Vec::new(), Vec::new()); layout.cell_count()];
        for (n, floors) in columns.into_iter().enumerate() {
            let (a, b) = (n as u32 % layout.cells_x, n as u32 / layout.cells_x);
            for (k, bits) in floors.into_iter().enumerate() {
                cells[layout.cell_index(CellId { a, b, k: k as u32 })] = bits;
            }
        }
        cells
    };
    let cells = if cfg.threads > 0 {
        match rayon::ThreadPoolBuilder::new().num_threads(cfg.threads).build() {
            Ok(pool) => pool.install(run),
            Err(_) => run(),
        }
    } else {
        run()
    };
    let per = layout.bytes_per_cell();
    let (mut s, mut c) = (Vec::with_capacity(per * cells.len()), Vec::new());
    c.reserve(per * cells.len());
    for (a, b) in cells {
        s.extend_from_slice(&a);
        c.extend_from_slice(&b);
    }
    let stats = BakeStats { cells: layout.cell_count(), elapsed: start.elapsed() };
    (
        Pvs { layout: layout.clone(), mode: PvsMode::Sampled, bits: s },
        Pvs { layout, mode: PvsMode::Conservative, bits: c },
        stats,
    )
}

struct Ctx<'a> {
    hm: &'a Heightmap,
    mip: &'a HeightMip<'a>,
    lines: &'a LineMins,
    /// The targets' heights (test points, witnesses, a patch's max height `Hp`): the occluders'
    /// own ([`Self::mip`]) in a bake of the grid itself, a max-reduced grid in the coarse bake
    /// of [`super::coarse`] (occluders never higher, targets never lower than the terrain).
    targets: &'a HeightMip<'a>,
    layout: &'a PvsLayout,
    cfg: &'a PvsConfig,
    proofs: bool,
    /// Whether to run the paper's test (the sampled mode's bits stay 0 otherwise).
    sampled: bool,
}

/// A cell's top plane.
#[derive(Debug, Clone, Copy)]
struct Top<'a> {
    lo: DVec2,
    hi: DVec2,
    z: f64,
    /// The conservative bits of the same plan cell's top plane at a height at most `z`.
    below: Option<Below<'a>>,
    /// The key viewpoints of every Fig. 6 case ([`fig6_case`]) from this plane.
    views: &'a [Vec<DVec3>],
    /// The patches (bit `j 2^L + i`) that the paper's test found visible from the same plan
    /// cell's top plane at a lower height through a pair whose plane was above the test point
    /// (see [`Ctx::column`]): visible from this plane too.
    seen_below: Option<&'a [u8]>,
    /// The bits of the same plan cell's top plane at a greater height (see [`Above`]).
    above: Option<Above<'a>>,
}

/// A higher top plane's bits (same plan rectangle), for a lower plane:
/// - a node hidden in its *conservative* bits had every patch under it proven hidden (its own
///   proof or those of nodes under it), and a proof that holds from a plane holds from every
///   plane below it (see [`Below`]), so the same proofs hold here: the node's subtree is 0 in
///   both modes (a proven patch is hidden for the paper's test too), as running it gives;
/// - a patch hidden in its *sampled* bits had every (test point, key viewpoint) pair hidden
///   there, and lowering the eye lowers every Bresenham step's sight line (the converse of
///   `Ctx::column`'s argument, the same margin): a test point whose Fig. 6 case is the same
///   from both planes (the plane above it in both or in neither) has the same viewpoints in
///   plan and all of them hidden here too; only the test points between the two heights are
///   tested.
#[derive(Debug, Clone, Copy)]
struct Above<'a> {
    sampled: &'a [u8],
    conservative: &'a [u8],
    z: f64,
}

fn bit(bits: &[u8], l: u8, i: u32, j: u32) -> bool {
    let n = PvsLayout::level_offset(l) + (j * (1 << l) + i) as usize;
    bits[n / 8] & (1 << (n % 8)) != 0
}

/// A lower top plane's conservative bits (same plan rectangle). A proof that fails from a
/// plane fails from every plane above it: raising `z` raises every sight line's height over
/// each interval and grid line, so each test of [`prove`] only gets harder, and the parts it
/// splits into do not depend on `z` (so the budget suffices no sooner). A node visible in the
/// lower plane's conservative bits had its proof fail, or skipped as refuted by a witness, so
/// from this plane its proof is skipped: the bits are those of running it.
#[derive(Debug, Clone, Copy)]
struct Below<'a> {
    bits: &'a [u8],
    z: f64,
}

impl Below<'_> {
    fn visible(&self, l: u8, i: u32, j: u32) -> bool {
        bit(self.bits, l, i, j)
    }
}

fn set(bits: &mut [u8], l: u8, i: u32, j: u32) {
    let n = PvsLayout::level_offset(l) + (j * (1 << l) + i) as usize;
    bits[n / 8] |= 1 << (n % 8);
}

impl<'a> Ctx<'a> {
    /// The context of a bake of `hm` itself: targets are the occluders' own heights (`mip`),
    /// occlusion proofs and the paper's sampled test on.
    fn of_grid(
        hm: &'a Heightmap,
        mip: &'a HeightMip<'a>,
        lines: &'a LineMins,
        layout: &'a PvsLayout,
        cfg: &'a PvsConfig,
    ) -> Self {
        Ctx { hm, mip, lines, layout, cfg, proofs: true, sampled: true, targets: mip }
    }
}

impl Ctx<'_> {
    /// The bits of every floor of plan cell `(a, b)`, lowest first, each floor's
    /// conservative bits telling the next which proofs are hopeless (see [`Below`]), and its
    /// sampled witnesses which patches the paper's test sees (below).
    ///
    /// **Sampled witnesses.** A patch seen from the plane at `z` through a pair `(v, t)` whose
    /// Fig. 6 case has the plane above `t` is seen from the plane at `z' > z` through
    /// `(v', t)`, `v'` being `v` raised to `z'`: the case is the same (still above `t`, same
    /// region), so `v'` is a key viewpoint there (the same plan points); the Bresenham steps
    /// and samples depend on plan coordinates alone; and at every step the sight line's
    /// height `e + (T - e) t_k` rises with the eye height `e` by `(z' - z)(1 - t_k) >= (z' -
    /// z) / N` (`t` at an integer sample, so `1 - t_k >= 1 / |len|`, `N` the grid's width
    /// plus height), which [`chain_margin`] checks is far above the rounding of the two
    /// evaluations. So no step that passed Eq. 4 at `z` blocks at `z'` and the test's result
    /// is known without running it: the bits are those of running it.
    ///
    /// **Order.** The lowest floor first, then the highest (chained to the lowest), then the
    /// others upwards, each chained to the nearest baked floor below it and to the highest
    /// (see [`Above`]): with the paper's 3 floors the middle one is bounded on both sides.
    fn column(&self, a: u32, b: u32) -> Vec<(Vec<u8>, Vec<u8>)> {
        let lay = self.layout;
        let f = lay.floors;
        let order: Vec<u32> = if f <= 2 {
            (0..f).collect()
        } else {
            std::iter::once(0).chain(std::iter::once(f - 1)).chain(1..f - 1).collect()
        };
        // Per floor: (sampled, conservative, sampled witnesses, top height).
        type Baked = (Vec<u8>, Vec<u8>, Vec<u8>, Option<f64>);
        let mut done: Vec<Option<Baked>> = vec![None; f as usize];
        for k in order {
            let n = lay.cell_index(CellId { a, b, k });
            let z = lay.floor_bounds(CellId { a, b, k }).map(|(_, z)| z);
            let lower = (0..k).rev().find_map(|j| done[j as usize].as_ref());
            let upper = (k + 1..f).find_map(|j| done[j as usize].as_ref());
            let below = match lower {
                Some((_, c, _, Some(z0))) => Some(Below { bits: c.as_slice(), z: *z0 }),
                _ => None,
            };
            let seen_below = match (lower, z) {
                (Some((_, _, w, Some(z0))), Some(z1)) if self.margin(*z0, z1) => Some(w.as_slice()),
                _ => None,
            };
            let above = match (upper, z) {
                (Some((s, c, _, Some(z1))), Some(z0)) if self.margin(z0, *z1) => {
                    Some(Above { sampled: s.as_slice(), conservative: c.as_slice(), z: *z1 })
                }
                _ => None,
            };
            let (s, c, w) = self.cell_chained(n, below, seen_below, above);
            done[k as usize] = Some((s, c, w, z));
        }
        done.into_iter().map(|d| d.map(|(s, c, _, _)| (s, c)).unwrap_or_default()).collect()
    }

    /// [`chain_margin`] for the occluders' and the targets' heights.
    fn margin(&self, z0: f64, z1: f64) -> bool {
        chain_margin(self.hm, z0, z1) && chain_margin(self.targets.heightmap(), z0, z1)
    }

    fn cell(&self, n: usize) -> (Vec<u8>, Vec<u8>) {
        let (s, c, _) = self.cell_chained(n, None, None, None);
        (s, c)
    }

    /// The cell's (sampled, conservative) bits and its sampled witnesses (see
    /// [`Self::column`]).
    fn cell_chained(
        &self,
        n: usize,
        below: Option<Below<'_>>,
        seen_below: Option<&[u8]>,
        above: Option<Above<'_>>,
    ) -> (Vec<u8>, Vec<u8>, Vec<u8>) {
        let lay = self.layout;
        let per = lay.bytes_per_cell();
        let c: CellId = lay.cell_at_index(n);
        let (Some((_, z)), Some((lo, hi))) = (lay.floor_bounds(c), lay.cell_rect_clipped(c.a, c.b))
        else {
            // Outside the grid: never looked up; all visible.
            return (vec![0xFF; per], vec![0xFF; per], Vec::new());
        };
        let mut top = Top {
            lo,
            hi,
            z,
            below: below.filter(|b| b.z <= z),
            views: &[],
            seen_below: None,
            above: above.filter(|u| u.z > z),
        };
        let views = view_table(&top, self.cfg.max_viewpoints.max(1) as usize);
        top.views = &views;
        let patches = 1usize << (2 * lay.patch_level);
        top.seen_below = seen_below.filter(|w| w.len() * 8 >= patches);
        let (mut s, mut k) = (vec![0u8; per], vec![0u8; per]);
        let mut w = vec![0u8; patches.div_ceil(8)];
        let mut hints = los::Hints::new();
        self.visit(&top, 0, 0, 0, &mut s, &mut k, &mut w, &mut hints);
        (s, k, w)
    }

    /// Fills the bits of node `(l, i, j)`'s subtree; returns (sampled, conservative) visibility.
    #[allow(clippy::too_many_arguments)]
    fn visit(
        &self,
        top: &Top<'_>,
        l: u8,
        i: u32,
        j: u32,
        s: &mut [u8],
        k: &mut [u8],
        w: &mut [u8],
        hints: &mut los::Hints,
    ) -> (bool, bool) {
        let Some(q) = self.layout.patch_samples(l, i, j) else { return (false, false) };
        if top.above.is_some_and(|u| !bit(u.conservative, l, i, j)) {
            // Proven hidden from a higher plane, so from this one (see [`Above`]).
            return (false, false);
        }
        let finest = l == self.layout.patch_level;
        let (vs, vk) = if finest {
            // Both modes from the paper's test first: a patch it finds visible can never be
            // proven hidden (the proof covers its sight lines), so the costly proof runs only
            // on patches it finds hidden (or on every unwitnessed patch without it).
            let p = (j * (1 << l) + i) as usize;
            let seen = self.sampled
                && if top.seen_below.is_some_and(|b| b[p / 8] & (1 << (p % 8)) != 0) {
                    w[p / 8] |= 1 << (p % 8);
                    true
                } else {
                    // Hidden from a higher plane: only the test points between the planes.
                    let between = top.above.filter(|u| !bit(u.sampled, l, i, j)).map(|u| u.z);
                    let (seen, chain) = sampled_patch_visible(
                        self.mip,
                        self.targets,
                        top,
                        q,
                        self.cfg,
                        between,
                        hints,
                    );
                    if chain {
                        w[p / 8] |= 1 << (p % 8);
                    }
                    seen
                };
            let proven = !seen
                && self.proofs
                && !top.below.is_some_and(|b| b.visible(l, i, j))
                && !self.quick_visible(top, q)
                && !self.witnessed(top, q, hints)
                && self.proven(top, q, 64);
            (seen, !proven)
        } else if self.proofs
            && !top.below.is_some_and(|b| b.visible(l, i, j))
            && !self.quick_visible(top, q)
            && !self.witnessed(top, q, hints)
            && self.proven(top, q, 16)
        {
            (false, false)
        } else {
            let mut acc = (false, false);
            for (ci, cj) in
                [(2 * i, 2 * j), (2 * i + 1, 2 * j), (2 * i, 2 * j + 1), (2 * i + 1, 2 * j + 1)]
            {
                let (a, b) = self.visit(top, l + 1, ci, cj, s, k, w, hints);
                acc = (acc.0 | a, acc.1 | b);
            }
            acc
        };
        if vs {
            set(s, l, i, j);
        }
        if vk {
            set(k, l, i, j);
        }
        (vs, vk)
    }

    /// A cheap witness that a node holds something visible (its centre sample seen from the
    /// top plane's centre): then no proof can succeed and none is tried.
    fn quick_visible(&self, top: &Top<'_>, q: (u32, u32, u32, u32)) -> bool {
        let (cx, cy) = ((q.0 + q.2) / 2, (q.1 + q.3) / 2);
        let t = DVec3::new(
            f64::from(cx),
            f64::from(cy),
            f64::from(self.targets.heightmap().get(cx as usize, cy as usize)),
        );
        let c = (top.lo + top.hi) * 0.5;
        los::visible(self.mip, c.extend(top.z), t, self.cfg.epsilon_m)
    }

    /// A witness that a node's proof must fail, tried before it (so skipping the proof
    /// changes no result). Each part `(R', Q')` of a proof shows every sight line from `R'`
    /// at the top plane to every point of `Q'`'s plan rectangle at `Q'`'s max height blocked
    /// (see the module docs); so an Eq. 4 sight line from the top plane to a sample `t` of the
    /// node, raised to a height no higher than the max of *every* part that can hold `t`, that
    /// is unblocked refutes the proof. Parts are sub-rectangles at least one sample wide on
    /// each axis ([`prove`] splits only rectangles two or more wide), so each holds one of the
    /// four 2 x 2 sample blocks at `t` ([`witness_height`]). Targets: a 3 x 3 grid of the
    /// node's samples; eyes: the top plane's centre and corners.
    fn witnessed(&self, top: &Top<'_>, q: (u32, u32, u32, u32), hints: &mut los::Hints) -> bool {
        let (mx, my) = ((q.0 + q.2) / 2, (q.1 + q.3) / 2);
        let views = [
            (top.lo + top.hi) * 0.5,
            DVec2::new(top.lo.x, top.lo.y),
            DVec2::new(top.hi.x, top.lo.y),
            DVec2::new(top.lo.x, top.hi.y),
            DVec2::new(top.hi.x, top.hi.y),
        ];
        [my, q.1, q.3].iter().any(|&y| {
            [mx, q.0, q.2].iter().any(|&x| {
                let t = DVec3::new(
                    f64::from(x),
                    f64::from(y),
                    witness_height(self.targets.heightmap(), q, x, y),
                );
                views.iter().any(|v| {
                    los::visible_with(self.mip, v.extend(top.z), t, self.cfg.epsilon_m, hints)
                })
            })
        })
    }

    fn proven(&self, top: &Top<'_>, q: (u32, u32, u32, u32), budget: u32) -> bool {
        let mut budget = budget;
        let occ = Occluders { mip: self.mip, lines: self.lines, targets: self.targets };
        prove(&occ, top.lo, top.hi, top.z, q, self.cfg.epsilon_m, &mut budget)
    }
}

/// The height to which a witness target at sample `(x, y)` of node `q` may be raised (see
/// `Ctx::witnessed`): the least, over the four 2 x 2 blocks of samples at `(x, y)` (clipped
/// to `q`), of the block's max.
fn witness_height(hm: &Heightmap, q: (u32, u32, u32, u32), x: u32, y: u32) -> f64 {
    let get = |x: u32, y: u32| hm.get(x as usize, y as usize);
    let mut best = f32::INFINITY;
    for nx in [x.saturating_sub(1).max(q.0), (x + 1).min(q.2)] {
        for ny in [y.saturating_sub(1).max(q.1), (y + 1).min(q.3)] {
            let m = get(x, y).max(get(nx, y)).max(get(x, ny)).max(get(nx, ny));
            best = best.min(m);
        }
    }
    f64::from(best)
}

/// The lower bounds of the terrain a proof reads.
#[derive(Debug, Clone, Copy)]
pub struct Occluders<'a> {
    /// 2D min/max blocks.
    pub mip: &'a HeightMip<'a>,
    /// Per grid line mins.
    pub lines: &'a LineMins,
    /// Where a target's max height `Hp` is read (the same mip as `mip` for a bake of the grid
    /// itself; see [`super::coarse`]).
    pub targets: &'a HeightMip<'a>,
}

/// Whether every sight line from `R x {z}` (`r_lo..r_hi`, grid coordinates) to the samples of
/// `q` (inclusive integer rectangle) is blocked (see the module docs). `budget` bounds the
/// number of (R, Q) parts tried; on return it holds what is left (0 when it ran out).
///
/// A part is proven directly or split in four (the larger of `R` and `Q`), and every part must
/// be proven. Which parts arise does not depend on the order they are tried in, so the proof
/// succeeds exactly when that whole tree of parts has every leaf proven and at most `budget`
/// parts: it is built level by level here, and fails as soon as the parts known to be needed
/// exceed the budget (the same result as a depth-first search, usually much sooner).
pub fn prove(
    occ: &Occluders<'_>,
    r_lo: DVec2,
    r_hi: DVec2,
    z: f64,
    q: (u32, u32, u32, u32),
    eps: f64,
    budget: &mut u32,
) -> bool {
    if *budget == 0 {
        return false;
    }
    let mut needed = 1u32;
    let mut level = vec![(r_lo, r_hi, q)];
    let mut next = Vec::new();
    while !level.is_empty() {
        for &(r_lo, r_hi, q) in &level {
            if part_proven(occ, r_lo, r_hi, z, q, eps) {
                continue;
            }
            let Some(parts) = split(r_lo, r_hi, q) else {
                *budget = 0;
                return false;
            };
            needed += 4;
            if needed > *budget {
                *budget = 0;
                return false;
            }
            next.extend(parts);
        }
        std::mem::swap(&mut level, &mut next);
        next.clear();
    }
    *budget -= needed;
    true
}

/// Whether one part `(R, Q)` is proven directly (by an interval or a grid line).
fn part_proven(
    occ: &Occluders<'_>,
    r_lo: DVec2,
    r_hi: DVec2,
    z: f64,
    q: (u32, u32, u32, u32),
    eps: f64,
) -> bool {
    let (q_lo, q_hi) =
        (DVec2::new(f64::from(q.0), f64::from(q.1)), DVec2::new(f64::from(q.2), f64::from(q.3)));
    let hp = f64::from(occ.targets.range_max(
        i64::from(q.0),
        i64::from(q.1),
        i64::from(q.2),
        i64::from(q.3),
    ));
    intervals_prove(occ.mip, r_lo, r_hi, z, q_lo, q_hi, hp, eps)
        || lines_prove(occ.lines, r_lo, r_hi, z, q_lo, q_hi, hp, eps)
}

/// A part's four sub-parts: the larger of `R` and `Q` split in four; `None` when neither can
/// be split.
#[allow(clippy::type_complexity)]
fn split(
    r_lo: DVec2,
    r_hi: DVec2,
    q: (u32, u32, u32, u32),
) -> Option<[(DVec2, DVec2, (u32, u32, u32, u32)); 4]> {
    let (q_lo, q_hi) =
        (DVec2::new(f64::from(q.0), f64::from(q.1)), DVec2::new(f64::from(q.2), f64::from(q.3)));
    let (rs, qs) = ((r_hi - r_lo).max_element(), (q_hi - q_lo).max_element());
    if qs >= rs && q.2 - q.0 >= 2 && q.3 - q.1 >= 2 {
        let (mx, my) = ((q.0 + q.2) / 2, (q.1 + q.3) / 2);
        Some(
            [(q.0, q.1, mx, my), (mx, q.1, q.2, my), (q.0, my, mx, q.3), (mx, my, q.2, q.3)]
                .map(|p| (r_lo, r_hi, p)),
        )
    } else if rs >= 2.0 {
        let m = (r_lo + r_hi) * 0.5;
        Some(
            [
                (r_lo, m),
                (DVec2::new(m.x, r_lo.y), DVec2::new(r_hi.x, m.y)),
                (DVec2::new(r_lo.x, m.y), DVec2::new(m.x, r_hi.y)),
                (m, r_hi),
            ]
            .map(|(lo, hi)| (lo, hi, q)),
        )
    } else {
        None
    }
}

/// The grid-line proof: when `R` and `Q` are apart along an axis, every sight line crosses each
/// grid line `x = i` between them exactly once, within a band of fractions `s` and a stretch
/// of the line bounded from the rectangles; if the terrain's min along that stretch is above
/// the sight lines' highest point over the band, every line is blocked there. Thin walls, which
/// 2D blocks average away with their low neighbours, are caught this way. The band is
/// `i +- 0.5` so the nearest-sample Bresenham traversal, which may step past `x = i`, still
/// samples column `i` inside it.
#[allow(clippy::too_many_arguments)]
fn lines_prove(
    lines: &LineMins,
    r_lo: DVec2,
    r_hi: DVec2,
    z: f64,
    q_lo: DVec2,
    q_hi: DVec2,
    hp: f64,
    eps: f64,
) -> bool {
    for axis in 0..2 {
        let (q0, q1, r0, r1) = (q_lo[axis], q_hi[axis], r_lo[axis], r_hi[axis]);
        let (first, last) = if q1 + 1.5 <= r0 - 1.5 {
            (ceil_i64(q1 + 1.5) as f64, floor_i64(r0 - 1.5) as f64)
        } else if r1 + 1.5 <= q0 - 1.5 {
            (ceil_i64(r1 + 1.5) as f64, floor_i64(q0 - 1.5) as f64)
        } else {
            continue;
        };
        let o = 1 - axis;
        // At most `MAX_LINES` lines per axis, evenly spaced (a bound on the cost; any line
        // that proves it is a valid proof).
        let step = (ceil_i64((last - first + 1.0) / MAX_LINES) as f64).max(1.0);
        let mut i = first;
        while i <= last {
            let (mut s0, mut s1) = (f64::INFINITY, f64::NEG_INFINITY);
            for x in [i - 0.5, i + 0.5] {
                for qa in [q0, q1] {
                    for va in [r0, r1] {
                        let s = (x - qa) / (va - qa);
                        s0 = s0.min(s);
                        s1 = s1.max(s);
                    }
                }
            }
            let (s0, s1) = (s0.clamp(0.0, 1.0), s1.clamp(0.0, 1.0));
            let ray_max = (hp * (1.0 - s0) + z * s0).max(hp * (1.0 - s1) + z * s1);
            let lo = (q_lo[o] * (1.0 - s0) + r_lo[o] * s0).min(q_lo[o] * (1.0 - s1) + r_lo[o] * s1);
            let hi = (q_hi[o] * (1.0 - s0) + r_hi[o] * s0).max(q_hi[o] * (1.0 - s1) + r_hi[o] * s1);
            let (a, b) = (floor_i64(lo), ceil_i64(hi));
            // As in `intervals_prove`: a block inside the stretch bounds its min from above.
            let one = if axis == 0 {
                lines.column_inner_min(i as usize, a, b)
            } else {
                lines.row_inner_min(i as usize, a, b)
            };
            if f64::from(one) <= ray_max + eps {
                i += step;
                continue;
            }
            let ground = if axis == 0 {
                lines.column_min(i as usize, a, b)
            } else {
                lines.row_min(i as usize, a, b)
            };
            if f64::from(ground) > ray_max + eps {
                return true;
            }
            i += step;
        }
    }
    false
}

/// Grid lines tried per axis by one grid-line proof.
const MAX_LINES: f64 = 16.0;

/// Plan distance between two rectangles.
fn rect_distance(a_lo: DVec2, a_hi: DVec2, b_lo: DVec2, b_hi: DVec2) -> f64 {
    let dx = (b_lo.x - a_hi.x).max(a_lo.x - b_hi.x).max(0.0);
    let dy = (b_lo.y - a_hi.y).max(a_lo.y - b_hi.y).max(0.0);
    dx.hypot(dy)
}

/// Minimum plan length of the sight lines within one proof interval, samples.
const MIN_INTERVAL_SAMPLES: f64 = 2.5;

#[allow(clippy::too_many_arguments)]
fn intervals_prove(
    mip: &HeightMip<'_>,
    r_lo: DVec2,
    r_hi: DVec2,
    z: f64,
    q_lo: DVec2,
    q_hi: DVec2,
    hp: f64,
    eps: f64,
) -> bool {
    let dmin = rect_distance(r_lo, r_hi, q_lo, q_hi);
    let n = floor_i64(dmin / MIN_INTERVAL_SAMPLES).clamp(0, 48) as usize;
    if n == 0 {
        return false;
    }
    // Per fraction `s`: the swept rectangle's corners and the sight lines' height there. Each
    // interval's end is the next one's start: computed once and carried (the same values).
    let at =
        |s: f64| (q_lo * (1.0 - s) + r_lo * s, q_hi * (1.0 - s) + r_hi * s, hp * (1.0 - s) + z * s);
    let (mut alo, mut ahi, mut ha) = at(0.0 / n as f64);
    for m in 0..n {
        let (blo, bhi, hb) = at((m + 1) as f64 / n as f64);
        let (lo, hi) = (alo.min(blo), ahi.max(bhi));
        let ray_max = ha.max(hb);
        (alo, ahi, ha) = (blo, bhi, hb);
        let (x0, y0, x1, y1) = (floor_i64(lo.x), floor_i64(lo.y), ceil_i64(hi.x), ceil_i64(hi.y));
        // A block wholly inside the rectangle bounds its min from above: a cheap exact reject
        // (the usual case) before the block query.
        if f64::from(mip.inner_min(x0, y0, x1, y1)) <= ray_max + eps {
            continue;
        }
        let (ground_min, _) = mip.range(x0, y0, x1, y1);
        if f64::from(ground_min) > ray_max + eps {
            return true;
        }
    }
    false
}

/// Whether raising the eye from `z0` to `z1` provably raises every Bresenham step's sight
/// line height on `hm` despite rounding (see `Ctx::column`): the least rise, `(z1 - z0) / N`,
/// must exceed a generous bound (`32 ε` of the largest magnitude involved) on the rounding
/// of the two evaluations of `e + (T - e) t`.
fn chain_margin(hm: &Heightmap, z0: f64, z1: f64) -> bool {
    let n = (hm.width() + hm.height()) as f64;
    let big = z0.abs().max(z1.abs()).max(f64::from(hm.min()).abs()).max(f64::from(hm.max()).abs());
    (z1 - z0) / n > 32.0 * f64::EPSILON * (big + 1.0)
}

/// The PVPS paper's per-patch test (section 2.2.2): `n x n` test points evenly over the
/// patch (at DEM samples), key viewpoints on the top plane's edges chosen by Fig. 6, midpoint
/// refinement up to `max_viewpoints`, Eq. 4 line of sight; stops at the first visible pair.
/// Returns (visible, visible through a pair whose plane is above its test point or with a
/// test point under the plane: one that any higher plane also sees, see `Ctx::column`).
/// With `between: Some(z_u)` (the patch is hidden from the plane at `z_u` above, see
/// [`Above`]), the test points whose Fig. 6 case is the same at `z_u` are known hidden and
/// skipped.
fn sampled_patch_visible(
    mip: &HeightMip<'_>,
    targets: &HeightMip<'_>,
    top: &Top<'_>,
    q: (u32, u32, u32, u32),
    cfg: &PvsConfig,
    between: Option<f64>,
    hints: &mut los::Hints,
) -> (bool, bool) {
    let hm = targets.heightmap();
    let n = cfg.test_points.max(1);
    let coord = |a: u32, b: u32, k: u32| -> u32 {
        if n == 1 {
            (a + b) / 2
        } else {
            los::round_i64(f64::from(a) + f64::from(b - a) * f64::from(k) / f64::from(n - 1)) as u32
        }
    };
    let mut points: Vec<DVec3> = Vec::with_capacity((n * n) as usize);
    for ty in 0..n {
        for tx in 0..n {
            let (x, y) = (coord(q.0, q.2, tx), coord(q.1, q.3, ty));
            let t =
                DVec3::new(f64::from(x), f64::from(y), f64::from(hm.get(x as usize, y as usize)));
            if (top.lo.x..=top.hi.x).contains(&t.x) && (top.lo.y..=top.hi.y).contains(&t.y) {
                // Under the cell: seen straight down from the top plane (Z >= the cell's max).
                return (true, true);
            }
            points.push(t);
        }
    }
    // The result is the OR over every (test point, key viewpoint) pair, so the order is free.
    // The highest test point first, as it is the likeliest to be seen (a speed choice).
    if let Some(k) = (0..points.len()).max_by(|&a, &b| points[a].z.total_cmp(&points[b].z)) {
        points.swap(0, k);
    }
    for &t in &points {
        let case = fig6_case(top, t);
        if between.is_some_and(|zu| (zu - t.z > 0.0) == (case & ABOVE != 0)) {
            continue;
        }
        if top.views[case].iter().any(|&v| los::visible_with(mip, v, t, cfg.epsilon_m, hints)) {
            return (true, case & ABOVE != 0);
        }
    }
    (false, false)
}

/// [`fig6_case`]'s bit for a plane above the test point.
const ABOVE: usize = 16;

/// Which case of Fig. 6's table test point `t` falls in: its region around the plane (west,
/// east, south, north flags) and whether the plane is above it; [`key_viewpoints`] depends on
/// `t` through these alone.
fn fig6_case(top: &Top<'_>, t: DVec3) -> usize {
    usize::from(t.x < top.lo.x)
        | usize::from(t.x > top.hi.x) << 1
        | usize::from(t.y < top.lo.y) << 2
        | usize::from(t.y > top.hi.y) << 3
        | if top.z - t.z > 0.0 { ABOVE } else { 0 }
}

/// The key viewpoints of every case of [`fig6_case`] (computed once per plane).
fn view_table(top: &Top<'_>, max: usize) -> Vec<Vec<DVec3>> {
    (0..32)
        .map(|c| {
            let mut out = Vec::with_capacity(max);
            key_viewpoints_case(top, c, max, &mut out);
            out
        })
        .collect()
}

/// The key viewpoints of Fig. 6 for test point `t`: the top plane's edges facing `t` when
/// the plane is above it (`Z_top - Z_t > 0`), the far edges otherwise; first the edges' ends,
/// then midpoints of adjacent viewpoints, round by round, up to `max` in all.
///
/// Fig. 6 names edges 0-3 (top, left, bottom, right of its top view) and regions 0-7 around
/// the cell; a corner region takes the two edges meeting at the corner, a side region the one
/// edge on its side, exactly as the table lists them.
#[cfg(test)]
fn key_viewpoints(top: &Top<'_>, t: DVec3, max: usize, out: &mut Vec<DVec3>) {
    key_viewpoints_case(top, fig6_case(top, t), max, out);
}

/// [`key_viewpoints`] for the test points of one [`fig6_case`].
fn key_viewpoints_case(top: &Top<'_>, case: usize, max: usize, out: &mut Vec<DVec3>) {
    out.clear();
    let (lo, hi) = (top.lo, top.hi);
    let (west, east) = (case & 1 != 0, case & 2 != 0);
    let (south, north, above) = (case & 4 != 0, case & 8 != 0, case & ABOVE != 0);
    // Edges as (start, end) on the top plane.
    let w_edge = (DVec2::new(lo.x, lo.y), DVec2::new(lo.x, hi.y));
    let e_edge = (DVec2::new(hi.x, lo.y), DVec2::new(hi.x, hi.y));
    let s_edge = (DVec2::new(lo.x, lo.y), DVec2::new(hi.x, lo.y));
    let n_edge = (DVec2::new(lo.x, hi.y), DVec2::new(hi.x, hi.y));
    let mut edges: Vec<(DVec2, DVec2)> = Vec::with_capacity(2);
    let pick = |facing: bool, near: (DVec2, DVec2), far: (DVec2, DVec2)| {
        facing.then_some(if above { near } else { far })
    };
    edges.extend(pick(west, w_edge, e_edge));
    edges.extend(pick(east, e_edge, w_edge));
    edges.extend(pick(south, s_edge, n_edge));
    edges.extend(pick(north, n_edge, s_edge));
    let push = |out: &mut Vec<DVec3>, p: DVec2| {
        let v = p.extend(top.z);
        if out.len() < max && !out.iter().any(|o| (*o - v).length_squared() < 1e-18) {
            out.push(v);
        }
    };
    for &(a, b) in &edges {
        push(out, a);
        push(out, b);
    }
    let mut round = 1u32;
    while out.len() < max && round < 12 {
        let parts = 1u32 << round;
        for &(a, b) in &edges {
            for m in (1..parts).step_by(2) {
                push(out, a.lerp(b, f64::from(m) / f64::from(parts)));
            }
        }
        round += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chained_floors_have_shortcuts_to_take_and_equal_cells_baked_alone() {
        use terrain_core::georef::Georef;
        // Ridges across a plain: much is hidden from low floors, less from high ones.
        let hm = Heightmap::from_fn(129, 129, Georef::local(30.0), |i, j| {
            let r = ((i as f32 * 0.21).sin() * (j as f32 * 0.17).cos()).abs();
            if (i / 16) % 3 == 1 { 60.0 * r + 40.0 } else { 5.0 * r }
        })
        .unwrap();
        let cfg = PvsConfig {
            cells: (4, 4),
            floors: 3,
            floor_rule: crate::pvs::FloorRule::AboveTerrain { height_m: Some(15.0) },
            patch_level: 4,
            ..PvsConfig::default()
        };
        let layout = PvsLayout::new(&hm, &cfg);
        let mip = HeightMip::new(&hm);
        let lines = LineMins::new(&hm);
        let ctx = Ctx::of_grid(&hm, &mip, &lines, &layout, &cfg);
        let (mut witnesses, mut proven_above, mut hidden_above) = (0u32, 0u32, 0u32);
        for n in 0..16u32 {
            let (a, b) = (n % 4, n / 4);
            let id = |k| layout.cell_index(CellId { a, b, k });
            let chained = ctx.column(a, b);
            for k in 0..3u32 {
                assert_eq!(chained[k as usize], ctx.cell(id(k)), "cell ({a}, {b}, {k})");
            }
            // What the middle floor is chained to: floor 0's sampled witnesses, floor 2's bits.
            let (_, _, w) = ctx.cell_chained(id(0), None, None, None);
            witnesses += w.iter().map(|x| x.count_ones()).sum::<u32>();
            let (s2, c2) = &chained[2];
            let l = layout.patch_level;
            for j in 0..1u32 << l {
                for i in 0..1u32 << l {
                    proven_above += u32::from(!bit(c2, l, i, j));
                    hidden_above += u32::from(!bit(s2, l, i, j));
                }
            }
            let (z0, z1) = (
                layout.floor_bounds(CellId { a, b, k: 0 }),
                layout.floor_bounds(CellId { a, b, k: 2 }),
            );
            assert!(chain_margin(&hm, z0.unwrap().1, z1.unwrap().1));
        }
        assert!(witnesses > 100, "no sampled witnesses to chain: {witnesses}");
        assert!(proven_above > 10, "nothing proven from the top floor: {proven_above}");
        assert!(hidden_above > proven_above, "{hidden_above} {proven_above}");
        // The guard refuses floors too close for the rounding.
        assert!(!chain_margin(&hm, 100.0, 100.0 + 1e-12));
    }

    #[test]
    fn hidden_from_above_skips_only_test_points_of_the_same_case() {
        // `sampled_patch_visible` with `between` (the patch hidden from a higher plane) must
        // equal the full test, over many planes and patches of a rough terrain, many of them
        // with test points between the planes (tested) beside others (skipped).
        let hm =
            terrain_core::synth::FractalConfig::with_size(129, 129, 30.0).to_heightmap().unwrap();
        let mip = HeightMip::new(&hm);
        let cfg = PvsConfig::default();
        let (lo_h, hi_h) = (f64::from(hm.min()), f64::from(hm.max()));
        let (mut checked, mut mixed) = (0, 0);
        for (n, &(x0, y0)) in
            [(8.0, 8.0), (60.0, 20.0), (100.0, 96.0), (30.0, 90.0)].iter().enumerate()
        {
            let (lo, hi) = (DVec2::new(x0, y0), DVec2::new(x0 + 16.0, y0 + 16.0));
            for m in 0..6 {
                let zk = lo_h + (hi_h - lo_h) * (0.3 + 0.15 * f64::from(m));
                for zu in [zk + 0.1 * (hi_h - lo_h), zk + 0.4 * (hi_h - lo_h)] {
                    let plane = |z: f64, views: &'static [Vec<DVec3>]| Top {
                        lo,
                        hi,
                        z,
                        below: None,
                        views,
                        seen_below: None,
                        above: None,
                    };
                    let vk: &'static [Vec<DVec3>] = Vec::leak(view_table(&plane(zk, &[]), 16));
                    let vu: &'static [Vec<DVec3>] = Vec::leak(view_table(&plane(zu, &[]), 16));
                    let (tk, tu) = (plane(zk, vk), plane(zu, vu));
                    for j in 0..8u32 {
                        for i in 0..8u32 {
                            let q = (i * 16, j * 16, i * 16 + 16, j * 16 + 16);
                            let mut hints = los::Hints::new();
                            if sampled_patch_visible(&mip, &mip, &tu, q, &cfg, None, &mut hints).0 {
                                continue;
                            }
                            let full =
                                sampled_patch_visible(&mip, &mip, &tk, q, &cfg, None, &mut hints);
                            let skip = sampled_patch_visible(
                                &mip,
                                &mip,
                                &tk,
                                q,
                                &cfg,
                                Some(zu),
                                &mut hints,
                            );
                            assert_eq!(full.0, skip.0, "plane {n}, z {zk} / {zu}, patch {i} {j}");
                            checked += 1;
                            let z = |x: u32, y: u32| f64::from(hm.get(x as usize, y as usize));
                            let between = (q.1..=q.3.min(128))
                                .flat_map(|y| (q.0..=q.2.min(128)).map(move |x| (x, y)))
                                .filter(|&(x, y)| (zk..zu).contains(&z(x, y)))
                                .count();
                            mixed += usize::from(between > 0 && between < 200);
                        }
                    }
                }
            }
        }
        assert!(checked > 200 && mixed > 50, "{checked} {mixed}");
    }

    #[test]
    fn key_viewpoints_follow_fig6() {
        let top = Top {
            lo: DVec2::new(10.0, 10.0),
            hi: DVec2::new(20.0, 20.0),
            z: 100.0,
            below: None,
            views: &[],
            seen_below: None,
            above: None,
        };
        let mut v = Vec::new();
        // Region north-west, plane above the test point: the north and west edges.
        key_viewpoints(&top, DVec3::new(0.0, 30.0, 0.0), 16, &mut v);
        assert_eq!(v.len(), 16);
        assert!(v.iter().all(|p| p.x == 10.0 || p.y == 20.0));
        assert!(v.iter().all(|p| p.z == 100.0));
        // The same region, plane below the test point: the south and east edges.
        key_viewpoints(&top, DVec3::new(0.0, 30.0, 500.0), 16, &mut v);
        assert!(v.iter().all(|p| p.x == 20.0 || p.y == 10.0));
        // Region east, above: the east edge only; ends first, then the midpoint.
        key_viewpoints(&top, DVec3::new(30.0, 15.0, 0.0), 16, &mut v);
        assert!(v.iter().all(|p| p.x == 20.0));
        assert_eq!(
            &v[..3],
            &[
                DVec3::new(20.0, 10.0, 100.0),
                DVec3::new(20.0, 20.0, 100.0),
                DVec3::new(20.0, 15.0, 100.0)
            ]
        );
        assert_eq!(v.len(), 16);
    }
}
