//! The DSS paper's precomputed object-space errors as bytes (`dss_errors.bin` in a scene that
//! `terrain bake` writes): section 3.3.1 computes the 32 errors per M-block in preprocessing,
//! so the runtime reads them instead of computing them.
//!
//! Layout (little-endian):
//!
//! ```text
//! magic "TDSS" | version u32 = 2 | width u32 | height u32 | root_cells u32 | levels u32 |
//! heights u32 (CRC-32 of the heightmap's samples and void mask) | page_nodes u32 |
//! per level: nodes_x u32, nodes u32 | per node, level by level, row-major from the south:
//! 32 x f64 (delta_1 .. delta_32) |
//! per page (page_nodes consecutive nodes; the last may hold fewer): crc32 u32 of its bytes |
//! crc32 u32 (of the header, the counts and the page checksums)
//! ```
//!
//! Version 1 (still read) has no `page_nodes` and no page checksums: its last word is the
//! CRC-32 of every byte before it. Version 2's per-page checksums let a large table be read by
//! pages ([`DssErrorTable::open_paged`], [`super::dss_pages`]) and each page checked when read.
//!
//! Errors are stored as f64, so a table read back equals the one computed bit for bit (the
//! selections that use it do not change). A table is tied to its terrain: decoding checks the
//! grid size, the quadtree's root, and the heights' checksum, so a file baked from another DEM,
//! another crop or another vertical scale is refused instead of misread. A table with more
//! levels than the quadtree (a finer `leaf_cells` at bake time) serves it: node `(l, i, j)`
//! covers the same samples whatever the leaf size; its finer levels are dropped on reading.
//! terrain-core does no file I/O here; the app reads and writes the bytes and names the file.

use std::sync::Arc;

use super::dss_methods::DssErrorTable;
use super::dss_pages::{DssPagedLayout, DssPages, DssPaging, ENTRY_BYTES};
use super::geomip_pages::TableReader;
use crate::checksum::{crc32, crc32_combine, crc32_update};
use crate::heightmap::Heightmap;
use crate::metrics::dss::FACTORS;
use crate::quadtree::{Quadtree, TreeShape};

