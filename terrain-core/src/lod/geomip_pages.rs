//! Geomorph's table read by pages ([`GeomipTable::open_paged`]): a store's `geomip.bin` is
//! not decoded whole at open (40 bytes per 16-cell patch, 168 MB at 32769^2) but read where a
//! frame needs it, through a bounded cache, so memory and open time follow the view, not the
//! grid.
//!
//! What is read when: at open the header and the file's tail (a CRC-32 per page of entries,
//! and the coarsest-level pyramid's nodes `2^SUMMARY_LEVEL` patches wide, written by the
//! bake: 24 bytes per 64 patches); during a frame, the pages of entries that hold the
//! patches whose factors it computes, and the pyramid's lower levels for the regions it
//! walks down into, each computed from the entries of its region (a tile of
//! `2^SUMMARY_LEVEL` squared patches and the `L - 1` around it, the dilation's reach) exactly
//! as the whole table's pyramid computes them: the same maxima of the same values, so the
//! selection is bit for bit the whole table's. A page whose checksum fails is an error that
//! names the file and the page (kept for [`GeomipTable::try_select_runs`]); until then the
//! frame treats its patches as infinitely rough (the finest level, never a wrong coarse one).
//! A page the reader has not got yet and does not wait for (`WouldBlock`: a remote table
//! fetched in the background, `terrain_stream::SideTable::set_waiting`) is counted late
//! (`pages_late`) and its patches bounded by the summary node holding them (upper bounds of
//! their errors, their box for the distance): finer or as fine as their own entries give,
//! never coarser; it is read again by the next frame that needs it.
//! terrain-core does no file I/O: the caller reads the bytes ([`TableReader`]).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use rustc_hash::FxHashMap;

use super::geomip_file::GeomipFileError;
use super::geomipmap::{
    MAX_LEVELS, NodeBound, PatchEntries, PyramidLevel, dilate, first_levels, merge_up,
    scaled_error, scaled_height, vertex_range, z_union,
};
use crate::checksum::crc32;

/// Reads a table file's bytes at an offset: the caller's file, a remote store's mirror, or
/// bytes in memory (terrain-core does no file I/O of its own).
pub trait TableReader: Send + Sync {
    /// Fills `buf` with the bytes at `offset` (an error when fewer are there; of kind
    /// [`std::io::ErrorKind::WouldBlock`] when they are not here yet and the reader was told
    /// not to wait: [`TableReader::set_waiting`]).
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> std::io::Result<()>;

    /// Whether reads may wait for bytes not here yet (the default, and all a reader whose bytes
    /// are always here does); not waiting, such a read answers `WouldBlock` at once and the
    /// reader fetches the bytes in the background.
    fn set_waiting(&self, _wait: bool) {}

    /// Starts fetching every byte not here yet in the background (a reader whose bytes are
    /// always here does nothing).
    fn fetch_all_in_background(&self) {}
}

impl TableReader for Vec<u8> {
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> std::io::Result<()> {
        let start = usize::try_from(offset).unwrap_or(usize::MAX);
        match start.checked_add(buf.len()).and_then(|end| self.get(start..end)) {
            Some(b) => {
                buf.copy_from_slice(b);
                Ok(())
            }
            None => Err(std::io::Error::from(std::io::ErrorKind::UnexpectedEof)),
        }
    }
}

/// How a table read by pages caches what it read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GeomipPaging {
    /// Bytes of decoded pages and pyramid tiles kept (default 32 MiB: about 800 k 16-cell
    /// patches, a few frames' worth of views near the ground); the least recently used go
    /// first when it is exceeded.
    pub cache_bytes: u64,
}

impl Default for GeomipPaging {
    fn default() -> Self {
        Self { cache_bytes: 32 << 20 }
    }
}

/// What a table read by pages has read so far (for tests and measurements).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct GeomipPagingStats {
    /// Bytes read from the file, the open's included.
    pub bytes_read: u64,
    /// Pages of entries read (again after an eviction).
    pub pages_read: u64,
    /// Pyramid tiles computed from their region's entries.
    pub tiles_built: u64,
    /// Bytes the caches hold now.
    pub cached_bytes: u64,
    /// Reads of a page that was not here yet and not waited for (the reader said
    /// `WouldBlock`): its patches bounded by the coarse pyramid that frame.
    pub pages_late: u64,
}

