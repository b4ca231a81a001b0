//! A seeded, deterministic fractal terrain with sharp ridges and deep, carved valleys.
//!
//! # Technique
//!
//! Every height is a pure function of `(config, i, j)`; nothing is stored between samples, so
//! any row, block or single sample of an arbitrarily large grid (32769² and beyond) can be
//! produced in bounded memory, in any order, with bit-identical results.
//!
//! 1. **Lattice noise.** Perlin gradient noise (K. Perlin, "Improving Noise", SIGGRAPH 2002):
//!    quintic fade `6t⁵ - 15t⁴ + 10t³`, one of 16 unit gradients per lattice point chosen by an
//!    integer hash of `(seed, layer, octave, lattice x, lattice y)` (the SplitMix64 / MurmurHash3
//!    `fmix64` finaliser). Its range is `±√2/2`, scaled to `[-1, 1]`.
//! 2. **Domain warping** (Perlin & Hoffert, "Hypertexture", SIGGRAPH 1989; I. Quilez, "Domain
//!    warping", 2002): the sample position is displaced by two low-frequency fBm fields, which
//!    bends ridges and valleys away from the lattice axes.
//! 3. **Ridged multifractal** (F. K. Musgrave, in Ebert et al., *Texturing & Modeling: A
//!    Procedural Approach*, 3rd ed., 2003, ch. 16): `signal = (offset - |noise|)²`, each octave
//!    weighted by the previous octave's signal, giving sharp ridge crests and rough peaks with
//!    smoother valley floors. It is mixed with plain fBm (same book, ch. 14) for rolling relief.
//! 4. **Contrast** by the smooth rational sigmoid `x / √(1 + x²)`, which spreads the mixed
//!    signal over `(0, 1)` without clipping (IEEE `sqrt` is correctly rounded, hence portable).
//! 5. **Valley carving**, an erosion-like river network: the zero set of a warped, low-frequency
//!    noise field forms meandering curves ("ridged" rivers, as in Musgrave's river networks and
//!    Ebert et al. ch. 16); near it the height is multiplied down towards
//!    `1 - valley_depth`, with a smoothstep profile. These valleys cut through ridges, so a
//!    viewer at a valley floor sees little: occlusion culling matters.
//!
//! **Range by construction.** Each stage maps into `[0, 1]` by its analytic bound (noise,
//! weighted sums divided by their amplitude sum, sigmoid, carving factor in `[1 - depth, 1]`),
//! so the height is `relief_m * t` with `t ∈ [0, 1]`; a final clamp only absorbs rounding.
//!
//! **Determinism.** Only integer hashing and IEEE-754 `+ - * /`, `floor`, `abs` and `sqrt` in
//! f64 (all exactly specified; Rust never fuses them into FMAs implicitly): no `rand`, no hash
//! maps, no `sin`/`cos`/`exp`/`pow`. Heights depend on grid indices, not world coordinates, so
//! the same terrain can be placed at any origin (see `HardCase::HugeOrigin`).

use crate::georef::Georef;
use crate::hash::mix64;
use crate::heightmap::{Heightmap, HeightmapError};

/// The most octaves a [`FractalConfig`] may ask for.
pub const MAX_OCTAVES: u32 = 24;

/// Octaves of the domain-warp fBm fields.
const WARP_OCTAVES: usize = 3;
/// Octaves of the valley-network field.
const VALLEY_OCTAVES: usize = 2;
/// Musgrave's ridged-multifractal `offset` and `gain`.
const RIDGE_OFFSET: f64 = 1.0;
const RIDGE_GAIN: f64 = 2.0;
/// Centre and steepness of the contrast sigmoid (measured on the mixed signal so that the
/// bulk of the distribution spreads over most of `[0, 1]`).
const CONTRAST_CENTRE: f64 = 0.55;
const CONTRAST_GAIN: f64 = 7.0;

/// Parameters of the fractal terrain. Every sample is a pure function of these and `(i, j)`.
///
/// `Default` is the engine's embedded terrain: 1025 x 1025 samples at 10 m (a 10.24 km
/// square), 1500 m of relief, seed 1.
#[derive(Debug, Clone, PartialEq)]
pub struct FractalConfig {
    /// Seed of every noise layer. Default 1.
    pub seed: u64,
    /// Columns (west to east). Default 1025.
    pub width: u64,
    /// Rows (south to north). Default 1025.
    pub height: u64,
    /// Grid spacing in metres (both axes). Default 10.
    pub spacing_m: f64,
    /// Heights lie in `[0, relief_m]`. Default 1500.
    pub relief_m: f64,
    /// Octaves of the ridged multifractal and the fBm, `1..=MAX_OCTAVES`. Default 8
    /// (4000 m down to ~31 m, three samples at 10 m).
    pub octaves: u32,
    /// Wavelength of the first (coarsest) octave in metres. Default 4000.
    pub base_wavelength_m: f64,
    /// Frequency ratio between octaves. Default 2.
    pub lacunarity: f64,
    /// Amplitude ratio between fBm octaves (the ridged octaves use `1 / lacunarity`). Default 0.5.
    pub persistence: f64,
    /// Share of the ridged multifractal in the mix, the rest is fBm, `0..=1`. Default 0.7.
    pub ridge_mix: f64,
    /// Domain-warp displacement in units of the base wavelength. Default 0.35.
    pub warp: f64,
    /// Wavelength of the valley network in metres. Default 6000.
    pub valley_wavelength_m: f64,
    /// Half-width of the carved valleys as a fraction of the valley field's range (`0..1`;
    /// about `valley_width * valley_wavelength_m / 2` metres). Default 0.12.
    pub valley_width: f64,
    /// How much a valley floor is lowered, `0..=1`: heights are multiplied by
    /// `1 - valley_depth` at the valley axis. Default 0.85.
    pub valley_depth: f64,
}

