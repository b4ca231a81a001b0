//! `lod::select_nodes` (Qiu 2013, sections 3.1-3.3) against a brute force over every node of a
//! block: the exact selection set, Eq. 7 met by every selected node (with the node's exact
//! `StaticE` recomputed from the heights), bounding-circle culling, and a cover of the visible
//! part of the block without overlap; `needed_level` bounds the selection from above.

use std::collections::BTreeSet;
use std::ops::ControlFlow;
use std::path::PathBuf;

use glam::{DVec3, dvec3};
use terrain_core::Georef;
use terrain_core::geometry::project_view_to_ground;
use terrain_core::geometry::{Camera, Classification, GroundRegion, circle_vs_region};
use terrain_core::heightmap::Heightmap;
use terrain_core::metrics::screen::sight_line_eq7;
use terrain_core::metrics::static_error::StaticErrorPyramid;
use terrain_core::quadtree::NodeId;
use terrain_stream::format::BlockEntry;
use terrain_stream::lod::{View, needed_level, select_nodes};
use terrain_stream::{BakeConfig, BlockId, Header, HeightEncoding, Store, bake};

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("terrain-stream-lod-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// Rough integer terrain (lossless with 1 m steps): ridges plus a hash-like roughness.
fn terrain(w: usize, h: usize) -> Heightmap {
    Heightmap::from_fn(w, h, Georef::local(10.0), |i, j| {
        let (x, y) = (i as f32, j as f32);
        (300.0 + 150.0 * (x * 0.05).sin() * (y * 0.04).cos() + ((i * 7 + j * 13) % 11) as f32)
            .round()
    })
    .unwrap()
}

fn bake_store(hm: &Heightmap, name: &str, k: u8, node_levels: u8) -> (PathBuf, Store) {
    let dir = scratch(name);
    let cfg = BakeConfig {
        k,
        node_levels,
        encoding: HeightEncoding::Quantized { step_m: 1.0, offset_m: 0.0 },
        ..Default::default()
    };
    let r = bake(hm, &dir, &cfg, &mut |_: &terrain_stream::BakeProgress| ControlFlow::Continue(()))
        .unwrap();
    assert!(r.lossless);
    let store = Store::open(&dir).unwrap();
    (dir, store)
}

/// The brute force's view of one node: everything computed directly from the index.
struct Brute {
    outside: bool,
    err: f64,
    rho: f64,
}

/// Node `(l, i, j)` of block `b`, or `None` when it covers no valid vertex.
fn brute(
    h: &Header,
    e: &BlockEntry,
    b: BlockId,
    view: &View,
    region: &GroundRegion,
    n: NodeId,
) -> Option<Brute> {
    let c = h.block_cells() >> n.level;
    let (x0, y0) = (n.i * c, n.j * c);
    let (vw, vh) = (e.valid_w - 1, e.valid_h - 1);
    if (x0 > 0 && x0 >= vw) || (y0 > 0 && y0 >= vh) {
        return None;
    }
    let lo = h.vertex_world(b, x0 as f64, y0 as f64);
    let hi = h.vertex_world(b, (x0 + c).min(vw) as f64, (y0 + c).min(vh) as f64);
    let outside = circle_vs_region(region, (lo + hi) * 0.5, (hi - lo).length() * 0.5)
        == Classification::Outside;
    // Error bound and height range: stored per node down to node_levels; below, the chain of
    // per-level maxima under the deepest stored ancestor.
    let stored = n.level.min(h.node_levels.saturating_sub(1));
    let s = n.level - stored;
    let anc = e.node(stored, n.i >> s, n.j >> s).unwrap();
    let mut err = anc.static_error as f64;
    for l in h.node_levels.max(1)..=n.level {
        err = err.min(e.level_errors.get(l as usize).map_or(0.0, |&x| x as f64));
    }
    let (blo, bhi) = (lo.extend(anc.min as f64), hi.extend(anc.max as f64));
    let d = (blo - view.eye).max(view.eye - bhi).max(DVec3::ZERO).length();
    let to_centre = (blo + bhi) * 0.5 - view.eye;
    let rho = sight_line_eq7(view.lambda, err, d, view.dir, to_centre);
    Some(Brute { outside, err, rho })
}

fn splits(h: &Header, b: &Brute, level: u8, tau: f64) -> bool {
    !b.outside && level < h.k && b.err > 0.0 && b.rho > tau
}

fn ancestors(n: NodeId) -> impl Iterator<Item = NodeId> {
    (0..n.level).map(move |l| {
        let s = n.level - l;
        NodeId { level: l, i: n.i >> s, j: n.j >> s }
    })
}

fn all_nodes(k: u8) -> impl Iterator<Item = NodeId> {
    (0..=k).flat_map(|level| {
        let n = 1u32 << level;
        (0..n * n).map(move |p| NodeId { level, i: p % n, j: p / n })
    })
}

/// Checks one block for one view; returns the number of selected nodes.
fn check(
    store: &Store,
    b: BlockId,
    camera: &Camera,
    tau: f64,
    exact: Option<&[Vec<f64>]>,
) -> usize {
    let h = store.header();
    let e = store.entry(b).unwrap();
    let view = View::new(camera, tau);
    let region = project_view_to_ground(camera);
    let selected = select_nodes(h, e, b, &view, &region);
    let set: BTreeSet<(u8, u32, u32)> = selected.iter().map(|n| (n.level, n.i, n.j)).collect();
    assert_eq!(set.len(), selected.len(), "{b}: a node selected twice");

    // 1. The exact set: not culled, every ancestor splits, the node itself does not.
    let mut expected = BTreeSet::new();
    for n in all_nodes(h.k) {
        let Some(me) = brute(h, e, b, &view, &region, n) else { continue };
        if me.outside {
            assert!(!set.contains(&(n.level, n.i, n.j)), "{b} {n:?}: culled node selected");
            continue;
        }
        let parents_split = ancestors(n).all(|a| {
            brute(h, e, b, &view, &region, a).is_some_and(|p| splits(h, &p, a.level, tau))
        });
        if parents_split && !splits(h, &me, n.level, tau) {
            expected.insert((n.level, n.i, n.j));
        }
    }
    assert_eq!(set, expected, "{b}: selection differs from the brute force");

    // 2. Eq. 7: every selected node meets the threshold or is at the finest level; with the
    // exact StaticE (recomputed from the heights) it does too, as the bound is never below it.
    for n in &selected {
        let me = brute(h, e, b, &view, &region, *n).unwrap();
        assert!(!me.outside);
        assert!(n.level == h.k || me.err <= 0.0 || me.rho <= tau, "{b} {n:?}: rho {}", me.rho);
        if let Some(x) = exact {
            let side = 1usize << n.level;
            let ex = x.get(n.level as usize).map_or(0.0, |l| l[n.j as usize * side + n.i as usize]);
            assert!(ex <= me.err + 1e-4, "{b} {n:?}: exact StaticE {ex} > bound {}", me.err);
        }
    }

    // 3. Cover without overlap: each finest cell of the block lies in at most one selected
    // node, and in exactly one when its centre is inside the view region.
    let (vw, vh) = (e.valid_w - 1, e.valid_h - 1);
    for cj in 0..vh.max(1) {
        for ci in 0..vw.max(1) {
            let inside = |n: &&NodeId| {
                let c = h.block_cells() >> n.level;
                (n.i * c..(n.i + 1) * c).contains(&ci) && (n.j * c..(n.j + 1) * c).contains(&cj)
            };
            let covering = selected.iter().filter(inside).count();
            let centre = h.vertex_world(b, ci as f64 + 0.5, cj as f64 + 0.5);
            if region.contains(centre) {
                assert_eq!(covering, 1, "{b} cell ({ci}, {cj}) in view");
            } else {
                assert!(covering <= 1, "{b} cell ({ci}, {cj}) covered {covering} times");
            }
        }
    }

    // 4. The runtime's needed level bounds the selection (exact when every level is stored).
    let needed = needed_level(h, e, b, &view, &region);
    let deepest = selected.iter().map(|n| n.level).max();
    assert_eq!(needed.is_some(), deepest.is_some(), "{b}");
    if let (Some(nl), Some(d)) = (needed, deepest) {
        assert!(nl >= d, "{b}: needed {nl} < deepest selected {d}");
        if h.node_levels >= h.k {
            assert_eq!(nl, d, "{b}");
        }
    }
    selected.len()
}

/// The exact monotone StaticE of every node of a block (levels `0..k`), from the source heights.
fn exact_static_e(hm: &Heightmap, h: &Header, b: BlockId) -> Vec<Vec<f64>> {
    let c = h.block_cells() as usize;
    let side = c + 1;
    let (x0, y0) = (b.col as usize * c, b.row as usize * c);
    let block =
        Heightmap::from_fn(side, side, Georef::local(1.0), |i, j| hm.get(x0 + i, y0 + j)).unwrap();
    let pyr = StaticErrorPyramid::build(&block, h.k as usize);
    (0..pyr.levels())
        .map(|l| {
            let n = 1usize << l;
            (0..n * n).map(|p| pyr.get(l, p % n, p / n)).collect()
        })
        .collect()
}

fn cameras() -> Vec<Camera> {
    let cam = |x, y, z, yaw, pitch, far| {
        Camera::from_yaw_pitch(dvec3(x, y, z), yaw, pitch).with_clip(1.0, far)
    };
    vec![
        // Low and oblique over the grid, looking north-east.
        cam(100.0, 150.0, 420.0, 45.0, -12.0, 3000.0),
        // Inside the grid, looking south, short far plane (the far edge crosses blocks).
        cam(700.0, 1200.0, 500.0, 180.0, -25.0, 900.0),
        // High and steep: the near-vertical fallback polygon.
        cam(640.0, 640.0, 2500.0, 10.0, -89.0, 5000.0),
        // Outside the grid, looking away: nothing selected.
        cam(-500.0, -500.0, 400.0, 225.0, -10.0, 2000.0),
    ]
}

#[test]
fn selection_equals_the_brute_force_with_exact_static_error() {
    // 129 x 129 at 10 m, blocks of 33^2: 4 x 4 blocks, no padding; node values stored down to
    // level 3 of 5, so levels 3..5 use the per-level bounds.
    let hm = terrain(129, 129);
    for node_levels in [3u8, 5] {
        let (dir, store) = bake_store(&hm, &format!("exact{node_levels}"), 5, node_levels);
        let h = store.header().clone();
        let exact: Vec<(BlockId, Vec<Vec<f64>>)> =
            store.block_ids().map(|b| (b, exact_static_e(&hm, &h, b))).collect();
        // The index holds exactly the recomputed StaticE at the stored levels, and per-level
        // maxima that bound every node of that level.
        for (b, x) in &exact {
            let e = store.entry(*b).unwrap();
            for l in 0..h.k {
                let n = 1u32 << l;
                let level_max = x[l as usize].iter().copied().fold(0.0, f64::max);
                assert!((e.level_errors[l as usize] as f64 - level_max).abs() < 1e-3, "{b} {l}");
                if l < h.node_levels {
                    for p in 0..n * n {
                        let v = e.node(l, p % n, p / n).unwrap().static_error as f64;
                        assert!((v - x[l as usize][p as usize]).abs() < 1e-3, "{b} ({l}, {p})");
                    }
                }
            }
        }
        let mut total = 0;
        let mut deepest_seen = 0;
        for (ci, cam) in cameras().iter().enumerate() {
            for tau in [1.0, 4.0] {
                for (b, x) in &exact {
                    let n = check(&store, *b, cam, tau, Some(x));
                    if ci == 3 {
                        assert_eq!(n, 0, "{b}: a block behind the camera is selected");
                    }
                    total += n;
                    let e = store.entry(*b).unwrap();
                    let view = View::new(cam, tau);
                    let region = project_view_to_ground(cam);
                    deepest_seen = deepest_seen.max(
                        select_nodes(&h, e, *b, &view, &region)
                            .iter()
                            .map(|n| n.level)
                            .max()
                            .unwrap_or(0),
                    );
                }
            }
        }
        // The views exercise the whole range: many nodes, down to the finest level.
        assert!(total > 100, "{total} nodes selected");
        assert_eq!(deepest_seen, h.k);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

#[test]
fn padded_blocks_are_covered_without_overlap() {
    // 150 x 120 samples: the east and north blocks are partly padding (clipped node rects).
    let hm = terrain(150, 120);
    let (dir, store) = bake_store(&hm, "padded", 5, 2);
    assert_eq!((store.header().blocks_x, store.header().blocks_y), (5, 4));
    let ids: Vec<BlockId> = store.block_ids().collect();
    let mut total = 0;
    for cam in cameras() {
        for tau in [0.5, 2.0, 8.0] {
            for &b in &ids {
                total += check(&store, b, &cam, tau, None);
            }
        }
    }
    assert!(total > 100, "{total} nodes selected");
    std::fs::remove_dir_all(&dir).unwrap();
}
