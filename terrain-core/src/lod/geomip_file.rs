//! The geomorph method's per-patch table as bytes (`geomip.bin` in a store folder that
//! `terrain bake` writes): the article's max-error vertices are computed "in preprocessing"
//! (Wagner 2003), so a store's runtime reads them instead of the heightmap.
//!
//! Layout (little-endian):
//!
//! ```text
//! magic "TGMP" | version u32 = 1 | width u32 | height u32 | patch_cells u32 | levels u32 |
//! patches_x u32 | patches_y u32 | heights u32 (CRC-32 of the heightmap's samples and void
//! mask, see `dss_file::heights_checksum`) |
//! per patch, row-major from the south, per level 1 .. levels - 1:
//!   error f32 (monotone, rounded up) | height f32 | vertex u16 (dj (P + 1) + di) |
//! crc32 u32 (of every byte before it)
//! ```
//!
//! 10 bytes per patch and level (40 per 16-cell patch) plus 40 bytes. A table read back equals
//! the computed one bit for bit, so the selection does not change. It is tied to its grid and
//! patch size (checked on reading), and to its heights when the reader has them at hand; a
//! store folder is written whole by one bake, so a store's table is read without that check,
//! like the DSS table. terrain-core does no file I/O here; the app reads and writes the bytes.

use super::dss_file::heights_checksum;
use super::geomipmap::{BandStack, GeomipTable};
use crate::checksum::{crc32, crc32_combine, crc32_update};
use crate::heightmap::Heightmap;

/// The magic bytes.
pub const MAGIC: [u8; 4] = *b"TGMP";
/// The format version this build reads and writes.
pub const VERSION: u32 = 1;
/// The fixed header's length.
const HEADER_LEN: usize = 4 + 4 * 8;
/// Bytes per patch and level.
const ENTRY_LEN: usize = 10;

/// Why a geo-mipmap table's bytes cannot be used: the table files' one error.
pub type GeomipFileError = crate::checksum::TableFileError;

/// The kind of table, in its errors.
const TABLE: &str = "geo-mipmap table";

/// What a table must have been made for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GeomipFor {
    /// Grid samples along x.
    pub width: u32,
    /// Grid samples along y.
    pub height: u32,
    /// Cells per patch side.
    pub patch_cells: u32,
    /// The heights' checksum ([`heights_checksum`]) when the reader has the heights.
    pub heights_crc: Option<u32>,
}

/// Geomorph's table file written band by band, for a grid whose table is computed from bands
/// of its rows and never held whole (a bake's pass, a sharded bake's merge): the caller
/// reserves [`GeomipEncoder::HEADER_LEN`] bytes at the file's start, appends each band's
/// entries ([`GeomipEncoder::push`], south first, the bands as [`GeomipTable::stack`] takes
/// them) and, when the heights' checksum is known, writes [`GeomipEncoder::finish`]'s header
/// over the reserved bytes and its CRC-32 after the last entry. The file is byte for byte
/// [`GeomipTable::encode_for`] of the stacked table (which is written by this encoder too).
#[derive(Debug, Clone, Default)]
pub struct GeomipEncoder {
    bands: BandStack,
    /// CRC-32 of the entries so far.
    crc: u32,
    /// Bytes of the entries so far.
    len: u64,
}

impl GeomipEncoder {
    /// Bytes of the file's header, before the first entry.
    pub const HEADER_LEN: usize = HEADER_LEN;

    /// An encoder with no band yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends the entries of the next band (rows of the grid as a grid of their own, see
    /// [`GeomipTable::stack`]) to `out`. The error says which band does not fit the ones
    /// before it; nothing is appended then.
    pub fn push(&mut self, band: &GeomipTable, out: &mut Vec<u8>) -> Result<(), String> {
        self.bands.add(band)?;
        let start = out.len();
        let (errors, heights, vertices) = band.parts();
        out.reserve(errors.len() * ENTRY_LEN);
        for ((e, z), v) in errors.iter().zip(heights).zip(vertices) {
            out.extend_from_slice(&e.to_le_bytes());
            out.extend_from_slice(&z.to_le_bytes());
            out.extend_from_slice(&v.to_le_bytes());
        }
        self.crc = crc32_update(self.crc, &out[start..]);
        self.len += (out.len() - start) as u64;
        Ok(())
    }

