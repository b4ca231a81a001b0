//! Stores on object storage and plain HTTP: `s3://`, `gs://`, `az://`, `http(s)://` locations
//! read through the `object_store` crate, with retries and timeouts, and a local disk cache.
//!
//! **Runtime.** A [`Remote`] owns one small tokio runtime (two worker threads) that drives
//! object_store's futures. Callers block on it with `block_on`: the stream's worker threads
//! (and `Store::open_location`, `upload_store`) do; the frame thread never does after a
//! session's first frame, because it never reads a block (the real-time contract of
//! [`crate::Streamer`]).
//!
//! **What is fetched.** At open: a version-4 (paged) index's header and head by range GETs
//! (a first GET of at most [`INDEX_PROBE`] bytes, a second for the rest of the head when it is
//! longer), kept in the mirror as `index.head`; each index page by a range GET when one of its
//! blocks is first asked for, kept as `index.pages/pNNNNNNNN` and checked by its page CRC-32
//! (a cached page that fails it is fetched again; a fetched one that fails is a
//! [`StoreError::IndexPage`] naming the URL and the page). An older index (versions 2-3) is
//! fetched whole once (a later open checks the mirror's copy against the object's length and
//! first bytes, one range GET, and its own CRC-32, instead of fetching it again). Side tables
//! (files beside the index) come into a local mirror folder, which is the store's
//! [`crate::Store::dir`], so code reading tables beside the index works unchanged: those the
//! caller names in [`RemoteOptions::side_files`] at open (the ones present), any other when it
//! is first asked for ([`crate::Store::side_file`]: one GET, so a method's table, e.g.
//! geomorph's `geomip.bin`, 168 MB on a 32769^2 store, is fetched only by a session that draws
//! with that method).
//! Blocks: by range GETs, one request per load request covering the levels asked for
//! ([`Remote::fetch_levels`]); the first request of a block in a session starts at byte 0 so the
//! block header and the object's size are checked as the local reader checks them.
//!
//! **Disk cache.** Each level's payload fetched is kept under the mirror folder
//! (`blocks/rRRRRR_cCCCCC.tsb.L<level>`), checked by its index CRC-32 when read back, evicted
//! least recently used first above [`RemoteOptions::disk_cache_bytes`] (over every store of
//! the cache folder). A second run reads from disk. A changed index (another bake at the same
//! URL: its header and head, which hold the bake id and the head's CRC-32, or the whole older
//! index, differ from the mirror's) clears the store's mirror.

use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime};

use object_store::path::Path as ObjectPath;
use object_store::{
    BackoffConfig, ClientOptions, GetOptions, GetRange, ObjectStore, PutPayload, RetryConfig,
    WriteMultipart,
};

use crate::error::{BakeError, StoreError};
use crate::format::{
    BLOCK_HEADER_LEN, BlockEntry, BlockId, INDEX_FILE, MAGIC, PAGED_INDEX_VERSION, Reader,
    block_file_name, read_header,
};

/// Bytes of an index the first request at open asks for: the whole of a small index, the
/// header of a paged one (more are asked for, doubling, while the header is longer) and the
/// head of a small grid.
pub(crate) const INDEX_PROBE: u64 = 4 << 10;
/// The mirror's copy of a paged index's header and head.
const HEAD_FILE: &str = "index.head";
/// The mirror's folder of a paged index's pages.
const PAGES_DIR: &str = "index.pages";

/// A remote store's index as [`Remote::open`] fetched it.
pub(crate) enum RemoteIndex {
    /// A version 2-3 index, whole.
    Whole(Vec<u8>),
    /// A paged index (version 4): its bytes up to the first page, and the object's size.
    Paged { prefix: Vec<u8>, size: u64 },
}

/// Objects above this size are uploaded in parts (multipart upload), 16 MiB each.
pub const MULTIPART_ABOVE: usize = 16 << 20;

/// Whether `location` names a store on object storage or HTTP (`s3://`, `gs://`, `az://`,
/// `azure://`, `abfs://`, `abfss://`, `http://`, `https://`) rather than a local folder.
pub fn is_url(location: &str) -> bool {
    location.split_once("://").is_some_and(|(scheme, _)| {
        matches!(
            scheme.to_ascii_lowercase().as_str(),
            "s3" | "s3a" | "gs" | "az" | "azure" | "abfs" | "abfss" | "http" | "https"
        )
    })
}

