//! Paged heights: the grid the renderer draws, split into pages of `(cx + 1) x (cy + 1)`
//! samples of which only some are resident, so a DEM larger than memory (or than the device's
//! largest texture) renders. This is the CPU side and the CPU reference of the lookup
//! `terrain.wgsl` does (`height_sample`); [`crate::TerrainRenderer::new_paged`] keeps the same
//! pages in a texture atlas with a page table.
//!
//! # Pages
//! Page `(px, py)` covers grid samples `px cx ..= px cx + cx` by `py cy ..= py cy + cy`
//! ([`PageLayout`]), so neighbouring pages share their border samples, like the blocks of an
//! out-of-core store (a store block of `(2^k + 1)^2` vertices is one page with
//! `cx = cy = 2^k`). Samples of a page past the grid's east or north border are never read.
//! The whole-heightmap renderer ([`crate::TerrainRenderer::new`]) is the special case of one
//! page covering the grid, always resident.
//!
//! # The lookup (one rule on the CPU and the GPU)
//! Sample `(i, j)` (already clamped to the grid) belongs to page
//! `(min(i / cx, pages_x - 1), min(j / cy, pages_y - 1))`; when the sample lies on the page's
//! west (south) border, the page to the west (south) and the diagonal one hold it too. Of the
//! resident pages holding it, the one of the **finest** lattice (smallest stride) gives its
//! value, the first of them in that order where several are equally fine
//! ([`PagedHeights::locate`]). A border sample is thus exact whenever either side holds it at
//! full resolution: a coarse neighbour's interpolated value never replaces a finer page's own
//! border (that step between a page's last sample and a coarse neighbour's border showed as a
//! dark seam along block borders in the shading). Every sample has one value for a given set
//! of resident pages, so the drawn surface (the
//! bilinear interpolation of the samples, [`crate::surface`]) is one continuous function of
//! the grid position: patches that agree on their shared edges' tessellation meet without
//! cracks whatever level each page was filled from. A sample on no resident page reads as 0
//! (callers draw only over resident pages), and the normals' central differences become
//! one-sided where a neighbouring sample is on no resident page, as at the grid's border.
//!
//! # Filling a page from a coarse level
//! A store block with only its levels `0..=L` resident has the level-`L` vertices, every
//! `d = 2^(k - L)` samples. [`fill_from_level`] fills the page's other samples by **bilinear**
//! interpolation in the level-`L` cell around them (the standard choice for a regular grid
//! and the same interpolation the renderer applies between samples, so the drawn surface of
//! such a page *is* the bilinear surface of the level-`L` grid). The renderer and
//! [`crate::surface`] only ever see the filled samples, so they agree exactly.

use std::collections::BTreeMap;

use glam::DVec2;
use terrain_core::Heightmap;

/// A grid of heights the renderer can draw, fully resident or paged: what [`crate::surface`]
/// reads.
pub trait HeightGrid {
    /// Width and height in samples.
    fn size(&self) -> [u32; 2];
    /// World position (metres) of sample `(0, 0)` and the spacing in metres (x east, y north).
    fn frame(&self) -> (DVec2, DVec2);
    /// Height of sample `(i, j)` (inside the grid), or `None` where it is on no resident page.
    fn sample(&self, i: u32, j: u32) -> Option<f32>;
}

impl HeightGrid for Heightmap {
    fn size(&self) -> [u32; 2] {
        [self.width() as u32, self.height() as u32]
    }

    fn frame(&self) -> (DVec2, DVec2) {
        (self.georef().world_origin, self.georef().spacing_m)
    }

    fn sample(&self, i: u32, j: u32) -> Option<f32> {
        Some(self.get(i as usize, j as usize))
    }
}

/// How a grid is cut into pages.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PageLayout {
    /// Grid width and height in samples (at least 1 each).
    pub grid: [u32; 2],
    /// Cells per page along x and y (a page holds `cells + 1` samples per side; at least 1).
    pub page_cells: [u32; 2],
    /// World position (metres) of sample `(0, 0)`.
    pub origin: DVec2,
    /// Spacing in metres (x east, y north), positive.
    pub spacing: DVec2,
}

