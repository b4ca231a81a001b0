//! The store format: the non-redundant vertex order of a block (Qiu 2013, section 2.2,
//! Eq. 1-2), the grid index file (header, georeference, per-block entries with per-level
//! offsets and CRC-32s, per-node min/max and static error, the DSS paper's 32 object-space
//! errors), and the block file header.
//!
//! # Layout on disk (all integers and floats little-endian)
//!
//! A store is a folder:
//! - `index.tsi`, the paper's *grid index file*: [`MAGIC`], [`VERSION`], the [`Header`]
//!   (source size, block exponent `k`, grid of blocks, height encoding, georeference and CRS),
//!   then one [`BlockEntry`] per block, row-major from the south-west block (extent, file
//!   length, height range, per level `(offset, length, crc32)`, per-level maximum `StaticE`,
//!   the 32 DSS mean then 32 DSS max errors (all 64 NaN in every block of a store baked
//!   without them, `BakeConfig::dss_errors` false), per-node min/max/`StaticE`, and (index
//!   version 3, [`INDEX_VERSION`]) the fine maxima: per deepest stored node, its descendants'
//!   largest `StaticE` at each finer level), then the CRC-32 of everything before it. A
//!   version-2 index (no fine maxima) still opens. Version 4 ([`INDEX_VERSION`], the one a
//!   bake writes) keeps the same entries but pages them (`crate::pages`): after the header, a
//!   *head* (entries per page, bytes per entry, flags, total block bytes, a pyramid of the
//!   blocks' min/max and per-level error bounds over at most 8 levels of the quadtree above
//!   the blocks, and the head's CRC-32), then pages of at most 64 KiB of entries each followed
//!   by its CRC-32, then the CRC-32 of the whole file; a reader reads the head at open and a
//!   page when one of its blocks is asked for.
//! - `blocks/r{row}_c{col}.tsb`, one file per block: [`BLOCK_MAGIC`], [`VERSION`], the bake id
//!   (which ties the file to its index), row and column, then the levels' payloads in level
//!   order (level 0 first), each located by the index's `(offset, length, crc32)`.
//! - `overview.bin` (optional, `crate::overview`): every block's levels 0-4 in one file.
//! - `decimation.bin` (optional, [`crate::DECIMATION_FILE`], `crate::decimation`): per block
//!   in row-major order, its decimation error as one region at the strides `2^1..=2^k` (`k`
//!   f32 values, stride 2 first; the `tin` method's region errors when `2^k` = 256), computed
//!   by the bake from the stored heights; magic `TSDECIMA`, version, `k`, the bake id (tying it
//!   to the index), first block and block count, the values, a CRC-32 of it all. Read by
//!   [`crate::Store::decimation_errors`]; a store baked before it existed has none.
//! - `geomip.bin` (optional, [`crate::GEOMIP_FILE`]): geomorph's per-patch table.
//!
//! # Vertex order in a block (Eq. 1-2)
//!
//! A block has `(2^k + 1)^2` vertices. Level 0 holds the four corners; level `n >= 1` holds
//! only the vertices the `(2^n + 1)^2` grid adds to the `(2^(n-1) + 1)^2` grid of level
//! `n - 1`. Within a level vertices are in row-major order (rows south to north, columns west
//! to east) over that level's grid, skipping the coarser ones: the paper's order index. The
//! concatenation of levels `0..=n` is a linear sequence whose level `n` starts at
//! `Offset(n)_start` (Eq. 1) and ends at `Offset(n)_end` (Eq. 2). The level and order of a
//! vertex are computed ([`vertex_index`]) instead of being stored as the paper's level and
//! order index files: the computation is a few bit operations.

use std::fmt;
use std::sync::OnceLock;

use glam::DVec2;
use terrain_core::georef::{AngularOrLinear, Crs, Georef};

/// Magic bytes of the index file.
pub const MAGIC: [u8; 8] = *b"TSTRIDX\0";
/// Magic bytes of a block file.
pub(crate) const BLOCK_MAGIC: [u8; 8] = *b"TSTRBLK\0";
/// The block files' format version, which this crate writes and reads, and the oldest index
/// version it reads. Version 2 added the DSS paper's 32 object-space errors to every block
/// entry; version-1 stores must be baked again.
pub(crate) const VERSION: u32 = 2;

/// The index version this crate writes. Version 3 added, per block, the fine maxima
/// ([`BlockEntry::fine_errors`]); a version-2 index (block files unchanged) still opens,
/// without them (the factor walk then bounds nodes below the stored levels by the block's
/// per-level maximum, as before). Version 4 pages the entries (`crate::pages`): a head with
/// totals and the block pyramid, then pages of entries each with a CRC-32, read on demand;
/// version-2 and 3 indexes are read whole, as before.
pub(crate) const INDEX_VERSION: u32 = 4;
/// The first index version whose entries are paged.
pub(crate) const PAGED_INDEX_VERSION: u32 = 4;
/// Name of the grid index file inside a store folder.
pub const INDEX_FILE: &str = "index.tsi";
/// Bytes of a block file's header: magic, version, bake id, row, column.
pub(crate) const BLOCK_HEADER_LEN: u64 = 8 + 4 + 8 + 4 + 4;
/// Smallest and largest block exponent `k` (blocks of `(2^k + 1)^2` vertices).
pub(crate) const K_RANGE: std::ops::RangeInclusive<u8> = 2..=12;

/// A block of the grid: `col` counts east, `row` north, from the south-west block.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct BlockId {
    /// Row (north), 0 = southernmost.
    pub row: u32,
    /// Column (east), 0 = westernmost.
    pub col: u32,
}

impl BlockId {
    /// The block at `row`, `col`.
    pub fn new(row: u32, col: u32) -> Self {
        Self { row, col }
    }
}

impl fmt::Display for BlockId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "(row {}, col {})", self.row, self.col)
    }
}

/// The path of a block's file relative to the store folder.
pub(crate) fn block_file_name(id: BlockId) -> String {
    format!("blocks/r{:05}_c{:05}.tsb", id.row, id.col)
}

/// Eq. 1: first position of level `n` in a block's linear sequence.
pub(crate) fn offset_start(n: u8) -> usize {
    if n == 0 { 0 } else { ((1usize << (n - 1)) + 1).pow(2) }
}

/// Eq. 2: last position of level `n` in a block's linear sequence.
pub(crate) fn offset_end(n: u8) -> usize {
    ((1usize << n) + 1).pow(2) - 1
}