    /// The file's header (for its first [`GeomipEncoder::HEADER_LEN`] bytes), tied to heights
    /// whose [`heights_checksum`] is `heights_crc`, and its CRC-32 (its last 4 bytes, after
    /// the entries). An error when no band was pushed.
    pub fn finish(&self, heights_crc: u32) -> Result<([u8; HEADER_LEN], [u8; 4]), String> {
        let (w, h, p) = self.bands.grid()?;
        let count = |n: u32| (n.saturating_sub(1)).div_ceil(p).max(1);
        let levels = p.trailing_zeros() + 1;
        let mut header = [0u8; HEADER_LEN];
        header[..4].copy_from_slice(&MAGIC);
        for (k, v) in [VERSION, w, h, p, levels, count(w), count(h), heights_crc].iter().enumerate()
        {
            header[4 + 4 * k..8 + 4 * k].copy_from_slice(&v.to_le_bytes());
        }
        let crc = crc32_combine(crc32(&header), self.crc, self.len);
        Ok((header, crc.to_le_bytes()))
    }
}

impl GeomipTable {
    /// The table as bytes, tied to `hm` (the terrain it was computed from).
    ///
    /// # Panics
    /// If the table was computed for another grid size.
    pub fn encode(&self, hm: &Heightmap) -> Vec<u8> {
        let (w, h) = self.grid_size();
        assert_eq!((w, h), (hm.width() as u32, hm.height() as u32), "the table of another grid");
        self.encode_for(heights_checksum(hm))
    }

    /// The table as bytes, tied to heights whose [`heights_checksum`] is `heights_crc` (a
    /// table computed band by band, with the checksum accumulated over the bands' rows).
    pub fn encode_for(&self, heights_crc: u32) -> Vec<u8> {
        let mut encoder = GeomipEncoder::new();
        let mut out = Vec::with_capacity(HEADER_LEN + self.parts().0.len() * ENTRY_LEN + 4);
        out.resize(HEADER_LEN, 0);
        encoder.push(self, &mut out).expect("a table is a band of itself");
        let (header, crc) = encoder.finish(heights_crc).expect("one band");
        out[..HEADER_LEN].copy_from_slice(&header);
        out.extend_from_slice(&crc);
        out
    }

    /// Reads a table from `bytes`: refused unless the file is whole (checksum), of this
    /// version, consistent, and made for `want`'s grid, patch size and (when given) heights.
    pub fn decode(bytes: &[u8], want: &GeomipFor) -> Result<Self, GeomipFileError> {
        if bytes.len() < 4 || bytes[..4] != MAGIC {
            return Err(GeomipFileError::Magic { table: TABLE });
        }
        if bytes.len() < HEADER_LEN {
            return Err(GeomipFileError::Truncated { len: bytes.len(), needed: HEADER_LEN });
        }
        let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().expect("4 bytes"));
        let version = u32_at(4);
        if version != VERSION {
            return Err(GeomipFileError::Version {
                table: TABLE,
                found: version,
                expected: VERSION,
            });
        }
        let (width, height, p, levels) = (u32_at(8), u32_at(12), u32_at(16), u32_at(20));
        let (nx, ny, heights_crc) = (u32_at(24), u32_at(28), u32_at(32));
        if !(2..=64).contains(&p) || !p.is_power_of_two() || levels != p.trailing_zeros() + 1 {
            return Err(GeomipFileError::Layout(format!("{p}-cell patches with {levels} levels")));
        }
        let count = |n: u32| (n.saturating_sub(1)).div_ceil(p).max(1);
        if (nx, ny) != (count(width), count(height)) {
            return Err(GeomipFileError::Layout(format!(
                "{nx} x {ny} patches for {width} x {height} samples"
            )));
        }
        let entries = (nx as usize).saturating_mul(ny as usize).saturating_mul(levels as usize - 1);
        let needed = entries.saturating_mul(ENTRY_LEN).saturating_add(HEADER_LEN + 4);
        if bytes.len() != needed {
            return Err(GeomipFileError::Truncated { len: bytes.len(), needed });
        }
        let stored = u32_at(needed - 4);
        let computed = crc32(&bytes[..needed - 4]);
        if stored != computed {
            return Err(GeomipFileError::Checksum { stored, computed });
        }
        let expect = |what: &str, file: u32, here: u32| {
            if file == here {
                Ok(())
            } else {
                Err(GeomipFileError::Mismatch(format!("{what} {file} in the file, {here} here")))
            }
        };
        expect("width", width, want.width)?;
        expect("height", height, want.height)?;
        expect("patch cells", p, want.patch_cells)?;
        if want.heights_crc.is_some_and(|c| c != heights_crc) {
            return Err(GeomipFileError::Mismatch(
                "the heights differ (another DEM, crop, void filling or vertical scale)".into(),
            ));
        }
        let (mut errors, mut heights, mut vertices) =
            (Vec::with_capacity(entries), Vec::with_capacity(entries), Vec::with_capacity(entries));
        let last = (p + 1) * (p + 1);
        for (k, b) in bytes[HEADER_LEN..needed - 4].chunks_exact(ENTRY_LEN).enumerate() {
            let e = f32::from_le_bytes(b[0..4].try_into().expect("4 bytes"));
            let z = f32::from_le_bytes(b[4..8].try_into().expect("4 bytes"));
            let v = u16::from_le_bytes(b[8..10].try_into().expect("2 bytes"));
            if !(e.is_finite() && e >= 0.0 && z.is_finite() && u32::from(v) < last) {
                return Err(GeomipFileError::Layout(format!(
                    "entry {k}: error {e}, height {z}, vertex {v}"
                )));
            }
            errors.push(e);
            heights.push(z);
            vertices.push(v);
        }
        Ok(GeomipTable::from_parts((width, height, p), errors, heights, vertices))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Camera;
    use crate::lod::{GeomipConfig, GeomipScene};
    use crate::synth::FractalConfig;

