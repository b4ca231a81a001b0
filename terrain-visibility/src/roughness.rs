//! Slope and roughness: the PVPS paper's (Zhang 2021) roughness map (section 2.2.3, Eq. 5) and
//! the roughness measures of its two comparison methods, as per-node pyramids over the quadtree.
//!
//! * Slope is the Horn (1981) 3x3 method, which is what ArcGIS's Slope tool computes (the paper
//!   used ArcGIS 10.3). At the grid's border and next to voids, a missing neighbour takes the
//!   centre sample's value, as the ArcGIS tool does.
//! * Roughness (Eq. 5) is `1 / cos(slope)`, the ratio of surface area to projected area. It is
//!   infinite at a vertical cliff; we clamp the slope to [`RoughnessConfig::max_slope_deg`]
//!   (default 89°, roughness ≤ 57.3) so cliffs stay finite and still rank as the roughest.
//! * The paper normalises roughness to 0-255 and stores it as a grey image; we normalise the
//!   same way but keep it as `f32`, and write 8-bit PNGs only for export.
//!
//! Pyramids are indexed like the engine's quadtree: the root covers `root_cells`, the next
//! power of two of cells at or above the grid's larger side, and node `(level, i, j)` covers
//! `root_cells / 2^level` cells starting at `(i, j)` times that. A node's value is the exact
//! mean (or min / max) over the samples it covers; for a full power-of-two grid this is the
//! paper's "arithmetic mean of four neighbourhood pixels of the level above".

use terrain_core::Heightmap;
use terrain_core::lod::NodeField;
use terrain_core::quadtree::NodeId;

pub mod file;
pub mod stream;

/// Settings of the roughness computation.
#[derive(Debug, Clone, PartialEq)]
pub struct RoughnessConfig {
    /// Slopes are clamped to this many degrees before Eq. 5, so a vertical cliff gives a
    /// finite roughness (1 / cos 89° ≈ 57.3). Default 89.
    pub max_slope_deg: f64,
}

impl Default for RoughnessConfig {
    fn default() -> Self {
        Self { max_slope_deg: 89.0 }
    }
}

/// Slope in degrees at every sample, by Horn's 3x3 method (row-major, row 0 = south).
pub fn slope_degrees(hm: &Heightmap) -> Vec<f32> {
    let (w, h) = (hm.width(), hm.height());
    let s = hm.georef().spacing_m;
    let voids = hm.voids();
    let mut out = Vec::with_capacity(w * h);
    for j in 0..h {
        for i in 0..w {
            let c = hm.get(i, j) as f64;
            // z(di, dj): a neighbour's height, or the centre's when outside the grid or void.
            let z = |di: i64, dj: i64| -> f64 {
                let (x, y) = (i as i64 + di, j as i64 + dj);
                if x < 0
                    || y < 0
                    || x >= w as i64
                    || y >= h as i64
                    || voids.get(x as usize, y as usize)
                {
                    c
                } else {
                    hm.get(x as usize, y as usize) as f64
                }
            };
            out.push(horn_slope_deg(z, s));
        }
    }
    out
}

/// Horn 1981's slope in degrees from a sample's 3x3 neighbourhood `z(di, dj)` (x east, y
/// north; the caller gives the centre's height for a missing neighbour) and the grid spacing:
/// the one kernel of [`slope_degrees`] and of the pyramids computed by bands of rows
/// ([`stream`]), so both give the same bits.
pub(crate) fn horn_slope_deg(z: impl Fn(i64, i64) -> f64, s: glam::DVec2) -> f32 {
    // Horn 1981: weighted central differences, x east, y north.
    let dzdx = ((z(1, 1) + 2.0 * z(1, 0) + z(1, -1)) - (z(-1, 1) + 2.0 * z(-1, 0) + z(-1, -1)))
        / (8.0 * s.x);
    let dzdy = ((z(-1, 1) + 2.0 * z(0, 1) + z(1, 1)) - (z(-1, -1) + 2.0 * z(0, -1) + z(1, -1)))
        / (8.0 * s.y);
    dzdx.hypot(dzdy).atan().to_degrees() as f32
}

