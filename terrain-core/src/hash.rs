//! Integer hashing: the SplitMix64 finaliser, for deterministic, platform-independent
//! pseudo-random choices (noise lattices, stratified sample offsets), and [`KeyHasher`], the
//! hasher of maps keyed by integers ([`IdMap`], [`KeyMap`]: lattice points, [`NodeId::key`],
//! a store's block ids), whose order is the same from run to run.
//!
//! [`NodeId::key`]: crate::quadtree::NodeId::key

/// The SplitMix64 / MurmurHash3 `fmix64`-style finaliser (Stafford's "Mix13" constants).
#[inline(always)]
pub(crate) fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A multiply-shift hasher for keys that are integers packed into a `u64` (lattice points,
/// [`NodeId::key`](crate::quadtree::NodeId::key)) or a few `u32` (a store's block ids), where
/// the default SipHash is a measurable share of the work: the entropy method's crack
/// elimination, the PVPS selections' map of patch corners, a store's cache of blocks. Its
/// output is fixed (no random state), so a map's iteration order is the same from run to
/// run. Not for keys an adversary chooses (no flooding resistance).
#[derive(Debug, Default, Clone, Copy)]
pub struct KeyHasher(u64);

impl std::hash::Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x100_0000_01B3);
        }
    }
    fn write_u64(&mut self, k: u64) {
        let z = (k ^ (k >> 29)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        self.0 = z ^ (z >> 32);
    }
    /// A key of several `u32` fields (a derived `Hash`, e.g. a block's row and column): each
    /// mixed in after the ones before, shifted out of its way.
    fn write_u32(&mut self, k: u32) {
        self.write_u64(self.0.rotate_left(32) ^ u64::from(k));
    }
    fn write_usize(&mut self, k: usize) {
        self.write_u64(k as u64);
    }
}

/// A map keyed by packed integers, hashed by [`KeyHasher`].
pub type KeyMap<V> = IdMap<u64, V>;

/// A map keyed by a few integers (a `u64`, a `usize`, a derived `Hash` of `u32` fields such
/// as a store's block ids), hashed by [`KeyHasher`].
pub type IdMap<K, V> = std::collections::HashMap<K, V, std::hash::BuildHasherDefault<KeyHasher>>;

#[cfg(test)]
mod tests {
    use super::*;
    use std::hash::{BuildHasher, BuildHasherDefault};

    /// Keys of two `u32` fields (a derived `Hash`, as a store's block ids) and single `u64`
    /// keys hash without a collision over a grid of small values (a hasher that kept only the
    /// last field, or left the fields' order out, fails it).
    #[test]
    fn small_keys_of_u32_fields_and_u64_hash_apart() {
        let b = BuildHasherDefault::<KeyHasher>::default();
        let mut seen = std::collections::HashSet::new();
        for row in 0..128u32 {
            for col in 0..128u32 {
                assert!(seen.insert(b.hash_one((row, col))), "({row}, {col})");
            }
        }
        let mut seen = std::collections::HashSet::new();
        for k in 0..16_384u64 {
            assert!(seen.insert(b.hash_one(k)), "{k}");
        }
    }
}
