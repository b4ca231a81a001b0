//! The viewer's camera: fly mode (mouse look while a button is held, WASD to move, Q/E down and
//! up, speed on the mouse wheel) and orbit mode (the same keys and drag turn, tilt and zoom
//! around a point on the ground). The pose is `terrain render --camera`'s `x,y,z,yaw,pitch`
//! (compass yaw, pitch negative down), and [`ViewCamera::camera`] builds the engine's camera
//! exactly as `terrain render` does, so a viewer frame and a render of the same pose agree.
//! The eye never goes below the ground: after every move it is lifted to the terrain height
//! under it (bilinear, [`Ground`]) plus a clearance.

use glam::DVec3;
use terrain_core::Heightmap;
use terrain_core::geometry::Camera;

/// Degrees of yaw or pitch per pixel of mouse drag.
pub(crate) const LOOK_DEG_PER_PX: f64 = 0.2;
/// Speed factor per wheel step (fly) and distance factor per step (orbit, inverted).
const WHEEL_FACTOR: f64 = 1.25;
/// Pitch is kept within this many degrees of straight up or down.
const MAX_PITCH: f64 = 89.0;

/// Terrain heights under the camera (world metres).
pub(crate) trait Ground {
    /// The ground height at `(x, y)` (clamped to the terrain's extent).
    fn height(&self, x: f64, y: f64) -> f64;
}

impl Ground for Heightmap {
    fn height(&self, x: f64, y: f64) -> f64 {
        f64::from(self.sample_world(glam::dvec2(x, y)))
    }
}

/// Fly or orbit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Mode {
    /// Free flight.
    Fly,
    /// Around [`ViewCamera::target`].
    Orbit,
}

/// The movement keys held this frame, each -1, 0 or 1.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Motion {
    /// W (+1) / S (-1).
    pub forward: f64,
    /// D (+1) / A (-1).
    pub right: f64,
    /// E (+1) / Q (-1).
    pub up: f64,
}

/// The viewer's camera state.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ViewCamera {
    /// Eye, world metres.
    pub position: DVec3,
    /// Compass yaw, degrees (0 north, 90 east).
    pub yaw: f64,
    /// Pitch, degrees (negative looks down).
    pub pitch: f64,
    /// Fly speed, metres per second.
    pub speed: f64,
    /// Fly or orbit.
    pub mode: Mode,
    /// The orbit's centre.
    pub target: DVec3,
    /// Metres the eye keeps above the ground.
    pub clearance: f64,
}

impl ViewCamera {
    /// A camera at `position` looking along `yaw`, `pitch`, flying at `speed` m/s.
    pub(crate) fn new(position: DVec3, yaw: f64, pitch: f64, speed: f64, clearance: f64) -> Self {
        Self { position, yaw, pitch, speed, mode: Mode::Fly, target: position, clearance }
    }

    /// The engine's camera for this pose, as `terrain render --camera` builds it (the clip
    /// range is the caller's: it depends on the terrain).
    pub(crate) fn camera(&self, fov_deg: f64, (w, h): (u32, u32), clip: (f64, f64)) -> Camera {
        Camera::from_yaw_pitch(self.position, self.yaw, self.pitch)
            .with_fov_y_deg(fov_deg)
            .with_viewport(f64::from(w), f64::from(h))
            .with_clip(clip.0, clip.1)
    }

    /// The pose as `--camera` spells it (`{}` of f64 reads back to the same bits).
    pub(crate) fn spec(&self) -> String {
        let p = self.position;
        format!("{},{},{},{},{}", p.x, p.y, p.z, self.yaw, self.pitch)
    }

    fn axes(&self) -> (DVec3, DVec3) {
        let c = Camera::from_yaw_pitch(self.position, self.yaw, self.pitch);
        (c.forward(), c.right())
    }

