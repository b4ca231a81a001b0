//! The reader: opens a store's grid index and reads one block level at a time by positioned
//! reads, checking the block header (bake id, position), the file length and the level's
//! CRC-32, then decoding it on top of the coarser levels ([`BlockLevels`]).

use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use crate::codec::decode_level;
use crate::decimation::{DECIMATION_FILE, DecimationErrors};
use crate::error::StoreError;
use crate::format::{
    BLOCK_HEADER_LEN, BLOCK_MAGIC, BlockEntry, BlockId, Header, INDEX_FILE, INDEX_VERSION, MAGIC,
    PAGED_INDEX_VERSION, SampleEncoding, VERSION, block_file_name, crc32, level_len, read_index,
    vertex_index,
};
use crate::overview::Overview;
use crate::pages::{PagedIndex, index_err, scale_entry};
use crate::remote::{Remote, RemoteIndex, RemoteOptions, is_url};
use crate::side_table::{SideParts, SideTable};

/// An open store: the header and its grid index, block files on disk or, for a store opened
/// from a URL ([`Store::open_location`]), on object storage or HTTP (read by range requests
/// through a local disk cache). A version-4 index is read page by page as blocks are asked
/// for, through a bounded cache of decoded pages ([`Store::with_page_cache_bytes`]); older
/// indexes are read whole. `Sync` and cheap to clone (clones share the index and its cache):
/// worker threads share it behind an `Arc`.
#[derive(Debug, Clone)]
pub struct Store {
    /// The store folder; for a remote store, its local mirror (index and side tables).
    dir: PathBuf,
    header: Header,
    index: Arc<Index>,
    remote: Option<Arc<Remote>>,
    /// The blocks' coarsest levels in one file (`None` inside: the store has none): opened
    /// with a local store; a remote store's is fetched into the mirror when first needed
    /// (unset until then, and after a failed fetch, which the next read tries again).
    overview: Arc<Mutex<Option<Option<Arc<Overview>>>>>,
    /// A remote store's side tables being read where they lie, by name, kept alive by the
    /// store and its clones: one part per table and mirror in the process (shared with stores
    /// opened apart on the same location and cache), so each byte is fetched once a session
    /// however many readers open the table, one after another or at once.
    parts: SideParts,
    /// The blocks' decimation errors (`decimation.bin`), read on the first
    /// [`Store::decimation_errors`] that finds the file good or absent (`None` inside: absent);
    /// shared by clones, not by an exaggerated store (whose values are scaled).
    decimation: Arc<OnceLock<Option<Arc<DecimationErrors>>>>,
}

/// A store's block entries: every one in memory (index versions 2 and 3) or paged (4).
#[derive(Debug)]
enum Index {
    Whole(Vec<Arc<BlockEntry>>),
    Paged {
        pages: Box<PagedIndex>,
        /// The first page that could not be read through [`Store::entry`] (which says `None`).
        fault: Mutex<Option<String>>,
    },
}

impl Index {
    fn paged(pages: PagedIndex) -> Self {
        Index::Paged { pages: Box::new(pages), fault: Mutex::default() }
    }
}

/// One level read and decoded, with what it cost.
#[derive(Debug, Clone)]
pub struct LoadedLevel {
    /// The level's samples in stored order (decode with [`SampleEncoding::height`]).
    pub samples: Arc<[i32]>,
    /// Bytes read from disk.
    pub disk_bytes: u64,
    /// Time spent reading and checking (not decoding).
    pub io_time: Duration,
}

/// Opens the index file at `path`: a version-4 index by its head alone, an older one whole.
fn open_index(path: &Path) -> Result<(Header, Index), StoreError> {
    let io = |cause| StoreError::Io { path: path.to_path_buf(), cause };
    let file = File::open(path).map_err(io)?;
    let len = file.metadata().map_err(io)?.len();
    let mut magic = [0u8; 12];
    if len >= 12 {
        crate::pages::read_exact_at(&file, 0, &mut magic).map_err(io)?;
        let version = u32::from_le_bytes([magic[8], magic[9], magic[10], magic[11]]);
        if magic[..8] == MAGIC && version >= PAGED_INDEX_VERSION && version <= INDEX_VERSION {
            let pages = PagedIndex::open(path.to_path_buf(), file, len)?;
            return Ok((pages.header().clone(), Index::paged(pages)));
        }
    }
    let bytes = std::fs::read(path).map_err(io)?;
    let (header, blocks) = parse_index(&bytes, path.to_path_buf())?;
    Ok((header, Index::Whole(blocks.into_iter().map(Arc::new).collect())))
}