/// Number of vertices stored at level `n`: `Offset(n)_end - Offset(n)_start + 1`.
pub(crate) fn level_len(n: u8) -> usize {
    offset_end(n) + 1 - offset_start(n)
}

/// Where a vertex lives: its level, its order within the level, and its offset in the linear
/// sequence (`offset_start(level) + order`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct VertexIndex {
    /// The coarsest level holding the vertex.
    pub level: u8,
    /// Position within that level (the paper's order index).
    pub order: u32,
    /// Position in the block's linear sequence.
    pub offset: u32,
}

/// The coarsest level of a block of `(2^k + 1)^2` vertices that holds vertex `(i, j)` (the
/// store's non-redundant order, Eq. 1-2): the vertex first appears at the level whose stride
/// is the largest power of two dividing both coordinates (the corners at level 0).
pub fn vertex_level(k: u8, i: u32, j: u32) -> u8 {
    let s = (i | j | (1u32 << k)).trailing_zeros().min(u32::from(k));
    k - s as u8
}

/// The level, order and offset of block vertex `(i, j)` (column east, row north) in a block
/// of `(2^k + 1)^2` vertices. `None` outside the block.
pub(crate) fn vertex_index(k: u8, i: u32, j: u32) -> Option<VertexIndex> {
    let side = 1u32 << k;
    if i > side || j > side {
        return None;
    }
    let level = vertex_level(k, i, j);
    let s = u32::from(k - level);
    let d = 1u32 << s;
    let (a, b) = (i >> s, j >> s);
    let order = if level == 0 {
        (b * 2 + a) as usize
    } else {
        let n = (1usize << level) + 1;
        let half = 1usize << (level - 1);
        let (a, b) = (a as usize, b as usize);
        // Rows before b: even rows hold the 2^(l-1) odd columns, odd rows hold all n.
        let before = b.div_ceil(2) * half + (b / 2) * n;
        before + if b % 2 == 1 { a } else { a / 2 }
    } as u32;
    debug_assert!(level == 0 || d < side);
    Some(VertexIndex { level, order, offset: offset_start(level) as u32 + order })
}

/// Calls `f(i, j)` for every vertex of level `n` of a `2^k` block, in the stored order.
pub(crate) fn for_each_level_vertex(k: u8, n: u8, mut f: impl FnMut(u32, u32)) {
    let d = 1u32 << (k - n);
    let cnt = (1u32 << n) + 1;
    if n == 0 {
        for b in 0..2 {
            for a in 0..2 {
                f(a * d, b * d);
            }
        }
        return;
    }
    for b in 0..cnt {
        if b % 2 == 1 {
            for a in 0..cnt {
                f(a * d, b * d);
            }
        } else {
            for a in (1..cnt).step_by(2) {
                f(a * d, b * d);
            }
        }
    }
}

pub(crate) use terrain_core::checksum::crc32;

/// How heights are stored.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SampleEncoding {
    /// Integers `q` with `height = (offset_m + q * step_m) as f32`, computed in f64.
    Quantized {
        /// Metres per step.
        step_m: f64,
        /// Height of `q = 0`.
        offset_m: f64,
    },
    /// IEEE f32 bits as they came.
    F32,
}

impl SampleEncoding {
    /// The height of a stored sample (an integer step, or f32 bits in an `i32`).
    #[inline]
    pub fn height(&self, q: i32) -> f32 {
        match *self {
            SampleEncoding::Quantized { step_m, offset_m } => (offset_m + q as f64 * step_m) as f32,
            SampleEncoding::F32 => f32::from_bits(q as u32),
        }
    }

    /// [`SampleEncoding::height`] times `scale` (a vertical exaggeration), multiplied in f64
    /// and rounded to f32 once: for f32 heights the correctly rounded `height * scale`, as a
    /// DEM's f32 heights scaled in f32 (`height` itself at `scale` 1).
    #[inline]
    pub fn height_scaled(&self, q: i32, scale: f64) -> f32 {
        match *self {
            SampleEncoding::Quantized { step_m, offset_m } => {
                ((offset_m + q as f64 * step_m) * scale) as f32
            }
            SampleEncoding::F32 => (f64::from(f32::from_bits(q as u32)) * scale) as f32,
        }
    }
}

/// Heights to integer steps, `round((height - offset_m) / step_m)` (f64, halves away from
/// zero), the bake's quantization ([`SampleEncoding::Quantized`]), without a division or a
/// libm `round` per sample where that gives the same integer.
///
/// With `inv = 1 / step_m` rounded once, `y = (height - offset_m) * inv` is within
/// `3.01 * 2^-53 |y| < 2^-51 |y|` of the quotient the division rounds to (three roundings of
/// relative error at most `2^-53` each: `inv`, the product, and the division's own; `inv`
/// normal, and a subnormal `y` is within `2^-1075` of it, which is far from any half). So where
/// `|y| < 2^30` and `y` is more than `2^-50 |y|` from the nearest half-integer, the quotient
/// lies strictly between the same two half-integers as `y` and rounds to the same integer,
/// which `y`'s truncation and fraction give exactly (`y - trunc(y)` is exact). Everywhere else
/// (near a half, large, NaN, infinite) the division and `round` themselves decide: the result
/// is the division's, bit for bit, always (test `quantize_is_the_division_rounded`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Quantizer {
    step_m: f64,
    offset_m: f64,
    /// `1 / step_m`, NaN where it is not normal (then every sample takes the division).
    inv: f64,
}

impl Quantizer {
    /// The quantizer of steps of `step_m` metres from `offset_m`.
    pub(crate) fn new(step_m: f64, offset_m: f64) -> Self {
        let inv = 1.0 / step_m;
        Self { step_m, offset_m, inv: if inv.is_normal() { inv } else { f64::NAN } }
    }

    /// `round((height - offset_m) / step_m)` as f64 (`None` outside the `i32` range, or NaN).
    #[inline]
    pub(crate) fn steps(&self, height: f32) -> Option<i32> {
        /// `|y|` below which the fast path runs (its integer fits an `i32` with room).
        const FAST_LIMIT: f64 = 1_073_741_824.0; // 2^30
        /// `2^-50`: twice the bound on `|y - quotient| / |y|`.
        const MARGIN: f64 = 1.0 / 1_125_899_906_842_624.0;
        let x = f64::from(height) - self.offset_m;
        let y = x * self.inv;
        if y.abs() < FAST_LIMIT {
            let n = y as i64; // truncation toward zero, exact here
            let f = y - n as f64; // exact: the fraction, sign of y
            let fa = f.abs();
            if (fa - 0.5).abs() > y.abs() * MARGIN {
                let away = if fa > 0.5 { if y < 0.0 { -1 } else { 1 } } else { 0 };
                return Some((n + away) as i32);
            }
        }
        self.divided(x)
    }

