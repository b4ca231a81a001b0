//! The three roughness pyramids ([`RoughnessTables`]) of a grid read by bands of rows, for a
//! bake of a DEM larger than memory: memory is one band of rows (plus one row of margin on
//! each side, for Horn's 3x3 slope) and the pyramids' finest level, never the whole grid.
//!
//! The values are bit-identical to [`RoughnessTables::compute`] on the same grid in memory:
//! both go through the same kernels (`horn_slope_deg`, `secant`, `Normalize255`, `d2_node`,
//! `PyramidAccumulator`) and feed the per-node sums in the same row-major order.
//!
//! Two passes over the rows, because method C normalises every sample's roughness to 0-255
//! with the whole grid's range before averaging it per node (the paper's grey image, Eq. 5):
//! pass 1 takes that range, the heights' checksum ([`HeightsChecksum`]), method B's per-node
//! min/max and method A's `d2` (which reads only the rows at a node's bottom, middle and top,
//! clamped: kept while a pending node row needs them); pass 2 reads the rows again (or, for a
//! grid small enough, takes pass 1's roughness kept in memory) and averages the normalised
//! roughness per node.

use std::collections::BTreeMap;

use glam::DVec2;
use rayon::prelude::*;
use terrain_core::lod::dss_file::HeightsChecksum;

use super::{
    NodePyramid, Normalize255, PyramidAccumulator, Reduce, RoughnessConfig, RoughnessTables,
    d2_node, d2_spacing, horn_slope_deg, max_slope, root_cells, secant,
};

/// The grid the rows come from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RowGrid {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Metric spacing (x east, y north), as the heightmap's `georef().spacing_m`.
    pub spacing_m: DVec2,
}

/// What [`tables_by_rows`] returns: the pyramids and the heights' checksum
/// ([`terrain_core::lod::dss_file::heights_checksum`] of the same grid).
#[derive(Debug, Clone, PartialEq)]
pub struct ByRows {
    /// The three pyramids.
    pub tables: RoughnessTables,
    /// The CRC-32 of the heights and void flags.
    pub heights_checksum: u32,
}

