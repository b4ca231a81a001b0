//! The decimation error of a DEM and the budget a tile meshed from decimated samples gets:
//! **one implementation** for both error-bounded TIN pyramids built from strided samples, the
//! geographic tiles of `terrain tiles` and the grid tiles of the `tin` method (in memory with
//! `max_tile_cells`, and from a store).
//!
//! **Decimation error** ([`Decimation`]): for every region of `region x region` cells and every
//! stride `2^s` (`1 <= s <= max_s`), the largest difference between a non-void sample in it
//! and the bilinear interpolation of the strided samples (every `2^s`-th row and column from
//! 0, the last row or column standing in past the grid's edge). Measured per region on first
//! need ([`Decimation::error_in`]) or for every region at once on every core
//! ([`Decimation::measure_all`], which hands each region's samples at stride 1 to the caller
//! too, so another measure of every sample rides on the same read); either way a region is
//! measured once and reads its samples at stride 1 once.
//!
//! **Budget** ([`build_within`]): a tile of bound `e` whose own stride is `2^s` is meshed within
//! `e - E_s` of its strided samples, `E_s` the decimation error under it, at the coarsest
//! stride up to its own where that budget is at least `min_budget_fraction x e` (at `s = 0`,
//! `E = 0` and the mesher's own verification covers every sample). A decimated tile is then
//! checked against every sample under it (the caller's check); one that fails is built again
//! with its budget cut by the excess measured (and a hundredth of the bound), at most
//! `max_retries` times, then one stride finer. So every tile returned is within its bound of
//! every non-void sample, while coarse tiles read and mesh a bounded number of samples.

use std::sync::OnceLock;

use rayon::prelude::*;

use terrain_core::tin::decimation::region_errors;

use crate::samples::{Samples, Window};

/// Cells per side of the regions the decimation error is measured in, for every source (so a
/// store and its DEM in memory get the same budgets, and the same tiles).
pub const DECIMATION_REGION: usize = 256;

/// The decimation error of a grid per region and stride (see the module docs).
#[derive(Debug)]
pub struct Decimation {
    width: usize,
    height: usize,
    region: usize,
    regions_x: usize,
    regions_y: usize,
    max_s: u32,
    /// Per region (row-major): its error per stride `s - 1`, metres, once measured.
    errors: Vec<OnceLock<Vec<f32>>>,
}

impl Decimation {
    /// The (not yet measured) decimation error of a `width x height` grid in regions of
    /// `region` cells, strides `2^1..=2^max_s`.
    pub fn new(width: usize, height: usize, region: usize, max_s: u32) -> Self {
        let region = region.max(1);
        let (rx, ry) = (
            width.saturating_sub(1).div_ceil(region).max(1),
            height.saturating_sub(1).div_ceil(region).max(1),
        );
        let errors = (0..rx * ry).map(|_| OnceLock::new()).collect();
        Self { width, height, region, regions_x: rx, regions_y: ry, max_s, errors }
    }

    /// Measures every region on every core (one measured before is read again and keeps its
    /// numbers), handing each region's samples at stride 1 to `each` (its first column and
    /// row, and the window: the region's `region + 1` columns and rows clipped to the grid,
    /// so neighbouring windows share their border): what `each` returns, in region order.
    pub fn measure_all<T: Send>(
        &self,
        samples: &dyn Samples,
        each: impl Fn(usize, usize, &Window) -> T + Sync,
    ) -> anyhow::Result<Vec<T>> {
        (0..self.errors.len())
            .into_par_iter()
            .map(|r| {
                let (i0, j0, fine) = self.region_window(samples, r)?;
                let seen = each(i0, j0, &fine);
                if self.errors[r].get().is_none() {
                    let e = self.measure_region(samples, i0, j0, &fine)?;
                    // Another thread may have measured it meanwhile: the same numbers.
                    self.errors[r].get_or_init(|| e);
                }
                Ok(seen)
            })
            .collect()
    }

