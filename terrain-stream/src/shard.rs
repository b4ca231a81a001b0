//! Sharded bakes: shard `K` of `N` bakes a contiguous, disjoint range of block rows into a
//! *part* folder ([`bake_shard`]); [`merge`] joins the `N` parts into a store that is byte for
//! byte the store a single [`crate::bake`] of the same source and config writes.
//!
//! Why it is byte-identical: a block's file and entry depend only on the block's own samples
//! and the config, never on its neighbours' blocks or the bake's order, so the shards write the
//! same block files (with a bake id of 0) and entries as the single bake; the store-wide
//! values are reductions the merge computes from the parts exactly (the largest errors, the
//! `lossless` flag) or from the entries in row-major order (the bake id, an FNV-1a hash of
//! every level's checksum), and the index is then written by the same function.
//!
//! A part is a folder published atomically like a store (written as `.NAME.part`, renamed
//! when complete), holding `blocks/` and [`PART_FILE`]: the shard `K/N` and its block rows, the
//! caller's identity of the source (a DEM's size and checksum) and the bake options, the
//! grid's header, and the entries of its blocks, with a trailing CRC-32. A shard that died
//! left no part (only its `.NAME.part` folder, which its re-run removes), so re-running that
//! shard alone is enough; the merge reads the parts and never changes them.

use std::fmt;
use std::fs;
use std::ops::{ControlFlow, Range};
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::time::{Duration, Instant};

use rayon::prelude::*;

use terrain_core::lod::GeomipTable;
use terrain_core::lod::dss_file::{HEIGHTS_CHECKSUM_BYTES, HeightsChecksum};
use terrain_core::lod::geomip_file::GeomipFor;

use crate::bake::{
    BakeConfig, BakeProgress, BakeReport, BakedRows, GEOMIP_FILE, GeomipOut, Plan, bake_rows,
    index_file, publish,
};
use crate::decimation::DecimationOut;
use crate::entries::EntryFile;
use crate::error::BakeError;
use crate::format::{
    BLOCK_HEADER_LEN, BlockEntry, Header, IndexError, Reader, Writer, block_file_name, crc32,
    entry_len, fine_count, read_entry, read_header, write_header,
};
use crate::source::HeightSource;
use terrain_core::checksum::crc32_update;

/// Name of the part file inside a part folder.
pub const PART_FILE: &str = "part.tsp";
const PART_MAGIC: [u8; 8] = *b"TSTRPRT\0";
const PART_VERSION: u32 = 2;

/// Shard `index` of `count` (`index` counts from 0, as a Kubernetes Indexed Job's
/// `JOB_COMPLETION_INDEX` does). Written and parsed as `K/N`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Shard {
    /// `K`, in `0..count`.
    pub index: u32,
    /// `N`, at least 1.
    pub count: u32,
}

impl Shard {
    /// Shard `index` of `count`; refuses `count == 0` and `index >= count`.
    pub fn new(index: u32, count: u32) -> Result<Self, BakeError> {
        if count == 0 || index >= count {
            return Err(BakeError::InvalidConfig(format!(
                "shard {index}/{count}: K/N needs N >= 1 and K in 0..N (K counts from 0)"
            )));
        }
        Ok(Self { index, count })
    }