/// How a remote store is read: the disk cache, timeouts and retries, and the side tables
/// mirrored at open.
#[derive(Debug, Clone, PartialEq)]
pub struct RemoteOptions {
    /// The disk cache folder; `None` = `$TERRAIN_CACHE_DIR`, else `$XDG_CACHE_HOME/terrain`,
    /// else `$HOME/.cache/terrain`, else the temporary folder's `terrain-cache`.
    pub cache_dir: Option<PathBuf>,
    /// Bytes of block levels kept in the disk cache, over every store of the folder (least
    /// recently used evicted first). Default 2 GiB; 0 keeps none (every run fetches again).
    pub disk_cache_bytes: u64,
    /// Time limit of one request (connect, send, receive). Default 30 s.
    pub request_timeout: Duration,
    /// Time limit to connect. Default 5 s.
    pub connect_timeout: Duration,
    /// Retries of a failed request (server errors, timeouts, connection resets), with
    /// exponential backoff. Default 3.
    pub retries: usize,
    /// Files beside the index fetched at open into the mirror folder when present (tables the
    /// caller reads from [`crate::Store::dir`] without asking [`crate::Store::side_file`]
    /// first); a missing one is skipped.
    pub side_files: Vec<String>,
    /// Whether [`crate::Store::side_table`] reads a table where it lies, by chunks, instead of
    /// fetching it whole into the mirror first. A chunk is fetched on the reading thread when
    /// a read first reaches it, unless the reader said not to wait
    /// ([`crate::SideTable::set_waiting`]): then the read fails at once (`WouldBlock`) and a
    /// background fill fetches the chunk, and the rest of the table after it. Off by default
    /// (the table fetched whole, once, before it is first read); the `terrain` app turns it on:
    /// one view fetches only the chunks it reads, a flight's first frame too, and its later
    /// frames do not wait.
    pub side_tables_in_chunks: bool,
    /// Bytes a side table read where it lies is fetched in: the chunks a read covers that are
    /// not there yet, one range GET per run of them. Default 1 MiB (`geomip.bin` of a 32769^2
    /// grid is 162 of them); at least 4 KiB.
    pub side_chunk_bytes: u64,
}

impl Default for RemoteOptions {
    fn default() -> Self {
        Self {
            cache_dir: None,
            disk_cache_bytes: 2 << 30,
            request_timeout: Duration::from_secs(30),
            connect_timeout: Duration::from_secs(5),
            retries: 3,
            side_files: Vec::new(),
            side_tables_in_chunks: false,
            side_chunk_bytes: 1 << 20,
        }
    }
}

impl RemoteOptions {
    /// The disk cache folder these options use.
    pub fn cache_folder(&self) -> PathBuf {
        if let Some(d) = &self.cache_dir {
            return d.clone();
        }
        let env = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty()).map(PathBuf::from);
        env("TERRAIN_CACHE_DIR")
            .or_else(|| env("XDG_CACHE_HOME").map(|d| d.join("terrain")))
            .or_else(|| env("HOME").map(|d| d.join(".cache").join("terrain")))
            .unwrap_or_else(|| std::env::temp_dir().join("terrain-cache"))
    }
}

/// A store's location on object storage or HTTP: the client, the key prefix, the runtime.
pub(crate) struct Remote {
    /// The location as given, without a trailing `/`.
    url: String,
    store: Arc<dyn ObjectStore>,
    prefix: ObjectPath,
    runtime: tokio::runtime::Runtime,
    /// The local mirror folder (index, side tables, cached levels).
    mirror: PathBuf,
    disk: DiskCache,
    /// Blocks whose header and object size were checked this session.
    verified: Mutex<std::collections::HashSet<BlockId>>,
    /// Levels fetched by [`Remote::fetch_levels`] not yet taken by [`Remote::level`].
    fetched: Mutex<HashMap<(BlockId, u8), Vec<u8>>>,
    /// Bytes received from the location so far (index, side tables, blocks).
    received: AtomicU64,
    /// [`RemoteOptions::side_chunk_bytes`], when [`RemoteOptions::side_tables_in_chunks`].
    side_chunk: Option<u64>,
}

impl std::fmt::Debug for Remote {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Remote").field("url", &self.url).field("mirror", &self.mirror).finish()
    }
}

fn remote_err(url: &str, message: impl std::fmt::Display) -> StoreError {
    StoreError::Remote { location: url.to_string(), message: message.to_string() }
}

