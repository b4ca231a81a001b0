//! The DSS paper's precomputed object-space errors as bytes (`dss_errors.bin` in a scene that
//! `terrain bake` writes): section 3.3.1 computes the 32 errors per M-block in preprocessing,
//! so the runtime reads them instead of computing them.
//!
//! Layout (little-endian):
//!
//! ```text
//! magic "TDSS" | version u32 = 1 | width u32 | height u32 | root_cells u32 | levels u32 |
//! heights u32 (CRC-32 of the heightmap's samples and void mask) |
//! per level: nodes_x u32, nodes u32 | per node, level by level, row-major from the south:
//! 32 x f64 (delta_1 .. delta_32) | crc32 u32 (of every byte before it)
//! ```
//!
//! Errors are stored as f64, so a table read back equals the one computed bit for bit (the
//! selections that use it do not change). A table is tied to its terrain: decoding checks the
//! grid size, the quadtree's root, and the heights' checksum, so a file baked from another DEM,
//! another crop or another vertical scale is refused instead of misread. A table with more
//! levels than the quadtree (a finer `leaf_cells` at bake time) serves it: node `(l, i, j)`
//! covers the same samples whatever the leaf size; its finer levels are dropped on reading.
//! terrain-core does no file I/O here; the app reads and writes the bytes and names the file.

use super::dss_methods::DssErrorTable;
use crate::checksum::{crc32, crc32_combine, crc32_update};
use crate::heightmap::Heightmap;
use crate::metrics::dss::FACTORS;
use crate::quadtree::{Quadtree, TreeShape};

/// The magic bytes.
pub const MAGIC: [u8; 4] = *b"TDSS";
/// The format version this build reads and writes.
pub const VERSION: u32 = 1;
/// The length of the fixed header before the per-level counts.
const HEADER_LEN: usize = 4 + 4 * 6;

/// Why a DSS error table's bytes cannot be used: the table files' one error.
pub type DssFileError = crate::checksum::TableFileError;

/// The kind of table, in its errors.
const TABLE: &str = "DSS error table";

/// CRC-32 of a heightmap's sample bits (row by row) and void flags: the terrain a table belongs
/// to. [`HeightsChecksum`] computes the same value from rows streamed in order.
pub fn heights_checksum(hm: &Heightmap) -> u32 {
    let mut sum = HeightsChecksum::new();
    let mut flags = Vec::with_capacity(hm.width());
    let any = hm.voids().any();
    for (j, row) in hm.data().chunks(hm.width().max(1)).enumerate() {
        sum.add_heights(row);
        if any {
            flags.clear();
            flags.extend((0..hm.width()).map(|i| hm.voids().get(i, j)));
            sum.add_voids(&flags);
        }
    }
    sum.finish()
}

/// [`heights_checksum`] over rows given south first (a bake that reads the grid by bands):
/// the heights' bytes and the void flags are checksummed side by side and joined at the end
/// with [`crate::checksum::crc32_combine`], so the result equals the whole-grid function's.
#[derive(Debug, Clone, Default)]
pub struct HeightsChecksum {
    heights: u32,
    height_bytes: u64,
    voids: u32,
    void_bytes: u64,
    any_void: bool,
    buf: Vec<u8>,
}

/// Bytes of [`HeightsChecksum::to_bytes`].
pub const HEIGHTS_CHECKSUM_BYTES: usize = 4 + 8 + 4 + 8 + 1;

impl HeightsChecksum {
    /// An empty checksum.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds the next row's heights.
    pub fn add_heights(&mut self, row: &[f32]) {
        self.buf.clear();
        self.buf.extend(row.iter().flat_map(|z| z.to_bits().to_le_bytes()));
        self.heights = crc32_update(self.heights, &self.buf);
        self.height_bytes += self.buf.len() as u64;
    }

    /// Adds the next row's void flags (every row's, or none at all: a grid without voids may
    /// skip them).
    pub fn add_voids(&mut self, row: &[bool]) {
        self.buf.clear();
        self.buf.extend(row.iter().map(|&v| u8::from(v)));
        self.any_void |= row.iter().any(|&v| v);
        self.voids = crc32_update(self.voids, &self.buf);
        self.void_bytes += row.len() as u64;
    }

