//! The PVPS paper's line of sight (Zhang 2021, section 2.2.2, Figure 3, Eq. 4): the terrain
//! section line of a 3D Bresenham traversal between a viewpoint and a test point, each point
//! taking the height of the nearest DEM sample, and the slope test of Eq. 4, accelerated by
//! max-height early exits.
//!
//! **Eq. 4 and its sign.** `f(v, t, p') = K(v -> p') - K(v -> t)` compares the slope from the
//! viewpoint to a section-line point with the slope to the test point. The text says "if all
//! results are less than 0, there is no visibility"; that is inverted (all section points below
//! the sight line is the *visible* case). We use the standard reading: the test point is hidden
//! when some `f > 0` (a section point above the sight line), visible otherwise. Comparing slopes
//! over the same plan distance is comparing the point's height with the sight line's height
//! there, which is how it is computed here.
//!
//! **Traversal.** Grid coordinates (x, y in samples, z in metres). The traversal steps along
//! the major plan axis at every integer coordinate strictly between the two ends (the black
//! points of Figure 3a: where the perpendicular through a column's centre meets the segment),
//! rounds the minor coordinate to the nearest sample and interpolates z: one point per column
//! crossed, as Bresenham's algorithm visits them.
//!
//! **Early exits** (none changes a result; `tests/pvs_pinned.rs` compares with a plain walk).
//! [`Hints`] first (samples that blocked recent lines); then the `PROBE_STEPS` steps nearest
//! the test point one by one (where a hidden target is usually blocked); then the remaining
//! steps are halved recursively: a range whose samples' max height (from [`HeightMip`]) is not
//! above the sight line's lowest point over it cannot block and is skipped whole, so a sight
//! line high above the terrain costs a few lookups. Steps read the heightmap row by row for
//! lines along x and a column-major copy ([`HeightMip::columns`]) for lines along y, so
//! consecutive steps touch neighbouring memory. Each step's sample and height are computed
//! exactly as `eye + (target - eye) t`, with exact integer rounding ([`round_i64`]).

use glam::DVec3;
use terrain_core::Heightmap;

use super::mip::HeightMip;

/// Step ranges at most this long are walked sample by sample.
const LEAF_STEPS: i64 = 16;

/// Steps nearest the test point checked one by one before the halving (see `walk`).
const PROBE_STEPS: i64 = 16;

/// Occluder hints: DEM samples that blocked recent sight lines. A sight line that passes a
/// sample which blocks it is hidden whatever the rest of the line does, so checking the
/// sample the traversal visits in a hint's column (or row) first is an exact early exit:
/// sight lines from one cell to one patch are usually blocked by the same ridge.
#[derive(Debug, Clone, Default)]
pub struct Hints {
    /// Most recently useful first.
    samples: [Option<(i64, i64)>; HINTS],
}

/// Occluder hints kept per [`Hints`].
const HINTS: usize = 8;

impl Hints {
    /// No hints.
    pub fn new() -> Self {
        Self::default()
    }

    /// Moves hint `k` to the front, or inserts `p` at the front.
    fn promote(&mut self, k: Option<usize>, p: (i64, i64)) {
        let k = k.unwrap_or(HINTS - 1);
        self.samples.copy_within(0..k, 1);
        self.samples[0] = Some(p);
    }
}

/// `x.floor() as i64` without a libm call (the build targets CPUs without a rounding
/// instruction, where `f64::floor` is a function call): equal for every `f64`, saturating
/// and NaN to 0 alike (tested against the standard library).
#[inline]
pub fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x { t.saturating_sub(1) } else { t }
}

/// `x.ceil() as i64` without a libm call (see [`floor_i64`]).
#[inline]
pub fn ceil_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) < x { t.saturating_add(1) } else { t }
}

/// `x.round() as i64` (halves away from zero) without a libm call (see [`floor_i64`]). `x -
/// trunc(x)` is exact (Sterbenz's lemma for `|x| >= 1`, `x` itself below), so comparing it
/// with one half rounds exactly as `f64::round`.
#[inline]
pub fn round_i64(x: f64) -> i64 {
    let t = x as i64;
    let f = x - t as f64;
    if f >= 0.5 {
        t.saturating_add(1)
    } else if f <= -0.5 {
        t.saturating_sub(1)
    } else {
        t
    }
}

/// One sight line's Bresenham section line: its steps are the integer major coordinates
/// strictly between the ends (see the module docs). Only the minor plan coordinate and the
/// height of the line are kept, each computed exactly as `eye + (target - eye) t` would.
struct Section {
    /// The eye's minor coordinate and the line's extent along it.
    e_minor: f64,
    d_minor: f64,
    /// The eye's height and the line's rise.
    e_z: f64,
    d_z: f64,
    major_x: bool,
    a: f64,
    len: f64,
    dir: i64,
    first: i64,
    steps: i64,
}

