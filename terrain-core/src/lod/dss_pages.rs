//! The DSS paper's error table read by pages ([`DssErrorTable::open_paged`]): a store's
//! `dss_errors.bin` holds 32 `f64` per quadtree node (1.43 GB at 32769^2 with 16-cell leaves,
//! more than a stream cache's default budget), so a large one is not decoded whole at open but
//! read where a frame's selection asks, page by page, through a bounded cache: memory and open
//! time follow the view, not the grid.
//!
//! What is read when: at open the header, the per-level counts and the tail (a CRC-32 per page
//! and the CRC-32 of those); during a frame, the pages holding the nodes the selection asks
//! ([`DssErrorTable::get`]), each checked against its CRC-32, decoded and scaled as the whole
//! table's values are (the same `f64` products in the same order), so the selection is bit for
//! bit the whole table's. A page that cannot be read or fails its checksum is an error that
//! names the file and the page (kept for [`DssErrorTable::take_error`]); its nodes get
//! infinite errors, so the selection splits them to the leaves at the finest factor (finer,
//! never a wrong coarse one). A reader that does not wait (`WouldBlock`) is treated the same
//! way for that call, without an error, and counted late. The layout is the format's
//! ([`super::dss_file`], version 2): pages are runs of consecutive nodes in the file's order.
//! terrain-core does no file I/O: the caller's [`TableReader`] reads the bytes.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use rustc_hash::{FxHashMap, FxHashSet};

use super::dss_file::DssFileError;
use super::geomip_pages::{TableReader, lru_cut, read_checked_page};
use crate::metrics::dss::FACTORS;
use crate::quadtree::NodeId;

/// One node's errors.
pub(super) type Errors = [f64; FACTORS];

/// Bytes of one node's entry.
pub(super) const ENTRY_BYTES: usize = FACTORS * 8;

/// How a table read by pages caches what it read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DssPaging {
    /// Bytes of decoded pages kept (default 32 MiB: 128 k nodes, a few frames' views near the
    /// ground); the least recently used go first when it is exceeded.
    pub cache_bytes: u64,
}

impl Default for DssPaging {
    fn default() -> Self {
        Self { cache_bytes: 32 << 20 }
    }
}

/// What a table read by pages has read so far (for tests and measurements).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DssPagingStats {
    /// Bytes read from the file, the open's included.
    pub bytes_read: u64,
    /// Pages read (again after an eviction).
    pub pages_read: u64,
    /// Bytes the cache holds now.
    pub cached_bytes: u64,
    /// Reads not waited for (the reader said `WouldBlock`): those nodes were split finest.
    pub pages_late: u64,
}

/// The layout of a version-2 file, from its header and tail.
#[derive(Debug, Clone)]
pub(super) struct DssPagedLayout {
    /// The file's name in errors.
    pub(super) file: String,
    /// Per level used: nodes per row, and the global index of its first node.
    pub(super) levels: Vec<(u32, u64)>,
    /// Nodes of the levels used.
    pub(super) used_nodes: u64,
    /// Nodes in the file (every level, those not used included).
    pub(super) nodes: u64,
    /// Nodes per page.
    pub(super) page_nodes: u64,
    /// Where the entries start.
    pub(super) entries_at: u64,
    /// Per page: the CRC-32 of its bytes.
    pub(super) page_crcs: Vec<u32>,
}

/// A page read and decoded: its nodes' errors and, beside them, each node's finest error
/// (`delta_32`, the one Eq. 3's split reads at every node the walk visits: 8 bytes a node
/// in a row of their own stay in the CPU's caches from frame to frame, where the 256-byte
/// entries a frame's nodes are spread over do not).
#[derive(Debug)]
pub(super) struct PageData {
    pub(super) errors: Vec<Errors>,
    pub(super) finest: Vec<f64>,
}

impl PageData {
    fn new(errors: Vec<Errors>) -> Self {
        let finest = errors.iter().map(|e| e[FACTORS - 1]).collect();
        Self { errors, finest }
    }

    /// Bytes held.
    fn bytes(&self) -> u64 {
        (self.errors.len() * (ENTRY_BYTES + 8)) as u64
    }
}

pub(super) type Page = Arc<PageData>;

/// The least recently used go first.
#[derive(Debug, Default)]
struct Cache {
    pages: FxHashMap<u64, (Page, u64)>,
    tick: u64,
    bytes: u64,
    /// Pages that could not be used (read or checksum failures): not read again.
    failed: FxHashSet<u64>,
}

/// A table's pages read on demand (see the module docs).
pub(super) struct DssPages {
    layout: DssPagedLayout,
    reader: Arc<dyn TableReader>,
    /// Vertical exaggerations applied, in order ([`super::DssErrorTable::exaggerated`]).
    scales: Vec<f64>,
    budget: u64,
    cache: Mutex<Cache>,
    /// The first page that could not be used since [`DssPages::take_error`].
    failed: Mutex<Option<DssFileError>>,
    bytes_read: AtomicU64,
    pages_read: AtomicU64,
    pages_late: AtomicU64,
}