/// Computes the three pyramids of `levels` levels of `grid`, reading it through `read(j0, rows,
/// heights, voids)` (rows `j0 .. j0 + rows`, south first, row-major, voids filled as the
/// heightmap would hold them, and the void mask) in bands of `band_rows` rows (each band is
/// read with one row of margin on each side), twice. Bands are read and their roughness
/// computed on rayon's threads, as many bands at a time as it has threads (memory: that many
/// bands); the sums are then taken in row order, so the result does not depend on the threads.
/// A grid of at most `keep_samples` samples keeps pass 1's roughness and void flags (5 bytes
/// per sample) instead of reading its rows again (a synthetic source regenerates them, a file
/// decodes them again); 0 always reads twice. `progress` gets the fraction done. Errors of
/// `read` are returned as they are.
pub fn tables_by_rows<E: Send>(
    grid: &RowGrid,
    levels: usize,
    config: &RoughnessConfig,
    band_rows: usize,
    keep_samples: usize,
    read: impl Fn(usize, usize, &mut [f32], &mut [bool]) -> Result<(), E> + Sync,
    mut progress: impl FnMut(f64),
) -> Result<ByRows, E> {
    assert!(levels >= 1, "a pyramid has at least the root level");
    let (w, h) = (grid.width, grid.height);
    let band = band_rows.max(1).min(h.max(1));
    let bands: Vec<(usize, usize)> =
        (0..h).step_by(band).map(|j0| (j0, (j0 + band).min(h))).collect();
    let group = rayon::current_num_threads().max(1);
    let max = max_slope(config);

    let mut checksum = HeightsChecksum::new();
    let mut range = PyramidAccumulator::new(w, h, levels, Reduce::Range);
    let mut d2 = D2Rows::new(w, h, levels, d2_spacing(grid.spacing_m));
    let mut mean = PyramidAccumulator::new(w, h, levels, Reduce::Mean);
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    let keep = w.saturating_mul(h) <= keep_samples;
    let mut kept: Vec<Band> = Vec::new();
    for pass in 0..2 {
        if pass == 1 && keep {
            // Pass 2 from pass 1's roughness: normalised the same way, summed in the same order.
            let norm = Normalize255::new(lo, hi);
            for b in &mut kept {
                b.rough.iter_mut().for_each(|v| *v = norm.apply(*v));
                for (j, r) in (b.j0..b.j1).zip(b.rough.chunks_exact(w.max(1))) {
                    let at = (j - b.r0) * w;
                    mean.add_row(j, r, |i| b.voids[at + i]);
                }
                progress((1.0 + b.j1 as f64 / h as f64) / 2.0);
            }
            break;
        }
        // Pass 2 normalises with the whole grid's range from pass 1.
        let norm = (pass == 1).then(|| Normalize255::new(lo, hi));
        for chunk in bands.chunks(group) {
            let read_band = |&(j0, j1): &(usize, usize)| -> Result<Band, E> {
                let (r0, r1) = (j0.saturating_sub(1), (j1 + 1).min(h));
                let mut heights = vec![0f32; (r1 - r0) * w];
                let mut voids = vec![false; (r1 - r0) * w];
                read(r0, r1 - r0, &mut heights, &mut voids)?;
                let mut rough = vec![0f32; (j1 - j0) * w];
                for (j, out) in (j0..j1).zip(rough.chunks_exact_mut(w.max(1))) {
                    roughness_row(&heights, &voids, grid, r0, j, max, out);
                    if let Some(n) = norm {
                        out.iter_mut().for_each(|v| *v = n.apply(*v));
                    }
                }
                Ok(Band { j0, j1, r0, heights, voids, rough })
            };
            let read: Vec<Result<Band, E>> = chunk.par_iter().map(read_band).collect();
            for b in read {
                let b = b?;
                for (j, r) in (b.j0..b.j1).zip(b.rough.chunks_exact(w.max(1))) {
                    let at = (j - b.r0) * w;
                    let (hrow, vrow) = (&b.heights[at..at + w], &b.voids[at..at + w]);
                    if pass == 0 {
                        checksum.add_heights(hrow);
                        checksum.add_voids(vrow);
                        range.add_row(j, hrow, |i| vrow[i]);
                        d2.push_row(j, hrow);
                        (lo, hi) = r.iter().fold((lo, hi), |(a, b), &v| (a.min(v), b.max(v)));
                    } else {
                        mean.add_row(j, r, |i| vrow[i]);
                    }
                }
                progress((pass as f64 + b.j1 as f64 / h as f64) / 2.0);
                if keep {
                    // Only the band's own rows' void flags are needed again.
                    let (a, z) = ((b.j0 - b.r0) * w, (b.j1 - b.r0) * w);
                    let voids = b.voids[a..z].to_vec();
                    kept.push(Band { r0: b.j0, heights: Vec::new(), voids, ..b });
                }
            }
        }
    }
    Ok(ByRows {
        tables: RoughnessTables {
            a: d2.finish().normalized_255(),
            b: range.finish().normalized_255(),
            c: mean.finish(),
        },
        heights_checksum: checksum.finish(),
    })
}

/// One band read: rows `j0 .. j1` with their margin from `r0`, and their roughness (normalised
/// in pass 2).
struct Band {
    j0: usize,
    j1: usize,
    r0: usize,
    heights: Vec<f32>,
    voids: Vec<bool>,
    rough: Vec<f32>,
}

/// Eq. 5 roughness of row `j` into `out`, from a band holding rows `r0 ..` (with the rows
/// above and below `j` where the grid has them), as `roughness` computes it on the whole grid:
/// a neighbour outside the grid or void takes the centre's height.
fn roughness_row(
    heights: &[f32],
    voids: &[bool],
    grid: &RowGrid,
    r0: usize,
    j: usize,
    max: f64,
    out: &mut [f32],
) {
    let (w, h) = (grid.width as i64, grid.height as i64);
    for (i, o) in out.iter_mut().enumerate() {
        let at = |x: i64, y: i64| (y as usize - r0) * grid.width + x as usize;
        let c = heights[at(i as i64, j as i64)] as f64;
        let z = |di: i64, dj: i64| -> f64 {
            let (x, y) = (i as i64 + di, j as i64 + dj);
            if x < 0 || y < 0 || x >= w || y >= h || voids[at(x, y)] {
                c
            } else {
                heights[at(x, y)] as f64
            }
        };
        *o = secant(horn_slope_deg(z, grid.spacing_m), max);
    }
}

