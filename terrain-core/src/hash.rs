//! Integer hashing shared inside the crate: the SplitMix64 finaliser, for deterministic,
//! platform-independent pseudo-random choices (noise lattices, stratified sample offsets).

/// The SplitMix64 / MurmurHash3 `fmix64`-style finaliser (Stafford's "Mix13" constants).
#[inline(always)]
pub(crate) fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}
