//! The out-of-core paper's (Qiu 2013) projected view region on the ground plane (its
//! section 3.1) and its bounding-circle test for quadtree nodes (its section 3.3).
//!
//! The paper works in OpenGL's y-up frame and projects the frustum onto its x-z plane; in
//! our z-up frame that is the x-y (plan) plane: paper (X, Y, Z) = our (x, z, -y). The
//! paper keeps three of the six planes (left, right, far) and drops near, top and bottom, so
//! the region is an isosceles triangle: apex at the eye, two legs of length R along the
//! outermost horizontal viewing directions, and the far side square to the horizontal
//! heading (its Fig. 5 and Fig. 9).
//!
//! Our construction is an *orthogonal* projection along z, so it is conservative for any
//! terrain height: every point inside the 3D frustum has its plan position inside the
//! region, whatever its z (the `ground_z` argument only sets the plane the region is
//! reported on). The triangle is the smallest isosceles triangle with apex at the eye's plan
//! position, axis along the horizontal heading, holding the plan positions of the four far
//! corners (the near corners lie on the segments from the eye to the far corners, so they
//! are inside too).
//!
//! Degenerate views: when the camera looks (nearly) straight down or up, some far corner is
//! level with or behind the eye horizontally and no such triangle exists (the paper does
//! not cover the case). We then fall back to [`GroundRegion::Polygon`], the convex hull of
//! the plan positions of all eight frustum corners, which is exactly the frustum's
//! projection: still conservative, and tight. The fallback is taken when any far corner's
//! horizontal distance along the heading is below 1e-6 of the far distance or the triangle's
//! half-angle would exceed 80 degrees.

use glam::{DVec2, DVec3};

use super::{camera::Camera, frustum::Classification};

/// A convex region of the ground plane (plan coordinates x east, y north), vertices in
/// counter-clockwise order.
#[derive(Debug, Clone, PartialEq)]
pub enum GroundRegion {
    /// The paper's projected view triangle, counter-clockwise: `[apex (the eye's plan
    /// position), far-right corner, far-left corner]`.
    Triangle([DVec2; 3]),
    /// The fallback for (near-)vertical views: the convex hull of the projected frustum.
    Polygon(Vec<DVec2>),
}

impl GroundRegion {
    /// Counter-clockwise vertices.
    pub fn vertices(&self) -> &[DVec2] {
        match self {
            GroundRegion::Triangle(t) => t,
            GroundRegion::Polygon(p) => p,
        }
    }

    /// Whether the plan point `p` is inside or on the boundary.
    pub fn contains(&self, p: DVec2) -> bool {
        let v = self.vertices();
        (0..v.len()).all(|k| edge_signed_distance(v[k], v[(k + 1) % v.len()], p) >= -1e-9)
    }

    /// The region's vertices on the plane `z = ground_z` (for drawing and debugging).
    pub fn vertices_3d(&self, ground_z: f64) -> Vec<DVec3> {
        self.vertices().iter().map(|v| v.extend(ground_z)).collect()
    }
}

/// Signed distance of `p` from the directed edge `a -> b` (positive on the left, i.e.
/// inside a counter-clockwise polygon).
fn edge_signed_distance(a: DVec2, b: DVec2, p: DVec2) -> f64 {
    let e = b - a;
    let len = e.length();
    if len == 0.0 {
        return -(p - a).length();
    }
    e.perp_dot(p - a) / len
}

/// Distance from `p` to the segment `a b`.
fn segment_distance(a: DVec2, b: DVec2, p: DVec2) -> f64 {
    let e = b - a;
    let t = if e.length_squared() == 0.0 {
        0.0
    } else {
        ((p - a).dot(e) / e.length_squared()).clamp(0.0, 1.0)
    };
    (a + e * t - p).length()
}

