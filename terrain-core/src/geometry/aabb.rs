//! Axis-aligned bounding boxes in f64 world coordinates.

use glam::DVec3;

/// An axis-aligned box, `min <= max` component-wise (or [`Aabb::EMPTY`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// Smallest corner.
    pub min: DVec3,
    /// Largest corner.
    pub max: DVec3,
}

impl Aabb {
    /// The empty box: the identity of [`Aabb::union`] (min = +inf, max = -inf).
    pub const EMPTY: Aabb = Aabb { min: DVec3::INFINITY, max: DVec3::NEG_INFINITY };

    /// A box from two corners, in any order.
    pub fn new(a: DVec3, b: DVec3) -> Self {
        Self { min: a.min(b), max: a.max(b) }
    }

    /// The smallest box holding all `points` ([`Aabb::EMPTY`] for none).
    pub fn from_points(points: impl IntoIterator<Item = DVec3>) -> Self {
        points.into_iter().fold(Self::EMPTY, |b, p| b.union_point(p))
    }

    /// Whether the box holds no point.
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x || self.min.y > self.max.y || self.min.z > self.max.z
    }

    /// The smallest box holding both boxes.
    pub fn union(&self, other: &Aabb) -> Aabb {
        Aabb { min: self.min.min(other.min), max: self.max.max(other.max) }
    }

    /// The smallest box holding this box and `p`.
    pub fn union_point(&self, p: DVec3) -> Aabb {
        Aabb { min: self.min.min(p), max: self.max.max(p) }
    }

    /// Whether `p` is inside or on the boundary.
    pub fn contains(&self, p: DVec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }

    /// Whether `other` lies entirely inside this box.
    pub fn contains_aabb(&self, other: &Aabb) -> bool {
        other.min.cmpge(self.min).all() && other.max.cmple(self.max).all()
    }

    /// The point of the box closest to `p` (`p` itself when inside).
    pub fn closest_point(&self, p: DVec3) -> DVec3 {
        p.clamp(self.min, self.max)
    }

    /// Euclidean distance from `p` to the box (0 inside).
    pub fn distance(&self, p: DVec3) -> f64 {
        (self.closest_point(p) - p).length()
    }

    /// Centre.
    pub fn center(&self) -> DVec3 {
        (self.min + self.max) * 0.5
    }

    /// Half the size along each axis.
    pub fn half_extents(&self) -> DVec3 {
        (self.max - self.min) * 0.5
    }

    /// The eight corners; bit 0 of the index picks max x, bit 1 max y, bit 2 max z.
    pub fn corners(&self) -> [DVec3; 8] {
        std::array::from_fn(|k| {
            DVec3::new(
                if k & 1 == 0 { self.min.x } else { self.max.x },
                if k & 2 == 0 { self.min.y } else { self.max.y },
                if k & 4 == 0 { self.min.z } else { self.max.z },
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::dvec3;

    #[test]
    fn union_contains_distance_corners() {
        let a = Aabb::new(dvec3(1.0, 2.0, 3.0), dvec3(0.0, 0.0, 0.0));
        assert_eq!(a.min, DVec3::ZERO);
        assert_eq!(a.max, dvec3(1.0, 2.0, 3.0));
        let b = Aabb::new(dvec3(-1.0, 1.0, 1.0), dvec3(0.5, 5.0, 2.0));
        let u = a.union(&b);
        assert_eq!(u, Aabb::new(dvec3(-1.0, 0.0, 0.0), dvec3(1.0, 5.0, 3.0)));
        assert_eq!(Aabb::EMPTY.union(&a), a);
        assert!(Aabb::EMPTY.is_empty() && !a.is_empty());
        assert!(a.contains(dvec3(1.0, 2.0, 3.0)) && !a.contains(dvec3(1.0, 2.0, 3.1)));
        assert!(u.contains_aabb(&a) && !a.contains_aabb(&u));
        assert_eq!(a.distance(dvec3(0.5, 1.0, 1.0)), 0.0);
        assert!((a.distance(dvec3(4.0, 6.0, 3.0)) - 5.0).abs() < 1e-12);
        assert_eq!(a.closest_point(dvec3(-1.0, 1.0, 9.0)), dvec3(0.0, 1.0, 3.0));
        let c = a.corners();
        assert_eq!(c[0], a.min);
        assert_eq!(c[7], a.max);
        assert_eq!(c[5], dvec3(1.0, 0.0, 3.0));
        assert_eq!(Aabb::from_points(c), a);
        assert_eq!(a.center(), dvec3(0.5, 1.0, 1.5));
    }
}
