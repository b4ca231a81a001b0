//! What a camera sees of a heightmap, computed on the CPU without drawing: the share of the
//! image the terrain covers (rays cast through a grid of pixels and marched over the bilinear
//! surface), the share of the terrain inside the view, the terrain's size on screen; and the
//! default framing built from them, which fills the image with terrain.
//!
//! Ray marching over a height field (Musgrave 1988, "Grid tracing"; the fixed-step form):
//! a ray hits the terrain at the first step whose height is at or below the surface's
//! bilinear height there. Steps are at most half a cell, so a ridge narrower than that can be
//! missed by a grazing ray: the shares are estimates at the resolution asked for, good to a
//! few per cent, which is what framing and the "sees no terrain" warning need.

use glam::{DVec2, DVec3, dvec2, dvec3};

use super::Camera;
use crate::Heightmap;

/// Most steps a ray takes through the terrain's box.
const MAX_STEPS: usize = 4096;

/// The terrain's world-frame box `(min, max)`: the grid's extent and its height range.
pub fn terrain_box(hm: &Heightmap) -> (DVec3, DVec3) {
    let lo = hm.grid_to_world(0.0, 0.0);
    let hi = hm.grid_to_world((hm.width() - 1) as f64, (hm.height() - 1) as f64);
    (dvec3(lo.x, lo.y, f64::from(hm.min())), dvec3(hi.x, hi.y, f64::from(hm.max())))
}

/// Where the ray from `origin` along unit `dir` first meets the terrain surface, as a distance
/// along the ray; `None` when it misses (leaves the terrain's box, or never enters it).
pub fn ray_hit(hm: &Heightmap, origin: DVec3, dir: DVec3) -> Option<f64> {
    let (lo, hi) = terrain_box(hm);
    // Slab test against the box (Kay & Kajiya 1986); a flat terrain's box has zero height, so
    // the top is raised by a millimetre to keep it a box.
    let hi = hi + DVec3::Z * 1e-3;
    let inv = dir.recip();
    let (a, b) = ((lo - origin) * inv, (hi - origin) * inv);
    let t0 = a.min(b).max_element().max(0.0);
    let t1 = a.max(b).min_element();
    if t0.is_nan() || t1.is_nan() || t0 > t1 {
        return None;
    }
    let cell = hm.georef().spacing_m.min_element();
    let steps = (((t1 - t0) / (0.5 * cell)).ceil() as usize).clamp(2, MAX_STEPS);
    let dt = (t1 - t0) / steps as f64;
    for k in 0..=steps {
        let t = t0 + dt * k as f64;
        let p = origin + dir * t;
        if p.z <= f64::from(hm.sample_world(dvec2(p.x, p.y))) {
            return Some(t);
        }
    }
    None
}

/// Share (0 to 1) of the image that shows terrain: rays through the centres of a `cols` x
/// `rows` grid of pixels, each marched over the terrain ([`ray_hit`]). Sky and anything beyond
/// the far plane count as not terrain.
pub fn terrain_coverage(hm: &Heightmap, camera: &Camera, cols: u32, rows: u32) -> f64 {
    let (cols, rows) = (cols.max(1), rows.max(1));
    let mut hits = 0u32;
    for r in 0..rows {
        for c in 0..cols {
            let px = dvec2(
                (f64::from(c) + 0.5) / f64::from(cols) * camera.viewport_px.x,
                (f64::from(r) + 0.5) / f64::from(rows) * camera.viewport_px.y,
            );
            let dir = camera.pixel_ray(px);
            if ray_hit(hm, camera.position, dir)
                .is_some_and(|t| t * dir.dot(camera.forward()) <= camera.far)
            {
                hits += 1;
            }
        }
    }
    f64::from(hits) / f64::from(cols * rows)
}

/// Share (0 to 1) of the terrain's area inside the view: of a 33 x 33 lattice of ground points
/// (the surface at those samples), those that project inside the viewport in front of the
/// camera. Occlusion is not counted.
pub fn footprint_share(hm: &Heightmap, camera: &Camera) -> f64 {
    const N: usize = 33;
    let (w, h) = ((hm.width() - 1) as f64, (hm.height() - 1) as f64);
    let mut inside = 0usize;
    for b in 0..N {
        for a in 0..N {
            let (u, v) = (w * a as f64 / (N - 1) as f64, h * b as f64 / (N - 1) as f64);
            let p = hm.grid_to_world(u, v).extend(f64::from(hm.sample_grid(u, v)));
            let seen = camera.project_world(p).is_some_and(|s| {
                (0.0..=camera.viewport_px.x).contains(&s.x)
                    && (0.0..=camera.viewport_px.y).contains(&s.y)
            });
            inside += usize::from(seen);
        }
    }
    inside as f64 / (N * N) as f64
}

