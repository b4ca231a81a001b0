//! Curvature entropy and the entropy quadtree (the entropy paper, Chen 2018): exact values on
//! the hard cases, the sliding-window entropy against Eq. 1-3 evaluated directly, watertight
//! meshes (no crack, no T-junction) on synthetic and real DEMs and on scattered points, and the
//! view-dependent cut (Eq. 4-5).

mod common;

use common::data;

use glam::{DVec2, DVec3, dvec3};
use terrain_core::dem::{LoadOptions, load};
use terrain_core::synth::{FractalConfig, HardCase};
use terrain_core::{Georef, Heightmap, VoidMask};
use terrain_visibility::entropy::compare::compare_curvature_entropy;
use terrain_visibility::entropy::local::{
    class_of, class_range, entropy_of_classes, local_entropy_with_range,
};
use terrain_visibility::entropy::quadtree::WatertightError;
use terrain_visibility::entropy::source::{build_from_grid_with_map, entropy_map, grid_depth_cap};
use terrain_visibility::entropy::{
    EntropyConfig, EntropyError, EntropyQuadtree, FocusThreshold, Interpolation, MAX_DEPTH,
    ScalarMap, ScatteredPoints, TreeConfig, ViewThreshold, build_from_grid, build_from_points,
    local_entropy, profile_curvature,
};

/// A `size x size` crop of a heightmap starting at `(i0, j0)`, voids kept.
fn crop(hm: &Heightmap, i0: usize, j0: usize, size: usize) -> Heightmap {
    let mut voids = VoidMask::new(size, size);
    let mut data = Vec::with_capacity(size * size);
    for j in 0..size {
        for i in 0..size {
            data.push(hm.get(i0 + i, j0 + j));
            voids.set(i, j, hm.voids().get(i0 + i, j0 + j));
        }
    }
    let g = hm.georef().offset_samples(i0 as f64, j0 as f64);
    Heightmap::new(size, size, data, voids, g).expect("a crop of a valid heightmap")
}

fn puget_crop(size: usize) -> Heightmap {
    let opts = LoadOptions { vertical_scale: 0.1, spacing_m: 160.0, ..LoadOptions::default() };
    let hm = load(data("puget_sound/ps_height_1k.png"), &opts).expect("Puget Sound").heightmap;
    crop(&hm, 384, 384, size)
}

fn fractal(size: usize) -> Heightmap {
    FractalConfig::with_size(size as u64, size as u64, 10.0).to_heightmap().expect("fractal")
}

/// Build, eliminate cracks, mesh, and check watertightness.
fn watertight(tree: &mut EntropyQuadtree) -> terrain_visibility::entropy::EntropyMesh {
    let mesh = tree.mesh();
    mesh.check_watertight(tree.lattice.depth).expect("watertight");
    mesh
}

#[test]
fn flat_terrain_has_zero_curvature_and_zero_entropy_and_one_tile() {
    let hm = HardCase::Flat.build();
    let curv = profile_curvature(&hm);
    assert!(curv.values().iter().all(|&v| v == 0.0), "flat curvature must be exactly 0");
    let ent = local_entropy(&curv, &EntropyConfig::default());
    assert!(ent.values().iter().all(|&v| v == 0.0), "flat entropy must be exactly 0 (no NaN)");
    for e0 in [0.0, 10.0] {
        let mut tree = build_from_grid(&hm, &TreeConfig { e0, ..TreeConfig::default() }).unwrap();
        assert_eq!(tree.tiles(), 1, "E0 = {e0}: nothing to refine on flat terrain");
        let mesh = watertight(&mut tree);
        assert_eq!(mesh.triangles.len(), 2);
        assert!(mesh.positions.iter().all(|p| p.z == f64::from(HardCase::FLAT_HEIGHT)));
    }
}

#[test]
fn a_tilted_plane_has_zero_curvature_up_to_the_border() {
    let hm = Heightmap::from_fn(33, 21, Georef::local(10.0), |i, j| {
        (3.0 * i as f64 - 2.0 * j as f64 + 50.0) as f32
    })
    .unwrap();
    let curv = profile_curvature(&hm);
    for (k, v) in curv.values().iter().enumerate() {
        assert!(v.abs() < 1e-4, "sample {k}: plane curvature {v}");
    }
}