    /// The largest decimation error at stride `2^s` over the regions meeting the samples
    /// `[i0, j0, i1, j1]` (inclusive), measuring those not measured yet (0 at `s = 0`;
    /// infinite past the strides measured).
    pub fn error_in(
        &self,
        samples: &dyn Samples,
        [i0, j0, i1, j1]: [usize; 4],
        s: u32,
    ) -> anyhow::Result<f64> {
        if s == 0 {
            return Ok(0.0);
        }
        if s > self.max_s {
            return Ok(f64::INFINITY);
        }
        let r = |v: usize, n: usize| (v / self.region).min(n - 1);
        let mut worst = 0f64;
        for y in r(j0, self.regions_y)..=r(j1, self.regions_y) {
            for x in r(i0, self.regions_x)..=r(i1, self.regions_x) {
                let e = self.region_errors(samples, y * self.regions_x + x)?;
                worst = worst.max(f64::from(e[(s - 1) as usize]));
            }
        }
        Ok(worst)
    }

    /// The largest decimation error measured so far at any stride anywhere, metres.
    pub fn max(&self) -> f64 {
        self.errors
            .iter()
            .filter_map(OnceLock::get)
            .flatten()
            .fold(0f64, |a, &e| a.max(f64::from(e)))
    }

    /// Region `r`'s errors per stride, measured on first need.
    fn region_errors(&self, samples: &dyn Samples, r: usize) -> anyhow::Result<&[f32]> {
        if let Some(e) = self.errors[r].get() {
            return Ok(e);
        }
        let (i0, j0, fine) = self.region_window(samples, r)?;
        let e = self.measure_region(samples, i0, j0, &fine)?;
        // Another thread may have measured it meanwhile: the same numbers.
        Ok(self.errors[r].get_or_init(|| e))
    }

    /// Region `r`'s first column and row, and its samples at stride 1.
    fn region_window(
        &self,
        samples: &dyn Samples,
        r: usize,
    ) -> anyhow::Result<(usize, usize, Window)> {
        let (w, h, region) = (self.width, self.height, self.region);
        let (i0, j0) = ((r % self.regions_x) * region, (r / self.regions_x) * region);
        let (i1, j1) = ((i0 + region).min(w - 1), (j0 + region).min(h - 1));
        Ok((i0, j0, samples.window(i0, j0, i1 - i0 + 1, j1 - j0 + 1, 0)?))
    }

    /// The errors per stride of the region from `(i0, j0)` whose samples are `fine`
    /// ([`terrain_core::tin::decimation::region_errors`], the one implementation, which the
    /// bake of a store's table calls too).
    fn measure_region(
        &self,
        samples: &dyn Samples,
        i0: usize,
        j0: usize,
        fine: &Window,
    ) -> anyhow::Result<Vec<f32>> {
        region_errors(
            &fine.data,
            fine.width,
            (i0, j0),
            fine.voids.as_ref(),
            self.max_s,
            |s, a0, b0, na, nb| samples.window(a0, b0, na, nb, s).map(|w| w.data),
        )
    }

    /// Regions across and up.
    pub fn regions(&self) -> (usize, usize) {
        (self.regions_x, self.regions_y)
    }

    /// The strides measured: `2^1..=2^max_s`.
    pub fn max_s(&self) -> u32 {
        self.max_s
    }

    /// Takes region `(x, y)`'s errors from elsewhere (a store's table, which the bake measured
    /// by the same function from the same heights): its first `max_s` values, per stride
    /// `2^1` up. False (nothing taken) when `errors` has fewer values or the region is
    /// measured already.
    pub fn set_region(&self, x: usize, y: usize, errors: &[f32]) -> bool {
        let n = self.max_s as usize;
        if x >= self.regions_x || y >= self.regions_y || errors.len() < n {
            return false;
        }
        self.errors[y * self.regions_x + x].set(errors[..n].to_vec()).is_ok()
    }
}

/// How a tile's budget and stride are chosen ([`build_within`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BudgetPolicy {
    /// The least fraction of a decimated tile's bound its mesh gets against the decimated
    /// samples: below it the tile is meshed one stride finer.
    pub min_budget_fraction: f64,
    /// Rebuilds of a tile at one stride with a smaller budget before it goes one stride finer.
    pub max_retries: u32,
}

