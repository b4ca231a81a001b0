//! The paged grid index (index version 4): block entries in fixed-size pages, each with its
//! own CRC-32, read on demand through a bounded least-recently-used cache of decoded pages, so
//! opening a store reads its header and head (a few hundred KB at most) whatever the number
//! of blocks, and memory holds the pages in use. A remote store's index is read the same
//! way: its header and head fetched at open, each page by a range request when first needed,
//! through the mirror folder ([`PageSource::Remote`], `remote`'s module docs).
//!
//! # Layout after the header (see `format`'s module docs for the whole file)
//!
//! The *head*: entries per page (`u32`), bytes per entry (`u32`), flags (`u8`: 1 = DSS errors,
//! 2 = fine maxima), the bytes of every block file (`u64`), the pyramid's level count `P`
//! (`u8`), then the block pyramid: for each level `l < P` of the quadtree over the blocks
//! (the root spans the block grid rounded up to a power of two per side; level `l` has
//! `4^l` nodes, row-major), per node its blocks' least and greatest height and, per
//! block-local lattice level `0..=k`, the largest of its blocks' `level_errors` (0 at `k`;
//! empty nodes `+inf, -inf, 0...`); then the CRC-32 of the file's bytes so far. `P` is
//! `min(block levels, HEAD_LEVELS)`: the head is bounded by `4^HEAD_LEVELS` nodes, never by
//! the blocks. Then the pages: page `p` holds the entries of blocks `p E .. (p + 1) E`
//! (row-major positions, the last page shorter) and the CRC-32 of `p` (`u64`) followed by
//! those entry bytes (so a page read from another page's place fails it). Then the
//! CRC-32 of the whole file, which only a reader of every byte checks (the roughness file's tie
//! to its store).

use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use terrain_core::hash::IdMap;

use crate::error::StoreError;
use crate::format::{
    BlockEntry, Header, IndexError, Reader, Writer, crc32, entry_len, fine_count, index_prefix,
    read_entry, read_header,
};
use crate::remote::Remote;

/// Bytes of entries a page holds at most (a page has at least one entry).
pub(crate) const PAGE_BYTES: usize = 64 << 10;
/// Levels of the block pyramid kept in the head at most (`4^7` nodes at its finest level).
pub(crate) const HEAD_LEVELS: u8 = 8;
/// Default bytes of decoded pages a store keeps ([`crate::Store::with_page_cache_bytes`]):
/// about 5,800 entries of the 32769^2 store's index (5.5 KB each). A flight's selection and
/// the streamer's Eq. 7 walk read the entries of the blocks near the eye, a few thousand, and
/// their pages hold their rows' neighbours too: at 8 MiB (until 2026-12-05) `store_frame` on
/// that store read about 200 entries a frame that the selection's and the streamer's own
/// caches did not hold, decoding pages and entries took 15 % of its samples, and the `ooc`
/// frame took 19-20 ms of frame-thread CPU (selection 6-7 ms) against 15-16 ms (2.5 ms) at
/// 32 MiB and 15.1 ms at 64 (bench/ooc/README.md, "The index's page cache at 32 MiB").
pub(crate) const DEFAULT_PAGE_CACHE_BYTES: u64 = 32 << 20;
/// Bytes a decoded entry takes beyond its stored bytes (its `Vec`s and `Arc`), for the
/// cache's accounting.
const ENTRY_OVERHEAD: u64 = 160;

/// What the head of a version-4 index says: the page geometry, totals, and the block
/// pyramid the traversal above the blocks reads.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct IndexHead {
    /// Entries per page.
    pub page_entries: u32,
    /// Bytes of one entry.
    pub entry_len: u32,
    /// Whether every block has the DSS paper's errors.
    pub has_dss: bool,
    /// Whether the entries hold the fine maxima.
    pub has_fine: bool,
    /// Bytes of every block file.
    pub blocks_bytes: u64,
    /// Levels of the pyramid (`0..levels`).
    pub levels: u8,
    /// Per node of the pyramid, level-major and row-major: least and greatest height.
    pub upper: Vec<[f32; 2]>,
    /// Per node, `k + 1` values: the largest `level_errors[l]` of its blocks (0 at `k`).
    pub upper_err: Vec<f32>,
}