/// The magic bytes.
pub const MAGIC: [u8; 4] = *b"TDSS";
/// The format version this build writes (it reads 1 and 2).
pub const VERSION: u32 = 2;
/// The length of version 1's fixed header before the per-level counts.
const HEADER_LEN: usize = 4 + 4 * 6;
/// The length of version 2's (one more word: nodes per page).
const HEADER_LEN_V2: usize = HEADER_LEN + 4;

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
    /// The table as bytes (version 2), tied to `hm` (the terrain it was computed from).
    pub fn encode(&self, hm: &Heightmap) -> Vec<u8> {
        self.encode_for(hm.width() as u32, hm.height() as u32, heights_checksum(hm))
    }

    /// [`DssErrorTable::encode`] for a `width x height` grid whose heights have checksum
    /// `heights_crc` ([`heights_checksum`]; a grid read by rows: [`DssErrorTable::from_rows`]
    /// returns it). A table in memory only: one read by pages is its file already (and one of
    /// its pages may be unreadable), so writing it back is refused (a panic: no caller does).
    pub fn encode_for(&self, width: u32, height: u32, heights_crc: u32) -> Vec<u8> {
        assert!(self.paged.is_none(), "a DSS table read by pages is not written back");
        let nodes: usize = self.levels.iter().map(|(_, v)| v.len()).sum();
        let pages = nodes.div_ceil(PAGE_NODES);
        let mut out = Vec::with_capacity(
            HEADER_LEN_V2 + 8 * self.levels.len() + nodes * ENTRY_BYTES + 4 * pages + 4,
        );
        out.extend_from_slice(&MAGIC);
        let levels = self.levels.len() as u32;
        let head = [VERSION, width, height, self.root_cells, levels, heights_crc];
        for v in head.into_iter().chain([PAGE_NODES as u32]) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for (nx, v) in &self.levels {
            out.extend_from_slice(&nx.to_le_bytes());
            out.extend_from_slice(&(v.len() as u32).to_le_bytes());
        }
        let entries_at = out.len();
        for (_, v) in &self.levels {
            for e in v.iter().flatten() {
                out.extend_from_slice(&e.to_le_bytes());
            }
        }
        let mut tail: Vec<u8> = Vec::with_capacity(4 * pages + 4);
        for page in out[entries_at..].chunks(PAGE_NODES * ENTRY_BYTES) {
            tail.extend_from_slice(&crc32(page).to_le_bytes());
        }
        let crc = crc32_update(crc32(&out[..entries_at]), &tail);
        tail.extend_from_slice(&crc.to_le_bytes());
        out.extend_from_slice(&tail);
        out
    }

    /// Reads a table from `bytes` for the terrain `hm` and its quadtree `qt`: refused unless
    /// the file is whole (checksums), of a version this build reads, and made for this grid,
    /// root and heights with at least the quadtree's levels.
    pub fn decode(bytes: &[u8], hm: &Heightmap, qt: &Quadtree) -> Result<Self, DssFileError> {
        assert_eq!((qt.width(), qt.height()), (hm.width() as u32, hm.height() as u32));
        Self::decode_for(bytes, qt.shape(), Some(heights_checksum(hm)))
    }

    /// [`DssErrorTable::decode`] for the quadtree geometry `shape`, without a heightmap at
    /// hand (a baked store's): the heights are checked against `heights` (a
    /// [`heights_checksum`]) when given. A store folder is written whole by one bake, which
    /// writes the table from the heights it stored, so a store's table is read with `None`.
    /// Reads versions 1 and 2.
    pub fn decode_for(
        bytes: &[u8],
        shape: &TreeShape,
        heights_crc: Option<u32>,
    ) -> Result<Self, DssFileError> {
        let head = Head::parse(bytes)?;
        let needed = head.file_len();
        if bytes.len() as u64 != needed {
            return Err(DssFileError::Truncated { len: bytes.len(), needed: needed as usize });
        }
        let entries_at = head.entries_at() as usize;
        let entries_end = entries_at + head.nodes as usize * ENTRY_BYTES;
        let end = bytes.len() - 4;
        let stored = u32_le(bytes, end);
        if head.version == 1 {
            let computed = crc32(&bytes[..end]);
            if stored != computed {
                return Err(DssFileError::Checksum { stored, computed });
            }
        } else {
            let computed = crc32_update(crc32(&bytes[..entries_at]), &bytes[entries_end..end]);
            if stored != computed {
                return Err(DssFileError::Checksum { stored, computed });
            }
            let pages =
                bytes[entries_at..entries_end].chunks(head.page_nodes as usize * ENTRY_BYTES);
            for (p, page) in pages.enumerate() {
                let (stored, computed) = (u32_le(bytes, entries_end + 4 * p), crc32(page));
                if stored != computed {
                    return Err(DssFileError::Checksum { stored, computed });
                }
            }
        }
        let used = head.check_for(shape, heights_crc)?;
        let mut at = entries_at;
        let mut out = Vec::with_capacity(used);
        for &(nx, n) in head.counts.iter().take(used) {
            let mut v = Vec::with_capacity(n as usize);
            for _ in 0..n {
                v.push(decode_entry(&bytes[at..at + ENTRY_BYTES]));
                at += ENTRY_BYTES;
            }
            out.push((nx, v));
        }
        Ok(DssErrorTable { root_cells: head.root_cells, levels: out, paged: None })
    }

    /// Opens a version-2 table of `len` bytes for reading by pages through `reader` (`file`
    /// names it in errors), for the quadtree geometry `shape` (heights checked against
    /// `heights_crc` when given, as [`DssErrorTable::decode_for`]): reads and checks the header,
    /// the level counts and the tail only (4 bytes per page of [`PAGE_NODES`] nodes: 88 KB of a
    /// 32769^2 grid's 1.43 GB), then each page when a selection first asks one of its nodes,
    /// through a cache of `paging.cache_bytes` ([`super::dss_pages`]). The selections are bit
    /// for bit those of the table read whole. A version-1 file is refused
    /// ([`DssFileError::Version`]): [`DssErrorTable::decode_for`] reads it whole.
    pub fn open_paged(
        file: &str,
        reader: Arc<dyn TableReader>,
        len: u64,
        shape: &TreeShape,
        heights_crc: Option<u32>,
        paging: &DssPaging,
    ) -> Result<Self, DssFileError> {
        let read = |offset: u64, n: usize| -> Result<Vec<u8>, DssFileError> {
            let mut buf = vec![0u8; n];
            reader.read_at(offset, &mut buf).map_err(|e| DssFileError::Read(e.to_string()))?;
            Ok(buf)
        };
        let fixed = read(0, HEADER_LEN_V2.min(len as usize))?;
        let version = Head::version_of(&fixed)?;
        if version == 1 {
            return Err(DssFileError::Version { table: TABLE, found: 1, expected: VERSION });
        }
        if fixed.len() < HEADER_LEN_V2 {
            return Err(DssFileError::Truncated { len: fixed.len(), needed: HEADER_LEN_V2 });
        }
        let levels = u32_le(&fixed, 20);
        if levels == 0 || levels > 32 {
            return Err(DssFileError::Layout(format!("{levels} levels")));
        }
        let counts_len = 8 * levels as usize;
        if len < (HEADER_LEN_V2 + counts_len) as u64 {
            return Err(DssFileError::Truncated {
                len: len as usize,
                needed: HEADER_LEN_V2 + counts_len,
            });
        }
        let mut head_bytes = fixed;
        head_bytes.extend(read(HEADER_LEN_V2 as u64, counts_len)?);
        let head = Head::parse(&head_bytes)?;
        let needed = head.file_len();
        if len != needed {
            return Err(DssFileError::Truncated { len: len as usize, needed: needed as usize });
        }
        let entries_end = head.entries_at() + head.nodes * ENTRY_BYTES as u64;
        let tail = read(entries_end, (needed - entries_end) as usize)?;
        let stored = u32_le(&tail, tail.len() - 4);
        let computed = crc32_update(crc32(&head_bytes), &tail[..tail.len() - 4]);
        if stored != computed {
            return Err(DssFileError::Checksum { stored, computed });
        }
        let used = head.check_for(shape, heights_crc)?;
        let mut first = 0u64;
        let mut levels = Vec::with_capacity(used);
        for &(nx, n) in head.counts.iter().take(used) {
            levels.push((nx, first));
            first += u64::from(n);
        }
        let pages = (tail.len() - 4) / 4;
        let layout = DssPagedLayout {
            file: file.to_string(),
            levels,
            used_nodes: first,
            nodes: head.nodes,
            page_nodes: u64::from(head.page_nodes),
            entries_at: head.entries_at(),
            page_crcs: (0..pages).map(|p| u32_le(&tail, 4 * p)).collect(),
        };
        let open_bytes = (head_bytes.len() + tail.len()) as u64;
        let pages = DssPages::new(layout, reader, paging, open_bytes);
        Ok(DssErrorTable {
            root_cells: head.root_cells,
            levels: Vec::new(),
            paged: Some(Arc::new(pages)),
        })
    }
}