impl Store {
    /// Opens the store in folder `dir`, reading and checking its index's header (a version-4
    /// index: its head; an older one: every entry).
    pub fn open(dir: impl AsRef<Path>) -> Result<Self, StoreError> {
        let dir = dir.as_ref().to_path_buf();
        let (header, index) = open_index(&dir.join(INDEX_FILE))?;
        let overview = Overview::open(&dir, &header)?.map(Arc::new);
        let overview = Arc::new(Mutex::new(Some(overview)));
        Ok(Self {
            dir,
            header,
            index: Arc::new(index),
            remote: None,
            overview,
            parts: SideParts::default(),
            decimation: Arc::default(),
        })
    }

    /// Opens the store at `location`: a local folder ([`Store::open`]) or a URL (`s3://`,
    /// `gs://`, `az://`, `http(s)://`, [`crate::is_url`]) read with the default
    /// [`RemoteOptions`].
    pub fn open_location(location: &str) -> Result<Self, StoreError> {
        Self::open_location_with(location, &RemoteOptions::default())
    }

    /// [`Store::open_location`] with the remote options given (disk cache, timeouts,
    /// retries, side tables to mirror). A URL's paged index (version 4) is read as a local
    /// one is, its header and head fetched here and each page by a range request when one of
    /// its blocks is first asked for, kept in the local mirror; an older index is fetched
    /// whole, here. Its blocks are read by range requests when loaded, through the disk cache.
    pub fn open_location_with(location: &str, options: &RemoteOptions) -> Result<Self, StoreError> {
        if !is_url(location) {
            return Self::open(location);
        }
        let (remote, index) = Remote::open(location, options)?;
        let remote = Arc::new(remote);
        let dir = remote.mirror().to_path_buf();
        let (header, index) = match index {
            RemoteIndex::Paged { prefix, size } => {
                let pages = PagedIndex::open_remote(remote.clone(), &prefix, size)?;
                (pages.header().clone(), Index::paged(pages))
            }
            RemoteIndex::Whole(bytes) => {
                let path = PathBuf::from(format!("{}/{INDEX_FILE}", remote.url()));
                let (header, blocks) = parse_index(&bytes, path)?;
                (header, Index::Whole(blocks.into_iter().map(Arc::new).collect()))
            }
        };
        // The overview is fetched when a coarse level is first read (`Store::overview`).
        let overview = Arc::default();
        Ok(Self {
            dir,
            header,
            index: Arc::new(index),
            remote: Some(remote),
            overview,
            parts: SideParts::default(),
            decimation: Arc::default(),
        })
    }

    /// The finest level the store's overview (`overview.bin`: every block's coarsest levels
    /// in one file) holds, read from it instead of the blocks' files; `None` for a store
    /// baked without one. A store at a URL fetches its overview here if it has not yet
    /// (`None` when that fails).
    pub fn overview_levels(&self) -> Option<u8> {
        self.overview().ok().flatten().map(|o| o.top())
    }

    /// The store's overview, fetched into a remote store's mirror on first use (one GET).
    fn overview(&self) -> Result<Option<Arc<Overview>>, StoreError> {
        let mut slot = self.overview.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(known) = &*slot {
            return Ok(known.clone());
        }
        let remote = self.remote.as_ref().expect("a local store's overview is opened with it");
        let found = if remote.mirror_file(crate::overview::OVERVIEW_FILE)? {
            Overview::open(&self.dir, &self.header)?.map(Arc::new)
        } else {
            None
        };
        *slot = Some(found.clone());
        Ok(found)
    }

