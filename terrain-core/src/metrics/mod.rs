//! Error metrics of the papers, as pure functions over a square [`Region`] of a [`Heightmap`].
//!
//! One concept per file:
//! - [`static_error`]: the out-of-core paper's (Qiu 2013, section 2.3) six-point static error
//!   `H` (Eq. 4-5) and the monotone `StaticE` (Eq. 3), bottom-up over a whole quadtree.
//! - [`dss`]: the DSS paper's (Zhang 2019, section 3.3.1) 32 object-space errors per block, its
//!   view-angle screen error (Eq. 3) and continuous tessellation factor `F_thr` (Eq. 4).
//! - [`geomorph`]: the geomorphing article's (Wagner 2003) max-error vertex per level of a
//!   geo-mipmapped patch.
//! - [`pvps`]: the PVPS paper's (Zhang 2021, section 2.3.4) roughness-weighted split ratio
//!   (Eq. 8-9) and the per-cell roughness it reads (Eq. 5).
//! - [`screen`]: screen-space projections (plain `lambda * delta / d`, DSS Eq. 1-3, out-of-core
//!   Eq. 6-7) and the node bounding box they measure distance to.
//!
//! # Frames
//! The papers use OpenGL's y-up frame; this crate uses x east, y north, **z up**. Every place a
//! paper says "Y" for height (or "the XOY plane" for the ground, as the DSS paper does with its
//! z-up normal) is converted in the comments where it is used. Error metrics work on grid indices
//! and heights only; screen metrics work on differences `eye - box`, so nothing depends on the
//! absolute projected origin (translation invariance is tested).
//!
//! # Degenerate cases (all handled, none panics, none returns NaN)
//! - **Zero-area node** (`cells == 0`, or the region lies outside the grid): [`Coverage::Empty`],
//!   error 0.
//! - **Void-only node** (every sample the metric would measure is void): [`Coverage::VoidOnly`],
//!   error 0. Errors are measured over non-void samples only; void samples keep their filled
//!   heights as *geometry* (corners, tessellated vertices), because that is what is rendered.
//! - **Camera inside the node's box** (`d -> 0`): screen errors return
//!   [`screen::MUST_SPLIT`] (`f64::INFINITY`) when the object-space error is positive, and 0 when
//!   it is 0 (an exact node gains nothing from splitting; avoids `0 * inf`).
//! - **Looking straight down**: the DSS paper's `sin(theta)` (and the out-of-core paper's
//!   `cos(theta)`, the same factor) is clamped to [`screen::MIN_VIEW_SIN`]; see there for why.
//! - **Angles at their limits**: the field of view is clamped into
//!   [`screen::MIN_FOV_Y`]`..=`[`screen::MAX_FOV_Y`]; the out-of-core paper's `beta` into
//!   `[0, pi/2]`; a zero view direction counts as horizontal.

use crate::heightmap::Heightmap;

pub mod dss;
pub mod geomorph;
pub mod pvps;
pub mod screen;
pub mod static_error;

/// A quadtree node as metrics see it: samples `x0..=x0 + cells` by `y0..=y0 + cells`
/// (column `i` east, row `j` north, row 0 south), clipped to the grid at the east and north
/// borders. The quadtree converts its node ids into this.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Region {
    /// First column (west edge), in samples.
    pub x0: usize,
    /// First row (south edge), in samples.
    pub y0: usize,
    /// Side length in cells (the node spans `cells + 1` samples per side before clipping).
    pub cells: usize,
}

/// A region after clipping to the grid: inclusive sample ranges `x0..=x1`, `y0..=y1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ClippedRegion {
    /// First column.
    pub x0: usize,
    /// First row.
    pub y0: usize,
    /// Last column (inclusive).
    pub x1: usize,
    /// Last row (inclusive).
    pub y1: usize,
}

impl ClippedRegion {
    /// Number of samples inside.
    pub fn sample_count(&self) -> usize {
        (self.x1 - self.x0 + 1) * (self.y1 - self.y0 + 1)
    }

    /// Whether sample `(i, j)` lies inside.
    pub fn contains(&self, i: usize, j: usize) -> bool {
        (self.x0..=self.x1).contains(&i) && (self.y0..=self.y1).contains(&j)
    }
}

impl Region {
    /// A region of `cells` cells with its south-west sample at `(x0, y0)`.
    pub const fn new(x0: usize, y0: usize, cells: usize) -> Self {
        Self { x0, y0, cells }
    }

    /// The whole grid as one square region (side: the larger of width and height, in cells).
    pub fn whole(hm: &Heightmap) -> Self {
        Self::new(0, 0, (hm.width() - 1).max(hm.height() - 1))
    }

    /// Clips to the grid; `None` for a zero-area region (`cells == 0`, or clipped away
    /// entirely, or clipped to a single row or column of samples).
    pub fn clip(&self, hm: &Heightmap) -> Option<ClippedRegion> {
        self.clip_to(hm.width(), hm.height())
    }

