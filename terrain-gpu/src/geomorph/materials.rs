//! Materials blended by alpha maps (Wagner 2003, "Materials" and "Optimizations"): a base
//! material drawn everywhere, then one alpha-blended pass per further material, each with an
//! alpha map over the whole terrain; a patch skips every pass whose alpha is zero over all of
//! its samples (precomputed once: the alpha maps do not change at run time).
//!
//! The materials and their alphas are the tessellation renderer's colour ramp
//! (`render/terrain.wgsl`, `ramp`) taken apart: meadow as the base, then forest, rock and snow
//! by height and rock by slope, each mixed over the previous ones, exactly the ramp's sequence
//! of `mix` calls. Alpha blending `src * alpha + dst * (1 - alpha)` is that `mix`, and the
//! lightmap multiplies every pass alike, so the passes add up to `light * ramp`: the image
//! looks like the other renderer's (the ramp is evaluated per sample and filtered here, per
//! fragment there).

use terrain_core::Heightmap;
use terrain_core::lightmap::sample_normal;

/// Number of materials (the base and four blended ones).
pub const MATERIALS: usize = 5;

/// Material names, in pass order.
pub const MATERIAL_NAMES: [&str; MATERIALS] = ["meadow", "forest", "rock", "snow", "steep rock"];

/// The snow material's pass.
pub const SNOW: usize = 3;

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// The alpha maps (RGBA8: materials 1-4 in r, g, b, a; row-major, south row first) and, per
/// patch, which passes it draws.
#[derive(Debug, Clone, PartialEq)]
pub struct MaterialMaps {
    /// Per sample, the alphas of materials 1..=4 (0-255).
    pub alpha: Vec<[u8; 4]>,
    /// Patches along x and y.
    pub patches: (u32, u32),
    /// Per patch (row-major): bit `k` set when material `k` has a non-zero alpha somewhere over
    /// the patch (bit 0, the base, always).
    pub masks: Vec<u8>,
}

impl MaterialMaps {
    /// Alpha maps of `hm` and pass masks of its patches of `patch_cells` cells.
    pub fn new(hm: &Heightmap, patch_cells: u32) -> Self {
        let (w, h) = (hm.width(), hm.height());
        let (lo, range) = (f64::from(hm.min()), f64::from(hm.max() - hm.min()).max(1e-6));
        let q = |a: f64| (a * 255.0).round().clamp(0.0, 255.0) as u8;
        let mut alpha = Vec::with_capacity(w * h);
        for j in 0..h {
            for i in 0..w {
                let t = ((f64::from(hm.get(i, j)) - lo) / range).clamp(0.0, 1.0);
                let n = sample_normal(hm, i, j);
                alpha.push([
                    q(smoothstep(0.0, 0.35, t)),
                    q(smoothstep(0.45, 0.75, t)),
                    q(smoothstep(0.8, 0.95, t)),
                    q(smoothstep(0.55, 0.8, 1.0 - n.z)),
                ]);
            }
        }
        let p = patch_cells.max(1) as usize;
        let nx = (w.saturating_sub(1)).div_ceil(p).max(1);
        let ny = (h.saturating_sub(1)).div_ceil(p).max(1);
        let mut masks = vec![1u8; nx * ny];
        for pj in 0..ny {
            for pi in 0..nx {
                let mask = &mut masks[pj * nx + pi];
                for j in pj * p..=((pj + 1) * p).min(h - 1) {
                    for i in pi * p..=((pi + 1) * p).min(w - 1) {
                        for (k, &a) in alpha[j * w + i].iter().enumerate() {
                            if a > 0 {
                                *mask |= 1 << (k + 1);
                            }
                        }
                    }
                }
            }
        }
        Self { alpha, patches: (nx as u32, ny as u32), masks }
    }

    /// Whether patch `(i, j)` draws material `k`.
    pub fn draws(&self, i: u32, j: u32, k: usize) -> bool {
        self.masks[(j * self.patches.0 + i) as usize] & (1 << k) != 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use terrain_core::Georef;

    #[test]
    fn a_patch_below_the_snow_line_skips_snow() {
        // Low plain in the west, a high plateau in the east: snow only over the plateau.
        let hm =
            Heightmap::from_fn(
                65,
                33,
                Georef::local(10.0),
                |i, _| if i >= 40 { 1000.0 } else { 0.0 },
            )
            .unwrap();
        let m = MaterialMaps::new(&hm, 16);
        assert_eq!(m.patches, (4, 2));
        assert!(!m.draws(0, 0, SNOW), "the plain is below the snow line");
        assert!(m.draws(3, 0, SNOW), "the plateau is snow");
        assert!(m.draws(0, 0, 0) && m.draws(3, 1, 0), "the base always");
        // Steep rock only where the cliff is (column 39-40, patch 2).
        assert!(m.draws(2, 0, 4) && !m.draws(0, 0, 4));
    }
}
