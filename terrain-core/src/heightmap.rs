//! The heightmap: a georeferenced grid of f32 heights with a void mask.
//!
//! Grid convention (an architecture invariant, see ARCHITECTURE.md): sample `(i, j)` is column
//! `i` (eastwards) and row `j` (northwards); row 0 is the *southern* edge. Readers flip north-up
//! files while reading, so that index -> world is a pure affine map with positive spacing:
//! `world = origin + (i * dx, j * dy)`. World frame: right-handed, x east, y north, z up, metres.

use glam::DVec2;

use crate::georef::Georef;

/// A bitset over the grid marking void (no-data) samples.
#[derive(Clone, PartialEq, Eq)]
pub struct VoidMask {
    width: usize,
    height: usize,
    bits: Vec<u64>,
    count: usize,
}

impl std::fmt::Debug for VoidMask {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VoidMask")
            .field("width", &self.width)
            .field("height", &self.height)
            .field("count", &self.count)
            .finish()
    }
}

impl VoidMask {
    /// A mask with no voids.
    pub fn new(width: usize, height: usize) -> Self {
        let n = width * height;
        Self { width, height, bits: vec![0; n.div_ceil(64)], count: 0 }
    }

    /// Whether sample `(i, j)` is void. Out-of-range samples are not void.
    #[inline]
    pub fn get(&self, i: usize, j: usize) -> bool {
        if i >= self.width || j >= self.height {
            return false;
        }
        let k = j * self.width + i;
        self.bits[k / 64] >> (k % 64) & 1 == 1
    }

    /// Marks or clears sample `(i, j)`.
    #[inline]
    pub fn set(&mut self, i: usize, j: usize, void: bool) {
        assert!(i < self.width && j < self.height, "void mask index out of range");
        let k = j * self.width + i;
        let (w, b) = (k / 64, 1u64 << (k % 64));
        let was = self.bits[w] & b != 0;
        if void && !was {
            self.bits[w] |= b;
            self.count += 1;
        } else if !void && was {
            self.bits[w] &= !b;
            self.count -= 1;
        }
    }

    /// Number of void samples.
    pub fn count(&self) -> usize {
        self.count
    }

    /// Whether any sample is void.
    pub fn any(&self) -> bool {
        self.count > 0
    }

    /// Whether any of the samples `i0..=i1` of row `j` is void (columns past the grid are
    /// not; an empty range or a row past the grid has none). Word by word, so a reader copying
    /// a window skips the rows without voids whole.
    pub fn any_in_row(&self, j: usize, i0: usize, i1: usize) -> bool {
        let i1 = i1.min(self.width.saturating_sub(1));
        if self.count == 0 || j >= self.height || i0 > i1 {
            return false;
        }
        let (a, b) = (j * self.width + i0, j * self.width + i1);
        let (wa, wb) = (a / 64, b / 64);
        let low = u64::MAX << (a % 64);
        let high = u64::MAX >> (63 - b % 64);
        if wa == wb {
            return self.bits[wa] & low & high != 0;
        }
        self.bits[wa] & low != 0
            || self.bits[wa + 1..wb].iter().any(|&w| w != 0)
            || self.bits[wb] & high != 0
    }

    /// Grid width in samples.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Grid height in samples.
    pub fn height(&self) -> usize {
        self.height
    }
}

/// A georeferenced grid of heights in metres.
///
/// Heights of void samples hold a *filled* value (see [`crate::dem::voids`]) so geometry is
/// always finite; the [`VoidMask`] says which samples were void in the source so analysis
/// and error measurement can exclude them.
#[derive(Clone)]
pub struct Heightmap {
    width: usize,
    height: usize,
    data: Vec<f32>,
    voids: VoidMask,
    georef: Georef,
    min: f32,
    max: f32,
}

impl std::fmt::Debug for Heightmap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Heightmap")
            .field("width", &self.width)
            .field("height", &self.height)
            .field("min", &self.min)
            .field("max", &self.max)
            .field("voids", &self.voids.count())
            .field("georef", &self.georef)
            .finish()
    }
}

/// Why a heightmap could not be built from its parts.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum HeightmapError {
    /// Width or height is zero.
    #[error("the grid is empty ({width} x {height} samples)")]
    Empty {
        /// Columns.
        width: usize,
        /// Rows.
        height: usize,
    },
    /// `data.len()` or the mask's size does not match `width * height`.
    #[error("{what} has {got} samples, expected {width} x {height}")]
    SizeMismatch {
        /// Which buffer is wrong.
        what: &'static str,
        /// Columns.
        width: usize,
        /// Rows.
        height: usize,
        /// What it had.
        got: usize,
    },
    /// A non-void sample is NaN or infinite.
    #[error("sample ({i}, {j}) is not finite and not marked void")]
    NonFinite {
        /// Column.
        i: usize,
        /// Row.
        j: usize,
    },
    /// Every sample is void: nothing to fill from.
    #[error("every sample is void")]
    AllVoid,
}

