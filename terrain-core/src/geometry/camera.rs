//! The perspective camera: f64 pose, camera-relative f32 matrices for the GPU.

use glam::{DMat4, DQuat, DVec2, DVec3, DVec4, Mat4, Vec3, dvec3};

use super::frustum::Frustum;

/// A perspective camera in the world frame (x east, y north, z up, metres).
///
/// `orientation` maps *view space* to world space. View space is glam's / wgpu's right-handed
/// convention: the camera looks down view -Z, view +Y is screen up, view +X is screen right.
/// (The papers' OpenGL eye space is the same; only their *world* is y-up, ours is z-up.)
/// The aspect ratio is the viewport's: `viewport_px.x / viewport_px.y`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Eye position, world frame, metres.
    pub position: DVec3,
    /// Rotation from view space to world space.
    pub orientation: DQuat,
    /// Vertical field of view, radians.
    pub fov_y: f64,
    /// Near clipping distance, metres (> 0).
    pub near: f64,
    /// Far clipping distance, metres (> near).
    pub far: f64,
    /// Viewport size in pixels (width, height).
    pub viewport_px: DVec2,
}

impl Camera {
    /// A camera at `position` looking along compass heading `yaw_deg` (0 = north (+y),
    /// 90 = east (+x)) tilted by `pitch_deg` (negative looks down, -90 straight down, where
    /// screen-up then points along the heading). Defaults: 60 degree vertical fov,
    /// 1280 x 720 viewport, near 1 m, far 100 km.
    pub fn from_yaw_pitch(position: DVec3, yaw_deg: f64, pitch_deg: f64) -> Self {
        Self::from_yaw_pitch_roll(position, yaw_deg, pitch_deg, 0.0)
    }

    /// Like [`Camera::from_yaw_pitch`] with a roll about the viewing axis (positive rolls the
    /// image clockwise, i.e. the camera's right side goes down).
    pub fn from_yaw_pitch_roll(
        position: DVec3,
        yaw_deg: f64,
        pitch_deg: f64,
        roll_deg: f64,
    ) -> Self {
        Self {
            position,
            orientation: Self::orientation_from_yaw_pitch_roll(yaw_deg, pitch_deg, roll_deg),
            fov_y: 60f64.to_radians(),
            near: 1.0,
            far: 100_000.0,
            viewport_px: DVec2::new(1280.0, 720.0),
        }
    }

    /// The view-to-world rotation for a compass yaw, pitch and roll in degrees.
    ///
    /// At yaw = pitch = roll = 0 view -Z (forward) is world +y (north), view +Y (up) is world
    /// +z, view +X (right) is world +x: that is a +90 degree turn about x. Pitch adds to it
    /// about the right axis, roll turns about the view axis first, and the compass yaw
    /// (clockwise seen from above) is a turn of -yaw about world +z.
    pub fn orientation_from_yaw_pitch_roll(yaw_deg: f64, pitch_deg: f64, roll_deg: f64) -> DQuat {
        DQuat::from_rotation_z(-yaw_deg.to_radians())
            * DQuat::from_rotation_x((pitch_deg + 90.0).to_radians())
            * DQuat::from_rotation_z(-roll_deg.to_radians())
    }

    /// A camera at `eye` looking at `target` with world +z as up (world +y when looking
    /// straight up or down). Other parameters as in [`Camera::from_yaw_pitch`].
    pub fn look_at(eye: DVec3, target: DVec3) -> Self {
        let f = (target - eye).normalize();
        let up = if f.cross(DVec3::Z).length_squared() < 1e-12 { DVec3::Y } else { DVec3::Z };
        // glam's view rotation maps world -> view; ours is its inverse.
        let view = glam::dcamera::rh::view::look_to_quat(f, up);
        let mut c = Self::from_yaw_pitch(eye, 0.0, 0.0);
        c.orientation = view.conjugate().normalize();
        c
    }

    /// Builder: sets the vertical field of view in degrees.
    pub fn with_fov_y_deg(mut self, fov_deg: f64) -> Self {
        self.fov_y = fov_deg.to_radians();
        self
    }

    /// Builder: sets the near and far distances.
    pub fn with_clip(mut self, near: f64, far: f64) -> Self {
        self.near = near;
        self.far = far;
        self
    }

