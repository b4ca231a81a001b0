//! Camera flights: timed keyframes in a JSON file, smooth interpolation, deterministic playback
//! at a fixed frame rate, so every LOD method is measured along exactly the same cameras.
//!
//! # File format
//! ```json
//! { "name": "pvps_884", "fps": 30, "height_above": "mean",
//!   "keyframes": [
//!     { "t": 0,  "relative": [0.2, 0.2, 0.44], "yaw": 45, "pitch": -20 },
//!     { "t": 30, "relative": [0.5, 0.5, 0.44], "look_at": "peak" },
//!     { "t": 60, "position": [1000.0, 2000.0, 900.0], "yaw": 90, "pitch": -15 } ] }
//! ```
//! - `fps` (> 0) and `t` in seconds; the first keyframe is at `t = 0`, times strictly increase.
//!   A flight has at most [`MAX_FRAMES`] frames (`fps` x the last `t`): every frame's camera
//!   is computed when the flight is placed on a DEM, so an absurd `fps` or end time is refused
//!   when the file is read ([`FlightError::TooManyFrames`]) instead of exhausting memory.
//! - A keyframe's position is exactly one of:
//!   - `"position": [x, y, z]`: world metres (x east, y north, z up);
//!   - `"relative": [u, v, h]`: `u`, `v` fractions of the DEM's extent from its south-west
//!     sample (`x = x0 + u (w - 1) dx`, `y = y0 + v (h - 1) dy`), `h` in units of the DEM's
//!     relief above the flight's `height_above` reference (see below);
//!   - `"peak_relative": [du, dv, h]`: like `relative`, offset from the DEM's highest sample.
//!
//!   So one relative flight file works on every DEM.
//! - `height_above` (flight level, default `"ground"`): `"ground"` (bilinear DEM height below
//!   the keyframe), `"mean"` (mean of the non-void samples) or `"min"`. The relief is
//!   `max - min` of the non-void samples, floored at [`FlightConfig::min_relief_fraction`] of
//!   the larger horizontal extent so a flat DEM still gets a usable height.
//! - The view is `"yaw"` (compass degrees: 0 north, 90 east) and `"pitch"` (degrees, negative
//!   down) or `"look_at"`: `"peak"` (the highest non-void sample), `"center"` (the DEM's centre
//!   on the ground) or `[u, v, h]` (relative, as above). `look_at` wins over yaw/pitch.
//! - Optional `"fov_y_deg"` (default 60) for the whole flight.
//!
//! # Interpolation and playback
//! Frame `k` is at `t = k / fps` exactly, for every `k` with `k / fps < t_last`: a 60 s flight at
//! 30 fps has 1800 frames. Positions follow a centripetal Catmull-Rom spline (alpha = 1/2,
//! Barry-Goldman evaluation) through the keyframes, the ends extended by reflection; within a
//! segment the spline parameter is linear in time. Yaw is unwrapped along the shortest arc
//! between consecutive keyframes, then yaw and pitch follow a uniform Catmull-Rom spline.
//!
//! # Clamping (warnings, not errors)
//! A keyframe outside the DEM's plan extent is moved onto the nearest point of the extent, and
//! one below `ground + clearance` ([`FlightConfig::clearance_m`]) is raised to it; each returns
//! a [`FlightWarning`]. Interpolated frames that dip below the clearance are raised as well and
//! reported once, as [`FlightWarning::FramesRaised`]. Everything is a pure function of the file,
//! the DEM and the config.
//!
//! This and the DEM readers are the only parts of terrain-core that read files
//! ([`FlightSpec::load`]); [`FlightSpec::parse`] takes text.

use std::path::{Path, PathBuf};

use glam::{DVec2, DVec3, dvec2, dvec3};
use serde::Deserialize;

use crate::geometry::Camera;
use crate::heightmap::Heightmap;