/// A page asked of [`PagedEntries::page`].
enum PageRead {
    Here(Arc<Page>),
    /// Not here yet, not waited for: bound its patches by the coarse pyramid.
    Late,
    /// Unreadable (the error is kept): its patches are infinitely rough.
    Failed,
}

/// The layout of a table file read by pages, from its header and tail
/// ([`super::geomip_file`]).
#[derive(Debug, Clone)]
pub(super) struct PagedLayout {
    /// The file's name in errors.
    pub(super) file: String,
    /// Cells per patch side.
    pub(super) p: u32,
    /// Levels below the finest per patch (`L`).
    pub(super) l: usize,
    /// Patches along x and y.
    pub(super) nx: u32,
    pub(super) ny: u32,
    /// Patches per page of entries.
    pub(super) page_patches: usize,
    /// Where the entries start.
    pub(super) entries_at: u64,
    /// Per page: the CRC-32 of its bytes.
    pub(super) page_crcs: Arc<[u32]>,
    /// The pyramid level the file holds (nodes `2^summary_level` patches wide).
    pub(super) summary_level: usize,
}

/// One page of entries, decoded (and scaled).
#[derive(Debug)]
struct Page {
    errors: Vec<f32>,
    heights: Vec<f32>,
    vertices: Vec<u16>,
}

/// The pyramid's levels `0..summary_level` over one node of the summary level: level `m` is
/// `side >> m` squared nodes, row-major.
#[derive(Debug)]
struct Tile {
    levels: Vec<PyramidLevel>,
}

/// What one selection over a table read by pages found last: the page of the patch it asked
/// last and the pyramid tile of the node it asked last ([`PagedEntries::patch_memo`],
/// [`PagedEntries::node_memo`]). On its thread, for the length of one selection (a frame's
/// late pages and tiles are asked again by the next: [`PagedEntries::new_frame`]).
#[derive(Default)]
pub(super) struct SelectionMemo {
    page: std::cell::RefCell<Option<(usize, PageRead)>>,
    tile: std::cell::RefCell<Option<TileAt>>,
}

/// A pyramid tile and its summary node.
type TileAt = ((u32, u32), Arc<Tile>);

/// The least recently used go first.
#[derive(Debug, Default)]
struct Caches {
    pages: FxHashMap<usize, (Arc<Page>, u64)>,
    tiles: FxHashMap<(u32, u32), (Arc<Tile>, u64)>,
    tick: u64,
    bytes: u64,
    /// Pages found not here this frame, and tiles over them: not asked again until the next
    /// frame ([`PagedEntries::new_frame`]), so a frame counts a late page once and bounds its
    /// patches without reading again (a frame asks a tile for every node it walks under it).
    late_pages: rustc_hash::FxHashSet<usize>,
    late_tiles: rustc_hash::FxHashSet<(u32, u32)>,
}

impl Caches {
    /// Drops the least recently used until at most 3/4 of `budget` is held.
    fn trim(&mut self, budget: u64, l: usize) {
        if self.bytes <= budget {
            return;
        }
        let mut items: Vec<(u64, u64)> =
            self.pages.values().map(|v| (v.1, page_bytes(&v.0))).collect();
        items.extend(self.tiles.values().map(|v| (v.1, tile_bytes(&v.0, l))));
        let (cut, bytes) = lru_cut(items, self.bytes, budget);
        self.pages.retain(|_, v| v.1 >= cut);
        self.tiles.retain(|_, v| v.1 >= cut);
        self.bytes = bytes;
    }
}