    /// [`Quantizer::steps`] of a row of heights into `out` (as long), by lanes: the fast path
    /// computed for every sample without a branch, and the row again sample by sample only
    /// where some sample needs the division. The error is the first sample outside the `i32`
    /// range.
    pub(crate) fn steps_row(&self, heights: &[f32], out: &mut [i32]) -> Result<(), usize> {
        const FAST_LIMIT: f64 = 1_073_741_824.0; // 2^30, as in `steps`
        const MARGIN: f64 = 1.0 / 1_125_899_906_842_624.0; // 2^-50, as in `steps`
        let mut fast = true;
        for (q, &h) in out.iter_mut().zip(heights) {
            let y = (f64::from(h) - self.offset_m) * self.inv;
            let small = y.abs() < FAST_LIMIT;
            let y = if small { y } else { 0.0 };
            let n = y as i32;
            let f = y - f64::from(n);
            let fa = f.abs();
            fast &= small & ((fa - 0.5).abs() > y.abs() * MARGIN);
            let away = if fa > 0.5 { if y < 0.0 { -1 } else { 1 } } else { 0 };
            *q = n + away;
        }
        if !fast {
            for (i, (q, &h)) in out.iter_mut().zip(heights).enumerate() {
                *q = self.steps(h).ok_or(i)?;
            }
        }
        Ok(())
    }

    /// The definition: the division and `round`, checked against the `i32` range.
    #[cold]
    fn divided(&self, x: f64) -> Option<i32> {
        let t = (x / self.step_m).round();
        (i32::MIN as f64..=i32::MAX as f64).contains(&t).then_some(t as i32)
    }
}

/// Payload codec of a level (the first byte of every payload says which was used).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Codec {
    /// Fixed width: i16 when the level's values fit, else i32 (f32 bits for raw floats).
    Plain,
    /// Lossless: every new vertex predicted from the coarser level (mean of the two edge
    /// ends, or of the four cell corners), residual zig-zag LEB128 varints. Quantized only.
    Predictive,
    /// [`Codec::Predictive`]'s varints compressed with Deflate (each level alone, kept only
    /// where smaller). Quantized only. The default: 14-85% smaller than `Predictive` on the
    /// shared DEMs for 15-30% slower decoding (see `examples/stream_bench.rs codec`).
    PredictiveDeflate,
}

/// The store's header: what the index says about the whole store.
#[derive(Debug, Clone, PartialEq)]
pub struct Header {
    /// Columns of the source grid (samples).
    pub width: u64,
    /// Rows of the source grid (samples).
    pub height: u64,
    /// Blocks are `(2^k + 1)^2` vertices.
    pub k: u8,
    /// Blocks per row (east).
    pub blocks_x: u32,
    /// Blocks per column (north).
    pub blocks_y: u32,
    /// How heights are stored.
    pub encoding: SampleEncoding,
    /// Codec the bake asked for (payloads may fall back to [`Codec::Plain`]).
    pub codec: Codec,
    /// Largest |stored - source| over non-void samples, metres (0 = lossless).
    pub max_error_m: f64,
    /// Largest |stored - source| over void (filled) samples, metres.
    pub max_void_error_m: f64,
    /// The vertical error bound the bake promised (and verified), metres; 0 = lossless promised.
    pub error_bound_m: f64,
    /// Quadtree levels with per-node values in each [`BlockEntry`] (`4^l` nodes at level `l`).
    pub node_levels: u8,
    /// Georeference and CRS of the source grid (sample (0, 0) is block (0, 0)'s south-west vertex).
    pub georef: Georef,
    /// Ties block files to this index: a hash of every level's checksum.
    pub bake_id: u64,
    /// Not stored: the vertical exaggeration every height and height error of this store is
    /// read with ([`crate::Store::exaggerated`]); 1 as the index is read and as a bake writes it.
    pub vertical_scale: f64,
}

impl Header {
    /// Cells per block side, `2^k`.
    pub fn block_cells(&self) -> u32 {
        1 << self.k
    }

    /// Vertices per block side, `2^k + 1`.
    pub fn block_side(&self) -> u32 {
        (1 << self.k) + 1
    }

    /// Number of blocks.
    pub fn block_count(&self) -> usize {
        self.blocks_x as usize * self.blocks_y as usize
    }

    /// Number of levels per block, `k + 1`.
    pub fn levels(&self) -> u8 {
        self.k + 1
    }

    /// Row-major position of a block in the index, or `None` outside the grid.
    pub fn block_position(&self, id: BlockId) -> Option<usize> {
        (id.col < self.blocks_x && id.row < self.blocks_y)
            .then(|| id.row as usize * self.blocks_x as usize + id.col as usize)
    }

    /// The block at a row-major position.
    pub fn block_at(&self, pos: usize) -> BlockId {
        BlockId::new((pos / self.blocks_x as usize) as u32, (pos % self.blocks_x as usize) as u32)
    }

    /// World plan position (metres) of block vertex `(i, j)` of block `id`.
    pub fn vertex_world(&self, id: BlockId, i: f64, j: f64) -> DVec2 {
        let c = self.block_cells() as f64;
        self.georef.grid_to_world(DVec2::new(id.col as f64 * c + i, id.row as f64 * c + j))
    }

    /// Bytes of one decoded sample in memory.
    pub const SAMPLE_BYTES: u64 = 4;
}

/// Min/max height and monotone static error (Qiu 2013 Eq. 3) of one quadtree node of a block.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeValues {
    /// Lowest stored height in the node's valid samples (metres).
    pub min: f32,
    /// Highest stored height (metres).
    pub max: f32,
    /// `StaticE` of the node, metres.
    pub static_error: f32,
}

/// Where a level's payload lies in its block file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LevelEntry {
    /// Byte offset in the block file.
    pub offset: u64,
    /// Payload bytes.
    pub len: u32,
    /// CRC-32 of the payload.
    pub crc32: u32,
}