impl Heightmap {
    /// Builds a heightmap from row-major samples (row 0 = south) and a void mask.
    ///
    /// Void samples may hold anything (NaN included): callers fill them first with
    /// [`crate::dem::voids::fill_voids`] or use [`Heightmap::from_fn`] for grids without voids.
    /// Non-void samples must be finite.
    pub fn new(
        width: usize,
        height: usize,
        data: Vec<f32>,
        voids: VoidMask,
        georef: Georef,
    ) -> Result<Self, HeightmapError> {
        if width == 0 || height == 0 {
            return Err(HeightmapError::Empty { width, height });
        }
        if data.len() != width * height {
            return Err(HeightmapError::SizeMismatch {
                what: "data",
                width,
                height,
                got: data.len(),
            });
        }
        if voids.width != width || voids.height != height {
            return Err(HeightmapError::SizeMismatch {
                what: "void mask",
                width,
                height,
                got: voids.width * voids.height,
            });
        }
        if voids.count() == width * height {
            return Err(HeightmapError::AllVoid);
        }
        // Without voids (most grids, and every block of a bake) by lanes; the same values as
        // the sample-by-sample scan, which decides anywhere else.
        let lanes = if voids.any() { None } else { finite_range_by_lanes(&data) };
        let (min, max) = match lanes {
            Some(range) => range,
            None => finite_range(&data, width, &voids)?,
        };
        Ok(Self { width, height, data, voids, georef, min, max })
    }

    /// Builds a heightmap with no voids.
    pub fn from_fn(
        width: usize,
        height: usize,
        georef: Georef,
        mut f: impl FnMut(usize, usize) -> f32,
    ) -> Result<Self, HeightmapError> {
        let mut data = Vec::with_capacity(width * height);
        for j in 0..height {
            for i in 0..width {
                data.push(f(i, j));
            }
        }
        Self::new(width, height, data, VoidMask::new(width, height), georef)
    }

    /// Columns (west to east).
    #[inline]
    pub fn width(&self) -> usize {
        self.width
    }

    /// Rows (south to north).
    #[inline]
    pub fn height(&self) -> usize {
        self.height
    }

    /// Row-major samples, row 0 = south.
    #[inline]
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// The void mask (samples that were no-data in the source).
    #[inline]
    pub fn voids(&self) -> &VoidMask {
        &self.voids
    }

    /// Georeference and CRS.
    #[inline]
    pub fn georef(&self) -> &Georef {
        &self.georef
    }

    /// Smallest height over the non-void samples.
    #[inline]
    pub fn min(&self) -> f32 {
        self.min
    }

    /// Largest height over the non-void samples.
    #[inline]
    pub fn max(&self) -> f32 {
        self.max
    }

    /// Sample `(i, j)`; panics out of range (use [`Heightmap::get_clamped`] at borders).
    #[inline]
    pub fn get(&self, i: usize, j: usize) -> f32 {
        self.data[j * self.width + i]
    }

    /// Sample with indices clamped into the grid (edge extension).
    #[inline]
    pub fn get_clamped(&self, i: i64, j: i64) -> f32 {
        let i = i.clamp(0, self.width as i64 - 1) as usize;
        let j = j.clamp(0, self.height as i64 - 1) as usize;
        self.get(i, j)
    }

    /// Bilinear height at fractional grid coordinates `(u, v)` (in samples), clamped to the grid.
    pub fn sample_grid(&self, u: f64, v: f64) -> f32 {
        bilinear_clamped(self.width, self.height, u, v, |i, j| self.get(i, j))
    }

    /// Bilinear height at a world position (metres, world frame), clamped to the grid.
    pub fn sample_world(&self, p: DVec2) -> f32 {
        let g = self.georef.world_to_grid(p);
        self.sample_grid(g.x, g.y)
    }

    /// World position (metres, x east, y north) of sample `(i, j)`.
    #[inline]
    pub fn grid_to_world(&self, i: f64, j: f64) -> DVec2 {
        self.georef.grid_to_world(glam::dvec2(i, j))
    }

    /// Grid coordinates (fractional samples) of a world position.
    #[inline]
    pub fn world_to_grid(&self, p: DVec2) -> DVec2 {
        self.georef.world_to_grid(p)
    }

    /// World-space extent in metres: `(width - 1) * dx` by `(height - 1) * dy`.
    pub fn extent_m(&self) -> DVec2 {
        let s = self.georef.spacing_m;
        glam::dvec2((self.width - 1) as f64 * s.x, (self.height - 1) as f64 * s.y)
    }