/// Roughness per sample, PVPS paper Eq. 5: `1 / cos(slope)`, slope clamped (see the module doc).
pub fn roughness(hm: &Heightmap, config: &RoughnessConfig) -> Vec<f32> {
    let max = max_slope(config);
    slope_degrees(hm).into_iter().map(|deg| secant(deg, max)).collect()
}

/// The slope clamp of Eq. 5 in degrees.
pub(crate) fn max_slope(config: &RoughnessConfig) -> f64 {
    config.max_slope_deg.clamp(0.0, 89.999)
}

/// Eq. 5 at one sample: `1 / cos(min(slope, max))`.
pub(crate) fn secant(deg: f32, max: f64) -> f32 {
    (1.0 / (deg as f64).min(max).to_radians().cos()) as f32
}

/// Normalises values to 0-255 (kept as float), as the paper does before storing its roughness
/// image. A constant field (a plane) maps to 0 everywhere.
pub fn normalize_255(values: &[f32]) -> Vec<f32> {
    let (lo, hi) =
        values.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
    let n = Normalize255::new(lo, hi);
    values.iter().map(|&v| n.apply(v)).collect()
}

/// [`normalize_255`]'s map from the values' range `lo ..= hi` (one implementation for the
/// whole-grid and the by-rows pyramids).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Normalize255 {
    lo: f32,
    /// `None`: a constant field, all 0.
    k: Option<f64>,
}

impl Normalize255 {
    pub(crate) fn new(lo: f32, hi: f32) -> Self {
        Self { lo, k: (hi > lo).then(|| 255.0 / (hi - lo) as f64) }
    }

    pub(crate) fn apply(&self, v: f32) -> f32 {
        match self.k {
            Some(k) => ((v - self.lo) as f64 * k) as f32,
            None => 0.0,
        }
    }
}

/// How the quadtree's root covers a grid: the next power of two of cells.
pub fn root_cells(width: usize, height: usize) -> usize {
    (width.max(height).saturating_sub(1)).max(1).next_power_of_two()
}

/// Levels of terrain-core's `Quadtree` over a `width x height` grid with leaves of
/// `leaf_cells` (a power of two): its `max_level() + 1`, the levels the PVPS methods' pyramids
/// have, known without the heights (a bake by rows, a store-backed method).
pub fn quadtree_levels(width: usize, height: usize, leaf_cells: usize) -> usize {
    let root = root_cells(width, height).max(leaf_cells.max(1));
    (root / leaf_cells.max(1)).trailing_zeros() as usize + 1
}

/// One value per quadtree node, level 0 (the root, 1x1) to `levels - 1` (`2^(levels-1)` square).
#[derive(Debug, Clone, PartialEq)]
pub struct NodePyramid {
    levels: Vec<Vec<f32>>,
    root_cells: usize,
}

impl NodePyramid {
    /// Number of levels (the paper: 7 for a 64x64 patch grid).
    pub fn levels(&self) -> usize {
        self.levels.len()
    }

    /// Nodes per side at `level`.
    pub fn side(&self, level: usize) -> usize {
        1 << level
    }

    /// Cells covered by the root.
    pub fn root_cells(&self) -> usize {
        self.root_cells
    }

    /// The value of node `(level, i, j)` (i east, j north). Nodes wholly outside the grid hold 0.
    pub fn get(&self, level: usize, i: usize, j: usize) -> f32 {
        self.levels[level][j * self.side(level) + i]
    }

    /// All values of one level, row-major, row 0 = south.
    pub fn level(&self, level: usize) -> &[f32] {
        &self.levels[level]
    }

    /// The pyramid scaled so its largest value is 255 (a pyramid without a positive value
    /// becomes all 0): puts methods A and B of the PVPS paper on the 0-255 scale of its own
    /// roughness image, so one `C1`, `C2` (Eq. 8) serves all three methods.
    pub fn normalized_255(&self) -> NodePyramid {
        let max = self.levels.iter().flatten().fold(0.0f32, |m, &v| m.max(v));
        let k = if max > 0.0 && max.is_finite() { 255.0 / max } else { 0.0 };
        NodePyramid {
            levels: self.levels.iter().map(|l| l.iter().map(|&v| v * k).collect()).collect(),
            root_cells: self.root_cells,
        }
    }
}

