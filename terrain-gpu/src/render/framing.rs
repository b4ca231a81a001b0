//! Cameras for a heightmap: a default view that frames the whole terrain, and near/far
//! distances that fit the terrain's bounding box as seen from a position.

use glam::{DVec3, dvec3};
use terrain_core::Heightmap;
use terrain_core::geometry::Camera;

/// The terrain's bounding box in the world frame: `(min, max)` corners.
fn bounds(hm: &Heightmap) -> (DVec3, DVec3) {
    let lo = hm.grid_to_world(0.0, 0.0);
    let hi = hm.grid_to_world((hm.width() - 1) as f64, (hm.height() - 1) as f64);
    (dvec3(lo.x, lo.y, f64::from(hm.min())), dvec3(hi.x, hi.y, f64::from(hm.max())))
}

/// Samples per side of the blocks whose boxes bound the distance to the terrain.
const BLOCK: usize = 16;

/// Near and far clipping distances for a camera at `position`: far reaches the farthest
/// corner of the terrain's bounding box (with 5 % to spare); near is half the distance to the
/// nearest box around a block of 16 x 16 samples (so no terrain is nearer than near and none
/// is clipped by it), at least `far / 1e6` and 0.05 m. Scans the whole heightmap; a caller
/// asking every frame (`terrain view`) keeps a [`ClipBoxes`] instead.
pub fn clip_range(hm: &Heightmap, position: DVec3) -> (f64, f64) {
    ClipBoxes::new(hm).range(position)
}

/// The block boxes [`clip_range`] measures distances to, computed once per heightmap: the
/// same near and far for any position without scanning the heights again.
#[derive(Debug, Clone)]
pub struct ClipBoxes {
    /// The terrain's bounding box.
    lo: DVec3,
    hi: DVec3,
    /// Per block of 16 x 16 samples: its box's corners.
    boxes: Vec<(DVec3, DVec3)>,
}

impl ClipBoxes {
    /// The boxes of `hm`'s blocks (one pass over its heights).
    pub fn new(hm: &Heightmap) -> Self {
        let (lo, hi) = bounds(hm);
        let (w, h) = (hm.width(), hm.height());
        let mut boxes = Vec::with_capacity(w.div_ceil(BLOCK) * h.div_ceil(BLOCK));
        for j0 in (0..h).step_by(BLOCK) {
            let j1 = (j0 + BLOCK).min(h - 1);
            for i0 in (0..w).step_by(BLOCK) {
                let i1 = (i0 + BLOCK).min(w - 1);
                let (mut zlo, mut zhi) = (f32::INFINITY, f32::NEG_INFINITY);
                for j in j0..=j1 {
                    for &z in &hm.data()[j * w + i0..=j * w + i1] {
                        zlo = zlo.min(z);
                        zhi = zhi.max(z);
                    }
                }
                let a = hm.grid_to_world(i0 as f64, j0 as f64).extend(f64::from(zlo));
                let b = hm.grid_to_world(i1 as f64, j1 as f64).extend(f64::from(zhi));
                boxes.push((a, b));
            }
        }
        Self { lo, hi, boxes }
    }

    /// Near and far for a camera at `position` (see [`clip_range`]).
    pub fn range(&self, position: DVec3) -> (f64, f64) {
        let nearest = self
            .boxes
            .iter()
            .map(|&(a, b)| (position.clamp(a, b) - position).length())
            .fold(f64::INFINITY, f64::min);
        near_far(self.lo, self.hi, nearest, position)
    }
}

/// Near and far planes for a camera at `position` over terrain inside the box `lo..hi`,
/// `nearest` metres from the nearest part of it: far reaches the box's farthest corner (plus
/// 5 % and 1 m), near is half the nearest distance, at least `far / 1e6` and 0.05 m. The one
/// rule of every renderer's clip range (whole DEMs here, stores in the app's `ooc`).
pub fn near_far(lo: DVec3, hi: DVec3, nearest: f64, position: DVec3) -> (f64, f64) {
    let mut far: f64 = 0.0;
    for k in 0..8 {
        let c = dvec3(
            if k & 1 == 0 { lo.x } else { hi.x },
            if k & 2 == 0 { lo.y } else { hi.y },
            if k & 4 == 0 { lo.z } else { hi.z },
        );
        far = far.max((c - position).length());
    }
    far = far * 1.05 + 1.0;
    ((0.5 * nearest).max(far * 1e-6).max(0.05), far)
}

