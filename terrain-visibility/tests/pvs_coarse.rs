//! The PVS of a grid not held in memory (`pvs::coarse`): its coarse terrain is conservative
//! (occluders never above, targets never below the fine samples), its PVS contains every patch
//! the exact in-memory PVS finds visible, for every view cell, it has no false culls against
//! dense ground truth, and it keeps the fine grid's layout and heights' CRC-32.

mod common;

use common::data;

use terrain_core::Heightmap;
use terrain_core::dem::{LoadOptions, load};
use terrain_core::georef::Georef;
use terrain_core::lod::dss_file::heights_checksum;
use terrain_core::quadtree::NodeId;
use terrain_core::synth::FractalConfig;
use terrain_visibility::pvs::coarse::{BYTES_PER_COARSE_SAMPLE, CoarseTerrain, factor_for};
use terrain_visibility::pvs::truth::{TruthConfig, check, sample_cells};
use terrain_visibility::pvs::{CellId, FloorRule, Pvs, PvsConfig, PvsLayout, bake_both};

fn cfg(cells: u32, floors: u32, floor_m: f64, patch_level: u8) -> PvsConfig {
    PvsConfig {
        cells: (cells, cells),
        floors,
        floor_rule: FloorRule::AboveTerrain { height_m: Some(floor_m) },
        patch_level,
        ..PvsConfig::default()
    }
}

/// A 129 x 129 crop of the Puget Sound 1k DEM (the Olympic mountains' east flank).
fn puget_crop() -> Heightmap {
    let opts = LoadOptions { vertical_scale: 0.1, spacing_m: 160.0, ..Default::default() };
    let hm = load(data("puget_sound/ps_height_1k.png"), &opts).unwrap().heightmap;
    let (x0, y0) = (700, 300);
    Heightmap::from_fn(129, 129, Georef::local(160.0), |i, j| hm.get(x0 + i, y0 + j)).unwrap()
}

fn visible(p: &Pvs, c: CellId, l: u8, a: u32, b: u32) -> bool {
    p.visible(c, NodeId::new(l, a, b))
}

#[test]
fn the_coarse_occluders_are_never_above_and_the_targets_never_below_the_terrain() {
    // A non-square grid whose sides are not 1 + a multiple of the factor (clipped windows).
    let hm = FractalConfig::with_size(131, 98, 30.0).to_heightmap().unwrap();
    let f = 4usize;
    let t = CoarseTerrain::from_heightmap(&hm, &cfg(4, 1, 10.0, 3), f as u32).unwrap();
    assert_eq!(t.factor, 4);
    assert_eq!(
        (t.occluders.width(), t.occluders.height()),
        (130usize.div_ceil(4) + 1, 97usize.div_ceil(4) + 1)
    );
    let (cw, ch) = (t.occluders.width(), t.occluders.height());
    let (mut below, mut above) = (0usize, 0usize);
    for y in 0..hm.height() {
        for x in 0..hm.width() {
            let z = hm.get(x, y);
            // Every coarse sample within one coarse cell of the sample: the corners of every
            // coarse cell that holds it (two or four on a cell edge or corner).
            for j in y.saturating_sub(f).div_ceil(f)..=((y + f) / f).min(ch - 1) {
                for i in x.saturating_sub(f).div_ceil(f)..=((x + f) / f).min(cw - 1) {
                    let o = t.occluders.get(i, j);
                    assert!(o <= z, "occluder ({i}, {j}) = {o} above sample ({x}, {y}) = {z}");
                    below += usize::from(o < z);
                }
            }
            // The nearest coarse sample's target is at least the sample.
            let (i, j) = (((x + f / 2) / f).min(cw - 1), ((y + f / 2) / f).min(ch - 1));
            let g = t.targets.get(i, j);
            assert!(g >= z, "target ({i}, {j}) = {g} below sample ({x}, {y}) = {z}");
            above += usize::from(g > z);
        }
    }
    // The reductions did something (the fractal is not flat).
    assert!(below > 0 && above > 0);
}

#[test]
fn the_coarse_layout_is_the_fine_grids_with_its_heights_crc() {
    let hm = puget_crop();
    let c = cfg(4, 2, 40.0, 4);
    let t = CoarseTerrain::from_heightmap(&hm, &c, 4).unwrap();
    assert_eq!(t.layout, PvsLayout::new(&hm, &c));
    assert_eq!(t.layout.heights, heights_checksum(&hm));
    let (s, k, _) = t.bake_both(&c, &|_, _| ());
    assert!(s.matches_heights(&hm) && k.matches_heights(&hm));
    let mut edited = hm.data().to_vec();
    edited[77] += 1.0;
    let edited =
        Heightmap::from_fn(129, 129, Georef::local(160.0), |i, j| edited[j * 129 + i]).unwrap();
    assert!(!k.matches_heights(&edited), "a coarse PVS matched other heights");
}

