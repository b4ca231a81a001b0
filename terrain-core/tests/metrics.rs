//! Integration tests of `terrain_core::metrics`: planes, spikes, StaticE monotonicity, DSS
//! factor behaviour, translation invariance and the degenerate cases.

use glam::{DVec2, DVec3, dvec2, dvec3};
use proptest::prelude::*;
use terrain_core::metrics::geomorph::{self, Reference};
use terrain_core::metrics::static_error::{StaticErrorPyramid, node_error};
use terrain_core::metrics::{Coverage, Region, dss, pvps, screen};
use terrain_core::{Crs, Georef, Heightmap, VoidMask};

/// splitmix64: a seeded generator so every terrain is reproducible from its seed.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn random_heights(w: usize, h: usize, seed: u64, amp: f64) -> Vec<f32> {
    let mut r = Rng(seed);
    (0..w * h).map(|_| (r.unit() * amp) as f32).collect()
}

fn hm_from(w: usize, h: usize, data: Vec<f32>, georef: Georef) -> Heightmap {
    Heightmap::new(w, h, data, VoidMask::new(w, h), georef).unwrap()
}

fn local(w: usize, h: usize, f: impl FnMut(usize, usize) -> f32) -> Heightmap {
    Heightmap::from_fn(w, h, Georef::local(1.0), f).unwrap()
}

/// Every StaticE and H of a pyramid, flattened.
fn pyramid_values(p: &StaticErrorPyramid) -> Vec<f64> {
    let mut v = Vec::new();
    for l in 0..p.levels() {
        let n = p.nodes_per_side(l);
        for j in 0..n {
            for i in 0..n {
                v.push(p.get(l, i, j));
                v.push(p.h(l, i, j));
            }
        }
    }
    v
}

// ---------------------------------------------------------------------------------------------
// Planes: zero error in every metric that measures error.

fn assert_plane_zero(hm: &Heightmap, tol: f64) {
    let p = StaticErrorPyramid::build(hm, 8);
    assert!(p.levels() >= 3);
    for v in pyramid_values(&p) {
        assert!(v.abs() <= tol, "StaticE/H of a plane: {v}");
    }
    for region in [Region::new(0, 0, 16), Region::new(4, 8, 8), Region::new(16, 16, 32)] {
        let e = dss::object_errors(hm, region);
        assert!(e.coverage.is_measured());
        for k in 0..dss::FACTORS {
            assert!(e.avg[k] <= tol && e.max[k] <= tol, "DSS f={} {e:?}", dss::factor(k));
        }
        for f in [1, 3, 5, 7, 13, 33] {
            assert!(dss::object_error(hm, region, f).max <= tol, "DSS odd f={f}");
        }
    }
    for reference in [Reference::FullResolution, Reference::PreviousLevel] {
        let levels = geomorph::max_error_vertices(hm, Region::new(8, 16, 16), reference);
        assert_eq!(levels.len(), geomorph::PATCH_LEVELS);
        for l in &levels {
            assert!(l.error <= tol, "geomorph {reference:?} level {}: {}", l.level, l.error);
        }
        assert!(levels[1..].iter().all(|l| l.vertex.is_some()));
    }
}

#[test]
fn plane_has_zero_error_exact_dyadic() {
    let hm = local(41, 37, |i, j| 0.5 * i as f32 - 0.25 * j as f32 + 100.0);
    assert_plane_zero(&hm, 1e-9);
}

#[test]
fn plane_has_zero_error_any_tilt() {
    let mut r = Rng(7);
    for _ in 0..5 {
        let (a, b, c) = (r.unit() * 8.0 - 4.0, r.unit() * 8.0 - 4.0, r.unit() * 1000.0);
        let hm = local(49, 49, |i, j| (a * i as f64 + b * j as f64 + c) as f32);
        // f32 storage rounds the samples (about 1e-4 m at these heights); the interpolants of
        // the rounded samples differ from the rounded samples by about that much.
        assert_plane_zero(&hm, 1e-3);
    }
}