impl Default for FractalConfig {
    fn default() -> Self {
        Self {
            seed: 1,
            width: 1025,
            height: 1025,
            spacing_m: 10.0,
            relief_m: 1500.0,
            octaves: 8,
            base_wavelength_m: 4000.0,
            lacunarity: 2.0,
            persistence: 0.5,
            ridge_mix: 0.7,
            warp: 0.35,
            valley_wavelength_m: 6000.0,
            valley_width: 0.12,
            valley_depth: 0.85,
        }
    }
}

impl FractalConfig {
    /// The default terrain at another size and spacing.
    pub fn with_size(width: u64, height: u64, spacing_m: f64) -> Self {
        Self { width, height, spacing_m, ..Self::default() }
    }

    /// The default terrain with another seed.
    pub fn with_seed(seed: u64) -> Self {
        Self { seed, ..Self::default() }
    }

    /// Height in metres of sample `(i, j)` (column east, row north; row 0 = south).
    ///
    /// Defined for every `(i, j)`, inside the grid or not (the terrain is unbounded; `width`
    /// and `height` only bound [`FractalConfig::to_heightmap`] and the generators). Always
    /// finite and within `[0, relief_m]`. Prepares the per-octave tables on each call: prefer
    /// [`FractalConfig::generate_rows`] or [`FractalConfig::generate_block`] for many samples.
    ///
    /// # Panics
    /// If the configuration is invalid (see [`FractalConfig::validate`]).
    pub fn sample(&self, i: u64, j: u64) -> f32 {
        Generator::new(self).sample(i, j)
    }

    /// Writes rows `j0 .. j0 + rows` (all `width` columns, row-major, south row first) into
    /// `out`, which must hold exactly `width * rows` samples. Memory use is `out` only.
    ///
    /// # Panics
    /// If `out` has the wrong length, the rows leave the grid, or the config is invalid.
    pub fn generate_rows(&self, j0: u64, rows: usize, out: &mut [f32]) {
        let w = usize::try_from(self.width).expect("grid width does not fit in memory");
        self.generate_block(0, j0, w, rows, out);
    }

    /// Writes the `w x h` block whose south-west sample is `(x0, y0)` into `out` (row-major,
    /// south row first), which must hold exactly `w * h` samples. Memory use is `out` only.
    ///
    /// # Panics
    /// If `out` has the wrong length, the block leaves the grid, or the config is invalid.
    pub fn generate_block(&self, x0: u64, y0: u64, w: usize, h: usize, out: &mut [f32]) {
        assert_eq!(out.len(), w * h, "output buffer must hold w * h samples");
        assert!(
            x0.checked_add(w as u64).is_some_and(|e| e <= self.width)
                && y0.checked_add(h as u64).is_some_and(|e| e <= self.height),
            "block ({x0}, {y0}) + {w} x {h} leaves the {} x {} grid",
            self.width,
            self.height
        );
        if w == 0 {
            return;
        }
        let g = Generator::new(self);
        // Along a row neighbouring samples share lattice cells: one cache per noise field.
        let mut caches = Caches::new();
        for (r, row) in out.chunks_exact_mut(w).enumerate() {
            g.row(x0, y0 + r as u64, row, &mut caches);
        }
    }

    /// The whole grid as a heightmap with [`Georef::local`] at `spacing_m`.
    ///
    /// Allocates `width * height` samples: for large grids stream with
    /// [`FractalConfig::generate_rows`] instead. Errors if the grid is empty.
    ///
    /// # Panics
    /// If the config is invalid or `width * height` does not fit in `usize`.
    pub fn to_heightmap(&self) -> Result<Heightmap, HeightmapError> {
        let w = usize::try_from(self.width).expect("grid width does not fit in memory");
        let h = usize::try_from(self.height).expect("grid height does not fit in memory");
        let n = w.checked_mul(h).expect("grid does not fit in memory");
        if n == 0 {
            return Err(HeightmapError::Empty { width: w, height: h });
        }
        let mut data = vec![0.0f32; n];
        self.generate_rows(0, h, &mut data);
        Heightmap::new(
            w,
            h,
            data,
            crate::heightmap::VoidMask::new(w, h),
            Georef::local(self.spacing_m),
        )
    }