/// Nodes per page of a version-2 file (64 KiB of entries): the unit [`DssErrorTable::open_paged`]
/// reads and checks.
pub const PAGE_NODES: usize = 256;

/// One node's 32 errors from its bytes.
pub(super) fn decode_entry(b: &[u8]) -> [f64; FACTORS] {
    let mut e = [0.0f64; FACTORS];
    for (x, c) in e.iter_mut().zip(b.chunks_exact(8)) {
        *x = f64::from_le_bytes(c.try_into().expect("8 bytes"));
    }
    e
}

fn u32_le(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes(b[o..o + 4].try_into().expect("4 bytes"))
}

/// A file's header and level counts.
struct Head {
    version: u32,
    width: u32,
    height: u32,
    root_cells: u32,
    heights: u32,
    /// Nodes per page (version 2; version 1 has no pages).
    page_nodes: u32,
    counts: Vec<(u32, u32)>,
    /// Nodes of every level.
    nodes: u64,
}

impl Head {
    /// The version of a file starting with `bytes` (its magic checked).
    fn version_of(bytes: &[u8]) -> Result<u32, DssFileError> {
        if bytes.len() < 4 || bytes[..4] != MAGIC {
            return Err(DssFileError::Magic { table: TABLE });
        }
        if bytes.len() < 8 {
            return Err(DssFileError::Truncated { len: bytes.len(), needed: 8 });
        }
        match u32_le(bytes, 4) {
            v @ (1 | 2) => Ok(v),
            found => Err(DssFileError::Version { table: TABLE, found, expected: VERSION }),
        }
    }

