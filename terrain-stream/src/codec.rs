//! Level payloads: fixed-width samples, or the lossless predictive codec (each new vertex
//! predicted from the coarser level it refines, residuals as zig-zag LEB128 varints),
//! optionally deflated.
//!
//! Why this codec: the non-redundant levels of Qiu 2013 (Eq. 1-2) make every new vertex of
//! level `n` an edge midpoint or a cell centre of level `n - 1`, whose ends are already
//! resident when level `n` loads (levels load coarse to fine). The mean of those ends is a good
//! predictor on terrain, so residuals are small and most take one byte; the codec is
//! integer-only, hence lossless and deterministic. Varints cost at least a byte a sample, so
//! flat or smooth terrain (runs of zero residuals) and the skewed residual distribution are
//! left on the table; Deflate over the varints takes them (miniz_oxide, each level alone so
//! levels still load one at a time). Measured by `examples/stream_bench.rs codec` (release,
//! k = 8, deflate level 6; MB of payloads, decode MB/s of decoded samples including inflation,
//! on a shared 2-core machine, so speeds vary by about 25% between runs):
//!
//! | dataset | predictive | deflate(plain i16) | predictive + deflate |
//! |---|---|---|---|
//! | Puget 1k | 1.61 MB, 120 MB/s | 1.77 MB, 184 MB/s | 1.38 MB, 81 MB/s |
//! | Puget 4k | 16.91 MB, 137 MB/s | 4.88 MB, 465 MB/s | 2.60 MB, 116 MB/s |
//! | N42E001 .hgt | 1.69 MB, 129 MB/s | 2.09 MB, 329 MB/s | 1.09 MB, 94 MB/s |
//!
//! (Those figures are for the former Deflate level 6; see below for the levels now used.)
//!
//! Predictive + Deflate is the smallest everywhere (1.3-1.9x smaller than deflate alone,
//! 1.2-6.5x smaller than the varints alone), and the disk bytes are what an out-of-core
//! runtime waits on; decoding runs on the worker threads at 70-85% of the varint decoder's
//! speed (about 2 ms for the finest level of a 257^2 block, against 1.5 ms), so it is the
//! default. Deflate alone decodes 1.5-3.5x faster: the varint decoder, not inflation, is the
//! slow part, and the place to optimise if decoding ever shows in the frame budget.
//!
//! **The decoder by rows (2026-12-04).** Decoding did show: `terrain tiles` over a store
//! spent about 13 % of its CPU there (each prediction found its coarser neighbours' level and
//! order vertex by vertex). It now scatters the coarser levels onto the level's lattice once
//! and walks it by rows, as the encoder does. Same binary, old and new decoder alternated, two
//! rounds each (`stream_bench codec`, decode MB/s; the encoder unchanged):
//!
//! | dataset | predictive, before -> after | predictive + deflate, before -> after |
//! |---|---|---|
//! | Puget 1k | 266 -> 599-603 | 151-200 -> 339-342 |
//! | Puget 4k | 311 -> 980-988 | 258 -> 591-594 |
//! | N42E001 .hgt | 305-306 -> 922-935 | 241 -> 516 |
//!
//! **Deflate levels (the bake's cost).** Level 6 took a quarter of a bake's CPU. Every level
//! writes a raw Deflate stream that the same inflater reads, so the level is not part of the
//! format (stores of either level read alike). Re-packing the varints of real stores' payloads
//! at each miniz level (release, one thread; packed bytes / varint bytes, MB/s of varints):
//!
//! | varints of | level 1 | level 2 | level 3 | level 6 |
//! |---|---|---|---|---|
//! | synthetic 8193^2 (200 blocks, 20.8 MB) | 0.865, 29.2 MB/s | 0.874, 5.7 | 0.874, 5.0 | 0.874, 3.7 |
//! | Puget 4k (13.2 MB) | 0.230, 62.6 MB/s | 0.181, 26.6 | 0.166, 14.3 | 0.155, 3.5 |
//! | N42E001 .hgt (1.7 MB) | 0.630, 32.9 MB/s | 0.650, 12.4 | 0.651, 12.8 | 0.649, 15.0 |
//!
//! Level 1 (miniz's greedy compressor) is 4-8x faster than level 6 and as small or smaller on
//! rough terrain; on smooth terrain (runs of zero residuals) it is 1.5x larger. So a payload
//! is packed at level 1, and packed again at level 3 where level 1 left under half of the
//! varints (smooth terrain: 1.07x level 6's bytes at a quarter of its time); the smaller is
//! kept. Deterministic, like every choice of the codec.
//!
//! **The compressor: literals first, libdeflate where matches pay** (branch `deflate18`).
//! miniz_oxide zeroed and rebuilt its 160 KB of hash tables and 64 KB LZ buffer for every
//! payload, and its level 1 took about a fifth of a rough bake's CPU (`perf`). On rough
//! terrain matches buy nothing: re-packing the varints of stores main baked (`stream_bench
//! repack`, one thread, loaded machine; bytes against miniz's rule, MB/s of varints):
//!
//! | varints of | miniz 1 (+3) | miniz Huffman-only | libdeflate 1 (+3) | libdeflate 1 alone |
//! |---|---|---|---|---|
//! | synthetic 8193^2 (105.8 MB) | 1, 91 MB/s | 0.995 | 0.997, 96-101 MB/s | 0.997 |
//! | Puget 1k (1.6 MB) | 1, 100 MB/s | 1.0005 | 0.996, 106 MB/s | 0.996 |
//! | Puget 4k (16.9 MB) | 1, 38 MB/s | 0.999 | 0.971, 73 MB/s | 1.054 |
//! | lidar f32 (0.26 MB) | 1, 44 MB/s | 1.168 | 0.953, 53 MB/s | 0.995 |
//!
//! So a payload is first written as one Huffman-coded block of literals
//! ([`huffman::deflate_literals`]: a histogram, a length-limited code and one pass, no match
//! finder); where that leaves under [`LITERALS_RATIO`] of the varints (smooth terrain, voids:
//! runs that matches take), libdeflate (`libdeflater`, a compressor kept per thread) packs it
//! at level 1, and at level 3 where level 1 left under half; the smallest is kept. Whole
//! stores against main's (bench/ooc/README.md, "Block payloads by libdeflate"): 0.2-3.7 %
//! smaller, Everest SRTM (voids) 0.3 % larger. Every compressor writes raw Deflate, which the
//! inflater below reads: stores of either read alike (the payload format is unchanged).