/// Checks the coarse PVS of `hm` against its exact bake on every cell, pyramid level and
/// patch: the coarse conservative PVS contains every node the exact sampled PVS finds visible
/// (always, by the argument of `pvs::coarse`) and the coarse sampled one. Returns, over the
/// finest patches, (pairs the exact *conservative* PVS keeps that the coarse one culls: not
/// guaranteed 0 in general, since the coarse proofs split into fewer parts and may prove what
/// the exact bake's budget could not, but every such cull is a true one, see the dense truth
/// test; pairs the coarse conservative PVS culls; pairs the exact one culls).
fn assert_superset(hm: &Heightmap, c: &PvsConfig, factor: u32) -> (usize, usize, usize) {
    let (s, k, _) = bake_both(hm, c);
    let t = CoarseTerrain::from_heightmap(hm, c, factor).unwrap();
    let (cs, ck, _) = t.bake_both(c, &|_, _| ());
    let lay = &k.layout;
    let l = lay.patch_level;
    let (mut missed, mut coarse_culled, mut exact_culled) = (0, 0, 0);
    for n in 0..lay.cell_count() {
        let cell = lay.cell_at_index(n);
        for level in 0..=l {
            for b in 0..1u32 << level {
                for a in 0..1u32 << level {
                    let (es, ek) = (visible(&s, cell, level, a, b), visible(&k, cell, level, a, b));
                    let (vs, vk) =
                        (visible(&cs, cell, level, a, b), visible(&ck, cell, level, a, b));
                    assert!(
                        !es || vk,
                        "{cell:?} ({level}, {a}, {b}): exact sampled visible, coarse culled"
                    );
                    assert!(
                        !vs || vk,
                        "{cell:?} ({level}, {a}, {b}): coarse sampled not within coarse conservative"
                    );
                    if level == l && lay.patch_samples(l, a, b).is_some() {
                        missed += usize::from(ek && !vk);
                        coarse_culled += usize::from(!vk);
                        exact_culled += usize::from(!ek);
                    }
                }
            }
        }
    }
    (missed, coarse_culled, exact_culled)
}

#[test]
fn the_coarse_pvs_contains_the_exact_pvs_on_a_real_crop() {
    let (missed, coarse, exact) = assert_superset(&puget_crop(), &cfg(4, 2, 40.0, 4), 2);
    // It still culls: otherwise the superset would hold trivially.
    assert!(coarse > 0, "the coarse PVS culled nothing (exact culled {exact})");
    assert_eq!(missed, 0, "the coarse conservative PVS culled {missed} exact-visible patches");
}

#[test]
fn the_coarse_pvs_contains_the_exact_pvs_on_the_fractal() {
    let hm = FractalConfig::with_size(257, 257, 30.0).to_heightmap().unwrap();
    let (missed, coarse, exact) = assert_superset(&hm, &cfg(4, 2, 20.0, 4), 4);
    assert!(coarse > 0, "the coarse PVS culled nothing (exact culled {exact})");
    assert_eq!(missed, 0, "the coarse conservative PVS culled {missed} exact-visible patches");
}

#[test]
fn the_coarse_conservative_pvs_has_no_false_culls_against_dense_truth() {
    let hm = puget_crop();
    let c = cfg(4, 2, 40.0, 4);
    let t = CoarseTerrain::from_heightmap(&hm, &c, 2).unwrap();
    let (_, k, _) = t.bake_both(&c, &|_, _| ());
    let cells = sample_cells(&k, 6);
    let truth = TruthConfig { plan_viewpoints: 4, heights: 2, ..TruthConfig::default() };
    let counts = check(&hm, &[&k], &cells, &truth)[0];
    assert!(counts.culled > 0, "nothing culled: {counts:?}");
    assert_eq!(counts.false_culls, 0, "{counts:?}");
}

#[test]
fn factor_one_is_the_exact_bake() {
    let hm = puget_crop();
    let c = cfg(4, 2, 40.0, 4);
    let t = CoarseTerrain::from_heightmap(&hm, &c, 1).unwrap();
    assert_eq!(t.occluders.data(), hm.data());
    let (s, k, _) = bake_both(&hm, &c);
    let (cs, ck, _) = t.bake_both(&c, &|_, _| ());
    assert_eq!((cs, ck), (s, k));
}

#[test]
fn the_factor_fits_the_budget_and_keeps_a_coarse_cell_per_patch() {
    let c = PvsConfig::default(); // 64 x 64 patches
    // 4097^2 at 1 MiB: 2^k with (4096 / 2^k + 1)^2 * bytes <= 1 MiB.
    let (f, fits) = factor_for(4097, 4097, &c, 1 << 20);
    assert!(fits);
    let side = 4096 / u64::from(f) + 1;
    assert!(side * side * BYTES_PER_COARSE_SAMPLE <= 1 << 20);
    let half = 4096 / u64::from(f / 2) + 1;
    assert!(half * half * BYTES_PER_COARSE_SAMPLE > 1 << 20, "factor {f} is not the least");
    // A budget too small for one coarse cell per patch: capped at the patch side, not fitting.
    assert_eq!(factor_for(4097, 4097, &c, 1000), (64, false));
    // A budget that holds the grid: no reduction.
    assert_eq!(factor_for(129, 129, &c, 1 << 30), (1, true));
}
