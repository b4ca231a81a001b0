//! The scheduler's geometry (Qiu 2013, section 4): the projected view triangle, the visual
//! region M (blocks meeting it), the view frustum extension with `L` and `S` (Eq. 8), the
//! scheduling region N (blocks meeting the extension), and the pre-loading region N - M.
//!
//! **Reading of the paper's extension.** Fig. 9: the extension is a triangle similar to the
//! view triangle, its apex A a distance `L` behind the eye B along the view axis, and "the
//! distance from vertex A to the hypotenuse is L + R + S". We take that distance along the
//! axis, with R the view triangle's depth (apex to far side), so the extension's depth is
//! `L + R + S` and, being similar with an apex behind the eye, it contains the view
//! triangle. `L` defaults to one block's side ("generally ... the same value as the length
//! of a block boundary"). For the near-vertical fallback polygon (which the paper does not
//! cover) the extension moves each vertex `L + S` away from the polygon's centroid.

use glam::DVec2;
use terrain_core::geometry::{
    Aabb, Camera, Classification, Frustum, GroundRegion, project_view_to_ground,
};

use crate::format::{BlockEntry, BlockId, Header};

/// Parameters of the scheduler.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScheduleConfig {
    /// `L` in metres; `None` (the default) = one block's side.
    pub extension_l_m: Option<f64>,
    /// The frame rate `f` of Eq. 8, frames per second. Default 60. The runtime measures the
    /// eye's speed as its displacement per frame times `f`, so `S = V cos(alpha) / f` is the
    /// displacement of one frame along the sight line whatever `f` is; `f` matters only to
    /// callers of `eq8_s` and `regions` with a velocity of their own.
    pub frame_rate_hz: f64,
    /// How many frames ahead the runtime preloads: `S` of Eq. 8 and the eye used for the
    /// levels prefetched one frame ahead are multiplied by this. Default 1: the paper's
    /// one-frame Eq. 8 ("the predicted data of next frame").
    pub lookahead_frames: f64,
    /// Latency-aware Eq. 8: the look-ahead grows with the measured request latency over the
    /// frame interval, `lookahead_frames + latency * f` frames (at most
    /// [`ScheduleConfig::MAX_LATENCY_FRAMES`] more), so a block requested now arrives before the
    /// eye needs it even when each request takes many frames (a store on object storage or
    /// HTTP). The latency is a moving average of the workers' request times
    /// ([`crate::FrameStats::request_latency`]). Default true; on a local disk it adds a small
    /// fraction of a frame.
    pub latency_aware: bool,
}

impl ScheduleConfig {
    /// The most frames the measured latency adds to the look-ahead.
    pub const MAX_LATENCY_FRAMES: f64 = 60.0;

    /// The look-ahead in frames for a measured request latency of `latency_s` seconds.
    pub fn effective_lookahead(&self, latency_s: f64) -> f64 {
        let extra = if self.latency_aware && latency_s.is_finite() && self.frame_rate_hz > 0.0 {
            (latency_s * self.frame_rate_hz).clamp(0.0, Self::MAX_LATENCY_FRAMES)
        } else {
            0.0
        };
        self.lookahead_frames.max(0.0) + extra
    }
}

impl Default for ScheduleConfig {
    fn default() -> Self {
        Self {
            extension_l_m: None,
            frame_rate_hz: 60.0,
            lookahead_frames: 1.0,
            latency_aware: true,
        }
    }
}

/// Eq. 8: `S = V cos(alpha) / f` for `alpha` (between motion and sight line) in `[0, pi/2)`,
/// else 0. `velocity` is the eye's plan velocity (m/s), `view_dir` the plan view direction.
pub(crate) fn eq8_s(velocity: DVec2, view_dir: DVec2, frame_rate_hz: f64) -> f64 {
    let v = velocity.length();
    let d = view_dir.length();
    if !(v.is_finite() && d.is_finite())
        || v == 0.0
        || d == 0.0
        || frame_rate_hz.is_nan()
        || frame_rate_hz <= 0.0
    {
        return 0.0;
    }
    let cos_a = velocity.dot(view_dir) / (v * d);
    if cos_a > 0.0 { v * cos_a / frame_rate_hz } else { 0.0 }
}