/// A camera that frames the whole terrain from the south-west, looking north-east and 35
/// degrees down at the centre of its bounding box, as close as it can be while every corner
/// of the box stays inside the viewport with a 4 % margin. `fov_y_deg` is the vertical field
/// of view.
pub fn default_camera(hm: &Heightmap, width: u32, height: u32, fov_y_deg: f64) -> Camera {
    let (lo, hi) = bounds(hm);
    let centre = (lo + hi) * 0.5;
    let radius = ((hi - lo) * 0.5).length().max(1.0);
    let camera = Camera::from_yaw_pitch(centre, 45.0, -35.0)
        .with_fov_y_deg(fov_y_deg)
        .with_viewport(f64::from(width.max(1)), f64::from(height.max(1)));
    let at = |distance: f64| Camera { position: centre - camera.forward() * distance, ..camera };
    let fits = |c: &Camera| {
        let (w, h) = (c.viewport_px.x, c.viewport_px.y);
        (0..8).all(|k| {
            let p = dvec3(
                if k & 1 == 0 { lo.x } else { hi.x },
                if k & 2 == 0 { lo.y } else { hi.y },
                if k & 4 == 0 { lo.z } else { hi.z },
            );
            c.project_world(p).is_some_and(|s| {
                s.x >= 0.04 * w && s.x <= 0.96 * w && s.y >= 0.04 * h && s.y <= 0.96 * h
            })
        })
    };
    // The bounding sphere fits at `far`; bisect down to the closest distance that fits.
    let half_fov = (camera.fov_y * 0.5).min(camera.tan_half_fov_x().atan());
    let (mut near, mut far) = (0.0, radius / (0.96 * half_fov).sin());
    for _ in 0..50 {
        let mid = 0.5 * (near + far);
        if fits(&at(mid)) { far = mid } else { near = mid }
    }
    let camera = at(far);
    let (near, far) = clip_range(hm, camera.position);
    camera.with_clip(near, far)
}

#[cfg(test)]
mod tests {
    use super::*;
    use terrain_core::synth::FractalConfig;

    /// Kept boxes give a near plane that clips no sample, and close to it: within half a
    /// block's diagonal of half the distance to the nearest sample; far reaches every sample.
    #[test]
    fn kept_boxes_bound_the_distance_to_every_sample() {
        let hm = FractalConfig::with_size(97, 70, 10.0).to_heightmap().unwrap();
        let boxes = ClipBoxes::new(&hm);
        let (lo, hi) = bounds(&hm);
        let diag = (hm.grid_to_world(BLOCK as f64, BLOCK as f64) - hm.grid_to_world(0.0, 0.0))
            .length()
            .hypot(f64::from(hm.max() - hm.min()));
        for (k, p) in [
            dvec3(lo.x - 50.0, lo.y - 80.0, hi.z + 200.0),
            dvec3(0.5 * (lo.x + hi.x), 0.5 * (lo.y + hi.y), hi.z + 5.0),
            dvec3(hi.x + 900.0, lo.y + 10.0, lo.z + 1.0),
        ]
        .into_iter()
        .enumerate()
        {
            let (near, far) = boxes.range(p);
            let (mut nearest, mut farthest) = (f64::INFINITY, 0.0f64);
            for j in 0..hm.height() {
                for i in 0..hm.width() {
                    let s = hm.grid_to_world(i as f64, j as f64).extend(f64::from(hm.get(i, j)));
                    nearest = nearest.min((s - p).length());
                    farthest = farthest.max((s - p).length());
                }
            }
            assert!(near <= 0.5 * nearest + 1e-9, "{k}: near {near}, nearest sample {nearest}");
            assert!(near >= 0.5 * (nearest - diag) - 1e-9, "{k}: near {near} of {nearest}");
            assert!(far >= farthest, "{k}: far {far}, farthest sample {farthest}");
            assert_eq!((near, far), clip_range(&hm, p), "{k}: the one-shot function agrees");
        }
    }
}