    /// [`Region::clip`] to a `width x height` grid whose samples are not at hand (read by
    /// bands of rows).
    pub fn clip_to(&self, width: usize, height: usize) -> Option<ClippedRegion> {
        if self.cells == 0 || self.x0 + 1 >= width || self.y0 + 1 >= height {
            return None;
        }
        Some(ClippedRegion {
            x0: self.x0,
            y0: self.y0,
            x1: (self.x0 + self.cells).min(width - 1),
            y1: (self.y0 + self.cells).min(height - 1),
        })
    }

    /// The four children (half the cells each), anticlockwise from the south-west as in the
    /// DSS paper's Figure 5: SW, SE, NE, NW. Odd `cells` round the children down.
    pub fn children(&self) -> [Region; 4] {
        let c = self.cells / 2;
        [
            Region::new(self.x0, self.y0, c),
            Region::new(self.x0 + c, self.y0, c),
            Region::new(self.x0 + c, self.y0 + c, c),
            Region::new(self.x0, self.y0 + c, c),
        ]
    }
}

/// What a metric could measure over a region. Errors are always finite and `>= 0`; this says
/// whether a zero means "exact" or "nothing to measure".
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Coverage {
    /// `samples` non-void samples were measured (the error is their max or mean).
    Measured {
        /// How many samples the metric compared (for `H`, points: the centre counts twice).
        samples: usize,
    },
    /// Every sample the metric would measure is void (or off the grid): the error is 0 by
    /// convention, not because the surface is exact.
    VoidOnly,
    /// The region has no area (`cells == 0`, or clipped away): the error is 0.
    Empty,
}

impl Coverage {
    /// `Measured` for `n > 0` samples, `VoidOnly` for none.
    pub(crate) fn from_count(n: usize) -> Self {
        if n == 0 { Coverage::VoidOnly } else { Coverage::Measured { samples: n } }
    }

    /// Whether some sample was measured.
    pub fn is_measured(&self) -> bool {
        matches!(self, Coverage::Measured { .. })
    }
}

/// Which diagonal splits a coarse quad into two triangles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Diagonal {
    /// From the south-west to the north-east corner.
    SwNe,
    /// From the south-east to the north-west corner.
    SeNw,
}

/// Height on a quad with corner heights `z00` (SW), `z10` (SE), `z01` (NW), `z11` (NE),
/// triangulated along `diag`, at local `(u, v)` in `[0, 1]^2` (u east, v north).
#[inline]
pub(crate) fn tri_interp(
    z00: f64,
    z10: f64,
    z01: f64,
    z11: f64,
    u: f64,
    v: f64,
    diag: Diagonal,
) -> f64 {
    match diag {
        Diagonal::SwNe => {
            if u >= v {
                // Triangle SW, SE, NE.
                z00 + u * (z10 - z00) + v * (z11 - z10)
            } else {
                // Triangle SW, NW, NE.
                z00 + v * (z01 - z00) + u * (z11 - z01)
            }
        }
        Diagonal::SeNw => {
            if u + v <= 1.0 {
                // Triangle SW, SE, NW.
                z00 + u * (z10 - z00) + v * (z01 - z00)
            } else {
                // Triangle NE, NW, SE.
                z11 + (1.0 - u) * (z01 - z11) + (1.0 - v) * (z10 - z11)
            }
        }
    }
}

/// Bilinear height in f64 on a quad with corners `z00` (SW), `z10` (SE), `z01` (NW), `z11` (NE).
#[inline]
pub(crate) fn bilerp(z00: f64, z10: f64, z01: f64, z11: f64, u: f64, v: f64) -> f64 {
    let a = z00 + (z10 - z00) * u;
    let b = z01 + (z11 - z01) * u;
    a + (b - a) * v
}

/// Bilinear DEM height at fractional grid coordinates, in f64 (clamped to the grid). [`Heightmap::sample_grid`] interpolates in f32; metrics compare errors down to
/// zero, so they interpolate in f64 to keep planes exact.
pub(crate) fn dem_bilinear(hm: &Heightmap, u: f64, v: f64) -> f64 {
    let (i0, i1, fu) = bilinear_axis(u, hm.width());
    let (j0, j1, fv) = bilinear_axis(v, hm.height());
    let z = |i: usize, j: usize| f64::from(hm.get(i, j));
    bilerp(z(i0, j0), z(i1, j0), z(i0, j1), z(i1, j1), fu, fv)
}

/// One axis of [`dem_bilinear`]: the two samples around coordinate `u` (clamped to a grid of
/// `n` samples) and the fraction between them. Callers that interpolate many points on shared
/// rows or columns compute it once per row or column and get the same bits.
#[inline]
pub(crate) fn bilinear_axis(u: f64, n: usize) -> (usize, usize, f64) {
    let u = u.clamp(0.0, (n - 1) as f64);
    let i0 = (u.floor() as usize).min(n.saturating_sub(2));
    (i0, (i0 + 1).min(n - 1), u - i0 as f64)
}
