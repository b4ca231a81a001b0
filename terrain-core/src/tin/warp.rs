//! Grids onto longitude/latitude for the TIN pyramid: projected grids resampled onto a
//! geographic grid ([`to_geographic`]), grids without a georeference placed by the user
//! ([`place`]).
//!
//! Resampling is the standard inverse mapping of image warping (as `gdalwarp` does): each
//! output sample's longitude/latitude is projected into the source grid with
//! [`crate::lonlat::LonLat`] (`proj4rs`, pure Rust) and read bilinearly there; an output sample
//! outside the source, or next to a source void, is void (then filled as the readers fill
//! voids, and never measured). The output keeps the source's metric resolution at its centre.

use glam::{DVec2, dvec2};

use crate::dem::voids::fill_voids;
use crate::georef::{AngularOrLinear, Crs, Georef, metres_per_degree_lat, metres_per_degree_lon};
use crate::heightmap::{Heightmap, HeightmapError, VoidMask};
use crate::lonlat::{LonLat, LonLatError};

/// Most output samples a warp may produce, as a multiple of the source's (a projection that
/// blows the grid up this much is a wrong CRS, not a DEM).
const MAX_GROWTH: f64 = 4.0;

/// Why a grid could not be put on longitude/latitude.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum WarpError {
    /// The grid's CRS cannot be converted.
    #[error(transparent)]
    LonLat(#[from] LonLatError),
    /// The geographic grid would be far larger than the source.
    #[error(
        "reprojected to longitude/latitude the grid would be {width} x {height} samples, more \
         than {MAX_GROWTH} times the source's: is the CRS right?"
    )]
    TooLarge {
        /// Columns.
        width: usize,
        /// Rows.
        height: usize,
    },
    /// The resampled grid could not be built (every sample void, ...).
    #[error("the reprojected grid: {0}")]
    Grid(#[from] HeightmapError),
    /// The placement is not a longitude/latitude on the Earth or the grid does not fit there.
    #[error("cannot place the grid at longitude {lon}, latitude {lat}: {reason}")]
    Placement {
        /// Longitude.
        lon: f64,
        /// Latitude.
        lat: f64,
        /// Why.
        reason: String,
    },
}

/// The geographic georeference of a grid of `size` samples at `spacing_deg` from `origin`.
fn geographic(origin: DVec2, spacing_deg: DVec2, size: (usize, usize)) -> Georef {
    let centre_lat = origin.y + 0.5 * (size.1 as f64 - 1.0) * spacing_deg.y;
    Georef::geographic(Crs::Epsg(4326), origin, spacing_deg, centre_lat)
}

/// Places a grid without a georeference with its sample (0, 0) (south-west) at `sw_lonlat`
/// (degrees): its metric spacing becomes degrees at its centre latitude (an equirectangular
/// placement, exact at the centre). The heights are unchanged.
pub fn place(hm: &Heightmap, sw_lonlat: DVec2) -> Result<Heightmap, WarpError> {
    let g = place_georef(hm.georef(), (hm.width(), hm.height()), sw_lonlat)?;
    Ok(hm.clone().with_georef(g))
}

/// The geographic georeference [`place`] gives a grid of `size` samples whose georeference is
/// `georef` (its metric spacing is kept): for grids read without loading them (a store).
pub fn place_georef(
    georef: &Georef,
    size: (usize, usize),
    sw_lonlat: DVec2,
) -> Result<Georef, WarpError> {
    let (lon, lat) = (sw_lonlat.x, sw_lonlat.y);
    let refuse = |reason: &str| WarpError::Placement { lon, lat, reason: reason.into() };
    if !(sw_lonlat.is_finite() && (-180.0..=180.0).contains(&lon) && (-90.0..=90.0).contains(&lat))
    {
        return Err(refuse("not within longitude -180..180, latitude -90..90"));
    }
    let s = georef.spacing_m;
    let cells = dvec2(size.0.saturating_sub(1) as f64, size.1.saturating_sub(1) as f64);
    let extent_m = cells * s;
    let centre_lat = lat + 0.5 * extent_m.y / metres_per_degree_lat(lat);
    let spacing =
        dvec2(s.x / metres_per_degree_lon(centre_lat), s.y / metres_per_degree_lat(centre_lat));
    let ne = sw_lonlat + spacing * cells;
    if !(ne.is_finite() && ne.x <= 180.0 && ne.y <= 90.0) || centre_lat.abs() >= 89.0 {
        return Err(refuse("the grid would reach beyond longitude 180 or latitude 90 from there"));
    }
    Ok(geographic(sw_lonlat, spacing, size))
}