/// The LOD methods read a pyramid through terrain-core's [`NodeField`]: node `(level, i, j)` is
/// pixel `(i, j)` of level `level` (both count i east and j north over the same
/// [`root_cells`]). A node deeper than the pyramid reads its ancestor at the finest level; a
/// node outside the pyramid reads 0.
impl NodeField for NodePyramid {
    fn value(&self, node: NodeId) -> f32 {
        let l = (node.level as usize).min(self.levels() - 1);
        let n = node.ancestor(l as u8);
        let side = self.side(l);
        if n.i as usize >= side || n.j as usize >= side {
            return 0.0;
        }
        self.get(l, n.i as usize, n.j as usize)
    }
}

/// How a node's value is reduced from the samples it covers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Reduce {
    Mean,
    Range,
}

/// The finest level of a pyramid being built, fed row by row (south first): per finest node
/// the sum and count (mean) or min and max (range) of the samples it covers. Rows fed in
/// order give the same sums, so the whole-grid and by-rows pyramids are bit-identical.
#[derive(Debug, Clone)]
pub(crate) struct PyramidAccumulator {
    reduce: Reduce,
    root: usize,
    levels: usize,
    /// Finest nodes per side.
    n: usize,
    /// Cells per finest node.
    c: usize,
    sum: Vec<f64>,
    cnt: Vec<u64>,
    lo: Vec<f32>,
    hi: Vec<f32>,
}

impl PyramidAccumulator {
    /// An empty pyramid of `levels` levels over a `width x height` grid.
    pub(crate) fn new(width: usize, height: usize, levels: usize, reduce: Reduce) -> Self {
        assert!(levels >= 1, "a pyramid has at least the root level");
        let root = root_cells(width, height);
        let n = 1usize << (levels - 1);
        // Per finest node: the samples [x0, x0 + c) x [y0, y0 + c) where c = root / n; the last
        // sample row/column of the grid falls in the node that starts at or before it.
        let c = (root / n).max(1);
        let (mean, range) = match reduce {
            Reduce::Mean => (n * n, 0),
            Reduce::Range => (0, n * n),
        };
        Self {
            reduce,
            root,
            levels,
            n,
            c,
            sum: vec![0.0; mean],
            cnt: vec![0; mean],
            lo: vec![f32::INFINITY; range],
            hi: vec![f32::NEG_INFINITY; range],
        }
    }

    /// Adds row `j`'s values; `is_void(i)` leaves sample `i` out.
    pub(crate) fn add_row(&mut self, j: usize, values: &[f32], is_void: impl Fn(usize) -> bool) {
        let (n, c) = (self.n, self.c);
        let base = (j / c).min(n - 1) * n;
        for (i, &v) in values.iter().enumerate() {
            if is_void(i) {
                continue;
            }
            let k = base + (i / c).min(n - 1);
            match self.reduce {
                Reduce::Mean => {
                    self.sum[k] += v as f64;
                    self.cnt[k] += 1;
                }
                Reduce::Range => {
                    self.lo[k] = self.lo[k].min(v);
                    self.hi[k] = self.hi[k].max(v);
                }
            }
        }
    }

    /// The pyramid: the finest level's nodes, then each parent from its four children (sums
    /// and counts add, mins and maxes combine). Nodes without samples hold 0.
    pub(crate) fn finish(self) -> NodePyramid {
        let Self { reduce, root, levels, n, mut sum, mut cnt, mut lo, mut hi, .. } = self;
        let mut out = vec![Vec::new(); levels];
        let mut side = n;
        loop {
            let level = side.trailing_zeros() as usize;
            out[level] = (0..side * side)
                .map(|k| match reduce {
                    Reduce::Mean if cnt[k] > 0 => (sum[k] / cnt[k] as f64) as f32,
                    // A node with samples has lo <= hi (heights are finite).
                    Reduce::Range if lo[k] <= hi[k] => hi[k] - lo[k],
                    _ => 0.0,
                })
                .collect();
            if side == 1 {
                break;
            }
            let half = side / 2;
            let (mean, range) =
                if reduce == Reduce::Mean { (half * half, 0) } else { (0, half * half) };
            let mut s2 = vec![0.0f64; mean];
            let mut c2 = vec![0u64; mean];
            let mut lo2 = vec![f32::INFINITY; range];
            let mut hi2 = vec![f32::NEG_INFINITY; range];
            for j in 0..side {
                for i in 0..side {
                    let (k, p) = (j * side + i, (j / 2) * half + i / 2);
                    if reduce == Reduce::Mean {
                        s2[p] += sum[k];
                        c2[p] += cnt[k];
                    } else {
                        lo2[p] = lo2[p].min(lo[k]);
                        hi2[p] = hi2[p].max(hi[k]);
                    }
                }
            }
            (sum, cnt, lo, hi, side) = (s2, c2, lo2, hi2, half);
        }
        NodePyramid { levels: out, root_cells: root }
    }
}

