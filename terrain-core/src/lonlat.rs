//! Longitude/latitude (WGS84 degrees) to and from a grid's world frame, both ways: cameras
//! placed by lon/lat (`terrain render --camera lonlat:...`) and, the other way, vertices written
//! with lon/lat (tilesets).
//!
//! Projected CRSs given by an EPSG code (UTM, State Plane, national grids: transverse Mercator,
//! Lambert conformal conic, Albers, stereographic, ...) are converted with `proj4rs`, a pure-Rust
//! port of PROJ's projections, from the EPSG code's proj string (its `crs-definitions` table);
//! native coordinates in feet are converted to the world frame's metres with the georeference's
//! own linear unit. Geographic grids map degrees to the world frame by their equirectangular
//! projection ([`crate::georef`]); an EPSG geographic CRS other than WGS84 gets its datum shift
//! from its proj string, a geographic CRS known only by name takes lon/lat as its own (datums
//! differ by metres to at most a few hundred metres). A grid without a CRS, or a projected CRS
//! without an EPSG code (a GeoTIFF's user-defined projection), has no lon/lat: refused by name.
//!
//! ```
//! use glam::dvec2;
//! use terrain_core::{Crs, Georef, lonlat::LonLat};
//!
//! // A grid on UTM zone 11N (WGS84).
//! let g = Georef::projected(Crs::Epsg(32611), dvec2(376_328.655, 3_788_642.828), dvec2(30.0, 30.0));
//! let ll = LonLat::new(&g).unwrap();
//! let p = ll.to_world(dvec2(-118.25, 34.25)).unwrap();
//! assert!((p - dvec2(384_901.104, 3_790_582.735)).length() < 0.01); // PROJ's cs2cs
//! let back = ll.to_lonlat(p).unwrap();
//! assert!((back - dvec2(-118.25, 34.25)).length() < 1e-9);
//! ```

use glam::{DVec2, dvec2};
use proj4rs::proj::Proj;

use crate::georef::{AngularOrLinear, Crs, Georef};

/// Why lon/lat cannot be converted for a grid, or for a point.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum LonLatError {
    /// The grid has no coordinate reference system (images, raw files, `--spacing` grids).
    #[error(
        "the DEM has no coordinate reference system (CRS {crs}), so longitude/latitude cannot be \
         placed on it; give world coordinates (metres) instead"
    )]
    NoCrs {
        /// The grid's CRS as described.
        crs: String,
    },
    /// The CRS is known but cannot be converted (no EPSG code, or a code without a definition).
    #[error("cannot convert longitude/latitude to the DEM's CRS {crs}: {reason}")]
    Unsupported {
        /// The grid's CRS.
        crs: String,
        /// Why.
        reason: String,
    },
    /// The point is outside the valid range or the projection's domain.
    #[error("longitude {lon}, latitude {lat}: {reason}")]
    OutOfDomain {
        /// Longitude, degrees.
        lon: f64,
        /// Latitude, degrees.
        lat: f64,
        /// Why.
        reason: String,
    },
}

/// The two-way conversion between WGS84 lon/lat (degrees, x = longitude, y = latitude) and one
/// grid's world frame (metres). Build once per grid with [`LonLat::new`].
#[derive(Clone)]
pub struct LonLat {
    /// WGS84 degrees <-> the CRS's native coordinates, or `None` to take lon/lat as native.
    projs: Option<(Proj, Proj)>,
    /// The CRS's native coordinates are degrees (a geographic grid).
    geographic: bool,
    /// World metres per native unit, per axis (the geographic grid's metres per degree at its
    /// centre latitude, or a projected CRS's linear unit).
    scale: DVec2,
    crs: String,
}

impl std::fmt::Debug for LonLat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LonLat")
            .field("crs", &self.crs)
            .field("geographic", &self.geographic)
            .field("scale", &self.scale)
            .finish()
    }
}

/// WGS84 geographic coordinates, as PROJ writes EPSG:4326.
const WGS84: &str = "+proj=longlat +datum=WGS84 +no_defs";

