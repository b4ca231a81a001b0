//! Named hard cases for numerical-stability tests, each with exact known properties.
//!
//! Analytic cases use heights that are exact in f32 (small integers), so tests can compare
//! with `==`: a plane has zero approximation error; dropping the spike's sample costs exactly
//! [`HardCase::SPIKE_HEIGHT`]; and so on. Fractal cases are exactly
//! [`FractalConfig::sample`] of their config ([`HardCase::fractal_config`]).
//!
//! Unless stated otherwise a case uses [`Georef::local`] at [`HardCase::SPACING_M`] and has no
//! voids.

use glam::dvec2;

use super::fractal::FractalConfig;
use crate::georef::{Crs, Georef};
use crate::heightmap::{Heightmap, VoidMask};

/// A named hard case. [`HardCase::build`] makes its heightmap; the associated constants give
/// its exact properties.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum HardCase {
    /// 65 x 65, every sample [`HardCase::FLAT_HEIGHT`]. Any triangulation is exact.
    Flat,
    /// 65 x 65 plain at 0 m with one sample at [`HardCase::SPIKE_POS`] of
    /// [`HardCase::SPIKE_HEIGHT`]: leaving that vertex out costs exactly the spike height.
    Spike,
    /// 65 x 65 vertical step: columns `i < CLIFF_COLUMN` at [`HardCase::CLIFF_LOW`], columns
    /// `i >= CLIFF_COLUMN` at [`HardCase::CLIFF_HIGH`] (the step lies between two columns).
    Cliff,
    /// 65 x 65 sawtooth along x: `h = SAWTOOTH_STEP * (i % SAWTOOTH_PERIOD)`, i.e. ramps of
    /// 0, 10, ..., 70 m then a 70 m drop, constant along y.
    Sawtooth,
    /// 65 x 65 plain at 0 m with a square plateau at [`HardCase::PLATEAU_HEIGHT`] on
    /// `PLATEAU_MIN..=PLATEAU_MAX` in both axes, holed by the void rectangles
    /// [`HardCase::PLATEAU_VOIDS`] (all inside the plateau; void samples hold the plateau
    /// height, so geometry is a plain plateau).
    PlateauWithVoids,
    /// The fractal ([`HardCase::fractal_config`]: 513 x 513 at 10 m) placed in UTM zone 11N
    /// (EPSG:32611) with sample (0, 0) at easting [`HardCase::HUGE_ORIGIN_EASTING`], northing
    /// [`HardCase::HUGE_ORIGIN_NORTHING`]: f32 world positions would lose metres here.
    HugeOrigin,
    /// 2 x 2, the smallest grid with a cell: [`HardCase::TINY2_DATA`].
    Tiny2,
    /// 3 x 3, a centre peak: [`HardCase::TINY3_DATA`].
    Tiny3,
    /// The fractal at 1000 x 777 (neither a power of two nor one plus one, and not square).
    OddSize,
    /// 65 x 65 at [`HardCase::HUGE_RANGE_SPACING_M`]: a plain at 0 m with one spike of
    /// [`HardCase::HUGE_RANGE_MAX`] at [`HardCase::HUGE_RANGE_PEAK_POS`] and one pit of
    /// [`HardCase::HUGE_RANGE_MIN`] at [`HardCase::HUGE_RANGE_PIT_POS`] (Everest to the
    /// Challenger Deep; integers, exact in f32).
    HugeRange,
}

impl HardCase {
    /// Grid spacing of every case except [`HardCase::HugeRange`], metres.
    pub const SPACING_M: f64 = 10.0;
    /// Width and height of the 65 x 65 analytic cases.
    pub const SMALL_SIZE: usize = 65;

    /// Height of [`HardCase::Flat`], metres.
    pub const FLAT_HEIGHT: f32 = 100.0;

    /// Sample `(i, j)` of the spike in [`HardCase::Spike`] (the centre).
    pub const SPIKE_POS: (usize, usize) = (32, 32);
    /// Height of the spike above the 0 m plain in [`HardCase::Spike`], metres.
    pub const SPIKE_HEIGHT: f32 = 1000.0;