/// The client for `url` (any scheme [`is_url`] accepts) and the key prefix of the store.
fn client_for(
    url: &str,
    options: &RemoteOptions,
) -> Result<(Arc<dyn ObjectStore>, ObjectPath), StoreError> {
    let parsed = url::Url::parse(url).map_err(|e| remote_err(url, format!("not a URL: {e}")))?;
    let client = ClientOptions::new()
        .with_timeout(options.request_timeout)
        .with_connect_timeout(options.connect_timeout);
    let retry = RetryConfig {
        backoff: BackoffConfig {
            init_backoff: Duration::from_millis(100),
            max_backoff: Duration::from_secs(5),
            base: 2.0,
        },
        max_retries: options.retries,
        retry_timeout: options.request_timeout * (options.retries as u32 + 1),
    };
    let env_true = |k: &str| std::env::var(k).is_ok_and(|v| v.eq_ignore_ascii_case("true"));
    let bad = |e: object_store::Error| remote_err(url, e);
    let key_prefix = || ObjectPath::from(parsed.path().trim_matches('/'));
    match parsed.scheme().to_ascii_lowercase().as_str() {
        "s3" | "s3a" => {
            // `with_client_options` replaces the options `from_env` read (AWS_ALLOW_HTTP among
            // them): allow plain HTTP again, explicitly, for an http:// endpoint.
            let endpoint = std::env::var("AWS_ENDPOINT_URL")
                .or_else(|_| std::env::var("AWS_ENDPOINT"))
                .unwrap_or_default();
            let allow_http = env_true("AWS_ALLOW_HTTP") || endpoint.starts_with("http://");
            let b = object_store::aws::AmazonS3Builder::from_env()
                .with_url(url)
                .with_client_options(client)
                .with_retry(retry)
                .with_allow_http(allow_http);
            Ok((Arc::new(b.build().map_err(bad)?), key_prefix()))
        }
        "gs" => {
            // The endpoint is the credentials' `gcs_base_url` (Google's https one by default;
            // an emulator's `http://127.0.0.1:PORT` in the tests). `with_client_options`
            // replaces the builder's own options, whose default allows plain HTTP for such a
            // base URL: allowed again here, else every request fails as a "builder error".
            let b = object_store::gcp::GoogleCloudStorageBuilder::from_env()
                .with_url(url)
                .with_client_options(client.with_allow_http(true))
                .with_retry(retry);
            Ok((Arc::new(b.build().map_err(bad)?), key_prefix()))
        }
        "az" | "azure" | "abfs" | "abfss" => {
            let b = object_store::azure::MicrosoftAzureBuilder::from_env()
                .with_url(url)
                .with_client_options(client)
                .with_retry(retry)
                .with_allow_http(env_true("AZURE_ALLOW_HTTP"));
            Ok((Arc::new(b.build().map_err(bad)?), key_prefix()))
        }
        "http" | "https" => {
            let b = object_store::http::HttpBuilder::new()
                .with_url(url)
                .with_client_options(client.with_allow_http(true))
                .with_retry(retry);
            Ok((Arc::new(b.build().map_err(bad)?), ObjectPath::default()))
        }
        other => Err(remote_err(url, format!("unsupported scheme {other}://"))),
    }
}

fn runtime(url: &str) -> Result<tokio::runtime::Runtime, StoreError> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("terrain-remote")
        .enable_all()
        .build()
        .map_err(|e| remote_err(url, format!("starting the I/O runtime: {e}")))
}

/// A short stable name of a URL for its mirror folder (FNV-1a, 64 bits, and the URL's tail).
fn mirror_name(url: &str) -> String {
    let h =
        terrain_core::checksum::fnv1a_update(terrain_core::checksum::FNV1A_START, url.as_bytes());
    let tail: String = url
        .rsplit('/')
        .find(|s| !s.is_empty())
        .unwrap_or("store")
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '_' { c } else { '_' })
        .take(40)
        .collect();
    format!("{tail}-{h:016x}")
}

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> StoreError + '_ {
    move |cause| StoreError::Io { path: path.to_path_buf(), cause }
}

/// Writes `bytes` to `path` through a temporary file and a rename (readers never see half).
fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    if let Some(p) = path.parent() {
        std::fs::create_dir_all(p)?;
    }
    let tmp = path.with_extension(format!("tmp{}", std::process::id()));
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path)
}

impl Remote {
    /// Opens the store at `url`: fetches its index (a paged one: its header and head only;
    /// returned) and, when the mirror's copy differs, the side tables into the mirror folder.
    pub(crate) fn open(
        url: &str,
        options: &RemoteOptions,
    ) -> Result<(Self, RemoteIndex), StoreError> {
        let url = url.trim_end_matches('/').to_string();
        let (store, prefix) = client_for(&url, options)?;
        let runtime = runtime(&url)?;
        let cache = options.cache_folder();
        let mirror = cache.join(mirror_name(&url));
        // The disk cache is scanned once the mirror is settled (below).
        let disk = DiskCache::open(&cache, 0);
        let mut remote = Self {
            url,
            store,
            prefix,
            runtime,
            mirror,
            disk,
            verified: Mutex::default(),
            fetched: Mutex::default(),
            received: AtomicU64::new(0),
            side_chunk: options.side_tables_in_chunks.then(|| options.side_chunk_bytes.max(4096)),
        };
        let index = remote.fetch_index()?;
        let (mirrored, copy) = match &index {
            RemoteIndex::Whole(bytes) => (remote.mirror.join(INDEX_FILE), &bytes[..]),
            RemoteIndex::Paged { prefix, .. } => (remote.mirror.join(HEAD_FILE), &prefix[..]),
        };
        if std::fs::read(&mirrored).ok().as_deref() != Some(copy) {
            // Another store at this URL (or the first open): nothing cached is valid.
            let mirror = &remote.mirror;
            let _ = std::fs::remove_dir_all(mirror);
            std::fs::create_dir_all(mirror).map_err(io_err(mirror))?;
            let _ = std::fs::write(mirror.join("url.txt"), format!("{}\n", remote.url));
            for name in &options.side_files {
                remote.mirror_file(name)?;
            }
            // The index last: a mirror with an index has its eager side tables (the others
            // come when first asked for).
            write_atomic(&mirrored, copy).map_err(io_err(&mirrored))?;
        }
        remote.disk = DiskCache::open(&cache, options.disk_cache_bytes);
        Ok((remote, index))
    }