#[test]
fn curvature_of_a_paraboloid_matches_zevenbergen_thorne() {
    // z = x² / 2 along x (spacing 1): profile curvature along the slope direction is
    // -2 D G² / G² · 100 = -2 · (1/2 · 2 / 2)... evaluated: D = ((z4+z6)/2 - z5) = 0.5,
    // so the profile curvature is -2 · 0.5 · 100 = -100 wherever G != 0.
    let hm = Heightmap::from_fn(9, 5, Georef::local(1.0), |i, _| {
        let x = i as f64 - 2.0; // slope never 0 on interior samples i >= 3
        (0.5 * x * x) as f32
    })
    .unwrap();
    let curv = profile_curvature(&hm);
    for i in 3..8 {
        let v = curv.get(i, 2).unwrap();
        assert!((v + 100.0).abs() < 1e-3, "column {i}: {v}");
    }
    // At the vertex of the parabola (i = 2) the slope is 0: curvature defined as 0.
    assert_eq!(curv.get(2, 2), Some(0.0));
}

#[test]
fn spike_and_cliff_entropy_is_confined_to_the_feature() {
    let cfg = EntropyConfig { radius: 2, ..EntropyConfig::default() };
    let spike = HardCase::Spike.build();
    let (si, sj) = HardCase::SPIKE_POS;
    let curv = profile_curvature(&spike);
    let ent = local_entropy(&curv, &cfg);
    // Curvature is non-zero only within one sample of the spike.
    for j in 0..65usize {
        for i in 0..65usize {
            let near = i.abs_diff(si) <= 1 && j.abs_diff(sj) <= 1;
            let c = curv.get(i, j).unwrap();
            if !near {
                assert_eq!(c, 0.0, "curvature at ({i}, {j})");
            }
            // Entropy only where the window (radius 2) sees a non-zero curvature.
            let sees = i.abs_diff(si) <= 3 && j.abs_diff(sj) <= 3;
            let e = ent.get(i, j).unwrap();
            assert!(e.is_finite() && e >= 0.0);
            if !sees {
                assert_eq!(e, 0.0, "entropy at ({i}, {j})");
            }
        }
    }
    assert!(ent.get(si, sj).unwrap() > 0.5);
    // Cliff: entropy is zero away from the step and positive next to it.
    let cliff = HardCase::Cliff.build();
    let ent = local_entropy(&profile_curvature(&cliff), &cfg);
    let col = HardCase::CLIFF_COLUMN;
    for j in 0..65 {
        assert_eq!(ent.get(col - 6, j), Some(0.0));
        assert_eq!(ent.get(col + 6, j), Some(0.0));
    }
    assert!(ent.get(col, 32).unwrap() > 0.0);
    // The tree refines only along the cliff.
    let cfgt = TreeConfig { e0: 1.0, max_depth: 6, ..TreeConfig::default() };
    let mut tree = build_from_grid(&cliff, &cfgt).unwrap();
    assert_eq!(tree.depth_reached(), 6);
    let mesh = watertight(&mut tree);
    assert!(tree.tiles() < 4096 / 4, "{} tiles", tree.tiles());
    // The mesh holds the cliff's exact heights at its vertices.
    for (p, l) in mesh.positions.iter().zip(&mesh.lattice) {
        let want = if l[0] as usize >= col { HardCase::CLIFF_HIGH } else { HardCase::CLIFF_LOW };
        assert_eq!(p.z, f64::from(want));
    }
}

