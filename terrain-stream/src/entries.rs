//! Block entries written to disk as the bake's blocks finish, so that a bake's memory does not
//! grow with its block count (16,384 entries of 7.3 KB at 32769^2, 120 MB, were held until the
//! end before).
//!
//! An index, and a shard's part file, is a prefix whose values are known only at the end (the
//! header's bake id and largest errors), the block entries, a tail, and the CRC-32 of all of
//! it. [`EntryFile`] reserves the prefix's bytes as zeros (no magic bytes: a half-written file
//! never reads as an index or a part), appends each entry as it comes, and
//! [`EntryFile::finish`] appends the tail and the CRC-32 (the prefix's checksum combined with
//! the streamed bytes', zlib's `crc32_combine`) and writes the prefix last, as terrain-core's
//! `GeomipEncoder` does for geomorph's table. The bytes are those of the file built whole.

use std::fs;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::PathBuf;

use terrain_core::checksum::{FNV1A_START, crc32, crc32_combine, crc32_update, fnv1a_update};

use crate::error::BakeError;
use crate::format::{BlockEntry, Header, Writer, fine_count, write_entry};
use crate::pages::{HeadBuilder, paged_prefix, paged_prefix_len};

/// Bytes of entries buffered before they go to the file.
const BUFFER_BYTES: usize = 64 << 10;

/// A file of block entries after a reserved prefix, written entry by entry (see the module
/// docs). It also keeps what the end of a bake needs from the entries: their count, the bytes
/// of their block files, and the bake id.
#[derive(Debug)]
pub(crate) struct EntryFile {
    path: PathBuf,
    file: BufWriter<fs::File>,
    prefix_len: usize,
    /// CRC-32 and length of the bytes after the prefix.
    crc: u32,
    len: u64,
    count: usize,
    block_bytes: u64,
    /// FNV-1a over every level's checksum, entry by entry.
    bake_id: u64,
    /// One entry's bytes, reused.
    buf: Writer,
    /// For a store's index (version 4): the head being built and the pages' CRC-32s, written
    /// after each page's entries.
    head: Option<HeadBuilder>,
}

impl EntryFile {
    /// Creates `path` with `prefix_len` zero bytes, to be overwritten by [`EntryFile::finish`].
    pub(crate) fn create(path: PathBuf, prefix_len: usize) -> Result<Self, BakeError> {
        let err = |cause| BakeError::Io { path: path.clone(), cause };
        let mut file =
            BufWriter::with_capacity(BUFFER_BYTES, fs::File::create(&path).map_err(err)?);
        file.write_all(&vec![0; prefix_len]).map_err(err)?;
        Ok(Self {
            path,
            file,
            prefix_len,
            crc: 0,
            len: 0,
            count: 0,
            block_bytes: 0,
            bake_id: FNV1A_START,
            buf: Writer::default(),
            head: None,
        })
    }

    /// Creates the index of a store of `header`'s grid at `path`, paged (index version 4,
    /// `crate::pages`): each page's CRC-32 after its entries, and the head, built from the
    /// entries, written with the header by [`EntryFile::finish_index`].
    pub(crate) fn create_index(path: PathBuf, header: &Header) -> Result<Self, BakeError> {
        let mut f = Self::create(path, paged_prefix_len(header))?;
        f.head = Some(HeadBuilder::new(header, fine_count(header.k, header.node_levels)));
        Ok(f)
    }

    /// Appends the next entry (entries come in the order the file stores them).
    pub(crate) fn push(&mut self, entry: &BlockEntry) -> Result<(), BakeError> {
        self.buf.buf.clear();
        write_entry(&mut self.buf, entry);
        if let Some(crc) = self.head.as_mut().and_then(|h| h.push(entry, &self.buf.buf)) {
            self.buf.u32(crc);
        }
        let bytes = &self.buf.buf;
        self.file
            .write_all(bytes)
            .map_err(|cause| BakeError::Io { path: self.path.clone(), cause })?;
        self.crc = crc32_update(self.crc, bytes);
        self.len += bytes.len() as u64;
        self.count += 1;
        self.block_bytes += entry.file_len;
        for l in &entry.levels {
            self.bake_id = fnv1a_update(self.bake_id, &l.crc32.to_le_bytes());
        }
        Ok(())
    }

    /// Entries pushed.
    pub(crate) fn count(&self) -> usize {
        self.count
    }