/// The eviction of a table's page cache (this module's and [`super::dss_pages`]'): of the
/// entries `items` (last use, bytes) holding `bytes` in all, the least recently used go until
/// at most 3/4 of `budget` is held. Returns the last-use tick from which entries stay, and the
/// bytes they hold.
pub(super) fn lru_cut(mut items: Vec<(u64, u64)>, bytes: u64, budget: u64) -> (u64, u64) {
    items.sort_unstable();
    let target = budget / 4 * 3;
    let (mut bytes, mut cut) = (bytes, 0);
    for (tick, size) in items {
        if bytes <= target {
            break;
        }
        (cut, bytes) = (tick + 1, bytes.saturating_sub(size));
    }
    (cut, bytes)
}

/// Reads page `page` of a table file, `len` bytes at `offset` through `reader`, counted in
/// `read` (bytes, pages) once read, and checks it against its CRC-32 `crc` (this module's
/// pages and [`super::dss_pages`]'). `Ok(None)`: not here yet, the reader does not wait.
pub(super) fn read_checked_page(
    reader: &dyn TableReader,
    (file, page, offset): (&str, usize, u64),
    len: usize,
    crc: u32,
    read: [&AtomicU64; 2],
) -> Result<Option<Vec<u8>>, GeomipFileError> {
    let mut buf = vec![0u8; len];
    match reader.read_at(offset, &mut buf) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => return Ok(None),
        Err(e) => {
            return Err(page_error((file, page, offset), GeomipFileError::Read(e.to_string())));
        }
    }
    read[0].fetch_add(buf.len() as u64, Ordering::Relaxed);
    read[1].fetch_add(1, Ordering::Relaxed);
    let computed = crc32(&buf);
    if crc != computed {
        let cause = GeomipFileError::Checksum { stored: crc, computed };
        return Err(page_error((file, page, offset), cause));
    }
    Ok(Some(buf))
}

/// `cause` as the error of page `page` of `file`, at byte `offset`.
pub(super) fn page_error(
    (file, page, offset): (&str, usize, u64),
    cause: GeomipFileError,
) -> GeomipFileError {
    GeomipFileError::Page { file: file.to_string(), page, offset, cause: Box::new(cause) }
}

fn page_bytes(p: &Page) -> u64 {
    (p.errors.len() * 10) as u64
}

fn tile_bytes(t: &Tile, l: usize) -> u64 {
    t.levels.iter().map(|lv| (lv.z.len() * (8 + 4 * l)) as u64).sum()
}

/// A table's entries and lower pyramid levels read on demand (see the module docs).
pub(super) struct PagedEntries {
    layout: PagedLayout,
    reader: Arc<dyn TableReader>,
    /// The grid's pyramid levels from `summary_level` up (scaled).
    summary: Arc<Vec<PyramidLevel>>,
    /// The level of the pyramid's one-node top (`0` for one patch).
    top_level: usize,
    /// Vertical exaggerations applied, in order ([`super::GeomipTable::exaggerated`]).
    scales: Vec<f64>,
    budget: u64,
    cache: Mutex<Caches>,
    /// The first page that could not be read since [`PagedEntries::take_error`].
    failed: Mutex<Option<GeomipFileError>>,
    failures: AtomicU64,
    bytes_read: AtomicU64,
    pages_read: AtomicU64,
    tiles_built: AtomicU64,
    pages_late: AtomicU64,
}

impl std::fmt::Debug for PagedEntries {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PagedEntries")
            .field("layout", &self.layout)
            .field("scales", &self.scales)
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

/// Two tables read by pages are equal when they are the same one.
impl PartialEq for PagedEntries {
    fn eq(&self, other: &Self) -> bool {
        std::ptr::eq(self, other)
    }
}

impl PagedEntries {
    /// The entries of `layout` read through `reader`, the pyramid's summary level `base`
    /// (unscaled), `open_bytes` read so far.
    pub(super) fn new(
        layout: PagedLayout,
        reader: Arc<dyn TableReader>,
        base: PyramidLevel,
        paging: &GeomipPaging,
        open_bytes: u64,
    ) -> Self {
        let (mut a, mut b, mut top_level) = (layout.nx, layout.ny, 0);
        while a > 1 || b > 1 {
            (a, b, top_level) = (a.div_ceil(2), b.div_ceil(2), top_level + 1);
        }
        let summary = Arc::new(merge_up(base, layout.l));
        Self {
            layout,
            reader,
            summary,
            top_level,
            scales: Vec::new(),
            budget: paging.cache_bytes,
            cache: Mutex::default(),
            failed: Mutex::default(),
            failures: AtomicU64::new(0),
            bytes_read: AtomicU64::new(open_bytes),
            pages_read: AtomicU64::new(0),
            tiles_built: AtomicU64::new(0),
            pages_late: AtomicU64::new(0),
        }
    }