/// Sliding-window entropy equals Eq. 1-3 evaluated window by window, at borders and around
/// voids (void samples left out of the histograms).
#[test]
fn sliding_entropy_equals_equations_1_to_3_with_voids_and_borders() {
    let hm = HardCase::PlateauWithVoids.build();
    let fr = fractal(65);
    // Plateau geometry plus fractal texture, voids of the plateau case.
    let (w, h) = (65, 65);
    let mut data = Vec::new();
    for j in 0..h {
        for i in 0..w {
            data.push(hm.get(i, j) + fr.get(i, j) * 0.05);
        }
    }
    let hm = Heightmap::new(w, h, data, hm.voids().clone(), hm.georef().clone()).unwrap();
    let curv = profile_curvature(&hm);
    for cfg in [
        EntropyConfig { radius: 1, classes: 8, clip_percentile: 0.9 },
        EntropyConfig { radius: 3, classes: 32, clip_percentile: 0.98 },
    ] {
        let c = class_range(&curv, &cfg);
        let ent = local_entropy_with_range(&curv, &cfg, c);
        let r = cfg.radius as i64;
        for j in 0..h {
            for i in 0..w {
                if hm.voids().get(i, j) {
                    assert_eq!(curv.get(i, j), None);
                    assert_eq!(ent.get(i, j), None, "void ({i}, {j}) has no entropy");
                    continue;
                }
                let mut classes = Vec::new();
                for y in (j as i64 - r).max(0)..=(j as i64 + r).min(h as i64 - 1) {
                    for x in (i as i64 - r).max(0)..=(i as i64 + r).min(w as i64 - 1) {
                        if let Some(v) = curv.get(x as usize, y as usize) {
                            classes.push(class_of(v, c, cfg.classes));
                        }
                    }
                }
                let want = entropy_of_classes(&classes);
                let got = f64::from(ent.get(i, j).unwrap());
                assert!((got - want).abs() < 1e-5, "({i}, {j}): {got} vs {want}");
                assert!(got <= cfg.max_entropy_bits() + 1e-9);
            }
        }
    }
}

#[test]
fn entropy_of_classes_is_eq_3() {
    assert_eq!(entropy_of_classes(&[3, 3, 3, 3]), 0.0);
    assert_eq!(entropy_of_classes(&[0, 1]), 1.0);
    assert_eq!(entropy_of_classes(&[0, 1, 2, 3]), 2.0);
    let e = entropy_of_classes(&[0, 0, 0, 1]);
    let want = -(0.75f64 * 0.75f64.log2() + 0.25 * 0.25f64.log2());
    assert!((e - want).abs() < 1e-12);
}

#[test]
fn without_crack_elimination_the_mesh_has_cracks_and_with_it_none() {
    let hm = fractal(129);
    let cfg = TreeConfig { e0: 30.0, max_depth: 7, ..TreeConfig::default() };
    let tree = build_from_grid(&hm, &cfg).unwrap();
    assert!(tree.depth_reached() >= 3 && tree.tiles() < 4usize.pow(7), "an adaptive tree");
    let raw = tree.triangulate();
    match raw.check_watertight(tree.lattice.depth) {
        Err(WatertightError::OpenInterior(_)) | Err(WatertightError::TJunction { .. }) => {}
        other => panic!("expected cracks before the update, got {other:?}"),
    }
    let mut tree = tree;
    let t = tree.eliminate_cracks();
    assert!(t >= 0.0);
    let mesh = tree.triangulate();
    mesh.check_watertight(tree.lattice.depth).unwrap();
    // Some tiles needed the constrained triangulation (more than 2 triangles per tile).
    assert!(mesh.triangles.len() > 2 * tree.tiles());
}

#[test]
fn real_dem_meshes_are_watertight_for_every_threshold_and_vertices_are_samples() {
    let hm = puget_crop(257);
    let cfg = TreeConfig::default();
    let emap = entropy_map(&hm, &cfg);
    let (lo, hi) = emap.range().unwrap();
    assert!(lo >= 0.0 && hi <= 100.0 + 1e-3, "percent scale: {lo}..{hi}");
    let mut tiles = Vec::new();
    for e0 in [0.0, 10.0, 14.0, 18.0, f64::from(hi) + 1.0] {
        let mut tree = build_from_grid_with_map(&hm, &emap, &TreeConfig { e0, ..cfg.clone() });
        let mesh = watertight(&mut tree);
        for (p, q) in mesh.positions.iter().zip(&mesh.plan) {
            assert_eq!(q.x.fract(), 0.0);
            assert_eq!(p.z, f64::from(hm.get(q.x as usize, q.y as usize)));
        }
        tiles.push(tree.tiles());
    }
    // E0 = 0 refines everywhere with entropy (all of a real DEM): the full tree.
    assert_eq!(tiles[0], 4usize.pow(8));
    // Raising E0 never adds tiles; above the largest entropy only the root is left.
    assert!(tiles.windows(2).all(|w| w[1] <= w[0]), "{tiles:?}");
    assert_eq!(*tiles.last().unwrap(), 1);
}

