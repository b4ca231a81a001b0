//! The store's table of decimation errors (`decimation.bin`): per block, the decimation
//! error of the block as one region at the strides `2^1..=2^k`, computed by the bake from the
//! stored heights (it reads every sample anyway), so the `tin` method's coarse tiles need not
//! read every sample under them at run time to learn it.
//!
//! **What a value is**: terrain-core's `tin::decimation::region_errors` (one implementation)
//! of the block's valid samples (columns `0..valid_w`, rows `0..valid_h`: the grid's samples
//! from the block's origin `(col 2^k, row 2^k)`, its last column and row shared with the next
//! block), heights as a reader decodes them (no void mask: a store keeps none, so a void is
//! measured as its stored fill height), the strided samples read with the grid's rule (an
//! index past the grid's last column or row reads the last one; within a block, past
//! `valid_w - 1` / `valid_h - 1`, which are the grid's last for an edge block, and which an
//! interior block's lattice never passes since block origins are multiples of `2^k`). So with
//! `2^k` = 256 cells (the default `k` = 8) a block's values are, bit for bit, what the app's
//! `Decimation` measures for the region of 256 cells over the store's decoded samples.
//!
//! Layout, little-endian: magic `TSDECIMA`, version (u32, [`VERSION`]), values per block
//! `k` (u32), the bake id (u64, the index header's; 0 in a shard's part), the row-major
//! position of the first block (u64; 0 in a store, the first block of its rows in a part), the
//! block count (u64); per block its `k` f32 values, stride `2^1` first; then the CRC-32 (u32)
//! of everything before it. 4 k bytes a block: 512 KiB at 32769^2 with `k` = 8. Written by
//! every bake through a temporary file renamed when complete ([`DecimationOut`]), its values
//! streamed as each band of blocks finishes; a shard writes its rows' table into its part and
//! the merge joins them. Optional, like `overview.bin`: a store baked before it existed has
//! none ([`crate::Store::decimation_errors`] says `None`).
//!
//! Cost: `k` passes over each block's samples, on the bake's block threads. `terrain bake
//! --synthetic 4097 --no-pvs` (2 cores): the blocks stage 0.7-0.8 s wall, 1.4 CPU s before,
//! 0.9-1.0 s wall, 1.7-1.9 CPU s with the table; about 1% of that command's 21 s wall, 31 CPU s.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use terrain_core::checksum::{crc32_combine, crc32_update};
use terrain_core::tin::decimation::region_errors;

use crate::error::{BakeError, StoreError};
use crate::format::{BlockId, Header, crc32};

/// The table's file name in a store folder (and in a shard's part folder).
pub const DECIMATION_FILE: &str = "decimation.bin";

const MAGIC: [u8; 8] = *b"TSDECIMA";

/// The table's format version.
const VERSION: u32 = 1;

/// Bytes before the values: magic, version, values per block, bake id, first block, count.
const HEAD_LEN: usize = 8 + 4 + 4 + 8 + 8 + 8;

/// The decimation errors of one block (see the module docs): `z` its stored heights
/// (`side x side`, row-major, south row first, `side = 2^k + 1`), `(x0, y0)` its first
/// sample in the grid, `valid_w x valid_h` its valid samples. Element `s - 1` is stride `2^s`.
pub(crate) fn block_errors(
    z: &[f32],
    k: u8,
    (x0, y0): (usize, usize),
    valid_w: usize,
    valid_h: usize,
) -> Vec<f32> {
    let side = (1usize << k) + 1;
    debug_assert!(z.len() == side * side && valid_w <= side && valid_h <= side);
    let (lw, lh) = (valid_w.max(1) - 1, valid_h.max(1) - 1);
    // The valid samples alone: padding (past `valid_w` or `valid_h`) is never measured.
    let cropped: Vec<f32>;
    let fine = if valid_w == side {
        &z[..side * valid_h]
    } else {
        cropped = z.chunks_exact(side).take(valid_h).flat_map(|r| &r[..valid_w]).copied().collect();
        &cropped
    };
    let lattice = |s: u32, a0: usize, b0: usize, na: usize, nb: usize| {
        let t = 1usize << s;
        // Grid indices made the block's, clamped to its last valid column and row.
        let (a0, b0) = (a0 - x0, b0 - y0);
        Ok::<_, std::convert::Infallible>(
            (0..na * nb)
                .map(|p| {
                    let (a, b) = ((a0 + (p % na) * t).min(lw), (b0 + (p / na) * t).min(lh));
                    z[b * side + a]
                })
                .collect(),
        )
    };
    match region_errors(fine, valid_w, (x0, y0), None, u32::from(k), lattice) {
        Ok(e) => e,
        Err(never) => match never {},
    }
}