    /// Appends `next`, the checksum of the rows that follow this one's (a sharded bake joins
    /// its shards' checksums, south first, with [`crate::checksum::crc32_combine`]): the result
    /// is the checksum of all the rows added to either. Both must hold void flags for every
    /// row or for none.
    pub fn append(&mut self, next: &HeightsChecksum) {
        self.heights = crc32_combine(self.heights, next.heights, next.height_bytes);
        self.height_bytes += next.height_bytes;
        self.voids = crc32_combine(self.voids, next.voids, next.void_bytes);
        self.void_bytes += next.void_bytes;
        self.any_void |= next.any_void;
    }

    /// The running state as bytes (a shard's part records it for the merge's [`append`]).
    ///
    /// [`append`]: HeightsChecksum::append
    pub fn to_bytes(&self) -> [u8; HEIGHTS_CHECKSUM_BYTES] {
        let mut out = [0u8; HEIGHTS_CHECKSUM_BYTES];
        out[..4].copy_from_slice(&self.heights.to_le_bytes());
        out[4..12].copy_from_slice(&self.height_bytes.to_le_bytes());
        out[12..16].copy_from_slice(&self.voids.to_le_bytes());
        out[16..24].copy_from_slice(&self.void_bytes.to_le_bytes());
        out[24] = u8::from(self.any_void);
        out
    }

    /// The state [`HeightsChecksum::to_bytes`] wrote.
    pub fn from_bytes(b: &[u8; HEIGHTS_CHECKSUM_BYTES]) -> Self {
        let u32_at = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().expect("4 bytes"));
        let u64_at = |o: usize| u64::from_le_bytes(b[o..o + 8].try_into().expect("8 bytes"));
        Self {
            heights: u32_at(0),
            height_bytes: u64_at(4),
            voids: u32_at(12),
            void_bytes: u64_at(16),
            any_void: b[24] != 0,
            buf: Vec::new(),
        }
    }

    /// The checksum: the heights' bytes, followed by the void flags when any sample is void.
    pub fn finish(&self) -> u32 {
        if self.any_void {
            crc32_combine(self.heights, self.voids, self.void_bytes)
        } else {
            self.heights
        }
    }
}

impl DssErrorTable {
    /// The table as bytes, tied to `hm` (the terrain it was computed from).
    pub fn encode(&self, hm: &Heightmap) -> Vec<u8> {
        self.encode_for(hm.width() as u32, hm.height() as u32, heights_checksum(hm))
    }

    /// [`DssErrorTable::encode`] for a `width x height` grid whose heights have checksum
    /// `heights_crc` ([`heights_checksum`]; a grid read by rows: [`DssErrorTable::from_rows`]
    /// returns it).
    pub fn encode_for(&self, width: u32, height: u32, heights_crc: u32) -> Vec<u8> {
        let nodes: usize = self.levels.iter().map(|(_, v)| v.len()).sum();
        let mut out =
            Vec::with_capacity(HEADER_LEN + 8 * self.levels.len() + nodes * FACTORS * 8 + 4);
        out.extend_from_slice(&MAGIC);
        for v in [VERSION, width, height, self.root_cells, self.levels.len() as u32, heights_crc] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for (nx, v) in &self.levels {
            out.extend_from_slice(&nx.to_le_bytes());
            out.extend_from_slice(&(v.len() as u32).to_le_bytes());
        }
        for (_, v) in &self.levels {
            for e in v.iter().flatten() {
                out.extend_from_slice(&e.to_le_bytes());
            }
        }
        let crc = crc32(&out);
        out.extend_from_slice(&crc.to_le_bytes());
        out
    }

    /// Reads a table from `bytes` for the terrain `hm` and its quadtree `qt`: refused unless
    /// the file is whole (checksum), of this version, and made for this grid, root and heights
    /// with at least the quadtree's levels.
    pub fn decode(bytes: &[u8], hm: &Heightmap, qt: &Quadtree) -> Result<Self, DssFileError> {
        assert_eq!((qt.width(), qt.height()), (hm.width() as u32, hm.height() as u32));
        Self::decode_for(bytes, qt.shape(), Some(heights_checksum(hm)))
    }