#[test]
fn srtm_with_voids_and_odd_size() {
    let hm = load(data("srtm/mt_rainier_90m.tif"), &LoadOptions::default()).unwrap().heightmap;
    assert!(hm.voids().any());
    // A crop around voids; 200 x 200 is not 2^k + 1: lattice lines snap to samples.
    let (mut vi, mut vj) = (0, 0);
    'find: for j in 0..hm.height() {
        for i in 0..hm.width() {
            if hm.voids().get(i, j) {
                (vi, vj) = (i, j);
                break 'find;
            }
        }
    }
    let i0 = vi.saturating_sub(100).min(hm.width() - 200);
    let j0 = vj.saturating_sub(100).min(hm.height() - 200);
    let hm = crop(&hm, i0, j0, 200);
    assert!(hm.voids().any());
    let cfg = TreeConfig { e0: 12.0, ..TreeConfig::default() };
    let emap = entropy_map(&hm, &cfg);
    for j in 0..200 {
        for i in 0..200 {
            assert_eq!(emap.get(i, j).is_none(), hm.voids().get(i, j));
        }
    }
    let mut tree = build_from_grid(&hm, &cfg).unwrap();
    assert_eq!(tree.lattice.depth, 7, "floor(log2(199))");
    let mesh = watertight(&mut tree);
    let surface = mesh.to_surface(|p| p);
    assert!(surface.open_edges().iter().all(|e| {
        let [a, b] = e.map(|k| surface.grid[k as usize]);
        (a.x == b.x && (a.x == 0.0 || a.x == 199.0)) || (a.y == b.y && (a.y == 0.0 || a.y == 199.0))
    }));
    let tri = mesh.to_trimesh();
    let stats = terrain_core::mesh::verify::measure(&hm, &tri).unwrap();
    assert!(stats.max_error.is_finite() && stats.rms_error <= stats.max_error);
}

#[test]
fn depth_zero_and_maximum_and_thresholds() {
    let hm = fractal(65);
    let d0 = TreeConfig { e0: 0.0, max_depth: 0, ..TreeConfig::default() };
    let mut tree = build_from_grid(&hm, &d0).unwrap();
    assert_eq!(tree.tiles(), 1);
    assert_eq!(watertight(&mut tree).triangles.len(), 2);
    let dmax = TreeConfig { e0: 0.0, max_depth: MAX_DEPTH, ..TreeConfig::default() };
    let mut tree = build_from_grid(&hm, &dmax).unwrap();
    assert_eq!(grid_depth_cap(&hm), 6);
    assert_eq!(tree.lattice.depth, 6, "capped at the grid's depth");
    assert_eq!(tree.tiles(), 4096);
    assert_eq!(watertight(&mut tree).triangles.len(), 2 * 4096, "every sample a vertex");
    let too_deep = TreeConfig { max_depth: MAX_DEPTH + 1, ..TreeConfig::default() };
    assert_eq!(build_from_grid(&hm, &too_deep).unwrap_err(), EntropyError::DepthTooLarge(17));
    let nan = TreeConfig { e0: f64::NAN, ..TreeConfig::default() };
    assert_eq!(build_from_grid(&hm, &nan).unwrap_err(), EntropyError::ThresholdNan);
    // Every node stores its maxE, and a parent's is the max of its children's.
    for n in &tree.nodes {
        if let Some(c) = n.children {
            let m = (0..4).map(|k| tree.nodes[(c + k) as usize].max_e).fold(0.0, f32::max);
            assert_eq!(n.max_e, m);
        }
    }
}

fn scattered_from(hm: &Heightmap, n: usize, seed: u64) -> Vec<DVec3> {
    // A small deterministic LCG: positions anywhere in the grid, heights bilinear.
    let mut s = seed;
    let mut next = || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let (w, h) = ((hm.width() - 1) as f64, (hm.height() - 1) as f64);
    (0..n)
        .map(|_| {
            let (u, v) = (next() * w, next() * h);
            let p = hm.grid_to_world(u, v);
            dvec3(p.x, p.y, f64::from(hm.sample_grid(u, v)))
        })
        .collect()
}