    /// Mouse look by a drag of `(dx, dy)` pixels: fly mode turns the eye, orbit mode turns
    /// around the target.
    pub(crate) fn look(&mut self, dx: f64, dy: f64, ground: &dyn Ground) {
        self.yaw = (self.yaw + dx * LOOK_DEG_PER_PX).rem_euclid(360.0);
        self.pitch = (self.pitch - dy * LOOK_DEG_PER_PX).clamp(-MAX_PITCH, MAX_PITCH);
        if self.mode == Mode::Orbit {
            self.place_on_orbit(self.position.distance(self.target));
        }
        self.keep_above(ground);
    }

    /// `steps` wheel steps: faster (fly) or closer (orbit) for positive steps.
    pub(crate) fn wheel(&mut self, steps: f64, ground: &dyn Ground) {
        match self.mode {
            Mode::Fly => self.speed = (self.speed * WHEEL_FACTOR.powf(steps)).clamp(0.01, 1e7),
            Mode::Orbit => {
                let d = self.position.distance(self.target) / WHEEL_FACTOR.powf(steps);
                self.place_on_orbit(d.max(1.0));
            }
        }
        self.keep_above(ground);
    }

    /// Moves by the held keys for `dt` seconds. Orbit: W/S zoom, A/D turn, Q/E tilt.
    pub(crate) fn step(&mut self, m: Motion, dt: f64, ground: &dyn Ground) {
        if m == Motion::default() {
            return;
        }
        match self.mode {
            Mode::Fly => {
                let (forward, right) = self.axes();
                let v = forward * m.forward + right * m.right + DVec3::Z * m.up;
                self.position += v * self.speed * dt;
            }
            Mode::Orbit => {
                // 90 degrees per second of turn and tilt; zoom by the speed.
                self.yaw = (self.yaw + 90.0 * dt * m.right).rem_euclid(360.0);
                self.pitch = (self.pitch - 90.0 * dt * m.up).clamp(-MAX_PITCH, MAX_PITCH);
                let d = self.position.distance(self.target) - self.speed * dt * m.forward;
                self.place_on_orbit(d.max(1.0));
            }
        }
        self.keep_above(ground);
    }

    /// Fly <-> orbit. Orbit centres on the ground point the eye looks at (or a point at
    /// `fallback` metres ahead when the view ray meets no ground within `fallback * 4`).
    pub(crate) fn toggle_mode(&mut self, ground: &dyn Ground, fallback: f64) {
        self.mode = match self.mode {
            Mode::Fly => {
                let (forward, _) = self.axes();
                let hit = ray_hit(self.position, forward, ground, fallback * 4.0);
                self.target = hit.unwrap_or(self.position + forward * fallback);
                Mode::Orbit
            }
            Mode::Orbit => Mode::Fly,
        };
    }

    fn place_on_orbit(&mut self, distance: f64) {
        let (forward, _) = self.axes();
        self.position = self.target - forward * distance;
    }

    /// Lifts the eye to the ground plus the clearance where it is lower.
    pub(crate) fn keep_above(&mut self, ground: &dyn Ground) {
        let floor = ground.height(self.position.x, self.position.y) + self.clearance;
        if self.position.z < floor {
            self.position.z = floor;
        }
    }
}

