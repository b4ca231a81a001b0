//! The file format of a store's baked [`GridTile`]s (`tin_tiles.bin`; the bake and the reader
//! live in terrain-app's `tin_scene`, which ties the file to a store): every decoder here
//! checks its counts against its bytes before allocating by them, so a damaged file is a
//! [`TileFileError`], never a panic.
//!
//! Layout (little-endian): a [`HEADER_BYTES`]-byte header (`TINT`, [`VERSION`], the grid and
//! tree, the settings the tiles were built for, the bake id of the store's blocks, the tile
//! count and the index's offset), the tiles one after the other, then the index
//! ([`ENTRY_BYTES`] per tile: level, column, row, stride, offset, length, CRC-32 of its bytes).
//! A tile's vertices are offsets from its node's south-west sample (16 bits each where they
//! fit), its indices 16 bits where it has at most 65,536 vertices.

use std::collections::HashMap;

use crate::bytes::{LeReader, LeWriter, Short};
use crate::checksum::crc32;
use crate::mesh::verify::MaxError;
use crate::quadtree::{NodeId, TreeShape};
use crate::tin::grid::GridTile;

/// The file's first bytes.
pub const MAGIC: &[u8; 4] = b"TINT";
/// The format version this build reads and writes.
pub const VERSION: u32 = 1;
/// Bytes of the header.
pub const HEADER_BYTES: usize = 64;
/// Bytes of an index entry.
pub const ENTRY_BYTES: usize = 32;

/// Bytes of a tile before its vertices: flags, stride, counts (vertices, triangles, the four
/// sides), bound, range, measured error, its samples and worst sample.
const TILE_HEAD_BYTES: usize = 2 + 4 * 6 + 8 + 8 + 8 + 8 + 16;

/// What a file's tiles were built for: a reader uses them only where all of it matches
/// (but `min_stride_log2`, which only says which tiles the file holds).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TileFileKey {
    /// The grid's samples across.
    pub width: u32,
    /// The grid's samples down.
    pub height: u32,
    /// Cells across the tree's root.
    pub root_cells: u32,
    /// The tree's deepest level.
    pub max_level: u32,
    /// The level bounds' scale.
    pub error_scale: f64,
    /// Most cells across a tile's mesh input.
    pub max_tile_cells: u32,
    /// How many strides finer than its own a tile is meshed at most.
    pub finer_strides: u32,
    /// The file holds the tiles whose own stride is at least `2^min_stride_log2`.
    pub min_stride_log2: u32,
    /// The bake id of the store's blocks the tiles were built from.
    pub bake_id: u64,
}

/// A file's header as read.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FileHeader {
    /// What the tiles were built for.
    pub key: TileFileKey,
    /// Tiles in the file.
    pub tiles: u32,
    /// Where the index starts.
    pub index_offset: u64,
}

/// Where a tile lies in the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Slot {
    /// The stride (log2) the tile was built at.
    pub stride_log2: u32,
    /// Its first byte.
    pub offset: u64,
    /// Its bytes.
    pub len: u32,
    /// CRC-32 of its bytes.
    pub crc: u32,
}

/// Why a file or one of its tiles does not read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TileFileError {
    /// Not this format.
    #[error("not a table of tin tiles")]
    NotTinTiles,
    /// Another version.
    #[error("version {found}, this build reads {VERSION}")]
    Version {
        /// The file's version.
        found: u32,
    },
    /// The header or a tile ends early.
    #[error("cut short: {0}")]
    Short(#[from] Short),
    /// The file's length is not its index's end.
    #[error("{len} bytes, its index says {expected}")]
    Length {
        /// The file's bytes.
        len: u64,
        /// Where its index ends.
        expected: u64,
    },
    /// An index entry of a level that cannot be.
    #[error("a tile of level {0}, past 255")]
    Level(u32),
    /// An index entry outside the file or the grid.
    #[error("tile {0:?} lies outside the file or the grid")]
    Outside(NodeId),
    /// Two index entries for one tile.
    #[error("tile {0:?} is in the index twice")]
    Twice(NodeId),
    /// A tile's bytes fail their checksum.
    #[error("tile {0:?} fails its checksum")]
    Checksum(NodeId),
    /// A tile's stride is not its index entry's.
    #[error("tile {0:?} has another stride than its index says")]
    Stride(NodeId),
    /// A tile's bytes do not decode to a tile.
    #[error("tile {node:?} is damaged ({why})")]
    Damaged {
        /// The tile.
        node: NodeId,
        /// What is wrong.
        why: String,
    },
}

