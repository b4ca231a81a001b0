//! Cesium's quantized-mesh-1.0 terrain tile format: the encoder of `terrain tiles`, a decoder
//! (for the round-trip tests and checks), and gzip framing.
//!
//! Layout (all little-endian), as the format's specification (CesiumGS/quantized-mesh) gives it:
//!
//! - header, 88 bytes: tile centre (ECEF, 3 x f64), minimum and maximum height (2 x f32),
//!   bounding sphere (centre 3 x f64, radius f64), horizon occlusion point (ellipsoid-scaled
//!   ECEF, 3 x f64);
//! - vertex data: `u32` count, then all `u`, all `v`, all heights, each `u16` in `0..=32767`
//!   across the tile (west to east, south to north, minimum to maximum height), each array
//!   delta-encoded and zig-zag encoded;
//! - index data: padding to the index size, `u32` triangle count, indices (`u16`, or `u32` when
//!   there are more than 65536 vertices) *high-water-mark* encoded (vertices numbered in the
//!   order of their first use, each index written as `highest - index`);
//! - edge indices: the vertices on the west, south, east and north borders (`u32` count and
//!   plain indices each), from which clients hang skirts;
//! - extensions: `u8` id, `u32` length, bytes: oct-encoded vertex normals (id 1, two bytes per
//!   vertex, Cigolle et al. 2014 "A survey of efficient representations for independent unit
//!   vectors" with Cesium's `AttributeCompression.octEncode` to 8 bits) and metadata (id 4: a
//!   `u32` length and JSON; `{"available": [[ranges of the children's level]]}`).

use glam::{DVec2, DVec3, Vec3, dvec2};

use crate::bytes::{LeReader, Short};
use crate::mesh::vertex_normals;
use crate::tin::{TileMesh, TileRange};

/// Largest quantized coordinate.
pub const QUANTIZED_MAX: u32 = 32767;

/// WGS84 semi-major axis, metres.
const WGS84_A: f64 = 6_378_137.0;
/// WGS84 flattening.
const WGS84_F: f64 = 1.0 / 298.257_223_563;

/// Extension id of oct-encoded vertex normals.
pub const EXT_OCT_NORMALS: u8 = 1;
/// Extension id of the metadata JSON.
pub const EXT_METADATA: u8 = 4;

/// Why a tile could not be encoded or decoded.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum QmError {
    /// The bytes end before the structure they announce.
    #[error("the tile is truncated at byte {at} (reading {what})")]
    Truncated {
        /// Byte offset.
        at: usize,
        /// What was being read.
        what: &'static str,
    },
    /// An index points past the vertices.
    #[error("index {index} is past the {vertices} vertices")]
    BadIndex {
        /// The index.
        index: u32,
        /// Vertex count.
        vertices: usize,
    },
    /// A tile without triangles (every triangle collapsed when quantized).
    #[error("the tile has no triangle left after quantization")]
    Empty,
    /// Gzip framing is wrong or its checksum does not match.
    #[error("gzip: {0}")]
    Gzip(String),
}

/// WGS84 geodetic (longitude, latitude in degrees, height in metres) to Earth-centred,
/// Earth-fixed metres.
pub fn ecef(lon_deg: f64, lat_deg: f64, height: f64) -> DVec3 {
    let e2 = WGS84_F * (2.0 - WGS84_F);
    let (lat, lon) = (lat_deg.to_radians(), lon_deg.to_radians());
    let n = WGS84_A / (1.0 - e2 * lat.sin() * lat.sin()).sqrt();
    DVec3::new(
        (n + height) * lat.cos() * lon.cos(),
        (n + height) * lat.cos() * lon.sin(),
        (n * (1.0 - e2) + height) * lat.sin(),
    )
}

/// Zig-zag encoding of a signed delta (`0, -1, 1, -2, ...` to `0, 1, 2, 3, ...`).
pub fn zigzag(v: i32) -> u16 {
    ((v << 1) ^ (v >> 31)) as u16
}

/// Inverse of [`zigzag`].
pub fn unzigzag(v: u16) -> i32 {
    let v = i32::from(v);
    (v >> 1) ^ -(v & 1)
}