    /// Fetches the store's file `name` whole into the mirror (one GET), unless the mirror has
    /// it: whether the store has one.
    pub(crate) fn mirror_file(&self, name: &str) -> Result<bool, StoreError> {
        let path = self.mirror.join(name);
        if path.is_file() {
            return Ok(true);
        }
        match self.get(&self.prefix.child(name), None) {
            Ok((bytes, _)) => {
                write_atomic(&path, &bytes).map_err(io_err(&path))?;
                Ok(true)
            }
            Err(object_store::Error::NotFound { .. }) => Ok(false),
            Err(e) => Err(remote_err(&self.url, format!("reading {name}: {e}"))),
        }
    }

    /// Whether the store has the file `name` beside its index: the mirror's copy, else one
    /// HEAD request (nothing is fetched).
    pub(crate) fn has_file(&self, name: &str) -> Result<bool, StoreError> {
        Ok(self.mirror.join(name).is_file() || self.file_size(name)?.is_some())
    }

    /// The size of the store's file `name` by one HEAD request (nothing fetched; counted as
    /// no bytes), `None` when there is none.
    pub(crate) fn file_size(&self, name: &str) -> Result<Option<u64>, StoreError> {
        let key = self.prefix.child(name);
        match self.runtime.block_on(self.store.head(&key)) {
            Ok(meta) => Ok(Some(meta.size)),
            Err(object_store::Error::NotFound { .. }) => Ok(None),
            Err(e) => Err(remote_err(&self.url, format!("asking for {name}: {e}"))),
        }
    }

    /// Bytes `range` of the store's file `name`, by one range GET (counted in
    /// [`Remote::bytes_received`]); fewer bytes than asked for is an error.
    pub(crate) fn read_range(
        &self,
        name: &str,
        range: std::ops::Range<u64>,
    ) -> Result<Vec<u8>, StoreError> {
        let (at, end) = (range.start, range.end);
        let failed =
            |e: String| remote_err(&self.url, format!("reading bytes {at}..{end} of {name}: {e}"));
        let (bytes, _) =
            self.get(&self.prefix.child(name), Some(range)).map_err(|e| failed(e.to_string()))?;
        if bytes.len() as u64 != end - at {
            return Err(failed(format!("{} bytes came", bytes.len())));
        }
        Ok(bytes)
    }

    /// One GET of `key` (`range`: those bytes only): the bytes and the object's size, counted
    /// in [`Remote::bytes_received`].
    fn get(
        &self,
        key: &ObjectPath,
        range: Option<std::ops::Range<u64>>,
    ) -> Result<(Vec<u8>, u64), object_store::Error> {
        let opts = GetOptions { range: range.map(GetRange::Bounded), ..Default::default() };
        let (bytes, size) = self.runtime.block_on(async {
            let r = self.store.get_opts(key, opts).await?;
            let size = r.meta.size;
            Ok::<_, object_store::Error>((r.bytes().await?, size))
        })?;
        self.received.fetch_add(bytes.len() as u64, Ordering::Relaxed);
        Ok((bytes.to_vec(), size))
    }

    /// The index: its first [`INDEX_PROBE`] bytes, then a paged index's rest of the head or an
    /// older index's rest.
    fn fetch_index(&self) -> Result<RemoteIndex, StoreError> {
        let key = self.prefix.child(INDEX_FILE);
        let failed = |e: object_store::Error| match e {
            object_store::Error::NotFound { .. } => remote_err(
                &self.url,
                format!(
                    "{INDEX_FILE} is not there: not a terrain store (bake one with `terrain bake -o URL`)"
                ),
            ),
            e => remote_err(&self.url, format!("reading {INDEX_FILE}: {e}")),
        };
        let (mut bytes, size) = self.get(&key, Some(0..INDEX_PROBE)).map_err(failed)?;
        let version = bytes.get(8..12).map(|v| u32::from_le_bytes([v[0], v[1], v[2], v[3]]));
        if bytes.len() >= 12
            && bytes[..8] == MAGIC
            && version.is_some_and(|v| v >= PAGED_INDEX_VERSION)
        {
            // The header's length is known once read; the head's from the header.
            let header = loop {
                match read_header(&mut Reader::new(&bytes[12..])) {
                    Ok(h) => break h,
                    Err(_) if (bytes.len() as u64) < size => {
                        let have = bytes.len() as u64;
                        let more = (2 * have).min(size);
                        bytes.extend(self.get(&key, Some(have..more)).map_err(failed)?.0);
                    }
                    Err(e) => {
                        let path = PathBuf::from(format!("{}/{INDEX_FILE}", self.url));
                        return Err(crate::pages::index_err(e, &path));
                    }
                }
            };
            let want = crate::pages::paged_prefix_len(&header) as u64;
            if want > size {
                return Err(StoreError::CorruptIndex {
                    path: PathBuf::from(format!("{}/{INDEX_FILE}", self.url)),
                    message: format!("{size} bytes, shorter than its head ({want})"),
                });
            }
            let have = bytes.len() as u64;
            if want > have {
                bytes.extend(self.get(&key, Some(have..want)).map_err(failed)?.0);
            }
            bytes.truncate(want as usize);
            return Ok(RemoteIndex::Paged { prefix: bytes, size });
        }
        let have = bytes.len() as u64;
        if size > have {
            // An older index is fetched whole; the mirror's copy of it serves when it is the
            // object's: the same length, the same first bytes (the header, whose bake id
            // hashes every block level's CRC-32) and its own CRC-32 intact.
            if let Some(copy) = self.mirrored_index(&bytes, size) {
                return Ok(RemoteIndex::Whole(copy));
            }
            bytes.extend(self.get(&key, Some(have..size)).map_err(failed)?.0);
        }
        Ok(RemoteIndex::Whole(bytes))
    }