impl LonLat {
    /// The conversion for a grid with georeference `g`; refuses a grid without a usable CRS.
    pub fn new(g: &Georef) -> Result<Self, LonLatError> {
        let crs = g.crs.to_string();
        let unsupported = |reason: String| LonLatError::Unsupported { crs: crs.clone(), reason };
        let geographic = g.units == AngularOrLinear::Degrees;
        let scale = match g.units {
            AngularOrLinear::Degrees => g.spacing_m / g.native_spacing,
            AngularOrLinear::Metres => DVec2::splat(g.linear_unit_m().unwrap_or(1.0)),
        };
        if !(scale.is_finite() && scale.min_element() > 0.0) {
            return Err(unsupported("the georeference's spacing is not positive".into()));
        }
        let projs = match (&g.crs, geographic) {
            (Crs::Unknown, _) => return Err(LonLatError::NoCrs { crs }),
            (Crs::Epsg(4326), true) => None,
            (Crs::Epsg(code), _) => {
                let code16 = u16::try_from(*code)
                    .map_err(|_| unsupported(format!("EPSG:{code} has no definition here")))?;
                let native = Proj::from_epsg_code(code16).map_err(|e| {
                    unsupported(format!("EPSG:{code} has no projection definition here ({e})"))
                })?;
                if native.is_latlong() != geographic {
                    return Err(unsupported(format!(
                        "EPSG:{code} is {} but the file's georeference is {}",
                        if native.is_latlong() { "geographic" } else { "projected" },
                        if geographic { "in degrees" } else { "in linear units" }
                    )));
                }
                let wgs84 = Proj::from_proj_string(WGS84).expect("WGS84's proj string");
                Some((wgs84, native))
            }
            (Crs::Text(_), true) => None,
            (Crs::Text(_), false) => {
                return Err(unsupported(
                    "a projected CRS without an EPSG code (user-defined) is not converted; \
                     give world coordinates (metres) instead"
                        .into(),
                ));
            }
        };
        Ok(Self { projs, geographic, scale, crs })
    }

    /// The grid's CRS, as described in messages.
    pub fn crs(&self) -> &str {
        &self.crs
    }

    /// World position (metres) of WGS84 `lonlat` (degrees: x = longitude, y = latitude).
    pub fn to_world(&self, lonlat: DVec2) -> Result<DVec2, LonLatError> {
        let (lon, lat) = (lonlat.x, lonlat.y);
        let domain = |reason: String| LonLatError::OutOfDomain { lon, lat, reason };
        if !(lonlat.is_finite() && (-180.0..=180.0).contains(&lon) && (-90.0..=90.0).contains(&lat))
        {
            return Err(domain(
                "longitude must be within -180..180 and latitude within -90..90 degrees".into(),
            ));
        }
        let native = match &self.projs {
            None => lonlat,
            Some((wgs84, native)) => {
                let mut p = (lon.to_radians(), lat.to_radians(), 0.0);
                proj4rs::transform::transform(wgs84, native, &mut p)
                    .map_err(|e| domain(format!("outside the projection of {} ({e})", self.crs)))?;
                if self.geographic {
                    dvec2(p.0.to_degrees(), p.1.to_degrees())
                } else {
                    dvec2(p.0, p.1)
                }
            }
        };
        let world = native * self.scale;
        if !world.is_finite() {
            return Err(domain(format!("outside the projection of {}", self.crs)));
        }
        Ok(world)
    }

    /// [`LonLat::to_world`], with a geographic grid's longitude taken modulo 360 degrees to land
    /// nearest world position `near` (the grid's centre, say): a grid in the 0..360 convention
    /// (ocean and climate grids) or one crossing 180 is then found from -180..180 longitudes.
    /// Projected grids are unaffected.
    pub fn to_world_near(&self, lonlat: DVec2, near: DVec2) -> Result<DVec2, LonLatError> {
        let w = self.to_world(lonlat)?;
        if !self.geographic {
            return Ok(w);
        }
        let turn = 360.0 * self.scale.x;
        let k = ((near.x - w.x) / turn).round();
        Ok(dvec2(w.x + k * turn, w.y))
    }