    /// The same file with its errors and heights times `scale` (after those applied before),
    /// empty caches.
    pub(super) fn exaggerated(&self, scale: f64) -> Self {
        let l = self.layout.l;
        let summary = self
            .summary
            .iter()
            .map(|lv| PyramidLevel {
                nx: lv.nx,
                ny: lv.ny,
                errors: lv.errors.iter().map(|&e| scaled_error(e, scale)).collect(),
                z: lv.z.iter().map(|z| z.map(|v| scaled_height(v, scale))).collect(),
            })
            .collect::<Vec<_>>();
        debug_assert!(summary.iter().all(|lv| lv.errors.len() == lv.z.len() * l));
        let mut scales = self.scales.clone();
        scales.push(scale);
        Self {
            layout: self.layout.clone(),
            reader: self.reader.clone(),
            summary: Arc::new(summary),
            top_level: self.top_level,
            scales,
            budget: self.budget,
            cache: Mutex::default(),
            failed: Mutex::default(),
            failures: AtomicU64::new(0),
            bytes_read: AtomicU64::new(self.bytes_read.load(Ordering::Relaxed)),
            pages_read: AtomicU64::new(0),
            tiles_built: AtomicU64::new(0),
            pages_late: AtomicU64::new(0),
        }
    }

    /// A frame starts: the pages found not here in the last one are asked again.
    pub(super) fn new_frame(&self) {
        let mut cache = self.lock();
        cache.late_pages.clear();
        cache.late_tiles.clear();
    }

    /// [`TableReader::set_waiting`] of the reader.
    pub(super) fn set_waiting(&self, wait: bool) {
        self.reader.set_waiting(wait);
    }

    /// [`TableReader::fetch_all_in_background`] of the reader.
    pub(super) fn fetch_all_in_background(&self) {
        self.reader.fetch_all_in_background();
    }

    /// What was read so far.
    pub(super) fn stats(&self) -> GeomipPagingStats {
        GeomipPagingStats {
            bytes_read: self.bytes_read.load(Ordering::Relaxed),
            pages_read: self.pages_read.load(Ordering::Relaxed),
            tiles_built: self.tiles_built.load(Ordering::Relaxed),
            cached_bytes: self.lock().bytes,
            pages_late: self.pages_late.load(Ordering::Relaxed),
        }
    }

    /// Bytes held: the summary levels and the caches.
    pub(super) fn memory_bytes(&self) -> usize {
        super::geomipmap::levels_bytes(&self.summary) + self.lock().bytes as usize
    }