/// The header of a file of `tiles` tiles built for `key` whose index starts at `index_offset`.
pub fn encode_header(key: &TileFileKey, tiles: u32, index_offset: u64) -> [u8; HEADER_BYTES] {
    let mut w = LeWriter::with_capacity(HEADER_BYTES);
    w.bytes(MAGIC);
    for v in [VERSION, key.width, key.height, key.root_cells, key.max_level] {
        w.u32(v);
    }
    w.f64(key.error_scale);
    for v in [key.max_tile_cells, key.finer_strides, key.min_stride_log2] {
        w.u32(v);
    }
    w.u64(key.bake_id);
    w.u32(tiles);
    w.u64(index_offset);
    let mut h = [0u8; HEADER_BYTES];
    h[..w.buf.len()].copy_from_slice(&w.buf);
    h
}

/// The header of a file of `file_len` bytes from its first bytes `head`: its magic, version
/// and key, and its index ending at the file's end.
pub fn parse_header(head: &[u8], file_len: u64) -> Result<FileHeader, TileFileError> {
    let mut r = LeReader::new(head);
    if r.take(4)? != MAGIC {
        return Err(TileFileError::NotTinTiles);
    }
    let found = r.u32()?;
    if found != VERSION {
        return Err(TileFileError::Version { found });
    }
    let (width, height, root_cells, max_level) = (r.u32()?, r.u32()?, r.u32()?, r.u32()?);
    let error_scale = r.f64()?;
    let (max_tile_cells, finer_strides, min_stride_log2) = (r.u32()?, r.u32()?, r.u32()?);
    let key = TileFileKey {
        width,
        height,
        root_cells,
        max_level,
        error_scale,
        max_tile_cells,
        finer_strides,
        min_stride_log2,
        bake_id: r.u64()?,
    };
    let (tiles, index_offset) = (r.u32()?, r.u64()?);
    let expected = index_offset.checked_add(u64::from(tiles) * ENTRY_BYTES as u64);
    if index_offset < HEADER_BYTES as u64 || expected != Some(file_len) {
        return Err(TileFileError::Length {
            len: file_len,
            expected: expected.unwrap_or(u64::MAX),
        });
    }
    Ok(FileHeader { key, tiles, index_offset })
}

/// The index entry of tile `node`, built at stride `2^stride_log2`, written as `bytes` at
/// `offset`.
pub fn encode_entry(
    node: NodeId,
    stride_log2: u32,
    offset: u64,
    bytes: &[u8],
) -> [u8; ENTRY_BYTES] {
    let mut w = LeWriter::with_capacity(ENTRY_BYTES);
    for v in [u32::from(node.level), node.i, node.j, stride_log2] {
        w.u32(v);
    }
    w.u64(offset);
    w.u32(bytes.len() as u32);
    w.u32(crc32(bytes));
    let mut e = [0u8; ENTRY_BYTES];
    e.copy_from_slice(&w.buf);
    e
}

/// The index `index` of a file whose tiles end at `header.index_offset`, over tree `shape`:
/// every tile inside the file and the grid, none twice.
pub fn parse_index(
    index: &[u8],
    header: &FileHeader,
    shape: &TreeShape,
) -> Result<HashMap<NodeId, Slot>, TileFileError> {
    let mut slots = HashMap::with_capacity(index.len() / ENTRY_BYTES);
    let mut r = LeReader::new(index);
    for _ in 0..header.tiles {
        let level = r.u32()?;
        let level = u8::try_from(level).map_err(|_| TileFileError::Level(level))?;
        let node = NodeId::new(level, r.u32()?, r.u32()?);
        let slot = Slot { stride_log2: r.u32()?, offset: r.u64()?, len: r.u32()?, crc: r.u32()? };
        let end = slot.offset.checked_add(u64::from(slot.len));
        if slot.offset < HEADER_BYTES as u64
            || end.is_none_or(|e| e > header.index_offset)
            || shape.clipped_rect(node).is_none()
        {
            return Err(TileFileError::Outside(node));
        }
        if slots.insert(node, slot).is_some() {
            return Err(TileFileError::Twice(node));
        }
    }
    Ok(slots)
}

/// The origin a tile's vertices are stored from: its node's south-west sample in tree
/// `shape` (the corner of its clipped rectangle), for [`encode_tile`] and [`decode_tile`].
pub fn tile_origin(shape: &TreeShape, node: NodeId) -> Result<[u32; 2], TileFileError> {
    let r = shape.clipped_rect(node).ok_or(TileFileError::Outside(node))?;
    Ok([r.x0, r.y0])
}