impl PageLayout {
    /// One page covering the whole of `hm` (the whole-heightmap renderer's layout).
    pub fn whole(hm: &Heightmap) -> Self {
        let grid = [hm.width() as u32, hm.height() as u32];
        let (origin, spacing) = hm.frame();
        Self { grid, page_cells: grid.map(|n| n.saturating_sub(1).max(1)), origin, spacing }
    }

    /// Pages along x and y.
    pub fn pages(&self) -> [u32; 2] {
        let c = self.cells();
        [0, 1].map(|a| self.grid[a].saturating_sub(1).div_ceil(c[a]).max(1))
    }

    /// Cells per page, at least 1.
    pub fn cells(&self) -> [u32; 2] {
        self.page_cells.map(|c| c.max(1))
    }

    /// Samples per page side as stored: `cells + 1`, but no more than the grid has.
    pub fn page_samples(&self) -> [u32; 2] {
        let c = self.cells();
        [0, 1].map(|a| (c[a] + 1).min(self.grid[a].max(1)))
    }

    /// Number of samples one page holds.
    pub fn page_len(&self) -> usize {
        let [w, h] = self.page_samples();
        w as usize * h as usize
    }

    /// The lattice a page of `stride` stores, samples per side: [`PageLayout::page_samples`]
    /// for stride 1, else `cells / stride + 1` (whole, even past the grid's border). `None`
    /// when `stride` is not 1 or a power of two dividing both cell counts.
    pub fn lattice(&self, stride: u32) -> Option<[u32; 2]> {
        if stride == 1 {
            return Some(self.page_samples());
        }
        let c = self.cells();
        (stride.is_power_of_two() && c.iter().all(|&n| n.is_multiple_of(stride)))
            .then(|| c.map(|n| n / stride + 1))
    }

    /// The strides a page may be stored at: 1, 2, 4, ... while they divide both cell counts.
    pub fn strides(&self) -> Vec<u32> {
        let mut out = vec![1];
        while self.lattice(out[out.len() - 1] * 2).is_some() {
            out.push(out[out.len() - 1] * 2);
        }
        out
    }

    /// The pages that may hold sample `(i, j)`, in lookup order (see the module docs).
    pub fn candidates(&self, i: u32, j: u32) -> [[u32; 2]; 4] {
        let c = self.cells();
        let n = self.pages();
        let p0 = [(i / c[0]).min(n[0] - 1), (j / c[1]).min(n[1] - 1)];
        let back = |g: u32, p: u32, c: u32| if g == p * c && p > 0 { p - 1 } else { p };
        let p1 = [back(i, p0[0], c[0]), back(j, p0[1], c[1])];
        [[p0[0], p0[1]], [p1[0], p0[1]], [p0[0], p1[1]], [p1[0], p1[1]]]
    }
}

/// One resident page: the lattice of samples it stores, row-major, south row first, and the
/// lattice's stride.
#[derive(Debug, Clone, PartialEq)]
pub struct Page {
    /// [`PageLayout::lattice`]`(stride)` wide and high, row-major, south row first: with
    /// `stride` 1 every sample of the page ([`PageLayout::page_samples`]), else every
    /// `stride`-th sample (a store block's level `L` with `stride = 2^(k - L)`), the others
    /// read by bilinear interpolation in the lattice cell around them ([`lattice_bilinear`]).
    pub samples: Vec<f32>,
    /// Grid samples between lattice samples: 1, or a power of two dividing the page's cells.
    pub stride: u32,
}