    /// The block rows this shard bakes out of `blocks_y`: `K * rows / N .. (K + 1) * rows / N`,
    /// contiguous so a shard reads only its own bands of the source. Empty when there are
    /// fewer rows than shards.
    pub fn rows(&self, blocks_y: u64) -> Range<u64> {
        let (k, n) = (self.index as u64, self.count as u64);
        k * blocks_y / n..(k + 1) * blocks_y / n
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl FromStr for Shard {
    type Err = BakeError;

    /// `K/N`, e.g. `0/4` for the first of four shards.
    fn from_str(s: &str) -> Result<Self, BakeError> {
        let bad = || BakeError::InvalidConfig(format!("shard {s:?}: expected K/N, e.g. 0/4"));
        let (k, n) = s.split_once('/').ok_or_else(bad)?;
        Shard::new(k.trim().parse().map_err(|_| bad())?, n.trim().parse().map_err(|_| bad())?)
    }
}

/// The bake options a part records, in words: every [`BakeConfig`] field that changes the
/// bytes (not `threads` nor `overwrite`).
pub fn bake_options(config: &BakeConfig) -> String {
    format!(
        "k {}, {:?}, {:?}, {} node levels, DSS errors {}, geomorph table {}",
        config.k,
        config.encoding,
        config.codec,
        config.node_levels,
        if config.dss_errors { "on" } else { "off" },
        match config.geomip_patch_cells {
            Some(p) => format!("of {}-cell patches", GeomipTable::patch_cells_for(p)),
            None => "off".into(),
        }
    )
}

/// What one shard baked.
#[derive(Debug, Clone)]
pub struct ShardReport {
    /// The shard.
    pub shard: Shard,
    /// Its block rows.
    pub rows: Range<u64>,
    /// Blocks baked.
    pub blocks: usize,
    /// Bytes of its block files.
    pub bytes: u64,
    /// Wall time.
    pub elapsed: Duration,
}

/// What a part folder holds (its [`PART_FILE`], checked).
#[derive(Debug, Clone)]
pub struct PartInfo {
    /// The part folder.
    pub path: PathBuf,
    /// Its shard.
    pub shard: Shard,
    /// Its block rows.
    pub rows: Range<u64>,
    /// The caller's identity of the source (`bake_shard`'s `source_id`).
    pub source_id: String,
    /// The bake options ([`bake_options`]).
    pub options: String,
    /// The grid's header, with this part's own largest errors and a bake id of 0.
    pub header: Header,
    lossless: bool,
    bound: Option<f64>,
    /// Its block entries, never held whole (a 32769^2 grid's are 120 MB): their count, the
    /// bytes of their block files, and where they start in the part file.
    blocks: usize,
    block_bytes: u64,
    entries_at: u64,
    /// The part file's CRC-32 as checked when it was read.
    crc: u32,
    /// Geomorph's table of the part's rows: its patch cells and the rows' heights checksum
    /// (the table itself is the part's [`GEOMIP_FILE`], of the part's rows as a grid).
    geomip: Option<(u32, HeightsChecksum)>,
}

impl PartInfo {
    /// Blocks in the part.
    pub fn blocks(&self) -> usize {
        self.blocks
    }
}

/// Bakes shard `shard` of `source` into the part folder `part` (published atomically; an
/// existing part is replaced only with `config.overwrite`). `source_id` names the source (a
/// DEM's name, size and checksum): the merge refuses parts whose ids differ.
pub fn bake_shard(
    source: &dyn HeightSource,
    part: &Path,
    config: &BakeConfig,
    shard: Shard,
    source_id: &str,
    progress: &mut (dyn FnMut(&BakeProgress) -> ControlFlow<()> + Send),
) -> Result<ShardReport, BakeError> {
    let start = Instant::now();
    let shard = Shard::new(shard.index, shard.count)?;
    let plan = Plan::new(source, config)?;
    let rows = shard.rows(plan.blocks_y);
    let options = bake_options(config);
    publish(part, config.overwrite, config.threads, is_part, |tmp| {
        // The part file, its entries written as the blocks finish, its prefix last.
        let header = plan.header(source);
        let blocks = ((rows.end - rows.start) * plan.blocks_x) as usize;
        let prefix = part_prefix(shard, &rows, source_id, &options, true, None, &header, blocks);
        let entries = EntryFile::create(tmp.join(PART_FILE), prefix.len())?;
        let mut baked = bake_rows(source, tmp, &plan, config, rows.clone(), entries, progress)?;
        // Geomorph's table of the shard's rows, as a grid of their own.
        let geomip = match (baked.geomip.take(), plan.geomip) {
            (Some((out, heights)), Some(p)) => {
                out.finish(HeightsChecksum::new().finish())?;
                Some((p, heights))
            }
            _ => None,
        };
        // The decimation errors of the shard's blocks, its first block's position recorded.
        if let Some(table) = baked.decimation.take() {
            table.finish(0, rows.start * plan.blocks_x)?;
        }
        let BakedRows { header, entries, lossless, bound, .. } = baked;
        let (blocks, bytes) = (entries.count(), entries.block_bytes());
        let prefix =
            part_prefix(shard, &rows, source_id, &options, lossless, bound, &header, blocks);
        entries.finish(&prefix, &part_tail(&geomip))?;
        Ok(ShardReport { shard, rows: rows.clone(), blocks, bytes, elapsed: start.elapsed() })
    })
}

/// Whether `path` is a part folder (it holds a [`PART_FILE`] with the part's magic).
pub fn is_part(path: &Path) -> bool {
    use std::io::Read;
    let mut magic = [0u8; 8];
    path.is_dir()
        && fs::File::open(path.join(PART_FILE)).and_then(|mut f| f.read_exact(&mut magic)).is_ok()
        && magic == PART_MAGIC
}

/// The parts `path` names: itself when it is a part, else the parts among its sub-folders
/// (sorted by name; hidden `.NAME.part` folders of unfinished bakes are skipped). A folder that
/// is neither, or holds no part, is an error.
pub fn find_parts(path: &Path) -> Result<Vec<PathBuf>, BakeError> {
    if is_part(path) {
        return Ok(vec![path.to_path_buf()]);
    }
    let bad = |reason: &str| BakeError::BadPart { path: path.to_path_buf(), reason: reason.into() };
    if !path.is_dir() {
        return Err(bad("not a shard's part folder nor a folder of parts"));
    }
    let dir =
        fs::read_dir(path).map_err(|cause| BakeError::Io { path: path.to_path_buf(), cause })?;
    let mut parts: Vec<PathBuf> = dir
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| !p.file_name().is_some_and(|n| n.to_string_lossy().starts_with('.')))
        .filter(|p| is_part(p))
        .collect();
    parts.sort();
    if parts.is_empty() {
        return Err(bad("a folder with no shard's part in it (none has a part.tsp)"));
    }
    Ok(parts)
}

/// A part file's bytes before its block entries: magic, version, shard and rows, source id and
/// options, the encoding's verdict, the header, the number of entries. Its length does not
/// depend on the values known only at the end (`lossless`, `bound`, the header's errors).
#[allow(clippy::too_many_arguments)]
fn part_prefix(
    shard: Shard,
    rows: &Range<u64>,
    source_id: &str,
    options: &str,
    lossless: bool,
    bound: Option<f64>,
    header: &Header,
    entries: usize,
) -> Vec<u8> {
    let mut w = Writer::default();
    w.bytes(&PART_MAGIC);
    w.u32(PART_VERSION);
    w.u32(shard.index);
    w.u32(shard.count);
    w.u64(rows.start);
    w.u64(rows.end);
    for s in [source_id, options] {
        w.u32(s.len() as u32);
        w.bytes(s.as_bytes());
    }
    w.u8(lossless as u8);
    w.u8(bound.is_some() as u8);
    w.f64(bound.unwrap_or(0.0));
    write_header(&mut w, header);
    w.u64(entries as u64);
    w.buf
}

/// A part file's bytes after its block entries (before its CRC-32): geomorph's table's patch
/// cells and the rows' heights checksum, if computed.
fn part_tail(geomip: &Option<(u32, HeightsChecksum)>) -> Vec<u8> {
    let mut w = Writer::default();
    w.u8(geomip.is_some() as u8);
    if let Some((p, heights)) = geomip {
        w.u32(*p);
        w.bytes(&heights.to_bytes());
    }
    w.buf
}

/// Reads and checks the part folder `part`: its file's magic, version, checksum, and that its
/// entries are its shard's rows of the grid.
pub fn read_part(part: &Path) -> Result<PartInfo, BakeError> {
    let bad = |reason: String| BakeError::BadPart { path: part.to_path_buf(), reason };
    let mut file = PartFile::open(part)?;
    // The checksum first, so a damaged file is said to be damaged, whatever byte it hit.
    let crc = file.checksum()?;
    let body_len = file.body_len;
    // The prefix, up to the entry count: a few hundred bytes plus the georeference's text.
    let mut head = Vec::new();
    let (mut info, n) = loop {
        let want = (head.len().max(4096) * 2).min(body_len as usize);
        head.resize(want, 0);
        file.read_at(0, &mut head)?;
        match parse_prefix(part, &head) {
            Ok(parsed) => break parsed,
            // Cut short by our read, not by the file: read more of it.
            Err(PrefixError::Short) if want < body_len as usize => continue,
            Err(PrefixError::Short) => {
                return Err(bad(format!("{PART_FILE}: cut short before its block entries")));
            }
            Err(PrefixError::Bad(m)) => return Err(bad(format!("{PART_FILE}: {m}"))),
        }
    };
    // The entries, a batch at a time: each is checked, then dropped.
    let mut block_bytes = 0;
    file.entries(&info, n, ENTRY_BATCH, &mut |batch| {
        block_bytes += batch.iter().map(|e| e.file_len).sum::<u64>();
        Ok(())
    })?;
    info.blocks = n as usize;
    info.block_bytes = block_bytes;
    // The tail: geomorph's table's patch cells and the rows' heights checksum, if any.
    let tail_at = info.entries_at + n * entry_len(&info.header, info.fine()) as u64;
    let mut tail = vec![0; (body_len - tail_at.min(body_len)) as usize];
    file.read_at(tail_at, &mut tail)?;
    let mut r = Reader::new(&tail);
    let parse_tail = |r: &mut Reader<'_>| -> Result<Option<(u32, HeightsChecksum)>, String> {
        let geomip = match r.u8()? {
            0 => None,
            _ => {
                let p = r.u32()?;
                let state: &[u8; HEIGHTS_CHECKSUM_BYTES] =
                    r.take(HEIGHTS_CHECKSUM_BYTES)?.try_into().map_err(|_| "checksum state")?;
                Some((p, HeightsChecksum::from_bytes(state)))
            }
        };
        if r.remaining() != 0 {
            return Err(format!("{} bytes after the last entry", r.remaining()));
        }
        Ok(geomip)
    };
    info.geomip = parse_tail(&mut r).map_err(|m| bad(format!("{PART_FILE}: {m}")))?;
    info.crc = crc;
    Ok(info)
}

