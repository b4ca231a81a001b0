//! The geomorph method's per-patch table as bytes (`geomip.bin` in a store folder that
//! `terrain bake` writes): the article's max-error vertices are computed "in preprocessing"
//! (Wagner 2003), so a store's runtime reads them instead of the heightmap.
//!
//! Layout (little-endian), version 2, made to be read by pages ([`GeomipTable::open_paged`],
//! `geomip_pages`):
//!
//! ```text
//! magic "TGMP" | version u32 = 2 | width u32 | height u32 | patch_cells u32 | levels u32 |
//! patches_x u32 | patches_y u32 | heights u32 (CRC-32 of the heightmap's samples and void
//! mask, see `dss_file::heights_checksum`) | page_patches u32 | summary_level u32 |
//! entries: per patch, row-major from the south, per level 1 .. levels - 1:
//!   error f32 (monotone, rounded up) | height f32 | vertex u16 (dj (P + 1) + di) |
//! tail: per page of page_patches patches (the last one shorter): crc32 u32 of its entries |
//!   the coarsest-level pyramid's nodes 2^summary_level patches wide (row-major from the
//!   south, ceil(patches_x / 2^s) x ceil(patches_y / 2^s)): L errors f32, z_lo f32, z_hi f32 |
//! crc32 u32 (of the header and the tail before it)
//! ```
//!
//! 10 bytes per patch and level (40 per 16-cell patch), plus a page checksum per 128 patches
//! and 24 bytes per 64 patches. Opening reads the header and the tail (1.7 MB for a
//! 32769^2 grid, whose entries are 168 MB); the entries are read a page at a time when a
//! frame needs them, each checked by its CRC-32. Version 1 (the same entries after a 36-byte
//! header without the last two fields, then one CRC-32 of every byte) is still read whole
//! ([`GeomipTable::decode`]); [`GeomipTable::open_paged`] refuses it with
//! [`GeomipFileError::Version`] (bake the store again to read it by pages).
//!
//! A table read back equals the computed one bit for bit, so the selection does not change.
//! It is tied to its grid and patch size (checked on reading), and to its heights when the
//! reader has them at hand; a store folder is written whole by one bake, so a store's table
//! is read without that check, like the DSS table. terrain-core does no file I/O here; the
//! app reads and writes the bytes.

use std::sync::Arc;

use super::dss_file::heights_checksum;
use super::geomip_pages::{
    GeomipPaging, GeomipPagingStats, PagedEntries, PagedLayout, TableReader,
};
use super::geomipmap::{BandStack, GeomipRuns, GeomipTable, PyramidLevel, vertex_range, z_union};
use crate::checksum::{crc32, crc32_update};
use crate::geometry::Camera;
use crate::heightmap::Heightmap;
use crate::quadtree::NodeTree;

/// The magic bytes.
pub const MAGIC: [u8; 4] = *b"TGMP";
/// The format version this build writes (it reads version 1 too, whole).
pub const VERSION: u32 = 2;
/// The fixed header's length.
const HEADER_LEN: usize = 4 + 4 * 10;
/// Version 1's header length.
const V1_HEADER_LEN: usize = 4 + 4 * 8;
/// Bytes per patch and level.
const ENTRY_LEN: usize = 10;
/// Patches per page of entries (5 KiB at 16 cells).
const PAGE_PATCHES: u32 = 128;
/// The pyramid level the tail holds: nodes of 8 x 8 patches, the width up to which a partly
/// visible node is a run (`GeomipConfig::partial_run_patches`' default), so the walk along
/// the frustum's sides is decided from the tail and reads no page.
const SUMMARY_LEVEL: u32 = 3;

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

/// An entry's error, height and vertex.
pub(super) fn decode_entry(b: &[u8]) -> (f32, f32, u16) {
    let e = f32::from_le_bytes(b[0..4].try_into().expect("4 bytes"));
    let z = f32::from_le_bytes(b[4..8].try_into().expect("4 bytes"));
    let v = u16::from_le_bytes(b[8..10].try_into().expect("2 bytes"));
    (e, z, v)
}

/// Whether an entry is one a table can hold (`last`: samples per patch).
pub(super) fn entry_ok(e: f32, z: f32, v: u16, last: u32) -> bool {
    e.is_finite() && e >= 0.0 && z.is_finite() && u32::from(v) < last
}

/// The pyramid's summary level, streamed: per node `2^SUMMARY_LEVEL` patches wide and radius
/// `r < L`, the largest `m_{L-r}` over the node's patches widened by `r` (clipped to the
/// grid), and the height range of the vertices with a positive error over the node widened
/// by `L - 1`: the whole table's `CoarsePyramid` at that level, computed row by row of
/// patches as the bake writes them.
#[derive(Debug, Clone, Default)]
struct SummaryRows {
    /// Per node row, per node: `L` errors.
    errors: Vec<Vec<f32>>,
    z: Vec<Vec<[f32; 2]>>,
    /// Patch rows seen.
    rows: usize,
}

