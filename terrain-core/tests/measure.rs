//! Exact error measurement against known answers: a plane, a single bump, a hidden valley
//! behind a wall (false culls by brute-force line of sight), popping and the stride.

use glam::{DVec3, dvec3};
use terrain_core::geometry::Camera;
use terrain_core::lod::surface::fan_tessellation;
use terrain_core::lod::{EdgeRule, Patch, Selection, build_surface, outer_factors};
use terrain_core::measure::{MeasureConfig, Measurer, measure_frame};
use terrain_core::quadtree::{LeafSet, NodeId, Quadtree, balance};
use terrain_core::{Georef, Heightmap};

/// Every existing node of `level`, factor `f` on every edge.
fn uniform(qt: &Quadtree, level: u8, f: f32) -> Selection {
    let n = 1u32 << level;
    let mut patches = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let node = NodeId::new(level, i, j);
            if qt.contains_node(node) {
                patches.push(Patch { node, outer: [f; 4], inner: [f; 2] });
            }
        }
    }
    patches.sort_by_key(|p| p.node.dfs_key());
    Selection { patches, ..Default::default() }
}

/// Refined towards the south-west corner and balanced, with matching edge factors.
fn mixed(qt: &Quadtree) -> Selection {
    struct Rule;
    impl EdgeRule for Rule {
        fn same_level(&self, _: NodeId, _: terrain_core::lod::Edge, _: NodeId) -> f32 {
            3.0
        }
        fn coarse_edge(&self, _: NodeId, _: terrain_core::lod::Edge, _: &[NodeId]) -> f32 {
            4.0
        }
        fn unshared(&self, _: NodeId, _: terrain_core::lod::Edge) -> f32 {
            2.0
        }
    }
    let deep = NodeId::new(qt.max_level(), 0, 0);
    let mut leaves = Vec::new();
    for l in 1..=qt.max_level() {
        for c in deep.ancestor(l - 1).children() {
            if qt.contains_node(c) && !c.is_ancestor_or_self_of(deep) || c == deep {
                leaves.push(c);
            }
        }
    }
    let leaves = balance(qt, &leaves);
    let set = LeafSet::new(leaves.iter().copied());
    let patches = leaves
        .iter()
        .map(|&n| Patch { node: n, outer: outer_factors(&set, n, &Rule), inner: [1.0; 2] })
        .collect();
    Selection { patches, ..Default::default() }
}

#[test]
fn a_plane_has_zero_error_for_any_selection() {
    // Heights exactly representable; every bilinear and barycentric value is the plane.
    let hm = Heightmap::from_fn(65, 49, Georef::local(2.0), |i, j| {
        100.0 + 0.5 * i as f32 + 0.25 * j as f32
    })
    .unwrap();
    let qt = Quadtree::new(&hm, 8);
    let cam = Camera::from_yaw_pitch(dvec3(64.0, -40.0, 200.0), 0.0, -50.0);
    for sel in [uniform(&qt, 0, 1.0), uniform(&qt, 2, 3.0), uniform(&qt, 3, 1.0), mixed(&qt)] {
        let mesh = build_surface(&hm, &qt, &sel, fan_tessellation);
        let e = measure_frame(&hm, &qt, &cam, &sel, &mesh, &MeasureConfig::default());
        assert!(e.samples > 1000, "{e:?}");
        assert_eq!((e.unlocated, e.culled_samples, e.false_culls, e.stride), (0, 0, 0, 1));
        assert_eq!(e.samples, e.frustum_samples);
        assert!(e.max_abs_m < 1e-4 && e.max_px < 1e-3, "{e:?}");
    }
}