    /// The blocks' decimation errors, the bake's table of them ([`crate::DECIMATION_FILE`]):
    /// per block, its decimation error as one region of `2^k` cells at the strides
    /// `2^1..=2^k` (with the default `k` = 8, the `tin` method's regions of 256 cells), times
    /// the store's vertical exaggeration ([`Store::exaggerated`]). Read whole on the first call
    /// (a remote store's fetched into its mirror, one GET) and kept by the store and its
    /// clones. `None` for a store baked without one (before the table existed, or merged from
    /// parts that lack it); a damaged table, another bake's or another grid's is
    /// [`StoreError::Decimation`] naming the file (and read again at the next call).
    pub fn decimation_errors(&self) -> Result<Option<Arc<DecimationErrors>>, StoreError> {
        if let Some(known) = self.decimation.get() {
            return Ok(known.clone());
        }
        let table = match self.side_file(DECIMATION_FILE)? {
            Some(path) => {
                crate::decimation::read(&path, &self.header, self.height_bound())?.map(Arc::new)
            }
            None => None,
        };
        // Another thread may have read it meanwhile: the same table.
        Ok(self.decimation.get_or_init(|| table).clone())
    }

    /// The largest magnitude of the store's heights as read (its exaggeration applied), from
    /// the index without reading a block: every entry's least and greatest of a whole index,
    /// the root of a paged index's block pyramid.
    fn height_bound(&self) -> f32 {
        let m = |[lo, hi]: [f32; 2]| lo.abs().max(hi.abs());
        match &*self.index {
            Index::Whole(blocks) => blocks.iter().map(|b| m([b.min, b.max])).fold(0.0, f32::max),
            Index::Paged { pages, .. } => pages.head().upper.first().copied().map_or(0.0, m),
        }
    }

    /// The store's side table `name` (a file beside its index, e.g. [`crate::GEOMIP_FILE`])
    /// as a local path, if the store has one: a local store's in its folder; a remote store's
    /// fetched whole into its mirror on the first call (one GET), so a session fetches only
    /// the tables it reads.
    pub fn side_file(&self, name: &str) -> Result<Option<PathBuf>, StoreError> {
        let found = match &self.remote {
            Some(remote) => remote.mirror_file(name)?,
            None => self.dir.join(name).is_file(),
        };
        Ok(found.then(|| self.dir.join(name)))
    }

    /// The store's side table `name` for reading at offsets ([`SideTable`]), if the store has
    /// one: a local store's file; a remote store's copy in its mirror, fetched whole first
    /// ([`Store::side_file`]) unless the store was opened with
    /// [`RemoteOptions::side_tables_in_chunks`]: then the object itself, its size asked by one
    /// HEAD and each read fetching the chunks it covers that are not there yet (or, not
    /// waiting, leaving them to a background fill: [`SideTable::set_waiting`]), so a reader
    /// that needs a few pages of a large table (geomorph's `geomip.bin` read by pages) fetches
    /// their chunks only.
    pub fn side_table(&self, name: &str) -> Result<Option<SideTable>, StoreError> {
        let local = self.dir.join(name);
        let chunked = self.remote.as_ref().and_then(|r| Some((r, r.side_chunk()?)));
        let (remote, chunk) = match chunked {
            Some(rc) if !local.is_file() => rc,
            _ if self.side_file(name)?.is_none() => return Ok(None),
            _ => {
                let file = match std::fs::File::open(&local) {
                    Ok(f) => f,
                    Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
                    Err(cause) => return Err(StoreError::Io { path: local, cause }),
                };
                let io = |cause| StoreError::Io { path: local.clone(), cause };
                let len = file.metadata().map_err(io)?.len();
                return Ok(Some(SideTable::file(file, len, local.display().to_string())));
            }
        };
        let Some(len) = remote.file_size(name)? else { return Ok(None) };
        Ok(Some(SideTable::remote(remote, name, len, chunk, &self.parts)?))
    }