fn build_pyramid(hm: &Heightmap, values: &[f32], levels: usize, reduce: Reduce) -> NodePyramid {
    let (w, h) = (hm.width(), hm.height());
    let mut acc = PyramidAccumulator::new(w, h, levels, reduce);
    for j in 0..h {
        acc.add_row(j, &values[j * w..(j + 1) * w], |i| hm.voids().get(i, j));
    }
    acc.finish()
}

/// The PVPS paper's roughness image pyramid (method C): Eq. 5 roughness, normalised to 0-255,
/// averaged per node. `levels` = 7 gives the paper's 64x64 patch grid at the finest level.
pub fn roughness_pyramid(hm: &Heightmap, levels: usize, config: &RoughnessConfig) -> NodePyramid {
    let r = normalize_255(&roughness(hm, config));
    build_pyramid(hm, &r, levels, Reduce::Mean)
}

/// Method B's roughness (Dong et al. 2017, the PVPS paper's ref. 21): the difference between the
/// maximum and minimum elevation inside the node, in metres. Voids are excluded.
pub fn range_pyramid(hm: &Heightmap, levels: usize) -> NodePyramid {
    build_pyramid(hm, hm.data(), levels, Reduce::Range)
}

/// Method A's roughness. Zhai et al. 2016 (the PVPS paper's ref. 18) is described there only as
/// "based on quadtrees, taking terrain roughness into consideration"; its text is not part of
/// our spec. We implement the roughness that the quadtree-tessellation literature it builds on
/// uses, Röttger et al. 1998's `d2`: the largest vertical distance between the true heights at
/// the node's four edge midpoints and centre and the bilinear interpolation of its four corners,
/// divided by the node's edge length in metres (dimensionless, like a slope). Computed per node
/// of every level; nodes wholly outside the grid hold 0.
pub fn d2_pyramid(hm: &Heightmap, levels: usize) -> NodePyramid {
    let root = root_cells(hm.width(), hm.height());
    let spacing = d2_spacing(hm.georef().spacing_m);
    let z = |i: usize, j: usize| hm.get_clamped(i as i64, j as i64) as f64;
    let mut out = Vec::with_capacity(levels);
    for level in 0..levels {
        let side = 1usize << level;
        let c = (root / side).max(1);
        let mut v = vec![0.0f32; side * side];
        for nj in 0..side {
            for ni in 0..side {
                let (x0, y0) = (ni * c, nj * c);
                if x0 >= hm.width() || y0 >= hm.height() {
                    continue;
                }
                v[nj * side + ni] = d2_node(z, x0, y0, c, spacing);
            }
        }
        out.push(v);
    }
    NodePyramid { levels: out, root_cells: root }
}

/// The metres per cell that [`d2_pyramid`] divides by: the smaller of the two spacings.
pub(crate) fn d2_spacing(s: glam::DVec2) -> f64 {
    s.x.min(s.y)
}

