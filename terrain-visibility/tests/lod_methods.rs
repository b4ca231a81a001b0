//! Every LOD method of terrain-core's `lod` module on real roughness fields: shared-edge factor
//! agreement over many cameras and terrains, the CPU crack check, and the PVPS split's
//! behaviour on flat and rough terrain.

use glam::{DVec3, dvec3};
use terrain_core::geometry::Camera;
use terrain_core::lod::surface::fan_tessellation;
use terrain_core::lod::{
    DssConfig, DssErrorTable, GridSource, Method, PvpsConfig, Selection, build_surface,
    check_shared_edges, select_dss_power_of_two, select_dss_uniform, select_pvps,
};
use terrain_core::quadtree::{Quadtree, is_balanced};
use terrain_core::synth::{FractalConfig, HardCase};
use terrain_core::{Georef, Heightmap};
use terrain_visibility::roughness::{
    NodePyramid, RoughnessConfig, d2_pyramid, range_pyramid, roughness_pyramid,
};

/// A terrain with everything the methods need.
struct Scene {
    name: &'static str,
    hm: Heightmap,
    qt: Quadtree,
    fields: [(Method, NodePyramid); 3],
    dss: DssErrorTable,
}

impl Scene {
    fn new(name: &'static str, hm: Heightmap, leaf_cells: u32) -> Self {
        let qt = Quadtree::new(&hm, leaf_cells);
        let levels = qt.max_level() as usize + 1;
        let fields = [
            (Method::A, d2_pyramid(&hm, levels).normalized_255()),
            (Method::B, range_pyramid(&hm, levels).normalized_255()),
            (Method::C, roughness_pyramid(&hm, levels, &RoughnessConfig::default())),
        ];
        let dss = DssErrorTable::new(&hm, &qt);
        Self { name, hm, qt, fields, dss }
    }

    fn pvps_cfg(&self) -> PvpsConfig {
        PvpsConfig { leaf_cells: self.qt.leaf_cells(), max_level: 30, ..Default::default() }
    }

    fn dss_cfg(&self) -> DssConfig {
        DssConfig {
            leaf_cells: self.qt.leaf_cells(),
            uniform_block_cells: self.qt.leaf_cells() * 4,
            ..Default::default()
        }
    }

    /// Every method's selection for `cam`, named.
    fn all(&self, cam: &Camera, cull: bool) -> Vec<(String, Selection)> {
        let mut out = Vec::new();
        let pcfg = PvpsConfig { frustum_cull: cull, ..self.pvps_cfg() };
        for (m, f) in &self.fields {
            out.push((
                m.name().to_string(),
                select_pvps(&GridSource::new(&self.qt, &self.hm), cam, f, &pcfg),
            ));
        }
        let dcfg = DssConfig { frustum_cull: cull, ..self.dss_cfg() };
        out.push(("dss-1".into(), select_dss_power_of_two(&self.qt, cam, &self.dss, &dcfg)));
        out.push(("dss-2".into(), select_dss_uniform(&self.qt, cam, &self.dss, &dcfg)));
        out
    }

    fn extent(&self) -> (DVec3, DVec3) {
        let e = self.hm.extent_m();
        let o = self.hm.grid_to_world(0.0, 0.0);
        (o.extend(self.hm.min() as f64), (o + e).extend(self.hm.max() as f64))
    }
}

/// xorshift64*: deterministic cameras without a dependency.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    }

    fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.next()
    }
}

/// Grazing, straight down, far away and inside the terrain's box, each a few times.
fn cameras(s: &Scene, rng: &mut Rng) -> Vec<(&'static str, Camera)> {
    let (lo, hi) = s.extent();
    let size = (hi - lo).truncate().max_element();
    let mut out = Vec::new();
    for _ in 0..3 {
        let (x, y) = (rng.range(lo.x, hi.x), rng.range(lo.y, hi.y));
        let ground = s.hm.sample_world(glam::dvec2(x, y)) as f64;
        let yaw = rng.range(0.0, 360.0);
        out.push((
            "grazing",
            Camera::from_yaw_pitch(
                dvec3(x, y, ground + rng.range(1.0, 20.0)),
                yaw,
                rng.range(-3.0, 3.0),
            ),
        ));
        out.push((
            "straight down",
            Camera::from_yaw_pitch(dvec3(x, y, hi.z + rng.range(10.0, 500.0)), yaw, -90.0),
        ));
        let far = dvec3(
            (lo.x + hi.x) / 2.0 + rng.range(-10.0, 10.0) * size,
            (lo.y + hi.y) / 2.0 + rng.range(-10.0, 10.0) * size,
            hi.z + rng.range(1.0, 5.0) * size,
        );
        out.push(("far", Camera::look_at(far, (lo + hi) * 0.5).with_clip(1.0, 1e7)));
        let inside = dvec3(x, y, rng.range(lo.z, hi.z));
        out.push((
            "inside box",
            Camera::from_yaw_pitch_roll(
                inside,
                yaw,
                rng.range(-89.0, 89.0),
                rng.range(-30.0, 30.0),
            ),
        ));
    }
    // Exactly at a node corner, exactly on the terrain, straight down.
    let c = lo + (hi - lo) * 0.5;
    out.push(("on a corner", Camera::from_yaw_pitch(dvec3(c.x, c.y, hi.z), 0.0, -90.0)));
    out
}