use std::cell::RefCell;

use libdeflater::{CompressionLvl, Compressor};

use crate::format::{Codec, for_each_level_vertex, level_len};
use crate::huffman;

/// Payload tag: little-endian i16 samples.
const TAG_I16: u8 = 0;
/// Payload tag: little-endian i32 samples (or f32 bits).
const TAG_I32: u8 = 1;
/// Payload tag: predictive zig-zag varints.
const TAG_PREDICTIVE: u8 = 2;
/// Payload tag: predictive zig-zag varints, deflated (raw Deflate stream).
const TAG_PREDICTIVE_DEFLATE: u8 = 3;
/// Deflate effort first tried: libdeflate level 1 (its fastest, hash-table match finder). See
/// the module docs for the measurement behind the two levels.
const DEFLATE_FAST: i32 = 1;
/// Deflate effort for varints that level 1 packs below [`SMOOTH_RATIO`] of their size (smooth
/// terrain, long runs of zero residuals, where more effort still pays in disk bytes).
const DEFLATE_SMOOTH: i32 = 3;
/// Packed / varint size under which a payload is packed again at [`DEFLATE_SMOOTH`].
const SMOOTH_RATIO: f64 = 0.5;
/// Literals-only / varint size under which libdeflate's matches are tried too.
const LITERALS_RATIO: f64 = 0.8;
/// Bytes of one varint at most (a 64-bit zig-zag value).
const MAX_VARINT: usize = 10;