/// The larger side, in pixels, of the screen rectangle around the terrain's box; `None` when
/// some corner of the box is at or behind the eye plane (the box is then not small on screen).
pub fn projected_size_px(hm: &Heightmap, camera: &Camera) -> Option<f64> {
    let (lo, hi) = terrain_box(hm);
    let (mut smin, mut smax) = (DVec2::INFINITY, DVec2::NEG_INFINITY);
    for k in 0..8 {
        let c = dvec3(
            if k & 1 == 0 { lo.x } else { hi.x },
            if k & 2 == 0 { lo.y } else { hi.y },
            if k & 4 == 0 { lo.z } else { hi.z },
        );
        let s = camera.project_world(c)?;
        smin = smin.min(s);
        smax = smax.max(s);
    }
    Some((smax - smin).max_element())
}

/// Share of the image the default framing aims to fill with terrain ([`fill_camera`]).
pub const FILL_TARGET: f64 = 0.9;

/// The default framing: a camera that fills the image with the terrain (at least
/// [`FILL_TARGET`] of it where the terrain's shape allows) while keeping as much of the
/// terrain in view as it can, with the horizon at the top edge or out of view.
///
/// It looks across the terrain's longer side (north when the grid is wider east-west than
/// north-south, east otherwise), at the centre of the grid at its mean height. For each pitch
/// of 30 to 90 degrees down it backs away as far as the image stays filled (bisection on the
/// distance, coverage by [`terrain_coverage`] on a grid of at most 129 x 129 samples), and
/// keeps the pitch that shows the largest share of the terrain ([`footprint_share`]), the
/// shallower on a tie. A terrain no pitch can fill (a long thin strip seen across a wide
/// image) gets the framing that came closest. The camera's near/far planes are left to the
/// caller (they depend on the data at full resolution).
pub fn fill_camera(hm: &Heightmap, viewport_px: DVec2, fov_y_deg: f64) -> Camera {
    let coarse = coarse_copy(hm, 129);
    let (lo, hi) = terrain_box(hm);
    let extent = hi - lo;
    let radius = (extent * 0.5).length().max(1.0);
    let mean = hm.data().iter().map(|&z| f64::from(z)).sum::<f64>() / hm.data().len() as f64;
    let centre = ((lo + hi) * 0.5).truncate().extend(mean);
    let yaw = if extent.x >= extent.y { 0.0 } else { 90.0 };
    let (cols, rows) = coverage_grid(viewport_px);
    let mut best: Option<(f64, f64, Camera)> = None; // (coverage met, footprint, camera)
    for pitch in [-30.0, -40.0, -50.0, -60.0, -70.0, -80.0, -90.0] {
        let base = Camera::from_yaw_pitch(centre, yaw, pitch)
            .with_fov_y_deg(fov_y_deg)
            .with_viewport(viewport_px.x.max(1.0), viewport_px.y.max(1.0))
            .with_clip(1e-3, 1e12);
        let at = |d: f64| Camera { position: centre - base.forward() * d, ..base };
        let cover = |d: f64| terrain_coverage(&coarse, &at(d), cols, rows);
        // Coverage falls as the camera backs away; bisect for the farthest distance that
        // still fills the image (or the closest sensible one when none does).
        let (mut near, mut far) = (radius * 1e-3, radius * 8.0);
        let filled_near = cover(near);
        let target = FILL_TARGET.min(filled_near);
        // 12 halvings of a ratio of 8000 in log space: the distance to 0.2 %.
        for _ in 0..12 {
            let mid = (near * far).sqrt();
            if cover(mid) >= target { near = mid } else { far = mid }
        }
        let camera = at(near);
        let key = (target, footprint_share(&coarse, &camera));
        // More of the image filled first, then more of the terrain in view (by at least
        // 2 % of it, so a near tie keeps the shallower, more three-dimensional view).
        let better = |(t, f, _): &(f64, f64, Camera)| {
            key.0 > t + 1e-9 || ((key.0 - t).abs() <= 1e-9 && key.1 > f + 0.02)
        };
        if best.as_ref().is_none_or(better) {
            best = Some((key.0, key.1, camera));
        }
    }
    best.expect("seven pitches tried").2
}