    /// The mirror's copy of a whole (version 2-3) index whose object is `size` bytes and
    /// starts with `probe`, if it is that object's (see [`Remote::fetch_index`]).
    fn mirrored_index(&self, probe: &[u8], size: u64) -> Option<Vec<u8>> {
        // The whole header (with its bake id) must be in what the first GET brought.
        read_header(&mut Reader::new(probe.get(12..)?)).ok()?;
        let path = self.mirror.join(INDEX_FILE);
        if std::fs::metadata(&path).ok()?.len() != size {
            return None;
        }
        let copy = std::fs::read(&path).ok()?;
        let (body, tail) = copy.split_at_checked(copy.len().checked_sub(4)?)?;
        let stored = u32::from_le_bytes(tail.try_into().ok()?);
        (copy.starts_with(probe) && crate::format::crc32(body) == stored).then_some(copy)
    }

    /// Page `page` of a paged index (`at..at + len` of the object): the mirror's copy if
    /// `check` (its CRC-32) accepts it, else fetched by a range GET, checked and kept. A fetched
    /// page that fails `check` is a [`StoreError::IndexPage`] naming the URL (`blocks`: its
    /// blocks' positions, for the message).
    pub(crate) fn index_page(
        &self,
        page: usize,
        (at, len): (u64, u64),
        blocks: (usize, usize),
        check: impl Fn(&[u8]) -> Result<(), String>,
    ) -> Result<Vec<u8>, StoreError> {
        let cached = self.mirror.join(PAGES_DIR).join(format!("p{page:08}"));
        if let Ok(b) = std::fs::read(&cached)
            && b.len() as u64 == len
            && check(&b).is_ok()
        {
            return Ok(b);
        }
        let path = PathBuf::from(format!("{}/{INDEX_FILE}", self.url));
        let bad =
            |message: String| StoreError::IndexPage { path: path.clone(), page, blocks, message };
        let key = self.prefix.child(INDEX_FILE);
        let (bytes, _) = self
            .get(&key, Some(at..at + len))
            .map_err(|e| bad(format!("fetching bytes {at}..{}: {e}", at + len)))?;
        if bytes.len() as u64 != len {
            return Err(bad(format!("{} bytes fetched of {len}", bytes.len())));
        }
        check(&bytes).map_err(bad)?;
        // A cache that cannot be written is only slower.
        let _ = write_atomic(&cached, &bytes);
        Ok(bytes)
    }

    /// The chunk a side table read where it lies is fetched in; `None`: side tables are
    /// fetched whole ([`RemoteOptions`]).
    pub(crate) fn side_chunk(&self) -> Option<u64> {
        self.side_chunk
    }

    /// Bytes received from the location so far (index, side tables, blocks).
    pub(crate) fn bytes_received(&self) -> u64 {
        self.received.load(Ordering::Relaxed)
    }

    /// The location, without a trailing `/`.
    pub(crate) fn url(&self) -> &str {
        &self.url
    }

    /// The local mirror folder.
    pub(crate) fn mirror(&self) -> &Path {
        &self.mirror
    }

    /// The URL of a block's file (for messages).
    pub(crate) fn block_url(&self, id: BlockId) -> PathBuf {
        PathBuf::from(format!("{}/{}", self.url, block_file_name(id)))
    }

    fn cache_path(&self, id: BlockId, level: u8) -> PathBuf {
        self.mirror.join(format!("{}.L{level}", block_file_name(id)))
    }

