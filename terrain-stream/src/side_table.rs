//! A store's side table read at offsets ([`SideTable`]): a local file, or a remote store's
//! object read where it lies by chunks (`RemotePart`), fetched on the reading thread while the
//! table waits and, once a reader says it must not wait ([`SideTable::set_waiting`]), on a
//! thread of its own: the chunks a read asked for first, then every other one in order, so a
//! flight's frames after the first never wait for the table and the table is whole in the
//! mirror soon after.

use std::collections::{HashMap, VecDeque};
use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, OnceLock, Weak};

use crate::error::StoreError;
use crate::remote::Remote;
use crate::store::read_at;

/// Chunks the background fill fetches in one range GET when no read is waiting for others.
const FILL_RUN_CHUNKS: usize = 8;

/// A store's side table read at offsets ([`crate::Store::side_table`]): a file, or a remote
/// store's object read by range requests. Its reads are positioned (any thread may read).
///
/// A remote table waits by default: a read fetches the chunks it covers that are not there
/// yet on the reading thread. [`SideTable::set_waiting`]`(false)` starts the background fill
/// and makes a read that reaches a missing chunk fail at once with
/// [`std::io::ErrorKind::WouldBlock`] (the chunk queued first for the fill): the reader
/// decides what to do without it (geomorph's selection bounds the patches of a page not there
/// by its coarse pyramid) and reads again later.
#[derive(Debug)]
pub struct SideTable {
    len: u64,
    /// Its path, or its URL for a remote object (for messages).
    location: String,
    source: SideSource,
}

#[derive(Debug)]
enum SideSource {
    File(File),
    Remote(Arc<RemotePart>),
}

/// The remote side tables a store (and its clones) reads where they lie, by name: the store
/// keeps them alive.
pub(crate) type SideParts = Arc<Mutex<HashMap<String, Arc<RemotePart>>>>;

/// A part of this process by its mirror folder and table name.
type LiveParts = HashMap<(PathBuf, String), Weak<RemotePart>>;

/// Every live [`RemotePart`] of this process by its mirror folder and table name, so stores
/// opened separately on one location (and cache) read one part: each chunk fetched once a
/// process. Weak: a part lives while a store or a reader holds it.
fn live_parts() -> MutexGuard<'static, LiveParts> {
    static LIVE: OnceLock<Mutex<LiveParts>> = OnceLock::new();
    LIVE.get_or_init(Default::default).lock().unwrap_or_else(|e| e.into_inner())
}

impl SideTable {
    /// A local file of `len` bytes at `location`.
    pub(crate) fn file(file: File, len: u64, location: String) -> Self {
        Self { len, location, source: SideSource::File(file) }
    }

    /// Remote table `name` of `len` bytes, read by chunks of `chunk` bytes: the store's part
    /// of it in `parts` (what earlier readers fetched, its fill if it runs), else the part
    /// another store of this process reads from the same mirror ([`live_parts`]), else a new
    /// one. A shared part counts its bytes in the store that opened it
    /// ([`crate::Store::remote_bytes_received`]).
    pub(crate) fn remote(
        remote: &Arc<Remote>,
        name: &str,
        len: u64,
        chunk: u64,
        parts: &SideParts,
    ) -> Result<Self, StoreError> {
        let location = format!("{}/{name}", remote.url());
        let fits = |p: &RemotePart| p.inner.len == len && p.inner.chunk == chunk;
        let mut parts = parts.lock().unwrap_or_else(|e| e.into_inner());
        let part = match parts.get(name) {
            Some(p) if fits(p) => p.clone(),
            _ => {
                let key = (remote.mirror().to_path_buf(), name.to_string());
                let mut live = live_parts();
                let p = match live.get(&key).and_then(Weak::upgrade) {
                    Some(p) if fits(&p) => p,
                    _ => {
                        let p = Arc::new(RemotePart::open(remote, name, len, chunk));
                        live.retain(|_, w| w.strong_count() > 0);
                        live.insert(key, Arc::downgrade(&p));
                        p
                    }
                };
                parts.insert(name.to_string(), p.clone());
                p
            }
        };
        Ok(Self { len, location, source: SideSource::Remote(part) })
    }

    /// Its length in bytes.
    pub fn len(&self) -> u64 {
        self.len
    }

    /// Whether it has no bytes.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Its path, or its URL when it is read from a remote store by range requests.
    pub fn location(&self) -> &str {
        &self.location
    }

    /// Whether its reads are range requests to a remote store.
    pub fn is_remote(&self) -> bool {
        matches!(self.source, SideSource::Remote(..))
    }

