//! Min/max height mip over a heightmap's samples: conservative rectangle queries for the PVS
//! bake's early exits (max heights: can anything block this stretch of a sight line?) and for
//! the conservative mode's occluder proofs (min heights: is the terrain surely above it?).

use terrain_core::Heightmap;

/// Per level `k >= 1`, the min and max of the samples `[i 2^k, (i + 1) 2^k - 1]` in x and y
/// (clipped to the grid); level 0 is the heightmap itself.
#[derive(Debug, Clone)]
pub struct HeightMip<'a> {
    hm: &'a Heightmap,
    /// `levels[k - 1]`: (nx, ny, min, max).
    levels: Vec<(usize, usize, Vec<f32>, Vec<f32>)>,
    /// The heightmap column by column (`columns[x * h + y]`): a sight line stepping along y
    /// reads neighbouring memory (see [`Self::columns`]).
    columns: Vec<f32>,
}

impl<'a> HeightMip<'a> {
    /// Builds the mip of `hm` (about a third of the grid's size in each of min and max).
    pub fn new(hm: &'a Heightmap) -> Self {
        let (w, h) = (hm.width(), hm.height());
        let mut levels: Vec<(usize, usize, Vec<f32>, Vec<f32>)> = Vec::new();
        let (mut pw, mut ph) = (w, h);
        while pw > 1 || ph > 1 {
            let (nx, ny) = (pw.div_ceil(2), ph.div_ceil(2));
            let mut mn = vec![f32::INFINITY; nx * ny];
            let mut mx = vec![f32::NEG_INFINITY; nx * ny];
            for y in 0..ph {
                for x in 0..pw {
                    let (a, b) = match levels.last() {
                        None => {
                            let z = hm.get(x, y);
                            (z, z)
                        }
                        Some((fx, _, fmn, fmx)) => (fmn[y * fx + x], fmx[y * fx + x]),
                    };
                    let k = (y / 2) * nx + x / 2;
                    mn[k] = mn[k].min(a);
                    mx[k] = mx[k].max(b);
                }
            }
            levels.push((nx, ny, mn, mx));
            pw = nx;
            ph = ny;
        }
        let mut columns = vec![0.0f32; w * h];
        for (y, row) in hm.data().chunks_exact(w).enumerate() {
            for (x, &v) in row.iter().enumerate() {
                columns[x * h + y] = v;
            }
        }
        Self { hm, levels, columns }
    }

    /// The heightmap's samples column by column: sample `(x, y)` at `x * height + y` (the
    /// heightmap's own `data()` is row by row).
    pub fn columns(&self) -> &[f32] {
        &self.columns
    }

    /// The heightmap.
    pub fn heightmap(&self) -> &'a Heightmap {
        self.hm
    }

    /// `(min, max)` bounds of the samples in the inclusive rectangle `x0..=x1`, `y0..=y1`
    /// (clamped to the grid): the min is a lower bound and the max an upper bound (exact on
    /// level 0, otherwise over the covering blocks, which may reach a little outside).
    pub fn range(&self, x0: i64, y0: i64, x1: i64, y1: i64) -> (f32, f32) {
        let (x0, y0, x1, y1, k) = self.covering(x0, y0, x1, y1);
        let (mut mn, mut mx) = (f32::INFINITY, f32::NEG_INFINITY);
        for by in (y0 >> k)..=(y1 >> k) {
            for bx in (x0 >> k)..=(x1 >> k) {
                let (a, b) = if k == 0 {
                    let z = self.hm.get(bx, by);
                    (z, z)
                } else {
                    let (nx, _, lmn, lmx) = &self.levels[k - 1];
                    (lmn[by * nx + bx], lmx[by * nx + bx])
                };
                mn = mn.min(a);
                mx = mx.max(b);
            }
        }
        (mn, mx)
    }
}