/// High-water-mark encoding of indices numbered in order of first use.
///
/// Returns `None` if an index skips ahead of the next new one (the vertices are not in
/// first-use order).
pub fn hwm_encode(indices: &[u32]) -> Option<Vec<u32>> {
    let mut highest = 0u32;
    let mut out = Vec::with_capacity(indices.len());
    for &i in indices {
        if i > highest {
            return None;
        }
        out.push(highest - i);
        if i == highest {
            highest += 1;
        }
    }
    Some(out)
}

/// Inverse of [`hwm_encode`].
pub fn hwm_decode(codes: &[u32]) -> Vec<u32> {
    let mut highest = 0u32;
    codes
        .iter()
        .map(|&c| {
            let i = highest.wrapping_sub(c);
            if c == 0 {
                highest += 1;
            }
            i
        })
        .collect()
}

/// Cesium's `toSNorm` to 8 bits: `[-1, 1]` to `0..=255`.
fn to_snorm(v: f32) -> u8 {
    ((v.clamp(-1.0, 1.0) * 0.5 + 0.5) * 255.0).round() as u8
}

fn from_snorm(v: u8) -> f32 {
    f32::from(v).clamp(0.0, 255.0) / 255.0 * 2.0 - 1.0
}

fn sign_not_zero(v: f32) -> f32 {
    if v < 0.0 { -1.0 } else { 1.0 }
}

/// Oct encoding of a unit vector to two bytes (Cesium's `AttributeCompression.octEncode`).
pub fn oct_encode(n: Vec3) -> [u8; 2] {
    let l1 = n.x.abs() + n.y.abs() + n.z.abs();
    let (mut x, mut y) = (n.x / l1, n.y / l1);
    if n.z < 0.0 {
        let (ox, oy) = (x, y);
        x = (1.0 - oy.abs()) * sign_not_zero(ox);
        y = (1.0 - ox.abs()) * sign_not_zero(oy);
    }
    [to_snorm(x), to_snorm(y)]
}

/// Inverse of [`oct_encode`] (Cesium's `octDecode`), normalised.
pub fn oct_decode(e: [u8; 2]) -> Vec3 {
    let (x, y) = (from_snorm(e[0]), from_snorm(e[1]));
    let z = 1.0 - (x.abs() + y.abs());
    let (x, y) = if z < 0.0 {
        ((1.0 - y.abs()) * sign_not_zero(x), (1.0 - x.abs()) * sign_not_zero(y))
    } else {
        (x, y)
    };
    Vec3::new(x, y, z).normalize()
}

/// The horizon occlusion point of `points` (ECEF) seen along `direction`, in the
/// ellipsoid-scaled frame (Cesium's `EllipsoidalOccluder.computeHorizonCullingPoint`); `None`
/// when no such point exists (a tile spanning too much of the globe).
fn horizon_occlusion_point(points: &[DVec3], direction: DVec3) -> Option<DVec3> {
    let radii = DVec3::new(WGS84_A, WGS84_A, WGS84_A * (1.0 - WGS84_F));
    let dir = (direction / radii).try_normalize()?;
    let mut max_magnitude = 0.0f64;
    for p in points {
        let s = *p / radii;
        let mag2 = s.length_squared().max(1.0);
        let mag = mag2.sqrt();
        let d = s.try_normalize()?;
        let cos_alpha = d.dot(dir);
        let sin_alpha = d.cross(dir).length();
        let cos_beta = 1.0 / mag;
        let sin_beta = (mag2 - 1.0).sqrt() * cos_beta;
        let denom = cos_alpha * cos_beta - sin_alpha * sin_beta;
        if denom <= 0.0 {
            return None;
        }
        max_magnitude = max_magnitude.max(1.0 / denom);
    }
    Some(dir * max_magnitude)
}

