//! The PVS bake on terrains with known answers (a wall, a flat plain, a bowl), the monotonicity
//! of Fig. 5, the pyramid's OR property, the file's errors, the runtime cull policy, and the
//! conservative mode's zero false culls against dense ground truth on a real DEM crop and on
//! the synthetic fractal.

mod common;

use common::data;

use glam::dvec3;
use terrain_core::Heightmap;
use terrain_core::dem::{LoadOptions, load};
use terrain_core::geometry::Camera;
use terrain_core::georef::Georef;
use terrain_core::lod::{
    ConstantField, GridSource, PvpsConfig, select_pvps, select_pvps_with_cull,
};
use terrain_core::measure::LineOfSight;
use terrain_core::quadtree::{NodeId, Quadtree};
use terrain_core::synth::FractalConfig;
use terrain_visibility::pvs::bake::bake_sampled_without_proofs;
use terrain_visibility::pvs::file::{decode, encode};
use terrain_visibility::pvs::mip::HeightMip;
use terrain_visibility::pvs::truth::{TruthConfig, check, sample_cells};
use terrain_visibility::pvs::{
    CellId, FloorRule, Pvs, PvsConfig, PvsFileError, PvsLayout, bake_both, los, read_pvs, write_pvs,
};

fn grid(n: usize, f: impl Fn(usize, usize) -> f32) -> Heightmap {
    Heightmap::from_fn(n, n, Georef::local(10.0), f).unwrap()
}

fn small_cfg(cells: u32, floors: u32, floor_m: f64, patch_level: u8) -> PvsConfig {
    PvsConfig {
        cells: (cells, cells),
        floors,
        floor_rule: FloorRule::AboveTerrain { height_m: Some(floor_m) },
        patch_level,
        ..PvsConfig::default()
    }
}

fn patch_visible(p: &Pvs, c: CellId, a: u32, b: u32) -> bool {
    p.visible(c, NodeId::new(p.layout.patch_level, a, b))
}

/// The pyramid's OR property on every cell of `p`.
fn assert_or_pyramid(p: &Pvs) {
    for n in 0..p.layout.cell_count() {
        let c = p.layout.cell_at_index(n);
        for l in 0..p.layout.patch_level {
            let side = 1u32 << l;
            for j in 0..side {
                for i in 0..side {
                    let or = NodeId::new(l, i, j).children().iter().any(|&ch| p.visible(c, ch));
                    assert_eq!(
                        p.visible(c, NodeId::new(l, i, j)),
                        or,
                        "{c:?} level {l} ({i}, {j})"
                    );
                }
            }
        }
    }
}

#[test]
fn a_wall_hides_everything_behind_it() {
    // Flat ground with a 500 m wall three samples thick at x = 63..=65, across the whole grid.
    let hm = grid(129, |i, _| if (63..=65).contains(&i) { 500.0 } else { 0.0 });
    let cfg = small_cfg(4, 1, 20.0, 4);
    let (s, k, _) = bake_both(&hm, &cfg);
    let (mut proven, mut hidden) = (0, 0);
    for b in 0..4 {
        // Cell column 0 (x in 0..32) is west of the wall, its top plane 20 m up.
        let c = CellId { a: 0, b, k: 0 };
        for pb in 0..16 {
            for pa in 0..16 {
                // Patches are 8 cells: patch 7 (x in 56..=64) holds the wall's west face
                // (x = 63); the rest of the wall's top (x = 64, 65) is hidden by its west
                // edge from a plane below it, and patches 8.. lie behind.
                assert_eq!(patch_visible(&s, c, pa, pb), pa <= 7, "sampled {c:?} patch {pa},{pb}");
                // The conservative mode raises a patch to its max height, so it keeps patch 8
                // (whose max is the wall's top); behind the wall it culls what it can prove.
                if pa <= 8 {
                    assert!(patch_visible(&k, c, pa, pb), "conservative {c:?} patch {pa},{pb}");
                } else {
                    proven += usize::from(!patch_visible(&k, c, pa, pb));
                    hidden += 1;
                }
            }
        }
    }
    // The proofs try a bounded number of grid lines, so a wall can slip between them for some
    // (cell, patch) pairs; most are proven.
    assert!(proven * 2 > hidden, "conservative culled {proven} of {hidden} hidden patches");
    assert_or_pyramid(&s);
    assert_or_pyramid(&k);
}