fn scenes() -> Vec<Scene> {
    vec![
        Scene::new(
            "fractal 257",
            FractalConfig::with_size(257, 257, 10.0).to_heightmap().unwrap(),
            8,
        ),
        Scene::new("cliff", HardCase::Cliff.build(), 4),
        Scene::new("spike", HardCase::Spike.build(), 4),
        Scene::new("odd 1000x777", HardCase::OddSize.build(), 32),
    ]
}

fn on_border(g: [glam::DVec2; 2], w: f64, h: f64) -> bool {
    let [a, b] = g;
    (a.x == 0.0 && b.x == 0.0)
        || (a.y == 0.0 && b.y == 0.0)
        || (a.x == w && b.x == w)
        || (a.y == h && b.y == h)
}

#[test]
fn every_method_agrees_on_every_shared_edge() {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let mut checked = 0usize;
    let mut mixed_levels = 0usize;
    for s in scenes() {
        for (kind, cam) in cameras(&s, &mut rng) {
            for (name, sel) in s.all(&cam, true) {
                let what = format!("{} / {kind} / {name} at {}", s.name, cam.position);
                assert_eq!(check_shared_edges(&sel), [], "{what}");
                assert!(sel.factors_in_range(), "{what}: {:?}", sel.patches);
                let nodes: Vec<_> = sel.patches.iter().map(|p| p.node).collect();
                assert!(is_balanced(&nodes), "{what}");
                assert!(nodes.windows(2).all(|w| w[0].dfs_key() < w[1].dfs_key()), "{what}");
                assert_eq!(sel.stats.patches, sel.patches.len());
                let lo = nodes.iter().map(|n| n.level).min();
                if lo != nodes.iter().map(|n| n.level).max() {
                    mixed_levels += 1;
                }
                checked += 1;
            }
        }
    }
    assert!(checked >= 4 * 13 * 5);
    // The check is only meaningful if level changes happen often.
    assert!(mixed_levels > checked / 3, "{mixed_levels} of {checked}");
}

#[test]
fn selections_are_deterministic() {
    let s = Scene::new("cliff", HardCase::Cliff.build(), 4);
    let cam = Camera::from_yaw_pitch(dvec3(100.0, -50.0, 300.0), 20.0, -35.0);
    let a = s.all(&cam, true);
    let b = s.all(&cam, true);
    for ((n, x), (_, y)) in a.iter().zip(&b) {
        assert_eq!(x.patches, y.patches, "{n}");
    }
}

#[test]
fn surfaces_are_watertight_without_culling() {
    let mut rng = Rng(7);
    for s in scenes() {
        let (w, h) = ((s.hm.width() - 1) as f64, (s.hm.height() - 1) as f64);
        for (kind, cam) in cameras(&s, &mut rng).into_iter().step_by(3) {
            for (name, sel) in s.all(&cam, false) {
                let mesh = build_surface(&s.hm, &s.qt, &sel, fan_tessellation);
                let cracks: Vec<_> = mesh
                    .open_edges()
                    .into_iter()
                    .filter(|e| !on_border(e.map(|k| mesh.grid[k as usize]), w, h))
                    .collect();
                assert_eq!(cracks, Vec::<[u32; 2]>::new(), "{} / {kind} / {name}", s.name);
                assert!(mesh.positions.iter().all(|p| p.is_finite()));
            }
        }
    }
}

#[test]
fn flat_terrain_gets_fewer_patches_than_rough() {
    let rough =
        Scene::new("fractal", FractalConfig::with_size(257, 257, 10.0).to_heightmap().unwrap(), 8);
    let flat_hm = Heightmap::from_fn(257, 257, Georef::local(10.0), |_, _| 0.0).unwrap();
    let flat = Scene::new("flat", flat_hm, 8);
    let mut rng = Rng(99);
    for (kind, cam) in cameras(&rough, &mut rng) {
        let (_, r) = &rough.fields[2];
        let (_, f) = &flat.fields[2];
        assert!(f.level(0)[0] == 0.0 && r.level(0)[0] > 0.0);
        let cfg = rough.pvps_cfg();
        let a = select_pvps(&GridSource::new(&rough.qt, &rough.hm), &cam, r, &cfg);
        let b = select_pvps(&GridSource::new(&flat.qt, &flat.hm), &cam, f, &cfg);
        assert!(b.factors_in_range() && a.factors_in_range());
        if kind == "grazing" || kind == "straight down" {
            assert!(
                b.stats.patches < a.stats.patches,
                "{kind}: flat {} vs rough {}",
                b.stats.patches,
                a.stats.patches
            );
        } else if kind != "inside box" {
            // (A camera inside the rough terrain's box may be under its surface, looking at
            // different parts of the two terrains: no comparison.)
            assert!(b.stats.patches <= a.stats.patches, "{kind}");
        }
    }
}

