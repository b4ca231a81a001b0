//! What a bake reads: [`HeightSource`], a grid delivered by rows, so that grids larger than
//! memory (the 32769^2 synthetic terrain) stream through the bake in bounded memory.

use rayon::prelude::*;
use terrain_core::dem::RowReader;
use terrain_core::georef::Georef;
use terrain_core::heightmap::Heightmap;
use terrain_core::synth::FractalConfig;

/// A grid of heights in metres delivered by rows (row 0 = south, as in
/// [`terrain_core::heightmap`]). `Sync`: the bake reads bands of rows in parallel.
pub trait HeightSource: Sync {
    /// Columns.
    fn width(&self) -> u64;
    /// Rows.
    fn height(&self) -> u64;
    /// Georeference and CRS of sample (0, 0).
    fn georef(&self) -> Georef;
    /// Writes rows `j0 .. j0 + rows` (row-major, all columns) into `out`
    /// (`width * rows` samples, finite).
    fn read_rows(&self, j0: u64, rows: usize, out: &mut [f32]) -> std::io::Result<()>;
    /// Marks the void (no-data, filled) samples of the same rows; the default has none.
    fn read_void_rows(&self, j0: u64, rows: usize, out: &mut [bool]) -> std::io::Result<()> {
        let _ = (j0, rows);
        out.fill(false);
        Ok(())
    }
    /// Both at once: [`HeightSource::read_rows`] into `heights` and
    /// [`HeightSource::read_void_rows`] into `voids` (the default calls one, then the other; a
    /// file reader reads the rows once for both).
    fn read_rows_and_voids(
        &self,
        j0: u64,
        rows: usize,
        heights: &mut [f32],
        voids: &mut [bool],
    ) -> std::io::Result<()> {
        self.read_rows(j0, rows, heights)?;
        self.read_void_rows(j0, rows, voids)
    }
}

/// Rows `j0 .. j0 + heights.len() / width` of `source`, heights and void flags, read in chunks
/// of rows on rayon's threads (a synthetic source generates them, a file decodes them, on every
/// core); the bytes are those of one [`HeightSource::read_rows_and_voids`] of the whole band.
/// The error names the chunk that failed.
pub fn read_rows_parallel(
    source: &dyn HeightSource,
    j0: u64,
    heights: &mut [f32],
    voids: &mut [bool],
) -> Result<(), crate::BakeError> {
    let width = usize::try_from(source.width()).unwrap_or(usize::MAX).max(1);
    let rows = heights.len() / width;
    let chunk = rows.div_ceil(rayon::current_num_threads() * 2).max(1);
    heights
        .par_chunks_mut(width * chunk)
        .zip(voids.par_chunks_mut(width * chunk))
        .enumerate()
        .try_for_each(|(c, (out, void))| {
            let r0 = j0 + (c * chunk) as u64;
            let n = out.len() / width;
            source.read_rows_and_voids(r0, n, out, void).map_err(|e| crate::BakeError::Source {
                j0: r0,
                rows: n,
                cause: e,
            })
        })
}

fn check(w: u64, h: u64, j0: u64, rows: usize, len: usize) -> std::io::Result<()> {
    let ok = j0.checked_add(rows as u64).is_some_and(|e| e <= h) && len as u64 == w * rows as u64;
    if ok {
        Ok(())
    } else {
        Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("rows {j0}..+{rows} with a buffer of {len} do not fit a {w} x {h} grid"),
        ))
    }
}

impl HeightSource for Heightmap {
    fn width(&self) -> u64 {
        Heightmap::width(self) as u64
    }
    fn height(&self) -> u64 {
        Heightmap::height(self) as u64
    }
    fn georef(&self) -> Georef {
        Heightmap::georef(self).clone()
    }
    fn read_rows(&self, j0: u64, rows: usize, out: &mut [f32]) -> std::io::Result<()> {
        check(HeightSource::width(self), HeightSource::height(self), j0, rows, out.len())?;
        let w = Heightmap::width(self);
        let start = j0 as usize * w;
        out.copy_from_slice(&self.data()[start..start + rows * w]);
        Ok(())
    }
    fn read_void_rows(&self, j0: u64, rows: usize, out: &mut [bool]) -> std::io::Result<()> {
        check(HeightSource::width(self), HeightSource::height(self), j0, rows, out.len())?;
        let w = Heightmap::width(self);
        let v = self.voids();
        if !v.any() {
            out.fill(false);
            return Ok(());
        }
        for (r, row) in out.chunks_exact_mut(w).enumerate() {
            for (i, o) in row.iter_mut().enumerate() {
                *o = v.get(i, j0 as usize + r);
            }
        }
        Ok(())
    }
}

/// The synthetic fractal streams by rows: nothing of the whole grid is ever allocated.
impl HeightSource for FractalConfig {
    fn width(&self) -> u64 {
        self.width
    }
    fn height(&self) -> u64 {
        self.height
    }
    fn georef(&self) -> Georef {
        Georef::local(self.spacing_m)
    }
    fn read_rows(&self, j0: u64, rows: usize, out: &mut [f32]) -> std::io::Result<()> {
        check(self.width, self.height, j0, rows, out.len())?;
        self.validate().map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))?;
        self.generate_rows(j0, rows, out);
        Ok(())
    }
}

/// A GeoTIFF or raw file read by bands of rows: DEMs larger than memory bake in bounded
/// memory (voids filled as [`RowReader`] documents).
impl HeightSource for RowReader {
    fn width(&self) -> u64 {
        RowReader::width(self)
    }
    fn height(&self) -> u64 {
        RowReader::height(self)
    }
    fn georef(&self) -> Georef {
        RowReader::georef(self).clone()
    }
    fn read_rows(&self, j0: u64, rows: usize, out: &mut [f32]) -> std::io::Result<()> {
        let mut voids = vec![false; out.len()];
        RowReader::read_rows(self, j0, rows, out, &mut voids).map_err(std::io::Error::other)
    }
    fn read_void_rows(&self, j0: u64, rows: usize, out: &mut [bool]) -> std::io::Result<()> {
        RowReader::read_void_rows(self, j0, rows, out).map_err(std::io::Error::other)
    }
    fn read_rows_and_voids(
        &self,
        j0: u64,
        rows: usize,
        heights: &mut [f32],
        voids: &mut [bool],
    ) -> std::io::Result<()> {
        RowReader::read_rows(self, j0, rows, heights, voids).map_err(std::io::Error::other)
    }
}