/// The plan region seen by `camera` (see the module docs): the paper's triangle, or the
/// projected frustum's convex hull for (near-)vertical views.
pub fn project_view_to_ground(camera: &Camera) -> GroundRegion {
    let corners = camera.frustum_corners();
    let eye = camera.position.truncate();
    let f3 = camera.forward();
    let fh = f3.truncate();
    if fh.length() > 1e-9 {
        let fh = fh.normalize();
        let rh = DVec2::new(fh.y, -fh.x); // right of the heading
        let mut max_u = 0.0f64;
        let mut max_tan = 0.0f64;
        let mut ok = true;
        for c in &corners[4..] {
            let d = c.truncate() - eye;
            let (u, v) = (d.dot(fh), d.dot(rh));
            if u <= 1e-6 * camera.far {
                ok = false;
                break;
            }
            max_u = max_u.max(u);
            max_tan = max_tan.max(v.abs() / u);
        }
        if ok && max_tan < 80f64.to_radians().tan() {
            let base = eye + fh * max_u;
            let half = rh * (max_u * max_tan);
            // apex, far-right, far-left: counter-clockwise (right is clockwise of forward).
            return GroundRegion::Triangle([eye, base + half, base - half]);
        }
    }
    GroundRegion::Polygon(convex_hull(corners.iter().map(|c| c.truncate()).collect()))
}

