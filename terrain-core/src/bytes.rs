//! Little-endian byte cursors for the engine's binary files: [`LeWriter`] appends values,
//! [`LeReader`] reads them back, bounds-checked, so a short or damaged file is an error
//! ([`Short`]), never a panic nor an allocation its bytes cannot back ([`LeReader::count`]).

use glam::DVec2;

/// A read past the end: `needed` bytes asked for at offset `at`, `left` there.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("needs {needed} bytes at offset {at}, {left} left")]
pub struct Short {
    /// Where the read started.
    pub at: usize,
    /// Bytes it needed.
    pub needed: usize,
    /// Bytes there were.
    pub left: usize,
}

impl From<Short> for String {
    fn from(s: Short) -> Self {
        s.to_string()
    }
}

/// Reads little-endian values off a byte slice, front to back.
#[derive(Debug, Clone)]
pub struct LeReader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> LeReader<'a> {
    /// A reader at the start of `buf`.
    pub fn new(buf: &'a [u8]) -> Self {
        Self { buf, pos: 0 }
    }

    /// The next `n` bytes.
    pub fn take(&mut self, n: usize) -> Result<&'a [u8], Short> {
        let left = self.remaining();
        if n > left {
            return Err(Short { at: self.pos, needed: n, left });
        }
        let s = &self.buf[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    /// The next `N` bytes as an array.
    pub fn array<const N: usize>(&mut self) -> Result<[u8; N], Short> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N)?);
        Ok(a)
    }

    /// A byte.
    pub fn u8(&mut self) -> Result<u8, Short> {
        Ok(self.take(1)?[0])
    }

    /// A `u16`.
    pub fn u16(&mut self) -> Result<u16, Short> {
        Ok(u16::from_le_bytes(self.array()?))
    }

    /// A `u32`.
    pub fn u32(&mut self) -> Result<u32, Short> {
        Ok(u32::from_le_bytes(self.array()?))
    }

    /// A `u64`.
    pub fn u64(&mut self) -> Result<u64, Short> {
        Ok(u64::from_le_bytes(self.array()?))
    }

    /// An `f32`.
    pub fn f32(&mut self) -> Result<f32, Short> {
        Ok(f32::from_le_bytes(self.array()?))
    }

    /// An `f64`.
    pub fn f64(&mut self) -> Result<f64, Short> {
        Ok(f64::from_le_bytes(self.array()?))
    }

    /// Two `f64`s, x then y.
    pub fn dvec2(&mut self) -> Result<DVec2, Short> {
        Ok(DVec2::new(self.f64()?, self.f64()?))
    }

    /// A `u32` count of items of `per_item` bytes each, refused (before anything is allocated
    /// by it) when the bytes left cannot hold them.
    pub fn count(&mut self, per_item: usize) -> Result<usize, Short> {
        let at = self.pos;
        let n = self.u32()? as usize;
        let left = self.remaining();
        match n.checked_mul(per_item) {
            Some(b) if b <= left => Ok(n),
            b => Err(Short { at, needed: b.unwrap_or(usize::MAX), left }),
        }
    }

    /// Offset of the next byte.
    pub fn pos(&self) -> usize {
        self.pos
    }

    /// Bytes not read yet.
    pub fn remaining(&self) -> usize {
        self.buf.len() - self.pos
    }
}

/// Appends little-endian values to a byte vector.
#[derive(Debug, Default, Clone)]
pub struct LeWriter {
    /// The bytes so far.
    pub buf: Vec<u8>,
}

impl LeWriter {
    /// A writer whose buffer has room for `n` bytes.
    pub fn with_capacity(n: usize) -> Self {
        Self { buf: Vec::with_capacity(n) }
    }

    /// A byte.
    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    /// A `u16`.
    pub fn u16(&mut self, v: u16) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// A `u32`.
    pub fn u32(&mut self, v: u32) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// A `u64`.
    pub fn u64(&mut self, v: u64) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// An `f32`.
    pub fn f32(&mut self, v: f32) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// An `f64`.
    pub fn f64(&mut self, v: f64) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Two `f64`s, x then y.
    pub fn dvec2(&mut self, v: DVec2) {
        self.f64(v.x);
        self.f64(v.y);
    }

    /// Raw bytes.
    pub fn bytes(&mut self, b: &[u8]) {
        self.buf.extend_from_slice(b);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_read_back_as_written_and_a_short_read_is_an_error() {
        let mut w = LeWriter::default();
        w.u8(7);
        w.u16(0xbeef);
        w.u32(u32::MAX - 1);
        w.u64(1 << 40);
        w.f32(-2.5);
        w.f64(8848.86);
        w.dvec2(DVec2::new(1.0, -1.0));
        w.bytes(b"ab");
        let mut r = LeReader::new(&w.buf);
        assert_eq!(r.u8(), Ok(7));
        assert_eq!(r.u16(), Ok(0xbeef));
        assert_eq!(r.u32(), Ok(u32::MAX - 1));
        assert_eq!(r.u64(), Ok(1 << 40));
        assert_eq!(r.f32(), Ok(-2.5));
        assert_eq!(r.f64(), Ok(8848.86));
        assert_eq!(r.dvec2(), Ok(DVec2::new(1.0, -1.0)));
        assert_eq!(r.remaining(), 2);
        assert_eq!(r.u32(), Err(Short { at: 43, needed: 4, left: 2 }));
        // A failed read consumes nothing.
        assert_eq!(r.take(2), Ok(&b"ab"[..]));
        assert_eq!(r.remaining(), 0);
        assert_eq!(
            String::from(Short { at: 1, needed: 8, left: 3 }),
            "needs 8 bytes at offset 1, 3 left"
        );
    }

    #[test]
    fn a_count_the_bytes_cannot_hold_is_refused() {
        let mut w = LeWriter::default();
        w.u32(3);
        w.bytes(&[0; 12]);
        assert_eq!(LeReader::new(&w.buf).count(4), Ok(3));
        assert!(LeReader::new(&w.buf).count(5).is_err());
        let mut huge = LeWriter::default();
        huge.u32(u32::MAX);
        assert!(LeReader::new(&huge.buf).count(usize::MAX / 2).is_err());
    }
}