/// Method A's `d2` per node, fed rows in order: node row `nj` of a level with `c` cells per
/// node reads rows `y0 = nj c`, `y0 + c / 2` and `y0 + c` (clamped to the grid), so it is
/// computed when its top row arrives; only the rows a level's next node row reads are kept
/// (at most three per level).
#[derive(Debug)]
struct D2Rows {
    w: usize,
    h: usize,
    root: usize,
    spacing: f64,
    /// The next node row to compute, per level.
    next: Vec<usize>,
    out: Vec<Vec<f32>>,
    rows: BTreeMap<usize, Vec<f32>>,
}

impl D2Rows {
    fn new(w: usize, h: usize, levels: usize, spacing: f64) -> Self {
        Self {
            w,
            h,
            root: root_cells(w, h),
            spacing,
            next: vec![0; levels],
            out: (0..levels).map(|l| vec![0.0; 1 << (2 * l)]).collect(),
            rows: BTreeMap::new(),
        }
    }

    /// Cells per node side at `level` (as `d2_pyramid`: `root / side`, at least 1).
    fn cells(&self, level: usize) -> usize {
        (self.root >> level).max(1)
    }

    /// Whether `level` has a node row left that covers grid samples.
    fn pending(&self, level: usize) -> bool {
        let nj = self.next[level];
        nj < 1 << level && nj * self.cells(level) < self.h
    }

    /// The rows node row `nj` of `level` reads: bottom, middle, top, clamped.
    fn rows_of(&self, level: usize, nj: usize) -> [usize; 3] {
        let (c, last) = (self.cells(level), self.h - 1);
        let y0 = nj * c;
        [y0.min(last), (y0 + c / 2).min(last), (y0 + c).min(last)]
    }

    fn push_row(&mut self, j: usize, row: &[f32]) {
        let levels = self.next.len();
        let needed = j == self.h - 1
            || (0..levels).any(|l| {
                let (c, y0) = (self.cells(l), self.next[l] * self.cells(l));
                self.pending(l) && j >= y0 && (j - y0).is_multiple_of((c / 2).max(1))
            });
        if needed {
            self.rows.insert(j, row.to_vec());
        }
        for l in 0..levels {
            while self.pending(l) {
                let nj = self.next[l];
                let [r0, rm, r1] = self.rows_of(l, nj);
                if r1 > j {
                    break;
                }
                let (c, side, w) = (self.cells(l), 1usize << l, self.w);
                let (bottom, middle, top) = (&self.rows[&r0], &self.rows[&rm], &self.rows[&r1]);
                let y0 = nj * c;
                let z = |x: usize, y: usize| -> f64 {
                    let row = if y <= y0 {
                        bottom
                    } else if y < y0 + c {
                        middle
                    } else {
                        top
                    };
                    row[x.min(w - 1)] as f64
                };
                for ni in 0..side {
                    let x0 = ni * c;
                    if x0 >= w {
                        continue;
                    }
                    self.out[l][nj * side + ni] = d2_node(z, x0, y0, c, self.spacing);
                }
                self.next[l] += 1;
            }
        }
        let keep: Vec<usize> = (0..levels)
            .filter(|&l| self.pending(l))
            .flat_map(|l| self.rows_of(l, self.next[l]))
            .collect();
        self.rows.retain(|r, _| keep.contains(r));
    }