    /// Checks the parameters; every generator calls this and panics with its message.
    pub fn validate(&self) -> Result<(), String> {
        let pos = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!("{name} must be finite and > 0, got {v}"))
            }
        };
        let unit = |name: &str, v: f64| {
            if (0.0..=1.0).contains(&v) {
                Ok(())
            } else {
                Err(format!("{name} must be in [0, 1], got {v}"))
            }
        };
        pos("spacing_m", self.spacing_m)?;
        pos("base_wavelength_m", self.base_wavelength_m)?;
        pos("valley_wavelength_m", self.valley_wavelength_m)?;
        pos("lacunarity", self.lacunarity)?;
        if !(self.relief_m.is_finite() && self.relief_m >= 0.0) {
            return Err(format!("relief_m must be finite and >= 0, got {}", self.relief_m));
        }
        if !(1..=MAX_OCTAVES).contains(&self.octaves) {
            return Err(format!("octaves must be in 1..={MAX_OCTAVES}, got {}", self.octaves));
        }
        unit("persistence", self.persistence)?;
        unit("ridge_mix", self.ridge_mix)?;
        unit("valley_depth", self.valley_depth)?;
        if !(self.valley_width.is_finite() && self.valley_width > 0.0 && self.valley_width <= 1.0) {
            return Err(format!("valley_width must be in (0, 1], got {}", self.valley_width));
        }
        if !(self.warp.is_finite() && self.warp >= 0.0) {
            return Err(format!("warp must be finite and >= 0, got {}", self.warp));
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------------
// Hashing and noise.

/// Salt of one noise layer/octave: a pure function of the seed.
fn salt(seed: u64, layer: u64, octave: u64) -> u64 {
    mix64(
        seed.wrapping_add(0x9E37_79B9_7F4A_7C15).wrapping_mul(0x2545_F491_4F6C_DD1D)
            ^ mix64((layer << 32) | octave),
    )
}

/// `cos 45° = sin 45°`.
const S: f64 = std::f64::consts::FRAC_1_SQRT_2;

/// 16 unit gradients, at multiples of 22.5 degrees (literals, so no platform trigonometry).
const GRADIENTS: [(f64, f64); 16] = [
    (1.0, 0.0),
    (0.923_879_532_511_286_7, 0.382_683_432_365_089_8),
    (S, S),
    (0.382_683_432_365_089_8, 0.923_879_532_511_286_7),
    (0.0, 1.0),
    (-0.382_683_432_365_089_8, 0.923_879_532_511_286_7),
    (-S, S),
    (-0.923_879_532_511_286_7, 0.382_683_432_365_089_8),
    (-1.0, 0.0),
    (-0.923_879_532_511_286_7, -0.382_683_432_365_089_8),
    (-S, -S),
    (-0.382_683_432_365_089_8, -0.923_879_532_511_286_7),
    (0.0, -1.0),
    (0.382_683_432_365_089_8, -0.923_879_532_511_286_7),
    (S, -S),
    (0.923_879_532_511_286_7, -0.382_683_432_365_089_8),
];

/// Hash of lattice point `(ix, iy)` under `salt`.
#[inline(always)]
fn lattice_hash(salt: u64, ix: i64, iy: i64) -> u64 {
    mix64(
        salt.wrapping_add((ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15))
            .wrapping_add((iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)),
    )
}

/// Two gradient dot products at one lattice point for offset `(dx, dy)`: the gradients are
/// picked by independent bit fields of one hash (bits 60..64 and 56..60), so one hash feeds
/// two independent noise fields.
#[cfg(test)]
#[inline(always)]
fn grad2(h: u64, dx: f64, dy: f64) -> (f64, f64) {
    let (ax, ay) = GRADIENTS[(h >> 60) as usize];
    let (bx, by) = GRADIENTS[((h >> 56) & 15) as usize];
    (ax * dx + ay * dy, bx * dx + by * dy)
}

/// Perlin's quintic fade.
#[inline(always)]
fn fade(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// `floor` by truncation (exact; avoids a libm call on targets without SSE4.1).
#[inline(always)]
fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x { t - 1 } else { t }
}

/// Two independent 2-D gradient noise fields at `(x, y)`, each in `[-1, 1]` (the reference
/// of [`noise2_lanes`], which the generator uses).
#[cfg(test)]
fn noise2(salt: u64, x: f64, y: f64) -> (f64, f64) {
    let (ix, iy) = (floor_i64(x), floor_i64(y));
    let (fx, fy) = (x - ix as f64, y - iy as f64);
    let a00 = grad2(lattice_hash(salt, ix, iy), fx, fy);
    let a10 = grad2(lattice_hash(salt, ix + 1, iy), fx - 1.0, fy);
    let a01 = grad2(lattice_hash(salt, ix, iy + 1), fx, fy - 1.0);
    let a11 = grad2(lattice_hash(salt, ix + 1, iy + 1), fx - 1.0, fy - 1.0);
    blend([a00, a10, a01, a11], fx, fy)
}

/// Both fields' corner values `00, 10, 01, 11` interpolated at `(fx, fy)` in the cell (the
/// one interpolation of [`noise2`] and [`noise2_lanes`]).
#[inline(always)]
fn blend(c: [(f64, f64); 4], fx: f64, fy: f64) -> (f64, f64) {
    let (u, v) = (fade(fx), fade(fy));
    let interp = |n00: f64, n10: f64, n01: f64, n11: f64| {
        let a = n00 + (n10 - n00) * u;
        let b = n01 + (n11 - n01) * u;
        // Perlin noise with unit gradients lies in [-sqrt(2)/2, sqrt(2)/2].
        ((a + (b - a) * v) * std::f64::consts::SQRT_2).clamp(-1.0, 1.0)
    };
    (interp(c[0].0, c[1].0, c[2].0, c[3].0), interp(c[0].1, c[1].1, c[2].1, c[3].1))
}

/// The gradients of the last lattice cell one noise field was evaluated in: neighbouring
/// samples mostly fall in the same cell (hundreds of samples a cell at the coarse octaves),
/// so [`noise2_lanes`] hashes a cell once per run of samples instead of once per sample. The
/// hashes are pure functions of the cell, so the result is bit-identical to [`noise2`].
#[derive(Clone, Copy)]
struct CellCache {
    cell: (i64, i64),
    /// Both fields' gradients at the cell's corners `00, 10, 01, 11`: `(ax, ay, bx, by)`.
    grads: [(f64, f64, f64, f64); 4],
}

impl CellCache {
    /// A cache that matches no cell yet.
    const EMPTY: Self = Self { cell: (i64::MIN, i64::MIN), grads: [(0.0, 0.0, 0.0, 0.0); 4] };
}

impl CellCache {
    /// Makes the cache hold cell `(ix, iy)` of the field `salt` (hashing its corners if it
    /// held another).
    #[inline(always)]
    fn hold(&mut self, salt: u64, ix: i64, iy: i64) {
        if self.cell != (ix, iy) {
            let g = |h: u64| {
                let (ax, ay) = GRADIENTS[(h >> 60) as usize];
                let (bx, by) = GRADIENTS[((h >> 56) & 15) as usize];
                (ax, ay, bx, by)
            };
            self.cell = (ix, iy);
            self.grads = [
                g(lattice_hash(salt, ix, iy)),
                g(lattice_hash(salt, ix + 1, iy)),
                g(lattice_hash(salt, ix, iy + 1)),
                g(lattice_hash(salt, ix + 1, iy + 1)),
            ];
        }
    }
}

/// `[f(0), f(1), ..]`: one value per lane.
#[inline(always)]
fn lanes<const N: usize>(f: impl Fn(usize) -> f64) -> [f64; N] {
    std::array::from_fn(f)
}

/// Samples the row path computes side by side ([`Generator::unit_height_lanes`]): its
/// arithmetic runs on arrays of this many lanes, which the compiler turns into vector
/// instructions (the same IEEE operations in the same order for each lane: same bits).
const LANES: usize = 4;

/// [`noise2`] at `N` points side by side, each field's lattice cell through a [`CellCache`]
/// (same result, bit for bit: the reference is `noise2`, test `cached_noise_is_bit_identical`).
/// When the `N` points share one cell (most of them at the coarse octaves) the gradients are
/// read once for all; otherwise point by point.
#[inline(always)]
fn noise2_lanes<const N: usize>(
    salt: u64,
    x: &[f64; N],
    y: &[f64; N],
    cache: &mut CellCache,
) -> ([f64; N], [f64; N]) {
    let (mut ix, mut iy) = ([0i64; N], [0i64; N]);
    let (mut fx, mut fy) = ([0.0; N], [0.0; N]);
    for l in 0..N {
        ix[l] = floor_i64(x[l]);
        iy[l] = floor_i64(y[l]);
        fx[l] = x[l] - ix[l] as f64;
        fy[l] = y[l] - iy[l] as f64;
    }
    // Both fields' values at the corners 00, 10, 01, 11: `c[corner][field][lane]`, the same
    // products in the same order as `grad2`.
    let mut c = [[[0.0; N]; 2]; 4];
    #[inline(always)]
    fn corners<const N: usize>(
        g: &[(f64, f64, f64, f64); 4],
        fx: f64,
        fy: f64,
        c: &mut [[[f64; N]; 2]; 4],
        l: usize,
    ) {
        for (k, (dx, dy)) in
            [(fx, fy), (fx - 1.0, fy), (fx, fy - 1.0), (fx - 1.0, fy - 1.0)].into_iter().enumerate()
        {
            c[k][0][l] = g[k].0 * dx + g[k].1 * dy;
            c[k][1][l] = g[k].2 * dx + g[k].3 * dy;
        }
    }
    if ix.iter().all(|&v| v == ix[0]) && iy.iter().all(|&v| v == iy[0]) {
        cache.hold(salt, ix[0], iy[0]);
        let g = cache.grads;
        for l in 0..N {
            corners(&g, fx[l], fy[l], &mut c, l);
        }
    } else {
        for l in 0..N {
            cache.hold(salt, ix[l], iy[l]);
            corners(&cache.grads, fx[l], fy[l], &mut c, l);
        }
    }
    let (mut a, mut b) = ([0.0; N], [0.0; N]);
    for l in 0..N {
        let corner = |k: usize| (c[k][0][l], c[k][1][l]);
        (a[l], b[l]) = blend([corner(0), corner(1), corner(2), corner(3)], fx[l], fy[l]);
    }
    (a, b)
}

/// One [`CellCache`] per noise field of a [`Generator`] (warp, octaves, valleys).
struct Caches {
    warp: [CellCache; WARP_OCTAVES],
    octave: [CellCache; MAX_OCTAVES as usize],
    valley: [CellCache; VALLEY_OCTAVES],
}

impl Caches {
    fn new() -> Self {
        Self {
            warp: [CellCache::EMPTY; WARP_OCTAVES],
            octave: [CellCache::EMPTY; MAX_OCTAVES as usize],
            valley: [CellCache::EMPTY; VALLEY_OCTAVES],
        }
    }
}

/// 2-D gradient noise in `[-1, 1]` (the first field of [`noise2`]).
#[cfg(test)]
fn noise(salt: u64, x: f64, y: f64) -> f64 {
    noise2(salt, x, y).0
}

/// Smoothstep from 0 at `e0` to 1 at `e1`.
#[inline]
fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Noise layers (part of the hash input, so layers are independent).
const LAYER_OCTAVE: u64 = 1;
const LAYER_WARP: u64 = 2;
const LAYER_VALLEY: u64 = 3;

/// The config with its per-octave tables prepared (salts, frequencies, normalised amplitudes).
struct Generator {
    octaves: usize,
    /// Feature units (base wavelengths) per sample.
    scale: f64,
    relief: f64,
    warp: f64,
    ridge_mix: f64,
    valley_scale: f64,
    valley_width: f64,
    valley_depth: f64,
    freq: [f64; MAX_OCTAVES as usize],
    /// Salt of each octave; one hash per lattice point feeds the ridged and the fBm field.
    salt: [u64; MAX_OCTAVES as usize],
    /// Ridged amplitudes `lacunarity^-k`, divided by their sum.
    ridged_amp: [f64; MAX_OCTAVES as usize],
    /// fBm amplitudes `persistence^k`, divided by their sum.
    fbm_amp: [f64; MAX_OCTAVES as usize],
    warp_salt: [u64; WARP_OCTAVES],
    valley_salt: [u64; VALLEY_OCTAVES],
}

/// Normalised amplitudes `[1, 1/2, 1/4, ...] / sum` of the fixed small fields (warp, valleys).
const fn small_amps<const N: usize>() -> [f64; N] {
    // Persistence 1/2: 1, 1/2, 1/4, ... divided by (2 - 2^(1-N)).
    let mut a = [0.0; N];
    let mut sum = 0.0;
    let mut k = 0;
    let mut amp = 1.0;
    while k < N {
        a[k] = amp;
        sum += amp;
        amp *= 0.5;
        k += 1;
    }
    let mut k = 0;
    while k < N {
        a[k] /= sum;
        k += 1;
    }
    a
}
const WARP_AMPS: [f64; WARP_OCTAVES] = small_amps::<WARP_OCTAVES>();
const VALLEY_AMPS: [f64; VALLEY_OCTAVES] = small_amps::<VALLEY_OCTAVES>();

impl Generator {
    fn new(c: &FractalConfig) -> Self {
        if let Err(e) = c.validate() {
            panic!("invalid FractalConfig: {e}");
        }
        let octaves = c.octaves as usize;
        let mut g = Self {
            octaves,
            scale: c.spacing_m / c.base_wavelength_m,
            relief: c.relief_m,
            warp: c.warp,
            ridge_mix: c.ridge_mix,
            valley_scale: c.base_wavelength_m / c.valley_wavelength_m,
            valley_width: c.valley_width,
            valley_depth: c.valley_depth,
            freq: [0.0; MAX_OCTAVES as usize],
            salt: [0; MAX_OCTAVES as usize],
            ridged_amp: [0.0; MAX_OCTAVES as usize],
            fbm_amp: [0.0; MAX_OCTAVES as usize],
            warp_salt: [0; WARP_OCTAVES],
            valley_salt: [0; VALLEY_OCTAVES],
        };
        let (mut f, mut ra, mut fa) = (1.0, 1.0, 1.0);
        let (mut rsum, mut fsum) = (0.0, 0.0);
        for k in 0..octaves {
            g.freq[k] = f;
            g.salt[k] = salt(c.seed, LAYER_OCTAVE, k as u64);
            g.ridged_amp[k] = ra;
            g.fbm_amp[k] = fa;
            rsum += ra;
            fsum += fa;
            f *= c.lacunarity;
            ra /= c.lacunarity;
            fa *= c.persistence;
        }
        for k in 0..octaves {
            g.ridged_amp[k] /= rsum;
            g.fbm_amp[k] /= fsum;
        }
        for k in 0..WARP_OCTAVES {
            g.warp_salt[k] = salt(c.seed, LAYER_WARP, k as u64);
        }
        for k in 0..VALLEY_OCTAVES {
            g.valley_salt[k] = salt(c.seed, LAYER_VALLEY, k as u64);
        }
        g
    }

    /// Normalised height `t ∈ [0, 1]` at feature-space position `(x, y)`.
    #[inline]
    fn unit_height(&self, x: f64, y: f64) -> f64 {
        self.unit_height_lanes(&[x], &[y], &mut Caches::new())[0]
    }

    /// [`Generator::unit_height`] at `N` positions side by side, the noise fields' lattice
    /// cells cached in `caches` (bit-identical for each lane; faster along a row).
    #[inline(always)]
    fn unit_height_lanes<const N: usize>(
        &self,
        x: &[f64; N],
        y: &[f64; N],
        caches: &mut Caches,
    ) -> [f64; N] {
        // Domain warp: two 3-octave fBm fields at half the base frequency.
        let (mut wx, mut wy, mut f) = ([0.0; N], [0.0; N], 0.5);
        for ((&salt, &amp), cache) in
            self.warp_salt.iter().zip(&WARP_AMPS).zip(caches.warp.iter_mut())
        {
            let (nx, ny) =
                noise2_lanes(salt, &lanes::<N>(|l| x[l] * f), &lanes::<N>(|l| y[l] * f), cache);
            for l in 0..N {
                wx[l] += amp * nx[l];
                wy[l] += amp * ny[l];
            }
            f *= 2.0;
        }
        let qx = lanes::<N>(|l| x[l] + self.warp * wx[l]);
        let qy = lanes::<N>(|l| y[l] + self.warp * wy[l]);

        // Ridged multifractal (Musgrave) and fBm, each in [0, 1].
        let (mut ridged, mut fbm, mut weight) = ([0.0; N], [0.0; N], [1.0; N]);
        for k in 0..self.octaves {
            let fk = self.freq[k];
            let (px, py) = (lanes::<N>(|l| qx[l] * fk), lanes::<N>(|l| qy[l] * fk));
            let (nr, nf) = noise2_lanes(self.salt[k], &px, &py, &mut caches.octave[k]);
            for l in 0..N {
                let s = RIDGE_OFFSET - nr[l].abs();
                let s = s * s * weight[l];
                ridged[l] += s * self.ridged_amp[k];
                weight[l] = (s * RIDGE_GAIN).clamp(0.0, 1.0);
                fbm[l] += nf[l] * self.fbm_amp[k];
            }
        }
        let mut t = [0.0; N];
        for l in 0..N {
            let fbm01 = 0.5 * (fbm[l] + 1.0);
            let mixed = self.ridge_mix * ridged[l] + (1.0 - self.ridge_mix) * fbm01;
            // Contrast: smooth rational sigmoid onto (0, 1).
            let z = (mixed - CONTRAST_CENTRE) * CONTRAST_GAIN;
            t[l] = 0.5 + 0.5 * z / (1.0 + z * z).sqrt();
        }

        // Valley carving along the zero set of a warped low-frequency field.
        let (vx, vy) =
            (lanes::<N>(|l| qx[l] * self.valley_scale), lanes::<N>(|l| qy[l] * self.valley_scale));
        let mut v = [0.0; N];
        let mut f = 1.0;
        for ((&salt, &amp), cache) in
            self.valley_salt.iter().zip(&VALLEY_AMPS).zip(caches.valley.iter_mut())
        {
            let (n, _) =
                noise2_lanes(salt, &lanes::<N>(|l| vx[l] * f), &lanes::<N>(|l| vy[l] * f), cache);
            for l in 0..N {
                v[l] += amp * n[l];
            }
            f *= 2.0;
        }
        for l in 0..N {
            let carve = smoothstep(0.0, self.valley_width, v[l].abs());
            t[l] *= 1.0 - self.valley_depth * (1.0 - carve);
        }
        t
    }

    #[inline]
    fn sample(&self, i: u64, j: u64) -> f32 {
        let t = self.unit_height(i as f64 * self.scale, j as f64 * self.scale);
        self.height_of(t)
    }

    /// Metres of a normalised height (the final clamp only absorbs rounding).
    #[inline(always)]
    fn height_of(&self, t: f64) -> f32 {
        (t.clamp(0.0, 1.0) * self.relief) as f32
    }

    /// Samples `x0 .. x0 + out.len()` of row `j` into `out` ([`LANES`] side by side, the rest
    /// one by one; bit-identical to [`Generator::sample`]), through `caches`.
    fn row(&self, x0: u64, j: u64, out: &mut [f32], caches: &mut Caches) {
        let y = j as f64 * self.scale;
        let mut chunks = out.chunks_exact_mut(LANES);
        let mut i = x0;
        for chunk in &mut chunks {
            let x = std::array::from_fn(|l| (i + l as u64) as f64 * self.scale);
            let t = self.unit_height_lanes::<LANES>(&x, &[y; LANES], caches);
            for (z, t) in chunk.iter_mut().zip(t) {
                *z = self.height_of(t);
            }
            i += LANES as u64;
        }
        for z in chunks.into_remainder() {
            let t = self.unit_height_lanes(&[i as f64 * self.scale], &[y], caches);
            *z = self.height_of(t[0]);
            i += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small() -> FractalConfig {
        FractalConfig::with_size(97, 61, 10.0)
    }

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|z| z.to_bits()).collect()
    }

    #[test]
    fn same_config_gives_bit_identical_samples() {
        let c = FractalConfig::default();
        let a = c.to_heightmap().unwrap();
        let b = c.clone().to_heightmap().unwrap();
        assert_eq!(bits(a.data()), bits(b.data()));
        for (i, j) in [(0, 0), (1024, 1024), (17, 900), (512, 3)] {
            assert_eq!(c.sample(i, j).to_bits(), c.sample(i, j).to_bits());
            assert_eq!(c.sample(i, j).to_bits(), a.get(i as usize, j as usize).to_bits());
        }
    }

    /// Pinned values: any change of the algorithm or a platform difference shows up here.
    #[test]
    fn golden_samples() {
        let c = FractalConfig::default();
        let got: Vec<(u64, u64, u32)> = [(0, 0), (512, 512), (1024, 0), (100, 900), (33, 777)]
            .iter()
            .map(|&(i, j)| (i, j, c.sample(i, j).to_bits()))
            .collect();
        let want: [(u64, u64, u32); 5] = GOLDEN;
        assert_eq!(
            got,
            want,
            "golden values (as f32: {:?})",
            got.iter().map(|g| f32::from_bits(g.2)).collect::<Vec<_>>()
        );
    }

    // 214.07181, 275.26022, 1280.9337, 437.93027, 245.77559 m.
    const GOLDEN: [(u64, u64, u32); 5] = [
        (0, 0, 1_129_714_274),
        (512, 512, 1_133_093_199),
        (1024, 0, 1_151_344_097),
        (100, 900, 1_138_423_571),
        (33, 777, 1_131_792_013),
    ];

    /// Every sample of a 259 x 67 block of the default terrain and of a rougher, more warped
    /// one (12 octaves: lattice cells of under a sample), hashed (FNV-1a over the f32 bits) and
    /// pinned: the generator's row path computes samples side by side, and any change of a
    /// bit of any sample shows up here (the golden samples above pin only five).
    #[test]
    fn pinned_block_checksums() {
        let fnv = |v: &[f32]| {
            v.iter().fold(crate::checksum::FNV1A_START, |h, z| {
                crate::checksum::fnv1a_update(h, &z.to_bits().to_le_bytes())
            })
        };
        let rough = FractalConfig {
            seed: 7,
            octaves: 12,
            warp: 3.0,
            ..FractalConfig::with_size(1025, 1025, 10.0)
        };
        let mut got = Vec::new();
        for (c, x0, y0) in [(FractalConfig::default(), 700u64, 3u64), (rough, 3, 900)] {
            let mut out = vec![f32::NAN; 259 * 67];
            c.generate_block(x0, y0, 259, 67, &mut out);
            got.push(fnv(&out));
        }
        assert_eq!(got, PINNED, "{got:#x?}");
    }

    const PINNED: [u64; 2] = [0x8d54_fe4c_eea4_a553, 0x23f1_cb38_ef0a_9ed2];

    #[test]
    fn generate_block_equals_sample() {
        let c = small();
        for &(x0, y0, w, h) in &[
            (0u64, 0u64, 97usize, 61usize),
            (5, 7, 13, 11),
            (96, 60, 1, 1),
            (40, 0, 57, 2),
            (0, 30, 0, 3),
        ] {
            let mut out = vec![f32::NAN; w * h];
            c.generate_block(x0, y0, w, h, &mut out);
            for r in 0..h {
                for q in 0..w {
                    let want = c.sample(x0 + q as u64, y0 + r as u64);
                    assert_eq!(
                        out[r * w + q].to_bits(),
                        want.to_bits(),
                        "block ({x0},{y0}) sample ({q},{r})"
                    );
                }
            }
        }
    }

    /// The cached noise equals the reference bit for bit, along a path that stays in a cell,
    /// steps to its neighbours, jumps back and crosses zero (negative lattice indices).
    #[test]
    fn cached_noise_is_bit_identical() {
        let mut cache = CellCache::EMPTY;
        let mut state = 0x1234_5678_u64;
        let mut x = -3.3f64;
        let mut y = 0.7f64;
        for k in 0..20_000 {
            state = mix64(state);
            // Mostly small steps (same cell), sometimes a jump.
            let step = if k % 97 == 0 { 5.0 } else { 0.03 };
            x += ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.45) * step;
            y += ((state & 0xFFFF) as f64 / 65536.0 - 0.5) * step;
            let ([a], [b]) = noise2_lanes(99, &[x], &[y], &mut cache);
            let (c, d) = noise2(99, x, y);
            assert_eq!((a.to_bits(), b.to_bits()), (c.to_bits(), d.to_bits()), "at ({x}, {y})");
        }
    }

    #[test]
    fn generate_rows_equals_heightmap_rows() {
        let c = small();
        let hm = c.to_heightmap().unwrap();
        let w = hm.width();
        for (j0, rows) in [(0u64, 1usize), (0, 61), (13, 7), (60, 1)] {
            let mut out = vec![f32::NAN; w * rows];
            c.generate_rows(j0, rows, &mut out);
            let j0 = j0 as usize;
            assert_eq!(bits(&out), bits(&hm.data()[j0 * w..(j0 + rows) * w]));
        }
    }

    #[test]
    fn a_different_seed_differs() {
        let a = small().to_heightmap().unwrap();
        let b = FractalConfig { seed: 2, ..small() }.to_heightmap().unwrap();
        let same = a.data().iter().zip(b.data()).filter(|(x, y)| x == y).count();
        assert!(same * 100 < a.data().len(), "{same} of {} samples equal", a.data().len());
    }

    #[test]
    fn heights_are_finite_and_within_relief() {
        for c in [
            FractalConfig::default(),
            FractalConfig { seed: 0xDEAD_BEEF, relief_m: 8848.0, octaves: 12, ..small() },
            FractalConfig { warp: 3.0, ridge_mix: 0.0, valley_depth: 1.0, ..small() },
            FractalConfig { octaves: 1, ridge_mix: 1.0, valley_depth: 0.0, ..small() },
        ] {
            let hm = c.to_heightmap().unwrap();
            let top = c.relief_m as f32;
            assert!(hm.data().iter().all(|z| z.is_finite() && (0.0..=top).contains(z)), "{c:?}");
        }
    }

    #[test]
    fn the_default_has_real_relief() {
        let c = FractalConfig::default();
        let hm = c.to_heightmap().unwrap();
        assert_eq!((hm.width(), hm.height()), (1025, 1025));
        assert_eq!(hm.georef().spacing_m, glam::dvec2(10.0, 10.0));
        let range = hm.max() - hm.min();
        assert!(range > 0.5 * c.relief_m as f32, "relief {range} m");
    }

    /// Fraction of targets (every `step`-th sample) that a viewer `eye_m` above sample
    /// `(vi, vj)` cannot see (some terrain between rises above the sight line).
    fn hidden_fraction(hm: &Heightmap, vi: usize, vj: usize, eye_m: f32, step: usize) -> f64 {
        let (vx, vy) = (vi as f64, vj as f64);
        let vz = hm.get(vi, vj) + eye_m;
        let (mut hidden, mut total) = (0usize, 0usize);
        for tj in (0..hm.height()).step_by(step) {
            for ti in (0..hm.width()).step_by(step) {
                let (dx, dy) = (ti as f64 - vx, tj as f64 - vy);
                let dist = dx.hypot(dy);
                if dist < 2.0 {
                    continue;
                }
                total += 1;
                let tz = hm.get(ti, tj) + 0.5;
                let n = (dist * 2.0) as usize;
                let blocked = (1..n).any(|k| {
                    let t = k as f64 / n as f64;
                    let ray = vz + (tz - vz) * t as f32;
                    hm.sample_grid(vx + dx * t, vy + dy * t) > ray
                });
                hidden += usize::from(blocked);
            }
        }
        hidden as f64 / total as f64
    }

    #[test]
    fn the_default_has_valleys_that_hide_terrain() {
        let hm = FractalConfig::default().to_heightmap().unwrap();
        // The lowest sample (a valley floor) with a 2 m eye.
        let k =
            (0..hm.data().len()).min_by(|&a, &b| hm.data()[a].total_cmp(&hm.data()[b])).unwrap();
        let (vi, vj) = (k % hm.width(), k / hm.width());
        let hidden = hidden_fraction(&hm, vi, vj, 2.0, 16);
        assert!(hidden > 0.5, "only {:.1}% hidden from the valley floor", hidden * 100.0);
        // The same test on a plane hides nothing, so the measure is meaningful.
        let flat = Heightmap::from_fn(65, 65, Georef::local(10.0), |_, _| 100.0).unwrap();
        assert_eq!(hidden_fraction(&flat, 10, 10, 2.0, 1), 0.0);
    }

    #[test]
    fn a_32769_squared_grid_streams_its_last_row() {
        let c = FractalConfig { width: 32769, height: 32769, ..FractalConfig::default() };
        let mut row = vec![f32::NAN; 32769];
        c.generate_rows(32768, 1, &mut row);
        assert!(row.iter().all(|z| z.is_finite() && (0.0..=1500.0).contains(z)));
        for i in [0u64, 1, 16384, 32767, 32768] {
            assert_eq!(row[i as usize].to_bits(), c.sample(i, 32768).to_bits());
        }
        let mut block = vec![f32::NAN; 4 * 3];
        c.generate_block(32765, 32766, 4, 3, &mut block);
        assert_eq!(block[11].to_bits(), row[32768].to_bits());
        let range = row.iter().fold(f32::INFINITY, |a, &b| a.min(b))
            ..=row.iter().fold(0.0f32, |a, &b| a.max(b));
        assert!(range.end() - range.start() > 100.0, "the far row has relief too: {range:?}");
    }

    #[test]
    fn empty_grids_and_bad_configs_are_refused() {
        assert!(matches!(
            FractalConfig::with_size(0, 5, 10.0).to_heightmap(),
            Err(HeightmapError::Empty { .. })
        ));
        assert!(FractalConfig::default().validate().is_ok());
        assert!(FractalConfig { octaves: 0, ..small() }.validate().is_err());
        assert!(FractalConfig { octaves: MAX_OCTAVES + 1, ..small() }.validate().is_err());
        assert!(FractalConfig { spacing_m: 0.0, ..small() }.validate().is_err());
        assert!(FractalConfig { relief_m: f64::NAN, ..small() }.validate().is_err());
        assert!(FractalConfig { valley_depth: 1.5, ..small() }.validate().is_err());
    }

    #[test]
    fn a_block_outside_the_grid_panics() {
        // Caller misuse (like slice indexing out of range): a panic with a message that says so.
        let result = std::panic::catch_unwind(|| {
            let mut out = vec![0.0; 4];
            small().generate_block(96, 0, 2, 2, &mut out);
        });
        let payload = result.expect_err("a block outside the grid must panic");
        let message = payload
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_default();
        assert!(message.contains("leaves the"), "{message}");
    }

    #[test]
    fn hash_and_noise_basics() {
        // Noise vanishes at lattice points and stays within [-1, 1].
        assert_eq!(noise(7, 3.0, -4.0), 0.0);
        let mut lo: f64 = 0.0;
        let mut hi: f64 = 0.0;
        for k in 0..20_000 {
            let (x, y) = (k as f64 * 0.0137 - 50.0, k as f64 * 0.0291 - 300.0);
            let (a, b) = noise2(11, x, y);
            lo = lo.min(a).min(b);
            hi = hi.max(a).max(b);
        }
        assert!((-1.0..-0.5).contains(&lo) && (0.5..=1.0).contains(&hi), "{lo} {hi}");
        assert_eq!(floor_i64(-0.5), -1);
        assert_eq!(floor_i64(-1.0), -1);
        assert_eq!(floor_i64(2.999), 2);
    }
}
