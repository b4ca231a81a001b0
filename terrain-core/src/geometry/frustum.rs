//! The view frustum as six f64 planes, and box / sphere classification.

use glam::{DMat4, DVec3, DVec4, dvec3};

use super::{aabb::Aabb, camera::Camera};

/// A plane `normal . p + d = 0`; the positive side (`>= 0`) is inside.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// Unit normal pointing into the frustum.
    pub normal: DVec3,
    /// Offset: `-normal . (any point on the plane)`.
    pub d: f64,
}

impl Plane {
    /// The plane through `point` with (not necessarily unit) inward normal `normal`.
    pub fn from_point_normal(point: DVec3, normal: DVec3) -> Self {
        let n = normal.normalize();
        Self { normal: n, d: -n.dot(point) }
    }

    /// Signed distance of `p` (positive inside).
    #[inline]
    pub fn distance(&self, p: DVec3) -> f64 {
        self.normal.dot(p) + self.d
    }

    /// Normalises a plane given as raw coefficients `(a, b, c, d)`.
    fn from_coefficients(v: DVec4) -> Self {
        let len = v.truncate().length();
        Self { normal: v.truncate() / len, d: v.w / len }
    }
}

/// Where a volume lies with respect to a frustum.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Classification {
    /// Entirely outside (certainly invisible).
    Outside,
    /// Straddles at least one plane, or could not be proven inside or outside.
    Intersecting,
    /// Entirely inside every plane.
    Inside,
}

/// A view frustum: six planes with inward normals, in world coordinates (f64).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frustum {
    /// Left, right, bottom, top, near, far.
    pub planes: [Plane; 6],
}

impl Frustum {
    /// Index of the left plane in [`Frustum::planes`].
    pub const LEFT: usize = 0;
    /// Index of the right plane.
    pub const RIGHT: usize = 1;
    /// Index of the bottom plane.
    pub const BOTTOM: usize = 2;
    /// Index of the top plane.
    pub const TOP: usize = 3;
    /// Index of the near plane.
    pub const NEAR: usize = 4;
    /// Index of the far plane.
    pub const FAR: usize = 5;

    /// The planes built directly from the camera's pose and field of view (the most
    /// accurate way: no matrix inversion, no f32).
    pub fn from_camera(c: &Camera) -> Self {
        let tx = c.tan_half_fov_x();
        let ty = (c.fov_y * 0.5).tan();
        let q = c.orientation;
        let e = c.position;
        // Inward normals in view space (camera looks down -Z): e.g. the right plane holds
        // the direction (tx, 0, -1) and the Y axis, and the axis (0, 0, -1) is on its inside.
        let side = |n: DVec3| Plane::from_point_normal(e, q * n);
        let f = c.forward();
        Self {
            planes: [
                side(dvec3(1.0, 0.0, -tx)),
                side(dvec3(-1.0, 0.0, -tx)),
                side(dvec3(0.0, 1.0, -ty)),
                side(dvec3(0.0, -1.0, -ty)),
                Plane::from_point_normal(e + f * c.near, f),
                Plane::from_point_normal(e + f * c.far, -f),
            ],
        }
    }

    /// The planes of a world -> clip matrix with wgpu's clip volume (`-w <= x, y <= w`,
    /// `0 <= z <= w`), by the Gribb-Hartmann row combinations. Same order as
    /// [`Frustum::from_camera`].
    pub fn from_view_proj(m: DMat4) -> Self {
        let (r0, r1, r2, r3) = (m.row(0), m.row(1), m.row(2), m.row(3));
        Self {
            planes: [r3 + r0, r3 - r0, r3 + r1, r3 - r1, r2, r3 - r2].map(Plane::from_coefficients),
        }
    }

    /// Whether `p` is inside or on every plane.
    pub fn contains_point(&self, p: DVec3) -> bool {
        self.planes.iter().all(|pl| pl.distance(p) >= 0.0)
    }

    /// Classifies a box by the usual nearest/farthest-corner test against each plane.
    ///
    /// `Outside` is exact (the box is behind one plane). `Intersecting` is conservative:
    /// a box near a frustum edge but outside it may be reported as intersecting.
    pub fn classify(&self, b: &Aabb) -> Classification {
        if b.is_empty() {
            return Classification::Outside;
        }
        let mut result = Classification::Inside;
        for pl in &self.planes {
            let n = pl.normal;
            // The corner farthest along the normal and the one farthest against it.
            let pos = DVec3::select(n.cmpge(DVec3::ZERO), b.max, b.min);
            let neg = DVec3::select(n.cmpge(DVec3::ZERO), b.min, b.max);
            if pl.distance(pos) < 0.0 {
                return Classification::Outside;
            }
            if pl.distance(neg) < 0.0 {
                result = Classification::Intersecting;
            }
        }
        result
    }