    /// The first page that could not be read since the last call, if any.
    pub(super) fn take_error(&self) -> Option<GeomipFileError> {
        self.failed.lock().unwrap_or_else(|e| e.into_inner()).take()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Caches> {
        self.cache.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn fail(&self, e: GeomipFileError) {
        self.failures.fetch_add(1, Ordering::Relaxed);
        let mut slot = self.failed.lock().unwrap_or_else(|e| e.into_inner());
        slot.get_or_insert(e);
    }

    /// Reads and checks page `p` (`Ok(None)`: not here yet, the reader does not wait).
    fn read_page(&self, p: usize) -> Result<Option<Page>, GeomipFileError> {
        let lay = &self.layout;
        let l = lay.l;
        let total = lay.nx as usize * lay.ny as usize;
        let first = p * lay.page_patches;
        let patches = lay.page_patches.min(total - first);
        let offset = lay.entries_at + (first * l * 10) as u64;
        let at = (lay.file.as_str(), p, offset);
        let page_err = |cause: GeomipFileError| page_error(at, cause);
        let read = [&self.bytes_read, &self.pages_read];
        let Some(buf) =
            read_checked_page(&*self.reader, at, patches * l * 10, lay.page_crcs[p], read)?
        else {
            return Ok(None);
        };
        let n = patches * l;
        let mut page = Page {
            errors: Vec::with_capacity(n),
            heights: Vec::with_capacity(n),
            vertices: Vec::with_capacity(n),
        };
        let last = (lay.p + 1) * (lay.p + 1);
        for (k, b) in buf.chunks_exact(10).enumerate() {
            let (e, z, v) = super::geomip_file::decode_entry(b);
            if !super::geomip_file::entry_ok(e, z, v, last) {
                return Err(page_err(GeomipFileError::Layout(format!(
                    "entry {}: error {e}, height {z}, vertex {v}",
                    first * l + k
                ))));
            }
            let (mut e, mut z) = (e, z);
            for &s in &self.scales {
                (e, z) = (scaled_error(e, s), scaled_height(z, s));
            }
            page.errors.push(e);
            page.heights.push(z);
            page.vertices.push(v);
        }
        Ok(Some(page))
    }

    /// Page `p`, from the cache or read (not here yet: counted late; unreadable: the error
    /// kept).
    fn page(&self, p: usize) -> PageRead {
        let mut cache = self.lock();
        cache.tick += 1;
        let tick = cache.tick;
        if let Some(slot) = cache.pages.get_mut(&p) {
            slot.1 = tick;
            return PageRead::Here(slot.0.clone());
        }
        if cache.late_pages.contains(&p) {
            return PageRead::Late;
        }
        match self.read_page(p) {
            Ok(Some(page)) => {
                let page = Arc::new(page);
                cache.bytes += page_bytes(&page);
                cache.pages.insert(p, (page.clone(), tick));
                cache.trim(self.budget, self.layout.l);
                PageRead::Here(page)
            }
            Ok(None) => {
                self.pages_late.fetch_add(1, Ordering::Relaxed);
                cache.late_pages.insert(p);
                PageRead::Late
            }
            Err(e) => {
                drop(cache);
                self.fail(e);
                PageRead::Failed
            }
        }
    }

    /// Patch `k`'s entries (see [`super::GeomipTable::patch`]); `last` keeps the page asked
    /// last for the next call (a run of patches in one page locks the cache once). A page not
    /// here yet gives the patch the coarse pyramid's bound: per level the summary node's
    /// largest monotone error (`m_l`, at radius `L - l`, over a region holding the patch) and
    /// its vertices' height range, so its factor is never coarser than its own entries'.
    fn patch_in(&self, k: usize, last: &mut Option<(usize, PageRead)>) -> PatchEntries {
        let l = self.layout.l;
        let p = k / self.layout.page_patches;
        let mut out = PatchEntries { n: l, ..PatchEntries::default() };
        if last.as_ref().is_none_or(|(q, _)| *q != p) {
            *last = Some((p, self.page(p)));
        }
        let page = match last.as_ref().map(|(_, read)| read) {
            Some(PageRead::Here(page)) => page,
            Some(PageRead::Late) => {
                let nx = self.layout.nx as usize;
                let m0 = self.layout.summary_level;
                let bound = self.summary_node((k % nx) as u32 >> m0, (k / nx) as u32 >> m0);
                for e in 0..l {
                    out.errors[e] = bound.errors[l - 1 - e];
                }
                out.bounded = Some(bound.z);
                return out;
            }
            _ => {
                out.errors[..l].fill(f32::INFINITY);
                return out;
            }
        };
        let at = (k - p * self.layout.page_patches) * l;
        out.errors = first_levels(&page.errors[at..at + l]);
        out.heights = first_levels(&page.heights[at..at + l]);
        out.vertices = first_levels(&page.vertices[at..at + l]);
        out
    }

    /// Patch `k`'s entries (see [`super::GeomipTable::patch`]).
    pub(super) fn patch(&self, k: usize) -> PatchEntries {
        self.patch_in(k, &mut None)
    }

    /// [`PagedEntries::patch`] through one selection's `memo`: a page read here stays in it
    /// for the next patch, so a run of patches in one page locks the cache once. Only a page
    /// that was here is kept; one not here or unreadable is asked again, as without the memo.
    pub(super) fn patch_memo(&self, k: usize, memo: &SelectionMemo) -> PatchEntries {
        let mut last = memo.page.borrow_mut();
        let out = self.patch_in(k, &mut last);
        if !matches!(&*last, Some((_, PageRead::Here(_)))) {
            *last = None;
        }
        out
    }

    /// The pyramid's node `m` levels above the patches at `(i, j)` (see
    /// `GeomipTable::node_bound`): from the summary at or above its level, else from the
    /// tile of the summary node holding it. The tile found last stays in `memo` (the traversal
    /// asks about a tile's nodes one after another, depth first), so the cache's lock and map
    /// are not asked per node; only a tile the cache keeps is kept in the memo (one over a
    /// page not here, or unreadable, is asked again, as without it).
    pub(super) fn node_memo(
        &self,
        m: usize,
        i: u32,
        j: u32,
        memo: &SelectionMemo,
    ) -> Option<NodeBound> {
        let l = self.layout.l;
        let m0 = self.layout.summary_level;
        if m > self.top_level {
            let top = self.summary.last()?;
            return Some(top.bound(0, l));
        }
        if m >= m0 {
            let lv = self.summary.get(m - m0)?;
            return (i < lv.nx && j < lv.ny).then(|| lv.bound(lv.index(i, j), l));
        }
        let (nxm, nym) = (self.layout.nx.div_ceil(1 << m), self.layout.ny.div_ceil(1 << m));
        if i >= nxm || j >= nym {
            return None;
        }
        let shift = m0 - m;
        let at = (i >> shift, j >> shift);
        let bound_in = |tile: &Tile| {
            let lv = &tile.levels[m];
            let side = lv.nx;
            let k = ((j - ((j >> shift) << shift)) * side + (i - ((i >> shift) << shift))) as usize;
            lv.bound(k, l)
        };
        // The memo's tile read in place (no reference count changed per node).
        if let Some((_, tile)) = memo.tile.borrow().as_ref().filter(|(t, _)| *t == at) {
            return Some(bound_in(tile));
        }
        let Some((tile, kept)) = self.tile(at.0, at.1) else {
            // A page under it not here yet: the summary node holding it bounds it (its region,
            // dilated, holds the node's).
            return Some(self.summary_node(i >> shift, j >> shift));
        };
        let bound = bound_in(&tile);
        if kept {
            *memo.tile.borrow_mut() = Some((at, tile));
        }
        Some(bound)
    }

    /// Node `(i, j)` of the summary level (nodes `2^summary_level` patches wide).
    fn summary_node(&self, i: u32, j: u32) -> NodeBound {
        let lv = &self.summary[0];
        lv.bound(lv.index(i, j), self.layout.l)
    }

    /// The tile of summary node `(ti, tj)`, from the cache or computed, and whether the cache
    /// keeps it (not when a page under it could not be read).
    /// (`None`: a page under it is not here yet.)
    fn tile(&self, ti: u32, tj: u32) -> Option<(Arc<Tile>, bool)> {
        {
            let mut cache = self.lock();
            cache.tick += 1;
            let tick = cache.tick;
            if let Some(slot) = cache.tiles.get_mut(&(ti, tj)) {
                slot.1 = tick;
                return Some((slot.0.clone(), true));
            }
            if cache.late_tiles.contains(&(ti, tj)) {
                return None;
            }
        }
        let failures = self.failures.load(Ordering::Relaxed);
        let Some(tile) = self.build_tile(ti, tj) else {
            self.lock().late_tiles.insert((ti, tj));
            return None;
        };
        let tile = Arc::new(tile);
        self.tiles_built.fetch_add(1, Ordering::Relaxed);
        // A tile built over a page that could not be read is not kept: the next frame that
        // needs it reads the page again (and reports it again).
        let kept = self.failures.load(Ordering::Relaxed) == failures;
        if kept {
            let l = self.layout.l;
            let mut cache = self.lock();
            cache.tick += 1;
            let tick = cache.tick;
            cache.bytes += tile_bytes(&tile, l);
            cache.tiles.insert((ti, tj), (tile.clone(), tick));
            cache.trim(self.budget, l);
        }
        Some((tile, kept))
    }

    /// Levels `0..summary_level` over summary node `(ti, tj)`, as `CoarsePyramid::new`
    /// computes them for the whole grid: per patch and radius `r < L` the largest `m_{L-r}`
    /// over the square of radius `r` (clipped to the grid), the height range over radius
    /// `L - 1`, then 2 x 2 maxima. The window holds every patch within `L - 1` of the tile's,
    /// so clipping the dilation to it is clipping it to the grid.
    /// `None` when a page under it is not here yet.
    fn build_tile(&self, ti: u32, tj: u32) -> Option<Tile> {
        let (l, nx, ny) = (self.layout.l, self.layout.nx as usize, self.layout.ny as usize);
        let m0 = self.layout.summary_level;
        let side = 1usize << m0;
        let reach = l.saturating_sub(1);
        let (px0, py0) = (ti as usize * side, tj as usize * side);
        let (px1, py1) = ((px0 + side).min(nx), (py0 + side).min(ny));
        let (wx0, wy0) = (px0.saturating_sub(reach), py0.saturating_sub(reach));
        let (wx1, wy1) = ((px1 + reach).min(nx), (py1 + reach).min(ny));
        let (ww, wh) = (wx1 - wx0, wy1 - wy0);
        let mut own = vec![vec![0f32; ww * wh]; l];
        let mut own_z = vec![[f32::INFINITY, f32::NEG_INFINITY]; ww * wh];
        let mut last = None;
        for j in wy0..wy1 {
            for i in wx0..wx1 {
                let e = self.patch_in(j * nx + i, &mut last);
                if matches!(last, Some((_, PageRead::Late))) {
                    return None;
                }
                let w = (j - wy0) * ww + i - wx0;
                for (r, o) in own.iter_mut().enumerate() {
                    o[w] = e.errors[(l - r) - 1];
                }
                own_z[w] = vertex_range(&e.errors[..l], &e.heights[..l]);
            }
        }
        let dims = (ww, wh);
        // A tile's levels are row-major (`side >> m` nodes a side), not in the whole
        // pyramid's 8 x 8 slots: all 0, height ranges empty.
        let dense = |s: usize| PyramidLevel {
            nx: s as u32,
            ny: s as u32,
            errors: vec![0.0; s * s * l],
            z: vec![[f32::INFINITY, f32::NEG_INFINITY]; s * s],
        };
        let mut base = dense(side);
        let at = |i: usize, j: usize| (j - wy0) * ww + i - wx0;
        for (r, o) in own.iter().enumerate() {
            let d = dilate(&dilate(o, dims, r, true, f32::max), dims, r, false, f32::max);
            for j in py0..py1 {
                for i in px0..px1 {
                    base.errors[((j - py0) * side + i - px0) * l + r] = d[at(i, j)];
                }
            }
        }
        let z = dilate(&dilate(&own_z, dims, reach, true, z_union), dims, reach, false, z_union);
        for j in py0..py1 {
            for i in px0..px1 {
                base.z[(j - py0) * side + i - px0] = z[at(i, j)];
            }
        }
        // Nodes past the grid keep 0 and an empty range, as the whole pyramid's do, so the
        // 2 x 2 maxima are its.
        let mut levels = vec![base];
        for _ in 1..m0 {
            let prev = levels.last().expect("level 0");
            let s = prev.nx as usize / 2;
            let mut next = dense(s);
            for b in 0..s {
                for a in 0..s {
                    for (da, db) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let c = (2 * b + db) * prev.nx as usize + 2 * a + da;
                        next.absorb(b * s + a, prev, c, l);
                    }
                }
            }
            levels.push(next);
        }
        debug_assert!(l <= MAX_LEVELS);
        Some(Tile { levels })
    }
}