    /// Fetches levels `first..=last` of block `id` (from the first not in memory nor in the disk
    /// cache) in one range GET ([`Remote::get_levels`]) and keeps the payloads for
    /// [`Remote::level`] (memory, and the disk cache). CRCs are checked when the levels are
    /// taken.
    pub(crate) fn fetch_levels(
        &self,
        id: BlockId,
        entry: &BlockEntry,
        first: u8,
        last: u8,
        bake_id: u64,
    ) -> Result<(), StoreError> {
        let last = last.min(entry.levels.len().saturating_sub(1) as u8);
        let Some(first) = (first..=last).find(|&l| {
            !self.fetched.lock().expect("fetched").contains_key(&(id, l))
                && !self.disk.contains(&self.cache_path(id, l))
        }) else {
            return Ok(());
        };
        let payloads = self.get_levels(id, entry, first, last, bake_id)?;
        let mut fetched = self.fetched.lock().expect("fetched");
        if fetched.len() > 4096 {
            fetched.clear();
        }
        for (l, payload) in payloads {
            self.disk.put(&self.cache_path(id, l), &payload);
            fetched.insert((id, l), payload);
        }
        Ok(())
    }

    /// Levels `first..=last` of block `id` in one range GET (the block header and object size
    /// checked on the block's first request): each level's payload, not yet CRC-checked.
    fn get_levels(
        &self,
        id: BlockId,
        entry: &BlockEntry,
        first: u8,
        last: u8,
        bake_id: u64,
    ) -> Result<Vec<(u8, Vec<u8>)>, StoreError> {
        let verified = self.verified.lock().expect("verified").contains(&id);
        let levels = &entry.levels[first as usize..=last as usize];
        let start = if verified { levels[0].offset } else { 0 };
        let end = levels.iter().map(|l| l.offset + u64::from(l.len)).max().unwrap_or(start);
        let key =
            self.prefix.child("blocks").child(block_file_name(id).trim_start_matches("blocks/"));
        let path = self.block_url(id);
        let opts = GetOptions { range: Some(GetRange::Bounded(start..end)), ..Default::default() };
        let got = self.runtime.block_on(async {
            let r = self.store.get_opts(&key, opts).await?;
            let size = r.meta.size;
            Ok::<_, object_store::Error>((size, r.bytes().await?))
        });
        if let Ok((_, b)) = &got {
            self.received.fetch_add(b.len() as u64, Ordering::Relaxed);
        }
        let (size, bytes) = got.map_err(|e| match e {
            object_store::Error::NotFound { .. } => {
                StoreError::MissingBlock { path: path.clone(), block: id, level: first }
            }
            e => StoreError::RemoteBlock {
                location: path.display().to_string(),
                block: id,
                level: first,
                message: e.to_string(),
            },
        })?;
        if size < entry.file_len || (bytes.len() as u64) < end - start {
            return Err(StoreError::Truncated {
                path,
                block: id,
                level: first,
                expected: entry.file_len,
                got: size.min(start + bytes.len() as u64),
            });
        }
        if size != entry.file_len {
            return Err(StoreError::Changed {
                path,
                block: id,
                level: first,
                message: format!("{size} bytes, the index says {}", entry.file_len),
            });
        }
        if !verified {
            crate::store::check_block_header(
                &bytes[..BLOCK_HEADER_LEN as usize],
                &path,
                id,
                first,
                bake_id,
            )?;
            self.verified.lock().expect("verified").insert(id);
        }
        Ok((first..=last)
            .zip(levels)
            .map(|(l, le)| {
                let a = (le.offset - start) as usize;
                (l, bytes[a..a + le.len as usize].to_vec())
            })
            .collect())
    }

    /// The payload of `level` of block `id`: fetched by the last [`Remote::fetch_levels`], from
    /// the disk cache, or fetched now. `crc` is the index's: a cached copy that fails it is
    /// dropped and fetched again.
    pub(crate) fn level(
        &self,
        id: BlockId,
        entry: &BlockEntry,
        level: u8,
        bake_id: u64,
    ) -> Result<(Vec<u8>, bool), StoreError> {
        let crc = entry.levels[level as usize].crc32;
        if let Some(p) = self.fetched.lock().expect("fetched").remove(&(id, level)) {
            return Ok((p, true));
        }
        let cached = self.cache_path(id, level);
        if let Some(p) = self.disk.get(&cached) {
            if crate::format::crc32(&p) == crc {
                return Ok((p, false));
            }
            self.disk.remove(&cached);
        }
        // Not at hand: never fetched, evicted, or fetched by this thread and taken by another
        // reading the same level since (the disk cache then said it was there when this
        // thread's fetch looked, so that fetch skipped it). Fetched now, for this call alone.
        let (_, payload) = self
            .get_levels(id, entry, level, level, bake_id)?
            .pop()
            .expect("one level asked, one level got");
        self.disk.put(&cached, &payload);
        Ok((payload, true))
    }
}

/// The disk cache of block levels: files under the cache folder, least recently used evicted
/// first above a byte limit (shared by every store of the folder; access order from the
/// files' modification times at open, then this process's reads and writes).
struct DiskCache {
    limit: u64,
    state: Mutex<LruState>,
}

#[derive(Default)]
struct LruState {
    clock: u64,
    total: u64,
    files: HashMap<PathBuf, (u64, u64)>,
}