/// Levels of the quadtree above a store's blocks: the root spans the block grid rounded up to
/// a power of two per side, so block `(row, col)` is a node of level `block_level`.
pub(crate) fn block_level(h: &Header) -> u8 {
    h.blocks_x.max(h.blocks_y).next_power_of_two().trailing_zeros() as u8
}

/// Nodes of levels `0..levels`: `(4^levels - 1) / 3`.
fn pyramid_nodes(levels: u8) -> usize {
    ((1usize << (2 * levels as usize)) - 1) / 3
}

/// Levels of the head's pyramid for `h`.
pub(crate) fn head_levels(h: &Header) -> u8 {
    block_level(h).min(HEAD_LEVELS)
}

/// Entries per page for `h` (fine maxima as `fine` says).
pub(crate) fn page_entries(h: &Header, fine: usize) -> u32 {
    (PAGE_BYTES / entry_len(h, fine)).max(1) as u32
}

/// Bytes of the head after the header: fields, pyramid, CRC-32.
fn head_fields_len(h: &Header) -> usize {
    4 + 4 + 1 + 8 + 1 + pyramid_nodes(head_levels(h)) * (2 + h.k as usize + 1) * 4 + 4
}

/// Bytes of a version-4 index before its first page: magic, version, header, head.
pub(crate) fn paged_prefix_len(h: &Header) -> usize {
    index_prefix(h).len() + head_fields_len(h)
}

/// The prefix of a version-4 index: [`index_prefix`] and the head with its CRC-32.
pub(crate) fn paged_prefix(h: &Header, head: &IndexHead) -> Vec<u8> {
    let mut w = Writer { buf: index_prefix(h) };
    w.u32(head.page_entries);
    w.u32(head.entry_len);
    w.u8(u8::from(head.has_dss) | (u8::from(head.has_fine) << 1));
    w.u64(head.blocks_bytes);
    w.u8(head.levels);
    let per = h.k as usize + 1;
    for (n, [lo, hi]) in head.upper.iter().enumerate() {
        w.f32(*lo);
        w.f32(*hi);
        head.upper_err[n * per..(n + 1) * per].iter().for_each(|e| w.f32(*e));
    }
    let crc = crc32(&w.buf);
    w.u32(crc);
    w.buf
}

/// Reads the head after the header (`r` just past it; `prefix` the bytes from the file's
/// start, for the head's CRC-32), checked against the header.
pub(crate) fn read_head(
    r: &mut Reader<'_>,
    prefix: &[u8],
    h: &Header,
) -> Result<IndexHead, IndexError> {
    let start = prefix.len() - r.remaining();
    let page_entries = r.u32()?;
    let entry_bytes = r.u32()?;
    let flags = r.u8()?;
    let blocks_bytes = r.u64()?;
    let levels = r.u8()?;
    let has_fine = flags & 2 != 0;
    let fine = if has_fine { fine_count(h.k, h.node_levels) } else { 0 };
    if flags & !3 != 0
        || entry_bytes as usize != entry_len(h, fine)
        || page_entries != page_entries_for(h, fine)
        || levels != head_levels(h)
    {
        return Err(IndexError::Corrupt(format!(
            "head: {page_entries} entries of {entry_bytes} bytes per page, flags {flags:#x}, \
             {levels} pyramid levels do not fit the header"
        )));
    }
    let per = h.k as usize + 1;
    let nodes = pyramid_nodes(levels);
    let mut upper = Vec::with_capacity(nodes);
    let mut upper_err = Vec::with_capacity(nodes * per);
    for _ in 0..nodes {
        upper.push([r.f32()?, r.f32()?]);
        for _ in 0..per {
            upper_err.push(r.f32()?);
        }
    }
    let end = prefix.len() - r.remaining();
    let stored = r.u32()?;
    let computed = crc32(&prefix[..end]);
    if stored != computed {
        return Err(IndexError::Corrupt(format!(
            "head (bytes {start}..{end}): checksum mismatch (stored {stored:08x}, computed {computed:08x})"
        )));
    }
    if !upper_err.iter().all(|e| e.is_finite() && *e >= 0.0) {
        return Err(IndexError::Corrupt("head: bad pyramid errors".into()));
    }
    Ok(IndexHead {
        page_entries,
        entry_len: entry_bytes,
        has_dss: flags & 1 != 0,
        has_fine,
        blocks_bytes,
        levels,
        upper,
        upper_err,
    })
}

