//! `lod::select_patches` (Qiu 2013, sections 3.1-3.3, through terrain-core's traversal) against
//! a brute force over the index: every patch's drawn resolution meets Eq. 7 with the index's
//! `StaticE` and is the coarsest that does, patches cover the visible part of the grid without
//! overlap (every cell in the view region whose own box meets the frustum is drawn), shared
//! edges agree (`check_shared_edges`), no patch is drawn finer than its data or its block's
//! resident level, no traversal leaf lies outside the frustum, and the streamer's
//! `needed_level` is the deepest level the selection draws in a block.

use std::collections::HashMap;
use std::ops::ControlFlow;
use std::sync::Arc;

use crate::lod::{
    Refinement, SplitRule, StoreTree, View, needed_geometry_level, needed_level,
    needed_vertex_level, select_patches, shading_level, traversal_leaves,
};
use crate::{BakeConfig, BlockId, HeightEncoding, Store, bake};
use glam::{DVec3, dvec3};
use terrain_core::Georef;
use terrain_core::geometry::{Aabb, Camera, Classification, Frustum, project_view_to_ground};
use terrain_core::heightmap::Heightmap;
use terrain_core::lod::{Selection, check_shared_edges};
use terrain_core::metrics::screen::sight_line_eq7;
use terrain_core::quadtree::{NodeId, NodeSource};