/// Counter-clockwise convex hull (Andrew's monotone chain), collinear points dropped.
fn convex_hull(mut pts: Vec<DVec2>) -> Vec<DVec2> {
    pts.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    pts.dedup();
    if pts.len() < 3 {
        return pts;
    }
    let cross = |o: DVec2, a: DVec2, b: DVec2| (a - o).perp_dot(b - o);
    let mut hull: Vec<DVec2> = Vec::with_capacity(2 * pts.len());
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &DVec2>> =
            if pass == 0 { Box::new(pts.iter()) } else { Box::new(pts.iter().rev()) };
        for &p in iter {
            while hull.len() >= start + 2
                && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0
            {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop();
    }
    hull
}

/// The paper's bounding-circle test (its section 3.3, step 2-3): a quadtree node's circle
/// has the node's plan diagonal as diameter; `Outside` when it misses the region, `Inside`
/// when the whole circle is inside, `Intersecting` otherwise.
pub fn circle_vs_region(region: &GroundRegion, center: DVec2, radius: f64) -> Classification {
    let v = region.vertices();
    if v.len() < 3 {
        return Classification::Intersecting; // degenerate region: never reject
    }
    let n = v.len();
    let mut min_signed = f64::INFINITY;
    for k in 0..n {
        min_signed = min_signed.min(edge_signed_distance(v[k], v[(k + 1) % n], center));
    }
    if min_signed >= radius {
        return Classification::Inside;
    }
    if min_signed >= 0.0 {
        return Classification::Intersecting; // centre inside
    }
    let nearest = (0..n)
        .map(|k| segment_distance(v[k], v[(k + 1) % n], center))
        .fold(f64::INFINITY, f64::min);
    if nearest <= radius { Classification::Intersecting } else { Classification::Outside }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{dvec2, dvec3};

    #[test]
    fn level_camera_gives_isosceles_triangle() {
        let c = Camera::from_yaw_pitch(dvec3(100.0, 200.0, 50.0), 0.0, 0.0)
            .with_fov_y_deg(60.0)
            .with_viewport(1000.0, 1000.0)
            .with_clip(1.0, 1000.0);
        let GroundRegion::Triangle(t) = project_view_to_ground(&c) else {
            panic!("expected a triangle")
        };
        // Looking north, square viewport: base at y = 200 + 1000, half-width 1000 tan 30.
        let h = 1000.0 * 30f64.to_radians().tan();
        assert!((t[0] - dvec2(100.0, 200.0)).length() < 1e-9);
        assert!((t[1] - dvec2(100.0 + h, 1200.0)).length() < 1e-6, "{t:?}");
        assert!((t[2] - dvec2(100.0 - h, 1200.0)).length() < 1e-6);
        // Isosceles: legs R equal.
        assert!(((t[1] - t[0]).length() - (t[2] - t[0]).length()).abs() < 1e-9);
        let r = GroundRegion::Triangle(t);
        assert!(r.contains(dvec2(100.0, 700.0)));
        assert!(!r.contains(dvec2(100.0, 100.0)));
        assert!(!r.contains(dvec2(100.0 + 600.0, 700.0)));
    }

    #[test]
    fn triangle_holds_every_frustum_point() {
        for (yaw, pitch) in [(0.0, 0.0), (33.0, -20.0), (250.0, -50.0), (120.0, 30.0)] {
            let c =
                Camera::from_yaw_pitch(dvec3(5e5, 4e6, 3000.0), yaw, pitch).with_clip(1.0, 2000.0);
            let r = project_view_to_ground(&c);
            assert!(matches!(r, GroundRegion::Triangle(_)), "yaw {yaw} pitch {pitch}: {r:?}");
            // Sample rays through the viewport: every point along them is inside the region.
            for k in 0..25 {
                let px = dvec2((k % 5) as f64 * 320.0, (k / 5) as f64 * 180.0);
                let d = c.pixel_ray(px);
                for t in [1.0, 100.0, 1000.0] {
                    let p = c.position + d * t * (1.0 / d.dot(c.forward()));
                    assert!(r.contains(p.truncate()), "{p}");
                }
            }
        }
    }

    #[test]
    fn straight_down_and_up_fall_back_to_the_projected_frustum() {
        let c = Camera::from_yaw_pitch(dvec3(0.0, 0.0, 500.0), 0.0, -90.0).with_clip(1.0, 1000.0);
        let r = project_view_to_ground(&c);
        let GroundRegion::Polygon(p) = &r else { panic!("expected the fallback polygon") };
        // A rectangle: the far-plane footprint, 1000 tan30 north-south, 1000 * 16/9 tan30 east-west.
        assert_eq!(p.len(), 4);
        let ty = 1000.0 * 30f64.to_radians().tan();
        assert!(r.contains(dvec2(0.0, 0.0)));
        assert!(r.contains(dvec2(ty * 16.0 / 9.0 - 1.0, ty - 1.0)));
        assert!(!r.contains(dvec2(0.0, ty + 1.0)));
        let up = Camera::from_yaw_pitch(dvec3(0.0, 0.0, 500.0), 45.0, 89.0).with_clip(1.0, 1000.0);
        let r = project_view_to_ground(&up);
        assert!(matches!(r, GroundRegion::Polygon(_)));
        assert!(r.contains(dvec2(0.0, 0.0)));
        // Steep-down views whose bottom edge passes the vertical also fall back.
        let steep = Camera::from_yaw_pitch(dvec3(0.0, 0.0, 500.0), 0.0, -70.0);
        let r = project_view_to_ground(&steep);
        assert!(matches!(r, GroundRegion::Polygon(_)));
        // Points south of the eye (seen past the vertical) are inside the fallback.
        assert!(r.contains(dvec2(0.0, -10.0)));
    }

    #[test]
    fn bounding_circle_classification() {
        let r =
            GroundRegion::Triangle([dvec2(0.0, 0.0), dvec2(100.0, 100.0), dvec2(-100.0, 100.0)]);
        assert_eq!(circle_vs_region(&r, dvec2(0.0, 60.0), 5.0), Classification::Inside);
        assert_eq!(circle_vs_region(&r, dvec2(0.0, 60.0), 50.0), Classification::Intersecting);
        assert_eq!(circle_vs_region(&r, dvec2(0.0, -10.0), 5.0), Classification::Outside);
        // Centre outside but the circle reaches the apex.
        assert_eq!(circle_vs_region(&r, dvec2(0.0, -10.0), 10.5), Classification::Intersecting);
        // Outside near the corner (beyond both the edge lines' reach).
        assert_eq!(circle_vs_region(&r, dvec2(110.0, 110.0), 14.0), Classification::Outside);
        assert_eq!(circle_vs_region(&r, dvec2(110.0, 110.0), 14.2), Classification::Intersecting);
    }
}