fn page_entries_for(h: &Header, fine: usize) -> u32 {
    page_entries(h, fine)
}

impl IndexHead {
    /// Number of pages for `blocks` blocks.
    pub(crate) fn page_count(&self, blocks: usize) -> usize {
        blocks.div_ceil(self.page_entries as usize)
    }

    /// Page `p`'s first block position, its entry count, and its bytes' offset and length in
    /// the file (CRC-32 included), given the prefix length and the block count.
    pub(crate) fn page_span(
        &self,
        p: usize,
        prefix: u64,
        blocks: usize,
    ) -> (usize, usize, u64, u64) {
        let per = self.page_entries as usize;
        let first = p * per;
        let count = per.min(blocks.saturating_sub(first));
        let full = (per * self.entry_len as usize + 4) as u64;
        (first, count, prefix + p as u64 * full, (count * self.entry_len as usize + 4) as u64)
    }

    /// The length of the whole index file for `blocks` blocks.
    pub(crate) fn file_len(&self, prefix: u64, blocks: usize) -> u64 {
        let entries = (blocks * self.entry_len as usize) as u64;
        prefix + entries + 4 * self.page_count(blocks) as u64 + 4
    }
}

/// Builds the head of an index from its entries as a bake writes them (row-major).
#[derive(Debug)]
pub(crate) struct HeadBuilder {
    header: Header,
    head: IndexHead,
    /// Bytes of the entries of the page being written, for its CRC-32.
    page_crc: u32,
    count: usize,
}

impl HeadBuilder {
    /// An empty head for `header`'s grid (`fine`: the entries hold the fine maxima).
    pub(crate) fn new(header: &Header, fine: usize) -> Self {
        let levels = head_levels(header);
        let nodes = pyramid_nodes(levels);
        let head = IndexHead {
            page_entries: page_entries(header, fine),
            entry_len: entry_len(header, fine) as u32,
            has_dss: false,
            has_fine: fine > 0,
            blocks_bytes: 0,
            levels,
            upper: vec![[f32::INFINITY, f32::NEG_INFINITY]; nodes],
            upper_err: vec![0.0; nodes * (header.k as usize + 1)],
        };
        Self { header: header.clone(), head, page_crc: page_seed(0), count: 0 }
    }

    /// Adds the next entry (its stored `bytes`). Returns the page's CRC-32 when the entry
    /// completes a page.
    pub(crate) fn push(&mut self, entry: &BlockEntry, bytes: &[u8]) -> Option<u32> {
        let h = &self.header;
        let id = h.block_at(self.count);
        if self.count == 0 {
            self.head.has_dss = entry.dss.is_some();
        }
        self.head.blocks_bytes += entry.file_len;
        if self.head.levels > 0 {
            // The finest level of the pyramid; coarser ones are reduced in `finish`.
            let top = self.head.levels - 1;
            let s = block_level(h) - top;
            let side = 1usize << top;
            let n = pyramid_nodes(top) + (id.row >> s) as usize * side + (id.col >> s) as usize;
            let m = &mut self.head.upper[n];
            m[0] = m[0].min(entry.min);
            m[1] = m[1].max(entry.max);
            let per = h.k as usize + 1;
            for (o, v) in self.head.upper_err[n * per..(n + 1) * per]
                .iter_mut()
                .zip(entry.level_errors.iter().take(h.k as usize))
            {
                *o = o.max(*v);
            }
        }
        self.count += 1;
        self.page_crc = terrain_core::checksum::crc32_update(self.page_crc, bytes);
        let per = self.head.page_entries as usize;
        let full = self.count.is_multiple_of(per);
        full.then(|| std::mem::replace(&mut self.page_crc, page_seed(self.count / per)))
    }