    /// Replaces the georeference (used when the user supplies spacing for an image DEM).
    pub fn with_georef(mut self, georef: Georef) -> Self {
        self.georef = georef;
        self
    }

    /// Takes the parts apart: `(width, height, data, voids, georef)`.
    pub fn into_parts(self) -> (usize, usize, Vec<f32>, VoidMask, Georef) {
        (self.width, self.height, self.data, self.voids, self.georef)
    }
}

/// Bilinear height at fractional grid coordinates `(u, v)` of a `width x height` grid whose
/// samples `get(i, j)` gives, clamped to the grid: the one bilinear lookup of the engine
/// ([`Heightmap::sample_grid`], a store's resident levels), so every holder of the same samples
/// answers bit for bit the same.
pub fn bilinear_clamped(
    width: usize,
    height: usize,
    u: f64,
    v: f64,
    get: impl Fn(usize, usize) -> f32,
) -> f32 {
    let u = u.clamp(0.0, (width - 1) as f64);
    let v = v.clamp(0.0, (height - 1) as f64);
    let i0 = (u.floor() as usize).min(width.saturating_sub(2));
    let j0 = (v.floor() as usize).min(height.saturating_sub(2));
    let i1 = (i0 + 1).min(width - 1);
    let j1 = (j0 + 1).min(height - 1);
    let fu = (u - i0 as f64) as f32;
    let fv = (v - j0 as f64) as f32;
    // Each corner read once (a store's `get` looks its block up).
    let (z00, z10, z01, z11) = (get(i0, j0), get(i1, j0), get(i0, j1), get(i1, j1));
    let a = z00 + (z10 - z00) * fu;
    let b = z01 + (z11 - z01) * fu;
    a + (b - a) * fv
}

/// The smallest and largest non-void height of `data` (rows of `width`), sample by sample;
/// the first non-finite one (south row first, west first) is an error.
fn finite_range(
    data: &[f32],
    width: usize,
    voids: &VoidMask,
) -> Result<(f32, f32), HeightmapError> {
    let mut min = f32::INFINITY;
    let mut max = f32::NEG_INFINITY;
    // By rows, the void flags looked up only when there are voids (a block of the bake
    // is built as a heightmap: this loop ran a division per sample).
    let any_void = voids.any();
    for (j, row) in data.chunks_exact(width).enumerate() {
        for (i, &z) in row.iter().enumerate() {
            if any_void && voids.get(i, j) {
                continue;
            }
            if !z.is_finite() {
                return Err(HeightmapError::NonFinite { i, j });
            }
            min = min.min(z);
            max = max.max(z);
        }
    }
    Ok((min, max))
}

/// [`finite_range`] of a grid without voids by [`range_by_lanes`], or `None` where it might
/// differ: when some height is not finite (the error names the first, which the plain scan
/// finds) or at a zero extreme.
fn finite_range_by_lanes(data: &[f32]) -> Option<(f32, f32)> {
    range_by_lanes(data).and_then(|(min, max, finite)| finite.then_some((min, max)))
}

/// The smallest and largest non-NaN value of `data` (infinite ones included; `(inf, -inf)`
/// when there is none) and whether every value is finite, by eight interleaved running
/// minima and maxima (the comparisons do not wait on each other), or `None` when the minimum
/// or maximum is zero: -0 and +0 compare equal, so which one a scan left to right keeps
/// (`f32::min`, `f32::max`) depends on the order. Anywhere else the extremes of a set are the
/// same values whatever the order, so this is the plain scan's answer.
pub(crate) fn range_by_lanes(data: &[f32]) -> Option<(f32, f32, bool)> {
    let (min, max, finite) = extremes_by_lanes(data);
    (min != 0.0 && max != 0.0).then_some((min, max, finite))
}