    /// Whether the store has the side table `name`, without fetching it (a remote store:
    /// its mirror's copy or one HEAD request).
    pub fn has_side_file(&self, name: &str) -> Result<bool, StoreError> {
        match &self.remote {
            Some(remote) => remote.has_file(name),
            None => Ok(self.dir.join(name).is_file()),
        }
    }

    /// Bytes received from a remote store's location so far (its index at open, then index
    /// pages, the side tables asked for and block levels), by this store and its clones; 0 for
    /// a local store. For tests and measurements.
    pub fn remote_bytes_received(&self) -> u64 {
        self.remote.as_ref().map_or(0, |r| r.bytes_received())
    }

    /// The index's bytes before its final CRC-32 (what a table tied to the store hashes):
    /// the file's; a paged index's head and every page (a remote store's fetched as needed,
    /// each checked by its CRC-32).
    pub fn index_content(&self) -> Result<Vec<u8>, StoreError> {
        match &*self.index {
            Index::Paged { pages, .. } => pages.content(),
            Index::Whole(_) => {
                let path = self.dir.join(INDEX_FILE);
                let mut b = std::fs::read(&path).map_err(|cause| StoreError::Io { path, cause })?;
                b.truncate(b.len().saturating_sub(4));
                Ok(b)
            }
        }
    }

    /// Bytes of the index (the file, or a remote store's object), when the index is paged
    /// (version 4); `None` for an index read whole.
    pub fn index_bytes(&self) -> Option<u64> {
        match &*self.index {
            Index::Paged { pages, .. } => Some(pages.file_len()),
            Index::Whole(_) => None,
        }
    }

    /// This store with a cache of decoded index pages of at most `bytes` (default 32 MiB; at
    /// least one page is kept), its own and empty. Nothing changes for an index read whole
    /// (versions 2 and 3).
    pub fn with_page_cache_bytes(mut self, bytes: u64) -> Result<Self, StoreError> {
        if let Index::Paged { pages, .. } = &*self.index {
            let p = pages.exaggerated(1.0)?;
            p.set_budget(bytes);
            self.index = Arc::new(Index::paged(p));
        }
        Ok(self)
    }

    /// Sets the byte budget of the decoded index pages this store and its clones share
    /// (default 32 MiB; at least one page is kept); pages beyond it leave at once, least
    /// recently used first. Nothing changes for an index read whole (versions 2 and 3). A
    /// runtime whose view's entries outgrow the default sizes it from its memory budget
    /// (terrain-app's `OocScene`): a cache smaller than the pages a flight keeps asking for
    /// decodes each of them again and again, on the frame thread too.
    pub fn set_index_cache_bytes(&self, bytes: u64) {
        if let Index::Paged { pages, .. } = &*self.index {
            pages.set_budget(bytes);
        }
    }

    /// Bytes of decoded index pages this store's cache keeps at most and the most it could
    /// hold (the whole index decoded); `None` for an index read whole.
    pub fn index_cache_bytes(&self) -> Option<(u64, u64)> {
        match &*self.index {
            Index::Paged { pages, .. } => Some((pages.budget(), pages.decoded_len())),
            Index::Whole(_) => None,
        }
    }

    /// Index pages read and decoded so far by this store and its clones (cache misses);
    /// `None` for an index read whole. For tests and measurements.
    pub fn index_pages_decoded(&self) -> Option<u64> {
        match &*self.index {
            Index::Paged { pages, .. } => Some(pages.pages_decoded()),
            Index::Whole(_) => None,
        }
    }

    /// The first index page [`Store::entry`] could not read (it then says `None`), with why;
    /// `None` while every page read was good. [`Store::try_entry`] returns the error itself.
    pub fn index_fault(&self) -> Option<String> {
        match &*self.index {
            Index::Paged { fault, .. } => fault.lock().expect("index fault").clone(),
            Index::Whole(_) => None,
        }
    }

    /// Where the store was opened from: its URL for a remote store, else its folder.
    pub fn location(&self) -> String {
        match &self.remote {
            Some(r) => r.url().to_string(),
            None => self.dir.display().to_string(),
        }
    }

    /// Whether the store is read from object storage or HTTP.
    pub fn is_remote(&self) -> bool {
        self.remote.is_some()
    }