/// Tile `t` in bytes, its vertices as offsets from `origin`, its node's south-west sample
/// ([`tile_origin`]).
pub fn encode_tile(t: &GridTile, origin: [u32; 2]) -> Vec<u8> {
    let span = t.vertices.iter().map(|v| (v[0] - origin[0]).max(v[1] - origin[1])).max();
    let wide_xy = span.unwrap_or(0) > u32::from(u16::MAX);
    let wide_idx = t.vertices.len() > 1 << 16;
    let sides: usize = t.sides.iter().map(Vec::len).sum();
    let mut w = LeWriter::with_capacity(
        TILE_HEAD_BYTES + t.vertices.len() * 8 + t.triangles.len() * 6 + sides * 2,
    );
    let idx = |w: &mut LeWriter, v: u32| if wide_idx { w.u32(v) } else { w.u16(v as u16) };
    w.u8(u8::from(wide_xy) | u8::from(wide_idx) << 1);
    w.u8(t.stride_log2 as u8);
    w.u32(t.vertices.len() as u32);
    w.u32(t.triangles.len() as u32);
    for s in &t.sides {
        w.u32(s.len() as u32);
    }
    w.f64(t.bound);
    w.f32(t.range[0]);
    w.f32(t.range[1]);
    w.f64(t.measured.max_error);
    w.u64(t.measured.samples as u64);
    let worst = t.measured.worst.map_or([u64::MAX; 2], |(i, j)| [i as u64, j as u64]);
    w.u64(worst[0]);
    w.u64(worst[1]);
    for v in &t.vertices {
        for (c, o) in v.iter().zip(origin) {
            if wide_xy { w.u32(c - o) } else { w.u16((c - o) as u16) }
        }
    }
    for &z in &t.heights {
        w.f32(z);
    }
    for tri in &t.triangles {
        for &v in tri {
            idx(&mut w, v);
        }
    }
    for s in &t.sides {
        for &v in s {
            idx(&mut w, v);
        }
    }
    w.buf
}

/// Tile `node` from the bytes [`encode_tile`] wrote with `origin`.
pub fn decode_tile(
    node: NodeId,
    bytes: &[u8],
    origin: [u32; 2],
) -> Result<GridTile, TileFileError> {
    let damaged = |why: &str| TileFileError::Damaged { node, why: why.into() };
    let mut r = LeReader::new(bytes);
    let flags = r.u8()?;
    let (wide_xy, wide_idx) = (flags & 1 != 0, flags & 2 != 0);
    let stride_log2 = u32::from(r.u8()?);
    let (nv, nt) = (r.u32()? as usize, r.u32()? as usize);
    let mut side_lens = [0usize; 4];
    for s in &mut side_lens {
        *s = r.u32()? as usize;
    }
    // Counts checked against the bytes before anything is allocated by them.
    let (xy, ix) = (if wide_xy { 4 } else { 2 }, if wide_idx { 4 } else { 2 });
    let need = nv
        .checked_mul(2 * xy + 4)
        .zip(nt.checked_mul(3 * ix))
        .and_then(|(a, b)| a.checked_add(b)?.checked_add(side_lens.iter().sum::<usize>() * ix))
        .and_then(|n| n.checked_add(TILE_HEAD_BYTES - r.pos()));
    if need.is_none_or(|n| n > r.remaining()) {
        return Err(damaged("its counts exceed its bytes"));
    }
    let bound = r.f64()?;
    let range = [r.f32()?, r.f32()?];
    let max_error = r.f64()?;
    let samples = r.u64()? as usize;
    let worst = [r.u64()?, r.u64()?];
    let worst = (worst != [u64::MAX; 2]).then(|| (worst[0] as usize, worst[1] as usize));
    let mut vertices = Vec::with_capacity(nv);
    for _ in 0..nv {
        let mut v = [0u32; 2];
        for (k, o) in origin.iter().enumerate() {
            let d = if wide_xy { r.u32()? } else { u32::from(r.u16()?) };
            v[k] = o.checked_add(d).ok_or_else(|| damaged("a vertex past the grid"))?;
        }
        vertices.push(v);
    }
    let heights = (0..nv).map(|_| r.f32()).collect::<Result<Vec<f32>, Short>>()?;
    let index = |r: &mut LeReader<'_>| -> Result<u32, TileFileError> {
        let v = if wide_idx { r.u32()? } else { u32::from(r.u16()?) };
        if v as usize >= nv {
            return Err(damaged("a vertex index past the tile's vertices"));
        }
        Ok(v)
    };
    let mut triangles = Vec::with_capacity(nt);
    for _ in 0..nt {
        triangles.push([index(&mut r)?, index(&mut r)?, index(&mut r)?]);
    }
    let mut sides: [Vec<u32>; 4] = Default::default();
    for (s, &n) in sides.iter_mut().zip(&side_lens) {
        *s = (0..n).map(|_| index(&mut r)).collect::<Result<_, _>>()?;
    }
    if r.remaining() != 0 {
        return Err(damaged("longer than its counts"));
    }
    Ok(GridTile {
        node,
        vertices,
        heights,
        stride_log2,
        range,
        triangles,
        sides,
        bound,
        measured: MaxError { max_error, samples, worst },
    })
}