impl HeightMip<'_> {
    /// The inclusive rectangle clamped to the grid and ordered, and the finest level `k` at
    /// which it touches at most 3 x 3 blocks (the blocks [`Self::range`] and
    /// [`Self::range_max`] read).
    #[inline]
    fn covering(&self, x0: i64, y0: i64, x1: i64, y1: i64) -> (usize, usize, usize, usize, usize) {
        let (w, h) = (self.hm.width() as i64, self.hm.height() as i64);
        let (x0, x1) = (x0.clamp(0, w - 1) as usize, x1.clamp(0, w - 1) as usize);
        let (y0, y1) = (y0.clamp(0, h - 1) as usize, y1.clamp(0, h - 1) as usize);
        let (x0, x1) = (x0.min(x1), x0.max(x1));
        let (y0, y1) = (y0.min(y1), y0.max(y1));
        // Below `bits(span) - 4` a block row or column alone holds more than 9 blocks.
        let span = (x1 - x0).max(y1 - y0);
        let mut k = ((usize::BITS - span.leading_zeros()).saturating_sub(4) as usize)
            .min(self.levels.len());
        while k < self.levels.len() && ((x1 >> k) - (x0 >> k) + 1) * ((y1 >> k) - (y0 >> k) + 1) > 9
        {
            k += 1;
        }
        (x0, y0, x1, y1, k)
    }

    /// [`Self::range`]'s max alone (the same blocks; reads only the max levels).
    pub fn range_max(&self, x0: i64, y0: i64, x1: i64, y1: i64) -> f32 {
        let w = self.hm.width();
        let (x0, y0, x1, y1, k) = self.covering(x0, y0, x1, y1);
        let mut mx = f32::NEG_INFINITY;
        if k == 0 {
            let data = self.hm.data();
            for y in y0..=y1 {
                for &v in &data[y * w + x0..=y * w + x1] {
                    mx = mx.max(v);
                }
            }
        } else {
            let (nx, _, _, lmx) = &self.levels[k - 1];
            for by in (y0 >> k)..=(y1 >> k) {
                for &v in &lmx[by * nx + (x0 >> k)..=by * nx + (x1 >> k)] {
                    mx = mx.max(v);
                }
            }
        }
        mx
    }

    /// An *upper* bound of the min of the samples in the inclusive rectangle (clamped to the
    /// grid as [`Self::range`]): the min of the largest aligned mip block wholly inside it (a
    /// subset's min is at least the whole's). A cheap exact reject for min queries: `range`'s
    /// min is at most this. The block's level has at most a quarter of the rectangle's samples
    /// per entry, so large rectangles read small, cache-resident levels.
    #[inline]
    pub fn inner_min(&self, x0: i64, y0: i64, x1: i64, y1: i64) -> f32 {
        let (w, h) = (self.hm.width() as i64, self.hm.height() as i64);
        let (x0, x1) = (x0.clamp(0, w - 1), x1.clamp(0, w - 1));
        let (y0, y1) = (y0.clamp(0, h - 1), y1.clamp(0, h - 1));
        let (x0, x1) = (x0.min(x1) as usize, x0.max(x1) as usize);
        let (y0, y1) = (y0.min(y1) as usize, y0.max(y1) as usize);
        let k = inner_level(x1 - x0 + 1).min(inner_level(y1 - y0 + 1)).min(self.levels.len());
        let (bx, by) = (x0.div_ceil(1 << k), y0.div_ceil(1 << k));
        if k == 0 {
            self.hm.get(bx, by)
        } else {
            let (nx, _, lmn, _) = &self.levels[k - 1];
            lmn[by * nx + bx]
        }
    }
}

/// The largest `k` such that every run of `n >= 1` consecutive samples holds an aligned block
/// of `2^k` (true when `2^(k + 1) - 1 <= n`): `floor(log2(n + 1)) - 1`.
#[inline]
fn inner_level(n: usize) -> usize {
    (usize::BITS - 1 - (n + 1).leading_zeros()) as usize - 1
}