/// The prediction of vertex `(i, j)` of level `n` from coarser vertices given by `at(i, j)`:
/// the rule itself, vertex by vertex, which the encoder's and the decoder's row walks follow
/// (the tests' reference).
#[cfg(test)]
fn predict(k: u8, n: u8, i: u32, j: u32, at: impl Fn(u32, u32) -> i64) -> i64 {
    // The stride is a power of two: shifts, not divisions (this runs for every sample of
    // every level encoded and decoded).
    let s = u32::from(k - n);
    let d = 1u32 << s;
    let (a_odd, b_odd) = ((i >> s) & 1 == 1, (j >> s) & 1 == 1);
    match (a_odd, b_odd) {
        (true, false) => (at(i - d, j) + at(i + d, j)).div_euclid(2),
        (false, true) => (at(i, j - d) + at(i, j + d)).div_euclid(2),
        _ => (at(i - d, j - d) + at(i + d, j - d) + at(i - d, j + d) + at(i + d, j + d))
            .div_euclid(4),
    }
}

/// Appends `v` as a LEB128 varint (7 bits a byte, low bits first, the high bit set on every
/// byte but the last).
#[cfg(test)]
fn put_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// [`put_varint`] at `buf[*pos..]` (grown as needed; the bytes past `*pos` are scratch): the
/// same bytes. A value below `2^14` (most residuals) takes one or two bytes without a branch
/// on which (both written, the position advanced by one or two), so the encoder does not
/// mispredict on the mix of one- and two-byte residuals.
#[inline]
fn put_varint_at(buf: &mut Vec<u8>, pos: &mut usize, mut v: u64) {
    if buf.len() < *pos + MAX_VARINT {
        buf.resize((*pos + MAX_VARINT).max(2 * buf.len()), 0);
    }
    let out = &mut buf[*pos..*pos + MAX_VARINT];
    if v < 1 << 14 {
        let two = v >= 0x80;
        out[0] = (v as u8 & 0x7F) | if two { 0x80 } else { 0 };
        out[1] = (v >> 7) as u8;
        *pos += 1 + usize::from(two);
        return;
    }
    let mut k = 0;
    while v >= 0x80 {
        out[k] = (v as u8) | 0x80;
        v >>= 7;
        k += 1;
    }
    out[k] = v as u8;
    *pos += k + 1;
}

fn zigzag(v: i64) -> u64 {
    ((v << 1) ^ (v >> 63)) as u64
}

fn unzigzag(v: u64) -> i64 {
    (v >> 1) as i64 ^ -((v & 1) as i64)
}

/// The residuals of level `n` of a block (`grid` row-major `(2^k + 1)^2`), in the order of
/// [`for_each_level_vertex`]: each vertex minus [`predict`]'s prediction (level 0: minus the
/// previous corner, the first minus 0). The same values as [`predict`] at every vertex, by
/// rows of the grid: a row of level-`n` vertices between two rows of coarser ones (every
/// vertex predicted from the rows `d` below and above) or a row of coarser vertices whose odd
/// ones are new (predicted from their west and east neighbours); `div_euclid` by 2 or 4 is an
/// arithmetic shift. Test `the_row_walk_is_predict` checks it against [`predict`].
fn for_each_residual(k: u8, n: u8, grid: &[i32], mut f: impl FnMut(i64)) {
    let side = (1usize << k) + 1;
    let row = |j: usize| &grid[j * side..][..side];
    let d = 1usize << (k - n);
    if n == 0 {
        let mut prev = 0i64;
        for j in [0, d] {
            for i in [0, d] {
                let v = i64::from(row(j)[i]);
                f(v - prev);
                prev = v;
            }
        }
        return;
    }
    let cnt = (1usize << n) + 1;
    for b in 0..cnt {
        let r = row(b * d);
        if b % 2 == 1 {
            let (south, north) = (row((b - 1) * d), row((b + 1) * d));
            for a in 0..cnt {
                let i = a * d;
                let p = if a % 2 == 0 {
                    (i64::from(south[i]) + i64::from(north[i])) >> 1
                } else {
                    (i64::from(south[i - d])
                        + i64::from(south[i + d])
                        + i64::from(north[i - d])
                        + i64::from(north[i + d]))
                        >> 2
                };
                f(i64::from(r[i]) - p);
            }
        } else {
            for i in (d..side).step_by(2 * d) {
                let p = (i64::from(r[i - d]) + i64::from(r[i + d])) >> 1;
                f(i64::from(r[i]) - p);
            }
        }
    }
}

