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
//! **Early exits.** The steps are halved recursively; a range whose samples' max height (from
//! [`HeightMip`]) is not above the sight line's lowest point over it cannot block and is
//! skipped whole, so a sight line high above the terrain costs a few lookups.

use glam::DVec3;

use super::mip::HeightMip;

/// Step ranges at most this long are walked sample by sample.
const LEAF_STEPS: i64 = 16;

/// Whether `target` is visible from `eye` (grid coordinates, z in metres) by Eq. 4 over the
/// 3D Bresenham section line; terrain must exceed the sight line by more than `eps` to block.
pub fn visible(mip: &HeightMip<'_>, eye: DVec3, target: DVec3, eps: f64) -> bool {
    let hm = mip.heightmap();
    let d = target - eye;
    let (major_x, len) = if d.x.abs() >= d.y.abs() { (true, d.x) } else { (false, d.y) };
    if len.abs() < 1e-12 {
        return true;
    }
    let (a, b) = if major_x { (eye.x, target.x) } else { (eye.y, target.y) };
    // Integer major coordinates strictly between the ends, in walking order.
    let dir: i64 = if b > a { 1 } else { -1 };
    let first = if dir > 0 { a.floor() as i64 + 1 } else { a.ceil() as i64 - 1 };
    let last = if dir > 0 { b.ceil() as i64 - 1 } else { b.floor() as i64 + 1 };
    if (last - first) * dir < 0 {
        return true;
    }
    let steps = (last - first) * dir + 1;
    let (w, h) = (hm.width() as i64, hm.height() as i64);
    let point = |k: i64| -> (i64, i64, f64) {
        let m = first + k * dir;
        let t = (m as f64 - a) / len;
        let p = eye + d * t;
        let (x, y) = if major_x { (m, p.y.round() as i64) } else { (p.x.round() as i64, m) };
        (x, y, p.z)
    };
    // Steps `k0..=k1`; the section line is monotone in x and y, so its samples lie in the
    // box of the two ends' samples, and the sight line's lowest point is at an end.
    let mut stack = vec![(0i64, steps - 1)];
    while let Some((k0, k1)) = stack.pop() {
        let (x0, y0, z0) = point(k0);
        let (x1, y1, z1) = point(k1);
        let (_, top) = mip.range(x0.min(x1), y0.min(y1), x0.max(x1), y0.max(y1));
        if f64::from(top) <= z0.min(z1) + eps {
            continue;
        }
        if k1 - k0 < LEAF_STEPS {
            for k in k0..=k1 {
                let (x, y, z) = point(k);
                if x < 0 || y < 0 || x >= w || y >= h {
                    continue;
                }
                // Eq. 4: f > 0, the section point lies above the sight line.
                if f64::from(hm.get(x as usize, y as usize)) > z + eps {
                    return false;
                }
            }
        } else {
            let mid = (k0 + k1) / 2;
            // The half nearer the test point last pushed, so first popped: hidden targets are
            // usually hidden by the terrain just in front of them.
            stack.push((k0, mid));
            stack.push((mid + 1, k1));
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::dvec3;
    use terrain_core::Heightmap;
    use terrain_core::georef::Georef;

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
