//! Integration tests of `geometry` and `quadtree`: traversal counts, frustum-culled
//! selections, neighbours across levels, the balanced post-pass (property test), and
//! camera-relative f32 precision at a projected origin of 500 km E / 4000 km N / 3000 m.

use std::collections::HashSet;

use glam::{DVec2, DVec3, DVec4, Vec4, dvec2, dvec3};
use proptest::prelude::*;
use terrain_core::geometry::{Aabb, Camera, Classification, project_view_to_ground};
use terrain_core::quadtree::{
    AlwaysSplit, BoundingCircleCull, Cull, Direction, FrustumCull, LeafSet, NoCull, NodeId,
    NodeInfo, Quadtree, SplitToLevel, Visit, balance, is_balanced, select, traverse,
};
use terrain_core::{Crs, Georef, Heightmap};

/// A smooth synthetic terrain, heights quantised to 1/8 m (exact in f32 even after +3000).
fn terrain(w: usize, h: usize, origin: DVec2, base: f32, spacing: f64) -> Heightmap {
    let g = Georef::projected(Crs::Epsg(32611), origin, dvec2(spacing, spacing));
    Heightmap::from_fn(w, h, g, |i, j| {
        let (x, y) = (i as f32 * 0.05, j as f32 * 0.07);
        let z = 200.0 + 120.0 * x.sin() * y.cos() + 40.0 * (0.3 * x + 0.2 * y).sin();
        base + (z * 8.0).round() / 8.0
    })
    .unwrap()
}

/// Total cell area of a selection, from the clipped rectangles.
fn cell_area(qt: &Quadtree, leaves: &[NodeId]) -> u64 {
    leaves
        .iter()
        .map(|&n| {
            let r = qt.clipped_rect(n).unwrap();
            ((r.x1 - r.x0).max(1) as u64) * ((r.y1 - r.y0).max(1) as u64)
        })
        .sum()
}

fn assert_disjoint(leaves: &[NodeId]) {
    let set: HashSet<NodeId> = leaves.iter().copied().collect();
    assert_eq!(set.len(), leaves.len(), "duplicate leaves");
    for &n in leaves {
        for l in 0..n.level {
            assert!(!set.contains(&n.ancestor(l)), "{n:?} and its ancestor both selected");
        }
    }
}

#[test]
fn always_split_gives_4_pow_l_leaves() {
    for (size, leaf, levels) in [(33usize, 1u32, 5u32), (65, 4, 4), (2, 1, 0), (3, 1, 1)] {
        let qt = Quadtree::new(&terrain(size, size, DVec2::ZERO, 0.0, 1.0), leaf);
        assert_eq!(qt.max_level() as u32, levels);
        let (mut splits, mut leaves_seen) = (0u64, 0u64);
        let leaves = traverse(&qt, &mut AlwaysSplit, &mut NoCull, &mut |_, v| match v {
            Visit::Split => splits += 1,
            Visit::Leaf => leaves_seen += 1,
            Visit::Culled => panic!("nothing is culled"),
        });
        assert_eq!(leaves.len() as u64, 4u64.pow(levels));
        assert_eq!(leaves_seen, 4u64.pow(levels));
        assert_eq!(splits, (4u64.pow(levels) - 1) / 3);
        assert!(leaves.iter().all(|n| n.level as u32 == levels));
        // Deterministic traversal order.
        let mut sorted = leaves.clone();
        sorted.sort_by_key(|n| n.dfs_key());
        assert_eq!(sorted, leaves);
    }
}

