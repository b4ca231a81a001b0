//! Screen-space projections of an object-space error: the plain `lambda * delta / d`, the DSS
//! paper's view-angle error (Zhang 2019, Eq. 1-3), and the out-of-core paper's sight-line
//! error (Qiu 2013, section 3.2, Eq. 6-7); plus the node box their distance is measured to.
//!
//! Frames: the papers are OpenGL y-up; here z is up. The DSS paper's block normal is already
//! "+Z, the terrain plane parallel with XOY", which is our +z; the out-of-core paper's "angle
//! between the sight line and terrain" is measured against the ground plane, our xy plane.
//! Distances are computed from differences `eye - box`, never from absolute coordinates.

use glam::DVec3;

use crate::heightmap::Heightmap;
use crate::metrics::Region;

/// The screen error returned when the camera is inside (or on) the node's box and the node has
/// a positive error: the node must split. It compares greater than any threshold.
pub const MUST_SPLIT: f64 = f64::INFINITY;

/// Distances at or below this (metres) count as "camera inside the node's box".
pub const MIN_DISTANCE_M: f64 = 1e-9;

/// Floor of the view-angle factor: the DSS paper's `sin(theta)` (Eq. 3) and the out-of-core
/// paper's `cos(theta)` (Eq. 6-7), which are the same quantity (the horizontal part of the unit
/// view direction).
///
/// Why: looking straight down makes the factor 0, so every block would report zero screen
/// error and never refine, however close, although a perspective camera sees the blocks around
/// the view axis along rays up to `fov/2` off vertical, and their vertical error shows in
/// silhouettes, shading and parallax. 0.25 (about 14.5 degrees from vertical) keeps refinement
/// alive below the camera (at a quarter of the horizontal rate, i.e. blocks refine at a quarter
/// of the distance) while leaving every view more than 14.5 degrees off vertical exactly as the
/// papers define it. It is not in either paper. The default of the methods' configurable
/// floor (`DssConfig::view_angle_floor`, the out-of-core `Refinement::view_angle_floor`; the
/// floor study on a straight-down flight, `cargo xtask papers --paper dss`, says what each
/// choice does: 0 leaves the error unbounded below the camera, 1 ignores the angle).
pub const MIN_VIEW_SIN: f64 = 0.25;

/// Smallest vertical field of view (radians) accepted by [`lambda`]; smaller ones are clamped
/// (at 0, `tan(fov/2) = 0` would make `lambda` infinite).
pub const MIN_FOV_Y: f64 = 1e-4;

/// Largest vertical field of view (radians) accepted by [`lambda`]; larger ones are clamped
/// (at pi, `tan(fov/2)` is infinite and `lambda` would be 0).
pub const MAX_FOV_Y: f64 = std::f64::consts::PI - 1e-4;

/// `lambda = y / (2 tan(phi / 2))` (DSS Eq. 1-2): pixels per metre at unit distance, for a
/// viewport `viewport_height_px` pixels tall and a vertical field of view `fov_y` radians.
///
/// `fov_y` is clamped into [`MIN_FOV_Y`]`..=`[`MAX_FOV_Y`] (NaN counts as [`MAX_FOV_Y`], the
/// coarsest); a negative or NaN viewport height counts as 0.
pub fn lambda(viewport_height_px: f64, fov_y: f64) -> f64 {
    let fov = if fov_y.is_nan() { MAX_FOV_Y } else { fov_y.clamp(MIN_FOV_Y, MAX_FOV_Y) };
    let y = if viewport_height_px.is_nan() { 0.0 } else { viewport_height_px.max(0.0) };
    y / (2.0 * (fov / 2.0).tan())
}

/// The plain projection `rho = lambda * delta / d` (DSS Eq. 2; the classical metric).
///
/// Degenerate: `delta <= 0` (or NaN) gives 0, whatever `d`; `d <= `[`MIN_DISTANCE_M`] (camera
/// inside the node's box, or NaN) gives [`MUST_SPLIT`].
pub fn plain(lambda: f64, delta: f64, d: f64) -> f64 {
    if delta.is_nan() || delta <= 0.0 {
        return 0.0;
    }
    if d.is_nan() || d <= MIN_DISTANCE_M {
        return MUST_SPLIT;
    }
    lambda * delta / d
}