impl Default for BudgetPolicy {
    /// Three quarters of the bound at least. A decimated tile's triangles grow as its budget
    /// shrinks (roughly as `1 / budget` for a linear interpolant), so under half its bound a
    /// tile is meshed tighter than its children's bound and a client loading the coarser level
    /// pays more triangles than at the finer one. At a quarter (the default before
    /// 2026-12-05) the mirrored Everest's (`ev16k`) level 5 had 334,258 triangles in 12 tiles
    /// against level 6's 119,646 in 36, and `pyr16k`'s level 8 1.45 M against 0.88 M at a
    /// half. At three quarters a tile has at most about 4/3 of the triangles it would have
    /// from every sample: `ev16k`'s level 5 9,532, `pyr16k`'s levels 7-8 151 k / 669 k (were
    /// 414 k / 1.45 M), for 0-1.5 % (`pyr16k`, two rounds) and 1.4 % (`ev16k`, one run) more
    /// user CPU over the whole tileset (bench/mesh/README, "The budget floor").
    fn default() -> Self {
        Self { min_budget_fraction: 0.75, max_retries: 2 }
    }
}

/// A tile built by [`build_within`].
#[derive(Debug, Clone)]
pub struct Budgeted<M> {
    /// The tile.
    pub mesh: M,
    /// Its largest error against every sample under it, metres.
    pub measured: f64,
    /// The decimation error of the stride it was meshed at (0 at full resolution), metres.
    pub decimation: f64,
    /// log2 of that stride.
    pub stride_log2: u32,
    /// Whether it was first meshed from decimated samples (and so checked).
    pub decimated: bool,
    /// Rebuilds after a failed check.
    pub retries: usize,
}

/// The stride `2^s'` [`build_within`] first meshes a tile of bound `bound` and own stride `2^s`
/// at: the coarsest, up to `s` and down to `min_s`, whose decimation error (`error(s')`)
/// leaves at least `min_budget_fraction` of the bound (0: every sample). What a tile will be
/// built at, known before it is built where the decimation errors are (a rebuild after a
/// failed check may go finer).
pub fn planned_stride(
    bound: f64,
    mut s: u32,
    min_s: u32,
    policy: &BudgetPolicy,
    error: impl Fn(u32) -> anyhow::Result<f64>,
) -> anyhow::Result<u32> {
    let floor = policy.min_budget_fraction * bound;
    while s > min_s && bound - error(s)? < floor {
        s -= 1;
    }
    Ok(s)
}

