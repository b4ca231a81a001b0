//! Mutators: byte-level ones (truncation, bit flips, interesting words, splices, insertions
//! and deletions) and format-aware ones that reach past the first checks (TIFF IFD entries:
//! declared sizes, types, tag counts, strip and tile offsets and byte counts, IFD offsets and
//! loops; PNG IHDR fields and chunks with their CRC fixed; JPEG frame, scan and table
//! segments; trailing CRC-32s of the store's index and tables fixed after a mutation), in the
//! spirit of AFL's havoc stage with format dictionaries.

use crate::rng::Rng;
use terrain_core::checksum::crc32;

/// What a file is, for the format-aware mutators.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Kind {
    Tiff,
    Png,
    Jpeg,
    /// Headerless samples: `.hgt` and raw grids.
    Samples,
    /// A file that ends with the CRC-32 (little-endian) of everything before it: the store's
    /// index and its per-node tables.
    Crc32Tail,
    /// Anything else (block files are mutated by the store target, which knows their levels).
    Bytes,
}

const U16S: [u16; 12] = [0, 1, 2, 3, 7, 0x7F, 0x80, 0xFF, 0x100, 0x7FFF, 0x8000, 0xFFFF];
const U32S: [u32; 16] = [
    0,
    1,
    2,
    3,
    4,
    8,
    16,
    255,
    256,
    0x7FFF,
    0xFFFF,
    0x1_0000,
    0x7FFF_FFFF,
    0x8000_0000,
    0xFFFF_FFFE,
    0xFFFF_FFFF,
];

/// An interesting 32-bit value for a file of `len` bytes: boundaries, the file's length and
/// its neighbours, or a random word.
fn interesting_u32(rng: &mut Rng, len: usize) -> u32 {
    match rng.below(4) {
        0 | 1 => *rng.pick(&U32S),
        2 => {
            let len = len as u32;
            *rng.pick(&[
                len,
                len.wrapping_sub(1),
                len.wrapping_add(1),
                len / 2,
                len.wrapping_mul(2),
            ])
        }
        _ => rng.next_u64() as u32,
    }
}

fn put(bytes: &mut [u8], at: usize, value: &[u8]) {
    if let Some(dst) = bytes.get_mut(at..at + value.len()) {
        dst.copy_from_slice(value);
    }
}

fn put_u16(bytes: &mut [u8], at: usize, v: u16, le: bool) {
    put(bytes, at, &if le { v.to_le_bytes() } else { v.to_be_bytes() });
}

fn put_u32(bytes: &mut [u8], at: usize, v: u32, le: bool) {
    put(bytes, at, &if le { v.to_le_bytes() } else { v.to_be_bytes() });
}

fn put_u64(bytes: &mut [u8], at: usize, v: u64, le: bool) {
    put(bytes, at, &if le { v.to_le_bytes() } else { v.to_be_bytes() });
}

fn get_u16(b: &[u8], at: usize, le: bool) -> Option<u16> {
    let a: [u8; 2] = b.get(at..at + 2)?.try_into().ok()?;
    Some(if le { u16::from_le_bytes(a) } else { u16::from_be_bytes(a) })
}

fn get_u32(b: &[u8], at: usize, le: bool) -> Option<u32> {
    let a: [u8; 4] = b.get(at..at + 4)?.try_into().ok()?;
    Some(if le { u32::from_le_bytes(a) } else { u32::from_be_bytes(a) })
}

fn get_u64(b: &[u8], at: usize, le: bool) -> Option<u64> {
    let a: [u8; 8] = b.get(at..at + 8)?.try_into().ok()?;
    Some(if le { u64::from_le_bytes(a) } else { u64::from_be_bytes(a) })
}