/// Why a page was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum PageError {
    /// The page is outside the layout.
    #[error("page {page:?} is outside the {pages:?} pages of the layout")]
    OutOfRange {
        /// The page.
        page: [u32; 2],
        /// Pages along x and y.
        pages: [u32; 2],
    },
    /// The samples do not fill a page.
    #[error("page {page:?} has {got} samples; a page holds {expected}")]
    WrongLength {
        /// The page.
        page: [u32; 2],
        /// Samples given.
        got: usize,
        /// Samples a page holds.
        expected: usize,
    },
    /// A sample is not finite.
    #[error("page {page:?} has a non-finite height at index {index}")]
    NotFinite {
        /// The page.
        page: [u32; 2],
        /// The sample's index.
        index: usize,
    },
    /// Every page slot of the renderer's atlas for the page's stride is taken.
    #[error("no free page slot of stride {stride} for page {page:?}: all {capacity} are resident")]
    Full {
        /// The page.
        page: [u32; 2],
        /// Slots of that stride in the atlas.
        capacity: u32,
        /// The page's stride.
        stride: u32,
    },
    /// The stride is not one the layout's pages (or the renderer's slot classes) allow.
    #[error("page {page:?} has stride {stride}; allowed: {allowed:?}")]
    BadStride {
        /// The page.
        page: [u32; 2],
        /// The stride given.
        stride: u32,
        /// The strides allowed.
        allowed: Vec<u32>,
    },
}

/// Checks a page of `stride` for `layout`.
pub(crate) fn check_page(
    layout: &PageLayout,
    page: [u32; 2],
    samples: &[f32],
    stride: u32,
) -> Result<(), PageError> {
    let pages = layout.pages();
    if page[0] >= pages[0] || page[1] >= pages[1] {
        return Err(PageError::OutOfRange { page, pages });
    }
    let Some([w, h]) = layout.lattice(stride) else {
        return Err(PageError::BadStride { page, stride, allowed: layout.strides() });
    };
    let expected = w as usize * h as usize;
    if samples.len() != expected {
        return Err(PageError::WrongLength { page, got: samples.len(), expected });
    }
    if let Some(index) = samples.iter().position(|h| !h.is_finite()) {
        return Err(PageError::NotFinite { page, index });
    }
    Ok(())
}

/// The CPU mirror of the pages a paged renderer holds: the CPU reference of its heights.
#[derive(Debug, Clone, PartialEq)]
pub struct PagedHeights {
    layout: PageLayout,
    pages: BTreeMap<[u32; 2], Page>,
}

impl PagedHeights {
    /// No page resident.
    pub fn new(layout: PageLayout) -> Self {
        Self { layout, pages: BTreeMap::new() }
    }

    /// Every page of `hm` resident at full resolution (tests; small grids).
    pub fn from_heightmap(hm: &Heightmap, page_cells: u32) -> Self {
        let (origin, spacing) = hm.frame();
        let layout =
            PageLayout { grid: hm.size(), page_cells: [page_cells.max(1); 2], origin, spacing };
        let mut out = Self::new(layout);
        let [nx, ny] = layout.pages();
        for py in 0..ny {
            for px in 0..nx {
                let samples =
                    page_from_grid(&layout, [px, py], |i, j| hm.get(i as usize, j as usize));
                out.insert([px, py], Page { samples, stride: 1 }).expect("a page of the grid");
            }
        }
        out
    }

    /// The layout.
    pub fn layout(&self) -> &PageLayout {
        &self.layout
    }

    /// Makes `page` resident (replacing what it held).
    pub fn insert(&mut self, page: [u32; 2], value: Page) -> Result<(), PageError> {
        check_page(&self.layout, page, &value.samples, value.stride)?;
        self.pages.insert(page, value);
        Ok(())
    }

    /// Drops `page`; returns whether it was resident.
    pub fn remove(&mut self, page: [u32; 2]) -> bool {
        self.pages.remove(&page).is_some()
    }

    /// A resident page.
    pub fn get(&self, page: [u32; 2]) -> Option<&Page> {
        self.pages.get(&page)
    }

    /// The resident pages, in page order (row `py`, then `px`, as `[px, py]` sorts).
    pub fn pages(&self) -> impl Iterator<Item = (&[u32; 2], &Page)> {
        self.pages.iter()
    }