/// Röttger's `d2` of the node of `c` cells from `(x0, y0)`, with `z(i, j)` the clamped height:
/// the one kernel of [`d2_pyramid`] and of the by-rows pyramids ([`stream`]). It reads rows
/// `y0`, `y0 + c / 2` and `y0 + c` (clamped into the grid) only.
pub(crate) fn d2_node(
    z: impl Fn(usize, usize) -> f64,
    x0: usize,
    y0: usize,
    c: usize,
    spacing: f64,
) -> f32 {
    let (x1, y1) = (x0 + c, y0 + c);
    let (xm, ym) = (x0 + c / 2, y0 + c / 2);
    let (a, b, cc, d) = (z(x0, y0), z(x1, y0), z(x0, y1), z(x1, y1));
    let errs = [
        z(xm, y0) - (a + b) / 2.0,
        z(xm, y1) - (cc + d) / 2.0,
        z(x0, ym) - (a + cc) / 2.0,
        z(x1, ym) - (b + d) / 2.0,
        z(xm, ym) - (a + b + cc + d) / 4.0,
    ];
    let e = errs.iter().fold(0.0f64, |m, e| m.max(e.abs()));
    (e / (c as f64 * spacing)) as f32
}

/// The three roughness pyramids of the PVPS methods, exactly as they read them: A (`d2`) and B
/// (height range) normalised to 0-255 ([`NodePyramid::normalized_255`]), C (Eq. 5) as
/// [`roughness_pyramid`] gives it. `terrain bake` stores them as a scene file ([`file`]);
/// [`stream`] computes them by bands of rows, bit-identical to [`RoughnessTables::compute`].
#[derive(Debug, Clone, PartialEq)]
pub struct RoughnessTables {
    /// Method A: [`d2_pyramid`], normalised.
    pub a: NodePyramid,
    /// Method B: [`range_pyramid`], normalised.
    pub b: NodePyramid,
    /// Method C: [`roughness_pyramid`].
    pub c: NodePyramid,
}

impl RoughnessTables {
    /// The three pyramids of `hm` with `levels` levels each (the quadtree's levels:
    /// `max_level + 1`), from the whole grid in memory.
    pub fn compute(hm: &Heightmap, levels: usize, config: &RoughnessConfig) -> Self {
        Self {
            a: d2_pyramid(hm, levels).normalized_255(),
            b: range_pyramid(hm, levels).normalized_255(),
            c: roughness_pyramid(hm, levels, config),
        }
    }

    /// Levels of each pyramid.
    pub fn levels(&self) -> usize {
        self.c.levels()
    }

    /// The pyramids in the order A, B, C.
    pub fn into_array(self) -> [NodePyramid; 3] {
        [self.a, self.b, self.c]
    }

    /// Whether every value of every pyramid has the same bits as `other`'s (`==` on floats
    /// would call 0.0 and -0.0 equal).
    pub fn bits_eq(&self, other: &Self) -> bool {
        let bits = |t: &Self| -> Vec<u32> {
            [&t.a, &t.b, &t.c]
                .iter()
                .flat_map(|p| p.levels.iter().flatten().map(|v| v.to_bits()))
                .collect()
        };
        self.levels() == other.levels()
            && [(&self.a, &other.a), (&self.b, &other.b), (&self.c, &other.c)]
                .iter()
                .all(|(x, y)| x.root_cells == y.root_cells && x.levels.len() == y.levels.len())
            && bits(self) == bits(other)
    }
}

/// An 8-bit grey image of one pyramid level (values clamped to 0-255 after `scale`), north up,
/// as the paper's Figure 8 / 10 images. Returns (side, pixels row-major north row first).
pub fn level_to_grey(p: &NodePyramid, level: usize, scale: f32) -> (usize, Vec<u8>) {
    let side = p.side(level);
    let mut px = Vec::with_capacity(side * side);
    for j in (0..side).rev() {
        for i in 0..side {
            px.push((p.get(level, i, j) * scale).round().clamp(0.0, 255.0) as u8);
        }
    }
    (side, px)
}

#[cfg(test)]
mod tests {
    use super::*;
    use terrain_core::Georef;

    fn grid(n: usize, spacing: f64, f: impl Fn(f64, f64) -> f64) -> Heightmap {
        Heightmap::from_fn(n, n, Georef::local(spacing), |i, j| {
            f(i as f64 * spacing, j as f64 * spacing) as f32
        })
        .unwrap()
    }

