//! The store's overview (`overview.bin`): the coarsest levels of every block in one file, so a
//! reader that needs them for the whole grid (the camera placed on a level-4 overview, the
//! streamer's coarse floor of level 0 everywhere) opens one file instead of every block's five
//! times, and a store at a URL fetches them in one request instead of one per block and level.
//!
//! Layout, little-endian: magic `TSOVERV1`, the bake id (u64, the index header's), the top
//! level `T` (u8) and 7 zero bytes, the block count (u64), a CRC-32 (u32) of those 32 bytes;
//! per block in the index's row-major order a record of [`RECORD_LEN`] bytes: the offset (u64)
//! of its levels' bytes, then per level `0..=OVERVIEW_TOP` its length and CRC-32 (u32 each,
//! the index entry's; zeros above `T`); then per block its levels `0..=T`, each level's
//! payload exactly as in its block file. A read needs no index entry, so the coarse levels of
//! the whole grid are read without a page of the index ([`Overview::level_bytes`]: each level
//! checked by its CRC-32; a damaged record reads bytes that fail it). Opening reads the 36
//! bytes of the head alone (the store's invariant: opening does not grow with the blocks); a
//! read is the block's record (once per block, memoized) and the level. Written by every bake
//! (and shard merge) after the index ([`write`]); a store without one (baked before it
//! existed) reads its blocks' own files. Not in the index's format version: an optional file. A store at a URL fetches it whole, in one request, when a
//! coarse level is first read (`Store::read_level_bytes`).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use rayon::prelude::*;

use crate::error::{BakeError, StoreError};
use crate::format::{BlockId, Header, crc32};
use crate::store::{Store, read_at};

/// The overview's file name in a store folder.
pub(crate) const OVERVIEW_FILE: &str = "overview.bin";

/// The finest level an overview holds (fewer when the blocks have fewer levels): level 4 is
/// what `terrain render` and `terrain view` place their camera on.
pub(crate) const OVERVIEW_TOP: u8 = 4;

const OVERVIEW_MAGIC: [u8; 8] = *b"TSOVERV1";

/// Bytes of the head: magic, bake id, top level and padding, block count; then its CRC-32.
const FIXED_LEN: usize = 8 + 8 + 8 + 8;

/// Bytes before the offsets.
const HEAD_LEN: usize = FIXED_LEN + 4;

/// Bytes of a block's record: its offset, then length and CRC-32 of levels `0..=OVERVIEW_TOP`.
const RECORD_LEN: usize = 8 + 8 * (OVERVIEW_TOP as usize + 1);

/// Slots of an overview's record memo (64 KiB, whatever the blocks).
const MEMO_SLOTS: usize = 1024;

/// A block's record, decoded: `pos + 1` (0: an empty memo slot), its offset, and per level
/// its length and CRC-32.
#[derive(Debug, Clone, Copy, Default)]
struct Record {
    tag: u64,
    offset: u64,
    levels: [(u32, u32); OVERVIEW_TOP as usize + 1],
}

/// The error of a damaged overview (or another bake's): what is wrong, and what to do.
fn damaged(path: &Path, message: &str) -> StoreError {
    StoreError::Overview {
        path: path.to_path_buf(),
        message: format!(
            "{message}; remove it (the store then reads every block's own file) or bake the \
             store again"
        ),
    }
}

/// An open overview: its file and its top level.
#[derive(Debug)]
pub(crate) struct Overview {
    path: PathBuf,
    file: File,
    top: u8,
    len: u64,
    /// The records read last, direct-mapped by block position: a block's levels are read one
    /// after the other, so its record is read once.
    memo: Mutex<Box<[Record]>>,
}