    /// The resident page holding sample `(i, j)` and the sample's position in it: of the
    /// candidates ([`PageLayout::candidates`]) resident, the one of the smallest stride, the
    /// first in candidate order among equals (see the module docs).
    pub fn locate(&self, i: u32, j: u32) -> Option<([u32; 2], [u32; 2])> {
        let c = self.layout.cells();
        let mut best: Option<([u32; 2], u32)> = None;
        for p in self.layout.candidates(i, j) {
            if let Some(page) = self.pages.get(&p)
                && best.is_none_or(|(_, s)| page.stride < s)
            {
                best = Some((p, page.stride));
            }
        }
        best.map(|(p, _)| (p, [i - p[0] * c[0], j - p[1] * c[1]]))
    }

    /// Samples of pages resident: a full-size heightmap of the drawn heights, the rest from
    /// `fallback` (benchmark DEMs, which fit in memory).
    pub fn to_heightmap(&self, fallback: &Heightmap) -> Heightmap {
        let (w, h) = (fallback.width(), fallback.height());
        let mut data = fallback.data().to_vec();
        // Pages written coarse to fine, and among equal strides south to north, west to east:
        // where pages share a sample, the one written last is the one `locate` picks (the
        // finest; among equals the first it tries: east before west, north before south), so
        // every sample gets the lookup's value.
        let mut order: Vec<&[u32; 2]> = self.pages.keys().collect();
        order.sort_by_key(|p| (std::cmp::Reverse(self.pages[*p].stride), p[1], p[0]));
        let c = self.layout.cells();
        let [pw, ph] = self.layout.page_samples();
        for p in order {
            let expanded = self.pages[p].expanded(&self.layout);
            let samples = &expanded;
            for b in 0..ph as usize {
                let j = (p[1] * c[1]) as usize + b;
                if j >= h {
                    break;
                }
                let i0 = (p[0] * c[0]) as usize;
                let n = (pw as usize).min(w.saturating_sub(i0));
                let row = &samples[b * pw as usize..b * pw as usize + n];
                data[j * w + i0..j * w + i0 + n].copy_from_slice(row);
            }
        }
        Heightmap::new(w, h, data, fallback.voids().clone(), fallback.georef().clone())
            .expect("pages hold finite heights only")
    }
}

impl HeightGrid for PagedHeights {
    fn size(&self) -> [u32; 2] {
        self.layout.grid
    }

    fn frame(&self) -> (DVec2, DVec2) {
        (self.layout.origin, self.layout.spacing)
    }

    fn sample(&self, i: u32, j: u32) -> Option<f32> {
        let (p, [a, b]) = self.locate(i, j)?;
        Some(self.pages[&p].height(&self.layout, a, b))
    }
}

impl Page {
    /// The height of the page's sample `(a, b)` (page-local): the stored sample at stride 1,
    /// else the bilinear interpolation in its lattice cell ([`lattice_bilinear`]).
    pub fn height(&self, layout: &PageLayout, a: u32, b: u32) -> f32 {
        let w = layout.lattice(self.stride).map_or(1, |l| l[0]);
        if self.stride == 1 {
            return self.samples[(b * w + a) as usize];
        }
        let n = layout.cells().map(|c| c / self.stride);
        lattice_bilinear(|x, y| self.samples[(y * w + x) as usize], n, self.stride, a, b)
    }

    /// Every sample of the page ([`PageLayout::page_samples`] wide and high), as
    /// [`Page::height`] reads them.
    pub fn expanded(&self, layout: &PageLayout) -> Vec<f32> {
        if self.stride == 1 {
            return self.samples.clone();
        }
        let [w, h] = layout.page_samples();
        (0..h).flat_map(|b| (0..w).map(move |a| self.height(layout, a, b))).collect()
    }
}