    /// The last page's CRC-32 if it is short, and the head: every coarser level of the
    /// pyramid as the least, greatest and largest of its four children.
    pub(crate) fn finish(mut self) -> (Option<u32>, IndexHead) {
        let tail =
            (!self.count.is_multiple_of(self.head.page_entries as usize)).then_some(self.page_crc);
        let per = self.header.k as usize + 1;
        for level in (0..self.head.levels.saturating_sub(1)).rev() {
            let (m, base, child) =
                (1usize << level, pyramid_nodes(level), pyramid_nodes(level + 1));
            for j in 0..m {
                for i in 0..m {
                    let o = base + j * m + i;
                    for (ci, cj) in [
                        (2 * i, 2 * j),
                        (2 * i + 1, 2 * j),
                        (2 * i, 2 * j + 1),
                        (2 * i + 1, 2 * j + 1),
                    ] {
                        let c = child + cj * 2 * m + ci;
                        let [lo, hi] = self.head.upper[c];
                        let u = &mut self.head.upper[o];
                        u[0] = u[0].min(lo);
                        u[1] = u[1].max(hi);
                        for l in 0..per {
                            let v = self.head.upper_err[c * per + l];
                            let e = &mut self.head.upper_err[o * per + l];
                            *e = e.max(v);
                        }
                    }
                }
            }
        }
        (tail, self.head)
    }
}

/// The CRC-32 state a page's checksum starts from: that of its number `p` as a `u64`.
fn page_seed(p: usize) -> u32 {
    crc32(&(p as u64).to_le_bytes())
}

/// The entries of page `p`'s bytes (entries and their CRC-32), checked: the CRC-32, every
/// entry, the DSS errors as the head says.
pub(crate) fn decode_page(
    bytes: &[u8],
    header: &Header,
    head: &IndexHead,
    p: usize,
) -> Result<Vec<BlockEntry>, String> {
    let first = p * head.page_entries as usize;
    check_page_crc(bytes, p)?;
    let entries = &bytes[..bytes.len() - 4];
    let n = entries.len() / head.entry_len as usize;
    if n * head.entry_len as usize != entries.len() {
        return Err(format!("{} bytes are not whole entries", entries.len()));
    }
    let fine = if head.has_fine { fine_count(header.k, header.node_levels) } else { 0 };
    let mut r = Reader::new(entries);
    let mut out = Vec::with_capacity(n);
    for pos in first..first + n {
        let id = header.block_at(pos);
        let e = read_entry(&mut r, header, id, fine).map_err(|e| e.to_string())?;
        if e.dss.is_some() != head.has_dss {
            return Err(format!("block {id}: DSS errors where the head says otherwise"));
        }
        out.push(e);
    }
    Ok(out)
}

/// Parses a version-4 index whole (every page), for tools and tests: the same entries as the
/// paged reader decodes one page at a time.
pub(crate) fn read_paged_whole(bytes: &[u8]) -> Result<(Header, Vec<BlockEntry>), IndexError> {
    let mut r = Reader::new(&bytes[12..]);
    let header = read_header(&mut r)?;
    let prefix_len = paged_prefix_len(&header);
    let prefix = bytes
        .get(..prefix_len)
        .ok_or_else(|| IndexError::Corrupt("shorter than its head".into()))?;
    let mut r = Reader::new(&prefix[12..]);
    read_header(&mut r)?;
    let head = read_head(&mut r, prefix, &header)?;
    let n = header.block_count();
    if head.file_len(prefix_len as u64, n) != bytes.len() as u64 {
        return Err(IndexError::Corrupt(format!(
            "{} bytes, expected {} for {n} blocks",
            bytes.len(),
            head.file_len(prefix_len as u64, n)
        )));
    }
    let mut blocks = Vec::with_capacity(n);
    for p in 0..head.page_count(n) {
        let (_, _, at, len) = head.page_span(p, prefix_len as u64, n);
        let page = &bytes[at as usize..(at + len) as usize];
        blocks.extend(
            decode_page(page, &header, &head, p)
                .map_err(|m| IndexError::Corrupt(format!("page {p}: {m}")))?,
        );
    }
    Ok((header, blocks))
}

/// Scales every height and height error of an entry (a vertical exaggeration,
/// [`crate::Store::exaggerated`]).
pub(crate) fn scale_entry(b: &mut BlockEntry, scale: f64) {
    let f = |v: &mut f32| *v = (f64::from(*v) * scale) as f32;
    f(&mut b.min);
    f(&mut b.max);
    for n in &mut b.nodes {
        f(&mut n.min);
        f(&mut n.max);
        f(&mut n.static_error);
    }
    b.level_errors.iter_mut().for_each(f);
    b.fine_errors.iter_mut().for_each(f);
    b.fine_max.reset();
    if let Some(d) = &mut b.dss {
        d.avg.iter_mut().chain(d.max.iter_mut()).for_each(f);
    }
}

