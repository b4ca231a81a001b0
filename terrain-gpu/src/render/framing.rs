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

/// Near and far clipping distances for a camera at `position`: far reaches the farthest
/// corner of the terrain's bounding box (with 5 % to spare); near is half the distance to the
/// box (half the height above the ground below when inside it), at least `far / 1e5` and
/// 0.05 m, so depth precision goes where the terrain is.
pub fn clip_range(hm: &Heightmap, position: DVec3) -> (f64, f64) {
    let (lo, hi) = bounds(hm);
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
    let to_box = (position.clamp(lo, hi) - position).length();
    let near = if to_box > 0.0 {
        0.5 * to_box
    } else {
        let ground = f64::from(hm.sample_world(position.truncate()));
        0.5 * (position.z - ground).max(0.0)
    };
    (near.max(far * 1e-5).max(0.05), far)
}

/// A camera that frames the whole terrain from the south-west, looking north-east and 35
/// degrees down at the centre of its bounding box, far enough that the box's bounding sphere
/// fits the narrower field of view. `fov_y_deg` is the vertical field of view.
pub fn default_camera(hm: &Heightmap, width: u32, height: u32, fov_y_deg: f64) -> Camera {
    let (lo, hi) = bounds(hm);
    let centre = (lo + hi) * 0.5;
    let radius = ((hi - lo) * 0.5).length().max(1.0);
    let camera = Camera::from_yaw_pitch(centre, 45.0, -35.0)
        .with_fov_y_deg(fov_y_deg)
        .with_viewport(f64::from(width.max(1)), f64::from(height.max(1)));
    let half_fov = (camera.fov_y * 0.5).min(camera.tan_half_fov_x().atan());
    let distance = radius / half_fov.sin();
    let mut camera = Camera { position: centre - camera.forward() * distance, ..camera };
    let (near, far) = clip_range(hm, camera.position);
    camera = camera.with_clip(near, far);
    camera
}