#[test]
fn grids_that_are_not_power_of_two_plus_one() {
    let hm = terrain(1000, 777, DVec2::ZERO, 0.0, 1.0);
    let qt = Quadtree::new(&hm, 16);
    assert_eq!((qt.root_cells(), qt.max_level()), (1024, 6));
    let leaves = select(&qt, &mut AlwaysSplit, &mut NoCull);
    // ceil(999 / 16) x ceil(776 / 16) nodes hold cells; the rest are skipped.
    assert_eq!(leaves.len(), 63 * 49);
    assert_eq!(cell_area(&qt, &leaves), 999 * 776);
    assert_disjoint(&leaves);
    // Partial nodes at the east / north edges are clipped to the last sample.
    let r = qt.clipped_rect(NodeId::new(6, 62, 48)).unwrap();
    assert_eq!((r.x0, r.x1, r.y0, r.y1), (992, 999, 768, 776));
    // Uniform level 3: 8 x 7 nodes (north row 7 starts at 896 > 776: outside).
    let l3 = select(&qt, &mut SplitToLevel(3), &mut NoCull);
    assert_eq!(l3.len(), 8 * 7);
    assert_eq!(cell_area(&qt, &l3), 999 * 776);
    // Tiny grids.
    for (w, h) in [(2, 2), (3, 3), (2, 9)] {
        let qt = Quadtree::new(&terrain(w, h, DVec2::ZERO, 0.0, 1.0), 1);
        let leaves = select(&qt, &mut AlwaysSplit, &mut NoCull);
        assert_eq!(leaves.len(), (w - 1) * (h - 1));
        assert_eq!(cell_area(&qt, &leaves), ((w - 1) * (h - 1)) as u64);
    }
}

#[test]
fn frustum_culled_selection_is_exactly_the_intersecting_nodes() {
    let hm = terrain(129, 129, dvec2(1000.0, 2000.0), 0.0, 10.0);
    let qt = Quadtree::new(&hm, 4);
    let cam =
        Camera::from_yaw_pitch(dvec3(1300.0, 2100.0, 600.0), 30.0, -25.0).with_clip(1.0, 900.0);
    let f = cam.frustum();
    let mut culled = 0;
    let leaves = traverse(&qt, &mut AlwaysSplit, &mut FrustumCull::new(f), &mut |_, v| {
        culled += (v == Visit::Culled) as usize
    });
    assert!(culled > 0);
    let got: HashSet<NodeId> = leaves.iter().copied().collect();
    let n = 1u32 << qt.max_level();
    let mut want = HashSet::new();
    for j in 0..n {
        for i in 0..n {
            let id = NodeId::new(qt.max_level(), i, j);
            if f.classify(&qt.node_info(id).unwrap().aabb) != Classification::Outside {
                want.insert(id);
            }
        }
    }
    assert!(!want.is_empty() && want.len() < (n * n) as usize);
    assert_eq!(got, want);
}

#[test]
fn bounding_circle_cull_keeps_nodes_touching_the_view_triangle() {
    let hm = terrain(257, 257, DVec2::ZERO, 0.0, 4.0);
    let qt = Quadtree::new(&hm, 8);
    let cam = Camera::from_yaw_pitch(dvec3(500.0, 300.0, 400.0), 45.0, -15.0).with_clip(1.0, 600.0);
    let region = project_view_to_ground(&cam);
    let leaves = select(&qt, &mut AlwaysSplit, &mut BoundingCircleCull::new(region.clone()));
    assert!(!leaves.is_empty() && leaves.len() < 32 * 32);
    for &n in &leaves {
        let info = qt.node_info(n).unwrap();
        let (lo, hi) = (info.aabb.min.truncate(), info.aabb.max.truncate());
        let c = (lo + hi) * 0.5;
        // The circle around the node reaches the region: the region's closest vertex or
        // the centre is within the radius, or the centre is inside.
        let r = (hi - lo).length() * 0.5;
        let v = region.vertices();
        let near = region.contains(c)
            || (0..v.len()).any(|e| segment_distance(v[e], v[(e + 1) % v.len()], c) <= r + 1e-9);
        assert!(near, "{n:?}");
    }
    // The eye's node is selected; a node far behind the camera is not.
    let eye_node = NodeId::new(qt.max_level(), (500.0 / 32.0) as u32, (300.0 / 32.0) as u32);
    assert!(leaves.contains(&eye_node));
    assert!(!leaves.contains(&NodeId::new(qt.max_level(), 0, 0)));
    // Combining two cull policies keeps only what both keep.
    let both = select(
        &qt,
        &mut AlwaysSplit,
        &mut (BoundingCircleCull::new(region), FrustumCull::new(cam.frustum())),
    );
    let fr: HashSet<NodeId> =
        select(&qt, &mut AlwaysSplit, &mut FrustumCull::new(cam.frustum())).into_iter().collect();
    let bc: HashSet<NodeId> = leaves.iter().copied().collect();
    assert!(!both.is_empty());
    assert!(both.iter().all(|n| fr.contains(n) && bc.contains(n)));
}