    /// The header and counts at the start of `bytes` (at least those), checked for
    /// consistency.
    fn parse(bytes: &[u8]) -> Result<Self, DssFileError> {
        let version = Self::version_of(bytes)?;
        let fixed = if version == 1 { HEADER_LEN } else { HEADER_LEN_V2 };
        if bytes.len() < fixed {
            return Err(DssFileError::Truncated { len: bytes.len(), needed: fixed });
        }
        let (width, height, root_cells) = (u32_le(bytes, 8), u32_le(bytes, 12), u32_le(bytes, 16));
        let (levels, heights) = (u32_le(bytes, 20), u32_le(bytes, 24));
        let page_nodes = if version == 1 { 0 } else { u32_le(bytes, 28) };
        if levels == 0 || levels > 32 {
            return Err(DssFileError::Layout(format!("{levels} levels")));
        }
        if version == 2 && page_nodes == 0 {
            return Err(DssFileError::Layout("pages of 0 nodes".into()));
        }
        let needed = fixed + 8 * levels as usize;
        if bytes.len() < needed {
            return Err(DssFileError::Truncated { len: bytes.len(), needed });
        }
        let mut counts = Vec::with_capacity(levels as usize);
        let mut nodes = 0u64;
        for l in 0..levels as usize {
            let (nx, n) = (u32_le(bytes, fixed + 8 * l), u32_le(bytes, fixed + 8 * l + 4));
            if nx == 0 || n % nx != 0 {
                return Err(DssFileError::Layout(format!("level {l}: {n} nodes in rows of {nx}")));
            }
            nodes += u64::from(n);
            counts.push((nx, n));
        }
        Ok(Self { version, width, height, root_cells, heights, page_nodes, counts, nodes })
    }

    /// Where the entries start.
    fn entries_at(&self) -> u64 {
        let fixed = if self.version == 1 { HEADER_LEN } else { HEADER_LEN_V2 };
        (fixed + 8 * self.counts.len()) as u64
    }

    /// Pages of a version-2 file (0 for version 1).
    fn pages(&self) -> u64 {
        if self.version == 1 { 0 } else { self.nodes.div_ceil(u64::from(self.page_nodes)) }
    }

    /// The length the header implies.
    fn file_len(&self) -> u64 {
        self.entries_at() + self.nodes * ENTRY_BYTES as u64 + 4 * self.pages() + 4
    }