#[test]
fn a_single_bump_has_the_pixel_error_lambda_h_over_d() {
    // Flat, one sample raised by h; the root patch with outer factor 1 has vertices only at
    // the corners and the centre (32, 32), so it draws z = 0 everywhere.
    let h = 5.0f32;
    let bump = (10usize, 20usize);
    let hm =
        Heightmap::from_fn(65, 65, Georef::local(1.0), |i, j| if (i, j) == bump { h } else { 0.0 })
            .unwrap();
    let qt = Quadtree::new(&hm, 64);
    let sel = uniform(&qt, 0, 1.0);
    let mesh = build_surface(&hm, &qt, &sel, fan_tessellation);
    let p = dvec3(10.0, 20.0, h as f64);
    let eye = dvec3(37.0, -15.0, 30.0);
    let cam = Camera::look_at(eye, p);
    let e = measure_frame(&hm, &qt, &cam, &sel, &mesh, &MeasureConfig::default());
    let expect = cam.lambda() * h as f64 / (p - eye).length();
    assert!(((e.max_px - expect) / expect).abs() < 1e-6, "{} vs {expect}", e.max_px);
    assert_eq!(e.max_abs_m, h as f64);
    assert_eq!(e.p99_px, 0.0); // one error among > 100 samples
    let n = e.samples as f64;
    assert!(n > 100.0);
    assert!((e.rmse_m - (h as f64 * h as f64 / n).sqrt()).abs() < 1e-12);
    assert!((e.mean_abs_m - h as f64 / n).abs() < 1e-12);
}

#[test]
fn popping_is_zero_for_identical_frames_and_the_shift_for_a_shifted_field() {
    let hm = Heightmap::from_fn(65, 65, Georef::local(1.0), |i, j| ((i * 7 + j * 3) % 5) as f32)
        .unwrap();
    let qt = Quadtree::new(&hm, 16);
    let sel = uniform(&qt, 1, 2.0);
    let mesh = build_surface(&hm, &qt, &sel, fan_tessellation);
    let cam = Camera::from_yaw_pitch(dvec3(32.0, -30.0, 60.0), 0.0, -40.0);
    let mut m = Measurer::new(&hm, &qt, MeasureConfig::default());
    let first = m.measure(&cam, &sel, &mesh);
    assert_eq!((first.popping_samples, first.rmse_change_m), (0, None));
    let same = m.measure(&cam, &sel, &mesh);
    assert_eq!(same.popping_samples, first.samples);
    assert_eq!((same.popping_rms_m, same.popping_max_m, same.rmse_change_m), (0.0, 0.0, Some(0.0)));
    // The drawn surface raised by 0.5 m: every delta changes by exactly 0.5.
    let mut up = mesh.clone();
    up.positions.iter_mut().for_each(|p| p.z += 0.5);
    let shifted = m.measure(&cam, &sel, &up);
    assert_eq!(shifted.popping_samples, first.samples);
    assert!(
        (shifted.popping_rms_m - 0.5).abs() < 1e-9 && (shifted.popping_max_m - 0.5).abs() < 1e-9
    );
    assert!((shifted.rmse_change_m.unwrap() - (shifted.rmse_m - first.rmse_m).abs()).abs() < 1e-15);
    assert!(shifted.rmse_m > first.rmse_m);
    // Only samples measured in both frames count: a narrower view shares fewer.
    m.reset();
    m.measure(&cam, &sel, &mesh);
    let narrow = m.measure(&cam.with_fov_y_deg(20.0), &sel, &up);
    assert!(narrow.popping_samples < first.samples && narrow.popping_samples == narrow.samples);
}

/// South plain at 0, a wall 200 m high on rows 28..=30, a hidden valley behind it, and a slope
/// rising from row 45 that shows again over the wall. 10 m spacing.
fn walled() -> Heightmap {
    Heightmap::from_fn(65, 65, Georef::local(10.0), |_, j| match j {
        28..=30 => 200.0,
        46.. => (j - 45) as f32 * 20.0,
        _ => 0.0,
    })
    .unwrap()
}