// ---------------------------------------------------------------------------------------------
// A single spike of height h on a flat plain.

const H: f32 = 37.0;
const BASE: f32 = 120.0;

fn spike(w: usize, at: (usize, usize)) -> Heightmap {
    local(w, w, |i, j| if (i, j) == at { BASE + H } else { BASE })
}

#[test]
fn static_error_spike_at_odd_position() {
    // (3, 5): odd/odd, so it is the centre of one finest (2-cell) node and nothing coarser
    // measures it. H = h exactly there, 0 at every other node; StaticE carries h to the root.
    let hm = spike(17, (3, 5));
    let p = StaticErrorPyramid::build(&hm, 4);
    assert_eq!(p.levels(), 4);
    for l in 0..4 {
        let n = p.nodes_per_side(l);
        for j in 0..n {
            for i in 0..n {
                let expect_h = if l == 3 && (i, j) == (1, 2) { f64::from(H) } else { 0.0 };
                assert_eq!(p.h(l, i, j), expect_h, "H level {l} ({i}, {j})");
                let r = p.region(l, i, j);
                let contains =
                    (r.x0..=r.x0 + r.cells).contains(&3) && (r.y0..=r.y0 + r.cells).contains(&5);
                let expect_e = if contains { f64::from(H) } else { 0.0 };
                assert_eq!(p.get(l, i, j), expect_e, "StaticE level {l} ({i}, {j})");
            }
        }
    }
}

#[test]
fn static_error_spike_at_centre() {
    // (8, 8) is dropped by the root (its centre): H = h. Every finer level keeps it as a
    // corner; the spike's own error there is 0, but the coarse surface leans on it, so the
    // midpoints next to it are off by exactly h / 2; nodes away from it are exact.
    let hm = spike(17, (8, 8));
    let root = node_error(&hm, Region::new(0, 0, 16));
    assert_eq!(root.error, f64::from(H));
    assert_eq!(root.coverage, Coverage::Measured { samples: 6 });
    let p = StaticErrorPyramid::build(&hm, 4);
    assert_eq!(p.h(0, 0, 0), f64::from(H));
    for l in 1..4 {
        let n = p.nodes_per_side(l);
        for j in 0..n {
            for i in 0..n {
                let r = p.region(l, i, j);
                let corner =
                    [r.x0, r.x0 + r.cells].contains(&8) && [r.y0, r.y0 + r.cells].contains(&8);
                let expect = if corner { f64::from(H) / 2.0 } else { 0.0 };
                assert_eq!(p.h(l, i, j), expect, "level {l} ({i}, {j})");
            }
        }
    }
}

#[test]
fn dss_spike() {
    // Spike at (3, 5) of a 16-cell block: factors whose vertices miss it (2, 4, 8) see a flat
    // surface: max = h, avg = h / 289 exactly; factors that put a vertex on every sample
    // (multiples of 16) are exact.
    let hm = spike(17, (3, 5));
    let e = dss::object_errors(&hm, Region::new(0, 0, 16));
    for f in [2, 4, 8] {
        let k = f / 2 - 1;
        assert_eq!(e.max[k], f64::from(H), "f = {f}");
        assert!((e.avg[k] - f64::from(H) / 289.0).abs() < 1e-12, "f = {f}");
    }
    for f in [16, 32, 48, 64] {
        let k = f / 2 - 1;
        assert_eq!(e.max[k], 0.0, "f = {f}");
        assert_eq!(e.avg[k], 0.0, "f = {f}");
    }
    assert_eq!(e.coverage, Coverage::Measured { samples: 289 });
}