/// Why a part file's prefix did not parse.
enum PrefixError {
    /// It needs more bytes than were read.
    Short,
    Bad(String),
}

/// A part file's prefix (through its entry count) from its first bytes `head`: the part's
/// description with no entries yet, and the entry count, checked against its shard's rows.
fn parse_prefix(part: &Path, head: &[u8]) -> Result<(PartInfo, u64), PrefixError> {
    // A short read of the prefix's fields or of its header: more bytes are needed; any other
    // failure is the file's.
    let sh = |_: terrain_core::bytes::Short| PrefixError::Short;
    let mut r = Reader::new(&head[8..]);
    let version = r.u32().map_err(sh)?;
    if version != PART_VERSION {
        return Err(PrefixError::Bad(format!(
            "part format version {version}, this reader reads {PART_VERSION}"
        )));
    }
    let shard = Shard::new(r.u32().map_err(sh)?, r.u32().map_err(sh)?)
        .map_err(|e| PrefixError::Bad(e.to_string()))?;
    let rows = r.u64().map_err(sh)?..r.u64().map_err(sh)?;
    let mut text = || -> Result<String, PrefixError> {
        let n = r.u32().map_err(sh)? as usize;
        let bytes = r.take(n).map_err(sh)?;
        String::from_utf8(bytes.to_vec()).map_err(|_| PrefixError::Bad("text is not UTF-8".into()))
    };
    let (source_id, options) = (text()?, text()?);
    let lossless = r.u8().map_err(sh)? != 0;
    let has_bound = r.u8().map_err(sh)? != 0;
    let bound = r.f64().map_err(sh)?;
    let bound = has_bound.then_some(bound);
    let header = read_header(&mut r).map_err(|e| match e {
        IndexError::Short(_) => PrefixError::Short,
        e => PrefixError::Bad(format!("header: {e}")),
    })?;
    if rows != shard.rows(header.blocks_y as u64) {
        return Err(PrefixError::Bad(format!(
            "block rows {rows:?}, but shard {shard} of {} rows is {:?}",
            header.blocks_y,
            shard.rows(header.blocks_y as u64)
        )));
    }
    let n = r.u64().map_err(sh)?;
    let expected = (rows.end - rows.start) * header.blocks_x as u64;
    if n != expected {
        return Err(PrefixError::Bad(format!(
            "{n} block entries, expected {expected} for rows {rows:?}"
        )));
    }
    let entries_at = 8 + (head.len() - 8 - r.remaining()) as u64;
    let info = PartInfo {
        path: part.to_path_buf(),
        shard,
        rows,
        source_id,
        options,
        header,
        lossless,
        bound,
        blocks: 0,
        block_bytes: 0,
        entries_at,
        crc: 0,
        geomip: None,
    };
    Ok((info, n))
}