/// A distance-based split policy (screen-space size of the node's edge > 64 px).
fn size_split(cam: Camera, px: f64) -> impl FnMut(NodeId, &NodeInfo) -> bool {
    move |_, info: &NodeInfo| {
        let d = info.aabb.distance(cam.position).max(1.0);
        let edge = (info.aabb.max.x - info.aabb.min.x).max(info.aabb.max.y - info.aabb.min.y);
        cam.lambda() * edge / d > px
    }
}

/// Distance from `p` to the segment `a b`.
fn segment_distance(a: DVec2, b: DVec2, p: DVec2) -> f64 {
    let e = b - a;
    let t = ((p - a).dot(e) / e.length_squared()).clamp(0.0, 1.0);
    (a + e * t - p).length()
}

#[test]
fn neighbours_across_levels() {
    // Root split; SW quadrant split to level 3 near the centre.
    let hm = terrain(65, 65, DVec2::ZERO, 0.0, 1.0);
    let qt = Quadtree::new(&hm, 1);
    // Refine every node holding the point (20.5, 20.5) down to the finest level.
    let mut around = |_: NodeId, i: &NodeInfo| i.aabb.contains(dvec3(20.5, 20.5, i.aabb.min.z));
    let leaves = select(&qt, &mut around, &mut NoCull);
    let set = LeafSet::new(leaves.iter().copied());
    assert!(
        leaves.iter().map(|n| n.level).max().unwrap()
            > leaves.iter().map(|n| n.level).min().unwrap() + 1
    );
    // Brute force: the neighbours across edge d are the leaves that share an edge and lie
    // on that side.
    for &n in &leaves {
        for d in Direction::ALL {
            let got: HashSet<NodeId> = set.neighbours(n, d).into_iter().collect();
            let want: HashSet<NodeId> = leaves
                .iter()
                .copied()
                .filter(|&m| m != n && n.shares_edge_with(m) && side_of(n, m) == Some(d))
                .collect();
            assert_eq!(got, want, "{n:?} {d:?}");
        }
    }
    // A coarse leaf finds its fine neighbours in south-to-north order.
    let coarse = *leaves.iter().min_by_key(|n| (n.level, n.i, n.j)).unwrap();
    for d in Direction::ALL {
        let v = set.neighbours(coarse, d);
        let keys: Vec<(u32, u32)> =
            v.iter().map(|m| (m.i << (8 - m.level), m.j << (8 - m.level))).collect();
        let mut sorted = keys.clone();
        sorted.sort();
        assert_eq!(keys, sorted);
    }
}

/// Which side of `n` the leaf `m` lies on (assuming they share an edge).
fn side_of(n: NodeId, m: NodeId) -> Option<Direction> {
    let l = n.level.max(m.level) as u32;
    let r = |a: NodeId| {
        let s = 1u64 << (l - a.level as u32);
        (a.i as u64 * s, a.j as u64 * s, (a.i as u64 + 1) * s, (a.j as u64 + 1) * s)
    };
    let (a, b) = (r(n), r(m));
    if b.0 == a.2 {
        Some(Direction::East)
    } else if b.2 == a.0 {
        Some(Direction::West)
    } else if b.1 == a.3 {
        Some(Direction::North)
    } else if b.3 == a.1 {
        Some(Direction::South)
    } else {
        None
    }
}