/// Per grid line (every column `x = i`, every row `y = j`), a 1D min pyramid along it: lower
/// bounds of the terrain on a stretch of one grid line, without the neighbouring lines that a
/// 2D block would mix in (a one-sample-thin wall keeps its height).
///
/// Stored per level with the *line index fastest* (level `k` of the columns is a
/// `ceil(h / 2^k) x w` row-major array), so the grid-line proof, which reads neighbouring lines
/// at about the same place, touches neighbouring memory.
#[derive(Debug, Clone)]
pub struct LineMins {
    /// `cols[k][m * w + i]`: the min of column `i` over rows `m 2^k ..= (m + 1) 2^k - 1`
    /// (clipped to the grid).
    cols: Vec<Vec<f32>>,
    /// `rows[k][m * h + j]`: the min of row `j` over columns `m 2^k ..= (m + 1) 2^k - 1`.
    rows: Vec<Vec<f32>>,
    w: usize,
    h: usize,
}

/// The levels of a pyramid of `lines` lines of `len` samples each, level 0 given as
/// `base[m * lines + i]` (sample `m` of line `i`): level `k + 1` holds the min of pairs of
/// level `k` (the last one alone when the count is odd), down to one entry per line.
fn line_pyramid(base: Vec<f32>, lines: usize, len: usize) -> Vec<Vec<f32>> {
    let mut levels = vec![base];
    let mut n = len;
    while n > 1 {
        let prev = levels.last().expect("a level");
        let next_n = n.div_ceil(2);
        let mut next = vec![f32::INFINITY; next_n * lines];
        for m in 0..n {
            let (src, dst) = (&prev[m * lines..(m + 1) * lines], &mut next[(m / 2) * lines..]);
            for (d, &v) in dst[..lines].iter_mut().zip(src) {
                *d = d.min(v);
            }
        }
        levels.push(next);
        n = next_n;
    }
    levels
}

/// A lower bound of samples `a..=b` (within `0..len`) of line `i`: the min over the coarsest
/// level's entries covering them, at most 4 (unchanged from the per-line layout).
fn line_min(levels: &[Vec<f32>], lines: usize, i: usize, a: usize, b: usize) -> f32 {
    let mut k = 0;
    while k + 1 < levels.len() && (b >> k) - (a >> k) + 1 > 4 {
        k += 1;
    }
    ((a >> k)..=(b >> k)).map(|m| levels[k][m * lines + i]).fold(f32::INFINITY, f32::min)
}

/// An upper bound of the min of samples `a..=b` (clamped to `0..len`) of line `i`: the min of
/// the largest aligned level entry wholly inside them (see [`HeightMip::inner_min`]).
#[inline]
fn line_inner_min(levels: &[Vec<f32>], lines: usize, len: usize, i: usize, a: i64, b: i64) -> f32 {
    let n = len as i64;
    let (a, b) = (a.clamp(0, n - 1), b.clamp(0, n - 1));
    let (a, b) = (a.min(b) as usize, a.max(b) as usize);
    let k = inner_level(b - a + 1).min(levels.len() - 1);
    levels[k][a.div_ceil(1 << k) * lines + i]
}

impl LineMins {
    /// An upper bound of [`Self::column_min`]'s true min (see [`HeightMip::inner_min`]).
    #[inline]
    pub fn column_inner_min(&self, i: usize, y0: i64, y1: i64) -> f32 {
        line_inner_min(&self.cols, self.w, self.h, i, y0, y1)
    }

    /// An upper bound of [`Self::row_min`]'s true min (see [`HeightMip::inner_min`]).
    #[inline]
    pub fn row_inner_min(&self, j: usize, x0: i64, x1: i64) -> f32 {
        line_inner_min(&self.rows, self.h, self.w, j, x0, x1)
    }

    /// Builds the pyramids of every column and row of `hm` (twice the grid's size in all).
    pub fn new(hm: &Heightmap) -> Self {
        let (w, h) = (hm.width(), hm.height());
        let cols = line_pyramid(hm.data().to_vec(), w, h);
        let mut t = vec![0.0f32; w * h];
        for (j, row) in hm.data().chunks_exact(w).enumerate() {
            for (x, &v) in row.iter().enumerate() {
                t[x * h + j] = v;
            }
        }
        let rows = line_pyramid(t, h, w);
        Self { cols, rows, w, h }
    }