#[test]
fn larger_c1_never_selects_more_patches() {
    // Eq. 8 has C1 in the numerator: ratio = C1 D / (Span (R + C2)), split below 1. A larger C1
    // raises every ratio, so every node that splits at a larger C1 also splits at a smaller
    // one: without culling the selection only coarsens as C1 grows (balancing preserves that).
    let s =
        Scene::new("fractal", FractalConfig::with_size(257, 257, 10.0).to_heightmap().unwrap(), 4);
    let (_, field) = &s.fields[2];
    let mut rng = Rng(3);
    for (kind, cam) in cameras(&s, &mut rng) {
        let mut last = usize::MAX;
        let mut counts = Vec::new();
        for c1 in [5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 1000.0] {
            let cfg = PvpsConfig { c1, frustum_cull: false, ..s.pvps_cfg() };
            let n = select_pvps(&GridSource::new(&s.qt, &s.hm), &cam, field, &cfg).stats.patches;
            assert!(n <= last, "{kind}: {counts:?} then {n}");
            counts.push(n);
            last = n;
        }
        assert!(counts[0] > *counts.last().unwrap(), "{kind}: {counts:?}");
    }
}

#[test]
fn frustum_culling_drops_patches_behind_the_camera() {
    let s =
        Scene::new("fractal", FractalConfig::with_size(257, 257, 10.0).to_heightmap().unwrap(), 8);
    let (_, field) = &s.fields[2];
    let cam = Camera::from_yaw_pitch(dvec3(1280.0, 1280.0, 2500.0), 0.0, -10.0);
    let behind = |sel: &Selection| {
        sel.patches
            .iter()
            .filter(|p| {
                let b = s.qt.node_info(p.node).unwrap().aabb;
                b.corners().iter().all(|c| (*c - cam.position).dot(cam.forward()) < 0.0)
            })
            .count()
    };
    let on = select_pvps(&GridSource::new(&s.qt, &s.hm), &cam, field, &s.pvps_cfg());
    let off = select_pvps(
        &GridSource::new(&s.qt, &s.hm),
        &cam,
        field,
        &PvpsConfig { frustum_cull: false, ..s.pvps_cfg() },
    );
    assert!(behind(&off) > 0);
    assert_eq!(behind(&on), 0);
    assert!(on.stats.culled > 0 && off.stats.culled == 0);
    assert!(on.stats.patches < off.stats.patches);
    let dcfg = DssConfig { frustum_cull: true, ..s.dss_cfg() };
    assert_eq!(behind(&select_dss_power_of_two(&s.qt, &cam, &s.dss, &dcfg)), 0);
    assert_eq!(behind(&select_dss_uniform(&s.qt, &cam, &s.dss, &dcfg)), 0);
}

#[test]
fn straight_down_and_inside_a_node_box_give_finite_factors() {
    for s in [
        Scene::new("spike", HardCase::Spike.build(), 4),
        Scene::new("cliff", HardCase::Cliff.build(), 4),
    ] {
        let (lo, hi) = s.extent();
        let mid = (lo + hi) * 0.5;
        for cam in [
            // Straight down, right above the spike / the cliff's step.
            Camera::from_yaw_pitch(dvec3(320.0, 320.0, hi.z + 50.0), 0.0, -90.0),
            // Inside the root's and a finest node's box, looking anywhere.
            Camera::from_yaw_pitch(dvec3(mid.x, mid.y, mid.z), 0.0, 0.0),
            Camera::from_yaw_pitch(dvec3(5.0, 5.0, hi.z * 0.5), 45.0, -89.9),
            // On a sample, at exactly its height.
            Camera::from_yaw_pitch(dvec3(320.0, 320.0, s.hm.get(32, 32) as f64), 90.0, -90.0),
        ] {
            for (name, sel) in s.all(&cam, true) {
                assert!(sel.factors_in_range(), "{} {name}", s.name);
                assert_eq!(check_shared_edges(&sel), [], "{} {name}", s.name);
                assert!(!sel.patches.is_empty(), "{} {name}", s.name);
            }
        }
        // A camera inside a finest node's box (the node straddling the cliff's step or holding
        // the spike: grid 28..=32, heights 0 to the top) splits the PVPS quadtree down to it.
        let cam = Camera::from_yaw_pitch(dvec3(310.0, 310.0, 250.0), 45.0, -30.0);
        let inside = terrain_core::quadtree::NodeId::new(4, 7, 7);
        assert!(s.qt.node_info(inside).unwrap().aabb.contains(cam.position));
        let (_, f) = &s.fields[2];
        let sel = select_pvps(&GridSource::new(&s.qt, &s.hm), &cam, f, &s.pvps_cfg());
        assert!(sel.patch(inside).is_some(), "{}", s.name);
        assert!(sel.factors_in_range());
        assert_eq!(sel.stats.max_level, s.qt.max_level());
    }
}