impl Section {
    /// `None` when the line has no interior step (nothing can block it).
    #[inline]
    fn new(eye: DVec3, target: DVec3) -> Option<Self> {
        let d = target - eye;
        let (major_x, len) = if d.x.abs() >= d.y.abs() { (true, d.x) } else { (false, d.y) };
        if len.abs() < 1e-12 {
            return None;
        }
        let (a, b) = if major_x { (eye.x, target.x) } else { (eye.y, target.y) };
        let dir: i64 = if b > a { 1 } else { -1 };
        let first = if dir > 0 { floor_i64(a) + 1 } else { ceil_i64(a) - 1 };
        let last = if dir > 0 { ceil_i64(b) - 1 } else { floor_i64(b) + 1 };
        if (last - first) * dir < 0 {
            return None;
        }
        let steps = (last - first) * dir + 1;
        let (e_minor, d_minor) = if major_x { (eye.y, d.y) } else { (eye.x, d.x) };
        Some(Self { e_minor, d_minor, e_z: eye.z, d_z: d.z, major_x, a, len, dir, first, steps })
    }

    /// Step `k`'s sample and the sight line's height there.
    #[inline]
    fn point(&self, k: i64) -> (i64, i64, f64) {
        let m = self.first + k * self.dir;
        let t = (m as f64 - self.a) / self.len;
        let minor = round_i64(self.e_minor + self.d_minor * t);
        let z = self.e_z + self.d_z * t;
        let (x, y) = if self.major_x { (m, minor) } else { (minor, m) };
        (x, y, z)
    }

    /// The step at major coordinate `m`, if inside.
    #[inline]
    fn step_at(&self, m: i64) -> Option<i64> {
        let k = (m - self.first) * self.dir;
        (0..self.steps).contains(&k).then_some(k)
    }

    /// Eq. 4 at step `k`: whether the section point lies above the sight line (`f > 0`).
    /// `along`: read the copy of the heightmap in which consecutive steps of this line are
    /// neighbours in memory (a walk); otherwise the one in which the samples of one step of
    /// neighbouring lines are (a hint's column or row, crossed by the lines of a cell). Both
    /// hold the same samples.
    #[inline]
    fn blocks(&self, g: &Grid<'_>, k: i64, eps: f64, along: bool) -> Option<(i64, i64)> {
        let (x, y, z) = self.point(k);
        if x < 0 || y < 0 || x >= g.w || y >= g.h {
            return None;
        }
        let v = if self.major_x == along {
            g.rows[(y * g.w + x) as usize]
        } else {
            g.columns[(x * g.h + y) as usize]
        };
        (f64::from(v) > z + eps).then_some((x, y))
    }
}

/// The heightmap's samples, row by row and column by column.
struct Grid<'a> {
    rows: &'a [f32],
    columns: &'a [f32],
    w: i64,
    h: i64,
}

impl<'a> Grid<'a> {
    #[inline]
    fn new(mip: &'a HeightMip<'_>) -> Self {
        let hm = mip.heightmap();
        Self {
            rows: hm.data(),
            columns: mip.columns(),
            w: hm.width() as i64,
            h: hm.height() as i64,
        }
    }
}

/// Whether `target` is visible from `eye` (grid coordinates, z in metres) by Eq. 4 over the
/// 3D Bresenham section line; terrain must exceed the sight line by more than `eps` to block.
pub fn visible(mip: &HeightMip<'_>, eye: DVec3, target: DVec3, eps: f64) -> bool {
    visible_with(mip, eye, target, eps, &mut Hints::new())
}

/// [`visible`], trying the occluder `hints` first and recording the blocking sample in them.
/// The result does not depend on the hints.
#[inline]
pub fn visible_with(
    mip: &HeightMip<'_>,
    eye: DVec3,
    target: DVec3,
    eps: f64,
    hints: &mut Hints,
) -> bool {
    let g = Grid::new(mip);
    let Some(line) = Section::new(eye, target) else { return true };
    // The usual case (a hint blocks) inlined into the caller's loop; the walk is not.
    for n in 0..HINTS {
        let Some((hx, hy)) = hints.samples[n] else { break };
        let m = if line.major_x { hx } else { hy };
        if let Some(k) = line.step_at(m)
            && let Some(p) = line.blocks(&g, k, eps, false)
        {
            if n > 0 {
                hints.promote(Some(n), p);
            } else {
                hints.samples[0] = Some(p);
            }
            return false;
        }
    }
    walk(mip, &line, eps, hints)
}

