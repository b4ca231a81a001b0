//! A Huffman-only raw Deflate writer (RFC 1951): one dynamic block of literals, no matches.
//!
//! For the predictive codec's varints of rough terrain, matches buy nothing: re-packing the
//! varints of a 8193^2 synthetic store, miniz's Huffman-only strategy wrote 0.5 % fewer bytes
//! than its level 1 with matches (91.18 against 91.62 MB), and on Puget 1k 0.05 % more
//! (`stream_bench repack`). A literal-only block needs no match finder, no hash table and no
//! second pass: a histogram, a length-limited code, and one loop writing each byte's code.
//! Any Deflate inflater reads it (the store's reader is miniz_oxide's).

/// Deflate's longest literal/length code, and longest code-length code.
const MAX_BITS: usize = 15;
const MAX_CL_BITS: usize = 7;
/// The end-of-block symbol.
const EOB: usize = 256;
/// The order in which the code-length code's lengths are sent (RFC 1951, 3.2.7).
const CL_ORDER: [usize; 19] = [16, 17, 18, 0, 8, 7, 9, 6, 10, 5, 11, 4, 12, 3, 13, 2, 14, 1, 15];

/// Code lengths of a length-limited Huffman code for `freq` (zero for unused symbols; at
/// least two symbols get a code, so every length is at least 1). Deterministic: ties are
/// broken by symbol. The tree's depths are limited to `max_bits` by JPEG's adjustment (ITU
/// T.81, Annex K.2, `Adjust_BITS`), which keeps the code complete, and the lengths are then
/// given to the symbols by decreasing frequency.
fn code_lengths(freq: &[u32], max_bits: usize) -> Vec<u8> {
    let n = freq.len();
    let mut used: Vec<usize> = (0..n).filter(|&s| freq[s] > 0).collect();
    // At least two codes (Deflate's inflaters want a complete code): add the first unused ones.
    for s in 0..n {
        if used.len() >= 2 {
            break;
        }
        if !used.contains(&s) {
            used.push(s);
        }
    }
    // Most frequent first, then by symbol.
    used.sort_by(|&a, &b| freq[b].cmp(&freq[a]).then(a.cmp(&b)));
    // Depths of the plain Huffman tree (Moffat-Katajainen in place, on the weights sorted
    // ascending): `w` ends as each leaf's depth.
    let m = used.len();
    let mut w: Vec<u64> = used.iter().rev().map(|&s| u64::from(freq[s].max(1))).collect();
    huffman_depths(&mut w);
    // Count codes per depth (depths can exceed max_bits here).
    let deepest = w.iter().copied().max().unwrap_or(1) as usize;
    let mut count = vec![0u32; deepest.max(max_bits) + 1];
    for &d in &w {
        count[d as usize] += 1;
    }
    for i in (max_bits + 1..count.len()).rev() {
        while count[i] > 0 {
            let mut j = i - 2;
            while count[j] == 0 {
                j -= 1;
            }
            count[i] -= 2;
            count[i - 1] += 1;
            count[j + 1] += 2;
            count[j] -= 1;
        }
    }
    // Shortest lengths to the most frequent symbols.
    let mut lengths = vec![0u8; n];
    let mut k = 0;
    for (len, &c) in count.iter().enumerate().take(max_bits + 1).skip(1) {
        for _ in 0..c {
            lengths[used[k]] = len as u8;
            k += 1;
        }
    }
    debug_assert_eq!(k, m);
    lengths
}

/// In-place minimum-redundancy code lengths (Moffat and Katajainen, 1995): `a` holds the
/// weights in ascending order and ends holding each one's depth.
fn huffman_depths(a: &mut [u64]) {
    let n = a.len();
    if n == 1 {
        a[0] = 1;
        return;
    }
    // Phase 1: internal node weights, parents recorded in place.
    a[0] += a[1];
    let (mut root, mut leaf) = (0usize, 2usize);
    for next in 1..n - 1 {
        if leaf >= n || a[root] < a[leaf] {
            a[next] = a[root];
            a[root] = next as u64;
            root += 1;
        } else {
            a[next] = a[leaf];
            leaf += 1;
        }
        if leaf >= n || (root < next && a[root] < a[leaf]) {
            a[next] += a[root];
            a[root] = next as u64;
            root += 1;
        } else {
            a[next] += a[leaf];
            leaf += 1;
        }
    }
    // Phase 2: internal node depths.
    a[n - 2] = 0;
    for next in (0..n - 2).rev() {
        a[next] = a[a[next] as usize] + 1;
    }
    // Phase 3: leaf depths.
    let (mut avail, mut used, mut depth) = (1i64, 0i64, 0u64);
    let (mut root, mut next) = (n as i64 - 2, n as i64 - 1);
    while avail > 0 {
        while root >= 0 && a[root as usize] == depth {
            used += 1;
            root -= 1;
        }
        while avail > used {
            a[next as usize] = depth;
            next -= 1;
            avail -= 1;
        }
        avail = 2 * used;
        depth += 1;
        used = 0;
    }
}