/// The view-angle factor shared by DSS Eq. 3 and out-of-core Eq. 6-7, clamped below by
/// [`MIN_VIEW_SIN`].
///
/// DSS: `sin(theta)`, `theta` the angle between the view direction `e` and the block normal
/// (their +Z, our +z). Out-of-core: `cos(theta)`, `theta` the angle between the sight line and
/// the terrain (our xy plane). Both equal `|e_xy| / |e|`. A zero or non-finite `view_dir` has
/// no angle and counts as horizontal (factor 1).
pub fn view_sin(view_dir: DVec3) -> f64 {
    view_sin_floored(view_dir, MIN_VIEW_SIN)
}

/// [`view_sin`] with the floor `floor` in place of [`MIN_VIEW_SIN`] (clamped into `[0, 1]`;
/// NaN counts as [`MIN_VIEW_SIN`]): 0 is the papers' own factor, 1 ignores the view angle.
pub fn view_sin_floored(view_dir: DVec3, floor: f64) -> f64 {
    let floor = if floor.is_nan() { MIN_VIEW_SIN } else { floor.clamp(0.0, 1.0) };
    let len = view_dir.length();
    if !len.is_finite() || len == 0.0 {
        return 1.0;
    }
    (view_dir.truncate().length() / len).clamp(floor, 1.0)
}

/// DSS paper Eq. 3: `rho = lambda * delta / d * sin(theta)`, with `sin(theta)` from
/// [`view_sin`] (floored at [`MIN_VIEW_SIN`]) and the degenerate cases of [`plain`].
pub fn dss(lambda: f64, delta: f64, d: f64, view_dir: DVec3) -> f64 {
    dss_floored(lambda, delta, d, view_dir, MIN_VIEW_SIN)
}

/// [`dss`] with the view-angle floor `floor` ([`view_sin_floored`]).
pub fn dss_floored(lambda: f64, delta: f64, d: f64, view_dir: DVec3, floor: f64) -> f64 {
    dss_at_sin(lambda, delta, d, view_sin_floored(view_dir, floor))
}

/// [`dss_floored`] with its view-angle factor `sin` ([`view_sin_floored`]) worked out by the
/// caller: once per node for its 32 errors.
pub fn dss_at_sin(lambda: f64, delta: f64, d: f64, sin: f64) -> f64 {
    let rho = plain(lambda, delta, d);
    if rho.is_infinite() { rho } else { rho * sin }
}

/// The out-of-core paper's `beta` (Eq. 7): the angle between the sight line (`view_dir`) and
/// the direction from the eye to the node (`eye_to_node`), clamped into `[0, pi/2]`: nodes
/// more than 90 degrees off the sight line (behind the camera) count as 90 degrees, where
/// `1 + sin(beta)` has its largest value 2. A zero or non-finite vector gives `beta = 0`
/// (the node is on the sight line; the largest error, the safe side).
pub fn beta(view_dir: DVec3, eye_to_node: DVec3) -> f64 {
    let (a, b) = (view_dir.length(), eye_to_node.length());
    if !(a.is_finite() && b.is_finite()) || a == 0.0 || b == 0.0 {
        return 0.0;
    }
    let c = (view_dir.dot(eye_to_node) / (a * b)).clamp(-1.0, 1.0);
    c.acos().min(std::f64::consts::FRAC_PI_2)
}

/// `sin(beta)` of [`beta`] without the angle: `|v x w| / (|v| |w|)` (the cross product's
/// length, exact where `beta` is small, unlike `sqrt(1 - cos^2 beta)`), 1 where the node is 90
/// degrees or more off the sight line (`v . w <= 0`, [`beta`]'s clamp), 0 for a zero or
/// non-finite vector. Equals `beta(v, w).sin()` up to rounding (test
/// `sin_beta_equals_the_angle_s_sine`); Eq. 7 needs only the sine, and `acos` plus `sin` were
/// 13 % of the out-of-core selection's profile.
pub fn sin_beta(view_dir: DVec3, eye_to_node: DVec3) -> f64 {
    let (a2, b2) = (view_dir.length_squared(), eye_to_node.length_squared());
    if !(a2.is_finite() && b2.is_finite()) || a2 == 0.0 || b2 == 0.0 {
        return 0.0;
    }
    if view_dir.dot(eye_to_node) <= 0.0 {
        return 1.0;
    }
    (view_dir.cross(eye_to_node).length_squared() / (a2 * b2)).sqrt().min(1.0)
}