/// Why a flight could not be read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FlightError {
    /// The file could not be read (missing, permissions).
    #[error("{}: cannot read the flight file: {cause}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause (in the message; not an error `source`, so an error chain prints it once).
        cause: std::io::Error,
    },
    /// Not valid JSON, or not the flight schema.
    #[error("{}line {line}, column {column}: {message}", path.as_ref().map(|p| format!("{}: ", p.display())).unwrap_or_default())]
    Json {
        /// The file, when read from one.
        path: Option<PathBuf>,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
        /// What the parser said.
        message: String,
    },
    /// A flight needs at least two keyframes.
    #[error("a flight needs at least 2 keyframes, found {count}")]
    TooFewKeyframes {
        /// How many there were.
        count: usize,
    },
    /// The first keyframe is not at `t = 0`.
    #[error("the first keyframe must be at t = 0, found t = {t}")]
    FirstTimeNotZero {
        /// Its time.
        t: f64,
    },
    /// Keyframe times must strictly increase.
    #[error("keyframe {index}: t = {t} does not come after the previous t = {previous}")]
    NonIncreasingTime {
        /// The keyframe (0-based).
        index: usize,
        /// Its time.
        t: f64,
        /// The previous keyframe's time.
        previous: f64,
    },
    /// A number is NaN or infinite, or `fps` is not positive.
    #[error("{field} is not a finite number in range{}: {value}", index.map(|i| format!(" (keyframe {i})")).unwrap_or_default())]
    InvalidNumber {
        /// The keyframe, or `None` for a flight-level field.
        index: Option<usize>,
        /// Which field.
        field: &'static str,
        /// Its value.
        value: f64,
    },
    /// `fps` x the last keyframe's `t` is more than [`MAX_FRAMES`] frames.
    #[error(
        "{}fps = {fps} with the last keyframe at t = {duration} s makes {frames:.3e} frames, more \
         than the {max} a flight may have (about 9 hours at 30 fps); lower \"fps\" or the \
         keyframes' \"t\"",
        path.as_ref().map(|p| format!("{}: ", p.display())).unwrap_or_default()
    )]
    TooManyFrames {
        /// The file, when read from one.
        path: Option<PathBuf>,
        /// Frames per second.
        fps: f64,
        /// The last keyframe's time, seconds.
        duration: f64,
        /// `fps x duration`.
        frames: f64,
        /// [`MAX_FRAMES`].
        max: usize,
    },
    /// A keyframe gives no position or more than one.
    #[error("keyframe {index}: give exactly one of \"position\", \"relative\", \"peak_relative\"")]
    Position {
        /// The keyframe.
        index: usize,
    },
    /// A keyframe gives neither `look_at` nor both `yaw` and `pitch`.
    #[error("keyframe {index}: give \"look_at\" or both \"yaw\" and \"pitch\"")]
    View {
        /// The keyframe.
        index: usize,
    },
    /// `look_at` names an unknown target.
    #[error(
        "keyframe {index}: unknown look_at target {name:?} (use \"peak\", \"center\" or [u, v, h])"
    )]
    Target {
        /// The keyframe.
        index: usize,
        /// The name given.
        name: String,
    },
}

/// Something a flight had to change to be usable on this DEM.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[non_exhaustive]
pub enum FlightWarning {
    /// A keyframe lay outside the DEM's plan extent and was moved onto it.
    MovedInside {
        /// The keyframe.
        index: usize,
        /// Where it was (x, y), metres.
        from: [f64; 2],
        /// Where it is now.
        to: [f64; 2],
    },
    /// A keyframe lay below `ground + clearance` and was raised.
    Raised {
        /// The keyframe.
        index: usize,
        /// Its height before, metres.
        from_z: f64,
        /// Its height now.
        to_z: f64,
    },
    /// Interpolated frames dipped below `ground + clearance` and were raised.
    FramesRaised {
        /// How many frames.
        count: usize,
        /// The largest raise, metres.
        max_raise_m: f64,
    },
}

impl std::fmt::Display for FlightWarning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::MovedInside { index, from, to } => write!(
                f,
                "keyframe {index} was outside the DEM at ({:.1}, {:.1}); moved to ({:.1}, {:.1})",
                from[0], from[1], to[0], to[1]
            ),
            Self::Raised { index, from_z, to_z } => write!(
                f,
                "keyframe {index} was below the terrain clearance at z = {from_z:.1}; raised to {to_z:.1}"
            ),
            Self::FramesRaised { count, max_raise_m } => write!(
                f,
                "{count} interpolated frames dipped below the terrain clearance; raised by up to {max_raise_m:.1} m"
            ),
        }
    }
}

/// What the relative heights `h` are measured from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum HeightRef {
    /// The bilinear DEM height below the keyframe.
    #[default]
    Ground,
    /// The mean of the DEM's non-void samples.
    Mean,
    /// The lowest non-void sample.
    Min,
}

/// Where a keyframe is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum KeyPosition {
    /// World metres.
    World(DVec3),
    /// `[u, v, h]`: fractions of the extent, and relief units above the flight's reference.
    Relative(DVec3),
    /// `[du, dv, h]`: offsets from the highest sample in fractions of the extent, and `h`.
    PeakRelative(DVec3),
}

/// Where a keyframe looks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum KeyView {
    /// Compass yaw and pitch, degrees.
    YawPitch {
        /// 0 north, 90 east.
        yaw: f64,
        /// Negative looks down.
        pitch: f64,
    },
    /// At the highest non-void sample.
    Peak,
    /// At the DEM's centre, on the ground.
    Center,
    /// At a relative point `[u, v, h]` (heights as for [`KeyPosition::Relative`]).
    Relative(DVec3),
}