/// Everything the index holds about one block: the one place precomputed per-block values live.
#[derive(Debug, Clone, PartialEq)]
pub struct BlockEntry {
    /// Valid (non-padding) vertices along x: the rest of the block is padding, which repeats
    /// the source's last column.
    pub valid_w: u32,
    /// Valid vertices along y (padding repeats the last row).
    pub valid_h: u32,
    /// Length of the block file in bytes.
    pub file_len: u64,
    /// Lowest and highest valid height.
    pub min: f32,
    /// See `min`.
    pub max: f32,
    /// One entry per level, 0..=k.
    pub levels: Vec<LevelEntry>,
    /// Per node, level-major (`4^l` nodes at level `l`, row-major `j * 2^l + i`), levels
    /// `0..node_levels`.
    pub nodes: Vec<NodeValues>,
    /// Per quadtree level `l` in `0..k`: the largest `StaticE` of any node at that level
    /// (bounds every node below the stored node levels).
    pub level_errors: Vec<f32>,
    /// The fine maxima: per node of the deepest stored level `L = node_levels - 1` (row-major
    /// `j * 2^L + i`), `k - node_levels` values: at `l - node_levels`, the largest `StaticE` of
    /// its descendants at level `l` (`node_levels <= l < k`). Empty in a version-2 index (or
    /// when `node_levels` is 0 or `k`): nodes below the stored levels are then bounded by
    /// `level_errors`.
    pub fine_errors: Vec<f32>,
    /// The DSS paper's (Zhang 2019, section 3.3.1) 32 object-space errors of the whole block
    /// (its valid extent), precomputed by the bake with
    /// `terrain_core::metrics::dss::object_errors` from the stored heights; `None` in every
    /// block of a store baked without them (`BakeConfig::dss_errors` false; stored as NaN).
    pub dss: Option<DssBlockErrors>,
    /// The fine maxima's pyramid above the deepest stored level, built on first need
    /// ([`BlockEntry::fine_max_above`]).
    pub(crate) fine_max: FineMaxima,
}

/// [`BlockEntry::fine_errors`] reduced up the stored node levels: per node of levels
/// `0..node_levels - 1` (level-major, row-major, like [`BlockEntry::nodes`]), `k - node_levels`
/// values, the largest fine maximum per level over its descendants of the deepest stored
/// level. Derived from the entry's own values once, on first need (the walks ask for the
/// maxima of a block's shallow nodes every frame, which otherwise read up to `4^(node_levels -
/// 1)` fine maxima each); never part of an entry's identity (equal whether built or not), and
/// dropped whenever the fine maxima change ([`crate::pages::scale_entry`]). Its bytes are
/// under a third of the entry's fine maxima, and the index's page cache does not count them
/// (its budget counts an entry's stored bytes and a fixed overhead).
#[derive(Clone, Default)]
pub(crate) struct FineMaxima(OnceLock<Box<[f32]>>);

impl FineMaxima {
    /// Bytes of the pyramid, once built.
    fn heap_bytes(&self) -> usize {
        self.0.get().map_or(0, |p| std::mem::size_of_val(&**p))
    }

    /// Forgets the pyramid (the fine maxima changed).
    pub(crate) fn reset(&mut self) {
        self.0 = OnceLock::new();
    }
}

impl PartialEq for FineMaxima {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl fmt::Debug for FineMaxima {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(if self.0.get().is_some() { "FineMaxima(built)" } else { "FineMaxima" })
    }
}

/// The pyramid of [`FineMaxima`] from `fine` (the deepest stored level `top`, `per` values a
/// node): each node's values the largest of its four children's, level by level up.
fn fine_pyramid(fine: &[f32], top: u8, per: usize) -> Box<[f32]> {
    let mut out = vec![0f32; node_count(top) * per];
    for t in (0..top).rev() {
        let (parents, below) = out.split_at_mut(node_count(t + 1) * per);
        let children: &[f32] = if t + 1 == top { fine } else { below };
        max_up(&mut parents[node_count(t) * per..], children, t, per);
    }
    out.into_boxed_slice()
}

/// One level up a max pyramid (level-major, row-major, `per` values a node): each of the
/// `4^t` nodes of level `t` in `parents` (from its first) takes, value by value, the largest
/// of its own and its four children's in `children` (level `t + 1`, from its first). The one
/// reduction of [`fine_pyramid`] and of `lod`'s per-block maxima (`block_sub_max`).
pub(crate) fn max_up(parents: &mut [f32], children: &[f32], t: u8, per: usize) {
    let side = 1usize << t;
    for j in 0..side {
        for i in 0..side {
            let o = (j * side + i) * per;
            for (di, dj) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let c = ((2 * j + dj) * 2 * side + 2 * i + di) * per;
                for (p, &v) in parents[o..o + per].iter_mut().zip(&children[c..c + per]) {
                    *p = p.max(v);
                }
            }
        }
    }
}

/// The DSS paper's 32 object-space errors of a block, index `i` for the tessellation factor
/// `terrain_core::metrics::dss::factor(i) = 2 (i + 1)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DssBlockErrors {
    /// Mean vertical error (the paper's `delta_i`), metres.
    pub avg: [f32; DSS_FACTORS],
    /// Largest vertical error, metres.
    pub max: [f32; DSS_FACTORS],
}

/// Number of DSS object-space errors per block (the paper's 32).
pub(crate) const DSS_FACTORS: usize = terrain_core::metrics::dss::FACTORS;

impl BlockEntry {
    /// Bytes the entry holds in memory: itself, its vectors' capacities and its fine maxima's
    /// pyramid once built (what a cache of entries counts).
    pub(crate) fn heap_bytes(&self) -> usize {
        use std::mem::size_of;
        size_of::<Self>()
            + self.levels.capacity() * size_of::<LevelEntry>()
            + self.nodes.capacity() * size_of::<NodeValues>()
            + (self.level_errors.capacity() + self.fine_errors.capacity()) * size_of::<f32>()
            + self.fine_max.heap_bytes()
    }

    /// The values of node `(i, j)` at node level `l`, if stored.
    pub fn node(&self, l: u8, i: u32, j: u32) -> Option<&NodeValues> {
        let n = 1usize << l;
        if i as usize >= n || j as usize >= n {
            return None;
        }
        let base = ((1usize << (2 * l as usize)) - 1) / 3;
        self.nodes.get(base + j as usize * n + i as usize)
    }

