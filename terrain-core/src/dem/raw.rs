//! Headerless raw grids: little-endian int16, uint16 or float32 samples, rows north first.
//!
//! There is no header, so the dimensions and sample type come from [`RawSpec`](super::RawSpec); the file length
//! must be exactly `width x height x bytes per sample`. Heights are
//! `raw x vertical_scale + vertical_offset`; there is no georeference, so the grid is placed in
//! a local metric frame with `LoadOptions::spacing_m`.

use std::path::Path;

use crate::dem::{LoadOptions, RawGrid, RawSampleType, check_size};
use crate::error::{DemError, DemErrorKind};
use crate::georef::Georef;

/// Reads a raw file of `len` bytes with the dimensions in `options.raw`.
pub(crate) fn read(path: &Path, len: u64, options: &LoadOptions) -> Result<RawGrid, DemError> {
    let err = |kind| DemError::new(path, kind);
    let Some(spec) = options.raw else {
        return Err(err(DemErrorKind::InvalidOptions(
            "a raw file needs its size and sample type: --raw WIDTHxHEIGHT:TYPE (TYPE f32, i16 or u16)".to_string(),
        )));
    };
    let (bytes_per, name) = match spec.sample {
        RawSampleType::I16 => (2u64, "int16"),
        RawSampleType::U16 => (2, "uint16"),
        RawSampleType::F32 => (4, "float32"),
    };
    // The file's samples are read whole.
    check_size(path, spec.width, spec.height, bytes_per, options)?;
    // check_size bounded width * height, so this cannot overflow.
    let expected = spec.width * spec.height * bytes_per;
    if len != expected {
        return Err(err(DemErrorKind::InvalidOptions(format!(
            "raw {} x {} {name} needs exactly {expected} bytes, the file has {len} bytes",
            spec.width, spec.height
        ))));
    }
    let bytes = std::fs::read(path).map_err(|e| err(DemErrorKind::Io(e)))?;
    if bytes.len() as u64 != expected {
        return Err(err(DemErrorKind::Truncated {
            what: "raw samples",
            offset: 0,
            expected,
            got: bytes.len() as u64,
        }));
    }
    let (w, h) = (spec.width as usize, spec.height as usize);
    let (scale, offset) = (options.vertical_scale, options.vertical_offset);
    let nodata = options.nodata;
    let mut data = vec![0f32; w * h];
    let row_bytes = w * bytes_per as usize;
    for (r, row) in bytes.chunks_exact(row_bytes).enumerate() {
        let j = h - 1 - r; // file rows are north first
        let out = &mut data[j * w..(j + 1) * w];
        for (o, s) in out.iter_mut().zip(row.chunks_exact(bytes_per as usize)) {
            let v = match spec.sample {
                RawSampleType::I16 => i16::from_le_bytes([s[0], s[1]]) as f64,
                RawSampleType::U16 => u16::from_le_bytes([s[0], s[1]]) as f64,
                RawSampleType::F32 => f32::from_le_bytes([s[0], s[1], s[2], s[3]]) as f64,
            };
            // No-data is a raw value: keep it as it is (NaN) so the void mask finds it.
            *o = if nodata.is_some_and(|nd| v == nd) || !v.is_finite() {
                f32::NAN
            } else {
                super::metres(path, v, scale, offset)?
            };
        }
    }
    Ok(RawGrid {
        width: w,
        height: h,
        data,
        georef: Georef::local(options.spacing_m),
        nodata,
        sample_type: name.to_string(),
        notes: Vec::new(),
        vertical: (scale, offset),
    })
}