impl Overview {
    /// Opens the overview of the store in `dir` whose index header is `header`: `None` when
    /// there is none; an error naming the file when it is damaged or belongs to another bake.
    pub(crate) fn open(dir: &Path, header: &Header) -> Result<Option<Self>, StoreError> {
        let path = dir.join(OVERVIEW_FILE);
        let file = match File::open(&path) {
            Ok(f) => f,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(cause) => return Err(StoreError::Io { path, cause }),
        };
        let bad = |message: String| damaged(&path, &message);
        let len = file.metadata().map_err(|cause| StoreError::Io { path: path.clone(), cause })?;
        let len = len.len();
        let blocks = header.block_count();
        let data_start = (HEAD_LEN + blocks * RECORD_LEN) as u64;
        if len < data_start {
            return Err(bad(format!("{len} bytes, shorter than its table of {blocks} blocks")));
        }
        let mut head = [0u8; HEAD_LEN];
        read_at(&file, 0, &mut head)
            .map_err(|cause| StoreError::Io { path: path.clone(), cause })?;
        let (body, crc) = head.split_at(FIXED_LEN);
        if crc32(body) != u32::from_le_bytes(crc.try_into().expect("4 bytes")) {
            return Err(bad("its head fails its checksum".into()));
        }
        if body[..8] != OVERVIEW_MAGIC {
            return Err(bad("not an overview (wrong magic bytes)".into()));
        }
        let u64_at = |at: usize| u64::from_le_bytes(body[at..at + 8].try_into().expect("8 bytes"));
        if u64_at(8) != header.bake_id {
            return Err(bad(format!(
                "written by another bake (bake id {:016x}, the index's {:016x})",
                u64_at(8),
                header.bake_id
            )));
        }
        let top = body[16];
        if top > header.k || u64_at(24) != blocks as u64 {
            return Err(bad(format!(
                "levels 0-{top} of {} blocks, for a store of levels 0-{} and {blocks} blocks",
                u64_at(24),
                header.k
            )));
        }
        let memo = Mutex::new(vec![Record::default(); MEMO_SLOTS].into_boxed_slice());
        Ok(Some(Self { path, file, top, len, memo }))
    }

    /// The finest level held.
    pub(crate) fn top(&self) -> u8 {
        self.top
    }

    /// The payload of `level` (at most [`Overview::top`]) of block `id` at row-major position
    /// `pos`, checked by its CRC-32 (a mismatch is [`StoreError::Checksum`] naming the
    /// overview): the block's record (once per block) and one positioned read.
    pub(crate) fn level_bytes(
        &self,
        pos: usize,
        id: BlockId,
        level: u8,
    ) -> Result<Vec<u8>, StoreError> {
        debug_assert!(level <= self.top);
        let io = |cause| StoreError::Io { path: self.path.clone(), cause };
        let slot = pos % MEMO_SLOTS;
        let memo = self.memo.lock().unwrap_or_else(|e| e.into_inner())[slot];
        let record = if memo.tag == pos as u64 + 1 {
            memo
        } else {
            let mut raw = [0u8; RECORD_LEN];
            read_at(&self.file, (HEAD_LEN + RECORD_LEN * pos) as u64, &mut raw).map_err(io)?;
            let u32_at = |at: usize| u32::from_le_bytes(raw[at..at + 4].try_into().expect("4"));
            let mut r = Record {
                tag: pos as u64 + 1,
                offset: u64::from_le_bytes(raw[..8].try_into().expect("8 bytes")),
                ..Record::default()
            };
            for (l, v) in r.levels.iter_mut().enumerate() {
                *v = (u32_at(8 + 8 * l), u32_at(12 + 8 * l));
            }
            self.memo.lock().unwrap_or_else(|e| e.into_inner())[slot] = r;
            r
        };
        let before: u64 = record.levels[..level as usize].iter().map(|l| u64::from(l.0)).sum();
        let (len, stored) = record.levels[level as usize];
        let start = record.offset.saturating_add(before);
        if start.saturating_add(u64::from(len)) > self.len {
            return Err(damaged(
                &self.path,
                &format!("block {pos}'s level {level} lies past the end of the file"),
            ));
        }
        let mut bytes = vec![0u8; len as usize];
        read_at(&self.file, start, &mut bytes).map_err(io)?;
        let computed = crc32(&bytes);
        if computed != stored {
            return Err(StoreError::Checksum {
                path: self.path.clone(),
                block: id,
                level,
                stored,
                computed,
            });
        }
        Ok(bytes)
    }
}

