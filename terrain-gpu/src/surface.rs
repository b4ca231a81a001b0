//! The CPU reference of the surface the renderer draws: where a tessellated domain point of a
//! [`DrawPatch`] lands in the world, and the shading normal there. `render/terrain.wgsl`
//! repeats these functions operation for operation in f32 (`grid_of`, `surface_at`,
//! `normal_at`); change both together.
//!
//! The surface is the bilinear interpolation of the heightmap's samples (the same formula as
//! [`terrain_core::Heightmap::sample_grid`]). A domain point `(u, v)` of a patch with rect `[x0, y0, x1, y1]`
//! sits at grid coordinates `(x0 + u (x1 - x0), y0 + v (y1 - y0))`, computed in f32 so the
//! GPU's arithmetic is reproduced: two patches sharing an edge compute bit-identical grid
//! coordinates there, because the edge's coordinate is an integer (`u = 1` on one side,
//! `u = 0` on the other) and the coordinate along the edge comes from the same `v`.
//!
//! Normals come from central differences of the samples (one-sided at the grid's border),
//! interpolated bilinearly between the four samples around the point: the shading is that of
//! the full-resolution DEM whatever the tessellation, so level of detail changes geometry but
//! not lighting.
//!
//! Every function reads a [`HeightGrid`]: a whole [`terrain_core::Heightmap`], or the resident
//! pages of [`crate::paged::PagedHeights`] (a sample on no resident page reads as 0, and
//! central differences turn one-sided next to it; see [`crate::paged`]).

use glam::{DVec3, Vec2, Vec3};

pub use crate::paged::HeightGrid;
use crate::render::DrawPatch;

/// Grid coordinates (fractional samples, f32 as on the GPU) of domain point `uv` of `patch`.
pub fn grid_coords(patch: &DrawPatch, uv: [f32; 2]) -> Vec2 {
    let [x0, y0, x1, y1] = patch.rect;
    let lo = Vec2::new(x0 as f32, y0 as f32);
    let size = Vec2::new((x1 - x0) as f32, (y1 - y0) as f32);
    lo + Vec2::from(uv) * size
}

/// The height of sample `(i, j)` as the shader reads it: 0 where it is on no resident page.
fn height_sample<G: HeightGrid + ?Sized>(hm: &G, i: u32, j: u32) -> f32 {
    hm.sample(i, j).unwrap_or(0.0)
}

/// The cell and the fractions inside it of grid coordinates `g`, clamped to the grid: the
/// first step of every lookup, shared by positions and normals.
fn cell_of<G: HeightGrid + ?Sized>(hm: &G, g: Vec2) -> ([u32; 2], [u32; 2], Vec2) {
    let [w, h] = hm.size();
    let gmax = Vec2::new((w - 1) as f32, (h - 1) as f32);
    let g = g.clamp(Vec2::ZERO, gmax);
    let cell = g.floor();
    let f = g - cell;
    let i0 = [cell.x as u32, cell.y as u32];
    let i1 = [(i0[0] + 1).min(w - 1), (i0[1] + 1).min(h - 1)];
    (i0, i1, f)
}

/// Bilinear height at grid coordinates `g` (clamped to the grid), in f32 as on the GPU.
pub fn height_at<G: HeightGrid + ?Sized>(hm: &G, g: Vec2) -> f32 {
    let (i0, i1, f) = cell_of(hm, g);
    let h00 = height_sample(hm, i0[0], i0[1]);
    let h10 = height_sample(hm, i1[0], i0[1]);
    let h01 = height_sample(hm, i0[0], i1[1]);
    let h11 = height_sample(hm, i1[0], i1[1]);
    let a = h00 + (h10 - h00) * f.x;
    let b = h01 + (h11 - h01) * f.x;
    a + (b - a) * f.y
}

/// World position (metres, f64) of domain point `uv` of `patch`: what the vertex stage
/// computes, relative to its anchor.
pub fn vertex_position<G: HeightGrid + ?Sized>(hm: &G, patch: &DrawPatch, uv: [f32; 2]) -> DVec3 {
    let g = grid_coords(patch, uv);
    surface_position(hm, g)
}

/// World position (metres, f64) of the surface at grid coordinates `g` (clamped to the grid).
pub fn surface_position<G: HeightGrid + ?Sized>(hm: &G, g: Vec2) -> DVec3 {
    position_at_height(hm, g, height_at(hm, g))
}

/// World position (metres, f64) of a vertex at grid coordinates `g` (clamped to the grid) drawn
/// at height `h`: [`surface_position`]'s `x` and `y` (the shader's `plane_at`), with a given
/// height (extra triangles with their own heights, the shader's `vs_explicit`).
pub fn position_at_height<G: HeightGrid + ?Sized>(hm: &G, g: Vec2, h: f32) -> DVec3 {
    let (i0, _, f) = cell_of(hm, g);
    let (origin, spacing) = hm.frame();
    let x = origin.x + (f64::from(i0[0]) + f64::from(f.x)) * spacing.x;
    let y = origin.y + (f64::from(i0[1]) + f64::from(f.y)) * spacing.y;
    DVec3::new(x, y, f64::from(h))
}

/// A sample of the normals' stencil: `None` outside the grid (the differences turn one-sided
/// at the border) and on no resident page.
fn stencil<G: HeightGrid + ?Sized>(hm: &G, i: i64, j: i64) -> Option<f32> {
    let [w, h] = hm.size();
    if i < 0 || j < 0 || i >= i64::from(w) || j >= i64::from(h) {
        return None;
    }
    hm.sample(i as u32, j as u32)
}