    /// First column of the high side of [`HardCase::Cliff`].
    pub const CLIFF_COLUMN: usize = 32;
    /// Height west of the cliff, metres.
    pub const CLIFF_LOW: f32 = 0.0;
    /// Height east of the cliff, metres.
    pub const CLIFF_HIGH: f32 = 500.0;

    /// Period of [`HardCase::Sawtooth`] in samples.
    pub const SAWTOOTH_PERIOD: usize = 8;
    /// Rise per sample of [`HardCase::Sawtooth`], metres (the drop is `7 *` this).
    pub const SAWTOOTH_STEP: f32 = 10.0;

    /// Height of the plateau of [`HardCase::PlateauWithVoids`], metres (the plain is 0 m).
    pub const PLATEAU_HEIGHT: f32 = 300.0;
    /// First plateau sample index (both axes).
    pub const PLATEAU_MIN: usize = 16;
    /// Last plateau sample index (both axes, inclusive).
    pub const PLATEAU_MAX: usize = 48;
    /// Void rectangles `(i0, j0, w, h)` of [`HardCase::PlateauWithVoids`]: a 1-sample hole,
    /// a 4 x 3 hole and a 5 x 5 hole touching the plateau's north-east corner.
    pub const PLATEAU_VOIDS: [(usize, usize, usize, usize); 3] =
        [(24, 24, 1, 1), (30, 20, 4, 3), (44, 44, 5, 5)];
    /// Number of void samples in [`HardCase::PlateauWithVoids`].
    pub const PLATEAU_VOID_COUNT: usize = 1 + 12 + 25;

    /// Easting of sample (0, 0) of [`HardCase::HugeOrigin`], metres.
    pub const HUGE_ORIGIN_EASTING: f64 = 500_000.0;
    /// Northing of sample (0, 0) of [`HardCase::HugeOrigin`], metres.
    pub const HUGE_ORIGIN_NORTHING: f64 = 4_000_000.0;
    /// EPSG code of [`HardCase::HugeOrigin`] (WGS 84 / UTM zone 11N).
    pub const HUGE_ORIGIN_EPSG: u32 = 32611;

    /// Row-major (south row first) samples of [`HardCase::Tiny2`].
    pub const TINY2_DATA: [f32; 4] = [0.0, 10.0, 20.0, 40.0];
    /// Row-major (south row first) samples of [`HardCase::Tiny3`]: a 100 m centre peak on a
    /// tilted rim.
    pub const TINY3_DATA: [f32; 9] = [0.0, 5.0, 10.0, 5.0, 100.0, 15.0, 10.0, 15.0, 20.0];

    /// Grid spacing of [`HardCase::HugeRange`], metres.
    pub const HUGE_RANGE_SPACING_M: f64 = 100.0;
    /// Lowest height of [`HardCase::HugeRange`], metres (a single-sample pit).
    pub const HUGE_RANGE_MIN: f32 = -11_000.0;
    /// Highest height of [`HardCase::HugeRange`], metres (a single-sample spike).
    pub const HUGE_RANGE_MAX: f32 = 8_850.0;
    /// Sample of the spike of [`HardCase::HugeRange`].
    pub const HUGE_RANGE_PEAK_POS: (usize, usize) = (20, 40);
    /// Sample of the pit of [`HardCase::HugeRange`].
    pub const HUGE_RANGE_PIT_POS: (usize, usize) = (44, 24);