/// The view frustum extension of `view` (see the module docs).
pub(crate) fn extend_region(view: &GroundRegion, l: f64, s: f64) -> GroundRegion {
    match view {
        GroundRegion::Triangle([b, r, lft]) => {
            let mid = (*r + *lft) * 0.5;
            let depth = (mid - *b).length();
            if depth <= 0.0 {
                return view.clone();
            }
            let axis = (mid - *b) / depth;
            let a = *b - axis * l;
            let scale = (l + depth + s) / depth;
            GroundRegion::Triangle([a, a + (*r - *b) * scale, a + (*lft - *b) * scale])
        }
        GroundRegion::Polygon(p) => {
            if p.is_empty() {
                return view.clone();
            }
            let c = p.iter().copied().sum::<DVec2>() / p.len() as f64;
            GroundRegion::Polygon(
                p.iter()
                    .map(|&v| v + (v - c).try_normalize().unwrap_or(DVec2::ZERO) * (l + s))
                    .collect(),
            )
        }
    }
}

/// Whether a convex counter-clockwise polygon meets the rectangle `[lo, hi]` (separating axes).
pub(crate) fn polygon_meets_rect(poly: &[DVec2], lo: DVec2, hi: DVec2) -> bool {
    if poly.is_empty() {
        return false;
    }
    let (mut pmin, mut pmax) = (poly[0], poly[0]);
    for &v in poly {
        pmin = pmin.min(v);
        pmax = pmax.max(v);
    }
    if pmax.x < lo.x || pmin.x > hi.x || pmax.y < lo.y || pmin.y > hi.y {
        return false;
    }
    if poly.len() < 3 {
        return true;
    }
    let corners = [lo, DVec2::new(hi.x, lo.y), hi, DVec2::new(lo.x, hi.y)];
    for k in 0..poly.len() {
        let (a, b) = (poly[k], poly[(k + 1) % poly.len()]);
        let e = b - a;
        // Outward normal of a counter-clockwise edge is (e.y, -e.x).
        let n = DVec2::new(e.y, -e.x);
        if corners.iter().all(|&c| n.dot(c - a) > 0.0) {
            return false;
        }
    }
    true
}

/// Whether a block with box `b` (world metres) is in the visual region M of a frame with view
/// region `view` and frustum `frustum`: its plan rectangle meets the view region and the box
/// is not outside the frustum (the paper's projected triangle alone keeps blocks below and
/// beside a pitched view). The streamer's schedule and the tree warmer's prediction of the
/// next frame's drawn blocks (`warm::next_frame_levels`) ask it.
pub(crate) fn in_visual_region(view: &GroundRegion, frustum: &Frustum, b: &Aabb) -> bool {
    polygon_meets_rect(view.vertices(), b.min.truncate(), b.max.truncate())
        && frustum.classify(b) != Classification::Outside
}

/// The plan rectangle (world metres) of a block's valid (non-padding) vertices.
pub(crate) fn block_rect(header: &Header, entry: &BlockEntry, id: BlockId) -> (DVec2, DVec2) {
    let a = header.vertex_world(id, 0.0, 0.0);
    let b = header.vertex_world(id, (entry.valid_w - 1) as f64, (entry.valid_h - 1) as f64);
    (a.min(b), a.max(b))
}