    /// For a remote store, fetches levels `first..=last` of block `id` in one range request
    /// (those not in the disk cache), so the [`Store::load_level`] calls that follow read
    /// them without a request each. Nothing for a local store, nor for the levels the store's
    /// overview holds (read from the mirrored overview, [`Store::overview_levels`]).
    pub fn prefetch_levels(&self, id: BlockId, first: u8, last: u8) -> Result<(), StoreError> {
        let first = match self.overview_levels() {
            Some(top) if top >= last => return Ok(()),
            Some(top) => first.max(top + 1),
            None => first,
        };
        match (&self.remote, self.try_entry(id)?) {
            (Some(r), Some(e)) => r.fetch_levels(id, &e, first, last, self.header.bake_id),
            _ => Ok(()),
        }
    }
}

/// The header and block entries of index bytes read from `path` (a file or a URL).
fn parse_index(bytes: &[u8], path: PathBuf) -> Result<(Header, Vec<BlockEntry>), StoreError> {
    read_index(bytes).map_err(|e| index_err(e, &path))
}

/// Checks a block file's header (magic, version, bake id, block position).
pub(crate) fn check_block_header(
    head: &[u8],
    path: &Path,
    id: BlockId,
    level: u8,
    bake_id: u64,
) -> Result<(), StoreError> {
    let path = path.to_path_buf();
    if head[..8] != BLOCK_MAGIC {
        return Err(StoreError::NotABlock { path, block: id, level });
    }
    let u32_at = |o: usize| u32::from_le_bytes([head[o], head[o + 1], head[o + 2], head[o + 3]]);
    let version = u32_at(8);
    if version != VERSION {
        return Err(StoreError::Version { path, found: version, expected: VERSION });
    }
    let mut idb = [0u8; 8];
    idb.copy_from_slice(&head[12..20]);
    let found = u64::from_le_bytes(idb);
    if found != bake_id || u32_at(20) != id.row || u32_at(24) != id.col {
        return Err(StoreError::Foreign {
            path,
            block: id,
            level,
            message: format!(
                "its header says bake {found:016x} block (row {}, col {}), the index bake {bake_id:016x}",
                u32_at(20),
                u32_at(24),
            ),
        });
    }
    Ok(())
}

impl Store {
    /// This store read with its heights exaggerated `scale` times (a vertical exaggeration):
    /// every decoded height ([`BlockLevels::height`], multiplied in f64 and rounded once) and
    /// every height and height error of the index (block and node minima and maxima,
    /// `StaticE`, the per-level and fine maxima, the DSS errors, the header's error bounds)
    /// times `scale`, so everything that selects from the store (the streamer's Eq. 7 and Eq. 8,
    /// the culling boxes, the patch selection) sees the exaggerated terrain: all of these are
    /// vertical distances, linear in the heights. Scales compose (`exaggerated(a)` then
    /// `exaggerated(b)` reads `a b`). The block files are unchanged; `scale` must be finite and
    /// positive.
    pub fn exaggerated(&self, scale: f64) -> Result<Store, StoreError> {
        if !(scale.is_finite() && scale > 0.0) {
            return Err(StoreError::Exaggeration { path: self.dir.clone(), scale });
        }
        let mut s = self.clone();
        // Its own decimation errors, read and scaled when first asked for.
        s.decimation = Arc::default();
        let h = &mut s.header;
        h.vertical_scale *= scale;
        h.max_error_m *= scale;
        h.max_void_error_m *= scale;
        h.error_bound_m *= scale;
        s.index = Arc::new(match &*self.index {
            Index::Whole(blocks) => Index::Whole(
                blocks
                    .iter()
                    .map(|b| {
                        let mut b = BlockEntry::clone(b);
                        scale_entry(&mut b, scale);
                        Arc::new(b)
                    })
                    .collect(),
            ),
            Index::Paged { pages, .. } => Index::paged(pages.exaggerated(scale)?),
        });
        Ok(s)
    }