/// Canonical codes (RFC 1951, 3.2.2) for `lengths`, bit-reversed for an LSB-first writer.
fn canonical_codes(lengths: &[u8]) -> Vec<u32> {
    let mut bl_count = [0u32; MAX_BITS + 1];
    for &l in lengths {
        bl_count[l as usize] += 1;
    }
    bl_count[0] = 0;
    let mut next = [0u32; MAX_BITS + 2];
    let mut code = 0u32;
    for bits in 1..=MAX_BITS {
        code = (code + bl_count[bits - 1]) << 1;
        next[bits] = code;
    }
    lengths
        .iter()
        .map(|&l| {
            if l == 0 {
                return 0;
            }
            let c = next[l as usize];
            next[l as usize] += 1;
            c.reverse_bits() >> (32 - u32::from(l))
        })
        .collect()
}

/// LSB-first bit writer into a byte vector.
struct Bits {
    out: Vec<u8>,
    acc: u64,
    n: u32,
}

impl Bits {
    #[inline]
    fn put(&mut self, value: u32, bits: u32) {
        self.acc |= u64::from(value) << self.n;
        self.n += bits;
        if self.n >= 32 {
            self.out.extend_from_slice(&(self.acc as u32).to_le_bytes());
            self.acc >>= 32;
            self.n -= 32;
        }
    }

    fn finish(mut self) -> Vec<u8> {
        while self.n > 0 {
            self.out.push(self.acc as u8);
            self.acc >>= 8;
            self.n = self.n.saturating_sub(8);
        }
        self.out
    }
}

