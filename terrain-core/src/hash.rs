//! Integer hashing: the SplitMix64 finaliser, for deterministic, platform-independent
//! pseudo-random choices (noise lattices, stratified sample offsets), and [`KeyHasher`], the
//! hasher of maps keyed by integers packed into a `u64` (lattice points, [`NodeId::key`]).
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
/// [`NodeId::key`](crate::quadtree::NodeId::key)), where the default SipHash is a measurable
/// share of the work: the entropy method's crack elimination, and the PVPS selections' map of
/// patch corners. Not for keys an adversary chooses (no flooding resistance).
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
}

/// A map keyed by packed integers, hashed by [`KeyHasher`].
pub type KeyMap<V> = std::collections::HashMap<u64, V, std::hash::BuildHasherDefault<KeyHasher>>;
