//! SRTM `.hgt` tiles: headerless big-endian int16, north row first, square.
//!
//! The format (NASA SRTM documentation, "SRTM Topography" v2.1): a 1 x 1 degree tile of
//! 1201 x 1201 samples (3 arc-seconds) or 3601 x 3601 (1 arc-second); the side follows from the
//! file length alone. The file name gives the latitude and longitude of the *centre* of the
//! south-west sample (`N41E001` -> 41 N, 1 E; `S` and `W` are negative); edge rows and columns
//! are shared with the neighbouring tiles. Heights are metres above the EGM96 geoid, WGS84
//! horizontal datum (EPSG:4326); voids are -32768.

use std::path::Path;

use glam::dvec2;

use crate::dem::{LoadOptions, RawGrid, check_size};
use crate::error::{DemError, DemErrorKind};
use crate::georef::{Crs, Georef};

/// The SRTM void value.
pub const HGT_NODATA: f64 = -32768.0;

const FORMAT: &str = "SRTM .hgt";

/// Tile sides we accept, with their spacing in arc-seconds.
const SIDES: [(u64, f64); 2] = [(1201, 3.0), (3601, 1.0)];

/// Parses the south-west corner from a tile name such as `N41E001` (case-insensitive, any
/// suffix after the seven characters, e.g. `N41E001.SRTMGL1.hgt`). Returns `(lat, lon)`.
pub fn parse_tile_name(name: &str) -> Option<(i32, i32)> {
    let b = name.as_bytes();
    if b.len() < 7 {
        return None;
    }
    let digits = |s: &[u8]| -> Option<i32> {
        if s.iter().all(u8::is_ascii_digit) {
            std::str::from_utf8(s).ok()?.parse().ok()
        } else {
            None
        }
    };
    let lat_sign = match b[0].to_ascii_uppercase() {
        b'N' => 1,
        b'S' => -1,
        _ => return None,
    };
    let lat = digits(&b[1..3])?;
    let lon_sign = match b[3].to_ascii_uppercase() {
        b'E' => 1,
        b'W' => -1,
        _ => return None,
    };
    let lon = digits(&b[4..7])?;
    if lat > 90 || lon > 180 {
        return None;
    }
    Some((lat_sign * lat, lon_sign * lon))
}

/// Reads a `.hgt` tile of `len` bytes.
pub(crate) fn read(path: &Path, len: u64, options: &LoadOptions) -> Result<RawGrid, DemError> {
    let err = |kind| DemError::new(path, kind);
    let Some(&(side, arcsec)) = SIDES.iter().find(|(s, _)| s * s * 2 == len) else {
        let small = SIDES[0].0 * SIDES[0].0 * 2;
        if len < small {
            return Err(err(DemErrorKind::Truncated {
                what: "SRTM .hgt samples (1201 x 1201 int16)",
                offset: 0,
                expected: small,
                got: len,
            }));
        }
        return Err(err(DemErrorKind::Malformed {
            format: FORMAT,
            message: format!(
                "the file is {len} bytes; a .hgt tile is 2,884,802 bytes (1201 x 1201, 3\") or \
                 25,934,402 bytes (3601 x 3601, 1\")"
            ),
        }));
    };
    // The file's int16 samples are read whole.
    check_size(path, side, side, 2, options)?;
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
    let Some((lat, lon)) = parse_tile_name(name) else {
        return Err(err(DemErrorKind::Malformed {
            format: FORMAT,
            message: format!(
                "the file name {name:?} does not start with a tile name like N41E001 or S09W078, \
                 which is the only georeference a .hgt file has"
            ),
        }));
    };

    let bytes = std::fs::read(path).map_err(|e| err(DemErrorKind::Io(e)))?;
    if bytes.len() as u64 != len {
        // The file changed between the size check and the read.
        return Err(err(DemErrorKind::Truncated {
            what: "SRTM .hgt samples",
            offset: 0,
            expected: len,
            got: bytes.len() as u64,
        }));
    }
    let d = arcsec / 3600.0;
    let georef = Georef::geographic(
        Crs::Epsg(4326),
        dvec2(lon as f64, lat as f64),
        dvec2(d, d),
        lat as f64 + 0.5 * (side - 1) as f64 * d,
    );
    super::refuse_spacing(path, options, "this .hgt tile", &georef)?;
    let side = side as usize;
    let mut data = vec![0f32; side * side];
    let nodata = options.nodata.unwrap_or(HGT_NODATA);
    let (scale, offset) = (options.vertical_scale, options.vertical_offset);
    // File rows are north first; ours are south first. Voids stay NaN through the vertical
    // scale (the options' conversion of the file's metres, if any).
    for (r, row) in bytes.chunks_exact(side * 2).enumerate() {
        let j = side - 1 - r;
        let out = &mut data[j * side..(j + 1) * side];
        for (o, s) in out.iter_mut().zip(row.chunks_exact(2)) {
            let v = f64::from(i16::from_be_bytes([s[0], s[1]]));
            *o = if v == nodata { f32::NAN } else { super::metres(path, v, scale, offset)? };
        }
    }
    Ok(RawGrid {
        width: side,
        height: side,
        data,
        georef,
        nodata: Some(nodata),
        sample_type: "int16".to_string(),
        notes: Vec::new(),
        vertical: (scale, offset),
    })
}

#[cfg(test)]
mod tests {
    use super::parse_tile_name;

    #[test]
    fn tile_names() {
        assert_eq!(parse_tile_name("N41E001.hgt"), Some((41, 1)));
        assert_eq!(parse_tile_name("s09w078.SRTMGL1.hgt"), Some((-9, -78)));
        assert_eq!(parse_tile_name("N41E01.hgt"), None);
        assert_eq!(parse_tile_name("X41E001.hgt"), None);
        assert_eq!(parse_tile_name("N91E001.hgt"), None);
        assert_eq!(parse_tile_name(""), None);
    }
}