    /// Builder: sets the viewport in pixels.
    pub fn with_viewport(mut self, width_px: f64, height_px: f64) -> Self {
        self.viewport_px = DVec2::new(width_px, height_px);
        self
    }

    /// This camera with a field of view `k` times wider (vertically, at most 170 degrees; the
    /// aspect kept) and the viewport grown with it, so that [`Camera::lambda`] (pixels per
    /// radian, what every screen-space error multiplies by) is unchanged: the view frustum
    /// extension of the out-of-core paper (Qiu 2013, section 4, Fig. 9: a larger frustum
    /// similar to the view's), selecting what this view would at its edges and beyond them.
    pub fn widened(&self, k: f64) -> Self {
        let fov_y = (self.fov_y * k.max(1.0)).min(170f64.to_radians());
        let grow = (fov_y * 0.5).tan() / (self.fov_y * 0.5).tan();
        Self { fov_y, viewport_px: self.viewport_px * grow, ..*self }
    }

    /// Width over height of the viewport.
    pub fn aspect(&self) -> f64 {
        self.viewport_px.x / self.viewport_px.y
    }

    /// Unit viewing direction in the world.
    pub fn forward(&self) -> DVec3 {
        self.orientation * DVec3::NEG_Z
    }

    /// Unit screen-right direction in the world.
    pub fn right(&self) -> DVec3 {
        self.orientation * DVec3::X
    }

    /// Unit screen-up direction in the world.
    pub fn up(&self) -> DVec3 {
        self.orientation * DVec3::Y
    }

    /// Pixels per radian at the screen centre: `viewport_height_px / (2 tan(fov_y / 2))`.
    /// A length `e` seen at distance `d` square to the view spans about `lambda * e / d`
    /// pixels; every screen-space error metric multiplies by this.
    pub fn lambda(&self) -> f64 {
        self.viewport_px.y / (2.0 * (self.fov_y * 0.5).tan())
    }

    /// Tangent of half the horizontal field of view.
    pub fn tan_half_fov_x(&self) -> f64 {
        self.aspect() * (self.fov_y * 0.5).tan()
    }

    /// f64 view matrix with the camera at the origin (rotation only): world offsets from
    /// the eye to view space.
    pub fn view_relative_f64(&self) -> DMat4 {
        DMat4::from_quat(self.orientation.conjugate())
    }

    /// f64 view matrix in absolute world coordinates (for CPU-side work only: never
    /// send a matrix with a translation of millions of metres to the GPU in f32).
    pub fn view_f64(&self) -> DMat4 {
        self.view_relative_f64() * DMat4::from_translation(-self.position)
    }

    /// f32 view matrix with the camera at the origin: apply it to `p - camera.position`.
    pub fn view_relative(&self) -> Mat4 {
        self.view_relative_f64().as_mat4()
    }

    /// f64 projection to wgpu clip space (right-handed view space, NDC y up, depth in
    /// [0, 1]). This is glam's `camera::rh::proj::directx::perspective`, the former
    /// `perspective_rh` (glam 0.34 moved the projection constructors into modules).
    pub fn projection_f64(&self) -> DMat4 {
        glam::dcamera::rh::proj::directx::perspective(
            self.fov_y,
            self.aspect(),
            self.near,
            self.far,
        )
    }

    /// f32 projection to wgpu clip space (depth in [0, 1]; see [`Camera::projection_f64`]).
    pub fn projection(&self) -> Mat4 {
        glam::camera::rh::proj::directx::perspective(
            self.fov_y as f32,
            self.aspect() as f32,
            self.near as f32,
            self.far as f32,
        )
    }

    /// f32 `projection * view_relative`: maps `p - camera.position` to clip space.
    pub fn view_proj_relative(&self) -> Mat4 {
        (self.projection_f64() * self.view_relative_f64()).as_mat4()
    }

    /// f32 model-view matrix for vertices stored as f32 offsets from the f64 `anchor`:
    /// the translation `anchor - position` is taken in f64 first, so it is small and exact.
    pub fn view_for_anchor(&self, anchor: DVec3) -> Mat4 {
        (self.view_relative_f64() * DMat4::from_translation(anchor - self.position)).as_mat4()
    }

