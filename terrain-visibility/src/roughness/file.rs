//! The PVPS methods' roughness pyramids as bytes (`roughness.bin` in a scene or store folder
//! that `terrain bake` writes), so a method reads them instead of computing them from the whole
//! grid (a store-backed method has no grid in memory).
//!
//! Layout (little-endian):
//!
//! ```text
//! magic "TRGH" | version u32 = 1 | width u32 | height u32 | root_cells u32 | levels u32 |
//! heights u32 (CRC-32 of the heights and void mask: lod::dss_file::heights_checksum) |
//! store index u32 (CRC-32 of the store's index content) | store bake_id u64 (both 0: written
//! into no store) | max_slope_deg f64 (RoughnessConfig) |
//! pyramids A, B, C: per level 0 .. levels, 4^level f32 row-major from the south |
//! crc32 u32 (of every byte before it)
//! ```
//!
//! Values are stored as f32 bits, so pyramids read back equal the computed ones bit for bit.
//! A file is tied to its terrain in two ways, and a reader checks the one it can:
//!
//! * **Heights** ([`TerrainTie::Heights`]): a reader with the heightmap (the in-memory methods)
//!   compares the heights' CRC-32, the same one the DSS error table uses, so a file baked from
//!   another DEM, crop, void filling or vertical scale is refused.
//! * **Store** ([`TerrainTie::Store`]): a reader without the heightmap (a method drawing from a
//!   baked store) compares the store's `bake_id` (terrain-stream's index header: a hash of every
//!   stored level's checksum) and the CRC-32 of the store's index content (the index file less
//!   its own trailing CRC), both recorded here by the bake after it wrote the blocks. The id
//!   alone is not enough: an integer DEM baked with another vertical scale stores the same
//!   integer codes (same id) with another step in the index header; the index also holds the
//!   georeference and every block's min/max and errors in metres. Reading the index is cheap
//!   (no heights), the store format stays unchanged, and a bake is deterministic, so re-baking
//!   the same DEM with the same settings gives the same index and the same pyramids. A file
//!   written into no store (both 0) never matches a store.
//!
//! Either way the grid size, the level count (the quadtree's `max_level + 1` for the reader's
//! leaf size; the pyramids' parents are sums of their children, so levels are not dropped) and
//! the slope clamp must match. terrain-visibility does no file I/O here; the app names the file.

use super::{NodePyramid, RoughnessConfig, RoughnessTables, root_cells};
use terrain_core::checksum::crc32;

/// The magic bytes.
pub const MAGIC: [u8; 4] = *b"TRGH";
/// The format version this build reads and writes.
pub const VERSION: u32 = 1;
/// The fixed header: magic, seven u32, bake id, slope clamp.
const HEADER_LEN: usize = 4 + 4 * 7 + 8 + 8;
/// Most levels a file may hold (a 2^20 root at leaf 1: far above any grid).
const MAX_LEVELS: u32 = 21;

/// Why a roughness table's bytes cannot be used: the table files' one error.
pub type RoughnessFileError = terrain_core::checksum::TableFileError;

/// The kind of table, in its errors.
const TABLE: &str = "roughness table";

/// What ties a file to the terrain its reader has.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TerrainTie {
    /// The heights' checksum ([`terrain_core::lod::dss_file::heights_checksum`]).
    Heights(u32),
    /// A baked store's `bake_id` and a 32-bit hash of its index content.
    Store {
        /// The store header's `bake_id`.
        bake_id: u64,
        /// A 32-bit hash of the index file's bytes before its own trailing CRC-32 (the store
        /// reader's choice: terrain-app's `roughness_scene::store_tie`).
        index_crc: u32,
    },
}

