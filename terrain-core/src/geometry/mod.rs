//! Geometry in the world frame: axis-aligned boxes, the camera, the view frustum, and the
//! out-of-core paper's projected view triangle on the ground plane, and what a camera sees of
//! a heightmap (image coverage by ray marching, the default framing that fills the image).
//!
//! World frame (see the crate docs): right-handed, x east, y north, z up, metres, f64.
//! The papers use OpenGL's y-up convention; every conversion is stated where it happens.
//!
//! Camera-relative rendering: positions stay f64 on the CPU. What goes to the GPU is an f32
//! vertex *offset* from an f64 anchor (a tile's centre, say) and an f32 matrix built from
//! `anchor - camera.position` computed in f64 ([`Camera::view_proj_for_anchor`]), so f32
//! only ever holds small numbers and stays millimetre-exact far from the world origin.

mod aabb;
mod camera;
mod frustum;
mod ground;
mod view;

pub use aabb::Aabb;
pub use camera::Camera;
pub use frustum::{Classification, Frustum, Plane};
pub use ground::{GroundRegion, circle_vs_region, project_view_to_ground};
pub use view::{
    FILL_TARGET, coarse_copy, fill_camera, footprint_share, projected_size_px, ray_hit,
    terrain_box, terrain_coverage,
};