/// Terrain height on grid lines, as the line-of-sight definition says (independent code).
fn brute_visible(hm: &Heightmap, eye: DVec3, (ti, tj): (usize, usize), eps: f64) -> bool {
    let g = hm.world_to_grid(eye.truncate());
    let e = dvec3(g.x, g.y, eye.z);
    let t = dvec3(ti as f64, tj as f64, hm.get(ti, tj) as f64);
    let d = t - e;
    let h = |i: usize, j: usize| hm.get(i, j) as f64;
    for i in 0..hm.width() {
        if d.x == 0.0 {
            break;
        }
        let s = (i as f64 - e.x) / d.x;
        let y = e.y + s * d.y;
        if !(0.0..=1.0).contains(&s) || y < 0.0 || y > (hm.height() - 1) as f64 {
            continue;
        }
        let j0 = (y.floor() as usize).min(hm.height() - 2);
        let z = h(i, j0) + (h(i, j0 + 1) - h(i, j0)) * (y - j0 as f64);
        if z > e.z + s * d.z + eps {
            return false;
        }
    }
    for j in 0..hm.height() {
        if d.y == 0.0 {
            break;
        }
        let s = (j as f64 - e.y) / d.y;
        let x = e.x + s * d.x;
        if !(0.0..=1.0).contains(&s) || x < 0.0 || x > (hm.width() - 1) as f64 {
            continue;
        }
        let i0 = (x.floor() as usize).min(hm.width() - 2);
        let z = h(i0, j) + (h(i0 + 1, j) - h(i0, j)) * (x - i0 as f64);
        if z > e.z + s * d.z + eps {
            return false;
        }
    }
    true
}

/// In-frustum samples not covered by `sel` and visible by brute force.
fn expected_false_culls(
    hm: &Heightmap,
    qt: &Quadtree,
    cam: &Camera,
    sel: &Selection,
) -> (usize, usize) {
    let fr = cam.frustum();
    let (mut culled, mut visible) = (0, 0);
    for j in 0..hm.height() {
        for i in 0..hm.width() {
            let p = hm.grid_to_world(i as f64, j as f64).extend(hm.get(i, j) as f64);
            if !fr.contains_point(p) {
                continue;
            }
            let covered = sel.patches.iter().any(|pt| {
                let r = qt.clipped_rect(pt.node).unwrap();
                (r.x0 as usize..=r.x1 as usize).contains(&i)
                    && (r.y0 as usize..=r.y1 as usize).contains(&j)
            });
            if !covered {
                culled += 1;
                visible += brute_visible(hm, cam.position, (i, j), 1e-3) as usize;
            }
        }
    }
    (culled, visible)
}

#[test]
fn false_culls_behind_a_wall_match_brute_force() {
    let hm = walled();
    let qt = Quadtree::new(&hm, 8);
    let cam = Camera::from_yaw_pitch(dvec3(320.0, -100.0, 100.0), 0.0, -10.0);
    let full = uniform(&qt, 3, 2.0);
    let cfg = MeasureConfig::default();
    let measure = |sel: &Selection| {
        let mesh = build_surface(&hm, &qt, sel, fan_tessellation);
        measure_frame(&hm, &qt, &cam, sel, &mesh, &cfg)
    };
    let e = measure(&full);
    assert_eq!((e.culled_samples, e.false_culls, e.unlocated), (0, 0, 0));
    // Remove a visible patch in front of the wall, a hidden one in the valley, and one on
    // the far slope that shows over the wall.
    let without = |node: NodeId| {
        let mut s = full.clone();
        s.patches.retain(|p| p.node != node);
        s
    };
    let cases =
        [(NodeId::new(3, 4, 1), true), (NodeId::new(3, 4, 4), false), (NodeId::new(3, 4, 7), true)];
    for (node, any_visible) in cases {
        let sel = without(node);
        let e = measure(&sel);
        let (culled, visible) = expected_false_culls(&hm, &qt, &cam, &sel);
        assert!(culled > 0, "{node:?} is in view");
        assert_eq!((e.culled_samples, e.false_culls), (culled, visible), "{node:?}");
        eprintln!("{node:?}: {visible} of {culled} culled samples visible");
        assert_eq!(visible > 0, any_visible, "{node:?}: {visible} of {culled} visible");
    }
    // The far slope is only partly visible over the wall: line of sight really decides.
    let (culled, visible) = expected_false_culls(&hm, &qt, &cam, &without(NodeId::new(3, 4, 7)));
    assert!(0 < visible && visible < culled, "{visible} of {culled}");
}