    /// The largest `StaticE` at level `l` (`node_levels <= l < k`) under node `(i, j)` of the
    /// deepest stored level `node_levels - 1` ([`BlockEntry::fine_errors`]), if stored.
    pub fn fine_error(&self, node_levels: u8, k: u8, i: u32, j: u32, l: u8) -> Option<f32> {
        let top = node_levels.checked_sub(1)?;
        let side = 1usize << top;
        if l < node_levels || l >= k || i as usize >= side || j as usize >= side {
            return None;
        }
        let per = (k - node_levels) as usize;
        let o = (j as usize * side + i as usize) * per + (l - node_levels) as usize;
        self.fine_errors.get(o).copied()
    }

    /// The largest fine maximum at level `l` (`node_levels <= l < k`) over the descendants of
    /// node `(i, j)` of node level `level` (above the deepest stored level `node_levels - 1`)
    /// at that deepest level: the largest [`BlockEntry::fine_error`] of those descendants,
    /// from the entry's pyramid ([`FineMaxima`], built on the first call). `None` where
    /// `fine_error` has no value for some descendant (no fine maxima, or not a node above the
    /// deepest stored level).
    pub(crate) fn fine_max_above(
        &self,
        node_levels: u8,
        k: u8,
        n: [u32; 2],
        level: u8,
        l: u8,
    ) -> Option<f32> {
        let top = node_levels.checked_sub(1)?;
        let side = 1usize << level;
        let [i, j] = n.map(|v| v as usize);
        if level >= top || l < node_levels || l >= k || i >= side || j >= side {
            return None;
        }
        let per = usize::from(k - node_levels);
        if self.fine_errors.len() != (1usize << (2 * usize::from(top))) * per {
            return None;
        }
        let pyramid = self.fine_max.0.get_or_init(|| fine_pyramid(&self.fine_errors, top, per));
        let o = (node_count(level) + j * side + i) * per + usize::from(l - node_levels);
        pyramid.get(o).copied()
    }

    /// Decoded bytes of levels `0..=level` in memory.
    pub fn resident_bytes(level: u8) -> u64 {
        (offset_end(level) as u64 + 1) * Header::SAMPLE_BYTES
    }

    /// Stored bytes of levels `0..=level` on disk.
    pub fn disk_bytes(&self, level: u8) -> u64 {
        self.levels.iter().take(level as usize + 1).map(|l| l.len as u64).sum()
    }
}

/// Number of fine maxima per block ([`BlockEntry::fine_errors`]) for block exponent `k` and
/// `node_levels` stored node levels.
pub(crate) fn fine_count(k: u8, node_levels: u8) -> usize {
    match node_levels.checked_sub(1) {
        Some(top) => (1usize << (2 * top as usize)) * k.saturating_sub(node_levels) as usize,
        None => 0,
    }
}

/// Number of node entries for `levels` node levels: `(4^levels - 1) / 3`.
pub(crate) fn node_count(levels: u8) -> usize {
    ((1usize << (2 * levels as usize)) - 1) / 3
}

// ---------------------------------------------------------------------------------------------
// Little-endian writer and bounds-checked reader.

/// The shared little-endian cursors ([`terrain_core::bytes`]): a short read is an error
/// message (`String` from [`terrain_core::bytes::Short`]), never a panic.
pub(crate) type Writer = terrain_core::bytes::LeWriter;
pub(crate) type Reader<'a> = terrain_core::bytes::LeReader<'a>;

fn write_georef(w: &mut Writer, g: &Georef) {
    match &g.crs {
        Crs::Epsg(c) => {
            w.u8(1);
            w.u32(*c);
        }
        Crs::Text(t) => {
            w.u8(2);
            w.u32(t.len() as u32);
            w.bytes(t.as_bytes());
        }
        _ => w.u8(0),
    }
    w.u8(match g.units {
        AngularOrLinear::Metres => 0,
        AngularOrLinear::Degrees => 1,
    });
    w.dvec2(g.native_origin);
    w.dvec2(g.native_spacing);
    w.dvec2(g.spacing_m);
    w.dvec2(g.world_origin);
}

fn read_georef(r: &mut Reader<'_>) -> Result<Georef, IndexError> {
    let crs = match r.u8()? {
        0 => Crs::Unknown,
        1 => Crs::Epsg(r.u32()?),
        2 => {
            let n = r.u32()? as usize;
            let b = r.take(n)?;
            let text = String::from_utf8(b.to_vec());
            Crs::Text(text.map_err(|_| IndexError::Corrupt("CRS text is not UTF-8".into()))?)
        }
        t => return Err(format!("unknown CRS tag {t}").into()),
    };
    let units = match r.u8()? {
        0 => AngularOrLinear::Metres,
        1 => AngularOrLinear::Degrees,
        t => return Err(format!("unknown units tag {t}").into()),
    };
    let g = Georef {
        crs,
        units,
        native_origin: r.dvec2()?,
        native_spacing: r.dvec2()?,
        spacing_m: r.dvec2()?,
        world_origin: r.dvec2()?,
    };
    let ok = |v: DVec2| v.is_finite();
    let fine = ok(g.native_origin) && ok(g.world_origin) && ok(g.native_spacing);
    let positive = g.spacing_m.x > 0.0 && g.spacing_m.y > 0.0 && g.spacing_m.is_finite();
    if !(fine && positive) {
        return Err(IndexError::Corrupt(
            "georeference is not finite or has non-positive spacing".into(),
        ));
    }
    Ok(g)
}

/// The header's fields, as the index stores them after its magic and version.
pub(crate) fn write_header(w: &mut Writer, header: &Header) {
    w.u64(header.width);
    w.u64(header.height);
    w.u8(header.k);
    w.u32(header.blocks_x);
    w.u32(header.blocks_y);
    match header.encoding {
        SampleEncoding::Quantized { step_m, offset_m } => {
            w.u8(0);
            w.f64(step_m);
            w.f64(offset_m);
        }
        SampleEncoding::F32 => w.u8(1),
    }
    w.u8(match header.codec {
        Codec::Plain => 0,
        Codec::Predictive => 1,
        Codec::PredictiveDeflate => 2,
    });
    w.f64(header.max_error_m);
    w.f64(header.max_void_error_m);
    w.f64(header.error_bound_m);
    w.u8(header.node_levels);
    write_georef(w, &header.georef);
    w.u64(header.bake_id);
}