impl DiskCache {
    fn open(root: &Path, limit: u64) -> Self {
        let mut found = Vec::new();
        if limit > 0
            && let Ok(stores) = std::fs::read_dir(root)
        {
            for s in stores.flatten() {
                let Ok(blocks) = std::fs::read_dir(s.path().join("blocks")) else { continue };
                for f in blocks.flatten() {
                    let Ok(m) = f.metadata() else { continue };
                    if m.is_file() {
                        let t = m.modified().unwrap_or(SystemTime::UNIX_EPOCH);
                        found.push((t, f.path(), m.len()));
                    }
                }
            }
        }
        found.sort();
        let mut state = LruState::default();
        for (_, p, len) in found {
            state.clock += 1;
            state.total += len;
            state.files.insert(p, (len, state.clock));
        }
        let cache = Self { limit, state: Mutex::new(state) };
        cache.evict();
        cache
    }

    fn contains(&self, p: &Path) -> bool {
        self.limit > 0 && self.state.lock().expect("disk cache").files.contains_key(p)
    }

    fn get(&self, p: &Path) -> Option<Vec<u8>> {
        if !self.contains(p) {
            return None;
        }
        match std::fs::read(p) {
            Ok(b) => {
                let mut s = self.state.lock().expect("disk cache");
                s.clock += 1;
                let c = s.clock;
                if let Some(e) = s.files.get_mut(p) {
                    e.1 = c;
                }
                if let Ok(f) = std::fs::File::options().write(true).open(p) {
                    let _ = f.set_modified(SystemTime::now());
                }
                Some(b)
            }
            Err(_) => {
                self.remove(p);
                None
            }
        }
    }

    fn put(&self, p: &Path, bytes: &[u8]) {
        if self.limit == 0 || bytes.len() as u64 > self.limit || write_atomic(p, bytes).is_err() {
            return;
        }
        {
            let mut s = self.state.lock().expect("disk cache");
            s.clock += 1;
            let c = s.clock;
            let len = bytes.len() as u64;
            if let Some((old, _)) = s.files.insert(p.to_path_buf(), (len, c)) {
                s.total -= old;
            }
            s.total += len;
        }
        self.evict();
    }

    fn remove(&self, p: &Path) {
        let mut s = self.state.lock().expect("disk cache");
        if let Some((len, _)) = s.files.remove(p) {
            s.total -= len;
        }
        let _ = std::fs::remove_file(p);
    }

    fn evict(&self) {
        let mut s = self.state.lock().expect("disk cache");
        if s.total <= self.limit {
            return;
        }
        let mut by_age: Vec<(u64, PathBuf, u64)> =
            s.files.iter().map(|(p, &(len, t))| (t, p.clone(), len)).collect();
        by_age.sort();
        for (_, p, len) in by_age {
            if s.total <= self.limit {
                break;
            }
            let _ = std::fs::remove_file(&p);
            s.files.remove(&p);
            s.total -= len;
        }
    }
}

/// Before a bake to `url`: refuses to replace what is there, as [`crate::check_output`] refuses
/// a local folder. A store at the URL (an `index.tsi` object with the store's magic) is
/// [`BakeError::Exists`] unless `overwrite`; other objects under the URL's prefix (a prefix
/// that is not a store, or a store whose upload stopped before its index) are
/// [`BakeError::NotAStore`], even with `overwrite` (they may be the user's); nothing there is
/// fine. An `http(s)://` location is refused (a web server is read-only here: serve a baked
/// folder instead). Server errors are [`BakeError::Remote`] naming the URL.
pub fn check_remote_output(
    url: &str,
    overwrite: bool,
    options: &RemoteOptions,
) -> Result<(), BakeError> {
    let url = url.trim_end_matches('/');
    let bad = |message: String| BakeError::Remote { location: url.to_string(), message };
    if url
        .split_once("://")
        .is_some_and(|(s, _)| s.eq_ignore_ascii_case("http") || s.eq_ignore_ascii_case("https"))
    {
        return Err(bad(
            "an HTTP server is read-only: bake to a folder (or s3://, gs://, az://) and serve it"
                .into(),
        ));
    }
    let (store, prefix) = client_for(url, options).map_err(|e| bad(e.to_string()))?;
    let runtime = runtime(url).map_err(|e| bad(e.to_string()))?;
    let index_key = prefix.child(INDEX_FILE);
    let magic = runtime.block_on(async {
        match store
            .get_opts(
                &index_key,
                GetOptions { range: Some(GetRange::Bounded(0..8)), ..Default::default() },
            )
            .await
        {
            Ok(r) => Ok(Some(r.bytes().await?)),
            Err(object_store::Error::NotFound { .. }) => Ok(None),
            Err(e) => Err(e),
        }
    });
    let path = || PathBuf::from(url);
    match magic.map_err(|e| bad(format!("checking for a store ({INDEX_FILE}): {e}")))? {
        Some(m) if m.as_ref() == MAGIC => {
            return if overwrite { Ok(()) } else { Err(BakeError::Exists { path: path() }) };
        }
        Some(_) => {
            return Err(BakeError::NotAStore {
                path: path(),
                what: format!("holds an {INDEX_FILE} that is not a store's index"),
            });
        }
        None => {}
    }
    // Anything else under the prefix (objects, or folders of objects).
    let listed = runtime
        .block_on(store.list_with_delimiter(Some(&prefix)))
        .map_err(|e| bad(format!("listing what is there: {e}")))?;
    let first = listed.objects.first().map(|o| &o.location).or(listed.common_prefixes.first());
    if let Some(first) = first {
        return Err(BakeError::NotAStore {
            path: path(),
            what: format!(
                "holds objects ({first} among them) and no {INDEX_FILE}: not a store, or a store \
                 whose upload stopped before its index"
            ),
        });
    }
    Ok(())
}