#[test]
fn scattered_points_idw_and_natural_neighbour_trees_are_watertight() {
    let hm = puget_crop(129);
    let pts = scattered_from(&hm, 6000, 7);
    for interp in [Interpolation::IDW, Interpolation::NaturalNeighbour] {
        let src = ScatteredPoints::new(pts.clone(), interp).unwrap();
        // Exact at the input points.
        for p in pts.iter().take(50) {
            let z = src.height(p.truncate());
            assert!((z - p.z).abs() < 1e-6, "{interp:?}: {z} vs {}", p.z);
        }
        let cfg =
            TreeConfig { e0: 12.0, max_depth: 7, interpolation: interp, ..Default::default() };
        let mut built = build_from_points(&src, &cfg).unwrap();
        assert_eq!(built.raster.width(), 129);
        let mesh = watertight(&mut built.tree);
        assert!(built.tree.tiles() > 1);
        // Heights stay within the data's range (both interpolations are convex combinations).
        let (lo, hi) = (f64::from(hm.min()) - 1e-6, f64::from(hm.max()) + 1e-6);
        assert!(mesh.positions.iter().all(|p| p.z >= lo && p.z <= hi));
    }
}

#[test]
fn duplicate_and_collinear_scattered_points() {
    // Duplicates: merged into their mean height.
    let pts = vec![
        dvec3(0.0, 0.0, 1.0),
        dvec3(0.0, 0.0, 3.0),
        dvec3(10.0, 0.0, 0.0),
        dvec3(0.0, 10.0, 0.0),
        dvec3(10.0, 10.0, 0.0),
    ];
    for interp in [Interpolation::IDW, Interpolation::NaturalNeighbour] {
        let src = ScatteredPoints::new(pts.clone(), interp).unwrap();
        assert_eq!(src.duplicates, 1);
        assert_eq!(src.points().len(), 4);
        assert!((src.height(DVec2::ZERO) - 2.0).abs() < 1e-12);
    }
    // Collinear along a diagonal: IDW works, natural neighbour has no triangulation.
    let line: Vec<DVec3> = (0..10).map(|k| dvec3(k as f64, 2.0 * k as f64, k as f64)).collect();
    assert_eq!(
        ScatteredPoints::new(line.clone(), Interpolation::NaturalNeighbour).unwrap_err(),
        EntropyError::Collinear
    );
    let src = ScatteredPoints::new(line, Interpolation::IDW).unwrap();
    let cfg = TreeConfig {
        e0: 0.0,
        max_depth: 3,
        interpolation: Interpolation::IDW,
        ..Default::default()
    };
    let mut built = build_from_points(&src, &cfg).unwrap();
    watertight(&mut built.tree);
    // Collinear along an axis: no area at all.
    let flat_line: Vec<DVec3> = (0..10).map(|k| dvec3(k as f64, 5.0, 0.0)).collect();
    assert!(matches!(
        ScatteredPoints::new(flat_line, Interpolation::IDW).unwrap_err(),
        EntropyError::DegenerateBounds(_, y) if y == 0.0
    ));
    // All duplicates of one position.
    let same = vec![dvec3(1.0, 1.0, 1.0); 5];
    assert_eq!(
        ScatteredPoints::new(same, Interpolation::IDW).unwrap_err(),
        EntropyError::TooFewPoints(1)
    );
    let nan = vec![dvec3(0.0, 0.0, 0.0), dvec3(1.0, f64::NAN, 0.0), dvec3(0.0, 1.0, 0.0)];
    assert_eq!(
        ScatteredPoints::new(nan, Interpolation::IDW).unwrap_err(),
        EntropyError::NonFinite(1)
    );
}