#[test]
fn geomorph_spike_dropped_at_level_1() {
    let hm = spike(17, (3, 5));
    let prev = geomorph::max_error_vertices(&hm, Region::new(0, 0, 16), Reference::PreviousLevel);
    assert_eq!(prev[0].error, 0.0);
    assert!(prev[0].vertex.is_none());
    let v = prev[1].vertex.unwrap();
    assert_eq!((v.i, v.j, v.error), (3, 5, f64::from(H)));
    assert_eq!(v.offset, dvec3(3.0, 5.0, f64::from(BASE + H)));
    assert_eq!(v.coarse_height, f64::from(BASE));
    for l in &prev[2..] {
        assert_eq!(l.error, 0.0, "level {}", l.level);
    }
    // The article's reference: every coarser level misses it too.
    let full = geomorph::max_error_vertices(&hm, Region::new(0, 0, 16), Reference::FullResolution);
    for l in &full[1..] {
        assert_eq!(l.error, f64::from(H), "level {}", l.level);
        assert_eq!(l.vertex.map(|v| (v.i, v.j)), Some((3, 5)));
    }
}

#[test]
fn geomorph_spike_dropped_at_level_3() {
    // (4, 8): kept by levels 0-2, dropped by level 3 (step 8). PreviousLevel: h at level 3, 0
    // at level 4; levels 1-2 keep it as a vertex and their dropped neighbours lean on it: h/2.
    let hm = spike(17, (4, 8));
    let prev = geomorph::max_error_vertices(&hm, Region::new(0, 0, 16), Reference::PreviousLevel);
    assert_eq!(prev[3].error, f64::from(H));
    assert_eq!(prev[3].vertex.map(|v| (v.i, v.j)), Some((4, 8)));
    assert_eq!(prev[4].error, 0.0);
    assert_eq!(prev[1].error, f64::from(H) / 2.0);
    assert_eq!(prev[2].error, f64::from(H) / 2.0);
    let full = geomorph::max_error_vertices(&hm, Region::new(0, 0, 16), Reference::FullResolution);
    assert_eq!(full[3].error, f64::from(H));
    assert_eq!(full[4].error, f64::from(H));
    assert_eq!(full[1].error, f64::from(H) / 2.0);
}

// ---------------------------------------------------------------------------------------------
// StaticE is monotone: proptest over seeded random grids 17x17..65x65 (with voids).