/// Builds a tile of bound `bound` whose own stride is `2^s` (see the module docs): `error(s)`
/// is the decimation error under it at stride `2^s`; `build(s, budget)` meshes it from every
/// `2^s`-th sample within `budget` (at `s = 0`, within `bound`, verified against every sample
/// by the builder, whose measured error `exact` reads); `check(mesh)` measures a decimated
/// mesh against every sample under it (`None`: a sample left uncovered, a failure), or bounds
/// its error from above. `2^min_s` is the finest stride the caller wants (0: any): a tile
/// whose coarser strides all leave less than the floor is meshed there within what its
/// decimation error leaves of the bound (the caller's bound leaves some). One that fails its
/// check there goes finer as any other; finer than `2^min_s`, its budget is cut further, below
/// the floor if need be (to at most `2 max_retries + 2` tries), before it goes finer again.
/// (Cutting the budget at `2^min_s` itself does not pay: where the strided samples are rough,
/// the bilinear surface between them strays from any mesh of them by more than the bound
/// allows, so the cuts run the budget down to nothing and the mesh to every strided sample:
/// 30-85 k triangles for a tile that one stride finer takes 1-4 k, on the mirrored Everest.)
#[allow(clippy::too_many_arguments)]
pub fn build_within<M>(
    bound: f64,
    s: u32,
    min_s: u32,
    policy: &BudgetPolicy,
    error: impl Fn(u32) -> anyhow::Result<f64>,
    mut build: impl FnMut(u32, f64) -> anyhow::Result<M>,
    exact: impl Fn(&M) -> f64,
    mut check: impl FnMut(&M) -> anyhow::Result<Option<f64>>,
) -> anyhow::Result<Budgeted<M>> {
    let floor = policy.min_budget_fraction * bound;
    // The coarsest stride, up to `s` and down to `min`, whose decimation error leaves the
    // floor.
    let coarsest = |s: u32, min: u32| planned_stride(bound, s, min, policy, &error);
    let full = |build: &mut dyn FnMut(u32, f64) -> anyhow::Result<M>, retries: usize, decimated| {
        let mesh = build(0, bound)?;
        let measured = exact(&mesh);
        Ok(Budgeted { mesh, measured, decimation: 0.0, stride_log2: 0, decimated, retries })
    };
    let mut s = coarsest(s, min_s)?;
    if s == 0 {
        return full(&mut build, 0, false);
    }
    let mut budget = bound - error(s)?;
    let (mut tries, mut retries) = (0, 0);
    loop {
        let mesh = build(s, budget)?;
        let measured = check(&mesh)?;
        if let Some(e) = measured
            && e <= bound
        {
            let decimation = error(s)?;
            return Ok(Budgeted {
                mesh,
                measured: e,
                decimation,
                stride_log2: s,
                decimated: true,
                retries,
            });
        }
        retries += 1;
        tries += 1;
        // Cut the budget by the excess (and a hundredth of the bound more), or go finer.
        let cut = measured.map(|e| budget - (e - bound) - 0.01 * bound);
        let last_try = 2 * policy.max_retries + 2;
        match cut {
            Some(b) if tries <= policy.max_retries && b >= floor => budget = b,
            Some(b) if s < min_s && tries <= last_try && b > 0.0 => budget = b,
            _ => {
                s = coarsest(s - 1, 0)?;
                tries = 0;
                if s == 0 {
                    return full(&mut build, retries, true);
                }
                budget = bound - error(s)?;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::samples::HeightmapSamples;
    use terrain_core::Georef;
    use terrain_core::heightmap::{Heightmap, VoidMask};

    /// The decimation error of the samples `[i0..=i1] x [j0..=j1]` at stride `2^s`, sample by
    /// sample from the grid itself: the bilinear interpolation of the strided samples (the last
    /// row or column standing in past the edge), voids skipped, non-finite heights as 0.
    fn reference(hm: &Heightmap, [i0, j0, i1, j1]: [usize; 4], s: u32) -> f32 {
        let (w, h) = (hm.width(), hm.height());
        let t = 1usize << s;
        let z = |i: usize, j: usize| {
            let v = hm.get(i.min(w - 1), j.min(h - 1));
            if v.is_finite() { f64::from(v) } else { 0.0 }
        };
        let mut worst = 0f64;
        for j in j0..=j1 {
            for i in i0..=i1 {
                if hm.voids().get(i, j) {
                    continue;
                }
                let (a, b) = ((i / t) * t, (j / t) * t);
                let (fx, fy) = ((i - a) as f64 / t as f64, (j - b) as f64 / t as f64);
                let south = z(a, b) + fx * (z(a + t, b) - z(a, b));
                let north = z(a, b + t) + fx * (z(a + t, b + t) - z(a, b + t));
                worst = worst.max((z(i, j) - (south + fy * (north - south))).abs());
            }
        }
        worst as f32
    }

    /// Every region's error at every stride is the sample-by-sample reference's, bit for bit,
    /// on grids whose sides are no multiple of the regions or the strides, with voids and
    /// NaN heights.
    #[test]
    fn the_decimation_error_is_the_bilinear_reference_per_region() {
        for (w, h, region) in [(97, 61, 16), (300, 17, 32), (70, 70, 64), (1, 40, 16)] {
            let mut voids = VoidMask::new(w, h);
            for (i, j) in [(3, 5), (w / 2, h / 2), (w - 1, h - 1)] {
                voids.set(i.min(w - 1), j.min(h - 1), true);
            }
            let data = (0..w * h)
                .map(|p| {
                    let (i, j) = (p % w, p / w);
                    if (i * 7 + j * 3) % 41 == 0 {
                        voids.set(i, j, true); // a void's height: NaN
                        return f32::NAN;
                    }
                    let (x, y) = (i as f32, j as f32);
                    300.0 * (x * 0.13).sin() * (y * 0.09).cos() + 40.0 * (x * y * 0.021).sin()
                })
                .collect::<Vec<f32>>();
            let hm = Heightmap::new(w, h, data, voids, Georef::local(10.0)).unwrap();
            let d = Decimation::new(w, h, region, 4);
            let g = HeightmapSamples(&hm);
            let (rx, ry) = ((w - 1).div_ceil(region).max(1), (h - 1).div_ceil(region).max(1));
            for r in 0..rx * ry {
                let (i0, j0) = ((r % rx) * region, (r / rx) * region);
                let (i1, j1) = ((i0 + region).min(w - 1), (j0 + region).min(h - 1));
                for s in 1..=4 {
                    let got = d.error_in(&g, [i0, j0, i0, j0], s).unwrap() as f32;
                    let want = reference(&hm, [i0, j0, i1, j1], s);
                    assert_eq!(got.to_bits(), want.to_bits(), "{w} x {h}, region {r}, 2^{s}");
                }
            }
        }
    }
}