/// Candidate blocks under the bounding box of `region`, row-major (deterministic); callers
/// test each with [`polygon_meets_rect`] against [`block_rect`].
pub(crate) fn blocks_under_bbox(header: &Header, region: &GroundRegion) -> Vec<BlockId> {
    let v = region.vertices();
    if v.is_empty() {
        return Vec::new();
    }
    let (mut lo, mut hi) = (v[0], v[0]);
    for &p in v {
        lo = lo.min(p);
        hi = hi.max(p);
    }
    let c = header.block_cells() as f64;
    let g0 = header.georef.world_to_grid(lo) / c;
    let g1 = header.georef.world_to_grid(hi) / c;
    let clamp_x = |x: f64| x.floor().clamp(0.0, header.blocks_x as f64 - 1.0) as u32;
    let clamp_y = |y: f64| y.floor().clamp(0.0, header.blocks_y as f64 - 1.0) as u32;
    if g1.x < 0.0 || g1.y < 0.0 || g0.x > header.blocks_x as f64 || g0.y > header.blocks_y as f64 {
        return Vec::new();
    }
    let mut out = Vec::new();
    for row in clamp_y(g0.y)..=clamp_y(g1.y) {
        for col in clamp_x(g0.x)..=clamp_x(g1.x) {
            out.push(BlockId::new(row, col));
        }
    }
    out
}

/// The two regions of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Regions {
    /// The projected view triangle (or the near-vertical fallback polygon).
    pub view: GroundRegion,
    /// The view frustum extension.
    pub extension: GroundRegion,
    /// `L` used, metres.
    pub l_m: f64,
    /// `S` used (Eq. 8 times the look-ahead), metres.
    pub s_m: f64,
}

/// The regions for `camera` moving at plan `velocity` (m/s).
pub(crate) fn regions(
    header: &Header,
    config: &ScheduleConfig,
    camera: &Camera,
    velocity: DVec2,
) -> Regions {
    let view = project_view_to_ground(camera);
    let block_m = header.block_cells() as f64 * header.georef.spacing_m.max_element();
    let l_m = config.extension_l_m.unwrap_or(block_m).max(0.0);
    let s_m = eq8_s(velocity, camera.forward().truncate(), config.frame_rate_hz)
        * config.lookahead_frames.max(0.0);
    let extension = extend_region(&view, l_m, s_m);
    Regions { view, extension, l_m, s_m }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::dvec2;

    #[test]
    fn eq8_follows_the_paper() {
        let f = 50.0;
        assert_eq!(eq8_s(dvec2(0.0, 100.0), dvec2(0.0, 1.0), f), 2.0);
        // 60 degrees between motion and sight line: cos = 1/2.
        let v = dvec2(3f64.sqrt() * 50.0, 50.0);
        assert!((eq8_s(v, dvec2(0.0, 1.0), f) - 1.0).abs() < 1e-12);
        // Sideways or backwards: 0.
        assert_eq!(eq8_s(dvec2(100.0, 0.0), dvec2(0.0, 1.0), f), 0.0);
        assert_eq!(eq8_s(dvec2(0.0, -100.0), dvec2(0.0, 1.0), f), 0.0);
        assert_eq!(eq8_s(DVec2::ZERO, dvec2(0.0, 1.0), f), 0.0);
    }

    #[test]
    fn the_extension_is_similar_and_contains_the_view() {
        let view =
            GroundRegion::Triangle([dvec2(0.0, 0.0), dvec2(100.0, 100.0), dvec2(-100.0, 100.0)]);
        let ext = extend_region(&view, 10.0, 5.0);
        let GroundRegion::Triangle(t) = &ext else { panic!("a triangle") };
        assert_eq!(t[0], dvec2(0.0, -10.0));
        // Depth L + R + S = 10 + 100 + 5 from the apex.
        assert!(((t[1].y - t[0].y) - 115.0).abs() < 1e-9);
        for p in view.vertices() {
            assert!(ext.contains(*p));
        }
        assert!(polygon_meets_rect(ext.vertices(), dvec2(-5.0, -5.0), dvec2(5.0, 5.0)));
        assert!(!polygon_meets_rect(view.vertices(), dvec2(50.0, 0.0), dvec2(60.0, 40.0)));
        assert!(polygon_meets_rect(view.vertices(), dvec2(50.0, 0.0), dvec2(60.0, 55.0)));
    }
}