/// `data` as a raw Deflate stream of one final dynamic-Huffman block of literals. Appends to
/// `out` (which may hold a prefix, e.g. a payload tag).
pub(crate) fn deflate_literals(data: &[u8], out: Vec<u8>) -> Vec<u8> {
    let mut freq = [0u32; 257];
    for &b in data {
        freq[b as usize] += 1;
    }
    freq[EOB] = 1;
    let lit_len = code_lengths(&freq, MAX_BITS);
    let lit_code = canonical_codes(&lit_len);
    // The code lengths sent: 257 literal/length codes, then two distance codes of one bit
    // (none is used; a complete code, as zlib writes for a block without matches, which
    // every inflater accepts), run-length coded with symbols 16-18.
    let mut seq: Vec<u8> = lit_len.clone();
    seq.extend([1, 1]);
    let mut cl_syms: Vec<(u8, u8)> = Vec::new(); // (symbol, extra bits value)
    let mut i = 0;
    while i < seq.len() {
        let l = seq[i];
        let mut run = 1;
        while i + run < seq.len() && seq[i + run] == l {
            run += 1;
        }
        if l == 0 && run >= 3 {
            let r = run.min(138);
            if r >= 11 {
                cl_syms.push((18, (r - 11) as u8));
            } else {
                cl_syms.push((17, (r - 3) as u8));
            }
            i += r;
        } else if l != 0 && run >= 4 {
            cl_syms.push((l, 0));
            let r = (run - 1).min(6);
            cl_syms.push((16, (r - 3) as u8));
            i += 1 + r;
        } else {
            cl_syms.push((l, 0));
            i += 1;
        }
    }
    let mut cl_freq = [0u32; 19];
    for &(s, _) in &cl_syms {
        cl_freq[s as usize] += 1;
    }
    let cl_len = code_lengths(&cl_freq, MAX_CL_BITS);
    let cl_code = canonical_codes(&cl_len);
    let mut hclen = 19;
    while hclen > 4 && cl_len[CL_ORDER[hclen - 1]] == 0 {
        hclen -= 1;
    }
    let mut w = Bits { out, acc: 0, n: 0 };
    w.out.reserve(data.len() + 64);
    w.put(1, 1); // BFINAL
    w.put(2, 2); // BTYPE 10: dynamic Huffman
    w.put(0, 5); // HLIT: 257 codes
    w.put(1, 5); // HDIST: 2 codes
    w.put(hclen as u32 - 4, 4);
    for &s in &CL_ORDER[..hclen] {
        w.put(u32::from(cl_len[s]), 3);
    }
    for &(s, extra) in &cl_syms {
        w.put(cl_code[s as usize], u32::from(cl_len[s as usize]));
        match s {
            16 => w.put(u32::from(extra), 2),
            17 => w.put(u32::from(extra), 3),
            18 => w.put(u32::from(extra), 7),
            _ => {}
        }
    }
    // The literals: at most 15 bits each, so two fit in the writer's 32 free bits.
    let table: Vec<(u32, u32)> = (0..256).map(|s| (lit_code[s], u32::from(lit_len[s]))).collect();
    let mut pairs = data.chunks_exact(2);
    for p in &mut pairs {
        let (c0, l0) = table[p[0] as usize];
        let (c1, l1) = table[p[1] as usize];
        w.put(c0 | (c1 << l0), l0 + l1);
    }
    for &b in pairs.remainder() {
        let (c, l) = table[b as usize];
        w.put(c, l);
    }
    w.put(lit_code[EOB], u32::from(lit_len[EOB]));
    w.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn inflate(stream: &[u8]) -> Vec<u8> {
        miniz_oxide::inflate::decompress_to_vec(stream).expect("a valid raw Deflate stream")
    }

    #[test]
    fn literal_blocks_inflate_to_their_bytes() {
        let mut next = crate::tests::xorshift64_star(0x5EED_D1F1_A7E5_0018);
        let mut cases: Vec<Vec<u8>> = vec![
            vec![0],
            vec![7, 7],
            vec![0; 1000],
            (0..=255).collect(),
            (0..70_000).map(|i| (i % 251) as u8).collect(),
        ];
        // Skewed: byte b with weight about 2^-(b/2): deep trees that must be limited to 15 bits.
        for len in [50, 5_000, 200_000] {
            cases.push(
                (0..len)
                    .map(|_| (next().leading_zeros().min(63) * 4 + (next() % 4) as u32) as u8)
                    .collect(),
            );
        }
        // Fibonacci counts: the deepest plain Huffman tree for their total.
        let mut fib = vec![];
        let (mut a, mut b) = (1usize, 1usize);
        for s in 0..25u8 {
            fib.extend(std::iter::repeat_n(s, a));
            (a, b) = (b, a + b);
        }
        cases.push(fib);
        for _ in 0..20 {
            let len = (next() % 3000) as usize + 1;
            let span = next() % 256 + 1;
            cases.push((0..len).map(|_| (next() % span) as u8).collect());
        }
        for data in &cases {
            let stream = deflate_literals(data, vec![0xAB]);
            assert_eq!(stream[0], 0xAB, "the prefix is kept");
            assert_eq!(&inflate(&stream[1..]), data, "{} bytes", data.len());
            // Deterministic.
            assert_eq!(stream, deflate_literals(data, vec![0xAB]));
        }
        // Negative control: the inflater does refuse a damaged block header.
        let mut bad = deflate_literals(&cases[4], Vec::new());
        bad[0] ^= 0x06; // BTYPE 11, reserved
        assert!(miniz_oxide::inflate::decompress_to_vec(&bad).is_err());
    }

    #[test]
    fn limited_code_lengths_are_complete_and_bounded() {
        // Kraft's sum is exactly 1 (a complete code) and no length exceeds the limit.
        let mut next = crate::tests::xorshift64_star(0x00DD_BA11);
        let mut limited = 0;
        for max_bits in [7usize, 15] {
            for round in 0..200 {
                let n = if max_bits == 7 { 19 } else { 257 };
                let freq: Vec<u32> = (0..n)
                    .map(|s| match round % 3 {
                        0 => (next() % 1000) as u32,
                        1 => 1u32 << (next() % 24),
                        _ => u32::from(s % 5 == 0) * (1 + s as u32),
                    })
                    .collect();
                // Count the codes whose plain Huffman tree is deeper than the limit.
                let mut w: Vec<u64> =
                    freq.iter().filter(|&&f| f > 0).map(|&f| u64::from(f)).collect();
                w.sort_unstable();
                if w.len() > 1 {
                    huffman_depths(&mut w);
                    limited += usize::from(w.iter().any(|&d| d as usize > max_bits));
                }
                let len = code_lengths(&freq, max_bits);
                let kraft: f64 =
                    len.iter().filter(|&&l| l > 0).map(|&l| 0.5f64.powi(l.into())).sum();
                assert!((kraft - 1.0).abs() < 1e-12, "round {round}: Kraft sum {kraft}");
                assert!(len.iter().all(|&l| (l as usize) <= max_bits));
                assert!(
                    freq.iter().zip(&len).all(|(&f, &l)| f == 0 || l > 0),
                    "a used symbol has no code"
                );
            }
        }
        assert!(limited > 50, "the length limit was exercised ({limited} codes)");
    }
}