    fn terrain(w: u64, h: u64) -> Heightmap {
        FractalConfig::with_size(w, h, 10.0).to_heightmap().unwrap()
    }

    fn want(hm: &Heightmap, p: u32) -> GeomipFor {
        GeomipFor {
            width: hm.width() as u32,
            height: hm.height() as u32,
            patch_cells: p,
            heights_crc: Some(heights_checksum(hm)),
        }
    }

    #[test]
    fn a_table_read_back_equals_the_computed_one_and_selects_the_same() {
        let hm = terrain(201, 130);
        let table = GeomipTable::new(&hm, 16);
        assert!((1..4).any(|l| table.level_error(3, 2, l) > 0.0));
        let back = GeomipTable::decode(&table.encode(&hm), &want(&hm, 16)).unwrap();
        assert_eq!(back, table);
        // Row by row in any order, put back in order, gives the same table.
        let rev = GeomipTable::new_with(&hm, 16, |row, rows| {
            let mut v: Vec<_> = (0..rows).rev().map(row).collect();
            v.reverse();
            v
        });
        assert_eq!(rev, table);
        let scene = GeomipScene::with_table(&hm, back);
        let cam = Camera::from_yaw_pitch(hm.grid_to_world(20.0, 10.0).extend(900.0), 30.0, -25.0)
            .with_viewport(640.0, 360.0);
        let cfg = GeomipConfig::default();
        let a = GeomipScene::new(&hm, 16).select(&cam, &cfg);
        let b = scene.select(&cam, &cfg);
        assert!(!a.patches.is_empty());
        assert_eq!((a.patches, a.factors), (b.patches, b.factors));
    }

    /// The grid's rows `y0..y0 + rows` as a heightmap, voids included.
    fn band(hm: &Heightmap, y0: u32, rows: u32) -> Heightmap {
        let (w, y0) = (hm.width(), y0 as usize);
        let data = hm.data()[y0 * w..(y0 + rows as usize) * w].to_vec();
        let mut voids = crate::heightmap::VoidMask::new(w, rows as usize);
        for j in 0..rows as usize {
            for i in 0..w {
                voids.set(i, j, hm.voids().get(i, y0 + j));
            }
        }
        Heightmap::new(w, rows as usize, data, voids, hm.georef().clone()).unwrap()
    }

    #[test]
    fn a_table_read_band_by_band_equals_the_whole_grid_one() {
        // Voids (not measured) and sides that the patch does not divide.
        let f = terrain(203, 150);
        let mut voids = crate::heightmap::VoidMask::new(203, 150);
        for j in 40..70 {
            for i in 90..120 {
                voids.set(i, j, true);
            }
        }
        let hm = Heightmap::new(203, 150, f.data().to_vec(), voids, f.georef().clone()).unwrap();
        for (p, per_band) in [(16, 1), (16, 3), (8, 4), (32, 100)] {
            let whole = GeomipTable::new(&hm, p);
            let mut calls = 0;
            let banded = GeomipTable::from_bands(
                (203, 150),
                p,
                per_band,
                |y0, rows| {
                    calls += 1;
                    Ok::<_, ()>(band(&hm, y0, rows))
                },
                |row, rows| rows.map(row).collect(),
            )
            .unwrap();
            assert_eq!(banded, whole, "{p}-cell patches, {per_band} rows per band");
            assert_eq!(calls, whole.patch_counts().1.div_ceil(per_band), "one read per band");
        }
        // A band's error is the caller's.
        let e = GeomipTable::from_bands(
            (203, 150),
            16,
            2,
            |_, _| Err("no"),
            |r, rows| rows.map(r).collect(),
        );
        assert_eq!(e.unwrap_err(), "no");
    }