    /// The store folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The header.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// Whether the bake wrote the DSS paper's per-block object-space errors into the index
    /// (`BakeConfig::dss_errors`; every block has them or none does).
    pub fn has_dss_errors(&self) -> bool {
        match &*self.index {
            Index::Whole(blocks) => blocks.first().is_some_and(|b| b.dss.is_some()),
            Index::Paged { pages, .. } => pages.head().has_dss,
        }
    }

    /// Whether the index holds the fine maxima ([`BlockEntry::fine_errors`], index version 3
    /// and later), or needs none (node values stored down to the finest level). Without them
    /// (a version-2 index) nodes below the stored levels are bounded by the block's per-level
    /// maximum.
    pub fn has_fine_errors(&self) -> bool {
        let h = &self.header;
        h.node_levels == 0
            || h.node_levels >= h.k
            || match &*self.index {
                Index::Whole(blocks) => blocks.first().is_some_and(|b| !b.fine_errors.is_empty()),
                Index::Paged { pages, .. } => pages.head().has_fine,
            }
    }

    /// A block's index entry, or `None` outside the grid, or when its index page cannot be
    /// read (a version-4 index; [`Store::index_fault`] then says why, and
    /// [`Store::try_entry`] returns the error).
    pub fn entry(&self, id: BlockId) -> Option<Arc<BlockEntry>> {
        match self.try_entry(id) {
            Ok(e) => e,
            Err(e) => {
                if let Index::Paged { fault, .. } = &*self.index {
                    fault.lock().expect("index fault").get_or_insert_with(|| e.to_string());
                }
                None
            }
        }
    }

    /// A block's index entry (`None` outside the grid), or why its index page cannot be read.
    pub fn try_entry(&self, id: BlockId) -> Result<Option<Arc<BlockEntry>>, StoreError> {
        let Some(p) = self.header.block_position(id) else { return Ok(None) };
        match &*self.index {
            Index::Whole(blocks) => Ok(Some(blocks[p].clone())),
            Index::Paged { pages, .. } => pages.entry(p).map(Some),
        }
    }

    /// The block pyramid of a version-4 index's head: its levels, and per node (level-major,
    /// row-major) the blocks' min/max and `k + 1` per-level error bounds; `None` for an older
    /// index.
    pub(crate) fn block_pyramid(&self) -> Option<&crate::pages::IndexHead> {
        match &*self.index {
            Index::Paged { pages, .. } => Some(pages.head()),
            Index::Whole(_) => None,
        }
    }

    /// The plan rectangle (world metres, south-west and north-east corners) of block `id`'s
    /// valid (non-padding) vertices, or `None` outside the grid.
    pub fn block_rect(&self, id: BlockId) -> Option<(glam::DVec2, glam::DVec2)> {
        let e = self.entry(id)?;
        Some(crate::schedule::block_rect(&self.header, &e, id))
    }