/// The grid resampled onto longitude/latitude (EPSG:4326) at the source's resolution; a grid
/// already in degrees is returned as it is.
pub fn to_geographic(hm: &Heightmap) -> Result<Heightmap, WarpError> {
    let g = hm.georef();
    if g.units == AngularOrLinear::Degrees {
        return Ok(hm.clone());
    }
    let ll = LonLat::new(g)?;
    let (w, h) = (hm.width(), hm.height());
    // The lon/lat box of the border, walked at 64 points per side.
    let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
    let n = 64;
    for k in 0..=n {
        let t = k as f64 / n as f64;
        let (fw, fh) = ((w - 1) as f64, (h - 1) as f64);
        for gp in [dvec2(t * fw, 0.0), dvec2(t * fw, fh), dvec2(0.0, t * fh), dvec2(fw, t * fh)] {
            let p = ll.to_lonlat(hm.grid_to_world(gp.x, gp.y))?;
            lo = lo.min(p);
            hi = hi.max(p);
        }
    }
    let centre_lat = 0.5 * (lo.y + hi.y);
    let s = g.spacing_m;
    let spacing =
        dvec2(s.x / metres_per_degree_lon(centre_lat), s.y / metres_per_degree_lat(centre_lat));
    let ow = ((hi.x - lo.x) / spacing.x).ceil() as usize + 1;
    let oh = ((hi.y - lo.y) / spacing.y).ceil() as usize + 1;
    if (ow as f64) * (oh as f64) > MAX_GROWTH * (w as f64) * (h as f64) {
        return Err(WarpError::TooLarge { width: ow, height: oh });
    }
    let mut data = vec![0.0f32; ow * oh];
    let mut voids = VoidMask::new(ow, oh);
    let src_voids = hm.voids().any().then(|| hm.voids());
    for j in 0..oh {
        for i in 0..ow {
            let lonlat = lo + spacing * dvec2(i as f64, j as f64);
            let gp = ll.to_world(lonlat).map(|p| hm.world_to_grid(p));
            let inside = |gp: &DVec2| {
                gp.x >= 0.0 && gp.y >= 0.0 && gp.x <= (w - 1) as f64 && gp.y <= (h - 1) as f64
            };
            match gp {
                Ok(gp) if inside(&gp) => {
                    let (i0, j0) = (gp.x.floor() as usize, gp.y.floor() as usize);
                    let near_void = src_voids.is_some_and(|m| {
                        let (i1, j1) = ((i0 + 1).min(w - 1), (j0 + 1).min(h - 1));
                        m.get(i0, j0) || m.get(i1, j0) || m.get(i0, j1) || m.get(i1, j1)
                    });
                    if near_void {
                        voids.set(i, j, true);
                    } else {
                        data[j * ow + i] = hm.sample_grid(gp.x, gp.y);
                    }
                }
                _ => voids.set(i, j, true),
            }
        }
    }
    fill_voids(ow, oh, &mut data, &voids)?;
    Ok(Heightmap::new(ow, oh, data, voids, geographic(lo, spacing, (ow, oh)))?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_utm_plane_stays_a_plane_and_lands_where_proj_puts_it() {
        // A tilted plane on UTM 11N, 200 x 150 samples at 30 m.
        let origin = dvec2(384_901.104, 3_790_582.735); // lon -118.25, lat 34.25 (PROJ)
        let g = Georef::projected(Crs::Epsg(32611), origin, dvec2(30.0, 30.0));
        let plane = |x: f64, y: f64| (0.01 * x + 0.02 * y) as f32;
        let hm = Heightmap::from_fn(200, 150, g.clone(), |i, j| {
            let p = g.grid_to_world(dvec2(i as f64, j as f64)) - origin;
            plane(p.x, p.y)
        })
        .unwrap();
        let geo = to_geographic(&hm).unwrap();
        let gg = geo.georef();
        assert_eq!(gg.units, AngularOrLinear::Degrees);
        // The south-west corner is within one output sample of -118.25, 34.25.
        assert!((gg.native_origin - dvec2(-118.25, 34.25)).abs().max_element() < 2e-3);
        let ll = LonLat::new(hm.georef()).unwrap();
        let mut checked = 0;
        for j in (0..geo.height()).step_by(7) {
            for i in (0..geo.width()).step_by(7) {
                if geo.voids().get(i, j) {
                    continue;
                }
                let lonlat = gg.grid_to_native(dvec2(i as f64, j as f64));
                let p = ll.to_world(lonlat).unwrap() - origin;
                let want = plane(p.x, p.y);
                assert!((geo.get(i, j) - want).abs() < 1e-3, "({i}, {j}): {}", geo.get(i, j));
                checked += 1;
            }
        }
        assert!(checked > 400, "{checked}");
        // Same resolution: about as many samples per metre (the box grows by the rotation).
        let ratio = (geo.width() * geo.height()) as f64 / (200.0 * 150.0);
        assert!((1.0..1.2).contains(&ratio), "{ratio}");
    }

    #[test]
    fn grids_without_a_crs_are_refused_and_placement_is_checked() {
        let hm = Heightmap::from_fn(11, 11, Georef::local(100.0), |_, _| 1.0).unwrap();
        assert!(matches!(to_geographic(&hm), Err(WarpError::LonLat(LonLatError::NoCrs { .. }))));
        let placed = place(&hm, dvec2(-122.0, 47.0)).unwrap();
        let g = placed.georef();
        // 1 km north is about 0.009 degrees of latitude.
        let north = g.native_spacing.y * 10.0;
        assert!((north - 1000.0 / metres_per_degree_lat(47.0045)).abs() < 1e-9, "{north}");
        assert!((g.spacing_m - dvec2(100.0, 100.0)).abs().max_element() < 1e-6);
        assert!(place(&hm, dvec2(179.999, 0.0)).is_err());
        assert!(place(&hm, dvec2(f64::NAN, 0.0)).is_err());
    }
}