/// What a file holds besides the values.
#[derive(Debug, Clone, PartialEq)]
pub struct RoughnessHeader {
    /// Columns of the grid.
    pub width: u32,
    /// Rows of the grid.
    pub height: u32,
    /// Cells the quadtree's root covers.
    pub root_cells: u32,
    /// Levels of each pyramid.
    pub levels: u32,
    /// The heights' checksum.
    pub heights_checksum: u32,
    /// A 32-bit hash of the store's index content, 0 when written into no store.
    pub index_crc: u32,
    /// The store's `bake_id`, 0 when written into no store.
    pub bake_id: u64,
    /// [`RoughnessConfig::max_slope_deg`] of method C.
    pub max_slope_deg: f64,
}

/// What a reader expects of a file.
#[derive(Debug, Clone, PartialEq)]
pub struct Expected {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Levels the reader's quadtree has (`max_level + 1`).
    pub levels: usize,
    /// Method C's settings.
    pub config: RoughnessConfig,
    /// The terrain.
    pub tie: TerrainTie,
}

fn values_len(levels: u32) -> usize {
    // 3 pyramids x (4^levels - 1) / 3 nodes x 4 bytes.
    ((1usize << (2 * levels as usize)) - 1) * 4
}

/// The file's bytes for `tables` of a `width x height` grid with heights checksum `heights`,
/// written into the store `store` (`(bake_id, index_crc)`; `None`: no store), computed with
/// `config`.
pub fn encode(
    tables: &RoughnessTables,
    width: usize,
    height: usize,
    heights: u32,
    store: Option<(u64, u32)>,
    config: &RoughnessConfig,
) -> Vec<u8> {
    let (bake_id, index_crc) = store.unwrap_or((0, 0));
    let levels = tables.levels() as u32;
    let mut out = Vec::with_capacity(HEADER_LEN + values_len(levels) + 4);
    out.extend_from_slice(&MAGIC);
    for v in [
        VERSION,
        width as u32,
        height as u32,
        root_cells(width, height) as u32,
        levels,
        heights,
        index_crc,
    ] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&bake_id.to_le_bytes());
    out.extend_from_slice(&config.max_slope_deg.to_le_bytes());
    for p in [&tables.a, &tables.b, &tables.c] {
        for l in 0..p.levels() {
            for v in p.level(l) {
                out.extend_from_slice(&v.to_bits().to_le_bytes());
            }
        }
    }
    let crc = crc32(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

/// Reads a file whole: refused unless it has the magic, this version, its length and its
/// checksum. Says nothing about which terrain it fits: see [`decode_for`].
pub fn decode(bytes: &[u8]) -> Result<(RoughnessHeader, RoughnessTables), RoughnessFileError> {
    if bytes.len() < 4 || bytes[..4] != MAGIC {
        return Err(RoughnessFileError::Magic { table: TABLE });
    }
    if bytes.len() < HEADER_LEN {
        return Err(RoughnessFileError::Truncated { len: bytes.len(), needed: HEADER_LEN });
    }
    let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().expect("4 bytes"));
    let u64_at = |o: usize| u64::from_le_bytes(bytes[o..o + 8].try_into().expect("8 bytes"));
    let version = u32_at(4);
    if version != VERSION {
        return Err(RoughnessFileError::Version {
            table: TABLE,
            found: version,
            expected: VERSION,
        });
    }
    let header = RoughnessHeader {
        width: u32_at(8),
        height: u32_at(12),
        root_cells: u32_at(16),
        levels: u32_at(20),
        heights_checksum: u32_at(24),
        index_crc: u32_at(28),
        bake_id: u64_at(32),
        max_slope_deg: f64::from_bits(u64_at(40)),
    };
    if header.levels == 0 || header.levels > MAX_LEVELS {
        return Err(RoughnessFileError::Layout(format!("{} levels", header.levels)));
    }
    let needed = HEADER_LEN + values_len(header.levels) + 4;
    if bytes.len() != needed {
        return Err(RoughnessFileError::Truncated { len: bytes.len(), needed });
    }
    let stored = u32_at(needed - 4);
    let computed = crc32(&bytes[..needed - 4]);
    if stored != computed {
        return Err(RoughnessFileError::Checksum { stored, computed });
    }
    if header.width == 0
        || header.height == 0
        || root_cells(header.width as usize, header.height as usize) != header.root_cells as usize
    {
        return Err(RoughnessFileError::Layout(format!(
            "a {} x {} grid with a root of {} cells",
            header.width, header.height, header.root_cells
        )));
    }
    let mut at = HEADER_LEN;
    let mut pyramid = || {
        let levels = (0..header.levels as usize)
            .map(|l| {
                let n = 1usize << (2 * l);
                let v: Vec<f32> = bytes[at..at + 4 * n]
                    .chunks_exact(4)
                    .map(|b| f32::from_bits(u32::from_le_bytes(b.try_into().expect("4 bytes"))))
                    .collect();
                at += 4 * n;
                v
            })
            .collect();
        NodePyramid { levels, root_cells: header.root_cells as usize }
    };
    let (a, b, c) = (pyramid(), pyramid(), pyramid());
    Ok((header, RoughnessTables { a, b, c }))
}