#[test]
fn a_flat_plain_hides_nothing() {
    let hm = grid(65, |_, _| 100.0);
    let (s, k, _) = bake_both(&hm, &small_cfg(4, 2, 5.0, 3));
    assert_eq!(s.culled_fraction(), 0.0);
    assert_eq!(k.culled_fraction(), 0.0);
}

#[test]
fn a_bowl_is_seen_whole_from_inside() {
    // A paraboloid bowl: convex, so every point of it sees every other point above it.
    let hm = grid(65, |i, j| {
        let (x, y) = (i as f32 - 32.0, j as f32 - 32.0);
        0.2 * (x * x + y * y)
    });
    let (s, k, _) = bake_both(&hm, &small_cfg(4, 1, 2.0, 3));
    for p in [&s, &k] {
        for (a, b) in [(1, 1), (2, 2), (1, 2)] {
            let c = CellId { a, b, k: 0 };
            assert!(p.level_image(c, 3).iter().all(|&v| v == 1), "{:?} {c:?}", p.mode);
        }
    }
}

/// A 129 x 129 crop of the Puget Sound 1k DEM (the Olympic mountains' east flank).
fn puget_crop() -> Heightmap {
    let opts = LoadOptions { vertical_scale: 0.1, spacing_m: 160.0, ..Default::default() };
    let hm = load(data("puget_sound/ps_height_1k.png"), &opts).unwrap().heightmap;
    let (x0, y0) = (700, 300);
    Heightmap::from_fn(129, 129, Georef::local(160.0), |i, j| hm.get(x0 + i, y0 + j)).unwrap()
}

#[test]
fn visibility_only_grows_with_height() {
    // Fig. 5, first property, for both lines of sight (the paper's Eq. 4 over the Bresenham
    // section line, and exact grid-line interpolation).
    let hm = puget_crop();
    let mip = HeightMip::new(&hm);
    let qt = Quadtree::new(&hm, 4);
    let exact = LineOfSight::new(&hm, &qt, 1e-3);
    let (mut seen, mut pairs) = (0, 0);
    for k in 0..400u32 {
        let (ex, ey) = (f64::from(k * 37 % 129), f64::from(k * 91 % 129));
        let (tx, ty) = ((k * 53 + 11) % 129, (k * 17 + 5) % 129);
        let t = dvec3(f64::from(tx), f64::from(ty), f64::from(hm.get(tx as usize, ty as usize)));
        let ground = f64::from(hm.sample_grid(ex, ey));
        let mut prev = (false, false);
        for dz in [2.0, 20.0, 80.0, 300.0, 1500.0] {
            let e = dvec3(ex, ey, ground + dz);
            let now = (los::visible(&mip, e, t, 1e-3), exact.grid_visible(e, t));
            assert!(now.0 || !prev.0, "Eq. 4: seen at a lower eye, hidden higher: {e} {t}");
            assert!(now.1 || !prev.1, "exact: seen at a lower eye, hidden higher: {e} {t}");
            prev = now;
            pairs += 1;
            seen += usize::from(now.1);
        }
    }
    // Both outcomes occur: the test is not vacuous.
    assert!(seen > pairs / 10 && seen < pairs, "{seen} of {pairs}");
}