/// One block's entry, as the index stores it.
pub(crate) fn write_entry(w: &mut Writer, b: &BlockEntry) {
    w.u32(b.valid_w);
    w.u32(b.valid_h);
    w.u64(b.file_len);
    w.f32(b.min);
    w.f32(b.max);
    for l in &b.levels {
        w.u64(l.offset);
        w.u32(l.len);
        w.u32(l.crc32);
    }
    for e in &b.level_errors {
        w.f32(*e);
    }
    match &b.dss {
        Some(d) => d.avg.iter().chain(&d.max).for_each(|e| w.f32(*e)),
        // Absent: NaN, which no measured error is.
        None => (0..2 * DSS_FACTORS).for_each(|_| w.f32(f32::NAN)),
    }
    for n in &b.nodes {
        w.f32(n.min);
        w.f32(n.max);
        w.f32(n.static_error);
    }
    for e in &b.fine_errors {
        w.f32(*e);
    }
}

/// The bytes [`write_entry`] writes for every entry of a grid with `header`'s block size and
/// node levels (`fine` = [`fine_count`]): entries have one length per grid, so a reader can
/// stream them in fixed-size batches.
pub(crate) fn entry_len(header: &Header, fine: usize) -> usize {
    let k = header.k as usize;
    // Extent and file length, min and max; a level's offset, length and CRC; a level's error;
    // the DSS errors; a node's min, max and static error; a fine maximum.
    24 + (k + 1) * 16 + k * 4 + 2 * DSS_FACTORS * 4 + node_count(header.node_levels) * 12 + fine * 4
}

/// The index's bytes before its block entries: magic, version, header. Its length depends only
/// on the header's CRS and encoding, not on the values a bake knows only at its end.
pub(crate) fn index_prefix(header: &Header) -> Vec<u8> {
    let mut w = Writer::default();
    w.bytes(&MAGIC);
    w.u32(INDEX_VERSION);
    write_header(&mut w, header);
    w.buf
}

/// Serialises the index whole, as the version this crate writes (4, paged): the bytes a bake
/// writes entry by entry (`crate::entries::EntryFile`).
#[cfg(test)]
pub(crate) fn write_index(header: &Header, blocks: &[BlockEntry]) -> Vec<u8> {
    let fine = blocks.first().map_or(0, |b| b.fine_errors.len());
    let mut head = crate::pages::HeadBuilder::new(header, fine);
    let mut body = Writer::default();
    for b in blocks {
        let at = body.buf.len();
        write_entry(&mut body, b);
        let bytes = body.buf[at..].to_vec();
        if let Some(crc) = head.push(b, &bytes) {
            body.u32(crc);
        }
    }
    let (tail, head) = head.finish();
    if let Some(crc) = tail {
        body.u32(crc);
    }
    let mut w = Writer { buf: crate::pages::paged_prefix(header, &head) };
    w.bytes(&body.buf);
    let crc = crc32(&w.buf);
    w.u32(crc);
    w.buf
}

/// Serialises the index whole as version 2 or 3 wrote it (entries unpaged after the header,
/// the CRC-32 of everything before it), version 2 without the fine maxima: the old writer, for
/// tests that older indexes still open.
#[cfg(test)]
pub(crate) fn write_index_unpaged(header: &Header, blocks: &[BlockEntry], version: u32) -> Vec<u8> {
    assert!(version == 2 || version == 3);
    let mut w = Writer { buf: index_prefix(header) };
    w.buf[8..12].copy_from_slice(&version.to_le_bytes());
    for b in blocks {
        if version == 2 {
            let mut b = b.clone();
            b.fine_errors.clear();
            write_entry(&mut w, &b);
        } else {
            write_entry(&mut w, b);
        }
    }
    let crc = crc32(&w.buf);
    w.u32(crc);
    w.buf
}

/// Why [`read_index`] failed (mapped to [`crate::StoreError`] by the caller, which knows the path).
#[derive(Debug)]
pub(crate) enum IndexError {
    BadMagic,
    Version(u32),
    /// The bytes end inside a field (a reader of a file's first bytes reads more then).
    Short(terrain_core::bytes::Short),
    Corrupt(String),
}

/// What failed, in words (a caller that knows the file adds its path, or maps the variant to a
/// [`crate::StoreError`] of its own: `pages::index_err`).
impl fmt::Display for IndexError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            IndexError::BadMagic => f.write_str("bad magic bytes"),
            IndexError::Version(v) => write!(f, "version {v}"),
            IndexError::Short(s) => write!(f, "{s}"),
            IndexError::Corrupt(m) => f.write_str(m),
        }
    }
}

impl From<String> for IndexError {
    fn from(s: String) -> Self {
        IndexError::Corrupt(s)
    }
}

impl From<terrain_core::bytes::Short> for IndexError {
    fn from(s: terrain_core::bytes::Short) -> Self {
        IndexError::Short(s)
    }
}

/// The header's fields after the index's magic and version, checked (the grid of blocks
/// covers the size, tags and values in range).
pub(crate) fn read_header(r: &mut Reader<'_>) -> Result<Header, IndexError> {
    let width = r.u64()?;
    let height = r.u64()?;
    let k = r.u8()?;
    let blocks_x = r.u32()?;
    let blocks_y = r.u32()?;
    if !K_RANGE.contains(&k) {
        return Err(IndexError::Corrupt(format!("block exponent k = {k} out of range")));
    }
    let cells = 1u64 << k;
    let expect = |n: u64| (n.saturating_sub(1)).div_ceil(cells).max(1);
    if width == 0
        || height == 0
        || expect(width) != blocks_x as u64
        || expect(height) != blocks_y as u64
    {
        return Err(IndexError::Corrupt(format!(
            "{blocks_x} x {blocks_y} blocks do not cover {width} x {height} samples with k = {k}"
        )));
    }
    let encoding = match r.u8()? {
        0 => {
            let step_m = r.f64()?;
            let offset_m = r.f64()?;
            if !(step_m.is_finite() && step_m > 0.0 && offset_m.is_finite()) {
                return Err(IndexError::Corrupt("bad quantization step or offset".into()));
            }
            SampleEncoding::Quantized { step_m, offset_m }
        }
        1 => SampleEncoding::F32,
        t => return Err(IndexError::Corrupt(format!("unknown encoding tag {t}"))),
    };
    let codec = match r.u8()? {
        0 => Codec::Plain,
        1 => Codec::Predictive,
        2 => Codec::PredictiveDeflate,
        t => return Err(IndexError::Corrupt(format!("unknown codec tag {t}"))),
    };
    let max_error_m = r.f64()?;
    let max_void_error_m = r.f64()?;
    let error_bound_m = r.f64()?;
    let node_levels = r.u8()?;
    if node_levels > k {
        return Err(IndexError::Corrupt(format!("{node_levels} node levels for k = {k}")));
    }
    let georef = read_georef(r)?;
    let bake_id = r.u64()?;
    Ok(Header {
        width,
        height,
        k,
        blocks_x,
        blocks_y,
        encoding,
        codec,
        max_error_m,
        max_void_error_m,
        error_bound_m,
        node_levels,
        georef,
        bake_id,
        vertical_scale: 1.0,
    })
}