impl SummaryRows {
    /// Adds patch row `rows` (its `nx` patches' entries, `l` per patch).
    fn add_row(&mut self, entries: (&[f32], &[f32]), nx: usize, l: usize) {
        let (errors, heights) = entries;
        let side = 1usize << SUMMARY_LEVEL;
        let nodes = nx.div_ceil(side);
        let j = self.rows;
        self.rows += 1;
        let reach = l.saturating_sub(1);
        // Node rows this patch row reaches: J with J side - r <= j <= (J + 1) side - 1 + r.
        let grow = (j + reach) / side + 1;
        while self.errors.len() < grow {
            self.errors.push(vec![0.0; nodes * l]);
            self.z.push(vec![[f32::INFINITY, f32::NEG_INFINITY]; nodes]);
        }
        let cols = |n: usize, r: usize| {
            let lo = (n * side).saturating_sub(r);
            let hi = ((n + 1) * side).min(nx) + r;
            lo..hi.min(nx)
        };
        for r in 0..l {
            for n in 0..nodes {
                let v = cols(n, r).map(|i| errors[i * l + (l - r) - 1]).fold(0.0, f32::max);
                for row in &mut self.errors[j.saturating_sub(r) / side..=(j + r) / side] {
                    row[n * l + r] = row[n * l + r].max(v);
                }
            }
        }
        for n in 0..nodes {
            let mut z = [f32::INFINITY, f32::NEG_INFINITY];
            for i in cols(n, reach) {
                let e = i * l..(i + 1) * l;
                z = z_union(z, vertex_range(&errors[e.clone()], &heights[e]));
            }
            for row in &mut self.z[j.saturating_sub(reach) / side..=(j + reach) / side] {
                row[n] = z_union(row[n], z);
            }
        }
    }

    /// The summary's bytes for a grid of `ny` patch rows.
    fn bytes(&self, ny: usize, l: usize) -> Vec<u8> {
        let rows = ny.div_ceil(1 << SUMMARY_LEVEL);
        let mut out = Vec::new();
        for (e, z) in self.errors.iter().zip(&self.z).take(rows) {
            for (node, z) in e.chunks_exact(l).zip(z) {
                for v in node.iter().chain(z) {
                    out.extend_from_slice(&v.to_le_bytes());
                }
            }
        }
        out
    }
}

/// Geomorph's table file written band by band, for a grid whose table is computed from bands
/// of its rows and never held whole (a bake's pass, a sharded bake's merge): the caller
/// reserves [`GeomipEncoder::HEADER_LEN`] bytes at the file's start, appends each band's
/// entries ([`GeomipEncoder::push`], south first, the bands as [`GeomipTable::stack`] takes
/// them) and, when the heights' checksum is known, writes [`GeomipEncoder::finish`]'s header
/// over the reserved bytes and its tail (page checksums, the pyramid's summary level,
/// CRC-32) after the last entry. The file is byte for byte [`GeomipTable::encode_for`] of the
/// stacked table (which is written by this encoder too). Memory: the summary level (24 bytes
/// per 64 patches) and a CRC-32 per page.
#[derive(Debug, Clone, Default)]
pub struct GeomipEncoder {
    bands: BandStack,
    /// CRC-32 of each whole page of entries so far.
    pages: Vec<u32>,
    /// CRC-32 and bytes of the page being filled.
    page: (u32, usize),
    summary: SummaryRows,
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
        if band.paged().is_some() {
            return Err("a table read by pages is not a band".into());
        }
        self.bands.add(band)?;
        let start = out.len();
        let (errors, heights, vertices) = band.parts();
        out.reserve(errors.len() * ENTRY_LEN);
        for ((e, z), v) in errors.iter().zip(heights).zip(vertices) {
            out.extend_from_slice(&e.to_le_bytes());
            out.extend_from_slice(&z.to_le_bytes());
            out.extend_from_slice(&v.to_le_bytes());
        }
        let l = band.levels() - 1;
        let nx = band.patch_counts().0 as usize;
        let page_len = PAGE_PATCHES as usize * l * ENTRY_LEN;
        let mut rest = &out[start..];
        while !rest.is_empty() {
            let take = (page_len - self.page.1).min(rest.len());
            self.page = (crc32_update(self.page.0, &rest[..take]), self.page.1 + take);
            if self.page.1 == page_len {
                self.pages.push(self.page.0);
                self.page = (0, 0);
            }
            rest = &rest[take..];
        }
        let row = nx * l;
        for (e, z) in errors.chunks_exact(row).zip(heights.chunks_exact(row)) {
            self.summary.add_row((e, z), nx, l);
        }
        Ok(())
    }

    /// The file's header (for its first [`GeomipEncoder::HEADER_LEN`] bytes), tied to heights
    /// whose [`heights_checksum`] is `heights_crc`, and its tail (after the entries). An
    /// error when no band was pushed.
    pub fn finish(&self, heights_crc: u32) -> Result<([u8; HEADER_LEN], Vec<u8>), String> {
        let (w, h, p) = self.bands.grid()?;
        let count = |n: u32| (n.saturating_sub(1)).div_ceil(p).max(1);
        let levels = p.trailing_zeros() + 1;
        let mut header = [0u8; HEADER_LEN];
        header[..4].copy_from_slice(&MAGIC);
        let fields = [
            VERSION,
            w,
            h,
            p,
            levels,
            count(w),
            count(h),
            heights_crc,
            PAGE_PATCHES,
            SUMMARY_LEVEL,
        ];
        for (k, v) in fields.iter().enumerate() {
            header[4 + 4 * k..8 + 4 * k].copy_from_slice(&v.to_le_bytes());
        }
        let mut tail = Vec::new();
        let last = (self.page.1 > 0).then_some(self.page.0);
        for c in self.pages.iter().chain(&last) {
            tail.extend_from_slice(&c.to_le_bytes());
        }
        tail.extend(self.summary.bytes(count(h) as usize, (levels - 1) as usize));
        let crc = crc32_update(crc32(&header), &tail);
        tail.extend_from_slice(&crc.to_le_bytes());
        Ok((header, tail))
    }
}