fn scratch(name: &str) -> super::Scratch {
    super::scratch_store(&format!("terrain-stream-lod-{name}-"))
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

fn bake_store(hm: &Heightmap, name: &str, k: u8, node_levels: u8) -> (super::Scratch, Arc<Store>) {
    let dir = scratch(name);
    let cfg = BakeConfig {
        k,
        node_levels,
        encoding: HeightEncoding::Quantized { step_m: 1.0, offset_m: 0.0 },
        ..Default::default()
    };
    let r = bake(hm, &dir, &cfg, &mut |_: &crate::BakeProgress| ControlFlow::Continue(())).unwrap();
    assert!(r.lossless);
    let store = Arc::new(Store::open(&dir).unwrap());
    (dir, store)
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

/// The brute force's error bound of block-local node `n`: stored per node down to
/// `node_levels`; below, the deepest stored ancestor's fine maximum at `n`'s level (index
/// version 3) or else the block's per-level maximum, capped by the ancestor's `StaticE`.
fn bound(store: &Store, b: BlockId, n: NodeId) -> f64 {
    let h = store.header();
    let e = store.entry(b).unwrap();
    if n.level >= h.k {
        return 0.0;
    }
    let stored = n.level.min(h.node_levels - 1);
    let s = n.level - stored;
    let (ai, aj) = (n.i >> s, n.j >> s);
    let anc = e.node(stored, ai, aj).unwrap().static_error as f64;
    if n.level < h.node_levels {
        return anc;
    }
    let below = e.fine_error(h.node_levels, h.k, ai, aj, n.level);
    anc.min(below.unwrap_or(e.level_errors[n.level as usize]) as f64)
}

/// A copy of store `from`'s folder at `to` whose index is of format version 2 (no fine
/// maxima), as an earlier bake wrote it.
fn as_version_2(from: &std::path::Path, to: &std::path::Path) -> Arc<Store> {
    std::fs::create_dir_all(to.join("blocks")).unwrap();
    for f in std::fs::read_dir(from.join("blocks")).unwrap() {
        let p = f.unwrap().path();
        std::fs::copy(&p, to.join("blocks").join(p.file_name().unwrap())).unwrap();
    }
    let (h, blocks) =
        crate::format::read_index(&std::fs::read(from.join("index.tsi")).unwrap()).unwrap();
    let bytes = crate::format::write_index_unpaged(&h, &blocks, 2);
    std::fs::write(to.join("index.tsi"), bytes).unwrap();
    Arc::new(Store::open(to).unwrap())
}

/// Eq. 7 per metre of error at the box of global node `n` (computed here from the tree's
/// node values, independently of the selection's code path).
fn rho_per_metre(tree: &StoreTree, view: &View, n: NodeId) -> f64 {
    let info = tree.node_info(n).unwrap();
    let (lo, hi) = (info.aabb.min, info.aabb.max);
    let d = (lo - view.eye).max(view.eye - hi).max(DVec3::ZERO).length();
    sight_line_eq7(view.lambda, 1.0, d, view.dir, (lo + hi) * 0.5 - view.eye)
}

/// Max bound over block-local level `level` inside block-local node `n`.
fn level_max(store: &Store, b: BlockId, n: NodeId, level: u8) -> f64 {
    let s = level - n.level;
    let mut m = 0f64;
    for dj in 0..1u32 << s {
        for di in 0..1u32 << s {
            let c = NodeId { level, i: (n.i << s) + di, j: (n.j << s) + dj };
            m = m.max(bound(store, b, c));
        }
    }
    m
}

/// Eq. 7 exactly (no segment floor, whatever the default): the refinement of the tests that
/// pin Eq. 7's least factors.
fn eq7_exact(patch_cells: u32) -> Refinement {
    Refinement { patch_cells, max_segment_cells: 0, ..Refinement::default() }
}

/// [`eq7_exact`]'s tree over `store`.
fn eq7_tree(store: &Arc<Store>, patch_cells: u32) -> StoreTree {
    StoreTree::with_refinement(store.clone(), eq7_exact(patch_cells))
}

/// Checks a patch spanning several blocks: a power-of-two factor putting each block's
/// level-`l` vertices (`2^(s + l)` segments for `2^s` blocks per side), every block under it
/// resident at `l` or finer, and (unless the balance added patches) Eq. 7 at the patch's box
/// met at `l` with the brute force's bounds of every block, and not at `l - 1`.
fn check_spanning(
    tree: &StoreTree,
    view: &View,
    resident: &HashMap<BlockId, u8>,
    sel: &Selection,
    p: &terrain_core::lod::Patch,
) {
    let store = tree.store();
    let s = tree.block_level() - p.node.level;
    let f = p.inner[0];
    assert_eq!(p.inner[1], f);
    assert!(f.log2().fract() == 0.0 && (2.0..=64.0).contains(&f), "{:?}: factor {f}", p.node);
    let segments = f.log2() as u8;
    assert!(segments >= s, "{:?}: factor {f} coarser than its blocks' corners", p.node);
    let l = segments - s;
    let blocks = tree.blocks_under(p.node);
    assert!(!blocks.is_empty());
    for b in &blocks {
        let res =
            *resident.get(b).unwrap_or_else(|| panic!("{:?}: block {b} not resident", p.node));
        assert!(res >= l, "{:?}: draws level {l} of block {b}, resident {res}", p.node);
    }
    // A segment floor makes far patches finer than Eq. 7 needs, by design: Eq. 7's least
    // factors are checked only without one.
    if sel.stats.balance_added > 0 || tree.refinement().max_segment_cells > 0 {
        return;
    }
    let root = NodeId { level: 0, i: 0, j: 0 };
    let err = |l: u8| blocks.iter().map(|&b| level_max(store, b, root, l)).fold(0.0, f64::max);
    let per_metre = rho_per_metre(tree, view, p.node);
    assert!(per_metre * err(l) <= view.tau * (1.0 + 1e-6), "{:?}: level {l} misses tau", p.node);
    if l > 0 {
        assert!(
            per_metre * err(l - 1) > view.tau * (1.0 - 1e-6),
            "{:?}: level {} would meet tau",
            p.node,
            l - 1
        );
    }
}

/// Checks one selection of the store baked from `hm`; returns its patch count and the number
/// of cells in the view region left out because their box is outside the frustum.
fn check(
    hm: &Heightmap,
    tree: &StoreTree,
    camera: &Camera,
    tau: f64,
    resident: &HashMap<BlockId, u8>,
    sel: &Selection,
) -> (usize, usize) {
    let store = tree.store();
    let h = store.header();
    let view = View::new(camera, tau);
    assert!(check_shared_edges(sel).is_empty(), "shared edges disagree");
    assert!(sel.factors_in_range());
    for p in &sel.patches {
        let Some((b, local)) = tree.block_of(p.node) else {
            check_spanning(tree, &view, resident, sel, p);
            continue;
        };
        let res = *resident.get(&b).expect("only resident blocks are drawn");
        let cells = h.block_cells() >> local.level;
        let f = p.inner[0];
        assert_eq!(p.inner[1], f);
        assert!(f.log2().fract() == 0.0 && f >= 2.0, "{:?}: factor {f}", p.node);
        // Never finer than the data: at most one triangle pair per cell (factor 2 is the
        // tessellator's least, so a patch of 1 or 2 cells may take it).
        assert!(f as u32 <= cells.max(2), "{:?}: factor {f} > {cells} cells", p.node);
        // The drawn vertex level, and Eq. 7 at the patch's box: every sub-node at that level
        // is within tau (or the level is the block's resident one), and one level coarser
        // would not have been (minimality), unless the factor is the least one.
        let drawn = local.level + f.log2() as u8;
        let per_metre = rho_per_metre(tree, &view, p.node);
        if local.level <= res {
            assert!(
                drawn <= res.max(local.level + 1),
                "{:?}: drawn {drawn} > resident {res}",
                p.node
            );
        }
        if drawn < res.min(h.k) && drawn >= local.level {
            assert!(
                per_metre * level_max(store, b, local, drawn) <= tau * (1.0 + 1e-6),
                "{:?}: level {drawn} does not meet tau",
                p.node
            );
        }
        if f > 2.0 && tree.refinement().max_segment_cells == 0 {
            assert!(
                per_metre * level_max(store, b, local, drawn - 1) > tau * (1.0 - 1e-6),
                "{:?}: level {} would meet tau",
                p.node,
                drawn - 1
            );
        }
    }
    // The frustum cull: only patches the balance added (not culled again) may lie outside.
    let frustum = Frustum::from_camera(camera);
    let outside = sel
        .patches
        .iter()
        .filter(|p| {
            frustum.classify(&tree.node_info(p.node).unwrap().aabb) == Classification::Outside
        })
        .count();
    assert!(outside <= sel.stats.balance_added, "{outside} patches outside the frustum");
    // Cover without overlap: each grid cell in a resident block lies in at most one patch,
    // and in exactly one when its centre is inside the view region and its own box (its
    // corners' heights, inside every node box that holds the cell) meets the frustum.
    let region = project_view_to_ground(camera);
    let mut culled = 0;
    let root = tree.root_cells();
    let mut owner = vec![0u8; (h.width * h.height) as usize];
    for p in &sel.patches {
        let (x0, y0, c) = p.node.grid_rect(root);
        for y in y0..(y0 + c).min(h.height as u32 - 1) {
            for x in x0..(x0 + c).min(h.width as u32 - 1) {
                owner[(y as u64 * h.width + x as u64) as usize] += 1;
            }
        }
    }
    for y in 0..h.height as u32 - 1 {
        for x in 0..h.width as u32 - 1 {
            let n = owner[(y as u64 * h.width + x as u64) as usize];
            assert!(n <= 1, "cell ({x}, {y}) drawn {n} times");
            let b = BlockId::new(y / h.block_cells(), x / h.block_cells());
            let centre = h.georef.grid_to_world(glam::dvec2(x as f64 + 0.5, y as f64 + 0.5));
            if region.contains(centre) && resident.contains_key(&b) {
                let (i, j) = (x as usize, y as usize);
                let z = [hm.get(i, j), hm.get(i + 1, j), hm.get(i, j + 1), hm.get(i + 1, j + 1)];
                let lo = h.georef.grid_to_world(glam::dvec2(x as f64, y as f64));
                let hi = h.georef.grid_to_world(glam::dvec2(x as f64 + 1.0, y as f64 + 1.0));
                let cell = Aabb {
                    min: lo.min(hi).extend(z.iter().copied().fold(f32::INFINITY, f32::min).into()),
                    max: lo
                        .max(hi)
                        .extend(z.iter().copied().fold(f32::NEG_INFINITY, f32::max).into()),
                };
                if frustum.classify(&cell) == Classification::Outside {
                    culled += usize::from(n == 0);
                } else {
                    assert_eq!(n, 1, "cell ({x}, {y}) in view not drawn");
                }
            }
        }
    }
    (sel.patches.len(), culled)
}

#[test]
fn patches_meet_eq7_minimally_and_cover_the_view() {
    // 257 x 257 at 10 m in blocks of 65^2 (4 x 4), node values down to level 3 of 6, so the
    // finest levels use the per-level bounds; patches of 4 cells (deep inside the blocks) and
    // of the default size.
    let hm = terrain(257, 257);
    let (_dir, store) = bake_store(&hm, "eq7", 6, 4);
    let all: HashMap<BlockId, u8> = store.block_ids().map(|b| (b, 6)).collect();
    let (mut total, mut culled) = (0, 0);
    let mut factors = std::collections::BTreeSet::new();
    let refines =
        [(4, SplitRule::Eq7), (32, SplitRule::Eq7), (4, SplitRule::Cost), (16, SplitRule::Cost)]
            .map(|(patch_cells, split)| Refinement {
                split,
                cost_split_px: 0,
                ..eq7_exact(patch_cells)
            });
    for refine in refines {
        let tree = StoreTree::with_refinement(store.clone(), refine);
        for (ci, cam) in cameras().iter().enumerate() {
            for tau in [0.5, 2.0, 8.0] {
                let sel = select_patches(&tree, cam, tau, |b| all.get(&b).copied());
                let (n, c) = check(&hm, &tree, cam, tau, &all, &sel);
                culled += c;
                if ci == 3 {
                    assert_eq!(n, 0, "patches behind the camera");
                }
                total += n;
                factors.extend(sel.patches.iter().map(|p| p.inner[0] as u32));
                // The streamer's needed level is the deepest level drawn in each block (the
                // same traversal and split, given the tree's refinement).
                {
                    let view = View::new(cam, tau);
                    let region = project_view_to_ground(cam);
                    for b in store.block_ids() {
                        let drawn = sel
                            .patches
                            .iter()
                            .filter_map(|p| {
                                let (pb, local) = tree.block_of(p.node)?;
                                (pb == b).then(|| local.level + p.inner[0].log2() as u8)
                            })
                            .max();
                        let (h, e) = (store.header(), store.entry(b).unwrap());
                        let need = needed_geometry_level(h, &e, b, &view, &region, refine);
                        // What the streamer loads: that, and at least the shading level.
                        assert_eq!(
                            needed_level(h, &e, b, &view, &region, refine),
                            need.map(|n| n.max(shading_level(h, &e, b, &view)))
                        );
                        // Factor 2 is the least: a patch needing only its corners draws its
                        // next level's vertices by interpolation. (Balancing across blocks
                        // can split a block's leaves further, or split a patch spanning blocks
                        // into blocks outside the view region; then nothing is compared. The
                        // streamer loads the blocks of the view region; the selection drops
                        // those outside the frustum too.)
                        let balanced = sel.stats.balance_added > 0;
                        assert!(drawn.is_none() || need.is_some() || balanced, "{b} {refine:?}");
                        if let (Some(n), Some(d)) = (need, drawn)
                            && sel.stats.balance_added == 0
                        {
                            assert!(d == n || d == n + 1, "{b}: needed {n}, drawn {d} {refine:?}");
                        }
                    }
                }
            }
        }
    }
    assert!(total > 100, "{total} patches");
    assert!(factors.len() >= 3, "factors used: {factors:?}");
    // The frustum cull matters here: cells of the bounding-circle region are left out.
    // The frustum cull matters (cells of the bounding-circle region left out) on a grid of
    // more blocks: `spanning_patches_meet_eq7_over_their_blocks`. Here a far view draws the
    // whole 4 x 4 blocks as one patch spanning them when its box meets the frustum.
    let _ = culled;
}

#[test]
fn clamped_and_missing_blocks_stay_crack_free() {
    // 150 x 120 samples: the east and north blocks are partly padding (clipped node rects).
    let hm = terrain(150, 120);
    let (_dir, store) = bake_store(&hm, "clamped", 5, 3);
    assert_eq!((store.header().blocks_x, store.header().blocks_y), (5, 4));
    let tree = eq7_tree(&store, 4);
    // Resident levels vary per block; one block has nothing resident (not drawn).
    let resident: HashMap<BlockId, u8> = store
        .block_ids()
        .filter(|b| *b != BlockId::new(1, 1))
        .map(|b| (b, ((b.row * 3 + b.col) % 6) as u8))
        .collect();
    let mut total = 0;
    for cam in cameras() {
        for tau in [0.5, 2.0, 8.0] {
            let sel = select_patches(&tree, &cam, tau, |b| resident.get(&b).copied());
            total += check(&hm, &tree, &cam, tau, &resident, &sel).0;
        }
    }
    assert!(total > 50, "{total} patches");
}

/// A patch is split only where even its largest factor (64: its descendants' corners six
/// levels down) misses Eq. 7's tau: the parent of every selected patch inside a block had
/// that bound above tau at its box (or balancing split it). Splitting on the node's own
/// corners, as before, split parents whose tessellation would have met tau.
#[test]
fn patches_split_only_where_their_largest_factor_misses_tau() {
    // 513 x 513 at 10 m in blocks of 257^2 (k = 8, 2 x 2): nodes of 256 and 128 cells can
    // split inside a block (their vertices six levels down are coarser than the samples).
    let hm = terrain(513, 513);
    let (_dir, store) = bake_store(&hm, "split", 8, 4);
    let h = store.header().clone();
    let all: HashMap<BlockId, u8> = store.block_ids().map(|b| (b, 8)).collect();
    let tree = eq7_tree(&store, 32);
    let (mut inside, mut total) = (0, 0);
    for cam in cameras() {
        for tau in [0.25, 0.5, 2.0, 8.0] {
            let sel = select_patches(&tree, &cam, tau, |b| all.get(&b).copied());
            total += check(&hm, &tree, &cam, tau, &all, &sel).0;
            let view = View::new(&cam, tau);
            for p in &sel.patches {
                // Patches spanning blocks: `spanning_patches_meet_eq7_over_their_blocks`.
                let Some((b, local)) = tree.block_of(p.node) else { continue };
                let Some(parent) = local.parent() else { continue };
                inside += 1;
                if sel.stats.balance_added > 0 {
                    continue;
                }
                let e = store.entry(b).unwrap();
                // Independently of `patch_error`: the parent's bound, and the largest bound
                // of its descendants six levels below it (exact with the fine maxima; at most
                // the block's per-level maximum there).
                let err = if parent.level + 6 >= h.k {
                    0.0
                } else {
                    let six = level_max(&store, b, parent, parent.level + 6);
                    assert!(six <= f64::from(e.level_errors[parent.level as usize + 6]));
                    bound(&store, b, parent).min(six)
                };
                let global = tree.global(b, parent);
                assert!(
                    err > 0.0 && rho_per_metre(&tree, &view, global) * err > tau * (1.0 - 1e-6),
                    "{:?} split though its largest factor meets tau {tau}",
                    global
                );
            }
        }
    }
    assert!(inside > 20 && total > inside, "{inside} patches inside blocks of {total}");
}

/// The cost split ([`SplitRule::Cost`], 16-cell patches): inside a block a node splits where
/// even its largest factor misses Eq. 7's `tau` or where its four children, each at the
/// coarsest level meeting Eq. 7 at its own box, draw fewer triangles than it does at its own;
/// a traversal leaf larger than the smallest patch meets neither (minimality under the rule;
/// the balance may split leaves further for the edge rule, as under Eq. 7 alone). Checked
/// against a brute force over the index (each level's largest bound under the node, not the
/// selection's walk), skipping nodes within 1e-6 of a threshold; every selection also passes
/// `check` (Eq. 7 per patch, cover, shared edges). Eq. 7 alone on the same views draws more
/// triangles (the rule changes the selection). With a screen-size floor
/// ([`Refinement::cost_split_px`]) the cost decides only nodes whose children are at least
/// the floor across on screen at the node's nearest point (the brute force applies the same
/// floor; nodes within 1e-6 of it are skipped), so it splits fewer nodes by cost than without.
#[test]
fn cost_split_splits_where_the_children_draw_fewer_triangles() {
    // 513 x 513 at 10 m in blocks of 257^2 (k = 8, 2 x 2), node values to level 4 plus the
    // fine maxima, as a default bake.
    let hm = terrain(513, 513);
    let (_dir, store) = bake_store(&hm, "cost", 8, 5);
    let all: HashMap<BlockId, u8> = store.block_ids().map(|b| (b, 8)).collect();
    let mut by_cost_at = Vec::new();
    for px in [0u32, 200] {
        by_cost_at.push(cost_split_against_brute_force(&hm, &store, &all, px));
    }
    assert!(
        by_cost_at[1] < by_cost_at[0],
        "nodes split by cost with the floor {} against without {}",
        by_cost_at[1],
        by_cost_at[0]
    );
}

/// [`cost_split_splits_where_the_children_draw_fewer_triangles`] with the floor `px`: the
/// number of nodes split by their cost alone.
fn cost_split_against_brute_force(
    hm: &Heightmap,
    store: &Arc<Store>,
    all: &HashMap<BlockId, u8>,
    px: u32,
) -> usize {
    let h = store.header().clone();
    let tree_of = |split| {
        let refine = Refinement { split, cost_split_px: px, ..eq7_exact(16) };
        StoreTree::with_refinement(store.clone(), refine)
    };
    let (eq7, cost) = (tree_of(SplitRule::Eq7), tree_of(SplitRule::Cost));
    let patch_level = h.k - 4;
    let drawn =
        |s: &Selection| s.patches.iter().map(|p| f64::from(p.inner[0]).powi(2)).sum::<f64>();
    let (mut by_cost, mut leaves, mut tris) = (0, 0, [0f64; 2]);
    for cam in cameras() {
        for tau in [0.5, 1.0, 2.0, 8.0] {
            let sel = select_patches(&cost, &cam, tau, |b| all.get(&b).copied());
            check(hm, &cost, &cam, tau, all, &sel);
            tris[0] += drawn(&select_patches(&eq7, &cam, tau, |b| all.get(&b).copied()));
            tris[1] += drawn(&sel);
            let view = View::new(&cam, tau);
            // The brute force's least level meeting Eq. 7 at threshold `t` for local node `m`.
            let needed = |b: BlockId, m: NodeId, t: f64| {
                let pm = rho_per_metre(&cost, &view, cost.global(b, m));
                (m.level..h.k).find(|&l| pm * level_max(store, b, m, l) <= t).unwrap_or(h.k)
            };
            let triangles = |b: BlockId, m: NodeId, t: f64| {
                1u64 << (2 * (needed(b, m, t) - m.level).clamp(1, 6))
            };
            // Whether the rule splits `n` (`None`: within rounding of a threshold), and
            // whether only the cost decided.
            let decide = |b: BlockId, n: NodeId| -> Option<(bool, bool)> {
                let pm = rho_per_metre(&cost, &view, cost.global(b, n));
                let six = if n.level + 6 >= h.k {
                    0.0
                } else {
                    bound(store, b, n).min(level_max(store, b, n, n.level + 6))
                };
                if pm * six > tau * (1.0 + 1e-6) {
                    return Some((true, false));
                }
                if pm * six > tau * (1.0 - 1e-6) {
                    return None;
                }
                // The floor: a child's side on screen at the node's nearest point.
                let aabb = cost.node_info(cost.global(b, n)).unwrap().aabb;
                let d = (aabb.min - view.eye).max(view.eye - aabb.max).max(DVec3::ZERO).length();
                let side = (aabb.max.x - aabb.min.x).max(aabb.max.y - aabb.min.y) * 0.5;
                let on_screen = if d > 0.0 { view.lambda * side / d } else { f64::INFINITY };
                if px > 0 && on_screen < f64::from(px) * (1.0 - 1e-6) {
                    return Some((false, false));
                }
                if px > 0 && on_screen < f64::from(px) * (1.0 + 1e-6) {
                    return None;
                }
                let at = |t: f64| {
                    let kids: u64 = n
                        .children()
                        .iter()
                        .filter(|&&c| cost.node_info(cost.global(b, c)).is_some())
                        .map(|&c| triangles(b, c, t))
                        .sum();
                    kids < triangles(b, n, t)
                };
                let split = at(tau * (1.0 + 1e-6));
                (split == at(tau * (1.0 - 1e-6))).then_some((split, true))
            };
            let mut seen = std::collections::HashSet::new();
            // The traversal's leaves (the balance then splits some further).
            for leaf in traversal_leaves(&cost, &cam, tau, |b| all.get(&b).copied()) {
                let Some((b, local)) = cost.block_of(leaf) else { continue };
                if local.level < patch_level
                    && let Some((split, _)) = decide(b, local)
                {
                    assert!(!split, "{leaf:?} (tau {tau}) should have split");
                    leaves += 1;
                }
                let mut a = local;
                while let Some(parent) = a.parent() {
                    a = parent;
                    if !seen.insert((b, parent)) {
                        continue;
                    }
                    if let Some((split, cost_only)) = decide(b, parent) {
                        assert!(split, "{:?} (tau {tau}) split", cost.global(b, parent));
                        by_cost += usize::from(cost_only);
                    }
                }
            }
        }
    }
    // Fewer with the floor (18 at 200 px), but some: the floor is exercised on both sides.
    let least = if px == 0 { 20 } else { 5 };
    assert!(by_cost > least, "{by_cost} nodes split by their cost alone (floor {px} px)");
    assert!(leaves > 20, "{leaves} leaves larger than the smallest patch checked");
    assert!(tris[1] < tris[0], "cost split {} against Eq. 7 alone {}", tris[1], tris[0]);
    by_cost
}

/// Far terrain is drawn by patches spanning several blocks: a node above the blocks stays one
/// patch when Eq. 7 holds at some factor of at most 64 with the largest per-level error of its
/// blocks, and each of its blocks holds that level. Every spanning patch meets Eq. 7 minimally
/// over its blocks (`check`), the surface stays crack-free with resident levels varying per
/// block and a block with nothing resident, and a node above the blocks was split only where
/// no factor met `tau` or a block under it lacked the level.
#[test]
fn spanning_patches_meet_eq7_over_their_blocks() {
    // 513 x 513 at 10 m in blocks of 33^2 (16 x 16 blocks, 4 levels above them).
    let hm = terrain(513, 513);
    let (_dir, store) = bake_store(&hm, "span", 5, 3);
    let h = store.header().clone();
    assert_eq!((h.blocks_x, h.blocks_y), (16, 16));
    let tree = eq7_tree(&store, 32);
    let all: HashMap<BlockId, u8> = store.block_ids().map(|b| (b, h.k)).collect();
    let varied: HashMap<BlockId, u8> = store
        .block_ids()
        .filter(|b| *b != BlockId::new(9, 9))
        .map(|b| (b, ((b.row * 3 + b.col) % 6) as u8))
        .collect();
    let cam = |x, y, z, yaw, pitch| Camera::from_yaw_pitch(dvec3(x, y, z), yaw, pitch);
    let cams = [
        cam(300.0, 400.0, 420.0, 45.0, -8.0).with_clip(1.0, 9000.0),
        cam(2500.0, 300.0, 600.0, 0.0, -15.0).with_clip(1.0, 9000.0),
        cam(2560.0, 2560.0, 6000.0, 30.0, -70.0).with_clip(1.0, 20000.0),
    ];
    let (mut spanning, mut blocks_spanned, mut culled, mut parents) = (0, 0, 0, 0);
    for resident in [&all, &varied] {
        for c in &cams {
            for tau in [0.5, 2.0, 8.0] {
                let sel = select_patches(&tree, c, tau, |b| resident.get(&b).copied());
                culled += check(&hm, &tree, c, tau, resident, &sel).1;
                let view = View::new(c, tau);
                for p in &sel.patches {
                    if p.node.level < tree.block_level() {
                        spanning += 1;
                        blocks_spanned += tree.blocks_under(p.node).len();
                    }
                    // A parent above the blocks split: no factor met tau over its blocks, or
                    // one of them lacked the level that did.
                    let Some(parent) = p.node.parent() else { continue };
                    if parent.level >= tree.block_level() || sel.stats.balance_added > 0 {
                        continue;
                    }
                    parents += 1;
                    let s = tree.block_level() - parent.level;
                    let blocks = tree.blocks_under(parent);
                    let root = NodeId { level: 0, i: 0, j: 0 };
                    let per_metre = rho_per_metre(&tree, &view, parent);
                    let met = (0..=6u8.saturating_sub(s)).filter(|_| s <= 6).find(|&l| {
                        let err = blocks
                            .iter()
                            .map(|&b| level_max(&store, b, root, l.min(h.k)))
                            .fold(0.0, f64::max);
                        per_metre * err <= tau * (1.0 - 1e-6)
                    });
                    if let Some(l) = met {
                        assert!(
                            blocks.iter().any(|b| resident.get(b).is_none_or(|&r| r < l)),
                            "{parent:?} split though level {l} of its resident blocks meets tau"
                        );
                    }
                }
            }
        }
    }
    assert!(spanning > 20, "{spanning} spanning patches");
    assert!(blocks_spanned > 2 * spanning, "{blocks_spanned} blocks under {spanning} patches");
    assert!(parents > 20, "{parents} parents above the blocks checked");
    assert!(culled > 100, "{culled} cells culled by the frustum");
}

/// The segment floor ([`Refinement::max_segment_cells`]): with it, no drawn patch has segments
/// coarser than the floor (all blocks resident), the selection still covers the view without
/// overlap, shared edges agree and every patch meets Eq. 7 (`check`, less Eq. 7's minimality),
/// and the streamer's needed level is at least what is drawn; without it, the same cameras
/// draw coarser segments (the floor is not vacuous here).
#[test]
fn segment_floor_bounds_every_drawn_segment_and_stays_crack_free() {
    // 513 x 513 at 10 m in blocks of 33^2 (16 x 16 blocks, 4 levels above them).
    let hm = terrain(513, 513);
    let (_dir, store) = bake_store(&hm, "segfloor", 5, 3);
    let h = store.header().clone();
    let all: HashMap<BlockId, u8> = store.block_ids().map(|b| (b, h.k)).collect();
    let cam = |x, y, z, yaw, pitch| Camera::from_yaw_pitch(dvec3(x, y, z), yaw, pitch);
    let cams = [
        cam(300.0, 400.0, 420.0, 45.0, -8.0).with_clip(1.0, 9000.0),
        cam(2500.0, 300.0, 600.0, 0.0, -15.0).with_clip(1.0, 9000.0),
        cam(2560.0, 2560.0, 6000.0, 30.0, -70.0).with_clip(1.0, 20000.0),
    ];
    let coarsest = |tree: &StoreTree, sel: &Selection| {
        let root = tree.root_cells();
        sel.patches.iter().map(|p| p.node.grid_rect(root).2 as f32 / p.inner[0]).fold(0.0, f32::max)
    };
    for floor in [8u32, 16] {
        let (mut coarser_without, mut patches) = (0, 0);
        for patch_cells in [4, 32] {
            let off = eq7_exact(patch_cells);
            let on = Refinement { max_segment_cells: floor, ..off };
            assert_eq!(on.segment_floor_level(h.k), h.k - floor.ilog2() as u8);
            let tree_off = StoreTree::with_refinement(store.clone(), off);
            let tree = StoreTree::with_refinement(store.clone(), on);
            for c in &cams {
                for tau in [0.5, 2.0, 8.0] {
                    let sel = select_patches(&tree, c, tau, |b| all.get(&b).copied());
                    check(&hm, &tree, c, tau, &all, &sel);
                    patches += sel.patches.len();
                    let worst = coarsest(&tree, &sel);
                    assert!(worst <= floor as f32, "floor {floor}: a {worst}-cell segment");
                    // Negative control: Eq. 7 alone draws coarser segments somewhere.
                    let plain = select_patches(&tree_off, c, tau, |b| all.get(&b).copied());
                    coarser_without += usize::from(coarsest(&tree_off, &plain) > floor as f32);
                    // What the streamer loads covers what is drawn.
                    let view = View::new(c, tau);
                    let region = project_view_to_ground(c);
                    for p in &sel.patches {
                        let Some((b, local)) = tree.block_of(p.node) else { continue };
                        let drawn = local.level + p.inner[0].log2() as u8;
                        let e = store.entry(b).unwrap();
                        if let Some(need) = needed_geometry_level(&h, &e, b, &view, &region, on) {
                            assert!(
                                need + 1 >= drawn.min(h.k),
                                "{b}: needed {need}, drawn {drawn}"
                            );
                            assert!(need >= on.segment_floor_level(h.k));
                        }
                    }
                }
            }
        }
        assert!(patches > 50, "{patches} patches");
        assert!(coarser_without > 0, "floor {floor}: Eq. 7 alone never drew coarser segments");
    }
}

/// The leaves' factor from the tree's per-node arrays (the largest `StaticE` per level under
/// each node, one look per level) is the Eq. 7 walk's below the node, node by node: for every
/// node a patch can be, several cameras, `tau` and resident levels, on stores whose stored
/// node levels end above and below the patch level.
#[test]
fn patch_factor_from_level_maxima_equals_the_walk() {
    let hm = terrain(257, 257);
    let mut compared = 0;
    let mut levels = std::collections::BTreeSet::new();
    for (name, k, node_levels, patch_cells) in [("walk6", 6, 4, 4), ("walk6b", 6, 6, 8)] {
        let (_dir, store) = bake_store(&hm, name, k, node_levels);
        let h = store.header().clone();
        let tree = eq7_tree(&store, patch_cells);
        for cam in cameras() {
            for tau in [0.25, 1.0, 4.0] {
                let view = View::new(&cam, tau);
                for b in store.block_ids() {
                    let e = store.entry(b).unwrap();
                    for level in 0..=h.k - patch_cells.trailing_zeros() as u8 {
                        for j in 0..1u32 << level {
                            for i in 0..1u32 << level {
                                let local = NodeId { level, i, j };
                                let global = tree.global(b, local);
                                let Some(info) = tree.node_info(global) else { continue };
                                for max in [2, h.k] {
                                    let walk =
                                        needed_vertex_level(&h, &e, local, &info.aabb, &view, max);
                                    let fast = tree
                                        .needed_vertex_level(global, &info.aabb, &view, max)
                                        .unwrap();
                                    assert_eq!(fast - tree.block_level(), walk, "{b} {local:?}");
                                    levels.insert(walk);
                                    compared += 1;
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    assert!(compared > 1000, "{compared}");
    assert!(levels.len() >= 4, "levels reached: {levels:?}");
}

/// The fine maxima (index version 3) make the selection over node values stored to level 4 of
/// 6 the same, patch for patch and factor for factor, as over node values stored to full
/// depth (`node_levels` = `k`); the same store's version-2 index (no fine maxima, the block's
/// per-level bound) still opens, draws at least as much, and its factor walk needs finer
/// levels at some nodes (the negative control: the comparison sees a difference).
#[test]
fn fine_maxima_select_what_full_depth_node_values_select() {
    // The ridges everywhere, the roughness in some 16-cell squares only: a block's largest
    // error at a fine level is not every node's.
    let hm = Heightmap::from_fn(257, 257, Georef::local(10.0), |i, j| {
        let (x, y) = (i as f32, j as f32);
        let rough = ((i / 16 + 2 * (j / 16)) % 5 == 0) as usize * ((i * 7 + j * 13) % 11);
        (300.0 + 150.0 * (x * 0.05).sin() * (y * 0.04).cos() + rough as f32).round()
    })
    .unwrap();
    let (_full_dir, full) = bake_store(&hm, "full6", 6, 6);
    let (fine_dir, fine) = bake_store(&hm, "fine6", 6, 4);
    let v2_dir = scratch("fine6v2");
    let v2 = as_version_2(&fine_dir, &v2_dir);
    assert!(fine.has_fine_errors() && full.has_fine_errors() && !v2.has_fine_errors());
    let all: HashMap<BlockId, u8> = fine.block_ids().map(|b| (b, 6)).collect();
    let (mut compared, mut tris) = (0, [0f64; 2]);
    // The cost split compares a node with its children: exact where the children are stored
    // nodes (patches of at least 8 cells here: level 3 of the stored 0-3).
    let refines = [(4, SplitRule::Eq7), (32, SplitRule::Eq7), (8, SplitRule::Cost)].map(
        |(patch_cells, split)| Refinement { split, cost_split_px: 0, ..eq7_exact(patch_cells) },
    );
    for refine in refines {
        let trees = [&full, &fine, &v2].map(|s| StoreTree::with_refinement(s.clone(), refine));
        for cam in cameras() {
            for tau in [0.5, 2.0, 8.0, 32.0] {
                let [a, b, c] = trees
                    .each_ref()
                    .map(|t| select_patches(t, &cam, tau, |b| all.get(&b).copied()));
                let key = |s: &Selection| {
                    s.patches.iter().map(|p| (p.node, p.inner, p.outer)).collect::<Vec<_>>()
                };
                assert_eq!(key(&a), key(&b), "{refine:?} tau {tau}");
                check(&hm, &trees[1], &cam, tau, &all, &b);
                let drawn = |s: &Selection| {
                    s.patches.iter().map(|p| f64::from(p.inner[0]).powi(2)).sum::<f64>()
                };
                // The version-2 bounds draw at least as much under Eq. 7 alone (the cost split
                // is greedy: coarser bounds may split a node into cheaper children).
                if refine.split == SplitRule::Eq7 {
                    tris[0] += drawn(&b);
                    tris[1] += drawn(&c);
                } else {
                    check(&hm, &trees[2], &cam, tau, &all, &c);
                }
                compared += a.patches.len();
            }
        }
    }
    // The free walk (the streamer's) too: equal to full depth at every stored node (below the
    // stored levels a node takes its stored ancestor's maxima, a bound, not its own); the
    // version-2 bounds make some nodes need finer levels.
    let (h, hf) = (full.header().clone(), fine.header().clone());
    let tree = eq7_tree(&fine, 4);
    let mut walk_differ = 0;
    for tau in [0.5, 2.0, 8.0] {
        let view = View::new(&cameras()[0], tau);
        for b in fine.block_ids() {
            let (ef, ee, e2) =
                (full.entry(b).unwrap(), fine.entry(b).unwrap(), v2.entry(b).unwrap());
            for level in 0..hf.node_levels {
                for j in 0..1u32 << level {
                    for i in 0..1u32 << level {
                        let n = NodeId { level, i, j };
                        let Some(info) = tree.node_info(tree.global(b, n)) else { continue };
                        let exact = needed_vertex_level(&h, &ef, n, &info.aabb, &view, 6);
                        assert_eq!(
                            exact,
                            needed_vertex_level(&hf, &ee, n, &info.aabb, &view, 6),
                            "{b} {n:?}"
                        );
                        let old = needed_vertex_level(&hf, &e2, n, &info.aabb, &view, 6);
                        assert!(old >= exact, "{b} {n:?}: version 2 {old} < {exact}");
                        walk_differ += usize::from(old > exact);
                    }
                }
            }
        }
    }
    assert!(compared > 100, "{compared} patches");
    assert!(walk_differ > 100, "the version-2 bounds changed {walk_differ} walks");
    assert!(tris[1] >= tris[0], "version 2 draws {} against {}", tris[1], tris[0]);
}

/// The view-angle floor of Eq. 6-7 ([`Refinement::view_angle_floor`]): out-of-core `cos(theta)`
/// is the sight line's, one per view, so a view seen shallower than both floors selects the
/// same patches under either, and a view steeper than them (looking almost straight down)
/// selects fewer under the lower floor (the negative control: the comparison sees a
/// difference).
#[test]
fn the_view_angle_floor_changes_only_views_steeper_than_it() {
    let hm = terrain(257, 257);
    let (_dir, store) = bake_store(&hm, "floor", 6, 6);
    let all: HashMap<BlockId, u8> = store.block_ids().map(|b| (b, 6)).collect();
    let tree = |floor: f64| {
        let refine = Refinement { view_angle_floor: floor, ..eq7_exact(4) };
        StoreTree::with_refinement(store.clone(), refine)
    };
    let (low, high) = (tree(0.1), tree(0.25));
    assert_eq!(Refinement::default().view_angle_floor, 0.25);
    let key =
        |s: &Selection| s.patches.iter().map(|p| (p.node, p.inner, p.outer)).collect::<Vec<_>>();
    let at = |pitch: f64| {
        Camera::from_yaw_pitch(dvec3(1280.0, 1280.0, 900.0), 30.0, pitch).with_clip(1.0, 8000.0)
    };
    // cos(theta) = cos(pitch): 0.87 at -30 degrees, 0.5 at -60 (above both floors).
    for pitch in [-30.0, -60.0] {
        let cam = at(pitch);
        let [a, b] = [&low, &high].map(|t| select_patches(t, &cam, 1.0, |b| all.get(&b).copied()));
        assert!(!a.patches.is_empty());
        assert_eq!(key(&a), key(&b), "pitch {pitch}");
    }
    // cos(89 degrees) = 0.017: below both floors, each floor is the factor.
    let cam = at(-89.0);
    let [a, b] = [&low, &high].map(|t| select_patches(t, &cam, 1.0, |b| all.get(&b).copied()));
    assert!(a.patches.len() < b.patches.len(), "{} vs {}", a.patches.len(), b.patches.len());
}

/// `demand_of` (blocks and levels folded as the patches come, then sorted) equals the
/// per-patch map it replaced (a `BTreeMap` of each block's largest level), for patches in
/// traversal order, shuffled, spanning several blocks and with non-square factors; the
/// traversal through `with_traversal_source` (the tree's block memo) visits the same leaves
/// as through the tree itself.
#[test]
fn demand_and_memoised_traversal_equal_their_references() {
    use std::collections::BTreeMap;
    use terrain_core::lod::Patch;
    use terrain_core::quadtree::{FrustumCull, NodeInfo, NodeTree, SplitPolicy, select};

    let hm = terrain(300, 220);
    let (_dir, store) = bake_store(&hm, "demand", 5, 3);
    let tree = eq7_tree(&store, 4);
    let reference = |patches: &[Patch], on_squares: bool| -> Vec<(BlockId, u8)> {
        let mut need = BTreeMap::new();
        for p in patches {
            // One patch's demand: its block's (or blocks') level.
            let one = Selection { patches: vec![*p], ..Selection::default() };
            for (b, l) in crate::demand_of(&tree, &one, on_squares) {
                let e = need.entry(b).or_insert(0u8);
                *e = (*e).max(l);
            }
        }
        need.into_iter().collect()
    };
    struct Depth(u8);
    impl SplitPolicy for Depth {
        fn should_split(&mut self, n: NodeId, _: &NodeInfo) -> bool {
            n.level < self.0
        }
    }
    let mut checked = 0;
    for (k, cam) in cameras().iter().enumerate() {
        for depth in [1, 3, 5, 7] {
            let frustum = Frustum::from_camera(cam);
            let mut memo = Vec::new();
            tree.with_traversal_source(&mut |src| {
                memo = select(src, &mut Depth(depth), &mut FrustumCull::new(frustum));
            });
            let direct = select(&tree, &mut Depth(depth), &mut FrustumCull::new(frustum));
            assert_eq!(memo, direct, "camera {k}, depth {depth}: leaves");
            let factor = |i: usize| [1.0, 2.0, 4.0, 3.0][i % 4];
            let mut patches: Vec<Patch> = memo
                .iter()
                .enumerate()
                .map(|(i, &node)| Patch { node, outer: [factor(i); 4], inner: [factor(i + 1); 2] })
                .collect();
            let sel =
                |patches: &[Patch]| Selection { patches: patches.to_vec(), ..Default::default() };
            for on_squares in [true, false] {
                let demand = crate::demand_of(&tree, &sel(&patches), on_squares);
                assert_eq!(demand, reference(&patches, on_squares), "camera {k}, depth {depth}");
            }
            patches.reverse();
            let third = patches.len() / 3;
            patches.rotate_left(third);
            let demand = crate::demand_of(&tree, &sel(&patches), true);
            assert_eq!(demand, reference(&patches, true), "camera {k}, depth {depth}, shuffled");
            checked += demand.len();
        }
    }
    assert!(checked > 50, "{checked} block demands compared");
}

/// `demand_within`: the exact demand while it fits the budget; above it, patches of
/// continuous factors ask the power-of-two lattice at or above their largest factor (never
/// coarser than it, never finer than exact), power-of-two patches ask the same as exactly,
/// and off their squares (the strips' carriers) every patch asks its factor's lattice. Each case fails if the rule
/// changes: a lattice a level too coarse, a power-of-two patch held, or a fitting demand held.
#[test]
fn the_demand_held_to_the_budget_asks_the_lattice_of_each_continuous_factor() {
    use terrain_core::lod::Patch;
    use terrain_core::quadtree::{FrustumCull, NodeInfo, SplitPolicy, select};

    let hm = terrain(300, 220);
    let (_dir, store) = bake_store(&hm, "demand-within", 5, 3);
    let tree = eq7_tree(&store, 4);
    let k = store.header().k;
    struct Depth(u8);
    impl SplitPolicy for Depth {
        fn should_split(&mut self, n: NodeId, _: &NodeInfo) -> bool {
            n.level < self.0
        }
    }
    let cam = &cameras()[0];
    let leaves = select(&tree, &mut Depth(3), &mut FrustumCull::new(Frustum::from_camera(cam)));
    assert!(leaves.len() > 4, "{} leaves", leaves.len());
    let root = tree.root_cells();
    let bl = i32::from(tree.block_level());
    let mut held_somewhere = false;
    for f in [1.0f32, 2.0, 3.0, 4.5, 7.9, 8.0, 11.0, 40.0] {
        let sel = Selection {
            patches: leaves
                .iter()
                .map(|&node| Patch { node, outer: [f; 4], inner: [f; 2] })
                .collect(),
            ..Selection::default()
        };
        let exact = crate::demand_of(&tree, &sel, true);
        let bytes = crate::demand_bytes(&exact);
        assert!(bytes > 0);
        // Within the budget: the exact demand, not held.
        assert_eq!(crate::demand_within(&tree, &sel, true, bytes), (exact.clone(), false), "f {f}");
        // Above it: each patch's lattice, `l + ceil(log2 f)` capped at its full resolution.
        let (held, on_lattice) = crate::demand_within(&tree, &sel, true, bytes - 1);
        assert_eq!(on_lattice, held != exact, "f {f}");
        // Both from one pass: the exact demand, and the held one only above the budget.
        assert_eq!(crate::demand_and_held(&tree, &sel, true, bytes), (exact.clone(), None));
        let both = crate::demand_and_held(&tree, &sel, true, bytes - 1);
        assert_eq!(both, (exact.clone(), Some(held.clone())), "f {f}");
        let pow2 = f.fract() == 0.0 && (f as u32).is_power_of_two();
        let mut want = Vec::new();
        for &node in &leaves {
            let cells = root >> node.level;
            let steps = ((f.ceil() as u32).next_power_of_two().min(cells)).trailing_zeros() as i32;
            let level = (i32::from(node.level) - bl + steps).clamp(0, i32::from(k)) as u8;
            for b in tree.blocks_under(node) {
                want.push((b, level));
            }
        }
        want.sort_unstable();
        want.dedup_by(|later, kept| {
            let same = later.0 == kept.0;
            if same {
                kept.1 = kept.1.max(later.1);
            }
            same
        });
        assert_eq!(held, want, "f {f}");
        if pow2 {
            assert_eq!(held, exact, "f {f}: a power-of-two factor asks the same held or not");
        } else if held != exact {
            held_somewhere = true;
            assert!(crate::demand_bytes(&held) < bytes, "f {f}");
            for ((b, l), (eb, el)) in held.iter().zip(&exact) {
                assert_eq!(b, eb);
                assert!(l <= el, "f {f}: held finer than exact");
            }
        }
        // Off their squares (the strips' carriers): exactly every patch's full resolution,
        // held the same lattice as above, power of two or not.
        let strips = crate::demand_of(&tree, &sel, false);
        let budget = crate::demand_bytes(&strips);
        assert_eq!(crate::demand_within(&tree, &sel, false, budget), (strips.clone(), false));
        let changed = want != strips;
        assert!(changed || f >= 16.0, "f {f}: the lattice below 16-cell leaves' full resolution");
        assert_eq!(crate::demand_within(&tree, &sel, false, budget - 1), (want, changed), "f {f}");
    }
    assert!(held_somewhere, "no continuous factor was held below its full resolution");
}

/// A demand the lattices cannot hold is coarsened a level at a time from the block whose
/// samples are densest on screen (largest `2^level x distance`): it ends within the budget,
/// no block finer than asked, near blocks finer than far ones, and the screen density even
/// to a factor of two (every coarsened block at least half the densest block left); a demand
/// within the budget is left alone.
#[test]
fn a_demand_over_the_budget_is_coarsened_densest_on_screen_first() {
    use terrain_core::quadtree::NodeSource;

    let hm = terrain(300, 220);
    let (_dir, store) = bake_store(&hm, "coarsen", 5, 3);
    let tree = eq7_tree(&store, 4);
    let k = store.header().k;
    let asked: Vec<(BlockId, u8)> = store.block_ids().map(|b| (b, k)).collect();
    assert!(asked.len() >= 12, "{} blocks", asked.len());
    let bytes = crate::demand_bytes(&asked);
    let eye = dvec3(-50.0, -50.0, 400.0);
    let distance = |b: BlockId| {
        let info = tree.node_info(tree.global(b, NodeId { level: 0, i: 0, j: 0 })).unwrap();
        (info.aabb.min - eye).max(eye - info.aabb.max).max(DVec3::ZERO).length().max(1.0)
    };
    let mut same = asked.clone();
    assert_eq!(crate::coarsen_to_budget(&tree, &mut same, eye, bytes), 0);
    assert_eq!(same, asked, "a demand within the budget is not changed");
    for share in [2, 5, 40] {
        let budget = bytes / share;
        let mut held = asked.clone();
        let dropped = crate::coarsen_to_budget(&tree, &mut held, eye, budget);
        assert!(crate::demand_bytes(&held) <= budget, "1/{share}");
        let steps: usize = asked.iter().zip(&held).map(|(a, h)| usize::from(a.1 - h.1)).sum();
        assert_eq!(dropped, steps, "1/{share}");
        let key = |&(b, l): &(BlockId, u8)| distance(b) * f64::from(1u32 << l);
        let densest_left = held.iter().filter(|h| h.1 > 0).map(key).fold(0.0, f64::max);
        for (a, h) in asked.iter().zip(&held) {
            assert_eq!(a.0, h.0);
            assert!(h.1 <= a.1);
            if h.1 < a.1 {
                assert!(key(h) >= densest_left / 2.0, "1/{share}: {h:?} coarsened too far");
            }
        }
        let (near, far) = held.iter().fold((held[0], held[0]), |(n, f), h| {
            (
                if distance(h.0) < distance(n.0) { *h } else { n },
                if distance(h.0) > distance(f.0) { *h } else { f },
            )
        });
        assert!(near.1 > far.1, "1/{share}: near {near:?}, far {far:?}");
    }
}

#[test]
fn the_tree_keeps_the_current_views_blocks_and_others_within_their_bytes() {
    // 1025 x 1025 in blocks of 65^2: 256 blocks. A tree keeping no bytes beyond the current
    // selection's blocks selects what a tree keeping every visited block selects, camera after
    // camera, with its `sub_max` values computed when read; it then holds only the blocks the
    // last selection visited, where the other holds every block any selection visited.
    let hm = terrain(1025, 1025);
    let (_dir, store) = bake_store(&hm, "visited", 6, 4);
    let all: HashMap<BlockId, u8> = store.block_ids().map(|b| (b, 6)).collect();
    let free = eq7_tree(&store, 4);
    let tight = eq7_tree(&store, 4).with_visited_bytes(0);
    let mut seen = std::collections::BTreeSet::new();
    let cams = cameras();
    // A short view near the grid's far corner, as `cameras()[1]` is near the near one.
    let corner =
        Camera::from_yaw_pitch(dvec3(9500.0, 9000.0, 500.0), 0.0, -25.0).with_clip(1.0, 900.0);
    // The short view, the long oblique one over it, the short one at the far corner: each
    // visits blocks the ones before did not, which push out the blocks it does not visit (a
    // tree reading no new block drops none).
    for cam in [&cams[1], &cams[0], &corner] {
        let a = select_patches(&free, cam, 1.0, |b| all.get(&b).copied());
        let b = select_patches(&tight, cam, 1.0, |b| all.get(&b).copied());
        assert_eq!(a.patches, b.patches);
        let mut blocks = std::collections::BTreeSet::new();
        for p in &b.patches {
            if let Some((id, _)) = tight.block_of(p.node) {
                blocks.insert(id);
            }
        }
        seen.extend(blocks.iter().copied());
        let (held, bytes) = tight.visited();
        // At least the selection's drawn blocks, at most what the free tree holds.
        assert!(held >= blocks.len() && bytes > 0, "{held} held, {} drawn", blocks.len());
        assert!(held <= free.visited().0);
    }
    let (held, bytes) = free.visited();
    assert!(held >= seen.len() && seen.len() > 16, "{held} held, {} seen", seen.len());
    // The tight tree holds the last (short) view's blocks only.
    let (tight_held, tight_bytes) = tight.visited();
    assert!(tight_held * 2 < held && tight_bytes * 2 < bytes, "{tight_held} {tight_bytes} {bytes}");
}

#[test]
fn block_sub_max_bottom_up_equals_the_sweep_of_descendants() {
    // Node levels below, at and (clamped) above the patch level; with the fine maxima (index
    // version 3+) and without (version 2); every block, every value, bit for bit.
    let hm = terrain(257, 193);
    let mut compared = 0;
    for (k, node_levels) in [(6u8, 5u8), (5, 3), (6, 2)] {
        let (dir, store) = bake_store(&hm, &format!("sub-max-{k}-{node_levels}"), k, node_levels);
        let v2_dir = scratch(&format!("sub-max-v2-{k}-{node_levels}"));
        let v2 = as_version_2(&dir, &v2_dir);
        for s in [&store, &v2] {
            for patch_level in 0..=k {
                for b in s.block_ids() {
                    let (fast, sweep) = crate::lod::block_sub_max_both(s, b, patch_level).unwrap();
                    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&fast), bits(&sweep), "k {k}, {node_levels} levels, block {b}");
                    compared += usize::from(fast.iter().any(|&v| v > 0.0));
                }
            }
        }
    }
    assert!(compared > 100, "{compared} blocks with positive maxima compared");
}

#[test]
fn the_fine_maxima_pyramid_equals_the_sweep_of_descendants() {
    // Every node above the deepest stored level of every block, every level below the stored
    // ones: the maximum read from the entry's pyramid is the sweep's, bit for bit; a version-2
    // store (no fine maxima) gives the block-wide bound both ways.
    let hm = terrain(257, 193);
    let (mut compared, mut positive) = (0, 0);
    for (k, node_levels) in [(6u8, 5u8), (5, 3), (6, 4)] {
        let (dir, store) = bake_store(&hm, &format!("fine-pyr-{k}-{node_levels}"), k, node_levels);
        let v2_dir = scratch(&format!("fine-pyr-v2-{k}-{node_levels}"));
        let v2 = as_version_2(&dir, &v2_dir);
        for s in [&store, &v2] {
            for b in s.block_ids() {
                for (fast, sweep) in crate::lod::below_bound_both(s, b).unwrap() {
                    assert_eq!(
                        fast.to_bits(),
                        sweep.to_bits(),
                        "k {k}, {node_levels} levels, block {b}"
                    );
                    compared += 1;
                    positive += usize::from(fast > 0.0);
                }
            }
        }
    }
    assert!(compared > 1000 && positive > 500, "{compared} maxima compared, {positive} positive");
}

#[test]
fn a_walk_ahead_leaves_the_next_selection_no_block_to_read_and_the_same_patches() {
    // Along a path over a 1025^2 grid in blocks of 65^2, a tree walked at each next camera by
    // a `TreeWarmer` (as a real-time frame asks it) selects the same patches as a tree without
    // one, and its selection at that camera reads no block and computes no value the walk did
    // not (its visited blocks and their bytes do not change); the tree without reads new
    // blocks as the path goes on (so the check could fail).
    let hm = terrain(1025, 1025);
    let (_dir, store) = bake_store(&hm, "warm", 6, 4);
    let all: Vec<(BlockId, u8)> = store.block_ids().map(|b| (b, 6)).collect();
    let levels: HashMap<BlockId, u8> = all.iter().copied().collect();
    let (cold, warm) = (eq7_tree(&store, 4), eq7_tree(&store, 4));
    let warmer = crate::TreeWarmer::spawn(&warm).unwrap();
    let path: Vec<Camera> = (0..8)
        .map(|k| {
            let eye = dvec3(100.0 + 900.0 * k as f64, 150.0 + 800.0 * k as f64, 420.0);
            Camera::from_yaw_pitch(eye, 45.0, -12.0).with_clip(1.0, 2500.0)
        })
        .collect();
    let tau = 1.0;
    let mut cold_reads = 0;
    for (k, cam) in path.iter().enumerate() {
        let before = cold.visited();
        let a = select_patches(&cold, cam, tau, |b| levels.get(&b).copied());
        cold_reads += usize::from(k > 0 && cold.visited() != before);
        warmer.wait_idle();
        let walked = warm.visited();
        let b = select_patches(&warm, cam, tau, |b| levels.get(&b).copied());
        assert_eq!(a.patches, b.patches, "camera {k}");
        assert!(!b.patches.is_empty(), "camera {k}");
        if k > 0 {
            assert_eq!(warm.visited(), walked, "camera {k}: read blocks the walk did not");
        }
        if let Some(next) = path.get(k + 1) {
            warmer.ahead(next, next, tau, all.clone());
        }
    }
    warmer.wait_idle();
    assert_eq!(warmer.walks(), path.len() as u64 - 1);
    assert!(cold_reads >= 4, "the path read new blocks at {cold_reads} cameras only");
}

/// The walk at the next frame's camera: along a path down the view direction (far clip past
/// the grid, so blocks only leave the view region), each frame drawing the blocks of the
/// streamer's M for its camera (`next_frame_levels` over every block), a `TreeWarmer` told the
/// next camera and this frame's drawn blocks leaves the next selection no block to read, and
/// the same patches as a tree without. Told another camera for that walk (a view off the grid)
/// and the next camera for the eye ahead, the frames read blocks first (the nodes that split
/// because a block left the drawn set, which the walk over this frame's blocks keeps whole):
/// the control.
#[test]
fn a_walk_at_the_next_camera_reads_what_the_blocks_left_behind_send_the_frame_into() {
    let hm = terrain(1025, 1025);
    let (_dir, store) = bake_store(&hm, "warm-next", 6, 4);
    let every = crate::BlockLevelGrid::new(&store.block_ids().map(|b| (b, 6)).collect::<Vec<_>>());
    let path: Vec<Camera> = (0..10)
        .map(|k| {
            let eye = dvec3(400.0 + 500.0 * k as f64, 400.0 + 500.0 * k as f64, 700.0);
            Camera::from_yaw_pitch(eye, 45.0, -15.0).with_clip(1.0, 40_000.0)
        })
        .collect();
    let off =
        Camera::from_yaw_pitch(dvec3(-9000.0, -9000.0, 700.0), 225.0, -15.0).with_clip(1.0, 2000.0);
    let tau = 1.0;
    // The prediction holds every block the streamer puts in M for the camera (its box bound is
    // looser than the entry's), and not every block.
    let config = crate::StreamConfig { threads: 1, tau, ..Default::default() };
    let mut streamer = crate::Streamer::new(store.clone(), config);
    let tree = eq7_tree(&store, 4);
    let mut left_out = 0;
    for cam in path.iter().step_by(3) {
        streamer.update(cam);
        let predict = crate::warm::next_frame_levels(&tree, cam, &every);
        let m: Vec<BlockId> =
            streamer.scheduled().iter().filter(|s| s.visible).map(|s| s.block).collect();
        assert!(!m.is_empty());
        for &b in &m {
            assert!(predict(b).is_some(), "{b} in M and not predicted");
        }
        let predicted = store.block_ids().filter(|&b| predict(b).is_some()).count();
        left_out += usize::from(predicted < store.block_ids().count());
        assert!(predicted <= m.len() * 3 / 2 + 4, "{predicted} predicted for {} in M", m.len());
    }
    assert!(left_out >= 2, "every block predicted at all but {left_out} cameras");
    let mut reads = [0usize; 2];
    let mut left = 0;
    for (control, reads) in reads.iter_mut().enumerate() {
        let (cold, warm) = (eq7_tree(&store, 4), eq7_tree(&store, 4));
        let warmer = crate::TreeWarmer::spawn(&warm).unwrap();
        let mut last: Option<Vec<(BlockId, u8)>> = None;
        for (k, cam) in path.iter().enumerate() {
            let predict = crate::warm::next_frame_levels(&cold, cam, &every);
            let drawn: Vec<(BlockId, u8)> =
                store.block_ids().filter_map(|b| Some((b, predict(b)?))).collect();
            let levels = crate::BlockLevelGrid::new(&drawn);
            if let Some(last) = &last {
                assert!(drawn.len() <= last.len(), "camera {k}: blocks entered the view");
                left += usize::from(control == 0 && drawn.len() < last.len());
                warmer.ahead(cam, if control == 0 { cam } else { &off }, tau, last.clone());
                warmer.wait_idle();
            }
            let a = select_patches(&cold, cam, tau, |b| levels.get(b));
            let walked = warm.visited();
            let b = select_patches(&warm, cam, tau, |b| levels.get(b));
            assert_eq!(a.patches, b.patches, "camera {k}");
            assert!(!b.patches.is_empty(), "camera {k}");
            if k > 0 && warm.visited() != walked {
                *reads += 1;
            }
            last = Some(drawn);
        }
    }
    assert!(left >= 5, "blocks left the view at {left} cameras only");
    assert_eq!(reads[0], 0, "the frames read blocks the walks did not");
    assert!(reads[1] >= 2, "without the walk at the next camera: reads at {} cameras", reads[1]);
}

/// `BlockLevelGrid` answers what a map of its blocks answers, for every block in and around
/// its rectangle: a compact set (an array over its rectangle), a set spread thinly along a
/// diagonal of a large grid (a map), an empty set, and blocks listed twice (the last level).
#[test]
fn block_level_grid_answers_as_a_map() {
    let mut sets: Vec<Vec<(BlockId, u8)>> = Vec::new();
    // Most blocks of a 40 x 25 rectangle away from the origin, levels 0-8, a few listed twice.
    let compact: Vec<(BlockId, u8)> = (0..25u32)
        .flat_map(|r| (0..40u32).map(move |c| (r, c)))
        .filter(|&(r, c)| (r * 7 + c * 3) % 5 != 0)
        .map(|(r, c)| (BlockId::new(300 + r, 1000 + c), ((r + c) % 9) as u8))
        .chain([(BlockId::new(301, 1001), 3), (BlockId::new(301, 1001), 7)])
        .collect();
    sets.push(compact);
    // A thin diagonal over 3000 x 3000 blocks: 9 M slots for 3000 blocks.
    sets.push((0..3000u32).map(|k| (BlockId::new(k, 2999 - k), (k % 6) as u8)).collect());
    sets.push(Vec::new());
    for (k, set) in sets.iter().enumerate() {
        let grid = crate::BlockLevelGrid::new(set);
        assert_eq!(grid.is_sparse(), k == 1, "set {k}");
        let map: HashMap<BlockId, u8> = set.iter().copied().collect();
        let (c0, r0) =
            set.iter().fold((u32::MAX, u32::MAX), |(c, r), (b, _)| (c.min(b.col), r.min(b.row)));
        let (c1, r1) = set.iter().fold((0, 0), |(c, r), (b, _)| (c.max(b.col), r.max(b.row)));
        let (c0, r0) =
            if set.is_empty() { (0, 0) } else { (c0.saturating_sub(3), r0.saturating_sub(3)) };
        let step = if k == 1 { 7 } else { 1 };
        let mut found = 0;
        for r in (r0..=r1 + 3).step_by(step) {
            for c in (c0..=c1 + 3).step_by(step) {
                let b = BlockId::new(r, c);
                assert_eq!(grid.get(b), map.get(&b).copied(), "set {k}, {b}");
                found += usize::from(map.contains_key(&b));
            }
        }
        // Each block of the set and its eight neighbours.
        for &(b, _) in set {
            for (dr, dc) in (0..3u32).flat_map(|r| (0..3u32).map(move |c| (r, c))) {
                let n =
                    BlockId::new((b.row + dr).saturating_sub(1), (b.col + dc).saturating_sub(1));
                assert_eq!(grid.get(n), map.get(&n).copied(), "set {k}, {n}");
                found += usize::from(map.contains_key(&n));
            }
        }
        assert!(set.is_empty() || found > 1000, "set {k}: {found} blocks of the set asked");
        assert_eq!(grid.get(BlockId::new(u32::MAX, u32::MAX)), None);
    }
}