/// Encodes a tile. `children` is the availability of the next level below this tile, written in
/// the metadata extension.
pub fn encode(mesh: &TileMesh, children: Option<TileRange>) -> Result<Vec<u8>, QmError> {
    let q = QUANTIZED_MAX as f64;
    let (lo, hi) = mesh
        .vertices
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v.z), hi.max(v.z)));
    let (lo32, hi32) = (lo as f32, hi as f32);
    let (flo, fhi) = (f64::from(lo32), f64::from(hi32));
    let quant = |v: DVec3| -> [u16; 3] {
        let h = if fhi > flo { ((v.z - flo) / (fhi - flo) * q).round().clamp(0.0, q) } else { 0.0 };
        [(v.x * q).round() as u16, (v.y * q).round() as u16, h as u16]
    };
    // Vertices merged where quantization puts two at one (u, v); triangles that collapse are
    // dropped; the rest renumbered in order of first use (for the high-water mark). The map is
    // only looked up (FxHash: SipHash's time showed in `terrain tiles`).
    let mut at_uv =
        rustc_hash::FxHashMap::with_capacity_and_hasher(mesh.vertices.len(), Default::default());
    let mut merged: Vec<u32> = Vec::with_capacity(mesh.vertices.len());
    let qv: Vec<[u16; 3]> = mesh.vertices.iter().map(|&v| quant(v)).collect();
    for (k, v) in qv.iter().enumerate() {
        merged.push(*at_uv.entry((v[0], v[1])).or_insert(k as u32));
    }
    let mut order: Vec<u32> = vec![u32::MAX; mesh.vertices.len()];
    let mut first_use: Vec<u32> = Vec::new();
    let mut tris: Vec<[u32; 3]> = Vec::with_capacity(mesh.triangles.len());
    for t in &mesh.triangles {
        let t = t.map(|k| merged[k as usize]);
        let g = t.map(|k| {
            let v = qv[k as usize];
            [i64::from(v[0]), i64::from(v[1])]
        });
        let area =
            (g[1][0] - g[0][0]) * (g[2][1] - g[0][1]) - (g[1][1] - g[0][1]) * (g[2][0] - g[0][0]);
        if area == 0 {
            continue;
        }
        tris.push(t.map(|k| {
            if order[k as usize] == u32::MAX {
                order[k as usize] = first_use.len() as u32;
                first_use.push(k);
            }
            order[k as usize]
        }));
    }
    if tris.is_empty() {
        return Err(QmError::Empty);
    }
    let n = first_use.len();
    let positions: Vec<DVec3> = first_use
        .iter()
        .map(|&k| {
            let ll = mesh.lonlat(k as usize);
            ecef(ll.x, ll.y, mesh.vertices[k as usize].z)
        })
        .collect();
    let normals = vertex_normals(&positions, &tris);
    let (bmin, bmax) = positions
        .iter()
        .fold((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)), |(a, b), p| {
            (a.min(*p), b.max(*p))
        });
    let centre = 0.5 * (bmin + bmax);
    let radius = positions.iter().map(|p| p.distance(centre)).fold(0.0, f64::max);
    // No horizon point for a tile that wraps too much of the globe: one far out along its
    // centre, which culls it only from the far side of the Earth.
    let occlusion = horizon_occlusion_point(&positions, centre)
        .unwrap_or_else(|| centre.normalize_or_zero() * 1e3);

    let mut out = Vec::with_capacity(88 + n * 8 + tris.len() * 6 + 64);
    for v in [centre.x, centre.y, centre.z] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&lo32.to_le_bytes());
    out.extend_from_slice(&hi32.to_le_bytes());
    for v in [centre.x, centre.y, centre.z, radius, occlusion.x, occlusion.y, occlusion.z] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&(n as u32).to_le_bytes());
    for c in [0usize, 1, 2] {
        let mut prev = 0i32;
        for &k in &first_use {
            let v = i32::from(qv[k as usize][c]);
            out.extend_from_slice(&zigzag(v - prev).to_le_bytes());
            prev = v;
        }
    }
    let wide = n > 65536;
    let size = if wide { 4 } else { 2 };
    while !out.len().is_multiple_of(size) {
        out.push(0);
    }
    let put = |out: &mut Vec<u8>, i: u32| {
        if wide {
            out.extend_from_slice(&i.to_le_bytes());
        } else {
            out.extend_from_slice(&(i as u16).to_le_bytes());
        }
    };
    out.extend_from_slice(&(tris.len() as u32).to_le_bytes());
    let flat: Vec<u32> = tris.iter().flatten().copied().collect();
    let codes = hwm_encode(&flat).unwrap_or_else(|| unreachable!("numbered in first-use order"));
    for c in codes {
        put(&mut out, c);
    }
    let max = QUANTIZED_MAX as u16;
    // West (u = 0), south (v = 0), east (u = max), north (v = max): (coordinate, value).
    for (c, at) in [(0usize, 0u16), (1, 0), (0, max), (1, max)] {
        let list: Vec<u32> =
            (0..n as u32).filter(|&i| qv[first_use[i as usize] as usize][c] == at).collect();
        out.extend_from_slice(&(list.len() as u32).to_le_bytes());
        for i in list {
            put(&mut out, i);
        }
    }
    out.push(EXT_OCT_NORMALS);
    out.extend_from_slice(&(2 * n as u32).to_le_bytes());
    for nrm in &normals {
        out.extend_from_slice(&oct_encode(*nrm));
    }
    let available: Vec<Vec<TileRange>> = children.into_iter().map(|c| vec![c]).collect();
    let json = serde_json::json!({ "available": available }).to_string();
    out.push(EXT_METADATA);
    out.extend_from_slice(&(4 + json.len() as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(json.as_bytes());
    Ok(out)
}

/// A decoded tile.
#[derive(Debug, Clone, PartialEq)]
pub struct Decoded {
    /// Tile centre, ECEF.
    pub centre: DVec3,
    /// Height range, metres.
    pub min_height: f32,
    /// Height range, metres.
    pub max_height: f32,
    /// Bounding sphere centre and radius.
    pub sphere: (DVec3, f64),
    /// Horizon occlusion point, ellipsoid-scaled ECEF.
    pub occlusion: DVec3,
    /// Quantized `(u, v, height)` per vertex.
    pub vertices: Vec<[u16; 3]>,
    /// Triangles.
    pub triangles: Vec<[u32; 3]>,
    /// West, south, east and north edge vertices.
    pub edges: [Vec<u32>; 4],
    /// Oct-encoded normals, if present.
    pub normals: Option<Vec<[u8; 2]>>,
    /// Metadata JSON, if present.
    pub metadata: Option<String>,
}

impl Decoded {
    /// Vertex `k`'s position in the tile's unit square and its height in metres.
    pub fn position(&self, k: usize) -> (DVec2, f64) {
        let q = f64::from(QUANTIZED_MAX);
        let v = self.vertices[k];
        let h = f64::from(self.min_height)
            + f64::from(v[2]) / q * (f64::from(self.max_height) - f64::from(self.min_height));
        (dvec2(f64::from(v[0]) / q, f64::from(v[1]) / q), h)
    }
}

/// The shared little-endian reader, each short read naming what was being read.
struct Reader<'a>(LeReader<'a>);