/// A PVS is tied to the heights it was baked from (issue 15 item 7): the same grid size with
/// one sample changed, or one more void, does not match; the heights read back from the file
/// do.
#[test]
fn a_pvs_matches_only_the_heights_it_was_baked_from() {
    let hm = grid(65, |i, j| ((i * 7 + j * 3) % 23) as f32 * 4.0);
    let (s, _, _) = bake_both(&hm, &small_cfg(2, 2, 10.0, 3));
    let back = decode(&encode(&s), std::path::Path::new("pvs.bin")).unwrap();
    assert!(back.matches_heights(&hm));
    let edited =
        grid(65, |i, j| if (i, j) == (40, 20) { 1.0 } else { ((i * 7 + j * 3) % 23) as f32 * 4.0 });
    assert!(back.matches(Quadtree::new(&edited, 8).shape()));
    assert!(!back.matches_heights(&edited), "a PVS of other heights matched");
}

#[test]
fn the_file_round_trips_and_refuses_corruption() {
    let hm = grid(65, |i, j| ((i * 7 + j * 3) % 23) as f32 * 4.0);
    let (s, _, _) = bake_both(&hm, &small_cfg(2, 2, 10.0, 3));
    // Removed when dropped, also when the test panics.
    let tmp = tempfile::Builder::new().prefix("terrain-pvs-file-").tempdir().unwrap();
    let dir = tmp.path();
    let path = dir.join("pvs.bin");
    write_pvs(&s, &path).unwrap();
    assert_eq!(read_pvs(&path).unwrap(), s);

    let bytes = encode(&s);
    let mut flipped = bytes.clone();
    let mid = flipped.len() / 2;
    flipped[mid] ^= 0x10;
    std::fs::write(&path, &flipped).unwrap();
    let e = read_pvs(&path).unwrap_err();
    assert!(matches!(e, PvsFileError::Corrupt { .. }), "{e}");
    assert!(e.to_string().contains("pvs.bin") && e.to_string().contains("checksum"), "{e}");

    std::fs::write(&path, &bytes[..bytes.len() - 9]).unwrap();
    let e = read_pvs(&path).unwrap_err().to_string();
    assert!(e.contains("pvs.bin") && e.contains("truncated"), "{e}");
    let e = decode(&bytes[..20], &path).unwrap_err().to_string();
    assert!(e.contains("truncated"), "{e}");
    let e = decode(b"PNG\0 not a pvs file", &path).unwrap_err().to_string();
    assert!(e.contains("not a PVS file"), "{e}");
    let mut v3 = bytes.clone();
    v3[4] = 3;
    assert!(matches!(decode(&v3, &path), Err(PvsFileError::Version { found: 3, .. })));
    // A file of format 1 (no heights' checksum, written by earlier builds): refused, saying
    // it was baked by an older version and to bake again.
    let mut v1 = bytes.clone();
    v1[4] = 1;
    let e = decode(&v1, &path).unwrap_err().to_string();
    assert!(e.contains("pvs.bin") && e.contains("older version") && e.contains("bake"), "{e}");
    let e = read_pvs(&dir.join("missing.bin")).unwrap_err().to_string();
    assert!(e.contains("missing.bin"), "{e}");
}

/// Found by `cargo xtask fuzz`: header counts whose product overflows 64 bits (cells and
/// floors of 2^32 - 1 each) panicked with an arithmetic overflow while checking them, before
/// the checksum; they are refused as implausible.
#[test]
fn huge_header_counts_are_refused_without_overflow() {
    let hm = grid(33, |i, j| (i + j) as f32);
    let (s, _, _) = bake_both(&hm, &small_cfg(2, 1, 10.0, 2));
    let path = std::path::Path::new("pvs.bin");
    for field in [24usize, 28, 32] {
        let mut bytes = encode(&s);
        for f in [24usize, 28, 32] {
            let v: u32 = if f == field { u32::MAX } else { 0xFFFF_0000 };
            bytes[f..f + 4].copy_from_slice(&v.to_le_bytes());
        }
        let e = decode(&bytes, path).unwrap_err().to_string();
        assert!(e.contains("implausible header values"), "{e}");
    }
}

