//! Georeference: where a grid sits on the Earth, its CRS, and its spacing in metres.
//!
//! The engine works in one *world frame*: right-handed, x east, y north, z up, metres, with
//! f64 coordinates so projected origins (UTM eastings of 500 000 m, northings of 4 000 000 m)
//! keep millimetre precision. Projected grids use their CRS coordinates directly. Geographic
//! grids (EPSG:4326, spacing in degrees) are mapped by an equirectangular projection at the
//! grid's centre latitude, with the WGS84 lengths of a degree there (the standard series for
//! the meridian and parallel arc lengths), so the spacing in metres is exact at the centre.

use glam::{DVec2, dvec2};

/// A coordinate reference system as far as the engine needs it.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
#[non_exhaustive]
pub enum Crs {
    /// An EPSG code (e.g. 4326, 32611, 26915).
    Epsg(u32),
    /// A textual description the file carried (e.g. a GeoTIFF citation) without an EPSG code.
    Text(String),
    /// The file carried no georeference (images, raw grids).
    Unknown,
}

impl std::fmt::Display for Crs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Crs::Epsg(c) => write!(f, "EPSG:{c}"),
            Crs::Text(t) => write!(f, "{t}"),
            Crs::Unknown => write!(f, "unknown (local metres)"),
        }
    }
}

/// Units of the CRS's horizontal axes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum AngularOrLinear {
    /// Projected: a linear unit. Metres for most CRSs; for a CRS in feet (EPSG:2272, US survey
    /// feet) the native origin and spacing stay in feet and `spacing_m` / `world_origin` are
    /// converted ([`Georef::projected_in`]; [`Georef::linear_unit_m`] gives the unit).
    Metres,
    /// Geographic: degrees of longitude (x) and latitude (y).
    Degrees,
}

/// Metres per degree of latitude at latitude `lat_deg` on the WGS84 ellipsoid.
pub fn metres_per_degree_lat(lat_deg: f64) -> f64 {
    let p = lat_deg.to_radians();
    111_132.92 - 559.82 * (2.0 * p).cos() + 1.175 * (4.0 * p).cos() - 0.0023 * (6.0 * p).cos()
}

/// Metres per degree of longitude at latitude `lat_deg` on the WGS84 ellipsoid.
pub fn metres_per_degree_lon(lat_deg: f64) -> f64 {
    let p = lat_deg.to_radians();
    111_412.84 * p.cos() - 93.5 * (3.0 * p).cos() + 0.118 * (5.0 * p).cos()
}

/// Where a grid sits: CRS, native origin and spacing, and the world-frame mapping.
///
/// `native_origin` is the CRS coordinate of the *centre* of sample `(0, 0)`, the south-west
/// sample (grids are stored south row first). `spacing_m` is the metric spacing the engine
/// uses for geometry; `world_origin` is sample `(0, 0)` in the world frame.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Georef {
    /// The coordinate reference system.
    pub crs: Crs,
    /// Units of `native_origin` and `native_spacing`.
    pub units: AngularOrLinear,
    /// CRS coordinates of the centre of sample (0, 0) (south-west).
    pub native_origin: DVec2,
    /// Spacing in CRS units (x east, y north), both positive.
    pub native_spacing: DVec2,
    /// Spacing in metres (x east, y north), both positive.
    pub spacing_m: DVec2,
    /// World-frame position (metres) of sample (0, 0).
    pub world_origin: DVec2,
}

impl Georef {
    /// A local metric frame with no CRS: origin at (0, 0), the given spacing in metres.
    pub fn local(spacing_m: f64) -> Self {
        Self::projected(Crs::Unknown, DVec2::ZERO, dvec2(spacing_m, spacing_m))
    }

    /// A projected (metric) CRS: world coordinates are the CRS's coordinates.
    pub fn projected(crs: Crs, origin: DVec2, spacing: DVec2) -> Self {
        Self {
            crs,
            units: AngularOrLinear::Metres,
            native_origin: origin,
            native_spacing: spacing,
            spacing_m: spacing,
            world_origin: origin,
        }
    }

    /// A projected CRS whose linear unit is `unit_m` metres (1 for metres, 0.3048 for the
    /// international foot, 1200/3937 for the US survey foot): native coordinates stay in the
    /// CRS's unit; the world frame and `spacing_m` are in metres.
    pub fn projected_in(crs: Crs, origin: DVec2, spacing: DVec2, unit_m: f64) -> Self {
        Self {
            spacing_m: spacing * unit_m,
            world_origin: origin * unit_m,
            ..Self::projected(crs, origin, spacing)
        }
    }

    /// Metres per native unit of a projected georeference (1 unless its CRS is in feet or
    /// another linear unit); `None` for a geographic one.
    pub fn linear_unit_m(&self) -> Option<f64> {
        match self.units {
            AngularOrLinear::Degrees => None,
            AngularOrLinear::Metres if self.native_spacing.x > 0.0 => {
                Some(self.spacing_m.x / self.native_spacing.x)
            }
            AngularOrLinear::Metres => Some(1.0),
        }
    }

    /// A geographic CRS (degrees). `center_lat` is the grid's centre latitude, where the
    /// metric spacing is computed; the world frame is the equirectangular projection there.
    pub fn geographic(crs: Crs, origin_deg: DVec2, spacing_deg: DVec2, center_lat: f64) -> Self {
        let mx = metres_per_degree_lon(center_lat);
        let my = metres_per_degree_lat(center_lat);
        Self {
            crs,
            units: AngularOrLinear::Degrees,
            native_origin: origin_deg,
            native_spacing: spacing_deg,
            spacing_m: dvec2(spacing_deg.x * mx, spacing_deg.y * my),
            world_origin: dvec2(origin_deg.x * mx, origin_deg.y * my),
        }
    }

    /// World position (metres) of fractional grid coordinates `g` (in samples).
    #[inline]
    pub fn grid_to_world(&self, g: DVec2) -> DVec2 {
        self.world_origin + g * self.spacing_m
    }

    /// Fractional grid coordinates of world position `p`.
    #[inline]
    pub fn world_to_grid(&self, p: DVec2) -> DVec2 {
        (p - self.world_origin) / self.spacing_m
    }

    /// CRS coordinates of fractional grid coordinates `g`.
    #[inline]
    pub fn grid_to_native(&self, g: DVec2) -> DVec2 {
        self.native_origin + g * self.native_spacing
    }

    /// The same georeference moved so that sample `(di, dj)` of this grid becomes sample (0, 0)
    /// (used to cut sub-grids and to place mosaic tiles).
    pub fn offset_samples(&self, di: f64, dj: f64) -> Self {
        let d = dvec2(di, dj);
        Self {
            native_origin: self.native_origin + d * self.native_spacing,
            world_origin: self.world_origin + d * self.spacing_m,
            ..self.clone()
        }
    }
}