/// A version 2 file's layout from its header, checked for consistency: the grid, patch
/// size, levels, patch counts, heights' checksum, and the bytes of entries and tail.
struct Layout2 {
    width: u32,
    height: u32,
    p: u32,
    l: usize,
    nx: u32,
    ny: u32,
    heights_crc: u32,
    page_patches: u32,
    summary_level: u32,
    pages: usize,
    entries_len: u64,
    summary_nodes: (u32, u32),
    tail_len: u64,
}

fn u32_at(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes(b[o..o + 4].try_into().expect("4 bytes"))
}

/// A header's first fields (both versions).
struct Grid {
    width: u32,
    height: u32,
    p: u32,
    levels: u32,
    nx: u32,
    ny: u32,
    heights_crc: u32,
}

/// The grid's shape from a header's first fields (both versions), checked.
fn check_grid(head: &[u8]) -> Result<Grid, GeomipFileError> {
    let (width, height, p, levels) =
        (u32_at(head, 8), u32_at(head, 12), u32_at(head, 16), u32_at(head, 20));
    let (nx, ny, heights_crc) = (u32_at(head, 24), u32_at(head, 28), u32_at(head, 32));
    if !(2..=64).contains(&p) || !p.is_power_of_two() || levels != p.trailing_zeros() + 1 {
        return Err(GeomipFileError::Layout(format!("{p}-cell patches with {levels} levels")));
    }
    let count = |n: u32| (n.saturating_sub(1)).div_ceil(p).max(1);
    if (nx, ny) != (count(width), count(height)) {
        return Err(GeomipFileError::Layout(format!(
            "{nx} x {ny} patches for {width} x {height} samples"
        )));
    }
    Ok(Grid { width, height, p, levels, nx, ny, heights_crc })
}

/// Magic and version, before anything else is read.
fn check_magic(head: &[u8]) -> Result<u32, GeomipFileError> {
    if head.len() < 4 || head[..4] != MAGIC {
        return Err(GeomipFileError::Magic { table: TABLE });
    }
    if head.len() < 8 {
        return Err(GeomipFileError::Truncated { len: head.len(), needed: 8 });
    }
    match u32_at(head, 4) {
        v @ (1 | VERSION) => Ok(v),
        found => Err(GeomipFileError::Version { table: TABLE, found, expected: VERSION }),
    }
}

fn layout2(head: &[u8]) -> Result<Layout2, GeomipFileError> {
    if head.len() < HEADER_LEN {
        return Err(GeomipFileError::Truncated { len: head.len(), needed: HEADER_LEN });
    }
    let Grid { width, height, p, levels, nx, ny, heights_crc } = check_grid(head)?;
    let (page_patches, summary_level) = (u32_at(head, 36), u32_at(head, 40));
    if !(1..=1 << 20).contains(&page_patches) || summary_level > 16 {
        return Err(GeomipFileError::Layout(format!(
            "pages of {page_patches} patches, summary level {summary_level}"
        )));
    }
    let l = levels as usize - 1;
    let patches = u64::from(nx) * u64::from(ny);
    let pages = patches.div_ceil(u64::from(page_patches));
    let side = 1u32 << summary_level;
    let summary_nodes = (nx.div_ceil(side), ny.div_ceil(side));
    let nodes = u64::from(summary_nodes.0) * u64::from(summary_nodes.1);
    Ok(Layout2 {
        width,
        height,
        p,
        l,
        nx,
        ny,
        heights_crc,
        page_patches,
        summary_level,
        pages: pages as usize,
        entries_len: patches * (l * ENTRY_LEN) as u64,
        summary_nodes,
        tail_len: pages * 4 + nodes * (l as u64 + 2) * 4 + 4,
    })
}

/// The file must be `want`'s.
fn check_want(
    (width, height, p, heights_crc): (u32, u32, u32, u32),
    want: &GeomipFor,
) -> Result<(), GeomipFileError> {
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
    Ok(())
}

/// A table's entries as its three parts (errors, heights, vertices).
type Parts = (Vec<f32>, Vec<f32>, Vec<u16>);