/// Entries read from a part file per batch: 1,024 of about 7.3 KB at `k` = 8.
const ENTRY_BATCH: usize = 1024;

/// A part file read in pieces, its CRC-32 computed over the pieces in order.
struct PartFile {
    path: PathBuf,
    part: PathBuf,
    file: fs::File,
    /// The bytes before the trailing CRC-32.
    body_len: u64,
}

impl PartFile {
    /// Opens `part`'s part file and checks its magic bytes.
    fn open(part: &Path) -> Result<Self, BakeError> {
        let path = part.join(PART_FILE);
        let io = |cause| BakeError::Io { path: path.clone(), cause };
        let file = fs::File::open(&path).map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        let mut this = Self {
            path: path.clone(),
            part: part.to_path_buf(),
            file,
            body_len: len.saturating_sub(4),
        };
        let mut magic = [0u8; 8];
        if len < 16 || this.read_at(0, &mut magic).is_err() || magic != PART_MAGIC {
            return Err(BakeError::BadPart {
                path: part.to_path_buf(),
                reason: format!("{PART_FILE} is not a shard's part file (wrong magic bytes)"),
            });
        }
        Ok(this)
    }

    /// Fills `buf` from `offset`.
    fn read_at(&mut self, offset: u64, buf: &mut [u8]) -> Result<(), BakeError> {
        use std::os::unix::fs::FileExt;
        self.file
            .read_exact_at(buf, offset)
            .map_err(|cause| BakeError::Io { path: self.path.clone(), cause })
    }