/// Reads a file for the terrain a reader has ([`Expected`]): [`decode`], then refused unless
/// made for this grid size, level count, slope clamp and terrain ([`TerrainTie`]).
pub fn decode_for(
    bytes: &[u8],
    expected: &Expected,
) -> Result<RoughnessTables, RoughnessFileError> {
    let (header, tables) = decode(bytes)?;
    let mismatch = |what: &str, file: String, here: String| {
        Err(RoughnessFileError::Mismatch(format!("{what} {file} in the file, {here} here")))
    };
    if (header.width as usize, header.height as usize) != (expected.width, expected.height) {
        return mismatch(
            "grid",
            format!("{} x {}", header.width, header.height),
            format!("{} x {}", expected.width, expected.height),
        );
    }
    if header.levels as usize != expected.levels {
        return mismatch(
            "quadtree levels",
            header.levels.to_string(),
            format!("{} (another leaf size)", expected.levels),
        );
    }
    if header.max_slope_deg.to_bits() != expected.config.max_slope_deg.to_bits() {
        return mismatch(
            "slope clamp",
            format!("{} deg", header.max_slope_deg),
            format!("{} deg", expected.config.max_slope_deg),
        );
    }
    match expected.tie {
        TerrainTie::Heights(crc) if crc != header.heights_checksum => {
            Err(RoughnessFileError::Mismatch(
                "the heights differ (another DEM, crop, void filling or vertical scale)".into(),
            ))
        }
        TerrainTie::Store { bake_id, index_crc }
            if (bake_id, index_crc) != (header.bake_id, header.index_crc)
                || (bake_id, index_crc) == (0, 0) =>
        {
            Err(RoughnessFileError::Mismatch(format!(
                "baked for store {:016x} (index hash {:08x}), this store is {bake_id:016x} (index hash {index_crc:08x}): another store, or baked again since",
                header.bake_id, header.index_crc
            )))
        }
        _ => Ok(tables),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use terrain_core::lod::dss_file::heights_checksum;
    use terrain_core::synth::FractalConfig;

    fn setup() -> (terrain_core::Heightmap, RoughnessTables, Vec<u8>, Expected) {
        let hm = FractalConfig::with_size(75, 40, 10.0).to_heightmap().unwrap();
        let config = RoughnessConfig::default();
        let tables = RoughnessTables::compute(&hm, 4, &config);
        let crc = heights_checksum(&hm);
        let bytes = encode(&tables, 75, 40, crc, Some((0x1234, 0xabcd)), &config);
        let expected =
            Expected { width: 75, height: 40, levels: 4, config, tie: TerrainTie::Heights(crc) };
        (hm, tables, bytes, expected)
    }

    #[test]
    fn tables_read_back_equal_the_computed_ones_bit_for_bit() {
        let (_, tables, bytes, expected) = setup();
        assert!(tables.c.level(3).iter().any(|&v| v > 0.0));
        let back = decode_for(&bytes, &expected).unwrap();
        assert!(back.bits_eq(&tables));
        let store =
            Expected { tie: TerrainTie::Store { bake_id: 0x1234, index_crc: 0xabcd }, ..expected };
        assert!(decode_for(&bytes, &store).unwrap().bits_eq(&tables));
        let (header, _) = decode(&bytes).unwrap();
        assert_eq!(
            (header.width, header.height, header.root_cells, header.levels),
            (75, 40, 128, 4)
        );
        assert_eq!((header.bake_id, header.index_crc), (0x1234, 0xabcd));
        assert_eq!(bytes.len(), HEADER_LEN + 3 * 85 * 4 + 4);
    }

    #[test]
    fn damaged_files_are_refused() {
        let (_, _, bytes, expected) = setup();
        let dec = |b: &[u8]| decode_for(b, &expected).unwrap_err();
        assert_eq!(dec(b"TDSS\x01\0\0\0"), RoughnessFileError::Magic { table: TABLE });
        assert_eq!(dec(b""), RoughnessFileError::Magic { table: TABLE });
        assert!(matches!(dec(&bytes[..20]), RoughnessFileError::Truncated { .. }));
        assert!(matches!(dec(&bytes[..bytes.len() - 1]), RoughnessFileError::Truncated { .. }));
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(matches!(dec(&longer), RoughnessFileError::Truncated { .. }));
        for at in [HEADER_LEN + 3, bytes.len() / 2, bytes.len() - 5, 10] {
            let mut flipped = bytes.clone();
            flipped[at] ^= 0x10;
            assert!(matches!(dec(&flipped), RoughnessFileError::Checksum { .. }), "byte {at}");
        }
        let mut v2 = bytes.clone();
        v2[4] = 2;
        assert_eq!(
            dec(&v2),
            RoughnessFileError::Version { table: TABLE, found: 2, expected: VERSION }
        );
        assert!(dec(&v2).to_string().contains("bake it again"));
        let mut levels = bytes.clone();
        levels[20] = 40;
        assert!(matches!(dec(&levels), RoughnessFileError::Layout(_)));
    }

    #[test]
    fn files_of_another_terrain_are_refused() {
        let (hm, tables, bytes, expected) = setup();
        // Same size, other heights (a vertical scale): the heights' checksum.
        let scaled = terrain_core::Heightmap::from_fn(75, 40, hm.georef().clone(), |i, j| {
            hm.get(i, j) * 2.0
        })
        .unwrap();
        let other =
            Expected { tie: TerrainTie::Heights(heights_checksum(&scaled)), ..expected.clone() };
        let e = decode_for(&bytes, &other).unwrap_err();
        assert!(e.to_string().contains("heights differ"), "{e}");
        // Another store, and a file written beside no store.
        let e = decode_for(
            &bytes,
            &Expected {
                tie: TerrainTie::Store { bake_id: 7, index_crc: 0xabcd },
                ..expected.clone()
            },
        )
        .unwrap_err();
        assert!(e.to_string().contains("baked for store 0000000000001234"), "{e}");
        let none = encode(&tables, 75, 40, 0, None, &expected.config);
        let e = decode_for(
            &none,
            &Expected { tie: TerrainTie::Store { bake_id: 0, index_crc: 0 }, ..expected.clone() },
        );
        assert!(matches!(e, Err(RoughnessFileError::Mismatch(_))));
        // Another grid, leaf size, slope clamp.
        let e = decode_for(&bytes, &Expected { width: 76, ..expected.clone() }).unwrap_err();
        assert!(e.to_string().contains("grid 75 x 40 in the file, 76 x 40 here"), "{e}");
        let e = decode_for(&bytes, &Expected { levels: 5, ..expected.clone() }).unwrap_err();
        assert!(e.to_string().contains("quadtree levels 4"), "{e}");
        let config = RoughnessConfig { max_slope_deg: 80.0 };
        let e = decode_for(&bytes, &Expected { config, ..expected }).unwrap_err();
        assert!(e.to_string().contains("slope clamp"), "{e}");
    }
}
