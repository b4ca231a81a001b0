//! CPU reference of the hardware quad-domain tessellator with fractional-even spacing.
//!
//! It follows the Direct3D 11 functional specification's tessellator (§11.7, whose reference
//! implementation is Microsoft's `CHWTessellator`, also shipped in Mesa's
//! `gallium/auxiliary/tessellator`), restated in `f32` instead of the reference's 16.16 fixed
//! point, so that the WGSL emulation in `tessellate.wgsl` can repeat the arithmetic operation
//! for operation. Every function here has a twin of the same name in the shader; change both.
//!
//! The domain is `[0, 1]^2`. Points are laid out as the reference lays them out: the outer ring
//! (clockwise in D3D's picture, starting at `(0, 1)`), then the inner rings spiralling inwards,
//! then the degenerate centre ring (a row or column of points through the middle, which even
//! spacing always has). Triangles have positive signed area in the `(u, v)` plane.

use super::PatchFactors;

/// Smallest factor under fractional-even spacing: factors below it (1 included) act as 2.
pub const MIN_FACTOR: f32 = 2.0;
/// Largest factor (D3D11 and Vulkan `maxTessellationGenerationLevel` minimum): larger ones act as 64.
pub const MAX_FACTOR: f32 = 64.0;

/// For each of the 33 point slots of a half edge at the finest spacing (the midpoint
/// excluded), the half-factor step at which fractional spacing inserts it: the "ruler
/// function" order. A half edge with `h` points holds the slots whose entry is `< h`.
/// Stitching a transition advances the inner or outer row in this order, so both rows of any
/// two factors interleave the same way (D3D11 reference tessellator, `StitchTransition`).
/// `ruler_table_matches_split_order` derives it again from [`EdgeSpacing::new`]'s split rule.
pub const RULER_ORDER: [u32; 33] = [
    0, 32, 16, 8, 17, 4, 18, 9, 19, 2, 20, 10, 21, 5, 22, 11, 23, 1, 24, 12, 25, 6, 26, 13, 27, 3,
    28, 14, 29, 7, 30, 15, 31,
];

/// Clamps a factor for fractional-even spacing: NaN and everything below 2 give 2, above 64 give 64.
#[inline]
pub fn clamp_factor(factor: f32) -> f32 {
    // NaN lands on the lower bound, as the spec says.
    if factor > MAX_FACTOR {
        MAX_FACTOR
    } else if factor > MIN_FACTOR {
        factor
    } else {
        MIN_FACTOR
    }
}

/// `x` without its most significant set bit (0 for 0).
#[inline]
pub(crate) fn remove_msb(x: u32) -> u32 {
    if x == 0 { 0 } else { x & !(1u32 << (31 - x.leading_zeros())) }
}

/// Fractional-even spacing of one edge (or one inner axis): the `TESS_FACTOR_CONTEXT` of the
/// D3D11 reference, in `f32`.
///
/// With `t` the clamped factor, each half edge blends `floor(t/2)` and `ceil(t/2)` equal
/// segments by the fraction of `t/2`: the vertex that the finer layout adds (at the ruler
/// position `split`) grows out of its neighbour, so vertices move continuously as `t` grows.
/// The result has `2*ceil(t/2) - 2` equal segments plus two shorter ones of equal length placed
/// symmetrically about the midpoint, which is exactly 0.5; the other half mirrors the first.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EdgeSpacing {
    /// Points on a half edge, the midpoint excluded: `ceil(t / 2)`.
    pub half_points: u32,
    /// Index on the half edge after which the coarse layout repeats a point; beyond
    /// `half_points` when `t / 2` is an integer (no point is being inserted).
    pub split: u32,
    /// Fractional part of `t / 2`.
    pub frac: f32,
    /// `1 / (2 floor(t/2))`: segment length of the coarse layout.
    pub inv_floor: f32,
    /// `1 / (2 ceil(t/2))`: segment length of the fine layout.
    pub inv_ceil: f32,
}

impl EdgeSpacing {
    /// The spacing for a factor (clamped with [`clamp_factor`]).
    pub fn new(factor: f32) -> Self {
        let t = clamp_factor(factor);
        let half = t * 0.5;
        let lo = half.floor();
        let hi = half.ceil();
        let half_points = hi as u32;
        let split = if lo == hi { half_points + 1 } else { remove_msb(lo as u32) * 2 + 1 };
        Self {
            half_points,
            split,
            frac: half - lo,
            inv_floor: 1.0 / (2.0 * lo),
            inv_ceil: 1.0 / (2.0 * hi),
        }
    }

    /// Points on the whole edge, both ends included: `2 ceil(t/2) + 1`.
    #[inline]
    pub fn point_count(&self) -> u32 {
        2 * self.half_points + 1
    }

