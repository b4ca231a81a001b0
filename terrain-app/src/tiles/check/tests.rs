//! The hierarchical check against the scan of every sample, on random grids and meshes.

use std::sync::atomic::{AtomicUsize, Ordering};

use glam::DVec3;
use terrain_app::samples::Window;
use terrain_core::heightmap::VoidMask;
use terrain_core::tin::TileId;

use super::*;
use terrain_app::decimation::Decimation;

/// Uniform numbers in `[0, 1)`: Marsaglia's xorshift64 (13, 7, 17), top 53 bits (the
/// generator of terrain-core's unit tests, which is crate-private there).
fn unit_rng(seed: u64) -> impl FnMut() -> f64 {
    let mut x = seed | 1;
    move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        (x >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A grid in memory that counts the samples read (NaN and void samples allowed).
struct Grid {
    w: usize,
    h: usize,
    z: Vec<f32>,
    void: Vec<bool>,
    read: AtomicUsize,
}

impl Samples for Grid {
    fn size(&self) -> (usize, usize) {
        (self.w, self.h)
    }

    fn window(&self, i0: usize, j0: usize, w: usize, h: usize, s: u32) -> anyhow::Result<Window> {
        // The check reads every sample; the decimation pass reads strided ones too.
        if s == 0 {
            self.read.fetch_add(w * h, Ordering::Relaxed);
        }
        let mut data = Vec::with_capacity(w * h);
        let mut voids = VoidMask::new(w, h);
        for b in 0..h {
            for a in 0..w {
                let (i, j) = ((i0 + (a << s)).min(self.w - 1), (j0 + (b << s)).min(self.h - 1));
                data.push(self.z[j * self.w + i]);
                voids.set(a, b, self.void[j * self.w + i]);
            }
        }
        let voids = (voids.count() > 0).then_some(voids);
        Ok(Window { width: w, data, voids })
    }
}

/// A layout where tile 0/0/0 is the grid square from `(x0, y0)` (fractional) `cells` cells wide.
fn layout(w: usize, h: usize, x0: f64, y0: f64, cells: f64) -> GridLayout {
    let spacing = 180.0 / cells;
    GridLayout {
        width: w,
        height: h,
        origin: dvec2(-180.0 - x0 * spacing, -90.0 - y0 * spacing),
        spacing: dvec2(spacing, spacing),
    }
}

fn mesh(vertices: Vec<DVec3>, triangles: Vec<[u32; 3]>) -> TileMesh {
    TileMesh {
        tile: TileId { level: 0, x: 0, y: 0 },
        vertices,
        triangles,
        bound: 1.0,
        measured: None,
    }
}

/// What the scan of every sample gives.
fn reference(grid: &Grid, layout: &GridLayout, m: &TileMesh) -> Option<f64> {
    let Some(rect) = samples_inside(layout, m.tile) else { return Some(0.0) };
    let tris = grid_triangles(layout, m);
    let tris: Vec<&Tri> = tris.iter().collect();
    let at = |i: usize, j: usize| (!grid.void[j * grid.w + i]).then(|| grid.z[j * grid.w + i]);
    max_error(&tris, rect, at)
}

/// A jittered `n x n` lattice over the unit square, split into triangles along random
/// diagonals, heights from `f` plus noise (a valid triangulation of the square).
fn lattice(n: usize, unit: &mut impl FnMut() -> f64, f: impl Fn(f64, f64) -> f64) -> TileMesh {
    let mut v = Vec::new();
    for b in 0..=n {
        for a in 0..=n {
            let jitter = |k: usize, u: f64| {
                if k == 0 || k == n { 0.0 } else { (u - 0.5) * 0.6 / n as f64 }
            };
            let (x, y) =
                (a as f64 / n as f64 + jitter(a, unit()), b as f64 / n as f64 + jitter(b, unit()));
            v.push(DVec3::new(x, y, f(x, y) + (unit() - 0.5) * 4.0));
        }
    }
    let id = |a: usize, b: usize| (b * (n + 1) + a) as u32;
    let mut t = Vec::new();
    for b in 0..n {
        for a in 0..n {
            let (p, q, r, s) = (id(a, b), id(a + 1, b), id(a + 1, b + 1), id(a, b + 1));
            if unit() < 0.5 {
                t.extend([[p, q, r], [p, r, s]]);
            } else {
                t.extend([[p, q, s], [q, r, s]]);
            }
        }
    }
    mesh(v, t)
}

/// A random grid: a smooth surface of `relief` metres, noise, spikes, and (with `voids`) void
/// and NaN samples.
fn grid(w: usize, h: usize, relief: f64, voids: bool, unit: &mut impl FnMut() -> f64) -> Grid {
    let mut z = Vec::with_capacity(w * h);
    let mut void = Vec::with_capacity(w * h);
    for j in 0..h {
        for i in 0..w {
            let (x, y) = (i as f64 / w as f64, j as f64 / h as f64);
            let mut v = surface(x, y, relief) + (unit() - 0.5) * 6.0;
            if unit() < 0.002 {
                v += (unit() - 0.5) * 8.0 * relief;
            }
            let is_void = voids && unit() < 0.05;
            if voids && unit() < 0.01 {
                v = f64::NAN;
            }
            z.push(v as f32);
            void.push(is_void);
        }
    }
    Grid { w, h, z, void, read: AtomicUsize::new(0) }
}

fn surface(x: f64, y: f64, relief: f64) -> f64 {
    relief * (0.5 * (x * 5.0).sin() + 0.3 * (y * 7.0 + x * 2.0).cos() + 0.2 * x * y)
}

fn same(a: Option<f64>, b: Option<f64>) -> bool {
    a.map(f64::to_bits) == b.map(f64::to_bits)
}

#[test]
fn the_scan_measures_every_sample_and_finds_gaps() {
    // Two triangles covering the 0..10 square, the plane z = x; samples z = x + (i == 3).
    let l = layout(11, 11, 0.0, 0.0, 10.0);
    let m = mesh(
        vec![
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(1.0, 0.0, 10.0),
            DVec3::new(1.0, 1.0, 10.0),
            DVec3::new(0.0, 1.0, 0.0),
        ],
        vec![[0, 1, 2], [0, 2, 3]],
    );
    let t = grid_triangles(&l, &m);
    let at = |i: usize, j: usize| Some(i as f32 + if (i, j) == (3, 7) { 2.5 } else { 0.0 });
    let t: Vec<&Tri> = t.iter().collect();
    let e = max_error(&t, [0, 0, 10, 10], at).unwrap();
    assert!((e - 2.5).abs() < 1e-9, "{e}");
    // One triangle only: the samples above the diagonal are uncovered.
    assert_eq!(max_error(&t[..1], [0, 0, 10, 10], at), None);
    // ... unless they are void.
    let void_above = |i: usize, j: usize| (j <= i).then_some(i as f32);
    assert_eq!(max_error(&t[..1], [0, 0, 10, 10], void_above), Some(0.0));
}

/// The check measures a known error over the plane `z = x` (one sample 2.5 or 1.5 m off,
/// the 1,000 rows in 16 bands of the coverage sweep, the sample in the last), and the
/// decimated tile whose check exceeds its bound is rejected by the budget policy (rebuilt,
/// then meshed from every sample) while the one within it is kept: the check accepts and
/// rejects, not only measures.
#[test]
fn the_check_measures_a_known_error_and_a_mesh_over_its_bound_is_rejected() {
    let (w, h) = (11, 1001);
    let l = layout(w, h, 0.0, 0.0, 1000.0);
    // Grid units are equal along both axes: the tile spans 1000 cells; the plane rises 1 m a
    // column over the first 11 columns (z = 100 u over the tile's 1000 columns, 10 of them
    // in the grid: u = 0.01 at column 10).
    let m = mesh(
        vec![
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(0.01, 0.0, 10.0),
            DVec3::new(0.01, 1.0, 10.0),
            DVec3::new(0.0, 1.0, 0.0),
        ],
        vec![[0, 1, 2], [0, 2, 3]],
    );
    let Some(rect) = samples_inside(&l, m.tile) else { panic!("no sample inside") };
    assert_eq!(rect, [0, 0, 10, 1000]);
    let spiked = |off: f32| {
        let mut g = grid(w, h, 0.0, false, &mut unit_rng(3));
        for j in 0..h {
            for i in 0..w {
                g.z[j * w + i] = i as f32 + if (i, j) == (3, 990) { off } else { 0.0 };
            }
        }
        g
    };
    let policy = terrain_app::decimation::BudgetPolicy::default();
    for (off, kept) in [(2.5, false), (1.5, true)] {
        let g = spiked(off);
        let range = SampleRange::measure(&g, 64).unwrap();
        let e = check(&g, &l, &m, &range).unwrap().unwrap();
        assert!((e - f64::from(off)).abs() < 1e-9, "{off}: measured {e}");
        assert!(same(Some(e), reference(&g, &l, &m)), "{off}: check {e} differs from the scan");
        // Bound 2 m, no decimation error: the decimated mesh (stride 2^1) is this one; a
        // rebuild from every sample (stride 0) is a mesh of its own, told apart by its bound.
        let built = terrain_app::decimation::build_within(
            2.0,
            1,
            0,
            &policy,
            |_| Ok(0.0),
            |s, _| {
                let mut m = mesh(m.vertices.clone(), m.triangles.clone());
                m.bound = f64::from(s);
                Ok(m)
            },
            |_| 0.0,
            |m| check(&g, &l, m, &range),
        )
        .unwrap();
        if kept {
            assert_eq!((built.retries, built.stride_log2, built.mesh.bound), (0, 1, 1.0));
            assert_eq!(built.measured.to_bits(), e.to_bits());
        } else {
            assert!(built.retries > 0, "{off}: a mesh 2.5 m off passed a 2 m bound");
            assert_eq!((built.stride_log2, built.mesh.bound), (0, 0.0));
        }
    }
    // A triangle missing leaves the samples above the diagonal uncovered.
    let g = spiked(0.0);
    let range = SampleRange::measure(&g, 64).unwrap();
    let half = mesh(m.vertices.clone(), vec![m.triangles[0]]);
    assert_eq!(check(&g, &l, &half, &range).unwrap(), None);
    assert_eq!(check(&g, &l, &m, &range).unwrap().map(f64::to_bits), Some(0f64.to_bits()));
}

/// On random grids (voids, NaN, spikes) and random meshes (valid lattices, lattices with a
/// triangle missing, overlapping random triangles), over the whole grid or part of it, the
/// hierarchical check gives what the scan of every sample gives, bit for bit.
#[test]
fn the_check_is_the_scan_on_random_grids_and_meshes() {
    let mut unit = unit_rng(0x5eed_1234_abcd);
    let (mut none, mut some, mut void_gaps) = (0, 0, 0);
    for case in 0..160 {
        let w = 17 + (unit() * 90.0) as usize;
        let h = 17 + (unit() * 90.0) as usize;
        let relief = [5.0, 200.0, 3000.0][case % 3];
        let voids = case % 4 == 1;
        let g = grid(w, h, relief, voids, &mut unit);
        let range = SampleRange::measure(&g, 32 + 16 * (case % 3)).unwrap();
        // The tile over the whole grid, or a part of it from a fractional corner.
        let l = if case % 2 == 0 {
            layout(w, h, 0.0, 0.0, (w - 1) as f64)
        } else {
            layout(
                w,
                h,
                unit() * 10.0,
                unit() * 10.0,
                (w.min(h) as f64 - 12.0) * (0.5 + unit() * 0.5),
            )
        };
        let n = 1 + (unit() * 8.0) as usize;
        let f = |x: f64, y: f64| surface(x, y, relief);
        let mut m = lattice(n, &mut unit, f);
        match case % 5 {
            // One triangle missing: a gap, unless every sample in it is void.
            1 => {
                let k = (unit() * m.triangles.len() as f64) as usize;
                m.triangles.remove(k);
            }
            // Overlapping random triangles on top of the lattice.
            2 => {
                for _ in 0..6 {
                    let base = m.vertices.len() as u32;
                    for _ in 0..3 {
                        m.vertices.push(DVec3::new(unit(), unit(), (unit() - 0.5) * relief));
                    }
                    m.triangles.push([base, base + 1, base + 2]);
                    m.triangles.push([base, base + 2, base + 1]);
                }
            }
            // A large error at one vertex.
            3 => {
                let k = (unit() * m.vertices.len() as f64) as usize;
                m.vertices[k].z += 50.0 * relief;
            }
            _ => {}
        }
        let want = reference(&g, &l, &m);
        let got = check(&g, &l, &m, &range).unwrap();
        assert!(same(got, want), "case {case}: {w} x {h}, check {got:?}, scan {want:?}");
        // Larger finest boxes (a grid beyond the pyramid's box budget): the same, bit for bit.
        for leaf in [5, 6] {
            let coarse = SampleRange::measure_with(&g, 64, leaf).unwrap();
            let got = check(&g, &l, &m, &coarse).unwrap();
            assert!(same(got, want), "case {case}, boxes of 2^{leaf}: {got:?}, scan {want:?}");
        }
        match want {
            None => none += 1,
            Some(e) if e > 0.0 => some += 1,
            Some(_) => {}
        }
        if case % 5 == 1 && want.is_some() {
            void_gaps += 1;
        }
    }
    // Not vacuous: both outcomes, and gaps both refused and (all void, or missing no sample) let through.
    assert!(none >= 20 && some >= 80, "{none} uncovered, {some} measured");
    assert!(void_gaps >= 1, "no missing triangle left only voids or no sample uncovered");
}

/// A coarse tile over a large smooth grid reads few samples, and still finds the one sample
/// that is far off (a negative control: a check that skipped what the pyramid proves nothing
/// about would miss it).
#[test]
fn a_coarse_tile_reads_few_samples_and_finds_a_lone_spike() {
    let (w, h) = (1025, 1025);
    let mut unit = unit_rng(77);
    let mut g = grid(w, h, 100.0, false, &mut unit);
    // No spikes, a smooth surface with noise.
    for j in 0..h {
        for i in 0..w {
            let (x, y) = (i as f64 / w as f64, j as f64 / h as f64);
            g.z[j * w + i] = (surface(x, y, 100.0) + (unit() - 0.5) * 2.0) as f32;
        }
    }
    let l = layout(w, h, 0.0, 0.0, (w - 1) as f64);
    // Coarse: 8 triangles over a 100 m relief, tens of metres off where a 16 x 16 box spans a
    // few metres.
    let m = lattice(2, &mut unit, |x, y| surface(x, y, 100.0));
    let range = SampleRange::measure(&g, 256).unwrap();
    let read = |g: &Grid| g.read.swap(0, Ordering::Relaxed);
    read(&g);
    let want = reference(&g, &l, &m).unwrap();
    let got = check(&g, &l, &m, &range).unwrap();
    assert!(same(got, Some(want)), "{got:?} vs {want}");
    let n = read(&g);
    assert!(n < w * h / 4, "read {n} of {} samples", w * h);
    // One sample 500 m up, in the middle of a triangle.
    g.z[517 * w + 389] += 500.0;
    let want2 = reference(&g, &l, &m).unwrap();
    assert!(want2 > want + 400.0, "{want2} {want}");
    // Negative control: with the pyramid of the grid before the spike, the search proves the
    // spike's boxes within the bound and misses it (so the check above does prune, and the
    // pyramid is what it trusts).
    let stale = check(&g, &l, &m, &range).unwrap().unwrap();
    assert!(stale < want2 - 400.0, "{stale} {want2}");
    let range = SampleRange::measure(&g, 256).unwrap();
    let got2 = check(&g, &l, &m, &range).unwrap();
    assert!(same(got2, Some(want2)), "{got2:?} vs {want2}");
}

/// The pyramid's boxes, as bits.
fn bits(r: &SampleRange) -> Vec<Vec<[u32; 2]>> {
    r.levels.iter().map(|(_, v)| v.iter().map(|m| m.map(f32::to_bits)).collect()).collect()
}

/// The pyramid merged from the decimation pass's windows (each region's `region + 1` samples
/// a side, neighbours sharing a row or column) is the one measured by windows of its own,
/// bit for bit, on grids with voids and NaN whose sides are no multiple of the regions; and
/// the decimation errors measured in that pass are those measured region by region.
#[test]
fn the_decimation_pass_measures_the_same_pyramid() {
    let mut unit = unit_rng(0xdec1);
    for (w, h, region) in [(600, 530, 256), (97, 61, 16), (300, 17, 32), (1, 40, 16)] {
        let g = grid(w, h, 200.0, true, &mut unit);
        let pass = Decimation::new(w, h, region, 3);
        let leaf = leaf_log2_for(w, h);
        let leaves = pass.measure_all(&g, |i, j, win| LeafBoxes::of(leaf, i, j, win)).unwrap();
        let merged = SampleRange::from_leaves(w, h, leaf, &leaves);
        let own = SampleRange::measure(&g, 64).unwrap();
        assert!(bits(&merged) == bits(&own), "{w} x {h}, regions of {region}");
        // Negative control: without one window's boxes the pyramid differs.
        if leaves.len() > 1 {
            let part = SampleRange::from_leaves(w, h, leaf, &leaves[1..]);
            assert!(bits(&part) != bits(&own), "{w} x {h}: the first window changed nothing");
        }
        let lazy = Decimation::new(w, h, region, 3);
        for s in 1..=3 {
            let all = [0, 0, w - 1, h - 1];
            let (a, b) = (pass.error_in(&g, all, s).unwrap(), lazy.error_in(&g, all, s).unwrap());
            assert_eq!(a.to_bits(), b.to_bits(), "{w} x {h}, stride 2^{s}");
        }
        assert!(pass.max() > 0.0, "{w} x {h}: no decimation error measured");
    }
}

/// The pyramid's finest boxes grow with the grid beyond the box budget, so its memory is
/// bounded whatever the DEM's size: 16 x 16 up to the budget (the 16385^2 store's as before),
/// then the smallest power of two that fits.
#[test]
fn the_pyramid_stays_within_its_box_budget_on_any_grid() {
    assert_eq!(leaf_log2_for(1, 1), 4);
    assert_eq!(leaf_log2_for(16385, 16385), 4);
    assert_eq!(leaf_log2_for(32769, 32769), 5);
    assert_eq!(leaf_log2_for(1 << 20, 3), 4);
    for (w, h) in [(23_000, 23_000), (23_300, 23_300), (65_537, 65_537), (400_000, 250_000)] {
        let k = leaf_log2_for(w, h);
        let boxes = |k: u32| w.div_ceil(1 << k) * h.div_ceil(1 << k);
        assert!(boxes(k) <= MAX_LEAF_BOXES, "{w} x {h}: {} boxes", boxes(k));
        assert!(
            k == MIN_LEAF_LOG2 || boxes(k - 1) > MAX_LEAF_BOXES,
            "{w} x {h}: 2^{k} not the least"
        );
    }
    assert_eq!(leaf_log2_within(100, 100, 16), 5);
}