    /// Every block, row-major from the south-west.
    pub fn block_ids(&self) -> impl Iterator<Item = BlockId> + '_ {
        (0..self.header.block_count()).map(|p| self.header.block_at(p))
    }

    /// Total bytes of the block files.
    pub fn blocks_bytes(&self) -> u64 {
        match &*self.index {
            Index::Whole(blocks) => blocks.iter().map(|b| b.file_len).sum(),
            Index::Paged { pages, .. } => pages.head().blocks_bytes,
        }
    }

    /// Reads and checks the payload of `level` of block `id` (positioned read, CRC-32 verified).
    pub fn read_level_bytes(&self, id: BlockId, level: u8) -> Result<Vec<u8>, StoreError> {
        let bad = |message: String| StoreError::BadRequest { block: id, level, message };
        // The overview's levels need no index entry (its records carry lengths and CRCs). A
        // remote store whose overview cannot be fetched reads the block files (the same
        // bytes, checked the same way); a local one's was opened, or refused, with the store.
        if level <= crate::overview::OVERVIEW_TOP
            && let Some(pos) = self.header.block_position(id)
            && let Some(overview) = self.overview().ok().flatten().filter(|o| level <= o.top())
        {
            return overview.level_bytes(pos, id, level);
        }
        let entry =
            self.try_entry(id)?.ok_or_else(|| bad("block outside the store's grid".into()))?;
        let le = *entry
            .levels
            .get(level as usize)
            .ok_or_else(|| bad(format!("the finest level is {}", self.header.k)))?;
        if let Some(remote) = &self.remote {
            let (payload, _) = remote.level(id, &entry, level, self.header.bake_id)?;
            let computed = crc32(&payload);
            if computed != le.crc32 {
                return Err(StoreError::Checksum {
                    path: remote.block_url(id),
                    block: id,
                    level,
                    stored: le.crc32,
                    computed,
                });
            }
            return Ok(payload);
        }
        let path = self.dir.join(block_file_name(id));
        let file = File::open(&path).map_err(|cause| {
            if cause.kind() == std::io::ErrorKind::NotFound {
                StoreError::MissingBlock { path: path.clone(), block: id, level }
            } else {
                StoreError::Io { path: path.clone(), cause }
            }
        })?;
        let io = |cause| StoreError::Io { path: path.clone(), cause };
        let len = file.metadata().map_err(io)?.len();
        if len < entry.file_len {
            return Err(StoreError::Truncated {
                path,
                block: id,
                level,
                expected: entry.file_len,
                got: len,
            });
        }
        if len != entry.file_len {
            return Err(StoreError::Changed {
                path,
                block: id,
                level,
                message: format!("{len} bytes, the index says {}", entry.file_len),
            });
        }
        let mut head = [0u8; BLOCK_HEADER_LEN as usize];
        read_at(&file, 0, &mut head).map_err(io)?;
        check_block_header(&head, &path, id, level, self.header.bake_id)?;
        let mut payload = vec![0u8; le.len as usize];
        read_at(&file, le.offset, &mut payload).map_err(io)?;
        let computed = crc32(&payload);
        if computed != le.crc32 {
            return Err(StoreError::Checksum {
                path,
                block: id,
                level,
                stored: le.crc32,
                computed,
            });
        }
        Ok(payload)
    }

    /// Reads, checks and decodes `level` of block `id` on top of its decoded coarser levels
    /// (`coarser.len()` must equal `level`).
    pub fn load_level<L: AsRef<[i32]>>(
        &self,
        id: BlockId,
        level: u8,
        coarser: &[L],
    ) -> Result<LoadedLevel, StoreError> {
        if coarser.len() != level as usize {
            return Err(StoreError::BadRequest {
                block: id,
                level,
                message: format!(
                    "levels load coarse to fine: {} coarser levels given",
                    coarser.len()
                ),
            });
        }
        let t = Instant::now();
        let payload = self.read_level_bytes(id, level)?;
        let io_time = t.elapsed();
        let samples = decode_level(self.header.k, level, &payload, coarser)
            .map_err(|message| StoreError::CorruptLevel { block: id, level, message })?;
        Ok(LoadedLevel { samples: samples.into(), disk_bytes: payload.len() as u64, io_time })
    }

    /// Reads levels `0..=level` of block `id` (a convenience for tools and tests).
    pub fn read_block(&self, id: BlockId, level: u8) -> Result<BlockLevels, StoreError> {
        let mut b = BlockLevels::new(&self.header);
        for l in 0..=level {
            let loaded = self.load_level(id, l, b.levels())?;
            b.push(loaded.samples);
        }
        Ok(b)
    }
}

/// Positioned read (`pread` where the platform has it).
pub(crate) fn read_at(file: &File, offset: u64, buf: &mut [u8]) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileExt;
        file.read_exact_at(buf, offset)
    }
    #[cfg(not(unix))]
    {
        use std::io::{Read, Seek, SeekFrom};
        let mut file = file;
        file.seek(SeekFrom::Start(offset))?;
        file.read_exact(buf)
    }
}

/// Whether `path` is a baked store: a folder whose index file starts with the store's magic
/// (any version, intact or not). Nothing else is ever replaced by a bake.
pub fn is_store(path: &Path) -> bool {
    use std::io::Read;
    let mut magic = [0u8; 8];
    path.is_dir()
        && File::open(path.join(INDEX_FILE)).and_then(|mut f| f.read_exact(&mut magic)).is_ok()
        && magic == MAGIC
}