impl std::fmt::Debug for DssPages {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DssPages")
            .field("file", &self.layout.file)
            .field("scales", &self.scales)
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

/// Two tables read by pages are equal when they are the same one.
impl PartialEq for DssPages {
    fn eq(&self, other: &Self) -> bool {
        std::ptr::eq(self, other)
    }
}

/// Where a node's page lies, and its index there.
#[derive(Debug, Clone, Copy)]
pub(super) struct Slot {
    pub(super) page: u64,
    pub(super) index: usize,
}

impl DssPages {
    /// The pages of `layout` read through `reader`, `open_bytes` read so far.
    pub(super) fn new(
        layout: DssPagedLayout,
        reader: Arc<dyn TableReader>,
        paging: &DssPaging,
        open_bytes: u64,
    ) -> Self {
        Self {
            layout,
            reader,
            scales: Vec::new(),
            budget: paging.cache_bytes,
            cache: Mutex::default(),
            failed: Mutex::default(),
            bytes_read: AtomicU64::new(open_bytes),
            pages_read: AtomicU64::new(0),
            pages_late: AtomicU64::new(0),
        }
    }

    /// The same file with its errors times `scale` (after those applied before), an empty
    /// cache.
    pub(super) fn exaggerated(&self, scale: f64) -> Self {
        let mut scales = self.scales.clone();
        scales.push(scale);
        Self {
            layout: self.layout.clone(),
            reader: self.reader.clone(),
            scales,
            budget: self.budget,
            cache: Mutex::default(),
            failed: Mutex::default(),
            bytes_read: AtomicU64::new(self.bytes_read.load(Ordering::Relaxed)),
            pages_read: AtomicU64::new(0),
            pages_late: AtomicU64::new(0),
        }
    }

    /// The page and index of `node`, or `None` outside the table.
    pub(super) fn slot(&self, node: NodeId) -> Option<Slot> {
        let &(nx, first) = self.layout.levels.get(node.level as usize)?;
        let next = self
            .layout
            .levels
            .get(node.level as usize + 1)
            .map_or(self.layout.used_nodes, |&(_, first)| first);
        if node.i >= nx {
            return None;
        }
        let g = first + u64::from(node.j) * u64::from(nx) + u64::from(node.i);
        if g >= next {
            return None;
        }
        let p = self.layout.page_nodes;
        Some(Slot { page: g / p, index: (g % p) as usize })
    }

    /// Page `p`, read if need be; `None` when it cannot be had (an error kept, or not here yet).
    pub(super) fn page(&self, p: u64) -> Option<Page> {
        let mut cache = self.cache.lock().unwrap_or_else(|e| e.into_inner());
        cache.tick += 1;
        let tick = cache.tick;
        if let Some(slot) = cache.pages.get_mut(&p) {
            slot.1 = tick;
            return Some(slot.0.clone());
        }
        if cache.failed.contains(&p) {
            return None;
        }
        match self.read_page(p) {
            Ok(Some(page)) => {
                let page = Arc::new(PageData::new(page));
                cache.bytes += page.bytes();
                cache.pages.insert(p, (page.clone(), tick));
                trim(&mut cache, self.budget);
                Some(page)
            }
            Ok(None) => {
                self.pages_late.fetch_add(1, Ordering::Relaxed);
                None
            }
            Err(e) => {
                cache.failed.insert(p);
                drop(cache);
                self.failed.lock().unwrap_or_else(|e| e.into_inner()).get_or_insert(e);
                None
            }
        }
    }

    /// Reads and checks page `p` (`Ok(None)`: not here yet, the reader does not wait).
    fn read_page(&self, p: u64) -> Result<Option<Vec<Errors>>, DssFileError> {
        let lay = &self.layout;
        let first = p * lay.page_nodes;
        let nodes = lay.page_nodes.min(lay.nodes - first) as usize;
        let offset = lay.entries_at + first * ENTRY_BYTES as u64;
        let at = (lay.file.as_str(), p as usize, offset);
        let crc = lay.page_crcs[p as usize];
        let read = [&self.bytes_read, &self.pages_read];
        let Some(buf) = read_checked_page(&*self.reader, at, nodes * ENTRY_BYTES, crc, read)?
        else {
            return Ok(None);
        };
        Ok(Some(
            buf.chunks_exact(ENTRY_BYTES)
                .map(|b| {
                    let mut e = super::dss_file::decode_entry(b);
                    for &s in &self.scales {
                        for x in &mut e {
                            *x *= s;
                        }
                    }
                    e
                })
                .collect(),
        ))
    }

    /// What was read so far.
    pub(super) fn stats(&self) -> DssPagingStats {
        DssPagingStats {
            bytes_read: self.bytes_read.load(Ordering::Relaxed),
            pages_read: self.pages_read.load(Ordering::Relaxed),
            cached_bytes: self.cache.lock().unwrap_or_else(|e| e.into_inner()).bytes,
            pages_late: self.pages_late.load(Ordering::Relaxed),
        }
    }

    /// The first page that could not be used since the last call, if any.
    pub(super) fn take_error(&self) -> Option<DssFileError> {
        self.failed.lock().unwrap_or_else(|e| e.into_inner()).take()
    }
}

/// Drops the least recently used pages until at most 3/4 of `budget` is held (once over it).
fn trim(cache: &mut Cache, budget: u64) {
    if cache.bytes <= budget {
        return;
    }
    let items: Vec<(u64, u64)> = cache.pages.values().map(|v| (v.1, v.0.bytes())).collect();
    let (cut, bytes) = lru_cut(items, cache.bytes, budget);
    cache.pages.retain(|_, v| v.1 >= cut);
    cache.bytes = bytes;
}