/// One block's entry (`id` names it in errors), checked against the header: level offsets
/// that tile the file, a sane extent and height range, errors that are finite.
pub(crate) fn read_entry(
    r: &mut Reader<'_>,
    header: &Header,
    id: BlockId,
    fine: usize,
) -> Result<BlockEntry, IndexError> {
    let (k, node_levels) = (header.k, header.node_levels);
    let valid_w = r.u32()?;
    let valid_h = r.u32()?;
    let file_len = r.u64()?;
    let min = r.f32()?;
    let max = r.f32()?;
    let side = header.block_side();
    if valid_w == 0
        || valid_h == 0
        || valid_w > side
        || valid_h > side
        || min.partial_cmp(&max).is_none_or(|o| o.is_gt())
    {
        return Err(IndexError::Corrupt(format!("block {id}: bad extent or height range")));
    }
    let mut levels = Vec::with_capacity(k as usize + 1);
    let mut end = BLOCK_HEADER_LEN;
    for l in 0..=k {
        let e = LevelEntry { offset: r.u64()?, len: r.u32()?, crc32: r.u32()? };
        if e.offset != end {
            return Err(IndexError::Corrupt(format!(
                "block {id} level {l}: offset {} != {end}",
                e.offset
            )));
        }
        end += e.len as u64;
        levels.push(e);
    }
    if end != file_len {
        return Err(IndexError::Corrupt(format!(
            "block {id}: levels end at {end}, file length {file_len}"
        )));
    }
    // Collected at their exact lengths: a `Result` iterator's collect grows by doubling (its
    // size hint's lower bound is 0), and a tree keeps thousands of entries alive.
    let level_errors = read_f32s(r, k as usize)?;
    let mut d = DssBlockErrors { avg: [0.0; DSS_FACTORS], max: [0.0; DSS_FACTORS] };
    for v in d.avg.iter_mut().chain(d.max.iter_mut()) {
        *v = r.f32()?;
    }
    let absent = d.avg.iter().chain(&d.max).all(|v| v.is_nan());
    if !absent && !d.avg.iter().chain(&d.max).all(|v| v.is_finite() && *v >= 0.0) {
        return Err(IndexError::Corrupt(format!("block {id}: bad DSS errors")));
    }
    let dss = (!absent).then_some(d);
    let mut nodes = Vec::with_capacity(node_count(node_levels));
    for _ in 0..node_count(node_levels) {
        nodes.push(NodeValues { min: r.f32()?, max: r.f32()?, static_error: r.f32()? });
    }
    let fine_errors = read_f32s(r, fine)?;
    if !fine_errors.iter().all(|v| v.is_finite() && *v >= 0.0) {
        return Err(IndexError::Corrupt(format!("block {id}: bad fine maxima")));
    }
    Ok(BlockEntry {
        valid_w,
        valid_h,
        file_len,
        min,
        max,
        levels,
        nodes,
        level_errors,
        fine_errors,
        dss,
        fine_max: FineMaxima::default(),
    })
}

/// `n` values read into a vector of exactly `n`.
fn read_f32s(r: &mut Reader<'_>, n: usize) -> Result<Vec<f32>, IndexError> {
    let mut v = Vec::with_capacity(n);
    for _ in 0..n {
        v.push(r.f32()?);
    }
    Ok(v)
}

/// Parses and checks an index whole, any version (a version-4 index page by page).
pub(crate) fn read_index(bytes: &[u8]) -> Result<(Header, Vec<BlockEntry>), IndexError> {
    if bytes.len() < 12 || bytes[..8] != MAGIC {
        return Err(IndexError::BadMagic);
    }
    let version = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]);
    if !(VERSION..=INDEX_VERSION).contains(&version) {
        return Err(IndexError::Version(version));
    }
    if version >= PAGED_INDEX_VERSION {
        return crate::pages::read_paged_whole(bytes);
    }
    if bytes.len() < 16 {
        return Err(IndexError::Corrupt("shorter than its checksum".into()));
    }
    let (body, tail) = bytes.split_at(bytes.len() - 4);
    let stored = u32::from_le_bytes([tail[0], tail[1], tail[2], tail[3]]);
    let computed = crc32(body);
    if stored != computed {
        return Err(IndexError::Corrupt(format!(
            "checksum mismatch (stored {stored:08x}, computed {computed:08x})"
        )));
    }
    let mut r = Reader::new(&body[12..]);
    let header = read_header(&mut r)?;
    let k = header.k;
    let node_levels = header.node_levels;
    let n_blocks = header.block_count();
    let fine = if version >= 3 { fine_count(k, node_levels) } else { 0 };
    let per_block = 4
        + 4
        + 8
        + 8
        + (k as usize + 1) * 16
        + k as usize * 4
        + 2 * DSS_FACTORS * 4
        + node_count(node_levels) * 12
        + fine * 4;
    if r.remaining() != n_blocks * per_block {
        return Err(IndexError::Corrupt(format!(
            "{} bytes of block entries, expected {} for {n_blocks} blocks",
            r.remaining(),
            n_blocks * per_block
        )));
    }
    let mut blocks = Vec::with_capacity(n_blocks);
    for pos in 0..n_blocks {
        let id = header.block_at(pos);
        let entry = read_entry(&mut r, &header, id, fine)?;
        let dss = &entry.dss;
        // A store has the errors in every block or in none (one bake wrote them all).
        if blocks.first().is_some_and(|b: &BlockEntry| b.dss.is_some() != dss.is_some()) {
            return Err(IndexError::Corrupt(format!(
                "block {id}: DSS errors present in some blocks only"
            )));
        }
        blocks.push(entry);
    }
    Ok((header, blocks))
}