    /// Whether a read waits for chunks not fetched yet (the default), or fails at once with
    /// [`std::io::ErrorKind::WouldBlock`] and leaves them to the background fill, which the
    /// first `set_waiting(false)` starts (see the type's docs). A local file never waits.
    pub fn set_waiting(&self, wait: bool) {
        if let SideSource::Remote(part) = &self.source {
            part.set_waiting(wait);
        }
    }

    /// Starts the background fill of a remote table (the chunks not here yet, in order),
    /// unless it runs or ran; a local file has every byte.
    pub fn fetch_all_in_background(&self) {
        if let SideSource::Remote(part) = &self.source {
            part.start_fill();
        }
    }

    /// Whether every byte is here: a local file, or a remote table whose chunks were all
    /// fetched (then it is the mirror's copy too).
    pub fn is_complete(&self) -> bool {
        match &self.source {
            SideSource::File(_) => true,
            SideSource::Remote(part) => part.inner.lock().missing == 0,
        }
    }
}

impl terrain_core::lod::TableReader for SideTable {
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> std::io::Result<()> {
        match &self.source {
            SideSource::File(file) => read_at(file, offset, buf),
            SideSource::Remote(part) => part.read_at(offset, buf),
        }
    }

    fn set_waiting(&self, wait: bool) {
        SideTable::set_waiting(self, wait);
    }

    fn fetch_all_in_background(&self) {
        SideTable::fetch_all_in_background(self);
    }
}

/// A chunk's state in a [`RemotePart`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Chunk {
    Missing,
    /// Being fetched by a reader or the fill: wait for it.
    InFlight,
    Here,
}

/// The bytes of a remote side table fetched so far, in a sparse file in the store's mirror:
/// each chunk ([`crate::RemoteOptions::side_chunk_bytes`]) fetched once a session, by a
/// waiting read (one range GET per run of missing chunks it covers) or by the background fill;
/// no memory holds them. Once every chunk is there the file is the table: it is renamed to the
/// mirror's copy ([`crate::Store::side_file`] then finds it); a part left incomplete is
/// removed when the store and its readers drop it, and one a killed process left (or one a
/// store kept open to the end of its process) when a later process makes its part of the
/// table ([`remove_stale_parts`]). The file is made by the first fetch.
#[derive(Debug)]
pub(crate) struct RemotePart {
    inner: Arc<PartInner>,
    /// The background fill, once started; stopped and joined on drop.
    fill: Mutex<Option<std::thread::JoinHandle<()>>>,
}

#[derive(Debug)]
struct PartInner {
    remote: Arc<Remote>,
    /// The object's name beside the index.
    name: String,
    /// The sparse file at `path`, created by the first fetch (a table opened only to learn
    /// its length leaves no file behind).
    file: OnceLock<File>,
    /// Serialises the file's creation.
    creating: Mutex<()>,
    path: PathBuf,
    len: u64,
    chunk: u64,
    waiting: AtomicBool,
    state: Mutex<Chunks>,
    /// Signalled when chunks arrive (or fail back to missing) and when the fill should stop.
    arrived: Condvar,
}

/// Which chunks a [`RemotePart`] holds, which are asked for, and how many it lacks.
#[derive(Debug)]
struct Chunks {
    chunks: Vec<Chunk>,
    missing: usize,
    /// Chunks non-waiting reads asked for, fetched by the fill first.
    asked: VecDeque<usize>,
    /// Where the fill's in-order pass goes on.
    cursor: usize,
    /// The fill's last error (non-waiting reads return it once the fill has stopped).
    failed: Option<String>,
    fill_running: bool,
    stop: bool,
}