fn hash(n: NodeId, seed: u64) -> u64 {
    let mut x = seed ^ ((n.level as u64) << 58) ^ ((n.i as u64) << 29) ^ n.j as u64;
    x = x.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    x ^= x >> 31;
    x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^ (x >> 29)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn balance_makes_neighbours_differ_by_at_most_one_level(seed in any::<u64>(), p in 30u64..90, w in 9usize..70, h in 9usize..70) {
        let qt = Quadtree::new(&terrain(w, h, DVec2::ZERO, 0.0, 1.0), 1);
        let leaves = select(&qt, &mut |n: NodeId, _: &NodeInfo| n.level < 2 || hash(n, seed) % 100 < p, &mut NoCull);
        let out = balance(&qt, &leaves);
        prop_assert!(is_balanced(&out));
        // Brute force over every pair sharing an edge.
        for (k, &a) in out.iter().enumerate() {
            for &b in &out[k + 1..] {
                if a.shares_edge_with(b) {
                    prop_assert!(a.level.abs_diff(b.level) <= 1, "{:?} {:?}", a, b);
                }
            }
        }
        // Still a tiling of the grid, only refined, deterministic order.
        assert_disjoint(&out);
        prop_assert_eq!(cell_area(&qt, &out), cell_area(&qt, &leaves));
        prop_assert!(out.iter().all(|n| leaves.iter().any(|l| l.is_ancestor_or_self_of(*n))));
        let mut sorted = out.clone();
        sorted.sort_by_key(|n| n.dfs_key());
        prop_assert_eq!(&sorted, &out);
        // Already balanced input is left alone.
        prop_assert_eq!(balance(&qt, &out), out);
    }
}

#[test]
fn balance_fixes_a_known_unbalanced_selection() {
    let qt = Quadtree::new(&terrain(17, 17, DVec2::ZERO, 0.0, 1.0), 1);
    // Refine only the node touching the centre from the south-west down to level 4.
    let leaves = select(
        &qt,
        &mut |n: NodeId, _: &NodeInfo| {
            n.level == 0 || (n.i + 1 == (1 << n.level) / 2 && n.j == n.i)
        },
        &mut NoCull,
    );
    assert!(!is_balanced(&leaves));
    let out = balance(&qt, &leaves);
    assert!(is_balanced(&out));
    assert!(out.len() > leaves.len());
}

#[test]
fn camera_relative_f32_is_millimetre_exact_at_a_projected_origin() {
    let origin = dvec2(500_000.0, 4_000_000.0);
    let hm = terrain(257, 257, origin, 3000.0, 2.0);
    let cam = Camera::from_yaw_pitch(
        dvec3(origin.x + 256.5, origin.y - 100.25, 3000.0 + 450.0),
        40.0,
        -20.0,
    )
    .with_clip(0.5, 5000.0);
    let view64 = cam.view_f64();
    let (mut worst, mut worst_naive, mut worst_px) = (0.0f64, 0.0f64, 0.0f64);
    let naive_view = view64.as_mat4();
    // Anchors: the centres of 8 x 8 tiles of 32 cells.
    for tj in 0..8 {
        for ti in 0..8 {
            let anchor =
                hm.grid_to_world(ti as f64 * 32.0 + 16.0, tj as f64 * 32.0 + 16.0).extend(3200.0);
            let mv = cam.view_for_anchor(anchor);
            let mvp = cam.view_proj_for_anchor(anchor);
            for j in (tj * 32..=tj * 32 + 32).step_by(4) {
                for i in (ti * 32..=ti * 32 + 32).step_by(4) {
                    let p = hm.grid_to_world(i as f64, j as f64).extend(hm.get(i, j) as f64);
                    let off = Camera::offset_from_anchor(p, anchor);
                    let eye32 = mv * off.extend(1.0);
                    let eye64 = view64 * DVec4::new(p.x, p.y, p.z, 1.0);
                    worst = worst.max((eye32.truncate().as_dvec3() - eye64.truncate()).length());
                    let naive = naive_view * p.as_vec3().extend(1.0);
                    worst_naive =
                        worst_naive.max((naive.truncate().as_dvec3() - eye64.truncate()).length());
                    // Screen position through the f32 MVP vs the f64 projection.
                    let clip: Vec4 = mvp * off.extend(1.0);
                    let on_screen =
                        |q: DVec2| q.cmpge(DVec2::ZERO).all() && q.cmple(cam.viewport_px).all();
                    if let Some(px64) = cam.project_world(p).filter(|&q| on_screen(q)) {
                        let ndc = dvec2((clip.x / clip.w) as f64, (clip.y / clip.w) as f64);
                        let px32 = dvec2(
                            (ndc.x + 1.0) * 0.5 * cam.viewport_px.x,
                            (1.0 - ndc.y) * 0.5 * cam.viewport_px.y,
                        );
                        worst_px = worst_px.max((px32 - px64).length());
                    }
                }
            }
        }
    }
    assert!(worst < 1e-3, "camera-relative f32 error {worst} m");
    assert!(worst_px < 0.01, "screen error {worst_px} px");
    // The test has teeth: plain f32 world coordinates are off by decimetres here.
    assert!(worst_naive > 0.05, "naive f32 error only {worst_naive} m");
}