/// Writes the overview of the finished store in `dir` (its index and block files complete):
/// every block's levels `0..=min(OVERVIEW_TOP, k)` read back from its file (each checked
/// against the index), in row-major order, blocks read in parallel chunks so memory stays at
/// a chunk's levels and a few pages of the index. Written under a temporary name and
/// renamed: a reader never sees half of one. Returns its length in bytes.
pub(crate) fn write(dir: &Path) -> Result<u64, BakeError> {
    let store_err = |e: StoreError| BakeError::Encoding(format!("writing the overview: {e}"));
    let path = dir.join(OVERVIEW_FILE);
    // Never read through an overview being replaced.
    match std::fs::remove_file(&path) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(cause) => return Err(BakeError::Io { path, cause }),
    }
    // Read in row-major order, a page of entries at a time: a few pages of cache, so the
    // bake's memory does not grow with the index.
    let store =
        Store::open(dir).and_then(|s| s.with_page_cache_bytes(256 << 10)).map_err(store_err)?;
    let header = store.header().clone();
    let top = OVERVIEW_TOP.min(header.k);
    let blocks = header.block_count();
    let tmp = dir.join(format!("{OVERVIEW_FILE}.tmp"));
    let io = |p: &Path| {
        let p = p.to_path_buf();
        move |cause: std::io::Error| BakeError::Io { path: p.clone(), cause }
    };
    // The head, then each block's record from its entry, written as they come (the table is
    // never held: the bake's memory does not grow with the blocks).
    let mut out = BufWriter::new(File::create(&tmp).map_err(io(&tmp))?);
    let mut head = Vec::with_capacity(HEAD_LEN);
    head.extend_from_slice(&OVERVIEW_MAGIC);
    head.extend_from_slice(&header.bake_id.to_le_bytes());
    head.push(top);
    head.extend_from_slice(&[0u8; 7]);
    head.extend_from_slice(&(blocks as u64).to_le_bytes());
    let crc = crc32(&head);
    head.extend_from_slice(&crc.to_le_bytes());
    out.write_all(&head).map_err(io(&tmp))?;
    let mut offset = (HEAD_LEN + blocks * RECORD_LEN) as u64;
    for pos in 0..blocks {
        let entry = store.try_entry(header.block_at(pos)).map_err(store_err)?.ok_or_else(|| {
            BakeError::Encoding(format!("writing the overview: no entry for block {pos}"))
        })?;
        let mut record = [0u8; RECORD_LEN];
        record[..8].copy_from_slice(&offset.to_le_bytes());
        for (l, e) in entry.levels[..=top as usize].iter().enumerate() {
            record[8 + 8 * l..12 + 8 * l].copy_from_slice(&e.len.to_le_bytes());
            record[12 + 8 * l..16 + 8 * l].copy_from_slice(&e.crc32.to_le_bytes());
        }
        out.write_all(&record).map_err(io(&tmp))?;
        offset += entry.levels[..=top as usize].iter().map(|l| u64::from(l.len)).sum::<u64>();
    }
    const CHUNK: usize = 256;
    for start in (0..blocks).step_by(CHUNK) {
        let chunk: Vec<Vec<u8>> = (start..(start + CHUNK).min(blocks))
            .into_par_iter()
            .map(|pos| {
                let id = header.block_at(pos);
                let mut bytes = Vec::new();
                for level in 0..=top {
                    bytes.extend(store.read_level_bytes(id, level)?);
                }
                Ok(bytes)
            })
            .collect::<Result<_, StoreError>>()
            .map_err(store_err)?;
        for bytes in &chunk {
            out.write_all(bytes).map_err(io(&tmp))?;
        }
    }
    let file = out.into_inner().map_err(|e| io(&tmp)(e.into_error()))?;
    file.sync_all().map_err(io(&tmp))?;
    drop(file);
    std::fs::rename(&tmp, &path).map_err(io(&path))?;
    Ok(offset)
}