/// The resident levels `0..n` of one block, each level's samples in stored order: the
/// paper's linear sequence, cut at level boundaries so a level loads or unloads alone.
#[derive(Debug, Clone)]
pub struct BlockLevels {
    k: u8,
    encoding: SampleEncoding,
    /// The store's vertical exaggeration ([`Header::vertical_scale`]).
    scale: f64,
    levels: Vec<Arc<[i32]>>,
}

impl BlockLevels {
    /// No level resident.
    pub fn new(header: &Header) -> Self {
        Self {
            k: header.k,
            encoding: header.encoding,
            scale: header.vertical_scale,
            levels: Vec::new(),
        }
    }

    /// Number of resident levels (`0` = none; levels `0..count` are resident).
    pub fn count(&self) -> usize {
        self.levels.len()
    }

    /// The resident levels' samples.
    pub fn levels(&self) -> &[Arc<[i32]>] {
        &self.levels
    }

    /// Appends the next finer level. Returns false (and keeps nothing) if its length is not
    /// that level's.
    pub fn push(&mut self, samples: Arc<[i32]>) -> bool {
        if self.levels.len() > self.k as usize
            || samples.len() != level_len(self.levels.len() as u8)
        {
            return false;
        }
        self.levels.push(samples);
        true
    }

    /// Drops the finest resident level; returns its bytes in memory.
    pub fn pop(&mut self) -> u64 {
        self.levels.pop().map_or(0, |l| l.len() as u64 * Header::SAMPLE_BYTES)
    }

    /// Bytes in memory.
    pub fn bytes(&self) -> u64 {
        self.levels.iter().map(|l| l.len() as u64).sum::<u64>() * Header::SAMPLE_BYTES
    }

    /// Height of block vertex `(i, j)` (exaggerated as the store is read,
    /// [`Store::exaggerated`]), if its level is resident.
    pub fn height(&self, i: u32, j: u32) -> Option<f32> {
        let v = vertex_index(self.k, i, j)?;
        let q = *self.levels.get(v.level as usize)?.get(v.order as usize)?;
        Some(self.decode(q))
    }

    /// The height of stored sample `q`, exaggerated as the store is read.
    #[inline]
    fn decode(&self, q: i32) -> f32 {
        if self.scale == 1.0 {
            self.encoding.height(q)
        } else {
            self.encoding.height_scaled(q, self.scale)
        }
    }

    /// The `(2^level + 1)^2` grid of heights at `level` (row-major, south row first), if
    /// levels `0..=level` are resident.
    pub fn grid(&self, level: u8) -> Option<Vec<f32>> {
        if level as usize >= self.levels.len() {
            return None;
        }
        // Each resident level scattered in its stored order (that of
        // [`crate::format::for_each_level_vertex`], row by row, without a call per vertex):
        // the same values as `height` at every vertex (the store tests' `check_heights`). The
        // page fills of every store method run this on the frame thread, a block level a page.
        let n = (1usize << level) + 1;
        let mut out = vec![0f32; n * n];
        'level: for (l, samples) in self.levels.iter().take(level as usize + 1).enumerate() {
            // Level l's vertices are every `step`-th sample of the level's grid: rows `b` of
            // the level's `cnt` rows, odd rows whole and even rows at odd columns (level 0:
            // its four corners).
            let step = 1usize << (level as usize - l);
            let cnt = (1usize << l) + 1;
            let mut q = samples.iter().map(|&q| self.decode(q));
            for b in 0..cnt {
                let (first, every) = if l == 0 || b % 2 == 1 { (0, 1) } else { (1, 2) };
                let row = &mut out[b * step * n..][..n];
                for a in (first..cnt).step_by(every) {
                    // (`push` keeps every level at its length: the walk and the samples end
                    // together.)
                    let Some(z) = q.next() else { continue 'level };
                    row[a * step] = z;
                }
            }
        }
        Some(out)
    }
}
