//! The PVS file (`pvs.bin` in a scene): a header with magic, version, mode and the whole
//! [`PvsLayout`], the per-cell bit pyramids packed as bit fields (the geomorphing article's
//! "one bit per patch"), and a CRC-32 of everything before it.
//!
//! Layout, little-endian:
//! ```text
//! magic "TPVS" | version u32 = 2 | mode u8 (0 sampled, 1 conservative) | patch_level u8 |
//! 2 bytes zero | width u32 | height u32 | root_cells u32 | cells_x u32 | cells_y u32 |
//! floors u32 | floor_height_m f64 | origin 2 x f64 | spacing 2 x f64 |
//! heights u32 (CRC-32 of the heights and void mask baked, as in the DSS table) |
//! bases: cells_x cells_y x (bottom f32, top f32) |
//! bits: cells_x cells_y floors x bytes_per_cell | crc32 u32 (of all bytes before it)
//! ```
//!
//! Version 1 had no `heights`: a stale PVS (same grid size, other heights) could not be told
//! from a good one. Version 1 files are refused with a message to bake again.

use std::path::{Path, PathBuf};

use glam::DVec2;

use super::{Pvs, PvsLayout, PvsMode};

/// The file's magic bytes.
pub const MAGIC: [u8; 4] = *b"TPVS";
/// The format version this code writes and reads.
pub const VERSION: u32 = 2;
const HEADER_BYTES: usize = 4 + 4 + 4 + 6 * 4 + 8 + 4 * 8 + 4;

/// Why a PVS file could not be read or written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PvsFileError {
    /// The file could not be opened, read or written.
    #[error("{}: {cause}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error (in the message; not an error `source`, so an error chain prints it
        /// once).
        cause: std::io::Error,
    },
    /// The file is not a PVS file, is truncated or corrupt.
    #[error("{path}: {problem}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        problem: String,
    },
    /// The file was written by another version of the format.
    #[error(
        "{path}: {}: bake the scene again (terrain bake)",
        if *found < VERSION {
            format!("baked by an older version of terrain (PVS format {found}, this one reads {VERSION})")
        } else {
            format!("baked by a newer version of terrain (PVS format {found}, this one reads {VERSION})")
        }
    )]
    Version {
        /// The file.
        path: PathBuf,
        /// The version found.
        found: u32,
    },
}

pub use terrain_core::checksum::crc32;

/// The file's bytes.
pub fn encode(pvs: &Pvs) -> Vec<u8> {
    let l = &pvs.layout;
    let mut out = Vec::with_capacity(HEADER_BYTES + l.bases.len() * 8 + pvs.bits.len() + 4);
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.push(match pvs.mode {
        PvsMode::Sampled => 0,
        PvsMode::Conservative => 1,
    });
    out.push(l.patch_level);
    out.extend_from_slice(&[0, 0]);
    for v in [l.width, l.height, l.root_cells, l.cells_x, l.cells_y, l.floors] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for v in [l.floor_height_m, l.origin.x, l.origin.y, l.spacing.x, l.spacing.y] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&l.heights.to_le_bytes());
    for &(a, b) in &l.bases {
        out.extend_from_slice(&a.to_le_bytes());
        out.extend_from_slice(&b.to_le_bytes());
    }
    out.extend_from_slice(&pvs.bits);
    let crc = crc32(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

/// Parses the file's bytes; `path` names the file in errors.
pub fn decode(bytes: &[u8], path: &Path) -> Result<Pvs, PvsFileError> {
    let corrupt = |problem: String| PvsFileError::Corrupt { path: path.to_path_buf(), problem };
    if bytes.len() < 8 || bytes[..4] != MAGIC {
        return Err(corrupt("not a PVS file (no TPVS magic)".into()));
    }
    let version = u32::from_le_bytes(bytes[4..8].try_into().expect("4 bytes"));
    if version != VERSION {
        return Err(PvsFileError::Version { path: path.to_path_buf(), found: version });
    }
    if bytes.len() < HEADER_BYTES + 4 {
        return Err(corrupt(format!(
            "truncated: {} bytes, the header alone is {HEADER_BYTES}",
            bytes.len()
        )));
    }
    let (body, tail) = bytes.split_at(bytes.len() - 4);
    let stored = u32::from_le_bytes(tail.try_into().expect("4 bytes"));
    let u32_at = |o: usize| u32::from_le_bytes(body[o..o + 4].try_into().expect("4 bytes"));
    let f64_at = |o: usize| f64::from_le_bytes(body[o..o + 8].try_into().expect("8 bytes"));
    let mode = match body[8] {
        0 => PvsMode::Sampled,
        1 => PvsMode::Conservative,
        m => return Err(corrupt(format!("unknown mode {m}"))),
    };
    let patch_level = body[9];
    let [width, height, root_cells, cells_x, cells_y, floors] =
        std::array::from_fn(|k| u32_at(12 + 4 * k));
    let [floor_height_m, ox, oy, sx, sy] = std::array::from_fn(|k| f64_at(36 + 8 * k));
    let heights = u32_at(76);
    if patch_level > 12
        || width < 2
        || height < 2
        || cells_x == 0
        || cells_y == 0
        || floors == 0
        || !root_cells.is_power_of_two()
        // Saturating: three u32 counts can overflow even 64 bits (a hostile header).
        || u64::from(cells_x).saturating_mul(u64::from(cells_y)).saturating_mul(u64::from(floors))
            > 1 << 24
    {
        return Err(corrupt("implausible header values".into()));
    }
    let plan = (cells_x * cells_y) as usize;
    let mut layout = PvsLayout {
        width,
        height,
        root_cells,
        patch_level,
        cells_x,
        cells_y,
        floors,
        floor_height_m,
        origin: DVec2::new(ox, oy),
        spacing: DVec2::new(sx, sy),
        bases: Vec::new(),
        heights,
    };
    let bits_len = layout.cell_count() * layout.bytes_per_cell();
    let expected = HEADER_BYTES + plan * 8 + bits_len;
    if body.len() != expected {
        return Err(corrupt(format!(
            "truncated or padded: {} bytes, the header says {}",
            bytes.len(),
            expected + 4
        )));
    }
    let crc = crc32(body);
    if crc != stored {
        return Err(corrupt(format!(
            "checksum mismatch (stored {stored:08x}, computed {crc:08x})"
        )));
    }
    layout.bases = body[HEADER_BYTES..HEADER_BYTES + plan * 8]
        .chunks_exact(8)
        .map(|c| {
            (
                f32::from_le_bytes(c[..4].try_into().expect("4 bytes")),
                f32::from_le_bytes(c[4..].try_into().expect("4 bytes")),
            )
        })
        .collect();
    Ok(Pvs { layout, mode, bits: body[HEADER_BYTES + plan * 8..].to_vec() })
}

/// Writes `pvs` to `path` (through a temporary file renamed when complete).
pub fn write_pvs(pvs: &Pvs, path: &Path) -> Result<u64, PvsFileError> {
    let bytes = encode(pvs);
    let tmp = path.with_extension("bin.tmp");
    let io = |cause| PvsFileError::Io { path: path.to_path_buf(), cause };
    std::fs::write(&tmp, &bytes).map_err(io)?;
    std::fs::rename(&tmp, path).map_err(io)?;
    Ok(bytes.len() as u64)
}

/// Reads a PVS file.
pub fn read_pvs(path: &Path) -> Result<Pvs, PvsFileError> {
    let bytes = std::fs::read(path)
        .map_err(|cause| PvsFileError::Io { path: path.to_path_buf(), cause })?;
    decode(&bytes, path)
}
