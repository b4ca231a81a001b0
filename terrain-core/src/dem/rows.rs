//! DEMs read by bands of rows, never whole: [`RowReader`] streams GeoTIFF (strips or tiles,
//! any compression the `tiff` crate decodes) and raw files of any size in bounded memory, for
//! bakes of grids larger than memory (terrain-stream's `HeightSource`).
//!
//! Rows are delivered south first, like [`Heightmap`](crate::heightmap::Heightmap). Voids
//! (no-data, NaN) are marked and filled, but not as [`load`](super::load) fills them (the membrane
//! fill of [`voids`](super::voids) needs the whole grid): here a void sample takes the
//! inverse-distance-squared mean (distances in metres) of the nearest valid sample in each of
//! the four axis directions: along its row (the whole row) and along its column within
//! [`FILL_REACH_ROWS`] rows. That value is a pure function of the sample's row and the rows
//! within reach, so two bands that both read a row (blocks share their border rows) fill it
//! identically, whatever the band boundaries. A void with no valid sample in its row nor within
//! reach in its column (a row of open sea) is set to 0 m, and counted.

use std::collections::VecDeque;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use tiff::decoder::{ChunkType, Decoder};

use super::{
    Format, LoadOptions, RawSampleType, SourceInfo, detect_format, geotiff, geotiff_chunks,
};
use crate::error::{DemError, DemErrorKind};
use crate::georef::Georef;

/// How far (in rows) a void sample looks up and down its column for a valid sample.
pub const FILL_REACH_ROWS: usize = 64;

/// Decoders kept for reuse between band reads (one per concurrent reader at most).
const DECODER_POOL: usize = 8;

enum Inner {
    Raw {
        sample: RawSampleType,
        scale: f64,
        offset: f64,
    },
    Tiff {
        decoders: Mutex<Vec<Decoder<geotiff::Source>>>,
        /// How the samples lie in the chunks (Deflate chunks are checked, Adler-32 and end of
        /// stream, before each is decoded), the band read, GDAL's scale and offset, the mask.
        layout: Box<geotiff_chunks::Layout>,
        vertical: geotiff::Vertical,
        /// Recently decoded chunks, in metres, voids NaN: a band's rows are read in several
        /// pieces (and once more for the void mask), and each piece would otherwise decode the
        /// same strips or tiles.
        recent: Mutex<VecDeque<(u32, Arc<Vec<f32>>)>>,
        recent_cap: usize,
        chunk: ChunkType,
        chunk_w: u32,
        chunk_h: u32,
        max_bytes: usize,
    },
}

/// A GeoTIFF or raw DEM opened for reading by bands of rows (see the module docs).
///
/// `Sync`: bands may be read from several threads at once (each read opens its own file handle
/// or takes a pooled decoder).
pub struct RowReader {
    path: PathBuf,
    len: u64,
    width: u64,
    height: u64,
    georef: Georef,
    source: SourceInfo,
    inner: Inner,
    zero_filled: AtomicU64,
    /// Lowest and highest valid height read so far (for [`RowReader::warnings`]).
    seen: Mutex<(f32, f32)>,
    /// What was known when the file was opened (a band chosen among several, heights
    /// rescaled by the options), for [`RowReader::warnings`].
    notes: Vec<super::LoadWarning>,
}

impl std::fmt::Debug for RowReader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RowReader")
            .field("path", &self.path)
            .field("width", &self.width)
            .field("height", &self.height)
            .field("source", &self.source)
            .finish_non_exhaustive()
    }
}

/// Whether `format` can be read by rows (the others are read whole by [`load`](super::load)).
pub fn streams(format: Format) -> bool {
    matches!(format, Format::GeoTiff | Format::Raw)
}