    /// Refused unless made for `shape` (and `heights_crc`, when given) with at least its
    /// levels; the levels it uses.
    fn check_for(
        &self,
        shape: &TreeShape,
        heights_crc: Option<u32>,
    ) -> Result<usize, DssFileError> {
        let expect = |what: &str, file: u32, here: u32| -> Result<(), DssFileError> {
            if file == here {
                Ok(())
            } else {
                Err(DssFileError::Mismatch(format!("{what} {file} in the file, {here} here")))
            }
        };
        expect("width", self.width, shape.width())?;
        expect("height", self.height, shape.height())?;
        expect("quadtree root cells", self.root_cells, shape.root_cells())?;
        let used = shape.max_level() as usize + 1;
        let levels = self.counts.len();
        if levels < used {
            return Err(DssFileError::Mismatch(format!(
                "{levels} quadtree levels in the file, {used} needed (it was computed for larger leaves than this quadtree's)"
            )));
        }
        if heights_crc.is_some_and(|c| c != self.heights) {
            return Err(DssFileError::Mismatch(
                "the heights differ (another DEM, crop, void filling or vertical scale)".into(),
            ));
        }
        let reference = DssErrorTable::shape(shape);
        for (l, &(nx, n)) in self.counts.iter().enumerate().take(used) {
            if (nx, n as usize) != reference[l] {
                return Err(DssFileError::Layout(format!(
                    "level {l}: {n} nodes in rows of {nx}, the quadtree has {} in rows of {}",
                    reference[l].1, reference[l].0
                )));
            }
        }
        Ok(used)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Camera;
    use crate::lod::{DssConfig, RowsBudget};
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
        let mut v3 = bytes.clone();
        v3[4] = 3;
        assert_eq!(dec(&v3), DssFileError::Version { table: TABLE, found: 3, expected: VERSION });
        // A flipped byte in the page checksums, or in the last page.
        let mut tail = bytes.clone();
        let at = tail.len() - 6;
        tail[at] ^= 1;
        assert!(matches!(dec(&tail), DssFileError::Checksum { .. }));
        let mut last = bytes.clone();
        // 1 + 4 + 16 nodes: one page, its checksum and the header's after it.
        assert_eq!(bytes.len(), HEADER_LEN_V2 + 8 * 3 + 21 * ENTRY_BYTES + 4 + 4);
        let at = last.len() - 4 - 4 - 3;
        last[at] ^= 1;
        assert!(matches!(dec(&last), DssFileError::Checksum { .. }));
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

    /// Version 1's bytes of `t` (no pages): what bakes before version 2 wrote.
    fn encode_v1(t: &DssErrorTable, hm: &Heightmap) -> Vec<u8> {
        let mut out = MAGIC.to_vec();
        let head = [1, hm.width() as u32, hm.height() as u32, t.root_cells, t.levels.len() as u32];
        for v in head.into_iter().chain([heights_checksum(hm)]) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for (nx, v) in &t.levels {
            out.extend_from_slice(&nx.to_le_bytes());
            out.extend_from_slice(&(v.len() as u32).to_le_bytes());
        }
        for e in t.levels.iter().flat_map(|(_, v)| v).flatten() {
            out.extend_from_slice(&e.to_le_bytes());
        }
        let crc = crc32(&out);
        out.extend_from_slice(&crc.to_le_bytes());
        out
    }

    #[test]
    fn a_version_1_table_still_reads_whole_and_is_refused_by_pages() {
        let hm = terrain(83, 57);
        let qt = Quadtree::new(&hm, 4);
        let table = DssErrorTable::new(&hm, &qt);
        let v1 = encode_v1(&table, &hm);
        assert_eq!(DssErrorTable::decode(&v1, &hm, &qt).unwrap(), table);
        let mut flipped = v1.clone();
        flipped[HEADER_LEN + 100] ^= 1;
        let e = DssErrorTable::decode(&flipped, &hm, &qt).unwrap_err();
        assert!(matches!(e, DssFileError::Checksum { .. }), "{e}");
        let len = v1.len() as u64;
        let e = DssErrorTable::open_paged(
            "v1",
            Arc::new(v1),
            len,
            qt.shape(),
            None,
            &DssPaging::default(),
        )
        .unwrap_err();
        assert_eq!(e, DssFileError::Version { table: TABLE, found: 1, expected: VERSION });
    }

    /// A table read by pages (a cache of one page, so pages are evicted and read again) gives
    /// every node's errors bit for bit as the table read whole, exaggerated as well, and the
    /// DSS selections (Method I, Method II, the strips) select the same; a damaged page is
    /// reported with its page and file, its nodes infinitely rough, the others unchanged.
    #[test]
    fn a_table_read_by_pages_is_the_table_read_whole() {
        use crate::lod::{
            DssStripsConfig, StripFactors, select_dss_power_of_two, select_dss_strips,
            select_dss_uniform,
        };
        use glam::dvec3;
        let hm = terrain(300, 211);
        let qt = Quadtree::new(&hm, 4);
        let whole = DssErrorTable::new(&hm, &qt);
        let bytes = whole.encode(&hm);
        let pages = (bytes.len() - HEADER_LEN_V2) / (PAGE_NODES * ENTRY_BYTES);
        assert!(pages >= 4, "{pages} pages");
        let len = bytes.len() as u64;
        let reader: Arc<dyn TableReader> = Arc::new(bytes.clone());
        let tiny = DssPaging { cache_bytes: (PAGE_NODES * ENTRY_BYTES) as u64 };
        let open = |r: Arc<dyn TableReader>| {
            DssErrorTable::open_paged(
                "dss_errors.bin",
                r,
                len,
                qt.shape(),
                Some(heights_checksum(&hm)),
                &tiny,
            )
            .unwrap()
        };
        let paged = open(reader.clone());
        assert!(paged.is_paged() && !whole.is_paged());
        let bits = |t: &DssErrorTable| all_nodes(t, &qt);
        assert_eq!(bits(&paged), bits(&whole));
        let stats = paged.paging_stats().unwrap();
        assert!(
            stats.pages_read > pages as u64 && stats.cached_bytes <= tiny.cache_bytes,
            "{stats:?}"
        );
        assert_eq!(
            bits(&paged.clone().exaggerated(3.0).exaggerated(0.1)),
            bits(&whole.clone().exaggerated(3.0).exaggerated(0.1))
        );
        // Heights checked at open, as whole.
        let other = DssErrorTable::open_paged("x", reader.clone(), len, qt.shape(), Some(1), &tiny)
            .unwrap_err();
        assert!(other.to_string().contains("heights differ"), "{other}");
        // Selections.
        let cams = [
            Camera::from_yaw_pitch(dvec3(100.0, 100.0, 400.0), 30.0, -25.0),
            Camera::from_yaw_pitch(dvec3(1500.0, 1000.0, 900.0), 200.0, -40.0),
        ];
        for cam in &cams {
            for rho_thr in [0.5, 2.0, 8.0] {
                let cfg = DssConfig { leaf_cells: 4, rho_thr, ..Default::default() };
                let [a, b] = [&whole, &paged].map(|t| select_dss_power_of_two(&qt, cam, t, &cfg));
                assert_eq!(a.patches, b.patches, "Method I, rho {rho_thr}");
                let [a, b] = [&whole, &paged].map(|t| select_dss_uniform(&qt, cam, t, &cfg));
                assert_eq!(a.patches, b.patches, "Method II, rho {rho_thr}");
                let scfg = DssStripsConfig {
                    dss: cfg.clone(),
                    half_width_cells: 1,
                    factors: StripFactors::Sliding,
                };
                let [a, b] = [&whole, &paged].map(|t| select_dss_strips(&qt, cam, t, &scfg));
                assert_eq!(a.blocks, b.blocks, "strips, rho {rho_thr}");
            }
        }
        // A damaged page: reported once, naming it; its nodes infinite, the others as whole.
        let bad_page = 2;
        let mut damaged = bytes.clone();
        let entries_at = HEADER_LEN_V2 + 8 * whole.levels.len();
        damaged[entries_at + bad_page * PAGE_NODES * ENTRY_BYTES + 17] ^= 4;
        let paged = open(Arc::new(damaged));
        let (a, b) = (bits(&whole), bits(&paged));
        let f = FACTORS;
        for (k, (x, y)) in a.chunks(f).zip(b.chunks(f)).enumerate() {
            if k / PAGE_NODES == bad_page {
                assert!(y.iter().all(|&v| f64::from_bits(v) == f64::INFINITY), "node {k}");
            } else {
                assert_eq!(x, y, "node {k}");
            }
        }
        let e = paged.take_error().expect("the damaged page is reported");
        let text = e.to_string();
        assert!(text.contains("dss_errors.bin, page 2") && text.contains("checksum"), "{text}");
        assert!(paged.take_error().is_none(), "reported once");
    }
}