/// Where a paged index's bytes come from: the file, or a remote store's ranged reads.
#[derive(Debug)]
pub(crate) enum PageSource {
    /// A local index file.
    File(File),
    /// A remote store's index: each page by a range request, through the mirror
    /// ([`Remote::index_page`]).
    Remote(Arc<Remote>),
}

impl PageSource {
    fn try_clone(&self, path: &Path) -> Result<Self, StoreError> {
        Ok(match self {
            PageSource::File(f) => PageSource::File(
                f.try_clone()
                    .map_err(|cause| StoreError::Io { path: path.to_path_buf(), cause })?,
            ),
            PageSource::Remote(r) => PageSource::Remote(r.clone()),
        })
    }
}

/// Whether `bytes` (entries and their CRC-32) pass page `p`'s checksum.
fn check_page_crc(bytes: &[u8], p: usize) -> Result<(), String> {
    let body = bytes.len().checked_sub(4).ok_or("shorter than its checksum")?;
    let (entries, tail) = bytes.split_at(body);
    let stored = u32::from_le_bytes([tail[0], tail[1], tail[2], tail[3]]);
    let computed = terrain_core::checksum::crc32_update(page_seed(p), entries);
    if stored != computed {
        return Err(format!("checksum mismatch (stored {stored:08x}, computed {computed:08x})"));
    }
    Ok(())
}

/// Positioned read of a shared file.
pub(crate) fn read_exact_at(file: &File, offset: u64, buf: &mut [u8]) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileExt;
        file.read_exact_at(buf, offset)
    }
    #[cfg(not(unix))]
    {
        use std::io::{Read, Seek, SeekFrom};
        let mut f = file.try_clone()?;
        f.seek(SeekFrom::Start(offset))?;
        f.read_exact(buf)
    }
}

/// A decoded page in the cache.
#[derive(Debug)]
struct CachedPage {
    entries: Arc<[Arc<BlockEntry>]>,
    bytes: u64,
    stamp: u64,
}

#[derive(Debug)]
struct Lru {
    pages: IdMap<usize, CachedPage>,
    bytes: u64,
    /// Bytes of decoded pages kept at most (at least one page is kept).
    budget: u64,
    clock: u64,
    /// Pages decoded (misses), for tests and measurements.
    decoded: u64,
}

impl Lru {
    fn new(budget: u64) -> Mutex<Self> {
        Mutex::new(Self { pages: IdMap::default(), bytes: 0, budget, clock: 0, decoded: 0 })
    }

    /// Drops the least recently used pages but `keep` while over the budget.
    fn evict(&mut self, keep: usize) {
        while self.bytes > self.budget && self.pages.len() > 1 {
            let oldest = self
                .pages
                .iter()
                .filter(|(q, _)| **q != keep)
                .min_by_key(|(_, c)| c.stamp)
                .map(|(q, _)| *q);
            let Some(q) = oldest else { break };
            let gone = self.pages.remove(&q).expect("present");
            self.bytes -= gone.bytes;
        }
    }
}

/// A version-4 index read page by page: its head in memory, pages decoded on demand and kept
/// in a byte-bounded LRU cache shared by every thread and clone of the store.
#[derive(Debug)]
pub(crate) struct PagedIndex {
    path: PathBuf,
    source: PageSource,
    header: Header,
    head: IndexHead,
    prefix_len: u64,
    /// The file's bytes before the first page (header and head).
    prefix: Arc<[u8]>,
    /// Vertical exaggeration applied to every decoded entry ([`scale_entry`]).
    scale: f64,
    lru: Mutex<Lru>,
}

impl PagedIndex {
    /// Opens the version-4 index at `path` (`file` open on it, `len` bytes): reads its prefix
    /// only.
    pub(crate) fn open(path: PathBuf, file: File, len: u64) -> Result<Self, StoreError> {
        let corrupt = |message: String| StoreError::CorruptIndex { path: path.clone(), message };
        let io = |cause| StoreError::Io { path: path.clone(), cause };
        let mut first = vec![0u8; len.min(64 << 10) as usize];
        read_exact_at(&file, 0, &mut first).map_err(io)?;
        let mut r = Reader::new(first.get(12..).ok_or_else(|| corrupt("no header".into()))?);
        let header = read_header(&mut r).map_err(|e| index_err(e, &path))?;
        let prefix_len = paged_prefix_len(&header) as u64;
        if prefix_len > len {
            return Err(corrupt(format!("{len} bytes, shorter than its head ({prefix_len})")));
        }
        let mut prefix = first;
        if prefix.len() < prefix_len as usize {
            prefix = vec![0u8; prefix_len as usize];
            read_exact_at(&file, 0, &mut prefix).map_err(io)?;
        }
        prefix.truncate(prefix_len as usize);
        Self::from_prefix(path, PageSource::File(file), &prefix, len)
    }