impl Reader<'_> {
    fn named<T>(&mut self, v: Result<T, Short>, what: &'static str) -> Result<T, QmError> {
        v.map_err(|s| QmError::Truncated { at: s.at, what })
    }
    fn take(&mut self, n: usize, what: &'static str) -> Result<&[u8], QmError> {
        self.0.take(n).map_err(|s| QmError::Truncated { at: s.at, what })
    }
    fn f64(&mut self, what: &'static str) -> Result<f64, QmError> {
        let v = self.0.f64();
        self.named(v, what)
    }
    fn f32(&mut self, what: &'static str) -> Result<f32, QmError> {
        let v = self.0.f32();
        self.named(v, what)
    }
    fn u32(&mut self, what: &'static str) -> Result<u32, QmError> {
        let v = self.0.u32();
        self.named(v, what)
    }
    fn u16(&mut self, what: &'static str) -> Result<u16, QmError> {
        let v = self.0.u16();
        self.named(v, what)
    }
    fn index(&mut self, wide: bool, what: &'static str) -> Result<u32, QmError> {
        if wide { self.u32(what) } else { self.u16(what).map(u32::from) }
    }
    /// A count of items of `per_item` bytes, refused before allocating when the remaining
    /// bytes cannot hold them.
    fn count(&mut self, per_item: usize, what: &'static str) -> Result<usize, QmError> {
        let v = self.0.count(per_item);
        self.named(v, what)
    }
}