    #[test]
    fn a_file_written_band_by_band_is_the_stacked_tables_file() {
        let hm = terrain(75, 150);
        let crc = heights_checksum(&hm);
        let whole = GeomipTable::new(&hm, 16).encode(&hm);
        // Bands of 3, 1 and 2 rows of patches and the rest (not whole patch rows: the last).
        let mut file = vec![0u8; GeomipEncoder::HEADER_LEN];
        let mut encoder = GeomipEncoder::new();
        let mut bands = Vec::new();
        for (y0, rows) in [(0, 49), (48, 17), (64, 33), (96, 54)] {
            let t = GeomipTable::new(&band(&hm, y0, rows), 16);
            encoder.push(&t, &mut file).unwrap();
            bands.push(t);
        }
        let (header, tail) = encoder.finish(crc).unwrap();
        file[..GeomipEncoder::HEADER_LEN].copy_from_slice(&header);
        file.extend_from_slice(&tail);
        assert!(file == whole, "the file of the bands is the whole grid's");
        let stacked = GeomipTable::stack(bands).unwrap();
        assert!(stacked.encode_for(crc) == whole);
        // Negative control: another heights checksum is another file.
        assert_ne!(encoder.finish(crc ^ 1).unwrap(), (header, tail));
        // A band after one that is not whole rows of patches, or of another width, is refused
        // by name and appends nothing; no band, no file.
        let len = file.len();
        let e = encoder.push(&GeomipTable::new(&band(&hm, 149, 1), 16), &mut file).unwrap_err();
        assert!(e.contains("band 3: 54 rows are not whole rows of 16-cell patches"), "{e}");
        let mut other = GeomipEncoder::new();
        other.push(&GeomipTable::new(&band(&hm, 0, 17), 16), &mut file).unwrap();
        let e = other.push(&GeomipTable::new(&terrain(60, 17), 16), &mut file).unwrap_err();
        assert!(e.contains("band 1: 60 samples wide"), "{e}");
        assert_eq!(file.len(), len + 5 * 4 * 10, "one band of 5 patches appended");
        assert_eq!(GeomipEncoder::new().finish(crc).unwrap_err(), "no band to stack");
    }

    #[test]
    fn the_errors_bound_the_exact_ones_from_above() {
        let hm = terrain(65, 65);
        let table = GeomipTable::new(&hm, 16);
        let exact = crate::metrics::geomorph::max_error_vertices_with(
            &hm,
            crate::metrics::Region::new(16, 32, 16),
            crate::metrics::geomorph::Reference::FullResolution,
            crate::metrics::geomorph::Triangulation::UnionJack,
        );
        let mut running = 0.0f64;
        for (l, e) in exact.iter().enumerate().skip(1) {
            running = running.max(e.error);
            let stored = table.level_error(1, 2, l);
            assert!(stored >= running && stored - running <= running * 1e-6, "{l}");
        }
        assert!(running > 0.0);
    }

    #[test]
    fn damaged_or_foreign_tables_are_refused() {
        let hm = terrain(33, 49);
        let bytes = GeomipTable::new(&hm, 8).encode(&hm);
        let dec = |b: &[u8]| GeomipTable::decode(b, &want(&hm, 8)).unwrap_err();
        assert_eq!(dec(b"PNG\x0d"), GeomipFileError::Magic { table: TABLE });
        assert!(matches!(dec(&bytes[..10]), GeomipFileError::Truncated { .. }));
        assert!(matches!(dec(&bytes[..bytes.len() - 7]), GeomipFileError::Truncated { .. }));
        let mut flipped = bytes.clone();
        flipped[HEADER_LEN + 13] ^= 1;
        assert!(matches!(dec(&flipped), GeomipFileError::Checksum { .. }));
        let mut v2 = bytes.clone();
        v2[4] = 2;
        assert_eq!(
            dec(&v2),
            GeomipFileError::Version { table: TABLE, found: 2, expected: VERSION }
        );
        let e = GeomipTable::decode(&bytes, &want(&hm, 16)).unwrap_err();
        assert!(e.to_string().contains("patch cells 8 in the file, 16 here"), "{e}");
        let other = terrain(40, 49);
        let e = GeomipTable::decode(&bytes, &want(&other, 8)).unwrap_err();
        assert!(e.to_string().contains("width 33 in the file, 40 here"), "{e}");
        let scaled =
            Heightmap::from_fn(33, 49, hm.georef().clone(), |i, j| hm.get(i, j) * 2.0).unwrap();
        let e = GeomipTable::decode(&bytes, &want(&scaled, 8)).unwrap_err();
        assert!(e.to_string().contains("heights differ"), "{e}");
        // Without the heights at hand (a store), the grid and patch size still decide.
        let store = GeomipFor { heights_crc: None, ..want(&scaled, 8) };
        assert!(GeomipTable::decode(&bytes, &store).is_ok());
    }
}