    /// Opens a remote store's version-4 index from its `prefix` (header and head, fetched at
    /// open), its object `len` bytes long; pages come through `remote`.
    pub(crate) fn open_remote(
        remote: Arc<Remote>,
        prefix: &[u8],
        len: u64,
    ) -> Result<Self, StoreError> {
        let path = PathBuf::from(format!("{}/{}", remote.url(), crate::format::INDEX_FILE));
        Self::from_prefix(path, PageSource::Remote(remote), prefix, len)
    }

    /// The index whose bytes up to its first page are `prefix` (checked: header, head and its
    /// CRC-32) and whose whole length is `len`.
    fn from_prefix(
        path: PathBuf,
        source: PageSource,
        prefix: &[u8],
        len: u64,
    ) -> Result<Self, StoreError> {
        let corrupt = |message: String| StoreError::CorruptIndex { path: path.clone(), message };
        let mut r = Reader::new(prefix.get(12..).ok_or_else(|| corrupt("no header".into()))?);
        let header = read_header(&mut r).map_err(|e| index_err(e, &path))?;
        let prefix_len = paged_prefix_len(&header) as u64;
        if prefix.len() as u64 != prefix_len {
            return Err(corrupt(format!(
                "a head of {} bytes, expected {prefix_len}",
                prefix.len()
            )));
        }
        let head = read_head(&mut r, prefix, &header).map_err(|e| index_err(e, &path))?;
        let expected = head.file_len(prefix_len, header.block_count());
        if expected != len {
            return Err(corrupt(format!(
                "{len} bytes, expected {expected} for {} blocks in pages of {} (truncated or appended to)",
                header.block_count(),
                head.page_entries
            )));
        }
        Ok(Self {
            path,
            source,
            header,
            head,
            prefix_len,
            prefix: prefix.into(),
            scale: 1.0,
            lru: Lru::new(DEFAULT_PAGE_CACHE_BYTES),
        })
    }

    /// Bytes of the whole index.
    pub(crate) fn file_len(&self) -> u64 {
        self.head.file_len(self.prefix_len, self.header.block_count())
    }

    /// The header as stored.
    pub(crate) fn header(&self) -> &Header {
        &self.header
    }

    /// The head (its pyramid scaled as the entries are).
    pub(crate) fn head(&self) -> &IndexHead {
        &self.head
    }

    /// This index read with every height times `scale` more, with its own empty cache.
    pub(crate) fn exaggerated(&self, scale: f64) -> Result<Self, StoreError> {
        let source = self.source.try_clone(&self.path)?;
        let mut head = self.head.clone();
        let f = |v: &mut f32| *v = (f64::from(*v) * scale) as f32;
        head.upper.iter_mut().flatten().for_each(f);
        head.upper_err.iter_mut().for_each(f);
        Ok(Self {
            path: self.path.clone(),
            source,
            header: self.header.clone(),
            head,
            prefix_len: self.prefix_len,
            prefix: self.prefix.clone(),
            scale: self.scale * scale,
            lru: Lru::new(self.budget()),
        })
    }

    /// Sets the cache's byte budget (at least one page is always kept), for every thread and
    /// clone of the store that shares it; pages beyond it leave at once, least recently used
    /// first.
    pub(crate) fn set_budget(&self, bytes: u64) {
        let mut lru = self.lru.lock().expect("page cache");
        lru.budget = bytes;
        lru.evict(usize::MAX);
    }

    /// The cache's byte budget.
    pub(crate) fn budget(&self) -> u64 {
        self.lru.lock().expect("page cache").budget
    }

    /// Bytes of the whole index decoded, as the cache counts them: the most it can hold.
    pub(crate) fn decoded_len(&self) -> u64 {
        self.header.block_count() as u64 * (u64::from(self.head.entry_len) + ENTRY_OVERHEAD)
    }