#[test]
fn the_proofs_do_not_change_the_papers_test_and_sampled_is_within_conservative() {
    let hm = FractalConfig::with_size(65, 65, 30.0).to_heightmap().unwrap();
    let cfg = small_cfg(4, 2, 15.0, 3);
    let (s, k, _) = bake_both(&hm, &cfg);
    let plain = bake_sampled_without_proofs(&hm, &cfg);
    let lay = &s.layout;
    let (mut differ, mut culled) = (0, 0);
    for n in 0..lay.cell_count() {
        let c = lay.cell_at_index(n);
        for b in 0..8 {
            for a in 0..8 {
                let (vs, vk, vp) = (
                    patch_visible(&s, c, a, b),
                    patch_visible(&k, c, a, b),
                    patch_visible(&plain, c, a, b),
                );
                assert!(!vs || vk, "{c:?} {a},{b}: sampled visible, conservative culled");
                // Proofs only ever remove patches the paper's test also finds hidden.
                assert!(!vs || vp, "{c:?} {a},{b}: visible only with proofs");
                differ += usize::from(vs != vp);
                culled += usize::from(!vp);
            }
        }
    }
    assert!(culled > 0, "nothing hidden: the terrain does not test anything");
    assert_eq!(differ, 0, "the proofs changed {differ} of the paper's results");
}

fn assert_conservative(hm: &Heightmap, cfg: &PvsConfig, cells: usize) {
    let (s, k, _) = bake_both(hm, cfg);
    let cells = sample_cells(&k, cells);
    let truth = TruthConfig { plan_viewpoints: 4, heights: 2, ..TruthConfig::default() };
    let counts = check(hm, &[&s, &k], &cells, &truth);
    let (cs, ck) = (counts[0], counts[1]);
    assert_eq!(ck.false_culls, 0, "conservative false culls: {ck:?}");
    assert!(ck.culled > 0, "the conservative mode culled nothing: {ck:?} (sampled {cs:?})");
    assert!(cs.culled >= ck.culled, "{cs:?} {ck:?}");
}

#[test]
fn the_conservative_mode_has_no_false_culls_on_a_real_crop() {
    assert_conservative(&puget_crop(), &small_cfg(4, 2, 40.0, 4), 6);
}

#[test]
fn the_conservative_mode_has_no_false_culls_on_the_fractal() {
    let hm = FractalConfig::with_size(129, 129, 30.0).to_heightmap().unwrap();
    assert_conservative(&hm, &small_cfg(4, 2, 20.0, 4), 6);
}

#[test]
fn the_cull_policy_drops_hidden_nodes_and_cell_other_drops_nothing() {
    let hm = grid(129, |i, _| if (63..=65).contains(&i) { 500.0 } else { 0.0 });
    let (_, k, _) = bake_both(&hm, &small_cfg(4, 1, 20.0, 4));
    // A small C1 splits far nodes too, so hidden ones exist apart from visible ones.
    let pcfg = PvpsConfig { leaf_cells: 4, c1: 2.0, ..PvpsConfig::default() };
    let qt = pcfg.quadtree(&hm);
    assert!(k.matches(qt.shape()));
    // West of the wall, 10 m up, looking east at it.
    let cam = Camera::from_yaw_pitch(dvec3(100.0, 640.0, 10.0), 0.0, -5.0);
    let mut cull = k.cull_for(cam.position);
    assert_eq!(cull.cell, Some(CellId { a: 0, b: 2, k: 0 }));
    let field = ConstantField(100.0);
    let culled = select_pvps_with_cull(&GridSource::new(&qt, &hm), &cam, &field, &pcfg, &mut cull);
    let plain = select_pvps(&GridSource::new(&qt, &hm), &cam, &field, &pcfg);
    let xs = |sel: &terrain_core::lod::Selection| {
        sel.patches.iter().map(|p| qt.node_plan_rect(p.node).unwrap().0.x).collect::<Vec<_>>()
    };
    assert!(culled.patches.len() < plain.patches.len(), "{:?} {:?}", xs(&culled), xs(&plain));
    let behind = |sel: &terrain_core::lod::Selection| {
        sel.patches.iter().filter(|p| qt.node_plan_rect(p.node).unwrap().0.x >= 72.0 * 10.0).count()
    };
    assert!(behind(&plain) > 0);
    assert_eq!(behind(&culled), 0);
    // Above every floor: Cell_other, no culling.
    let high = Camera::from_yaw_pitch(dvec3(100.0, 640.0, 900.0), 0.0, -30.0);
    let mut other = k.cull_for(high.position);
    assert_eq!(other.cell, None);
    let a = select_pvps_with_cull(&GridSource::new(&qt, &hm), &high, &field, &pcfg, &mut other);
    let b = select_pvps(&GridSource::new(&qt, &hm), &high, &field, &pcfg);
    assert_eq!(a.patches, b.patches);
}