    /// Reads, checks and hands to `each` the part's `n` entries in batches of
    /// `batch_len` ([`ENTRY_BATCH`] but in tests), in file order.
    fn entries(
        &mut self,
        info: &PartInfo,
        n: u64,
        batch_len: usize,
        each: &mut dyn FnMut(&[BlockEntry]) -> Result<(), BakeError>,
    ) -> Result<(), BakeError> {
        let (header, fine) = (&info.header, info.fine());
        let len = entry_len(header, fine);
        let first = info.rows.start as usize * header.blocks_x as usize;
        let mut buf = Vec::new();
        let mut batch = Vec::with_capacity(batch_len);
        let mut done = 0u64;
        while done < n {
            let count = (n - done).min(batch_len.max(1) as u64) as usize;
            let at = info.entries_at + done * len as u64;
            if at + (count * len) as u64 > self.body_len {
                return Err(self.bad(format!("cut short in its block entries ({n} expected)")));
            }
            buf.resize(count * len, 0);
            self.read_at(at, &mut buf)?;
            batch.clear();
            for (i, bytes) in buf.chunks_exact(len).enumerate() {
                let mut r = Reader::new(bytes);
                let id = header.block_at(first + done as usize + i);
                let e =
                    read_entry(&mut r, header, id, fine).map_err(|e| self.bad(e.to_string()))?;
                if r.remaining() != 0 {
                    // Entries have a fixed length given by the header; bytes left over mean the
                    // part was written by a different format than the header says.
                    return Err(self.bad(format!(
                        "a block entry has {} bytes its fields do not account for",
                        r.remaining()
                    )));
                }
                batch.push(e);
            }
            each(&batch)?;
            done += count as u64;
        }
        Ok(())
    }

    /// The file's CRC-32, read through in pieces and checked against its trailing one.
    fn checksum(&mut self) -> Result<u32, BakeError> {
        let mut buf = vec![0u8; 1 << 20];
        let (mut crc, mut at) = (0, 0);
        while at < self.body_len {
            let n = (self.body_len - at).min(buf.len() as u64) as usize;
            self.read_at(at, &mut buf[..n])?;
            crc = crc32_update(crc, &buf[..n]);
            at += n as u64;
        }
        let mut tail = [0u8; 4];
        self.read_at(self.body_len, &mut tail)?;
        if crc.to_le_bytes() != tail {
            return Err(self.bad("checksum mismatch (the file is corrupt)".into()));
        }
        Ok(crc)
    }

    fn bad(&self, reason: String) -> BakeError {
        BakeError::BadPart { path: self.part.clone(), reason: format!("{PART_FILE}: {reason}") }
    }
}

impl PartInfo {
    /// Fine maxima per entry ([`fine_count`]).
    fn fine(&self) -> usize {
        fine_count(self.header.k, self.header.node_levels)
    }
}

/// How [`merge`] runs, and what the parts must hold.
#[derive(Debug, Clone, Default)]
pub struct MergeConfig {
    /// Replace an existing store at the output.
    pub overwrite: bool,
    /// Worker threads; 0 = rayon's global pool.
    pub threads: usize,
    /// The source every part must be of (`bake_shard`'s `source_id`); `None`: any, as long as
    /// the parts agree.
    pub source_id: Option<String>,
    /// The options every part must have been baked with; `None`: any, as long as the parts
    /// agree.
    pub bake: Option<BakeConfig>,
}