/// Applies one to four mutations to `bytes` (a file of `kind`); `donor` is another file to
/// splice from. Returns a short description of what was done, for the failure report.
pub(crate) fn mutate(bytes: &mut Vec<u8>, kind: Kind, rng: &mut Rng, donor: &[u8]) -> String {
    let mut done = Vec::new();
    let n = 1 + rng.below(4).min(rng.below(4));
    for step in 0..n {
        let structural = step == 0 && rng.chance(0.6);
        let what = if structural {
            match kind {
                Kind::Tiff => tiff(bytes, rng),
                Kind::Png => png(bytes, rng),
                Kind::Jpeg => jpeg(bytes, rng),
                Kind::Crc32Tail => table_header(bytes, rng),
                Kind::Samples | Kind::Bytes => None,
            }
        } else {
            None
        };
        done.push(match what {
            Some(w) => w,
            None => generic(bytes, rng, donor),
        });
    }
    if kind == Kind::Crc32Tail && rng.chance(0.75) {
        fix_crc_tail(bytes);
        done.push("trailing CRC-32 fixed".into());
    }
    done.join("; ")
}

/// Rewrites the last four bytes as the CRC-32 (little-endian) of the rest.
pub(crate) fn fix_crc_tail(bytes: &mut [u8]) {
    if bytes.len() >= 4 {
        let n = bytes.len() - 4;
        let c = crc32(&bytes[..n]);
        bytes[n..].copy_from_slice(&c.to_le_bytes());
    }
}

/// A byte-level mutation.
pub(crate) fn generic(bytes: &mut Vec<u8>, rng: &mut Rng, donor: &[u8]) -> String {
    let len = bytes.len();
    if len == 0 {
        bytes.extend((0..1 + rng.below(64)).map(|_| rng.next_u64() as u8));
        return "random bytes into an empty file".into();
    }
    // Positions near the start (headers) are more interesting than the middle of the data.
    let pos = |rng: &mut Rng| {
        if rng.chance(0.5) { rng.below(len.min(512)) } else { rng.below(len) }
    };
    match rng.below(9) {
        0 => {
            let to = match rng.below(3) {
                0 => rng.below(len.min(256)),
                1 => len - 1 - rng.below(len.min(4096)),
                _ => rng.below(len),
            };
            bytes.truncate(to);
            format!("truncated to {to} bytes")
        }
        1 | 2 => {
            let flips = 1 + rng.below(8);
            for _ in 0..flips {
                let at = pos(rng);
                bytes[at] ^= 1 << rng.below(8);
            }
            format!("{flips} bit flips")
        }
        3 => {
            let at = pos(rng);
            let v = interesting_u32(rng, len);
            let le = rng.chance(0.5);
            match rng.below(3) {
                0 => put(bytes, at, &[v as u8]),
                1 => put_u16(bytes, at, v as u16, le),
                _ => put_u32(bytes, at, v, le),
            }
            format!("interesting value {v:#x} at {at}")
        }
        4 => {
            let at = pos(rng);
            let n = 1 + rng.below(32);
            for b in bytes.iter_mut().skip(at).take(n) {
                *b = *rng.pick(&[0x00, 0xFF, 0x7F, 0x80, 0x01]);
            }
            format!("{n} bytes set at {at}")
        }
        5 if !donor.is_empty() => {
            // Splice a chunk of the donor (or of the file itself) over the file.
            let src: Vec<u8> = if rng.chance(0.5) { donor.to_vec() } else { bytes.clone() };
            let n = 1 + rng.below(src.len().min(4096));
            let from = rng.below(src.len() - n + 1);
            let at = pos(rng);
            let end = (at + n).min(len);
            bytes[at..end].copy_from_slice(&src[from..from + (end - at)]);
            format!("spliced {} bytes at {at}", end - at)
        }
        6 => {
            let at = pos(rng);
            let n = 1 + rng.below(64);
            let ins: Vec<u8> = (0..n).map(|_| rng.next_u64() as u8).collect();
            bytes.splice(at..at, ins);
            format!("inserted {n} bytes at {at}")
        }
        7 => {
            let at = pos(rng);
            let n = (1 + rng.below(256)).min(len - at);
            bytes.drain(at..at + n);
            format!("deleted {n} bytes at {at}")
        }
        _ => {
            let n = 1 + rng.below(1024);
            bytes.extend((0..n).map(|_| rng.next_u64() as u8));
            format!("appended {n} bytes")
        }
    }
}