#[test]
fn the_stride_thins_the_samples_and_is_reported() {
    let hm = walled();
    let qt = Quadtree::new(&hm, 8);
    let sel = uniform(&qt, 2, 4.0);
    let mesh = build_surface(&hm, &qt, &sel, fan_tessellation);
    let cam = Camera::from_yaw_pitch(dvec3(320.0, 320.0, 3000.0), 0.0, -90.0);
    let all = measure_frame(&hm, &qt, &cam, &sel, &mesh, &MeasureConfig::default());
    assert_eq!((all.stride, all.samples), (1, 65 * 65));
    let cfg = MeasureConfig { max_samples: 1000, ..Default::default() };
    let thin = measure_frame(&hm, &qt, &cam, &sel, &mesh, &cfg);
    // 65^2 = 4225 candidates: stride 3 gives ceil(4225 / 9) = 470 <= 1000 (stride 2: 1057).
    assert_eq!(thin.stride, 3);
    // One sample per 3 x 3 block: 21 x 21 whole blocks, plus the border blocks (two of three
    // rows or columns in the grid) whose hashed offset falls inside.
    assert!((21 * 21..=22 * 22).contains(&thin.samples), "{}", thin.samples);
    let fixed = measure_frame(&hm, &qt, &cam, &sel, &mesh, &MeasureConfig { stride: 8, ..cfg });
    assert_eq!(fixed.stride, 8);
    assert!((8 * 8..=9 * 9).contains(&fixed.samples), "{}", fixed.samples);
    // The selection's vertices lie every 4 samples (16-cell patches at factor 4), so an aligned
    // lattice of stride 8 would sit on vertices only and measure zero error. Stratified samples
    // fall between them and see the error the full measurement sees.
    assert!(all.max_abs_m > 0.0);
    assert!(fixed.max_abs_m > 0.0, "strided measurement biased to vertices: {fixed:?}");
    assert!(fixed.rmse_m > 0.25 * all.rmse_m, "{} vs {}", fixed.rmse_m, all.rmse_m);
}

#[test]
fn accelerated_line_of_sight_equals_brute_force_on_rough_terrain() {
    use terrain_core::measure::LineOfSight;
    let hm = Heightmap::from_fn(57, 45, Georef::local(5.0), |i, j| {
        let (x, y) = (i as f32 * 0.3, j as f32 * 0.25);
        40.0 * (x.sin() * y.cos()) + ((i * 31 + j * 17) % 13) as f32
    })
    .unwrap();
    for leaf in [1, 4, 16] {
        let qt = Quadtree::new(&hm, leaf);
        let los = LineOfSight::new(&hm, &qt, 1e-3);
        for eye in [dvec3(-20.0, 30.0, 45.0), dvec3(140.0, 100.0, 60.0), dvec3(100.0, 250.0, 20.0)]
        {
            let (mut vis, mut n) = (0, 0);
            for j in 0..hm.height() {
                for i in 0..hm.width() {
                    let b = brute_visible(&hm, eye, (i, j), 1e-3);
                    assert_eq!(
                        los.sample_visible(eye, i, j),
                        b,
                        "leaf {leaf} eye {eye} ({i}, {j})"
                    );
                    vis += b as usize;
                    n += 1;
                }
            }
            assert!(vis > n / 20 && vis < n * 19 / 20, "eye {eye}: {vis} of {n} visible");
        }
    }
}

#[test]
fn a_shipped_flight_on_the_default_terrain_measures_deterministically() {
    use terrain_core::flight::{FlightConfig, FlightSpec};
    let hm = terrain_core::synth::default_terrain();
    let qt = Quadtree::new(&hm, 32);
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../flights/pvps_884.json");
    let (flight, _) = FlightSpec::load(path).unwrap().resolve(&hm, &FlightConfig::default());
    let sel = uniform(&qt, 4, 8.0);
    let mesh = build_surface(&hm, &qt, &sel, fan_tessellation);
    let run = || {
        let mut m = Measurer::new(&hm, &qt, MeasureConfig::default());
        let t = std::time::Instant::now();
        let v: Vec<_> = flight.frames()[..3].iter().map(|c| m.measure(c, &sel, &mesh)).collect();
        eprintln!("3 frames in {:?}: {:?}", t.elapsed(), v[1]);
        v
    };
    let (a, b) = (run(), run());
    assert_eq!(a, b);
    for e in &a {
        assert!(e.samples > 10_000 && e.unlocated == 0 && e.culled_samples == 0, "{e:?}");
        assert!(e.rmse_m > 0.0 && e.max_px >= e.p99_px && e.p99_px > 0.0, "{e:?}");
    }
    assert!(a[1].popping_samples > 0 && a[1].rmse_change_m.is_some());
}