/// Encodes level `n` of a block whose samples `grid` are row-major `(2^k + 1)^2`.
/// `allow_predictive` is false for raw f32 bits (prediction would not be meaningful).
pub(crate) fn encode_level(
    k: u8,
    n: u8,
    grid: &[i32],
    codec: Codec,
    allow_predictive: bool,
) -> Vec<u8> {
    let side = (1usize << k) + 1;
    let at = |i: u32, j: u32| grid[j as usize * side + i as usize];
    if matches!(codec, Codec::Predictive | Codec::PredictiveDeflate) && allow_predictive {
        // One and a half bytes a residual to start with (grown as needed).
        let mut out = vec![0u8; 1 + level_len(n) * 3 / 2 + MAX_VARINT];
        out[0] = TAG_PREDICTIVE;
        let mut pos = 1;
        for_each_residual(k, n, grid, |r| put_varint_at(&mut out, &mut pos, zigzag(r)));
        out.truncate(pos);
        if codec == Codec::PredictiveDeflate
            && let Some(packed) = deflate_varints(&out[1..])
        {
            return packed;
        }
        return out;
    }
    let mut values = Vec::with_capacity(level_len(n));
    for_each_level_vertex(k, n, |i, j| values.push(at(i, j)));
    let fits16 = allow_predictive && values.iter().all(|&v| i16::try_from(v).is_ok());
    let mut out = Vec::with_capacity(1 + values.len() * if fits16 { 2 } else { 4 });
    if fits16 {
        out.push(TAG_I16);
        for v in values {
            out.extend_from_slice(&(v as i16).to_le_bytes());
        }
    } else {
        out.push(TAG_I32);
        for v in values {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

thread_local! {
    /// This thread's libdeflate compressors at [`DEFLATE_FAST`] and [`DEFLATE_SMOOTH`],
    /// allocated on first use and kept: libdeflate carries nothing from one buffer to the next
    /// (each call starts its match finder afresh), so reusing them changes no byte, and saves
    /// allocating their hash tables for every payload.
    static DEFLATERS: RefCell<[Option<Compressor>; 2]> = const { RefCell::new([None, None]) };
}

/// `varints` packed into a [`TAG_PREDICTIVE_DEFLATE`] payload (tag first): literals alone
/// (one Huffman-coded block, [`huffman::deflate_literals`]); where those leave under
/// [`LITERALS_RATIO`] of the varints (smooth terrain: runs of zero residuals, where matches
/// pay), also libdeflate at [`DEFLATE_FAST`], and again at [`DEFLATE_SMOOTH`] where that
/// left under [`SMOOTH_RATIO`]; the smallest kept. `None` where no stream is shorter than the
/// varints (the plain predictive payload is then smaller or as small).
fn deflate_varints(varints: &[u8]) -> Option<Vec<u8>> {
    if varints.len() < 2 {
        return None;
    }
    let lits = huffman::deflate_literals(varints, vec![TAG_PREDICTIVE_DEFLATE]);
    let literals_len = lits.len() - 1;
    // The payload to beat: tag + varints, then each one kept.
    let mut best = (lits.len() < 1 + varints.len()).then_some(lits);
    if (literals_len as f64) >= LITERALS_RATIO * varints.len() as f64 {
        return best;
    }
    DEFLATERS.with_borrow_mut(|[fast, smooth]| {
        let bound = best.as_ref().map_or(1 + varints.len(), Vec::len);
        if let Some(d) = deflate_within(deflater(fast, DEFLATE_FAST), varints, bound) {
            let fast_len = d.len() - 1;
            best = Some(d);
            if (fast_len as f64) < SMOOTH_RATIO * varints.len() as f64
                && let Some(e) =
                    deflate_within(deflater(smooth, DEFLATE_SMOOTH), varints, fast_len + 1)
            {
                best = Some(e);
            }
        }
        best
    })
}

/// A [`TAG_PREDICTIVE_DEFLATE`] payload of `varints` packed by `c`, if shorter than `bound`
/// bytes (libdeflate fails, and nothing is kept, when its stream does not fit).
fn deflate_within(c: &mut Compressor, varints: &[u8], bound: usize) -> Option<Vec<u8>> {
    if bound < 2 {
        return None;
    }
    let mut d = vec![0u8; bound - 1];
    d[0] = TAG_PREDICTIVE_DEFLATE;
    let n = c.deflate_compress(varints, &mut d[1..]).ok()?;
    d.truncate(1 + n);
    Some(d)
}

/// The compressor in `slot`, at `level`, made on first use.
fn deflater(slot: &mut Option<Compressor>, level: i32) -> &mut Compressor {
    slot.get_or_insert_with(|| Compressor::new(CompressionLvl::new(level).unwrap_or_default()))
}

/// Decodes level `n` given the decoded coarser levels `coarser[0..n]`. Errors describe what is
/// wrong; nothing panics on bad bytes.
pub(crate) fn decode_level<L: AsRef<[i32]>>(
    k: u8,
    n: u8,
    payload: &[u8],
    coarser: &[L],
) -> Result<Vec<i32>, String> {
    let count = level_len(n);
    let Some((&tag, body)) = payload.split_first() else {
        return Err("empty payload".into());
    };
    match tag {
        TAG_I16 | TAG_I32 => {
            let w = if tag == TAG_I16 { 2 } else { 4 };
            if body.len() != count * w {
                return Err(format!("{} bytes for {count} samples of {w} bytes", body.len()));
            }
            Ok(if w == 2 {
                body.chunks_exact(2).map(|c| i16::from_le_bytes([c[0], c[1]]) as i32).collect()
            } else {
                body.chunks_exact(4).map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect()
            })
        }
        TAG_PREDICTIVE => decode_predictive(k, n, body, coarser),
        TAG_PREDICTIVE_DEFLATE => INFLATED.with_borrow_mut(|out| {
            let written = inflate_exact(body, count * MAX_VARINT, out);
            let decoded = written.and_then(|w| decode_predictive(k, n, &out[..w], coarser));
            if out.len() > KEEP_INFLATED_BYTES {
                *out = Vec::new();
            }
            decoded
        }),
        t => Err(format!("unknown payload tag {t}")),
    }
}

thread_local! {
    /// A thread's inflated varints, kept from one level's decoding to the next: a level's
    /// output is bounded by ten bytes a sample (`MAX_VARINT`), so a new buffer was hundreds of
    /// kilobytes zeroed (and its pages faulted in) per level for a payload of a fifth of that.
    /// Up to [`KEEP_INFLATED_BYTES`] are kept; a larger one (a block finer than 2^10 cells) is
    /// freed after its level.
    static INFLATED: RefCell<Vec<u8>> = const { RefCell::new(Vec::new()) };
}

/// The largest inflate buffer a thread keeps between levels (a 1025-cell block's finest
/// level needs 7.9 MB).
const KEEP_INFLATED_BYTES: usize = 8 << 20;

/// Inflates a raw Deflate stream of at most `limit` bytes that must end exactly at the end of
/// `body` (trailing bytes, truncation and oversized output are errors, never panics) into the
/// start of `out` (grown to `limit` where shorter; what lies beyond the output is left as it
/// was): the inflated length.
fn inflate_exact(body: &[u8], limit: usize, out: &mut Vec<u8>) -> Result<usize, String> {
    use miniz_oxide::inflate::TINFLStatus;
    use miniz_oxide::inflate::core::inflate_flags::TINFL_FLAG_USING_NON_WRAPPING_OUTPUT_BUF;
    use miniz_oxide::inflate::core::{DecompressorOxide, decompress};
    if out.len() < limit {
        out.resize(limit, 0);
    }
    let mut d = DecompressorOxide::new();
    let flags = TINFL_FLAG_USING_NON_WRAPPING_OUTPUT_BUF;
    let (status, consumed, written) = decompress(&mut d, body, &mut out[..limit], 0, flags);
    match status {
        TINFLStatus::Done if consumed == body.len() => Ok(written),
        TINFLStatus::Done => {
            Err(format!("{} bytes after the deflate stream", body.len() - consumed))
        }
        s => Err(format!("deflate stream: {s:?}")),
    }
}

/// Decodes the varints of level `n` (the body of a predictive payload): the inverse of
/// [`for_each_residual`]. The coarser levels are scattered once onto the lattice of level `n`
/// (`(2^n + 1)^2`, a quarter of it filled), so each prediction reads its two or four coarser
/// neighbours by row and column instead of finding each one's level and order (every
/// neighbour of a level-`n` vertex is coarser: the same rule as the encoder's row walk).
fn decode_predictive<L: AsRef<[i32]>>(
    k: u8,
    n: u8,
    body: &[u8],
    coarser: &[L],
) -> Result<Vec<i32>, String> {
    let count = level_len(n);
    if coarser.len() < n as usize {
        return Err(format!("level {n} needs the {n} coarser levels, {} given", coarser.len()));
    }
    for (l, c) in coarser.iter().take(n as usize).enumerate() {
        if c.as_ref().len() != level_len(l as u8) {
            return Err(format!("coarser level {l} has {} samples", c.as_ref().len()));
        }
    }
    let mut out = Vec::with_capacity(count);
    let mut pos = 0usize;
    let mut next = |decoded: usize| -> Result<i64, String> {
        let mut v = 0u64;
        let mut shift = 0u32;
        loop {
            let Some(&b) = body.get(pos) else {
                return Err(format!("varints end after {decoded} of {count} samples"));
            };
            pos += 1;
            if shift > 63 {
                return Err("varint too long".to_string());
            }
            v |= ((b & 0x7F) as u64) << shift;
            shift += 7;
            if b & 0x80 == 0 {
                return Ok(unzigzag(v));
            }
        }
    };
    let push = |out: &mut Vec<i32>, x: i64| -> Result<(), String> {
        let x = i32::try_from(x).map_err(|_| format!("sample {x} out of range"))?;
        out.push(x);
        Ok(())
    };
    if n == 0 {
        let mut prev = 0i64;
        for _ in 0..count {
            let x = prev.wrapping_add(next(out.len())?);
            push(&mut out, x)?;
            prev = x;
        }
    } else {
        let cnt = (1usize << n) + 1;
        let to_lattice = k - n;
        let mut lattice = vec![0i32; cnt * cnt];
        for (l, c) in coarser.iter().take(n as usize).enumerate() {
            let mut q = c.as_ref().iter();
            for_each_level_vertex(k, l as u8, |i, j| {
                if let Some(&q) = q.next() {
                    let (a, b) = ((i >> to_lattice) as usize, (j >> to_lattice) as usize);
                    lattice[b * cnt + a] = q;
                }
            });
        }
        let at = |b: usize, a: usize| i64::from(lattice[b * cnt + a]);
        for b in 0..cnt {
            if b % 2 == 1 {
                for a in 0..cnt {
                    let p = if a % 2 == 0 {
                        (at(b - 1, a) + at(b + 1, a)) >> 1
                    } else {
                        (at(b - 1, a - 1) + at(b - 1, a + 1) + at(b + 1, a - 1) + at(b + 1, a + 1))
                            >> 2
                    };
                    let x = p.wrapping_add(next(out.len())?);
                    push(&mut out, x)?;
                }
            } else {
                for a in (1..cnt).step_by(2) {
                    let p = (at(b, a - 1) + at(b, a + 1)) >> 1;
                    let x = p.wrapping_add(next(out.len())?);
                    push(&mut out, x)?;
                }
            }
        }
    }
    if pos != body.len() {
        return Err(format!("{} bytes left after {count} samples", body.len() - pos));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Encodes and decodes every level of `grid` (a `(2^k + 1)^2` block) with `codec`: each
    /// level decodes to the grid's vertices of that level, and its payload cut short or
    /// extended by a byte is an error. Returns the decoded levels.
    fn round_trip(k: u8, grid: &[i32], codec: Codec) -> Vec<Vec<i32>> {
        let side = (1usize << k) + 1;
        let mut levels: Vec<Vec<i32>> = Vec::new();
        for n in 0..=k {
            let bytes = encode_level(k, n, grid, codec, true);
            let dec = decode_level(k, n, &bytes, &levels).unwrap();
            let mut expect = Vec::new();
            for_each_level_vertex(k, n, |i, j| expect.push(grid[j as usize * side + i as usize]));
            assert_eq!(dec, expect, "k {k} {codec:?} level {n}");
            assert!(decode_level(k, n, &bytes[..bytes.len() - 1], &levels).is_err());
            let mut longer = bytes.clone();
            longer.push(0);
            assert!(decode_level(k, n, &longer, &levels).is_err());
            levels.push(dec);
        }
        levels
    }

    /// A thread's inflate buffer is reused from one level to the next: a level decoded after a
    /// larger one (its buffer holding the larger one's bytes past this level's output) decodes
    /// the same, and its payload cut short or lengthened is still refused.
    #[test]
    fn levels_decode_the_same_after_a_larger_level_on_the_same_thread() {
        let k = 6u8;
        let side = (1usize << k) + 1;
        // Smooth with a repeating pattern: deflate wins at every level from 2 (checked below).
        let grid: Vec<i32> = (0..side * side)
            .map(|p| ((p % side) as i32 / 3) * 4 + ((p / side) as i32 % 5) * 2)
            .collect();
        let levels = round_trip(k, &grid, Codec::PredictiveDeflate);
        let finest = encode_level(k, k, &grid, Codec::PredictiveDeflate, true);
        let mut deflated = 0;
        for n in (1..k).rev() {
            // The finest level first: the buffer then holds its bytes beyond level n's output.
            assert_eq!(
                decode_level(k, k, &finest, &levels[..k as usize]).unwrap(),
                levels[k as usize]
            );
            let bytes = encode_level(k, n, &grid, Codec::PredictiveDeflate, true);
            deflated += usize::from(bytes[0] == TAG_PREDICTIVE_DEFLATE);
            let coarser = &levels[..n as usize];
            assert_eq!(decode_level(k, n, &bytes, coarser).unwrap(), levels[n as usize], "{n}");
            assert_eq!(
                decode_level(k, k, &finest, &levels[..k as usize]).unwrap(),
                levels[k as usize]
            );
            assert!(decode_level(k, n, &bytes[..bytes.len() - 1], coarser).is_err(), "{n}");
            let mut longer = bytes.clone();
            longer.push(0);
            assert!(decode_level(k, n, &longer, coarser).is_err(), "{n}");
        }
        assert_eq!(finest[0], TAG_PREDICTIVE_DEFLATE);
        assert!(deflated >= 3, "the deflated path taken at {deflated} levels");
    }

    #[test]
    fn both_codecs_round_trip_and_reject_garbage() {
        let k = 4u8;
        let side = 17usize;
        let grid: Vec<i32> =
            (0..side * side).map(|p| ((p * 7919) % 4001) as i32 - 2000 + (p as i32) * 3).collect();
        assert_eq!(grid.len(), side * side);
        for codec in [Codec::Plain, Codec::Predictive, Codec::PredictiveDeflate] {
            round_trip(k, &grid, codec);
        }
        assert!(decode_level::<Vec<i32>>(k, 0, &[], &[]).is_err());
        assert!(decode_level::<Vec<i32>>(k, 0, &[9, 1, 2], &[]).is_err());
        assert!(
            decode_level::<Vec<i32>>(
                k,
                0,
                &[TAG_PREDICTIVE, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF],
                &[]
            )
            .is_err()
        );
    }

    #[test]
    fn deflate_is_used_where_smaller_and_checked_strictly() {
        let k = 5u8;
        let side = 33usize;
        // Smooth: residuals are mostly zero, so the deflated varints win at the fine levels.
        let grid: Vec<i32> = (0..side * side).map(|p| (p % side + 2 * (p / side)) as i32).collect();
        let mut levels: Vec<Vec<i32>> = Vec::new();
        for n in 0..=k {
            let bytes = encode_level(k, n, &grid, Codec::PredictiveDeflate, true);
            if n == k {
                assert_eq!(bytes[0], TAG_PREDICTIVE_DEFLATE);
                let varints = encode_level(k, n, &grid, Codec::Predictive, true);
                assert!(bytes.len() * 4 < varints.len(), "{} vs {}", bytes.len(), varints.len());
            }
            let dec = decode_level(k, n, &bytes, &levels).unwrap();
            let mut expect = Vec::new();
            for_each_level_vertex(k, n, |i, j| expect.push(grid[j as usize * side + i as usize]));
            assert_eq!(dec, expect, "level {n}");
            if bytes[0] == TAG_PREDICTIVE_DEFLATE {
                assert!(decode_level(k, n, &bytes[..bytes.len() - 1], &levels).is_err());
                let mut longer = bytes.clone();
                longer.push(0);
                assert!(decode_level(k, n, &longer, &levels).is_err());
                // Every flipped byte is an error or other samples, never a panic.
                for p in 1..bytes.len() {
                    let mut b = bytes.clone();
                    b[p] ^= 0xA5;
                    let _ = decode_level(k, n, &b, &levels);
                }
            }
            levels.push(dec);
        }
    }

    #[test]
    fn the_varint_writer_is_leb128() {
        // Every byte-count boundary, both sides, and random values of each size: the same
        // bytes as the plain writer, written one after another into one buffer that starts
        // too small (so it grows), with scratch bytes left past the end each time.
        let mut values = vec![0u64, 1, 0x7F, 0x80, 0x81, 0x3FFF, 0x4000, 0x4001, u64::MAX];
        for b in 1..64 {
            values.extend([(1u64 << b) - 1, 1 << b, (1 << b) + 1]);
        }
        let mut next = crate::tests::xorshift64_star(0x1234_5678_9ABC_DEF1);
        for _ in 0..2000 {
            // Values of every magnitude: a random number shifted right by a random amount.
            let (v, shift) = (next(), next() % 64);
            values.push(v >> shift);
        }
        let (mut plain, mut buf, mut pos) = (Vec::new(), vec![0xFFu8; 3], 0);
        for &v in &values {
            put_varint(&mut plain, v);
            put_varint_at(&mut buf, &mut pos, v);
            assert_eq!(&buf[..pos], &plain[..], "after {v:#x}");
        }
        assert!(plain.len() > 2 * values.len(), "multi-byte values were written");
    }

    /// A `(2^k + 1)^2` block with negative values, odd sums (where `div_euclid` rounds down)
    /// and the extremes of i32 (residuals beyond 32 bits).
    fn extreme_grid(k: u8) -> Vec<i32> {
        let side = (1usize << k) + 1;
        (0..side * side)
            .map(|p| match p % 11 {
                0 => i32::MIN,
                1 => i32::MAX,
                _ => ((p * 7919) % 4001) as i32 - 2000 - (p as i32 % 3),
            })
            .collect()
    }

    /// The decoder inverts the encoder at every level of blocks of 2^1 to 2^8 cells, on grids
    /// with negative values, odd sums and the extremes of i32 (residuals beyond 32 bits).
    #[test]
    fn every_level_decodes_to_the_grid_it_was_encoded_from() {
        for k in [1u8, 2, 4, 6, 8] {
            let grid = extreme_grid(k);
            for codec in [Codec::Predictive, Codec::PredictiveDeflate] {
                let levels = round_trip(k, &grid, codec);
                // A coarser level of the wrong length is refused.
                let bytes = encode_level(k, k, &grid, codec, true);
                let mut short = levels[..k as usize].to_vec();
                short[0].pop();
                assert!(decode_level(k, k, &bytes, &short).is_err());
            }
        }
    }

    #[test]
    fn the_row_walk_is_predict() {
        // Every residual of every level against `predict` at the vertex, on a grid with
        // negative values, odd sums (where `div_euclid` rounds down) and extremes.
        for k in [1u8, 2, 4, 6] {
            let side = (1usize << k) + 1;
            let grid = extreme_grid(k);
            let at = |i: u32, j: u32| i64::from(grid[j as usize * side + i as usize]);
            for n in 0..=k {
                let (mut walk, mut want) = (Vec::new(), Vec::new());
                for_each_residual(k, n, &grid, |r| walk.push(r));
                let mut prev = 0i64;
                for_each_level_vertex(k, n, |i, j| {
                    let p = if n == 0 { prev } else { predict(k, n, i, j, at) };
                    prev = at(i, j);
                    want.push(at(i, j) - p);
                });
                assert_eq!(walk.len(), level_len(n), "k {k} level {n}");
                assert_eq!(walk, want, "k {k} level {n}");
            }
        }
    }
}