#[test]
fn visual_centre_follows_equation_4() {
    let eye = dvec3(100.0, 200.0, 1000.0);
    // Straight down: O is the foot V2 (= V1).
    let o = ViewThreshold::visual_centre(eye, dvec3(0.0, 0.0, -1.0), 0.0);
    assert!((o - dvec3(100.0, 200.0, 0.0)).length() < 1e-9);
    // 45 degrees down towards +x: V1 = (1100, 200), cos α = √2/2.
    let o = ViewThreshold::visual_centre(eye, dvec3(1.0, 0.0, -1.0), 0.0);
    let c = std::f64::consts::FRAC_1_SQRT_2;
    let want = dvec3(100.0, 200.0, 0.0) * (1.0 - c) + dvec3(1100.0, 200.0, 0.0) * c;
    assert!((o - want).length() < 1e-9, "{o} vs {want}");
    // Horizontal or upward sight: O = V2.
    let o = ViewThreshold::visual_centre(eye, dvec3(1.0, 0.0, 0.2), 0.0);
    assert!((o - dvec3(100.0, 200.0, 0.0)).length() < 1e-9);
    // Eq. 5.
    let v = ViewThreshold { e0: 5.0, c1: 0.01, c2: 0.001, centre: dvec3(0.0, 0.0, 0.0), eye };
    let d = eye.length();
    assert!(
        (v.threshold(DVec2::new(300.0, 400.0)) - (5.0 + 0.01 * 500.0 + 0.001 * d)).abs() < 1e-9
    );
}

#[test]
fn view_dependent_cut_coarsens_far_tiles_and_stays_watertight() {
    let hm = puget_crop(257);
    let cfg = TreeConfig { e0: 0.0, ..TreeConfig::default() };
    let tree = build_from_grid(&hm, &cfg).unwrap();
    let full = tree.tiles();
    // Eye above the south-west corner looking north-east and down.
    let origin = hm.grid_to_world(0.0, 0.0);
    let eye = dvec3(origin.x, origin.y, 3000.0);
    let centre = ViewThreshold::visual_centre(eye, dvec3(1.0, 1.0, -1.0), 0.0);
    let view = ViewThreshold { e0: 0.0, c1: 0.004, c2: 0.0, centre, eye };
    let mut cut = tree.schedule(&view);
    assert!(cut.tiles() < full, "{} of {full}", cut.tiles());
    watertight(&mut cut);
    // Tiles near O are finer than tiles far from it.
    let leaves: Vec<_> = cut.nodes.iter().filter(|n| n.children.is_none()).collect();
    let level_at = |p: DVec2| {
        leaves
            .iter()
            .filter(|n| {
                let s = 1u32 << (cut.lattice.depth - n.level);
                let a = cut.lattice.world(cut.lattice.plan(n.i * s, n.j * s));
                let b = cut.lattice.world(cut.lattice.plan(n.i * s + s, n.j * s + s));
                p.x >= a.x && p.x <= b.x && p.y >= a.y && p.y <= b.y
            })
            .map(|n| n.level)
            .max()
            .unwrap()
    };
    let far = hm.grid_to_world(256.0, 256.0);
    assert!(level_at(centre.truncate()) > level_at(far));
    // c1 = c2 = 0 and the same E0 is the tree itself.
    let same = tree.schedule(&ViewThreshold { c1: 0.0, ..view });
    assert_eq!(same.tiles(), full);
}