/// Joins the part folders `parts` (every shard `0..N` of one bake, exactly once) into the store
/// folder `out`, byte for byte what [`crate::bake`] writes for the same source and config.
/// Refuses, naming the part, a part of another source, other options, another grid or another
/// `N`, a shard given twice, and names the shards missing. The parts are only read (a failed
/// merge can be run again); every level's checksum is verified as its block is copied.
pub fn merge(
    parts: &[PathBuf],
    out: &Path,
    config: &MergeConfig,
    progress: &mut (dyn FnMut(&BakeProgress) -> ControlFlow<()> + Send),
) -> Result<BakeReport, BakeError> {
    let start = Instant::now();
    let mut infos = parts.iter().map(|p| read_part(p)).collect::<Result<Vec<_>, _>>()?;
    check_parts(&mut infos, config)?;
    let total: usize = infos.iter().map(PartInfo::blocks).sum();
    publish(out, config.overwrite, config.threads, crate::store::is_store, |tmp| {
        let mut prog =
            BakeProgress { blocks_done: 0, blocks_total: total, rows_read: 0, bytes_written: 0 };
        let first = &infos[0];
        let mut all = BakedRows {
            header: first.header.clone(),
            entries: index_file(tmp, &first.header)?,
            lossless: true,
            bound: first.bound,
            geomip: geomip_of(&infos, tmp)?,
            decimation: decimation_of(&infos, tmp)?,
        };
        for part in &infos {
            // The part's entries are read again, a batch at a time, and its checksum checked
            // again at the end: a part changed since it was read is refused, not merged.
            let mut file = PartFile::open(&part.path)?;
            let mut first = part.rows.start as usize * part.header.blocks_x as usize;
            file.entries(part, part.blocks as u64, ENTRY_BATCH, &mut |batch| {
                copy_blocks(part, first, batch, tmp)?;
                first += batch.len();
                for e in batch {
                    all.entries.push(e)?;
                }
                prog.blocks_done = all.entries.count();
                prog.bytes_written += batch.iter().map(|e| e.file_len).sum::<u64>();
                if progress(&prog).is_break() {
                    return Err(BakeError::Cancelled);
                }
                Ok(())
            })?;
            if file.checksum()? != part.crc {
                return Err(file.bad("changed while the merge read it; merge again".into()));
            }
            all.header.max_error_m = all.header.max_error_m.max(part.header.max_error_m);
            all.header.max_void_error_m =
                all.header.max_void_error_m.max(part.header.max_void_error_m);
            all.lossless &= part.lossless;
            prog.rows_read += part.rows.end - part.rows.start;
        }
        crate::bake::finish(tmp, all, start)
    })
}

/// Geomorph's table of the whole grid from the parts (sorted by shard), written into `dir`
/// part by part (one part's table in memory at a time): each part's table of its rows and
/// the checksum of its rows' heights, joined; `None` unless every part has them (a part whose
/// rows had a band without a valid sample has none, and then neither has the single bake).
fn geomip_of(
    infos: &[PartInfo],
    dir: &Path,
) -> Result<Option<(GeomipOut, HeightsChecksum)>, BakeError> {
    if infos.iter().any(|part| part.geomip.is_none()) {
        return Ok(None);
    }
    let mut out = GeomipOut::new(dir);
    let mut heights = HeightsChecksum::new();
    for part in infos {
        let Some((p, sum)) = &part.geomip else {
            continue;
        };
        heights.append(sum);
        if part.rows.is_empty() {
            continue;
        }
        let h = &part.header;
        let cells = 1u64 << h.k;
        let (y0, y1) = (part.rows.start * cells, (part.rows.end * cells).min(h.height - 1));
        let path = part.path.join(GEOMIP_FILE);
        let bad = |reason: String| BakeError::BadPart { path: part.path.clone(), reason };
        let bytes = fs::read(&path).map_err(|cause| BakeError::Io { path: path.clone(), cause })?;
        let want = GeomipFor {
            width: h.width as u32,
            height: (y1 - y0 + 1) as u32,
            patch_cells: *p,
            heights_crc: None,
        };
        let table = GeomipTable::decode(&bytes, &want)
            .map_err(|e| bad(format!("{GEOMIP_FILE}: {e}; bake shard {} again", part.shard)))?;
        out.push(&table)?;
    }
    Ok(Some((out, heights)))
}