/// Where the ray from `eye` along `dir` first goes below the ground, within `max` metres
/// (marched in 512 steps, then bisected).
fn ray_hit(eye: DVec3, dir: DVec3, ground: &dyn Ground, max: f64) -> Option<DVec3> {
    let below = |p: DVec3| p.z <= ground.height(p.x, p.y);
    let n = 512;
    let mut prev = 0.0;
    for k in 1..=n {
        let t = max * f64::from(k) / f64::from(n);
        if below(eye + dir * t) {
            let (mut lo, mut hi) = (prev, t);
            for _ in 0..30 {
                let mid = 0.5 * (lo + hi);
                if below(eye + dir * mid) { hi = mid } else { lo = mid }
            }
            return Some(eye + dir * hi);
        }
        prev = t;
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plane tilted up to the east: z = x / 10.
    struct Ramp;
    impl Ground for Ramp {
        fn height(&self, x: f64, _y: f64) -> f64 {
            x / 10.0
        }
    }

    fn cam() -> ViewCamera {
        ViewCamera::new(DVec3::new(0.0, 0.0, 100.0), 0.0, 0.0, 10.0, 5.0)
    }

    #[test]
    fn fly_moves_along_the_view_and_never_below_the_ground() {
        let mut c = cam();
        // North for one second at 10 m/s.
        c.step(Motion { forward: 1.0, ..Motion::default() }, 1.0, &Ramp);
        assert!((c.position - DVec3::new(0.0, 10.0, 100.0)).length() < 1e-9, "{:?}", c.position);
        // Down far below the ground: stopped at ground + clearance.
        c.step(Motion { up: -1.0, ..Motion::default() }, 100.0, &Ramp);
        assert_eq!(c.position.z, 5.0);
        // East up the ramp: lifted with it.
        c.step(Motion { right: 1.0, ..Motion::default() }, 50.0, &Ramp);
        assert!((c.position.x - 500.0).abs() < 1e-9);
        assert!((c.position.z - 55.0).abs() < 1e-9, "{}", c.position.z);
    }

    #[test]
    fn look_and_wheel_change_the_pose_and_speed() {
        let mut c = cam();
        c.look(100.0, 50.0, &Ramp);
        assert!((c.yaw - 20.0).abs() < 1e-12 && (c.pitch + 10.0).abs() < 1e-12);
        c.look(0.0, 10_000.0, &Ramp);
        assert_eq!(c.pitch, -MAX_PITCH);
        c.wheel(2.0, &Ramp);
        assert!((c.speed - 15.625).abs() < 1e-9);
    }

    #[test]
    fn orbit_keeps_its_centre_and_distance_while_turning() {
        let mut c = ViewCamera::new(DVec3::new(0.0, 0.0, 100.0), 0.0, -45.0, 10.0, 1.0);
        c.toggle_mode(&Ramp, 1000.0);
        assert_eq!(c.mode, Mode::Orbit);
        // The centre is on the ground, straight ahead.
        assert!((c.target.z - Ramp.height(c.target.x, c.target.y)).abs() < 1e-3);
        assert!(c.target.y > 0.0);
        let d = c.position.distance(c.target);
        c.look(450.0, 0.0, &Ramp);
        assert!((c.position.distance(c.target) - d).abs() < 1e-6);
        assert!((c.yaw - 90.0).abs() < 1e-9);
        // W zooms in.
        c.step(Motion { forward: 1.0, ..Motion::default() }, 1.0, &Ramp);
        assert!((c.position.distance(c.target) - (d - 10.0)).abs() < 1e-6);
        c.toggle_mode(&Ramp, 1000.0);
        assert_eq!(c.mode, Mode::Fly);
    }

    #[test]
    fn the_spec_reads_back_as_render_camera() {
        let c = ViewCamera::new(DVec3::new(0.1, -2.0 / 3.0, 1e7 / 7.0), 33.3, -12.25, 1.0, 1.0);
        let spec = terrain_app::camera::parse(&c.spec(), None).unwrap();
        let terrain_app::camera::Aim::YawPitch { yaw, pitch } = spec.aim else {
            panic!("a yaw/pitch camera read back as {:?}", spec.aim)
        };
        let terrain_app::camera::Horizontal::World(p) = spec.eye.horizontal else {
            panic!("a world camera read back as {:?}", spec.eye.horizontal)
        };
        let Some(terrain_app::camera::Height::Absolute(z)) = spec.eye.height else {
            panic!("an absolute height read back as {:?}", spec.eye.height)
        };
        assert_eq!((p.extend(z), yaw, pitch), (c.position, c.yaw, c.pitch));
    }
}
