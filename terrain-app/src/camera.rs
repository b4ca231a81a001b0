//! Cameras users place: the one parser of `--camera` and `--look-at` (world coordinates or
//! longitude/latitude, heights absolute or above the ground), the placement of a parsed camera
//! on a terrain, the default framing, and the check that a camera sees terrain. `render`,
//! `mesh --camera` and the viewer all call [`place`] and [`check_view`].
//!
//! Forms (documented in the README, "Cameras"):
//!
//! * `--camera X,Y,Z,YAW,PITCH`: world coordinates (metres; a projected DEM's CRS coordinates,
//!   a geographic DEM's equirectangular frame), compass yaw (0 north, 90 east), pitch
//!   (negative looks down), degrees.
//! * `--camera lonlat:LON,LAT,Z,YAW,PITCH`: WGS84 degrees, converted to the DEM's CRS
//!   ([`terrain_core::lonlat`]); a DEM without a CRS refuses it.
//! * `Z` ending in `agl` (`300agl`): metres above the ground there (the terrain's bilinear
//!   height, from the grid in memory or a store's coarse overview), instead of absolute.
//! * `--look-at X,Y[,Z]` or `--look-at lonlat:LON,LAT[,Z]`: aim at a target instead of giving
//!   yaw and pitch (`--camera` then has three values); `Z` defaults to the ground there.

use anyhow::{Context, bail};
use glam::{DVec2, DVec3, dvec2};
use terrain_core::geometry::{self, Camera};
use terrain_core::lonlat::LonLat;
use terrain_core::{Georef, Heightmap};

/// A horizontal position as given.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Horizontal {
    /// World coordinates, metres.
    World(DVec2),
    /// WGS84 longitude (x) and latitude (y), degrees.
    LonLat(DVec2),
}

/// A height as given.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Height {
    /// World z, metres.
    Absolute(f64),
    /// Metres above the ground under the point (`agl` suffix).
    AboveGround(f64),
}

/// A point as given: where, and how high (`None`: on the ground).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointSpec {
    /// The horizontal position.
    pub horizontal: Horizontal,
    /// The height; `None` for the ground there.
    pub height: Option<Height>,
}

/// Where the camera looks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Aim {
    /// Compass yaw and pitch, degrees.
    YawPitch {
        /// 0 north, 90 east.
        yaw: f64,
        /// Negative looks down.
        pitch: f64,
    },
    /// At a target point.
    LookAt(PointSpec),
}

/// A camera as given on the command line: `--camera` and `--look-at` parsed ([`parse`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraSpec {
    /// The eye.
    pub eye: PointSpec,
    /// Where it looks.
    pub aim: Aim,
}

/// The syntax, for messages.
const CAMERA_FORMS: &str = "X,Y,Z,YAW,PITCH or lonlat:LON,LAT,Z,YAW,PITCH (Z in metres, \
                            or metres above the ground as e.g. 300agl; yaw and pitch in degrees; \
                            with --look-at only X,Y,Z)";

/// Parses `--camera` (and `--look-at` when given): one parser for every command.
pub fn parse(camera: &str, look_at: Option<&str>) -> anyhow::Result<CameraSpec> {
    let bad = || format!("--camera expects {CAMERA_FORMS}, got `{camera}`");
    let (horizontal_of, fields) = split_form(camera);
    let fields = fields.with_context(bad)?;
    let aim = match (look_at, fields.len()) {
        (None, 5) => {
            let (yaw, pitch) =
                (number(&fields[3]).with_context(bad)?, number(&fields[4]).with_context(bad)?);
            Aim::YawPitch { yaw, pitch }
        }
        (Some(t), 3) => Aim::LookAt(parse_target(t)?),
        (Some(_), 5) => bail!(
            "--camera `{camera}` gives yaw and pitch and --look-at a target: give one of them \
             (with --look-at, --camera is X,Y,Z or lonlat:LON,LAT,Z)"
        ),
        _ => bail!("{}", bad()),
    };
    let xy = dvec2(number(&fields[0]).with_context(bad)?, number(&fields[1]).with_context(bad)?);
    let height = Some(height(&fields[2]).with_context(bad)?);
    Ok(CameraSpec { eye: PointSpec { horizontal: horizontal_of(xy), height }, aim })
}