    #[test]
    fn plane_slope_is_exact_and_roughness_is_its_secant() {
        // z = 0.5 x + 0.25 y: slope = atan(|grad|) everywhere inside; edges too (centre fill
        // keeps the one-sided difference at half weight, so check interior only).
        let hm = grid(9, 10.0, |x, y| 0.5 * x + 0.25 * y);
        let s = slope_degrees(&hm);
        let expect = (0.5f64.hypot(0.25)).atan().to_degrees();
        for j in 1..8 {
            for i in 1..8 {
                assert!(
                    (s[j * 9 + i] as f64 - expect).abs() < 1e-4,
                    "{} vs {expect}",
                    s[j * 9 + i]
                );
            }
        }
        let r = roughness(&hm, &RoughnessConfig::default());
        assert!((r[40] as f64 - 1.0 / expect.to_radians().cos()).abs() < 1e-4);
    }

    #[test]
    fn flat_is_zero_and_cliff_is_finite() {
        let flat = grid(17, 1.0, |_, _| 100.0);
        assert!(slope_degrees(&flat).iter().all(|&s| s == 0.0));
        assert!(
            normalize_255(&roughness(&flat, &RoughnessConfig::default())).iter().all(|&r| r == 0.0)
        );
        let cliff = grid(17, 1.0, |x, _| if x < 8.0 { 0.0 } else { 1.0e6 });
        let r = roughness(&cliff, &RoughnessConfig::default());
        assert!(r.iter().all(|v| v.is_finite()));
        let max = r.iter().cloned().fold(0.0, f32::max);
        assert!((max as f64 - 1.0 / 89f64.to_radians().cos()).abs() < 1e-3, "{max}");
    }

    #[test]
    fn pyramid_levels_are_means_of_their_children() {
        // 64 x 64 samples: the root covers 64 cells and every finest node holds one sample, so
        // each parent is exactly the paper's mean of four children.
        let hm = grid(64, 1.0, |x, y| (x * 0.3).sin() * 5.0 + (y * 0.2).cos() * 3.0);
        let p = roughness_pyramid(&hm, 7, &RoughnessConfig::default());
        assert_eq!(p.levels(), 7);
        assert_eq!(p.level(6).len(), 64 * 64);
        for level in 0..6 {
            for j in 0..p.side(level) {
                for i in 0..p.side(level) {
                    let kids = [(0, 0), (1, 0), (0, 1), (1, 1)]
                        .map(|(a, b)| p.get(level + 1, 2 * i + a, 2 * j + b));
                    let mean = kids.iter().sum::<f32>() / 4.0;
                    assert!((p.get(level, i, j) - mean).abs() <= 1e-3, "level {level} ({i},{j})");
                }
            }
        }
    }

    #[test]
    fn pyramid_nodes_are_exact_sample_means_on_odd_grids() {
        let hm =
            Heightmap::from_fn(100, 77, Georef::local(1.0), |i, j| ((i * 7 + j * 13) % 29) as f32)
                .unwrap();
        let v: Vec<f32> = hm.data().to_vec();
        let p = build_pyramid(&hm, &v, 4, Reduce::Mean);
        let root = root_cells(100, 77);
        assert_eq!(root, 128);
        for level in 0..4 {
            let c = root >> level;
            for nj in 0..p.side(level) {
                for ni in 0..p.side(level) {
                    let (mut s, mut n) = (0.0f64, 0);
                    for j in nj * c..((nj + 1) * c).min(77) {
                        for i in ni * c..((ni + 1) * c).min(100) {
                            s += v[j * 100 + i] as f64;
                            n += 1;
                        }
                    }
                    let want = if n == 0 { 0.0 } else { (s / n as f64) as f32 };
                    assert!(
                        (p.get(level, ni, nj) - want).abs() < 1e-4,
                        "level {level} ({ni},{nj})"
                    );
                }
            }
        }
    }

    #[test]
    fn method_b_is_the_height_range() {
        let hm = grid(17, 1.0, |x, y| x + 2.0 * y);
        let p = range_pyramid(&hm, 3);
        assert_eq!(p.get(0, 0, 0), 16.0 + 32.0);
        // Finest level: 4x4 nodes of 4 cells; node (0,0) covers samples 0..4 in each axis.
        assert_eq!(p.get(2, 0, 0), 3.0 + 6.0);
    }