/// A TIFF IFD entry as found in the file.
struct Entry {
    /// Where the entry starts.
    at: usize,
    tag: u16,
    typ: u16,
    count: u64,
    /// Where its value (or the offset of its values) is.
    value_at: usize,
}

/// The TIFF's byte order, BigTIFF-ness, the entries of its first IFDs and the positions of
/// its IFD pointers (the header's and each IFD's next-IFD field).
fn tiff_layout(b: &[u8]) -> Option<(bool, bool, Vec<Entry>, Vec<usize>)> {
    let le = match b.get(..2)? {
        b"II" => true,
        b"MM" => false,
        _ => return None,
    };
    let big = get_u16(b, 2, le)? == 43;
    let (mut entries, mut pointers) = (Vec::new(), Vec::new());
    let mut ptr_at = if big { 8 } else { 4 };
    for _ in 0..4 {
        pointers.push(ptr_at);
        let ifd = if big { get_u64(b, ptr_at, le)? } else { u64::from(get_u32(b, ptr_at, le)?) };
        let ifd = usize::try_from(ifd).ok()?;
        if ifd == 0 || ifd >= b.len() {
            break;
        }
        let (n, first, size) = if big {
            (get_u64(b, ifd, le)?, ifd + 8, 20)
        } else {
            (u64::from(get_u16(b, ifd, le)?), ifd + 2, 12)
        };
        let n = n.min(512) as usize;
        for e in 0..n {
            let at = first + e * size;
            let tag = get_u16(b, at, le)?;
            let typ = get_u16(b, at + 2, le)?;
            let (count, value_at) = if big {
                (get_u64(b, at + 4, le)?, at + 12)
            } else {
                (u64::from(get_u32(b, at + 4, le)?), at + 8)
            };
            entries.push(Entry { at, tag, typ, count, value_at });
        }
        ptr_at = first + n * size;
    }
    Some((le, big, entries, pointers))
}

/// Tags whose values decide sizes, layout and decoding.
const TIFF_TAGS: [u16; 22] = [
    256, 257, 258, 259, 262, 273, 277, 278, 279, 284, 317, 322, 323, 324, 325, 338, 339, 33550,
    33922, 34735, 34736, 42113,
];

fn type_size(typ: u16) -> usize {
    match typ {
        1 | 2 | 6 | 7 => 1,
        3 | 8 => 2,
        4 | 9 | 11 | 13 => 4,
        5 | 10 | 12 | 16 | 17 | 18 => 8,
        _ => 1,
    }
}

