//! What the crate's unit tests share: a seeded uniform generator, random leaf sets, and the
//! bit-for-bit comparison of two selections.

use crate::lod::{Selection, SelectionStats};
use crate::quadtree::NodeId;

/// Uniform numbers in `[0, 1)` from Marsaglia's xorshift64 (13, 7, 17) and the top 53 bits:
/// deterministic and platform-independent. `seed` must be non-zero (xorshift's fixed point).
pub(crate) fn unit_rng(seed: u64) -> impl FnMut() -> f64 {
    assert_ne!(seed, 0, "xorshift needs a non-zero seed");
    let mut x = seed;
    move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        (x >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Raw 64-bit numbers from Vigna's xorshift64* (12, 25, 27, multiplier 0x2545F4914F6CDD1D):
/// deterministic and platform-independent; a zero seed is taken as 1.
pub(crate) fn xorshift64_star(seed: u64) -> impl FnMut() -> u64 {
    let mut x = seed.max(1);
    move || {
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
}

/// A random disjoint leaf set, sorted by `dfs_key`: each node splits with a probability that
/// falls with depth (sometimes deep, to force long ripples), some subtrees are culled (holes),
/// and nodes past a `w x h`-cell grid's east or north border (root of `2^max` cells) are
/// absent; also the grid's `contains`.
pub(crate) fn random_tree(
    seed: u64,
    max: u8,
    w: u32,
    h: u32,
) -> (Vec<NodeId>, impl Fn(NodeId) -> bool) {
    let mut unit = unit_rng(seed | 1);
    let contains = move |n: NodeId| {
        let cells = 1u32 << (max - n.level);
        n.i * cells < w && n.j * cells < h
    };
    let mut out = Vec::new();
    let mut stack = vec![NodeId::ROOT];
    while let Some(n) = stack.pop() {
        if !contains(n) || (n.level >= 2 && unit() < 0.06) {
            continue; // outside the grid, or culled
        }
        let p = if n.level < 2 { 1.0 } else { 0.75 - 0.06 * f64::from(n.level) };
        if n.level < max && unit() < p {
            stack.extend(n.children().into_iter().rev());
        } else {
            out.push(n);
        }
    }
    out.sort_by_key(|n| n.dfs_key());
    (out, contains)
}

/// Asserts that `fast` and `slow` select the same patches with the same factors, bit for bit,
/// and the same statistics but their clocks (`label` names the case).
pub(crate) fn assert_same_selection(fast: &Selection, slow: &Selection, label: &str) {
    let bits = |s: &Selection| -> Vec<_> {
        s.patches
            .iter()
            .map(|p| (p.node, p.outer.map(f32::to_bits), p.inner.map(f32::to_bits)))
            .collect()
    };
    assert_eq!(bits(fast), bits(slow), "{label}");
    let stats = |s: &Selection| SelectionStats { cpu_time: Default::default(), ..s.stats };
    assert_eq!(stats(fast), stats(slow), "{label}");
}