/// Parses `--look-at X,Y[,Z]` or `lonlat:LON,LAT[,Z]`.
fn parse_target(s: &str) -> anyhow::Result<PointSpec> {
    let bad = || {
        format!(
            "--look-at expects X,Y[,Z] or lonlat:LON,LAT[,Z] (Z in metres or e.g. 10agl; \
             default the ground), got `{s}`"
        )
    };
    let (horizontal_of, fields) = split_form(s);
    let fields = fields.with_context(bad)?;
    if !(2..=3).contains(&fields.len()) {
        bail!("{}", bad());
    }
    let xy = dvec2(number(&fields[0]).with_context(bad)?, number(&fields[1]).with_context(bad)?);
    let height = match fields.get(2) {
        Some(f) => Some(height(f).with_context(bad)?),
        None => None,
    };
    Ok(PointSpec { horizontal: horizontal_of(xy), height })
}

type HorizontalOf = fn(DVec2) -> Horizontal;

/// Splits `lonlat:a,b,...` or `a,b,...` into the horizontal kind and the trimmed fields.
fn split_form(s: &str) -> (HorizontalOf, Option<Vec<String>>) {
    let t = s.trim();
    let (kind, rest): (HorizontalOf, &str) = match t.get(..7) {
        Some(p) if p.eq_ignore_ascii_case("lonlat:") => (Horizontal::LonLat, &t[7..]),
        _ => (Horizontal::World, t),
    };
    let fields: Vec<String> = rest.split(',').map(|f| f.trim().to_ascii_lowercase()).collect();
    (kind, (!fields.iter().any(String::is_empty)).then_some(fields))
}

fn number(s: &str) -> Option<f64> {
    s.parse::<f64>().ok().filter(|v| v.is_finite())
}

fn height(s: &str) -> Option<Height> {
    match s.strip_suffix("agl") {
        Some(h) => number(h.trim()).map(Height::AboveGround),
        None => number(s).map(Height::Absolute),
    }
}

/// The view a camera is placed for: image size in pixels and vertical field of view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewConfig {
    /// Image width and height, pixels.
    pub size_px: DVec2,
    /// Vertical field of view, degrees.
    pub fov_y_deg: f64,
}

/// The terrain a camera is placed on: heights for the ground under a point (the full grid,
/// or a store's coarse overview) and the georeference whose CRS converts lon/lat.
#[derive(Debug, Clone, Copy)]
pub struct Ground<'a> {
    /// Heights for the ground; its world frame is the terrain's.
    pub heights: &'a Heightmap,
    /// The terrain's georeference (a store's overview has the store's world frame but no CRS).
    pub georef: &'a Georef,
}

impl<'a> Ground<'a> {
    /// The ground of a heightmap in memory.
    pub fn of(hm: &'a Heightmap) -> Self {
        Self { heights: hm, georef: hm.georef() }
    }