fn random_voided(w: usize, h: usize, seed: u64) -> Heightmap {
    let data = random_heights(w, h, seed, 500.0);
    let mut mask = VoidMask::new(w, h);
    let mut r = Rng(seed ^ 0xABCD);
    for j in 0..h {
        for i in 0..w {
            if r.unit() < 0.1 {
                mask.set(i, j, true);
            }
        }
    }
    Heightmap::new(w, h, data, mask, Georef::local(10.0)).unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn static_e_is_monotone(w in 17usize..=65, h in 17usize..=65, seed in any::<u64>(), levels in 1usize..=8) {
        let hm = random_voided(w, h, seed);
        let p = StaticErrorPyramid::build(&hm, levels);
        for l in 0..p.levels() {
            let n = p.nodes_per_side(l);
            for j in 0..n {
                for i in 0..n {
                    let e = p.get(l, i, j);
                    prop_assert!(e.is_finite() && e >= p.h(l, i, j));
                    if l + 1 < p.levels() {
                        for (ci, cj) in [(2 * i, 2 * j), (2 * i + 1, 2 * j), (2 * i, 2 * j + 1), (2 * i + 1, 2 * j + 1)] {
                            prop_assert!(e >= p.get(l + 1, ci, cj), "parent {} < child {}", e, p.get(l + 1, ci, cj));
                        }
                    }
                }
            }
        }
        // Eq. 3 as the paper writes it: StaticE(root) = max of H over every node of every level.
        let all_h = (0..p.levels())
            .flat_map(|l| {
                let n = p.nodes_per_side(l);
                (0..n * n).map(move |k| (l, k % n, k / n))
            })
            .map(|(l, i, j)| p.h(l, i, j))
            .fold(0.0f64, f64::max);
        prop_assert_eq!(p.get(0, 0, 0), all_h);
    }

    // DSS: zero at f = block cells for any terrain and any block size.
    #[test]
    fn dss_zero_at_f_equal_cells(seed in any::<u64>(), cells in 1usize..=64, x0 in 0usize..8, y0 in 0usize..8) {
        let w = 72;
        let hm = hm_from(w, w, random_heights(w, w, seed, 300.0), Georef::local(5.0));
        let e = dss::object_error(&hm, Region::new(x0, y0, cells), cells);
        prop_assert_eq!(e.max, 0.0);
        prop_assert_eq!(e.avg, 0.0);
        prop_assert!(e.coverage.is_measured());
        // And at every multiple of the cells up to 64 (every sample is still a vertex).
        for f in (cells..=64).step_by(cells) {
            prop_assert!(dss::object_error(&hm, Region::new(x0, y0, cells), f).max < 1e-9);
        }
    }

    // DSS: non-increasing over the dividing (nested) factors of the block, on convex separable
    // terrain, where it holds (the finer interpolant lies between the coarser one and the
    // surface). It does not hold for general terrain: see dss_not_monotone_in_general.
    #[test]
    fn dss_non_increasing_over_dividing_factors(seed in any::<u64>(), log_cells in 1u32..=6) {
        let cells = 1usize << log_cells;
        let mut r = Rng(seed);
        let mut slopes = |n: usize| {
            let mut s: Vec<f64> = (0..n).map(|_| r.unit() * 10.0 - 5.0).collect();
            s.sort_by(f64::total_cmp);
            let mut z = vec![0.0];
            for d in s { z.push(z.last().unwrap() + d); }
            z
        };
        let (gx, gy) = (slopes(cells), slopes(cells));
        let hm = local(cells + 1, cells + 1, |i, j| (gx[i] + gy[j]) as f32);
        let region = Region::new(0, 0, cells);
        let mut prev = dss::object_error(&hm, region, 1);
        let mut f = 2;
        while f <= 64 {
            let e = dss::object_error(&hm, region, f);
            // f32 samples: allow their rounding.
            prop_assert!(e.avg <= prev.avg + 1e-4, "avg f={} {} > {}", f, e.avg, prev.avg);
            prop_assert!(e.max <= prev.max + 1e-4, "max f={} {} > {}", f, e.max, prev.max);
            if f >= cells { prop_assert_eq!(e.max, 0.0); }
            prev = e;
            f *= 2;
        }
    }
}

#[test]
fn dss_not_monotone_in_general() {
    // Pinned counterexamples to "delta decreases with the factor", for factors dividing the
    // block. (1) A pit at (4, 4) of a 16-cell block: at f = 2 only the pit is wrong; at f = 4
    // the pit is a vertex and its bilinear tent is wrong at 15 other samples: avg goes up.
    let hm = local(17, 17, |i, j| if (i, j) == (4, 4) { -8.0 } else { 0.0 });
    let r = Region::new(0, 0, 16);
    let (e2, e4) = (dss::object_error(&hm, r, 2), dss::object_error(&hm, r, 4));
    assert_eq!(e2.max, 8.0);
    assert_eq!(e4.max, 6.0);
    assert!((e2.avg - 8.0 / 289.0).abs() < 1e-12);
    assert!((e4.avg - 8.0 * 15.0 / 289.0).abs() < 1e-12);
    assert!(e4.avg > e2.avg);
    // (2) An alternating bump (+1 at x = 1, -1 at x = 2) of an 8-cell block: max goes up.
    let hm = local(9, 9, |i, _| match i {
        1 => 1.0,
        2 => -1.0,
        _ => 0.0,
    });
    let r = Region::new(0, 0, 8);
    let (e2, e4) = (dss::object_error(&hm, r, 2), dss::object_error(&hm, r, 4));
    assert_eq!(e2.max, 1.0);
    assert_eq!(e4.max, 1.5);
    // The envelope restores the paper's assumption.
    let env = dss::object_errors(&hm, r).monotone_envelope();
    assert!(env.max.windows(2).all(|w| w[0] >= w[1]));
    assert_eq!(env.max[0], 1.5);
}

// ---------------------------------------------------------------------------------------------
// Translation invariance: the same terrain at (0, 0) and at a UTM-like projected origin.