    #[test]
    fn method_a_is_zero_on_planes_and_sees_a_bump() {
        let plane = grid(17, 2.0, |x, y| 3.0 * x - y);
        let p = d2_pyramid(&plane, 4);
        assert!(p.level(3).iter().all(|&v| v.abs() < 1e-6));
        let bump = Heightmap::from_fn(17, 17, Georef::local(2.0), |i, j| {
            if (i, j) == (8, 8) { 32.0 } else { 0.0 }
        })
        .unwrap();
        let p = d2_pyramid(&bump, 2);
        // Root: centre error 32 m over a 16-cell, 32 m node.
        assert!((p.get(0, 0, 0) - 1.0).abs() < 1e-6);
    }

    #[test]
    fn pyramids_index_like_the_quadtree() {
        use terrain_core::quadtree::Quadtree;
        for (w, h) in [(2, 2), (3, 3), (65, 65), (100, 77), (1000, 777), (5, 40), (1025, 513)] {
            let hm =
                Heightmap::from_fn(w, h, Georef::local(1.0), |i, j| (i * 3 + j) as f32).unwrap();
            for leaf in [1, 4, 16] {
                let qt = Quadtree::new(&hm, leaf);
                if leaf as usize <= root_cells(w, h) {
                    assert_eq!(qt.root_cells() as usize, root_cells(w, h), "{w}x{h} leaf {leaf}");
                } else {
                    // The quadtree's root grows to one leaf; it is then its only node.
                    assert_eq!(qt.max_level(), 0);
                }
            }
            // A node's value is the pixel at its level and position; deeper nodes read their
            // finest ancestor.
            let p = range_pyramid(&hm, 3);
            let qt = Quadtree::new(&hm, 1);
            for level in 0..3u8 {
                for j in 0..(1u32 << level) {
                    for i in 0..(1u32 << level) {
                        let n = NodeId::new(level, i, j);
                        assert_eq!(p.value(n), p.get(level as usize, i as usize, j as usize));
                        // Same samples: the range over the quadtree's clipped rectangle
                        // (half-open in the pyramid, so compare on nodes the grid covers).
                        if let Some(info) = qt.node_info(n).filter(|_| level == 0) {
                            let (lo, hi) = info.data_range.unwrap();
                            assert_eq!(p.value(n), hi - lo);
                        }
                    }
                }
            }
            for leaf in [1, 2, 16, 64, 4096] {
                let qt = Quadtree::new(&hm, leaf);
                assert_eq!(
                    quadtree_levels(w, h, leaf as usize),
                    qt.max_level() as usize + 1,
                    "{w}x{h} leaf {leaf}"
                );
            }
            if qt.max_level() >= 4 {
                let deep = NodeId::new(4, 3, 1);
                assert_eq!(p.value(deep), p.get(2, 0, 0));
            }
        }
    }

    #[test]
    fn normalized_pyramid_tops_at_255() {
        let hm = grid(17, 1.0, |x, y| x + 2.0 * y);
        let p = range_pyramid(&hm, 3).normalized_255();
        assert_eq!(p.get(0, 0, 0), 255.0);
        assert!((p.get(2, 0, 0) - 255.0 * 9.0 / 48.0).abs() < 1e-4);
        let flat = range_pyramid(&grid(9, 1.0, |_, _| 3.0), 2).normalized_255();
        assert!(flat.level(1).iter().all(|&v| v == 0.0));
    }

    #[test]
    fn odd_and_tiny_grids_do_not_panic() {
        for (w, h) in [(2, 2), (3, 3), (1000, 777), (5, 40)] {
            let hm =
                Heightmap::from_fn(w, h, Georef::local(1.0), |i, j| (i * 3 + j) as f32).unwrap();
            for p in [
                roughness_pyramid(&hm, 4, &RoughnessConfig::default()),
                range_pyramid(&hm, 4),
                d2_pyramid(&hm, 4),
            ] {
                assert_eq!(p.levels(), 4);
                assert!(p.level(3).iter().all(|v| v.is_finite()));
            }
        }
    }
}