    /// [`DssErrorTable::decode`] for the quadtree geometry `shape`, without a heightmap at
    /// hand (a baked store's): the heights are checked against `heights` (a
    /// [`heights_checksum`]) when given. A store folder is written whole by one bake, which
    /// writes the table from the heights it stored, so a store's table is read with `None`.
    pub fn decode_for(
        bytes: &[u8],
        shape: &TreeShape,
        heights_crc: Option<u32>,
    ) -> Result<Self, DssFileError> {
        if bytes.len() < 4 || bytes[..4] != MAGIC {
            return Err(DssFileError::Magic { table: TABLE });
        }
        if bytes.len() < HEADER_LEN {
            return Err(DssFileError::Truncated { len: bytes.len(), needed: HEADER_LEN });
        }
        let u32_at = |o: usize| -> Result<u32, DssFileError> {
            bytes
                .get(o..o + 4)
                .map(|b| u32::from_le_bytes(b.try_into().expect("4 bytes")))
                .ok_or(DssFileError::Truncated { len: bytes.len(), needed: o + 4 })
        };
        let version = u32_at(4)?;
        if version != VERSION {
            return Err(DssFileError::Version { table: TABLE, found: version, expected: VERSION });
        }
        let (width, height, root_cells) = (u32_at(8)?, u32_at(12)?, u32_at(16)?);
        let (levels, heights) = (u32_at(20)?, u32_at(24)?);
        if levels == 0 || levels > 32 {
            return Err(DssFileError::Layout(format!("{levels} levels")));
        }
        let mut counts = Vec::with_capacity(levels as usize);
        let mut needed = HEADER_LEN + 8 * levels as usize;
        for l in 0..levels as usize {
            let (nx, n) = (u32_at(HEADER_LEN + 8 * l)?, u32_at(HEADER_LEN + 8 * l + 4)?);
            if nx == 0 || n % nx != 0 {
                return Err(DssFileError::Layout(format!("level {l}: {n} nodes in rows of {nx}")));
            }
            needed = needed.saturating_add((n as usize).saturating_mul(FACTORS * 8));
            counts.push((nx, n as usize));
        }
        needed = needed.saturating_add(4);
        if bytes.len() != needed {
            return Err(DssFileError::Truncated { len: bytes.len(), needed });
        }
        let stored = u32_at(needed - 4)?;
        let computed = crc32(&bytes[..needed - 4]);
        if stored != computed {
            return Err(DssFileError::Checksum { stored, computed });
        }
        let expect = |what: &str, file: u32, here: u32| -> Result<(), DssFileError> {
            if file == here {
                Ok(())
            } else {
                Err(DssFileError::Mismatch(format!("{what} {file} in the file, {here} here")))
            }
        };
        expect("width", width, shape.width())?;
        expect("height", height, shape.height())?;
        expect("quadtree root cells", root_cells, shape.root_cells())?;
        let used = shape.max_level() as usize + 1;
        if (levels as usize) < used {
            return Err(DssFileError::Mismatch(format!(
                "{levels} quadtree levels in the file, {used} needed (it was computed for larger leaves than this quadtree's)"
            )));
        }
        if heights_crc.is_some_and(|c| c != heights) {
            return Err(DssFileError::Mismatch(
                "the heights differ (another DEM, crop, void filling or vertical scale)".into(),
            ));
        }
        let reference = DssErrorTable::shape(shape);
        let mut at = HEADER_LEN + 8 * levels as usize;
        let mut out = Vec::with_capacity(used);
        for (l, &(nx, n)) in counts.iter().enumerate().take(used) {
            if (nx, n) != reference[l] {
                return Err(DssFileError::Layout(format!(
                    "level {l}: {n} nodes in rows of {nx}, the quadtree has {} in rows of {}",
                    reference[l].1, reference[l].0
                )));
            }
            let mut v = Vec::with_capacity(n);
            for _ in 0..n {
                let mut e = [0.0f64; FACTORS];
                for x in &mut e {
                    *x = f64::from_le_bytes(bytes[at..at + 8].try_into().expect("8 bytes"));
                    at += 8;
                }
                v.push(e);
            }
            out.push((nx, v));
        }
        Ok(DssErrorTable { root_cells, levels: out })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lod::RowsBudget;
    use crate::quadtree::NodeId;
    use crate::synth::FractalConfig;

    fn terrain(w: u64, h: u64) -> Heightmap {
        FractalConfig::with_size(w, h, 10.0).to_heightmap().unwrap()
    }

    #[test]
    fn checksums_of_consecutive_rows_appended_are_the_whole_grids() {
        let w = 37;
        let rows: Vec<Vec<f32>> =
            (0..11).map(|j| (0..w).map(|i| (i * 7 + j * 13) as f32 * 0.25).collect()).collect();
        for with_voids in [false, true] {
            let voids = |j: usize| -> Vec<bool> { (0..w).map(|i| with_voids && i == j).collect() };
            let sum = |range: std::ops::Range<usize>| {
                let mut c = HeightsChecksum::new();
                for j in range {
                    c.add_heights(&rows[j]);
                    c.add_voids(&voids(j));
                }
                c
            };
            let whole = sum(0..11).finish();
            for split in [0, 1, 5, 11] {
                let mut a = sum(0..split);
                let b = HeightsChecksum::from_bytes(&sum(split..11).to_bytes());
                a.append(&b);
                assert_eq!(a.finish(), whole, "split at {split}, voids {with_voids}");
            }
            // Negative control: rows appended in the wrong order.
            let mut b = sum(5..11);
            b.append(&sum(0..5));
            assert_ne!(b.finish(), whole);
        }
    }

    fn all_nodes(t: &DssErrorTable, qt: &Quadtree) -> Vec<u64> {
        let mut v = Vec::new();
        for (l, (nx, n)) in DssErrorTable::shape(qt.shape()).into_iter().enumerate() {
            for k in 0..n as u32 {
                let e = t.get(NodeId { level: l as u8, i: k % nx, j: k / nx }).unwrap();
                v.extend(e.iter().map(|x| x.to_bits()));
            }
        }
        v
    }

    #[test]
    fn a_table_read_back_equals_the_computed_one_bit_for_bit() {
        let hm = terrain(97, 70);
        let qt = Quadtree::new(&hm, 8);
        let table = DssErrorTable::new(&hm, &qt);
        assert!(all_nodes(&table, &qt).iter().any(|&b| f64::from_bits(b) > 0.0));
        let back = DssErrorTable::decode(&table.encode(&hm), &hm, &qt).unwrap();
        assert_eq!(back, table);
        // A caller's map that computes the rows in reverse and puts them back in order.
        let rev = DssErrorTable::new_with(&hm, &qt, |rows, f| {
            let mut out: Vec<_> = rows.iter().rev().map(f).collect();
            out.reverse();
            out
        });
        assert_eq!(rev, table);
    }

    #[test]
    fn a_finer_table_serves_a_coarser_quadtree() {
        let hm = terrain(65, 65);
        let (fine, coarse) = (Quadtree::new(&hm, 4), Quadtree::new(&hm, 16));
        assert!(fine.max_level() > coarse.max_level());
        let bytes = DssErrorTable::new(&hm, &fine).encode(&hm);
        let read = DssErrorTable::decode(&bytes, &hm, &coarse).unwrap();
        assert_eq!(read, DssErrorTable::new(&hm, &coarse));
        // Not the other way round.
        let bytes = DssErrorTable::new(&hm, &coarse).encode(&hm);
        let e = DssErrorTable::decode(&bytes, &hm, &fine).unwrap_err();
        assert!(matches!(e, DssFileError::Mismatch(_)), "{e}");
    }

    #[test]
    fn the_streamed_heights_checksum_is_the_checksum_of_heights_then_voids() {
        let mut with_voids = terrain(37, 21);
        let voids: Vec<(usize, usize)> = vec![(0, 0), (5, 3), (36, 20), (12, 12)];
        {
            let (w, h, data, mut mask, georef) = with_voids.clone().into_parts();
            for &(i, j) in &voids {
                mask.set(i, j, true);
            }
            with_voids = Heightmap::new(w, h, data, mask, georef).unwrap();
        }
        for hm in [terrain(37, 21), with_voids] {
            // The definition: every sample's bits, then (only with voids) every flag.
            let mut bytes: Vec<u8> =
                hm.data().iter().flat_map(|z| z.to_bits().to_le_bytes()).collect();
            if hm.voids().any() {
                for j in 0..hm.height() {
                    bytes.extend((0..hm.width()).map(|i| u8::from(hm.voids().get(i, j))));
                }
            }
            assert_eq!(heights_checksum(&hm), crc32(&bytes));
            // Streamed: heights and flags of every row, side by side.
            let mut s = HeightsChecksum::new();
            for j in 0..hm.height() {
                s.add_heights(&hm.data()[j * hm.width()..(j + 1) * hm.width()]);
                let flags: Vec<bool> = (0..hm.width()).map(|i| hm.voids().get(i, j)).collect();
                s.add_voids(&flags);
            }
            assert_eq!(s.finish(), crc32(&bytes), "voids: {}", hm.voids().count());
        }
    }

    /// `hm` read back by rows, counting the largest band asked for.
    fn by_rows(
        hm: &Heightmap,
        qt: &Quadtree,
        band: usize,
        coarse_bytes: usize,
    ) -> (Vec<u8>, usize) {
        let w = hm.width();
        let mut largest = 0;
        let mut read = |j0: usize, n: usize, heights: &mut [f32], voids: &mut [bool]| {
            largest = largest.max(n);
            heights.copy_from_slice(&hm.data()[j0 * w..(j0 + n) * w]);
            for (k, v) in voids.iter_mut().enumerate() {
                *v = hm.voids().get(k % w, j0 + k / w);
            }
            Ok::<(), std::convert::Infallible>(())
        };
        let budget = RowsBudget { band_rows: band, coarse_bytes };
        let (table, crc) = DssErrorTable::from_rows(
            qt.shape(),
            &budget,
            &mut read,
            &crate::lod::Sequential,
            &mut |_| {},
        )
        .unwrap();
        (table.encode_for(w as u32, hm.height() as u32, crc), largest)
    }

    #[test]
    fn a_table_computed_by_bands_of_rows_is_the_in_memory_one_byte_for_byte() {
        // Non-square, non-power-of-two, with voids (a row of them, scattered ones).
        let (w, h, data, mut mask, georef) = terrain(83, 57).into_parts();
        for (i, j) in [(3, 4), (40, 30), (82, 56), (0, 56)] {
            mask.set(i, j, true);
        }
        (10..30).for_each(|i| mask.set(i, 20, true));
        let voided = Heightmap::new(w, h, data, mask, georef).unwrap();
        for hm in [terrain(65, 65), voided] {
            let qt = Quadtree::new(&hm, 4);
            let whole = DssErrorTable::new(&hm, &qt).encode(&hm);
            // Bands of 2 rows: every level accumulated over bands; 10 and 20: the finer
            // levels by windows, the coarser accumulated; 200: one window for all. The coarse
            // levels in one sweep (no byte bound), or one sweep each (1 byte).
            for band in [2, 3, 10, 20, 200] {
                for coarse_bytes in [usize::MAX, 1] {
                    let (bytes, largest) = by_rows(&hm, &qt, band, coarse_bytes);
                    assert!(largest <= band, "band {band}: read {largest} rows at once");
                    assert_eq!(bytes.len(), whole.len());
                    let first = bytes.iter().zip(&whole).position(|(a, b)| a != b);
                    assert_eq!(first, None, "band {band}, {coarse_bytes} B: first differing byte");
                }
            }
            // Negative control: one height changed, the table by rows differs.
            let (w, h, mut data, mask, georef) = hm.clone().into_parts();
            data[w * (h / 2) + w / 3] += 5.0;
            let changed = Heightmap::new(w, h, data, mask, georef).unwrap();
            let (bytes, _) = by_rows(&changed, &qt, 10, usize::MAX);
            let errors = |b: &[u8]| b[HEADER_LEN..b.len() - 4].to_vec();
            assert_ne!(errors(&bytes), errors(&whole), "a changed height changes the errors");
        }
    }

    #[test]
    fn damaged_or_foreign_tables_are_refused() {
        let hm = terrain(33, 33);
        let qt = Quadtree::new(&hm, 8);
        let bytes = DssErrorTable::new(&hm, &qt).encode(&hm);
        let dec = |b: &[u8]| DssErrorTable::decode(b, &hm, &qt).unwrap_err();
        assert_eq!(dec(b"PNG\x0d"), DssFileError::Magic { table: TABLE });
        assert!(matches!(dec(&bytes[..10]), DssFileError::Truncated { .. }));
        assert!(matches!(dec(&bytes[..bytes.len() - 9]), DssFileError::Truncated { .. }));
        let mut flipped = bytes.clone();
        flipped[HEADER_LEN + 40] ^= 1;
        assert!(matches!(dec(&flipped), DssFileError::Checksum { .. }));
        let mut v2 = bytes.clone();
        v2[4] = 2;
        assert_eq!(dec(&v2), DssFileError::Version { table: TABLE, found: 2, expected: VERSION });
        // Same size, other heights (a vertical scale): refused by the heights' checksum.
        let scaled =
            Heightmap::from_fn(33, 33, hm.georef().clone(), |i, j| hm.get(i, j) * 2.0).unwrap();
        let e = DssErrorTable::decode(&bytes, &scaled, &qt).unwrap_err();
        assert!(e.to_string().contains("heights differ"), "{e}");
        // Another grid size.
        let other = terrain(40, 33);
        let e = DssErrorTable::decode(&bytes, &other, &Quadtree::new(&other, 8)).unwrap_err();
        assert!(e.to_string().contains("width 33 in the file, 40 here"), "{e}");
    }
}