fn tiff(bytes: &mut [u8], rng: &mut Rng) -> Option<String> {
    let (le, big, entries, pointers) = tiff_layout(bytes)?;
    let len = bytes.len();
    if entries.is_empty() || rng.chance(0.1) {
        let at = *rng.pick(&pointers);
        let v = if rng.chance(0.3) && pointers.len() > 1 {
            // A loop: point an IFD's successor back at the first IFD.
            if big { get_u64(bytes, 8, le)? } else { u64::from(get_u32(bytes, 4, le)?) }
        } else {
            u64::from(interesting_u32(rng, len))
        };
        if big {
            put_u64(bytes, at, v, le)
        } else {
            put_u32(bytes, at, v as u32, le)
        }
        return Some(format!("TIFF IFD pointer at {at} := {v:#x}"));
    }
    // Prefer the tags that matter.
    let wanted: Vec<&Entry> = entries.iter().filter(|e| TIFF_TAGS.contains(&e.tag)).collect();
    let e =
        if !wanted.is_empty() && rng.chance(0.8) { *rng.pick(&wanted) } else { rng.pick(&entries) };
    let word = if big { 8 } else { 4 };
    let inline = (e.count as usize).saturating_mul(type_size(e.typ)) <= word;
    Some(match rng.below(6) {
        0 => {
            let c = u64::from(interesting_u32(rng, len));
            if big {
                put_u64(bytes, e.at + 4, c, le)
            } else {
                put_u32(bytes, e.at + 4, c as u32, le)
            }
            format!("TIFF tag {} count {} := {c}", e.tag, e.count)
        }
        1 => {
            let t = rng.below(19) as u16;
            put_u16(bytes, e.at + 2, t, le);
            format!("TIFF tag {} type {} := {t}", e.tag, e.typ)
        }
        2 => {
            let t = *rng.pick(&TIFF_TAGS);
            put_u16(bytes, e.at, t, le);
            format!("TIFF tag {} := tag {t}", e.tag)
        }
        3 if !inline => {
            // One element of an out-of-line array: a strip or tile offset or byte count, a
            // GeoKey, a tie point.
            let off = if big {
                get_u64(bytes, e.value_at, le)?
            } else {
                get_u32(bytes, e.value_at, le)? as u64
            };
            let size = type_size(e.typ);
            let i = rng.below((e.count as usize).clamp(1, 256));
            let at = usize::try_from(off).ok()?.checked_add(i * size)?;
            let v = interesting_u32(rng, len);
            match size {
                1 => put(bytes, at, &[v as u8]),
                2 => put_u16(bytes, at, v as u16, le),
                4 => put_u32(bytes, at, v, le),
                _ => put_u64(bytes, at, u64::from(v), le),
            }
            format!("TIFF tag {} element {i} at {at} := {v:#x}", e.tag)
        }
        _ => {
            // The value itself, by the tag's own dictionary where it has one.
            let v: u32 = match e.tag {
                259 => *rng.pick(&[1, 2, 5, 7, 8, 32773, 32946, 34887, 50000, 0, 65535]),
                258 => *rng.pick(&[0, 1, 4, 7, 8, 12, 16, 24, 32, 64, 128, 65535]),
                262 => *rng.pick(&[0, 1, 2, 3, 4, 5, 6, 8, 32844, 65535]),
                277 => *rng.pick(&[0, 1, 2, 3, 4, 255, 65535]),
                284 => *rng.pick(&[0, 1, 2, 3]),
                317 => *rng.pick(&[0, 1, 2, 3, 4, 34892]),
                339 => *rng.pick(&[0, 1, 2, 3, 4, 5, 6]),
                _ => interesting_u32(rng, len),
            };
            if e.typ == 3 && !big {
                put_u16(bytes, e.value_at, v as u16, le);
            } else if big {
                put_u64(bytes, e.value_at, u64::from(v), le);
            } else {
                put_u32(bytes, e.value_at, v, le);
            }
            format!("TIFF tag {} value := {v}", e.tag)
        }
    })
}

/// PNG chunks: (start, data length, type).
fn png_chunks(b: &[u8]) -> Vec<(usize, usize, [u8; 4])> {
    let mut out = Vec::new();
    let mut at = 8;
    while let Some(n) = get_u32(b, at, false) {
        let Some(t) = b.get(at + 4..at + 8) else { break };
        out.push((at, n as usize, t.try_into().expect("4 bytes")));
        match at.checked_add(12 + n as usize) {
            Some(next) if next <= b.len() => at = next,
            _ => break,
        }
    }
    out
}

fn fix_png_crc(b: &mut [u8], at: usize, n: usize) {
    if let Some(body) = b.get(at + 4..at + 8 + n) {
        let c = crc32(body);
        put_u32(b, at + 8 + n, c, false);
    }
}