    /// Every case, in declaration order.
    pub fn all() -> &'static [HardCase] {
        use HardCase::*;
        &[
            Flat,
            Spike,
            Cliff,
            Sawtooth,
            PlateauWithVoids,
            HugeOrigin,
            Tiny2,
            Tiny3,
            OddSize,
            HugeRange,
        ]
    }

    /// A stable snake_case name (for test output and file names).
    pub fn name(&self) -> &'static str {
        match self {
            HardCase::Flat => "flat",
            HardCase::Spike => "spike",
            HardCase::Cliff => "cliff",
            HardCase::Sawtooth => "sawtooth",
            HardCase::PlateauWithVoids => "plateau_with_voids",
            HardCase::HugeOrigin => "huge_origin",
            HardCase::Tiny2 => "tiny2",
            HardCase::Tiny3 => "tiny3",
            HardCase::OddSize => "odd_size",
            HardCase::HugeRange => "huge_range",
        }
    }

    /// `(width, height)` in samples.
    pub fn size(&self) -> (usize, usize) {
        match self {
            HardCase::Tiny2 => (2, 2),
            HardCase::Tiny3 => (3, 3),
            HardCase::HugeOrigin | HardCase::OddSize => {
                let c = self.fractal_config().expect("fractal case");
                (c.width as usize, c.height as usize)
            }
            _ => (Self::SMALL_SIZE, Self::SMALL_SIZE),
        }
    }

    /// The fractal config of [`HardCase::HugeOrigin`] and [`HardCase::OddSize`] (their heights
    /// are exactly its [`FractalConfig::sample`]); `None` for the analytic cases.
    pub fn fractal_config(&self) -> Option<FractalConfig> {
        match self {
            HardCase::HugeOrigin => Some(FractalConfig::with_size(513, 513, Self::SPACING_M)),
            HardCase::OddSize => Some(FractalConfig::with_size(1000, 777, Self::SPACING_M)),
            _ => None,
        }
    }

    /// Exact `(min, max)` of the non-void heights for the analytic cases; `None` for the
    /// fractal cases (bounded by `[0, relief_m]` only).
    pub fn known_range(&self) -> Option<(f32, f32)> {
        match self {
            HardCase::Flat => Some((Self::FLAT_HEIGHT, Self::FLAT_HEIGHT)),
            HardCase::Spike => Some((0.0, Self::SPIKE_HEIGHT)),
            HardCase::Cliff => Some((Self::CLIFF_LOW, Self::CLIFF_HIGH)),
            HardCase::Sawtooth => {
                Some((0.0, Self::SAWTOOTH_STEP * (Self::SAWTOOTH_PERIOD - 1) as f32))
            }
            HardCase::PlateauWithVoids => Some((0.0, Self::PLATEAU_HEIGHT)),
            HardCase::Tiny2 => Some((0.0, 40.0)),
            HardCase::Tiny3 => Some((0.0, 100.0)),
            HardCase::HugeRange => Some((Self::HUGE_RANGE_MIN, Self::HUGE_RANGE_MAX)),
            HardCase::HugeOrigin | HardCase::OddSize => None,
        }
    }

    /// Whether sample `(i, j)` is void (only [`HardCase::PlateauWithVoids`] has voids).
    pub fn is_void(&self, i: usize, j: usize) -> bool {
        *self == HardCase::PlateauWithVoids
            && Self::PLATEAU_VOIDS
                .iter()
                .any(|&(i0, j0, w, h)| (i0..i0 + w).contains(&i) && (j0..j0 + h).contains(&j))
    }

    /// The exact height of sample `(i, j)` (void samples: their filled value). For the fractal
    /// cases this computes [`FractalConfig::sample`] (slow per call; use the built grid).
    pub fn height_at(&self, i: usize, j: usize) -> f32 {
        let (w, h) = self.size();
        assert!(i < w && j < h, "sample ({i}, {j}) outside the {w} x {h} case {}", self.name());
        match self {
            HardCase::Flat => Self::FLAT_HEIGHT,
            HardCase::Spike => {
                if (i, j) == Self::SPIKE_POS {
                    Self::SPIKE_HEIGHT
                } else {
                    0.0
                }
            }
            HardCase::Cliff => {
                if i < Self::CLIFF_COLUMN {
                    Self::CLIFF_LOW
                } else {
                    Self::CLIFF_HIGH
                }
            }
            HardCase::Sawtooth => Self::SAWTOOTH_STEP * (i % Self::SAWTOOTH_PERIOD) as f32,
            HardCase::PlateauWithVoids => {
                let on = |k: usize| (Self::PLATEAU_MIN..=Self::PLATEAU_MAX).contains(&k);
                if on(i) && on(j) { Self::PLATEAU_HEIGHT } else { 0.0 }
            }
            HardCase::Tiny2 => Self::TINY2_DATA[j * 2 + i],
            HardCase::Tiny3 => Self::TINY3_DATA[j * 3 + i],
            HardCase::HugeRange => {
                if (i, j) == Self::HUGE_RANGE_PEAK_POS {
                    Self::HUGE_RANGE_MAX
                } else if (i, j) == Self::HUGE_RANGE_PIT_POS {
                    Self::HUGE_RANGE_MIN
                } else {
                    0.0
                }
            }
            HardCase::HugeOrigin | HardCase::OddSize => {
                self.fractal_config().expect("fractal case").sample(i as u64, j as u64)
            }
        }
    }

    /// The case's georeference.
    pub fn georef(&self) -> Georef {
        match self {
            HardCase::HugeOrigin => Georef::projected(
                Crs::Epsg(Self::HUGE_ORIGIN_EPSG),
                dvec2(Self::HUGE_ORIGIN_EASTING, Self::HUGE_ORIGIN_NORTHING),
                dvec2(Self::SPACING_M, Self::SPACING_M),
            ),
            HardCase::HugeRange => Georef::local(Self::HUGE_RANGE_SPACING_M),
            _ => Georef::local(Self::SPACING_M),
        }
    }

    /// Builds the case's heightmap.
    pub fn build(&self) -> Heightmap {
        if let Some(c) = self.fractal_config() {
            return c
                .to_heightmap()
                .expect("fractal case configs are valid and non-empty")
                .with_georef(self.georef());
        }
        let (w, h) = self.size();
        let mut data = Vec::with_capacity(w * h);
        let mut voids = VoidMask::new(w, h);
        for j in 0..h {
            for i in 0..w {
                data.push(self.height_at(i, j));
                if self.is_void(i, j) {
                    voids.set(i, j, true);
                }
            }
        }
        Heightmap::new(w, h, data, voids, self.georef())
            .expect("analytic cases are finite and non-empty")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_case_builds_with_its_size_and_exact_values() {
        assert_eq!(HardCase::all().len(), 10);
        let mut names: Vec<_> = HardCase::all().iter().map(|c| c.name()).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), 10, "names are unique");
        for case in HardCase::all() {
            let hm = case.build();
            assert_eq!((hm.width(), hm.height()), case.size(), "{}", case.name());
            assert!(hm.data().iter().all(|z| z.is_finite()), "{}", case.name());
            if let Some((lo, hi)) = case.known_range() {
                assert_eq!((hm.min(), hm.max()), (lo, hi), "{}", case.name());
                for j in 0..hm.height() {
                    for i in 0..hm.width() {
                        assert_eq!(
                            hm.get(i, j),
                            case.height_at(i, j),
                            "{} ({i}, {j})",
                            case.name()
                        );
                    }
                }
            }
            let voids =
                if *case == HardCase::PlateauWithVoids { HardCase::PLATEAU_VOID_COUNT } else { 0 };
            assert_eq!(hm.voids().count(), voids, "{}", case.name());
        }
    }

    #[test]
    fn sizes_are_as_documented() {
        assert_eq!(HardCase::Tiny2.build().data(), &HardCase::TINY2_DATA);
        assert_eq!(HardCase::Tiny3.build().data(), &HardCase::TINY3_DATA);
        assert_eq!(HardCase::OddSize.size(), (1000, 777));
        assert_eq!(HardCase::HugeOrigin.size(), (513, 513));
        assert_eq!(HardCase::Flat.size(), (65, 65));
    }

    #[test]
    fn spike_cliff_sawtooth_exact_values() {
        let s = HardCase::Spike.build();
        let (si, sj) = HardCase::SPIKE_POS;
        assert_eq!(s.get(si, sj), HardCase::SPIKE_HEIGHT);
        assert_eq!(s.data().iter().filter(|&&z| z != 0.0).count(), 1);

        let c = HardCase::Cliff.build();
        let k = HardCase::CLIFF_COLUMN;
        assert_eq!(c.get(k - 1, 10), HardCase::CLIFF_LOW);
        assert_eq!(c.get(k, 10), HardCase::CLIFF_HIGH);

        let t = HardCase::Sawtooth.build();
        assert_eq!(t.get(7, 3), 70.0);
        assert_eq!(t.get(8, 3), 0.0);
        assert_eq!(t.get(63, 60), 70.0);
        assert_eq!(t.get(64, 0), 0.0);

        let f = HardCase::Flat.build();
        assert!(f.data().iter().all(|&z| z == HardCase::FLAT_HEIGHT));
    }

    #[test]
    fn plateau_voids_are_inside_the_plateau_and_hold_its_height() {
        let p = HardCase::PlateauWithVoids.build();
        let mut n = 0;
        for j in 0..p.height() {
            for i in 0..p.width() {
                if p.voids().get(i, j) {
                    n += 1;
                    assert!((HardCase::PLATEAU_MIN..=HardCase::PLATEAU_MAX).contains(&i));
                    assert!((HardCase::PLATEAU_MIN..=HardCase::PLATEAU_MAX).contains(&j));
                    assert_eq!(p.get(i, j), HardCase::PLATEAU_HEIGHT);
                }
            }
        }
        assert_eq!(n, HardCase::PLATEAU_VOID_COUNT);
        assert!(p.voids().get(48, 48) && p.voids().get(24, 24) && !p.voids().get(49, 49));
        assert_eq!(p.get(15, 30), 0.0);
        assert_eq!(p.get(16, 30), HardCase::PLATEAU_HEIGHT);
    }

    #[test]
    fn huge_origin_is_the_fractal_at_a_projected_origin() {
        let case = HardCase::HugeOrigin;
        let hm = case.build();
        let g = hm.georef();
        assert_eq!(g.crs, Crs::Epsg(32611));
        assert_eq!(hm.grid_to_world(0.0, 0.0), dvec2(500_000.0, 4_000_000.0));
        assert_eq!(hm.grid_to_world(512.0, 512.0), dvec2(505_120.0, 4_005_120.0));
        let c = case.fractal_config().unwrap();
        for (i, j) in [(0, 0), (512, 512), (100, 400), (511, 3)] {
            assert_eq!(hm.get(i, j), c.sample(i as u64, j as u64));
        }
        // Same heights as the local-frame fractal: only the placement differs.
        assert_eq!(hm.data(), c.to_heightmap().unwrap().data());
        assert!(hm.min() >= 0.0 && hm.max() <= c.relief_m as f32);
        assert!(hm.max() - hm.min() > 100.0);
    }

    #[test]
    fn odd_size_is_the_fractal() {
        let hm = HardCase::OddSize.build();
        let c = HardCase::OddSize.fractal_config().unwrap();
        assert_eq!((hm.width(), hm.height()), (1000, 777));
        assert_eq!(hm.get(999, 776), c.sample(999, 776));
        assert_eq!(hm.get(0, 776), HardCase::OddSize.height_at(0, 776));
    }

    #[test]
    fn huge_range_extremes() {
        let hm = HardCase::HugeRange.build();
        let (pi, pj) = HardCase::HUGE_RANGE_PEAK_POS;
        let (ti, tj) = HardCase::HUGE_RANGE_PIT_POS;
        assert_eq!(hm.get(pi, pj), 8850.0);
        assert_eq!(hm.get(ti, tj), -11000.0);
        assert_eq!(hm.max() - hm.min(), 19_850.0);
        assert_eq!(hm.georef().spacing_m, dvec2(100.0, 100.0));
        assert_eq!(hm.data().iter().filter(|&&z| z == 0.0).count(), 65 * 65 - 2);
    }
}