/// Out-of-core paper Eq. 6: `rho = H delta cos(theta) / (2 D tan(alpha / 2))`.
///
/// The paper calls `H` the screen *width* while `alpha` is the *vertical* field angle; we pair
/// like with like, `H / (2 tan(alpha/2)) = lambda` with the viewport height and vertical fov.
/// `cos(theta)` is [`view_sin`] (the same quantity, same floor). `d` is the paper's `D`.
pub fn sight_line_eq6(lambda: f64, delta: f64, d: f64, view_dir: DVec3) -> f64 {
    // Identical in form to DSS Eq. 3; kept separate for the citation.
    dss(lambda, delta, d, view_dir)
}

/// Out-of-core paper Eq. 7: `rho = H delta cos(theta) / (2 D tan(alpha/2) (1 + sin(beta)))`,
/// with `sin(beta)` from [`sin_beta`] (the angle [`beta`] itself is not needed). The paper's text says "split when `rho <= tau`"; its algorithm
/// (section 3.3, step 4) splits when `rho > tau`, which is the one that makes sense and the
/// one callers should use.
pub fn sight_line_eq7(lambda: f64, delta: f64, d: f64, view_dir: DVec3, eye_to_node: DVec3) -> f64 {
    SightLineEq7::new(lambda, view_dir).rho(delta, d, eye_to_node)
}

/// [`sight_line_eq7`] with its per-view part computed once (`lambda cos(theta)` and the unit
/// sight line): a selection evaluates Eq. 7 for thousands of nodes per frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SightLineEq7 {
    /// `lambda` times [`view_sin`] (Eq. 6's `H cos(theta) / (2 tan(alpha / 2))`).
    lambda_cos: f64,
    /// The unit sight line (zero for a zero or non-finite one: `beta = 0`).
    dir: DVec3,
}

impl SightLineEq7 {
    /// The per-view part of Eq. 7 for `lambda` and the sight line `view_dir`.
    pub fn new(lambda: f64, view_dir: DVec3) -> Self {
        Self::floored(lambda, view_dir, MIN_VIEW_SIN)
    }

    /// [`SightLineEq7::new`] with the view-angle floor `floor` ([`view_sin_floored`]).
    pub fn floored(lambda: f64, view_dir: DVec3, floor: f64) -> Self {
        let len = view_dir.length();
        let dir = if len.is_finite() && len > 0.0 { view_dir / len } else { DVec3::ZERO };
        Self { lambda_cos: lambda * view_sin_floored(view_dir, floor), dir }
    }

    /// Eq. 7's `rho` for object-space error `delta` at distance `d`, the node at `eye_to_node`
    /// (the degenerate cases of [`plain`]).
    pub fn rho(&self, delta: f64, d: f64, eye_to_node: DVec3) -> f64 {
        let rho = plain(self.lambda_cos, delta, d);
        if rho.is_infinite() { rho } else { rho / (1.0 + sin_beta(self.dir, eye_to_node)) }
    }
}

/// The axis-aligned world box of a node: its clipped samples' extent and height range (filled
/// void heights included: they are rendered).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeBox {
    /// South-west-bottom corner (world metres).
    pub min: DVec3,
    /// North-east-top corner (world metres).
    pub max: DVec3,
}

impl NodeBox {
    /// The box of `region`; `None` for a zero-area region.
    pub fn of(hm: &Heightmap, region: Region) -> Option<Self> {
        let c = region.clip(hm)?;
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for j in c.y0..=c.y1 {
            for i in c.x0..=c.x1 {
                let z = hm.get(i, j);
                lo = lo.min(z);
                hi = hi.max(z);
            }
        }
        let a = hm.grid_to_world(c.x0 as f64, c.y0 as f64);
        let b = hm.grid_to_world(c.x1 as f64, c.y1 as f64);
        Some(Self { min: a.extend(f64::from(lo)), max: b.extend(f64::from(hi)) })
    }

    /// Centre of the box.
    pub fn centre(&self) -> DVec3 {
        self.min + (self.max - self.min) * 0.5
    }

    /// Euclidean distance from `eye` to the box; 0 when the eye is inside or on it (the
    /// must-split case for the screen errors). Computed from per-axis differences, so large
    /// projected origins lose no precision.
    pub fn distance(&self, eye: DVec3) -> f64 {
        let d = (self.min - eye).max(eye - self.max).max(DVec3::ZERO);
        d.length()
    }