    /// Classifies a sphere (conservative in the same way as [`Frustum::classify`]).
    pub fn classify_sphere(&self, center: DVec3, radius: f64) -> Classification {
        let mut result = Classification::Inside;
        for pl in &self.planes {
            let s = pl.distance(center);
            if s < -radius {
                return Classification::Outside;
            }
            if s < radius {
                result = Classification::Intersecting;
            }
        }
        result
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use Classification::*;

    fn cam() -> Camera {
        // At 100 m, looking north, level.
        Camera::from_yaw_pitch(dvec3(0.0, 0.0, 100.0), 0.0, 0.0).with_clip(1.0, 1000.0)
    }

    fn cube(c: DVec3, h: f64) -> Aabb {
        Aabb::new(c - DVec3::splat(h), c + DVec3::splat(h))
    }

    #[test]
    fn boxes_in_front_behind_straddling() {
        let f = cam().frustum();
        assert_eq!(f.classify(&cube(dvec3(0.0, 200.0, 100.0), 5.0)), Inside);
        assert_eq!(f.classify(&cube(dvec3(0.0, -200.0, 100.0), 5.0)), Outside);
        // Beyond the far plane / straddling it.
        assert_eq!(f.classify(&cube(dvec3(0.0, 1100.0, 100.0), 5.0)), Outside);
        assert_eq!(f.classify(&cube(dvec3(0.0, 1000.0, 100.0), 5.0)), Intersecting);
        // Straddling the near plane and the eye.
        assert_eq!(f.classify(&cube(dvec3(0.0, 0.0, 100.0), 5.0)), Intersecting);
        // Far to the east at short range: outside the right plane.
        assert_eq!(f.classify(&cube(dvec3(500.0, 100.0, 100.0), 5.0)), Outside);
        // Straddling the right plane (hfov half-angle atan(16/9 * tan 30deg) ~ 45.8 deg).
        let tx = cam().tan_half_fov_x();
        assert_eq!(f.classify(&cube(dvec3(200.0 * tx, 200.0, 100.0), 5.0)), Intersecting);
        // A huge box holding the whole frustum intersects.
        assert_eq!(f.classify(&cube(DVec3::ZERO, 1e5)), Intersecting);
        assert_eq!(f.classify(&Aabb::EMPTY), Outside);
        assert_eq!(f.classify_sphere(dvec3(0.0, 200.0, 100.0), 5.0), Inside);
        assert_eq!(f.classify_sphere(dvec3(0.0, -200.0, 100.0), 5.0), Outside);
        assert_eq!(f.classify_sphere(dvec3(0.0, 1.0, 100.0), 5.0), Intersecting);
    }

    #[test]
    fn matrix_planes_match_camera_planes() {
        for c in [
            cam(),
            Camera::from_yaw_pitch(dvec3(5e5, 4e6, 3000.0), 37.0, -25.0),
            Camera::from_yaw_pitch(dvec3(1.0, 2.0, 3.0), 0.0, -90.0),
        ] {
            let a = c.frustum();
            let b = Frustum::from_view_proj(c.projection_f64() * c.view_f64());
            for (p, q) in a.planes.iter().zip(&b.planes) {
                assert!((p.normal - q.normal).length() < 1e-9, "{p:?} {q:?}");
                assert!((p.d - q.d).abs() < 1e-6 * (1.0 + p.d.abs()), "{p:?} {q:?}");
            }
            // Every corner of the frustum is on or inside every plane.
            for k in c.frustum_corners() {
                assert!(a.planes.iter().all(|p| p.distance(k) > -1e-6 * (1.0 + k.length())));
            }
        }
    }

    #[test]
    fn straight_down_camera() {
        let c = Camera::from_yaw_pitch(dvec3(0.0, 0.0, 500.0), 0.0, -90.0).with_clip(1.0, 1000.0);
        let f = c.frustum();
        // The ground right below is inside; the ground 1 km to the side is outside.
        let ground = |x: f64, y: f64| {
            Aabb::new(dvec3(x - 10.0, y - 10.0, 0.0), dvec3(x + 10.0, y + 10.0, 5.0))
        };
        assert_eq!(f.classify(&ground(0.0, 0.0)), Inside);
        assert_eq!(f.classify(&ground(1000.0, 0.0)), Outside);
        assert_eq!(f.classify(&ground(0.0, -1000.0)), Outside);
        // Above the camera: behind the near plane.
        assert_eq!(f.classify(&cube(dvec3(0.0, 0.0, 600.0), 5.0)), Outside);
        // Wider than tall: at 500 m the half-extents are 500 tan30 ~ 289 (north) and ~513 (east).
        assert_eq!(f.classify(&ground(400.0, 0.0)), Inside);
        assert_eq!(f.classify(&ground(0.0, 400.0)), Outside);
    }

    #[test]
    fn grazing_camera() {
        // 2 m above flat ground, looking 1 degree down: the ground is seen from far ahead.
        let c = Camera::from_yaw_pitch(dvec3(0.0, 0.0, 2.0), 0.0, -1.0).with_clip(0.5, 5000.0);
        let f = c.frustum();
        let tile = |y: f64| Aabb::new(dvec3(-20.0, y, 0.0), dvec3(20.0, y + 40.0, 0.0));
        // Right below the eye: below the bottom plane (30 deg below the view axis).
        assert_eq!(f.classify(&Aabb::new(dvec3(-1.0, 0.0, 0.0), dvec3(1.0, 1.0, 0.0))), Outside);
        for y in [100.0, 1000.0, 3000.0] {
            assert_ne!(f.classify(&tile(y)), Outside, "tile at {y}");
        }
        assert_eq!(f.classify(&tile(-100.0)), Outside);
        assert_eq!(f.classify(&tile(6000.0)), Outside);
        // The flat ground tile is cut by the bottom plane near the eye but fully in view
        // far away only if it is above the bottom plane: at 1000 m it is.
        assert_eq!(f.classify(&tile(1000.0)), Inside);
    }
}