    /// Parameter in `[0, 1]` of point `point` (`0..point_count()`): `PlacePointIn1D`.
    pub fn place(&self, point: u32) -> f32 {
        let flip = point >= self.half_points;
        let p = if flip { 2 * self.half_points - point } else { point };
        if p == self.half_points {
            // The midpoint is exact, so both halves meet there.
            return 0.5;
        }
        let on_floor = if p > self.split { p - 1 } else { p };
        let at_floor = on_floor as f32 * self.inv_floor;
        let at_ceil = p as f32 * self.inv_ceil;
        let at = at_floor * (1.0 - self.frac) + at_ceil * self.frac;
        if flip { 1.0 - at } else { at }
    }
}

/// The processed factors of one patch: spacing per outer edge and inner axis, point counts,
/// ring structure and the closed-form layout of points and triangles.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct QuadLayout {
    /// Whether the patch is culled (an outer factor is `<= 0` or NaN): no points, no triangles.
    pub culled: bool,
    /// Spacing of the outer edges, in [`PatchFactors::outer`]'s order.
    pub outer: [EdgeSpacing; 4],
    /// Spacing of the inner axes `u` and `v`.
    pub inner: [EdgeSpacing; 2],
    /// Number of rings inside the outer ring; ring `rings` is the degenerate centre ring.
    pub rings: u32,
}

impl QuadLayout {
    /// Processes a patch's factors (`QuadProcessTessFactors` for fractional-even).
    pub fn new(f: &PatchFactors) -> Self {
        // A patch is culled when an outer factor is not positive, NaN included.
        let culled = f.outer.iter().any(|&x| x.is_nan() || x <= 0.0);
        let outer = f.outer.map(EdgeSpacing::new);
        let inner = f.inner.map(EdgeSpacing::new);
        let rings = inner[0].half_points.min(inner[1].half_points);
        Self { culled, outer, inner, rings }
    }

    /// Points of inner axis `axis` (0 = u, 1 = v), both edges included.
    #[inline]
    fn inner_count(&self, axis: usize) -> u32 {
        self.inner[axis].point_count()
    }

    /// Inner axis along which side `side` of an inner ring runs: sides 0 and 2 run along `v`.
    #[inline]
    fn side_axis(side: usize) -> usize {
        if side.is_multiple_of(2) { 1 } else { 0 }
    }

    /// Points on side `side` of ring `ring`, both corners included.
    pub fn side_len(&self, ring: u32, side: usize) -> u32 {
        if ring == 0 {
            self.outer[side].point_count()
        } else {
            self.inner_count(Self::side_axis(side)) - 2 * ring
        }
    }

    /// Points of the outer ring (corners counted once).
    fn outer_ring_points(&self) -> u32 {
        self.outer.iter().map(|s| s.point_count() - 1).sum()
    }

    /// Index of the first point of ring `ring >= 1`: full rings `j` in `1..ring` hold
    /// `2 (nu - 2j - 1) + 2 (nv - 2j - 1)` points each.
    pub fn ring_base(&self, ring: u32) -> u32 {
        let r1 = ring - 1;
        let n = self.inner_count(0) + self.inner_count(1);
        self.outer_ring_points() + r1 * (2 * n - 4 * ring - 4)
    }

    /// Whether the degenerate centre ring is a row along `u` (else a column along `v`, or a point).
    #[inline]
    fn centre_is_row(&self) -> bool {
        self.inner_count(0) > self.inner_count(1)
    }

    /// Number of domain points: the outer ring plus `(nu - 2)(nv - 2)` inside it.
    pub fn point_count(&self) -> u32 {
        if self.culled {
            return 0;
        }
        self.outer_ring_points() + (self.inner_count(0) - 2) * (self.inner_count(1) - 2)
    }