    /// Vector from `eye` to the box centre (for [`beta`]).
    pub fn eye_to_centre(&self, eye: DVec3) -> DVec3 {
        (self.min - eye) + (self.max - self.min) * 0.5
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::dvec3;

    #[test]
    fn lambda_matches_definition_and_clamps() {
        let l = lambda(1080.0, 60f64.to_radians());
        assert!((l - 1080.0 / (2.0 * 30f64.to_radians().tan())).abs() < 1e-9);
        assert!(lambda(1080.0, 0.0).is_finite() && lambda(1080.0, 0.0) > l);
        assert!(lambda(1080.0, 4.0) > 0.0 && lambda(1080.0, 4.0) < l);
        assert_eq!(lambda(f64::NAN, 1.0), 0.0);
        assert!(lambda(1080.0, f64::NAN).is_finite());
    }

    #[test]
    fn inside_box_must_split_unless_exact() {
        assert_eq!(plain(1000.0, 1.0, 0.0), MUST_SPLIT);
        assert_eq!(dss(1000.0, 1.0, 0.0, dvec3(0.0, 0.0, -1.0)), MUST_SPLIT);
        assert_eq!(sight_line_eq7(1000.0, 1.0, 0.0, DVec3::X, DVec3::ZERO), MUST_SPLIT);
        assert_eq!(plain(1000.0, 0.0, 0.0), 0.0);
        assert_eq!(plain(1000.0, 2.0, 10.0), 200.0);
    }

    #[test]
    fn straight_down_is_floored() {
        let down = dvec3(0.0, 0.0, -1.0);
        assert_eq!(view_sin(down), MIN_VIEW_SIN);
        assert_eq!(dss(100.0, 1.0, 10.0, down), 10.0 * MIN_VIEW_SIN);
        assert_eq!(view_sin(dvec3(1.0, 0.0, 0.0)), 1.0);
        assert_eq!(view_sin(DVec3::ZERO), 1.0);
        let s = view_sin(dvec3(1.0, 0.0, -1.0));
        assert!((s - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-12);
    }

    #[test]
    fn beta_limits() {
        assert_eq!(beta(DVec3::X, DVec3::X * 5.0), 0.0);
        assert!((beta(DVec3::X, DVec3::Y) - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert_eq!(beta(DVec3::X, -DVec3::X), std::f64::consts::FRAC_PI_2);
        assert_eq!(beta(DVec3::ZERO, DVec3::X), 0.0);
        // Eq. 7 halves Eq. 6 at beta = 90 degrees.
        let e6 = sight_line_eq6(100.0, 1.0, 10.0, DVec3::X);
        assert_eq!(sight_line_eq7(100.0, 1.0, 10.0, DVec3::X, DVec3::Y), e6 / 2.0);
        assert_eq!(sight_line_eq7(100.0, 1.0, 10.0, DVec3::X, DVec3::X), e6);
    }

    #[test]
    fn sin_beta_equals_the_angle_s_sine() {
        let mut uniform = crate::test_support::unit_rng(0x9e37_79b9_7f4a_7c15);
        let mut unit = move || uniform() * 2.0 - 1.0;
        for k in 0..20_000 {
            let v = dvec3(unit(), unit(), unit());
            // Some nodes almost on the sight line (small beta: there `acos` of a cosine near 1
            // loses digits, the reference's error, about 1e-16 / beta).
            let w = if k % 4 == 0 {
                v * 3.0 + dvec3(unit(), unit(), unit()) * 1e-6
            } else {
                dvec3(unit(), unit(), unit()) * 1e4
            };
            // Eq. 7 divides by `1 + sin(beta)`: an absolute difference of the sines is the
            // relative difference of `rho` (the selection tests allow 1e-6).
            let (got, want) = (sin_beta(v, w), beta(v, w).sin());
            assert!((got - want).abs() <= 1e-7, "{v} {w}: {got} vs {want}");
        }
        assert_eq!(sin_beta(DVec3::X, -DVec3::X), 1.0);
        assert_eq!(sin_beta(DVec3::X, DVec3::Y), 1.0);
        assert_eq!(sin_beta(DVec3::X, DVec3::X * 5.0), 0.0);
        assert_eq!(sin_beta(DVec3::ZERO, DVec3::X), 0.0);
        assert_eq!(sin_beta(dvec3(f64::NAN, 0.0, 0.0), DVec3::X), 0.0);
    }

    #[test]
    fn box_distance() {
        let b = NodeBox { min: dvec3(0.0, 0.0, 0.0), max: dvec3(10.0, 10.0, 5.0) };
        assert_eq!(b.distance(dvec3(5.0, 5.0, 2.0)), 0.0);
        assert_eq!(b.distance(dvec3(5.0, 5.0, 8.0)), 3.0);
        assert_eq!(b.distance(dvec3(13.0, 14.0, 5.0)), 5.0);
    }
}