impl PartInner {
    fn lock(&self) -> MutexGuard<'_, Chunks> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The part's file, created on first use (after removing the parts of this table that
    /// dead processes left: [`remove_stale_parts`]).
    fn file(&self) -> std::io::Result<&File> {
        if let Some(f) = self.file.get() {
            return Ok(f);
        }
        let _one = self.creating.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(f) = self.file.get() {
            return Ok(f);
        }
        remove_stale_parts(self.remote.mirror(), &self.name);
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(&self.path)
            .map_err(|e| std::io::Error::new(e.kind(), format!("{}: {e}", self.path.display())))?;
        Ok(self.file.get_or_init(|| file))
    }

    /// Fetches chunks `k..=e` (marked in flight by the caller) and marks them here, or missing
    /// again on failure; wakes the waiting readers either way.
    fn fetch(&self, k: usize, e: usize) -> std::io::Result<()> {
        let c = self.chunk;
        let (at, to) = (k as u64 * c, ((e as u64 + 1) * c).min(self.len));
        let got = self
            .remote
            .read_range(&self.name, at..to)
            .map_err(std::io::Error::other)
            .and_then(|bytes| write_at(self.file()?, at, &bytes));
        let mut s = self.lock();
        let mark = if got.is_ok() { Chunk::Here } else { Chunk::Missing };
        s.chunks[k..=e].iter_mut().for_each(|h| *h = mark);
        if got.is_ok() {
            s.missing -= e + 1 - k;
            if s.missing == 0 {
                // Complete: the mirror's copy (a rename, so a reader sees it whole or not).
                let _ = std::fs::rename(&self.path, self.remote.mirror().join(&self.name));
            }
        }
        drop(s);
        self.arrived.notify_all();
        got
    }

    /// The background fill: chunks asked for first, then the rest in order, until every chunk
    /// is here, a fetch fails (kept in `failed`) or the part is dropped.
    fn fill(&self) {
        loop {
            let mut s = self.lock();
            if s.stop || s.missing == 0 {
                break;
            }
            let n = s.chunks.len();
            let mut asked = None;
            while let Some(k) = s.asked.pop_front() {
                if s.chunks[k] == Chunk::Missing {
                    asked = Some(k);
                    break;
                }
            }
            let start = asked.or_else(|| {
                let from = s.cursor;
                (from..n).chain(0..from).find(|&k| s.chunks[k] == Chunk::Missing)
            });
            let Some(k) = start else {
                // The rest is in flight on readers' threads: wait for them.
                drop(self.arrived.wait(s).unwrap_or_else(|e| e.into_inner()));
                continue;
            };
            let run = if asked.is_some() { 1 } else { FILL_RUN_CHUNKS };
            let mut e = k;
            while e + 1 < n && e + 1 - k < run && s.chunks[e + 1] == Chunk::Missing {
                e += 1;
            }
            s.chunks[k..=e].iter_mut().for_each(|h| *h = Chunk::InFlight);
            if asked.is_none() {
                s.cursor = e + 1;
            }
            drop(s);
            if let Err(err) = self.fetch(k, e) {
                let mut s = self.lock();
                s.failed = Some(err.to_string());
                break;
            }
        }
        self.lock().fill_running = false;
        self.arrived.notify_all();
    }
}

impl RemotePart {
    fn open(remote: &Arc<Remote>, name: &str, len: u64, chunk: u64) -> Self {
        use std::sync::atomic::AtomicU64;
        static PARTS: AtomicU64 = AtomicU64::new(0);
        let k = PARTS.fetch_add(1, Ordering::Relaxed);
        let path = remote.mirror().join(format!("{name}.part{}-{k}", std::process::id()));
        let n = len.div_ceil(chunk) as usize;
        let state = Chunks {
            chunks: vec![Chunk::Missing; n],
            missing: n,
            asked: VecDeque::new(),
            cursor: 0,
            failed: None,
            fill_running: false,
            stop: false,
        };
        let inner = PartInner {
            remote: remote.clone(),
            name: name.to_string(),
            file: OnceLock::new(),
            creating: Mutex::new(()),
            path,
            len,
            chunk,
            waiting: AtomicBool::new(true),
            state: Mutex::new(state),
            arrived: Condvar::new(),
        };
        Self { inner: Arc::new(inner), fill: Mutex::new(None) }
    }

    fn set_waiting(&self, wait: bool) {
        if !wait {
            // The fill runs before a read may stop waiting (a read that does not wait and
            // finds no fill running reports the fill's error).
            self.start_fill();
        }
        self.inner.waiting.store(wait, Ordering::Relaxed);
    }

    /// Starts the background fill, unless it runs or every chunk is here (a fill that stopped
    /// on an error starts again: its requests had their retries).
    fn start_fill(&self) {
        let mut fill = self.fill.lock().unwrap_or_else(|e| e.into_inner());
        if fill.as_ref().is_some_and(|h| !h.is_finished()) {
            return;
        }
        if let Some(done) = fill.take() {
            let _ = done.join();
        }
        let mut s = self.inner.lock();
        if s.missing == 0 || s.stop {
            return;
        }
        s.fill_running = true;
        drop(s);
        let inner = self.inner.clone();
        let spawned = std::thread::Builder::new()
            .name(format!("fill {}", self.inner.name))
            .spawn(move || inner.fill());
        match spawned {
            Ok(handle) => *fill = Some(handle),
            Err(e) => {
                let mut s = self.inner.lock();
                s.fill_running = false;
                s.failed = Some(format!("starting the background fill: {e}"));
            }
        }
    }