/// A table of decimation errors written as it is computed: the head's bytes reserved, each
/// band's blocks' values appended, the head (which needs the bake id) and the CRC-32 written
/// by [`DecimationOut::finish`], which renames the temporary file to [`DECIMATION_FILE`].
/// Memory holds nothing of the table.
#[derive(Debug)]
pub(crate) struct DecimationOut {
    dir: PathBuf,
    tmp: PathBuf,
    out: BufWriter<File>,
    strides: u8,
    blocks: u64,
    /// CRC-32 of the values written so far.
    crc: u32,
    len: u64,
}

impl DecimationOut {
    /// A table of `strides` values per block, to be written into `dir`.
    pub(crate) fn create(dir: &Path, strides: u8) -> Result<Self, BakeError> {
        let tmp = dir.join(format!("{DECIMATION_FILE}.tmp"));
        let io = |cause| BakeError::Io { path: tmp.clone(), cause };
        let mut out = BufWriter::new(File::create(&tmp).map_err(io)?);
        out.write_all(&[0u8; HEAD_LEN]).map_err(io)?;
        Ok(Self { dir: dir.to_path_buf(), tmp, out, strides, blocks: 0, crc: 0, len: 0 })
    }

    /// Appends the next block's values ([`block_errors`]).
    pub(crate) fn push(&mut self, values: &[f32]) -> Result<(), BakeError> {
        if values.len() != usize::from(self.strides) {
            return Err(BakeError::Encoding(format!(
                "{DECIMATION_FILE}: {} values for a block, expected {}",
                values.len(),
                self.strides
            )));
        }
        self.push_values(values)
    }

    /// Appends the values of whole blocks (a part's table, its length a multiple of the
    /// strides).
    fn push_values(&mut self, values: &[f32]) -> Result<(), BakeError> {
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.out
            .write_all(&bytes)
            .map_err(|cause| BakeError::Io { path: self.tmp.clone(), cause })?;
        self.crc = crc32_update(self.crc, &bytes);
        self.len += bytes.len() as u64;
        self.blocks += (values.len() / usize::from(self.strides.max(1))) as u64;
        Ok(())
    }

    /// Completes the table, tied to `bake_id`, its first block at row-major position `first`,
    /// and renames it into place. Returns its length in bytes.
    pub(crate) fn finish(self, bake_id: u64, first: u64) -> Result<u64, BakeError> {
        use std::io::{Seek, SeekFrom};
        let Self { dir, tmp, out, strides, blocks, crc, len } = self;
        let io = |cause| BakeError::Io { path: tmp.clone(), cause };
        let mut file = out.into_inner().map_err(|e| io(e.into_error()))?;
        let mut head = Vec::with_capacity(HEAD_LEN);
        head.extend_from_slice(&MAGIC);
        head.extend_from_slice(&VERSION.to_le_bytes());
        head.extend_from_slice(&u32::from(strides).to_le_bytes());
        head.extend_from_slice(&bake_id.to_le_bytes());
        head.extend_from_slice(&first.to_le_bytes());
        head.extend_from_slice(&blocks.to_le_bytes());
        debug_assert_eq!(head.len(), HEAD_LEN);
        // The CRC-32 of the head then the values, the values' own computed as they came.
        let all = crc32_combine(crc32(&head), crc, len);
        file.write_all(&all.to_le_bytes()).map_err(io)?;
        file.seek(SeekFrom::Start(0)).map_err(io)?;
        file.write_all(&head).map_err(io)?;
        file.sync_all().map_err(io)?;
        drop(file);
        let path = dir.join(DECIMATION_FILE);
        std::fs::rename(&tmp, &path).map_err(|cause| BakeError::Io { path, cause })?;
        Ok(HEAD_LEN as u64 + len + 4)
    }