impl RowReader {
    /// Opens `path` (format detected as [`load`](super::load) does, or `options.format`),
    /// reading only its header. `options.max_samples` does not apply (nothing of the grid's
    /// size is ever allocated) and `options.max_memory_bytes` bounds the strips or tiles held
    /// at once ([`DemErrorKind::ChunkMemoryLimit`]). Formats other than GeoTIFF and raw are
    /// refused with [`DemErrorKind::Unsupported`] (their readers decode the whole file; use `load`).
    pub fn open(path: impl AsRef<Path>, options: &LoadOptions) -> Result<Self, DemError> {
        let path = path.as_ref();
        let err = |kind| DemError::new(path, kind);
        let (len, head) = super::read_head(path)?;
        let format = options
            .format
            .or_else(|| detect_format(path, &head))
            .or(options.raw.map(|_| Format::Raw))
            .ok_or_else(|| {
                err(DemErrorKind::UnknownFormat(
                    "rows can be streamed from GeoTIFF and raw files only".to_string(),
                ))
            })?;
        let unbounded =
            LoadOptions { max_samples: u64::MAX, max_memory_bytes: u64::MAX, ..options.clone() };
        match format {
            Format::GeoTiff => {
                // One chunk (strip or tile) at a time, as f64 at most, within the memory limit.
                let max_bytes = options.max_memory_bytes.min(1 << 30) as usize;
                let opened = geotiff::open(path, len, &unbounded, max_bytes)?;
                let geotiff::Opened {
                    dec,
                    width,
                    height,
                    georef,
                    file_nodata,
                    mut layout,
                    sample_type,
                    bands,
                } = opened;
                layout.max_chunk_bytes = options.max_memory_bytes;
                let (chunk_w, chunk_h, chunk) = (layout.chunk_w, layout.chunk_h, layout.chunk);
                let mut notes = Vec::new();
                if bands > 1 {
                    let band = options.band;
                    notes.push(super::LoadWarning::Bands { path: path.to_path_buf(), band, bands });
                }
                notes.extend(super::rescaled(path, format, options));
                // Two rows of chunks (a band can straddle a chunk row) plus slack.
                let recent_cap = match chunk {
                    ChunkType::Strip => 4,
                    ChunkType::Tile => 2 * (width as usize).div_ceil(chunk_w as usize) + 4,
                };
                // What reading by rows holds at once: the cached chunks as f32 and one chunk
                // being decoded (as f64 at most, and its f32 copy: 12 bytes a sample).
                let chunk_samples = u64::from(chunk_w) * u64::from(chunk_h);
                let bytes = chunk_samples
                    .saturating_mul(4)
                    .saturating_mul(recent_cap as u64)
                    .saturating_add(chunk_samples.saturating_mul(12));
                if bytes > options.max_memory_bytes {
                    return Err(err(DemErrorKind::ChunkMemoryLimit {
                        chunk_w,
                        chunk_h,
                        chunks: recent_cap,
                        bytes,
                        limit: options.max_memory_bytes,
                    }));
                }
                let vertical = geotiff::Vertical::new(&layout, options);
                let reader = Self {
                    path: path.to_path_buf(),
                    len,
                    width: width as u64,
                    height: height as u64,
                    georef,
                    source: SourceInfo {
                        path: path.to_path_buf(),
                        format,
                        sample_type,
                        nodata: options.nodata.or(file_nodata),
                        vertical: (vertical.scale, vertical.offset),
                    },
                    inner: Inner::Tiff {
                        decoders: Mutex::new(vec![dec]),
                        vertical,
                        layout: Box::new(layout),
                        recent: Mutex::new(VecDeque::new()),
                        recent_cap,
                        chunk,
                        chunk_w,
                        chunk_h,
                        max_bytes,
                    },
                    zero_filled: AtomicU64::new(0),
                    seen: Mutex::new((f32::INFINITY, f32::NEG_INFINITY)),
                    notes,
                };
                // Decode the first chunk once (small), so a file that cannot be decoded is
                // refused when opened.
                reader.decode_chunk(0)?;
                Ok(reader)
            }
            Format::Raw => {
                let Some(spec) = options.raw else {
                    return Err(err(DemErrorKind::InvalidOptions(
                        "a raw file needs its size and sample type: --raw WIDTHxHEIGHT:TYPE (TYPE f32, i16 or u16)".into(),
                    )));
                };
                super::check_size(path, spec.width, spec.height, 0, &unbounded)?;
                let (bytes, name) = raw_sample(spec.sample);
                let expected = spec.width * spec.height * bytes;
                if len != expected {
                    return Err(err(DemErrorKind::InvalidOptions(format!(
                        "raw {} x {} {name} needs exactly {expected} bytes, the file has {len} bytes",
                        spec.width, spec.height
                    ))));
                }
                Ok(Self {
                    path: path.to_path_buf(),
                    len,
                    width: spec.width,
                    height: spec.height,
                    georef: Georef::local(options.spacing_m),
                    source: SourceInfo {
                        path: path.to_path_buf(),
                        format,
                        sample_type: name.to_string(),
                        nodata: options.nodata,
                        vertical: (options.vertical_scale, options.vertical_offset),
                    },
                    inner: Inner::Raw {
                        sample: spec.sample,
                        scale: options.vertical_scale,
                        offset: options.vertical_offset,
                    },
                    zero_filled: AtomicU64::new(0),
                    seen: Mutex::new((f32::INFINITY, f32::NEG_INFINITY)),
                    notes: Vec::new(),
                })
            }
            other => Err(err(DemErrorKind::Unsupported {
                format: other.name(),
                message: "rows can be streamed from GeoTIFF and raw files only; this format is read whole".to_string(),
            })),
        }
    }