    /// f32 model-view-projection for vertices stored as f32 offsets from the f64 `anchor`
    /// (camera-relative rendering; see the module docs).
    pub fn view_proj_for_anchor(&self, anchor: DVec3) -> Mat4 {
        (self.projection_f64()
            * self.view_relative_f64()
            * DMat4::from_translation(anchor - self.position))
        .as_mat4()
    }

    /// f32 offset of a world point from an f64 anchor (what a vertex buffer stores).
    pub fn offset_from_anchor(p: DVec3, anchor: DVec3) -> Vec3 {
        (p - anchor).as_vec3()
    }

    /// World point -> view space, f64.
    pub fn world_to_view(&self, p: DVec3) -> DVec3 {
        self.orientation.conjugate() * (p - self.position)
    }

    /// Screen position in pixels of a world point (origin top-left, x right, y down), or
    /// `None` when the point is at or behind the eye plane. Points outside the viewport or
    /// beyond near/far still get coordinates. Computed in f64.
    pub fn project_world(&self, p: DVec3) -> Option<DVec2> {
        let v = self.world_to_view(p);
        let clip = self.projection_f64() * DVec4::new(v.x, v.y, v.z, 1.0);
        if clip.w <= 0.0 {
            return None;
        }
        let ndc = DVec2::new(clip.x / clip.w, clip.y / clip.w);
        Some(DVec2::new(
            (ndc.x + 1.0) * 0.5 * self.viewport_px.x,
            (1.0 - ndc.y) * 0.5 * self.viewport_px.y,
        ))
    }