/// Decodes `bytes` of entries (`p`-cell patches) into the three parts.
fn decode_entries(bytes: &[u8], p: u32) -> Result<Parts, GeomipFileError> {
    let entries = bytes.len() / ENTRY_LEN;
    let (mut errors, mut heights, mut vertices) =
        (Vec::with_capacity(entries), Vec::with_capacity(entries), Vec::with_capacity(entries));
    let last = (p + 1) * (p + 1);
    for (k, b) in bytes.chunks_exact(ENTRY_LEN).enumerate() {
        let (e, z, v) = decode_entry(b);
        if !entry_ok(e, z, v, last) {
            return Err(GeomipFileError::Layout(format!(
                "entry {k}: error {e}, height {z}, vertex {v}"
            )));
        }
        errors.push(e);
        heights.push(z);
        vertices.push(v);
    }
    Ok((errors, heights, vertices))
}

impl GeomipTable {
    /// The table as bytes, tied to `hm` (the terrain it was computed from).
    ///
    /// # Panics
    /// If the table was computed for another grid size, or is read by pages.
    pub fn encode(&self, hm: &Heightmap) -> Vec<u8> {
        let (w, h) = self.grid_size();
        assert_eq!((w, h), (hm.width() as u32, hm.height() as u32), "the table of another grid");
        self.encode_for(heights_checksum(hm))
    }

    /// The table as bytes, tied to heights whose [`heights_checksum`] is `heights_crc` (a
    /// table computed band by band, with the checksum accumulated over the bands' rows).
    ///
    /// # Panics
    /// If the table is read by pages ([`GeomipTable::open_paged`]).
    pub fn encode_for(&self, heights_crc: u32) -> Vec<u8> {
        let mut encoder = GeomipEncoder::new();
        let mut out = Vec::with_capacity(HEADER_LEN + self.parts().0.len() * ENTRY_LEN + 4);
        out.resize(HEADER_LEN, 0);
        encoder.push(self, &mut out).expect("a table held whole is a band of itself");
        let (header, tail) = encoder.finish(heights_crc).expect("one band");
        out[..HEADER_LEN].copy_from_slice(&header);
        out.extend_from_slice(&tail);
        out
    }

    /// Reads a table whole from `bytes` (version 2, or version 1): refused unless the file is
    /// whole (checksums), of a version this build reads, consistent, and made for `want`'s
    /// grid, patch size and (when given) heights.
    pub fn decode(bytes: &[u8], want: &GeomipFor) -> Result<Self, GeomipFileError> {
        if check_magic(bytes)? == 1 {
            return Self::decode_v1(bytes, want);
        }
        let lay = layout2(bytes)?;
        let needed = HEADER_LEN as u64 + lay.entries_len + lay.tail_len;
        if bytes.len() as u64 != needed {
            return Err(GeomipFileError::Truncated { len: bytes.len(), needed: needed as usize });
        }
        let entries_end = HEADER_LEN + lay.entries_len as usize;
        let tail = &bytes[entries_end..];
        let stored = u32_at(tail, tail.len() - 4);
        let computed = crc32_update(crc32(&bytes[..HEADER_LEN]), &tail[..tail.len() - 4]);
        if stored != computed {
            return Err(GeomipFileError::Checksum { stored, computed });
        }
        let page_len = lay.page_patches as usize * lay.l * ENTRY_LEN;
        for (k, page) in bytes[HEADER_LEN..entries_end].chunks(page_len).enumerate() {
            let (stored, computed) = (u32_at(tail, 4 * k), crc32(page));
            if stored != computed {
                return Err(GeomipFileError::Checksum { stored, computed });
            }
        }
        check_want((lay.width, lay.height, lay.p, lay.heights_crc), want)?;
        let (errors, heights, vertices) = decode_entries(&bytes[HEADER_LEN..entries_end], lay.p)?;
        Ok(GeomipTable::from_parts((lay.width, lay.height, lay.p), errors, heights, vertices))
    }

    /// Version 1: one CRC-32 of every byte before it.
    fn decode_v1(bytes: &[u8], want: &GeomipFor) -> Result<Self, GeomipFileError> {
        if bytes.len() < V1_HEADER_LEN {
            return Err(GeomipFileError::Truncated { len: bytes.len(), needed: V1_HEADER_LEN });
        }
        let Grid { width, height, p, levels, nx, ny, heights_crc } = check_grid(bytes)?;
        let entries = (nx as usize).saturating_mul(ny as usize).saturating_mul(levels as usize - 1);
        let needed = entries.saturating_mul(ENTRY_LEN).saturating_add(V1_HEADER_LEN + 4);
        if bytes.len() != needed {
            return Err(GeomipFileError::Truncated { len: bytes.len(), needed });
        }
        let stored = u32_at(bytes, needed - 4);
        let computed = crc32(&bytes[..needed - 4]);
        if stored != computed {
            return Err(GeomipFileError::Checksum { stored, computed });
        }
        check_want((width, height, p, heights_crc), want)?;
        let (errors, heights, vertices) = decode_entries(&bytes[V1_HEADER_LEN..needed - 4], p)?;
        Ok(GeomipTable::from_parts((width, height, p), errors, heights, vertices))
    }