/// The header of a block file.
pub(crate) fn block_header(bake_id: u64, id: BlockId) -> Vec<u8> {
    let mut w = Writer::default();
    w.bytes(&BLOCK_MAGIC);
    w.u32(VERSION);
    w.u64(bake_id);
    w.u32(id.row);
    w.u32(id.col);
    w.buf
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The level of a vertex follows the largest power of two dividing its coordinates.
    #[test]
    fn vertex_levels_follow_the_stride() {
        assert_eq!(vertex_level(8, 0, 0), 0);
        assert_eq!(vertex_level(8, 256, 0), 0);
        assert_eq!(vertex_level(8, 128, 0), 1);
        assert_eq!(vertex_level(8, 128, 64), 2);
        assert_eq!(vertex_level(8, 1, 0), 8);
        assert_eq!(vertex_level(8, 0, 3), 8);
    }

    #[test]
    fn the_papers_5x5_example() {
        // Qiu 2013 Fig. 4: vertex 21 at (3, 3) is level 2, order 12, offset 9 + 12 = 21.
        let v = vertex_index(2, 3, 3).unwrap();
        assert_eq!(v, VertexIndex { level: 2, order: 12, offset: 21 });
        assert_eq!(offset_start(2), 9);
        assert_eq!((offset_start(0), offset_end(0)), (0, 3));
        assert_eq!((offset_start(1), offset_end(1)), (4, 8));
        assert_eq!((offset_start(2), offset_end(2)), (9, 24));
        // Fig. 3: level 0 is the four corners (0..3), level 1 the five vertices 4..8.
        let corners: Vec<u32> = [(0, 0), (4, 0), (0, 4), (4, 4)]
            .iter()
            .map(|&(i, j)| vertex_index(2, i, j).unwrap().offset)
            .collect();
        assert_eq!(corners, [0, 1, 2, 3]);
        let l1: Vec<u32> = [(2, 0), (0, 2), (2, 2), (4, 2), (2, 4)]
            .iter()
            .map(|&(i, j)| vertex_index(2, i, j).unwrap().offset)
            .collect();
        assert_eq!(l1, [4, 5, 6, 7, 8]);
        assert_eq!(vertex_index(2, 5, 0), None);
    }

    #[test]
    fn offsets_enumerate_every_vertex_once() {
        for k in 1..=6u8 {
            let side = (1usize << k) + 1;
            let mut seen = vec![false; side * side];
            for n in 0..=k {
                let mut order = 0u32;
                for_each_level_vertex(k, n, |i, j| {
                    let v = vertex_index(k, i, j).unwrap();
                    assert_eq!((v.level, v.order), (n, order), "k {k} ({i}, {j})");
                    assert!(!seen[v.offset as usize]);
                    seen[v.offset as usize] = true;
                    order += 1;
                });
                assert_eq!(order as usize, level_len(n));
            }
            assert!(seen.iter().all(|&s| s));
        }
    }

    #[test]
    fn quantize_is_the_division_rounded() {
        // The definition, as the bake computed it per sample.
        let divided = |h: f32, step: f64, offset: f64| {
            let t = ((h as f64 - offset) / step).round();
            (i32::MIN as f64..=i32::MAX as f64).contains(&t).then_some(t as i32)
        };
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let (mut checked, mut halves) = (0usize, 0usize);
        let steps = [
            1.0,
            0.5,
            2.0,
            0.1,
            0.018,
            1.8 * 0.01,
            1.0 / 3.0,
            0.3,
            7.25,
            1e-6,
            1e-30,
            1e30,
            1e300,
            5e-324,
        ];
        for &step in &steps {
            for &offset in &[0.0, -0.5, 12.75, -1234.567, 0.05] {
                let qz = Quantizer::new(step, offset);
                let mut check = |h: f32| {
                    let want = divided(h, step, offset);
                    assert_eq!(
                        qz.steps(h),
                        want,
                        "height {h:e} ({:#x}) step {step:e} offset {offset}",
                        h.to_bits()
                    );
                    checked += 1;
                };
                // Halves (the quotient k + 1/2, exactly or within an f32 ulp), both signs, and
                // their neighbours; whole steps; the extremes.
                for k in -3000i64..3000 {
                    for frac in [0.5, 0.0, 0.25, 0.4999999, 0.5000001] {
                        let h = (offset + (k as f64 + frac) * step) as f32;
                        for h in [h, h.next_up(), h.next_down()] {
                            if h.is_finite() {
                                check(h);
                            }
                        }
                    }
                    if ((k as f64 + 0.5) * step + offset) as f32 as f64
                        == (k as f64 + 0.5) * step + offset
                    {
                        halves += 1;
                    }
                }
                for h in [
                    0.0,
                    -0.0,
                    f32::MAX,
                    f32::MIN,
                    f32::MIN_POSITIVE,
                    -f32::MIN_POSITIVE,
                    1e-45,
                    8848.86,
                    -430.5,
                    2.1e9,
                    -2.2e9,
                    1e20,
                    f32::INFINITY,
                    f32::NEG_INFINITY,
                    f32::NAN,
                ] {
                    check(h);
                }
                // Random heights of every magnitude and random bit patterns.
                for _ in 0..20_000 {
                    let r = next();
                    check(f32::from_bits(r as u32));
                    check(((r >> 32) as i32 as f32) * (1.0 / 65536.0));
                }
            }
        }
        // By rows (the bake's path): the same integers, and the first height out of range.
        for &step in &steps {
            let qz = Quantizer::new(step, 3.5);
            for _ in 0..200 {
                let row: Vec<f32> = (0..37)
                    .map(|_| {
                        let r = next();
                        match r % 4 {
                            0 => f32::from_bits(r as u32 >> 1),
                            1 => ((r >> 40) as f32 + 0.5) * step as f32,
                            _ => ((r >> 32) as i32 as f32) * (1.0 / 4096.0),
                        }
                    })
                    .collect();
                let mut got = vec![0i32; row.len()];
                let want: Result<Vec<i32>, usize> =
                    row.iter().enumerate().map(|(i, &h)| divided(h, step, 3.5).ok_or(i)).collect();
                match (qz.steps_row(&row, &mut got), want) {
                    (Ok(()), Ok(want)) => assert_eq!(got, want, "step {step:e}"),
                    (Err(i), Err(j)) => assert_eq!(i, j, "step {step:e}"),
                    (a, b) => panic!("step {step:e}: {a:?} against {b:?}"),
                }
            }
        }
        assert!(checked > 1_000_000, "{checked} heights checked");
        // Negative control: exact halves were among them (where `round` and a naive
        // round-half-even differ), so the tie rule was exercised.
        assert!(halves > 1000, "{halves} exact halves");
        assert_eq!(Quantizer::new(1.0, 0.0).steps(2.5), Some(3));
        assert_eq!(Quantizer::new(1.0, 0.0).steps(-2.5), Some(-3));
        assert_eq!(Quantizer::new(2.0, 0.0).steps(-5.0), Some(-3));
    }
}
