//! Unit tests of the CPU reference tessellator: counts against the spec's formulas, edge
//! independence, containment, orientation, coverage and continuity in the factors.

use std::collections::{BTreeMap, BTreeSet};

use super::reference::{EdgeSpacing, QuadLayout, RULER_ORDER, clamp_factor, remove_msb};
use super::{PatchFactors, TessMesh, tessellate};

/// A small seeded generator (SplitMix64), so that every run sees the same factors.
pub(crate) struct Rng(u64);

impl Rng {
    pub(crate) fn new(seed: u64) -> Self {
        Self(seed)
    }

    pub(crate) fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[lo, hi)`.
    pub(crate) fn range(&mut self, lo: f32, hi: f32) -> f32 {
        let unit = (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32;
        lo + (hi - lo) * unit
    }

    /// A factor in `[1, 64]`, a third of the time one of the interesting fixed values.
    pub(crate) fn factor(&mut self) -> f32 {
        const SPECIAL: [f32; 10] = [1.0, 2.0, 3.7, 17.25, 63.9, 64.0, 4.0, 2.001, 7.999, 33.0];
        if self.next_u64().is_multiple_of(3) {
            SPECIAL[(self.next_u64() % SPECIAL.len() as u64) as usize]
        } else {
            self.range(1.0, 64.0)
        }
    }

    pub(crate) fn factors(&mut self) -> PatchFactors {
        PatchFactors {
            inner: [self.factor(), self.factor()],
            outer: [self.factor(), self.factor(), self.factor(), self.factor()],
        }
    }
}

/// Hand-picked patches, then seeded random ones: the shared test corpus of CPU and GPU tests.
pub(crate) fn factor_corpus(random: usize) -> Vec<PatchFactors> {
    let mut v = vec![
        PatchFactors::uniform(1.0),
        PatchFactors::uniform(2.0),
        PatchFactors::uniform(64.0),
        PatchFactors::uniform(3.7),
        PatchFactors::uniform(17.25),
        PatchFactors::uniform(63.9),
        PatchFactors { inner: [1.0, 64.0], outer: [64.0, 1.0, 2.0, 3.7] },
        PatchFactors { inner: [64.0, 1.0], outer: [17.25, 63.9, 1.0, 5.5] },
        PatchFactors { inner: [3.7, 17.25], outer: [2.0, 4.0, 8.0, 16.0] },
        PatchFactors { inner: [8.0, 8.0], outer: [1.0, 64.0, 1.0, 64.0] },
        PatchFactors { inner: [6.0, 12.0], outer: [6.0, 12.0, 6.0, 12.0] },
    ];
    let mut rng = Rng::new(0x7E55_E11A);
    v.extend((0..random).map(|_| rng.factors()));
    v
}

/// Checks everything a tessellation must satisfy on its own; returns the mesh.
fn check_mesh(f: &PatchFactors) -> TessMesh {
    let layout = QuadLayout::new(f);
    let mesh = tessellate(f);
    assert_eq!(mesh.points.len(), layout.point_count() as usize, "{f:?}");
    assert_eq!(mesh.triangle_count(), layout.triangle_count() as usize, "{f:?}");
    for (k, p) in mesh.points.iter().enumerate() {
        assert!(
            (0.0..=1.0).contains(&p[0]) && (0.0..=1.0).contains(&p[1]),
            "{f:?}: point {k} {p:?}"
        );
    }
    let mut used = vec![false; mesh.points.len()];
    for &i in &mesh.indices {
        used[i as usize] = true;
    }
    assert!(used.iter().all(|&u| u), "{f:?}: a point no triangle uses");
    // Fractional-even spacing never makes two points coincide, so no triangle is degenerate,
    // and all wind the same way.
    for t in 0..mesh.triangle_count() {
        assert!(
            mesh.doubled_area(t) > 0.0,
            "{f:?}: triangle {t} has area {}",
            mesh.doubled_area(t)
        );
    }
    assert_eq!(mesh.non_degenerate_triangle_count(), mesh.triangle_count());
    // The triangles tile the unit square: total area 1 ...
    let area: f64 = (0..mesh.triangle_count()).map(|t| mesh.doubled_area(t) / 2.0).sum();
    assert!((area - 1.0).abs() < 1e-5, "{f:?}: area {area}");
    // ... and as a manifold: every interior edge is shared by exactly two triangles in
    // opposite directions, every edge used once lies on the square's border.
    let mut directed = BTreeMap::new();
    for t in mesh.indices.chunks(3) {
        for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
            *directed.entry((a, b)).or_insert(0u32) += 1;
        }
    }
    for (&(a, b), &n) in &directed {
        assert_eq!(n, 1, "{f:?}: directed edge {a}->{b} used {n} times");
        if !directed.contains_key(&(b, a)) {
            let (p, q) = (mesh.points[a as usize], mesh.points[b as usize]);
            let on_border = (0..2).any(|c| p[c] == q[c] && (p[c] == 0.0 || p[c] == 1.0));
            assert!(on_border, "{f:?}: open edge {p:?}-{q:?} inside the square");
        }
    }
    mesh
}

#[test]
fn uniform_even_factor_gives_the_full_grid() {
    for n in (2..=64).step_by(2) {
        let mesh = check_mesh(&PatchFactors::uniform(n as f32));
        assert_eq!(mesh.points.len(), (n + 1) * (n + 1), "n = {n}");
        assert_eq!(mesh.triangle_count(), 2 * n * n, "n = {n}");
        // Every point sits on the grid i/n, and every grid node is present once.
        let mut nodes = BTreeSet::new();
        for p in &mesh.points {
            let (i, j) = ((p[0] * n as f32).round(), (p[1] * n as f32).round());
            assert!((p[0] - i / n as f32).abs() < 1e-6 && (p[1] - j / n as f32).abs() < 1e-6);
            assert!(nodes.insert((i as u32, j as u32)), "n = {n}: duplicate node");
        }
    }
}

#[test]
fn counts_follow_the_spec_formulas() {
    for f in factor_corpus(300) {
        let layout = QuadLayout::new(&f);
        let n = |t: f32| 2 * (clamp_factor(t) / 2.0).ceil() as u32 + 1;
        let outer: u32 = f.outer.iter().map(|&t| n(t) - 1).sum();
        let (nu, nv) = (n(f.inner[0]), n(f.inner[1]));
        assert_eq!(layout.point_count(), outer + (nu - 2) * (nv - 2), "{f:?}");
        // One triangle per segment of either row in each band: outer segments, twice every
        // inner ring's segments except the centre's, which has no inside.
        let outer_segments: u32 = f.outer.iter().map(|&t| n(t) - 1).sum();
        let rings = (nu.min(nv) - 1) / 2;
        let ring_segments = |r: u32| 2 * (nu - 2 * r - 1) + 2 * (nv - 2 * r - 1);
        let inner: u32 =
            (1..rings).map(|r| 2 * ring_segments(r)).sum::<u32>() + ring_segments(rings);
        assert_eq!(layout.triangle_count(), outer_segments + inner, "{f:?}");
        check_mesh(&f);
    }
}

#[test]
fn factors_below_two_act_as_two_and_out_of_range_clamp() {
    assert_eq!(tessellate(&PatchFactors::uniform(1.0)), tessellate(&PatchFactors::uniform(2.0)));
    assert_eq!(tessellate(&PatchFactors::uniform(0.25)), tessellate(&PatchFactors::uniform(2.0)));
    assert_eq!(tessellate(&PatchFactors::uniform(1e6)), tessellate(&PatchFactors::uniform(64.0)));
    let nan_inner = PatchFactors { inner: [f32::NAN, 4.0], outer: [4.0; 4] };
    let two_inner = PatchFactors { inner: [2.0, 4.0], outer: [4.0; 4] };
    assert_eq!(tessellate(&nan_inner), tessellate(&two_inner));
    // Factor 1 is two segments: 3 points per edge, 9 in all, 8 triangles.
    let one = tessellate(&PatchFactors::uniform(1.0));
    assert_eq!((one.points.len(), one.triangle_count()), (9, 8));
}

#[test]
fn patches_with_a_non_positive_outer_factor_are_culled() {
    for bad in [0.0, -1.0, f32::NAN] {
        let f = PatchFactors { inner: [4.0, 4.0], outer: [4.0, bad, 4.0, 4.0] };
        assert_eq!(tessellate(&f), TessMesh::default(), "{bad}");
    }
}

/// The points of outer edge `e`, in the edge's own order (increasing parameter).
fn edge_points(f: &PatchFactors, e: usize) -> Vec<[f32; 2]> {
    let layout = QuadLayout::new(f);
    let mesh = tessellate(f);
    let len = layout.side_len(0, e);
    let mut pts: Vec<_> =
        (0..len).map(|k| mesh.points[layout.side_point(0, e, k) as usize]).collect();
    // Sides 0 and 3 run backwards (ring order); report every edge by increasing parameter.
    if e == 0 || e == 3 {
        pts.reverse();
    }
    pts
}

#[test]
fn edge_vertices_depend_only_on_their_edge_factor() {
    let mut rng = super::tests::Rng::new(99);
    for _ in 0..200 {
        let a = rng.factors();
        let mut b = rng.factors();
        let e = (rng.next_u64() % 4) as usize;
        b.outer[e] = a.outer[e];
        assert_eq!(edge_points(&a, e), edge_points(&b, e), "{a:?} / {b:?} edge {e}");
        // The neighbour across the edge (u = 1 of one patch is u = 0 of the next, and
        // likewise for v) sees the same parameters, bit for bit.
        let opposite = (e + 2) % 4;
        let mut c = rng.factors();
        c.outer[opposite] = a.outer[e];
        let axis = if e.is_multiple_of(2) { 1 } else { 0 };
        let params = |pts: Vec<[f32; 2]>| pts.iter().map(|p| p[axis].to_bits()).collect::<Vec<_>>();
        assert_eq!(params(edge_points(&a, e)), params(edge_points(&c, opposite)));
        // The edge's points lie on the edge.
        let fixed = [0.0, 0.0, 1.0, 1.0][e];
        assert!(edge_points(&a, e).iter().all(|p| p[1 - axis] == fixed));
    }
}

#[test]
fn random_patches_are_valid_tilings() {
    for f in factor_corpus(400) {
        check_mesh(&f);
    }
}

#[test]
fn spacing_is_symmetric_increasing_and_has_two_short_segments() {
    let mut t = 1.0f32;
    while t <= 64.0 {
        let s = EdgeSpacing::new(t);
        let n = s.point_count();
        let params: Vec<f32> = (0..n).map(|k| s.place(k)).collect();
        assert_eq!((params[0], params[n as usize - 1]), (0.0, 1.0), "t = {t}");
        assert_eq!(params[s.half_points as usize], 0.5);
        for k in 0..n as usize {
            let mirror = params[n as usize - 1 - k];
            assert!((params[k] + mirror - 1.0).abs() <= 1e-7, "t = {t}: not symmetric at {k}");
            if k > 0 {
                assert!(params[k] > params[k - 1], "t = {t}: not increasing at {k}");
            }
        }
        // n - 3 equal segments and two equal shorter ones, mirrored (or all equal at even t).
        let seg: Vec<f32> = params.windows(2).map(|w| w[1] - w[0]).collect();
        let long = seg.iter().cloned().fold(0.0, f32::max);
        let short: Vec<usize> = (0..seg.len()).filter(|&k| seg[k] < long - 1e-6).collect();
        let even = clamp_factor(t) / 2.0 == (clamp_factor(t) / 2.0).floor();
        if even {
            assert!(short.is_empty(), "t = {t}: {seg:?}");
        } else if !short.is_empty() {
            assert_eq!(short.len(), 2, "t = {t}: {seg:?}");
            assert_eq!(short[0] + short[1], seg.len() - 1, "t = {t}: short segments not mirrored");
        }
        t += 0.0625;
    }
}

#[test]
fn vertices_move_continuously_with_the_factor() {
    // Within a topology (same ceil(t/2)), a step dt moves no point by more than dt / 4:
    // d(place)/dt = (at_ceil - at_floor) / 2 and both lie in [0, 1/2].
    let dt = 1e-3f32;
    let mut rng = Rng::new(5);
    for _ in 0..300 {
        let f = rng.factors();
        let mut g = f;
        for x in g.inner.iter_mut().chain(g.outer.iter_mut()) {
            *x += dt;
        }
        let (lf, lg) = (QuadLayout::new(&f), QuadLayout::new(&g));
        let same = lf.outer.iter().zip(&lg.outer).all(|(a, b)| a.half_points == b.half_points)
            && lf.inner.iter().zip(&lg.inner).all(|(a, b)| a.half_points == b.half_points);
        if !same {
            continue;
        }
        let (a, b) = (tessellate(&f), tessellate(&g));
        assert_eq!(a.indices, b.indices, "{f:?}: topology changed");
        for (p, q) in a.points.iter().zip(&b.points) {
            let d = (p[0] - q[0]).abs().max((p[1] - q[1]).abs());
            assert!(d <= dt / 4.0 + 1e-6, "{f:?}: moved {d}");
        }
    }
    // Across an even factor 2k the new points grow out of existing ones: at 2k + eps the
    // spacing, with the two new points dropped, is the spacing at 2k.
    for k in 1..32u32 {
        let at = EdgeSpacing::new(2.0 * k as f32);
        let above = EdgeSpacing::new(2.0 * k as f32 + 1e-4);
        assert_eq!(above.point_count(), at.point_count() + 2);
        let n = above.point_count();
        // The point at `split` grows out of its right neighbour (the coarse layout's point).
        let new_point = above.split;
        let kept: Vec<f32> = (0..n)
            .filter(|&q| q != new_point && q != n - 1 - new_point)
            .map(|q| above.place(q))
            .collect();
        for (q, x) in kept.iter().enumerate() {
            assert!((x - at.place(q as u32)).abs() < 1e-4, "k = {k}, point {q}");
        }
        // And the dropped points sit on their neighbours.
        assert!((above.place(new_point) - above.place(new_point + 1)).abs() < 1e-4, "k = {k}");
    }
}

#[test]
fn ruler_table_matches_split_order() {
    // RULER_ORDER[slot] is the step at which the half-edge point in `slot` (of 33, the
    // midpoint excluded) appears. Rebuild it by inserting one point per half-factor step at
    // the index the split rule gives: the corner is there from the start (step 0).
    let split = |lo: u32| remove_msb(lo) * 2 + 1;
    for lo in 1..32u32 {
        assert_eq!(EdgeSpacing::new(2.0 * lo as f32 + 1.0).split, split(lo));
    }
    let mut row: Vec<u32> = vec![0];
    for lo in 1..=32u32 {
        row.insert(split(lo) as usize, lo);
    }
    assert_eq!(row, RULER_ORDER);
}