    fn finish(self) -> NodePyramid {
        debug_assert!((0..self.next.len()).all(|l| !self.pending(l)), "rows missing");
        NodePyramid { levels: self.out, root_cells: self.root }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use terrain_core::Heightmap;
    use terrain_core::lod::dss_file::heights_checksum;
    use terrain_core::synth::{FractalConfig, HardCase};

    /// The pyramids of `hm` by rows of `band` rows, read from the heightmap.
    fn by_rows(hm: &Heightmap, levels: usize, band: usize, keep: usize) -> ByRows {
        let grid =
            RowGrid { width: hm.width(), height: hm.height(), spacing_m: hm.georef().spacing_m };
        let w = hm.width();
        let reads = std::sync::atomic::AtomicUsize::new(0);
        let out = tables_by_rows(
            &grid,
            levels,
            &RoughnessConfig::default(),
            band,
            keep,
            |j0, rows, heights: &mut [f32], voids: &mut [bool]| {
                assert!(rows <= band + 2, "a band of {rows} rows for bands of {band}");
                heights.copy_from_slice(&hm.data()[j0 * w..(j0 + rows) * w]);
                for (k, v) in voids.iter_mut().enumerate() {
                    *v = hm.voids().get(k % w, j0 + k / w);
                }
                reads.fetch_add(rows, std::sync::atomic::Ordering::Relaxed);
                Ok::<_, std::convert::Infallible>(())
            },
            |_| {},
        )
        .unwrap();
        // Two passes (one when kept), each band with at most two rows of margin.
        let reads = reads.into_inner();
        let passes = if hm.width() * hm.height() <= keep { 1 } else { 2 };
        assert!(
            reads >= passes * hm.height()
                && reads <= passes * (hm.height() + 2 * hm.height().div_ceil(band))
        );
        out
    }

    fn with_voids(hm: Heightmap, every: usize) -> Heightmap {
        let (w, h, data, mut mask, georef) = hm.into_parts();
        for k in (3..w * h).step_by(every) {
            mask.set(k % w, k / w, true);
        }
        // A void block at the north-east corner and one on the west border.
        for j in h.saturating_sub(4)..h {
            for i in w.saturating_sub(5)..w {
                mask.set(i, j, true);
            }
        }
        for j in h / 3..(h / 3 + 3).min(h) {
            mask.set(0, j, true);
        }
        Heightmap::new(w, h, data, mask, georef).unwrap()
    }

    fn check(name: &str, hm: &Heightmap, levels: usize, bands: &[usize]) {
        let want = RoughnessTables::compute(hm, levels, &RoughnessConfig::default());
        assert!(want.c.level(0)[0] > 0.0 || hm.max() == hm.min(), "{name}: C is all 0");
        for &band in bands {
            // Bands read twice, and pass 1's roughness kept.
            let got = by_rows(hm, levels, band, if band % 2 == 0 { 0 } else { usize::MAX });
            for (k, (x, y)) in
                [(&want.a, &got.tables.a), (&want.b, &got.tables.b), (&want.c, &got.tables.c)]
                    .into_iter()
                    .enumerate()
            {
                for l in 0..levels {
                    let bits = |p: &NodePyramid| {
                        p.level(l).iter().map(|v| v.to_bits()).collect::<Vec<_>>()
                    };
                    assert_eq!(
                        bits(x),
                        bits(y),
                        "{name}: pyramid {} level {l}, bands of {band}",
                        ["A", "B", "C"][k]
                    );
                }
            }
            assert!(got.tables.bits_eq(&want));
            assert_eq!(got.heights_checksum, heights_checksum(hm), "{name}: heights checksum");
        }
    }

    #[test]
    fn by_rows_equals_the_whole_grid_bit_for_bit_on_fractals_with_voids() {
        // Non-square, non-power-of-two, with voids; levels down to one sample per finest node
        // and beyond (c = 1 at the finest levels of the 8-level pyramid over a 128 root).
        let hm = with_voids(FractalConfig::with_size(97, 61, 10.0).to_heightmap().unwrap(), 37);
        assert!(hm.voids().count() > 100);
        for levels in [1, 3, 6, 8] {
            check("fractal 97 x 61 with voids", &hm, levels, &[1, 2, 3, 7, 16, 61, 1000]);
        }
        let tall = with_voids(
            Heightmap::from_fn(
                33,
                130,
                terrain_core::Georef::projected(
                    terrain_core::georef::Crs::Unknown,
                    glam::DVec2::ZERO,
                    glam::dvec2(30.0, 20.0),
                ),
                |i, j| ((i * 7 + j * 13) % 29) as f32 * 3.5 + (j as f32 * 0.37).sin() * 40.0,
            )
            .unwrap(),
            11,
        );
        check("tall 33 x 130, anisotropic spacing", &tall, 5, &[1, 5, 64, 129, 130]);
    }

    #[test]
    fn by_rows_equals_the_whole_grid_bit_for_bit_on_the_hard_cases() {
        for case in HardCase::all() {
            let hm = case.build();
            if hm.width() * hm.height() > 600_000 {
                continue;
            }
            let levels = (root_cells(hm.width(), hm.height()).trailing_zeros() as usize + 1).min(6);
            check(case.name(), &hm, levels, &[1, 4, 100]);
        }
        // The odd-size fractal (1000 x 777) once, in bands of 64 rows.
        check("odd size", &HardCase::OddSize.build(), 7, &[64]);
    }
}