#[test]
fn cells_floors_and_the_articles_layers() {
    // 129 x 129 samples of 10 m: the root square is 128 cells; a ramp from 0 to 128 m.
    let hm = grid(129, |i, _| i as f32);
    let lay = PvsLayout::new(&hm, &small_cfg(4, 3, 50.0, 4));
    assert_eq!((lay.root_cells, lay.cells_x, lay.floors), (128, 4, 3));
    // Cell column 1 spans x = 32..64 samples: heights 32..64 under it.
    let c = CellId { a: 1, b: 2, k: 0 };
    assert_eq!(lay.floor_bounds(c), Some((32.0, 114.0)));
    assert_eq!(lay.floor_bounds(CellId { k: 2, ..c }), Some((164.0, 214.0)));
    let at = |x: f64, z: f64| lay.locate(dvec3(x * 10.0, 700.0, z));
    assert_eq!(at(40.0, 60.0), Some(c));
    // Below the floor's bottom still reads floor 0 (visibility only shrinks downwards).
    assert_eq!(at(40.0, 10.0), Some(c));
    assert_eq!(at(40.0, 150.0), Some(CellId { k: 1, ..c }));
    assert_eq!(at(40.0, 300.0), None, "above the top floor: Cell_other");
    assert_eq!(at(-1.0, 60.0), None, "outside the grid: Cell_other");
    assert_eq!(at(129.0, 60.0), None);

    // The geomorphing article: cells on the 16 x 16 patch grid, 32 layers up to 3 reliefs.
    let art = PvsLayout::new(&hm, &PvsConfig::article(4));
    assert_eq!((art.cells_x, art.cells_y, art.floors, art.patches_per_side()), (16, 16, 32, 16));
    assert_eq!(art.cell_rect(3, 5), (glam::dvec2(24.0, 40.0), glam::dvec2(32.0, 48.0)));
    let top = art.floor_bounds(CellId { a: 3, b: 5, k: 31 }).unwrap().1;
    assert!((top - 3.0 * 128.0).abs() < 1e-9, "{top}");
    // One bit per patch and level: 341 bits, 43 bytes per cell (the article's 256 KB for the
    // finest level alone, 16 x 16 x 32 cells of 256 bits).
    assert_eq!((art.bits_per_cell(), art.bytes_per_cell()), (341, 43));
    assert_eq!(art.cell_count() * 256 / 8, 262_144);
}