    /// The world position of a horizontal position.
    pub fn world(&self, h: Horizontal) -> anyhow::Result<DVec2> {
        match h {
            Horizontal::World(p) => Ok(p),
            Horizontal::LonLat(ll) => {
                let c = LonLat::new(self.georef).context("lonlat: in --camera or --look-at")?;
                // The longitude modulo 360 nearest the terrain (a grid in 0..360 longitudes).
                let (w, h) = (self.heights.width(), self.heights.height());
                let centre =
                    self.heights.grid_to_world((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
                Ok(c.to_world_near(ll, centre)?)
            }
        }
    }

    /// The ground height at world `p` (bilinear; outside the grid, at its nearest border).
    pub fn height_at(&self, p: DVec2) -> f64 {
        f64::from(self.heights.sample_world(p))
    }

    /// Whether world `p` lies over the grid.
    pub fn covers(&self, p: DVec2) -> bool {
        let g = self.heights.world_to_grid(p);
        let (w, h) = ((self.heights.width() - 1) as f64, (self.heights.height() - 1) as f64);
        (0.0..=w).contains(&g.x) && (0.0..=h).contains(&g.y)
    }

    fn point(&self, p: &PointSpec) -> anyhow::Result<DVec3> {
        let xy = self.world(p.horizontal)?;
        let z = match p.height {
            Some(Height::Absolute(z)) => z,
            Some(Height::AboveGround(h)) => self.height_at(xy) + h,
            None => self.height_at(xy),
        };
        Ok(xy.extend(z))
    }
}

/// Height above the ground a camera given under it is lifted to, metres.
pub const LIFT_CLEARANCE_M: f64 = 2.0;

/// A camera placed, with what placing it changed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placed {
    /// The camera (near and far planes are the caller's: they depend on the data drawn).
    pub camera: Camera,
    /// Set when the eye was under the ground: the ground height there, metres; the camera was
    /// lifted to [`LIFT_CLEARANCE_M`] above it.
    pub lifted_from: Option<(f64, f64)>,
}

impl Placed {
    /// The warning to print when the camera was lifted.
    pub fn lift_warning(&self) -> Option<String> {
        self.lifted_from.map(|(given, ground)| {
            format!(
                "--camera: the eye at z = {given:.1} m is under the ground ({ground:.1} m there); \
                 lifted to {:.1} m ({LIFT_CLEARANCE_M} m above it). Give a higher Z in \
                 --camera, or a height above the ground such as 100agl",
                ground + LIFT_CLEARANCE_M
            )
        })
    }
}

/// Places `spec` on `ground` for `view`; without a spec, the default framing that fills the
/// image with the terrain ([`geometry::fill_camera`]). An eye under the ground (over the grid)
/// is lifted to [`LIFT_CLEARANCE_M`] above it ([`Placed::lifted_from`]).
pub fn place(
    spec: Option<&CameraSpec>,
    ground: &Ground<'_>,
    view: &ViewConfig,
) -> anyhow::Result<Placed> {
    if !(view.fov_y_deg.is_finite() && view.fov_y_deg > 0.0 && view.fov_y_deg < 180.0) {
        bail!("--fov must be between 0 and 180 degrees, got {}", view.fov_y_deg);
    }
    let Some(spec) = spec else {
        let camera = geometry::fill_camera(ground.heights, view.size_px, view.fov_y_deg);
        return Ok(Placed { camera, lifted_from: None });
    };
    let mut eye = ground.point(&spec.eye)?;
    let mut lifted_from = None;
    if ground.covers(eye.truncate()) {
        let floor = ground.height_at(eye.truncate());
        if eye.z < floor {
            lifted_from = Some((eye.z, floor));
            eye.z = floor + LIFT_CLEARANCE_M;
        }
    }
    let (yaw, pitch) = match spec.aim {
        Aim::YawPitch { yaw, pitch } => (yaw, pitch),
        Aim::LookAt(target) => {
            let t = ground.point(&target)?;
            yaw_pitch_towards(eye, t).with_context(|| {
                format!(
                    "--look-at: the target ({:.1}, {:.1}, {:.1}) is where the camera is",
                    t.x, t.y, t.z
                )
            })?
        }
    };
    let camera = Camera::from_yaw_pitch(eye, yaw, pitch)
        .with_fov_y_deg(view.fov_y_deg)
        .with_viewport(view.size_px.x, view.size_px.y);
    Ok(Placed { camera, lifted_from })
}

/// Compass yaw and pitch (degrees) of the direction from `eye` to `target`; `None` when they
/// coincide.
pub fn yaw_pitch_towards(eye: DVec3, target: DVec3) -> Option<(f64, f64)> {
    let d = target - eye;
    let flat = d.truncate().length();
    if d.length() < 1e-9 {
        return None;
    }
    // Compass yaw: clockwise from north (+y), so atan2(east, north).
    let yaw = if flat > 0.0 { d.x.atan2(d.y).to_degrees() } else { 0.0 };
    Some((yaw, d.z.atan2(flat).to_degrees()))
}

/// Why a camera sees no terrain ([`check_view`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum NoTerrain {
    /// The whole terrain is in front but smaller than a pixel.
    TooFar {
        /// Distance from the eye to the terrain's box, metres.
        distance_m: f64,
        /// The terrain's size on screen, pixels.
        size_px: f64,
    },
    /// No ray of the image meets the terrain: it is behind the camera, beside the view, or the
    /// camera looks above it.
    NotInView {
        /// The terrain's centre is behind the camera.
        behind: bool,
    },
}