    /// The eight frustum corners in the world: near plane first, then far plane; within each
    /// plane bottom-left, bottom-right, top-right, top-left (screen directions).
    pub fn frustum_corners(&self) -> [DVec3; 8] {
        let ty = (self.fov_y * 0.5).tan();
        let tx = self.tan_half_fov_x();
        let (f, r, u) = (self.forward(), self.right(), self.up());
        let signs = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)];
        std::array::from_fn(|k| {
            let d = if k < 4 { self.near } else { self.far };
            let (sx, sy) = signs[k % 4];
            self.position + (f + r * (sx * tx) + u * (sy * ty)) * d
        })
    }

    /// The view frustum (six f64 planes in the world frame).
    pub fn frustum(&self) -> Frustum {
        Frustum::from_camera(self)
    }

    /// The world-frame ray through pixel `(x, y)` (top-left origin): unit direction.
    pub fn pixel_ray(&self, px: DVec2) -> DVec3 {
        let ndc_x = px.x / self.viewport_px.x * 2.0 - 1.0;
        let ndc_y = 1.0 - px.y / self.viewport_px.y * 2.0;
        let ty = (self.fov_y * 0.5).tan();
        let d = dvec3(ndc_x * self.tan_half_fov_x(), ndc_y * ty, -1.0);
        (self.orientation * d).normalize()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: DVec3, b: DVec3, eps: f64) -> bool {
        (a - b).length() < eps
    }

    #[test]
    fn yaw_pitch_directions() {
        let c = Camera::from_yaw_pitch(DVec3::ZERO, 0.0, 0.0);
        assert!(close(c.forward(), DVec3::Y, 1e-12));
        assert!(close(c.up(), DVec3::Z, 1e-12));
        assert!(close(c.right(), DVec3::X, 1e-12));
        let c = Camera::from_yaw_pitch(DVec3::ZERO, 90.0, 0.0);
        assert!(close(c.forward(), DVec3::X, 1e-12));
        assert!(close(c.right(), DVec3::NEG_Y, 1e-12));
        let c = Camera::from_yaw_pitch(DVec3::ZERO, 180.0, -30.0);
        let s = 30f64.to_radians();
        assert!(close(c.forward(), dvec3(0.0, -s.cos(), -s.sin()), 1e-12));
        let c = Camera::from_yaw_pitch(DVec3::ZERO, 0.0, -90.0);
        assert!(close(c.forward(), DVec3::NEG_Z, 1e-12));
        assert!(close(c.up(), DVec3::Y, 1e-12));
        let c = Camera::from_yaw_pitch_roll(DVec3::ZERO, 0.0, 0.0, 90.0);
        assert!(close(c.forward(), DVec3::Y, 1e-12));
        assert!(close(c.right(), DVec3::NEG_Z, 1e-12));
    }

    #[test]
    fn look_at_matches_yaw_pitch() {
        let eye = dvec3(10.0, 20.0, 30.0);
        let a = Camera::look_at(eye, eye + dvec3(1.0, 0.0, -1.0));
        let b = Camera::from_yaw_pitch(eye, 90.0, -45.0);
        assert!(close(a.forward(), b.forward(), 1e-12));
        assert!(close(a.up(), b.up(), 1e-12));
        let down = Camera::look_at(eye, eye - DVec3::Z);
        assert!(close(down.forward(), DVec3::NEG_Z, 1e-12));
    }

    #[test]
    fn lambda_and_projection() {
        let c = Camera::from_yaw_pitch(DVec3::ZERO, 0.0, 0.0)
            .with_fov_y_deg(90.0)
            .with_viewport(800.0, 600.0);
        assert!((c.lambda() - 300.0).abs() < 1e-9);
        // The point straight ahead lands at the viewport centre.
        let p = c.project_world(dvec3(0.0, 100.0, 0.0)).unwrap();
        assert!((p - DVec2::new(400.0, 300.0)).length() < 1e-9);
        // 45 degrees up (the top edge with a 90 degree fov) lands at y = 0.
        let p = c.project_world(dvec3(0.0, 100.0, 100.0)).unwrap();
        assert!((p.y).abs() < 1e-9, "{p}");
        // East is screen right.
        assert!(c.project_world(dvec3(10.0, 100.0, 0.0)).unwrap().x > 400.0);
        // Behind the camera: no projection.
        assert!(c.project_world(dvec3(0.0, -1.0, 0.0)).is_none());
        // A small length at distance d spans lambda * e / d pixels at the centre.
        let a = c.project_world(dvec3(0.0, 1000.0, 0.0)).unwrap();
        let b = c.project_world(dvec3(0.0, 1000.0, 1.0)).unwrap();
        assert!(((a.y - b.y) - c.lambda() / 1000.0).abs() < 1e-6);
        // wgpu depth range: near -> 0, far -> 1.
        let m = c.projection_f64() * c.view_relative_f64();
        let n = m * DVec4::new(0.0, c.near, 0.0, 1.0);
        let f = m * DVec4::new(0.0, c.far, 0.0, 1.0);
        assert!((n.z / n.w).abs() < 1e-9 && (f.z / f.w - 1.0).abs() < 1e-9);
        // The f32 and f64 matrices agree.
        let d = (c.projection().as_dmat4() - c.projection_f64()).to_cols_array();
        assert!(d.iter().all(|x| x.abs() < 1e-4));
    }

    #[test]
    fn a_widened_camera_sees_more_at_the_same_pixels_per_radian() {
        let c = Camera::from_yaw_pitch(DVec3::new(0.0, 0.0, 100.0), 30.0, -10.0)
            .with_viewport(1280.0, 720.0);
        let w = c.widened(1.3);
        assert!((w.fov_y - 1.3 * c.fov_y).abs() < 1e-12);
        assert!((w.lambda() - c.lambda()).abs() < 1e-9 * c.lambda());
        assert!((w.aspect() - c.aspect()).abs() < 1e-12);
        assert!((w.tan_half_fov_x() / c.tan_half_fov_x() - w.viewport_px.x / 1280.0).abs() < 1e-12);
        assert_eq!((w.position, w.orientation), (c.position, c.orientation));
        // Capped at 170 degrees; never narrower.
        assert!((c.widened(100.0).fov_y - 170f64.to_radians()).abs() < 1e-12);
        assert_eq!(c.widened(0.5), c);
    }

    #[test]
    fn pixel_ray_round_trips() {
        let c = Camera::from_yaw_pitch(dvec3(5.0, 6.0, 100.0), 30.0, -20.0);
        for px in [DVec2::new(0.0, 0.0), DVec2::new(640.0, 360.0), DVec2::new(1000.0, 700.0)] {
            let p = c.position + c.pixel_ray(px) * 500.0;
            assert!((c.project_world(p).unwrap() - px).length() < 1e-6);
        }
        let k = c.frustum_corners();
        assert!((c.project_world(k[4]).unwrap() - DVec2::new(0.0, 720.0)).length() < 1e-6);
        assert!((c.project_world(k[2]).unwrap() - DVec2::new(1280.0, 0.0)).length() < 1e-6);
    }
}