    /// Triangles stitching ring `ring - 1` to ring `ring` along side `side`: one per segment of either row.
    #[inline]
    pub fn band_triangles(&self, ring: u32, side: usize) -> u32 {
        self.side_len(ring - 1, side) + self.side_len(ring, side) - 2
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> u32 {
        if self.culled {
            return 0;
        }
        (1..=self.rings).map(|r| (0..4).map(|e| self.band_triangles(r, e)).sum::<u32>()).sum()
    }

    /// Index of the `k`-th point (from corner to corner, in ring order) on side `side` of ring `ring`.
    pub fn side_point(&self, ring: u32, side: usize, k: u32) -> u32 {
        let len = self.side_len(ring, side);
        if ring == 0 || ring < self.rings {
            let (base, mut start) = if ring == 0 { (0, 0) } else { (self.ring_base(ring), 0) };
            for s in 0..side {
                start += self.side_len(ring, s) - 1;
            }
            // The last side ends where the ring started.
            if side == 3 && k == len - 1 { base } else { base + start + k }
        } else {
            let base = self.ring_base(ring);
            if self.centre_is_row() {
                let last = self.inner_count(0) - 2 * ring - 1;
                match side {
                    0 => base,
                    1 => base + k,
                    2 => base + last,
                    _ => base + last - k,
                }
            } else {
                let last = self.inner_count(1) - 2 * ring - 1;
                match side {
                    0 => base + k,
                    1 => base + last,
                    2 => base + last - k,
                    _ => base,
                }
            }
        }
    }

    /// Writes the domain points in the reference's order (`QuadGeneratePoints`).
    pub fn generate_points(&self, out: &mut Vec<[f32; 2]>) {
        if self.culled {
            return;
        }
        // Outer ring: each edge without its last point, which the next edge starts with.
        for (e, s) in self.outer.iter().enumerate() {
            let end = s.point_count() - 1;
            for p in 0..end {
                let q = if e == 1 || e == 2 { p } else { end - p };
                let t = s.place(q);
                out.push(match e {
                    0 => [0.0, t],
                    1 => [t, 0.0],
                    2 => [1.0, t],
                    _ => [t, 1.0],
                });
            }
        }
        // Full inner rings.
        for r in 1..self.rings {
            for e in 0..4 {
                let along = Self::side_axis(e);
                let across = 1 - along;
                let end = self.inner_count(along) - 1 - r;
                let across_point = if e < 2 { r } else { self.inner_count(across) - 1 - r };
                let c = self.inner[across].place(across_point);
                for p in r..end {
                    let q = if e == 1 || e == 2 { p } else { end - (p - r) };
                    let t = self.inner[along].place(q);
                    out.push(if along == 1 { [c, t] } else { [t, c] });
                }
            }
        }
        // The degenerate centre ring.
        let m = self.rings;
        if self.centre_is_row() {
            for p in m..=self.inner_count(0) - 1 - m {
                out.push([self.inner[0].place(p), 0.5]);
            }
        } else {
            for p in (m..=self.inner_count(1) - 1 - m).rev() {
                out.push([0.5, self.inner[1].place(p)]);
            }
        }
    }

    /// Writes the triangles (`QuadGenerateConnectivity`), ring by ring and side by side.
    pub fn generate_triangles(&self, out: &mut Vec<u32>) {
        if self.culled {
            return;
        }
        for r in 1..=self.rings {
            for e in 0..4 {
                let mut band = Band { layout: self, ring: r, side: e, o: 0, i: 0, out: &mut *out };
                if r == 1 {
                    let outer_half = self.outer[e].half_points;
                    let inner_half = self.inner[Self::side_axis(e)].half_points;
                    band.stitch_transition(outer_half, inner_half);
                } else {
                    band.stitch_regular(self.side_len(r, e));
                }
            }
        }
    }
}

/// A band of triangles between side `side` of ring `ring - 1` (outside, cursor `o`) and of
/// ring `ring` (inside, cursor `i`).
struct Band<'a> {
    layout: &'a QuadLayout,
    ring: u32,
    side: usize,
    o: u32,
    i: u32,
    out: &'a mut Vec<u32>,
}

impl Band<'_> {
    fn outside(&self, k: u32) -> u32 {
        self.layout.side_point(self.ring - 1, self.side, k)
    }

    fn inside(&self, k: u32) -> u32 {
        self.layout.side_point(self.ring, self.side, k)
    }

    fn tri(&mut self, a: u32, b: u32, c: u32) {
        self.out.extend_from_slice(&[a, b, c]);
    }

    /// Triangle on the next outside segment.
    fn advance_outside(&mut self) {
        let (a, b, c) = (self.outside(self.o), self.outside(self.o + 1), self.inside(self.i));
        self.tri(a, b, c);
        self.o += 1;
    }

    /// Triangle on the next inside segment.
    fn advance_inside(&mut self) {
        let (a, b, c) = (self.inside(self.i), self.outside(self.o), self.inside(self.i + 1));
        self.tri(a, b, c);
        self.i += 1;
    }

    /// Outer edge to first inner ring, rows of unrelated factors (`StitchTransition`, both
    /// parities even): walk the half edges in ruler order, then mirror.
    fn stitch_transition(&mut self, outer_half: u32, inner_half: u32) {
        // Under even spacing a half of the inner ring side has one segment fewer than the
        // factor's half: `inner_half - 1` advances per half, `outer_half` outside.
        if RULER_ORDER[0] < outer_half {
            self.advance_outside();
        }
        for &pos in &RULER_ORDER[1..] {
            if pos < inner_half {
                self.advance_inside();
            }
            if pos < outer_half {
                self.advance_outside();
            }
        }
        for &pos in RULER_ORDER[1..].iter().rev() {
            if pos < outer_half {
                self.advance_outside();
            }
            if pos < inner_half {
                self.advance_inside();
            }
        }
        if RULER_ORDER[0] < outer_half {
            self.advance_outside();
        }
    }

    /// Ring to ring with two points more outside (`StitchRegular`, trapezoid, mirrored
    /// diagonals so that the band is symmetric about its middle).
    fn stitch_regular(&mut self, inside_len: u32) {
        self.advance_outside();
        for p in 0..inside_len - 1 {
            let (o0, o1) = (self.outside(self.o), self.outside(self.o + 1));
            let (i0, i1) = (self.inside(self.i), self.inside(self.i + 1));
            if p < inside_len / 2 {
                self.tri(o0, i1, i0);
                self.tri(o0, o1, i1);
            } else {
                self.tri(i0, o0, o1);
                self.tri(i0, o1, i1);
            }
            self.o += 1;
            self.i += 1;
        }
        self.advance_outside();
    }
}