/// The static scheduling with several focuses (the paper's Fig. 13): every leaf of the initial
/// tree that holds a focus is kept, tiles coarsen away from the focuses, the cut is watertight
/// and has fewer tiles; one focus is Eq. 5's cut with the eye term off and the focus as centre.
#[test]
fn focus_scheduling_keeps_the_focus_areas_and_coarsens_elsewhere() {
    let hm = puget_crop(257);
    let cfg = TreeConfig { e0: 10.0, ..TreeConfig::default() };
    let tree = build_from_grid(&hm, &cfg).unwrap();
    let full = tree.tiles();
    let foci: Vec<DVec2> = [(64.0, 64.0), (192.0, 64.0), (64.0, 192.0), (192.0, 192.0)]
        .iter()
        .map(|&(i, j)| hm.grid_to_world(i, j))
        .collect();
    let focus = FocusThreshold { e0: 10.0, c1: 0.01, foci: foci.clone() };
    let mut cut = tree.schedule_by(|lo, hi| focus.threshold_tile(lo, hi));
    assert!(cut.tiles() < full / 2, "{} of {full}", cut.tiles());
    watertight(&mut cut);
    // The leaves holding a focus, in the initial tree and in the cut, are the same tiles.
    for f in &foci {
        assert_eq!(cut.leaves_at(*f), tree.leaves_at(*f), "at focus {f}");
    }
    // Halfway between the focuses (the centre of the grid) tiles are coarser than at a focus.
    let mid = hm.grid_to_world(128.0, 128.0);
    let deepest = |t: &EntropyQuadtree, p| t.leaves_at(p).iter().map(|n| n.0).max().unwrap();
    assert!(deepest(&cut, mid) < deepest(&tree, mid), "the middle was not coarsened");
    // Negative control: without distance cost the cut is the initial tree.
    let flat = FocusThreshold { c1: 0.0, ..focus.clone() };
    assert_eq!(tree.schedule_by(|lo, hi| flat.threshold_tile(lo, hi)).tiles(), full);
    // One focus is Eq. 5 with c2 = 0 centred on it.
    let one = FocusThreshold { foci: vec![foci[0]], ..focus };
    let eye = dvec3(foci[0].x, foci[0].y, 5000.0);
    let view =
        ViewThreshold { e0: 10.0, c1: 0.01, c2: 0.0, centre: eye.truncate().extend(0.0), eye };
    assert_eq!(
        tree.schedule_by(|lo, hi| one.threshold_tile(lo, hi)).tiles(),
        tree.schedule(&view).tiles()
    );
}

#[test]
fn entropy_is_smoother_than_curvature_on_a_real_dem_but_not_less_noise_sensitive() {
    let hm = puget_crop(257);
    let r = compare_curvature_entropy(&hm, &EntropyConfig::default(), 20, 0.5);
    // Fig. 3c: curvature's histogram is one spike, entropy's is spread out.
    assert!(r.entropy.peak_share < 0.5 * r.curvature.peak_share, "{r:?}");
    // Smoother: neighbours differ by a much smaller part of the map's spread.
    assert!(r.entropy.relative_neighbour_diff() < 0.5 * r.curvature.relative_neighbour_diff());
    assert!(r.entropy.mean_neighbour_diff < r.curvature.mean_neighbour_diff, "{r:?}");
    // Not less sensitive to height noise, though: half a metre of noise moves samples across
    // class boundaries, and entropy changes by a larger share of its spread than curvature.
    // The paper's "reduced sensitivity" holds for the spatial sense above, not for noise.
    assert!(r.entropy.relative_sensitivity() > r.curvature.relative_sensitivity(), "{r:?}");
}

#[test]
fn scalar_map_reports_none_for_nan() {
    let m = ScalarMap::new(2, 1, vec![1.0, f32::NAN]);
    assert_eq!(m.get(0, 0), Some(1.0));
    assert_eq!(m.get(1, 0), None);
    assert_eq!(m.range(), Some((1.0, 1.0)));
}

/// Every node's `maxE` is the largest entropy over the samples of its closed tile (brute
/// force), on a grid whose size is not `2^k + 1` (snapped lattice lines).
#[test]
fn node_max_entropy_equals_brute_force_over_the_tile() {
    let hm = crop(&puget_crop(257), 0, 0, 150);
    let cfg = TreeConfig { e0: 0.0, max_depth: 7, ..TreeConfig::default() };
    let emap = entropy_map(&hm, &cfg);
    let tree = build_from_grid_with_map(&hm, &emap, &cfg);
    assert_eq!(tree.lattice.depth, 7);
    for n in &tree.nodes {
        let s = 1u32 << (tree.lattice.depth - n.level);
        let lo = tree.lattice.plan(n.i * s, n.j * s);
        let hi = tree.lattice.plan(n.i * s + s, n.j * s + s);
        let mut m = 0.0f32;
        for j in lo.y as usize..=hi.y as usize {
            for i in lo.x as usize..=hi.x as usize {
                m = m.max(emap.get(i, j).unwrap_or(0.0));
            }
        }
        assert_eq!(n.max_e, m, "node {:?}", (n.level, n.i, n.j));
    }
}