/// [`range_by_lanes`] whatever the extremes: a zero extreme's sign is the one a lane kept
/// (for callers that ask its magnitude only).
pub(crate) fn extremes_by_lanes(data: &[f32]) -> (f32, f32, bool) {
    const L: usize = 8;
    let (mut lo, mut hi) = ([f32::INFINITY; L], [f32::NEG_INFINITY; L]);
    let mut finite = true;
    let mut chunks = data.chunks_exact(L);
    for ch in &mut chunks {
        for l in 0..L {
            let z = ch[l];
            finite &= z.is_finite();
            lo[l] = if z < lo[l] { z } else { lo[l] };
            hi[l] = if z > hi[l] { z } else { hi[l] };
        }
    }
    for &z in chunks.remainder() {
        finite &= z.is_finite();
        lo[0] = if z < lo[0] { z } else { lo[0] };
        hi[0] = if z > hi[0] { z } else { hi[0] };
    }
    let min = lo.iter().fold(f32::INFINITY, |m, &z| if z < m { z } else { m });
    let max = hi.iter().fold(f32::NEG_INFINITY, |m, &z| if z > m { z } else { m });
    (min, max, finite)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn any_in_row_is_the_sample_by_sample_answer() {
        // Masks of widths around the 64-bit words (rows starting mid-word), sparse and dense,
        // every range of every row, columns past the grid included.
        let mut next = crate::test_support::xorshift64_star(0x9E37_79B9_7F4A_7C15);
        let (mut ranges, mut voids_seen) = (0usize, 0usize);
        for (width, height, density) in
            [(5, 3, 3), (63, 4, 40), (64, 3, 90), (97, 5, 150), (130, 3, 400)]
        {
            let mut m = VoidMask::new(width, height);
            for j in 0..height {
                for i in 0..width {
                    if next() % 1000 < density {
                        m.set(i, j, true);
                    }
                }
            }
            for j in 0..height + 1 {
                for i0 in 0..width + 2 {
                    for i1 in i0.saturating_sub(1)..width + 3 {
                        let want = (i0..=i1).any(|i| m.get(i, j));
                        assert_eq!(
                            m.any_in_row(j, i0, i1),
                            want,
                            "{width} x {height}, row {j}, {i0}..={i1}"
                        );
                        ranges += 1;
                        voids_seen += usize::from(want);
                    }
                }
            }
        }
        assert!(
            ranges > 10_000 && voids_seen > ranges / 4,
            "{ranges} ranges, {voids_seen} with voids"
        );
        assert!(!VoidMask::new(70, 2).any_in_row(1, 0, 69));
    }

    #[test]
    fn the_range_by_lanes_is_the_plain_scan() {
        // Random finite heights of every length 0..40 (remainders of the lanes included) and
        // a few grids with ties, zeros of both signs, infinities and NaN: the lanes give the
        // plain scan's bits wherever they answer, and they answer for the ordinary grids.
        let mut next = crate::test_support::xorshift64_star(0x2545_F491_4F6C_DD1D);
        let mut answered = 0;
        for case in 0..400 {
            let n = case % 40;
            let data: Vec<f32> = (0..n)
                .map(|k| match (case / 40, next() % 16) {
                    (1, 0) => -0.0,
                    (1, 1) => 0.0,
                    (2, 0) if k > 3 => f32::NAN,
                    (3, 0) if k > 5 => f32::INFINITY,
                    (4, _) => (next() % 3) as f32 - 1.0,
                    _ => f32::from_bits(next() as u32 & 0xBF7F_FFFF) * 1e3,
                })
                .collect();
            let plain = finite_range(&data, n.max(1), &VoidMask::new(n.max(1), 1));
            match finite_range_by_lanes(&data) {
                Some((lo, hi)) => {
                    answered += 1;
                    let (plo, phi) = plain.expect("the lanes answer only for finite grids");
                    assert_eq!((lo.to_bits(), hi.to_bits()), (plo.to_bits(), phi.to_bits()));
                }
                None => {
                    let zero = plain.as_ref().is_ok_and(|&(lo, hi)| lo == 0.0 || hi == 0.0);
                    assert!(plain.is_err() || zero, "case {case}: the lanes gave up on {data:?}");
                }
            }
        }
        assert!(answered > 200, "{answered} grids answered by lanes");
        // The NaN-skipping range (the row reader's), on the same kinds of data.
        let mut with_nan = 0;
        for case in 0..400 {
            let data: Vec<f32> = (0..case % 40)
                .map(|_| match next() % 8 {
                    0 if case % 3 == 0 => f32::NAN,
                    1 if case % 5 == 0 => f32::NEG_INFINITY,
                    _ => f32::from_bits(next() as u32 & 0xBF7F_FFFF) * 1e3,
                })
                .collect();
            let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
            for &z in data.iter().filter(|z| !z.is_nan()) {
                lo = lo.min(z);
                hi = hi.max(z);
            }
            let finite = data.iter().all(|z| z.is_finite());
            with_nan += usize::from(data.iter().any(|z| z.is_nan()));
            let (l, h, f) = range_by_lanes(&data).expect("no zero extremes here");
            assert_eq!((l.to_bits(), h.to_bits(), f), (lo.to_bits(), hi.to_bits(), finite));
        }
        assert!(with_nan > 50, "{with_nan} rows with NaN");
        // Negative control: a non-finite height is found, and named, through `new`.
        let mut data = vec![1.0f32; 6 * 3];
        data[2 * 6 + 4] = f32::NAN;
        let e = Heightmap::new(6, 3, data, VoidMask::new(6, 3), Georef::local(1.0));
        assert!(matches!(e, Err(HeightmapError::NonFinite { i: 4, j: 2 })), "{e:?}");
    }
}