/// The grid of pixels [`fill_camera`] casts rays through: about 48 columns, rows by aspect.
fn coverage_grid(viewport_px: DVec2) -> (u32, u32) {
    let aspect = (viewport_px.x / viewport_px.y.max(1.0)).clamp(0.1, 10.0);
    let cols = 48u32;
    (cols, ((f64::from(cols) / aspect).round() as u32).clamp(4, 96))
}

/// Every `s`-th sample of `hm` with `s` chosen so neither side exceeds `max_side` samples, on
/// the same world frame (the extent rounded down to the stride). The heightmap itself when
/// it is small enough. What the estimates of this module run on when many cameras are checked.
pub fn coarse_copy(hm: &Heightmap, max_side: usize) -> std::borrow::Cow<'_, Heightmap> {
    let side = hm.width().max(hm.height());
    if side <= max_side {
        return std::borrow::Cow::Borrowed(hm);
    }
    let s = (side - 1).div_ceil(max_side - 1);
    let (w, h) = ((hm.width() - 1) / s + 1, (hm.height() - 1) / s + 1);
    let mut g = hm.georef().clone();
    g.spacing_m *= s as f64;
    g.native_spacing *= s as f64;
    let c = Heightmap::from_fn(w, h, g, |i, j| hm.get(i * s, j * s)).expect("finite heights");
    std::borrow::Cow::Owned(c)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Georef;

    /// A tilted plane z = 0.1 x over 101 x 51 samples at 10 m.
    fn plane() -> Heightmap {
        Heightmap::from_fn(101, 51, Georef::local(10.0), |i, _| i as f32).unwrap()
    }

    #[test]
    fn rays_hit_the_surface_where_it_is() {
        let hm = plane();
        // Straight down onto (500, 250): the surface is at z = 50.
        let t = ray_hit(&hm, dvec3(500.0, 250.0, 1000.0), -DVec3::Z).unwrap();
        assert!((t - 950.0).abs() < 5.0, "{t}");
        // Straight up, or beside the grid: no hit.
        assert!(ray_hit(&hm, dvec3(500.0, 250.0, 1000.0), DVec3::Z).is_none());
        assert!(ray_hit(&hm, dvec3(5000.0, 250.0, 10.0), -DVec3::Z).is_none());
    }

    #[test]
    fn coverage_counts_terrain_pixels() {
        let hm = plane();
        let down = Camera::from_yaw_pitch(dvec3(500.0, 250.0, 300.0), 0.0, -90.0)
            .with_viewport(160.0, 90.0)
            .with_fov_y_deg(60.0);
        // 300 m above a 1000 x 500 m plane, straight down: the view (about 700 x 390 m at the
        // surface) lies inside the grid.
        assert_eq!(terrain_coverage(&hm, &down, 32, 18), 1.0);
        let up = Camera::from_yaw_pitch(dvec3(500.0, 250.0, 300.0), 0.0, 80.0)
            .with_viewport(160.0, 90.0);
        assert_eq!(terrain_coverage(&hm, &up, 32, 18), 0.0);
        let far = Camera { position: dvec3(500.0, 250.0, 1e7), ..down };
        let share = terrain_coverage(&hm, &far, 32, 18);
        assert!(share < 0.05, "{share}");
        assert!(projected_size_px(&hm, &far).unwrap() < 1.0);
        assert!(projected_size_px(&hm, &up).is_none_or(|s| s > 1.0));
    }

    #[test]
    fn the_fill_framing_fills_the_image_and_keeps_terrain_in_view() {
        for (w, h) in [(257, 257), (401, 101), (101, 401)] {
            let hm = Heightmap::from_fn(w, h, Georef::local(30.0), |i, j| {
                (100.0 * ((i as f32) * 0.05).sin() * ((j as f32) * 0.07).cos()) + 500.0
            })
            .unwrap();
            let c = fill_camera(&hm, dvec2(1280.0, 720.0), 60.0);
            let cover = terrain_coverage(&hm, &c, 64, 36);
            assert!(cover >= 0.85, "{w} x {h}: coverage {cover}");
            let seen = footprint_share(&hm, &c);
            assert!(seen >= 0.25, "{w} x {h}: {seen} of the terrain in view");
        }
    }
}