    /// Pages decoded so far (cache misses).
    pub(crate) fn pages_decoded(&self) -> u64 {
        self.lru.lock().expect("page cache").decoded
    }

    /// The entry of the block at row-major position `pos` (inside the grid).
    pub(crate) fn entry(&self, pos: usize) -> Result<Arc<BlockEntry>, StoreError> {
        let per = self.head.page_entries as usize;
        let (p, i) = (pos / per, pos % per);
        {
            let mut lru = self.lru.lock().expect("page cache");
            lru.clock += 1;
            let clock = lru.clock;
            if let Some(page) = lru.pages.get_mut(&p) {
                page.stamp = clock;
                return Ok(page.entries[i].clone());
            }
        }
        // Decoded outside the lock: another thread may decode the same page meanwhile (the
        // second insert replaces the first; both are the same values).
        let entries = self.read_page(p)?;
        let e = entries[i].clone();
        let bytes = entries.len() as u64 * (u64::from(self.head.entry_len) + ENTRY_OVERHEAD);
        let mut lru = self.lru.lock().expect("page cache");
        lru.decoded += 1;
        lru.clock += 1;
        let stamp = lru.clock;
        if let Some(old) = lru.pages.insert(p, CachedPage { entries, bytes, stamp }) {
            lru.bytes -= old.bytes;
        }
        lru.bytes += bytes;
        lru.evict(p);
        Ok(e)
    }

    /// The file's bytes before its final CRC-32: the prefix and every page as stored.
    pub(crate) fn content(&self) -> Result<Vec<u8>, StoreError> {
        let mut out = self.prefix.to_vec();
        for p in 0..self.head.page_count(self.header.block_count()) {
            out.extend(self.page_bytes(p)?);
        }
        Ok(out)
    }

    /// Reads, checks and decodes page `p`.
    fn read_page(&self, p: usize) -> Result<Arc<[Arc<BlockEntry>]>, StoreError> {
        let n = self.header.block_count();
        let (first, count, ..) = self.head.page_span(p, self.prefix_len, n);
        let bytes = self.page_bytes(p)?;
        let page_err = |message: String| StoreError::IndexPage {
            path: self.path.clone(),
            page: p,
            blocks: (first, first + count),
            message,
        };
        let mut entries = decode_page(&bytes, &self.header, &self.head, p).map_err(page_err)?;
        if self.scale != 1.0 {
            entries.iter_mut().for_each(|e| scale_entry(e, self.scale));
        }
        Ok(entries.into_iter().map(Arc::new).collect())
    }

    /// Page `p`'s bytes as stored (a remote store's checked by their CRC-32).
    fn page_bytes(&self, p: usize) -> Result<Vec<u8>, StoreError> {
        let n = self.header.block_count();
        let (first, count, at, len) = self.head.page_span(p, self.prefix_len, n);
        let page_err = |message: String| StoreError::IndexPage {
            path: self.path.clone(),
            page: p,
            blocks: (first, first + count),
            message,
        };
        let bytes = match &self.source {
            PageSource::File(f) => {
                let mut buf = vec![0u8; len as usize];
                read_exact_at(f, at, &mut buf).map_err(|cause| {
                    if cause.kind() == std::io::ErrorKind::UnexpectedEof {
                        page_err(format!("truncated: bytes {at}..{} are not all there", at + len))
                    } else {
                        StoreError::Io { path: self.path.clone(), cause }
                    }
                })?;
                buf
            }
            PageSource::Remote(r) => {
                r.index_page(p, (at, len), (first, first + count), |b| check_page_crc(b, p))?
            }
        };
        Ok(bytes)
    }
}

/// An [`IndexError`] of the index at `path` as a [`StoreError`].
pub(crate) fn index_err(e: IndexError, path: &Path) -> StoreError {
    let path = path.to_path_buf();
    match e {
        IndexError::BadMagic => StoreError::BadMagic { path, what: "index" },
        IndexError::Version(found) => {
            StoreError::Version { path, found, expected: crate::format::INDEX_VERSION }
        }
        IndexError::Corrupt(message) => StoreError::CorruptIndex { path, message },
        IndexError::Short(s) => StoreError::CorruptIndex { path, message: s.to_string() },
    }
}