    /// Opens a version 2 table of `len` bytes for reading by pages through `reader` (`file`
    /// names it in errors): reads and checks the header and the tail only (the page
    /// checksums and the pyramid's summary level; for a 32769^2 grid 1.7 MB of its 168 MB),
    /// then each page of entries when a frame first needs it, through a cache of
    /// `paging.cache_bytes`. The selection is bit for bit that of the table read whole. A
    /// version 1 file is refused ([`GeomipFileError::Version`]): [`GeomipTable::decode`]
    /// reads it whole.
    pub fn open_paged(
        file: &str,
        reader: Arc<dyn TableReader>,
        len: u64,
        want: &GeomipFor,
        paging: &GeomipPaging,
    ) -> Result<Self, GeomipFileError> {
        let read = |offset: u64, n: usize| -> Result<Vec<u8>, GeomipFileError> {
            let mut buf = vec![0u8; n];
            reader.read_at(offset, &mut buf).map_err(|e| GeomipFileError::Read(e.to_string()))?;
            Ok(buf)
        };
        let head = read(0, HEADER_LEN.min(len as usize))?;
        if check_magic(&head)? == 1 {
            return Err(GeomipFileError::Version { table: TABLE, found: 1, expected: VERSION });
        }
        let lay = layout2(&head)?;
        let needed = HEADER_LEN as u64 + lay.entries_len + lay.tail_len;
        if len != needed {
            return Err(GeomipFileError::Truncated { len: len as usize, needed: needed as usize });
        }
        let tail = read(HEADER_LEN as u64 + lay.entries_len, lay.tail_len as usize)?;
        let stored = u32_at(&tail, tail.len() - 4);
        let computed = crc32_update(crc32(&head), &tail[..tail.len() - 4]);
        if stored != computed {
            return Err(GeomipFileError::Checksum { stored, computed });
        }
        check_want((lay.width, lay.height, lay.p, lay.heights_crc), want)?;
        let page_crcs: Arc<[u32]> = (0..lay.pages).map(|k| u32_at(&tail, 4 * k)).collect();
        let (snx, sny) = lay.summary_nodes;
        let mut base = PyramidLevel::empty(snx, sny, lay.l);
        let mut at = 4 * lay.pages;
        for j in 0..sny {
            for i in 0..snx {
                let k = base.index(i, j);
                for r in 0..lay.l {
                    base.errors[k * lay.l + r] =
                        f32::from_le_bytes(tail[at..at + 4].try_into().expect("4 bytes"));
                    at += 4;
                }
                let z = |o: usize| f32::from_le_bytes(tail[o..o + 4].try_into().expect("4 bytes"));
                base.z[k] = [z(at), z(at + 4)];
                at += 8;
            }
        }
        let layout = PagedLayout {
            file: file.to_string(),
            p: lay.p,
            l: lay.l,
            nx: lay.nx,
            ny: lay.ny,
            page_patches: lay.page_patches as usize,
            entries_at: HEADER_LEN as u64,
            page_crcs,
            summary_level: lay.summary_level as usize,
        };
        let open_bytes = (head.len() + tail.len()) as u64;
        let paged = PagedEntries::new(layout, reader, base, paging, open_bytes);
        Ok(GeomipTable::from_paged((lay.width, lay.height, lay.p), paged))
    }

    /// What a table read by pages has read and holds (`None` for a table held whole).
    pub fn paging_stats(&self) -> Option<GeomipPagingStats> {
        self.paged().map(|p| p.stats())
    }

    /// Whether a table read by pages waits for a page its reader has not got yet (the
    /// default), or bounds that page's patches by the coarse pyramid and counts it late
    /// ([`GeomipPagingStats::pages_late`]; see [`TableReader::set_waiting`]). A table held
    /// whole never waits.
    pub fn set_waiting(&self, wait: bool) {
        if let Some(p) = self.paged() {
            p.set_waiting(wait);
        }
    }

    /// Starts fetching the rest of a table read by pages in the background, where its reader
    /// fetches ([`TableReader::fetch_all_in_background`]).
    pub fn fetch_all_in_background(&self) {
        if let Some(p) = self.paged() {
            p.fetch_all_in_background();
        }
    }