/// The blocks' decimation errors of the whole grid from the parts (sorted by shard), each
/// part's table of its rows checked and appended in turn; `None` (and no table) unless every
/// part has one (parts baked before the table existed have none).
fn decimation_of(infos: &[PartInfo], dir: &Path) -> Result<Option<DecimationOut>, BakeError> {
    let mut out = DecimationOut::create(dir, infos[0].header.k)?;
    for part in infos {
        let first = part.rows.start * u64::from(part.header.blocks_x);
        if !out.push_part(&part.path, first, part.blocks as u64)? {
            out.abandon()?;
            return Ok(None);
        }
    }
    Ok(Some(out))
}

/// Checks that `infos` are every shard of one bake, once, and sorts them by shard.
fn check_parts(infos: &mut [PartInfo], config: &MergeConfig) -> Result<(), BakeError> {
    let Some(first) = infos.first() else {
        return Err(BakeError::Shards("no part to merge".into()));
    };
    let foreign =
        |p: &PartInfo, reason: String| BakeError::BadPart { path: p.path.clone(), reason };
    let want_source = config.source_id.clone().unwrap_or_else(|| first.source_id.clone());
    let want_options = config.bake.as_ref().map(bake_options).unwrap_or(first.options.clone());
    let same_grid = |a: &Header, b: &Header| {
        (a.width, a.height, a.k, a.blocks_x, a.blocks_y, a.node_levels)
            == (b.width, b.height, b.k, b.blocks_x, b.blocks_y, b.node_levels)
            && (a.encoding, a.codec, &a.georef) == (b.encoding, b.codec, &b.georef)
    };
    for p in infos.iter() {
        if p.source_id != want_source {
            return Err(foreign(
                p,
                format!(
                    "a part of another source: it holds {:?}, this merge is of {want_source:?}",
                    p.source_id
                ),
            ));
        }
        if p.options != want_options {
            return Err(foreign(
                p,
                format!(
                    "a part baked with other options: {:?}, this merge's are {want_options:?}",
                    p.options
                ),
            ));
        }
        if p.shard.count != first.shard.count {
            return Err(foreign(
                p,
                format!(
                    "shard {} of a {}-shard bake, but {} is shard {} of {}",
                    p.shard,
                    p.shard.count,
                    first.path.display(),
                    first.shard,
                    first.shard.count
                ),
            ));
        }
        if !same_grid(&p.header, &first.header) || p.bound != first.bound {
            return Err(foreign(
                p,
                format!("a part of another grid or encoding than {}", first.path.display()),
            ));
        }
    }
    let n = first.shard.count;
    infos.sort_by_key(|p| p.shard.index);
    for pair in infos.windows(2) {
        if pair[0].shard == pair[1].shard {
            return Err(BakeError::Shards(format!(
                "shard {} is given twice: {} and {}",
                pair[0].shard,
                pair[0].path.display(),
                pair[1].path.display()
            )));
        }
    }
    let missing: Vec<String> = (0..n)
        .filter(|k| !infos.iter().any(|p| p.shard.index == *k))
        .map(|k| format!("{k}/{n}"))
        .collect();
    if !missing.is_empty() {
        return Err(BakeError::Shards(format!(
            "shard{} {} missing (no part among the {} given holds {}): bake {} again with --shard",
            if missing.len() > 1 { "s" } else { "" },
            missing.join(", "),
            infos.len(),
            if missing.len() > 1 { "them" } else { "it" },
            if missing.len() > 1 { "them" } else { "it" },
        )));
    }
    Ok(())
}