    /// Appends a shard's part's table of the blocks `first..first + count` (row-major), read
    /// from `part` and checked (its checksum, strides, first block and count). `Ok(false)`
    /// when the part has none (baked before the table existed): nothing is appended.
    pub(crate) fn push_part(
        &mut self,
        part: &Path,
        first: u64,
        count: u64,
    ) -> Result<bool, BakeError> {
        let path = part.join(DECIMATION_FILE);
        let bytes = match std::fs::read(&path) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
            Err(cause) => return Err(BakeError::Io { path, cause }),
        };
        let bad = |m: String| BakeError::BadPart {
            path: part.to_path_buf(),
            reason: format!("{DECIMATION_FILE}: {m}; bake that shard again"),
        };
        let table = parse(&bytes).map_err(bad)?;
        if (table.strides, table.first, table.blocks) != (self.strides, first, count) {
            return Err(bad(format!(
                "{} values a block for blocks {}..{}, the part's are {} values for {first}..{}",
                table.strides,
                table.first,
                table.first + table.blocks,
                self.strides,
                first + count
            )));
        }
        self.push_values(&table.values)?;
        Ok(true)
    }

    /// Drops the table and its temporary file (a merge whose parts do not all have one).
    pub(crate) fn abandon(self) -> Result<(), BakeError> {
        drop(self.out);
        std::fs::remove_file(&self.tmp).map_err(|cause| BakeError::Io { path: self.tmp, cause })
    }
}

/// A table's file, parsed and checked against its own CRC-32 and lengths.
struct Parsed {
    strides: u8,
    bake_id: u64,
    first: u64,
    blocks: u64,
    values: Vec<f32>,
}

/// Parses a table's bytes: what is wrong with them, if anything.
fn parse(bytes: &[u8]) -> Result<Parsed, String> {
    if bytes.len() < HEAD_LEN + 4 {
        return Err(format!("{} bytes, shorter than its head", bytes.len()));
    }
    let (body, crc) = bytes.split_at(bytes.len() - 4);
    if crc32(body) != u32::from_le_bytes(crc.try_into().expect("4 bytes")) {
        return Err("it fails its checksum (the file is damaged)".into());
    }
    if body[..8] != MAGIC {
        return Err("not a table of decimation errors (wrong magic bytes)".into());
    }
    let u32_at = |at: usize| u32::from_le_bytes(body[at..at + 4].try_into().expect("4 bytes"));
    let u64_at = |at: usize| u64::from_le_bytes(body[at..at + 8].try_into().expect("8 bytes"));
    let version = u32_at(8);
    if version != VERSION {
        return Err(format!("format version {version}, this reader reads {VERSION}"));
    }
    let strides = u8::try_from(u32_at(12)).map_err(|_| format!("{} strides", u32_at(12)))?;
    let (bake_id, first, blocks) = (u64_at(16), u64_at(24), u64_at(32));
    let values = &body[HEAD_LEN..];
    let want = u128::from(blocks) * u128::from(strides) * 4;
    if values.len() as u128 != want {
        return Err(format!(
            "{} bytes of values, {blocks} blocks of {strides} need {want}",
            values.len()
        ));
    }
    let values: Vec<f32> = values
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().expect("4 bytes")))
        .collect();
    if let Some(p) = values.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
        return Err(format!("value {p} is {}, not an error", values[p]));
    }
    Ok(Parsed { strides, bake_id, first, blocks, values })
}

/// A store's decimation errors per block ([`crate::Store::decimation_errors`]): for block `id`
/// its decimation error as one region of `2^k` cells at the strides `2^1..=2^k`, metres, times
/// the store's vertical exaggeration. See the module docs of `decimation.bin` for what a value
/// is; with `k` = 8 (256 cells, the default) each block is one of the `tin` method's regions.
#[derive(Debug, Clone, PartialEq)]
pub struct DecimationErrors {
    strides: u8,
    blocks_x: u32,
    blocks_y: u32,
    /// Per block in row-major order, `strides` values.
    values: Vec<f32>,
}

impl DecimationErrors {
    /// Block `id`'s errors (element `s - 1` for stride `2^s`, `k` of them); `None` for a block
    /// outside the grid.
    pub fn errors(&self, id: BlockId) -> Option<&[f32]> {
        if id.col >= self.blocks_x || id.row >= self.blocks_y {
            return None;
        }
        let pos = id.row as usize * self.blocks_x as usize + id.col as usize;
        let n = usize::from(self.strides);
        self.values.get(pos * n..(pos + 1) * n)
    }

    /// Values per block: the store's `k` (strides `2^1..=2^k`).
    pub fn strides(&self) -> u8 {
        self.strides
    }
}