fn png(bytes: &mut Vec<u8>, rng: &mut Rng) -> Option<String> {
    let chunks = png_chunks(bytes);
    let &(at, n, t) = rng.pick(&chunks);
    let len = bytes.len();
    let what = match rng.below(6) {
        0 | 1 if &t == b"IHDR" && n >= 13 => {
            let d = at + 8;
            let what = match rng.below(5) {
                0 => {
                    let v = interesting_u32(rng, len);
                    put_u32(bytes, d, v, false);
                    format!("width := {v}")
                }
                1 => {
                    let v = interesting_u32(rng, len);
                    put_u32(bytes, d + 4, v, false);
                    format!("height := {v}")
                }
                2 => {
                    let v = *rng.pick(&[0u8, 1, 2, 3, 4, 8, 16, 32, 255]);
                    put(bytes, d + 8, &[v]);
                    format!("bit depth := {v}")
                }
                3 => {
                    let v = *rng.pick(&[0u8, 1, 2, 3, 4, 5, 6, 7, 255]);
                    put(bytes, d + 9, &[v]);
                    format!("colour type := {v}")
                }
                _ => {
                    let v = rng.below(3) as u8;
                    let f = d + 10 + rng.below(3);
                    put(bytes, f, &[v]);
                    format!("byte {f} := {v}")
                }
            };
            format!("PNG IHDR {what}")
        }
        2 => {
            let v = interesting_u32(rng, len);
            put_u32(bytes, at, v, false);
            return Some(format!("PNG {} length {n} := {v}", String::from_utf8_lossy(&t)));
        }
        3 if n > 0 => {
            // Inside the data (the zlib stream of an IDAT), with the CRC fixed below.
            for _ in 0..1 + rng.below(4) {
                let p = at + 8 + rng.below(n);
                if let Some(b) = bytes.get_mut(p) {
                    *b ^= 1 << rng.below(8);
                }
            }
            format!("PNG {} data flipped", String::from_utf8_lossy(&t))
        }
        4 => {
            let end = (at + 12 + n).min(bytes.len());
            let chunk: Vec<u8> = bytes[at..end].to_vec();
            if rng.chance(0.5) {
                bytes.drain(at..end);
                return Some(format!("PNG {} dropped", String::from_utf8_lossy(&t)));
            }
            bytes.splice(at..at, chunk);
            return Some(format!("PNG {} duplicated", String::from_utf8_lossy(&t)));
        }
        _ => {
            bytes.truncate(at + rng.below(n + 12));
            return Some(format!("PNG cut inside {}", String::from_utf8_lossy(&t)));
        }
    };
    if rng.chance(0.9) {
        fix_png_crc(bytes, at, n);
    }
    Some(what)
}

/// JPEG segments before the first scan's data: (marker position, marker, length field).
fn jpeg_segments(b: &[u8]) -> Vec<(usize, u8, usize)> {
    let mut out = Vec::new();
    let mut at = 2;
    while at + 4 <= b.len() && b[at] == 0xFF {
        let m = b[at + 1];
        let n = get_u16(b, at + 2, false).unwrap_or(0) as usize;
        out.push((at, m, n));
        if m == 0xDA || n < 2 {
            break;
        }
        at += 2 + n;
    }
    out
}

fn jpeg(bytes: &mut Vec<u8>, rng: &mut Rng) -> Option<String> {
    let segs = jpeg_segments(bytes);
    let &(at, m, n) = rng.pick(&segs);
    let sof = matches!(m, 0xC0..=0xCF) && !matches!(m, 0xC4 | 0xC8 | 0xCC);
    Some(match rng.below(6) {
        0 | 1 if sof => {
            let d = at + 4;
            match rng.below(6) {
                0 => {
                    let v = *rng.pick(&[0u8, 1, 8, 12, 16, 255]);
                    put(bytes, d, &[v]);
                    format!("JPEG SOF precision := {v}")
                }
                1 | 2 => {
                    let v = *rng.pick(&U16S);
                    let f = d + 1 + 2 * rng.below(2);
                    put_u16(bytes, f, v, false);
                    format!("JPEG SOF {} := {v}", if f == d + 1 { "height" } else { "width" })
                }
                3 => {
                    let v = *rng.pick(&[0u8, 1, 2, 3, 4, 255]);
                    put(bytes, d + 5, &[v]);
                    format!("JPEG SOF components := {v}")
                }
                4 => {
                    let v = *rng.pick(&[0x00u8, 0x11, 0x12, 0x21, 0x22, 0x44, 0x88, 0xFF]);
                    put(bytes, d + 7 + 3 * rng.below(3), &[v]);
                    format!("JPEG SOF sampling := {v:#x}")
                }
                _ => {
                    let v = *rng.pick(&[0xC0u8, 0xC1, 0xC2, 0xC3, 0xC5, 0xC9, 0xCA, 0xCB]);
                    put(bytes, at + 1, &[v]);
                    format!("JPEG SOF marker := {v:#x}")
                }
            }
        }
        2 => {
            let v = *rng.pick(&U16S);
            put_u16(bytes, at + 2, v, false);
            format!("JPEG segment {m:#x} length {n} := {v}")
        }
        3 if n > 2 => {
            // Inside a segment: Huffman counts, quantization values, scan parameters.
            let p = at + 4 + rng.below(n - 2);
            let v = *rng.pick(&[0u8, 1, 2, 3, 15, 16, 63, 64, 0x80, 0xFF]);
            put(bytes, p, &[v]);
            format!("JPEG segment {m:#x} byte {p} := {v}")
        }
        4 => {
            let end = (at + 2 + n).min(bytes.len());
            bytes.drain(at..end);
            format!("JPEG segment {m:#x} dropped")
        }
        _ => {
            // Cut the entropy-coded data (the missing tail and EOI of a truncated download).
            let from = segs.last().map_or(0, |s| s.0);
            let to = from + rng.below(bytes.len().saturating_sub(from).max(1));
            bytes.truncate(to);
            format!("JPEG cut at {to}")
        }
    })
}