/// Sample `(x, y)` of a page read from its lattice of `n` cells per side at `stride`
/// (`at(a, b)` the lattice sample): bilinear in the lattice cell around it, the cell index
/// clamped to `n - 1` so the page's east and north border samples are in its last cell. The
/// same operations in f32 as `lattice_height` in `terrain.wgsl` and [`fill_from_level`].
pub fn lattice_bilinear(
    at: impl Fn(u32, u32) -> f32,
    n: [u32; 2],
    stride: u32,
    x: u32,
    y: u32,
) -> f32 {
    let d = stride;
    let a = (x / d).min(n[0] - 1);
    let b = (y / d).min(n[1] - 1);
    let fx = (x - a * d) as f32 / d as f32;
    let fy = (y - b * d) as f32 / d as f32;
    let (h00, h10, h01, h11) = (at(a, b), at(a + 1, b), at(a, b + 1), at(a + 1, b + 1));
    let lo = h00 + (h10 - h00) * fx;
    let hi = h01 + (h11 - h01) * fx;
    lo + (hi - lo) * fy
}

/// One class of page slots of a paged renderer: pages stored at `stride`, `capacity` of
/// them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PageClass {
    /// The stride of the pages the class holds ([`PageLayout::lattice`]).
    pub stride: u32,
    /// Slots.
    pub capacity: u32,
}

impl PageClass {
    /// Bytes of one slot of this class for `layout` (f32 samples).
    pub fn slot_bytes(&self, layout: &PageLayout) -> u64 {
        let [w, h] = layout.lattice(self.stride).unwrap_or([1, 1]);
        4 * u64::from(w) * u64::from(h)
    }
}

/// Slot classes for every stride of `layout` within `budget_bytes` of atlas: the budget is
/// shared equally between the classes, smallest slots first, no class holding more slots than
/// the layout has pages (what it leaves goes to the larger classes). A coarse class of
/// stride `s` thus holds about `s^2` times the pages of the finest class for the same bytes.
/// Every class gets at least one slot.
pub fn classes_for_budget(layout: &PageLayout, budget_bytes: u64) -> Vec<PageClass> {
    let pages = layout.pages();
    let all = u64::from(pages[0]) * u64::from(pages[1]);
    let mut strides = layout.strides();
    strides.reverse(); // smallest slots first
    let mut left = budget_bytes;
    let mut out = Vec::new();
    for (k, &stride) in strides.iter().enumerate() {
        let class = PageClass { stride, capacity: 0 };
        let share = left / (strides.len() - k) as u64;
        let n = (share / class.slot_bytes(layout)).clamp(1, all.min(MAX_CLASS_SLOTS));
        left = left.saturating_sub(n * class.slot_bytes(layout));
        out.push(PageClass { stride, capacity: n as u32 });
    }
    out.reverse();
    out
}

/// The most slots one class may have (the page table packs a slot in 24 bits).
pub const MAX_CLASS_SLOTS: u64 = (1 << 24) - 2;

/// The samples of `page` read from a whole grid by `get(i, j)` (clamped to the grid: samples
/// past the east or north border repeat the last column or row, as store padding does).
pub fn page_from_grid(
    layout: &PageLayout,
    page: [u32; 2],
    get: impl Fn(u32, u32) -> f32,
) -> Vec<f32> {
    let [w, h] = layout.page_samples();
    let c = layout.cells();
    let mut out = Vec::with_capacity(layout.page_len());
    for b in 0..h {
        for a in 0..w {
            let i = (page[0] * c[0] + a).min(layout.grid[0] - 1);
            let j = (page[1] * c[1] + b).min(layout.grid[1] - 1);
            out.push(get(i, j));
        }
    }
    out
}