/// The section line's steps with max-height early exits (see the module docs).
#[inline(never)]
fn walk(mip: &HeightMip<'_>, line: &Section, eps: f64, hints: &mut Hints) -> bool {
    let g = Grid::new(mip);
    // Steps `k0..=k1`; the section line is monotone in x and y, so its samples lie in the
    // box of the two ends' samples, and the sight line's lowest point is at an end. A depth
    // first halving holds at most two ranges per level (64 covers 2^32 steps).
    //
    // First the `PROBE_STEPS` steps nearest the test point, one by one: a sight line that the
    // hints missed is usually blocked just in front of its target (the next test point of a
    // patch), and this finds it without descending the halving to it.
    let probe = line.steps.min(PROBE_STEPS);
    for k in (line.steps - probe..line.steps).rev() {
        if let Some(p) = line.blocks(&g, k, eps, true) {
            hints.promote(None, p);
            return false;
        }
    }
    if probe == line.steps {
        return true;
    }
    let mut stack = [(0i64, 0i64); 64];
    stack[0] = (0, line.steps - 1 - probe);
    let mut top = 1usize;
    while top > 0 {
        top -= 1;
        let (k0, k1) = stack[top];
        let (x0, y0, z0) = line.point(k0);
        let (x1, y1, z1) = line.point(k1);
        let high = mip.range_max(x0.min(x1), y0.min(y1), x0.max(x1), y0.max(y1));
        if f64::from(high) <= z0.min(z1) + eps {
            continue;
        }
        if k1 - k0 < LEAF_STEPS {
            // Nearest the test point first, as the halving below.
            for k in (k0..=k1).rev() {
                if let Some(p) = line.blocks(&g, k, eps, true) {
                    hints.promote(None, p);
                    return false;
                }
            }
        } else {
            let mid = (k0 + k1) / 2;
            // The half nearer the test point last pushed, so first popped: hidden targets are
            // usually hidden by the terrain just in front of them.
            stack[top] = (k0, mid);
            stack[top + 1] = (mid + 1, k1);
            top += 2;
        }
    }
    true
}

/// Eq. 4 over every step of the section line, without early exits or hints: the reference
/// that [`visible`] must equal (for tests).
pub fn visible_reference(hm: &Heightmap, eye: DVec3, target: DVec3, eps: f64) -> bool {
    let Some(line) = Section::new(eye, target) else { return true };
    (0..line.steps).all(|k| {
        let (x, y, z) = line.point(k);
        let inside = x >= 0 && y >= 0 && (x as usize) < hm.width() && (y as usize) < hm.height();
        !(inside && f64::from(hm.get(x as usize, y as usize)) > z + eps)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::dvec3;
    use terrain_core::georef::Georef;

    #[test]
    fn fast_rounding_equals_the_standard_library() {
        let mut v = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.5,
            -1.5,
            2.5,
            -2.5,
            0.49999999999999994,
            -0.49999999999999994,
            4503599627370495.5,
            -4503599627370495.5,
            4503599627370497.0,
            9.3e18,
            -9.3e18,
            f64::MAX,
            f64::MIN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            f64::MIN_POSITIVE,
            1e-300,
        ];
        let mut state = 7u64;
        for _ in 0..20_000 {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            let u = (state >> 11) as f64 / (1u64 << 53) as f64;
            v.push((u - 0.5) * 10_000.0);
            v.push(((u - 0.5) * 10_000.0).round() + 0.5);
            v.push(f64::from_bits(state));
        }
        for x in v {
            assert_eq!(floor_i64(x), x.floor() as i64, "floor {x}");
            assert_eq!(ceil_i64(x), x.ceil() as i64, "ceil {x}");
            assert_eq!(round_i64(x), x.round() as i64, "round {x}");
        }
    }

    #[test]
    fn a_wall_blocks_and_a_plain_does_not() {
        let hm =
            Heightmap::from_fn(
                100,
                100,
                Georef::local(1.0),
                |i, _| {
                    if i == 50 { 100.0 } else { 0.0 }
                },
            )
            .unwrap();
        let mip = HeightMip::new(&hm);
        assert!(!visible(&mip, dvec3(10.0, 20.0, 10.0), dvec3(90.0, 70.0, 0.0), 1e-3));
        assert!(visible(&mip, dvec3(10.0, 20.0, 300.0), dvec3(90.0, 70.0, 0.0), 1e-3));
        assert!(visible(&mip, dvec3(10.0, 20.0, 10.0), dvec3(40.0, 90.0, 0.0), 1e-3));
        // Nearly along the wall's column (major axis y).
        assert!(!visible(&mip, dvec3(49.0, 1.0, 5.0), dvec3(51.0, 98.0, 0.0), 1e-3));
    }
}