/// One keyframe as written in the file.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeySpec {
    /// Time, seconds.
    pub t: f64,
    /// Position.
    pub position: KeyPosition,
    /// View direction.
    pub view: KeyView,
}

/// A validated flight file, not yet placed on a DEM.
#[derive(Debug, Clone, PartialEq)]
pub struct FlightSpec {
    /// The flight's name.
    pub name: String,
    /// Frames per second of playback.
    pub fps: f64,
    /// Vertical field of view, degrees.
    pub fov_y_deg: f64,
    /// Reference of relative heights.
    pub height_above: HeightRef,
    /// At least two, times strictly increasing from 0.
    pub keyframes: Vec<KeySpec>,
}

/// How flights are placed on a DEM.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlightConfig {
    /// Minimum eye height above the bilinear terrain, metres. Default 10.
    pub clearance_m: f64,
    /// Relief used for relative heights is at least this fraction of the larger horizontal
    /// extent (flat DEMs). Default 0.02.
    pub min_relief_fraction: f64,
    /// Viewport of the generated cameras, pixels. Default 1280 x 720.
    pub viewport_px: DVec2,
    /// Near and far planes, metres. Default 1 and 1e6 (the whole DEM stays in view depth).
    pub near_far: (f64, f64),
}

impl Default for FlightConfig {
    fn default() -> Self {
        Self {
            clearance_m: 10.0,
            min_relief_fraction: 0.02,
            viewport_px: dvec2(1280.0, 720.0),
            near_far: (1.0, 1.0e6),
        }
    }
}

/// A resolved keyframe: world position and angles.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Keyframe {
    /// Time, seconds.
    pub t: f64,
    /// Eye, world metres.
    pub position: DVec3,
    /// Compass yaw, degrees (unwrapped along the shortest arc from the previous keyframe).
    pub yaw: f64,
    /// Pitch, degrees.
    pub pitch: f64,
}

/// A flight placed on a DEM: keyframes and every frame's camera.
#[derive(Debug, Clone, PartialEq)]
pub struct Flight {
    /// The flight's name.
    pub name: String,
    /// Frames per second.
    pub fps: f64,
    /// Resolved keyframes.
    pub keyframes: Vec<Keyframe>,
    frames: Vec<Camera>,
}

impl Flight {
    /// The camera of every frame: frame `k` at `t = k / fps`.
    pub fn frames(&self) -> &[Camera] {
        &self.frames
    }

    /// Duration in seconds (the last keyframe's time).
    pub fn duration(&self) -> f64 {
        self.keyframes.last().map_or(0.0, |k| k.t)
    }

    /// Time of frame `k`: exactly `k / fps`.
    pub fn frame_time(&self, k: usize) -> f64 {
        k as f64 / self.fps
    }
}

/// Most frames a flight may have: one million, 9.3 hours at 30 fps, about 96 MB of cameras
/// (`Camera` is 12 f64). Far beyond any benchmark flight (the papers' are minutes long), far
/// below what would exhaust memory.
pub const MAX_FRAMES: usize = 1_000_000;