/// Tile `node` of tree `shape` from its bytes `bytes` at `slot`: its checksum, its decoding
/// and its stride checked.
pub fn read_tile(
    node: NodeId,
    slot: &Slot,
    bytes: &[u8],
    shape: &TreeShape,
) -> Result<GridTile, TileFileError> {
    if bytes.len() != slot.len as usize || crc32(bytes) != slot.crc {
        return Err(TileFileError::Checksum(node));
    }
    let tile = decode_tile(node, bytes, tile_origin(shape, node)?).map_err(|e| match e {
        TileFileError::Short(s) => TileFileError::Damaged { node, why: s.to_string() },
        e => e,
    })?;
    if tile.stride_log2 != slot.stride_log2 {
        return Err(TileFileError::Stride(node));
    }
    Ok(tile)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tile() -> GridTile {
        GridTile {
            node: NodeId::new(1, 1, 0),
            vertices: vec![[512, 0], [1024, 0], [512, 512], [1024, 512]],
            heights: vec![1.0, -2.5, 3.25, 8848.0],
            stride_log2: 3,
            range: [-2.5, 8848.0],
            triangles: vec![[0, 1, 3], [0, 3, 2]],
            sides: [vec![2, 3], vec![1, 3], vec![0, 1], vec![0, 2]],
            bound: 12.5,
            measured: MaxError { max_error: 3.0, samples: 4225, worst: Some((700, 3)) },
        }
    }

    fn same(a: &GridTile, b: &GridTile) {
        assert_eq!(a.node, b.node);
        assert_eq!(a.vertices, b.vertices);
        assert_eq!(
            a.heights.iter().map(|z| z.to_bits()).collect::<Vec<_>>(),
            b.heights.iter().map(|z| z.to_bits()).collect::<Vec<_>>()
        );
        assert_eq!(
            (a.stride_log2, a.range, &a.triangles, &a.sides),
            (b.stride_log2, b.range, &b.triangles, &b.sides)
        );
        assert_eq!((a.bound.to_bits(), a.measured), (b.bound.to_bits(), b.measured));
    }

    #[test]
    fn a_tile_decodes_to_itself_narrow_and_wide() {
        let t = tile();
        let bytes = encode_tile(&t, [512, 0]);
        same(&decode_tile(t.node, &bytes, [512, 0]).unwrap(), &t);
        // Offsets past 16 bits and no worst sample.
        let mut w = t.clone();
        w.vertices[3] = [512 + 70_000, 70_000];
        w.measured.worst = None;
        let bytes = encode_tile(&w, [512, 0]);
        assert_eq!(bytes[0] & 1, 1, "wide offsets");
        same(&decode_tile(w.node, &bytes, [512, 0]).unwrap(), &w);
    }

    /// Every byte of a tile set to each of a few values (its counts, flags and offsets among
    /// them): decoding returns a tile or an error, never panics, and never allocates by a
    /// count its bytes cannot hold.
    #[test]
    fn mutated_tiles_decode_or_fail_without_panicking() {
        let t = tile();
        let bytes = encode_tile(&t, [512, 0]);
        let (mut ok, mut failed) = (0, 0);
        for at in 0..bytes.len() {
            for v in [0u8, 1, 0x7f, 0x80, 0xff] {
                let mut m = bytes.clone();
                m[at] = v;
                match decode_tile(t.node, &m, [512, 0]) {
                    Ok(d) => {
                        ok += 1;
                        assert_eq!(d.heights.len(), d.vertices.len());
                    }
                    Err(_) => failed += 1,
                }
            }
        }
        assert!(ok > 0 && failed > 0, "{ok} decoded, {failed} refused");
        // Offsets past the grid's coordinates.
        assert!(decode_tile(t.node, &bytes, [u32::MAX - 10, 0]).is_err());
    }

    #[test]
    fn a_truncated_or_lengthened_tile_is_an_error_not_a_panic() {
        let t = tile();
        let bytes = encode_tile(&t, [512, 0]);
        for n in 0..bytes.len() {
            assert!(decode_tile(t.node, &bytes[..n], [512, 0]).is_err(), "cut at {n}");
        }
        let mut long = bytes.clone();
        long.push(0);
        assert!(decode_tile(t.node, &long, [512, 0]).is_err());
        // A count far past the bytes.
        let mut huge = bytes;
        huge[2..6].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(decode_tile(t.node, &huge, [512, 0]), Err(TileFileError::Damaged { .. })));
    }

    /// A whole file in memory: header, tiles and index read back; each damage its error.
    #[test]
    fn a_file_reads_back_and_its_damage_is_named() {
        let shape = TreeShape::new(1025, 1025, 64, glam::DVec2::ZERO, glam::DVec2::ONE);
        let t = tile();
        let key = TileFileKey {
            width: 1025,
            height: 1025,
            root_cells: 1024,
            max_level: shape.max_level().into(),
            error_scale: 1.0,
            max_tile_cells: 64,
            finer_strides: 2,
            min_stride_log2: 4,
            bake_id: 0xfeed,
        };
        let bytes = encode_tile(&t, [512, 0]);
        let mut file = vec![0u8; HEADER_BYTES];
        let at = file.len() as u64;
        file.extend_from_slice(&bytes);
        let index_offset = file.len() as u64;
        file.extend_from_slice(&encode_entry(t.node, t.stride_log2, at, &bytes));
        file[..HEADER_BYTES].copy_from_slice(&encode_header(&key, 1, index_offset));
        let len = file.len() as u64;
        let header = parse_header(&file[..HEADER_BYTES], len).unwrap();
        assert_eq!(header, FileHeader { key, tiles: 1, index_offset });
        let slots = parse_index(&file[index_offset as usize..], &header, &shape).unwrap();
        let slot = slots[&t.node];
        let tile_bytes = &file[slot.offset as usize..][..slot.len as usize];
        // (Tile (1, 1, 0) lies at x 512: its vertices are offsets from there.)
        same(&read_tile(t.node, &slot, tile_bytes, &shape).unwrap(), &t);

        let mut bad = file.clone();
        bad[0] = b'X';
        assert_eq!(parse_header(&bad[..HEADER_BYTES], len), Err(TileFileError::NotTinTiles));
        bad = file.clone();
        bad[4] = 9;
        assert_eq!(
            parse_header(&bad[..HEADER_BYTES], len),
            Err(TileFileError::Version { found: 9 })
        );
        assert!(matches!(
            parse_header(&file[..HEADER_BYTES], len - 1),
            Err(TileFileError::Length { .. })
        ));
        assert!(matches!(parse_header(&file[..10], len), Err(TileFileError::Short(_))));
        // An entry past the tiles, of another tile's place, twice.
        let mut index = file[index_offset as usize..].to_vec();
        index[16..24].copy_from_slice(&index_offset.to_le_bytes());
        assert_eq!(parse_index(&index, &header, &shape), Err(TileFileError::Outside(t.node)));
        let two = FileHeader { tiles: 2, ..header };
        let twice = [&file[index_offset as usize..], &file[index_offset as usize..]].concat();
        assert_eq!(parse_index(&twice, &two, &shape), Err(TileFileError::Twice(t.node)));
        index = file[index_offset as usize..].to_vec();
        index[0..4].copy_from_slice(&300u32.to_le_bytes());
        assert_eq!(parse_index(&index, &header, &shape), Err(TileFileError::Level(300)));
        // A flipped byte of the tile; another stride in its entry.
        let mut flipped = tile_bytes.to_vec();
        flipped[40] ^= 1;
        assert_eq!(
            read_tile(t.node, &slot, &flipped, &shape),
            Err(TileFileError::Checksum(t.node))
        );
        let other = Slot { stride_log2: 2, ..slot };
        assert_eq!(
            read_tile(t.node, &other, tile_bytes, &shape),
            Err(TileFileError::Stride(t.node))
        );
    }
}
