//! Terrain analysis that decides where detail goes and what can be seen: slope and roughness
//! (the PVPS paper, Zhang 2021, Eq. 5, and its roughness pyramids), local curvature entropy
//! (the entropy paper, Chen 2018, Eq. 1-3), and potential visible patch sets per view cell
//! (the PVPS paper's 2.2-2.3 and the geomorphing article's PVS layers).
//!
//! **Boundary:** depends on `terrain-core` only; no GPU, no files except the PVS bake's own
//! output. Everything here is a pure function of a [`terrain_core::Heightmap`] and a config
//! struct, deterministic, and parallel with rayon where the work is large.
//!
//! This crate is filled by the renderer issue (roughness), the occlusion-culling issue (PVS)
//! and the terrain-features issue (curvature entropy); it holds no code before them.

#![deny(missing_docs)]

pub mod entropy;
pub mod pvs;
pub mod roughness;