impl NoTerrain {
    /// Why, without the advice.
    pub fn reason(&self) -> String {
        match self {
            NoTerrain::TooFar { distance_m, size_px } => format!(
                "the terrain is {:.0} km away and {size_px:.2} px across on screen",
                distance_m / 1000.0
            ),
            NoTerrain::NotInView { behind: true } => "the terrain is behind the camera".into(),
            NoTerrain::NotInView { behind: false } => {
                "the view misses the terrain (beside it, or above the horizon)".into()
            }
        }
    }
}

impl std::fmt::Display for NoTerrain {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let advice = match self {
            NoTerrain::TooFar { .. } => {
                "move the camera closer (--camera, or leave --camera out for the default framing)"
            }
            NoTerrain::NotInView { behind: true } => {
                "turn it round (the yaw and pitch of --camera) or aim it with --look-at"
            }
            NoTerrain::NotInView { behind: false } => {
                "change the yaw and pitch of --camera (negative pitch looks down) or aim it with \
                 --look-at"
            }
        };
        write!(f, "the camera sees no terrain: {}; {advice}", self.reason())
    }
}

/// Rays per image side [`check_view`] casts (the longer side; the other by aspect).
const CHECK_RAYS: u32 = 96;

/// Whether `camera` sees any of the terrain `heights` (a full grid or a coarse overview): the
/// terrain smaller than a pixel on screen, or no ray of a 96-column grid of pixels meeting it
/// within the far plane, is a [`NoTerrain`].
pub fn check_view(heights: &Heightmap, camera: &Camera) -> Option<NoTerrain> {
    let (lo, hi) = geometry::terrain_box(heights);
    let distance_m = (camera.position.clamp(lo, hi) - camera.position).length();
    if let Some(size_px) = geometry::projected_size_px(heights, camera)
        && size_px < 1.0
    {
        return Some(NoTerrain::TooFar { distance_m, size_px });
    }
    let aspect = (camera.viewport_px.x / camera.viewport_px.y).clamp(0.1, 10.0);
    let rows = ((f64::from(CHECK_RAYS) / aspect).round() as u32).max(2);
    if geometry::terrain_coverage(heights, camera, CHECK_RAYS, rows) > 0.0 {
        return None;
    }
    let centre = (lo + hi) * 0.5;
    Some(NoTerrain::NotInView { behind: (centre - camera.position).dot(camera.forward()) < 0.0 })
}

/// The frames of a flight (`cameras`) that see no terrain of `heights`, with why: each checked
/// as [`check_view`] does, on a copy of at most 257 x 257 samples (a flight has many frames).
pub fn frames_without_terrain(heights: &Heightmap, cameras: &[Camera]) -> Vec<(usize, NoTerrain)> {
    let coarse = geometry::coarse_copy(heights, 257);
    cameras
        .iter()
        .enumerate()
        .filter_map(|(k, c)| check_view(&coarse, c).map(|why| (k, why)))
        .collect()
}