/// A header word of a table or index (sizes, counts, levels: its first 64 bytes).
fn table_header(bytes: &mut [u8], rng: &mut Rng) -> Option<String> {
    if bytes.len() < 8 {
        return None;
    }
    let at = 4 * rng.below(bytes.len().min(64) / 4);
    let v = interesting_u32(rng, bytes.len());
    put_u32(bytes, at, v, true);
    Some(format!("header word at {at} := {v:#x}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small_tiff() -> Vec<u8> {
        use tiff::encoder::{TiffEncoder, colortype::Gray16};
        let mut out = std::io::Cursor::new(Vec::new());
        TiffEncoder::new(&mut out).unwrap().write_image::<Gray16>(8, 4, &[3u16; 32]).unwrap();
        out.into_inner()
    }

    #[test]
    fn the_tiff_layout_is_found_and_its_fields_mutated() {
        let bytes = small_tiff();
        let (le, big, entries, pointers) = tiff_layout(&bytes).unwrap();
        assert!(le && !big);
        assert_eq!(pointers[0], 4);
        let width = entries.iter().find(|e| e.tag == 256).unwrap();
        assert_eq!(width.count, 1);
        assert_eq!(get_u16(&bytes, width.value_at, le), Some(8));
        // Some iteration changes the header fields, and every mutant differs from the seed.
        let mut changed_entries = 0;
        for i in 0..200 {
            let mut b = bytes.clone();
            let mut rng = Rng::for_case(1, i);
            if tiff(&mut b, &mut rng).is_some() && b[..bytes.len().min(b.len())] != bytes[..] {
                changed_entries += 1;
            }
        }
        assert!(changed_entries > 100, "{changed_entries} of 200 TIFF mutations changed the file");
    }

    #[test]
    fn crc_fixing_mutators_leave_valid_checksums() {
        let mut table = b"TDSS0123456789abcdef".to_vec();
        table.extend_from_slice(&[0; 4]);
        fix_crc_tail(&mut table);
        let n = table.len() - 4;
        assert_eq!(table[n..], crc32(&table[..n]).to_le_bytes());

        let img = image::GrayImage::from_pixel(8, 8, image::Luma([5u8]));
        let mut png_bytes = std::io::Cursor::new(Vec::new());
        img.write_to(&mut png_bytes, image::ImageFormat::Png).unwrap();
        let png_bytes = png_bytes.into_inner();
        let mut ihdr_changed = 0;
        for i in 0..300 {
            let mut b = png_bytes.clone();
            let what = png(&mut b, &mut Rng::for_case(2, i)).unwrap();
            // A field of the header (not its length, which its CRC does not cover).
            if what.starts_with("PNG IHDR") && !what.contains("length") && b != png_bytes {
                let (at, n, _) = png_chunks(&b)[0];
                let crc_ok = get_u32(&b, at + 8 + n, false) == Some(crc32(&b[at + 4..at + 8 + n]));
                ihdr_changed += usize::from(crc_ok);
            }
        }
        assert!(ihdr_changed > 10, "{ihdr_changed} IHDR mutants with a valid CRC");
    }
}