    /// WGS84 lon/lat (degrees: x = longitude, y = latitude) of world position `world` (metres);
    /// the inverse of [`LonLat::to_world`].
    pub fn to_lonlat(&self, world: DVec2) -> Result<DVec2, LonLatError> {
        let native = world / self.scale;
        let out = |reason: String| LonLatError::OutOfDomain {
            lon: f64::NAN,
            lat: f64::NAN,
            reason: format!("world position ({}, {}) {reason}", world.x, world.y),
        };
        let ll = match &self.projs {
            None => native,
            Some((wgs84, proj)) => {
                let mut p = if self.geographic {
                    (native.x.to_radians(), native.y.to_radians(), 0.0)
                } else {
                    (native.x, native.y, 0.0)
                };
                proj4rs::transform::transform(proj, wgs84, &mut p)
                    .map_err(|e| out(format!("is outside the projection of {} ({e})", self.crs)))?;
                dvec2(p.0.to_degrees(), p.1.to_degrees())
            }
        };
        if !ll.is_finite() {
            return Err(out(format!("is outside the projection of {}", self.crs)));
        }
        Ok(ll)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Reference values from PROJ 9 (`echo LAT LON | cs2cs -f %.4f EPSG:4326 EPSG:code`): the
    /// conversion must agree with PROJ, the source of truth, to a centimetre.
    #[test]
    fn projected_crs_agree_with_proj() {
        let cases = [
            // UTM 11N (WGS84), UTM 15N (NAD83), Pennsylvania South (NAD83, US survey feet).
            (32611, 1.0, dvec2(-118.25, 34.25), dvec2(384901.1043, 3790582.7345)),
            (26915, 1.0, dvec2(-96.5, 45.0), dvec2(224146.2710, 4988911.8385)),
            (2272, 1200.0 / 3937.0, dvec2(-75.5, 40.0), dvec2(2598792.4328, 250887.2426)),
        ];
        for (code, unit, ll, native) in cases {
            let g = Georef::projected_in(Crs::Epsg(code), native, DVec2::ONE, unit);
            let c = LonLat::new(&g).unwrap();
            let w = c.to_world(ll).unwrap();
            assert!((w / unit - native).length() < 0.01, "EPSG:{code}: {w} vs {native}");
            let back = c.to_lonlat(w).unwrap();
            assert!((back - ll).length() < 1e-8, "EPSG:{code}: {back} vs {ll}");
        }
    }

    #[test]
    fn geographic_grids_use_their_equirectangular_frame() {
        let spacing = DVec2::splat(1.0 / 1200.0);
        let g = Georef::geographic(Crs::Epsg(4326), dvec2(-122.0, 46.5), spacing, 47.0);
        let c = LonLat::new(&g).unwrap();
        // Sample (600, 300) is at lon -121.5, lat 46.75.
        let expect = g.grid_to_world(dvec2(600.0, 300.0));
        let w = c.to_world(dvec2(-121.5, 46.75)).unwrap();
        assert!((w - expect).length() < 1e-6, "{w} vs {expect}");
        assert!((c.to_lonlat(w).unwrap() - dvec2(-121.5, 46.75)).length() < 1e-12);
        // A geographic CRS known by name only: lon/lat taken as its own.
        let named = Georef { crs: Crs::Text("NAD27".into()), ..g.clone() };
        let w2 = LonLat::new(&named).unwrap().to_world(dvec2(-121.5, 46.75)).unwrap();
        assert!((w2 - expect).length() < 1e-6);
        // NAD83 (EPSG:4269) goes through its datum: within a metre of WGS84 here.
        let nad83 = Georef { crs: Crs::Epsg(4269), ..g };
        let w3 = LonLat::new(&nad83).unwrap().to_world(dvec2(-121.5, 46.75)).unwrap();
        assert!((w3 - expect).length() < 2.0, "{w3} vs {expect}");
    }

    #[test]
    fn grids_without_a_usable_crs_are_refused_by_name() {
        // A grid in 0..360 longitudes is found from -180..180 ones, and near 180 either way.
        let east =
            Georef::geographic(Crs::Epsg(4326), dvec2(234.0, 48.0), DVec2::splat(0.25), 49.0);
        let c = LonLat::new(&east).unwrap();
        let centre = east.grid_to_world(dvec2(8.0, 4.0));
        let w = c.to_world_near(dvec2(-124.5, 48.5), centre).unwrap();
        assert!((w.x / c.scale.x - 235.5).abs() < 1e-9, "{w}");
        // Near the -180..180 place, the longitude stays as given.
        let west = c.to_world(dvec2(-124.0, 48.0)).unwrap();
        assert_eq!(c.to_world_near(dvec2(-124.5, 48.5), west), c.to_world(dvec2(-124.5, 48.5)));
        let e = LonLat::new(&Georef::local(10.0)).unwrap_err();
        assert!(matches!(e, LonLatError::NoCrs { .. }), "{e}");
        assert!(e.to_string().contains("no coordinate reference system"), "{e}");
        let user = Georef::projected(Crs::Text("my TM".into()), DVec2::ZERO, DVec2::ONE);
        let e = LonLat::new(&user).unwrap_err();
        assert!(e.to_string().contains("my TM") && e.to_string().contains("EPSG"), "{e}");
        // A projected code on a grid in degrees is a contradiction, said as such.
        let wrong = Georef::geographic(Crs::Epsg(32611), DVec2::ZERO, DVec2::ONE, 0.0);
        let e = LonLat::new(&wrong).unwrap_err();
        assert!(e.to_string().contains("projected"), "{e}");
        let ok = LonLat::new(&Georef::projected(Crs::Epsg(32611), DVec2::ZERO, DVec2::ONE));
        let e = ok.unwrap().to_world(dvec2(200.0, 0.0)).unwrap_err();
        assert!(matches!(e, LonLatError::OutOfDomain { .. }), "{e}");
    }
}