/// Copies a part's block files (`entries`, of blocks `first..` in row-major order) into the
/// store folder `dir`, checking each against its entry:
/// the block header (magic, bake id 0, row and column), the length, every level's CRC-32.
fn copy_blocks(
    part: &PartInfo,
    first: usize,
    entries: &[BlockEntry],
    dir: &Path,
) -> Result<(), BakeError> {
    entries.par_iter().enumerate().try_for_each(|(i, e)| {
        let id = part.header.block_at(first + i);
        let name = block_file_name(id);
        let from = part.path.join(&name);
        let bytes = fs::read(&from).map_err(|cause| BakeError::Io { path: from.clone(), cause })?;
        let bad = |what: String| BakeError::BadPart {
            path: part.path.clone(),
            reason: format!("{name}: {what}; bake shard {} again", part.shard),
        };
        if bytes.len() as u64 != e.file_len {
            return Err(bad(format!(
                "{} bytes, the part's entry says {}",
                bytes.len(),
                e.file_len
            )));
        }
        let head = crate::format::block_header(0, id);
        if bytes[..BLOCK_HEADER_LEN as usize] != head[..] {
            return Err(bad("not this block's header".into()));
        }
        for (l, level) in e.levels.iter().enumerate() {
            let data = &bytes[level.offset as usize..(level.offset + level.len as u64) as usize];
            if crc32(data) != level.crc32 {
                return Err(bad(format!("level {l} fails its checksum")));
            }
        }
        let to = dir.join(&name);
        fs::write(&to, &bytes).map_err(|cause| BakeError::Io { path: to, cause })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use terrain_core::synth::FractalConfig;

    /// A scratch folder named after `name`, and the part of a single-shard bake of a 301 x 203
    /// synthetic grid (k = 6: 20 blocks) in it; the folder is removed when the guard is dropped
    /// (also when the test panics).
    fn baked_part(name: &str) -> (crate::tests::Scratch, PathBuf) {
        let dir = crate::tests::scratch(&format!("terrain-shard-{name}-"));
        let part = dir.join("p0");
        let config = BakeConfig { k: 6, threads: 2, ..BakeConfig::default() };
        let source = FractalConfig::with_size(301, 203, 10.0);
        let shard = Shard::new(0, 1).unwrap();
        bake_shard(&source, &part, &config, shard, name, &mut |_| ControlFlow::Continue(()))
            .unwrap();
        (dir, part)
    }

    /// A part's entries read in batches of any length are the same entries, in the same order
    /// (the merge reads 1,024 at a time; a test grid has fewer blocks than that).
    #[test]
    fn entries_read_in_batches_are_the_same_entries() {
        let (_dir, part) = baked_part("batches");
        let info = read_part(&part).unwrap();
        assert_eq!(info.blocks(), 20);
        let read = |batch_len: usize| {
            let (mut all, mut sizes) = (Vec::new(), Vec::new());
            let mut file = PartFile::open(&part).unwrap();
            file.entries(&info, info.blocks as u64, batch_len, &mut |b| {
                sizes.push(b.len());
                all.extend(b.iter().cloned());
                Ok(())
            })
            .unwrap();
            (all, sizes)
        };
        let (whole, sizes) = read(ENTRY_BATCH);
        assert_eq!(sizes, [20]);
        for batch_len in [1, 3, 7, 19, 20] {
            let (entries, sizes) = read(batch_len);
            assert_eq!(entries, whole, "batches of {batch_len}");
            assert_eq!(sizes.len(), 20usize.div_ceil(batch_len), "batches of {batch_len}");
        }
    }

    /// A part's prefix cut anywhere before its entry count, inside its own fields or inside
    /// the grid header it holds, is short (the reader reads more), never damaged; the whole
    /// prefix parses, and a damaged header field is damage.
    #[test]
    fn a_prefix_cut_anywhere_is_short_and_a_damaged_one_is_bad() {
        let (_dir, part) = baked_part("prefix");
        let bytes = fs::read(part.join(PART_FILE)).unwrap();
        let (info, n) = match parse_prefix(&part, &bytes) {
            Ok(parsed) => parsed,
            Err(PrefixError::Short) => panic!("the whole file is short"),
            Err(PrefixError::Bad(m)) => panic!("the whole file is bad: {m}"),
        };
        assert_eq!(n, 20);
        let prefix_len = info.entries_at as usize;
        for cut in 12..prefix_len {
            match parse_prefix(&part, &bytes[..cut]) {
                Err(PrefixError::Short) => {}
                Err(PrefixError::Bad(m)) => panic!("cut at {cut} of {prefix_len}: bad: {m}"),
                Ok(_) => panic!("cut at {cut} of {prefix_len} parsed"),
            }
        }
        assert!(parse_prefix(&part, &bytes[..prefix_len]).is_ok());
        // The header's block exponent (after version, shard, rows, the two texts, the flags and
        // the bound, then width and height), out of range: damage, however many bytes follow.
        let text =
            |at: usize| 4 + u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
        let at = 8 + 4 + 8 + 16;
        let at = at + text(at);
        let at = at + text(at) + 2 + 8 + 16;
        let mut damaged = bytes.clone();
        damaged[at] = 200;
        assert!(
            matches!(parse_prefix(&part, &damaged), Err(PrefixError::Bad(m)) if m.contains("out of range"))
        );
    }
}
