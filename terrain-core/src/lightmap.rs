//! The geomorphing article's (Wagner 2003, "Materials") precomputed lightmap: one diffuse
//! light value per DEM sample from the normals, with optional static horizon shadows, so that
//! changing the tessellation (and morphing vertices) never changes the lighting.
//!
//! Normals are the article's "two 3d-vectors, each pointing from the current height value to the
//! neighboring height positions", crossed; we take the central differences (one-sided at the
//! border), the same normals the tessellation renderer shades with
//! (`terrain_gpu::surface::normal_at` at a sample). The article leaves shadows to external
//! tools ("Wilbur or Corel Bryce"); ours are the standard horizon test: a sample is in shadow
//! when the terrain rises above the straight ray towards the sun, marched over the bilinear
//! surface in steps of half a cell.

use glam::{DVec2, DVec3};

use crate::heightmap::Heightmap;

/// How the lightmap is computed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LightmapConfig {
    /// Direction towards the sun (x east, y north, z up); normalised here. Default from the
    /// north-west, 45 degrees up (the renderer's default sun).
    pub sun_direction: [f64; 3],
    /// Light where the sun does not reach. Default 0.3 (the renderer's ambient).
    pub ambient: f64,
    /// Weight of the diffuse term. Default 0.7 (the renderer's).
    pub diffuse: f64,
    /// Cast horizon shadows. Default true.
    pub shadows: bool,
}

impl Default for LightmapConfig {
    fn default() -> Self {
        Self { sun_direction: [-1.0, 1.0, 2f64.sqrt()], ambient: 0.3, diffuse: 0.7, shadows: true }
    }
}

/// Unit normal at sample `(i, j)` from central differences (one-sided at the border).
pub fn sample_normal(hm: &Heightmap, i: usize, j: usize) -> DVec3 {
    let (w, h) = (hm.width() - 1, hm.height() - 1);
    let s = hm.georef().spacing_m;
    let (il, ir) = (i.saturating_sub(1), (i + 1).min(w));
    let (jd, ju) = (j.saturating_sub(1), (j + 1).min(h));
    let z = |a: usize, b: usize| f64::from(hm.get(a, b));
    let dx = (z(ir, j) - z(il, j)) / ((ir - il).max(1) as f64 * s.x);
    let dy = (z(i, ju) - z(i, jd)) / ((ju - jd).max(1) as f64 * s.y);
    DVec3::new(-dx, -dy, 1.0).normalize()
}

/// Whether the terrain hides the sun (direction `sun`, unit, z > 0) from sample `(i, j)`.
pub fn in_shadow(hm: &Heightmap, i: usize, j: usize, sun: DVec3) -> bool {
    let flat = DVec2::new(sun.x, sun.y);
    let horizontal = flat.length();
    if sun.z <= 0.0 {
        return true;
    }
    if horizontal < 1e-12 {
        return false;
    }
    let s = hm.georef().spacing_m;
    // Half a cell per step, in grid units along the sun's plan direction.
    let dir_m = flat / horizontal;
    let step_grid = DVec2::new(dir_m.x / s.x, dir_m.y / s.y);
    let step = 0.5 / step_grid.abs().max_element();
    let rise_per_m = sun.z / horizontal;
    let z0 = f64::from(hm.get(i, j));
    let top = f64::from(hm.max());
    let (wmax, hmax) = ((hm.width() - 1) as f64, (hm.height() - 1) as f64);
    let mut k = 1.0;
    loop {
        let g = DVec2::new(i as f64, j as f64) + step_grid * (step * k);
        if g.x < 0.0 || g.y < 0.0 || g.x > wmax || g.y > hmax {
            return false;
        }
        let ray = z0 + rise_per_m * step * k;
        if ray > top {
            return false;
        }
        if f64::from(hm.sample_grid(g.x, g.y)) > ray + 1e-6 {
            return true;
        }
        k += 1.0;
    }
}

/// The light of every sample, row-major, south row first: `ambient + diffuse * max(n . sun, 0)`,
/// the diffuse term dropped in shadow.
pub fn lightmap(hm: &Heightmap, cfg: &LightmapConfig) -> Vec<f32> {
    let sun = DVec3::from(cfg.sun_direction).normalize_or(DVec3::Z);
    let mut out = Vec::with_capacity(hm.width() * hm.height());
    for j in 0..hm.height() {
        for i in 0..hm.width() {
            let lambert = sample_normal(hm, i, j).dot(sun).max(0.0);
            let lit = !(cfg.shadows && lambert > 0.0 && in_shadow(hm, i, j, sun));
            let d = if lit { cfg.diffuse * lambert } else { 0.0 };
            out.push((cfg.ambient + d) as f32);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::georef::Georef;
    use crate::synth::HardCase;

    #[test]
    fn flat_is_uniform() {
        let hm = HardCase::Flat.build();
        let l = lightmap(&hm, &LightmapConfig::default());
        let want = (0.3 + 0.7 * 0.5f64.sqrt()) as f32;
        assert!(l.iter().all(|&x| (x - want).abs() < 1e-6), "{:?}", &l[..4]);
    }

    #[test]
    fn a_wall_casts_a_shadow_of_its_height_over_tan_elevation() {
        // Flat ground at 0, a 10 m wall along column 20, 1 m spacing; sun in the west at
        // elevation e: the shadow covers the samples east of the wall closer than 10 / tan(e).
        let hm =
            Heightmap::from_fn(64, 8, Georef::local(1.0), |i, _| if i == 20 { 10.0 } else { 0.0 })
                .unwrap();
        for (elev_deg, length) in [(45.0f64, 10usize), (63.434_948_822_922, 5)] {
            let e = elev_deg.to_radians();
            let sun = DVec3::new(-e.cos(), 0.0, e.sin());
            let shadowed: Vec<usize> = (0..64).filter(|&i| in_shadow(&hm, i, 4, sun)).collect();
            let want: Vec<usize> = (21..20 + length).collect();
            assert_eq!(shadowed, want, "elevation {elev_deg}");
            let cfg = LightmapConfig { sun_direction: sun.to_array(), ..Default::default() };
            let l = lightmap(&hm, &cfg);
            assert_eq!(l[4 * 64 + 23], 0.3);
            assert!(l[4 * 64 + 10] > 0.75);
        }
    }
}