/// The central difference across a sample of height `c` from `a` (before it) to `b` (after
/// it), one-sided where one of them is `None`, per metre of `spacing`; f32 as on the GPU.
fn difference(a: Option<f32>, c: f32, b: Option<f32>, spacing: f32) -> f32 {
    let n = u32::from(a.is_some()) + u32::from(b.is_some());
    (b.unwrap_or(c) - a.unwrap_or(c)) / (n.max(1) as f32 * spacing)
}

/// Unit normal (world frame, z up) at grid coordinates `g`: the bilinear blend of the
/// central-difference gradients (one-sided at the border and next to a sample on no resident
/// page) at the four samples around `g`. The four gradients share their samples: rows `j` and
/// `j + 1` at columns `i - 1 ..= i + 2`, and columns `i` and `i + 1` at rows `j - 1` and `j + 2`,
/// 12 reads (the shader's lookups) instead of 4 x 5. At the grid's last column (row) the
/// corners `i + 1` (`j + 1`) lie outside it and their gradients are weighted 0 (the fraction
/// there is 0).
pub fn normal_at<G: HeightGrid + ?Sized>(hm: &G, g: Vec2) -> Vec3 {
    let (i0, _, f) = cell_of(hm, g);
    let (i, j) = (i64::from(i0[0]), i64::from(i0[1]));
    let at = |di: i64, dj: i64| stencil(hm, i + di, j + dj);
    let [a0, a1, a2, a3] = [at(-1, 0), at(0, 0), at(1, 0), at(2, 0)];
    let [b0, b1, b2, b3] = [at(-1, 1), at(0, 1), at(1, 1), at(2, 1)];
    let [d0, d1, u0, u1] = [at(0, -1), at(1, -1), at(0, 2), at(1, 2)];
    let s = hm.frame().1.as_vec2();
    // The centre's height as the shader reads it: 0 on no resident page.
    let h = |x: Option<f32>| x.unwrap_or(0.0);
    let g00 = Vec2::new(difference(a0, h(a1), a2, s.x), difference(d0, h(a1), b1, s.y));
    let g10 = Vec2::new(difference(a1, h(a2), a3, s.x), difference(d1, h(a2), b2, s.y));
    let g01 = Vec2::new(difference(b0, h(b1), b2, s.x), difference(a1, h(b1), u0, s.y));
    let g11 = Vec2::new(difference(b1, h(b2), b3, s.x), difference(a2, h(b2), u1, s.y));
    let a = g00 + (g10 - g00) * f.x;
    let b = g01 + (g11 - g01) * f.x;
    let grad = a + (b - a) * f.y;
    Vec3::new(-grad.x, -grad.y, 1.0).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tess::PatchFactors;
    use terrain_core::Heightmap;
    use terrain_core::synth::{HardCase, default_terrain};

    #[test]
    fn positions_follow_the_grid_convention_and_sample_grid() {
        let hm = HardCase::HugeOrigin.build();
        let patch = DrawPatch { rect: [32, 64, 48, 80], factors: PatchFactors::uniform(16.0) };
        let origin = hm.georef().world_origin;
        // Corner (0, 0) is sample (32, 64): east of the origin by 32 dx, north by 64 dy.
        let p = vertex_position(&hm, &patch, [0.0, 0.0]);
        assert_eq!(p.x, origin.x + 320.0);
        assert_eq!(p.y, origin.y + 640.0);
        assert_eq!(p.z, f64::from(hm.get(32, 64)));
        let p = vertex_position(&hm, &patch, [1.0, 1.0]);
        assert_eq!(p.z, f64::from(hm.get(48, 80)));
        for uv in [[0.25, 0.5], [0.3, 0.9], [0.77, 0.01]] {
            let g = grid_coords(&patch, uv);
            let p = vertex_position(&hm, &patch, uv);
            let want = hm.sample_grid(f64::from(g.x), f64::from(g.y));
            assert!((p.z - f64::from(want)).abs() < 1e-3, "{uv:?}: {} vs {want}", p.z);
        }
    }

    #[test]
    fn shared_edges_are_bit_identical() {
        let hm = default_terrain();
        let a = DrawPatch { rect: [0, 0, 16, 16], factors: PatchFactors::uniform(5.0) };
        let b = DrawPatch { rect: [16, 0, 32, 16], factors: PatchFactors::uniform(5.0) };
        for t in [0.0, 0.1, 0.37, 0.5, 0.999] {
            assert_eq!(vertex_position(&hm, &a, [1.0, t]), vertex_position(&hm, &b, [0.0, t]));
        }
    }

    #[test]
    fn normals_of_a_plane_and_a_cliff() {
        let flat = HardCase::Flat.build();
        assert_eq!(normal_at(&flat, Vec2::new(10.3, 20.7)), Vec3::Z);
        // A ramp rising 2 m per 10 m eastwards: normal (-0.2, 0, 1) normalised, borders included.
        let ramp =
            Heightmap::from_fn(9, 9, terrain_core::Georef::local(10.0), |i, _| 2.0 * i as f32)
                .unwrap();
        let want = Vec3::new(-0.2, 0.0, 1.0).normalize();
        for g in [Vec2::new(0.0, 0.0), Vec2::new(3.5, 4.25), Vec2::new(8.0, 8.0)] {
            assert!((normal_at(&ramp, g) - want).length() < 1e-6, "{g}");
        }
        let cliff = HardCase::Cliff.build();
        let n = normal_at(&cliff, Vec2::new(HardCase::CLIFF_COLUMN as f32 - 0.5, 10.0));
        assert!(n.x < -0.5, "the cliff rises eastwards: {n}");
    }
}
