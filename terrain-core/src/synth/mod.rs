//! Synthetic terrain: the embedded default terrain and the named hard cases.
//!
//! [`default_terrain`] is the engine's built-in terrain (no download): the seeded fractal of
//! [`fractal`] with [`FractalConfig::default`]. [`cases`] holds small analytic grids with exact
//! known properties for numerical-stability tests.

pub mod cases;
pub mod fractal;

pub use cases::HardCase;
pub use fractal::{FractalConfig, MAX_OCTAVES};

use crate::heightmap::Heightmap;

/// The embedded default terrain: [`FractalConfig::default`] (1025 x 1025 at 10 m, heights in
/// `[0, 1500]` m, seed 1) as a heightmap in a local metric frame.
pub fn default_terrain() -> Heightmap {
    FractalConfig::default()
        .to_heightmap()
        .expect("the default fractal config is valid and non-empty")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_terrain_is_the_default_fractal() {
        let hm = default_terrain();
        assert_eq!((hm.width(), hm.height()), (1025, 1025));
        assert_eq!(hm.georef().spacing_m, glam::dvec2(10.0, 10.0));
        assert!(!hm.voids().any());
        assert!(hm.min() >= 0.0 && hm.max() <= 1500.0);
        let c = FractalConfig::default();
        for (i, j) in [(0, 0), (1024, 1024), (700, 200)] {
            assert_eq!(hm.get(i, j).to_bits(), c.sample(i as u64, j as u64).to_bits());
        }
    }
}
