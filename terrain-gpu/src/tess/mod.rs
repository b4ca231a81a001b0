//! Emulated quad-domain tessellation with fractional-even spacing: a CPU reference
//! ([`reference`](mod@reference)) and a compute-shader twin ([`gpu`], `tessellate.wgsl`) that must agree.
//!
//! # Why a compute pass, and how it is laid out
//!
//! WGSL has no hull/domain stages, so the fixed-function tessellator is emulated in compute.
//! We chose *compute emission into storage buffers plus one indexed indirect draw* over pure
//! vertex pulling (decoding `(patch, vertex)` from `vertex_index` in the vertex shader):
//!
//! - The tessellator's stitching is sequential per band (it walks two rows in ruler order), so
//!   decoding the `k`-th triangle in closed form inside a vertex shader would repeat that walk
//!   for every vertex; emitting once and drawing many times (shadow passes, several views) is
//!   cheaper.
//! - The output is exactly the reference's points and indices, so a read-back compares with
//!   [`tessellate`] point by point and index by index.
//! - Three passes, all deterministic (no atomics): `count` (one invocation per patch, closed
//!   form), `scan` (one workgroup: exclusive prefix sums give every patch its point and index
//!   ranges, and the total goes into the indirect draw arguments), `emit` (one invocation per
//!   patch writes its points and indices). Patch order in the buffers is input order.
//!
//! Each emitted point is a [`gpu::GpuDomainPoint`]: `(u, v)` plus the patch index, so the
//! renderer's vertex shader pulls the patch's corners (and morphs) from the point alone.
//!
//! # Factors
//!
//! [`PatchFactors::outer`] follows Vulkan's (and D3D11's `SV_TessFactor`) order for quads:
//! `outer[0]` is the `u = 0` edge, `outer[1]` the `v = 0` edge, `outer[2]` the `u = 1` edge and
//! `outer[3]` the `v = 1` edge. `inner[0]` subdivides along `u` (the rows parallel to `v = 0`),
//! `inner[1]` along `v`. Fractional-even spacing clamps every factor to `[2, 64]` first, so a
//! factor of 1 (or anything below 2, or NaN) tessellates like 2: two segments per edge. A patch
//! whose outer factor is `<= 0` or NaN is culled (no output), as the specifications say.
//!
//! Crack-freedom rests on one property, which the tests check: the points on an outer edge
//! depend only on that edge's factor (bit for bit), so two patches that share an edge and
//! agree on its factor emit the same edge vertices.

pub mod gpu;
pub mod reference;

pub use gpu::{
    DrawIndexedArgs, GpuDomainPoint, GpuPatchFactors, GpuTessOutput, GpuTessellator, PatchRange,
    TessReadBack,
};
pub use reference::{EdgeSpacing, QuadLayout};

/// The tessellation factors of one quad patch, as a hull shader would output them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PatchFactors {
    /// Inner factors: `[u, v]`.
    pub inner: [f32; 2],
    /// Outer factors: `[u = 0, v = 0, u = 1, v = 1]` edges (Vulkan's order).
    pub outer: [f32; 4],
}

impl PatchFactors {
    /// Every factor the same.
    pub fn uniform(factor: f32) -> Self {
        Self { inner: [factor; 2], outer: [factor; 4] }
    }
}

/// A tessellated patch: domain points in `[0, 1]^2` and a triangle list indexing them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TessMesh {
    /// Domain points `(u, v)`.
    pub points: Vec<[f32; 2]>,
    /// Triangle list; every triangle has non-negative signed area in the `(u, v)` plane.
    pub indices: Vec<u32>,
}

impl TessMesh {
    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// Twice the signed area of triangle `t` in the `(u, v)` plane, in `f64`.
    pub fn doubled_area(&self, t: usize) -> f64 {
        let p = |k: usize| {
            let [u, v] = self.points[self.indices[3 * t + k] as usize];
            (f64::from(u), f64::from(v))
        };
        let (a, b, c) = (p(0), p(1), p(2));
        (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0)
    }

    /// Number of triangles with positive area (the others are degenerate).
    pub fn non_degenerate_triangle_count(&self) -> usize {
        (0..self.triangle_count()).filter(|&t| self.doubled_area(t) > 0.0).count()
    }
}

/// Tessellates one patch on the CPU: the reference the GPU path is tested against.
pub fn tessellate(factors: &PatchFactors) -> TessMesh {
    let layout = QuadLayout::new(factors);
    let mut mesh = TessMesh {
        points: Vec::with_capacity(layout.point_count() as usize),
        indices: Vec::with_capacity(3 * layout.triangle_count() as usize),
    };
    layout.generate_points(&mut mesh.points);
    layout.generate_triangles(&mut mesh.indices);
    mesh
}

#[cfg(test)]
mod gpu_tests;
#[cfg(test)]
mod tests;
