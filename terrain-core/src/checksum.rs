//! CRC-32 for the engine's file formats (the block store, PVS files, DSS error tables): one
//! implementation, so every file is checked with the same function; and the one error of the
//! per-node table files ([`TableFileError`]: the DSS errors, the roughness pyramids,
//! geomorph's table), which share their framing (magic, version, CRC-32, what they were made
//! for).

/// CRC-32 (IEEE 802.3, reflected, polynomial 0xEDB88320), as zlib and PNG compute it
/// (crc32fast: SIMD where the CPU has it, a table otherwise; the same values either way).
pub fn crc32(bytes: &[u8]) -> u32 {
    crc32_update(0, bytes)
}

/// The start of an FNV-1a (64-bit) hash, for [`fnv1a_update`].
pub const FNV1A_START: u64 = 0xcbf2_9ce4_8422_2325;

/// Continues a 64-bit FNV-1a hash over `bytes` (Fowler, Noll and Vo; offset basis
/// [`FNV1A_START`], prime `0x100_0000_01b3`): the fingerprints the tests and benchmarks pin.
pub fn fnv1a_update(mut h: u64, bytes: &[u8]) -> u64 {
    for &b in bytes {
        h = (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
    }
    h
}

/// Continues a CRC-32: `crc32_update(crc32(a), b) == crc32(a ++ b)`, for checksumming data
/// that is not in one slice (a heightmap's samples, converted as they go).
pub fn crc32_update(crc: u32, bytes: &[u8]) -> u32 {
    let mut h = crc32fast::Hasher::new_with_initial(crc);
    h.update(bytes);
    h.finalize()
}

/// The CRC-32 of `a ++ b` from `crc32(a)`, `crc32(b)` and `b`'s length, without `b`'s bytes:
/// zlib's `crc32_combine` (Adler, zlib 1.2: appending `len_b` zero bytes is a linear map over
/// GF(2), applied by repeated squaring of the one-zero-bit operator). Lets a checksum over two
/// interleaved streams (a grid's samples, then its void flags) be computed in one pass.
pub fn crc32_combine(crc_a: u32, crc_b: u32, len_b: u64) -> u32 {
    fn times(mat: &[u32; 32], mut vec: u32) -> u32 {
        let mut sum = 0;
        let mut i = 0;
        while vec != 0 {
            if vec & 1 != 0 {
                sum ^= mat[i];
            }
            vec >>= 1;
            i += 1;
        }
        sum
    }
    fn square(mat: &[u32; 32]) -> [u32; 32] {
        std::array::from_fn(|n| times(mat, mat[n]))
    }
    if len_b == 0 {
        return crc_a;
    }
    // The operator for one zero bit, then two, then four.
    let mut odd = [0u32; 32];
    odd[0] = 0xEDB8_8320;
    for (n, o) in odd.iter_mut().enumerate().skip(1) {
        *o = 1 << (n - 1);
    }
    let mut even = square(&odd);
    odd = square(&even);
    let (mut crc, mut len) = (crc_a, len_b);
    // Each round squares the operator (one byte, two, four...) and applies it per set bit.
    loop {
        even = square(&odd);
        if len & 1 != 0 {
            crc = times(&even, crc);
        }
        len >>= 1;
        if len == 0 {
            break;
        }
        odd = square(&even);
        if len & 1 != 0 {
            crc = times(&odd, crc);
        }
        len >>= 1;
        if len == 0 {
            break;
        }
    }
    crc ^ crc_b
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32_matches_the_standard_check_value() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(b""), 0);
    }

    /// The published FNV-1a 64 test vectors ("" is the offset basis; "a" and "foobar").
    #[test]
    fn fnv1a_matches_the_published_vectors() {
        assert_eq!(fnv1a_update(FNV1A_START, b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a_update(FNV1A_START, b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(fnv1a_update(FNV1A_START, b"foobar"), 0x8594_4171_f739_67e8);
        assert_eq!(fnv1a_update(fnv1a_update(FNV1A_START, b"foo"), b"bar"), 0x8594_4171_f739_67e8);
    }

    #[test]
    fn update_continues_a_checksum() {
        let all = b"terrain engine block store";
        for split in [0, 1, 7, all.len()] {
            let (a, b) = all.split_at(split);
            assert_eq!(crc32_update(crc32(a), b), crc32(all), "split at {split}");
        }
    }

    #[test]
    fn combine_equals_the_checksum_of_the_concatenation() {
        let all: Vec<u8> = (0..3000u32).map(|k| (k * 7919 % 251) as u8).collect();
        for split in [0, 1, 2, 3, 4, 5, 8, 100, 1023, 2999, 3000] {
            let (a, b) = all.split_at(split);
            assert_eq!(
                crc32_combine(crc32(a), crc32(b), b.len() as u64),
                crc32(&all),
                "split at {split}"
            );
        }
    }
}

/// Why a per-node table file's bytes cannot be used: the one error of the table files (the DSS
/// paper's errors, the PVPS roughness pyramids, geomorph's max-error vertices), which share
/// their framing. `table` names the kind of file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TableFileError {
    /// Not this kind of table (wrong magic bytes).
    #[error("not a {table} (wrong magic bytes)")]
    Magic {
        /// The kind of table expected.
        table: &'static str,
    },
    /// Another format version.
    #[error("{table} format version {found}, this build reads version {expected}: bake it again")]
    Version {
        /// The kind of table.
        table: &'static str,
        /// The version found.
        found: u32,
        /// The version this build reads.
        expected: u32,
    },
    /// Shorter or longer than its header says.
    #[error("truncated: {len} bytes, the header needs {needed}")]
    Truncated {
        /// Bytes present.
        len: usize,
        /// Bytes the header implies.
        needed: usize,
    },
    /// The checksum does not match (a damaged file).
    #[error(
        "checksum mismatch (stored {stored:#010x}, computed {computed:#010x}): the file is damaged"
    )]
    Checksum {
        /// Stored CRC-32.
        stored: u32,
        /// Computed CRC-32.
        computed: u32,
    },
    /// Inconsistent values inside the file.
    #[error("inconsistent table: {0}")]
    Layout(String),
    /// Made for another terrain, store, grid, leaf or patch size.
    #[error("made for another terrain: {0}")]
    Mismatch(String),
    /// A page of a table read by pages cannot be used (found when a frame first needs it).
    #[error("{file}, page {page} (at byte {offset}): {cause}")]
    Page {
        /// The file's name.
        file: String,
        /// The page.
        page: usize,
        /// Where it starts in the file.
        offset: u64,
        /// What is wrong with it.
        cause: Box<TableFileError>,
    },
    /// The file could not be read.
    #[error("read failed: {0}")]
    Read(String),
}