    /// Bytes of the pushed entries' block files.
    pub(crate) fn block_bytes(&self) -> u64 {
        self.block_bytes
    }

    /// The bake id of the pushed entries: FNV-1a over every level's checksum, in order.
    pub(crate) fn bake_id(&self) -> u64 {
        self.bake_id
    }

    /// Completes a store's index ([`EntryFile::create_index`]): the last page's CRC-32, then
    /// the prefix with `header` (its final bake id and errors) and the head. Returns the
    /// file's length.
    pub(crate) fn finish_index(mut self, header: &Header) -> Result<u64, BakeError> {
        let builder = self.head.take().ok_or_else(|| {
            BakeError::Encoding(format!("{}: not an index file", self.path.display()))
        })?;
        let (tail, head) = builder.finish();
        let tail = tail.map(u32::to_le_bytes);
        let prefix = paged_prefix(header, &head);
        self.finish(&prefix, tail.as_ref().map_or(&[][..], |t| &t[..]))
    }

    /// Completes the file: `tail` after the entries, the CRC-32 of `prefix`, the entries and
    /// `tail`, then `prefix` (which must have the reserved length) over the reserved zeros.
    /// Returns the file's length.
    pub(crate) fn finish(self, prefix: &[u8], tail: &[u8]) -> Result<u64, BakeError> {
        let Self { path, file, prefix_len, crc, len, .. } = self;
        if prefix.len() != prefix_len {
            return Err(BakeError::Encoding(format!(
                "{}: a prefix of {} bytes for the {prefix_len} reserved",
                path.display(),
                prefix.len()
            )));
        }
        let err = |cause| BakeError::Io { path: path.clone(), cause };
        let mut file = file.into_inner().map_err(|e| err(e.into_error()))?;
        let crc = crc32_update(crc, tail);
        let body = len + tail.len() as u64;
        let crc = crc32_combine(crc32(prefix), crc, body);
        file.write_all(tail).map_err(err)?;
        file.write_all(&crc.to_le_bytes()).map_err(err)?;
        file.seek(SeekFrom::Start(0)).map_err(err)?;
        file.write_all(prefix).map_err(err)?;
        Ok((prefix_len as u64) + body + 4)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::{LevelEntry, NodeValues};

    fn entry(seed: u32) -> BlockEntry {
        BlockEntry {
            valid_w: 5,
            valid_h: 3 + seed,
            file_len: 100 + seed as u64,
            min: seed as f32,
            max: 10.0 + seed as f32,
            levels: vec![LevelEntry { offset: 28, len: 72 + seed, crc32: 0xdead_0000 ^ seed }],
            nodes: vec![NodeValues { min: 1.0, max: 2.0, static_error: seed as f32 }],
            level_errors: vec![0.5],
            fine_errors: vec![0.25; seed as usize],
            dss: None,
            fine_max: Default::default(),
        }
    }

    /// The file written entry by entry, prefix last, is the file built whole in memory, for
    /// any number of entries (none included) and any tail; a wrong prefix length is refused.
    #[test]
    fn the_streamed_file_is_the_file_built_whole() {
        let dir = crate::tests::scratch("terrain-entries-");
        let path = dir.join("f");
        for (n, tail) in [(0u32, &b""[..]), (1, &b"t"[..]), (300, &b"tail bytes"[..])] {
            let prefix = b"PREFIX-of-some-length";
            let mut f = EntryFile::create(path.clone(), prefix.len()).unwrap();
            let mut whole = Writer::default();
            whole.bytes(prefix);
            for s in 0..n {
                f.push(&entry(s)).unwrap();
                write_entry(&mut whole, &entry(s));
            }
            assert_eq!(f.count(), n as usize);
            assert_eq!(f.block_bytes(), (0..n).map(|s| 100 + s as u64).sum::<u64>());
            whole.bytes(tail);
            let crc = crc32(&whole.buf);
            whole.u32(crc);
            let len = f.finish(prefix, tail).unwrap();
            let bytes = std::fs::read(&path).unwrap();
            assert_eq!(len, bytes.len() as u64);
            assert!(bytes == whole.buf, "{n} entries: the streamed bytes differ");
        }
        // Negative control: a prefix of another length than reserved is an error, not a file.
        let f = EntryFile::create(path.clone(), 4).unwrap();
        assert!(matches!(f.finish(b"12345", b""), Err(BakeError::Encoding(_))));
    }
}