fn all_metrics(hm: &Heightmap, eye_rel: DVec3) -> Vec<f64> {
    let o = hm.georef().world_origin;
    let eye = o.extend(0.0) + eye_rel;
    let mut v = pyramid_values(&StaticErrorPyramid::build(hm, 6));
    let view = dvec3(0.6, 0.7, -0.4);
    let lambda = screen::lambda(1080.0, 1.0);
    for region in [Region::new(0, 0, 16), Region::new(16, 32, 16), Region::new(32, 0, 32)] {
        let e = dss::object_errors(hm, region);
        v.extend(e.avg);
        v.extend(e.max);
        let b = screen::NodeBox::of(hm, region).unwrap();
        let d = b.distance(eye);
        v.push(d);
        let rho = dss::screen_errors(&e.avg, lambda, d, view);
        v.extend(rho);
        if let dss::Tessellation::Factor(f) = dss::tessellation_factor(&rho, 0.5) {
            v.push(f);
        }
        let delta = node_error(hm, region).error;
        v.push(screen::plain(lambda, delta, d));
        v.push(screen::sight_line_eq7(lambda, delta, d, view, b.eye_to_centre(eye)));
        let (rough, _) = pvps::region_roughness(hm, region);
        v.push(rough);
        v.push(pvps::split_ratio(d, pvps::span(hm.extent_m().x, 2), rough, 3.0, 1.0));
        for reference in [Reference::FullResolution, Reference::PreviousLevel] {
            for l in geomorph::max_error_vertices(hm, region, reference) {
                v.push(l.error);
                if let Some(mv) = l.vertex {
                    v.extend([mv.offset.x, mv.offset.y, mv.offset.z, mv.coarse_height]);
                }
            }
        }
    }
    v
}