/// Reads the table at `path` of the store whose header is `header`: `None` when there is
/// none; an error naming the file, saying to bake the store again, when it is damaged, of
/// another bake or of another grid. Values are multiplied by the header's vertical
/// exaggeration and raised by the heights' rounding (see [`exaggerate`]; `height_bound`: the
/// largest magnitude of the exaggerated heights).
pub(crate) fn read(
    path: &Path,
    header: &Header,
    height_bound: f32,
) -> Result<Option<DecimationErrors>, StoreError> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(cause) => return Err(StoreError::Io { path: path.to_path_buf(), cause }),
    };
    let bad = |message: String| StoreError::Decimation {
        path: path.to_path_buf(),
        message: format!("{message}; bake the store again"),
    };
    let t = parse(&bytes).map_err(bad)?;
    if t.bake_id != header.bake_id {
        return Err(bad(format!(
            "written by another bake (bake id {:016x}, the index's {:016x})",
            t.bake_id, header.bake_id
        )));
    }
    let blocks = header.block_count() as u64;
    if (t.strides, t.first, t.blocks) != (header.k, 0, blocks) {
        return Err(bad(format!(
            "{} values a block for blocks {}..{}, the store has k = {} and {blocks} blocks",
            t.strides,
            t.first,
            t.first + t.blocks,
            header.k
        )));
    }
    let mut values = t.values;
    exaggerate(&mut values, header.vertical_scale, height_bound);
    Ok(Some(DecimationErrors {
        strides: t.strides,
        blocks_x: header.blocks_x,
        blocks_y: header.blocks_y,
        values,
    }))
}

/// Decimation errors `values` of the heights as baked made those of the heights times
/// `scale` as an exaggerated store reads them (`height_bound`: their largest magnitude).
/// Each height is scaled and rounded on its own, within half an ulp (`|h| 2^-24`) of its
/// exact value, so the read heights' own error `|z - B_s|` can exceed the exactly scaled
/// error by the rounding of the sample and of the bilinear surface of its strided
/// neighbours: at most `2 x |h|max 2^-24`. Each value is scaled in f64, raised by twice that
/// (`|h|max` is itself a rounded height) and rounded up to an f32: an upper bound of the read
/// heights' error, which the `tin` method's proofs need (the scaled value alone can fall
/// short by about a millimetre at a few kilometres).
pub(crate) fn exaggerate(values: &mut [f32], scale: f64, height_bound: f32) {
    if scale == 1.0 {
        return;
    }
    let margin = 2.0 * f64::from(height_bound) * f64::from(f32::EPSILON);
    for v in values.iter_mut() {
        let x = f64::from(*v) * scale + margin;
        let f = x as f32;
        *v = if f64::from(f) < x { f.next_up() } else { f };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A block's errors never read its padding (the samples past `valid_w` and `valid_h`):
    /// with garbage there they are the errors of the valid samples alone, the strided samples
    /// past the last valid column or row reading the last one.
    #[test]
    fn a_blocks_errors_never_read_its_padding() {
        let k = 4u8;
        let side = 17;
        let mut next = crate::tests::xorshift64_star(17);
        for (valid_w, valid_h, x0, y0) in [(11, 6, 32, 48), (17, 9, 0, 16), (5, 17, 16, 0)] {
            let valid: Vec<f32> =
                (0..valid_w * valid_h).map(|_| (next() % 1000) as f32 * 0.25).collect();
            let mut z = vec![1.0e6f32; side * side];
            for j in 0..valid_h {
                z[j * side..j * side + valid_w].copy_from_slice(&valid[j * valid_w..][..valid_w]);
            }
            let at = |a: usize, b: usize| valid[b.min(valid_h - 1) * valid_w + a.min(valid_w - 1)];
            let want = region_errors(&valid, valid_w, (x0, y0), None, 4, |s, a0, b0, na, nb| {
                let t = 1usize << s;
                Ok::<_, ()>(
                    (0..na * nb)
                        .map(|p| at(a0 - x0 + (p % na) * t, b0 - y0 + (p / na) * t))
                        .collect(),
                )
            })
            .unwrap();
            let got = block_errors(&z, k, (x0, y0), valid_w, valid_h);
            assert_eq!(got, want, "{valid_w} x {valid_h}");
            assert!(got.iter().all(|&e| e > 0.0 && e < 1000.0), "{got:?}");
        }
    }
}