/// What [`upload_store`] sent.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct UploadReport {
    /// Files uploaded.
    pub files: usize,
    /// Bytes uploaded.
    pub bytes: u64,
    /// Of those files, the ones sent as multipart uploads (above [`MULTIPART_ABOVE`]).
    pub multipart: usize,
}

/// Uploads the store folder `dir` (every file, recursively) to `url`: block files and tables
/// first, the index **last**, so a reader never sees an index whose blocks are not all there
/// (an index already at the URL is deleted before anything is uploaded).
/// Files above [`MULTIPART_ABOVE`] go as multipart uploads, read a part at a time (two parts
/// in flight per file), so memory does not grow with a file's size. Retries and timeouts as
/// `options` says.
pub fn upload_store(
    dir: &Path,
    url: &str,
    options: &RemoteOptions,
) -> Result<UploadReport, StoreError> {
    let url = url.trim_end_matches('/');
    let (store, prefix) = client_for(url, options)?;
    let runtime = runtime(url)?;
    let mut files = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).map_err(io_err(&d))? {
            let p = e.map_err(io_err(&d))?.path();
            if p.is_dir() {
                stack.push(p);
            } else {
                files.push(p);
            }
        }
    }
    files.sort();
    let mut report = UploadReport::default();
    // A store being replaced (`--overwrite`) loses its index first: a reader sees no store
    // while the new blocks go up, never the old index over new blocks.
    let old_index = prefix.child(INDEX_FILE);
    match runtime.block_on(store.delete(&old_index)) {
        Ok(()) | Err(object_store::Error::NotFound { .. }) => {}
        Err(e) => return Err(remote_err(url, format!("removing the old {INDEX_FILE}: {e}"))),
    }
    let (index, rest): (Vec<PathBuf>, Vec<PathBuf>) = files
        .into_iter()
        .partition(|p| p.strip_prefix(dir).is_ok_and(|r| r == Path::new(INDEX_FILE)));
    for batch in [rest, index] {
        for chunk in batch.chunks(16) {
            let mut tasks = Vec::new();
            for p in chunk {
                let rel = p.strip_prefix(dir).expect("under dir");
                let key = rel
                    .components()
                    .fold(prefix.clone(), |k, c| k.child(&*c.as_os_str().to_string_lossy()));
                let len = std::fs::metadata(p).map_err(io_err(p))?.len();
                report.files += 1;
                report.bytes += len;
                let multipart = len > MULTIPART_ABOVE as u64;
                report.multipart += usize::from(multipart);
                // A file up to the threshold is read whole; a larger one a part at a time, at
                // most two parts in flight, so a table of any size costs a few parts of memory.
                let whole =
                    if multipart { None } else { Some(std::fs::read(p).map_err(io_err(p))?) };
                let store = store.clone();
                let name = rel.display().to_string();
                let path = p.clone();
                tasks.push(runtime.spawn(async move {
                    let r: Result<(), String> = async {
                        let e = |e: object_store::Error| e.to_string();
                        match whole {
                            Some(bytes) => {
                                store.put(&key, PutPayload::from(bytes)).await.map_err(e)?;
                            }
                            None => {
                                let upload = store.put_multipart(&key).await.map_err(e)?;
                                let mut w =
                                    WriteMultipart::new_with_chunk_size(upload, MULTIPART_ABOVE);
                                let mut file = std::fs::File::open(&path)
                                    .map_err(|e| format!("reading {}: {e}", path.display()))?;
                                let mut part = Vec::with_capacity(MULTIPART_ABOVE);
                                loop {
                                    // The next part: `MULTIPART_ABOVE` bytes, fewer at the end.
                                    part.clear();
                                    (&mut file)
                                        .take(MULTIPART_ABOVE as u64)
                                        .read_to_end(&mut part)
                                        .map_err(|e| format!("reading {}: {e}", path.display()))?;
                                    if part.is_empty() {
                                        break;
                                    }
                                    w.wait_for_capacity(2).await.map_err(e)?;
                                    w.write(&part);
                                }
                                w.finish().await.map_err(e)?;
                            }
                        }
                        Ok(())
                    }
                    .await;
                    r.map_err(|m| format!("uploading {name}: {m}"))
                }));
            }
            for t in tasks {
                runtime
                    .block_on(t)
                    .map_err(|e| remote_err(url, format!("upload task: {e}")))?
                    .map_err(|m| remote_err(url, m))?;
            }
        }
    }
    Ok(report)
}