/// Number of frames of a flight of `duration` seconds at `fps`: every `k` with `k / fps <
/// duration` (at least one).
pub fn frame_count(duration: f64, fps: f64) -> usize {
    let n = (duration * fps).ceil() as usize;
    // Guard the rounding of duration * fps: frame k exists iff k / fps < duration.
    let mut n = n.max(1);
    while n > 1 && (n - 1) as f64 / fps >= duration {
        n -= 1;
    }
    while (n as f64) / fps < duration {
        n += 1;
    }
    n
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileFlight {
    name: String,
    fps: f64,
    #[serde(default)]
    fov_y_deg: Option<f64>,
    #[serde(default)]
    height_above: HeightRef,
    keyframes: Vec<FileKey>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileKey {
    t: f64,
    #[serde(default)]
    position: Option<[f64; 3]>,
    #[serde(default)]
    relative: Option<[f64; 3]>,
    #[serde(default)]
    peak_relative: Option<[f64; 3]>,
    #[serde(default)]
    yaw: Option<f64>,
    #[serde(default)]
    pitch: Option<f64>,
    #[serde(default)]
    look_at: Option<FileTarget>,
}

#[derive(Deserialize)]
#[serde(untagged)]
enum FileTarget {
    Name(String),
    Point([f64; 3]),
}

impl FlightSpec {
    /// Reads and validates a flight file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, FlightError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path)
            .map_err(|cause| FlightError::Io { path: path.to_owned(), cause })?;
        Self::parse(&text).map_err(|e| match e {
            FlightError::Json { path: None, line, column, message } => {
                FlightError::Json { path: Some(path.to_owned()), line, column, message }
            }
            FlightError::TooManyFrames { path: None, fps, duration, frames, max } => {
                FlightError::TooManyFrames {
                    path: Some(path.to_owned()),
                    fps,
                    duration,
                    frames,
                    max,
                }
            }
            e => e,
        })
    }

    /// Parses and validates flight JSON.
    pub fn parse(text: &str) -> Result<Self, FlightError> {
        let f: FileFlight = serde_json::from_str(text).map_err(|e| FlightError::Json {
            path: None,
            line: e.line(),
            column: e.column(),
            message: e.to_string(),
        })?;
        let mut keyframes = Vec::with_capacity(f.keyframes.len());
        for (index, k) in f.keyframes.into_iter().enumerate() {
            let position = match (k.position, k.relative, k.peak_relative) {
                (Some(p), None, None) => KeyPosition::World(DVec3::from(p)),
                (None, Some(p), None) => KeyPosition::Relative(DVec3::from(p)),
                (None, None, Some(p)) => KeyPosition::PeakRelative(DVec3::from(p)),
                _ => return Err(FlightError::Position { index }),
            };
            let view = match (k.look_at, k.yaw, k.pitch) {
                (Some(FileTarget::Name(n)), _, _) => match n.as_str() {
                    "peak" => KeyView::Peak,
                    "center" | "centre" => KeyView::Center,
                    _ => return Err(FlightError::Target { index, name: n }),
                },
                (Some(FileTarget::Point(p)), _, _) => KeyView::Relative(DVec3::from(p)),
                (None, Some(yaw), Some(pitch)) => KeyView::YawPitch { yaw, pitch },
                _ => return Err(FlightError::View { index }),
            };
            keyframes.push(KeySpec { t: k.t, position, view });
        }
        let spec = Self {
            name: f.name,
            fps: f.fps,
            fov_y_deg: f.fov_y_deg.unwrap_or(60.0),
            height_above: f.height_above,
            keyframes,
        };
        spec.validate()?;
        Ok(spec)
    }

    /// Checks the rules of the module docs (also for specs built in code).
    pub fn validate(&self) -> Result<(), FlightError> {
        let bad = |index, field, value| Err(FlightError::InvalidNumber { index, field, value });
        if !(self.fps.is_finite() && self.fps > 0.0) {
            return bad(None, "fps", self.fps);
        }
        if !(self.fov_y_deg.is_finite() && self.fov_y_deg > 0.0 && self.fov_y_deg < 180.0) {
            return bad(None, "fov_y_deg", self.fov_y_deg);
        }
        if self.keyframes.len() < 2 {
            return Err(FlightError::TooFewKeyframes { count: self.keyframes.len() });
        }
        for (i, k) in self.keyframes.iter().enumerate() {
            if !k.t.is_finite() {
                return bad(Some(i), "t", k.t);
            }
            let p = match k.position {
                KeyPosition::World(p) | KeyPosition::Relative(p) | KeyPosition::PeakRelative(p) => {
                    p
                }
            };
            if !p.is_finite() {
                return bad(Some(i), "position", p.x + p.y + p.z);
            }
            match k.view {
                KeyView::YawPitch { yaw, pitch } => {
                    if !yaw.is_finite() {
                        return bad(Some(i), "yaw", yaw);
                    }
                    if !(pitch.is_finite() && (-90.0..=90.0).contains(&pitch)) {
                        return bad(Some(i), "pitch", pitch);
                    }
                }
                KeyView::Relative(p) if !p.is_finite() => {
                    return bad(Some(i), "look_at", p.x + p.y + p.z);
                }
                _ => {}
            }
            if i == 0 && k.t != 0.0 {
                return Err(FlightError::FirstTimeNotZero { t: k.t });
            }
            if i > 0 && k.t <= self.keyframes[i - 1].t {
                return Err(FlightError::NonIncreasingTime {
                    index: i,
                    t: k.t,
                    previous: self.keyframes[i - 1].t,
                });
            }
        }
        let duration = self.keyframes[self.keyframes.len() - 1].t;
        let frames = duration * self.fps;
        // Checked in f64 before any count is made: fps 1e9 or t 1e12 would overflow nothing
        // here, and frame_count below never sees them.
        if !(frames <= MAX_FRAMES as f64 && frame_count(duration, self.fps) <= MAX_FRAMES) {
            return Err(FlightError::TooManyFrames {
                path: None,
                fps: self.fps,
                duration,
                frames,
                max: MAX_FRAMES,
            });
        }
        Ok(())
    }

    /// Places the flight on `hm`: resolves relative positions and targets, clamps keyframes
    /// (see the module docs) and computes every frame's camera. The spec must have passed
    /// [`validate`](Self::validate) (as [`parse`](Self::parse) and [`load`](Self::load)
    /// do), which bounds the frames by [`MAX_FRAMES`].
    pub fn resolve(&self, hm: &Heightmap, cfg: &FlightConfig) -> (Flight, Vec<FlightWarning>) {
        let terrain = TerrainFacts::new(hm, cfg);
        let mut warnings = Vec::new();
        let mut keys: Vec<Keyframe> = Vec::with_capacity(self.keyframes.len());
        for (index, k) in self.keyframes.iter().enumerate() {
            let raw = match k.position {
                KeyPosition::World(p) => p,
                KeyPosition::Relative(r) => terrain.relative(hm, self.height_above, r),
                KeyPosition::PeakRelative(r) => terrain.relative(
                    hm,
                    self.height_above,
                    r + dvec3(terrain.peak_uv.x, terrain.peak_uv.y, 0.0),
                ),
            };
            let xy = terrain.clamp_plan(raw.truncate());
            if xy != raw.truncate() {
                warnings.push(FlightWarning::MovedInside {
                    index,
                    from: raw.truncate().to_array(),
                    to: xy.to_array(),
                });
            }
            let floor = f64::from(hm.sample_world(xy)) + cfg.clearance_m;
            let z = if raw.z < floor {
                warnings.push(FlightWarning::Raised { index, from_z: raw.z, to_z: floor });
                floor
            } else {
                raw.z
            };
            let position = xy.extend(z);
            let (yaw, pitch) = match k.view {
                KeyView::YawPitch { yaw, pitch } => (yaw, pitch),
                KeyView::Peak => yaw_pitch_towards(position, terrain.peak),
                KeyView::Center => yaw_pitch_towards(position, terrain.center),
                KeyView::Relative(r) => {
                    yaw_pitch_towards(position, terrain.relative(hm, self.height_above, r))
                }
            };
            // Shortest arc: unwrap yaw so consecutive keyframes differ by at most 180 degrees.
            let yaw = match keys.last() {
                Some(prev) => prev.yaw + wrap_deg(yaw - prev.yaw),
                None => yaw,
            };
            keys.push(Keyframe { t: k.t, position, yaw, pitch });
        }
        let duration = keys.last().expect("validated: >= 2 keyframes").t;
        let n = frame_count(duration, self.fps);
        let mut frames = Vec::with_capacity(n);
        let (mut raised, mut max_raise) = (0usize, 0.0f64);
        for k in 0..n {
            let t = k as f64 / self.fps;
            let (p, yaw, pitch) = sample(&keys, t);
            let xy = terrain.clamp_plan(p.truncate());
            let floor = f64::from(hm.sample_world(xy)) + cfg.clearance_m;
            let z = if p.z < floor {
                raised += 1;
                max_raise = max_raise.max(floor - p.z);
                floor
            } else {
                p.z
            };
            let cam = Camera::from_yaw_pitch(xy.extend(z), yaw, pitch.clamp(-90.0, 90.0))
                .with_fov_y_deg(self.fov_y_deg)
                .with_viewport(cfg.viewport_px.x, cfg.viewport_px.y)
                .with_clip(cfg.near_far.0, cfg.near_far.1);
            frames.push(cam);
        }
        if raised > 0 {
            warnings.push(FlightWarning::FramesRaised { count: raised, max_raise_m: max_raise });
        }
        (Flight { name: self.name.clone(), fps: self.fps, keyframes: keys, frames }, warnings)
    }
}

/// Loads a flight file and places it on `hm` (see [`FlightSpec::load`] and
/// [`FlightSpec::resolve`]).
pub fn load_flight(
    path: impl AsRef<Path>,
    hm: &Heightmap,
    cfg: &FlightConfig,
) -> Result<(Flight, Vec<FlightWarning>), FlightError> {
    Ok(FlightSpec::load(path)?.resolve(hm, cfg))
}

/// What relative positions are measured against.
struct TerrainFacts {
    origin: DVec2,
    extent: DVec2,
    min: f64,
    mean: f64,
    relief: f64,
    peak: DVec3,
    peak_uv: DVec2,
    center: DVec3,
}

impl TerrainFacts {
    fn new(hm: &Heightmap, cfg: &FlightConfig) -> Self {
        let (w, h) = (hm.width(), hm.height());
        let voids = hm.voids();
        let (mut sum, mut n) = (0.0f64, 0usize);
        let (mut best, mut peak_ij) = (f32::NEG_INFINITY, (0, 0));
        for j in 0..h {
            for i in 0..w {
                if voids.any() && voids.get(i, j) {
                    continue;
                }
                let z = hm.get(i, j);
                sum += f64::from(z);
                n += 1;
                // First maximum in row-major order: deterministic on ties.
                if z > best {
                    best = z;
                    peak_ij = (i, j);
                }
            }
        }
        let origin = hm.grid_to_world(0.0, 0.0);
        let extent = hm.extent_m();
        let min = f64::from(hm.min());
        let relief =
            (f64::from(hm.max()) - min).max(cfg.min_relief_fraction * extent.max_element());
        let peak_xy = hm.grid_to_world(peak_ij.0 as f64, peak_ij.1 as f64);
        let uv = |p: DVec2| {
            let d = p - origin;
            dvec2(
                if extent.x > 0.0 { d.x / extent.x } else { 0.0 },
                if extent.y > 0.0 { d.y / extent.y } else { 0.0 },
            )
        };
        let center_xy = origin + extent * 0.5;
        Self {
            origin,
            extent,
            min,
            mean: sum / n.max(1) as f64,
            relief,
            peak: peak_xy.extend(f64::from(best)),
            peak_uv: uv(peak_xy),
            center: center_xy.extend(f64::from(hm.sample_world(center_xy))),
        }
    }

    fn relative(&self, hm: &Heightmap, reference: HeightRef, r: DVec3) -> DVec3 {
        let xy = self.origin + self.extent * dvec2(r.x, r.y);
        let base = match reference {
            HeightRef::Ground => f64::from(hm.sample_world(self.clamp_plan(xy))),
            HeightRef::Mean => self.mean,
            HeightRef::Min => self.min,
        };
        xy.extend(base + r.z * self.relief)
    }

    fn clamp_plan(&self, p: DVec2) -> DVec2 {
        p.clamp(self.origin, self.origin + self.extent)
    }
}

/// Compass yaw and pitch (degrees) of the direction from `eye` to `target`.
pub fn yaw_pitch_towards(eye: DVec3, target: DVec3) -> (f64, f64) {
    let d = target - eye;
    let horizontal = d.truncate().length();
    if horizontal == 0.0 && d.z == 0.0 {
        return (0.0, 0.0);
    }
    // Compass yaw: 0 = +y (north), 90 = +x (east).
    let yaw = if horizontal > 0.0 { d.x.atan2(d.y).to_degrees() } else { 0.0 };
    let pitch = d.z.atan2(horizontal).to_degrees();
    (yaw, pitch)
}

/// `a` wrapped into `(-180, 180]` degrees.
fn wrap_deg(a: f64) -> f64 {
    let r = a.rem_euclid(360.0);
    if r > 180.0 { r - 360.0 } else { r }
}

/// Position, yaw and pitch at time `t` (clamped to the keyframes' span).
fn sample(keys: &[Keyframe], t: f64) -> (DVec3, f64, f64) {
    let n = keys.len();
    let t = t.clamp(keys[0].t, keys[n - 1].t);
    // Segment i: keys[i].t <= t < keys[i + 1].t (the last one includes its end).
    let i = keys.partition_point(|k| k.t <= t).saturating_sub(1).min(n - 2);
    let s = ((t - keys[i].t) / (keys[i + 1].t - keys[i].t)).clamp(0.0, 1.0);
    let p = |k: isize| -> DVec3 {
        if k < 0 {
            2.0 * keys[0].position - keys[1].position
        } else if k as usize >= n {
            2.0 * keys[n - 1].position - keys[n - 2].position
        } else {
            keys[k as usize].position
        }
    };
    let a = |k: isize, f: fn(&Keyframe) -> f64| -> f64 {
        if k < 0 {
            2.0 * f(&keys[0]) - f(&keys[1])
        } else if k as usize >= n {
            2.0 * f(&keys[n - 1]) - f(&keys[n - 2])
        } else {
            f(&keys[k as usize])
        }
    };
    let i = i as isize;
    let pos = centripetal_catmull_rom([p(i - 1), p(i), p(i + 1), p(i + 2)], s);
    let yaw = uniform_catmull_rom(
        [a(i - 1, |k| k.yaw), a(i, |k| k.yaw), a(i + 1, |k| k.yaw), a(i + 2, |k| k.yaw)],
        s,
    );
    let pitch = uniform_catmull_rom(
        [a(i - 1, |k| k.pitch), a(i, |k| k.pitch), a(i + 1, |k| k.pitch), a(i + 2, |k| k.pitch)],
        s,
    );
    (pos, yaw, pitch)
}

/// Centripetal Catmull-Rom (alpha = 1/2) between `p[1]` (s = 0) and `p[2]` (s = 1), by the
/// Barry-Goldman pyramid. Knot gaps are floored so coincident control points stay finite.
pub fn centripetal_catmull_rom(p: [DVec3; 4], s: f64) -> DVec3 {
    if s <= 0.0 {
        return p[1];
    }
    if s >= 1.0 {
        return p[2];
    }
    let gap = |a: DVec3, b: DVec3| (a - b).length().sqrt().max(1e-6);
    let t0 = 0.0;
    let t1 = t0 + gap(p[0], p[1]);
    let t2 = t1 + gap(p[1], p[2]);
    let t3 = t2 + gap(p[2], p[3]);
    let t = t1 + s * (t2 - t1);
    let lerp = |a: DVec3, b: DVec3, ta: f64, tb: f64| {
        a * ((tb - t) / (tb - ta)) + b * ((t - ta) / (tb - ta))
    };
    let a1 = lerp(p[0], p[1], t0, t1);
    let a2 = lerp(p[1], p[2], t1, t2);
    let a3 = lerp(p[2], p[3], t2, t3);
    let b1 = lerp(a1, a2, t0, t2);
    let b2 = lerp(a2, a3, t1, t3);
    lerp(b1, b2, t1, t2)
}

/// Uniform Catmull-Rom between `v[1]` (s = 0) and `v[2]` (s = 1).
pub fn uniform_catmull_rom(v: [f64; 4], s: f64) -> f64 {
    let (s2, s3) = (s * s, s * s * s);
    0.5 * (2.0 * v[1]
        + (v[2] - v[0]) * s
        + (2.0 * v[0] - 5.0 * v[1] + 4.0 * v[2] - v[3]) * s2
        + (3.0 * v[1] - v[0] - 3.0 * v[2] + v[3]) * s3)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::georef::Georef;

    fn flat(z: f32) -> Heightmap {
        Heightmap::from_fn(101, 51, Georef::local(10.0), |_, _| z).unwrap()
    }

    fn spec(text: &str) -> Result<FlightSpec, FlightError> {
        FlightSpec::parse(text)
    }

    #[test]
    fn frame_times_and_counts_are_exact() {
        assert_eq!(frame_count(60.0, 30.0), 1800);
        assert_eq!(frame_count(1.0, 3.0), 3);
        assert_eq!(frame_count(0.1, 30.0), 3); // 0, 1/30, 2/30 < 0.1, 3/30 is not < 0.1
        let f = spec(
            r#"{"name":"a","fps":4,"keyframes":[
                {"t":0,"position":[0,0,100],"yaw":0,"pitch":0},
                {"t":2,"position":[200,0,100],"yaw":90,"pitch":-10}]}"#,
        )
        .unwrap();
        let (fl, warn) = f.resolve(&flat(0.0), &FlightConfig::default());
        assert!(warn.is_empty(), "{warn:?}");
        assert_eq!(fl.frames().len(), 8);
        assert_eq!(fl.frame_time(5), 1.25);
        // Two keyframes: the reflected ends make the spline a straight line through both.
        assert_eq!(fl.frames()[0].position, dvec3(0.0, 0.0, 100.0));
        let mid = fl.frames()[4].position;
        assert!((mid - dvec3(100.0, 0.0, 100.0)).length() < 1e-9, "{mid}");
    }

    #[test]
    fn interpolation_passes_through_keyframes_and_takes_the_short_arc() {
        let f = spec(
            r#"{"name":"a","fps":10,"keyframes":[
                {"t":0,"position":[0,0,100],"yaw":350,"pitch":0},
                {"t":1,"position":[100,50,120],"yaw":10,"pitch":-20},
                {"t":2,"position":[300,100,90],"yaw":30,"pitch":-30},
                {"t":3,"position":[400,300,200],"yaw":40,"pitch":-30}]}"#,
        )
        .unwrap();
        let (fl, _) = f.resolve(&flat(0.0), &FlightConfig::default());
        assert_eq!(fl.frames().len(), 30);
        for (k, key) in fl.keyframes.iter().enumerate().take(3) {
            let cam = fl.frames()[k * 10];
            assert!((cam.position - key.position).length() < 1e-9);
            let expect = Camera::from_yaw_pitch(key.position, key.yaw, key.pitch);
            assert!((cam.forward() - expect.forward()).length() < 1e-9);
        }
        // 350 -> 10 goes through north (+20 degrees), not back through south.
        assert_eq!(fl.keyframes[1].yaw, 370.0);
        for k in 0..10 {
            let fwd = fl.frames()[k].forward();
            assert!(fwd.y > 0.9, "frame {k} looks {fwd}");
        }
        assert!(fl.frames().iter().all(|c| c.position.is_finite() && c.orientation.is_finite()));
    }

    #[test]
    fn clamping_warns() {
        let hm = flat(50.0);
        let f = spec(
            r#"{"name":"a","fps":1,"keyframes":[
                {"t":0,"position":[-100,200,10],"yaw":0,"pitch":0},
                {"t":1,"relative":[0.5,0.5,0.0],"look_at":"center"},
                {"t":2,"relative":[2.0,0.5,3.0],"look_at":"peak"}]}"#,
        )
        .unwrap();
        let (fl, warn) = f.resolve(&hm, &FlightConfig::default());
        assert_eq!(
            warn[..2],
            [
                FlightWarning::MovedInside { index: 0, from: [-100.0, 200.0], to: [0.0, 200.0] },
                FlightWarning::Raised { index: 0, from_z: 10.0, to_z: 60.0 },
            ]
        );
        assert!(warn.contains(&FlightWarning::Raised { index: 1, from_z: 50.0, to_z: 60.0 }));
        assert!(warn.iter().any(|w| matches!(w, FlightWarning::MovedInside { index: 2, .. })));
        // Relief of a flat DEM is floored at 2 % of 1000 m: h = 3 -> 60 m above ground.
        assert_eq!(fl.keyframes[2].position, dvec3(1000.0, 250.0, 110.0));
        assert!(fl.frames().iter().all(|c| c.position.z >= 60.0 - 1e-9));
        assert!(!warn[0].to_string().is_empty());
    }

    #[test]
    fn look_at_peak_points_at_the_highest_sample() {
        let hm = Heightmap::from_fn(41, 41, Georef::local(5.0), |i, j| {
            if (i, j) == (30, 10) { 100.0 } else { 0.0 }
        })
        .unwrap();
        let f = spec(
            r#"{"name":"a","fps":2,"height_above":"min","keyframes":[
                {"t":0,"peak_relative":[0,-0.3,2],"look_at":"peak"},
                {"t":1,"relative":[0.1,0.1,1],"look_at":[0.75,0.25,1]}]}"#,
        )
        .unwrap();
        let (fl, warn) = f.resolve(&hm, &FlightConfig::default());
        let peak = dvec3(150.0, 50.0, 100.0);
        let cam = fl.frames()[0];
        assert!(matches!(warn[..], [FlightWarning::MovedInside { index: 0, .. }]), "{warn:?}");
        assert_eq!(cam.position, dvec3(150.0, 0.0, 200.0));
        assert!((cam.forward() - (peak - cam.position).normalize()).length() < 1e-9);
    }

    #[test]
    fn validation_errors() {
        let key = r#"{"t":0,"position":[0,0,1],"yaw":0,"pitch":0}"#;
        let one = format!(r#"{{"name":"a","fps":30,"keyframes":[{key}]}}"#);
        assert!(matches!(spec(&one), Err(FlightError::TooFewKeyframes { count: 1 })));
        let same = format!(r#"{{"name":"a","fps":30,"keyframes":[{key},{key}]}}"#);
        assert!(matches!(spec(&same), Err(FlightError::NonIncreasingTime { index: 1, .. })));
        let json = "{\"name\": \"a\",\n  \"fps\": 30,\n  \"keyframes\": [ oops ]}";
        match spec(json) {
            Err(FlightError::Json { line: 3, column, .. }) => assert!(column > 10),
            other => panic!("{other:?}"),
        }
        let nan = r#"{"name":"a","fps":NaN,"keyframes":[]}"#;
        assert!(matches!(spec(nan), Err(FlightError::Json { line: 1, .. })));
        let fps = format!(r#"{{"name":"a","fps":0,"keyframes":[{key},{key}]}}"#);
        assert!(matches!(spec(&fps), Err(FlightError::InvalidNumber { field: "fps", .. })));
        let late = r#"{"name":"a","fps":1,"keyframes":[{"t":1,"position":[0,0,1],"yaw":0,"pitch":0},
            {"t":2,"position":[0,0,1],"yaw":0,"pitch":0}]}"#;
        assert!(matches!(spec(late), Err(FlightError::FirstTimeNotZero { .. })));
        let two = r#"{"name":"a","fps":1,"keyframes":[{"t":0,"position":[0,0,1],"relative":[0,0,1],"yaw":0,"pitch":0},
            {"t":2,"position":[0,0,1],"yaw":0,"pitch":0}]}"#;
        assert!(matches!(spec(two), Err(FlightError::Position { index: 0 })));
        let noview = r#"{"name":"a","fps":1,"keyframes":[{"t":0,"position":[0,0,1],"yaw":0},
            {"t":2,"position":[0,0,1],"yaw":0,"pitch":0}]}"#;
        assert!(matches!(spec(noview), Err(FlightError::View { index: 0 })));
        let mut s = spec(&format!(
            r#"{{"name":"a","fps":1,"keyframes":[{key},{{"t":1,"position":[0,0,1],"yaw":0,"pitch":0}}]}}"#
        ))
        .unwrap();
        s.keyframes[1].view = KeyView::YawPitch { yaw: f64::NAN, pitch: 0.0 };
        assert!(matches!(s.validate(), Err(FlightError::InvalidNumber { field: "yaw", .. })));
        let missing = FlightSpec::load("/nonexistent/flight.json").unwrap_err();
        assert!(matches!(missing, FlightError::Io { .. }));
        assert!(missing.to_string().contains("/nonexistent/flight.json"));
    }
}