/// The one warning for a flight whose frames (of `total`) see no terrain, or `None`.
pub fn flight_warning(name: &str, frames: &[(usize, NoTerrain)], total: usize) -> Option<String> {
    let (first, why) = frames.first()?;
    Some(format!(
        "flight {name}: {} of {total} drawn frames see no terrain (the first, drawn frame {}: \
         {}); a flight's cameras come from its keyframes: check their positions and yaw/pitch",
        frames.len(),
        first + 1,
        why.reason()
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::dvec3;
    use terrain_core::Crs;

    #[test]
    fn every_form_parses() {
        let s = parse("429000.5,5000000,450,90,-35", None).unwrap();
        assert_eq!(s.eye.horizontal, Horizontal::World(dvec2(429000.5, 5000000.0)));
        assert_eq!(s.eye.height, Some(Height::Absolute(450.0)));
        assert_eq!(s.aim, Aim::YawPitch { yaw: 90.0, pitch: -35.0 });
        let s = parse("lonlat:-121.76, 46.85, 500agl, 0, -20", None).unwrap();
        assert_eq!(s.eye.horizontal, Horizontal::LonLat(dvec2(-121.76, 46.85)));
        assert_eq!(s.eye.height, Some(Height::AboveGround(500.0)));
        let s = parse("LONLAT:1,2,3", Some("lonlat:1.5,2.5")).unwrap();
        let t = PointSpec { horizontal: Horizontal::LonLat(dvec2(1.5, 2.5)), height: None };
        assert_eq!(s.aim, Aim::LookAt(t));
        let s = parse("1,2,3", Some("4,5,6AGL")).unwrap();
        let t = PointSpec {
            horizontal: Horizontal::World(dvec2(4.0, 5.0)),
            height: Some(Height::AboveGround(6.0)),
        };
        assert_eq!(s.aim, Aim::LookAt(t));
    }

    #[test]
    fn bad_forms_are_refused_with_the_input_named() {
        for bad in ["1,2,3,4", "1,2,3,4,x", "1,2,3,4,5,6", "1,2,NaN,4,5", "lonlat:1,2", "1,,3,4,5"]
        {
            let e = parse(bad, None).unwrap_err().to_string();
            assert!(e.contains(bad) && e.contains("--camera"), "{bad}: {e}");
        }
        let e = parse("1,2,3,4,5", Some("1,2")).unwrap_err().to_string();
        assert!(e.contains("--look-at") && e.contains("one of them"), "{e}");
        for bad in ["1", "1,2,3,4", "1,2,x"] {
            let e = parse("1,2,3", Some(bad)).unwrap_err().to_string();
            assert!(e.contains("--look-at") && e.contains(bad), "{bad}: {e}");
        }
    }

    /// A plane rising 1 m per 10 m east, 101 x 101 samples at 10 m, at UTM 11N coordinates.
    fn plane() -> Heightmap {
        let g =
            Georef::projected(Crs::Epsg(32611), dvec2(384_000.0, 3_790_000.0), DVec2::splat(10.0));
        Heightmap::from_fn(101, 101, g, |i, _| i as f32).unwrap()
    }

    fn view() -> ViewConfig {
        ViewConfig { size_px: dvec2(320.0, 180.0), fov_y_deg: 60.0 }
    }

    #[test]
    fn heights_above_ground_and_look_at_targets_are_placed() {
        let hm = plane();
        let ground = Ground::of(&hm);
        // 500 m east of the origin the ground is at 50 m.
        let spec = parse("384500,3790500,100agl,0,-10", None).unwrap();
        let c = place(Some(&spec), &ground, &view()).unwrap().camera;
        assert!((c.position - dvec3(384_500.0, 3_790_500.0, 150.0)).length() < 1e-6);
        // Looking at the ground 100 m north (z = 50 there): yaw 0, pitch atan(-100 / 100).
        let spec = parse("384500,3790500,150", Some("384500,3790600")).unwrap();
        let c = place(Some(&spec), &ground, &view()).unwrap().camera;
        assert!((c.forward() - dvec3(0.0, 1.0, -1.0).normalize()).length() < 1e-9);
        let (yaw, pitch) = yaw_pitch_towards(DVec3::ZERO, dvec3(1.0, 0.0, 0.0)).unwrap();
        assert!((yaw - 90.0).abs() < 1e-12 && pitch.abs() < 1e-12);
        let e = place(Some(&parse("0,0,0", Some("0,0,0")).unwrap()), &ground, &view());
        assert!(e.unwrap_err().to_string().contains("--look-at"));
    }

    #[test]
    fn lonlat_is_converted_to_the_crs_and_refused_without_one() {
        let hm = plane();
        // -118.25, 34.25 is (384901.104, 3790582.735) on UTM 11N (PROJ's cs2cs).
        let spec = parse("lonlat:-118.25,34.25,10agl,0,-10", None).unwrap();
        let c = place(Some(&spec), &Ground::of(&hm), &view()).unwrap().camera;
        assert!((c.position.truncate() - dvec2(384_901.104, 3_790_582.735)).length() < 0.01);
        assert!(
            (c.position.z - (f64::from(hm.sample_world(c.position.truncate())) + 10.0)).abs()
                < 1e-6
        );
        let local = hm.clone().with_georef(Georef::local(10.0));
        let e = place(Some(&spec), &Ground::of(&local), &view()).unwrap_err();
        assert!(format!("{e:#}").contains("no coordinate reference system"), "{e:#}");
    }

    #[test]
    fn a_camera_under_the_ground_is_lifted_and_said() {
        let hm = plane();
        let spec = parse("384500,3790500,10,0,-10", None).unwrap();
        let p = place(Some(&spec), &Ground::of(&hm), &view()).unwrap();
        assert_eq!(p.lifted_from, Some((10.0, 50.0)));
        assert!((p.camera.position.z - (50.0 + LIFT_CLEARANCE_M)).abs() < 1e-9);
        assert!(p.lift_warning().unwrap().contains("--camera"));
        // Beside the grid there is no ground to be under.
        let spec = parse("380000,3790500,-10,0,-10", None).unwrap();
        assert_eq!(place(Some(&spec), &Ground::of(&hm), &view()).unwrap().lifted_from, None);
    }

    #[test]
    fn cameras_that_see_no_terrain_are_told_why() {
        let hm = plane();
        let ground = Ground::of(&hm);
        let at = |s: &str| place(Some(&parse(s, None).unwrap()), &ground, &view()).unwrap().camera;
        let good = at("384500,3789000,800,0,-30").with_clip(1.0, 1e9);
        assert_eq!(check_view(&hm, &good), None);
        let far = at("384500,-6000000,800,0,0").with_clip(1.0, 1e12);
        let e = check_view(&hm, &far).unwrap();
        assert!(matches!(e, NoTerrain::TooFar { .. }) && e.to_string().contains("--camera"), "{e}");
        let behind = at("384500,3789000,800,180,-30").with_clip(1.0, 1e9);
        let e = check_view(&hm, &behind).unwrap();
        assert_eq!(e, NoTerrain::NotInView { behind: true });
        let frames = frames_without_terrain(&hm, &[good, far, good]);
        assert_eq!(frames.iter().map(|f| f.0).collect::<Vec<_>>(), [1]);
        let w = flight_warning("f", &frames, 3).unwrap();
        assert!(w.contains("1 of 3") && w.contains("frame 2"), "{w}");
        assert_eq!(flight_warning("f", &[], 3), None);
        let sky = at("384500,3789000,800,0,40").with_clip(1.0, 1e9);
        let e = check_view(&hm, &sky).unwrap();
        assert_eq!(e, NoTerrain::NotInView { behind: false });
        assert!(e.to_string().contains("--camera"));
    }
}