    /// A lower bound of the samples of column `i`, rows `y0..=y1` (clamped to the grid).
    pub fn column_min(&self, i: usize, y0: i64, y1: i64) -> f32 {
        let n = self.h as i64;
        let (a, b) = (y0.clamp(0, n - 1) as usize, y1.clamp(0, n - 1) as usize);
        line_min(&self.cols, self.w, i, a, b)
    }

    /// A lower bound of the samples of row `j`, columns `x0..=x1` (clamped to the grid).
    pub fn row_min(&self, j: usize, x0: i64, x1: i64) -> f32 {
        let n = self.w as i64;
        let (a, b) = (x0.clamp(0, n - 1) as usize, x1.clamp(0, n - 1) as usize);
        line_min(&self.rows, self.h, j, a, b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use terrain_core::georef::Georef;

    #[test]
    fn ranges_bound_the_samples() {
        let hm = Heightmap::from_fn(37, 29, Georef::local(1.0), |i, j| {
            ((i * 7 + j * 13) % 17) as f32 + (i as f32 * 0.3).sin()
        })
        .unwrap();
        let mip = HeightMip::new(&hm);
        for (x0, y0, x1, y1) in [(0, 0, 36, 28), (3, 4, 9, 20), (10, 10, 10, 10), (30, 1, 36, 2)] {
            let (mn, mx) = mip.range(x0, y0, x1, y1);
            let mut emn = f32::INFINITY;
            let mut emx = f32::NEG_INFINITY;
            for y in y0..=y1 {
                for x in x0..=x1 {
                    emn = emn.min(hm.get(x as usize, y as usize));
                    emx = emx.max(hm.get(x as usize, y as usize));
                }
            }
            assert!(mn <= emn && mx >= emx, "{mn} {emn} {mx} {emx}");
        }
        for (x0, y0, x1, y1) in [(0, 0, 36, 28), (3, 4, 9, 20), (10, 10, 10, 10), (30, 1, 40, 2)] {
            let mut emn = f32::INFINITY;
            for y in y0..=y1.min(28) {
                for x in x0..=x1.min(36) {
                    emn = emn.min(hm.get(x as usize, y as usize));
                }
            }
            let inner = mip.inner_min(x0, y0, x1, y1);
            assert!(inner >= emn && inner >= mip.range(x0, y0, x1, y1).0, "{inner} {emn}");
            // The bound is some sample's height inside the rectangle.
            assert!(
                (y0..=y1.min(28))
                    .any(|y| (x0..=x1.min(36)).any(|x| hm.get(x as usize, y as usize) == inner))
            );
        }
        let lines = LineMins::new(&hm);
        for (i, a, b) in [(0usize, 0i64, 28i64), (5, 3, 17), (36, 9, 9), (12, -4, 40)] {
            let exact =
                (a.max(0)..=b.min(28)).map(|y| hm.get(i, y as usize)).fold(f32::INFINITY, f32::min);
            let inner = lines.column_inner_min(i, a, b);
            assert!(inner >= exact && inner >= lines.column_min(i, a, b), "{inner} {exact}");
            let exact = (a.max(0)..=b.min(36))
                .map(|x| hm.get(x as usize, i.min(28)))
                .fold(f32::INFINITY, f32::min);
            assert!(lines.row_inner_min(i.min(28), a, b) >= exact);
        }
        for (x0, y0, x1, y1) in [(0, 0, 36, 28), (3, 4, 9, 20), (10, 10, 10, 10), (30, 1, 40, -2)] {
            assert_eq!(mip.range_max(x0, y0, x1, y1), mip.range(x0, y0, x1, y1).1);
        }
        assert_eq!(mip.range(0, 0, 36, 28), (hm.min(), hm.max()));
        for (x, y) in [(0, 0), (36, 0), (0, 28), (17, 11)] {
            assert_eq!(mip.columns()[x * 29 + y], hm.get(x, y));
        }
        assert_eq!(mip.range(5, 6, 5, 6), (hm.get(5, 6), hm.get(5, 6)));
    }
}