    /// Columns.
    pub fn width(&self) -> u64 {
        self.width
    }

    /// Rows.
    pub fn height(&self) -> u64 {
        self.height
    }

    /// Georeference of sample (0, 0) (the south-west one).
    pub fn georef(&self) -> &Georef {
        &self.georef
    }

    /// Where the samples come from.
    pub fn source(&self) -> &SourceInfo {
        &self.source
    }

    /// Void samples set to 0 m so far, for want of any valid sample within reach.
    pub fn zero_filled(&self) -> u64 {
        self.zero_filled.load(Ordering::Relaxed)
    }

    /// What looks like a mistake in the rows read so far (as [`super::load`] reports in
    /// [`super::Dem::warnings`]): the lowest or highest valid height is a void sentinel no
    /// terrain has (below -11,000 m or above 9,000 m) while no no-data value is in force. The
    /// count of such samples is not known here (bands share rows).
    pub fn warnings(&self) -> Vec<super::LoadWarning> {
        let mut out = self.notes.clone();
        let Ok(&(lo, hi)) = self.seen.lock().as_deref() else { return out };
        if self.source.nodata.is_some() || !(lo.is_finite() && hi.is_finite()) {
            return out;
        }
        for v in [lo, hi] {
            let v = f64::from(v);
            let known = out
                .iter()
                .any(|w| matches!(w, super::LoadWarning::Sentinel { value, .. } if *value == v));
            if !super::plausible(v) && !known {
                out.push(super::LoadWarning::Sentinel {
                    path: self.path.clone(),
                    value: v,
                    count: None,
                });
            }
        }
        out
    }

    fn error(&self, kind: DemErrorKind) -> DemError {
        DemError::new(&self.path, kind)
    }

    /// Decodes plane chunk `index` (strip or tile) of the band read: heights in metres, voids
    /// (no-data, masked, sparse with no-data) NaN.
    fn decode_chunk(&self, index: u32) -> Result<Arc<Vec<f32>>, DemError> {
        let Inner::Tiff { decoders, layout, vertical, recent, recent_cap, max_bytes, .. } =
            &self.inner
        else {
            unreachable!("decode_chunk on a raw reader")
        };
        if let Some(hit) = recent
            .lock()
            .ok()
            .and_then(|r| r.iter().find(|(i, _)| *i == index).map(|(_, v)| Arc::clone(v)))
        {
            return Ok(hit);
        }
        let pooled = decoders.lock().map(|mut d| d.pop()).unwrap_or(None);
        let mut dec = match pooled {
            Some(d) => d,
            None => geotiff::decoder(&self.path, self.len, *max_bytes)?,
        };
        let raw = geotiff_chunks::band_chunk(&self.path, self.len, &mut dec, layout, index)?;
        let mask = geotiff_chunks::mask_chunk(&self.path, self.len, &mut dec, layout, index)?;
        if let Ok(mut pool) = decoders.lock()
            && pool.len() < DECODER_POOL
        {
            pool.push(dec);
        }
        let nodata = self.source.nodata;
        let values = raw
            .iter()
            .enumerate()
            .map(|(k, &v)| {
                let valid = mask.as_ref().is_none_or(|m| m[k]);
                vertical.metres(&self.path, v, nodata, valid)
            })
            .collect::<Result<Vec<f32>, DemError>>()?;
        let values = Arc::new(values);
        if let Ok(mut r) = recent.lock() {
            if r.len() >= *recent_cap {
                r.pop_front();
            }
            r.push_back((index, Arc::clone(&values)));
        }
        Ok(values)
    }

