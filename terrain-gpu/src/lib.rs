//! The wgpu renderer: device selection (Vulkan first, then GL; software adapters such as
//! lavapipe and llvmpipe included), emulated quad-domain tessellation with fractional-even
//! spacing (WGSL has no tessellation stages), geomorphing in the vertex stage and the DSS
//! paper's stitching strips.
//!
//! **Boundary:** depends on `terrain-core` only; with `terrain-app`, the only crate that may
//! depend on wgpu. Every GPU computation has one CPU reference here, and tests compare the
//! GPU's read-back output with it. Shaders are `.wgsl` files beside the module that drives them.
//!
//! This crate is filled by the renderer issue; it holds no code before it.