    /// Reads `buf` at `offset`: at once when its chunks are here; else, waiting, after fetching
    /// the missing ones (and waiting for those in flight); not waiting, an error of kind
    /// `WouldBlock` (the missing chunks asked of the fill), or the fill's error once it
    /// stopped on one.
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> std::io::Result<()> {
        let inner = &*self.inner;
        let end = offset.saturating_add(buf.len() as u64);
        if end > inner.len {
            return Err(std::io::Error::new(
                std::io::ErrorKind::UnexpectedEof,
                format!("bytes {offset}..{end} of {} ({} bytes)", inner.name, inner.len),
            ));
        }
        if buf.is_empty() {
            return Ok(());
        }
        let c = inner.chunk;
        let (first, last) = ((offset / c) as usize, ((end - 1) / c) as usize);
        let mut s = inner.lock();
        loop {
            if s.missing == 0 || s.chunks[first..=last].iter().all(|&h| h == Chunk::Here) {
                drop(s);
                return read_at(inner.file()?, offset, buf);
            }
            if !inner.waiting.load(Ordering::Relaxed) {
                if !s.fill_running {
                    // The fill stopped on an error: this read reports it, the fill starts
                    // again for the next.
                    let why = s.failed.take().unwrap_or_else(|| "the fill stopped".into());
                    drop(s);
                    self.start_fill();
                    return Err(std::io::Error::other(format!(
                        "fetching {} in the background: {why}",
                        inner.name
                    )));
                }
                let missing: Vec<usize> =
                    (first..=last).filter(|&k| s.chunks[k] == Chunk::Missing).collect();
                s.asked.extend(missing);
                drop(s);
                inner.arrived.notify_all();
                return Err(std::io::Error::new(
                    std::io::ErrorKind::WouldBlock,
                    format!("bytes {offset}..{end} of {} are being fetched", inner.name),
                ));
            }
            // Waiting: fetch the first run of missing chunks here, or wait for those in flight.
            match (first..=last).find(|&k| s.chunks[k] == Chunk::Missing) {
                Some(k) => {
                    let mut e = k;
                    while e < last && s.chunks[e + 1] == Chunk::Missing {
                        e += 1;
                    }
                    s.chunks[k..=e].iter_mut().for_each(|h| *h = Chunk::InFlight);
                    drop(s);
                    inner.fetch(k, e)?;
                    s = inner.lock();
                }
                None => s = inner.arrived.wait(s).unwrap_or_else(|e| e.into_inner()),
            }
        }
    }
}

impl Drop for RemotePart {
    fn drop(&mut self) {
        self.inner.lock().stop = true;
        self.inner.arrived.notify_all();
        if let Some(fill) = self.fill.get_mut().unwrap_or_else(|e| e.into_inner()).take() {
            // It stops after the fetch in progress, if any.
            let _ = fill.join();
        }
    }
}

impl Drop for PartInner {
    fn drop(&mut self) {
        // Gone already when it was completed and renamed; never made when nothing was fetched.
        if self.file.get().is_some() {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

/// Removes the part files of table `name` in `mirror` that a process no longer running left
/// (killed before it could remove them): `NAME.partPID-K` whose `PID` is not a live process.
/// Where the platform cannot tell (no `/proc`), none is removed. A part removed under a process
/// that still reads it (another PID namespace sharing the cache) costs it nothing on unix: its
/// open file stays; only its rename to the mirror's copy fails, which is only a cache miss.
fn remove_stale_parts(mirror: &Path, name: &str) {
    if !Path::new("/proc/self").exists() {
        return;
    }
    let Ok(entries) = std::fs::read_dir(mirror) else { return };
    let prefix = format!("{name}.part");
    for e in entries.flatten() {
        let file = e.file_name();
        let Some(pid) = file
            .to_str()
            .and_then(|f| f.strip_prefix(&prefix))
            .and_then(|rest| rest.split_once('-'))
            .and_then(|(pid, _)| pid.parse::<u32>().ok())
        else {
            continue;
        };
        if !Path::new("/proc").join(pid.to_string()).exists() {
            let _ = std::fs::remove_file(e.path());
        }
    }
}

/// Positioned write (`pwrite` where the platform has it).
fn write_at(file: &File, offset: u64, buf: &[u8]) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileExt;
        file.write_all_at(buf, offset)
    }
    #[cfg(not(unix))]
    {
        use std::io::{Seek, SeekFrom, Write};
        let mut file = file;
        file.seek(SeekFrom::Start(offset))?;
        file.write_all(buf)
    }
}