/// A page of `(cells + 1)^2` samples filled from the `(n + 1)^2` vertices of a coarse level
/// (`n` a power of two dividing `cells`; row-major, south row first) by bilinear interpolation
/// in each coarse cell (see the module docs), in f32. `None` when the sizes do not fit.
pub fn fill_from_level(level: &[f32], cells: u32) -> Option<Vec<f32>> {
    let side = (level.len() as f64).sqrt() as u32;
    if side < 2 || side * side != level.len() as u32 || !cells.is_multiple_of(side - 1) {
        return None;
    }
    let n = side - 1;
    let d = cells / n;
    let at = |a: u32, b: u32| level[(b * side + a) as usize];
    let mut out = Vec::with_capacity(((cells + 1) * (cells + 1)) as usize);
    for y in 0..=cells {
        for x in 0..=cells {
            out.push(lattice_bilinear(at, [n, n], d, x, y));
        }
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use terrain_core::synth::default_terrain;

    #[test]
    fn all_pages_resident_read_like_the_heightmap() {
        let hm = default_terrain();
        let paged = PagedHeights::from_heightmap(&hm, 32);
        assert!(paged.layout().pages()[0] > 1);
        for j in 0..hm.height() as u32 {
            for i in 0..hm.width() as u32 {
                assert_eq!(paged.sample(i, j), hm.sample(i, j), "({i}, {j})");
            }
        }
    }

    #[test]
    fn shared_samples_fall_back_to_the_neighbouring_page() {
        let hm = default_terrain();
        let mut paged = PagedHeights::from_heightmap(&hm, 32);
        assert!(paged.remove([1, 1]));
        // (32, 32) is the south-west corner of page (1, 1): page (0, 0) holds it too.
        assert_eq!(paged.locate(32, 32), Some(([0, 1], [32, 0])));
        assert_eq!(paged.locate(40, 32), Some(([1, 0], [8, 32])));
        assert_eq!(paged.locate(40, 40), None);
        assert_eq!(paged.sample(32, 32), hm.sample(32, 32));
        // The whole-grid copy agrees with the lookup everywhere a page is resident.
        let mut mixed = paged.clone();
        let mut p = mixed.get([1, 0]).unwrap().clone();
        p.samples.iter_mut().for_each(|h| *h += 1000.0);
        mixed.insert([1, 0], p).unwrap();
        let copy = mixed.to_heightmap(&hm);
        for j in 0..hm.height() as u32 {
            for i in 0..hm.width() as u32 {
                let want = mixed.sample(i, j).unwrap_or(hm.get(i as usize, j as usize));
                assert_eq!(copy.get(i as usize, j as usize), want, "({i}, {j})");
            }
        }
    }

    #[test]
    fn shared_samples_come_from_the_finest_page() {
        let hm = default_terrain();
        let full = PagedHeights::from_heightmap(&hm, 32);
        let layout = *full.layout();
        // Page (0, 0) at full resolution, page (1, 0) east of it at stride 8.
        let mut mixed = PagedHeights::new(layout);
        mixed.insert([0, 0], full.get([0, 0]).unwrap().clone()).unwrap();
        let w = layout.page_samples()[0];
        let east = &full.get([1, 0]).unwrap().samples;
        let lattice: Vec<f32> = (0..=4)
            .flat_map(|b| (0..=4).map(move |a| east[(b * 8 * w + a * 8) as usize]))
            .collect();
        mixed.insert([1, 0], Page { samples: lattice, stride: 8 }).unwrap();
        // The shared column x = 32: exact from the fine page, though the coarse page comes
        // first in candidate order and would interpolate between its lattice rows.
        let mut interpolated = 0;
        for j in 0..=32 {
            assert_eq!(mixed.locate(32, j).unwrap().0, [0, 0], "row {j}");
            assert_eq!(mixed.sample(32, j), hm.sample(32, j), "row {j}");
            let l = &mixed.get([1, 0]).unwrap().samples;
            let coarse = lattice_bilinear(|a, b| l[(b * 5 + a) as usize], [4, 4], 8, 0, j);
            interpolated += usize::from(coarse != hm.get(32, j as usize));
        }
        assert!(interpolated > 0, "the coarse page's border differs (the control)");
        // Equal strides: east (the page it falls in) first.
        assert_eq!(full.locate(32, 5).unwrap().0, [1, 0]);
        let copy = mixed.to_heightmap(&hm);
        for j in 0..=32u32 {
            assert_eq!(Some(copy.get(32, j as usize)), mixed.sample(32, j));
        }
    }

    #[test]
    fn a_level_fills_its_page_bilinearly() {
        // A 3 x 3 level (n = 2) into 4 cells: every other sample is a level vertex.
        let level = [0.0, 2.0, 4.0, 1.0, 3.0, 5.0, 2.0, 4.0, 10.0];
        let page = fill_from_level(&level, 4).unwrap();
        assert_eq!(page.len(), 25);
        assert_eq!(page[0], 0.0);
        assert_eq!(page[1], 1.0); // half way along the south edge
        assert_eq!(page[2], 2.0);
        assert_eq!(page[24], 10.0);
        // Centre of the north-east coarse cell: mean of 3, 5, 4, 10.
        assert_eq!(page[3 * 5 + 3], 5.5);
        assert!(fill_from_level(&level, 3).is_none());
        assert!(fill_from_level(&level[..8], 4).is_none());
    }

    #[test]
    fn a_coarse_page_reads_like_its_filled_page() {
        let hm = default_terrain();
        let full = PagedHeights::from_heightmap(&hm, 32);
        let layout = *full.layout();
        assert_eq!(layout.strides(), vec![1, 2, 4, 8, 16, 32]);
        assert_eq!(layout.lattice(8), Some([5, 5]));
        assert_eq!(layout.lattice(3), None);
        let mut coarse = PagedHeights::new(layout);
        let mut filled = PagedHeights::new(layout);
        for (k, (&page, p)) in full.pages().enumerate() {
            let d = 1u32 << (k % 6);
            let n = 32 / d;
            let w = layout.page_samples()[0];
            let lattice: Vec<f32> = (0..=n)
                .flat_map(|b| (0..=n).map(move |a| (a, b)))
                .map(|(a, b)| p.samples[(b * d * w + a * d) as usize])
                .collect();
            let f = fill_from_level(&lattice, 32).unwrap();
            coarse.insert(page, Page { samples: lattice, stride: d }).unwrap();
            filled.insert(page, Page { samples: f, stride: 1 }).unwrap();
        }
        let mut differs = 0;
        let copy = coarse.to_heightmap(&hm);
        for j in 0..hm.height() as u32 {
            for i in 0..hm.width() as u32 {
                // Inside a page, the lattice reads like its filled page; a shared border sample
                // comes from the finest page holding it (the filled pages all claim stride 1).
                if i % 32 != 0 && j % 32 != 0 {
                    assert_eq!(coarse.sample(i, j), filled.sample(i, j), "({i}, {j})");
                }
                differs += usize::from(coarse.sample(i, j) != hm.sample(i, j));
                assert_eq!(Some(copy.get(i as usize, j as usize)), coarse.sample(i, j));
            }
        }
        assert!(differs > 1000, "coarse pages change the surface: {differs}");
        let bad = Page { samples: vec![0.0; 9], stride: 32 };
        assert!(matches!(coarse.insert([0, 0], bad), Err(PageError::WrongLength { .. })));
        let bad = Page { samples: vec![0.0; 9], stride: 64 };
        assert!(matches!(coarse.insert([0, 0], bad), Err(PageError::BadStride { .. })));
    }

    #[test]
    fn classes_share_the_budget_and_coarse_ones_hold_more_pages() {
        let layout = PageLayout {
            grid: [32769, 32769],
            page_cells: [256, 256],
            origin: DVec2::ZERO,
            spacing: DVec2::ONE,
        };
        let budget = 256u64 << 20;
        let classes = classes_for_budget(&layout, budget);
        assert_eq!(classes.len(), 9);
        assert_eq!(classes[0].stride, 1);
        let bytes: u64 =
            classes.iter().map(|c| c.slot_bytes(&layout) * u64::from(c.capacity)).sum();
        assert!(bytes <= budget, "{bytes}");
        assert!(bytes > budget / 10 * 9, "{bytes}");
        // The coarsest classes hold every page; finer classes hold fewer, the finest fewest.
        assert_eq!(classes[8].capacity, 128 * 128);
        for w in classes.windows(2) {
            assert!(w[0].capacity <= w[1].capacity, "{classes:?}");
        }
        assert!(classes[0].capacity >= 100, "{classes:?}");
        // A budget smaller than one slot per class still gives one slot each.
        assert!(classes_for_budget(&layout, 0).iter().all(|c| c.capacity == 1));
    }
}