    /// [`GeomipTable::select_runs`], failing when a page of a table read by pages that the
    /// frame needed could not be read or is damaged (the error names the file and the page).
    /// A table held whole never fails.
    ///
    /// # Panics
    /// If `tree` does not fit the table ([`GeomipTable::fits`]).
    pub fn try_select_runs(
        &self,
        tree: &dyn NodeTree,
        camera: &Camera,
        cfg: &super::GeomipConfig,
    ) -> Result<GeomipRuns, GeomipFileError> {
        let paged = self.paged();
        if let Some(p) = paged {
            p.take_error();
        }
        let runs = self.select_runs(tree, camera, cfg);
        match paged.and_then(|p| p.take_error()) {
            Some(e) => Err(e),
            None => Ok(runs),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Camera;
    use crate::lod::{GeomipConfig, GeomipScene, PatchLod};
    use crate::quadtree::Quadtree;
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
        let mut v3 = bytes.clone();
        v3[4] = 3;
        assert_eq!(
            dec(&v3),
            GeomipFileError::Version { table: TABLE, found: 3, expected: VERSION }
        );
        // A damaged tail (the pyramid's summary, the page checksums) is refused too.
        let mut tail = bytes.clone();
        let n = tail.len();
        tail[n - 9] ^= 1;
        assert!(matches!(dec(&tail), GeomipFileError::Checksum { .. }));
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

    /// `bytes` in memory, counting what is read.
    #[derive(Default)]
    struct Counted {
        bytes: Vec<u8>,
        read: std::sync::atomic::AtomicU64,
    }

    impl TableReader for Counted {
        fn read_at(&self, offset: u64, buf: &mut [u8]) -> std::io::Result<()> {
            self.read.fetch_add(buf.len() as u64, std::sync::atomic::Ordering::Relaxed);
            self.bytes.read_at(offset, buf)
        }
    }

    fn open(bytes: Vec<u8>, w: &GeomipFor, cache: u64) -> (GeomipTable, Arc<Counted>) {
        let reader = Arc::new(Counted { bytes, ..Counted::default() });
        let len = reader.bytes.len() as u64;
        let paging = GeomipPaging { cache_bytes: cache };
        let t = GeomipTable::open_paged("geomip.bin", reader.clone(), len, w, &paging).unwrap();
        (t, reader)
    }

    fn same_runs(a: &GeomipRuns, b: &GeomipRuns) -> bool {
        (&a.runs, &a.patches, &a.factors, a.culled) == (&b.runs, &b.patches, &b.factors, b.culled)
    }

    /// The first node of a pyramid level that differs, bit for bit (past the grid: none in
    /// both).
    fn pyramid_diff(a: &GeomipTable, b: &GeomipTable) -> Option<String> {
        let (nx, ny) = a.patch_counts();
        let l = a.levels() - 1;
        for m in 0..=(nx.max(ny).next_power_of_two().ilog2() as usize + 2) {
            for j in 0..=ny.div_ceil(1 << m) {
                for i in 0..=nx.div_ceil(1 << m) {
                    let (x, y) = (a.node_bound(m, i, j), b.node_bound(m, i, j));
                    let bits = |n: Option<super::super::geomipmap::NodeBound>| {
                        n.map(|n| {
                            let e: Vec<u32> = n.errors[..l].iter().map(|v| v.to_bits()).collect();
                            (e, n.z.map(f32::to_bits))
                        })
                    };
                    if bits(x) != bits(y) {
                        return Some(format!("level {m}, node ({i}, {j})"));
                    }
                }
            }
        }
        None
    }

    /// `bytes` whose entries past `from` are not here yet while `missing` holds, answering
    /// `WouldBlock` for them when told not to wait (as a remote table being fetched).
    struct Arriving {
        bytes: Vec<u8>,
        from: u64,
        missing: std::sync::atomic::AtomicBool,
        waiting: std::sync::atomic::AtomicBool,
    }

    impl TableReader for Arriving {
        fn read_at(&self, offset: u64, buf: &mut [u8]) -> std::io::Result<()> {
            use std::sync::atomic::Ordering::Relaxed;
            let late = self.missing.load(Relaxed) && offset + buf.len() as u64 > self.from;
            if late && !self.waiting.load(Relaxed) {
                return Err(std::io::ErrorKind::WouldBlock.into());
            }
            self.bytes.read_at(offset, buf)
        }

        fn set_waiting(&self, wait: bool) {
            self.waiting.store(wait, std::sync::atomic::Ordering::Relaxed);
        }
    }

    /// A page not here yet, not waited for, is counted late and its patches bounded by the
    /// coarse pyramid: every patch drawn as fine as, or finer than, its own entries draw it
    /// (some finer), never coarser; once the pages arrive the selection is the whole table's,
    /// bit for bit (nothing bounded was kept). Waiting, the same table reads them at once.
    #[test]
    fn a_page_not_here_yet_is_drawn_finer_never_coarser_and_exactly_once_it_arrives() {
        use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
        let hm = terrain(1025, 707);
        let whole = GeomipTable::new(&hm, 16);
        let bytes = whole.encode(&hm);
        let len = bytes.len() as u64;
        // Entries of the northern half (pages past the middle) not here yet.
        let from = HEADER_LEN as u64 + (len - HEADER_LEN as u64) / 2;
        let reader = Arc::new(Arriving {
            bytes,
            from,
            missing: AtomicBool::new(true),
            waiting: AtomicBool::new(true),
        });
        let w = want(&hm, 16);
        let paging = GeomipPaging::default();
        let paged = GeomipTable::open_paged("geomip.bin", reader.clone(), len, &w, &paging)
            .unwrap()
            .exaggerated(1.5);
        let whole = whole.exaggerated(1.5);
        let tree = Quadtree::new(&hm, 16);
        let cfg = GeomipConfig::default();
        let cams: Vec<Camera> = [
            (0.5, 0.9, 200.0, 270.0),
            (0.2, 0.6, 60.0, 0.0),
            (0.8, 0.95, 900.0, 200.0),
            (0.5, 0.1, 400.0, 90.0),
        ]
        .iter()
        .map(|&(x, y, z, yaw)| {
            let pos = hm.grid_to_world(x * 1025.0, y * 707.0).extend(z);
            Camera::from_yaw_pitch(pos, yaw, -20.0).with_viewport(1280.0, 720.0)
        })
        .collect();
        paged.set_waiting(false);
        let (mut finer, mut late_frames) = (0, 0);
        for (k, cam) in cams.iter().enumerate() {
            let late = paged.paging_stats().unwrap().pages_late;
            let a = whole.select_runs(&tree, cam, &cfg).expand();
            let b = paged.try_select_runs(&tree, cam, &cfg).unwrap().expand();
            late_frames += usize::from(paged.paging_stats().unwrap().pages_late > late);
            let level = |p: &PatchLod| f32::from(p.level) + p.tween;
            let of_b: std::collections::HashMap<(u32, u32), f32> =
                b.patches.iter().map(|p| ((p.i, p.j), level(p))).collect();
            assert_eq!(a.patches.len(), b.patches.len(), "camera {k}");
            for p in &a.patches {
                let lb = of_b[&(p.i, p.j)];
                assert!(lb <= level(p) + 1e-6, "camera {k}, patch ({}, {}) coarser", p.i, p.j);
                finer += usize::from(lb < level(p) - 1e-6);
            }
        }
        assert!(late_frames >= 2 && finer > 0, "{late_frames} frames late, {finer} finer");
        // Waiting, the same table reads the pages at once: the whole table's selection.
        paged.set_waiting(true);
        let late = paged.paging_stats().unwrap().pages_late;
        for cam in &cams {
            let (a, b) = (whole.select_runs(&tree, cam, &cfg), paged.select_runs(&tree, cam, &cfg));
            assert!(same_runs(&a, &b));
        }
        assert_eq!(paged.paging_stats().unwrap().pages_late, late);
        // Arrived, not waiting: the same, nothing late.
        reader.missing.store(false, Relaxed);
        paged.set_waiting(false);
        for cam in &cams {
            let (a, b) = (whole.select_runs(&tree, cam, &cfg), paged.select_runs(&tree, cam, &cfg));
            assert!(same_runs(&a, &b));
        }
        assert_eq!(paged.paging_stats().unwrap().pages_late, late);
    }

    #[test]
    fn a_table_read_by_pages_selects_bit_for_bit_and_opens_with_its_header_and_tail() {
        // Sides the patch does not divide; 16-cell patches (pages of 128 patches) and 8-cell
        // ones; a grid smaller than one summary node; a vertical exaggeration.
        for (w, h, p, scale) in
            [(1025, 707, 16, 1.0), (1025, 707, 16, 2.5), (601, 390, 8, 1.0), (100, 90, 16, 1.0)]
        {
            let hm = terrain(w, h);
            let whole = GeomipTable::new(&hm, p);
            let bytes = whole.encode(&hm);
            let len = bytes.len() as u64;
            let w = want(&hm, p);
            let (paged, reader) = open(bytes, &w, 48 << 10);
            let opened = reader.read.load(std::sync::atomic::Ordering::Relaxed);
            let (nx, ny) = whole.patch_counts();
            let (pages, nodes) =
                (u64::from(nx * ny).div_ceil(128), u64::from(nx.div_ceil(8) * ny.div_ceil(8)));
            let levels = u64::from(p.trailing_zeros());
            assert_eq!(opened, 44 + pages * 4 + nodes * (levels + 2) * 4 + 4, "{w:?}");
            assert_eq!(paged.paging_stats().unwrap().bytes_read, opened);
            if nx * ny > 1000 {
                assert!(opened * 20 < len, "{opened} of {len} bytes read at open");
            }
            let (whole, paged) = (whole.exaggerated(scale), paged.exaggerated(scale));
            assert_eq!(pyramid_diff(&whole, &paged), None);
            let tree = Quadtree::new(&hm, p);
            let cfg = GeomipConfig::default();
            let mut cams = 0;
            for (x, y, z, yaw) in [
                (0.1, 0.1, 300.0, 45.0),
                (0.5, 0.5, 80.0, 200.0),
                (0.9, 0.2, 2000.0, 120.0),
                (0.3, 0.8, 30.0, 300.0),
            ] {
                let pos = hm.grid_to_world(x * w.width as f64, y * w.height as f64).extend(z);
                let cam = Camera::from_yaw_pitch(pos, yaw, -20.0).with_viewport(1280.0, 720.0);
                let a = whole.select_runs(&tree, &cam, &cfg);
                let b = paged.try_select_runs(&tree, &cam, &cfg).unwrap();
                assert!(same_runs(&a, &b), "{w:?} camera {cams}");
                cams += usize::from(!a.patches.is_empty());
                // The cache stays within its budget.
                assert!(paged.paging_stats().unwrap().cached_bytes <= 48 << 10);
            }
            assert!(cams > 0, "some patches computed one by one");
            for (i, j) in [(0, 0), (nx - 1, ny - 1), (nx / 2, ny / 3)] {
                for lv in 0..p.trailing_zeros() as usize + 1 {
                    assert_eq!(
                        whole.level_error(i, j, lv).to_bits(),
                        paged.level_error(i, j, lv).to_bits()
                    );
                }
            }
        }
        // Negative control: one entry changed (its page's checksum made to match) changes
        // the pyramid the tiles compute.
        let hm = terrain(300, 300);
        let table = GeomipTable::new(&hm, 16);
        let mut bytes = table.encode(&hm);
        let off = HEADER_LEN + 40 * 19 + 10; // patch 19's level 2 error
        let e = f32::from_le_bytes(bytes[off..off + 4].try_into().unwrap());
        bytes[off..off + 4].copy_from_slice(&(e * 4.0 + 1.0).to_le_bytes());
        let page_len = 128 * 40;
        let entries = 19 * 19 * 40;
        let crc = crc32(&bytes[HEADER_LEN..HEADER_LEN + page_len]);
        let at = HEADER_LEN + entries;
        bytes[at..at + 4].copy_from_slice(&crc.to_le_bytes());
        let n = bytes.len();
        let tail = crc32_update(crc32(&bytes[..HEADER_LEN]), &bytes[at..n - 4]);
        bytes[n - 4..].copy_from_slice(&tail.to_le_bytes());
        let (paged, _) = open(bytes, &want(&hm, 16), 1 << 20);
        assert!(pyramid_diff(&table, &paged).is_some(), "a changed entry shows in the pyramid");
    }

    #[test]
    fn a_damaged_page_fails_only_the_frames_that_need_it_naming_the_file() {
        let hm = terrain(1025, 1025);
        let table = GeomipTable::new(&hm, 16);
        let mut bytes = table.encode(&hm);
        // The last page: the northernmost patches (64 x 64 patches, 32 pages).
        let last = HEADER_LEN + 64 * 64 * 40 - 100;
        bytes[last] ^= 0x40;
        let w = want(&hm, 16);
        assert!(matches!(
            GeomipTable::decode(&bytes, &w).unwrap_err(),
            GeomipFileError::Checksum { .. }
        ));
        let (paged, _) = open(bytes, &w, 1 << 20);
        let tree = Quadtree::new(&hm, 16);
        let cfg = GeomipConfig::default();
        let south =
            Camera::from_yaw_pitch(hm.grid_to_world(512.0, 40.0).extend(120.0), 180.0, -20.0)
                .with_viewport(1280.0, 720.0);
        let a = table.select_runs(&tree, &south, &cfg);
        let b = paged.try_select_runs(&tree, &south, &cfg).unwrap();
        assert!(same_runs(&a, &b), "a view away from the damaged page is drawn as before");
        let north =
            Camera::from_yaw_pitch(hm.grid_to_world(512.0, 1010.0).extend(60.0), 0.0, -30.0)
                .with_viewport(1280.0, 720.0);
        let e = paged.try_select_runs(&tree, &north, &cfg).unwrap_err();
        assert!(
            matches!(&e, GeomipFileError::Page { page: 31, cause, .. }
            if matches!(**cause, GeomipFileError::Checksum { .. })),
            "{e:?}"
        );
        let msg = e.to_string();
        assert!(msg.contains("geomip.bin, page 31") && msg.contains("damaged"), "{msg}");
        // Again on the next frame (nothing damaged is cached); the whole table has no error.
        assert!(paged.try_select_runs(&tree, &north, &cfg).is_err());
        assert!(table.try_select_runs(&tree, &north, &cfg).is_ok());
        // A damaged tail fails the open.
        let mut bytes = table.encode(&hm);
        let n = bytes.len();
        bytes[n - 30] ^= 1;
        let r: Arc<dyn TableReader> = Arc::new(bytes);
        let e = GeomipTable::open_paged("geomip.bin", r, n as u64, &w, &GeomipPaging::default());
        assert!(matches!(e.unwrap_err(), GeomipFileError::Checksum { .. }));
    }

    /// `table`'s version 1 file (as bakes before version 2 wrote it).
    fn encode_v1(table: &GeomipTable, heights_crc: u32) -> Vec<u8> {
        let (w, h) = table.grid_size();
        let p = table.patch_cells();
        let (nx, ny) = table.patch_counts();
        let mut out = MAGIC.to_vec();
        for v in [1, w, h, p, table.levels() as u32, nx, ny, heights_crc] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        let (e, z, v) = table.parts();
        for ((e, z), v) in e.iter().zip(z).zip(v) {
            out.extend_from_slice(&e.to_le_bytes());
            out.extend_from_slice(&z.to_le_bytes());
            out.extend_from_slice(&v.to_le_bytes());
        }
        let crc = crc32(&out);
        out.extend_from_slice(&crc.to_le_bytes());
        out
    }

    #[test]
    fn a_version_1_table_is_read_whole_and_refused_by_pages() {
        let hm = terrain(201, 130);
        let table = GeomipTable::new(&hm, 16);
        let v1 = encode_v1(&table, heights_checksum(&hm));
        assert_eq!(v1.len(), 36 + 13 * 9 * 40 + 4);
        assert_eq!(GeomipTable::decode(&v1, &want(&hm, 16)).unwrap(), table);
        let mut bad = v1.clone();
        bad[50] ^= 1;
        assert!(matches!(
            GeomipTable::decode(&bad, &want(&hm, 16)).unwrap_err(),
            GeomipFileError::Checksum { .. }
        ));
        let n = v1.len() as u64;
        let r: Arc<dyn TableReader> = Arc::new(v1);
        let e =
            GeomipTable::open_paged("geomip.bin", r, n, &want(&hm, 16), &GeomipPaging::default())
                .unwrap_err();
        assert_eq!(e, GeomipFileError::Version { table: TABLE, found: 1, expected: 2 });
        assert!(e.to_string().contains("bake it again"), "{e}");
    }
}