    /// File rows `r0 .. r0 + n` (north first, as stored), row-major, no-data as NaN.
    fn read_file_rows(&self, r0: u64, n: usize, out: &mut [f32]) -> Result<(), DemError> {
        let w = self.width as usize;
        debug_assert_eq!(out.len(), w * n);
        match &self.inner {
            Inner::Raw { sample, scale, offset } => {
                let (bytes, _) = raw_sample(*sample);
                let mut buf = vec![0u8; w * n * bytes as usize];
                let mut file =
                    File::open(&self.path).map_err(|e| self.error(DemErrorKind::Io(e)))?;
                file.seek(SeekFrom::Start(r0 * self.width * bytes))
                    .and_then(|_| file.read_exact(&mut buf))
                    .map_err(|e| self.error(DemErrorKind::Io(e)))?;
                for (o, s) in out.iter_mut().zip(buf.chunks_exact(bytes as usize)) {
                    let v = match sample {
                        RawSampleType::I16 => i16::from_le_bytes([s[0], s[1]]) as f64,
                        RawSampleType::U16 => u16::from_le_bytes([s[0], s[1]]) as f64,
                        RawSampleType::F32 => f32::from_le_bytes([s[0], s[1], s[2], s[3]]) as f64,
                    };
                    *o = self.value(v, *scale, *offset)?;
                }
            }
            Inner::Tiff { chunk, chunk_w, chunk_h, .. } => {
                let (cw, ch) = (*chunk_w as u64, *chunk_h as u64);
                let across = match chunk {
                    ChunkType::Strip => 1,
                    ChunkType::Tile => self.width.div_ceil(cw),
                };
                let first = r0 / ch;
                let last = (r0 + n as u64 - 1) / ch;
                for band in first..=last {
                    for t in 0..across {
                        let index = u32::try_from(band * across + t).map_err(|_| {
                            self.error(DemErrorKind::Malformed {
                                format: "GeoTIFF",
                                message: format!("chunk index {} out of range", band * across + t),
                            })
                        })?;
                        let values = self.decode_chunk(index)?;
                        // Strips span the whole width; tiles `cw` columns. The decoder
                        // returns a chunk's data without the padding of east and south edge
                        // tiles, so a row of the result is `min(cw, w - x0)` samples.
                        let x0 = match chunk {
                            ChunkType::Strip => 0,
                            ChunkType::Tile => (t * cw) as usize,
                        };
                        let stride = match chunk {
                            ChunkType::Strip => w,
                            ChunkType::Tile => (cw as usize).min(w - x0),
                        };
                        let cols = stride;
                        let rows_in = values.len() / stride.max(1);
                        for k in 0..rows_in {
                            let r = band * ch + k as u64;
                            if r < r0 || r >= r0 + n as u64 {
                                continue;
                            }
                            let dst = (r - r0) as usize * w + x0;
                            for c in 0..cols {
                                out[dst + c] = values[k * stride + c];
                            }
                        }
                    }
                }
            }
        }
        Ok(())
    }

    /// A raw file's value in metres, NaN for no-data.
    fn value(&self, v: f64, scale: f64, offset: f64) -> Result<f32, DemError> {
        if self.source.nodata.is_some_and(|nd| v == nd || (nd.is_nan() && v.is_nan()))
            || !v.is_finite()
        {
            Ok(f32::NAN)
        } else {
            super::metres(&self.path, v, scale, offset)
        }
    }

    /// The void mask of rows `j0 .. j0 + rows` (south first), row-major (`width * rows`).
    pub fn read_void_rows(&self, j0: u64, rows: usize, voids: &mut [bool]) -> Result<(), DemError> {
        let (w, h) = (self.width, self.height);
        if !(j0.checked_add(rows as u64).is_some_and(|e| e <= h)
            && voids.len() as u64 == w * rows as u64)
        {
            return Err(self.error(DemErrorKind::InvalidOptions(format!(
                "rows {j0}..+{rows} with a buffer of {} samples do not fit a {w} x {h} grid",
                voids.len()
            ))));
        }
        if rows == 0 {
            return Ok(());
        }
        let mut band = vec![0f32; voids.len()];
        self.read_south_rows(j0, rows, &mut band)?;
        for (v, x) in voids.iter_mut().zip(&band) {
            *v = x.is_nan();
        }
        Ok(())
    }

    /// Rows `j0 .. j0 + rows` (south first), row-major, no-data as NaN: the file's rows
    /// (north first) flipped. South row `j` is file row `h - 1 - j`, so the band is file rows
    /// `[h - j0 - rows, h - j0)`.
    fn read_south_rows(&self, j0: u64, rows: usize, out: &mut [f32]) -> Result<(), DemError> {
        if let Inner::Tiff { layout, .. } = &self.inner
            && layout.south_up
        {
            // A south-up GeoTIFF stores the south row first: file rows are ours.
            return self.read_file_rows(j0, rows, out);
        }
        let wu = self.width as usize;
        let mut file_band = vec![0f32; out.len()];
        self.read_file_rows(self.height - j0 - rows as u64, rows, &mut file_band)?;
        for (k, row) in file_band.chunks_exact(wu).enumerate() {
            let j = rows - 1 - k;
            out[j * wu..(j + 1) * wu].copy_from_slice(row);
        }
        Ok(())
    }