#[test]
fn the_same_scene_at_the_origin_selects_the_same_nodes() {
    let shift = dvec3(500_000.0, 4_000_000.0, 3000.0);
    let far = terrain(257, 257, shift.truncate(), 3000.0, 2.0);
    let near = terrain(257, 257, DVec2::ZERO, 0.0, 2.0);
    let qt_far = Quadtree::new(&far, 4);
    let qt_near = Quadtree::new(&near, 4);
    let eye = dvec3(180.5, 60.25, 400.0);
    let run = |qt: &Quadtree, offset: DVec3| {
        let cam = Camera::from_yaw_pitch(eye + offset, 20.0, -12.0).with_clip(1.0, 2000.0);
        let leaves = select(qt, &mut size_split(cam, 48.0), &mut FrustumCull::new(cam.frustum()));
        balance(qt, &leaves)
    };
    let a = run(&qt_far, shift);
    let b = run(&qt_near, DVec3::ZERO);
    assert_eq!(a, b);
    let levels: HashSet<u8> = a.iter().map(|n| n.level).collect();
    assert!(levels.len() >= 3, "a non-trivial selection: {levels:?}");
    assert!(a.len() < 64 * 64);
    // And the boxes agree up to the shift.
    for &n in a.iter().take(50) {
        let (x, y) = (qt_far.node_info(n).unwrap().aabb, qt_near.node_info(n).unwrap().aabb);
        assert!((x.min - shift - y.min).length() < 1e-6 && (x.max - shift - y.max).length() < 1e-6);
    }
}

#[test]
fn straight_down_and_grazing_traversals() {
    // Straight down over the middle of flat ground: finest at the nadir.
    let flat = Heightmap::from_fn(257, 257, Georef::local(2.0), |_, _| 0.0).unwrap();
    let qt = Quadtree::new(&flat, 4);
    let cam = Camera::from_yaw_pitch(dvec3(256.0, 256.0, 600.0), 0.0, -90.0).with_clip(1.0, 1000.0);
    let leaves = select(&qt, &mut size_split(cam, 64.0), &mut FrustumCull::new(cam.frustum()));
    let set = LeafSet::new(leaves.iter().copied());
    let nadir = set.leaf_covering(NodeId::new(qt.max_level(), 32, 32)).expect("nadir selected");
    assert!(leaves.iter().all(|n| n.level <= nadir.level));
    assert!(leaves.iter().any(|n| n.level < nadir.level));
    // The footprint is 2 tan30 x 600 ~ 693 m north-south: the whole 512 m grid is in view.
    assert_eq!(cell_area(&qt, &leaves), 256 * 256);
    let hm = terrain(257, 257, DVec2::ZERO, 0.0, 2.0);
    let qt = Quadtree::new(&hm, 4);
    // Grazing, from the south edge looking north along the ground: everything selected is
    // in front of the eye.
    let cam = Camera::from_yaw_pitch(dvec3(256.0, -5.0, 420.0), 0.0, -3.0).with_clip(1.0, 3000.0);
    let f = cam.frustum();
    let leaves = select(&qt, &mut size_split(cam, 32.0), &mut FrustumCull::new(f));
    assert!(!leaves.is_empty());
    for &n in &leaves {
        let b: Aabb = qt.node_info(n).unwrap().aabb;
        assert_ne!(f.classify(&b), Classification::Outside);
        assert!(b.max.y > cam.position.y);
    }
    // A custom cull closure plugs into the same traversal.
    let only_east = select(&qt, &mut AlwaysSplit, &mut |_: NodeId, i: &NodeInfo| {
        if i.aabb.min.x >= 256.0 {
            Cull::AcceptAll
        } else if i.aabb.max.x <= 256.0 {
            Cull::Reject
        } else {
            Cull::Accept
        }
    });
    assert_eq!(only_east.len(), 32 * 64);
}