/// Decodes a tile (not gzipped: see [`gunzip`]).
pub fn decode(bytes: &[u8]) -> Result<Decoded, QmError> {
    let mut r = Reader(LeReader::new(bytes));
    let v3 = |r: &mut Reader<'_>, what| -> Result<DVec3, QmError> {
        Ok(DVec3::new(r.f64(what)?, r.f64(what)?, r.f64(what)?))
    };
    let centre = v3(&mut r, "header")?;
    let (min_height, max_height) = (r.f32("header")?, r.f32("header")?);
    let sphere = (v3(&mut r, "header")?, r.f64("header")?);
    let occlusion = v3(&mut r, "header")?;
    let n = r.count(6, "vertex count")?;
    let mut cols = [vec![0u16; n], vec![0u16; n], vec![0u16; n]];
    for col in &mut cols {
        let mut acc = 0i32;
        for slot in col.iter_mut() {
            acc += unzigzag(r.u16("vertex data")?);
            *slot = acc as u16;
        }
    }
    let vertices: Vec<[u16; 3]> = (0..n).map(|k| [cols[0][k], cols[1][k], cols[2][k]]).collect();
    let wide = n > 65536;
    let size = if wide { 4 } else { 2 };
    while !r.0.pos().is_multiple_of(size) {
        r.take(1, "padding")?;
    }
    let nt = r.count(3 * size, "triangle count")?;
    let mut codes = Vec::with_capacity(3 * nt);
    for _ in 0..3 * nt {
        codes.push(r.index(wide, "indices")?);
    }
    let flat = hwm_decode(&codes);
    if let Some(&index) = flat.iter().find(|&&i| i as usize >= n) {
        return Err(QmError::BadIndex { index, vertices: n });
    }
    let triangles = flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let mut edges: [Vec<u32>; 4] = Default::default();
    for e in &mut edges {
        let m = r.count(size, "edge indices")?;
        for _ in 0..m {
            let index = r.index(wide, "edge indices")?;
            if index as usize >= n {
                return Err(QmError::BadIndex { index, vertices: n });
            }
            e.push(index);
        }
    }
    let (mut normals, mut metadata) = (None, None);
    while r.0.pos() < bytes.len() {
        let id = r.take(1, "extension id")?[0];
        let len = r.u32("extension length")? as usize;
        let body = r.take(len, "extension")?;
        match id {
            EXT_OCT_NORMALS => normals = Some(body.chunks_exact(2).map(|c| [c[0], c[1]]).collect()),
            EXT_METADATA if len >= 4 => {
                let json = &body[4..];
                metadata = Some(String::from_utf8_lossy(json).into_owned());
            }
            _ => {}
        }
    }
    Ok(Decoded {
        centre,
        min_height,
        max_height,
        sphere,
        occlusion,
        vertices,
        triangles,
        edges,
        normals,
        metadata,
    })
}

/// Gzip framing (RFC 1952) around raw Deflate (`miniz_oxide`), with the engine's CRC-32.
pub fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut out = vec![0x1f, 0x8b, 8, 0, 0, 0, 0, 0, 0, 255];
    out.extend(miniz_oxide::deflate::compress_to_vec(bytes, 6));
    out.extend_from_slice(&crate::checksum::crc32(bytes).to_le_bytes());
    out.extend_from_slice(&(bytes.len() as u32).to_le_bytes());
    out
}

/// Whether `bytes` start with the gzip magic number.
pub fn is_gzip(bytes: &[u8]) -> bool {
    bytes.starts_with(&[0x1f, 0x8b])
}

/// Inverse of [`gzip`] (members written without optional header fields, as [`gzip`] writes).
pub fn gunzip(bytes: &[u8]) -> Result<Vec<u8>, QmError> {
    let bad = |m: &str| QmError::Gzip(m.into());
    if bytes.len() < 18 || !is_gzip(bytes) || bytes[2] != 8 {
        return Err(bad("not a gzip member with Deflate"));
    }
    if bytes[3] != 0 {
        return Err(bad("optional header fields are not read"));
    }
    let body = &bytes[10..bytes.len() - 8];
    let data = miniz_oxide::inflate::decompress_to_vec(body).map_err(|e| bad(&format!("{e:?}")))?;
    let tail = &bytes[bytes.len() - 8..];
    let crc = u32::from_le_bytes([tail[0], tail[1], tail[2], tail[3]]);
    if crc != crate::checksum::crc32(&data) {
        return Err(bad("CRC-32 mismatch"));
    }
    Ok(data)
}