    /// Rows `j0 .. j0 + rows` (south first), row-major: heights in metres with voids filled
    /// (see the module docs) into `heights`, the void mask into `voids`. Both buffers hold
    /// `width * rows` samples.
    pub fn read_rows(
        &self,
        j0: u64,
        rows: usize,
        heights: &mut [f32],
        voids: &mut [bool],
    ) -> Result<(), DemError> {
        let (w, h) = (self.width, self.height);
        let fits = j0.checked_add(rows as u64).is_some_and(|e| e <= h)
            && heights.len() as u64 == w * rows as u64
            && voids.len() == heights.len();
        if !fits {
            return Err(self.error(DemErrorKind::InvalidOptions(format!(
                "rows {j0}..+{rows} with buffers of {} and {} samples do not fit a {w} x {h} grid",
                heights.len(),
                voids.len()
            ))));
        }
        if rows == 0 {
            return Ok(());
        }
        let wu = w as usize;
        self.read_south_rows(j0, rows, heights)?;
        for (v, &x) in voids.iter_mut().zip(heights.iter()) {
            *v = x.is_nan();
        }
        // The non-void range by lanes; sample by sample where they might differ (a zero).
        let (lo_z, hi_z) = match crate::heightmap::range_by_lanes(heights) {
            Some((lo, hi, _)) => (lo, hi),
            None => {
                let (mut lo_z, mut hi_z) = (f32::INFINITY, f32::NEG_INFINITY);
                for &x in heights.iter().filter(|x| !x.is_nan()) {
                    lo_z = lo_z.min(x);
                    hi_z = hi_z.max(x);
                }
                (lo_z, hi_z)
            }
        };
        if let Ok(mut seen) = self.seen.lock() {
            *seen = (seen.0.min(lo_z), seen.1.max(hi_z));
        }
        if !voids.iter().any(|&v| v) {
            return Ok(());
        }
        // Rows within reach below and above the band (south-first indices lo .. hi).
        let lo = j0.saturating_sub(FILL_REACH_ROWS as u64);
        let hi = (j0 + rows as u64 + FILL_REACH_ROWS as u64).min(h);
        let n = (hi - lo) as usize;
        let mut ext = vec![0f32; wu * n];
        self.read_south_rows(lo, n, &mut ext)?;
        let (dx, dy) = (self.georef.spacing_m.x, self.georef.spacing_m.y);
        let off = (j0 - lo) as usize;
        let mut zero = 0u64;
        let mut left = vec![usize::MAX; wu];
        let mut right = vec![usize::MAX; wu];
        for r in 0..rows {
            let row = &ext[(off + r) * wu..(off + r + 1) * wu];
            let mut last = usize::MAX;
            for i in 0..wu {
                if !row[i].is_nan() {
                    last = i;
                }
                left[i] = last;
            }
            last = usize::MAX;
            for i in (0..wu).rev() {
                if !row[i].is_nan() {
                    last = i;
                }
                right[i] = last;
            }
            for i in 0..wu {
                if !row[i].is_nan() {
                    continue;
                }
                let (mut sum, mut wsum) = (0f64, 0f64);
                let mut add = |v: f32, d: f64| {
                    let wt = 1.0 / (d * d);
                    sum += wt * v as f64;
                    wsum += wt;
                };
                if left[i] != usize::MAX {
                    add(row[left[i]], (i - left[i]) as f64 * dx);
                }
                if right[i] != usize::MAX {
                    add(row[right[i]], (right[i] - i) as f64 * dx);
                }
                let jr = off + r;
                if let Some(d) =
                    (1..=jr.min(FILL_REACH_ROWS)).find(|&d| !ext[(jr - d) * wu + i].is_nan())
                {
                    add(ext[(jr - d) * wu + i], d as f64 * dy);
                }
                if let Some(d) = (1..=(n - 1 - jr).min(FILL_REACH_ROWS))
                    .find(|&d| !ext[(jr + d) * wu + i].is_nan())
                {
                    add(ext[(jr + d) * wu + i], d as f64 * dy);
                }
                heights[r * wu + i] = if wsum > 0.0 {
                    (sum / wsum) as f32
                } else {
                    zero += 1;
                    0.0
                };
            }
        }
        self.zero_filled.fetch_add(zero, Ordering::Relaxed);
        Ok(())
    }
}

fn raw_sample(sample: RawSampleType) -> (u64, &'static str) {
    match sample {
        RawSampleType::I16 => (2, "int16"),
        RawSampleType::U16 => (2, "uint16"),
        RawSampleType::F32 => (4, "float32"),
    }
}