#[test]
fn translation_invariance() {
    let (w, h) = (65, 65);
    let data = random_heights(w, h, 42, 800.0);
    let spacing = dvec2(30.0, 30.0);
    let at = |origin: DVec2| {
        hm_from(w, h, data.clone(), Georef::projected(Crs::Epsg(32611), origin, spacing))
    };
    let near = at(DVec2::ZERO);
    let far = at(dvec2(500_000.0, 4_000_000.0));
    for eye_rel in
        [dvec3(-300.0, 250.5, 900.0), dvec3(700.25, 1100.0, 400.0), dvec3(500.0, 500.0, 100.0)]
    {
        let (a, b) = (all_metrics(&near, eye_rel), all_metrics(&far, eye_rel));
        assert_eq!(a.len(), b.len());
        assert!(a.len() > 500 && a.iter().any(|&x| x > 0.0));
        for (k, (x, y)) in a.iter().zip(&b).enumerate() {
            let tol = 1e-6 * x.abs().max(y.abs());
            assert!(x == y || (x - y).abs() <= tol, "metric #{k}: {x} vs {y}");
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Degenerate cases.

#[test]
fn zero_area_regions_are_empty() {
    let hm = local(17, 17, |i, j| (i * j) as f32);
    for r in
        [Region::new(0, 0, 0), Region::new(17, 0, 8), Region::new(0, 30, 8), Region::new(16, 4, 8)]
    {
        let n = node_error(&hm, r);
        assert_eq!((n.error, n.coverage), (0.0, Coverage::Empty), "{r:?}");
        let e = dss::object_errors(&hm, r);
        assert_eq!(e.coverage, Coverage::Empty);
        assert!(e.avg.iter().chain(&e.max).all(|&x| x == 0.0));
        let g = geomorph::max_error_vertices(&hm, r, Reference::FullResolution);
        assert_eq!(g.len(), 1);
        assert_eq!(g[0].coverage, Coverage::Empty);
        assert_eq!(pvps::region_roughness(&hm, r), (0.0, Coverage::Empty));
        assert!(screen::NodeBox::of(&hm, r).is_none());
    }
    // A node too small to drop a vertex (1 cell) is Empty for H as well.
    assert_eq!(node_error(&hm, Region::new(3, 3, 1)).coverage, Coverage::Empty);
    // A 2x2 grid still builds a one-level pyramid.
    let tiny = local(2, 2, |i, j| (i + j) as f32);
    let p = StaticErrorPyramid::build(&tiny, 5);
    assert_eq!((p.levels(), p.get(0, 0, 0)), (1, 0.0));
}

#[test]
fn clipped_regions_measure_only_the_grid() {
    // A 20x20 grid: a 16-cell node at (8, 8) is clipped to samples 8..=19.
    let hm = local(20, 20, |i, j| 0.5 * i as f32 + 0.25 * j as f32);
    let r = Region::new(8, 8, 16);
    // The clipped block is tessellated over its extent (11 x 11 cells): a plane stays exact.
    for f in [2, 4, 11, 16, 64] {
        let e = dss::object_error(&hm, r, f);
        assert_eq!(e.coverage, Coverage::Measured { samples: 144 });
        assert!(e.max < 1e-9, "f = {f}: {}", e.max);
    }
    let n = node_error(&hm, r);
    assert!(n.error < 1e-9);
    // South and west edge midpoints (16, 8) and (8, 16) and the centre (16, 16), measured
    // twice (once per diagonal), are on the grid; the north and east midpoints are not.
    assert_eq!(n.coverage, Coverage::Measured { samples: 4 });
    let g = geomorph::max_error_vertices(&hm, r, Reference::FullResolution);
    assert_eq!(g.len(), 5);
    assert!(g.iter().all(|l| l.error < 1e-9 && l.coverage.is_measured()));
}

fn voided(w: usize, spike_at: (usize, usize), void: impl Fn(usize, usize) -> bool) -> Heightmap {
    let data: Vec<f32> =
        (0..w * w).map(|k| if (k % w, k / w) == spike_at { BASE + H } else { BASE }).collect();
    let mut mask = VoidMask::new(w, w);
    for j in 0..w {
        for i in 0..w {
            if void(i, j) {
                mask.set(i, j, true);
            }
        }
    }
    Heightmap::new(w, w, data, mask, Georef::local(1.0)).unwrap()
}

#[test]
fn void_only_nodes_have_zero_error_and_say_so() {
    // The south-west 9x9 samples are void (spike inside them); the rest of the grid is not.
    let hm = voided(33, (3, 5), |i, j| i <= 8 && j <= 8);
    let r = Region::new(0, 0, 8);
    let n = node_error(&hm, r);
    assert_eq!((n.error, n.coverage), (0.0, Coverage::VoidOnly));
    let e = dss::object_errors(&hm, r);
    assert_eq!(e.coverage, Coverage::VoidOnly);
    assert!(e.avg.iter().chain(&e.max).all(|&x| x == 0.0));
    for reference in [Reference::FullResolution, Reference::PreviousLevel] {
        let g = geomorph::max_error_vertices(&hm, r, reference);
        assert_eq!(g.len(), 4);
        assert!(
            g.iter()
                .all(|l| l.coverage == Coverage::VoidOnly && l.error == 0.0 && l.vertex.is_none())
        );
    }
    assert_eq!(pvps::region_roughness(&hm, r), (0.0, Coverage::VoidOnly));
    // The pyramid's finest node holding the (void) spike as its centre is 0.
    let p = StaticErrorPyramid::build(&hm, 5);
    assert_eq!(p.region(4, 1, 2), Region::new(2, 4, 2));
    assert_eq!(p.get(4, 1, 2), 0.0);
}

#[test]
fn errors_skip_void_samples() {
    // The spike sample itself is void: it is never measured. Its filled height is still
    // geometry, but for factors dividing the block every tessellated vertex sits on a sample
    // other than the spike (f = 2, 4, 8) or every sample is a vertex (f >= 16), so the
    // measured samples see a flat surface. (Non-dividing factors put vertices between the
    // spike and its neighbours and do see it: that is geometry, not measurement.)
    let hm = voided(17, (3, 5), |i, j| (i, j) == (3, 5));
    let r = Region::new(0, 0, 16);
    let e = dss::object_errors(&hm, r);
    assert_eq!(e.coverage, Coverage::Measured { samples: 288 });
    for f in [2, 4, 8, 16, 32, 64] {
        assert_eq!(e.max[f / 2 - 1], 0.0, "f = {f}");
    }
    let g = geomorph::max_error_vertices(&hm, r, Reference::FullResolution);
    assert!(g.iter().all(|l| l.error == 0.0));
    assert_eq!(StaticErrorPyramid::build(&hm, 4).get(0, 0, 0), 0.0);
}

#[test]
fn camera_inside_box_must_split() {
    let hm = local(33, 33, |i, j| ((i * 7 + j * 13) % 11) as f32);
    let r = Region::new(0, 0, 16);
    let b = screen::NodeBox::of(&hm, r).unwrap();
    let eye = b.centre();
    assert_eq!(b.distance(eye), 0.0);
    let e = dss::object_errors(&hm, r);
    let lambda = screen::lambda(1080.0, 1.0);
    let rho = dss::screen_errors(&e.avg, lambda, b.distance(eye), dvec3(1.0, 0.0, -0.2));
    assert!(rho[0].is_infinite());
    // A 16-cell block is exact at f = 64 (every sample a vertex, rho_32 = 0): no split, but
    // the finest factor.
    assert_eq!(rho[dss::FACTORS - 1], 0.0);
    assert_eq!(dss::tessellation_factor(&rho, 1.0), dss::Tessellation::Factor(64.0));
    // A 128-cell block is not exact even at 64: with the camera inside it must split.
    let big = local(129, 129, |i, j| ((i * 7 + j * 13) % 11) as f32);
    let rb = Region::new(0, 0, 128);
    let bb = screen::NodeBox::of(&big, rb).unwrap();
    let eb = dss::object_errors(&big, rb);
    assert!(eb.avg[dss::FACTORS - 1] > 0.0);
    let rho = dss::screen_errors(&eb.avg, lambda, bb.distance(bb.centre()), DVec3::X);
    assert_eq!(dss::tessellation_factor(&rho, 1.0), dss::Tessellation::MustSplit);
    let delta = node_error(&hm, r).error;
    assert!(delta > 0.0);
    assert_eq!(screen::plain(lambda, delta, 0.0), screen::MUST_SPLIT);
    assert_eq!(
        screen::sight_line_eq7(lambda, delta, 0.0, DVec3::X, b.eye_to_centre(eye)),
        screen::MUST_SPLIT
    );
    // PVPS: D = 0 gives ratio 0, a split.
    let ratio = pvps::split_ratio(b.distance(eye), pvps::span(32.0, 1), 2.0, 3.0, 1.0);
    assert_eq!(ratio, 0.0);
    assert!(pvps::should_split(ratio));
    // An exact (flat) node never needs a split, even with the camera inside: 0, not NaN.
    assert_eq!(screen::plain(lambda, 0.0, 0.0), 0.0);
    assert_eq!(dss::tessellation_factor(&[0.0; dss::FACTORS], 1.0), dss::Tessellation::Factor(2.0));
}

#[test]
fn looking_straight_down_still_refines() {
    let lambda = screen::lambda(1000.0, 1.2);
    let down = dvec3(0.0, 0.0, -1.0);
    let rho = screen::dss(lambda, 2.0, 50.0, down);
    assert!(rho.is_finite() && rho > 0.0);
    assert_eq!(rho, screen::plain(lambda, 2.0, 50.0) * screen::MIN_VIEW_SIN);
    // Nearly straight down is floored too; far from vertical is untouched.
    let nearly = dvec3(1e-9, 0.0, -1.0);
    assert_eq!(screen::view_sin(nearly), screen::MIN_VIEW_SIN);
    let oblique = dvec3(1.0, 1.0, -1.0);
    assert!((screen::view_sin(oblique) - (2.0f64 / 3.0).sqrt()).abs() < 1e-12);
    // F_thr is a finite factor (or a split) for the straight-down view of a rough block.
    let hm = local(17, 17, |i, j| ((i * 31 + j * 17) % 7) as f32);
    let e = dss::object_errors(&hm, Region::new(0, 0, 16));
    let rho = dss::screen_errors(&e.avg, lambda, 40.0, down);
    assert!(rho.iter().all(|x| x.is_finite()));
    assert!(rho[0] > 0.0);
    match dss::tessellation_factor(&rho, 1.0) {
        dss::Tessellation::Factor(f) => assert!((2.0..=64.0).contains(&f)),
        dss::Tessellation::MustSplit => assert!(rho[dss::FACTORS - 1] > 1.0),
    }
}

#[test]
fn angles_at_their_limits_are_finite() {
    for fov in [0.0, -1.0, 1e-12, std::f64::consts::PI, 10.0, f64::NAN] {
        let l = screen::lambda(1080.0, fov);
        assert!(l.is_finite() && l > 0.0, "fov {fov}: {l}");
    }
    for view in [DVec3::ZERO, dvec3(f64::NAN, 0.0, 0.0), DVec3::Z, -DVec3::Z, DVec3::X] {
        for to_node in [DVec3::ZERO, DVec3::X, -DVec3::X, DVec3::Y, dvec3(f64::INFINITY, 0.0, 0.0)]
        {
            let b = screen::beta(view, to_node);
            assert!((0.0..=std::f64::consts::FRAC_PI_2).contains(&b));
            let rho = screen::sight_line_eq7(100.0, 1.0, 10.0, view, to_node);
            assert!(rho.is_finite() && rho > 0.0);
            // Eq. 7 lies between half of Eq. 6 and Eq. 6.
            let e6 = screen::sight_line_eq6(100.0, 1.0, 10.0, view);
            assert!(rho <= e6 && rho >= e6 / 2.0 - 1e-12);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// The fast 32-factor DSS errors equal the single-factor reference bit for bit.

fn assert_dss_fast_equals_reference(hm: &Heightmap, region: Region) {
    let fast = dss::object_errors(hm, region);
    for k in 0..dss::FACTORS {
        let one = dss::object_error(hm, region, dss::factor(k));
        assert_eq!(
            (fast.avg[k].to_bits(), fast.max[k].to_bits()),
            (one.avg.to_bits(), one.max.to_bits()),
            "{region:?} factor {}: fast {} / {}, reference {} / {}",
            dss::factor(k),
            fast.avg[k],
            fast.max[k],
            one.avg,
            one.max
        );
        assert_eq!(fast.coverage, one.coverage, "{region:?} factor {}", dss::factor(k));
    }
}

#[test]
fn dss_object_errors_equal_object_error_per_factor_bit_for_bit() {
    // An odd-sized rough grid with scattered voids and a void-only corner.
    let (w, h) = (83, 71);
    let mut voids = VoidMask::new(w, h);
    let mut r = Rng(7);
    for _ in 0..300 {
        voids.set((r.unit() * w as f64) as usize, (r.unit() * h as f64) as usize, true);
    }
    for j in 0..5 {
        for i in 0..5 {
            voids.set(i, j, true);
        }
    }
    let hm =
        Heightmap::new(w, h, random_heights(w, h, 11, 900.0), voids, Georef::local(1.0)).unwrap();
    for region in [
        Region::new(0, 0, 64),
        Region::new(16, 16, 16),
        Region::new(64, 64, 64), // clipped at both borders
        Region::new(80, 0, 4),   // clipped to a thin strip
        Region::new(0, 0, 4),    // void only
        Region::new(40, 8, 1),
        Region::new(90, 90, 8), // outside
    ] {
        assert_dss_fast_equals_reference(&hm, region);
    }
    // Without voids (the fast path skips the mask).
    let plain = hm_from(w, h, random_heights(w, h, 12, 50.0), Georef::local(1.0));
    for region in [Region::new(0, 0, 128), Region::new(32, 32, 32), Region::new(7, 3, 13)] {
        assert_dss_fast_equals_reference(&plain, region);
    }
}