#[test]
fn the_scaled_configuration_keeps_the_papers_patch_and_cell_sizes() {
    use terrain_visibility::pvs::{PAPER_PATCH_CELLS, cells_per_side};
    // The paper's 4096^2 DEM: exactly its configuration (64 x 64 patches, 32 x 32 x 3 cells).
    assert_eq!(PvsConfig::scaled(4097, 4097), PvsConfig::default());
    assert_eq!(PvsConfig::scaled(4096, 3000), PvsConfig::default());
    // Larger: still 64 x 64 patches (larger ones), as before.
    assert_eq!(PvsConfig::scaled(16385, 16385), PvsConfig::default());
    let at = |w, h| {
        let c = PvsConfig::scaled(w, h);
        (c.patch_level, c.cells.0, c.cells.1, c.floors)
    };
    // An SRTM tile: root 2048 cells, 32 patches of 64 cells under 16 x 16 cells.
    assert_eq!(at(1201, 1201), (5, 16, 16, 3));
    assert_eq!(at(1025, 1025), (4, 8, 8, 3));
    assert_eq!(at(429, 279), (3, 4, 4, 3));
    // Grids of one patch or less: one patch, one cell per floor.
    assert_eq!(at(65, 65), (0, 1, 1, 3));
    assert_eq!(at(2, 2), (0, 1, 1, 3));
    // Every size: patches of at least 64 cells (at most 64 per side), two patches a cell.
    for n in [2u32, 3, 64, 65, 66, 129, 600, 2049, 5000, 40000] {
        let c = PvsConfig::scaled(n, n);
        let lay = PvsLayout::new(&grid(n.min(700) as usize, |_, _| 0.0), &c);
        let root = terrain_visibility::pvs::root_cells(n, n);
        assert!(root >> c.patch_level >= PAPER_PATCH_CELLS.min(root), "{n}: {c:?}");
        assert!(c.patch_level <= 6 && c.cells.0 == cells_per_side(c.patch_level), "{n}");
        assert_eq!(cells_per_side(c.patch_level), ((1u32 << c.patch_level) / 2).max(1));
        assert!(lay.cell_count() >= 3);
    }
}

#[test]
fn spread_samples_take_the_middle_of_each_block() {
    use terrain_visibility::pvs::spread_sample;
    assert_eq!(spread_sample(8, 4, 4), vec![(2, 2), (6, 2)]);
    assert_eq!(spread_sample(1, 1, 4), vec![(0, 0)]);
    // A block cut by the edge keeps its cell inside the layout.
    assert_eq!(spread_sample(5, 2, 4), vec![(2, 1), (4, 1)]);
    assert_eq!(spread_sample(3, 3, 1).len(), 9);
}

#[test]
fn the_cull_estimate_of_a_sample_is_the_full_bakes_on_those_cells() {
    use terrain_visibility::pvs::{estimate_cull, spread_sample};
    let hm = puget_crop();
    let cfg = small_cfg(4, 2, 60.0, 4);
    let (s, c, _) = bake_both(&hm, &cfg);
    // Stride 1: every cell, so the whole bake's fractions.
    let all = estimate_cull(&hm, &cfg, 1);
    assert_eq!((all.plan_cells, all.plan_total), (16, 16));
    assert_eq!((all.sampled, all.conservative), (s.culled_fraction(), c.culled_fraction()));
    assert!(all.sampled > 0.0, "the crop hides something from some cell");
    // Stride 2: the same counts over the sampled cells of the full bake.
    let e = estimate_cull(&hm, &cfg, 2);
    let lay = &s.layout;
    let per = lay.bytes_per_cell();
    let (mut hidden, mut total) = (0, 0);
    for (a, b) in spread_sample(4, 4, 2) {
        for k in 0..2 {
            let n = lay.cell_index(CellId { a, b, k });
            if let Some((h, t)) =
                lay.hidden_patches(lay.cell_at_index(n), &s.bits[n * per..][..per])
            {
                (hidden, total) = (hidden + h, total + t);
            }
        }
    }
    assert_eq!(e.plan_cells, 4);
    assert_eq!(e.sampled, hidden as f64 / total as f64);
    // Negative control: another cell's bits count differently somewhere.
    assert_ne!(e.sampled, all.sampled, "the sample is not the whole");
}
