//! Regression pins for the PVS bake's speed-ups: the bits baked on a real DEM crop and on a
//! synthetic fractal must equal those of the bake before the speed-ups (FNV-1a hashes of the
//! full bitsets, recorded from the unoptimised bake at commit b4be0bc), and the accelerated
//! Eq. 4 line of sight must agree with a plain sample-by-sample walk of the same Bresenham
//! section line on many sight lines.

mod common;

use common::data;

use glam::DVec3;
use terrain_core::Heightmap;
use terrain_core::dem::{LoadOptions, load};
use terrain_core::georef::Georef;
use terrain_core::synth::FractalConfig;
use terrain_visibility::pvs::bake::bake_cells;
use terrain_visibility::pvs::mip::HeightMip;
use terrain_visibility::pvs::{FloorRule, PvsConfig, bake_both, los};

fn fnv(bits: &[u8]) -> u64 {
    terrain_core::checksum::fnv1a_update(terrain_core::checksum::FNV1A_START, bits)
}

/// A 257 x 257 crop of the Puget Sound 1k DEM (mountains and valleys).
fn puget_crop() -> Heightmap {
    let opts = LoadOptions { vertical_scale: 0.1, spacing_m: 160.0, ..Default::default() };
    let hm = load(data("puget_sound/ps_height_1k.png"), &opts).unwrap().heightmap;
    let (x0, y0) = (600, 250);
    Heightmap::from_fn(257, 257, Georef::local(160.0), |i, j| hm.get(x0 + i, y0 + j)).unwrap()
}

fn cfg(cells: u32, floors: u32, floor_m: f64, patch_level: u8) -> PvsConfig {
    PvsConfig {
        cells: (cells, cells),
        floors,
        floor_rule: FloorRule::AboveTerrain { height_m: Some(floor_m) },
        patch_level,
        ..PvsConfig::default()
    }
}

fn hashes(hm: &Heightmap, cfg: &PvsConfig) -> (u64, u64, f64) {
    let (s, k, _) = bake_both(hm, cfg);
    (fnv(&s.bits), fnv(&k.bits), s.culled_fraction())
}

#[test]
fn the_bake_is_unchanged_on_a_real_crop() {
    let h = hashes(&puget_crop(), &cfg(4, 2, 60.0, 5));
    assert!(h.2 > 0.05, "too little is hidden for the pin to test anything: {h:?}");
    assert_eq!((h.0, h.1), (13_980_125_240_585_439_354, 127_642_041_776_348_927), "{h:?}");
}

#[test]
fn the_bake_is_unchanged_on_the_fractal() {
    let hm = FractalConfig::with_size(129, 129, 30.0).to_heightmap().unwrap();
    let h = hashes(&hm, &cfg(4, 2, 20.0, 4));
    assert!(h.2 > 0.05, "too little is hidden for the pin to test anything: {h:?}");
    assert_eq!((h.0, h.1), (3_049_715_311_235_966_988, 13_164_170_336_371_822_656), "{h:?}");
}

#[test]
fn the_accelerated_line_of_sight_equals_the_plain_walk() {
    let hm = puget_crop();
    let mip = HeightMip::new(&hm);
    let mut hints = los::Hints::new();
    // A deterministic spread of eyes and targets (an LCG), eyes 0-3 km above the terrain.
    let mut state = 12_345u64;
    let mut next = || {
        state =
            state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        (state >> 33) as f64 / f64::from(1u32 << 31)
    };
    let (mut seen, mut hidden) = (0, 0);
    for _ in 0..3000 {
        let (ex, ey) = (next() * 256.0, next() * 256.0);
        let ground = f64::from(hm.get(ex.round() as usize, ey.round() as usize));
        let eye = DVec3::new(ex, ey, ground + next() * 3000.0);
        let (tx, ty) = ((next() * 256.0).round(), (next() * 256.0).round());
        let target = DVec3::new(tx, ty, f64::from(hm.get(tx as usize, ty as usize)));
        let want = los::visible_reference(&hm, eye, target, 1e-3);
        assert_eq!(los::visible(&mip, eye, target, 1e-3), want, "{eye} -> {target}");
        assert_eq!(
            los::visible_with(&mip, eye, target, 1e-3, &mut hints),
            want,
            "{eye} -> {target}"
        );
        if want { seen += 1 } else { hidden += 1 }
    }
    assert!(seen > 300 && hidden > 300, "seen {seen}, hidden {hidden}: not a mixed test");
}

/// Bakes `cfg` with chained floors (`bake_both`) and every cell alone (`bake_cells`), asserts
/// that every bit agrees, and returns the chained bake's (sampled, conservative) PVS.
fn assert_chained_equals_alone(
    hm: &Heightmap,
    cfg: &PvsConfig,
) -> (terrain_visibility::pvs::Pvs, terrain_visibility::pvs::Pvs) {
    let (s, k, _) = bake_both(hm, cfg);
    let n = s.layout.cell_count();
    let alone = bake_cells(hm, cfg, &(0..n).collect::<Vec<_>>());
    let per = s.layout.bytes_per_cell();
    for (c, (bs, bk)) in alone.iter().enumerate() {
        assert_eq!(&s.bits[c * per..(c + 1) * per], bs.as_slice(), "sampled, cell {c}");
        assert_eq!(&k.bits[c * per..(c + 1) * per], bk.as_slice(), "conservative, cell {c}");
    }
    (s, k)
}

#[test]
fn chaining_the_floors_changes_no_bit() {
    // `bake_both` bakes each plan cell's floors lowest first and skips the proofs a lower
    // floor showed hopeless; `bake_cells` bakes every cell alone.
    let (_, k) = assert_chained_equals_alone(&puget_crop(), &cfg(4, 3, 10.0, 5));
    assert!(
        k.culled_fraction() > 0.02,
        "too little is hidden to test anything: {}",
        k.culled_fraction()
    );
}

#[test]
fn chaining_four_floors_on_the_fractal_changes_no_bit() {
    // Four floors are baked in the order 0, 3, 1, 2: floors 1 and 2 are chained both to a
    // floor below and to one above; every bit must equal the cell baked alone.
    let hm = FractalConfig::with_size(129, 129, 30.0).to_heightmap().unwrap();
    let (s, _) = assert_chained_equals_alone(&hm, &cfg(4, 4, 8.0, 4));
    assert!(s.culled_fraction() > 0.05, "too little is hidden to test anything");
}
